r"""Step doubling: the local error estimate of error-controlled steps.

An error-controlled step of size h from ``y_0 = (q_0, p_0)`` is two steps of the method of
size h/2, ``y_1 = Φ_{h/2}(Φ_{h/2}(y_0))``, which are kept, and one step of size h,
``ỹ_1 = Φ_h(y_0)``, which is only compared. The local error of one step is
``C(t_0) h^(2s-1) + O(h^(2s))`` (the method has global order 2s - 2), so

    ỹ_1 - y_1 = C h^(2s-1) (1 - 2^(-(2s-2))) + O(h^(2s)),

and the local error of the kept pair of half steps, ``2 C (h/2)^(2s-1)``, is estimated by

    err = (y_1 - ỹ_1) / (2^(2s-2) - 1)                                       (Richardson)

(Hairer, Nørsett & Wanner, *Solving ODEs I*, II.4). Nothing in it is fitted to problems: it
measures the step's own error, whatever λ mode, projection or problem.

The divisor assumes the asymptotic ratio of the two errors, 2^(2s-2). That ratio holds for the
modes a step resolves and fails for those it does not: a constraint-damped mode that the exact
flow has damped but the method, not L-stable (|R(z)| → 1 where e^z → 0), carries and amplifies
(a Chaplygin sleigh settling into straight motion: at h = 118 from a turning mode of 1e-10 the
half steps err by 3.2e-8 and the Richardson quotient was 161× too small), or an oscillation
shorter than the step. So the estimate first asks along which modes the error lies. The vector
field on the constraint manifold (λ from the hidden constraint, which each sub-step computes
anyway) differs between the two results by ``J e``, e = y_1 − ỹ_1, and its Rayleigh quotient
(weighted like the error test, 1 / (1 + |y|))

    z = h ⟨e, J e⟩ / ⟨e, e⟩ + i h (‖J e‖² / ‖e‖² − (⟨e, J e⟩ / ⟨e, e⟩)²)^(1/2)

is the step's hμ for the modes of the difference. Within the tableau's
:attr:`~lobattodae.LobattoPair.richardson_radius` (|z| up to 2.6, 3.6, 4.5, 5.3, 6.0 for
s = 2..6, where the linear theory's ratio stays within a factor two of 2^(2s-2) for damped and
oscillating modes alike) the divisor is Richardson's. Beyond it, it is that ratio for the test
equation ``y' = μ y``,

    D(z) = (R(z/2)² − R(z)) / (R(z/2)² − e^z),

R the stability function, kept between 1 and 2^(2s-2) − 1 (never less cautious than
Richardson): where |R(z)| → 1 it falls towards 1 and the estimate is the whole difference; for a
damped mode just beyond the radius it is still 2^(2s-2) or more, and steps held there by
stiffness keep their size. That R is IIIA's, the diagonal Padé approximant, for modes of the
ODE; a mode that the *constraint* damps (the sleigh's turning on straight motion) is multiplied
by ``R_c``, the (s, s−2) Padé approximant (:meth:`~lobattodae.LobattoPair.constraint_stability`),
which grows like z² and exceeds 1 beyond −z = 2.0, 5.4, 9.6, 14.7, 20.6 (s = 2..6). Where
``R_c(z/2)² ≈ R_c(z)`` the whole step and the half steps amplify such a mode alike: their results
agree while both are far off (s = 4, kh = 34: to 0.4 %, both ~50 times the mode's size off), and
the ODE theory's D, about 9 there, made the estimate 3,600 times too small. z does not tell the
two kinds of mode apart; the forces do: the momenta's field at the kept result is evaluated once
more with the whole step's λ, and where λ's change moves it more than the applied forces' change
(the sleigh's turning: the constraint's force alone), the share beyond the radius is the larger
of the two theories', the constraint's ``1 / D_c`` allowed above 1, up to 2^(2s-2) − 1; elsewhere
the ODE theory's. (Asked everywhere, the constraint's theory cost up to 42 % more attempts on
problems whose modes beyond the radius are the applied forces', the Fekete particles and the
slider crank, with errors far below rtol either way.) Inside the radius Richardson's divisor
holds for such modes too: D_c lies within 0.5 and 3 times it, for s = 2..6. A sleigh that
settles: step points at most 7.3 × rtol over 36 runs with the ODE theory (before it: up to
251 ×, 10 runs above 30 ×; ``benchmarks/RESULTS.md``, 2026-11-28, 12:00), 0.72 × with both and
the check of large steps below (2026-11-29).
Where a step is too long for the asymptotic expansion in the other way (a fast transient), the
two approximations disagree by much and the step is rejected; where they agree too well for the
change of the error constant from the step before, the controller checks the divisor on a step of
half the size (``PIController``, "Large steps": the settling sleigh's 36 runs then at most 2.2 ×,
2026-11-28 21:55; this module reports the share it used in ``StepInfo.share``). The
whole step starts from its own Jacobian and predictor (kept across steps like the half steps'):
an independent extrapolation, not the half steps' result, whose Newton failures are what keeps
Andrews' steps out of that range (predicted from the halves, its error reached 92 × rtol).

A step costs three Newton solves and three evaluations of the vector field. An attempt whose
whole step fails to converge is rejected whatever the half steps do, so they are then not
solved (their stage solves stop after the fast start's iterations: ``solve`` of
:meth:`~lobattodae.LobattoIIIAIIIB.step`), and the retry takes half the size. A failed attempt
then costs one solve instead of three: 6–19 % less time on runs with failed solves (Andrews'
squeezer at rtol 1e-4…1e-6 11–19 %; ``benchmarks/RESULTS.md``, 2026-11-29 09:35).

The three solves are one traced step of the method run three times (``lax.scan`` over
"whole step, first half, second half"), so the compiled program holds the stage equations
once. The step's dense output is that of the two half steps (two pieces, see
:class:`~lobattodae._dense.DenseStep`).
"""

from __future__ import annotations

import dataclasses
import functools
from dataclasses import dataclass
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from ._controllers import PIController
from ._dense import joined
from ._newton import JacobianCache
from ._problem import vector_field
from ._results import Result
from ._stepper import History, LobattoIIIAIIIB, StepInfo, StepperState, as_step_arrays
from ._tableau import LobattoPair
from ._validate import check_method

__all__ = ["DoublingState", "MethodSteps", "StepDoubling", "for_error_control"]

#: Differences of the two results up to NOISE Newton tolerances, ``NOISE·tol·(1 + |y|)``, are
#: not counted as error: each result is only solved to that tolerance, and an error test per
#: unit step (``PIController``) would otherwise chase Newton's noise with ever smaller steps.
NOISE = 2.0


class DoublingState(NamedTuple):
    """The half steps' state, and what the whole step keeps of its own.

    The two Jacobian factorisations (the whole step's, index 0, and the half steps', index 1)
    are stacked in ``jacobians`` and not held in ``half`` (whose ``jacobian`` and
    ``h_jacobian`` are None): each sub-step reads its own by index and writes it back in
    place. Selected between sub-steps like the rest of the state, they were copied about
    sixteen times per attempt, which doubled an attempt's time at 340 unknowns
    (``benchmarks/RESULTS.md``, 2026-11-28 05:10).
    """

    half: StepperState
    jacobians: JacobianCache  # every leaf with a leading axis of 2: (whole step, half steps)
    h_jacobians: jax.Array  # (2,): the step sizes they were evaluated with
    whole_history: History

    @property
    def monitor(self):
        """The λ drift monitor of the kept (half) steps."""
        return self.half.monitor


def _where(pred, a, b):
    return jax.tree_util.tree_map(lambda x, y: jnp.where(pred, x, y), a, b)


@dataclass(frozen=True)
class MethodSteps:
    """A stepper that takes ``method``'s steps its own way: its stages, tableaus, multiplier
    policy and orders are the method's."""

    method: LobattoIIIAIIIB

    @property
    def stages(self) -> int:
        return self.method.stages

    @property
    def pair(self) -> LobattoPair:
        return self.method.pair

    @property
    def lam_start(self) -> str:
        return self.method.lam_start

    def order(self) -> dict[str, int]:
        return self.method.order()


@dataclass(frozen=True)
class StepDoubling(MethodSteps):
    """The method as error-controlled runs take its steps: two half steps kept, the whole step
    compared (Richardson's estimate of the local error; see the module docstring)."""

    pieces = 2

    @property
    def richardson(self) -> float:
        """``1 / (2^(2s-2) - 1)``: the half steps' share of the difference of the two results."""
        return 1.0 / (2.0 ** (2 * self.stages - 2) - 1.0)

    def _share(self, h, diff, slopes, y1, through_lam):
        """``(share, resolved)``: the half steps' share of the difference ``diff`` of the two
        results, Richardson's ``1 / (2^(2s-2) - 1)`` along modes the step resolves, else the
        linear theory's ratio at ``z = h μ``, μ the Rayleigh quotient of the vector field's
        Jacobian along ``diff`` (``slopes``: its change between the two results; ``through_lam``:
        the part of it that λ's change makes), that of ODE modes (never above 1) or, where the
        constraint's force changes more than the applied forces, the larger of it and that of
        modes the constraint damps (see the module docstring); and whether those modes lay
        within Richardson's radius (``resolved``)."""
        weight = 1.0 / (1.0 + jnp.abs(y1))
        e, je = weight * diff, jnp.abs(h) * weight * slopes
        # the force on p along e: more of its change from the constraint's (λ's) than from the
        # applied forces' makes a mode the constraint damps
        n = diff.shape[-1] // 2
        by_lam, applied = weight[n:] * through_lam[n:], weight[n:] * (slopes[n:] - through_lam[n:])
        by_constraint = jnp.sum(by_lam * by_lam) > jnp.sum(applied * applied)
        size2 = jnp.maximum(jnp.sum(e * e), jnp.finfo(e.dtype).tiny)
        modulus = jnp.sqrt(jnp.sum(je * je) / size2)
        real = jnp.sum(e * je) / size2
        z = jax.lax.complex(real, jnp.sqrt(jnp.maximum(modulus**2 - real**2, 0.0)))

        def ratio(num, den):
            """``|D(z)|`` for a mode that one step multiplies by ``num(z) / den(z)``."""
            num, den = (jnp.asarray(c[::-1], dtype=z.dtype) for c in (num, den))

            def stability(x):
                return jnp.polyval(num, x) / jnp.polyval(den, x)

            half = stability(0.5 * z) ** 2
            return jnp.abs((half - stability(z)) / (half - jnp.exp(z)))

        pade = self.pair.pade_coefficients
        ode = ratio(pade, pade * (-1.0) ** np.arange(pade.size))
        constrained = ratio(*self.pair.constraint_pade)
        d0 = 1.0 / self.richardson
        # an ODE mode: never less cautious than Richardson, never more than the whole difference
        ode = jnp.where(jnp.isfinite(ode), jnp.clip(ode, 1.0, d0), 1.0)
        # a mode the constraint damps: its two results can agree while both are far off (the step
        # amplifies it, |R_c| > 1), so the share may exceed 1, up to the inverse of Richardson's
        constrained = jnp.where(jnp.isfinite(constrained), jnp.clip(constrained, 1.0 / d0, d0), 1.0)
        share = jnp.where(by_constraint, jnp.maximum(1.0 / ode, 1.0 / constrained), 1.0 / ode)
        resolved = modulus <= self.pair.richardson_radius
        return jnp.where(resolved, self.richardson, share), resolved

    def init(self, problem, t0, q0, p0, lam0, args: Any = None, h=None, lam_hidden=None) -> DoublingState:
        half = self.method.init(problem, t0, q0, p0, lam0, args, None if h is None else 0.5 * h, lam_hidden)
        whole_h = jnp.asarray(0.0 if h is None else h, half.h_jacobian.dtype)
        jacobians = jax.tree_util.tree_map(lambda x: jnp.stack([x, x]), half.jacobian)
        return DoublingState(half._replace(jacobian=None, h_jacobian=None), jacobians,
                             jnp.stack([whole_h, half.h_jacobian]), half.history)

    def after_rejection(self, kept, new: DoublingState, old: DoublingState) -> DoublingState:
        """As :meth:`LobattoIIIAIIIB.after_rejection`, for the half steps' state and the whole
        step's own: both Jacobian factorisations are the attempt's."""
        half = self.method.after_rejection(kept, new.half, old.half)
        history = jax.tree_util.tree_map(functools.partial(jnp.where, kept), new.whole_history, old.whole_history)
        return DoublingState(half, new.jacobians, new.h_jacobians, history)

    def step(self, problem, t0, q0, p0, lam0, h, args: Any = None, state: DoublingState | None = None):
        """A step of size h as two half steps, with the local error estimate (Richardson) in
        ``info.error``; returns what :meth:`LobattoIIIAIIIB.step` returns."""
        t0, q0, p0, lam0, h = as_step_arrays(t0, q0, p0, lam0, h)
        if state is None:
            state = self.init(problem, t0, q0, p0, lam0, args, h)
        # the whole step starts from the same multiplier policy as the first half (same λ_0 data)
        whole = state.half._replace(history=state.whole_history)

        def sub_step(carry, i):
            """i = 0: the whole step; 1, 2: the half steps (``chain``: where the halves are;
            ``jacobians``: both factorisations, read and written at index ``j``; ``whole_failed``:
            the whole step did not converge, and the halves are not solved)."""
            chain, jacobians, h_jacobians, whole_failed = carry
            q, p, lam, st = chain
            is_whole, is_second = i == 0, i == 2
            j = jnp.minimum(i, 1)
            start = _where(is_second, (q, p, lam), (q0, p0, lam0))
            t = jnp.where(is_second, t0 + 0.5 * h, t0)
            size = jnp.where(is_whole, h, 0.5 * h)
            cache = jax.tree_util.tree_map(lambda x: jax.lax.dynamic_index_in_dim(x, j, keepdims=False), jacobians)
            st = _where(is_whole, whole, st)._replace(jacobian=cache, h_jacobian=h_jacobians[j])
            q1, p1, lam1, info, new = self.method.step(problem, t, *start, size, args, st, solve=is_whole | ~whole_failed)
            whole_failed = whole_failed | (is_whole & (info.result != Result.SUCCESSFUL))
            jacobians = jax.tree_util.tree_map(lambda x, y: jax.lax.dynamic_update_index_in_dim(x, y, j, 0),
                                               jacobians, new.jacobian)
            h_jacobians = h_jacobians.at[j].set(new.h_jacobian)
            new = new._replace(jacobian=None, h_jacobian=None)
            chain = _where(is_whole, chain, (q1, p1, lam1, new))
            return (chain, jacobians, h_jacobians, whole_failed), (q1, p1, info, new.history, new.lam_hidden)

        carry = ((q0, p0, lam0, state.half), state.jacobians, state.h_jacobians, jnp.asarray(False))
        ((q1, p1, lam1, half), jacobians, h_jacobians, _), (qs, ps, infos, histories, lams) = jax.lax.scan(
            sub_step, carry, jnp.arange(3))
        y1 = jnp.concatenate([q1, p1])
        diff = y1 - jnp.concatenate([qs[0], ps[0]])
        # Newton's tolerance bounds what the two results can agree to: below it the difference is noise
        noise = NOISE * self.method.tol * (1.0 + jnp.abs(y1))
        # the vector field on the constraint manifold (λ from the hidden constraint) at both results
        # and at the kept result with the whole step's λ: what λ's change alone changes in it
        fields = jax.vmap(lambda q, p, lam: jnp.concatenate(vector_field(problem, t0 + h, q, p, lam, args)))(
            qs[jnp.array([0, 2, 2])], ps[jnp.array([0, 2, 2])], lams[jnp.array([0, 2, 0])])
        slopes = fields[1] - fields[0]
        share, resolved = self._share(h, diff, slopes, y1, fields[1] - fields[2])
        error = share * jnp.sign(diff) * jnp.maximum(jnp.abs(diff) - noise, 0.0)
        failed = infos.result != Result.SUCCESSFUL
        result = jnp.where(jnp.any(failed), infos.result[jnp.argmax(failed)], Result.SUCCESSFUL).astype(jnp.int32)
        first, second = (jax.tree_util.tree_map(lambda x, k=k: x[k], infos.dense) for k in (1, 2))
        info = StepInfo(
            result=result,
            iterations=jnp.sum(infos.iterations).astype(jnp.int32),
            residual_norm=jnp.max(infos.residual_norm),
            n_jacobians=jnp.sum(infos.n_jacobians).astype(jnp.int32),
            drift=infos.drift[2],
            resync=infos.resync[1],
            error=error,
            dense=joined(first, second),
            # the compared whole step failed (and the half steps were not solved): the retry is a step
            # of the first half's size, whose solve converges where the whole step's size was the cause
            retry=jnp.where(failed[0], 0.5, jnp.min(infos.retry)),
            share=share,
            resolved=resolved,
        )
        new_state = DoublingState(half, jacobians, h_jacobians, jax.tree_util.tree_map(lambda x: x[0], histories))
        return q1, p1, lam1, info, new_state


def for_error_control(method, controller, problem=None, *, native: bool = False) -> Any:
    """The method as ``controller`` runs it: the one place where it is adapted.

    Error-controlled steps (:class:`~lobattodae.PIController`) start every step from the
    hidden constraint's multiplier (``lam_start="auto"`` becomes ``"consistent"``; an explicit
    ``"previous"`` is kept): the symmetric scheme's undamped λ mode would otherwise answer in
    the error estimate rather than the solution's error. With the default estimate the steps are
    :class:`StepDoubling`; ``PIController(estimate="embedded")`` keeps single steps. Other
    controllers run the method as it is.

    ``method`` may be a model's :class:`~lobattodae.mechanics.NativeIntegrator` where ``native``
    allows it (:func:`lobattodae.solve`): the same decisions, the steps (or attempts of step
    doubling) then native calls for ``problem``, the model's
    (:mod:`lobattodae.mechanics._native_loop`).
    """
    check_method(method, native=native)
    integrator = None
    if not isinstance(method, LobattoIIIAIIIB):  # a NativeIntegrator
        integrator, method = method, method.method
    if isinstance(controller, PIController) and method.lam_start == "auto":
        method = dataclasses.replace(method, lam_start="consistent")
    if isinstance(controller, PIController) and controller.estimate == "doubling":
        return StepDoubling(method) if integrator is None else integrator.doubling(method, problem)
    return method if integrator is None else integrator.single(method, problem)
