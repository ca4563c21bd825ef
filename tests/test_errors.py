"""Every error path: kind and message."""

import jax.numpy as jnp
import numpy as np
import pytest

import lobattodae as L
from lobattodae.examples import get_example


@pytest.fixture(scope="module")
def particle():
    return get_example("particle")


def _solve(ex, **kw):
    kw.setdefault("n_steps", 10)
    method = kw.pop("method", L.LobattoIIIAIIIB(stages=2))
    q0 = kw.pop("q0", ex.q0)
    p0 = kw.pop("p0", ex.p0)
    t_span = kw.pop("t_span", ex.t_span)
    return L.solve(ex.problem, method, t_span, q0, p0, args=ex.args, **kw)


@pytest.mark.parametrize("s", [1, 0, -3])
def test_too_few_stages(s):
    with pytest.raises(ValueError, match="s must be an integer >= 2"):
        L.LobattoIIIAIIIB(stages=s)


def test_non_integer_stages():
    with pytest.raises(TypeError):
        L.LobattoIIIAIIIB(stages=2.5)


def test_bad_lam_start():
    with pytest.raises(ValueError, match="lam_start must be 'auto'.*'previous'.*'consistent'"):
        L.LobattoIIIAIIIB(stages=3, lam_start="zero")


def test_shape_mismatch_q_p(particle):
    with pytest.raises(L.ShapeError, match="same shape"):
        _solve(particle, p0=np.ones(4))


def test_q0_not_1d(particle):
    with pytest.raises(L.ShapeError, match=r"1-D array of shape \(n,\)"):
        _solve(particle, q0=np.zeros((3, 1)))


def test_nonfinite_initial_values(particle):
    with pytest.raises(L.ShapeError, match="non-finite"):
        _solve(particle, q0=np.array([0.0, np.nan, 0.0]))


def test_lam0_wrong_shape(particle):
    with pytest.raises(L.ShapeError, match=r"lam0 must have shape \(m,\) = \(1,\)"):
        _solve(particle, lam0=np.ones(2))


def test_user_function_wrong_output_shape():
    prob = L.PartitionedDAE(
        f=lambda t, q, p, a: p[:2],
        g=lambda t, q, p, lam, a: -q,
        phi=lambda t, q, p, a: jnp.array([p[0]]),
    )
    with pytest.raises(L.ShapeError, match=r"f\(t, q, p, args\) must return an array of shape \(3,\)"):
        L.solve(prob, L.LobattoIIIAIIIB(stages=2), (0, 1), np.zeros(3), np.zeros(3), n_steps=2)


def test_user_function_raises():
    def bad_phi(t, q, p, a):
        raise KeyError("oops")

    prob = L.PartitionedDAE(lambda t, q, p, a: p, lambda t, q, p, lam, a: -q, bad_phi)
    with pytest.raises(L.ProblemFunctionError, match="calling phi.*KeyError.*problem's function") as info:
        L.solve(prob, L.LobattoIIIAIIIB(stages=2), (0, 1), np.zeros(3), np.zeros(3), n_steps=2)
    assert isinstance(info.value.__cause__, KeyError) and isinstance(info.value, L.LobattoDAEInputError)
    assert not isinstance(info.value, L.ShapeError)


def test_inconsistent_initial_values(particle):
    with pytest.raises(L.InconsistentInitialValuesError, match=r"violate the constraint.*project_initial=True"):
        _solve(particle, p0=np.array([1.0, 1.0, 0.5]))


def test_inconsistent_initial_values_projected(particle):
    sol = _solve(particle, p0=np.array([1.0, 1.0, 0.5]), project_initial=True)
    assert sol.success
    phi0 = particle.problem.phi(0.0, jnp.asarray(sol.q[0]), jnp.asarray(sol.p[0]), particle.args)
    assert float(jnp.max(jnp.abs(phi0))) < 1e-14
    assert np.max(sol.stats["constraint_residual"]) < 1e-13


def test_inconsistent_lambda0(particle):
    with pytest.raises(L.InconsistentInitialValuesError, match=r"lam0 violates the hidden constraint.*lam0 = \[1\.\]"):
        _solve(particle, lam0=np.array([3.0]))


def test_consistent_lambda0_accepted(particle):
    sol = _solve(particle, lam0=particle.lam0)
    np.testing.assert_array_equal(sol.lam[0], particle.lam0)


def test_singular_holonomic_constraint():
    # φ(q) = q_0 does not depend on p: D_pφ D_λg = 0, the problem is index 3.
    prob = L.PartitionedDAE(
        f=lambda t, q, p, a: p,
        g=lambda t, q, p, lam, a: -q + jnp.array([lam[0], 0.0]),
        phi=lambda t, q, p, a: jnp.array([q[0]]),
    )
    with pytest.raises(L.SingularConstraintError, match="holonomic constraint .* must be differentiated"):
        L.solve(prob, L.LobattoIIIAIIIB(stages=2), (0, 1), np.zeros(2), np.array([0.0, 1.0]), n_steps=2)


def test_repeated_constraint_is_singular():
    prob = L.NonholonomicSystem(
        lambda t, q, p, a: 0.5 * p @ p,
        lambda t, q, a: jnp.array([[-q[1], 0.0, 1.0], [-q[1], 0.0, 1.0]]),
    )
    with pytest.raises(L.SingularConstraintError, match="singular"):
        L.solve(prob, L.LobattoIIIAIIIB(stages=2), (0, 1), np.zeros(3), np.array([1.0, 1.0, 0.0]), n_steps=2)


@pytest.mark.parametrize(
    "kw, match",
    [
        ({"t_span": (0.0, 0.0)}, "empty"),
        ({"t_span": (1e16, 1e16 + 2)}, "resolution of t"),
        ({"n_steps": None, "dt": 1e-12}, "more than"),
        ({"n_steps": None, "dt": 1e-300}, "more than"),
        ({"t_span": (0.0, np.inf)}, "finite"),
        ({"t_span": 3.0}, "pair"),
        ({"n_steps": 0}, "positive integer"),
        ({"n_steps": -5}, "positive integer"),
        ({"n_steps": 2.5}, "positive integer"),
        ({"n_steps": None, "dt": -0.1}, "positive finite step"),
        ({"n_steps": 10, "dt": 0.1}, "at most one"),
        ({"n_steps": 10, "rtol": 1e-6}, "applies to adaptive steps"),
        ({"n_steps": None, "rtol": 0.0}, "rtol must be a positive"),
        ({"n_steps": None, "rtol": float("nan")}, "rtol must be a positive"),
        ({"n_steps": None, "rtol": 1e-17}, "below what float64"),
        ({"n_steps": None, "atol": -1.0}, "atol must be a non-negative"),
        ({"n_steps": None, "first_step": -0.5}, "first_step must be a non-negative"),
        ({"n_steps": None, "first_step": 5.0}, "longer than the interval"),
        ({"n_steps": None, "max_step": -1.0}, "max_step must be a positive"),
        ({"n_steps": None, "t_eval": [0.5, 0.2]}, "sorted in the direction"),
        ({"n_steps": None, "t_eval": [0.5, 3.0]}, "within t_span"),
        ({"n_steps": None, "t_eval": [0.5, np.nan]}, "NaN"),
        ({"n_steps": None, "t_eval": [0.5], "save_every": 3}, "not both"),
        ({"n_steps": None, "save_every": 0}, "save_every must be"),
        ({"n_steps": None, "events": 3.0}, "events must be"),
        ({"n_steps": None, "max_recoveries": 2}, "adaptive steps recover"),
    ],
)
def test_bad_interval_and_step_arguments(particle, kw, match):
    with pytest.raises(L.LobattoDAEInputError, match=match):
        _solve(particle, **kw)


def test_method_must_be_a_method_object(particle):
    with pytest.raises(TypeError, match="LobattoIIIAIIIB"):
        _solve(particle, method=3)


def _stiff_particle():
    return L.NonholonomicSystem(
        lambda t, q, p, a: 0.5 * p @ p + a * q[0] ** 4,
        lambda t, q, a: jnp.array([[-q[1], 0.0, 1.0]]),
    )


def test_newton_failure_raises_with_step_and_time():
    prob = _stiff_particle()
    with pytest.raises(L.NewtonFailure, match=r"Step 0 \(t = 0, h = 5\) failed: Newton") as info:
        L.solve(prob, L.LobattoIIIAIIIB(stages=3), (0, 10), np.zeros(3), np.array([1.0, 1.0, 0.0]), n_steps=2,
                args=1e4)
    assert info.value.step == 0 and info.value.t == 0.0
    assert isinstance(info.value, RuntimeError)


def test_newton_failure_status_without_throw_returns_prefix():
    prob = _stiff_particle()
    # a step size that works for a while, then fails as the particle accelerates
    sol = L.solve(prob, L.LobattoIIIAIIIB(stages=3), (0, 10), np.zeros(3), np.array([1.0, 1.0, 0.0]), n_steps=2,
                  args=1e4, throw=False)
    assert not sol.success
    assert sol.result in (L.Result.DIVERGED, L.Result.MAX_ITERATIONS, L.Result.NONFINITE)
    assert "Step 0" in sol.message
    assert sol.stats["failed_step"] == 0
    assert len(sol.t) == 1 and np.all(np.isfinite(sol.q))  # only the initial point


def test_failure_midway_keeps_finite_prefix():
    prob = _stiff_particle()
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
