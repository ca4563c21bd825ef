"""Time-reversible step sizes (:class:`ReversibleStepSize`): the variable-step method kept
symmetric for reversible problems, so that energy errors stay bounded over long times.

The step size follows a density σ(t, q, p) of the state (by default :func:`phase_space_speed`)
through a control variable integrated with the steps (``docs/reversible-control.md``); it obeys
the controller contract of :mod:`lobattodae._controllers`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable, NamedTuple

import jax
import jax.numpy as jnp

from ._controllers import ControlOptions, StepReport, _end_clipped, _TimeAndEnd, initial_step
from ._errors import ShapeError
from ._problem import consistent_lambda, vector_field
from ._results import Result

__all__ = ["MAX_DENSITY_CHANGE", "ReversibleState", "ReversibleStepSize", "phase_space_speed"]

#: Safeguard of the reversible control variable: ρ changes by at most this factor in one step.
#: A larger change means ε is far too large for the density; the clamp keeps ρ positive but
#: makes that step unsymmetric, so it is counted (``ReversibleState.n_clamped``).
MAX_DENSITY_CHANGE = 4.0


class ReversibleState(NamedTuple):
    """The memory of :class:`ReversibleStepSize` at the step point ``t_n``."""

    t: jax.Array  # the current step point t_n
    rho: jax.Array  # ρ_{n+1/2}: the next step is h_n = d·min(ε/ρ_{n+1/2}, max_step)
    epsilon: jax.Array  # ε > 0: the (constant) step in the fictive time τ
    t0: jax.Array
    t_end: jax.Array
    direction: jax.Array  # d = +1 forwards, -1 backwards
    max_step: jax.Array
    n_clamped: jax.Array  # int32: steps where the MAX_DENSITY_CHANGE safeguard acted


def phase_space_speed(t, q, p, lam, f, g, args):
    """The default step density ``σ = ‖(f, g)‖₂``: steps inversely proportional to the speed
    in phase space (``f, g`` at the consistent multiplier, see :class:`ReversibleStepSize`).

    Even under the reversing symmetry ``p ↦ -p`` of a mechanical system (``f`` changes sign,
    ``g`` does not), as the control requires."""
    return jnp.sqrt(jnp.sum(f * f) + jnp.sum(g * g))


@dataclass(frozen=True)
class ReversibleStepSize(_TimeAndEnd):
    r"""Explicit, time-reversible step-size control (Hairer & Söderlind, SIAM J. Sci. Comput.
    26, 2005) for reversible problems.

    A step density ``σ(t, y) > 0``, ``y = (q, p)``, asks for steps ``h ≈ ε/σ``: constant steps
    ``ε`` in a fictive time τ with ``dt/dτ = 1/σ``. Evaluating σ at the step's midpoint would
    make the step implicit; instead a control variable ρ follows σ through

        dρ/dτ = G(t, y),   G = d/dt log σ(t, y(t)) = ∂_t log σ + ∇_y log σ · y',

    for which ``ρ/σ`` is a first integral of the (y, ρ) system in τ (ρ = σ from the start).
    Its leapfrog discretisation around the step points is explicit,

        ρ_{1/2} = σ(y_0) + d (ε/2) G(y_0),
        h_n = d ε / ρ_{n+1/2},   y_{n+1} = Φ_{h_n}(y_n),
        ρ_{n+3/2} = ρ_{n+1/2} + d ε G(y_{n+1}),

    with ``d = ±1`` the direction of integration. With a symmetric one-step map Φ
    (``Φ_{-h} ∘ Φ_h = id``) the step ``(y_n, ρ_n) ↦ (y_{n+1}, ρ_{n+1})`` (``ρ_n`` the
    synchronised value between two half-steps of ρ) is symmetric: running back from
    ``(y_N, ρ_{N-1/2})`` with ``d → -d`` retraces ``y_{N-1}, …, y_0`` (:meth:`turn_around`).
    If moreover σ is even under a reversing symmetry R of the problem (``σ(Ry) = σ(y)``, so G
    is odd), the variable-step method is R-reversible, and on reversible integrable problems
    its energy error stays bounded, as with constant steps (Hairer & Söderlind, backward
    error analysis), while error-controlled steps (:class:`PIController`) make it drift
    (measured in [Reversible step sizes](../reversible-control.md) and on the
    [benchmarks page](../benchmarks/index.md)).
    On problems that are not reversible it protects nothing.

    On the constraint manifold ``y = (q, p)`` is the state: σ and G are evaluated at the
    multiplier ``λ(t, q, p)`` of the hidden constraint (one Newton update of the stepper's
    λ, exact when g is affine in λ, as for every nonholonomic system), and G differentiates
    through it (forward mode along ``(1, f, g)``), so that G is the exact derivative of σ
    along the DAE's flow and ρ keeps tracking σ over long runs.

    There is no error test and no rejection. ``ε`` is fixed by the first step (``ε = h_0
    σ(y_0)``): ``first_step`` (at most ``max_step``) or, without it, the automatic first step
    for ``rtol``/``atol`` as given (the :class:`PIController`'s first-step formula for a local
    error of order 2s - 1; a heuristic, not an error test: check the accuracy by halving
    ``first_step``); ``max_step`` caps ``ε/ρ`` (a function of ρ alone, so the map stays
    symmetric). Use it with the symmetric scheme, ``lam_start="previous"`` or ``"auto"``
    (error-controlled runs switch ``"auto"`` to the unsymmetric ``"consistent"``; this
    controller does not). The last step is shortened to end on ``t1``. A density that is not
    positive and finite along the solution stops the run with ``Result.DENSITY_NOT_POSITIVE``;
    one that does not return a scalar is refused when the loop is set up (``ShapeError``).

    Parameters
    ----------
    density : callable, optional
        ``density(t, q, p, lam, f, g, args) -> σ > 0``, with ``lam`` the consistent
        multiplier and ``f, g`` the vector field there; default :func:`phase_space_speed`,
        ``‖(f, g)‖₂``. Written in ``jax.numpy`` (it is differentiated), even under the
        problem's reversing symmetry, and a fixed function object: the controller is part of
        the compiled loop's identity, so a new ``lambda`` per call recompiles.

    Raises
    ------
    TypeError
        ``density`` is not callable, or not hashable.
    """

    density: Callable[..., Any] = phase_space_speed

    def __post_init__(self):
        if not callable(self.density):
            raise TypeError(
                "density must be a function density(t, q, p, lam, f, g, args) -> positive scalar, e.g. "
                f"lambda t, q, p, lam, f, g, args: jnp.sqrt(f @ f + g @ g) (the default); got {self.density!r}."
            )
        try:
            hash(self.density)
        except TypeError:
            raise TypeError(
                f"density must be hashable (a plain function, not {type(self.density).__name__}): the "
                "controller is part of the compiled loop's identity."
            ) from None

    def density_and_rate(self, problem, t, q, p, lam, args):
        """``(σ(t, q, p), G(t, q, p))``: the density and its logarithmic rate of change along
        the flow, both at the consistent multiplier ``λ(t, q, p)``.

        Parameters
        ----------
        problem : PartitionedDAE, NonholonomicSystem or MechanicalSystem
            The problem.
        t : float
            Time.
        q, p : jax.Array, shape (n,)
            The state.
        lam : jax.Array, shape (m,)
            Newton's starting guess for the consistent multiplier ``λ(t, q, p)``.
        args : pytree
            Passed to the problem functions and the density.

        Returns
        -------
        sigma, rate : jax.Array
            σ and ``G = d/dt log σ`` along the DAE's flow (scalars).

        Raises
        ------
        ShapeError
            The density does not return a single number (found when the loop is traced).
        """

        def log_density(tt, qq, pp):
            lam_c = consistent_lambda(problem, tt, qq, pp, lam, args, iterations=1)
            f, g = vector_field(problem, tt, qq, pp, lam_c, args)
            return jnp.log(self._scalar(self.density(tt, qq, pp, lam_c, f, g, args))), (f, g)

        t = jnp.asarray(t, q.dtype)
        _, (f, g) = log_density(t, q, p)
        value, rate = jax.jvp(lambda *x: log_density(*x)[0], (t, q, p), (jnp.ones_like(t), f, g))
        return jnp.exp(value), rate

    def _scalar(self, sigma):
        """The density's value as a 0-d array; anything but one number is refused when the loop is
        traced (set up), naming the density."""
        sigma = jnp.asarray(sigma)
        if sigma.size != 1:
            name = getattr(self.density, "__name__", repr(self.density))
            raise ShapeError(
                f"ReversibleStepSize density {name!r} must return one positive number σ(t, q, p) (a scalar); "
                f"it returned shape {sigma.shape}. Reduce it to a scalar, e.g. jnp.linalg.norm(...) or "
                "jnp.sum(...)."
            )
        return jnp.reshape(sigma, ())

    def init(self, problem, method, t0, t1, q0, p0, lam0, args, options: ControlOptions) -> ReversibleState:
        """The controller's state before the first step: ε from the first step size and σ(y_0),
        and ``ρ_{1/2}``.

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
        ReversibleState
            The state at ``t0`` (ε is NaN when the density or its rate is not finite and
            positive there: the first step then ends the run with
            ``Result.DENSITY_NOT_POSITIVE``).
        """
        k = 2 * method.stages - 2
        auto = jnp.abs(initial_step(problem, t0, t1, q0, p0, lam0, args, options.rtol, options.atol, k, options.max_step))
        h0 = jnp.where(options.first_step > 0, jnp.minimum(options.first_step, options.max_step), auto)
        # as for PIController, derivatives follow the step sequence the run chose (see adapt)
        h0, (sigma0, rate) = jax.lax.stop_gradient((h0, self.density_and_rate(problem, t0, q0, p0, lam0, args)))
        usable = jnp.isfinite(sigma0) & (sigma0 > 0) & jnp.isfinite(rate)
        epsilon = jnp.where(usable, h0 * sigma0, jnp.nan)  # NaN: the first step fails, DENSITY_NOT_POSITIVE
        direction = jnp.where(t1 >= t0, 1.0, -1.0).astype(q0.dtype)
        return ReversibleState(
            t=t0, rho=sigma0 + direction * 0.5 * epsilon * rate, epsilon=epsilon, t0=t0, t_end=t1,
            direction=direction, max_step=jnp.asarray(options.max_step, q0.dtype),
            n_clamped=jnp.asarray(0, jnp.int32),
        )

    def proposal(self, st: ReversibleState):
        """The next step, ``h = d·min(ε/ρ, max_step)``.

        Part of the controller protocol that the compiled loop calls; users pass the
        controller to :func:`~lobattodae.solve` and do not call it.

        Parameters
        ----------
        st : ReversibleState
            The controller's state.

        Returns
        -------
        t, h : jax.Array
            The step's start and size, shortened (or slightly stretched) to end on the end of
            the interval when it comes near it.
        """
        h = st.direction * jnp.minimum(st.epsilon / st.rho, st.max_step)
        return st.t, _end_clipped(st.t, h, st.t_end)

    def adapt(self, st: ReversibleState, problem, args, report: StepReport):
        """Advance ρ by the leapfrog update after a step (there is no error test).

        Part of the controller protocol that the compiled loop calls; users pass the
        controller to :func:`~lobattodae.solve` and do not call it.

        Parameters
        ----------
        st : ReversibleState
            The controller's state.
        problem : PartitionedDAE, NonholonomicSystem or MechanicalSystem
            The problem (σ and G are evaluated at the step's end).
        args : pytree
            Passed to the problem functions and the density.
        report : StepReport
            The step taken.

        Returns
        -------
        accept : jax.Array
            Bool: Newton converged and the density is positive and finite at the step's end.
        state : ReversibleState
            The state after the step (unchanged if not accepted).
        result : jax.Array
            ``Result.SUCCESSFUL``, the stepper's code of a failed step, or
            ``Result.DENSITY_NOT_POSITIVE``.
        """
        t1 = jnp.where(report.h == st.t_end - report.t, st.t_end, report.t + report.h)
        # The step sizes are not differentiated (as with PIController): derivatives are those of
        # the discrete map along the chosen steps. (Through ρ they would need the second
        # derivatives of the density, and its norm has no derivative where the speed vanishes.)
        sigma1, rate = jax.lax.stop_gradient(self.density_and_rate(problem, t1, report.q1, report.p1, report.lam1, args))
        usable = jnp.isfinite(sigma1) & (sigma1 > 0) & jnp.isfinite(rate)
        rho = st.rho + st.direction * st.epsilon * rate
        # ρ must stay positive: see MAX_DENSITY_CHANGE.
        bounded = jnp.clip(rho, st.rho / MAX_DENSITY_CHANGE, MAX_DENSITY_CHANGE * st.rho)
        ok = report.ok & usable
        new = st._replace(
            t=jnp.where(ok, t1, st.t), rho=jnp.where(ok, bounded, st.rho),
            n_clamped=st.n_clamped + (ok & (bounded != rho)).astype(jnp.int32),
        )
        bad = Result.DENSITY_NOT_POSITIVE
        result = jnp.where(report.ok, jnp.where(usable, Result.SUCCESSFUL, bad), report.result)
        # ε is NaN when the density was unusable at the start (init): the first step cannot be sized
        result = jnp.where(jnp.isnan(st.epsilon), bad, result)
        return ok, new, result.astype(jnp.int32)

    def stop_at(self, st: ReversibleState, t_stop) -> ReversibleState:
        """Move the end of the run to ``t_stop`` (a terminal event's zero); the next step is
        shortened to end there by :meth:`proposal`.

        Part of the controller protocol that the compiled loop calls; users pass the
        controller to :func:`~lobattodae.solve` and do not call it.

        Parameters
        ----------
        st : ReversibleState
            The controller's state.
        t_stop : jax.Array
            The new end.

        Returns
        -------
        ReversibleState
            The state with ``t_end = t_stop``.
        """
        return st._replace(t_end=t_stop)

    def turn_around(self, st: ReversibleState, problem, args, q, p, lam, t_end) -> ReversibleState:
        """The state that runs the control backwards from the current step point ``(q, p, λ)``
        towards ``t_end``: ``ρ_{N-1/2} = ρ_{N+1/2} - d ε G(y_N)`` and ``d → -d``, so that
        (with a symmetric method) the steps of the forward run are retraced in reverse order
        and ``y_{N-1}, …, y_0`` are recovered up to round-off and Newton's tolerance.

        Parameters
        ----------
        st : ReversibleState
            The state at the end of the forward run (at ``y_N``).
        problem : PartitionedDAE, NonholonomicSystem or MechanicalSystem
            The problem.
        args : pytree
            Passed to the problem functions and the density.
        q, p : jax.Array, shape (n,)
            The current step point ``y_N``.
        lam : jax.Array, shape (m,)
            Its multiplier (Newton's starting guess for the consistent one).
        t_end : float
            Where the backward run is to end.

        Returns
        -------
        ReversibleState
            The state of the backward run, starting at ``st.t``.
        """
        _, rate = self.density_and_rate(problem, st.t, q, p, lam, args)
        return st._replace(
            rho=st.rho - st.direction * st.epsilon * rate, direction=-st.direction, t0=st.t,
            t_end=jnp.asarray(t_end, st.t.dtype),
        )
