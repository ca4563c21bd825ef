"""Solution's views in scipy's layout and vocabulary, checked against ``scipy.integrate.solve_ivp``
on the same ODE.

The problem: a planar harmonic oscillator with a third coordinate z held by the constraint
z' = 0 (μ = (0, 0, 1), λ ≡ 0), so that its (q₁, q₂, p₁, p₂) are solve_ivp's four unknowns.
"""

import jax.numpy as jnp
import numpy as np
import pytest
from scipy.integrate import solve_ivp

import lobattodae as L

N, M = 3, 1
T_SPAN = (0.0, 3.0)
Q0, P0 = np.array([1.0, 0.0, 0.0]), np.array([0.0, 0.5, 0.0])
TOL = dict(rtol=1e-10, atol=1e-12)

OSCILLATOR = L.NonholonomicSystem(
    hamiltonian=lambda t, q, p, args: 0.5 * p @ p + 0.5 * (q[0] ** 2 + q[1] ** 2),
    constraint_matrix=lambda t, q, args: jnp.array([[0.0, 0.0, 1.0]]),
)
METHOD = L.LobattoIIIAIIIB(stages=4)


def _rhs(t, y):
    return np.array([y[2], y[3], -y[0], -y[1]])


def _scipy(**kw):
    return solve_ivp(_rhs, T_SPAN, np.r_[Q0[:2], P0[:2]], method="DOP853", **TOL, **kw)


def _ours(**kw):
    return L.solve(OSCILLATOR, METHOD, T_SPAN, Q0, P0, **TOL, **kw)


# rows of our y that are scipy's y: q₁, q₂ (0, 1) and p₁, p₂ (3, 4)
SHARED = [0, 1, N, N + 1]


def _falls_through_half(t, q, p, args):
    return q[0] - 0.5


def _falls_through_half_scipy(t, y):
    return y[0] - 0.5


@pytest.fixture(scope="module")
def both():
    t_eval = np.linspace(0.0, 3.0, 7)
    return _ours(t_eval=t_eval, dense_output=True), _scipy(t_eval=t_eval, dense_output=True)


def test_y_is_solve_ivps_stacked_layout(both):
    ours, theirs = both
    assert ours.y.shape == (2 * N + M, len(ours.t)) and theirs.y.shape == (4, len(theirs.t))
    np.testing.assert_array_equal(ours.t, theirs.t)
    np.testing.assert_allclose(ours.y[SHARED], theirs.y, atol=1e-9)
    np.testing.assert_array_equal(ours.y, np.vstack([ours.q.T, ours.p.T, ours.lam.T]))


def test_status_integers_follow_scipy(both):
    ours, theirs = both
    assert ours.status == theirs.status == 0 and ours.result == L.Result.SUCCESSFUL
    _falls_through_half.terminal = True
    _falls_through_half_scipy.terminal = True
    stopped, scipy_stopped = _ours(events=_falls_through_half), _scipy(events=_falls_through_half_scipy)
    assert stopped.status == scipy_stopped.status == 1 and stopped.result == L.Result.EVENT
    short = _ours(max_steps=2, chunk_size=2)  # the cap is checked between chunks
    assert short.status == -1 and short.result == L.Result.MAX_STEPS and not short.success


def test_every_result_has_a_scipy_status_that_agrees_with_success():
    for result in L.Result:
        status = L._solution.SCIPY_STATUS.get(result, -1)
        assert status in (-1, 0, 1) and (status >= 0) == result.success


def test_events_agree_with_solve_ivp_in_times_and_states():
    _falls_through_half.terminal = False
    _falls_through_half_scipy.terminal = False
    ours, theirs = _ours(events=_falls_through_half), _scipy(events=_falls_through_half_scipy)
    assert len(ours.t_events) == len(theirs.t_events) == 1
    np.testing.assert_allclose(ours.t_events[0], theirs.t_events[0], atol=1e-9)
    (y_events,) = ours.y_events
    assert y_events.shape == (len(ours.t_events[0]), 2 * N + M) and theirs.y_events[0].shape[1] == 4
    np.testing.assert_allclose(y_events[:, SHARED], theirs.y_events[0], atol=1e-9)
    assert _ours().y_events is None


def test_dense_output_in_scipys_layout(both):
    ours, theirs = both
    t = np.array([0.1, 1.3, 2.9])
    stacked = ours.sol(t, layout="scipy")
    assert stacked.shape == (2 * N + M, 3) and theirs.sol(t).shape == (4, 3)
    np.testing.assert_array_equal(stacked, np.vstack([x.T for x in ours.sol(t)]))
    np.testing.assert_allclose(stacked[SHARED], theirs.sol(t), atol=1e-7)  # interpolants of order ~s, 7
    one = ours.sol(1.3, layout="scipy")
    assert one.shape == (2 * N + M,) and theirs.sol(1.3).shape == (4,)
    np.testing.assert_array_equal(one, stacked[:, 1])
    with pytest.raises(L.LobattoDAEInputError, match="layout must be one of"):
        ours.sol(1.3, layout="columns")


def test_counters_speak_scipys_names(both):
    ours, _ = both
    st = ours.stats
    assert ours.nfev == METHOD.stages * st["n_newton"] > 0
    assert ours.njev == ours.nlu == st["n_jacobians"] >= 1


def test_stats_keys_are_public_and_documented(both):
    ours, _ = both
    assert set(ours.stats) == set(L.STATS)
    assert all(isinstance(text, str) and text for text in L.STATS.values())
