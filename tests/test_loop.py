"""The compiled loop (lobattodae._loop): integrate's contract (shapes, statuses, NaN rows after a
failure, also under vmap), the constant step-size controller, and chunked runs equal to one."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import lobattodae as L
from lobattodae._controllers import ConstantStepSize, ControlOptions, StepReport
from lobattodae._chunks import init_host, row_capacity, run_host, start_host
from lobattodae._loop import Output
from lobattodae.examples import get_example


@pytest.fixture(scope="module")
def knife():
    return get_example("knife-edge")


def _stiff_particle():
    return L.NonholonomicSystem(
        lambda t, q, p, a: 0.5 * p @ p + a * q[0] ** 4,
        lambda t, q, a: jnp.array([[-q[1], 0.0, 1.0]]),
    )


def test_integrate_shapes_and_success(knife):
    m = L.LobattoIIIAIIIB(stages=3)
    res = L.integrate(knife.problem, m, 0.0, 0.05, 40, knife.q0, knife.p0, knife.lam0, knife.args)
    q, p, lam, status = res  # unpacks as before
    assert isinstance(res, L.IntegrateResult)
    assert q.shape == (41, 3) and p.shape == (41, 3) and lam.shape == (41, 1) and int(status) == 0
    sol = L.solve(knife.problem, m, (0.0, 2.0), knife.q0, knife.p0, n_steps=40, args=knife.args)
    np.testing.assert_allclose(q, sol.q, rtol=0, atol=1e-14)


def test_integrate_after_a_failed_step_returns_nan_rows_and_the_status():
    prob = _stiff_particle()
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


def _report(ok):
    z = jnp.zeros(2)
    return StepReport(jnp.asarray(ok), jnp.asarray(0 if ok else 1), 0.0, 0.0, z, z, z, z[:1], z[:1], z[:1])


def test_constant_controller_lands_exactly_on_t1():
    c = ConstantStepSize()
    st = c.init(None, None, jnp.asarray(0.1), jnp.asarray(0.7), None, None, None, None, ControlOptions(n=3))
    times = []
    while not bool(c.done(st)):
        t, h = c.proposal(st)
        times.append(float(t))
        _, st, _ = c.adapt(st, None, None, _report(True))
    assert float(c.time(st)) == 0.7
    np.testing.assert_allclose(times, [0.1, 0.3, 0.5], rtol=1e-15)
    accept, st2, result = c.adapt(st, None, None, _report(False))
    assert int(st2.k) == int(st.k) and not bool(accept) and int(result) == 1  # a failed step ends the run


def _sixty_steps(knife):
    """``(t0, t1, options, q0, p0, lam0)`` of 60 constant steps of the knife edge on [0, 3]."""
    f64 = lambda x: jnp.asarray(x, jnp.float64)  # noqa: E731
    return f64(0.0), f64(3.0), ControlOptions(n=60), f64(knife.q0), f64(knife.p0), f64(knife.lam0)


def test_chunks_give_the_same_numbers_as_one_run(knife):
    m = L.LobattoIIIAIIIB(stages=3)
    c = ConstantStepSize()
    out = Output()
    state, packing = init_host(knife.problem, m, c, out, *_sixty_steps(knife), knife.args)
    whole, chunk = run_host(knife.problem, m, c, out, packing, state, knife.args, 64)
    rec = chunk.rows
    assert int(chunk.n_rows) == 60 and np.all(np.isnan(np.asarray(rec.q[60:])))
    part = state
    rows = []
    for _ in range(4):
        part, r = run_host(knife.problem, m, c, out, packing, part, knife.args, 16)
        rows.append(np.asarray(r.rows.q)[: int(r.n_rows)])
    np.testing.assert_array_equal(np.concatenate(rows), np.asarray(rec.q)[:60])
    np.testing.assert_array_equal(np.asarray(part.q), np.asarray(whole.q))


def test_the_first_chunk_initialises_the_state_it_would_get_from_init_host(knife):
    """start_host (init and first chunk in one compiled call) gives the numbers, bit for bit,
    of init_host followed by run_host, and hands on a state the next run_host continues from."""
    m = L.LobattoIIIAIIIB(stages=3)
    c = ConstantStepSize()
    out = Output()
    start = _sixty_steps(knife)
    state, packing = init_host(knife.problem, m, c, out, *start, knife.args)
    ref_state, ref = run_host(knife.problem, m, c, out, packing, state, knife.args, 64)
    first, chunk, packing2 = start_host(knife.problem, m, c, out, *start, knife.args, 32)
    assert packing2 == packing and int(chunk.n_rows) == 32 and int(first.n_accepted) == 32
    rest, chunk2 = run_host(knife.problem, m, c, out, packing2, first, knife.args, 64)
    for f in ("t", "q", "p", "lam", "iterations"):
        got = np.concatenate([getattr(chunk.rows, f)[:32], getattr(chunk2.rows, f)[: int(chunk2.n_rows)]])
        np.testing.assert_array_equal(got, np.asarray(getattr(ref.rows, f))[:60])
    np.testing.assert_array_equal(np.asarray(rest.q), np.asarray(ref_state.q))


@pytest.mark.parametrize("length", [1, 16, 100, 2048])
@pytest.mark.parametrize("every", [1, 2, 3, 7, 100, 2**31 - 1])
def test_row_capacity_holds_every_row_a_chunk_can_keep(length, every):
    """Saved rows in a chunk of ``length`` attempts: the multiples of ``every`` among ≤ length
    consecutive step counts (≤ length // every + 1) and the final step."""
    cap = row_capacity(length, every)
    power_of_two = cap & (cap - 1) == 0
    assert cap == length or (cap >= length // every + 2 and power_of_two and cap < length)


def test_a_sparse_output_chunk_runs_its_whole_length(knife):
    """With save_every=5 the chunk's buffer is smaller than its length, yet the chunk runs every
    attempt it may (a too-small buffer would end it early) and keeps exactly the 5th rows."""
    m = L.LobattoIIIAIIIB(stages=3)
    c = ConstantStepSize()
    start = _sixty_steps(knife)
    assert row_capacity(64, 5) < 64
    state, chunk, _ = start_host(knife.problem, m, c, Output(), *start, knife.args, 64, 5)
    _, full, _ = start_host(knife.problem, m, c, Output(), *start, knife.args, 64)
    assert int(state.n_accepted) == 60 and int(chunk.n_rows) == 12
    np.testing.assert_array_equal(chunk.rows.q[:12], full.rows.q[4:60:5])


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
