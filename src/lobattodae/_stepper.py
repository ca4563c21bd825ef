"""The Lobatto-type IIIA-IIIB step for partitioned index-2 DAEs."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from ._problem import consistent_lambda, vector_field
from ._newton import JacobianCache, empty_jacobian_cache, newton_solve
from ._tableau import LobattoPair, lobatto_pair

__all__ = ["LobattoIIIAIIIB", "StageSlopes", "StepperState", "StepInfo"]

# Extrapolating the previous step's stage polynomial amplifies its values by the Lebesgue-type
# constant max_i sum_j |l_j(1 + c_i)|; beyond this bound the explicit guess is used instead.
_MAX_EXTRAPOLATION_GAIN = 1e4


class StageSlopes(NamedTuple):
    """Stage slopes of a step, kept to predict the next step's stages:
    ``V (s, n)``, ``W (s, n)``, ``Lam (s, m)``."""

    V: jax.Array
    W: jax.Array
    Lam: jax.Array


class StepperState(NamedTuple):
    """What a step hands to the next: the Jacobian cache and the last stage slopes."""

    jacobian: JacobianCache
    slopes: StageSlopes
    correction: StageSlopes  # error of the plain extrapolation at the last step
    have_slopes: jax.Array  # bool scalar
    have_correction: jax.Array  # bool scalar


class StepInfo(NamedTuple):
    """Diagnostics of one step (all JAX scalars)."""

    result: jax.Array
    iterations: jax.Array
    residual_norm: jax.Array
    n_jacobians: jax.Array


@dataclass(frozen=True)
class LobattoIIIAIIIB:
    r"""The s-stage Lobatto-type IIIA-IIIB partitioned Runge-Kutta method for index-2 DAEs.

    For ``q' = f(t, q, p)``, ``p' = g(t, q, p, λ)``, ``0 = φ(t, q, p)`` one step of size h
    from consistent ``(t0, q0, p0, λ0)`` solves, with ``A = (a_ij), b, c`` Lobatto IIIA and
    ``Â = (â_ij)`` Lobatto IIIB (``â_ij = b_j (1 - a_ji / b_i)``), ``t_j = t0 + c_j h``:

    .. math::

        Q_i &= q_0 + h \sum_{j=1}^s a_{ij} V_j,  & V_j &= f(t_j, Q_j, P_j),\\
        P_i &= p_0 + h \sum_{j=1}^s \hat a_{ij} W_j, & W_j &= g(t_j, Q_j, P_j, Λ_j),\\
        \tilde p_i &= p_0 + h \sum_{j=1}^s a_{ij} W_j, & 0 &= φ(t_i, Q_i, \tilde p_i),
            \quad i = 2, \dots, s,\\
        Λ_1 &= λ_0, & &\\
        q_1 &= q_0 + h \sum_j b_j V_j = Q_s, & p_1 &= p_0 + h \sum_j b_j W_j = \tilde p_s,
            \quad λ_1 = Λ_s.

    The constraint is imposed at ``p̃_i`` (IIIA coefficients) rather than at ``P_i``: IIIB's
    last column is zero, which would make ``D_pφ (Â ⊗ I) D_λ g`` singular. Since
    ``a_sj = b_j``, ``φ(t_1, q_1, p_1) = 0`` holds at every step to Newton tolerance.

    Unknowns: ``Q_2..Q_s`` (``Q_1 = q_0``), ``P_1..P_s`` and ``Λ_2..Λ_s``, i.e.
    ``(2s-1) n + (s-1) m`` scalars. Newton works on ``Z_j = h Λ_j`` (λ enters every
    equation multiplied by h, so this keeps the Jacobian O(1) as h → 0), with an autodiff
    Jacobian; the iteration stops on the scaled increment (Hairer-Wanner rate test).

    Global orders on ``[t0, t0 + T]`` (Martín de Diego & Sato, Corollary): q, p
    ``h^(2s-2)``; λ ``h^s`` for even s and ``h^(s-1)`` for odd s.

    Parameters
    ----------
    stages : int
        Number of stages s ≥ 2.
    tol : float
        Relative/absolute tolerance of the Newton increment, ``|Δx_i| ≤ tol (1 + |x_i|)``.
    max_iterations : int
        Newton iterations per step before the step is declared failed.
    reuse_jacobian : bool
        Simplified Newton: keep the LU factors of the stage Jacobian across iterations and
        steps, refreshing them only when the contraction rate degrades. Much cheaper per
        step; the converged solution is the same to Newton tolerance.
    lam_start : {"previous", "consistent"}
        What ``Λ_1`` is at step n > 0; a trade-off, measured in ``docs/verification.md``.

        * ``"previous"`` (default) is the paper's scheme: ``Λ_1 = λ_n``, the ``Λ_s`` of the
          previous step; the proven orders above refer to it. The step map on (q, p, λ) is
          symmetric, so energy errors stay bounded on reversible problems. But λ errors are
          propagated with ``|R(∞)| = 1`` (never damped) and on some problems (the Chaplygin
          sleigh, the rolling disk) they grow like ``exp(C t)`` over long runs and then spoil
          q and p too; ``solve`` warns when ``|λ_n − λ(q_n, p_n)|`` grows.
        * ``"consistent"`` sets ``Λ_1 = λ(t_n, q_n, p_n)`` solved from the hidden constraint
          ``φ_t + φ_q f + φ_p g = 0``, so λ errors cannot accumulate (on the first step both
          coincide). Observed orders: q, p ``2s-2``, λ ``s`` for every s, and Newton needs
          fewer iterations. The step is no longer symmetric: on reversible problems the
          energy error drifts (linearly, at the order of the method) instead of staying
          bounded.
    jacobian : {"structured", "autodiff"}
        How Newton's Jacobian is formed. ``"structured"`` (default) differentiates each
        stage's ``(f, g)`` in ``(q, p, λ)`` and ``φ`` in ``(q, p)`` and assembles the
        block matrix from the coefficients (about 2x cheaper on the falling disk);
        ``"autodiff"`` applies ``jax.jacfwd`` to the whole stage residual. Both give the
        same matrix up to round-off.
    extrapolate : bool
        Start Newton from the previous step's stage polynomial extrapolated to the new step
        (falls back to an explicit Euler-type guess on the first step, and for large s where
        extrapolation is ill-conditioned).
    """

    stages: int = 3
    tol: float = 1e-14
    max_iterations: int = 20
    reuse_jacobian: bool = True
    extrapolate: bool = True
    lam_start: str = "previous"
    jacobian: str = "structured"

    def __post_init__(self):
        lobatto_pair(self.stages)  # validates s
        if not (isinstance(self.tol, (int, float)) and 0 < self.tol < 1):
            raise ValueError(f"tol must be a float in (0, 1); got tol={self.tol!r}.")
        if self.lam_start not in ("previous", "consistent"):
            raise ValueError(
                f"lam_start must be 'previous' (the paper's scheme, Λ_1 = λ_n) or 'consistent' "
                f"(Λ_1 from the hidden constraint at (t_n, q_n, p_n)); got {self.lam_start!r}."
            )
        if self.jacobian not in ("structured", "autodiff"):
            raise ValueError(
                f"jacobian must be 'structured' (per-stage blocks, the default) or 'autodiff' "
                f"(forward-mode through the whole stage residual); got {self.jacobian!r}."
            )
        if not (isinstance(self.max_iterations, int) and self.max_iterations >= 1):
            raise ValueError(
                f"max_iterations must be a positive integer; got {self.max_iterations!r}."
            )

    # -- tableau and theory -------------------------------------------------------------
    @property
    def pair(self) -> LobattoPair:
        """The Lobatto IIIA-IIIB coefficients ``(s, c, b, a, a_hat)``."""
        return lobatto_pair(self.stages)

    def order(self) -> dict[str, int]:
        """Global orders proven for this method: ``{"q": 2s-2, "p": 2s-2, "lam": ...}``."""
        s = self.stages
        return {"q": 2 * s - 2, "p": 2 * s - 2, "lam": s if s % 2 == 0 else s - 1}

    def n_unknowns(self, n: int, m: int) -> int:
        """Size of the Newton system, ``(2s-1) n + (s-1) m``."""
        s = self.stages
        return (2 * s - 1) * n + (s - 1) * m

    def _extrapolation_matrix(self) -> np.ndarray | None:
        c = self.pair.c
        s = self.stages
        e = np.ones((s, s))
        for i in range(s):
            x = 1.0 + c[i]
            for j in range(s):
                for k in range(s):
                    if k != j:
                        e[i, j] *= (x - c[k]) / (c[j] - c[k])
        if np.max(np.sum(np.abs(e), axis=1)) > _MAX_EXTRAPOLATION_GAIN:
            return None
        return e

    # -- stepping -----------------------------------------------------------------------
    def init(self, q0, p0, lam0) -> StepperState:
        """Initial stepper state (no Jacobian yet, no previous stages)."""
        s, n, m = self.stages, q0.shape[-1], lam0.shape[-1]
        dtype = q0.dtype
        zeros = StageSlopes(jnp.zeros((s, n), dtype), jnp.zeros((s, n), dtype), jnp.zeros((s, m), dtype))
        return StepperState(
            jacobian=empty_jacobian_cache(self.n_unknowns(n, m), dtype),
            slopes=zeros,
            correction=zeros,
            have_slopes=jnp.asarray(False),
            have_correction=jnp.asarray(False),
        )

    def step(self, problem, t0, q0, p0, lam0, h, args: Any = None, state: StepperState | None = None):
        """Take one step of size ``h`` from consistent ``(t0, q0, p0, λ0)``.

        Pure and jit/vmap-able. ``h`` may be negative (a step backwards in time).

        Returns
        -------
        q1, p1, lam1 : jax.Array
        info : StepInfo
            ``result`` (a :class:`Result` code; anything but 0 means the step failed and
            ``q1, p1, lam1`` are not a solution), ``iterations``, ``residual_norm``,
            ``n_jacobians``.
        state : StepperState
            To be passed to the next step (Jacobian reuse, initial guess).
        """
        q0 = jnp.asarray(q0)
        dtype = q0.dtype
        p0 = jnp.asarray(p0, dtype)
        lam0 = jnp.asarray(lam0, dtype)
        t0 = jnp.asarray(t0, dtype)
        if self.lam_start == "consistent":
            lam0 = consistent_lambda(problem, t0, q0, p0, lam0, args, iterations=1)
        return self.step_from(problem, t0, q0, p0, lam0, h, args, state)

    def step_from(self, problem, t0, q0, p0, lam_start, h, args: Any = None, state: StepperState | None = None):
        """:meth:`step` with ``Λ_1 = lam_start`` given as is (``lam_start`` is not applied).

        For loops that already know ``λ(t_n, q_n, p_n)``: :func:`~lobattodae.solve` computes
        it after every step for its multiplier-drift diagnostic and, with
        ``lam_start="consistent"``, hands it to the next step instead of solving for it twice.
        """
        q0 = jnp.asarray(q0)
        dtype = q0.dtype
        p0 = jnp.asarray(p0, dtype)
        lam0 = jnp.asarray(lam_start, dtype)
        h = jnp.asarray(h, dtype)
        t0 = jnp.asarray(t0, dtype)
        if state is None:
            state = self.init(q0, p0, lam0)
        pair = self.pair
        a = jnp.asarray(pair.a, dtype)
        a_hat = jnp.asarray(pair.a_hat, dtype)
        system = self._stage_system(problem, t0, q0, p0, lam0, h, args)
        residual, structured_jacobian, unpack, pack, fg, tj = system

        x0, plain = self._initial_guess(lam0, h, state, q0, p0, a, a_hat, pack)
        x, ninfo, cache = newton_solve(
            residual,
            x0,
            state.jacobian,
            tol=self.tol,
            max_iterations=self.max_iterations,
            reuse_jacobian=self.reuse_jacobian,
            jacobian=structured_jacobian if self.jacobian == "structured" else None,
        )
        Q, P, Z = unpack(x)
        lam = Z / h
        V, W = fg(tj, Q, P, lam)
        b = jnp.asarray(pair.b, dtype)
        q1 = Q[-1]
        p1 = p0 + h * (b @ W)
        lam1 = lam[-1]
        info = StepInfo(ninfo.result, ninfo.iterations, ninfo.residual_norm, ninfo.n_jacobians)
        new_slopes = StageSlopes(V, W, lam)
        have_correction = jnp.logical_and(state.have_slopes, plain is not None)
        correction = new_slopes if plain is None else jax.tree_util.tree_map(jnp.subtract, new_slopes, plain)
        new_state = StepperState(cache, new_slopes, correction, jnp.asarray(True), have_correction)
        return q1, p1, lam1, info, new_state

    def _stage_system(self, problem, t0, q0, p0, lam0, h, args):
        """The Newton system of one step: ``(residual, structured_jacobian, unpack, pack,
        fg, tj)`` for the unknowns ``x = (Q_2..Q_s, P_1..P_s, Z_2..Z_s)`` (arrays as
        prepared by :meth:`step_from`)."""
        pair = self.pair
        s = self.stages
        dtype = q0.dtype
        n, m = q0.shape[0], lam0.shape[0]
        a = jnp.asarray(pair.a, dtype)
        a_hat = jnp.asarray(pair.a_hat, dtype)
        c = jnp.asarray(pair.c, dtype)
        tj = t0 + c * h

        fg = jax.vmap(lambda t, q, p, lam: vector_field(problem, t, q, p, lam, args))
        phi = jax.vmap(lambda t, q, p: problem.phi(t, q, p, args))

        def unpack(x):
            i1 = (s - 1) * n
            i2 = i1 + s * n
            Q = jnp.concatenate([q0[None], x[:i1].reshape(s - 1, n)])
            P = x[i1:i2].reshape(s, n)
            Z = jnp.concatenate([(h * lam0)[None], x[i2:].reshape(s - 1, m)])
            return Q, P, Z

        def pack(Q, P, Z):
            return jnp.concatenate([Q[1:].ravel(), P.ravel(), Z[1:].ravel()])

        def stage_residual(Q, P, V, W, phi_values):
            r_q = Q[1:] - q0 - h * (a[1:] @ V)
            r_p = P - p0 - h * (a_hat @ W)
            return jnp.concatenate([r_q.ravel(), r_p.ravel(), phi_values.ravel()])

        def residual(x):
            Q, P, Z = unpack(x)
            V, W = fg(tj, Q, P, Z / h)
            p_tilde = p0 + h * (a[1:] @ W)
            return stage_residual(Q, P, V, W, phi(tj[1:], Q[1:], p_tilde))

        def structured_jacobian(x):
            Q, P, Z = unpack(x)
            (fq, fp, gq, gp, gl), (V, W) = _stage_jacobians(problem, tj, Q, P, Z / h, args)
            p_tilde = p0 + h * (a[1:] @ W)
            (phi_q, phi_p), phi_values = _constraint_jacobians(problem, tj[1:], Q[1:], p_tilde, args)
            jac = _assemble_jacobian(a, a_hat, h, fq, fp, gq, gp, gl, phi_q, phi_p)
            return stage_residual(Q, P, V, W, phi_values), jac

        return residual, structured_jacobian, unpack, pack, fg, tj

    def _initial_guess(self, lam0, h, state, q0, p0, a, a_hat, pack):
        """Newton's starting point, and the plain extrapolation of the slopes (or None).

        From the second step on, the previous step's slopes ``V, W`` and multipliers ``Λ`` are
        extrapolated (Lagrange interpolation at ``c``, evaluated at ``1 + c``), corrected by
        the error this extrapolation made at the previous step, and the stages rebuilt from the
        *new* ``q0, p0``: ``Q = q0 + h A V``, ``P = p0 + h Â W``. The IIIB stages (and with
        them the slopes) deviate from a smooth polynomial by O(h^(s-1)) in a pattern that
        varies smoothly from step to step, which the correction removes. First step: constant
        stages ``(q0, p0, λ0)``.
        """
        s = self.stages
        constant = pack(
            jnp.broadcast_to(q0, (s, q0.shape[0])),
            jnp.broadcast_to(p0, (s, p0.shape[0])),
            jnp.broadcast_to(h * lam0, (s, lam0.shape[0])),
        )
        e = self._extrapolation_matrix() if self.extrapolate else None
        if e is None:
            return constant, None
        e = jnp.asarray(e, q0.dtype)
        plain = StageSlopes(*(e @ x for x in state.slopes))
        use_corr = state.have_correction
        V, W, Lam = (jnp.where(use_corr, x + d, x) for x, d in zip(plain, state.correction))
        extrap = pack(q0 + h * (a @ V), p0 + h * (a_hat @ W), h * Lam)
        usable = jnp.logical_and(state.have_slopes, jnp.all(jnp.isfinite(extrap)))
        return jnp.where(usable, extrap, constant), plain


# -- the stage Jacobian from per-stage blocks ---------------------------------------------
def _stage_jacobians(problem, tj, Q, P, lam, args):
    """Per stage j: ``f_q, f_p, g_q, g_p, g_λ`` at ``(t_j, Q_j, P_j, Λ_j)`` and ``(V_j, W_j)``.

    One forward-mode pass with ``2n + m`` tangents per stage, instead of the
    ``(2s-1) n + (s-1) m`` tangents of the whole residual, each of which runs all s stages.
    """

    def one(t, q, p, lam_j):
        def field(qq, pp, ll):
            v, w = vector_field(problem, t, qq, pp, ll, args)
            return (v, w), (v, w)

        ((fq, fp, _), (gq, gp, gl)), vw = jax.jacfwd(field, argnums=(0, 1, 2), has_aux=True)(q, p, lam_j)
        return (fq, fp, gq, gp, gl), vw

    return jax.vmap(one)(tj, Q, P, lam)


def _constraint_jacobians(problem, t, Q, p_tilde, args):
    """``(φ_q, φ_p)`` and ``φ`` at the constrained stages ``(t_i, Q_i, p̃_i)``, i = 2..s."""

    def one(ti, q, p):
        def con(qq, pp):
            r = problem.phi(ti, qq, pp, args)
            return r, r

        return jax.jacfwd(con, argnums=(0, 1), has_aux=True)(q, p)

    return jax.vmap(one)(t, Q, p_tilde)


def _assemble_jacobian(a, a_hat, h, fq, fp, gq, gp, gl, phi_q, phi_p):
    r"""The Jacobian of the stage residual with respect to ``(Q_2..Q_s, P_1..P_s, Z_2..Z_s)``.

    With ``Z_k = h Λ_k``, ``p̃_i = p_0 + h Σ_k a_ik W_k`` and per-stage blocks
    ``F_x = ∂f/∂x``, ``G_x = ∂g/∂x`` at stage k, ``Φ_x = ∂φ/∂x`` at ``(Q_i, p̃_i)``:

    * ``r_q,i = Q_i - q_0 - h Σ a_ik V_k``: ``δ_ik I - h a_ik F_q``, ``-h a_ik F_p``, 0;
    * ``r_p,i = P_i - p_0 - h Σ â_ik W_k``: ``-h â_ik G_q``, ``δ_ik I - h â_ik G_p``, ``-â_ik G_λ``;
    * ``r_φ,i = φ(Q_i, p̃_i)``: ``δ_ik Φ_q + h a_ik Φ_p G_q``, ``h a_ik Φ_p G_p``, ``a_ik Φ_p G_λ``.
    """
    s, n, m = fq.shape[0], fq.shape[1], gl.shape[2]
    eye_n = jnp.eye(n, dtype=fq.dtype)
    eye_s = jnp.eye(s, dtype=fq.dtype)
    a1 = a[1:]

    def kron(coef, blocks):  # (rows, cols) coefficients times per-column blocks (cols, x, y)
        return jnp.einsum("ik,kab->iakb", coef, blocks)

    def flat(block):
        r, x, c, y = block.shape
        return block.reshape(r * x, c * y)

    def through_phi(blocks):  # Φ_p,i @ block_k for rows i = 2..s, columns k
        return jnp.einsum("ica,kab->ickb", phi_p, blocks)

    rq_q = jnp.einsum("ik,ab->iakb", eye_s[1:, 1:], eye_n) - h * kron(a1[:, 1:], fq[1:])
    rq_p = -h * kron(a1, fp)
    rq_z = jnp.zeros((s - 1, n, s - 1, m), fq.dtype)
    rp_q = -h * kron(a_hat[:, 1:], gq[1:])
    rp_p = jnp.einsum("ik,ab->iakb", eye_s, eye_n) - h * kron(a_hat, gp)
    rp_z = -kron(a_hat[:, 1:], gl[1:])
    rf_q = jnp.einsum("ik,icb->ickb", eye_s[1:, 1:], phi_q) + h * a1[:, None, 1:, None] * through_phi(gq[1:])
    rf_p = h * a1[:, None, :, None] * through_phi(gp)
    rf_z = a1[:, None, 1:, None] * through_phi(gl[1:])
    rows = [[rq_q, rq_p, rq_z], [rp_q, rp_p, rp_z], [rf_q, rf_p, rf_z]]
    return jnp.concatenate([jnp.concatenate([flat(b) for b in row], axis=1) for row in rows], axis=0)
