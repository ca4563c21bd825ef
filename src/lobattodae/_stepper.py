"""The Lobatto IIIA-IIIB method object: options, theory, one step, and the Λ₁ policy.

The stage equations are in :mod:`lobattodae._stage_equations` (the paper's scheme in its
docstring, row by row); this module decides what a step starts from (Newton's guess, the
reused Jacobian, the start multiplier Λ₁) and what it hands to the next step.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp

from . import _stage_equations as se
from ._newton import JacobianCache, NewtonOptions, empty_jacobian_cache, implicit_root, newton_solve
from ._problem import consistent_lambda
from ._projection import project_step_end
from ._tableau import LobattoPair, lobatto_pair
from ._dense import DenseStep, one_piece

__all__ = ["LobattoIIIAIIIB", "StepInfo", "StepperState", "LAM_START_MODES"]

#: A step whose Newton solve failed is attempted again with this factor times its size (the
#: solve's contraction rate falls at least linearly with h).
RETRY_FACTOR = 0.25

#: The start-multiplier policies; see :class:`LobattoIIIAIIIB` (``lam_start``).
LAM_START_MODES = ("auto", "previous", "consistent")
#: By the option ``jacobian`` of :class:`LobattoIIIAIIIB`: (simplified Newton's matrix, the
#: exact Jacobian that the derivatives of a step use).
NEWTON_JACOBIANS = {
    "differences": (se.stage_jacobian_differences, se.stage_jacobian),
    "structured": (se.stage_jacobian, se.stage_jacobian),
    "autodiff": (se.stage_jacobian_autodiff, se.stage_jacobian_autodiff),
}
#: A reused Jacobian is refreshed when the step size changed by more than this fraction.
H_CHANGE_REFRESH = 0.2
#: The λ drift monitor compares the drift ‖λ_n − λ(t_n, q_n, p_n)‖∞ with its largest value in
#: the previous epoch; epochs start DRIFT_EPOCH steps long after a (re)start and double. A drift
#: above DRIFT_BAND times that level (and above the round-off floor DRIFT_FLOOR·(1 + ‖λ_n‖∞))
#: is an excursion: λ is re-synchronised ("auto") or the excursion reported ("previous").
DRIFT_EPOCH = 10
DRIFT_BAND = 10.0
DRIFT_FLOOR = 1e-12


class Slopes(NamedTuple):
    """Stage slopes and multipliers of a step: ``V (s, n)``, ``W (s, n)``, ``Lam (s, m)``."""

    V: jax.Array
    W: jax.Array
    Lam: jax.Array


class History(NamedTuple):
    """The previous step's stages, for the predictor."""

    slopes: Slopes
    correction: Slopes  # what the plain extrapolation missed at the previous step
    h: jax.Array
    have_slopes: jax.Array  # bool
    have_correction: jax.Array  # bool


class LamMonitor(NamedTuple):
    """The drift monitor of the multiplier, ``d_n = ‖λ_n − λ(t_n, q_n, p_n)‖∞`` (see ``_watch``)."""

    level: jax.Array  # largest d_n in the previous epoch (0 in the first epoch after a (re)start)
    current: jax.Array  # largest d_n so far in this epoch
    count: jax.Array  # int32, steps in this epoch
    length: jax.Array  # int32, length of this epoch
    excursions: jax.Array  # int32, steps with d_n above the band (re-synchronised with "auto")


class StepperState(NamedTuple):
    """What a step hands to the next: reused Jacobian, predictor history, λ bookkeeping.

    Made by :meth:`LobattoIIIAIIIB.init` and :meth:`LobattoIIIAIIIB.step`; pass it on
    unchanged.

    Attributes
    ----------
    jacobian : JacobianCache
        The inverse of the stage Jacobian kept for simplified Newton, and whether it is valid.
    h_jacobian : jax.Array
        The step size that Jacobian was evaluated with.
    history : History
        The previous step's stage slopes and multipliers, for Newton's starting guess.
    lam_hidden : jax.Array, shape (m,)
        λ(t_n, q_n, p_n) from the hidden constraint at the current step point.
    resync : jax.Array
        Bool: the next step starts from ``lam_hidden`` (``lam_start="auto"`` after an
        excursion of the λ drift).
    monitor : LamMonitor
        The λ drift monitor of ``lam_start="auto"`` (its epochs and its count of excursions).
    compensation : jax.Array, shape (2n,)
        What the step point ``(q_n, p_n)`` lost to rounding when the last step's increment was
        added to it, added to the next increment (compensated summation, see
        :func:`~lobattodae._stage_equations.step_values`).
    """

    jacobian: JacobianCache
    h_jacobian: jax.Array  # the step size the cached Jacobian was evaluated with
    history: History
    lam_hidden: jax.Array  # λ(t_n, q_n, p_n), from the hidden constraint at the start point
    resync: jax.Array  # bool: the next step starts from lam_hidden ("auto" after an excursion)
    monitor: LamMonitor
    compensation: jax.Array  # (2n,): the rounding error of (q_n, p_n), carried into the next sum


class StepInfo(NamedTuple):
    """Diagnostics of one step (JAX arrays; scalars but ``error`` and ``dense``).

    Attributes
    ----------
    result : jax.Array
        A :class:`~lobattodae.Result` code; anything but 0 means the step failed.
    iterations : jax.Array
        Newton iterations of the step.
    residual_norm : jax.Array
        The max-norm of the last evaluated residual of the stage equations.
    n_jacobians : jax.Array
        Stage Jacobians evaluated (each with one factorisation) in the step; 0 when a kept
        one was reused throughout.
    drift : jax.Array
        ``‖λ_1 − λ(t_1, q_1, p_1)‖∞``: the distance of the step's multiplier from the hidden
        constraint's.
    resync : jax.Array
        Bool: this step started from λ(t_0, q_0, p_0) instead of λ_0 (``lam_start="auto"``).
    error : jax.Array, shape (2n,)
        The local error estimate of ``(q_1, p_1)`` (see :meth:`LobattoIIIAIIIB.step`).
    dense : DenseStep
        The step's stage slopes and multipliers, from which its continuous extension is
        evaluated.
    retry : jax.Array
        When the step failed: the factor by which its size is to shrink for the next attempt
        (:data:`RETRY_FACTOR`, or a larger one where the stepper knows a shorter solve to
        converge, see :class:`~lobattodae._doubling.StepDoubling`).
    share : jax.Array or None
        Step doubling: the share of the two results' difference that ``error`` is (Richardson's
        ``1 / (2^(2s-2) - 1)`` or larger, see :mod:`~lobattodae._doubling`); None otherwise.
    resolved : jax.Array or None
        Step doubling: bool, the difference lay along modes that the step resolves (``|h μ|``
        within the tableau's ``richardson_radius``, where Richardson's divisor holds); False
        where the step's size is beyond the reach of its modes (stiffness, the stability limit
        of a mode the constraint damps, an oscillation shorter than the step). None otherwise.
    """

    result: jax.Array
    iterations: jax.Array
    residual_norm: jax.Array
    n_jacobians: jax.Array
    drift: jax.Array  # ‖λ_1 − λ(t_1, q_1, p_1)‖∞
    resync: jax.Array  # bool: this step started from λ(t_0, q_0, p_0) instead of λ_0 ("auto")
    error: jax.Array  # (2n,) local error estimate of (q_1, p_1), see LobattoIIIAIIIB.step
    dense: DenseStep  # the step's continuous extension (lobattodae._dense)
    retry: jax.Array  # a failed step's size factor for the next attempt (RETRY_FACTOR or larger)
    share: Any = None  # step doubling: the share of the difference that error is
    resolved: Any = None  # step doubling: bool, the difference lay within Richardson's radius


@dataclass(frozen=True)
class LobattoIIIAIIIB:
    r"""The s-stage Lobatto-type IIIA-IIIB partitioned Runge-Kutta method for index-2 DAEs.

    One step solves the stage equations of the paper's scheme (Martín de Diego & Sato;
    written out in ``docs/theory/scheme.md``): IIIA for q and for the constraint
    momenta ``p̃_i``, IIIB for ``P_i``, ``φ(t_i, Q_i, p̃_i) = 0`` for i = 2..s, so that
    ``φ(t_1, q_1, p_1) = 0`` at every step point. Global orders on a fixed interval (the
    paper's Corollary): q, p ``h^(2s-2)``; λ ``h^s`` for even s and ``h^(s-1)`` for odd s.

    A problem with holonomic constraints ``position_constraint = ψ`` has every step's end
    point projected onto ``ψ(t_1, q_1) = 0`` and ``φ(t_1, q_1, p_1) = 0``
    (a projection after the step): both hold to round-off, the orders of q and p are kept,
    but the step is then not symmetric. Without ψ nothing is added to the step.

    Newton works on ``Z_j = h Λ_j`` with a structured Jacobian whose inverse is reused across
    iterations and steps (refreshed when the contraction slows or h changes by more than
    20 %), starting from the previous step's stage polynomials evaluated at the new stage
    times.

    Parameters
    ----------
    stages : int
        Number of stages s ≥ 2.
    tol : float
        Newton tolerance on the scaled increment, ``|Δx_i| ≤ tol (1 + |x_i|)``. Keep the
        default (1e-14, near round-off) under error control: step doubling takes differences
        below two Newton tolerances for noise, and with a looser ``tol`` the steps whose
        error falls below that noise propose the largest growth and are then rejected (knife
        edge, T = 100, rtol 1e-8: tol 1e-11 gives 53 rejections and 332 Newton matrices
        where 1e-14 gives none and 12, in the same time or more).
    max_iterations : int
        Newton iterations per step before the step is declared failed.
    reuse_jacobian : bool
        Simplified Newton (default): keep the inverse Jacobian across iterations and steps.
    lam_start : {"auto", "previous", "consistent"}
        What the start multiplier ``Λ_1`` of a step is.

        * ``"previous"`` is the paper's scheme, ``Λ_1 = λ_n``; the proven orders refer to it.
          The step is symmetric (bounded energy errors on reversible problems), but a λ error
          is carried with ``|R(∞)| = 1`` and never damped: on some problems (Chaplygin
          sleigh, rolling disk) it grows like ``exp(C t)`` and spoils q and p on long runs.
        * ``"consistent"`` sets ``Λ_1 = λ(t_n, q_n, p_n)`` from the hidden constraint at every
          step: λ errors cannot accumulate and λ reaches order s for every s, but the step is
          no longer symmetric and energy drifts on reversible problems.
        * ``"auto"`` (default) is the paper's scheme, re-synchronised with the hidden
          constraint (one step starts from ``λ(t_n, q_n, p_n)``) only when the drift
          ``‖λ_n − λ(t_n, q_n, p_n)‖∞`` leaves its normal band: more than ``DRIFT_BAND`` times
          its level in the previous epoch of a sequence of doubling epochs, which polynomial
          growth of the global λ error never does and the exponential growth of the undamped
          mode does. It keeps the symmetric scheme where λ errors stay bounded (reversible
          problems) and bounds them where they grow; resets are counted
          (``stats["lam_resets"]`` in :func:`~lobattodae.solve`).
    jacobian : {"differences", "structured", "autodiff"}
        How simplified Newton's matrix is made. ``"differences"`` (default) assembles it from
        per-stage blocks of f, g and φ by forward differences (as RADAU5 does); ``"structured"``
        from the same blocks by forward-mode autodiff; ``"autodiff"`` applies ``jax.jacfwd``
        to the whole stage residual (the same matrix as ``"structured"``). The matrix decides
        how fast Newton contracts, not the root (the residual alone decides where it stops),
        so the steps agree to round-off; differences compile faster and refresh faster on a
        CPU (no derivative code of the problem's functions in the step). The derivatives of a
        step (``jax.grad``, ``jvp``) always use the exact Jacobian of the root.
    extrapolate : bool
        Start Newton from the previous step's stage polynomials (default) or from constant
        stages. Extrapolation is switched off automatically for large s, where it is
        ill-conditioned.
    """

    stages: int = 3
    tol: float = 1e-14
    max_iterations: int = 20
    reuse_jacobian: bool = True
    extrapolate: bool = True
    lam_start: str = "auto"
    jacobian: str = "differences"

    def __post_init__(self):
        lobatto_pair(self.stages)  # validates s
        self.newton  # validates tol, max_iterations, reuse_jacobian
        if self.lam_start not in LAM_START_MODES:
            raise ValueError(
                "lam_start must be 'auto' (the paper's scheme, re-synchronised with the hidden "
                "constraint when λ drifts out of its band), 'previous' (the paper's scheme, Λ_1 = λ_n) "
                f"or 'consistent' (Λ_1 from the hidden constraint at every step); got {self.lam_start!r}."
            )
        if self.jacobian not in NEWTON_JACOBIANS:
            raise ValueError(
                "jacobian must be 'differences' (per-stage blocks by forward differences, the default), "
                "'structured' (per-stage blocks by forward-mode autodiff) or 'autodiff' (forward-mode "
                f"through the whole stage residual); got {self.jacobian!r}."
            )
        if not isinstance(self.extrapolate, bool):
            raise ValueError(f"extrapolate must be True or False; got {self.extrapolate!r}.")

    # -- tableau and theory ---------------------------------------------------------------
    #: Pieces of a step's dense output (:class:`~lobattodae._dense.DenseStep`): one step, one piece.
    pieces = 1

    @property
    def pair(self) -> LobattoPair:
        """The Lobatto IIIA-IIIB coefficients ``(s, c, b, a, a_hat)``."""
        return lobatto_pair(self.stages)

    @property
    def newton(self) -> NewtonOptions:
        return NewtonOptions(self.tol, self.max_iterations, self.reuse_jacobian)

    def order(self) -> dict[str, int]:
        """Global orders proven for this method (the paper's Corollary).

        Returns
        -------
        dict
            ``{"q": 2s-2, "p": 2s-2, "lam": s}`` for even s, ``"lam": s-1`` for odd s.
        """
        return self.pair.order()

    def n_unknowns(self, n: int, m: int) -> int:
        """Size of the Newton system of one step.

        Parameters
        ----------
        n : int
            Dimension of q (and of p).
        m : int
            Dimension of λ.

        Returns
        -------
        int
            ``(2s-1) n + (s-1) m``.
        """
        return se.Layout(self.stages, n, m).size

    @functools.cached_property
    def _use_extrapolation(self) -> bool:
        return self.extrapolate and se.extrapolation_gain(self.pair) <= se.MAX_EXTRAPOLATION_GAIN

    # -- stepping ---------------------------------------------------------------------------
    def init(self, problem, t0, q0, p0, lam0, args: Any = None, h=None, lam_hidden=None) -> StepperState:
        """The state before the first step from ``(t0, q0, p0, λ0)``: no Jacobian, no history,
        ``λ(t0, q0, p0)`` from the hidden constraint (one Newton update of λ0).

        Parameters
        ----------
        problem : PartitionedDAE, NonholonomicSystem or MechanicalSystem
            The problem.
        t0 : float
            Initial time.
        q0, p0 : array_like, shape (n,)
            Initial values; their float dtype is the state's.
        lam0 : array_like, shape (m,)
            Initial multiplier.
        args : pytree, optional
            Passed to the problem functions.
        h : float, optional
            The first step's size, recorded with the (still empty) Jacobian cache (default 0).
        lam_hidden : array_like, shape (m,), optional
            ``λ(t0, q0, p0)`` when the caller has it (:func:`~lobattodae.solve` computes it while
            it validates the initial values); computed here otherwise.

        Returns
        -------
        StepperState
            To be passed to the first :meth:`step`.
        """
        q0 = jnp.asarray(q0)
        dtype = q0.dtype
        lam0 = jnp.asarray(lam0, dtype)
        s, n, m = self.stages, q0.shape[-1], lam0.shape[-1]
        zeros = Slopes(jnp.zeros((s, n), dtype), jnp.zeros((s, n), dtype), jnp.zeros((s, m), dtype))
        if lam_hidden is None:
            lam_hidden = consistent_lambda(problem, jnp.asarray(t0, dtype), q0, jnp.asarray(p0, dtype), lam0, args,
                                           iterations=1)
        lam_hidden = jnp.asarray(lam_hidden, dtype)
        return StepperState(
            jacobian=empty_jacobian_cache(self.n_unknowns(n, m), dtype),
            h_jacobian=jnp.asarray(0.0 if h is None else h, dtype),
            history=History(zeros, zeros, jnp.asarray(1.0, dtype), jnp.asarray(False), jnp.asarray(False)),
            lam_hidden=lam_hidden,
            resync=jnp.asarray(False),
            monitor=_fresh_monitor(dtype, jnp.asarray(0, jnp.int32)),
            compensation=jnp.zeros((2 * n,), dtype),
        )

    def start_multiplier(self, lam_n, state: StepperState):
        """Λ₁ of the next step: the one place where the ``lam_start`` policy is applied.

        Parameters
        ----------
        lam_n : jax.Array, shape (m,)
            The multiplier λ_n at the step's start point.
        state : StepperState
            What the previous step returned (its ``lam_hidden`` and ``resync``).

        Returns
        -------
        jax.Array, shape (m,)
            ``λ_n`` (``"previous"``), ``λ(t_n, q_n, p_n)`` (``"consistent"``), or for ``"auto"``
            the latter only where ``state.resync`` asks for it.
        """
        if self.lam_start == "previous":
            return lam_n
        if self.lam_start == "consistent":
            return state.lam_hidden
        return jnp.where(state.resync, state.lam_hidden, lam_n)

    def after_rejection(self, kept, new: StepperState, old: StepperState) -> StepperState:
        """The state the next attempt starts from: ``new`` where the step was ``kept``, else the
        state before it, but with the attempt's Jacobian factorisation (and the step size it was
        evaluated with) either way. A factorisation stays an approximation of the Jacobian near
        the same point whatever became of the step (a failed one is marked invalid), and
        selecting the old one back would copy its N² numbers at every attempt: at N = 480, half
        a millisecond (``benchmarks/RESULTS.md``, 2026-11-28).

        Part of the stepper protocol that the compiled loop calls; users do not call it.

        Parameters
        ----------
        kept : jax.Array
            Bool: the attempt was kept.
        new, old : StepperState
            The state after the attempt and the state before it.

        Returns
        -------
        StepperState
            The state the next attempt starts from.
        """
        rest = jax.tree_util.tree_map(functools.partial(jnp.where, kept), new._replace(jacobian=None, h_jacobian=None),
                                      old._replace(jacobian=None, h_jacobian=None))
        return rest._replace(jacobian=new.jacobian, h_jacobian=new.h_jacobian)

    def step(self, problem, t0, q0, p0, lam0, h, args: Any = None, state: StepperState | None = None, solve=None):
        """Take one step of size ``h`` from consistent ``(t0, q0, p0, λ0)``.

        Pure and jit/vmap-able; ``h`` may be negative (a step backwards in time).

        Parameters
        ----------
        problem : PartitionedDAE, NonholonomicSystem or MechanicalSystem
            The problem.
        t0 : float
            Time at the start of the step.
        q0, p0 : array_like, shape (n,)
            Consistent values at ``t0``, ``φ(t0, q0, p0) = 0``.
        lam0 : array_like, shape (m,)
            The multiplier at ``t0``.
        h : float
            Step size (negative: backwards).
        args : pytree, optional
            Passed to the problem functions.
        state : StepperState, optional
            What the previous step returned (None for a first step: :meth:`init` makes it).
        solve : bool, optional
            Traced. False: the stage equations are not solved (Newton stops after its fast
            start, reports success with no iterations and keeps the Jacobian as it was; the
            values returned are not a step of the method). Step doubling passes False to the
            half steps of an attempt whose whole step failed. Default: always solve.

        Returns
        -------
        q1, p1, lam1 : jax.Array
            The values at ``t0 + h``.
        info : StepInfo
            ``result`` (a :class:`Result` code; anything but 0 means the step failed and
            ``q1, p1, lam1`` are not a solution), ``iterations``, ``residual_norm``,
            ``n_jacobians``, ``drift`` (‖λ_1 − λ(t_1, q_1, p_1)‖∞), ``resync``, ``error``
            (the local error estimate below) and ``dense`` (the continuous extension).
        state : StepperState
            To be passed to the next step (Jacobian reuse, predictor, λ bookkeeping).

        Notes
        -----
        With a ``position_constraint`` ψ, ``(q1, p1)`` is the end point projected onto
        ψ = 0 and φ = 0 (λ1 is the step's own), computed before λ(t_1, q_1, p_1) and
        differentiated with the step; the error estimate and the dense output are those of
        the unprojected step.

        The error estimate is the difference between the step and the embedded formula
        ``q̂_1 = q_0 + h Σ_j b̂_j V_j``, ``p̂_1 = p_0 + h Σ_j b̂_j W_j`` with weights
        ``b̂ = b - e`` exact for polynomials of degree s - 2
        (:attr:`~lobattodae.LobattoPair.error_weights`):

            err = h Σ_j e_j (V_j, W_j) = O(h^s).

        It estimates the local error of the embedded order-(s-1) formula, not the step's own
        ``O(h^(2s-1))``; the adaptive controller (:class:`~lobattodae.PIController`) maps the
        user's tolerance accordingly so that the global error is proportional to it. It costs
        no function evaluations. The start multiplier must be consistent for it to mean
        anything: the scheme's undamped λ error (``Λ_1 = λ_n``) answers in the stage
        multipliers with a pattern that is not smooth in the stage index and enters ``e·W`` at
        ``O(h)``, whatever the solution does; error-controlled runs therefore start every step
        from ``λ(t_n, q_n, p_n)``.
        """
        t0, q0, p0, lam0, h = as_step_arrays(t0, q0, p0, lam0, h)
        if state is None:
            state = self.init(problem, t0, q0, p0, lam0, args, h)
        pair = self.pair
        layout = se.Layout(self.stages, q0.shape[-1], lam0.shape[-1])
        params = se.StageParams(t0, h, q0, p0, self.start_multiplier(lam0, state), args)

        x0, plain = self._guess(layout, params, state.history)
        residual = functools.partial(se.stage_residual, problem, pair, layout)
        h_ok = jnp.abs(h - state.h_jacobian) <= H_CHANGE_REFRESH * jnp.abs(h)
        cache = state.jacobian._replace(valid=jnp.logical_and(state.jacobian.valid, h_ok))
        newton_matrix, exact = (functools.partial(fn, problem, pair, layout) for fn in NEWTON_JACOBIANS[self.jacobian])
        x, ninfo, cache = newton_solve(residual, newton_matrix, x0, params, cache, self.newton, solve)
        h_jac = jnp.where(ninfo.n_jacobians > 0, h, state.h_jacobian)
        position_constraint = getattr(problem, "position_constraint", None) is not None  # static

        @jax.checkpoint
        def complete(x, params, compensation):
            # Derivatives are those of the exact stage solution (implicit function theorem);
            # checkpointed, so that reverse mode keeps (x, params) per step and recomputes the
            # stage Jacobian and the vector fields from them instead of storing them.
            x = implicit_root(residual, exact, x, params)
            stages = se.stage_values(problem, pair, layout, x, params)
            q1, p1, lam1, compensation = se.step_values(pair, params, stages, compensation)
            if position_constraint:  # ψ(t_1, q_1) = 0 and φ(t_1, q_1, p_1) = 0 by projection
                q1, p1 = project_step_end(problem, params.t0 + params.h, q1, p1, lam1, params.args)
            lam_hidden = consistent_lambda(problem, params.t0 + params.h, q1, p1, lam1, params.args, iterations=1)
            return stages, q1, p1, lam1, lam_hidden, compensation

        stages, q1, p1, lam1, lam_hidden, compensation = complete(x, params, state.compensation)
        drift = jnp.max(jnp.abs(lam1 - lam_hidden))
        monitor, excursion = self._watch(state.monitor, drift, lam1, state.resync)
        history = self._remember(params, state.history, stages, plain)
        new_state = StepperState(
            jacobian=cache,
            h_jacobian=h_jac,
            history=history,
            lam_hidden=lam_hidden,
            resync=jnp.logical_and(excursion, self.lam_start == "auto"),
            monitor=monitor,
            compensation=compensation,
        )
        error = self._error_estimate(params, stages)
        dense = one_piece(t0, h, q0, p0, stages.V, stages.W, stages.Lam)
        info = StepInfo(ninfo.result, ninfo.iterations, ninfo.residual_norm, ninfo.n_jacobians, drift, state.resync,
                        error, dense, jnp.asarray(RETRY_FACTOR, error.dtype))
        return q1, p1, lam1, info, new_state

    def _error_estimate(self, params: se.StageParams, stages: se.Stages):
        """``h Σ_j e_j (V_j, W_j)`` (see :meth:`step`)."""
        e = self.pair.error_weights[None]
        return params.h * jnp.concatenate([se.tableau_product(e, stages.V)[0], se.tableau_product(e, stages.W)[0]])

    # -- what a step starts from and hands on ------------------------------------------------
    def _guess(self, layout, params, history: History):
        """Newton's start, ``(x0, plain)``: the extrapolated stage polynomials (and their
        uncorrected values, see :func:`~lobattodae._stage_equations.predict_stages`), or
        constant stages on a first step (``plain`` is None without extrapolation)."""
        constant = se.constant_stages(layout, params)
        if not self._use_extrapolation:
            return constant, None
        correction = Slopes(*(jnp.where(history.have_correction, d, 0.0) for d in history.correction))
        x0, plain = se.predict_stages(self.pair, layout, params, history.slopes, correction, history.h)
        usable = jnp.logical_and(history.have_slopes, jnp.all(jnp.isfinite(x0)))
        return jnp.where(usable, x0, constant), plain

    @staticmethod
    def _remember(params, history: History, stages: se.Stages, plain) -> History:
        """The stages of this step for the next predictor, and the error the plain
        extrapolation made on them (the next correction). The predictor only moves Newton's
        start, never the solution: no derivatives flow through the history."""
        slopes = Slopes(stages.V, stages.W, stages.Lam)
        if plain is None:
            history = History(slopes, history.correction, params.h, jnp.asarray(True), jnp.asarray(False))
        else:
            correction = Slopes(*(x - e for x, e in zip(slopes, plain)))
            history = History(slopes, correction, params.h, jnp.asarray(True), history.have_slopes)
        return jax.lax.stop_gradient(history)

    @staticmethod
    def _watch(monitor: LamMonitor, drift, lam1, restarted):
        """Update the λ drift monitor; return it and whether this step left the band.

        The paper's scheme carries a λ error with ``|R(∞)| = 1``: on reversible problems it
        stays bounded, elsewhere it can grow like ``exp(C t)`` (the sleigh, the rolling disk).
        Epochs of doubling length (DRIFT_EPOCH steps first) tell the two apart without knowing
        the problem's time scale: a drift that grows polynomially (the global error building
        up after a consistent start, t² at most) gains a bounded factor from one epoch to the
        next, an exponentially growing one exceeds DRIFT_BAND times the previous epoch's level
        once the epochs are long enough. A re-synchronised step starts a new first epoch.
        """
        monitor = jax.tree_util.tree_map(
            lambda fresh, old: jnp.where(restarted, fresh, old), _fresh_monitor(drift.dtype, monitor.excursions), monitor
        )
        floor = DRIFT_FLOOR * (1.0 + jnp.max(jnp.abs(lam1)))
        excursion = (monitor.level > 0) & (drift > jnp.maximum(DRIFT_BAND * monitor.level, floor))
        current = jnp.maximum(monitor.current, drift)
        count = monitor.count + 1
        ends = count >= monitor.length
        return LamMonitor(
            level=jnp.where(ends, current, monitor.level),
            current=jnp.where(ends, 0.0, current),
            count=jnp.where(ends, 0, count),
            length=jnp.where(ends, 2 * monitor.length, monitor.length),
            excursions=monitor.excursions + excursion.astype(jnp.int32),
        ), excursion


def as_step_arrays(t0, q0, p0, lam0, h):
    """A step's inputs as JAX arrays of q0's float dtype."""
    q0 = jnp.asarray(q0)
    dtype = q0.dtype
    return tuple(jnp.asarray(x, dtype) for x in (t0, q0, p0, lam0, h))


def _fresh_monitor(dtype, excursions) -> LamMonitor:
    zero = jnp.asarray(0.0, dtype)
    return LamMonitor(zero, zero, jnp.asarray(0, jnp.int32), jnp.asarray(DRIFT_EPOCH, jnp.int32), excursions)
