"""A small jit-able Newton solver with an optional reused (simplified-Newton) Jacobian.

The iteration never raises inside a trace: it returns a :class:`~lobattodae._results.Result`
code together with the iterate, so that callers decide whether to throw.
"""

from __future__ import annotations

from typing import Callable, NamedTuple

import jax
import jax.numpy as jnp
import jax.scipy.linalg as jsl

from ._results import Result

__all__ = ["JacobianCache", "NewtonInfo", "newton_solve", "empty_jacobian_cache"]

# Convergence is declared when the scaled increment |dx_i| / (tol (1 + |x_i|)) is <= 1,
# or when the Hairer-Wanner estimate theta/(1-theta) * |dx| of the remaining error is.
# Once the contraction rate theta exceeds THETA_STAGNATION the iterates are dominated by
# round-off; they are accepted when the increment is already below
# STAGNATION_LEVEL * tol (relative), and reported as divergence otherwise.
THETA_REFRESH = 0.05
THETA_STAGNATION = 0.9
STAGNATION_LEVEL = 1e3
THETA_DIVERGED = 2.0
#: With a reused Jacobian the rate estimate is less reliable: demand a 10x smaller predicted error.
KAPPA_STALE = 0.1


class JacobianCache(NamedTuple):
    """LU factors of the stage Jacobian, kept between Newton solves (simplified Newton)."""

    lu: jax.Array
    piv: jax.Array
    valid: jax.Array  # bool scalar


class NewtonInfo(NamedTuple):
    """Per-solve diagnostics."""

    result: jax.Array  # int32 Result code
    iterations: jax.Array  # int32
    residual_norm: jax.Array  # max-norm of the last evaluated residual
    n_jacobians: jax.Array  # int32, Jacobian evaluations + LU factorisations


def empty_jacobian_cache(size: int, dtype) -> JacobianCache:
    return JacobianCache(
        lu=jnp.zeros((size, size), dtype),
        piv=jnp.zeros((size,), jnp.int32),
        valid=jnp.asarray(False),
    )


class _Carry(NamedTuple):
    x: jax.Array
    k: jax.Array
    nrm_prev: jax.Array
    theta_prev: jax.Array
    done: jax.Array
    result: jax.Array
    res_norm: jax.Array
    cache: JacobianCache
    fresh: jax.Array  # the cached Jacobian was evaluated during this solve
    refresh: jax.Array  # evaluate a new Jacobian at the next iteration
    n_jac: jax.Array


def newton_solve(
    residual: Callable[[jax.Array], jax.Array],
    x0: jax.Array,
    cache: JacobianCache,
    *,
    tol: float,
    max_iterations: int,
    reuse_jacobian: bool,
    jacobian: Callable[[jax.Array], tuple[jax.Array, jax.Array]] | None = None,
) -> tuple[jax.Array, NewtonInfo, JacobianCache]:
    """Solve ``residual(x) = 0`` starting from ``x0``.

    With ``reuse_jacobian=False`` this is Newton's method with a fresh autodiff Jacobian at
    every iterate. With ``reuse_jacobian=True`` the LU factors in ``cache`` are reused
    (across calls too) as long as the iteration contracts with rate below
    ``THETA_REFRESH``; otherwise the Jacobian is re-evaluated at the current iterate.
    ``jacobian(x) -> (residual(x), J(x))`` replaces the forward-mode Jacobian of ``residual``
    when given (e.g. one assembled from structured blocks).
    """
    dtype = x0.dtype

    def fresh_jacobian(x):
        if jacobian is not None:
            r, jac = jacobian(x)
        else:

            def with_aux(y):
                r = residual(y)
                return r, r

            jac, r = jax.jacfwd(with_aux, has_aux=True)(x)
        lu, piv = jsl.lu_factor(jac)
        return r, JacobianCache(lu, piv.astype(jnp.int32), jnp.asarray(True))

    def old_jacobian(x, cache):
        return residual(x), cache

    def body(c: _Carry) -> _Carry:
        need = jnp.logical_or(c.refresh, jnp.logical_not(c.cache.valid))
        if not reuse_jacobian:
            need = jnp.asarray(True)
            r, cache = fresh_jacobian(c.x)
        else:
            r, cache = jax.lax.cond(need, fresh_jacobian, lambda x: old_jacobian(x, c.cache), c.x)
        dx = jsl.lu_solve((cache.lu, cache.piv), r)
        x = c.x - dx
        scale = tol * (1.0 + jnp.abs(x))
        nrm = jnp.max(jnp.abs(dx) / scale)
        first = c.k == 0
        theta = jnp.where(first, 0.0, nrm / jnp.where(c.nrm_prev > 0, c.nrm_prev, 1.0))
        fresh = jnp.logical_or(c.fresh, need)
        finite = jnp.logical_and(jnp.all(jnp.isfinite(x)), jnp.all(jnp.isfinite(r)))
        stale = jnp.logical_and(reuse_jacobian, ~need)
        # Hairer-Wanner: the remaining error is about theta/(1-theta) |dx|. With a stale
        # Jacobian a single ratio of increments can grossly underestimate the rate, so there
        # the larger of the last two ratios is used (and at least two are required).
        have_two = jnp.logical_and(c.k >= 2, ~c.refresh)
        theta_est = jnp.where(stale, jnp.maximum(theta, c.theta_prev), theta)
        rate_ok = jnp.logical_and(~first, jnp.logical_or(~stale, have_two))
        kappa = jnp.where(stale, KAPPA_STALE, 1.0)
        converged = jnp.logical_or(
            nrm <= 1.0,
            jnp.logical_and(rate_ok, jnp.logical_and(theta_est < 0.5, theta_est / (1.0 - theta_est) * nrm <= kappa)),
        )
        slow = jnp.logical_and(~first, theta >= THETA_STAGNATION)
        # With a stale Jacobian, slow contraction only asks for a fresh one.
        refresh = jnp.logical_and(stale, jnp.logical_and(~first, theta >= THETA_REFRESH))
        roundoff = jnp.logical_and(slow, jnp.logical_and(~stale, nrm <= STAGNATION_LEVEL))
        diverged = jnp.logical_and(~stale, jnp.logical_and(~first, theta >= THETA_DIVERGED))
        diverged = jnp.logical_and(diverged, ~roundoff)
        k = c.k + 1
        ok = jnp.logical_or(converged, roundoff)
        out_of_iters = jnp.logical_and(k >= max_iterations, ~ok)
        result = jnp.where(
            ~finite,
            Result.NONFINITE,
            jnp.where(
                ok,
                Result.SUCCESSFUL,
                jnp.where(diverged, Result.DIVERGED, jnp.where(out_of_iters, Result.MAX_ITERATIONS, -1)),
            ),
        ).astype(jnp.int32)
        done = result >= 0
        return _Carry(
            x=jnp.where(finite, x, c.x),
            k=k,
            nrm_prev=nrm,
            theta_prev=jnp.where(need, 1.0, theta),
            done=done,
            result=result,
            res_norm=jnp.max(jnp.abs(r)),
            cache=cache,
            fresh=fresh,
            refresh=refresh,
            n_jac=c.n_jac + need.astype(jnp.int32),
        )

    init = _Carry(
        x=x0,
        k=jnp.asarray(0, jnp.int32),
        nrm_prev=jnp.asarray(0.0, dtype),
        theta_prev=jnp.asarray(1.0, dtype),
        done=jnp.asarray(False),
        result=jnp.asarray(-1, jnp.int32),
        res_norm=jnp.asarray(jnp.inf, dtype),
        cache=cache,
        fresh=jnp.asarray(False),
        refresh=jnp.asarray(False),
        n_jac=jnp.asarray(0, jnp.int32),
    )
    out = jax.lax.while_loop(lambda c: ~c.done, body, init)
    # A failed solve leaves no reusable Jacobian behind.
    ok = out.result == Result.SUCCESSFUL
    cache = out.cache._replace(valid=jnp.logical_and(out.cache.valid, ok))
    info = NewtonInfo(out.result, out.k, out.res_norm, out.n_jac)
    return out.x, info, cache
