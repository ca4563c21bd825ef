"""``solve``: integrate a partitioned index-2 DAE over an interval with a constant step."""

from __future__ import annotations

import functools
import json
import math
import os
import sys
import time
import warnings
from dataclasses import dataclass, field
from typing import Any, Callable, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from ._errors import LobattoDAEInputError, NewtonFailure
from ._initial import check_float64, lambda_newton_update, validate_and_residual
from ._problem import consistent_lambda
from ._results import Result
from ._stepper import LobattoIIIAIIIB, StepperState

__all__ = ["Solution", "solve", "integrate"]

#: Longest compiled chunk of steps; longer runs loop over chunks (one compile per chunk
#: length, a power of two, so a convergence study compiles only a handful of times).
MAX_CHUNK = 4096
_MIN_CHUNK = 16
#: Status code of a step that was not taken (past the end, or after a failure).
_SKIPPED = -1
#: A RuntimeWarning is issued when ‖λ_k − λ(q_k, p_k)‖∞ grows DRIFT_GROWTH-fold over its level
#: in the first steps and exceeds DRIFT_FLOOR·(1 + max|λ|).
DRIFT_GROWTH = 1e3
DRIFT_FLOOR = 1e-6


class _Carry(NamedTuple):
    q: jax.Array
    p: jax.Array
    lam: jax.Array  # Λ_1 of the next step: λ_k, or λ(t_k, q_k, p_k) for lam_start="consistent"
    state: StepperState
    failed: jax.Array


class _StepOut(NamedTuple):
    q: jax.Array
    p: jax.Array
    lam: jax.Array
    result: jax.Array
    iterations: jax.Array
    residual_norm: jax.Array
    n_jacobians: jax.Array
    constraint: jax.Array
    drift: jax.Array


def _scan_steps(problem, method: LobattoIIIAIIIB, length: int, k0, n_total, t0, h, carry: _Carry, args):
    """``length`` steps with ``lax.scan``.

    Steps with index ≥ n_total (padding of the last chunk), or after a failed step, are
    computed but discarded (status ``_SKIPPED``): a branch-free loop body is much faster on CPU
    than a ``lax.cond`` around the step, and padding only ever occurs in the last chunk.
    """

    def body(c: _Carry, j):
        k = (k0 + j).astype(t0.dtype)
        active = jnp.logical_and(k0 + j < n_total, ~c.failed)
        t = t0 + k * h
        q1, p1, lam1, info, st = method.step_from(problem, t, c.q, c.p, c.lam, h, args, c.state)
        cons = jnp.max(jnp.abs(problem.phi(t + h, q1, p1, args)))
        # distance of λ_{k+1} from the hidden constraint at (q_{k+1}, p_{k+1}): an estimate
        # of the error in λ, and the symptom of the undamped λ mode of the paper's scheme.
        # With lam_start="consistent", λ(q_{k+1}, p_{k+1}) is the next step's Λ_1.
        lam_c = consistent_lambda(problem, t + h, q1, p1, lam1, args, iterations=1)
        drift = jnp.max(jnp.abs(lam1 - lam_c))
        lam_next = lam_c if method.lam_start == "consistent" else lam1
        ok = info.result == Result.SUCCESSFUL
        accept = jnp.logical_and(active, ok)
        new = _Carry(
            jnp.where(accept, q1, c.q),
            jnp.where(accept, p1, c.p),
            jnp.where(accept, lam_next, c.lam),
            jax.tree_util.tree_map(lambda a, b: jnp.where(accept, a, b), st, c.state),
            jnp.logical_or(c.failed, jnp.logical_and(active, ~ok)),
        )
        code = jnp.where(active, info.result, _SKIPPED).astype(jnp.int32)
        out = _StepOut(q1, p1, lam1, code, info.iterations, info.residual_norm, info.n_jacobians, cons, drift)
        return new, out

    return jax.lax.scan(body, carry, jnp.arange(length))


@functools.partial(jax.jit, static_argnames=("problem", "method", "length"))
def _run_chunk(problem, method, length, k0, n_total, t0, h, carry, args):
    return _scan_steps(problem, method, length, k0, n_total, t0, h, carry, args)


def integrate(problem, method: LobattoIIIAIIIB, t0, h, n_steps: int, q0, p0, lam0, args=None):
    """Pure, jit/vmap-able integration of ``n_steps`` steps of size ``h`` (no input checks).

    The building block of :func:`solve` for batched use: ``jax.vmap(integrate, ...)`` over
    initial values or ``args``. The initial values must be consistent (see
    :func:`consistent_lambda`); nothing is validated here.

    Returns
    -------
    q, p, lam : jax.Array
        Time-major, shapes ``(n_steps + 1, n)``, ``(n_steps + 1, n)``, ``(n_steps + 1, m)``.
        After a failed step the remaining rows are NaN.
    status : jax.Array
        ``Result`` code of the integration (0 on success, else the first failure's code).
    """
    q0 = jnp.asarray(q0, jnp.float64)
    p0 = jnp.asarray(p0, jnp.float64)
    lam0 = jnp.asarray(lam0, jnp.float64)
    t0 = jnp.asarray(t0, jnp.float64)
    h = jnp.asarray(h, jnp.float64)
    # the loop carries Λ_1 of the next step (see _Carry); with lam_start="consistent" the first
    # one comes from the hidden constraint, as in LobattoIIIAIIIB.step
    lam_start = lam0
    if method.lam_start == "consistent":
        lam_start = consistent_lambda(problem, t0, q0, p0, lam0, args, iterations=1)
    carry = _Carry(q0, p0, lam_start, method.init(q0, p0, lam0), jnp.asarray(False))
    _, out = _scan_steps(problem, method, n_steps, jnp.asarray(0), n_steps, t0, h, carry, args)
    codes = out.result
    failed = codes > 0
    status = jnp.where(jnp.any(failed), codes[jnp.argmax(failed)], 0)
    q = jnp.concatenate([q0[None], out.q])
    p = jnp.concatenate([p0[None], out.p])
    lam = jnp.concatenate([lam0[None], out.lam])
    return q, p, lam, status


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
        ``newton_iterations (N,)``, ``residual_norm (N,)`` (max-norm of the last Newton
        residual), ``constraint_residual (N+1,)`` (‖φ(t_k, q_k, p_k)‖∞), ``n_jacobians``
        (total), ``h``, ``n_steps``, ``failed_step`` (or None), ``compile_and_run_time``.
        When the solve stopped early the arrays hold the computed prefix only.
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


def _chunk_length(n: int, chunk_size: int | None) -> int:
    if chunk_size is not None:
        if not (isinstance(chunk_size, int) and chunk_size >= 1):
            raise LobattoDAEInputError(f"chunk_size must be a positive integer; got {chunk_size!r}.")
        return chunk_size
    return min(MAX_CHUNK, max(_MIN_CHUNK, 1 << (n - 1).bit_length()))


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
        Steps per compiled chunk (default: the next power of two ≥ n_steps, at most 4096).
    progress : bool or callable
        ``True`` prints a progress bar to stderr; a callable is called as
        ``progress(steps_done, n_steps)`` after each chunk. Ctrl-C between chunks returns the
        computed prefix with status ``INTERRUPTED``.
    max_recoveries : int
        Automatic recovery (off by default): a step whose Newton iteration fails is retried as
        2, 4, 8 or 16 substeps, at most this many times per solve; ``stats["recoveries"]``
        counts them. The recovered step restarts the Jacobian cache and the predictor.
    checkpoint : path, optional
        Write the computed prefix and the loop state to this ``.npz`` file every
        ``checkpoint_every`` steps (at chunk boundaries), at the end, and on Ctrl-C.
    checkpoint_every : int, optional
    resume : bool
        Continue from ``checkpoint`` if it exists (it must come from the same problem set-up:
        method, t_span, step and initial values are checked). A resumed run gives the same
        numbers, bit for bit, as an uninterrupted one.

    Returns
    -------
    Solution
    """
    check_float64()
    if not isinstance(method, LobattoIIIAIIIB):
        raise TypeError(
            f"method must be a LobattoIIIAIIIB instance, e.g. LobattoIIIAIIIB(stages=3); got {method!r}."
        )
    t0, t1 = _check_t_span(t_span)
    n, h = _step_count(t0, t1, n_steps, dt)
    q0, p0, lam0, phi0 = validate_and_residual(problem, t0, q0, p0, lam0, args, project=project_initial)
    length = _chunk_length(n, chunk_size)
    report = _progress_reporter(progress)

    q0j, p0j, lam0j = jnp.asarray(q0), jnp.asarray(p0), jnp.asarray(lam0)
    # The loop carries Λ_1 of the next step (see _Carry). With lam_start="consistent" the first
    # one is λ(t0, q0, p0): a computed λ0 already is; a given one is only checked to a tolerance.
    lam_start = lam0j
    if method.lam_start == "consistent":
        lam_start = jnp.asarray(lambda_newton_update(problem, t0, q0, p0, lam0, args))
    carry = _Carry(q0j, p0j, lam_start, method.init(q0j, p0j, lam0j), jnp.asarray(False))
    meta = _checkpoint_meta(method, t0, t1, n, h, length, q0, p0, lam0)
    accepted: list[_StepOut] = []
    done, recoveries = 0, 0
    if checkpoint is not None and resume and os.path.exists(checkpoint):
        done, recoveries, accepted, carry = _load_checkpoint(checkpoint, meta, carry)
    elif resume and checkpoint is None:
        raise LobattoDAEInputError("resume=True needs the checkpoint file to resume from (checkpoint=PATH).")
    if isinstance(max_recoveries, bool) or not isinstance(max_recoveries, int) or max_recoveries < 0:
        raise LobattoDAEInputError(f"max_recoveries must be a non-negative integer; got {max_recoveries!r}.")
    if checkpoint_every is not None and (not isinstance(checkpoint_every, int) or checkpoint_every < 1):
        raise LobattoDAEInputError(f"checkpoint_every must be a positive integer; got {checkpoint_every!r}.")
    interrupted = False
    failure: tuple[int, int, _StepOut] | None = None
    start = time.perf_counter()
    t0j, hj = jnp.asarray(t0), jnp.asarray(h)
    last_saved = done
    try:
        while done < n:
            new_carry, out = _run_chunk(problem, method, length, jnp.asarray(done), n, t0j, hj, carry, args)
            out = jax.tree_util.tree_map(np.asarray, out)
            bad = np.flatnonzero(out.result > 0)
            n_good = int(bad[0]) if bad.size else int(np.count_nonzero(out.result == Result.SUCCESSFUL))
            accepted.append(_rows(out, 0, n_good))
            done += n_good
            carry = new_carry._replace(failed=jnp.asarray(False))
            if bad.size:
                row = _rows(out, n_good, n_good + 1)
                rec = None
                if recoveries < max_recoveries:
                    rec = _recover_step(problem, method, args, t0 + done * h, h, carry)
                if rec is None:
                    failure = (done, int(out.result[n_good]), row)
                    break
                carry, rec_row = rec
                accepted.append(rec_row)
                done += 1
                recoveries += 1
            elif n_good == 0:  # pragma: no cover - cannot happen: a chunk either advances or fails
                raise RuntimeError("internal error: a chunk made no progress")
            if report is not None:
                report(done, n)
            if checkpoint is not None and checkpoint_every is not None and done - last_saved >= checkpoint_every:
                _save_checkpoint(checkpoint, meta, done, recoveries, accepted, carry)
                last_saved = done
    except KeyboardInterrupt:
        interrupted = True
    if checkpoint is not None and (interrupted or done > last_saved):
        _save_checkpoint(checkpoint, meta, done, recoveries, accepted, carry)
    elapsed = time.perf_counter() - start
    return _assemble(
        problem, method, args, t0, t1, h, n, q0, p0, lam0, phi0, accepted, failure, interrupted, throw, elapsed,
        recoveries,
    )


def _rows(out: _StepOut, i: int, j: int) -> _StepOut:
    return _StepOut(*(x[i:j] for x in out))


#: Automatic recovery retries a failed step as 2, 4, 8, 16 substeps (one compiled chunk of 16).
_RECOVERY_HALVINGS = 4


def _recover_step(problem, method, args, t_start, h, carry: _Carry):
    """Retry one failed step of size h as 2^j substeps; return (carry, one output row) or None.

    The Jacobian cache and the predictor are reset (they belong to the step size h); the
    step's statistics are the sums over the substeps.
    """
    length = 1 << _RECOVERY_HALVINGS
    for j in range(1, _RECOVERY_HALVINGS + 1):
        m = 1 << j
        fresh = _Carry(carry.q, carry.p, carry.lam, method.init(carry.q, carry.p, carry.lam), jnp.asarray(False))
        sub_carry, out = _run_chunk(
            problem, method, length, jnp.asarray(0), m, jnp.asarray(t_start), jnp.asarray(h / m), fresh, args
        )
        out = jax.tree_util.tree_map(np.asarray, out)
        if np.all(out.result[:m] == Result.SUCCESSFUL):
            row = _StepOut(
                out.q[m - 1 : m], out.p[m - 1 : m], out.lam[m - 1 : m], out.result[m - 1 : m],
                np.asarray([out.iterations[:m].sum()], np.int32), np.asarray([out.residual_norm[:m].max()]),
                np.asarray([out.n_jacobians[:m].sum()], np.int32), out.constraint[m - 1 : m], out.drift[m - 1 : m],
            )
            new = _Carry(
                sub_carry.q, sub_carry.p, sub_carry.lam,
                method.init(sub_carry.q, sub_carry.p, sub_carry.lam), jnp.asarray(False),
            )
            return new, row
    return None


def _checkpoint_meta(method, t0, t1, n, h, length, q0, p0, lam0) -> dict:
    return {
        "format": "lobattodae-checkpoint-1",
        "method": repr(method),
        "t0": t0, "t1": t1, "n_steps": n, "h": h, "chunk": length,
        "q0": np.asarray(q0).tolist(), "p0": np.asarray(p0).tolist(), "lam0": np.asarray(lam0).tolist(),
    }


def _save_checkpoint(path, meta, done, recoveries, accepted, carry: _Carry) -> None:
    """Write the computed prefix and the loop state atomically (temporary file + rename)."""
    rows = _concat(accepted, carry)
    leaves = jax.tree_util.tree_leaves(carry)
    payload = {f"leaf_{i}": np.asarray(x) for i, x in enumerate(leaves)}
    payload.update({f"out_{name}": np.asarray(x) for name, x in zip(_StepOut._fields, rows)})
    tmp = f"{path}.tmp"
    with open(tmp, "wb") as fh:
        np.savez(fh, meta=json.dumps(meta), done=done, recoveries=recoveries, **payload)
    os.replace(tmp, path)


def _load_checkpoint(path, meta, template: _Carry):
    with np.load(path, allow_pickle=False) as data:
        saved = json.loads(str(data["meta"]))
        if saved != meta:
            diff = sorted(k for k in set(saved) | set(meta) if saved.get(k) != meta.get(k))
            raise LobattoDAEInputError(
                f"checkpoint {path!r} belongs to a different run (differs in: {', '.join(diff)}); "
                "resume with the same problem, method, t_span, step and initial values, or delete it."
            )
        leaves, treedef = jax.tree_util.tree_flatten(template)
        restored = [jnp.asarray(data[f"leaf_{i}"], dtype=leaf.dtype) for i, leaf in enumerate(leaves)]
        carry = jax.tree_util.tree_unflatten(treedef, restored)
        rows = _StepOut(*(data[f"out_{name}"] for name in _StepOut._fields))
        return int(data["done"]), int(data["recoveries"]), [rows], carry


def _concat(accepted: list[_StepOut], carry: _Carry) -> _StepOut:
    if accepted:
        return _StepOut(*(np.concatenate(xs) for xs in zip(*accepted)))
    n, m = carry.q.shape[0], carry.lam.shape[0]
    return _StepOut(
        np.zeros((0, n)), np.zeros((0, n)), np.zeros((0, m)), np.zeros(0, np.int32), np.zeros(0, np.int32),
        np.zeros(0), np.zeros(0, np.int32), np.zeros(0), np.zeros(0),
    )


def _assemble(
    problem, method, args, t0, t1, h, n, q0, p0, lam0, phi0, accepted, failure, interrupted, throw, elapsed,
    recoveries,
) -> Solution:
    n_ok = sum(len(a.result) for a in accepted)
    out = _concat(accepted, _Carry(jnp.asarray(q0), jnp.asarray(p0), jnp.asarray(lam0), None, None))
    # Non-finite values reported as success would be a bug upstream; never let them through.
    finite = (np.all(np.isfinite(out.q), axis=1) & np.all(np.isfinite(out.p), axis=1)
              & np.all(np.isfinite(out.lam), axis=1))
    failed_step, status = None, Result.SUCCESSFUL
    if not np.all(finite):
        n_ok = int(np.flatnonzero(~finite)[0])
        failed_step, status = n_ok, Result.NONFINITE
    elif failure is not None:
        failed_step, status = failure[0], Result(failure[1])
    elif n_ok < n:
        status = Result.INTERRUPTED
    out = _rows(out, 0, n_ok)
    tk = t0 + np.arange(n_ok + 1) * h
    if n_ok == n:
        tk[-1] = t1
    q = np.vstack([q0[None], out.q])
    p = np.vstack([p0[None], out.p])
    lam = np.vstack([lam0[None], out.lam])
    drift = np.concatenate([[0.0], out.drift])
    n_jac = int(np.sum(out.n_jacobians)) + (int(failure[2].n_jacobians[0]) if failure is not None else 0)
    stats = {
        "newton_iterations": out.iterations,
        "residual_norm": out.residual_norm,
        "constraint_residual": np.concatenate([[phi0], out.constraint]),
        "n_jacobians": n_jac,
        "h": h,
        "n_steps": n,
        "failed_step": failed_step,
        "recoveries": recoveries,
        "compile_and_run_time": elapsed,
        "multiplier_drift": drift,
    }
    success = status == Result.SUCCESSFUL and n_ok == n
    message = status.message
    if failed_step is not None:
        tf = t0 + failed_step * h
        message = f"Step {failed_step} (t = {tf:.6g}, h = {h:.3g}) failed: {status.message}"
        if throw:
            raise NewtonFailure(message, step=failed_step, t=tf, reason=status.name.lower())
    elif status == Result.INTERRUPTED:
        message = f"Interrupted after {n_ok} of {n} steps (t = {tk[-1]:.6g}); the computed prefix is returned."
    k = _drift_onset(drift, 1.0 + float(np.max(np.abs(lam)))) if method.lam_start == "previous" else None
    if k is not None:
        warnings.warn(
            f"the multiplier λ_k drifts away from the hidden constraint: |λ_k − λ(q_k, p_k)| grows from "
            f"{float(np.max(drift[: _early(len(drift))])):.1e} in the first steps to {float(np.max(drift)):.2e} "
            f"(t = {tk[k]:.6g}). "
            "With lam_start='previous' (the paper's scheme) λ errors are propagated with |R(∞)| = 1 and "
            "can grow over long runs, and with them the errors in q and p. Use "
            "LobattoIIIAIIIB(..., lam_start='consistent') or a smaller step.",
            RuntimeWarning,
            stacklevel=3,
        )
    return Solution(tk, q, p, lam, bool(success), status, message, stats, problem, method, args)


def _early(n: int) -> int:
    return min(n, max(11, n // 20))


def _drift_onset(drift: np.ndarray, lam_scale: float) -> int | None:
    """Index where the multiplier drift has grown DRIFT_GROWTH-fold over its early level.

    A coarse step gives a large but steady λ error; the weak instability of the paper's scheme
    shows as *growth*. Only growth to above DRIFT_FLOOR·(1 + max|λ|) is reported.
    """
    if drift.size <= 1:
        return None
    early = float(np.max(drift[: _early(len(drift))]))
    limit = max(DRIFT_GROWTH * early, DRIFT_FLOOR * lam_scale)
    above = np.flatnonzero(drift > limit)
    return int(above[0]) if above.size else None


def _progress_reporter(progress):
    if progress is False or progress is None:
        return None
    if callable(progress):
        return progress
    start = time.perf_counter()

    def bar(done: int, total: int) -> None:
        width = 30
        frac = done / total
        fill = int(width * frac)
        el = time.perf_counter() - start
        eta = el / frac * (1 - frac) if frac > 0 else float("nan")
        sys.stderr.write(f"\r[{'#' * fill}{'.' * (width - fill)}] {done}/{total} steps  {el:6.1f}s  eta {eta:6.1f}s")
        if done >= total:
            sys.stderr.write("\n")
        sys.stderr.flush()

    return bar
