"""The pure entry points (lobattodae._integrate): ``integrate``'s contract (shapes, statuses,
NaN rows after a failure, also under vmap; compiled once per shape; equal to ``solve``),
``integrate_adaptive`` under vmap and at its step cap, forward mode through both, and their
options."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import lobattodae as L
from lobattodae.examples import get_example

from helpers import stiff_particle


# -- integrate ------------------------------------------------------------------------------------------
def test_integrate_shapes_and_success(knife):
    m = L.LobattoIIIAIIIB(stages=3)
    res = L.integrate(knife.problem, m, 0.0, 0.05, 40, knife.q0, knife.p0, knife.lam0, knife.args)
    q, p, lam, status = res  # unpacks as before
    assert isinstance(res, L.IntegrateResult)
    assert q.shape == (41, 3) and p.shape == (41, 3) and lam.shape == (41, 1) and int(status) == 0
    sol = L.solve(knife.problem, m, (0.0, 2.0), knife.q0, knife.p0, n_steps=40, args=knife.args)
    np.testing.assert_allclose(q, sol.q, rtol=0, atol=1e-14)


def test_integrate_after_a_failed_step_returns_nan_rows_and_the_status():
    prob = stiff_particle()
    q0, p0 = np.zeros(3), np.array([1.0, 1.0, 0.0])
    m = L.LobattoIIIAIIIB(stages=2)
    lam0 = np.zeros(1)
    q, p, lam, status = L.integrate(prob, m, 0.0, 0.3, 20, q0, p0, lam0, 100.0)
    assert int(status) in (L.Result.MAX_ITERATIONS, L.Result.DIVERGED, L.Result.NONFINITE)
    bad = np.flatnonzero(~np.all(np.isfinite(np.asarray(q)), axis=1))
    assert bad.size and np.all(np.isnan(np.asarray(q)[bad[0]:]))
    assert np.all(np.isfinite(np.asarray(q)[: bad[0]]))
    # under vmap: a good and a failing trajectory side by side keep their own outcome
    batch = jax.vmap(lambda a: L.integrate(prob, m, 0.0, 0.3, 20, q0, p0, lam0, a))(jnp.asarray([0.0, 100.0]))
    assert int(batch.status[0]) == 0 and np.all(np.isfinite(np.asarray(batch.q[0])))
    assert int(batch.status[1]) == int(status)
    np.testing.assert_array_equal(np.isnan(np.asarray(batch.q[1])), np.isnan(np.asarray(q)))


def test_integrate_rejects_a_bad_step_count(knife):
    m = L.LobattoIIIAIIIB(stages=2)
    for bad in (0, -3, 2.5, True):
        with pytest.raises(L.LobattoDAEInputError, match="n_steps must be a positive integer"):
            L.integrate(knife.problem, m, 0.0, 0.1, bad, knife.q0, knife.p0, knife.lam0, knife.args)


def test_integrate_is_compiled_once_per_shape(knife):
    from lobattodae._integrate import _integrate_compiled

    m = L.LobattoIIIAIIIB(stages=2)
    args = (knife.problem, m, 0.0, 0.05, 20, knife.q0, knife.p0, knife.lam0, knife.args)
    L.integrate(*args)
    size = _integrate_compiled._cache_size()
    L.integrate(*args[:5], knife.q0 + 1.0, *args[6:])
    assert _integrate_compiled._cache_size() == size


def test_integrate_batched_matches_solve(knife):
    m = L.LobattoIIIAIIIB(stages=3)
    n, h = 20, 0.1
    sol = L.solve(knife.problem, m, (0.0, n * h), knife.q0, knife.p0, n_steps=n, args=knife.args)
    run = jax.jit(lambda q0, p0, lam0: L.integrate(knife.problem, m, 0.0, h, n, q0, p0, lam0, knife.args))
    q, p, lam, status = run(knife.q0, knife.p0, knife.lam0)
    assert int(status) == 0
    # different compiled programs: equal to round-off, not necessarily bitwise
    np.testing.assert_allclose(np.asarray(q), sol.q, rtol=0, atol=1e-13)
    np.testing.assert_allclose(np.asarray(lam), sol.lam, rtol=0, atol=1e-11)
    shifts = jnp.array([[0.0, 0, 0], [2.0, -1.0, 0]])
    qb, pb, lb, sb = jax.vmap(run, in_axes=(0, None, None))(knife.q0 + shifts, knife.p0, knife.lam0)
    assert np.all(np.asarray(sb) == 0)
    # vmap turns cond into select: the batched run equals the unbatched one to round-off
    np.testing.assert_allclose(np.asarray(qb[0]), np.asarray(q), rtol=0, atol=1e-14)
    np.testing.assert_allclose(np.asarray(qb[1]), np.asarray(q) + np.array([2.0, -1.0, 0]), atol=1e-12)


def test_forward_mode_through_integrate_matches_central_differences(knife):
    """jax.jvp through integrate (it differentiates the converged Newton iterations) agrees with
    central differences of the same discrete map, as the README's transformation table says."""
    m = L.LobattoIIIAIIIB(stages=3)

    def final_y(g):
        args = knife.args._replace(g=g)
        lam0 = jnp.asarray(knife.lam0) * g / knife.args.g  # λ0 = m g cos θ0 scales with g here
        return L.integrate(knife.problem, m, 0.0, 0.05, 40, knife.q0, knife.p0, lam0, args).q[-1, 1]

    g = jnp.asarray(knife.args.g, jnp.float64)
    _, tangent = jax.jvp(final_y, (g,), (jnp.ones_like(g),))
    eps = 1e-5
    fd = (final_y(g + eps) - final_y(g - eps)) / (2 * eps)
    np.testing.assert_allclose(float(tangent), float(fd), rtol=1e-7)
    assert abs(float(tangent)) > 0.1


# -- integrate_adaptive ---------------------------------------------------------------------------------
def test_integrate_adaptive_is_vmappable_and_reports_max_steps(sleigh):
    method = L.LobattoIIIAIIIB(stages=3)

    def steps(rtol):
        r = L.integrate_adaptive(sleigh.problem, method, sleigh.t_span, sleigh.q0, sleigh.p0, sleigh.lam0, sleigh.args,
                                 rtol=rtol, atol=rtol, max_steps=512)
        return r.n_steps, r.status

    n, status = jax.vmap(steps)(jnp.asarray([1e-6, 1e-9]))
    assert int(n[0]) < int(n[1]) and np.all(np.asarray(status) == 0)
    r = L.integrate_adaptive(sleigh.problem, method, sleigh.t_span, sleigh.q0, sleigh.p0, sleigh.lam0, sleigh.args,
                             rtol=1e-12, atol=1e-12, max_steps=8)
    assert int(r.status) == L.Result.MAX_STEPS and int(r.n_steps) + int(r.n_rejected) == 8
    assert int(r.n_rows) == int(r.n_steps) + 1
    # with t_eval, max_steps still bounds the attempts; rows that end before t1 are a success
    te = np.linspace(0.0, 2.0, 50)
    r = L.integrate_adaptive(sleigh.problem, method, sleigh.t_span, sleigh.q0, sleigh.p0, sleigh.lam0, sleigh.args,
                             rtol=1e-9, atol=1e-9, t_eval=te, max_steps=10)
    assert int(r.status) == L.Result.MAX_STEPS and int(r.n_steps) + int(r.n_rejected) == 10
    r = L.integrate_adaptive(sleigh.problem, method, sleigh.t_span, sleigh.q0, sleigh.p0, sleigh.lam0, sleigh.args,
                             rtol=1e-9, atol=1e-9, t_eval=np.array([0.1, 0.5, 1.0]), max_steps=1000)
    assert int(r.status) == 0 and int(r.n_rows) == 3
    np.testing.assert_allclose(np.asarray(r.q), sleigh.exact(np.array([0.1, 0.5, 1.0]))[0], atol=1e-7)


def test_differentiable_runs_stop_at_max_steps_like_the_plain_loop():
    """With checkpointed segments the scan's trip count is rounded up (205 → 15 × 14); the
    attempts past max_steps are skipped, so the status is MAX_STEPS, not SUCCESSFUL with the
    outputs cut (issue #30: with t_eval = [1, 2], status 0 and t = [1, nan])."""
    ex = get_example("sleigh")
    m = L.LobattoIIIAIIIB(stages=3)
    kw = dict(rtol=1e-12, atol=1e-12, max_steps=205, t_eval=np.array([1.0, 2.0]))
    plain = L.integrate_adaptive(ex.problem, m, (0.0, 2.0), ex.q0, ex.p0, ex.lam0, ex.args, **kw)
    diff = L.integrate_adaptive(ex.problem, m, (0.0, 2.0), ex.q0, ex.p0, ex.lam0, ex.args, differentiable=True, **kw)
    assert int(plain.status) == int(diff.status) == L.Result.MAX_STEPS
    assert int(diff.n_steps) == int(plain.n_steps) and int(diff.n_rows) == int(plain.n_rows) < 2


def test_options_are_checked():
    ex = get_example("knife-edge")
    method = L.LobattoIIIAIIIB(stages=2)
    with pytest.raises(L.LobattoDAEInputError, match="checkpoints"):
        L.integrate(ex.problem, method, 0.0, 0.1, 4, ex.q0, ex.p0, ex.lam0, ex.args, checkpoints=0)
    with pytest.raises(L.LobattoDAEInputError, match="'auto'"):
        L.integrate(ex.problem, method, 0.0, 0.1, 4, ex.q0, ex.p0, ex.lam0, ex.args, checkpoints="sqrt")
    with pytest.raises(L.LobattoDAEInputError, match="differentiable"):
        L.integrate_adaptive(ex.problem, method, (0.0, 1.0), ex.q0, ex.p0, ex.lam0, ex.args, differentiable="yes")
