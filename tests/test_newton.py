"""The simplified Newton solver (lobattodae._newton): convergence, result codes, Jacobian reuse,
the stopping predicates, and the inverse it keeps; a long run of small steps does not stall it."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import lobattodae as L
from lobattodae import _newton as nw
from lobattodae._results import Result
from lobattodae.examples import get_example


def _system(x, c):
    """A small nonlinear system with the root x = (1, 2) for c = 1: x0² - c = 0, x0 x1 - 2 = 0."""
    return jnp.array([x[0] ** 2 - c, x[0] * x[1] - 2.0])


def _jac(x, c):
    return _system(x, c), jax.jacfwd(_system)(x, c)


def _counted_jacobian(calls):
    """:func:`_jac`, appending to ``calls`` each time a Jacobian is evaluated (a callback on its
    value: also under ``vmap`` and ``jit``)."""

    def jac(x, c):
        value, j = _jac(x, c)
        jax.debug.callback(lambda v: calls.append(1), j[0, 0])
        return value, j

    return jac


def _solve(x0, c=1.0, cache=None, **kw):
    options = nw.NewtonOptions(**kw)
    cache = nw.empty_jacobian_cache(2, jnp.float64) if cache is None else cache
    return jax.jit(lambda x, c, cache: nw.newton_solve(_system, _jac, x, c, cache, options))(jnp.asarray(x0), c, cache)


@pytest.mark.parametrize("reuse", [True, False])
def test_converges_to_the_root(reuse):
    x, info, cache = _solve([1.3, 1.0], reuse_jacobian=reuse)
    assert int(info.result) == Result.SUCCESSFUL
    np.testing.assert_allclose(x, [1.0, 2.0], rtol=1e-14)
    assert bool(cache.valid) and int(info.n_jacobians) >= 1


def test_reused_jacobian_is_not_reevaluated_near_the_solution():
    _, info, cache = _solve([1.3, 1.0])
    x, info2, _ = _solve([1.0 + 1e-9, 2.0 - 1e-9], cache=cache)
    assert int(info2.result) == Result.SUCCESSFUL and int(info2.n_jacobians) == 0
    np.testing.assert_allclose(x, [1.0, 2.0], rtol=1e-14)


def test_a_stale_jacobian_far_away_is_refreshed():
    _, _, cache = _solve([1.3, 1.0])
    x, info, _ = _solve([3.0, 0.5], c=9.0, cache=cache)  # root (3, 2/3): the old Jacobian is poor here
    assert int(info.result) == Result.SUCCESSFUL and int(info.n_jacobians) >= 1
    np.testing.assert_allclose(x, [3.0, 2.0 / 3.0], rtol=1e-14)


def test_a_solve_not_asked_for_returns_its_start_and_keeps_the_cache():
    """``solve=False`` (step doubling's half steps after a failed whole step): no refresh, no
    iteration counted, the start returned and the cache (inverse, validity, round-off floor)
    handed back as it came; ``solve=True`` is the plain solve."""
    options = nw.NewtonOptions()
    _, _, cache = _solve([1.3, 1.0])
    cache = cache._replace(floor=jnp.asarray(7.0))
    run = jax.jit(lambda x, cache, solve: nw.newton_solve(_system, _jac, x, 9.0, cache, options, solve))
    x0 = jnp.asarray([3.0, 0.5])  # far from the root (3, 2/3) of c = 9: the plain solve refreshes
    x, info, kept = run(x0, cache, False)
    np.testing.assert_array_equal(x, x0)
    assert int(info.result) == Result.SUCCESSFUL and int(info.iterations) == 0 and int(info.n_jacobians) == 0
    for a, b in zip(kept, cache):
        np.testing.assert_array_equal(a, b)
    x, info, fresh = run(x0, cache, True)
    np.testing.assert_allclose(x, [3.0, 2.0 / 3.0], rtol=1e-14)
    assert int(info.n_jacobians) >= 1 and not np.array_equal(fresh.inverse, cache.inverse)


def test_nonfinite_values_are_a_failure_not_a_nan_success():
    x, info, cache = _solve([jnp.nan, 1.0])
    assert int(info.result) == Result.NONFINITE and not bool(cache.valid)


def test_iteration_limit():
    _, info, cache = _solve([50.0, 1.0], max_iterations=2, reuse_jacobian=False)
    assert int(info.result) == Result.MAX_ITERATIONS and int(info.iterations) == 2
    assert not bool(cache.valid)  # a failed solve leaves nothing to reuse


def test_divergence_is_detected():
    def f(x, c):  # no root: x² + 1 = 0 (Newton wanders; increments grow at the sign changes)
        return jnp.array([x[0] ** 2 + 1.0])

    def j(x, c):
        return f(x, c), jax.jacfwd(f)(x, c)

    options = nw.NewtonOptions(max_iterations=50, reuse_jacobian=False)
    _, info, _ = jax.jit(lambda x: nw.newton_solve(f, j, x, 0.0, nw.empty_jacobian_cache(1, jnp.float64), options))(
        jnp.asarray([0.5])
    )
    assert int(info.result) in (Result.DIVERGED, Result.MAX_ITERATIONS)
    assert int(info.result) != Result.SUCCESSFUL


def test_predicates():
    t, f = jnp.asarray(True), jnp.asarray(False)
    assert bool(nw.converged(0.5, 0.9, f, f))  # the increment alone is below the tolerance
    assert bool(nw.converged(50.0, 0.01, t, f))  # θ/(1-θ)·|Δx| ≈ 0.5 ≤ 1
    assert not bool(nw.converged(50.0, 0.01, t, t))  # stale Jacobian: 10x stricter
    assert not bool(nw.converged(50.0, 0.01, f, f))  # no rate known yet
    assert bool(nw.diverged(3.0, f, f)) and not bool(nw.diverged(3.0, f, t))  # only with a fresh Jacobian
    z = 0.0  # no round-off level measured yet
    assert bool(nw.stagnated_at_roundoff(0.95, 10.0, f, f, z)) and not bool(nw.stagnated_at_roundoff(0.95, 1e5, f, f, z))
    # a reused Jacobian that contracts slowly at 1e-12 is not at round-off (it is refreshed)
    assert bool(nw.stagnated_at_roundoff(0.95, 100.0, f, f, z)) and not bool(nw.stagnated_at_roundoff(0.95, 100.0, f, t, z))
    assert bool(nw.stagnated_at_roundoff(0.95, nw.ROUNDOFF_LEVEL, f, t, z))
    assert bool(nw.needs_refresh(0.6, 1e6, 2, f, t, z))  # slow contraction while far from round-off
    assert not bool(nw.needs_refresh(0.6, 5.0, 2, f, t, z))  # at round-off the rate is noise
    assert bool(nw.needs_refresh(0.6, 100.0, 2, f, t, z))  # 1e-12: slow, not yet round-off
    assert bool(nw.needs_refresh(0.1, 1e6, nw.REFRESH_ITERATIONS, f, t, z))  # too many iterations
    # where a solve with a fresh Jacobian stopped at 30 x tol, a reused one may stagnate up to
    # FLOOR_FACTOR times that, and is not refreshed for its noise there; never above STAGNATION_LEVEL
    assert bool(nw.stagnated_at_roundoff(0.95, 100.0, f, t, 30.0)) and not bool(nw.needs_refresh(0.6, 100.0, 2, f, t, 30.0))
    assert not bool(nw.stagnated_at_roundoff(0.95, 130.0, f, t, 30.0)) and bool(nw.needs_refresh(0.6, 130.0, 2, f, t, 30.0))
    assert float(nw.stale_roundoff_level(1e6)) == nw.STAGNATION_LEVEL
    assert float(nw.stale_roundoff_level(0.5)) == nw.ROUNDOFF_LEVEL


def test_a_measured_roundoff_floor_spares_the_refresh():
    """A system whose residual carries round-off-like noise of ~30 x tol (as the Whipple bicycle's
    stage equations do, with momenta near 470): the first solve, with a fresh Jacobian, stops by
    stagnation and records its level in the cache; the next solve reuses the Jacobian and stops
    at the same noise without evaluating a new one (it refreshed at every step before: 1,052
    Jacobians in 1,000 bicycle steps)."""
    tol = 1e-14

    def noisy(x, c):  # root near (c, 2c); noise of ~30 tol, pseudo-random from one ulp of x to the next
        noise = 30.0 * tol * jnp.sin(3e17 * x)
        return jnp.array([2.0 * x[0] - 2.0 * c, x[1] - 2.0 * x[0]]) + noise

    def jac(x, c):
        return noisy(x, c), jnp.array([[2.0, 0.0], [-2.0, 1.0]])

    options = nw.NewtonOptions(tol=tol)
    solve = jax.jit(lambda x, c, cache: nw.newton_solve(noisy, jac, x, c, cache, options))
    x, info, cache = solve(jnp.asarray([1.3, 2.0]), 1.0, nw.empty_jacobian_cache(2, jnp.float64))
    # the Jacobian reused within the solve stagnates above ROUNDOFF_LEVEL: refreshed once, then accepted
    assert int(info.result) == Result.SUCCESSFUL and int(info.n_jacobians) == 2
    assert nw.ROUNDOFF_LEVEL < float(cache.floor) <= nw.STAGNATION_LEVEL  # measured: the noise's level
    np.testing.assert_allclose(x, [1.0, 2.0], rtol=0, atol=1e-12)
    x, info, _ = solve(jnp.asarray([1.01, 2.01]), 1.01, cache)
    assert int(info.result) == Result.SUCCESSFUL and int(info.n_jacobians) == 0
    np.testing.assert_allclose(x, [1.01, 2.02], rtol=0, atol=1e-12)
    # without the measured level, the same reused Jacobian is refreshed at the noise
    _, info, _ = solve(jnp.asarray([1.01, 2.01]), 1.01, cache._replace(floor=jnp.asarray(0.0)))
    assert int(info.result) == Result.SUCCESSFUL and int(info.n_jacobians) >= 1


def test_round_off_noise_that_goes_up_and_down_is_stagnation():
    """At round-off the increments rise and fall with the noise: measured on the Whipple bicycle
    (s = 4, h = 0.01, roll rate 1 rad/s) they went 9.9, 28.8, 19.4, 5.0, 23.4, 19.4, 9.9, 7.4, ... ×tol
    with fresh Jacobians, each ratio to the previous one below THETA_STAGNATION, until the
    iteration limit failed the step. The rule compares with the smallest increment so far: an
    increment (fresh Jacobian, within STAGNATION_LEVEL) that is no smaller than 0.9 of it ends
    the solve."""
    options = nw.NewtonOptions(tol=1e-14)
    x = jnp.ones(2)
    st = nw.newton_init(x, nw.empty_jacobian_cache(2, jnp.float64))._replace(
        k=jnp.asarray(8, jnp.int32), nrm_prev=jnp.asarray(28.8), nrm_best=jnp.asarray(9.9), refresh=jnp.asarray(True))
    dx = jnp.full(2, 19.4 * 1e-14 * 2.0)  # scaled increment 19.4: 0.67 of the last, 2.0 of the best
    out = nw._judge(st, x - dx, dx, jnp.zeros(2), options)
    assert int(out.result) == Result.SUCCESSFUL and float(out.nrm_best) == pytest.approx(9.9)
    # a converging iteration is not stopped by it: the increment is below the best so far
    dx = jnp.full(2, 5.0 * 1e-14 * 2.0)
    out = nw._judge(st, x - dx, dx, jnp.zeros(2), options)
    assert int(out.result) == -1 and float(out.nrm_best) == pytest.approx(5.0, rel=1e-12)


@pytest.mark.parametrize("n", [1, 5, 31, 53])
def test_inverse_of_a_matrix_that_needs_pivoting(n):
    rng = np.random.default_rng(n)
    a = rng.standard_normal((n, n))
    if n > 1:
        a[0, 0] = 0.0  # no pivot-free LU
    inv = nw.inverse(jnp.asarray(a))
    np.testing.assert_allclose(np.asarray(inv) @ a, np.eye(n), rtol=0, atol=1e-11 * np.linalg.cond(a))


def test_options_validate_themselves():
    with pytest.raises(ValueError, match="tol"):
        nw.NewtonOptions(tol=0.0)
    with pytest.raises(ValueError, match="max_iterations"):
        nw.NewtonOptions(max_iterations=0)
    with pytest.raises(ValueError, match="reuse_jacobian"):
        nw.NewtonOptions(reuse_jacobian="yes")


def test_small_steps_do_not_stall_newton():
    """Regression: with a long-reused Jacobian, increments just above round-off contracted
    slowly and the iteration ran into its limit (20; particle, s = 3, h = 60/24576). A reused
    Jacobian that contracts slowly above round-off is refreshed, at the latest after
    REFRESH_ITERATIONS iterations, and a fresh one converges at once."""
    from lobattodae._newton import REFRESH_ITERATIONS

    ex = get_example("particle")
    sol = L.solve(ex.problem, L.LobattoIIIAIIIB(stages=3), (0.0, 6.0), ex.q0, ex.p0, n_steps=2458, args=ex.args)
    assert sol.success and np.max(sol.stats["newton_iterations"]) <= REFRESH_ITERATIONS


@pytest.mark.parametrize("branch", ["cpu", "batch"])
def test_vmapped_solves_evaluate_no_jacobian_that_no_trajectory_asks_for(branch, monkeypatch):
    """Under ``vmap`` (``ensemble``) a ``lax.cond`` on the per-trajectory refresh flag becomes a
    select that evaluates and inverts the Jacobian in every epoch; the refresh's batching rule
    evaluates only the Jacobians asked for. Counted by a callback on the Jacobian's value: none
    with valid caches that converge; when one trajectory's cache is invalid, one evaluation on a
    CPU (that trajectory's), the batch's on other backends ("batch": the rule's other branch,
    taken by pretending to be on a GPU); either way that trajectory alone takes the fresh one
    (the others keep theirs, and the roots agree with solving one at a time)."""
    if branch == "batch":
        monkeypatch.setattr(jax, "default_backend", lambda: "gpu")
    calls = []
    jac = _counted_jacobian(calls)

    options = nw.NewtonOptions()
    _, _, cache = _solve([1.3, 1.0])
    caches = jax.tree_util.tree_map(lambda a: jnp.stack([a] * 4), cache)
    x0 = jnp.asarray([[1.0 + 1e-9 * i, 2.0 - 1e-9 * i] for i in range(4)])
    solve = jax.jit(jax.vmap(lambda x, cache: nw.newton_solve(_system, jac, x, 1.0, cache, options)))
    x, info, out = jax.block_until_ready(solve(x0, caches))
    assert calls == [] and np.all(np.asarray(info.result) == Result.SUCCESSFUL)
    np.testing.assert_allclose(x, np.tile([1.0, 2.0], (4, 1)), rtol=1e-14)

    invalid = caches._replace(valid=caches.valid.at[2].set(False), inverse=caches.inverse.at[2].set(0.0))
    x, info, out = jax.block_until_ready(solve(x0, invalid))
    assert len(calls) == (1 if branch == "cpu" else 4)
    assert np.asarray(info.n_jacobians).tolist() == [0, 0, 1, 0]
    np.testing.assert_array_equal(np.asarray(out.inverse)[[0, 1, 3]], np.asarray(caches.inverse)[[0, 1, 3]])
    assert np.asarray(out.valid).all()
    one, _, _ = nw.newton_solve(_system, _jac, x0[2], 1.0, nw.empty_jacobian_cache(2, jnp.float64), options)
    np.testing.assert_allclose(x[2], one, rtol=0, atol=1e-15)


def test_a_vmapped_solve_not_asked_for_evaluates_no_jacobian():
    """Under ``vmap`` a trajectory whose solve is not asked for (``solve=False``) stays out of the
    other trajectories' epochs: its fast start would ask for a refresh (it starts far from the
    root), but no Jacobian of its is evaluated (counted by a callback on the Jacobian's value, on
    a CPU, where the refresh's batching rule evaluates only those asked for)."""
    calls = []
    jac = _counted_jacobian(calls)

    options = nw.NewtonOptions()
    _, _, cache = _solve([1.3, 1.0])
    caches = jax.tree_util.tree_map(lambda a: jnp.stack([a] * 2), cache)
    x0 = jnp.asarray([[3.0, 0.5], [3.0, 0.5]])  # root (3, 2/3) of c = 9: the kept Jacobian is poor there
    run = jax.jit(jax.vmap(lambda x, cache, solve: nw.newton_solve(_system, jac, x, 9.0, cache, options, solve)))
    x, info, out = jax.block_until_ready(run(x0, caches, jnp.asarray([True, False])))
    n_jac = np.asarray(info.n_jacobians)
    assert n_jac[0] >= 1 and n_jac[1] == 0 and len(calls) == n_jac[0]
    np.testing.assert_allclose(x[0], [3.0, 2.0 / 3.0], rtol=1e-14)
    np.testing.assert_array_equal(x[1], x0[1])
    np.testing.assert_array_equal(np.asarray(out.inverse)[1], np.asarray(cache.inverse))
