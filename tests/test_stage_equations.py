"""The stage equations (lobattodae._stage_equations): the structured stage Jacobian (per-stage
blocks assembled from the coefficients) equals forward-mode autodiff of the whole stage
residual, the one by forward differences equals it to √ε, the three Newton variants give the
same solution, the residual vanishes at a converged step, the layout round-trips, and the
predictor evaluated at times is exact on polynomials."""

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import lobattodae as L
from lobattodae import _stage_equations as se
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
    n, m = q0.shape[0], lam0.shape[0]
    params = se.StageParams(jnp.asarray(0.3), jnp.asarray(h), q0, p0, lam0, ex.args)
    layout = se.Layout(s, n, m)

    def residual(x):
        return se.stage_residual(ex.problem, method.pair, layout, x, params)

    def structured(x):
        return se.stage_jacobian(ex.problem, method.pair, layout, x, params)

    rng = np.random.default_rng(s)
    # a generic point: stages scattered around the initial values
    x = layout.pack(
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
    # forward differences: the same residual, the same matrix to about √ε (1.5e-8) relative
    r_d, jac_d = jax.jit(lambda y: se.stage_jacobian_differences(ex.problem, method.pair, layout, y, params))(x)
    np.testing.assert_allclose(r_d, r_s, rtol=0, atol=1e-14)
    error = float(jnp.max(jnp.abs(jac_d - jac_a))) / scale
    assert 0 < error < 1e-6, error


@pytest.mark.parametrize("name", EXAMPLES)
def test_newton_matrices_agree(name):
    """The three ways of making Newton's matrix converge to the same stages: the exact two with
    the same iterations, the differences to round-off, with at most one more iteration a step."""
    ex = get_example(name)
    sols = {
        kind: L.solve(ex.problem, L.LobattoIIIAIIIB(stages=3, jacobian=kind), (0.0, 2.0), ex.q0, ex.p0,
                      n_steps=40, args=ex.args)
        for kind in ("structured", "autodiff", "differences")
    }
    a = sols["structured"]
    for kind in ("autodiff", "differences"):
        b = sols[kind]
        np.testing.assert_allclose(a.q, b.q, rtol=0, atol=1e-12)
        np.testing.assert_allclose(a.p, b.p, rtol=0, atol=1e-12)
        np.testing.assert_allclose(a.lam, b.lam, rtol=0, atol=1e-10)
    np.testing.assert_array_equal(a.stats["newton_iterations"], sols["autodiff"].stats["newton_iterations"])
    extra = np.asarray(sols["differences"].stats["newton_iterations"]) - np.asarray(a.stats["newton_iterations"])
    assert np.max(np.abs(extra)) <= 1, extra


def test_forward_differences():
    """Columns (fun(z + δ_j e_j) − fun(z)) / δ_j with δ_j = √ε max(1, |z_j|): an affine map's
    matrix up to round-off, a curved map's derivative to about √ε, also at z_j = 0 and for
    large |z_j|."""
    a = jnp.asarray([[2.0, -1.0, 0.5], [0.0, 3.0, 10.0]])
    z = jnp.asarray([0.0, 1.5, -2e3])
    value, jac = se.forward_differences(lambda y: a @ y + 1.0, z)
    np.testing.assert_allclose(value, a @ z + 1.0, rtol=1e-15)
    np.testing.assert_allclose(jac, a, rtol=0, atol=1e-5)

    def curved(y):
        return jnp.stack([jnp.sin(y[0]) * y[1], jnp.exp(y[1] / 3), 1e-3 * y[2] ** 2])

    value, jac = se.forward_differences(curved, z)
    exact = jax.jacfwd(curved)(z)
    np.testing.assert_allclose(value, curved(z), rtol=1e-15)
    np.testing.assert_allclose(jac, exact, rtol=3e-8, atol=3e-8)
    assert float(jnp.max(jnp.abs(jac - exact))) > 0  # differences, not derivatives


def test_bad_jacobian_option():
    with pytest.raises(ValueError, match="jacobian must be 'differences'"):
        L.LobattoIIIAIIIB(stages=3, jacobian="numeric")


def test_layout_round_trip():
    layout = se.Layout(4, 3, 2)
    rng = np.random.default_rng(0)
    Q, P, Z = rng.standard_normal((4, 3)), rng.standard_normal((4, 3)), rng.standard_normal((4, 2))
    params = se.StageParams(0.0, jnp.asarray(0.5), jnp.asarray(Q[0]), jnp.zeros(3), jnp.asarray(Z[0] / 0.5), None)
    x = layout.pack(jnp.asarray(Q), jnp.asarray(P), jnp.asarray(Z))
    assert x.shape == (layout.size,) == (L.LobattoIIIAIIIB(stages=4).n_unknowns(3, 2),)
    Q2, P2, Z2 = layout.unpack(x, params)
    np.testing.assert_allclose(Q2, Q, rtol=0, atol=1e-15)
    np.testing.assert_allclose(P2, P, rtol=0, atol=0)
    np.testing.assert_allclose(Z2, Z, rtol=0, atol=1e-15)


@pytest.mark.parametrize("s", [2, 3, 5])
def test_tableau_product_matches_matmul(s):
    pair = L.lobatto_pair(s)
    rng = np.random.default_rng(s)
    for shape in ((s, 4), (s, 2, 3)):
        x = jnp.asarray(rng.standard_normal(shape))
        for coef in (pair.a, pair.a_hat, pair.a[1:], pair.b[None]):
            expected = np.tensordot(coef, np.asarray(x), axes=1)
            np.testing.assert_allclose(se.tableau_product(coef, x), expected, rtol=1e-14, atol=1e-15)
    assert np.all(se.tableau_product(pair.a[:1], x) == 0.0)  # IIIA's first row is zero


@pytest.mark.parametrize("ratio", [1.0, 0.5, 1.7])
def test_predictor_is_exact_on_polynomial_slopes(ratio):
    """Slopes that are polynomials of degree s-1 in t are extrapolated exactly to the new stage
    times, also when the step size changes (the predictor works with times, not step counts)."""
    s = 4
    pair = L.lobatto_pair(s)
    layout = se.Layout(s, 1, 1)
    h_prev, h = 0.1, 0.1 * ratio
    poly = np.array([0.3, -1.0, 2.0, 0.5])  # degree 3 = s - 1
    t_prev = h_prev * pair.c  # the previous step's stage times, ending at t0 = h_prev
    slopes = tuple(jnp.asarray(np.polyval(poly * k, t_prev)[:, None]) for k in (1.0, 2.0, -1.0))
    zero = tuple(jnp.zeros((s, 1)) for _ in range(3))
    params = se.StageParams(jnp.asarray(h_prev), jnp.asarray(h), jnp.zeros(1), jnp.zeros(1), jnp.zeros(1), None)
    _, plain = se.predict_stages(pair, layout, params, slopes, zero, jnp.asarray(h_prev))
    t_new = h_prev + h * pair.c
    for k, got in zip((1.0, 2.0, -1.0), plain):
        np.testing.assert_allclose(np.asarray(got)[:, 0], np.polyval(poly * k, t_new), rtol=1e-12, atol=1e-13)


@pytest.mark.parametrize("s", [3])
def test_residual_vanishes_at_a_solved_step(s):
    ex = get_example("falling-disk-general")
    method = L.LobattoIIIAIIIB(stages=s)
    q0, p0, lam0 = map(jnp.asarray, (ex.q0, ex.p0, ex.lam0))
    step = jax.jit(lambda q, p, lam: method.step(ex.problem, 0.0, q, p, lam, 0.05, ex.args))
    q1, p1, lam1, info, state = step(q0, p0, lam0)
    assert int(info.result) == 0
    # the constraint holds at the step point (H3: a_sj = b_j), to round-off
    assert float(jnp.max(jnp.abs(ex.problem.phi(0.05, q1, p1, ex.args)))) < 1e-14


def _sleigh_turning(omega):
    """The sleigh on straight motion at speed √2 with turning rate ``omega``: its decay rate k
    and ``factor(s, h)``, the factor by which one step of s stages multiplies the turning rate."""
    ex = get_example("sleigh")
    a = ex.args
    v = np.sqrt(2.0)
    k = a.m * a.a * v / (a.I + a.m * a.a**2)
    q0, p0 = np.zeros(3), np.array([a.m * v, a.m * a.a * omega, a.I * omega])
    lam0 = L.consistent_lambda(ex.problem, 0.0, q0, p0, np.zeros(1), a)

    @functools.lru_cache(maxsize=None)
    def step(s):
        method = L.LobattoIIIAIIIB(stages=s)
        return jax.jit(lambda h: method.step(ex.problem, 0.0, q0, p0, lam0, h, a))

    def factor(s, h):
        _, p1, _, info, _ = step(s)(h)
        assert int(info.result) == 0
        return float(p1[2] / p0[2])

    return k, factor


def test_a_constraint_damped_mode_is_integrated_explicitly():
    """The sleigh on straight motion: its turning rate decays like exp(-k t) through the
    constraint, and one step multiplies it by R(h). For s = 2 the scheme gives exactly the
    Taylor polynomial 1 + z + z²/2 (z = -k h), as an explicit second-order method would; for
    s = 4 R is accurate for small h but exceeds 1 beyond k h ≈ 9.65 (the step-size limit
    documented in docs/variable-steps.md §2, benchmarks/stability_limit.py)."""
    k, factor = _sleigh_turning(1e-6)
    for h in (0.5, 2.0, 4.0, 8.0):
        z = -k * h
        assert factor(2, h) == pytest.approx(1 + z + z**2 / 2, rel=1e-6, abs=1e-9)
    assert factor(4, 1.0) == pytest.approx(np.exp(-k), rel=1e-4)
    assert abs(factor(4, 12.0)) < 1 < abs(factor(4, 16.0))


@pytest.mark.parametrize("s", [2, 3, 4, 5, 6])
def test_a_constraint_damped_mode_is_multiplied_by_the_s_s_minus_2_pade_function(s):
    """What step doubling's estimate assumes of such a mode (``LobattoPair.constraint_stability``):
    the sleigh's factor over one step equals the (s, s−2) Padé approximant of e^z, from the
    resolved range (k h = 0.35) to far beyond the stability limit (k h = 21, where the diagonal
    Padé function of ODE modes would stay below 1 in modulus)."""
    k, factor = _sleigh_turning(1e-9)
    pair = L.lobatto_pair(s)
    for h in (0.5, 3.0, 10.0, 30.0):
        expected = pair.constraint_stability(-k * h).real
        assert factor(s, h) == pytest.approx(expected, rel=1e-5, abs=1e-7), h


def test_step_values_sum_the_increment_with_compensation():
    """Row (4) as compensated summation: ``y_1 + compensation_1`` is ``y_0 + δ`` exactly (checked
    in rational arithmetic; s = 2, h = 1/2 and equal stage slopes make ``h Σ b_j V_j`` exact),
    where a plain sum loses the low bits of δ against a large ``y_0``."""
    from fractions import Fraction

    pair = L.lobatto_pair(2)
    y0 = np.array([700.1234567890123, -3.0, 1e-3, 2.5e16])
    slope = np.array([0.123456789012345, 1.0, 1e-20, 3.0])
    carried = np.array([1.1e-14, -3e-17, 2e-22, 0.25])
    params = se.StageParams(jnp.asarray(0.0), jnp.asarray(0.5), jnp.asarray(y0[:2]), jnp.asarray(y0[2:]),
                            jnp.zeros(1), None)
    stages = se.Stages(jnp.zeros((2, 2)), jnp.zeros((2, 2)), jnp.zeros((2, 1)),
                       jnp.asarray([slope[:2]] * 2), jnp.asarray([slope[2:]] * 2))
    # every number an argument: XLA folds constants with reassociation, which no run meets
    q1, p1, _, lost = jax.jit(functools.partial(se.step_values, pair))(params, stages, jnp.asarray(carried))
    y1, lost = np.concatenate([q1, p1]), np.asarray(lost)
    for i in range(4):
        delta = Fraction(float(np.float64(0.5 * slope[i]) + carried[i]))  # as summed before the compensation
        assert Fraction(y1[i]) + Fraction(lost[i]) == Fraction(y0[i]) + delta, i
    assert np.all(lost[[0, 3]] != 0.0)  # what a plain sum would have lost
