r"""The stage equations of one Lobatto IIIA-IIIB step (the paper's scheme, eq. RK_partitioned_system).

For ``q' = f(t, q, p)``, ``p' = g(t, q, p, λ)``, ``0 = φ(t, q, p)``, one step of size h from
``(t_0, q_0, p_0)`` with start multiplier ``Λ_1`` (decided by the stepper, see
:mod:`lobattodae._stepper`), ``A = (a_ij), b, c`` Lobatto IIIA, ``Â = (â_ij)`` Lobatto IIIB
(``â_ij = b_j (1 - a_ji / b_i)``) and stage times ``t_j = t_0 + c_j h``:

    Q_i = q_0 + h Σ_j a_ij V_j,     V_j = f(t_j, Q_j, P_j)                   (1)  i = 2..s
    P_i = p_0 + h Σ_j â_ij W_j,     W_j = g(t_j, Q_j, P_j, Λ_j)              (2)  i = 1..s
    0   = φ(t_i, Q_i, p̃_i),        p̃_i = p_0 + h Σ_j a_ij W_j  (IIIA!)    (3)  i = 2..s
    q_1 = Q_s,   p_1 = p̃_s = p_0 + h Σ_j b_j W_j,   λ_1 = Λ_s               (4)

``Q_1 = q_0`` (IIIA's first row is zero, H1). The constraint is imposed at ``p̃_i`` rather
than at ``P_i`` because IIIB's last column is zero (H1'), which would make
``D_pφ (Â ⊗ I) D_λg`` singular. Since ``a_sj = b_j`` (H3), ``φ(t_1, q_1, p_1) = 0`` holds at
every step point to the accuracy of the stage solve. The step's end point is summed as
``q_0 + h Σ_j b_j V_j`` (equal to ``Q_s`` by H3), with compensation for its rounding
(:func:`step_values`).

The unknowns are ``x = (Q_2..Q_s, P_1..P_s, Z_2..Z_s)`` with ``Z_j = h Λ_j`` (λ enters every
row multiplied by h; this keeps the Jacobian O(1) as h → 0): ``(2s-1) n + (s-1) m`` scalars,
laid out stage-major in :class:`Layout`. Everything here is a pure module-level function of
explicit arguments: the problem and the coefficients are static (hashable, baked into the
trace), the numbers are in :class:`StageParams`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from ._linalg import value_and_jacobian
from ._problem import vector_field
from ._tableau import LobattoPair, lagrange_basis

__all__ = [
    "Layout",
    "StageParams",
    "Stages",
    "assemble_jacobian",
    "constant_stages",
    "extrapolation_gain",
    "forward_differences",
    "predict_stages",
    "stage_jacobian",
    "stage_jacobian_autodiff",
    "stage_jacobian_differences",
    "stage_residual",
    "stage_values",
    "step_values",
    "tableau_product",
]

#: Extrapolating the previous step's stage polynomial amplifies its values by the Lebesgue-type
#: constant max_i Σ_j |l_j(1 + c_i)|; beyond this bound the constant guess is used instead.
MAX_EXTRAPOLATION_GAIN = 1e4


class StageParams(NamedTuple):
    """The numbers one step's stage system depends on (a pytree; everything traced)."""

    t0: jax.Array
    h: jax.Array
    q0: jax.Array  # (n,)
    p0: jax.Array  # (n,)
    lam1: jax.Array  # (m,) Λ_1, the start multiplier
    args: Any


class Stages(NamedTuple):
    """Stage values and slopes of a solved (or guessed) step."""

    Q: jax.Array  # (s, n)
    P: jax.Array  # (s, n)
    Lam: jax.Array  # (s, m)
    V: jax.Array  # (s, n) f at the stages
    W: jax.Array  # (s, n) g at the stages


@dataclass(frozen=True)
class Layout:
    """Where ``Q_2..Q_s``, ``P_1..P_s`` and ``Z_2..Z_s`` sit in the unknown vector x (static)."""

    s: int
    n: int
    m: int

    @property
    def size(self) -> int:
        return (2 * self.s - 1) * self.n + (self.s - 1) * self.m

    def unpack(self, x, params: StageParams):
        """``x -> (Q, P, Z)`` with ``Q_1 = q_0`` and ``Z_1 = h Λ_1`` filled in."""
        s, n, m = self.s, self.n, self.m
        i1 = (s - 1) * n
        i2 = i1 + s * n
        Q = jnp.concatenate([params.q0[None], x[:i1].reshape(s - 1, n)])
        P = x[i1:i2].reshape(s, n)
        Z = jnp.concatenate([(params.h * params.lam1)[None], x[i2:].reshape(s - 1, m)])
        return Q, P, Z

    @staticmethod
    def pack(Q, P, Z):
        """``(Q, P, Z) -> x`` (the first rows of Q and Z are not unknowns)."""
        return jnp.concatenate([Q[1:].ravel(), P.ravel(), Z[1:].ravel()])


def _coefficients(pair: LobattoPair, dtype):
    return (jnp.asarray(pair.a, dtype), jnp.asarray(pair.a_hat, dtype), jnp.asarray(pair.c, dtype))


def tableau_product(coef: np.ndarray, x):
    """``coef @ x`` for a constant coefficient matrix ``coef`` (k, s) and stage values x (s, ...).

    Written as a broadcast product summed over the stages, ``Σ_j coef[:, j] x[j]``: XLA fuses
    the product and the sum with the surrounding arithmetic into one loop whose code does not
    grow with s. A ``dot`` would be a kernel of its own (on CPU the per-kernel overhead of a
    5×5 product is far larger than its arithmetic: +50 % per step, measured); a sum written
    out term by term fuses too, but its code grows like s², and with it XLA's compile time
    (the error-controlled attempt on the sleigh, s = 2 → 8: +67 % written out, +15 % as a
    sum, at most +35 % at s = 6; ``benchmarks/program_size.py``, RESULTS.md 2026-11-27 22:45).
    """
    c = jnp.asarray(coef, x.dtype).reshape(coef.shape + (1,) * (x.ndim - 1))
    return jnp.sum(c * x[None], axis=1)


def _fields(problem, t, Q, P, Lam, args):
    """``V_j = f(t_j, Q_j, P_j)``, ``W_j = g(t_j, Q_j, P_j, Λ_j)`` for all stages at once."""
    return jax.vmap(lambda tj, q, p, lam: vector_field(problem, tj, q, p, lam, args))(t, Q, P, Lam)


def stage_values(problem, pair: LobattoPair, layout: Layout, x, params: StageParams) -> Stages:
    """The stages ``(Q, P, Λ)`` encoded in x and their slopes ``(V, W)``."""
    Q, P, Z = layout.unpack(x, params)
    lam = Z / params.h
    t = params.t0 + jnp.asarray(pair.c, x.dtype) * params.h
    V, W = _fields(problem, t, Q, P, lam, params.args)
    return Stages(Q, P, lam, V, W)


def _rows(pair: LobattoPair, params: StageParams, st: Stages, phi_values):
    """Rows (1), (2) and (3), given the stage slopes and ``φ(t_i, Q_i, p̃_i)``."""
    h = params.h
    r_q = st.Q[1:] - params.q0 - h * tableau_product(pair.a[1:], st.V)  # (1)
    r_p = st.P - params.p0 - h * tableau_product(pair.a_hat, st.W)  # (2)
    return jnp.concatenate([r_q.ravel(), r_p.ravel(), phi_values.ravel()])


def _p_tilde(pair: LobattoPair, params: StageParams, W):
    """``p̃_i = p_0 + h Σ_j a_ij W_j`` for i = 2..s (the IIIA momenta of row (3))."""
    return params.p0 + params.h * tableau_product(pair.a[1:], W)


def stage_residual(problem, pair: LobattoPair, layout: Layout, x, params: StageParams):
    """The residual of rows (1)-(3) at x: one fused evaluation of f, g (all stages) and φ."""
    st = stage_values(problem, pair, layout, x, params)
    t = params.t0 + jnp.asarray(pair.c[1:], x.dtype) * params.h
    phi = jax.vmap(lambda ti, q, p: problem.phi(ti, q, p, params.args))(t, st.Q[1:], _p_tilde(pair, params, st.W))
    return _rows(pair, params, st, phi)


def stage_jacobian(problem, pair: LobattoPair, layout: Layout, x, params: StageParams, derivative=value_and_jacobian):
    """``(residual, ∂residual/∂x)`` at x, assembled from per-stage blocks.

    One pass per stage for ``(f, g)`` in ``(q, p, λ)`` (``2n + m`` directions) and one for φ in
    ``(q, p̃)`` (``2n``), instead of the ``(2s-1) n + (s-1) m`` tangents (each running all s
    stages) of ``jax.jacfwd`` of the whole residual; :func:`assemble_jacobian` places the blocks.
    ``derivative(fun, z) -> (fun(z), ∂fun/∂z)`` differentiates a block: forward-mode autodiff
    (exact, the default) or :func:`forward_differences`.
    """
    Q, P, Z = layout.unpack(x, params)
    h, args = params.h, params.args
    n = Q.shape[1]
    lam = Z / h
    c = jnp.asarray(pair.c, x.dtype)
    t = params.t0 + c * h

    def field_blocks(tj, q, p, lj):
        def field(z):
            return jnp.concatenate(vector_field(problem, tj, z[:n], z[n : 2 * n], z[2 * n :], args))

        vw, d = derivative(field, jnp.concatenate([q, p, lj]))
        blocks = d[:n, :n], d[:n, n : 2 * n], d[n:, :n], d[n:, n : 2 * n], d[n:, 2 * n :]
        return blocks, (vw[:n], vw[n:])

    (fq, fp, gq, gp, gl), (V, W) = jax.vmap(field_blocks)(t, Q, P, lam)

    def constraint_blocks(ti, q, p):
        r, d = derivative(lambda z: problem.phi(ti, z[:n], z[n:], args), jnp.concatenate([q, p]))
        return (d[:, :n], d[:, n:]), r

    (phi_q, phi_p), phi = jax.vmap(constraint_blocks)(t[1:], Q[1:], _p_tilde(pair, params, W))
    st = Stages(Q, P, lam, V, W)
    jac = assemble_jacobian(pair, h, fq, fp, gq, gp, gl, phi_q, phi_p)
    return _rows(pair, params, st, phi), jac


def forward_differences(fun, z):
    r"""``(fun(z), ∂fun/∂z)`` by forward differences, for Newton's matrix.

    Column j is ``(fun(z + δ_j e_j) − fun(z)) / δ_j`` with ``δ_j = √ε max(1, |z_j|)``, taken as
    the difference that ``z + δ_j e_j`` actually represents; all ``len(z) + 1`` points in one
    batched evaluation of ``fun``. Its error is ``O(δ_j |fun''|)`` from the truncation and
    ``O(ε |fun| / δ_j)`` from rounding: about √ε (1.5e-8) for quantities of unit scale. That
    changes how fast simplified Newton contracts, not the root it converges to (the residual
    alone decides that). The program holds ``fun`` once, batched, where forward-mode autodiff
    holds its derivative code too (for a g that solves with a mass matrix, the derivatives of
    the elimination): less for XLA to compile, and on a CPU a cheaper refresh.
    """
    sqrt_eps = jnp.sqrt(jnp.finfo(z.dtype).eps)
    delta = (z + sqrt_eps * jnp.maximum(1.0, jnp.abs(z))) - z
    points = jnp.concatenate([z[None], z[None] + jnp.diag(delta)])
    values = jax.vmap(fun)(points)
    return values[0], ((values[1:] - values[0]) / delta[:, None]).T


def stage_jacobian_differences(problem, pair: LobattoPair, layout: Layout, x, params: StageParams):
    """:func:`stage_jacobian` with blocks by :func:`forward_differences` (the option
    ``jacobian="differences"``)."""
    return stage_jacobian(problem, pair, layout, x, params, derivative=forward_differences)


def stage_jacobian_autodiff(problem, pair: LobattoPair, layout: Layout, x, params: StageParams):
    """``(residual, ∂residual/∂x)`` by ``jax.jacfwd`` of the whole residual (the reference for
    :func:`stage_jacobian`, and the option ``jacobian="autodiff"``)."""

    def both(y):
        r = stage_residual(problem, pair, layout, y, params)
        return r, r

    jac, r = jax.jacfwd(both, has_aux=True)(x)
    return r, jac


def assemble_jacobian(pair: LobattoPair, h, fq, fp, gq, gp, gl, phi_q, phi_p):
    r"""The Jacobian of rows (1)-(3) with respect to ``(Q_2..Q_s, P_1..P_s, Z_2..Z_s)``.

    With ``Z_k = h Λ_k``, per-stage blocks ``F_x = ∂f/∂x``, ``G_x = ∂g/∂x`` at stage k and
    ``Φ_x = ∂φ/∂x`` at ``(Q_i, p̃_i)``:

    * (1) ``r_q,i``: ``δ_ik I - h a_ik F_q``, ``-h a_ik F_p``, 0;
    * (2) ``r_p,i``: ``-h â_ik G_q``, ``δ_ik I - h â_ik G_p``, ``-â_ik G_λ``;
    * (3) ``r_φ,i``: ``δ_ik Φ_q + h a_ik Φ_p G_q``, ``h a_ik Φ_p G_p``, ``a_ik Φ_p G_λ``.
    """
    s, n = fq.shape[0], fq.shape[1]
    dtype = fq.dtype
    a, a_hat, _ = _coefficients(pair, dtype)
    eye_n = jnp.eye(n, dtype=dtype)
    eye_s = jnp.eye(s, dtype=dtype)
    a1 = a[1:]

    def kron(coef, blocks):  # (rows, cols) coefficients times per-column blocks (cols, x, y)
        return jnp.einsum("ik,kab->iakb", coef, blocks)

    def flat(block):
        r, x, c, y = block.shape
        return block.reshape(r * x, c * y)

    def through_phi(blocks):  # Φ_p,i @ block_k for rows i = 2..s, columns k
        return jnp.einsum("ica,kab->ickb", phi_p, blocks)

    m = gl.shape[2]
    rq_q = jnp.einsum("ik,ab->iakb", eye_s[1:, 1:], eye_n) - h * kron(a1[:, 1:], fq[1:])
    rq_p = -h * kron(a1, fp)
    rq_z = jnp.zeros((s - 1, n, s - 1, m), dtype)
    rp_q = -h * kron(a_hat[:, 1:], gq[1:])
    rp_p = jnp.einsum("ik,ab->iakb", eye_s, eye_n) - h * kron(a_hat, gp)
    rp_z = -kron(a_hat[:, 1:], gl[1:])
    rf_q = jnp.einsum("ik,icb->ickb", eye_s[1:, 1:], phi_q) + h * a1[:, None, 1:, None] * through_phi(gq[1:])
    rf_p = h * a1[:, None, :, None] * through_phi(gp)
    rf_z = a1[:, None, 1:, None] * through_phi(gl[1:])
    rows = [[rq_q, rq_p, rq_z], [rp_q, rp_p, rp_z], [rf_q, rf_p, rf_z]]
    return jnp.concatenate([jnp.concatenate([flat(b) for b in row], axis=1) for row in rows], axis=0)


def step_values(pair: LobattoPair, params: StageParams, st: Stages, compensation):
    r"""Row (4), summed with compensation: ``q_1 = q_0 + h Σ_j b_j V_j`` (``= Q_s``, H3),
    ``p_1 = p_0 + h Σ_j b_j W_j``, ``λ_1 = Λ_s``.

    The increments are added to ``(q_0, p_0) + compensation``, the part of the state that its
    floating-point values could not hold, and what this sum cannot hold is returned as the next
    ``compensation`` (compensated summation, Hairer, Lubich & Wanner, *Geometric Numerical
    Integration*, VIII.5; Knuth's TwoSum, exact in round-to-nearest)::

        y_1 = fl(y_0 + δ),   δ = (h Σ_j b_j (V_j, W_j)) + compensation,
        compensation_1 = (y_0 + δ) − y_1     (exactly)

    Without it every step rounds ``y_0 + δ`` to the spacing of y, and with steps of nearly
    constant size the rounding errors have a constant sign: a knife edge whose angle grows to 700
    over T = 1000 ended 4.5e-11 off in it at s = 6 (1,667 steps of h ≈ 0.6), above rtol = 1e-12.
    ``Q_s`` solves the same sum to Newton's tolerance; the explicit sum is what the rounding
    analysis covers. Returns ``q_1, p_1, λ_1, compensation_1``.
    """
    n = params.q0.shape[-1]
    b = pair.b[None]
    delta = params.h * jnp.concatenate([tableau_product(b, st.V)[0], tableau_product(b, st.W)[0]]) + compensation
    y0 = jnp.concatenate([params.q0, params.p0])
    y1 = y0 + delta
    # TwoSum: what y1 lost of y0 and of delta, each recovered exactly
    delta_kept = y1 - y0
    y0_kept = y1 - delta_kept
    lost = (y0 - y0_kept) + (delta - delta_kept)
    return y1[:n], y1[n:], st.Lam[-1], lost


def extrapolation_gain(pair: LobattoPair) -> float:
    """``max_i Σ_j |l_j(1 + c_i)|``: how much extrapolating a stage polynomial by one step of
    the same size amplifies its values (grows quickly with s)."""
    return float(np.max(np.sum(np.abs(lagrange_basis(pair.c, 1.0 + pair.c)), axis=1)))


def predict_stages(pair: LobattoPair, layout: Layout, params: StageParams, slopes, correction, h_prev):
    r"""Newton's starting point from the previous step's stage polynomials, evaluated at *times*.

    The previous step (size ``h_prev``, ending at ``t_0``) had slopes ``V, W`` and multipliers
    ``Λ`` at ``t_0 - h_prev + c_j h_prev``; their interpolating polynomials are evaluated at
    the new stage times ``t_0 + c_i h``, i.e. at ``τ_i = 1 + c_i h / h_prev`` in the previous
    step's scaled time, corrected by ``correction`` (what this extrapolation missed at the
    previous step: the IIIB stages deviate from a smooth polynomial by O(h^(s-1)) in a pattern
    that varies smoothly from step to step), and the stages rebuilt from the *new* start:
    ``Q = q_0 + h A V``, ``P = p_0 + h Â W``.

    Returns ``(x0, plain)``: the packed guess and the uncorrected extrapolation (whose error
    becomes the next correction).
    """
    tau = 1.0 + jnp.asarray(pair.c, params.q0.dtype) * (params.h / h_prev)
    basis = lagrange_basis(pair.c, tau)
    plain = tuple(jnp.sum(basis[:, :, None] * v[None], axis=1) for v in slopes)
    V, W, Lam = (x + d for x, d in zip(plain, correction))
    Q = params.q0 + params.h * tableau_product(pair.a, V)
    x0 = layout.pack(Q, params.p0 + params.h * tableau_product(pair.a_hat, W), params.h * Lam)
    return x0, plain


def constant_stages(layout: Layout, params: StageParams):
    """The trivial guess: every stage equal to ``(q_0, p_0, Λ_1)``."""
    s, n, m = layout.s, layout.n, layout.m
    return layout.pack(
        jnp.broadcast_to(params.q0, (s, n)),
        jnp.broadcast_to(params.p0, (s, n)),
        jnp.broadcast_to(params.h * params.lam1, (s, m)),
    )
