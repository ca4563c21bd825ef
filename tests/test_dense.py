"""Dense output between step points (issue #10): observed orders of q, p, λ and of ‖φ‖.

The orders asserted here were measured with ``benchmarks/dense_output.py`` (tables in
``docs/variable-steps.md``) on the Chaplygin sleigh, with constant steps and evaluation
points strictly inside the steps (no Lobatto node): q (the IIIA collocation polynomial) has
order s, p (the polynomial through the IIIA momenta p̃_i) order s + 1 on this problem (its
mass matrix is constant) with the consistent start multiplier and for even s, λ (the
interpolant of the stage multipliers) order s with the consistent start and for even s
(s - 1 for odd s with the paper's Λ_1 = λ_n), and ‖φ‖ between the nodes order s. Each fit
uses errors well above the round-off plateau; a dense output one order less accurate fails.
Measured fits (2026-11-23): s = 3, consistent: q 3.00, p 3.99, λ 2.99, ‖φ‖ 2.96; s = 4, auto:
q 3.96, p 4.96, λ 4.03, ‖φ‖ 4.09.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import lobattodae as L

#: Evaluation points per step, θ = (k + 1/2)/N_THETA (none is a Lobatto node for s ≤ 5).
N_THETA = 8
#: Largest accepted |fitted - expected| order (measured deviations ≤ 0.09, see the module docstring).
ORDER_TOL = 0.25
#: (s, lam_start) -> step counts on t_span = (0, 2) and expected orders of the max error
#: inside the steps of q, p, λ and of max ‖φ(t, q(t), p(t))‖∞ there.
CASES = {
    (3, "consistent"): ((16, 24, 32, 48), {"q": 3, "p": 4, "lam": 3, "phi": 3}),
    (4, "auto"): ((8, 12, 16, 24), {"q": 4, "p": 5, "lam": 4, "phi": 4}),
}
#: Smallest errors used in the fits must stay above these levels (round-off is ~1e-15 for
#: q, p, φ and ~1e-13 for λ, which is solved through Z = hΛ).
FLOOR = {"q": 1e-12, "p": 1e-12, "lam": 1e-10, "phi": 1e-12}


@pytest.fixture(scope="module")
def phi_along(sleigh):
    return jax.jit(jax.vmap(lambda t, q, p: sleigh.problem.phi(t, q, p, sleigh.args)))


def _inside(t, theta):
    return (t[:-1, None] + np.asarray(theta)[None, :] * np.diff(t)[:, None]).ravel()


@pytest.mark.parametrize("s, lam_start", list(CASES))
def test_dense_output_orders_between_step_points(sleigh, phi_along, s, lam_start):
    counts, expected = CASES[(s, lam_start)]
    method = L.LobattoIIIAIIIB(stages=s, lam_start=lam_start)
    theta = (np.arange(N_THETA) + 0.5) / N_THETA
    errors = {c: [] for c in expected}
    for n in counts:
        sol = L.solve(sleigh.problem, method, sleigh.t_span, sleigh.q0, sleigh.p0, args=sleigh.args, n_steps=n,
                      dense_output=True)
        t = _inside(sol.t, theta)
        q, p, lam = sol.sol(t)
        qe, pe, le = sleigh.exact(t)
        errors["q"].append(np.abs(q - qe).max())
        errors["p"].append(np.abs(p - pe).max())
        errors["lam"].append(np.abs(lam - le).max())
        errors["phi"].append(np.abs(np.asarray(phi_along(jnp.asarray(t), jnp.asarray(q), jnp.asarray(p)))).max())
    h = 2.0 / np.asarray(counts, float)
    for c, order in expected.items():
        err = np.asarray(errors[c])
        assert err.min() > FLOOR[c], (c, err)  # the fit is above the round-off plateau
        fitted = np.polyfit(np.log(h), np.log(err), 1)[0]
        assert abs(fitted - order) < ORDER_TOL, (s, lam_start, c, fitted, err)


def test_dense_momenta_satisfy_the_constraint_at_the_nodes(sleigh, phi_along):
    """v passes through the IIIA momenta p̃_i, where φ = 0 is imposed: ‖φ‖ on the dense output
    is at round-off at every Lobatto node and only between them of the size of the
    interpolation error. (Same method as the s = 3 case above: no extra compilation.)"""
    method = L.LobattoIIIAIIIB(stages=3, lam_start="consistent")
    sol = L.solve(sleigh.problem, method, sleigh.t_span, sleigh.q0, sleigh.p0, args=sleigh.args, n_steps=16,
                  dense_output=True)

    def phi_max(theta):
        t = _inside(sol.t, theta)
        q, p, _ = sol.sol(t)
        return np.abs(np.asarray(phi_along(jnp.asarray(t), jnp.asarray(q), jnp.asarray(p)))).max()

    assert phi_max(L.lobatto_pair(3).c) < 1e-14
    assert phi_max([0.25, 0.75]) > 1e-8  # between the nodes: the interpolation error (measured 2.5e-6)


def test_projected_dense_output_satisfies_the_constraints_at_order_s(sleigh, phi_along):
    """``sol(t, project=True)``: φ to round-off between the nodes (where the interpolant misses
    it by ~1e-6), and p and λ still of order s against the closed form (the projection moves them
    by the interpolation error of q, order s: p, of order s + 1 on the sleigh, drops to s)."""
    method = L.LobattoIIIAIIIB(stages=3, lam_start="consistent")
    errors = []
    for n in (16, 32):
        sol = L.solve(sleigh.problem, method, sleigh.t_span, sleigh.q0, sleigh.p0, args=sleigh.args, n_steps=n,
                      dense_output=True)
        t = _inside(sol.t, [0.25, 0.75])
        q, p, lam = sol.sol(t)
        qp, pp, lamp = sol.sol(t, project=True)
        np.testing.assert_array_equal(qp, q)  # no position constraint: q is left alone
        assert np.abs(np.asarray(phi_along(jnp.asarray(t), jnp.asarray(q), jnp.asarray(p)))).max() > 1e-8
        assert np.abs(np.asarray(phi_along(jnp.asarray(t), jnp.asarray(qp), jnp.asarray(pp)))).max() < 1e-14
        qe, pe, le = sleigh.exact(t)
        errors.append((np.abs(pp - pe).max(), np.abs(lamp - le).max()))
    orders = np.log2(np.asarray(errors[0]) / np.asarray(errors[1]))
    assert np.all(orders > 3 - ORDER_TOL), (orders, errors)
    stacked = sol.sol(t[3], layout="scipy", project=True)
    np.testing.assert_allclose(stacked, np.concatenate([qp[3], pp[3], lamp[3]]), rtol=0, atol=1e-15)
    with pytest.raises(L.LobattoDAEInputError, match="project must be True or False"):
        sol.sol(t, project="yes")
