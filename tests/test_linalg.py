"""The small dense solves used inside the step, and the mass-matrix check of solve."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import lobattodae as L
from lobattodae._linalg import UNROLL_MAX, small_solve, spd_solve


@pytest.mark.parametrize("n", [1, 2, 3, 5, UNROLL_MAX, UNROLL_MAX + 3])
def test_spd_solve_matches_numpy(n):
    rng = np.random.default_rng(n)
    b = rng.standard_normal((n, n))
    a = b @ b.T + 0.1 * np.eye(n)  # SPD, condition number up to ~1e3
    rhs = rng.standard_normal(n)
    x = np.asarray(jax.jit(spd_solve)(jnp.asarray(a), jnp.asarray(rhs)))
    expected = np.linalg.solve(a, rhs)
    np.testing.assert_allclose(x, expected, rtol=1e-11 * np.linalg.cond(a), atol=0)
    # and its derivative (the stage Jacobian differentiates through it)
    da = rng.standard_normal((n, n))
    da = da + da.T
    _, dx = jax.jvp(lambda aa: spd_solve(aa, jnp.asarray(rhs)), (jnp.asarray(a),), (jnp.asarray(da),))
    np.testing.assert_allclose(dx, -np.linalg.solve(a, da @ expected), rtol=1e-9, atol=1e-12)
    # reverse mode (the gradient path transposes the derivative rule): ∂(cᵀx)/∂b = a⁻ᵀc, and
    # along the symmetric da (LAPACK's Cholesky reads one triangle of a) −(a⁻ᵀc)ᵀ da x
    c = rng.standard_normal(n)
    ga, gb = jax.grad(lambda aa, bb: jnp.dot(jnp.asarray(c), spd_solve(aa, bb)), argnums=(0, 1))(
        jnp.asarray(a), jnp.asarray(rhs))
    adj = np.linalg.solve(a.T, c)
    np.testing.assert_allclose(gb, adj, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(np.sum(ga * da), -adj @ da @ expected, rtol=1e-9, atol=1e-12)
    # second derivative along da (the stage Jacobian of a field that itself holds a jvp):
    # d²x[da, da] = 2 a⁻¹ da a⁻¹ da x
    second = jax.jvp(lambda aa: jax.jvp(lambda a2: spd_solve(a2, jnp.asarray(rhs)), (aa,), (jnp.asarray(da),))[1],
                     (jnp.asarray(a),), (jnp.asarray(da),))[1]
    np.testing.assert_allclose(second, 2 * np.linalg.solve(a, da @ np.linalg.solve(a, da @ expected)),
                               rtol=1e-8 * np.linalg.cond(a), atol=1e-11)


def test_spd_solve_is_public_and_batches_like_a_problem_function():
    """``lobattodae.spd_solve`` is this solve, for mass matrices in users' g: under ``vmap`` (the
    stages) it equals NumPy's solve of every system."""
    assert L.spd_solve is spd_solve
    rng = np.random.default_rng(3)
    mats = rng.normal(size=(5, 7, 7))
    mats = mats @ mats.transpose(0, 2, 1) + 7 * np.eye(7)
    rhs = rng.normal(size=(5, 7))
    x = jax.vmap(L.spd_solve)(jnp.asarray(mats), jnp.asarray(rhs))
    np.testing.assert_allclose(x, np.linalg.solve(mats, rhs[..., None])[..., 0], rtol=1e-12, atol=1e-14)


@pytest.mark.parametrize("m", [1, 2, 3])
def test_small_solve_matches_numpy(m):
    rng = np.random.default_rng(10 + m)
    a = rng.standard_normal((m, m)) + 2 * np.eye(m)
    rhs = rng.standard_normal(m)
    np.testing.assert_allclose(small_solve(jnp.asarray(a), jnp.asarray(rhs)), np.linalg.solve(a, rhs), rtol=1e-13, atol=1e-14)


def _disk_like(mass):
    return L.MechanicalSystem(
        mass_matrix=lambda t, q, args: mass,
        potential=lambda t, q, args: 0.5 * q @ q,
        constraint_matrix=lambda t, q, args: jnp.array([[-q[1], 0.0, 1.0]]),
    )


@pytest.mark.parametrize(
    "mass, needle",
    [
        (jnp.array([[1.0, 0.5, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]), "must be symmetric"),
        (jnp.diag(jnp.array([1.0, -1.0, 1.0])), "must be positive definite"),
        (jnp.diag(jnp.array([1.0, 0.0, 1.0])), "must be positive definite"),
        (jnp.eye(2), r"must return an array of shape \(3, 3\)"),
    ],
)
def test_bad_mass_matrix_is_rejected(mass, needle):
    with pytest.raises(L.ShapeError, match=needle):
        L.solve(_disk_like(mass), L.LobattoIIIAIIIB(stages=2), (0.0, 1.0), [0.0, 0.0, 0.0], [1.0, 1.0, 0.0], n_steps=4)


def test_good_mass_matrix_accepted_and_matches_nonholonomic_form():
    """MechanicalSystem with M = diag(1, 2, 3) equals the NonholonomicSystem with the same H."""
    mass = jnp.diag(jnp.array([1.0, 2.0, 3.0]))
    mech = _disk_like(mass)
    nh = L.NonholonomicSystem(
        hamiltonian=lambda t, q, p, args: 0.5 * p @ jnp.linalg.solve(mass, p) + 0.5 * q @ q,
        constraint_matrix=lambda t, q, args: jnp.array([[-q[1], 0.0, 1.0]]),
    )
    kw = dict(n_steps=20)
    a = L.solve(mech, L.LobattoIIIAIIIB(stages=3), (0.0, 1.0), [0.0, 0.0, 0.0], [1.0, 1.0, 0.0], **kw)
    b = L.solve(nh, L.LobattoIIIAIIIB(stages=3), (0.0, 1.0), [0.0, 0.0, 0.0], [1.0, 1.0, 0.0], **kw)
    np.testing.assert_allclose(a.q, b.q, atol=1e-13)
    np.testing.assert_allclose(a.lam, b.lam, atol=1e-12)
