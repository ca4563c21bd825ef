"""``solve``: integrate a partitioned index-2 DAE over an interval and return a :class:`Solution`.

The order of work: validate every option (paths included) → validate the problem and the
initial values → the loop :class:`~lobattodae._loop.State` → compiled chunks of the loop
(progress, Ctrl-C, checkpoints, recovery of failed steps) → :class:`Solution`.
"""

from __future__ import annotations

import math
import os
import signal
import sys
import threading
import time
import warnings
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Any, Callable, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from . import _checkpoint
from ._errors import LobattoDAEInputError, NewtonFailure
from ._loop import CHUNK, ConstantStepSize, Record, State, init_compiled, run_compiled
from ._results import Result
from ._stepper import LobattoIIIAIIIB
from ._validate import check_float64, validate_and_residual

__all__ = ["Solution", "solve", "STATS"]

#: The keys of ``Solution.stats`` (the one place they are documented).
STATS = {
    "newton_iterations": "(N,) Newton iterations of each step",
    "residual_norm": "(N,) max-norm of the last Newton residual of each step",
    "constraint_residual": "(N+1,) ‖φ(t_k, q_k, p_k)‖∞",
    "multiplier_drift": "(N+1,) ‖λ_k − λ(t_k, q_k, p_k)‖∞, the distance of λ from the hidden constraint",
    "lam_resync": "(N,) bool: the step started from λ(t_k, q_k, p_k) (lam_start='auto' re-synchronised λ)",
    "lam_resets": "number of re-synchronisations of λ (lam_start='auto')",
    "lam_excursions": "steps where the drift left its normal band (re-synchronised with 'auto', only counted otherwise)",
    "n_jacobians": "Newton Jacobian evaluations (each with one factorisation)",
    "n_newton": "Newton iterations in all",
    "h": "the step size",
    "n_steps": "the number of steps asked for",
    "failed_step": "index of the failed step, or None",
    "recoveries": "failed steps retried as substeps (max_recoveries)",
    "compile_and_run_time": "wall time of the integration loop, compilation included (s)",
}

#: Automatic recovery retries a failed step as 2, 4, 8, 16 substeps (one compiled chunk of 16).
_RECOVERY_HALVINGS = 4


@dataclass(frozen=True, eq=False)
class Solution:
    """The result of :func:`solve` (time-major NumPy arrays).

    Attributes
    ----------
    t : ndarray, shape (N+1,)
    q, p : ndarray, shape (N+1, n)
    lam : ndarray, shape (N+1, m)
        The multiplier λ_k at t_k (λ_0 is the consistent initial value).
    success : bool
    status : Result
        ``Result.SUCCESSFUL`` or the reason the integration stopped early.
    message : str
    stats : dict
        See :data:`STATS`. When the solve stopped early the arrays hold the computed prefix.
    problem, method, args
        What was solved, for diagnostics.
    """

    t: np.ndarray
    q: np.ndarray
    p: np.ndarray
    lam: np.ndarray
    success: bool
    status: Result
    message: str
    stats: dict = field(repr=False)
    problem: Any = field(repr=False, default=None)
    method: Any = field(repr=False, default=None)
    args: Any = field(repr=False, default=None)

    def __repr__(self) -> str:
        return (
            f"Solution(success={self.success}, status={self.status.name}, n_steps={len(self.t) - 1}, "
            f"t=[{self.t[0]:g}, {self.t[-1]:g}], max constraint residual="
            f"{np.max(self.stats['constraint_residual']):.2e})"
        )


# -- options ------------------------------------------------------------------------------------
@dataclass(frozen=True)
class _Options:
    """Every option of :func:`solve`, checked before any work is done."""

    t0: float
    t1: float
    n: int
    h: float
    chunk: int
    max_recoveries: int
    checkpoint: str | None
    checkpoint_every: int | None
    resume: bool

    @classmethod
    def check(cls, method, t_span, n_steps, dt, chunk_size, max_recoveries, checkpoint, checkpoint_every, resume):
        if not isinstance(method, LobattoIIIAIIIB):
            raise TypeError(
                f"method must be a LobattoIIIAIIIB instance, e.g. LobattoIIIAIIIB(stages=3); got {method!r}."
            )
        t0, t1 = _check_t_span(t_span)
        n, h = _step_count(t0, t1, n_steps, dt)
        if chunk_size is not None and (isinstance(chunk_size, bool) or not isinstance(chunk_size, int) or chunk_size < 1):
            raise LobattoDAEInputError(f"chunk_size must be a positive integer; got {chunk_size!r}.")
        if isinstance(max_recoveries, bool) or not isinstance(max_recoveries, int) or max_recoveries < 0:
            raise LobattoDAEInputError(f"max_recoveries must be a non-negative integer; got {max_recoveries!r}.")
        if checkpoint_every is not None and (
            isinstance(checkpoint_every, bool) or not isinstance(checkpoint_every, int) or checkpoint_every < 1
        ):
            raise LobattoDAEInputError(f"checkpoint_every must be a positive integer; got {checkpoint_every!r}.")
        if resume and checkpoint is None:
            raise LobattoDAEInputError("resume=True needs the checkpoint file to resume from (checkpoint=PATH).")
        path = None
        if checkpoint is not None:
            path = os.fspath(checkpoint)
            check_writable(path, "checkpoint")
        return cls(t0, t1, n, h, chunk_size or CHUNK, max_recoveries, path, checkpoint_every, bool(resume))


def check_writable(path: str, what: str) -> None:
    """Refuse up front a file that could not be written after the work (missing directory)."""
    directory = os.path.dirname(os.path.abspath(path))
    if not os.path.isdir(directory):
        raise LobattoDAEInputError(
            f"cannot write the {what} '{path}': the directory '{directory}' does not exist; create it first."
        )
    if not os.access(directory, os.W_OK):
        raise LobattoDAEInputError(f"cannot write the {what} '{path}': the directory '{directory}' is not writable.")
    if os.path.isdir(path):
        raise LobattoDAEInputError(f"cannot write the {what} '{path}': it is a directory.")


def _step_count(t0: float, t1: float, n_steps, dt) -> tuple[int, float]:
    if (n_steps is None) == (dt is None):
        raise LobattoDAEInputError("give exactly one of n_steps (number of steps) or dt (step size).")
    span = t1 - t0
    if n_steps is not None:
        if isinstance(n_steps, bool) or not isinstance(n_steps, (int, np.integer)):
            raise LobattoDAEInputError(f"n_steps must be a positive integer; got {n_steps!r}.")
        if n_steps <= 0:
            raise LobattoDAEInputError(f"n_steps must be a positive integer; got n_steps={n_steps}.")
        n = int(n_steps)
    else:
        if isinstance(dt, (bool, str)) or not isinstance(dt, (int, float, np.integer, np.floating)):
            raise LobattoDAEInputError(f"dt must be a positive finite number; got {dt!r}.")
        dt = float(dt)
        if not (math.isfinite(dt) and dt > 0):
            raise LobattoDAEInputError(f"dt must be a positive finite step size; got dt={dt!r}.")
        n = max(1, math.ceil(span / dt * (1 - 1e-12)))
    return n, span / n


def _check_t_span(t_span) -> tuple[float, float]:
    try:
        t0, t1 = (float(x) for x in t_span)
    except (TypeError, ValueError):
        raise LobattoDAEInputError(f"t_span must be a pair (t0, t1) of numbers; got {t_span!r}.") from None
    if not (math.isfinite(t0) and math.isfinite(t1)):
        raise LobattoDAEInputError(f"t_span must be finite; got {t_span!r}.")
    if not t1 > t0:
        raise LobattoDAEInputError(
            f"t_span = ({t0}, {t1}) is empty or reversed; solve integrates forward and needs t1 > t0 "
            "(for a step backwards use method.step with a negative h)."
        )
    return t0, t1


# -- the run ------------------------------------------------------------------------------------
class _Progress(NamedTuple):
    """How far a run got: replaced as a whole (one assignment), so that an interrupt can never
    see a step count that does not belong to the state and the rows."""

    done: int
    state: State
    rows: tuple  # of Record chunks (NumPy)
    recoveries: int


def solve(
    problem,
    method: LobattoIIIAIIIB,
    t_span,
    q0,
    p0,
    *,
    n_steps: int | None = None,
    dt: float | None = None,
    lam0=None,
    args: Any = None,
    throw: bool = True,
    project_initial: bool = False,
    chunk_size: int | None = None,
    progress: bool | Callable[[int, int], None] = False,
    max_recoveries: int = 0,
    checkpoint: str | os.PathLike | None = None,
    checkpoint_every: int | None = None,
    resume: bool = False,
) -> Solution:
    """Integrate a partitioned index-2 DAE from ``t_span[0]`` to ``t_span[1]``.

    Parameters
    ----------
    problem : PartitionedDAE, NonholonomicSystem or MechanicalSystem
        Reuse one problem object and pass parameters through ``args``: the compiled loop is
        cached per problem object, method and shapes, so new numbers (initial values,
        ``t_span``, ``n_steps``, ``args`` values) do not recompile.
    method : LobattoIIIAIIIB
    t_span : (float, float)
        ``(t0, t1)`` with ``t1 > t0``.
    q0, p0 : array_like, shape (n,)
        Consistent initial values, ``φ(t0, q0, p0) = 0``.
    n_steps, dt : int or float
        Exactly one: the number of steps, or a maximal step size (the step used is
        ``h = (t1 - t0) / ceil((t1 - t0) / dt)``, reported in ``stats["h"]``).
    lam0 : array_like, shape (m,), optional
        Initial multiplier. Computed from the hidden constraint when omitted; checked
        against it when given.
    args : pytree, optional
        Passed to the problem functions.
    throw : bool
        If True (default) a failed step raises :class:`NewtonFailure`; otherwise the
        computed prefix is returned with ``success=False`` and the status.
    project_initial : bool
        Replace ``p0`` by its least-squares projection onto the constraint
        {p : φ(t0, q0, p) = 0} (always, to round-off) instead of rejecting inconsistent values.
    chunk_size : int, optional
        Steps per compiled chunk (default :data:`~lobattodae._loop.CHUNK`); progress, Ctrl-C
        and checkpoints act between chunks.
    progress : bool or callable
        ``True`` shows a progress bar on stderr once the run has taken more than a second; a
        callable is called as ``progress(steps_done, n_steps)`` after each chunk. Ctrl-C
        returns the computed prefix with status ``INTERRUPTED`` at the end of the chunk (a
        second Ctrl-C stops at once).
    max_recoveries : int
        Automatic recovery (off by default): a step whose Newton iteration fails is retried as
        2, 4, 8 or 16 substeps, at most this many times per solve; ``stats["recoveries"]``
        counts them. The recovered step restarts the Jacobian and the predictor.
    checkpoint : path, optional
        Write the computed prefix and the loop state to this file (format:
        :mod:`lobattodae._checkpoint`) every ``checkpoint_every`` steps (at chunk boundaries),
        at the end, and on Ctrl-C. Its directory must exist.
    checkpoint_every : int, optional
    resume : bool
        Continue from ``checkpoint`` if it exists. It must come from the same run: problem
        functions, method, ``args``, ``t_span``, step and initial values are checked. A resumed
        run gives the same numbers, bit for bit, as an uninterrupted one.

    Returns
    -------
    Solution
    """
    check_float64()
    opt = _Options.check(method, t_span, n_steps, dt, chunk_size, max_recoveries, checkpoint, checkpoint_every, resume)
    # From here on a first Ctrl-C only asks the run to stop at the next chunk boundary (also
    # during validation and compilation), so it never lands inside JAX or between updates.
    with _deferred_interrupts() as interrupted:
        return _run(problem, method, opt, q0, p0, lam0, args, throw, project_initial, progress, interrupted)


def _run(problem, method, opt: _Options, q0, p0, lam0, args, throw, project_initial, progress, interrupted):
    """Validation, the loop state, the compiled chunks (progress, checkpoints, recovery), the
    Solution; ``interrupted()`` says whether Ctrl-C asked to stop."""
    q0, p0, lam0, phi0 = validate_and_residual(problem, opt.t0, q0, p0, lam0, args, project=project_initial)
    report = _progress_reporter(progress)
    controller = ConstantStepSize()
    f64 = jnp.float64
    state = init_compiled(
        problem, method, controller, jnp.asarray(opt.t0, f64), jnp.asarray(opt.t1, f64), opt.n,
        jnp.asarray(q0), jnp.asarray(p0), jnp.asarray(lam0), args,
    )
    run = _Progress(0, state, (), 0)
    meta = _run_identity(problem, method, args, opt, q0, p0, lam0) if opt.checkpoint else None
    if opt.checkpoint and opt.resume and _checkpoint.exists(opt.checkpoint):
        run = _resume(opt.checkpoint, meta, state)
    failure: tuple[int, Result] | None = None  # (failed step, its code)
    start = time.perf_counter()
    last_saved = run.done
    try:
        while run.done < opt.n and not interrupted():
            state, rec, count = run_compiled(problem, method, controller, run.state, args, opt.chunk)
            count = int(count)
            rows = run.rows + (_numpy_rows(rec, count),) if count else run.rows
            if int(state.result) != Result.SUCCESSFUL:
                rec_row = None
                if run.recoveries < opt.max_recoveries:
                    rec_row = _recover_step(problem, method, args, state)
                if rec_row is None:
                    run = _Progress(run.done + count, state, rows, run.recoveries)
                    failure = (run.done, Result(int(state.result)))
                    break
                state, row = rec_row
                rows, count = rows + (row,), count + 1
                run = _Progress(run.done + count, state, rows, run.recoveries + 1)
            else:
                run = _Progress(run.done + count, state, rows, run.recoveries)
            if report is not None:
                report(run.done, opt.n)
            if opt.checkpoint and opt.checkpoint_every and run.done - last_saved >= opt.checkpoint_every:
                _save(opt.checkpoint, meta, run)
                last_saved = run.done
    except KeyboardInterrupt:  # a second Ctrl-C, or one outside the main thread's handler
        pass
    was_interrupted = run.done < opt.n and failure is None
    if isinstance(report, _ProgressBar):
        report.close()
    if opt.checkpoint and (run.done > last_saved or was_interrupted):
        _save(opt.checkpoint, meta, run)
    elapsed = time.perf_counter() - start
    return _assemble(problem, method, args, opt, q0, p0, lam0, phi0, run, failure, throw, elapsed)


def _numpy_rows(rec: Record, count: int) -> Record:
    return Record(*(np.asarray(x)[:count] for x in rec))


def _recover_step(problem, method, args, state: State):
    """Retry the failed step of ``state`` as 2^j substeps; return ``(state, row)`` or None.

    The substeps start afresh (no reused Jacobian, no predictor history: those belong to the
    step size h), and so does the step after the recovered one. The row's statistics are the
    sums over the substeps.
    """
    controller = ConstantStepSize()
    ctrl = state.controller
    t_start, h = controller.proposal(ctrl)
    for j in range(1, _RECOVERY_HALVINGS + 1):
        sub = init_compiled(problem, method, controller, t_start, t_start + h, 1 << j, state.q, state.p, state.lam, args)
        sub, rec, count = run_compiled(problem, method, controller, sub, args, 1 << _RECOVERY_HALVINGS)
        if int(sub.result) != Result.SUCCESSFUL or int(count) != 1 << j:
            continue
        rows = _numpy_rows(rec, int(count))
        row = rows._replace(
            **{f: getattr(rows, f)[-1:] for f in ("t", "q", "p", "lam", "constraint", "drift")},
            iterations=np.asarray([rows.iterations.sum()], np.int32),
            n_jacobians=np.asarray([rows.n_jacobians.sum()], np.int32),
            residual_norm=np.asarray([rows.residual_norm.max()]),
            resync=np.asarray([rows.resync.any()]),
        )
        ctrl = ctrl._replace(k=ctrl.k + 1)
        t_next, h_next = controller.proposal(ctrl)
        new = state._replace(
            q=sub.q, p=sub.p, lam=sub.lam,
            stepper=_init_stepper(problem, method, t_next, sub.q, sub.p, sub.lam, args, h_next),
            controller=ctrl,
            result=jnp.asarray(Result.SUCCESSFUL, jnp.int32),
            n_accepted=state.n_accepted + 1,
            n_newton=state.n_newton + sub.n_newton,
            n_jacobians=state.n_jacobians + sub.n_jacobians,
        )
        return new, row
    return None


_init_stepper = jax.jit(
    lambda problem, method, t, q, p, lam, args, h: method.init(problem, t, q, p, lam, args, h),
    static_argnums=(0, 1),
)


# -- checkpoints ----------------------------------------------------------------------------------
def _run_identity(problem, method, args, opt: _Options, q0, p0, lam0) -> dict:
    """What a checkpoint must match to be resumed: the problem's functions, the method, args,
    the time grid and the initial values."""
    return {
        "problem": _checkpoint.fingerprint_callable(problem),
        "method": repr(method),
        "args": _checkpoint.fingerprint_arrays(args) if args is not None else None,
        "t_span": [opt.t0, opt.t1],
        "n_steps": opt.n,
        "h": opt.h,
        "initial_values": _checkpoint.fingerprint_arrays(np.asarray(q0), np.asarray(p0), np.asarray(lam0)),
    }


def _save(path: str, meta: dict, run: _Progress) -> None:
    rows = _concat(run.rows, run.state)
    _checkpoint.save(
        path, meta=meta, counters={"done": run.done, "recoveries": run.recoveries},
        state=run.state, rows=rows._asdict(),
    )


def _resume(path: str, meta: dict, template: State) -> _Progress:
    counters, state, rows = _checkpoint.load(path, meta=meta, state_template=template, row_names=Record._fields)
    done = int(counters.get("done", -1))
    rec = Record(**rows)
    if done < 0 or any(len(x) != done for x in rec) or int(state.n_accepted) != done:
        raise _checkpoint.CheckpointError(
            f"checkpoint '{path}' is corrupt or not a lobattodae checkpoint (it holds {len(rec.t)} rows for "
            f"{done} steps done); delete it or restart without resume."
        )
    return _Progress(done, state, (rec,), int(counters.get("recoveries", 0)))


def _concat(rows: tuple, state: State) -> Record:
    if rows:
        return Record(*(np.concatenate(xs) for xs in zip(*rows)))
    n, m = state.q.shape[-1], state.lam.shape[-1]
    return Record(
        np.zeros(0), np.zeros((0, n)), np.zeros((0, n)), np.zeros((0, m)), np.zeros(0, np.int32),
        np.zeros(0, np.int32), np.zeros(0), np.zeros(0), np.zeros(0), np.zeros(0, bool),
    )


# -- interrupts and progress ----------------------------------------------------------------------
@contextmanager
def _deferred_interrupts():
    """Within the block, Ctrl-C (SIGINT) only sets a flag that the chunk loop checks, so an
    interrupt never lands between updating the step count and the state; a second Ctrl-C
    raises KeyboardInterrupt as usual. Outside the main thread, or where SIGINT is ignored,
    nothing is changed."""
    flag = {"set": False}
    if threading.current_thread() is not threading.main_thread():
        yield lambda: False
        return
    previous = signal.getsignal(signal.SIGINT)
    if previous is signal.SIG_IGN:  # e.g. a background job: Ctrl-C stays ignored
        yield lambda: False
        return

    def handler(signum, frame):
        if flag["set"]:
            raise KeyboardInterrupt
        flag["set"] = True

    signal.signal(signal.SIGINT, handler)
    try:
        yield lambda: flag["set"]
    finally:
        signal.signal(signal.SIGINT, previous)


def _progress_reporter(progress):
    if progress is False or progress is None:
        return None
    if callable(progress):
        return progress
    return _ProgressBar()


class _ProgressBar:
    """A progress bar on stderr that appears once a run has taken more than ``delay`` seconds."""

    def __init__(self, delay: float = 1.0):
        self.start = time.perf_counter()
        self.delay = delay
        self.shown = False

    def __call__(self, done: int, total: int) -> None:
        el = time.perf_counter() - self.start
        if el < self.delay and not self.shown:
            return
        self.shown = True
        frac = done / total
        eta = el / frac * (1 - frac) if frac > 0 else float("nan")
        fill = int(30 * frac)
        sys.stderr.write(f"\r[{'#' * fill}{'.' * (30 - fill)}] {done}/{total} steps  {el:6.1f}s  eta {eta:6.1f}s")
        if done >= total:
            self.close()
        sys.stderr.flush()

    def close(self) -> None:
        """End the bar's line (also when the run stopped early)."""
        if self.shown:
            sys.stderr.write("\n")
            sys.stderr.flush()
            self.shown = False


# -- the Solution -----------------------------------------------------------------------------------
def _assemble(problem, method, args, opt: _Options, q0, p0, lam0, phi0, run: _Progress, failure, throw, elapsed):
    out = _concat(run.rows, run.state)
    n_ok = len(out.t)
    # Non-finite values reported as success would be a bug upstream; never let them through.
    finite = np.all(np.isfinite(out.q), axis=1) & np.all(np.isfinite(out.p), axis=1) & np.all(np.isfinite(out.lam), axis=1)
    failed_step, status = None, Result.SUCCESSFUL
    if not np.all(finite):
        n_ok = int(np.flatnonzero(~finite)[0])
        failed_step, status = n_ok, Result.NONFINITE
        out = Record(*(x[:n_ok] for x in out))
    elif failure is not None:
        failed_step, status = failure[0], failure[1]
    elif n_ok < opt.n:
        status = Result.INTERRUPTED
    t = np.concatenate([[opt.t0], out.t])
    excursions = int(run.state.stepper.monitor.excursions)
    stats = {
        "newton_iterations": out.iterations,
        "residual_norm": out.residual_norm,
        "constraint_residual": np.concatenate([[phi0], out.constraint]),
        "multiplier_drift": np.concatenate([[0.0], out.drift]),
        "lam_resync": out.resync,
        "lam_resets": int(np.count_nonzero(out.resync)),
        "lam_excursions": excursions,
        "n_jacobians": int(run.state.n_jacobians),
        "n_newton": int(run.state.n_newton),
        "h": opt.h,
        "n_steps": opt.n,
        "failed_step": failed_step,
        "recoveries": run.recoveries,
        "compile_and_run_time": elapsed,
    }
    success = status == Result.SUCCESSFUL and n_ok == opt.n
    message = status.message
    if failed_step is not None:
        tf = opt.t0 + failed_step * opt.h
        tried = f" (after {run.recoveries} recovered steps; max_recoveries={opt.max_recoveries})" if opt.max_recoveries else ""
        message = f"Step {failed_step} (t = {tf:.6g}, h = {opt.h:.3g}) failed{tried}: {status.message}"
        if throw:
            raise NewtonFailure(message, step=failed_step, t=tf, reason=status.name.lower())
    elif status == Result.INTERRUPTED:
        message = f"Interrupted after {n_ok} of {opt.n} steps (t = {t[-1]:.6g}); the computed prefix is returned."
    if method.lam_start == "previous" and excursions:
        k = _first_excursion(out.drift)
        note = (
            f"the multiplier λ_k left its normal band around the hidden constraint in {excursions} steps "
            f"(‖λ_k − λ(q_k, p_k)‖∞ up to {float(np.max(out.drift)):.2e}, first at t ≈ {t[k + 1]:.6g}). With "
            "lam_start='previous' (the paper's scheme) λ errors are carried with |R(∞)| = 1 and can grow, and with "
            "them the errors in q and p. Use lam_start='auto' (re-synchronise when λ drifts) or 'consistent', or a "
            "smaller step."
        )
        message = f"{message} Warning: {note}"
        warnings.warn(note, RuntimeWarning, stacklevel=3)
    return Solution(
        t, np.vstack([q0[None], out.q]), np.vstack([p0[None], out.p]), np.vstack([lam0[None], out.lam]),
        bool(success), status, message, stats, problem, method, args,
    )


def _first_excursion(drift: np.ndarray) -> int:
    """Index of the largest growth of the drift over its early level (for the message only)."""
    if drift.size == 0:
        return 0
    early = float(np.max(drift[: min(len(drift), 10)]))
    above = np.flatnonzero(drift > 10 * early)
    return int(above[0]) if above.size else int(np.argmax(drift))
