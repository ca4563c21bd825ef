"""A small jit-able (simplified) Newton solver for the stage equations.

``newton_solve(fn, jac_fn, x0, params, cache, options)`` solves ``fn(x, params) = 0``. It is
split into :func:`newton_init`, :func:`newton_step` and :func:`newton_done`, with the
stopping rules as named predicates. It never raises inside a trace: it returns a
:class:`~lobattodae._results.Result` code with the iterate, and the caller decides.

Simplified Newton: the inverse of the Jacobian (computed through an LU factorisation) is
kept in a :class:`JacobianCache` across iterations *and* across calls, and refreshed only
when the iteration contracts slowly. Each iteration is then one residual evaluation and one
matrix-vector product; the converged solution is the same to the tolerance, since only the
residual decides where the iteration stops.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import Any, Callable, NamedTuple

import jax
import jax.numpy as jnp

from ._results import Result

__all__ = ["JacobianCache", "NewtonInfo", "NewtonOptions", "empty_jacobian_cache", "implicit_root", "newton_solve"]

#: A reused Jacobian is refreshed (see ``needs_refresh``) when, above round-off, it contracts
#: slower than THETA_REFRESH or its rate predicts more than REFRESH_PREDICTED further
#: iterations, and in any case after REFRESH_ITERATIONS iterations. A fresh Jacobian and its
#: inverse cost 10-20 iterations on CPU (falling disk, s = 5: 60 µs against 3 µs). Measured
#: with (8, 12) against (4, 8) (``benchmarks/newton_refresh.py``): large steps, where the
#: Jacobian drifts within a step or two, gain (falling disk s = 5 at h = 0.25: 1.19x, 0.56
#: instead of 1.0 Jacobians per step; s = 3 at h = 0.05: 1.13x; adaptive sleigh: 1.10x);
#: small steps that reuse one Jacobian for many steps lose a little (falling disk s = 5 at
#: h = 0.05: 0.91x; particle at h = 0.0024: 0.92x).
THETA_REFRESH = 0.5
REFRESH_PREDICTED = 8.0
REFRESH_ITERATIONS = 12
#: A contraction rate above THETA_STAGNATION with an increment below STAGNATION_LEVEL·tol means,
#: with a fresh Jacobian, that the iterates are dominated by round-off: they are accepted. A
#: reused Jacobian contracts slowly for its own reasons: it must get below ROUNDOFF_LEVEL·tol,
#: or below FLOOR_FACTOR times the level at which the last solve with a fresh Jacobian ended
#: (the problem's own round-off, measured: where momenta or multipliers are large, as in models
#: in physical units, it lies well above ROUNDOFF_LEVEL·tol; Whipple bicycle: 20-40), never
#: above STAGNATION_LEVEL·tol.
THETA_STAGNATION = 0.9
STAGNATION_LEVEL = 1e3
FLOOR_FACTOR = 4.0
#: Scaled increments up to this size are round-off noise (their ratios say nothing about the
#: contraction of the iteration).
ROUNDOFF_LEVEL = 10.0
#: With a fresh Jacobian, increments growing by this factor mean divergence.
THETA_DIVERGED = 2.0
#: Iterations with a reused Jacobian before the stopping rules are first evaluated.
FAST_ITERATIONS = 3
#: With a reused Jacobian the rate estimate is less reliable: demand a 10x smaller predicted error.
KAPPA_STALE = 0.1


@dataclass(frozen=True)
class NewtonOptions:
    """Tolerance ``|Δx_i| ≤ tol (1 + |x_i|)``, iteration limit, and whether to reuse the
    Jacobian across iterations and calls (simplified Newton)."""

    tol: float = 1e-14
    max_iterations: int = 20
    reuse_jacobian: bool = True

    def __post_init__(self):
        if isinstance(self.tol, bool) or not (isinstance(self.tol, (int, float)) and 0 < self.tol < 1):
            raise ValueError(f"tol must be a float in (0, 1); got tol={self.tol!r}.")
        if isinstance(self.max_iterations, bool) or not (isinstance(self.max_iterations, int) and self.max_iterations >= 1):
            raise ValueError(f"max_iterations must be a positive integer; got {self.max_iterations!r}.")
        if not isinstance(self.reuse_jacobian, bool):
            raise ValueError(f"reuse_jacobian must be True or False; got {self.reuse_jacobian!r}.")


class JacobianCache(NamedTuple):
    """The inverse of a stage Jacobian, kept between Newton solves (simplified Newton).

    ``inverse`` holds the N × N inverse flattened row by row, shape (N²,). A matrix in the
    loop state would be laid out column-major by XLA (as LAPACK's triangular solves return
    it) while XLA:CPU's product wants it row-major: it copied the matrix at the entry of each
    Newton loop, two N² copies per step. A vector has one layout; the one transposing copy
    is made where the inverse is computed."""

    inverse: jax.Array  # (N * N,), row-major
    valid: jax.Array  # bool scalar
    floor: jax.Array  # the scaled increment at which the last solve ending with a fresh Jacobian stopped


class NewtonInfo(NamedTuple):
    """Per-solve diagnostics."""

    result: jax.Array  # int32 Result code
    iterations: jax.Array  # int32
    residual_norm: jax.Array  # max-norm of the last evaluated residual
    n_jacobians: jax.Array  # int32, Jacobian evaluations (each with one factorisation)


class NewtonState(NamedTuple):
    x: jax.Array
    k: jax.Array  # iterations done
    nrm_prev: jax.Array  # scaled norm of the last increment
    nrm_best: jax.Array  # the smallest scaled increment of this solve so far
    theta_prev: jax.Array  # the contraction rate before that
    result: jax.Array  # -1 while running, else a Result code
    res_norm: jax.Array
    cache: JacobianCache
    refresh: jax.Array  # evaluate a fresh Jacobian before the next iteration
    stale: jax.Array  # the last iteration used a Jacobian from an earlier iterate
    n_jac: jax.Array


def empty_jacobian_cache(size: int, dtype) -> JacobianCache:
    return JacobianCache(inverse=jnp.zeros((size * size,), dtype), valid=jnp.asarray(False),
                         floor=jnp.asarray(0.0, dtype))


def newton_init(x0, cache: JacobianCache) -> NewtonState:
    dtype = x0.dtype
    return NewtonState(
        x=x0,
        k=jnp.asarray(0, jnp.int32),
        nrm_prev=jnp.asarray(0.0, dtype),
        nrm_best=jnp.asarray(jnp.inf, dtype),
        theta_prev=jnp.asarray(1.0, dtype),
        result=jnp.asarray(-1, jnp.int32),
        res_norm=jnp.asarray(jnp.inf, dtype),
        cache=cache,
        refresh=jnp.logical_not(cache.valid),
        stale=jnp.asarray(False),
        n_jac=jnp.asarray(0, jnp.int32),
    )


# -- stopping rules -------------------------------------------------------------------------
def converged(nrm, theta_est, rate_known, stale):
    """Increment below the tolerance, or the Hairer-Wanner estimate ``θ/(1-θ)·|Δx|`` of the
    remaining error is (10x stricter with a reused Jacobian, whose rate estimate is rougher)."""
    kappa = jnp.where(stale, KAPPA_STALE, 1.0)
    rate_test = jnp.logical_and(rate_known, jnp.logical_and(theta_est < 0.5, theta_est / (1.0 - theta_est) * nrm <= kappa))
    return jnp.logical_or(nrm <= 1.0, rate_test)


def stale_roundoff_level(floor):
    """Up to which scaled increment a reused Jacobian's stagnation counts as round-off:
    ROUNDOFF_LEVEL, or FLOOR_FACTOR times ``floor`` (where the last solve with a fresh Jacobian
    stopped), at most STAGNATION_LEVEL."""
    return jnp.clip(FLOOR_FACTOR * floor, ROUNDOFF_LEVEL, STAGNATION_LEVEL)


def stagnated_at_roundoff(theta, nrm, first, stale, floor):
    """The iteration no longer contracts (``theta``: the increment over the smallest one of the
    solve so far, so that noise that makes the increments go up and down counts), but the
    increment is already within STAGNATION_LEVEL·tol (with a reused Jacobian, whose slow
    contraction is no evidence of round-off, within :func:`stale_roundoff_level`; above it the
    Jacobian is refreshed instead, see ``needs_refresh``): the iterates are dominated by round-off."""
    level = jnp.where(stale, stale_roundoff_level(floor), STAGNATION_LEVEL)
    return jnp.logical_and(~first, jnp.logical_and(theta >= THETA_STAGNATION, nrm <= level))


def diverged(theta, first, stale):
    """A fresh Jacobian makes the increments grow: the step is too large."""
    return jnp.logical_and(jnp.logical_and(~first, ~stale), theta >= THETA_DIVERGED)


def needs_refresh(theta, nrm, k, first, stale, floor):
    """A reused Jacobian is too poor: evaluate a fresh one at the current iterate.

    Above round-off (below :func:`stale_roundoff_level` the ratio of increments is noise): when it contracts slower than
    THETA_REFRESH, or when at its rate the increment would need more than REFRESH_PREDICTED
    further iterations to reach the tolerance (a fresh Jacobian costs about as much); and in
    any case after REFRESH_ITERATIONS iterations.
    """
    remaining = jnp.log(jnp.maximum(nrm, 1.0)) / -jnp.log(jnp.clip(theta, 1e-300, 0.999))
    above = nrm > stale_roundoff_level(floor)
    slow = jnp.logical_and(above, jnp.logical_or(theta >= THETA_REFRESH, remaining > REFRESH_PREDICTED))
    return jnp.logical_and(jnp.logical_and(stale, ~first), jnp.logical_or(slow, k >= REFRESH_ITERATIONS))


# -- one iteration ----------------------------------------------------------------------------
def fresh_jacobian(jac_fn, params, x) -> JacobianCache:
    """Evaluate the Jacobian at x and invert it (flattened, see :class:`JacobianCache`)."""
    _, jac = jac_fn(x, params)
    return JacobianCache(inverse(jac).ravel(), jnp.asarray(True), jnp.asarray(0.0, jac.dtype))


def inverse(a):
    """``a⁻¹`` from an LU factorisation with partial pivoting, ``P a = L U``, as
    ``U⁻¹ (L⁻¹ P)``: two triangular solves with many right-hand sides, which on CPU cost a
    fraction of ``jnp.linalg.inv`` for the small matrices of the stage system."""
    lu, _, perm = jax.lax.linalg.lu(a)
    p = jnp.eye(a.shape[0], dtype=a.dtype)[perm]
    lower = jax.lax.linalg.triangular_solve(lu, p, left_side=True, lower=True, unit_diagonal=True)
    return jax.lax.linalg.triangular_solve(lu, lower, left_side=True, lower=False)


def _increment(fn, params, x, inverse):
    """``x ← x - J⁻¹ fn(x)`` (``inverse``: J⁻¹ flattened row by row): returns the new
    iterate, the increment and the residual."""
    r = fn(x, params)
    dx = inverse.reshape(r.shape[0], r.shape[0]) @ r
    return x - dx, dx, r


def _scaled_norm(dx, x, tol):
    """``max_i |Δx_i| / (tol (1 + |x_i|))`` (NaN if anything is NaN)."""
    return jnp.max(jnp.abs(dx) / (tol * (1.0 + jnp.abs(x))))


def _judge(st: NewtonState, x, dx, r, options: NewtonOptions) -> NewtonState:
    """The stopping rules after the iteration ``st.x -> x`` (increment dx, residual r at st.x)."""
    nrm = _scaled_norm(dx, x, options.tol)
    res_norm = jnp.max(jnp.abs(r))
    first = st.k == 0
    theta = jnp.where(first, 0.0, nrm / jnp.where(st.nrm_prev > 0, st.nrm_prev, 1.0))
    # progress against the best increment so far: at round-off the increments go up and down with
    # the noise, and a ratio to the last one alone can stay below THETA_STAGNATION for many iterations
    best = jnp.minimum(st.nrm_best, st.nrm_prev)
    progress = jnp.where(first, 0.0, nrm / jnp.where(best > 0, best, 1.0))
    stale = ~st.refresh
    # With a stale Jacobian one ratio of increments can grossly underestimate the rate: use the
    # larger of the last two, and require two.
    rate_known = jnp.logical_and(~first, jnp.logical_or(~stale, jnp.logical_and(st.k >= 2, st.stale)))
    theta_est = jnp.where(stale, jnp.maximum(theta, st.theta_prev), theta)
    finite = jnp.logical_and(jnp.isfinite(nrm), jnp.isfinite(res_norm))
    floor = st.cache.floor
    ok = jnp.logical_or(converged(nrm, theta_est, rate_known, stale),
                        stagnated_at_roundoff(progress, nrm, first, stale, floor))
    k = st.k + 1
    result = jnp.select(
        [~finite, ok, diverged(theta, first, stale), k >= options.max_iterations],
        [Result.NONFINITE, Result.SUCCESSFUL, Result.DIVERGED, Result.MAX_ITERATIONS],
        -1,
    ).astype(jnp.int32)
    refresh = jnp.logical_or(needs_refresh(theta, nrm, k, first, stale, floor), not options.reuse_jacobian)
    return st._replace(
        x=jnp.where(finite, x, st.x),
        k=k,
        nrm_prev=nrm,
        nrm_best=jnp.where(first, nrm, jnp.minimum(best, nrm)),
        theta_prev=jnp.where(stale, theta, 1.0),
        result=result,
        res_norm=res_norm,
        refresh=jnp.logical_and(refresh, result < 0),
        stale=stale,
    )


def newton_step(fn, params, st: NewtonState, options: NewtonOptions) -> NewtonState:
    """One iteration with the Jacobian in ``st.cache``: residual, increment, stopping rules.

    ``st.refresh`` says that the cache was evaluated at this iterate (a Newton step proper);
    otherwise the Jacobian is from an earlier iterate or step (``stale``).
    """
    x, dx, r = _increment(fn, params, st.x, st.cache.inverse)
    return _judge(st, x, dx, r, options)


def fast_start(fn, params, st: NewtonState, options: NewtonOptions) -> NewtonState:
    """FAST_ITERATIONS iterations with the reused Jacobian, judged once at the end.

    On CPU the bookkeeping of an iteration (norms, rates, tests; a dozen tiny kernels) costs
    more than the iteration itself, and a step with a good reused Jacobian and predictor
    converges in about three iterations; so the first ones run back to back (one compiled
    copy of the residual, in a loop). Iterating past convergence only moves x by round-off.
    The rates that the stopping rules need come from the increments of the last iterations.
    """
    k = min(FAST_ITERATIONS, options.max_iterations)
    one = jnp.asarray(1.0, st.x.dtype)

    def iteration(_, carry):
        _, x, _, _, nrm, nrm_prev, _ = carry
        x_new, dx, r = _increment(fn, params, x, st.cache.inverse)
        return x, x_new, dx, r, _scaled_norm(dx, x_new, options.tol), nrm, nrm_prev

    zero = jnp.zeros_like(st.x)
    x_prev, x, dx, r, _, nrm_1, nrm_2 = jax.lax.fori_loop(0, k, iteration, (st.x, st.x, zero, zero, one, one, one))
    # nrm_1, nrm_2: the increments of the two iterations before the last (the stale-Jacobian
    # rate test uses the larger of the last two ratios)
    before = st._replace(
        x=x_prev, k=jnp.asarray(k - 1, jnp.int32), nrm_prev=nrm_1 if k >= 2 else st.nrm_prev,
        nrm_best=jnp.minimum(nrm_1, nrm_2) if k >= 3 else st.nrm_best,
        theta_prev=nrm_1 / jnp.where(nrm_2 > 0, nrm_2, 1.0) if k >= 3 else one,
        refresh=jnp.asarray(False), stale=jnp.asarray(k >= 2),
    )
    return _judge(before, x, dx, r, options)


def _refreshed(jac_fn, params, st: NewtonState) -> JacobianCache:
    """The cache, replaced by a fresh Jacobian at ``st.x`` where ``st.refresh`` asks for one.

    Unbatched a ``lax.cond``. Under ``vmap`` (``ensemble``) a cond on a batched predicate would
    become a select that evaluates and inverts the Jacobian of every trajectory at every epoch;
    the batching rule instead refreshes only the trajectories that ask: one after the other on a
    CPU (a loop over them, each a ``lax.cond``), and on other backends all at once when one asks,
    keeping the others' caches (a GPU pays for a batch what it pays for one)."""
    # The refresh as a function of explicit arguments only: what the Jacobian closes over (the
    # tableau, the problem's constants: values of the enclosing trace) becomes ``consts``, since
    # a custom_vmap function may not close over values that vmap batches.
    closed, shape = jax.make_jaxpr(lambda x, params: fresh_jacobian(jac_fn, params, x), return_shape=True)(st.x, params)
    out_tree = jax.tree_util.tree_structure(shape)

    def fresh(x, params, consts):
        out = jax.core.eval_jaxpr(closed.jaxpr, consts, *jax.tree_util.tree_leaves((x, params)))
        return jax.tree_util.tree_unflatten(out_tree, out)

    @jax.custom_batching.custom_vmap
    def refreshed(refresh, x, params, consts, cache):
        return jax.lax.cond(refresh, lambda: fresh(x, params, consts), lambda: cache)

    @refreshed.def_vmap
    def _batched(size, batched, refresh, x, params, consts, cache):
        b_refresh, b_x, b_params, b_consts, b_cache = batched
        refresh = refresh if b_refresh else jnp.broadcast_to(refresh, (size,))
        cache = jax.tree_util.tree_map(lambda c, b: c if b else jnp.broadcast_to(c, (size,) + c.shape), cache, b_cache)
        update = _refresh_one_by_one if jax.default_backend() == "cpu" else _refresh_all_at_once
        new = update(fresh, refresh, (x, params, consts), (b_x, b_params, b_consts), cache)
        return new, jax.tree_util.tree_map(lambda _: True, new)

    return refreshed(st.refresh, st.x, params, list(closed.consts), st.cache)


def _refresh_one_by_one(fresh, refresh, args, batched, cache):
    """On a CPU: a loop over the trajectories, each a ``lax.cond`` on its own flag (``args``:
    the arguments of ``fresh``, ``batched`` their flags)."""

    def one(i, cache):
        def update():
            lane = jax.tree_util.tree_map(lambda a, b: a[i] if b else a, args, batched)
            return jax.tree_util.tree_map(lambda c, n: c.at[i].set(n), cache, fresh(*lane))

        return jax.lax.cond(refresh[i], update, lambda: cache)

    return jax.lax.fori_loop(0, refresh.shape[0], one, cache)


def _refresh_all_at_once(fresh, refresh, args, batched, cache):
    """Elsewhere: the whole batch when one trajectory asks; the others keep their caches."""

    def update():
        new = jax.vmap(fresh, in_axes=jax.tree_util.tree_map(lambda b: 0 if b else None, batched))(*args)
        keep = lambda n, c: jnp.where(refresh.reshape(refresh.shape + (1,) * (c.ndim - 1)), n, c)
        return jax.tree_util.tree_map(keep, new, cache)

    return jax.lax.cond(jnp.any(refresh), update, lambda: cache)


def newton_done(st: NewtonState):
    return st.result >= 0


def newton_solve(
    fn: Callable[[jax.Array, Any], jax.Array],
    jac_fn: Callable[[jax.Array, Any], tuple[jax.Array, jax.Array]],
    x0: jax.Array,
    params: Any,
    cache: JacobianCache,
    options: NewtonOptions,
    solve: Any = None,
) -> tuple[jax.Array, NewtonInfo, JacobianCache]:
    """Solve ``fn(x, params) = 0`` from ``x0``; ``jac_fn(x, params) -> (fn(x), ∂fn/∂x)``.

    ``solve`` (a traced bool, or None for always): where False the solve stops after the fast
    start (no refresh, no further iteration) and returns ``x0``, a successful solve of no
    iterations and the cache as given (step doubling's half steps after a failed whole step).

    Returns the iterate, a :class:`NewtonInfo` and the Jacobian cache to hand to the next
    solve (marked invalid after a failure, so that the next solve starts fresh).

    The iterations are never differentiated: the iterate carries no derivatives. Pass it
    through :func:`implicit_root` to get those of the exact root.
    """
    x0, cache, params = jax.lax.stop_gradient((x0, cache, params))

    def iterate(st):
        return newton_step(fn, params, st, options)

    def epoch(st):
        # A fresh Jacobian at the current iterate when asked (at most once per epoch), then
        # iterations until the solve ends or the contraction asks for another refresh (the
        # first iteration of an epoch always runs: refresh=True marks it as the fresh one).
        cache = _refreshed(jac_fn, params, st)._replace(floor=st.cache.floor)
        st = st._replace(cache=cache, n_jac=st.n_jac + st.refresh.astype(jnp.int32))
        first = (jnp.asarray(True), st)
        _, out = jax.lax.while_loop(
            lambda c: c[0] | (~newton_done(c[1]) & ~c[1].refresh),
            lambda c: (jnp.asarray(False), iterate(c[1])),
            first,
        )
        return out

    st = newton_init(x0, cache)
    if options.reuse_jacobian:
        st = jax.tree_util.tree_map(functools.partial(jnp.where, cache.valid), fast_start(fn, params, st, options), st)
    if solve is not None:  # a solve not asked for ends here (after the fast start: no refresh, no epoch;
        # under vmap the other trajectories' epochs run, and a refresh asked for would be evaluated)
        st = st._replace(x=jnp.where(solve, st.x, x0), result=jnp.where(solve, st.result, Result.SUCCESSFUL),
                         k=jnp.where(solve, st.k, 0), res_norm=jnp.where(solve, st.res_norm, 0.0),
                         refresh=st.refresh & solve)
    out = jax.lax.while_loop(lambda st: ~newton_done(st), epoch, st)
    ok = out.result == Result.SUCCESSFUL
    # where a solve that ended with a fresh Jacobian stopped: the round-off level of the next ones
    floor = jnp.where(jnp.logical_and(ok, ~out.stale), out.nrm_prev, out.cache.floor)
    new = out.cache._replace(valid=jnp.logical_and(out.cache.valid, ok), floor=floor)
    if solve is not None:
        new = jax.tree_util.tree_map(functools.partial(jnp.where, solve), new, cache)
    return out.x, NewtonInfo(out.result, out.k, out.res_norm, out.n_jac), new


# -- derivatives of the root ------------------------------------------------------------------
@functools.partial(jax.custom_jvp, nondiff_argnums=(0, 1))
def implicit_root(fn, jac_fn, x, params):
    r"""``x`` (a root of ``fn(·, params)``), with the derivatives of the exact root.

    By the implicit function theorem, differentiating ``fn(x(θ), θ) = 0`` gives

        ∂x/∂θ · dθ = −J⁻¹ (∂fn/∂θ · dθ),   J = ∂fn/∂x at the root,

    one forward-mode pass of ``fn`` in θ and one solve with J (an LU factorisation of the
    Jacobian at the root, not the reused one of simplified Newton). The solve is a
    ``lax.custom_linear_solve`` with its transposed solve, so JAX transposes this rule for
    reverse mode: the discrete adjoint ``θ̄ = −(∂fn/∂θ)ᵀ J⁻ᵀ x̄`` of the stage solve, which
    never differentiates the iterations. The tangent of ``x`` itself (the guess) is ignored.
    """
    return x


@implicit_root.defjvp
def _implicit_root_jvp(fn, jac_fn, primals, tangents):
    x, params = primals
    _, params_dot = tangents
    _, dfn = jax.jvp(lambda p: fn(x, p), (params,), (params_dot,))
    _, jac = jac_fn(x, params)
    factors = jax.scipy.linalg.lu_factor(jac)
    dx = jax.lax.custom_linear_solve(
        lambda v: jac @ v,
        -dfn,
        solve=lambda _, b: jax.scipy.linalg.lu_solve(factors, b),
        transpose_solve=lambda _, b: jax.scipy.linalg.lu_solve(factors, b, trans=1),
    )
    return x, dx
