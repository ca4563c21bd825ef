"""``solve``: integrate a partitioned index-2 DAE over an interval and return a :class:`Solution`.

The order of work: validate every option (paths included) → validate the problem and the
initial values → compiled chunks of the loop, the first of which also makes the loop
:class:`~lobattodae._loop.State` (progress, Ctrl-C, checkpoints, recovery of failed steps)
→ :class:`Solution`.
"""

from __future__ import annotations

import dataclasses
import errno
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
from ._controllers import MIN_RELATIVE_STEP, ConstantStepSize, ControlOptions, PIController, ReversibleStepSize
from ._dense import DenseOutput, dense_size, stacked
from ._events import as_events
from ._loop import CHUNK, Output, Record, State, init_host, run_host, start_host, t_eval_output, t_eval_rows_mode
from ._results import Result
from ._doubling import for_error_control
from ._stepper import LobattoIIIAIIIB
from ._validate import check_float64, check_tolerance_attainable, validate_and_residual

__all__ = ["SCIPY_STATUS", "STATS", "Solution", "solve"]

#: The keys of ``Solution.stats`` (the one place they are documented). "Rows" are the output
#: rows after the initial one: step points (every ``save_every``-th) or ``t_eval`` times.
STATS = {
    "newton_iterations": "(rows,) Newton iterations of the step that produced each row",
    "residual_norm": "(rows,) max-norm of that step's last Newton residual",
    "constraint_residual": "(N+1,) ‖φ(t_k, q_k, p_k)‖∞ at the output rows (with t_eval: between steps, on the dense output)",
    "multiplier_drift": "(N+1,) ‖λ_k − λ(t_k, q_k, p_k)‖∞ of the step that produced each row",
    "lam_resync": "(rows,) bool: that step started from λ(t_k, q_k, p_k) (lam_start='auto' re-synchronised λ)",
    "lam_resets": "number of re-synchronisations of λ in the output rows (lam_start='auto')",
    "lam_excursions": "steps where the drift left its normal band (re-synchronised with 'auto', only counted otherwise)",
    "max_constraint_residual": "max ‖φ‖∞ over every step point (saved or not) and every row returned (t_eval rows "
                               "lie between step points)",
    "max_multiplier_drift": "max ‖λ − λ(t, q, p)‖∞ over every step point",
    "n_jacobians": "Newton Jacobian evaluations (each with one factorisation)",
    "n_newton": "Newton iterations in all",
    "n_steps": "accepted steps",
    "n_rejected": "rejected step attempts (error test or Newton failure; adaptive steps)",
    "h": "the constant step size, or None for adaptive steps",
    "n_clamped": "ReversibleStepSize: steps whose control variable ρ was clamped (MAX_DENSITY_CHANGE), each one "
                 "unsymmetric, so 0 for a reversible run; None for other step-size rules",
    "failed_step": "index of the failed step, or None",
    "recoveries": "failed steps retried as substeps (max_recoveries, constant steps)",
    "compile_and_run_time": "wall time of the integration loop, compilation included (s)",
}

#: Automatic recovery retries a failed step as 2, 4, 8, 16 substeps (one compiled chunk of 16).
_RECOVERY_HALVINGS = 4
#: Default tolerances of adaptive steps.
RTOL, ATOL = 1e-8, 1e-10
_EPS = float(np.finfo(np.float64).eps)


@dataclass(frozen=True, eq=False)
class Solution:
    """The result of :func:`solve` (time-major NumPy arrays, with scipy's views beside them).

    Attributes
    ----------
    t : ndarray, shape (k,)
        The initial time and the kept step points, or the ``t_eval`` times.
    q, p : ndarray, shape (k, n)
    lam : ndarray, shape (k, m)
        The multiplier λ_k at t_k (λ_0 is the consistent initial value).
    success : bool
        The run reached the end of the interval or a terminal event.
    result : Result
        ``SUCCESSFUL``, ``EVENT`` (a terminal event) or the reason the run stopped early.
    message : str
    stats : dict
        Counters and per-row diagnostics; the keys are documented in :data:`STATS`
        (``lobattodae.STATS``). When the solve stopped early the arrays hold the computed prefix.
    t_events, q_events, p_events, lam_events : list of ndarray or None
        One array per event function: the times and states of its zeros (None without
        events).
    sol : DenseOutput or None
        ``sol(t) -> (q, p, lam)`` between the step points (``dense_output=True``);
        ``sol(t, layout="scipy")`` returns scipy's stacked ``(2n + m, k)`` layout.
    problem, method, args
        What was solved, for diagnostics.

    The views in ``scipy.integrate.solve_ivp``'s layout and vocabulary: :attr:`y`,
    :attr:`y_events`, :attr:`status`, :attr:`nfev`, :attr:`njev`, :attr:`nlu`.

    Examples
    --------
    >>> sol = L.solve(problem, L.LobattoIIIAIIIB(stages=4), (0.0, 2.0), q0, p0)  # doctest: +SKIP
    >>> sol.y.shape                       # (2n + m, k), as solve_ivp lays it out  # doctest: +SKIP
    >>> sol.status, sol.result.name       # 0, 'SUCCESSFUL'  # doctest: +SKIP
    """

    t: np.ndarray
    q: np.ndarray
    p: np.ndarray
    lam: np.ndarray
    success: bool
    result: Result
    message: str
    stats: dict = field(repr=False)
    problem: Any = field(repr=False, default=None)
    method: Any = field(repr=False, default=None)
    args: Any = field(repr=False, default=None)
    t_events: list | None = field(repr=False, default=None)
    q_events: list | None = field(repr=False, default=None)
    p_events: list | None = field(repr=False, default=None)
    lam_events: list | None = field(repr=False, default=None)
    sol: DenseOutput | None = field(repr=False, default=None)

    # -- scipy's views -------------------------------------------------------------------------
    @property
    def status(self) -> int:
        """scipy's status: 0 the end of the interval was reached, 1 a terminal event, −1 the run
        stopped early (the reason is :attr:`result`)."""
        return SCIPY_STATUS.get(self.result, -1)

    @property
    def y(self) -> np.ndarray:
        """``[q; p; λ]`` stacked as ``solve_ivp`` lays out ``y``: shape (2n + m, k), one column per time."""
        return stacked(self.q, self.p, self.lam).T

    @property
    def y_events(self) -> list | None:
        """One (k_j, 2n + m) array per event function, the rows ``[q, p, λ]`` at its zeros (None
        without events), as ``solve_ivp``'s ``y_events``."""
        if self.t_events is None:
            return None
        return [stacked(q, p, lam) for q, p, lam in zip(self.q_events, self.p_events, self.lam_events)]

    @property
    def nfev(self) -> int:
        """Evaluations of the right-hand side (f, g) at a stage point in Newton's iterations
        (s per iteration: ``stats["n_newton"]`` × s)."""
        return self.stats["n_newton"] * self.method.stages

    @property
    def njev(self) -> int:
        """Jacobians of the stage equations (``stats["n_jacobians"]``)."""
        return self.stats["n_jacobians"]

    @property
    def nlu(self) -> int:
        """LU factorisations: one per Jacobian (``stats["n_jacobians"]``)."""
        return self.stats["n_jacobians"]

    def __repr__(self) -> str:
        return (
            f"Solution(success={self.success}, result={self.result.name}, n_steps={self.stats['n_steps']}, "
            f"t=[{self.t[0]:g}, {self.t[-1]:g}], max constraint residual="
            f"{self.stats['max_constraint_residual']:.2e})"
        )


#: ``Result`` → scipy's ``status``: 0 the end was reached, 1 a terminal event; every other result is −1.
SCIPY_STATUS = {Result.SUCCESSFUL: 0, Result.EVENT: 1}


# -- options ------------------------------------------------------------------------------------
@dataclass(frozen=True)
class _Options:
    """Every option of :func:`solve`, checked before any work is done."""

    t0: float
    t1: float
    n: int | None  # constant steps: their number (None: adaptive)
    h: float | None
    control: ControlOptions  # numbers (tolerances, step bounds)
    controller: Any  # the controller object (static)
    output: Output
    t_eval: np.ndarray | None
    every: int
    chunk: int
    max_recoveries: int
    checkpoint: str | None
    checkpoint_every: int | None
    resume: bool
    max_steps: int = 0  # adaptive steps: the cap on step attempts (0 for constant steps)

    @property
    def adaptive(self) -> bool:
        return self.n is None

    @classmethod
    def check(cls, method, t_span, n_steps, dt, rtol, atol, first_step, max_step, controller, t_eval, dense_output,
              events, save_every, chunk_size, max_recoveries, checkpoint, checkpoint_every, resume, t_eval_rows=None,
              max_steps=None):
        if not isinstance(method, LobattoIIIAIIIB):
            raise TypeError(
                f"method must be a LobattoIIIAIIIB instance, e.g. LobattoIIIAIIIB(stages=3); got {method!r}."
            )
        check_tolerance_attainable(method)
        t0, t1 = _check_t_span(t_span)
        constant = n_steps is not None or dt is not None
        if constant:
            n, h = _step_count(t0, t1, n_steps, dt)
            for name, value in (("rtol", rtol), ("atol", atol), ("first_step", first_step), ("controller", controller)):
                if value is not None:
                    raise LobattoDAEInputError(
                        f"{name} applies to adaptive steps; drop n_steps/dt to let the solver choose the steps, "
                        f"or drop {name}."
                    )
            if max_step is not None and not math.isinf(_positive_float("max_step", max_step, allow_inf=True)):
                raise LobattoDAEInputError("max_step applies to adaptive steps; with constant steps use dt.")
            control, ctrl = ControlOptions(n=n), ConstantStepSize()
            if max_steps is not None:
                raise LobattoDAEInputError("max_steps applies to adaptive steps; constant steps take n_steps (or dt).")
            max_steps = 0
        else:
            n = h = None
            rtol = RTOL if rtol is None else _positive_float("rtol", rtol)
            atol = ATOL if atol is None else _positive_float("atol", atol, allow_zero=True)
            if rtol < 100 * _EPS:
                raise LobattoDAEInputError(
                    f"rtol={rtol:g} is below what float64 can deliver; use rtol >= {100 * _EPS:.1e}."
                )
            first = 0.0 if first_step is None else _positive_float("first_step", first_step)
            if first > abs(t1 - t0):
                raise LobattoDAEInputError(f"first_step={first:g} is longer than the interval |t1 - t0| = {abs(t1 - t0):g}.")
            biggest = math.inf if max_step is None else _positive_float("max_step", max_step, allow_inf=True)
            _check_resolvable_steps(t0, t1, first, biggest)
            control = ControlOptions(1, rtol, atol, first, biggest)
            max_steps = _check_max_steps(max_steps, t0, t1, biggest)
            ctrl = PIController() if controller is None else controller
            if not isinstance(ctrl, (PIController, ReversibleStepSize)):
                raise LobattoDAEInputError(
                    f"controller must be lobattodae.PIController(...) or lobattodae.ReversibleStepSize(...); got {ctrl!r}."
                )
        t_eval = _check_t_eval(t_eval, t0, t1)
        every = _check_save_every(save_every)
        if t_eval is not None and save_every not in (None, 1):
            raise LobattoDAEInputError("give t_eval (rows at given times) or save_every (every k-th step point), not both.")
        output = t_eval_output(t_eval_rows_mode(t_eval_rows, ctrl, t_eval is not None), bool(dense_output),
                               as_events(events), ctrl)
        if chunk_size is not None and (isinstance(chunk_size, bool) or not isinstance(chunk_size, int) or chunk_size < 1):
            raise LobattoDAEInputError(f"chunk_size must be a positive integer; got {chunk_size!r}.")
        if isinstance(max_recoveries, bool) or not isinstance(max_recoveries, int) or max_recoveries < 0:
            raise LobattoDAEInputError(f"max_recoveries must be a non-negative integer; got {max_recoveries!r}.")
        if max_recoveries and (not constant or output != Output()):
            raise LobattoDAEInputError(
                "max_recoveries applies to constant steps without t_eval, events or dense_output; adaptive steps "
                "recover from failed steps by themselves (drop n_steps/dt)."
            )
        if checkpoint_every is not None and (
            isinstance(checkpoint_every, bool) or not isinstance(checkpoint_every, int) or checkpoint_every < 1
        ):
            raise LobattoDAEInputError(f"checkpoint_every must be a positive integer; got {checkpoint_every!r}.")
        if resume and checkpoint is None:
            raise LobattoDAEInputError("resume=True needs the checkpoint file to resume from (checkpoint=PATH).")
        if checkpoint_every is not None and checkpoint is None:
            raise LobattoDAEInputError(
                "checkpoint_every sets how often the checkpoint file is written; give the file (checkpoint=PATH) or "
                "drop checkpoint_every."
            )
        path = None
        if checkpoint is not None:
            path = os.fspath(checkpoint)
            check_writable(path, "checkpoint")
            rows_dir = _checkpoint.rows_directory(path)
            _checkpoint.check_rows_directory(path)  # a symbolic link there is refused before any work
            if os.path.lexists(rows_dir) and not os.path.isdir(rows_dir):
                raise LobattoDAEInputError(
                    f"cannot write the checkpoint '{path}': its rows go to the directory '{rows_dir}', and something "
                    "else is there; remove it or choose another checkpoint path."
                )
        return cls(t0, t1, n, h, control, ctrl, output, t_eval, every, chunk_size or CHUNK, max_recoveries, path,
                   checkpoint_every, bool(resume), max_steps)


#: The default cap on the step attempts of an adaptive ``solve`` (as scipy and diffrax cap theirs):
#: far above any run the tolerances ask for, and low enough that no counter can overflow.
MAX_STEPS = 10_000_000
#: The largest cap: every counter of the loop is int32 and a step attempt counts up to three
#: Newton solves of ``max_iterations`` iterations each.
_MAX_STEPS_LIMIT = 20_000_000


def _check_max_steps(max_steps, t0: float, t1: float, max_step: float) -> int:
    """The cap on step attempts; refuses up front a ``max_step`` that would need more steps."""
    if max_steps is None:
        max_steps = MAX_STEPS
    elif isinstance(max_steps, bool) or not isinstance(max_steps, (int, np.integer)) or not 0 < max_steps <= _MAX_STEPS_LIMIT:
        raise LobattoDAEInputError(
            f"max_steps must be a positive integer up to {_MAX_STEPS_LIMIT:,} (the cap on step attempts); got "
            f"{max_steps!r}. Split a longer run into several solve calls (or use checkpoint/resume)."
        )
    needed = abs(t1 - t0) / max_step
    if needed > max_steps:
        raise LobattoDAEInputError(
            f"max_step={max_step:g} needs at least {needed:.3g} steps over |t1 - t0| = {abs(t1 - t0):g}, more than "
            f"max_steps={max_steps:,}; raise max_step (or max_steps)."
        )
    return int(max_steps)


def _check_resolvable_steps(t0: float, t1: float, first_step: float, max_step: float) -> None:
    """Refuse up front a ``first_step`` or ``max_step`` below the smallest step the run can take,
    ``MIN_RELATIVE_STEP·max(|t|, |t1 - t0|)`` (a shorter one ends the run as
    ``STEP_SIZE_TOO_SMALL``, whose message would blame the problem)."""
    span = abs(t1 - t0)
    for name, value, largest_t in (("first_step", first_step, abs(t0)), ("max_step", max_step, max(abs(t0), abs(t1)))):
        smallest = MIN_RELATIVE_STEP * max(largest_t, span)
        if 0 < value < smallest:
            raise LobattoDAEInputError(
                f"{name}={value:g} is below the smallest step a run can take here, {MIN_RELATIVE_STEP:g}·max(|t|, "
                f"|t1 - t0|) = {smallest:.3g} (a shorter step is lost in the round-off of t, and the run would end "
                f"as STEP_SIZE_TOO_SMALL); use {name} >= {smallest:.3g}, or shift t_span towards 0."
            )


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


def _positive_float(name: str, value, allow_zero: bool = False, allow_inf: bool = False) -> float:
    if isinstance(value, (bool, str)) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise LobattoDAEInputError(f"{name} must be a positive number; got {value!r}.")
    x = float(value)
    if math.isnan(x) or (math.isinf(x) and not allow_inf) or x < 0 or (x == 0 and not allow_zero):
        what = "a non-negative" if allow_zero else "a positive"
        raise LobattoDAEInputError(f"{name} must be {what} finite number; got {name}={value!r}.")
    return x


def _check_save_every(save_every) -> int:
    if save_every is None:
        return 1
    if save_every == "final":
        return np.iinfo(np.int32).max
    if isinstance(save_every, bool) or not isinstance(save_every, (int, np.integer)) or save_every < 1:
        raise LobattoDAEInputError(
            f"save_every must be a positive integer (keep every k-th step point) or 'final'; got {save_every!r}."
        )
    return int(min(save_every, np.iinfo(np.int32).max))


def _check_t_eval(t_eval, t0: float, t1: float):
    if t_eval is None:
        return None
    try:
        if isinstance(t_eval, (str, bytes)):
            raise TypeError
        te = np.asarray(t_eval, dtype=np.float64)
    except (TypeError, ValueError):
        raise LobattoDAEInputError(f"t_eval must be a 1-D array of times; got {t_eval!r}.") from None
    te = np.atleast_1d(te)
    if te.ndim != 1 or te.size == 0:
        raise LobattoDAEInputError(f"t_eval must be a non-empty 1-D array of times; got shape {te.shape}.")
    if not np.all(np.isfinite(te)):
        raise LobattoDAEInputError("t_eval contains NaN or inf; give finite times.")
    lo, hi = min(t0, t1), max(t0, t1)
    if np.any(te < lo) or np.any(te > hi):
        raise LobattoDAEInputError(f"t_eval must lie within t_span = ({t0:g}, {t1:g}); got values in [{te.min():g}, {te.max():g}].")
    step = np.diff(te) * (1.0 if t1 > t0 else -1.0)
    if np.any(step < 0):
        raise LobattoDAEInputError(
            "t_eval must be sorted in the direction of integration (increasing for t1 > t0, decreasing for t1 < t0)."
        )
    return te


def _step_count(t0: float, t1: float, n_steps, dt) -> tuple[int, float]:
    if n_steps is not None and dt is not None:
        raise LobattoDAEInputError("give at most one of n_steps (number of steps) or dt (step size).")
    span = abs(t1 - t0)
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
        count = span / dt * (1 - 1e-12)
        if not math.isfinite(count) or count > _MAX_CONSTANT_STEPS:
            raise LobattoDAEInputError(
                f"dt={dt:g} over |t1 - t0| = {span:g} means {count:.3g} steps, more than {_MAX_CONSTANT_STEPS:.0e}; "
                "use a larger dt, or adaptive steps (drop dt and give rtol/atol)."
            )
        n = max(1, math.ceil(count))
    if n > _MAX_CONSTANT_STEPS:
        raise LobattoDAEInputError(f"n_steps={n} is more than {_MAX_CONSTANT_STEPS:.0e} steps; the step counter is 32-bit.")
    h = (t1 - t0) / n
    if abs(h) < 1e-14 * max(abs(t0), abs(t1)):
        raise LobattoDAEInputError(
            f"the step h = {h:g} is below the resolution of t (|t| up to {max(abs(t0), abs(t1)):g}); the times "
            "t_k would not be distinct. Use fewer steps or shift t_span towards 0."
        )
    return n, h


#: The step counter is int32.
_MAX_CONSTANT_STEPS = 2**31 - 2


def _check_t_span(t_span) -> tuple[float, float]:
    try:
        if isinstance(t_span, (str, bytes)):  # "02" would be (0.0, 2.0)
            raise TypeError
        t0, t1 = (float(x) for x in t_span)
    except (TypeError, ValueError):
        raise LobattoDAEInputError(f"t_span must be a pair (t0, t1) of numbers; got {t_span!r}.") from None
    if not (math.isfinite(t0) and math.isfinite(t1)):
        raise LobattoDAEInputError(f"t_span must be finite; got {t_span!r}.")
    if t1 == t0:
        raise LobattoDAEInputError(f"t_span = ({t0}, {t1}) is empty; give t1 != t0 (t1 < t0 integrates backwards).")
    if abs(t1 - t0) < 1e-13 * max(abs(t0), abs(t1)):
        raise LobattoDAEInputError(
            f"t_span = ({t0!r}, {t1!r}) is shorter than the resolution of t at that magnitude (about "
            f"{_EPS * max(abs(t0), abs(t1)):.2g}); shift the time origin (the problem functions can add it back "
            "through args)."
        )
    return t0, t1


# -- the run ------------------------------------------------------------------------------------
#: Recorded chunks are merged into one block every this many: few NumPy objects, and each
#: row is copied once more, not once per chunk.
_MERGE = 32


class _Rows(NamedTuple):
    """Output rows of one kind, immutable: NumPy blocks, each a tuple of fields (arrays with
    the same number of rows). Appending returns a new value; the trailing unmerged blocks are
    merged into one every :data:`_MERGE` appends. ``saved``: the first rows, already in the
    checkpoint (a save writes only the rows after them)."""

    empty: tuple  # the fields with no rows (dtypes and trailing shapes)
    blocks: tuple = ()
    merged: int = 0  # the first blocks are merged ones; the others are recent chunks
    count: int = 0
    saved: int = 0

    def append(self, block: tuple) -> _Rows:
        k = len(block[0])
        if not k:
            return self
        block = tuple(np.asarray(x, e.dtype) for x, e in zip(block, self.empty, strict=True))
        blocks, merged = self.blocks + (block,), self.merged
        if len(blocks) - merged >= _MERGE:
            blocks, merged = blocks[:merged] + (_cat(blocks[merged:]),), merged + 1
        return self._replace(blocks=blocks, merged=merged, count=self.count + k)

    def since(self, start: int) -> tuple:
        """The fields of the rows from ``start`` on, concatenated (only the blocks holding them
        are read)."""
        parts, first = [], self.count
        for block in reversed(self.blocks):
            if first <= start:
                break
            first -= len(block[0])
            parts.append(block if first >= start else tuple(x[start - first:] for x in block))
        return _cat(parts[::-1]) if parts else self.empty

    def all(self) -> tuple:
        return self.since(0)

    def unsaved(self) -> tuple:
        return self.since(self.saved)


def _cat(blocks) -> tuple:
    return blocks[0] if len(blocks) == 1 else tuple(np.concatenate(xs) for xs in zip(*blocks))


#: The names of the row fields in a checkpoint, per kind of rows.
_ROW_FIELDS = {"rows": Record._fields, "dense": ("dense",), "events": ("event_rows", "event_index")}


class _Progress(NamedTuple):
    """How far a run got: replaced as a whole (one assignment), so that an interrupt can never
    see a state that does not belong to its rows."""

    state: State
    rows: _Rows  # the output rows (Record fields)
    dense: _Rows | None  # packed dense-output rows (dense_output=True)
    events: _Rows | None  # (event_rows, event_index) (with events)
    recoveries: int
    segments: Any = None  # _checkpoint.Segments of the last checkpoint written or read

    @classmethod
    def start(cls, state: State, opt: _Options, recoveries: int = 0) -> _Progress:
        """No rows yet (their shapes from ``state``)."""
        n, m, (pieces, s) = state.q.shape[-1], state.lam.shape[-1], state.last.V.shape[:2]
        f, i = np.float64, np.int32
        rows = (np.zeros(0, f), np.zeros((0, n), f), np.zeros((0, n), f), np.zeros((0, m), f), np.zeros(0, i),
                np.zeros(0, i), np.zeros(0, f), np.zeros(0, f), np.zeros(0, f), np.zeros(0, bool))
        dense = _Rows((np.zeros((0, dense_size(pieces, s, n, m)), f),)) if opt.output.dense else None
        events = _Rows((np.zeros((0, 1 + 2 * n + m), f), np.zeros(0, i))) if opt.output.events else None
        return cls(state, _Rows(rows), dense, events, recoveries)

    def kinds(self):
        """``(name, rows)`` of each kind of rows the run records."""
        kinds = (("rows", self.rows), ("dense", self.dense), ("events", self.events))
        return [(kind, rows) for kind, rows in kinds if rows is not None]


def solve(
    problem,
    method: LobattoIIIAIIIB,
    t_span,
    q0,
    p0,
    *,
    n_steps: int | None = None,
    dt: float | None = None,
    rtol: float | None = None,
    atol: float | None = None,
    first_step: float | None = None,
    max_step: float | None = None,
    controller=None,
    t_eval=None,
    dense_output: bool = False,
    events=None,
    save_every: int | str | None = None,
    lam0=None,
    args: Any = None,
    throw: bool = True,
    project_initial: bool = False,
    chunk_size: int | None = None,
    progress: bool | Callable[[float, float], None] = False,
    max_recoveries: int = 0,
    checkpoint: str | os.PathLike | None = None,
    checkpoint_every: int | None = None,
    resume: bool = False,
    t_eval_rows: str | None = None,
    max_steps: int | None = None,
) -> Solution:
    """Integrate a partitioned index-2 DAE from ``t_span[0]`` to ``t_span[1]``.

    Steps are chosen by error control (``rtol``, ``atol``) unless ``n_steps`` or ``dt`` asks
    for constant steps. The vocabulary follows scipy's ``solve_ivp``.

    Parameters
    ----------
    problem : PartitionedDAE, NonholonomicSystem or MechanicalSystem
        Reuse one problem object and pass parameters through ``args``: the compiled loop is
        cached per problem object, method, options that shape the output and shapes, so new
        numbers (initial values, ``t_span``, tolerances, ``n_steps``, ``args`` values) do not
        recompile.
    method : LobattoIIIAIIIB
    t_span : (float, float)
        ``(t0, t1)``; ``t1 < t0`` integrates backwards.
    q0, p0 : array_like, shape (n,)
        Consistent initial values, ``φ(t0, q0, p0) = 0``.
    n_steps, dt : int or float, optional
        Constant steps: their number, or a maximal step size (the step used is
        ``h = (t1 - t0) / ceil(|t1 - t0| / dt)``, reported in ``stats["h"]``).
    rtol, atol : float, optional
        Adaptive steps (default ``1e-8``, ``1e-10``): the local error estimate of q and p is
        kept below ``atol + rtol·|y|`` in the RMS norm, mapped so that the global error is
        roughly proportional to rtol (:class:`~lobattodae.PIController`). λ is not error-controlled.
    first_step, max_step : float, optional
        Adaptive steps: the first step size (default: chosen from the initial slopes) and an
        upper bound on all of them (default: none).
    max_steps : int, optional
        Adaptive steps: the cap on step attempts (default :data:`MAX_STEPS` = 10⁷, at most
        2·10⁷), checked between compiled chunks of ``chunk_size`` attempts; reaching it ends
        the run with ``Result.MAX_STEPS`` (``success`` False) and the computed prefix. A
        ``max_step`` that would need more steps is refused up front.
    controller : PIController or ReversibleStepSize, optional
        The step-size rule of adaptive steps (default ``PIController()``);
        ``ReversibleStepSize()`` keeps the variable-step method symmetric for reversible
        problems (bounded energy errors over long times).
    t_eval : array_like, optional
        Output times (within ``t_span``, sorted in the direction of integration) instead of
        step points; memory is proportional to ``len(t_eval)``. ``t_eval=[t1]`` keeps the
        final state only.
    t_eval_rows : {"step", "interpolate", "project"}, optional
        How the ``t_eval`` rows are made. ``"step"`` (the default under error control): the
        steps are shortened to end on the requested times, so each row is a step point, as
        accurate as the run and on the constraint to round-off; a time between two steps
        the controller would take costs one extra step. ``"interpolate"`` (the default for
        constant steps and ``ReversibleStepSize``, which keep their steps): rows from the
        dense output, no extra steps, accurate to order s between step points (at tight
        tolerances orders of magnitude less accurate than the step points, and ‖φ‖ at the
        interpolation error; ``stats["constraint_residual"]`` reports it). ``"project"``: the
        interpolated rows moved onto the constraints (ψ = 0 for position constraints, φ = 0,
        λ the consistent multiplier), still of order s, with ‖φ‖ at round-off.
    dense_output : bool
        Keep every step's continuous extension: ``sol.sol(t) -> (q, p, lam)``.
    events : callable, Event, or list of them, optional
        ``e(t, q, p, args) -> float``; zeros are located on the dense output and returned in
        ``t_events``, ``q_events``, ... (one array per function). Attributes as in scipy:
        ``e.terminal`` (True, or stop at the k-th zero) and ``e.direction`` (> 0: rising
        zeros only, < 0: falling only). A terminal zero ends the run with a final step onto
        it, so the final state satisfies the constraint to round-off; under error control
        the steps land on every other zero too (its row a step point, as accurate as the
        steps), with constant or reversible steps those rows come from the dense output. Sign changes are looked
        for between the step's nodes (step points and stage points), so two zeros inside one
        step are found when a node lies between them; closer pairs need a smaller
        ``max_step``/``dt`` (:mod:`lobattodae._events`). A zero exactly at t0 counts as in
        scipy (when the function then moves in the event's direction; a terminal one ends the
        run at t0).
    save_every : int or 'final', optional
        Keep every k-th step point (and the last), or only the final one.
    lam0 : array_like, shape (m,), optional
        Initial multiplier. Computed from the hidden constraint when omitted; checked
        against it when given.
    args : pytree, optional
        Passed to the problem functions.
    throw : bool
        If True (default) a failed run raises :class:`NewtonFailure`; otherwise the computed
        prefix is returned with ``success=False`` and the reason in ``result``.
    project_initial : bool
        Replace ``p0`` by its least-squares projection onto the constraint
        {p : φ(t0, q0, p) = 0} (always, to round-off) instead of rejecting inconsistent values.
    chunk_size : int, optional
        Step attempts per compiled chunk (default :data:`~lobattodae._loop.CHUNK`); progress,
        Ctrl-C and checkpoints act between chunks.
    progress : bool or callable
        ``True`` shows a progress bar on stderr once the run has taken more than a second; a
        callable is called after each chunk as ``progress(steps_done, n_steps)`` (constant
        steps) or ``progress(t, t1)`` (adaptive). Ctrl-C returns the computed prefix with
        ``result`` ``INTERRUPTED`` at the end of the chunk (a second Ctrl-C stops at once).
    max_recoveries : int
        Constant steps only (off by default): a step whose Newton iteration fails is retried
        as 2, 4, 8 or 16 substeps, at most this many times per solve; ``stats["recoveries"]``
        counts them. Adaptive steps shrink a failed step by themselves.
    checkpoint : path, optional
        Write the loop state and the computed rows to this file every ``checkpoint_every``
        steps (at chunk boundaries), at the end, and on Ctrl-C. Each save writes only the
        rows since the previous one, appended as a segment file in the directory
        ``<checkpoint>.rows/`` next to it, and rewrites the small file itself (the state),
        atomically (a versioned format): bytes written grow with the rows
        kept (``save_every``), not with the number of saves. Keep (move, copy, delete) the
        file and its ``.rows`` directory together. Its directory must exist. A run without
        ``resume`` replaces an existing checkpoint (its segments are removed at the first save).
        A save that fails (a full disk, a directory made read-only) stops the run with
        :class:`~lobattodae.CheckpointWriteError`, which names the file and the fix and carries
        the computed prefix as ``.solution`` (with ``throw=False`` that prefix is returned,
        ``success`` False, the reason in ``message``); the checkpoint on disk stays the last
        one committed, intact, and resumes.
    checkpoint_every : int, optional
    resume : bool
        Continue from ``checkpoint`` if it exists. It must come from the same run (problem
        functions, method, ``args``, ``t_span``, steps or tolerances, output options, initial
        values). A resumed run gives the same numbers, bit for bit, as an uninterrupted one.

    Returns
    -------
    Solution
        The rows, how the run ended (``success``, ``status``, ``result``, ``message``) and
        ``stats``.

    Raises
    ------
    LobattoDAEInputError
        Bad input, before any work; the subclass says which kind: :class:`ShapeError`,
        :class:`ProblemFunctionError`, :class:`InconsistentInitialValuesError`,
        :class:`SingularConstraintError`, :class:`CheckpointError`.
    TypeError
        ``method`` is not a :class:`LobattoIIIAIIIB`.
    NewtonFailure
        A step failed and ``throw`` is True (the default), with ``.step``, ``.t`` and
        ``.reason``.
    """
    check_float64()
    _refuse_tracers(t_span=t_span, q0=q0, p0=p0, lam0=lam0, args=args, n_steps=n_steps, dt=dt, rtol=rtol, atol=atol)
    opt = _Options.check(
        method, t_span, n_steps, dt, rtol, atol, first_step, max_step, controller, t_eval, dense_output, events,
        save_every, chunk_size, max_recoveries, checkpoint, checkpoint_every, resume, t_eval_rows, max_steps,
    )
    # From here on a first Ctrl-C only asks the run to stop at the next chunk boundary (also
    # during validation and compilation), so it never lands inside JAX or between updates.
    with _deferred_interrupts() as interrupted:
        return _run(problem, method, opt, q0, p0, lam0, args, throw, project_initial, progress, interrupted)


def _refuse_tracers(**inputs) -> None:
    """``solve`` runs Python between compiled chunks and returns NumPy: under ``jax.grad``,
    ``jit`` or ``vmap`` its inputs are tracers, which it cannot use. Say so, and where to go."""
    for name, value in inputs.items():
        if any(isinstance(leaf, jax.core.Tracer) for leaf in jax.tree_util.tree_leaves(value)):
            raise LobattoDAEInputError(
                f"solve() was called with a traced {name} (inside jax.grad, jit, vmap or another JAX "
                "transformation); it runs Python between compiled chunks and returns NumPy arrays, so it "
                "cannot be transformed. Use the pure entry points instead: lobattodae.integrate (constant "
                "steps) or lobattodae.integrate_adaptive(..., differentiable=True) (variable steps), with "
                "lobattodae.consistent_lambda and lobattodae.project_momenta for initial values."
            )


def _padded_t_eval(opt: _Options):
    """t_eval padded with NaN to a power of two ≥ 16 (fewer distinct shapes to compile)."""
    if opt.t_eval is None:
        return None
    size = max(16, 1 << (len(opt.t_eval) - 1).bit_length())
    out = np.full(size, np.nan)
    out[: len(opt.t_eval)] = opt.t_eval
    return jnp.asarray(out)


def _finished(opt: _Options, state: State) -> bool:
    """The run is over: a failure or terminal event, or the end reached and every t_eval row written."""
    if int(state.result) != Result.SUCCESSFUL:
        return True
    if not bool(opt.controller.done(state.controller)):
        return False
    return opt.t_eval is None or int(state.k_eval) >= len(opt.t_eval)


def _run(problem, method, opt: _Options, q0, p0, lam0, args, throw, project_initial, progress, interrupted):
    """Validation, the loop state, the compiled chunks (progress, checkpoints, recovery), the
    Solution; ``interrupted()`` says whether Ctrl-C asked to stop."""
    q0, p0, lam0, phi0 = validate_and_residual(problem, opt.t0, q0, p0, lam0, args, project=project_initial)
    method = for_error_control(method, opt.controller)
    _check_events(opt.output.events, opt.t0, q0, p0, args)
    report = _progress_reporter(progress, opt)
    controller, output = opt.controller, opt.output

    def initial():
        state, packing = init_host(problem, method, controller, output, opt.t0, opt.t1, opt.control, q0, p0, lam0, args)
        return _Progress.start(state, opt), packing

    meta = _run_identity(problem, method, args, opt, q0, p0, lam0) if opt.checkpoint else None
    run = packing = None  # a fresh run computes its initial state in its first chunk's compiled call
    if opt.checkpoint and opt.resume and _checkpoint.exists(opt.checkpoint):
        run, packing = initial()
        run = _resume(opt, meta, run.state)
    t_eval = _padded_t_eval(opt)
    failed = False
    start = time.perf_counter()
    last_saved = 0 if run is None else int(run.state.n_accepted)
    saved_t = opt.t0 if run is None else float(controller.time(run.state.controller))
    write_error, stopped_early = None, False  # an OSError of a checkpoint save; it stopped the run
    try:
        while not interrupted() and (run is None or not (_finished(opt, run.state) or _capped(opt, run.state))):
            if run is None:
                state, chunk, packing = start_host(problem, method, controller, output, opt.t0, opt.t1, opt.control, q0,
                                                   p0, lam0, args, opt.chunk, opt.every, t_eval)
                run = _Progress.start(state, opt)
            else:
                state, chunk = run_host(problem, method, controller, output, packing, run.state, args, opt.chunk,
                                        opt.every, t_eval)
            rows, dense, events = _numpy_chunk(run, chunk)
            if int(state.result) not in (Result.SUCCESSFUL, Result.EVENT):
                recovered = None
                if run.recoveries < opt.max_recoveries:
                    recovered = _recover_step(problem, method, args, state)
                if recovered is None:
                    run = run._replace(state=state, rows=rows, dense=dense, events=events)
                    failed = True
                    break
                state, row = recovered
                run = run._replace(state=state, rows=rows.append(tuple(row)), dense=dense, events=events,
                                   recoveries=run.recoveries + 1)
            else:
                run = run._replace(state=state, rows=rows, dense=dense, events=events)
            if report is not None:
                report(*_progress_numbers(opt, run.state))
            done = int(run.state.n_accepted)
            if opt.checkpoint and opt.checkpoint_every and done - last_saved >= opt.checkpoint_every:
                try:
                    run = _save(opt.checkpoint, meta, run)
                except (OSError, _checkpoint.CheckpointError) as exc:  # the disk, not the run: stop here
                    write_error, stopped_early = exc, True
                    break
                last_saved, saved_t = done, float(controller.time(run.state.controller))
    except KeyboardInterrupt:  # a second Ctrl-C, or one outside the main thread's handler
        pass
    if run is None:  # interrupted before the first chunk
        run, _ = initial()
    if isinstance(report, _ProgressBar):
        report.close()
    finished = _finished(opt, run.state)
    if opt.checkpoint and write_error is None and (int(run.state.n_accepted) > last_saved or not finished):
        try:
            run = _save(opt.checkpoint, meta, run)
        except (OSError, _checkpoint.CheckpointError) as exc:
            write_error = exc
    elapsed = time.perf_counter() - start
    if write_error is None:
        return _assemble(problem, method, args, opt, q0, p0, lam0, phi0, run, failed, finished, throw, elapsed)
    sol = _assemble(problem, method, args, opt, q0, p0, lam0, phi0, run, failed, finished, False, elapsed)
    return _write_failed(opt, sol, write_error, float(controller.time(run.state.controller)),
                         last_saved if run.segments is not None else None, saved_t, stopped_early, throw)


def _write_failed(opt: _Options, sol: Solution, exc: Exception, t_now: float, saved_steps: int | None,
                  saved_t: float, stopped_early: bool, throw: bool) -> Solution:
    """The run whose checkpoint could not be written: :class:`~lobattodae.CheckpointWriteError`
    carrying the computed prefix (``throw``), or that prefix with the reason in its message.

    A failed periodic save stops the run (``stopped_early``: the result is ``INTERRUPTED``,
    ``success`` False; the disk would not take the next save either); a failed final save
    leaves the run's own result. The checkpoint on disk is the last one committed
    (``saved_steps`` steps; None: none of this run), intact."""
    path = opt.checkpoint
    code = getattr(exc, "errno", None)
    if code in (errno.ENOSPC, getattr(errno, "EDQUOT", None)):
        fix = "free space on that disk (or raise the quota)"
    elif code in (errno.EROFS, errno.EACCES, errno.EPERM):
        fix = "make the directory writable again (it may have been remounted read-only)"
    else:
        fix = "fix the cause"
    cause = f"{exc.strerror} (errno {exc.errno})" if isinstance(exc, OSError) and exc.strerror else str(exc)
    if saved_steps is None:
        on_disk = "no checkpoint of this run was committed"
        then = f"{fix} and run again, or choose another checkpoint path"
    else:
        on_disk = (f"the checkpoint on disk is intact and holds the run up to step {saved_steps:,} "
                   f"(t = {saved_t:.6g})")
        then = f"{fix} and continue from it with resume=True, or choose another checkpoint path"
    where = f"t = {t_now:.6g}, {sol.stats['n_steps']:,} steps"
    prefix = "in the error's .solution" if throw else "returned"
    stopped = f"The run stopped there ({where})" if stopped_early else f"The run itself ended ({where})"
    message = (f"cannot write the checkpoint '{path}': {cause}. {stopped}; {on_disk}. The computed prefix is "
               f"{prefix}. To go on, {then}.")
    # stopped early, the run is INTERRUPTED (success False): the message says why; a run that ended by
    # itself keeps its result and message, and this one is added
    own = not (stopped_early and sol.result == Result.INTERRUPTED)
    sol = dataclasses.replace(sol, message=f"{sol.message} {message}" if own else message)
    if throw:
        raise _checkpoint.CheckpointWriteError(message, path=path, solution=sol, errno=code) from exc
    return sol


def _capped(opt: _Options, state: State) -> bool:
    """The adaptive run used up its ``max_steps`` step attempts (checked between chunks)."""
    return opt.adaptive and int(state.n_accepted) + int(state.n_rejected) >= opt.max_steps


def _progress_numbers(opt: _Options, state: State):
    if opt.adaptive:
        return float(opt.controller.time(state.controller)), opt.t1
    return int(state.n_accepted), opt.n


def _check_events(events, t0, q0, p0, args) -> None:
    """Each event function must return one finite number at the initial point."""
    for i, ev in enumerate(events):
        try:
            value = np.asarray(ev.fn(jnp.asarray(t0), jnp.asarray(q0), jnp.asarray(p0), args), dtype=np.float64)
        except Exception as exc:  # noqa: BLE001 - the user's function, reported with its name
            raise LobattoDAEInputError(f"event function {ev.name!r} (events[{i}]) failed at t0: {exc}") from exc
        if value.size != 1:
            raise LobattoDAEInputError(
                f"event function {ev.name!r} (events[{i}]) must return one number; it returned shape {value.shape}."
            )
        if not np.isfinite(value).all():
            raise LobattoDAEInputError(f"event function {ev.name!r} (events[{i}]) is not finite at t0 ({float(value.ravel()[0])}).")


def _numpy_chunk(run: _Progress, chunk):
    """The rows, dense-output data and event zeros of a chunk (NumPy), appended to the run's.

    The used rows are copied out of the chunk's buffers, so that the buffers (up to
    ``chunk_size`` rows each) are freed: with ``save_every`` a chunk uses few of them."""

    def used(x, k):
        return np.array(x[:k])

    rows, dense, events = run.rows, run.dense, run.events
    rows = rows.append(tuple(used(x, int(chunk.n_rows)) for x in chunk.rows))
    if dense is not None:
        dense = dense.append((used(chunk.dense, int(chunk.n_dense)),))
    if events is not None:
        e = int(chunk.n_events)
        events = events.append((used(chunk.event_rows, e), used(chunk.event_index, e)))
    return rows, dense, events


def _recover_step(problem, method, args, state: State):
    """Retry the failed (constant) step of ``state`` as 2^j substeps; return ``(state, row)``
    or None.

    The substeps start afresh (no reused Jacobian, no predictor history: those belong to the
    step size h), and so does the step after the recovered one. The row's statistics are the
    sums over the substeps.
    """
    controller = ConstantStepSize()
    ctrl = state.controller
    t_start, h = controller.proposal(ctrl)
    for j in range(1, _RECOVERY_HALVINGS + 1):
        sub, packing = init_host(
            problem, method, controller, Output(), t_start, t_start + h, ControlOptions(n=1 << j),
            state.q, state.p, state.lam, args,
        )
        sub, chunk = run_host(problem, method, controller, Output(), packing, sub, args, 1 << _RECOVERY_HALVINGS)
        count = int(chunk.n_rows)
        if int(sub.result) != Result.SUCCESSFUL or count != 1 << j:
            continue
        rows = Record(*(x[:count] for x in chunk.rows))
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
            max_constraint=jnp.maximum(state.max_constraint, sub.max_constraint),
            max_drift=jnp.maximum(state.max_drift, sub.max_drift),
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
    the time grid or tolerances, the output options and the initial values."""
    return {
        "problem": _checkpoint.fingerprint_callable(problem),
        "method": repr(method),
        "args": _checkpoint.fingerprint_arrays(args) if args is not None else None,
        "t_span": [opt.t0, opt.t1],
        "steps": [opt.n, opt.h] if not opt.adaptive else [repr(opt.controller)] + [float(x) for x in opt.control[1:]],
        "output": [
            opt.output.dense, opt.every,
            _checkpoint.fingerprint_arrays(opt.t_eval) if opt.t_eval is not None else None,
            [_checkpoint.fingerprint_callable(ev.fn) + f"/{ev.terminal}/{ev.direction}" for ev in opt.output.events],
        ],
        "initial_values": _checkpoint.fingerprint_arrays(np.asarray(q0), np.asarray(p0), np.asarray(lam0)),
    }


def _save(path: str, meta: dict, run: _Progress) -> _Progress:
    """Commit a checkpoint of ``run``: its state and the rows since the last save (an
    incremental segment, :mod:`lobattodae._checkpoint`). Returns ``run`` with those rows
    marked saved."""
    new = {}
    for kind, rows in run.kinds():
        new.update(zip(_ROW_FIELDS[kind], rows.unsaved()))
    counters = {"done": int(run.state.n_accepted), "rows": run.rows.count, "recoveries": run.recoveries}
    segments = _checkpoint.save(path, meta=meta, counters=counters, state=run.state, rows=new, previous=run.segments)
    marked = {kind: rows._replace(saved=rows.count) for kind, rows in run.kinds()}
    return run._replace(segments=segments, **marked)


def _resume(opt: _Options, meta: dict, template: State) -> _Progress:
    path = opt.checkpoint
    empty = _Progress.start(template, opt)
    names = [name for kind, _ in empty.kinds() for name in _ROW_FIELDS[kind]]
    counters, state, rows, segments = _checkpoint.load(path, meta=meta, state_template=template, row_names=names)
    count = int(counters.get("rows", -1))
    if count < 0 or any(len(rows[f]) != count for f in Record._fields):
        raise _checkpoint.CheckpointError(
            f"checkpoint '{path}' is corrupt or not a lobattodae checkpoint (it holds {len(rows['t'])} rows, its "
            f"counter says {count}); delete it or restart without resume."
        )
    if opt.output.events and len(rows["event_rows"]) != len(rows["event_index"]):
        raise _checkpoint.CheckpointError(
            f"checkpoint '{path}' is corrupt or not a lobattodae checkpoint ({len(rows['event_rows'])} event rows, "
            f"{len(rows['event_index'])} event indices); delete it or restart without resume."
        )
    run = _Progress.start(state, opt, int(counters.get("recoveries", 0)))._replace(segments=segments)
    loaded = {}
    for kind, empty_rows in run.kinds():
        fields = tuple(rows[name] for name in _ROW_FIELDS[kind])
        loaded[kind] = empty_rows.append(fields)._replace(saved=len(fields[0]))
    return run._replace(**loaded)


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


def _progress_reporter(progress, opt):
    if progress is False or progress is None:
        return None
    if callable(progress):
        return progress
    return _ProgressBar(adaptive=opt.adaptive, t0=opt.t0)


class _ProgressBar:
    """A progress bar on stderr that appears once a run has taken more than ``delay`` seconds:
    steps for constant steps, simulated time for adaptive ones."""

    def __init__(self, delay: float = 1.0, adaptive: bool = False, t0: float = 0.0):
        self.start = time.perf_counter()
        self.delay = delay
        self.shown = False
        self.adaptive = adaptive
        self.t0 = t0

    def __call__(self, done: float, total: float) -> None:
        el = time.perf_counter() - self.start
        if el < self.delay and not self.shown:
            return
        self.shown = True
        if self.adaptive:
            frac = (done - self.t0) / (total - self.t0)
            what = f"t = {done:.6g} of {total:.6g}"
        else:
            frac = done / total
            what = f"{int(done)}/{int(total)} steps"
        eta = el / frac * (1 - frac) if frac > 0 else float("nan")
        fill = int(30 * frac)
        sys.stderr.write(f"\r[{'#' * fill}{'.' * (30 - fill)}] {what}  {el:6.1f}s  eta {eta:6.1f}s")
        if frac >= 1:
            self.close()
        sys.stderr.flush()

    def close(self) -> None:
        """End the bar's line (also when the run stopped early)."""
        if self.shown:
            sys.stderr.write("\n")
            sys.stderr.flush()
            self.shown = False


# -- the Solution -----------------------------------------------------------------------------------
def _assemble(problem, method, args, opt: _Options, q0, p0, lam0, phi0, run: _Progress, failed, finished, throw,
              elapsed):
    out = Record(*run.rows.all())
    state = run.state
    # Non-finite values reported as success would be a bug upstream; never let them through.
    finite = np.all(np.isfinite(out.q), axis=1) & np.all(np.isfinite(out.p), axis=1) & np.all(np.isfinite(out.lam), axis=1)
    failed_step, result = None, Result.SUCCESSFUL
    if not np.all(finite):
        n_ok = int(np.flatnonzero(~finite)[0])
        failed_step, result = n_ok, Result.NONFINITE
        out = Record(*(x[:n_ok] for x in out))
    elif failed or not Result(int(state.result)).success:  # failed here, or in the run resumed from
        failed_step, result = int(state.n_accepted), Result(int(state.result))
    elif not finished and _capped(opt, state):
        result = Result.MAX_STEPS
    elif not finished:
        result = Result.INTERRUPTED
    elif int(state.result) == Result.EVENT:
        result = Result.EVENT
    with_initial = opt.t_eval is None
    t = np.concatenate([[opt.t0], out.t]) if with_initial else out.t

    def column(x0, rows):
        return np.vstack([x0[None], rows]) if with_initial else rows

    def scalar(x0, rows):
        return np.concatenate([[x0], rows]) if with_initial else rows

    excursions = int(state.stepper.monitor.excursions)
    stats = {
        "newton_iterations": out.iterations,
        "residual_norm": out.residual_norm,
        "constraint_residual": scalar(phi0, out.constraint),
        "multiplier_drift": scalar(0.0, out.drift),
        "lam_resync": out.resync,
        "lam_resets": int(np.count_nonzero(out.resync)),
        "lam_excursions": excursions,
        "max_constraint_residual": max(float(state.max_constraint), float(np.max(out.constraint, initial=0.0))),
        "max_multiplier_drift": float(state.max_drift),
        "n_jacobians": int(state.n_jacobians),
        "n_newton": int(state.n_newton),
        "n_steps": int(state.n_accepted),
        "n_rejected": int(state.n_rejected),
        "h": opt.h,
        "n_clamped": int(state.controller.n_clamped) if isinstance(opt.controller, ReversibleStepSize) else None,
        "failed_step": failed_step,
        "recoveries": run.recoveries,
        "compile_and_run_time": elapsed,
    }
    events = _event_lists(opt, run, q0.shape[-1], lam0.shape[-1])
    sol = None
    if opt.output.dense:
        (dense,) = run.dense.all()
        sol = DenseOutput(method.pair, dense, method.pieces, q0.shape[-1], lam0.shape[-1], opt.t0, problem, args)
    success = result.success and failed_step is None
    message = result.message
    if failed_step is not None:
        tf, hf = (float(x) for x in opt.controller.proposal(state.controller))
        tried = f" (after {run.recoveries} recovered steps; max_recoveries={opt.max_recoveries})" if opt.max_recoveries else ""
        message = f"Step {failed_step} (t = {tf:.6g}, h = {hf:.3g}) failed{tried}: {result.message}"
        if result == Result.STEP_SIZE_TOO_SMALL:
            message += _zero_scale_hint(opt, state)
        if throw:
            raise NewtonFailure(message, step=failed_step, t=tf, reason=result.name.lower())
    elif result == Result.MAX_STEPS:
        t_now = float(opt.controller.time(state.controller))
        message = (f"The step limit max_steps={opt.max_steps:,} was reached at t = {t_now:.6g}, before the end of the "
                   "interval; the computed prefix is returned. Raise max_steps, or loosen the tolerances.")
    elif result == Result.INTERRUPTED:
        t_now = float(opt.controller.time(state.controller))
        of = f" of {opt.n}" if opt.n is not None else ""
        message = f"Interrupted after {int(state.n_accepted)}{of} steps (t = {t_now:.6g}); the computed prefix is returned."
    if method.lam_start == "previous" and excursions:
        k = _first_excursion(out.drift)
        note = (
            f"the multiplier λ_k left its normal band around the hidden constraint in {excursions} steps "
            f"(‖λ_k − λ(q_k, p_k)‖∞ up to {float(state.max_drift):.2e}, first at t ≈ {out.t[min(k, len(out.t) - 1)] if len(out.t) else opt.t0:.6g}). "
            "With lam_start='previous' (the paper's scheme) λ errors are carried with |R(∞)| = 1 and can grow, and with "
            "them the errors in q and p. Use lam_start='auto' (re-synchronise when λ drifts) or 'consistent', or a "
            "smaller step."
        )
        message = f"{message} Warning: {note}"
        warnings.warn(note, RuntimeWarning, stacklevel=3)
    return Solution(
        t, column(q0, out.q), column(p0, out.p), column(lam0, out.lam),
        bool(success), result, message, stats, problem, method, args, *events, sol,
    )


def _zero_scale_hint(opt: _Options, state: State) -> str:
    """The likely cause of a step size that collapsed under ``atol=0``: a component that is 0 at
    the step point has the error scale ``atol + rtol·|y| = 0``, which no error passes."""
    if not opt.adaptive or not isinstance(opt.controller, PIController) or float(opt.control.atol) != 0.0:
        return ""
    zero = [f"{name}[{i}]" for name, y in (("q", state.q), ("p", state.p)) for i in np.flatnonzero(np.asarray(y) == 0)]
    if not zero:
        return ""
    shown = ", ".join(zero[:4]) + (", ..." if len(zero) > 4 else "")
    return (f" Cause: atol=0 and {shown} = 0 there, so the error scale atol + rtol·|y| of that component is 0 "
            "and no step with an error in it passes the test; give a positive atol (an absolute accuracy for "
            "components that pass through or stay at 0, e.g. atol=1e-12).")


def _event_lists(opt: _Options, run: _Progress, n: int, m: int):
    """``(t_events, q_events, p_events, lam_events)``: one array per event function (or Nones)."""
    if not opt.output.events:
        return None, None, None, None
    rows, index = run.events.all()
    out = ([], [], [], [])
    for j in range(len(opt.output.events)):
        mine = rows[index == j]
        mine = mine[np.argsort(mine[:, 0] * np.sign(opt.t1 - opt.t0), kind="stable")]
        for lst, part in zip(out, (mine[:, 0], mine[:, 1 : 1 + n], mine[:, 1 + n : 1 + 2 * n], mine[:, 1 + 2 * n :])):
            lst.append(part)
    return out


def _first_excursion(drift: np.ndarray) -> int:
    """Index of the largest growth of the drift over its early level (for the message only)."""
    if drift.size == 0:
        return 0
    early = float(np.max(drift[: min(len(drift), 10)]))
    above = np.flatnonzero(drift > 10 * early)
    return int(above[0]) if above.size else int(np.argmax(drift))
