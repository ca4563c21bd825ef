"""Dense solves for the tiny systems inside the step (mass matrices, m×m constraint blocks).

XLA:CPU runs ``jnp.linalg.solve`` as a LAPACK call per (batched) system: for a 5×5 mass
matrix that call, not the arithmetic, dominates a stage evaluation. Up to
:data:`UNROLL_MAX` unknowns the elimination is written out column by column instead, which
XLA fuses with the surrounding arithmetic (and differentiates and vmaps like any other
expression); the measurements behind this choice are in ``benchmarks/RESULTS.md``.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

__all__ = ["spd_solve", "small_solve", "value_and_jacobian", "UNROLL_MAX"]

#: Largest system solved by the unrolled code; larger ones go to LAPACK.
UNROLL_MAX = 8


def spd_solve(a: jax.Array, b: jax.Array) -> jax.Array:
    """Solve ``a x = b`` for symmetric positive definite ``a`` (n×n) and ``b`` (n,).

    For ``n ≤ UNROLL_MAX``: Gauss-Jordan elimination without pivoting, unrolled over the
    columns with whole-matrix updates (a handful of fusible operations per column; the pivots
    of an SPD matrix are positive, so no pivoting is needed). This compiles to a smaller
    program than element-wise Cholesky and runs faster inside the stage Jacobian. Larger
    systems use LAPACK's Cholesky.
    """
    n = a.shape[-1]
    if n > UNROLL_MAX:
        return jax.scipy.linalg.cho_solve(jax.scipy.linalg.cho_factor(a, lower=True), b)
    aug = jnp.concatenate([a, b[:, None]], axis=1)
    for j in range(n):
        row = aug[j] / aug[j, j]
        aug = (aug - jnp.outer(aug[:, j], row)).at[j].set(row)
    return aug[:, n]


def small_solve(a: jax.Array, b: jax.Array) -> jax.Array:
    """Solve ``a x = b`` for a general nonsingular ``a``: closed form for 1×1 and 2×2
    (the m×m constraint blocks of the examples), LAPACK (partial pivoting) otherwise."""
    m = a.shape[-1]
    if m == 1:
        return b / a[0, 0]
    if m == 2:
        det = a[0, 0] * a[1, 1] - a[0, 1] * a[1, 0]
        return jnp.stack([a[1, 1] * b[0] - a[0, 1] * b[1], a[0, 0] * b[1] - a[1, 0] * b[0]]) / det
    return jnp.linalg.solve(a, b)


def value_and_jacobian(fn, x):
    """``(fn(x), ∂fn/∂x)`` in one forward-mode pass (as many tangents as x has entries: the
    small constraint and multiplier systems)."""

    def both(xx):
        r = fn(xx)
        return r, r

    jac, value = jax.jacfwd(both, has_aux=True)(x)
    return value, jac
