"""solve(): Solution contents, compilation caching, float64, a run that fails (the prefix, the
status, never NaN as success) and automatic recovery of failed steps."""

import functools
import subprocess
import sys

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import lobattodae as L
from lobattodae._chunks import _run_packed
from lobattodae.examples import get_example

from helpers import stiff_particle


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


# -- compiled once ---------------------------------------------------------------------------------------
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
    # what is recorded is data: every save_every runs the program of the plain run, and t_eval
    # of any length and the dense output share one more
    for every in (2, 7, 100, 5000, "final"):
        sol = L.solve(knife.problem, m, knife.t_span, knife.q0, knife.p0, n_steps=100, args=knife.args,
                      save_every=every)
        assert len(sol.t) == (2 if every in (5000, "final") else 100 // every + 1 + (100 % every > 0))
    assert _run_packed._cache_size() == size
    a, b = knife.t_span
    for times in (np.linspace(a, b, 5), np.linspace(a, b, 3001)):
        sol = L.solve(knife.problem, m, knife.t_span, knife.q0, knife.p0, n_steps=100, args=knife.args, t_eval=times)
        np.testing.assert_array_equal(sol.t, times)
    sol = L.solve(knife.problem, m, knife.t_span, knife.q0, knife.p0, n_steps=100, args=knife.args, dense_output=True)
    assert sol.sol is not None
    assert _run_packed._cache_size() == size + 1


def test_output_options_share_the_error_controlled_program(sleigh):
    """Under error control too, rows stepped onto or interpolated at any number of t_eval times
    and the dense output run one program, the plain run and save_every another; the rows are
    those of a run that records only them (a t_eval longer than a chunk spans several)."""
    ex = sleigh
    m = L.LobattoIIIAIIIB(stages=3)
    run = functools.partial(L.solve, ex.problem, m, (0.0, 3.0), ex.q0, ex.p0, args=ex.args, rtol=1e-8, atol=1e-8)
    plain = run()
    size = _run_packed._cache_size()
    times = np.linspace(0.0, 3.0, 2501)  # more than a chunk's window of 2048 times
    stepped = run(t_eval=times)
    interpolated = run(t_eval=times, t_eval_rows="interpolate")
    dense = run(dense_output=True)
    final = run(save_every="final")
    assert _run_packed._cache_size() == size + 1
    np.testing.assert_array_equal(stepped.t, times)
    np.testing.assert_array_equal(interpolated.t, times)
    np.testing.assert_array_equal(final.q[-1], plain.q[-1])
    np.testing.assert_array_equal(dense.q, plain.q)
    np.testing.assert_allclose(dense.sol(times)[0], interpolated.q, rtol=0, atol=1e-14)
    # stepped-onto rows are step points: on the constraint to round-off, and more steps than the plain run
    assert stepped.stats["n_steps"] > plain.stats["n_steps"]
    assert np.max(stepped.stats["constraint_residual"]) < 1e-14


def test_long_run_is_one_compiled_loop_per_chunk(knife):
    sol = L.solve(knife.problem, L.LobattoIIIAIIIB(stages=2), (0.0, 20.0), knife.q0, knife.p0,
                  n_steps=10_000, args=knife.args, chunk_size=5000)
    assert sol.success and len(sol.t) == 10_001


def test_repeated_runs_bitwise_identical(knife):
    a = _solve(knife, s=4, n=30)
    b = _solve(knife, s=4, n=30)
    np.testing.assert_array_equal(a.q, b.q)
    np.testing.assert_array_equal(a.lam, b.lam)


# -- float64 ---------------------------------------------------------------------------------------------
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


# -- problems -------------------------------------------------------------------------------------------
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


# -- a run that fails -------------------------------------------------------------------------------------
def test_newton_failure_raises_with_step_and_time():
    prob = stiff_particle()
    with pytest.raises(L.NewtonFailure, match=r"Step 0 \(t = 0, h = 5\) failed: Newton") as info:
        L.solve(prob, L.LobattoIIIAIIIB(stages=3), (0, 10), np.zeros(3), np.array([1.0, 1.0, 0.0]), n_steps=2,
                args=1e4)
    assert info.value.step == 0 and info.value.t == 0.0
    assert isinstance(info.value, RuntimeError)


def test_newton_failure_status_without_throw_returns_prefix():
    prob = stiff_particle()
    # a step size that works for a while, then fails as the particle accelerates
    sol = L.solve(prob, L.LobattoIIIAIIIB(stages=3), (0, 10), np.zeros(3), np.array([1.0, 1.0, 0.0]), n_steps=2,
                  args=1e4, throw=False)
    assert not sol.success
    assert sol.result in (L.Result.DIVERGED, L.Result.MAX_ITERATIONS, L.Result.NONFINITE)
    assert "Step 0" in sol.message
    assert sol.stats["failed_step"] == 0
    assert len(sol.t) == 1 and np.all(np.isfinite(sol.q))  # only the initial point


def test_failure_midway_keeps_finite_prefix():
    prob = stiff_particle()
    q0, p0 = np.zeros(3), np.array([1.0, 1.0, 0.0])
    sol = L.solve(prob, L.LobattoIIIAIIIB(stages=2), (0, 6), q0, p0, n_steps=20, args=100.0, throw=False)
    assert not sol.success and sol.result == L.Result.DIVERGED
    k = sol.stats["failed_step"]
    assert k == 2 and len(sol.t) == k + 1 and sol.t[-1] == pytest.approx(0.6)
    assert "Step 2 (t = 0.6, h = 0.3)" in sol.message
    assert np.all(np.isfinite(sol.q)) and np.all(np.isfinite(sol.lam))
    assert np.max(sol.stats["constraint_residual"]) < 1e-12
    assert len(sol.stats["newton_iterations"]) == k


def test_no_nan_reported_as_success():
    # g overflows to inf after a short while: must be a failure, never success with NaN.
    prob = L.NonholonomicSystem(
        lambda t, q, p, a: 0.5 * p @ p - jnp.exp(30.0 * q[0]),
        lambda t, q, a: jnp.array([[-q[1], 0.0, 1.0]]),
    )
    sol = L.solve(prob, L.LobattoIIIAIIIB(stages=2), (0, 5), np.zeros(3), np.array([1.0, 1.0, 0.0]), n_steps=50,
                  throw=False)
    assert not sol.success
    assert np.all(np.isfinite(sol.q)) and np.all(np.isfinite(sol.p)) and np.all(np.isfinite(sol.lam))


# -- automatic recovery ------------------------------------------------------------------------------------
def test_automatic_recovery_retries_failed_steps_as_substeps():
    prob = stiff_particle()
    q0, p0 = np.zeros(3), np.array([1.0, 1.0, 0.0])
    method = L.LobattoIIIAIIIB(stages=2)
    plain = L.solve(prob, method, (0, 6), q0, p0, n_steps=20, args=100.0, throw=False)
    assert not plain.success and plain.stats["recoveries"] == 0
    rec = L.solve(prob, method, (0, 6), q0, p0, n_steps=20, args=100.0, max_recoveries=20)
    assert rec.success and rec.stats["recoveries"] >= 1
    assert len(rec.t) == 21 and np.max(rec.stats["constraint_residual"]) < 1e-12
    # the recovered solution is a solution: the recovered step lands near a fine run, and
    # the energy stays near its initial value (the plain run could not get past step k)
    k = plain.stats["failed_step"]
    np.testing.assert_array_equal(rec.q[: k + 1], plain.q)  # identical up to the failed step
    assert not np.array_equal(rec.q[k + 1], rec.q[k])
    # the recovered step is the same method on 2, 4, 8 or 16 substeps from (t_k, q_k, p_k, λ_k)
    run = jax.jit(lambda m, h: L.integrate(prob, method, rec.t[k], h, 16, rec.q[k], rec.p[k], rec.lam[k], 100.0))
    candidates = []
    for m in (2, 4, 8, 16):
        q, _, _, _ = run(m, (rec.t[k + 1] - rec.t[k]) / m)
        candidates.append(np.max(np.abs(np.asarray(q[m]) - rec.q[k + 1])))
    assert min(candidates) < 1e-12


def test_recovery_budget_is_respected():
    prob = stiff_particle()
    sol = L.solve(prob, L.LobattoIIIAIIIB(stages=3), (0, 6), np.zeros(3), np.array([1.0, 1.0, 0.0]), n_steps=20,
                  args=100.0, max_recoveries=1, throw=False)
    assert sol.stats["recoveries"] <= 1
    with pytest.raises(L.LobattoDAEInputError, match="max_recoveries"):
        L.solve(prob, L.LobattoIIIAIIIB(stages=3), (0, 6), np.zeros(3), np.array([1.0, 1.0, 0.0]), n_steps=20,
                args=100.0, max_recoveries=-1)
