r"""Step doubling: the local error estimate of error-controlled steps.

An error-controlled step of size h from ``y_0 = (q_0, p_0)`` is two steps of the method of
size h/2, ``y_1 = Φ_{h/2}(Φ_{h/2}(y_0))``, which are kept, and one step of size h,
``ỹ_1 = Φ_h(y_0)``, which is only compared. The local error of one step is
``C(t_0) h^(2s-1) + O(h^(2s))`` (the method has global order 2s - 2), so

    ỹ_1 - y_1 = C h^(2s-1) (1 - 2^(-(2s-2))) + O(h^(2s)),

and the local error of the kept pair of half steps, ``2 C (h/2)^(2s-1)``, is estimated by

    err = (y_1 - ỹ_1) / (2^(2s-2) - 1)                                       (Richardson)

(Hairer, Nørsett & Wanner, *Solving ODEs I*, II.4). Nothing in it is fitted to problems: it
measures the step's own error, whatever λ mode, projection or problem, and where a step is
too long for the asymptotic expansion (a fast transient, a constraint-damped mode outside
the method's stability region, where |R(z)| → 1 instead of e^z → 0) the two
approximations disagree and the step is rejected. The divisor assumes the asymptotic ratio of
the two errors, 2^(2s-2): a step just outside that range, where the ratio is smaller, is
underestimated (Andrews' squeezer, s = 6: ratios 50–470 at its longest steps, estimates 3–400×
too small, ``benchmarks/RESULTS.md`` 2026-11-28). A step costs three Newton solves, the whole
step starting from its own Jacobian and predictor (kept across steps like the half steps'):
an independent extrapolation, not the half steps' result, whose Newton failures are what keeps
Andrews' steps out of that range (predicted from the halves, its error reached 92 × rtol).

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

from ._controllers import PIController
from ._dense import joined
from ._newton import JacobianCache
from ._results import Result
from ._stepper import History, LobattoIIIAIIIB, StepInfo, StepperState, as_step_arrays
from ._tableau import LobattoPair

__all__ = ["DoublingState", "StepDoubling", "for_error_control"]

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
class StepDoubling:
    """The method as error-controlled runs take its steps: two half steps kept, the whole step
    compared (Richardson's estimate of the local error; see the module docstring)."""

    method: LobattoIIIAIIIB
    pieces = 2

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

    @property
    def richardson(self) -> float:
        """``1 / (2^(2s-2) - 1)``: the half steps' share of the difference of the two results."""
        return 1.0 / (2.0 ** (2 * self.stages - 2) - 1.0)

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
            ``jacobians``: both factorisations, read and written at index ``j``)."""
            chain, jacobians, h_jacobians = carry
            q, p, lam, st = chain
            is_whole, is_second = i == 0, i == 2
            j = jnp.minimum(i, 1)
            start = _where(is_second, (q, p, lam), (q0, p0, lam0))
            t = jnp.where(is_second, t0 + 0.5 * h, t0)
            size = jnp.where(is_whole, h, 0.5 * h)
            cache = jax.tree_util.tree_map(lambda x: jax.lax.dynamic_index_in_dim(x, j, keepdims=False), jacobians)
            st = _where(is_whole, whole, st)._replace(jacobian=cache, h_jacobian=h_jacobians[j])
            q1, p1, lam1, info, new = self.method.step(problem, t, *start, size, args, st)
            jacobians = jax.tree_util.tree_map(lambda x, y: jax.lax.dynamic_update_index_in_dim(x, y, j, 0),
                                               jacobians, new.jacobian)
            h_jacobians = h_jacobians.at[j].set(new.h_jacobian)
            new = new._replace(jacobian=None, h_jacobian=None)
            chain = _where(is_whole, chain, (q1, p1, lam1, new))
            return (chain, jacobians, h_jacobians), (q1, p1, info, new.history)

        carry = ((q0, p0, lam0, state.half), state.jacobians, state.h_jacobians)
        ((q1, p1, lam1, half), jacobians, h_jacobians), (qs, ps, infos, histories) = jax.lax.scan(
            sub_step, carry, jnp.arange(3))
        y1 = jnp.concatenate([q1, p1])
        diff = y1 - jnp.concatenate([qs[0], ps[0]])
        # Newton's tolerance bounds what the two results can agree to: below it the difference is noise
        noise = NOISE * self.method.tol * (1.0 + jnp.abs(y1))
        error = self.richardson * jnp.sign(diff) * jnp.maximum(jnp.abs(diff) - noise, 0.0)
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
            # only the compared whole step failed: a step of half the size is a solve that has just
            # converged (the first half), so the retry need not shrink further
            retry=jnp.where(failed[0] & ~jnp.any(failed[1:]), 0.5, jnp.min(infos.retry)),
        )
        new_state = DoublingState(half, jacobians, h_jacobians, jax.tree_util.tree_map(lambda x: x[0], histories))
        return q1, p1, lam1, info, new_state


def for_error_control(method: LobattoIIIAIIIB, controller) -> Any:
    """The method as ``controller`` runs it: the one place where it is adapted.

    Error-controlled steps (:class:`~lobattodae.PIController`) start every step from the
    hidden constraint's multiplier (``lam_start="auto"`` becomes ``"consistent"``; an explicit
    ``"previous"`` is kept): the symmetric scheme's undamped λ mode would otherwise answer in
    the error estimate rather than the solution's error. With the default estimate the steps are
    :class:`StepDoubling`; ``PIController(estimate="embedded")`` keeps single steps. Other
    controllers run the method as it is.
    """
    if not isinstance(controller, PIController):
        return method
    if method.lam_start == "auto":
        method = dataclasses.replace(method, lam_start="consistent")
    return StepDoubling(method) if controller.estimate == "doubling" else method
