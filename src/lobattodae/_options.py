"""The options of a run, as frozen records that check themselves: one set of rules and the
defaults written once, for :func:`~lobattodae.solve`, :func:`~lobattodae.integrate`,
:func:`~lobattodae.integrate_adaptive`, :func:`~lobattodae.ensemble` and the CLI.

* :class:`TimeSpan` — ``(t0, t1)``;
* :class:`ConstantSteps` — ``n`` steps of size ``h``, from ``n_steps`` or ``dt`` over a span
  (:meth:`ConstantSteps.over`) or from ``(t0, h, n_steps)`` (:meth:`ConstantSteps.grid`);
* :class:`AdaptiveSteps` — ``rtol``, ``atol``, ``first_step``, ``max_step``, the controller and
  the cap on step attempts;
* :class:`Saving` — ``t_eval`` (and how its rows are made), ``save_every``, dense output, events;
* :class:`Persistence` — the checkpoint file, how often it is written, resume.

:func:`steps_over` picks constant or adaptive steps from the keyword arguments and refuses
options of the other kind. Each record has an ``identity()``: what a checkpoint or an
ensemble file must match to belong to the same run. The public signatures keep their keyword
arguments; each entry point maps them onto these records. Numbers that arrive as tracers
(inside ``jit``/``vmap``, :func:`~lobattodae.integrate_adaptive` only) are not checked here;
the loop reports what it can (``Result.INVALID_T_EVAL``).
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from ._io import checkpoint as _checkpoint
from ._io import fingerprint_arrays, fingerprint_callable
from ._controllers import ATOL, MIN_RELATIVE_STEP, RTOL, ConstantStepSize, ControlOptions, PIController
from ._reversible import ReversibleStepSize
from ._errors import LobattoDAEInputError
from ._events import Event, as_events
from ._chunks import CHUNK, recording_of
from ._loop import Output, Recording
from ._results import Result
from ._validate import check_method, check_tolerance_attainable

__all__ = [
    "ATOL",
    "MAX_STEPS",
    "RTOL",
    "STATIC_MAX_STEPS",
    "T_EVAL_ROWS",
    "AdaptiveSteps",
    "RunOptions",
    "ConstantSteps",
    "Persistence",
    "Saving",
    "TimeSpan",
    "check_count",
    "check_max_steps",
    "check_t_eval",
    "check_t_span",
    "check_writable",
    "concrete",
    "positive_float",
    "steps_over",
    "t_eval_output",
    "t_eval_rows_mode",
]

_EPS = float(np.finfo(np.float64).eps)
#: The default cap on the step attempts of an adaptive ``solve`` (as scipy and diffrax cap theirs):
#: far above any run the tolerances ask for, and low enough that no counter can overflow.
MAX_STEPS = 10_000_000
#: The largest cap: every counter of the loop is int32 and a step attempt counts up to three
#: Newton solves of ``max_iterations`` iterations each.
MAX_STEPS_LIMIT = 20_000_000
#: The default cap where it is static and sizes the output (:func:`~lobattodae.integrate_adaptive`,
#: :func:`~lobattodae.ensemble`): a buffer of this many rows per trajectory.
STATIC_MAX_STEPS = 4096
#: The step counter of constant steps is int32.
MAX_CONSTANT_STEPS = 2**31 - 2
#: The smallest rtol float64 can deliver.
MIN_RTOL = 100 * _EPS


# -- scalar rules ---------------------------------------------------------------------------------
def _is_real(value) -> bool:
    """A real number: a Python or NumPy scalar, or a 0-d NumPy or (concrete) JAX array (no bool)."""
    if isinstance(value, (bool, np.bool_, str, bytes)):
        return False
    if isinstance(value, (int, float, np.integer, np.floating)):
        return True
    dtype = getattr(value, "dtype", None)
    return (isinstance(value, (np.ndarray, jax.Array)) and value.ndim == 0
            and (np.issubdtype(dtype, np.integer) or np.issubdtype(dtype, np.floating)))


def positive_float(name: str, value, allow_zero: bool = False, allow_inf: bool = False) -> float:
    """``value`` as a float, refused unless positive (or zero, or inf, where allowed) and a number."""
    if not _is_real(value):
        raise LobattoDAEInputError(f"{name} must be a positive number; got {value!r}.")
    x = float(value)
    if math.isnan(x) or (math.isinf(x) and not allow_inf) or x < 0 or (x == 0 and not allow_zero):
        what = "a non-negative" if allow_zero else "a positive"
        raise LobattoDAEInputError(f"{name} must be {what} finite number; got {name}={value!r}.")
    return x


def check_count(name: str, value, what: str = "it sets the output shape") -> int:
    """A positive integer (``n_steps``, ``max_steps``, ``block_size``, ``chunk_size``)."""
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
        raise LobattoDAEInputError(f"{name} must be a positive integer ({what}); got {value!r}.")
    return int(value)


def check_t_span(t_span) -> tuple[float, float]:
    """``(t0, t1)``: two finite, distinct numbers, resolvable at their magnitude."""
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


def check_t_eval(t_eval, t0: float, t1: float) -> np.ndarray | None:
    """Output times: a non-empty 1-D array of finite times within ``(t0, t1)``, sorted in the
    direction of integration (None: none)."""
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


# -- records -----------------------------------------------------------------------------------------
@dataclass(frozen=True)
class TimeSpan:
    """``(t0, t1)``; ``t1 < t0`` integrates backwards."""

    t0: float
    t1: float

    @classmethod
    def of(cls, t_span) -> TimeSpan:
        return cls(*check_t_span(t_span))

    @property
    def length(self) -> float:
        return abs(self.t1 - self.t0)

    def identity(self) -> list[float]:
        return [self.t0, self.t1]


@dataclass(frozen=True)
class ConstantSteps:
    """``n`` steps of size ``h`` (negative: backwards)."""

    n: int
    h: float

    @classmethod
    def over(cls, span: TimeSpan, n_steps=None, dt=None) -> ConstantSteps:
        """``n_steps`` steps over ``span``, or steps of at most ``dt`` (``h = (t1 - t0) / ceil(|t1 - t0| / dt)``)."""
        if n_steps is not None and dt is not None:
            raise LobattoDAEInputError("give at most one of n_steps (number of steps) or dt (step size).")
        if n_steps is not None:
            if isinstance(n_steps, bool) or not isinstance(n_steps, (int, np.integer)):
                raise LobattoDAEInputError(f"n_steps must be a positive integer; got {n_steps!r}.")
            if n_steps <= 0:
                raise LobattoDAEInputError(f"n_steps must be a positive integer; got n_steps={n_steps}.")
            n = int(n_steps)
        else:
            if not _is_real(dt):
                raise LobattoDAEInputError(f"dt must be a positive finite number; got {dt!r}.")
            dt = float(dt)
            if not (math.isfinite(dt) and dt > 0):
                raise LobattoDAEInputError(f"dt must be a positive finite step size; got dt={dt!r}.")
            count = span.length / dt * (1 - 1e-12)
            if not math.isfinite(count) or count > MAX_CONSTANT_STEPS:
                raise LobattoDAEInputError(
                    f"dt={dt:g} over |t1 - t0| = {span.length:g} means {count:.3g} steps, more than "
                    f"{MAX_CONSTANT_STEPS:.0e}; use a larger dt, or adaptive steps (drop dt and give rtol/atol)."
                )
            n = max(1, math.ceil(count))
        if n > MAX_CONSTANT_STEPS:
            raise LobattoDAEInputError(f"n_steps={n} is more than {MAX_CONSTANT_STEPS:.0e} steps; the step counter is 32-bit.")
        h = (span.t1 - span.t0) / n
        if abs(h) < 1e-14 * max(abs(span.t0), abs(span.t1)):
            raise LobattoDAEInputError(
                f"the step h = {h:g} is below the resolution of t (|t| up to {max(abs(span.t0), abs(span.t1)):g}); "
                "the times t_k would not be distinct. Use fewer steps or shift t_span towards 0."
            )
        return cls(n, h)

    @classmethod
    def grid(cls, t0, h, n_steps) -> tuple[float, ConstantSteps]:
        """``(t0, steps)`` of ``n_steps`` steps of size ``h`` from ``t0`` (default 0)."""
        n = check_count("n_steps", n_steps)
        t0 = 0.0 if t0 is None else _finite("t0", t0)
        h = _finite("h", h)
        if h == 0.0:
            raise LobattoDAEInputError("h must be nonzero (negative h integrates backwards).")
        return t0, cls(n, h)

    controller = ConstantStepSize()

    @property
    def control(self) -> ControlOptions:
        return ControlOptions(n=self.n)

    def identity(self) -> list:
        return [self.n, self.h]


def _finite(name: str, value) -> float:
    if not _is_real(value):
        raise LobattoDAEInputError(f"{name} must be a real number; got {value!r}.")
    x = float(value)
    if not math.isfinite(x):
        raise LobattoDAEInputError(f"{name} must be a finite number; got {value!r}.")
    return x


@dataclass(frozen=True)
class AdaptiveSteps:
    """Error-controlled (or reversible) steps: tolerances, step bounds, the controller and the
    cap on step attempts."""

    rtol: float = RTOL
    atol: float = ATOL
    first_step: float = 0.0  # 0: chosen from the initial slopes
    max_step: float = math.inf
    controller: Any = PIController()
    max_steps: int = MAX_STEPS

    @classmethod
    def over(cls, span: TimeSpan, rtol=None, atol=None, first_step=None, max_step=None, controller=None,
             max_steps=None, default_max_steps: int = MAX_STEPS) -> AdaptiveSteps:
        rtol = RTOL if rtol is None else positive_float("rtol", rtol)
        atol = ATOL if atol is None else positive_float("atol", atol, allow_zero=True)
        if rtol < MIN_RTOL:
            raise LobattoDAEInputError(f"rtol={rtol:g} is below what float64 can deliver; use rtol >= {MIN_RTOL:.1e}.")
        first = 0.0 if first_step is None else positive_float("first_step", first_step, allow_zero=True)
        if first > span.length:
            raise LobattoDAEInputError(f"first_step={first:g} is longer than the interval |t1 - t0| = {span.length:g}.")
        biggest = math.inf if max_step is None else positive_float("max_step", max_step, allow_inf=True)
        _check_resolvable_steps(span, first, biggest)
        ctrl = cls.check_controller(PIController() if controller is None else controller)
        return cls(rtol, atol, first, biggest, ctrl, _check_max_steps(max_steps, span, biggest, default_max_steps))

    @staticmethod
    def check_controller(controller):
        if not isinstance(controller, (PIController, ReversibleStepSize)):
            raise LobattoDAEInputError(
                "controller must be lobattodae.PIController(...) or lobattodae.ReversibleStepSize(...); got "
                f"{controller!r}."
            )
        return controller

    @property
    def control(self) -> ControlOptions:
        return ControlOptions(1, self.rtol, self.atol, self.first_step, self.max_step)

    def identity(self) -> list:
        return [repr(self.controller), self.rtol, self.atol, self.first_step, self.max_step]


def check_max_steps(max_steps, default: int = MAX_STEPS) -> int:
    """The cap on step attempts (``default`` when None): a positive integer up to MAX_STEPS_LIMIT."""
    if max_steps is None:
        return default
    if isinstance(max_steps, bool) or not isinstance(max_steps, (int, np.integer)) or not 0 < max_steps <= MAX_STEPS_LIMIT:
        raise LobattoDAEInputError(
            f"max_steps must be a positive integer up to {MAX_STEPS_LIMIT:,} (the cap on step attempts); got "
            f"{max_steps!r}. Split a longer run into several solve calls (or use checkpoint/resume)."
        )
    return int(max_steps)


def _check_max_steps(max_steps, span: TimeSpan, max_step: float, default: int) -> int:
    """:func:`check_max_steps`, and a ``max_step`` that would need more steps refused up front."""
    max_steps = check_max_steps(max_steps, default)
    needed = span.length / max_step
    if needed > max_steps:
        raise LobattoDAEInputError(
            f"max_step={max_step:g} needs at least {needed:.3g} steps over |t1 - t0| = {span.length:g}, more than "
            f"max_steps={max_steps:,}; raise max_step (or max_steps)."
        )
    return max_steps


def _check_resolvable_steps(span: TimeSpan, first_step: float, max_step: float) -> None:
    """Refuse up front a ``first_step`` or ``max_step`` below the smallest step the run can take,
    ``MIN_RELATIVE_STEP·max(|t|, |t1 - t0|)`` (a shorter one ends the run as
    ``STEP_SIZE_TOO_SMALL``, whose message would blame the problem)."""
    for name, value, largest_t in (("first_step", first_step, abs(span.t0)),
                                   ("max_step", max_step, max(abs(span.t0), abs(span.t1)))):
        smallest = MIN_RELATIVE_STEP * max(largest_t, span.length)
        if 0 < value < smallest:
            raise LobattoDAEInputError(
                f"{name}={value:g} is below the smallest step a run can take here, {MIN_RELATIVE_STEP:g}·max(|t|, "
                f"|t1 - t0|) = {smallest:.3g} (a shorter step is lost in the round-off of t, and the run would end "
                f"as STEP_SIZE_TOO_SMALL); use {name} >= {smallest:.3g}, or shift t_span towards 0."
            )


_ADAPTIVE_ONLY = ("rtol", "atol", "first_step", "max_step", "controller", "max_steps")


def steps_over(span: TimeSpan, n_steps=None, dt=None, **adaptive) -> ConstantSteps | AdaptiveSteps:
    """Constant steps when ``n_steps`` or ``dt`` is given (the options of adaptive steps are then
    refused), else adaptive steps from ``adaptive`` (the keywords of :meth:`AdaptiveSteps.over`)."""
    if n_steps is None and dt is None:
        return AdaptiveSteps.over(span, **adaptive)
    steps = ConstantSteps.over(span, n_steps, dt)
    for name in _ADAPTIVE_ONLY:
        value = adaptive.get(name)
        if name == "max_step" and value is not None and math.isinf(positive_float("max_step", value, allow_inf=True)):
            continue
        if value is not None:
            fix = {"max_step": "with constant steps use dt", "max_steps": "constant steps take n_steps (or dt)"}.get(
                name, f"drop n_steps/dt to let the solver choose the steps, or drop {name}")
            raise LobattoDAEInputError(f"{name} applies to adaptive steps; {fix}.")
    return steps


#: How ``t_eval`` rows are made: ``"step"``, error-controlled steps end on the requested times
#: (rows as accurate as step points, at the cost of the extra steps); ``"interpolate"``, rows
#: from the dense output (order s between step points, no extra steps, φ violated by the
#: interpolation error); ``"project"``, interpolated rows moved onto the constraints (ψ = 0,
#: φ = 0 and the consistent λ: :func:`~lobattodae._projection.project_row`; order s, φ at round-off).
T_EVAL_ROWS = ("step", "interpolate", "project")


def t_eval_rows_mode(t_eval_rows, controller, has_t_eval: bool) -> str | None:
    """How the ``t_eval`` rows are made (one of T_EVAL_ROWS; None without ``t_eval``): the one
    place that decides it. Default (None): steps end on them under error control; constant steps
    (they keep their grid) and the reversible control (it would lose its symmetry) interpolate."""
    if t_eval_rows is not None and t_eval_rows not in T_EVAL_ROWS:
        raise LobattoDAEInputError(
            "t_eval_rows must be 'step' (error-controlled steps end on the t_eval times), 'interpolate' (rows from "
            f"the dense output) or 'project' (interpolated rows moved onto the constraints); got {t_eval_rows!r}."
        )
    if t_eval_rows == "step" and not isinstance(controller, PIController):
        raise LobattoDAEInputError(
            "t_eval_rows='step' needs error-controlled steps (rtol/atol with a PIController): constant steps keep "
            "their grid and ReversibleStepSize its symmetry; use t_eval_rows='interpolate' or 'project'."
        )
    if not has_t_eval:
        return None
    if t_eval_rows is None:
        return "step" if isinstance(controller, PIController) else "interpolate"
    return t_eval_rows


def t_eval_output(mode: str | None) -> Output:
    """The loop's :class:`~lobattodae._loop.Output` of :func:`~lobattodae.integrate_adaptive`:
    ``t_eval`` rows made as ``mode`` (:func:`t_eval_rows_mode`; None: step points)."""
    return Output(t_eval=mode is not None, step_to_t_eval=mode == "step", project_t_eval=mode == "project")


@dataclass(frozen=True)
class Saving:
    """What a run keeps: rows at ``t_eval`` (made as ``rows``, :data:`T_EVAL_ROWS`) or every
    ``every``-th step point, the dense output, the zeros of ``events``."""

    t_eval: np.ndarray | None = None
    rows: str | None = None  # how the t_eval rows are made (None without t_eval)
    every: int = 1
    dense: bool = False
    events: tuple[Event, ...] = ()
    land_on_events: bool = False

    @classmethod
    def of(cls, span: TimeSpan, controller, t_eval=None, t_eval_rows=None, save_every=None, dense_output=False,
           events=None) -> Saving:
        t_eval = check_t_eval(t_eval, span.t0, span.t1)
        every = _check_save_every(save_every)
        if t_eval is not None and save_every not in (None, 1):
            raise LobattoDAEInputError("give t_eval (rows at given times) or save_every (every k-th step point), not both.")
        rows = t_eval_rows_mode(t_eval_rows, controller, t_eval is not None)
        events = as_events(events)
        return cls(t_eval, rows, every, bool(dense_output), events, bool(events) and isinstance(controller, PIController))

    @property
    def output(self) -> Output:
        """The loop's static :class:`~lobattodae._loop.Output`: what the compiled program can
        record, which :meth:`recording` chooses among as data. Two programs per problem, method,
        controller and events: step points (any ``save_every``), and, with ``t_eval`` or the
        dense output, the one that can record both (``t_eval`` of any length, stepped onto or
        interpolated); ``t_eval_rows="project"`` adds the projection's code. The plain run does
        not carry the other's code (measured: +0.6-0.9 s of compilation, +5 % per step on the
        knife edge), and the first run with t_eval or the dense output compiles once for all of
        them."""
        records = self.t_eval is not None or self.dense
        return Output(t_eval=records, dense=records, events=self.events, step_to_t_eval=records,
                      project_t_eval=self.rows == "project", land_on_events=self.land_on_events)

    def recording(self, length: int, k_eval: int = 0) -> Recording:
        """What a chunk of ``length`` attempts records, the output times from row ``k_eval`` on."""
        return recording_of(length, self.every, self.t_eval, k_eval, step_to_t_eval=self.rows == "step",
                            dense=self.dense)

    def identity(self) -> list:
        """What a checkpoint or ensemble file of the run must match: the kept rows, the dense
        output, the events (their code) and, with ``t_eval``, how its rows are made."""
        made = [self.rows] if self.t_eval is not None else []  # no entry without t_eval: older files still match
        return [self.dense, self.every, None if self.t_eval is None else fingerprint_arrays(self.t_eval),
                [fingerprint_callable(ev.fn) + f"/{ev.terminal}/{ev.direction}" for ev in self.events], *made]


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


@dataclass(frozen=True)
class Persistence:
    """The checkpoint file (None: none), how often it is written (steps; None: at the end and
    on Ctrl-C only) and whether to resume from it."""

    checkpoint: str | None = None
    every: int | None = None
    resume: bool = False

    @classmethod
    def of(cls, checkpoint=None, checkpoint_every=None, resume=False) -> Persistence:
        """The file and its rows directory are checked before any work (a missing or read-only
        directory, a symbolic link or a file where the rows go)."""
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
        if checkpoint is None:
            return cls(None, None, bool(resume))
        path = os.fspath(checkpoint)
        check_writable(path, "checkpoint")
        rows_dir = _checkpoint.rows_directory(path)
        _checkpoint.check_links(path)  # a symbolic link at the path or its rows directory is refused before any work
        if os.path.lexists(rows_dir) and not os.path.isdir(rows_dir):
            raise LobattoDAEInputError(
                f"cannot write the checkpoint '{path}': its rows go to the directory '{rows_dir}', and something "
                "else is there; remove it or choose another checkpoint path."
            )
        return cls(path, checkpoint_every, bool(resume))


# -- all options of a solve -------------------------------------------------------------------------
@dataclass(frozen=True)
class RunOptions:
    """Every option of :func:`~lobattodae.solve`, as the records above, checked before any work
    is done."""

    span: TimeSpan
    steps: ConstantSteps | AdaptiveSteps
    saving: Saving
    persistence: Persistence
    chunk: int
    max_recoveries: int

    @classmethod
    def check(cls, method, t_span, n_steps, dt, rtol, atol, first_step, max_step, controller, t_eval, dense_output,
              events, save_every, chunk_size, max_recoveries, checkpoint, checkpoint_every, resume, t_eval_rows=None,
              max_steps=None):
        check_method(method, native=True)
        check_tolerance_attainable(method)
        span = TimeSpan.of(t_span)
        steps = steps_over(span, n_steps, dt, rtol=rtol, atol=atol, first_step=first_step, max_step=max_step,
                           controller=controller, max_steps=max_steps)
        saving = Saving.of(span, steps.controller, t_eval, t_eval_rows, save_every, dense_output, events)
        chunk = CHUNK if chunk_size is None else check_count("chunk_size", chunk_size, "step attempts per chunk")
        if isinstance(max_recoveries, bool) or not isinstance(max_recoveries, int) or max_recoveries < 0:
            raise LobattoDAEInputError(f"max_recoveries must be a non-negative integer; got {max_recoveries!r}.")
        if max_recoveries and (isinstance(steps, AdaptiveSteps) or saving.t_eval is not None or saving.dense
                               or saving.events):
            raise LobattoDAEInputError(
                "max_recoveries applies to constant steps without t_eval, events or dense_output; adaptive steps "
                "recover from failed steps by themselves (drop n_steps/dt)."
            )
        return cls(span, steps, saving, Persistence.of(checkpoint, checkpoint_every, resume), chunk, max_recoveries)

    # the names the run reads
    t0 = property(lambda self: self.span.t0)
    t1 = property(lambda self: self.span.t1)
    adaptive = property(lambda self: isinstance(self.steps, AdaptiveSteps))
    controller = property(lambda self: self.steps.controller)
    control = property(lambda self: self.steps.control)
    n = property(lambda self: None if self.adaptive else self.steps.n)
    h = property(lambda self: None if self.adaptive else self.steps.h)
    max_steps = property(lambda self: self.steps.max_steps if self.adaptive else 0)
    output = property(lambda self: self.saving.output)
    t_eval = property(lambda self: self.saving.t_eval)
    every = property(lambda self: self.saving.every)
    checkpoint = property(lambda self: self.persistence.checkpoint)
    checkpoint_every = property(lambda self: self.persistence.every)
    resume = property(lambda self: self.persistence.resume)

    def finished(self, state) -> bool:
        """The run is over: a failure or terminal event, or the end reached and every t_eval row written."""
        if int(state.result) != Result.SUCCESSFUL:
            return True
        if not bool(self.controller.done(state.controller)):
            return False
        return self.t_eval is None or int(state.k_eval) >= len(self.t_eval)

    def capped(self, state) -> bool:
        """The adaptive run used up its ``max_steps`` step attempts (checked between chunks)."""
        return self.adaptive and int(state.n_accepted) + int(state.n_rejected) >= self.max_steps

    def recording(self, state) -> Recording:
        """What the next chunk records (:meth:`Saving.recording`), from ``state``'s next t_eval row on."""
        return self.saving.recording(self.chunk, int(state.k_eval) if state is not None else 0)

    def progress_numbers(self, state):
        """``(done, total)`` for a progress report: the time reached (adaptive) or steps taken."""
        if self.adaptive:
            return float(self.controller.time(state.controller)), self.t1
        return int(state.n_accepted), self.n


def concrete(*values) -> bool:
    """No tracer among ``values`` (outside ``jit``/``vmap``/``grad``): they can be checked here."""
    return not any(isinstance(leaf, jax.core.Tracer) for leaf in jax.tree_util.tree_leaves(values))
