"""The structured stage Jacobian (per-stage blocks assembled from the coefficients) equals
forward-mode autodiff of the whole stage residual, and both Newton variants give the same
solution."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import lobattodae as L
from lobattodae.examples import get_example

# NonholonomicSystems and a MechanicalSystem with a configuration-dependent mass matrix (m = 2)
EXAMPLES = ["particle-harmonic", "falling-disk-general", "contact-nonreversible"]


class _General:
    """A PartitionedDAE with t-dependent f, g nonlinear in λ and φ nonlinear in (q, p)."""

    problem = L.PartitionedDAE(
        f=lambda t, q, p, args: p + 0.1 * jnp.sin(t) * q[::-1] ** 2,
        g=lambda t, q, p, lam, args: -q * jnp.cos(p) + jnp.array([1.0, 0.5 * q[0]]) * (lam[0] + 0.2 * lam[0] ** 3),
        phi=lambda t, q, p, args: jnp.array([p[0] + 0.3 * p[1] ** 2 - jnp.sin(q[1]) + 0.1 * t]),
    )
    q0, p0, lam0, args = np.array([0.3, -0.2]), np.array([0.1, 0.4]), np.array([0.7]), None


def _case(name):
    return _General if name == "general" else get_example(name)


@pytest.mark.parametrize("name", [*EXAMPLES, "general"])
@pytest.mark.parametrize("s", [2, 3, 4, 5])
def test_structured_jacobian_equals_autodiff(name, s):
    ex = _case(name)
    q0, p0, lam0 = map(jnp.asarray, (ex.q0, ex.p0, ex.lam0))
    method = L.LobattoIIIAIIIB(stages=s)
    h = 0.07
    t0, hj = jnp.asarray(0.3), jnp.asarray(h)
    residual, structured, unpack, pack, _, _ = method._stage_system(ex.problem, t0, q0, p0, lam0, hj, ex.args)
    n, m = q0.shape[0], lam0.shape[0]
    rng = np.random.default_rng(s)
    # a generic point: stages scattered around the initial values
    x = pack(
        q0 + 0.05 * rng.standard_normal((s, n)),
        p0 + 0.05 * rng.standard_normal((s, n)),
        h * (lam0 + 0.1 * rng.standard_normal((s, m))),
    )
    r_s, jac_s = jax.jit(structured)(x)
    jac_a = jax.jit(jax.jacfwd(residual))(x)
    assert jac_s.shape == (method.n_unknowns(n, m),) * 2
    np.testing.assert_allclose(r_s, jax.jit(residual)(x), rtol=0, atol=1e-14)
    scale = float(jnp.max(jnp.abs(jac_a)))
    np.testing.assert_allclose(jac_s, jac_a, rtol=0, atol=1e-14 * scale)
    assert float(jnp.max(jnp.abs(jac_a - jnp.eye(jac_a.shape[0])))) > 1e-3  # not trivially the identity


@pytest.mark.parametrize("name", EXAMPLES)
def test_structured_and_autodiff_newton_agree(name):
    ex = get_example(name)
    sols = {
        kind: L.solve(ex.problem, L.LobattoIIIAIIIB(stages=3, jacobian=kind), (0.0, 2.0), ex.q0, ex.p0,
                      n_steps=40, args=ex.args)
        for kind in ("structured", "autodiff")
    }
    a, b = sols["structured"], sols["autodiff"]
    np.testing.assert_allclose(a.q, b.q, rtol=0, atol=1e-12)
    np.testing.assert_allclose(a.p, b.p, rtol=0, atol=1e-12)
    np.testing.assert_allclose(a.lam, b.lam, rtol=0, atol=1e-10)
    np.testing.assert_array_equal(a.stats["newton_iterations"], b.stats["newton_iterations"])


def test_bad_jacobian_option():
    with pytest.raises(ValueError, match="jacobian must be 'structured'"):
        L.LobattoIIIAIIIB(stages=3, jacobian="numeric")
