"""solve(), the single-step API, Solution contents, compilation caching and float64."""

import subprocess
import sys

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import lobattodae as L
from lobattodae._chunks import _run_packed
from lobattodae.examples import get_example


@pytest.fixture(scope="module")
def knife():
    return get_example("knife-edge")


def _solve(ex, s=3, n=40, **kw):
    return L.solve(ex.problem, L.LobattoIIIAIIIB(stages=s), ex.t_span, ex.q0, ex.p0, n_steps=n, args=ex.args, **kw)


def test_solution_shapes_and_contents(knife):
    sol = _solve(knife, n=40)
    assert sol.success and sol.result == L.Result.SUCCESSFUL
    assert sol.t.shape == (41,) and sol.q.shape == (41, 3) and sol.p.shape == (41, 3) and sol.lam.shape == (41, 1)
    assert sol.t[0] == knife.t_span[0] and sol.t[-1] == knife.t_span[1]
    np.testing.assert_allclose(np.diff(sol.t), sol.stats["h"], rtol=1e-12)
    assert sol.q.dtype == np.float64 and sol.lam.dtype == np.float64
    st = sol.stats
    assert st["newton_iterations"].shape == (40,) and np.all(st["newton_iterations"] >= 1)
    assert st["constraint_residual"].shape == (41,)
    assert st["residual_norm"].shape == (40,) and np.all(st["residual_norm"] < 1e-10)
    assert st["n_jacobians"] >= 1 and st["failed_step"] is None
    # λ0 was computed from the hidden constraint and equals the exact one
    np.testing.assert_allclose(sol.lam[0], knife.lam0, atol=1e-14)
    # accuracy against the closed form (s=3: 4th order in q)
    qe, pe, le = knife.exact(sol.t)
    assert np.max(np.abs(sol.q - qe)) < 1e-6


def test_constraint_residual_tiny_at_every_step_long_run():
    ex = get_example("falling-disk-general")
    sol = L.solve(ex.problem, L.LobattoIIIAIIIB(stages=4, lam_start="consistent"), (0.0, 50.0), ex.q0, ex.p0,
                  dt=0.05, args=ex.args)
    assert sol.success
    assert np.max(sol.stats["constraint_residual"]) <= 1e-12
    # and the recomputed residual agrees with the stored one
    from lobattodae._diagnostics import constraint_residual, energy_error

    assert np.max(constraint_residual(sol)) <= 1e-12
    assert np.max(np.abs(energy_error(sol))) < 1e-6


def test_dt_rounds_to_equal_steps(knife):
    sol = L.solve(knife.problem, L.LobattoIIIAIIIB(stages=2), (0.0, 1.0), knife.q0, knife.p0, dt=0.3, args=knife.args)
    assert len(sol.t) == 5 and sol.stats["h"] == pytest.approx(0.25)
    assert sol.t[-1] == 1.0


def test_step_forward_then_backward_returns_to_start(knife):
    m = L.LobattoIIIAIIIB(stages=4)
    q0, p0, lam0 = map(jnp.asarray, (knife.q0, knife.p0, knife.lam0))
    h = 0.1
    step = jax.jit(lambda t, q, p, lam, dt: m.step(knife.problem, t, q, p, lam, dt, knife.args))  # one compile
    q1, p1, lam1, info, _ = step(0.0, q0, p0, lam0, h)
    assert int(info.result) == 0
    qb, pb, lamb, info_b, _ = step(h, q1, p1, lam1, -h)
    assert int(info_b.result) == 0
    # q, p: the Lobatto IIIA-IIIB pair is symmetric, so it returns to the start to round-off.
    np.testing.assert_allclose(qb, q0, atol=1e-13)
    np.testing.assert_allclose(pb, p0, atol=1e-13)
    assert float(jnp.max(jnp.abs(qb - q1))) > 1e-3  # the step really moved


@pytest.mark.parametrize("lam_start", ["previous", "consistent"])
def test_solve_equals_a_loop_of_public_steps(lam_start):
    """solve's compiled loop hands λ(q_k, p_k) from its drift diagnostic to the next step for
    lam_start="consistent" instead of solving for it again; the numbers must be those of
    the public one-step API called in a Python loop (the rolling disk: λ is 2-dimensional
    and the hidden constraint is nonlinear in q, so a wrong Λ_1 would show)."""
    ex = get_example("falling-disk-general")
    m = L.LobattoIIIAIIIB(stages=3, lam_start=lam_start)
    n, h = 12, 0.05
    sol = L.solve(ex.problem, m, (0.0, n * h), ex.q0, ex.p0, n_steps=n, args=ex.args)
    step = jax.jit(lambda t, q, p, lam, st: m.step(ex.problem, t, q, p, lam, h, ex.args, st))
    q, p, lam = map(jnp.asarray, (sol.q[0], sol.p[0], sol.lam[0]))
    state = m.init(ex.problem, sol.t[0], q, p, lam, ex.args)
    for k in range(n):
        q, p, lam, info, state = step(sol.t[0] + k * h, q, p, lam, state)
        assert int(info.result) == 0
        np.testing.assert_allclose(q, sol.q[k + 1], rtol=0, atol=1e-14)
        np.testing.assert_allclose(p, sol.p[k + 1], rtol=0, atol=1e-14)
        np.testing.assert_allclose(lam, sol.lam[k + 1], rtol=0, atol=1e-12)
        if lam_start == "consistent":
            lam_c = L.consistent_lambda(ex.problem, sol.t[k + 1], q, p, lam, ex.args)
            assert sol.stats["multiplier_drift"][k + 1] == pytest.approx(float(jnp.max(jnp.abs(lam - lam_c))), abs=1e-12)


def test_step_is_jittable_and_vmappable(knife):
    m = L.LobattoIIIAIIIB(stages=3)
    q0, p0, lam0 = map(jnp.asarray, (knife.q0, knife.p0, knife.lam0))
    step = jax.jit(lambda q, p, l: m.step(knife.problem, 0.0, q, p, l, 0.05, knife.args)[:3])
    single = step(q0, p0, lam0)
    qs = jnp.stack([q0, q0 + jnp.array([1.0, 0.0, 0.0])])  # x shift keeps consistency
    batched = jax.vmap(step)(qs, jnp.stack([p0, p0]), jnp.stack([lam0, lam0]))
    for a, b in zip(single, batched):
        np.testing.assert_allclose(b[0], a, rtol=0, atol=1e-15)
    np.testing.assert_allclose(batched[0][1], single[0] + jnp.array([1.0, 0, 0]), atol=1e-13)


def test_new_numbers_do_not_recompile(knife):
    """The loop is compiled once per (problem, method, shapes): a new number of steps, t_span,
    initial values or args values reuse it."""
    m = L.LobattoIIIAIIIB(stages=2)
    _solve(knife, s=2, n=100)
    size = _run_packed._cache_size()
    sol = L.solve(knife.problem, m, knife.t_span, knife.q0, knife.p0 * 1.0, n_steps=100, args=knife.args)
    assert sol.success
    assert _run_packed._cache_size() == size
    for n in (90, 3000, 7):
        L.solve(knife.problem, m, knife.t_span, knife.q0, knife.p0, n_steps=n, args=knife.args)
    L.solve(knife.problem, m, (1.0, 4.5), knife.q0, knife.p0, n_steps=33, args=knife.args)
    L.solve(knife.problem, m, knife.t_span, knife.q0, knife.p0, n_steps=33, args=knife.args._replace(g=2.5))
    assert _run_packed._cache_size() == size


def test_integrate_is_compiled_once_per_shape(knife):
    from lobattodae._integrate import _integrate_compiled

    m = L.LobattoIIIAIIIB(stages=2)
    args = (knife.problem, m, 0.0, 0.05, 20, knife.q0, knife.p0, knife.lam0, knife.args)
    L.integrate(*args)
    size = _integrate_compiled._cache_size()
    L.integrate(*args[:5], knife.q0 + 1.0, *args[6:])
    assert _integrate_compiled._cache_size() == size


def test_long_run_is_one_compiled_loop_per_chunk(knife):
    sol = L.solve(knife.problem, L.LobattoIIIAIIIB(stages=2), (0.0, 20.0), knife.q0, knife.p0,
                  n_steps=10_000, args=knife.args, chunk_size=5000)
    assert sol.success and len(sol.t) == 10_001


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


def test_repeated_runs_bitwise_identical(knife):
    a = _solve(knife, s=4, n=30)
    b = _solve(knife, s=4, n=30)
    np.testing.assert_array_equal(a.q, b.q)
    np.testing.assert_array_equal(a.lam, b.lam)


def test_lam_policies_on_the_sleigh():
    """The Chaplygin sleigh (s = 5, h = 0.1, t = 130): the paper's scheme carries a λ error that
    grows like exp(0.18 t) and spoils q (the run warns and says so in its message); the default
    re-synchronises λ when its drift leaves the band and stays at round-off, as does
    lam_start='consistent'."""
    import warnings

    ex = get_example("sleigh")
    qe = ex.exact(np.array([130.0]))[0][0]
    kw = dict(n_steps=1300, args=ex.args)
    with pytest.warns(RuntimeWarning, match="lam_start='auto'"):
        paper = L.solve(ex.problem, L.LobattoIIIAIIIB(stages=5, lam_start="previous"), (0.0, 130.0), ex.q0, ex.p0,
                        throw=False, **kw)
    assert np.max(paper.stats["multiplier_drift"]) > 1.0 and paper.stats["lam_excursions"] > 0
    assert "Warning: the multiplier" in paper.message and paper.stats["lam_resets"] == 0
    assert np.max(np.abs(paper.q[-1] - qe)) > 1e-2
    for mode in ("auto", "consistent"):
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            sol = L.solve(ex.problem, L.LobattoIIIAIIIB(stages=5, lam_start=mode), (0.0, 130.0), ex.q0, ex.p0, **kw)
        assert np.max(np.abs(sol.q[-1] - qe)) < 1e-9, mode
        assert np.max(sol.stats["multiplier_drift"]) < 1e-4, mode
    assert 1 <= sol.stats["lam_resets"] or mode == "consistent"
    auto = L.solve(ex.problem, L.LobattoIIIAIIIB(stages=5), (0.0, 130.0), ex.q0, ex.p0, **kw)
    assert 1 <= auto.stats["lam_resets"] <= 10 and auto.stats["lam_resets"] == int(np.sum(auto.stats["lam_resync"]))


def test_auto_never_resets_on_a_reversible_problem():
    """On the reversible contact oscillator the λ error of the paper's scheme stays in its band:
    'auto' never re-synchronises, so it is the symmetric scheme, bit for bit."""
    ex = get_example("contact")
    h = 2 * np.sin(np.pi / 15)
    kw = dict(n_steps=20_000, args=ex.args)
    auto = L.solve(ex.problem, L.LobattoIIIAIIIB(stages=3), (0.0, 20_000 * h), ex.q0, ex.p0, **kw)
    paper = L.solve(ex.problem, L.LobattoIIIAIIIB(stages=3, lam_start="previous"), (0.0, 20_000 * h), ex.q0, ex.p0, **kw)
    assert auto.stats["lam_resets"] == 0 and paper.stats["lam_excursions"] == 0
    np.testing.assert_array_equal(auto.q, paper.q)


def test_float64_without_user_configuration(tmp_path):
    code = (
        "import jax.numpy as jnp, numpy as np, lobattodae as L\n"
        "sys = L.NonholonomicSystem(lambda t, q, p, a: 0.5 * p @ p, lambda t, q, a: jnp.array([[-q[1], 0., 1.]]))\n"
        "sol = L.solve(sys, L.LobattoIIIAIIIB(stages=2), (0, 1), [0., 0., 0.], [1., 1., 0.], n_steps=4)\n"
        "assert sol.q.dtype == np.float64 and jnp.zeros(1).dtype == jnp.float64, sol.q.dtype\n"
        "print('ok')\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert "ok" in out.stdout


def test_float64_switched_off_is_an_error(knife):
    jax.config.update("jax_enable_x64", False)
    try:
        with pytest.raises(RuntimeError, match="jax_enable_x64"):
            _solve(knife)
    finally:
        jax.config.update("jax_enable_x64", True)


def test_partitioned_dae_with_nonlinear_lambda():
    """A general PartitionedDAE (g nonlinear in λ): λ0 by Newton, solve converges."""

    def f(t, q, p, a):
        return p

    def g(t, q, p, lam, a):
        return -q + jnp.array([0.0, lam[0] + 0.1 * lam[0] ** 3])

    def phi(t, q, p, a):
        return jnp.array([p[1] - 0.5 * q[0]])

    prob = L.PartitionedDAE(f, g, phi, name="toy")
    q0 = np.array([1.0, 0.0])
    p0 = np.array([0.0, 0.5])
    sol = L.solve(prob, L.LobattoIIIAIIIB(stages=3), (0.0, 1.0), q0, p0, n_steps=20)
    assert sol.success
    r = L.hidden_constraint(prob, 0.0, jnp.asarray(q0), jnp.asarray(p0), jnp.asarray(sol.lam[0]))
    assert float(jnp.max(jnp.abs(r))) < 1e-13
    assert np.max(sol.stats["constraint_residual"]) < 1e-13


def test_small_steps_do_not_stall_newton():
    """Regression: with a long-reused Jacobian, increments just above round-off contracted
    slowly and the iteration ran into its limit (20; particle, s = 3, h = 60/24576). A reused
    Jacobian that contracts slowly above round-off is refreshed, at the latest after
    REFRESH_ITERATIONS iterations, and a fresh one converges at once."""
    from lobattodae._newton import REFRESH_ITERATIONS

    ex = get_example("particle")
    sol = L.solve(ex.problem, L.LobattoIIIAIIIB(stages=3), (0.0, 6.0), ex.q0, ex.p0, n_steps=2458, args=ex.args)
    assert sol.success and np.max(sol.stats["newton_iterations"]) <= REFRESH_ITERATIONS


def test_ctrl_c_before_the_first_chunk_returns_the_initial_point(knife, monkeypatch, tmp_path):
    """The first chunk also builds the loop state; a Ctrl-C that arrives before it (during
    validation or compilation) still returns the initial point with status INTERRUPTED, and a
    checkpoint written then resumes to the uninterrupted numbers."""
    import contextlib

    import lobattodae._solve as S

    ref = _solve(knife, n=40)
    monkeypatch.setattr(S, "deferred_interrupts", lambda: contextlib.nullcontext(lambda: True))
    path = tmp_path / "run.npz"
    sol = _solve(knife, n=40, checkpoint=path)
    assert sol.result == L.Result.INTERRUPTED and sol.stats["n_steps"] == 0
    np.testing.assert_array_equal(sol.t, [knife.t_span[0]])
    np.testing.assert_array_equal(sol.q, np.asarray(knife.q0, np.float64)[None])
    monkeypatch.undo()
    full = _solve(knife, n=40, checkpoint=path, resume=True)
    for name in ("t", "q", "p", "lam"):
        np.testing.assert_array_equal(getattr(full, name), getattr(ref, name))
