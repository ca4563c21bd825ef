r"""Step-size controllers: where the next step goes, and whether the last one is kept.

The contract (every controller implements it; all methods are pure and traceable, the
controller object itself is static configuration):

1. ``init(problem, method, t0, t1, q0, p0, lam0, args, options) -> state``: the controller's
   memory before the first step. ``options`` (:class:`ControlOptions`) holds the traced
   numbers (tolerances, step bounds), so new values never recompile.
2. ``proposal(state) -> (t, h)``: the next step starts at t and is h long (h < 0 backwards);
   it never passes the end of the interval.
3. ``adapt(state, problem, args, report) -> (accept, state, result)``: after a step
   (:class:`StepReport`): keep it or not, the next proposal, and a :class:`Result` code
   (``SUCCESSFUL``, or why the run cannot go on).
4. ``done(state)``, ``time(state)``: whether the end is reached; the current step point.
5. ``stop_at(state, t)``: end the run at t instead (a terminal event): the next proposal
   lands on t exactly.

Three controllers:

* :class:`ConstantStepSize`: n equal steps; a failed Newton solve ends the run.
* :class:`PIController`: error-controlled steps (Gustafsson's PI rule on Richardson's
  estimate of each step's own error, :mod:`lobattodae._doubling`), automatic first step,
  rejections.
* :class:`~lobattodae.ReversibleStepSize` (in :mod:`lobattodae._reversible`): Hairer &
  Söderlind's explicit time-reversible control: the variable-step method stays symmetric
  (bounded energy errors on reversible problems).
"""

from __future__ import annotations

import math

from dataclasses import dataclass
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp

from ._problem import vector_field
from ._results import Result
from ._stepper import RETRY_FACTOR

__all__ = [
    "ConstantStepSize",
    "ControlOptions",
    "PIController",
    "StepReport",
    "initial_step",
    "roundoff_may_exceed",
]

#: The smallest step size relative to the time, ``|h| ≥ MIN_RELATIVE_STEP·max(|t|, |t1 - t0|)``;
#: below it the run ends with ``Result.STEP_SIZE_TOO_SMALL``.
MIN_RELATIVE_STEP = 1e-14
#: A step that would leave less than this fraction of itself before the end is stretched to it.
END_STRETCH = 0.01


#: The default tolerances of error-controlled steps (every entry point and the CLI).
RTOL, ATOL = 1e-8, 1e-10


class ControlOptions(NamedTuple):
    """The traced numbers a controller needs (new values do not recompile)."""

    n: Any = 1  # ConstantStepSize: number of steps
    rtol: Any = RTOL
    atol: Any = ATOL
    first_step: Any = 0.0  # 0: automatic
    max_step: Any = jnp.inf

    def cast(self, dtype) -> "ControlOptions":
        return ControlOptions(
            jnp.asarray(self.n, jnp.int32),
            *(jnp.asarray(x, dtype) for x in (self.rtol, self.atol, self.first_step, self.max_step)),
        )


class StepReport(NamedTuple):
    """What a controller sees of a step from t to t + h."""

    ok: jax.Array  # bool: the stage equations were solved
    result: jax.Array  # the stepper's Result code
    t: jax.Array
    h: jax.Array
    y0: jax.Array  # (2n,) (q0, p0)
    y1: jax.Array  # (2n,) (q1, p1)
    error: jax.Array  # (2n,) local error estimate
    q1: jax.Array
    p1: jax.Array
    lam1: jax.Array
    retry: Any = RETRY_FACTOR  # a failed step's size factor for the next attempt (StepInfo.retry)
    share: Any = None  # step doubling: the share of the two results' difference that error is (StepInfo.share)
    resolved: Any = None  # step doubling: bool, the difference lay within Richardson's radius (StepInfo.resolved)


def _rms(x):
    return jnp.sqrt(jnp.mean(x * x))


def _end_clipped(t, h, t_end):
    """``h``, shortened to end at ``t_end`` (or stretched to it when that is within
    END_STRETCH of h), so a run ends on ``t_end`` exactly; otherwise the step the time grid
    holds, ``fl(t + h) − t`` (exact while h ≤ |t|): the steps' sizes then sum to the time that
    passed. Rounding ``t + h`` instead drifts the steps against time by up to half a unit of t
    per step, with one sign while the steps keep their size (a knife edge over T = 1000 at
    s = 6: its angle, which grows at a constant rate, 1.0e-11 off in 1,667 steps)."""
    rest = t_end - t
    return jnp.where(jnp.abs(rest) <= (1.0 + END_STRETCH) * jnp.abs(h), rest, (t + h) - t)


def _too_small(h, t, t0, t_end):
    return jnp.abs(h) < MIN_RELATIVE_STEP * jnp.maximum(jnp.abs(t), jnp.abs(t_end - t0))


# -- constant steps -----------------------------------------------------------------------------
class ConstantState(NamedTuple):
    """Step k of n on ``[t0, t1]``: ``t_k = t0 + k h``, ``h = (t1 - t0) / n``, ``t_n = t1``; a
    terminal event moves the end to ``t_end``."""

    k: jax.Array  # int32
    n: jax.Array  # int32
    t0: jax.Array
    t1: jax.Array
    t_end: jax.Array


@dataclass(frozen=True)
class ConstantStepSize:
    """``n`` equal steps from ``t0`` to ``t1`` (negative h when ``t1 < t0``); every step whose
    stage equations are solved is accepted, a failed one ends the run."""

    #: An attempt this controller does not accept ends the run (no retry starts from the state
    #: before it): the loop then need not keep the method's state of the step before (see
    #: :func:`~lobattodae._loop.attempt`). The controllers of variable steps retry (False).
    ends_on_rejection = True

    def init(self, problem, method, t0, t1, q0, p0, lam0, args, options: ControlOptions) -> ConstantState:
        return ConstantState(jnp.asarray(0, jnp.int32), jnp.asarray(options.n, jnp.int32), t0, t1, t1)

    @staticmethod
    def _grid(st: ConstantState, k):
        h = (st.t1 - st.t0) / st.n
        return jnp.where(k >= st.n, st.t1, st.t0 + k * h)

    def time(self, st: ConstantState):
        t = self._grid(st, st.k)
        direction = jnp.sign(st.t1 - st.t0)
        return jnp.where(direction * (t - st.t_end) >= 0, st.t_end, t)

    def proposal(self, st: ConstantState):
        t = self.time(st)
        t_next = self._grid(st, st.k + 1)
        direction = jnp.sign(st.t1 - st.t0)
        return t, jnp.where(direction * (t_next - st.t_end) > 0, st.t_end, t_next) - t

    def adapt(self, st: ConstantState, problem, args, report: StepReport):
        result = jnp.where(report.ok, Result.SUCCESSFUL, report.result).astype(jnp.int32)
        return report.ok, st._replace(k=st.k + report.ok.astype(jnp.int32)), result

    def done(self, st: ConstantState):
        direction = jnp.sign(st.t1 - st.t0)
        return (st.k >= st.n) | (direction * (self.time(st) - st.t_end) >= 0)

    def stop_at(self, st: ConstantState, t_stop) -> ConstantState:
        return st._replace(t_end=t_stop)


# -- error control ------------------------------------------------------------------------------------
def initial_step(problem, t0, t1, q0, p0, lam0, args, rtol, atol, order, max_step):
    """A first step size from the initial slope and its change (Hairer, Nørsett & Wanner,
    *Solving ODEs I*, II.4; as in scipy's ``select_initial_step``), for an error estimate of
    local order ``order + 1``; never longer than the interval or ``max_step``."""
    span = t1 - t0
    direction = jnp.where(span >= 0, 1.0, -1.0)
    y0 = jnp.concatenate([q0, p0])
    f0 = jnp.concatenate(vector_field(problem, t0, q0, p0, lam0, args))
    scale = atol + rtol * jnp.abs(y0)
    d0, d1 = _rms(y0 / scale), _rms(f0 / scale)
    h0 = jnp.where((d0 < 1e-5) | (d1 < 1e-5), 1e-6, 0.01 * d0 / jnp.maximum(d1, 1e-300))
    h0 = jnp.minimum(h0, jnp.abs(span))
    n = q0.shape[-1]
    y1 = y0 + direction * h0 * f0
    f1 = jnp.concatenate(vector_field(problem, t0 + direction * h0, y1[:n], y1[n:], lam0, args))
    d2 = _rms((f1 - f0) / scale) / h0
    big = jnp.maximum(d1, d2)
    h1 = jnp.where(big <= 1e-15, jnp.maximum(1e-6, h0 * 1e-3), (0.01 / jnp.maximum(big, 1e-300)) ** (1.0 / (order + 1)))
    h = jnp.minimum(jnp.minimum(100 * h0, h1), jnp.minimum(jnp.abs(span), max_step))
    return direction * jnp.where(jnp.isfinite(h) & (h > 0), h, jnp.abs(span))


class AdaptiveState(NamedTuple):
    """The PI controller's memory."""

    t: jax.Array  # the current step point
    h: jax.Array  # the next step size (signed, before clipping to the end)
    t0: jax.Array
    t_end: jax.Array
    err_prev: jax.Array  # the last accepted step's scaled error (PI memory)
    h_rejected: jax.Array  # the size and scaled error of the last attempt if it was rejected (0, inf if not)
    err_rejected: jax.Array
    rtol: jax.Array  # internal tolerances (see PIController)
    atol: jax.Array
    max_step: jax.Array
    order: jax.Array  # k, the power of h in the controlled error (PIController.error_exponent)
    span: jax.Array  # |t1 - t0| of the requested interval (the unit of the error per unit step)
    n_rejected: jax.Array  # int32
    n_floored: jax.Array  # int32: accepted steps that passed only because of ROUNDOFF_FLOOR
    h_last: jax.Array  # size and unfloored scaled error of the last step the controller chose whose error lay
    err_last: jax.Array  # above Newton's noise (accepted, not shortened onto an output time; 0, 0 before one)
    checking: jax.Array  # bool: the last attempt was rejected to check its estimate on a shorter step
    n_checked: jax.Array  # int32: such checks
    radius: jax.Array  # the tableau's richardson_radius (LobattoPair)
    n_failed_solves: jax.Array  # int32: attempts rejected because a stage solve failed (in n_rejected)
    n_unresolved: jax.Array  # int32: accepted steps whose estimate lay beyond Richardson's radius

    @property
    def rejected(self):
        """The last attempt was rejected (no growth on the next step)."""
        return self.h_rejected != 0


class _TimeAndEnd:
    """``done``/``time`` of controllers whose state holds the current time ``t`` and the end
    ``t_end`` (an accepted step that reaches the end sets ``t = t_end`` exactly): the variable
    step sizes, which retry a rejected attempt from the state before it."""

    ends_on_rejection = False  # see ConstantStepSize

    def done(self, st):
        return st.t == st.t_end

    def time(self, st):
        return st.t


#: ``c_tol`` of ``PIController(estimate="embedded")`` per number of stages s (larger s use the
#: last one): ``mean^(-s/(2s-2))`` of the geometric mean of global error / rtol measured with
#: ``c_tol = 1`` on the knife edge, sleigh and steady falling disk (``benchmarks/error_estimate.py``;
#: refitted 2026-11-29 when the PI rule's hysteresis stopped holding steps far below the
#: tolerance: 0.61, 0.98, 4.9, 13.7 before). Not used by the default estimate.
C_TOL = {2: 0.35, 3: 0.41, 4: 1.59, 5: 3.95}
#: The least a step's local error is asked to be, relative to ``1 + |y|``: the error per unit
#: step of a long interval at a tight tolerance would otherwise ask a step for less than its
#: round-off, and the steps collapse (knife edge, T = 1000, rtol 1e-12: h fell to 2e-12 at
#: t = 372; with this floor 9,467 steps, none rejected, error 3.6e-11; with 1e-14: 13,474
#: steps, 1,443 rejected, error 4.0e-10, the extra steps' round-off).
ROUNDOFF_FLOOR = 1e-13

#: The power of h that :meth:`PIController._observed_order` gives when a shorter attempt had no
#: smaller error: ``err^(-1/STALLED_ORDER)`` is then far below ``fac_min``, which the step takes.
STALLED_ORDER = 0.05
#: The local error estimates :class:`PIController` knows.
ESTIMATES = ("doubling", "embedded")


def roundoff_may_exceed(n_floored, rtol):
    """Whether ``n_floored`` steps that passed only by :data:`ROUNDOFF_FLOOR` may add up to more
    than rtol (a count, or an array of counts: elementwise): the test by which
    :func:`~lobattodae.solve` and :func:`~lobattodae.ensemble` warn."""
    return n_floored * ROUNDOFF_FLOOR > rtol


@dataclass(frozen=True)
class PIController(_TimeAndEnd):
    r"""Error-controlled step sizes: Gustafsson's PI rule on an estimate of each step's own
    local error, with the tolerances as the user gives them.

    **The estimate** (``estimate="doubling"``, the default) is Richardson's: each step of size
    h is taken as two half steps (kept) and once whole (compared), and
    ``e = (y_halves - y_whole) / (2^(2s-2) - 1)`` estimates the local error of the kept result,
    ``O(h^(2s-1))`` (``docs/variable-steps.md`` §1). It is asymptotically exact, needs no constant
    fitted to problems, and a step too long for its asymptotics (a fast transient, a
    constraint-damped mode beyond the stability limit) shows as a large difference and is
    rejected. A step costs three Newton solves.

    **The test.** With ``sc_i = atol + rtol max(|y0_i|, |y1_i|)`` over q and p (λ is not
    error-controlled, as for the algebraic variables of index-2 DAEs in DAE codes), a step from
    t to t + h is kept when

        err = rms(e_i / max(sc_i |h| / |t_1 - t_0|, ROUNDOFF_FLOOR (1 + |y_i|))) ≤ 1,

    the error per unit step, in units of the requested interval ``(t_0, t_1)``: a step may make
    the share of the tolerance that its length is of the interval, so the local errors add up
    to at most the tolerance, the global error follows rtol proportionally (log-log slope 1)
    and does not grow with the number of steps, and steps at the start, whose errors travel
    furthest, are held as tightly as the others. (Asking for a longer interval than needed,
    e.g. to stop at a terminal event, makes every step more careful: the cost grows like
    ``(|t_1 - t_0| / h)^(1/(2s-1))``.) No step is asked for less than :data:`ROUNDOFF_FLOOR`
    relative to ``1 + |y|``, the level of its own round-off; steps that pass only by that floor
    are counted (``n_floored``, ``Solution.stats["n_roundoff_limited"]``), and :func:`~lobattodae.solve`
    warns when they may add up to more than rtol: the tolerance is then below what the steps
    resolve over the interval. The next step is

        h_new = h · clip(safety · err^(-β₁/k) · err_prev^(β₂/k), fac_min, fac_max),

    ``k = 2s - 2`` (err ∝ h^(2s-2)), ``β₁ = 0.7``, ``β₂ = 0.4``, no growth right after a
    rejection; a rejected step is retried with ``h · clip(safety · err^(-1/k), fac_min, 0.9)``,
    where a second rejection in a row uses the power of h by which the error actually fell
    between the two attempts when it is below k (at least 1; ``fac_min`` when it did not fall:
    a fast mode beyond the stability limit); a step whose Newton solve fails is retried with a
    quarter of the size (``StepInfo.retry``; half where step doubling's compared whole step
    failed, which ends the attempt before its half steps are solved). Factors in
    ``[1, hysteresis]`` keep h (and the reused Jacobians, see ``H_CHANGE_REFRESH``) where the
    error also asks for at most that factor (or the step's test is the round-off floor's),
    ``(err* / err)^(1/k) ≤ hysteresis`` with
    ``err* = safety^(k/(β₁-β₂))`` the error at which the rule keeps h (0.5, 0.25, 0.12, 0.06, 0.03
    of the tolerance for s = 2…6): the rule's steady-state gain is only (β₁ - β₂)/k, and by the
    factor alone steps stayed where their error was 10⁻⁴ of the tolerance (the test set's vertical
    disk at s = 6, rtol 1e-6: h constant from the second step on, 110 steps).

    **What set the steps.** Two counters say where a run's steps were not set by the accuracy
    the tolerance asks for: attempts rejected because a stage solve failed
    (``Solution.stats["n_failed_solves"]``, also in ``n_rejected``), and accepted steps whose
    difference lay along modes beyond the tableau's ``richardson_radius``
    (``Solution.stats["n_unresolved"]``): their size was set by the method's linear stability
    there (a stiff or constraint-damped mode, an oscillation shorter than the step), not by its
    asymptotic accuracy, and where most steps are such the error can lie orders of magnitude
    below rtol (a sleigh settling into straight motion, steps held by the stability limit of its
    damped turning; ``benchmarks/RESULTS.md``, 2026-11-29).

    **Large steps** (``check_large_steps=True``, the default). Richardson's divisor rests on the
    expansion ``C h^(k+1)`` with C nearly constant over the step. A step long against the scale
    on which the solution changes can pass with an estimate far too small (the four-bar linkage
    over its crank's turning point: one step of h = 0.30, whole and halved results whose errors
    differ 28 times where the divisor assumes 1023, ended 47 × rtol off). Such a step shows in
    the error constant ``err / h^k``: from the last step the controller chose (and whose error lay
    above Newton's noise) it grows by ``e^(|hμ|)`` for a solution that changes like ``e^(μ t)``.
    Where that growth says ``|hμ|`` exceeds the tableau's
    :attr:`~lobattodae.LobattoPair.richardson_radius` (measured over the distance between the two
    steps' midpoints), and the difference of the two results itself fails the test (so that the
    divisor decides: Richardson's, or the smaller ratio of the linear theory where the difference
    lies along modes the step does not resolve, :mod:`~lobattodae._doubling`), the attempt is
    rejected and retried with h/2; the retry measures the power of h by which the error fell,
    ``k_obs`` in ``[1, k]``, and divides by ``2^k_obs − 1`` where that is less than the divisor
    it used. Where the expansion held (k_obs = k) nothing changes and the step may grow again at
    once. Checks are counted (``Solution.stats["n_checked"]``, also in
    ``n_rejected``). Nothing in the test is fitted to problems: the radius is the one of the
    linear theory that the estimate's share already uses (:mod:`~lobattodae._doubling`).

    **The cheap estimate** (``estimate="embedded"``, opt-in) costs no extra solve: the
    difference to the embedded order-(s-1) formula of the same stages, ``O(h^s)``
    (:meth:`~lobattodae.LobattoIIIAIIIB.step`), with the tolerances mapped to
    ``rtol' = c_tol · rtol^(s/(2s-2))`` (``c_tol`` from :data:`C_TOL` unless given) and the
    plain per-step test (k = s). It is only safe where the solution is smooth on the scale of
    the steps: it does not measure the step's own error, and on problems with fast transients
    it returns errors orders of magnitude above rtol while reporting success (measured on the
    [benchmarks page](../benchmarks/index.md); on four problems that ``C_TOL`` was not fitted on,
    0.01 to 875 × rtol at rtol 1e-8: [the hold-outs](../variable-steps.md)).

    Every field is validated on construction: ``0 < safety ≤ 1``, ``0 < fac_min < 1 <
    fac_max``, ``beta1 > 0``, ``beta2 ≥ 0``, ``hysteresis ≥ 1``, ``estimate`` one of
    :data:`ESTIMATES`, ``c_tol > 0`` (or None) and only with ``estimate="embedded"``,
    ``check_large_steps`` a bool.

    Parameters
    ----------
    safety : float, optional
        The factor ``safety`` of the step-size rule (default 0.9).
    fac_min, fac_max : float, optional
        The bounds of the factor by which h changes from one step to the next (defaults
        0.2 and 5).
    beta1, beta2 : float, optional
        The PI exponents β₁, β₂ (defaults 0.7 and 0.4; ``beta2=0``: the plain I controller).
    hysteresis : float, optional
        Growth factors in ``[1, hysteresis]`` keep h where the error asks for at most that
        factor (default 1.2; 1 switches it off).
    estimate : {"doubling", "embedded"}, optional
        The local error estimate: step doubling (default) or the embedded formula.
    c_tol : float, optional
        ``estimate="embedded"`` only: the constant of the tolerance map (default: ``C_TOL``
        for the method's s).
    check_large_steps : bool, optional
        Check the estimate of steps long against the solution's scale on a step of half the
        size (default True; step doubling only, see "Large steps").

    Raises
    ------
    ValueError
        A field outside its range, an unknown ``estimate``, or ``c_tol`` without
        ``estimate="embedded"``.
    """

    safety: float = 0.9
    fac_min: float = 0.2
    fac_max: float = 5.0
    beta1: float = 0.7
    beta2: float = 0.4
    hysteresis: float = 1.2
    estimate: str = "doubling"
    c_tol: float | None = None
    check_large_steps: bool = True

    def __post_init__(self):
        def check(name, ok, rule):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) or not ok(value):
                raise ValueError(f"PIController: {name} must be a finite number with {rule}; got {name}={value!r}.")

        check("safety", lambda v: 0 < v <= 1, "0 < safety ≤ 1")
        check("fac_min", lambda v: 0 < v < 1, "0 < fac_min < 1")
        check("fac_max", lambda v: v > 1, "fac_max > 1")
        check("beta1", lambda v: v > 0, "beta1 > 0")
        check("beta2", lambda v: v >= 0, "beta2 ≥ 0")
        check("hysteresis", lambda v: v >= 1, "hysteresis ≥ 1 (1 switches it off)")
        if not isinstance(self.check_large_steps, bool):
            raise ValueError("PIController: check_large_steps must be True (the default) or False; "
                             f"got check_large_steps={self.check_large_steps!r}.")
        if self.estimate not in ESTIMATES:
            raise ValueError(
                "PIController: estimate must be 'doubling' (the step's own local error by step doubling, the "
                f"default) or 'embedded' (the cheap O(h^s) estimate, opt-in); got estimate={self.estimate!r}."
            )
        if self.c_tol is not None:
            if self.estimate != "embedded":
                raise ValueError(
                    "PIController: c_tol maps the tolerances of the embedded estimate; the default estimate "
                    "(step doubling) uses rtol and atol as given. Pass estimate='embedded' with c_tol, or drop c_tol."
                )
            check("c_tol", lambda v: v > 0, "c_tol > 0, or None for the calibrated C_TOL of the method's s")

    def tolerance_constant(self, stages: int) -> float:
        """``c_tol`` of the embedded estimate for an s-stage method.

        Parameters
        ----------
        stages : int
            The method's number of stages s.

        Returns
        -------
        float
            The field ``c_tol``, or :data:`C_TOL` of s (of its largest s for larger s).
        """
        if self.c_tol is not None:
            return float(self.c_tol)
        return C_TOL[min(stages, max(C_TOL))]

    def error_exponent(self, stages: int) -> int:
        """k: the power of h in the controlled error.

        Parameters
        ----------
        stages : int
            The method's number of stages s.

        Returns
        -------
        int
            ``2s - 2`` (step doubling), ``s`` (the embedded estimate).
        """
        return 2 * stages - 2 if self.estimate == "doubling" else stages

    def init(self, problem, method, t0, t1, q0, p0, lam0, args, options: ControlOptions) -> AdaptiveState:
        """The controller's state before the first step, with the first step size (``first_step``,
        or chosen from the initial slopes).

        Part of the controller protocol that the compiled loop calls; users pass the
        controller to :func:`~lobattodae.solve` and do not call it.

        Parameters
        ----------
        problem : PartitionedDAE, NonholonomicSystem or MechanicalSystem
            The problem.
        method : LobattoIIIAIIIB
            The method (its number of stages sets the order).
        t0, t1 : jax.Array
            The interval of the run.
        q0, p0 : jax.Array, shape (n,)
            Initial values; their dtype is the state's.
        lam0 : jax.Array, shape (m,)
            Initial multiplier.
        args : pytree
            Passed to the problem functions.
        options : ControlOptions
            The traced numbers of the run (``rtol``, ``atol``, ``first_step``, ``max_step``).

        Returns
        -------
        AdaptiveState
            The state at ``t0``.
        """
        s = method.stages
        rtol, atol = options.rtol, options.atol
        if self.estimate == "embedded":
            rtol = self.tolerance_constant(s) * options.rtol ** (s / (2.0 * s - 2.0))
            atol = options.atol * (rtol / options.rtol)
        k = self.error_exponent(s)
        auto = jax.lax.stop_gradient(initial_step(problem, t0, t1, q0, p0, lam0, args, rtol, atol, k, options.max_step))
        direction = jnp.where(t1 >= t0, 1.0, -1.0)
        first = jnp.minimum(jnp.minimum(options.first_step, options.max_step), jnp.abs(t1 - t0))
        h = jnp.where(options.first_step > 0, direction * first, auto)
        dtype = q0.dtype
        return AdaptiveState(
            t=t0, h=h.astype(dtype), t0=t0, t_end=t1, err_prev=jnp.asarray(1.0, dtype),
            h_rejected=jnp.asarray(0.0, dtype), err_rejected=jnp.asarray(jnp.inf, dtype),
            rtol=rtol, atol=atol, max_step=options.max_step,
            order=jnp.asarray(float(k), dtype), n_rejected=jnp.asarray(0, jnp.int32),
            n_floored=jnp.asarray(0, jnp.int32),
            span=jnp.abs(t1 - t0).astype(dtype),
            h_last=jnp.asarray(0.0, dtype), err_last=jnp.asarray(0.0, dtype),
            checking=jnp.asarray(False), n_checked=jnp.asarray(0, jnp.int32),
            radius=jnp.asarray(method.pair.richardson_radius, dtype),
            n_failed_solves=jnp.asarray(0, jnp.int32), n_unresolved=jnp.asarray(0, jnp.int32),
        )

    def proposal(self, st: AdaptiveState):
        """The next step to attempt.

        Part of the controller protocol that the compiled loop calls; users pass the
        controller to :func:`~lobattodae.solve` and do not call it.

        Parameters
        ----------
        st : AdaptiveState
            The controller's state.

        Returns
        -------
        t, h : jax.Array
            The step's start and size, shortened (or slightly stretched) to end on the end of
            the interval when it comes near it.
        """
        return st.t, _end_clipped(st.t, st.h, st.t_end)

    def adapt(self, st: AdaptiveState, problem, args, report: StepReport):
        """The error test of an attempted step and the next step size.

        Part of the controller protocol that the compiled loop calls; users pass the
        controller to :func:`~lobattodae.solve` and do not call it.

        Parameters
        ----------
        st : AdaptiveState
            The controller's state.
        problem : PartitionedDAE, NonholonomicSystem or MechanicalSystem
            The problem (not used by this controller).
        args : pytree
            Passed to the problem functions (not used by this controller).
        report : StepReport
            The attempted step: its size, values, error estimate and whether Newton converged.

        Returns
        -------
        accept : jax.Array
            Bool: the step passes the test and is kept.
        state : AdaptiveState
            The state after the step (moved on if accepted) with the next step size.
        result : jax.Array
            ``Result.SUCCESSFUL``, or ``Result.STEP_SIZE_TOO_SMALL`` when the next step would
            be below ``1e-14·max(|t|, |t1 - t0|)``.
        """
        k = st.order
        size = jnp.maximum(jnp.abs(report.y0), jnp.abs(report.y1))
        scale = st.atol + st.rtol * size

        def scaled(sc):
            # a component with no error where its scale is 0 (atol=0 and the component 0, e.g. held at
            # rest by the constraint) passes; an error there cannot (see below)
            return _rms(jnp.where(report.error == 0, 0.0, report.error / jnp.where(sc == 0, 1.0, sc)))

        floored = jnp.asarray(False)
        resolved = jnp.asarray(True) if report.resolved is None else report.resolved
        if self.estimate == "doubling":  # per unit step, relative to the requested interval
            asked = scale * jnp.abs(report.h) / st.span
            scale = jnp.maximum(asked, ROUNDOFF_FLOOR * (1.0 + size))
            # the error passes the floored test but not the one asked for: the tolerance asks this step
            # for less than its round-off (counted, and reported by solve when it adds up)
            floored = scaled(asked) > 1.0
        # an error where the scale is 0 fails the run (STEP_SIZE_TOO_SMALL)
        err = scaled(scale)
        err = jnp.where(jnp.any((scale == 0) & (report.error != 0)), jnp.inf, err)
        usable = report.ok & jnp.isfinite(err)
        err = jnp.where(usable, err, jnp.inf)
        check, confirmed, err = self._asymptotics(st, report, err, k)
        accept = (err <= 1.0) & ~check
        safe_err = jnp.maximum(err, 1e-10)
        grow = self.safety * safe_err ** (-self.beta1 / k) * st.err_prev ** (self.beta2 / k)
        # no growth right after a rejection, unless the attempt before only checked its estimate and it held
        grow = jnp.clip(grow, self.fac_min, jnp.where(st.rejected & ~confirmed, 1.0, self.fac_max))
        # h is kept where the PI rule changes it by less than `hysteresis` and the error asks for at most
        # that factor: at constant err the rule keeps h where err = safety^(k/(β₁-β₂)) (its steady state,
        # the gain (β₁-β₂)/k), and by itself would keep any h whose error lies within
        # hysteresis^(k/(β₁-β₂)) below it (a factor 440 at s = 6)
        steady = self.safety ** (k / (self.beta1 - self.beta2)) if self.beta1 > self.beta2 else self.safety**k
        # (a step whose test is floored is measured against its round-off, not the tolerance: there the
        # factor alone decides, as before, the behaviour ROUNDOFF_FLOOR was set with)
        near = ((steady / safe_err) ** (1.0 / k) <= self.hysteresis) | floored
        grow = jnp.where((grow >= 1.0) & (grow <= self.hysteresis) & near, 1.0, grow)
        shrink = jnp.where(usable, jnp.clip(self.safety * safe_err ** (-1.0 / self._observed_order(st, report, err, k)),
                                            self.fac_min, 0.9), report.retry)
        shrink = jnp.where(check, 0.5, shrink)
        # the step-size policy is a heuristic, not part of the model: derivatives follow the step
        # sequence the run chose (only the clipping to the end of the interval moves with t_span)
        h_new = report.h * jax.lax.stop_gradient(jnp.where(accept, grow, shrink))
        # a step the loop shortened to end on an output time (t_eval rows stepped onto) is not the
        # step size the error asked for: after it the run resumes its own proposal (unless the
        # shorter step's error asks for less), and the PI memory keeps the last full step's error
        shortened = jnp.abs(report.h) < jnp.abs(_end_clipped(st.t, st.h, st.t_end))
        resume = accept & shortened & (grow >= 1.0)
        h_new = jnp.where(resume, jnp.sign(h_new) * jnp.maximum(jnp.abs(h_new), jnp.abs(st.h)), h_new)
        h_new = jnp.sign(h_new) * jnp.minimum(jnp.abs(h_new), st.max_step)
        reaches_end = report.h == st.t_end - report.t  # bitwise: the proposal clipped it so
        t = jnp.where(accept, jnp.where(reaches_end, st.t_end, report.t + report.h), st.t)
        # the error constant that the check of large steps compares with: of the last step the controller
        # chose whose error was measured (above Newton's noise)
        measured = accept & ~shortened & (err > 0)
        new = st._replace(
            t=t, h=h_new,
            err_prev=jnp.where(accept & ~shortened, jnp.maximum(err, 1e-4), st.err_prev),
            h_rejected=jnp.where(accept, 0.0, report.h), err_rejected=jnp.where(accept, jnp.inf, err),
            n_rejected=st.n_rejected + (~accept).astype(jnp.int32),
            n_floored=st.n_floored + (accept & floored).astype(jnp.int32),
            h_last=jnp.where(measured, report.h, st.h_last), err_last=jnp.where(measured, err, st.err_last),
            checking=check, n_checked=st.n_checked + check.astype(jnp.int32),
            n_failed_solves=st.n_failed_solves + (~report.ok).astype(jnp.int32),
            n_unresolved=st.n_unresolved + (accept & ~resolved).astype(jnp.int32),
        )
        finished = accept & (t == st.t_end)
        small = ~finished & _too_small(h_new, t, st.t0, st.t_end)
        result = jnp.where(small, Result.STEP_SIZE_TOO_SMALL, Result.SUCCESSFUL).astype(jnp.int32)
        return accept, new, result

    def _asymptotics(self, st: AdaptiveState, report: StepReport, err, k):
        """Whether an attempt is to be checked on a step of half the size, whether it is the
        retry of a check that found the expansion holding, and the error (corrected on a retry
        where it did not); see the class docstring, "Large steps".

        An attempt is checked when its error constant ``err / h^k`` (per unit step) grew by more
        than ``e^r`` over the distance between its midpoint and that of the last measured step,
        in units of h (r the tableau's ``richardson_radius``), and the difference of the two
        results itself fails the test (``err / share > 1``, ``report.share`` the share of the
        difference that the estimate is, Richardson's ``1 / (2^k - 1)`` or the larger one of
        :meth:`~lobattodae._doubling.StepDoubling._share`: the divisor decides). Its retry
        measures the power of h by which the error fell between the two attempts, ``k_obs`` in
        ``[1, k]`` (:meth:`_observed_order`), and divides the difference by ``2^k_obs - 1`` where
        that is less than the divisor it used.
        """
        no = jnp.asarray(False)
        if self.estimate != "doubling" or not self.check_large_steps:
            return no, no, err
        # decisions about the step sequence, like the step-size rule: no derivatives through them
        e, st = jax.lax.stop_gradient((err, st))
        share = 1.0 / (2.0**k - 1.0) if report.share is None else jax.lax.stop_gradient(report.share)
        report = report._replace(h=jax.lax.stop_gradient(report.h))
        h = jnp.abs(report.h)
        retry = st.checking & (h < jnp.abs(st.h_rejected))
        observed = jnp.maximum(self._observed_order(st, report, e, k), 1.0)
        # the observed ratio of the whole and halved steps' errors where it is below the divisor used
        e = jnp.where(retry, e * jnp.maximum(1.0, 1.0 / (share * (2.0**observed - 1.0))), e)
        h_last = jnp.abs(st.h_last)
        predicted = st.err_last * (h / jnp.where(h_last == 0, 1.0, h_last)) ** k
        growth = jnp.log(e / jnp.maximum(predicted, 1e-300))
        check = (~retry & (h_last > 0) & (e <= 1.0) & (e / share > 1.0)
                 & (growth > st.radius * 0.5 * (h_last + h) / h))
        return check, retry & (observed >= k), e

    @staticmethod
    def _observed_order(st: AdaptiveState, report: StepReport, err, k):
        """The power of h by which a rejected step's error fell since the attempt before it.

        Two rejected attempts in a row start from the same point and differ only in h, so
        ``log(err_before / err) / log(h_before / h)`` measures how the error depends on h
        there. Where it is below k (the estimate is outside its asymptotic regime: a fast
        mode beyond the method's stability limit, whose undamped amplitude the per-unit-step
        test even reads as *larger* on a shorter step), the step shrinks by the observed power
        (at least 1; by ``fac_min`` where the error did not fall: STALLED_ORDER) instead of retrying
        sizes that the asymptotic rule ``err^(-1/k)`` lowers by a few per cent at a time.
        Otherwise, and after an accepted step, it is k.
        """
        # a shorter retry of a rejected attempt (h_rejected is 0 after an accepted one) whose error was finite
        again = (jnp.abs(report.h) < jnp.abs(st.h_rejected)) & jnp.isfinite(st.err_rejected)
        fell = jnp.log(st.err_rejected / jnp.maximum(err, 1e-300))
        shorter = jnp.log(jnp.abs(st.h_rejected) / jnp.abs(report.h))
        observed = jnp.where(fell > 0, jnp.clip(fell / jnp.where(again, shorter, 1.0), 1.0, k), STALLED_ORDER)
        return jnp.where(again, observed, k)

    def stop_at(self, st: AdaptiveState, t_stop) -> AdaptiveState:
        """Move the end of the run to ``t_stop`` (a terminal event's zero) and aim the next step
        at it.

        Part of the controller protocol that the compiled loop calls; users pass the
        controller to :func:`~lobattodae.solve` and do not call it.

        Parameters
        ----------
        st : AdaptiveState
            The controller's state.
        t_stop : jax.Array
            The new end.

        Returns
        -------
        AdaptiveState
            The state with ``t_end = t_stop`` and the next step ending there.
        """
        return st._replace(t_end=t_stop, h=t_stop - st.t)

    def step_to(self, st: AdaptiveState, t_target) -> AdaptiveState:
        """The next step ends at ``t_target`` (an event's zero to land on); the end stays.

        Parameters
        ----------
        st : AdaptiveState
            The controller's state.
        t_target : jax.Array
            Where the next step is to end.

        Returns
        -------
        AdaptiveState
            The state with the next step size ``t_target - t``.
        """
        return st._replace(h=t_target - st.t)
