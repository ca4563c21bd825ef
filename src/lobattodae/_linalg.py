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
    """Solve ``a x = b`` for a symmetric positive definite ``a``: for mass matrices in the
    problem functions.

    For n ≤ 8 the elimination is written out column by column (Gauss-Jordan without pivoting,
    a handful of fusible operations per column; the pivots of a symmetric positive definite
    matrix are positive), which XLA fuses with the surrounding arithmetic; ``jnp.linalg.solve``
    is a LAPACK call per system, whose overhead dominates a small system on CPU (a 7×7 mass
    matrix in ``g``, the test set's slider crank: 16-22 % of the run). Larger systems use
    LAPACK's Cholesky. Pure JAX: works under ``jit``, ``vmap`` and ``grad``. It does not check
    that ``a`` is symmetric positive definite; for another matrix the result is wrong or not
    finite (no pivoting).

    Parameters
    ----------
    a : jax.Array, shape (n, n)
        Symmetric positive definite.
    b : jax.Array, shape (n,)
        The right-hand side.

    Returns
    -------
    jax.Array, shape (n,)
        ``x`` with ``a x = b``.
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
