"""Tests of lobattodae.examples: closed forms against the DAE, first integrals, consistent
initial values, the registry and parameter overrides.

Derivatives of the exact solutions are taken by an 8th-order central finite difference
with step ``H_FD = 1e-2``: its truncation error is ``H_FD^8 |u^(9)| / 630`` (below 1e-16
for the frequencies used here, at most ~3) and its round-off error about
``eps · |u| · 1.7 / H_FD ≈ 4e-14 |u|``, so the DAE defects of a correct closed form are
~1e-13; ``TOL_DAE = 1e-11`` leaves a margin while a wrong sign or factor gives O(1e-1).
"""

from __future__ import annotations

import functools
import math
import zlib

import jax
import jax.numpy as jnp
import mpmath
import numpy as np
import pytest

import lobattodae  # noqa: F401  (enables float64)
from lobattodae.examples import (
    EXAMPLES,
    Example,
    chaplygin_sleigh,
    contact_oscillator,
    falling_rolling_disk,
    get_example,
    knife_edge,
    list_examples,
    nonholonomic_particle,
    steady_spin_rate,
    vertical_rolling_disk,
)

ALL_NAMES = [
    "particle",
    "particle-harmonic",
    "knife-edge",
    "sleigh",
    "vertical-disk",
    "falling-disk",
    "falling-disk-general",
    "contact",
    "contact-nonreversible",
]
CLOSED_FORM = ["particle", "knife-edge", "sleigh", "vertical-disk", "falling-disk"]

H_FD = 1e-2
FD_OFFSETS = np.arange(-4, 5)
FD_WEIGHTS = np.array(
    [1 / 280, -4 / 105, 1 / 5, -4 / 5, 0.0, 4 / 5, -1 / 5, 4 / 105, -1 / 280]
)
TOL_DAE = 1e-11
N_TIMES = 7

# Closed-form cases: defaults and overridden parameters, including the special branches
# (ω = 0 for the knife edge and the vertical disk, v = 0 for the particle, ω0 = 0 and
# ω0 < 0 for the sleigh).
CASES = [
    ("particle", {}),
    ("particle", dict(x0=0.3, y0=-0.5, z0=1.0, c=1.3, v=-0.7)),
    ("particle", dict(y0=0.4, v=0.0)),
    ("knife-edge", {}),
    ("knife-edge", dict(m=2.0, J=0.5, g=1.3, omega=2.5, theta0=0.4, v0=0.7, x0=1.0, y0=-1.0)),
    ("knife-edge", dict(omega=0.0, theta0=0.3, v0=0.5)),
    ("sleigh", {}),
    ("sleigh", dict(m=2.0, I=0.5, a=0.7, theta0=0.2, v0=0.3, omega0=-1.5, x0=0.5, y0=-0.2,
                    t_end=4.0)),
    ("sleigh", dict(v0=-0.4, omega0=0.8)),
    ("sleigh", dict(omega0=0.0, v0=0.7, theta0=0.3)),
    ("vertical-disk", {}),
    ("vertical-disk", dict(m=1.5, R=0.6, I=0.4, J=0.3, omega_phi=-1.3, omega_theta=2.2,
                           x0=0.2, y0=0.1, phi0=0.5, theta0=1.0)),
    ("vertical-disk", dict(omega_phi=0.0)),
    ("falling-disk", {}),
    ("falling-disk", dict(m=1.3, R=0.8, g=2.0, I1=0.3, I3=0.55, theta0=-0.4, Omega=-1.7,
                          phi0=0.3, psi0=0.2, x0=0.1, y0=-0.3)),
]


def _case_id(case):
    name, params = case
    return name + ("-" + "-".join(f"{k}={v}" for k, v in params.items()) if params else "")


@functools.lru_cache(maxsize=None)
def _example(name: str, params: tuple = ()) -> Example:
    return get_example(name, **dict(params))


def _get(case) -> Example:
    name, params = case
    return _example(name, tuple(sorted(params.items())))


# ----------------------------------------------------------------------------- helpers
@functools.partial(jax.jit, static_argnums=0)
def _ode_defects(problem, t, q, p, lam, dq, dp, args):
    """Per time: q' - f(t, q, p) and p' - g(t, q, p, λ)."""

    def one(t, q, p, lam, dq, dp):
        return dq - problem.f(t, q, p, args), dp - problem.g(t, q, p, lam, args)

    return jax.vmap(one)(t, q, p, lam, dq, dp)


def _fd_derivative(fun, t):
    """8th-order central difference of ``fun(t) -> (N, k)`` at the times ``t``."""
    tt = (t[:, None] + H_FD * FD_OFFSETS[None, :]).reshape(-1)
    vals = fun(tt).reshape(t.size, FD_OFFSETS.size, -1)
    return np.einsum("j,njk->nk", FD_WEIGHTS, vals) / H_FD


def _max_defects(ex: Example, exact, t) -> dict[str, float]:
    q, p, lam = exact(t)
    dq = _fd_derivative(lambda s: exact(s)[0], t)
    dp = _fd_derivative(lambda s: exact(s)[1], t)
    dq_f, dp_g = _ode_defects(ex.problem, *(jnp.asarray(a) for a in (t, q, p, lam, dq, dp)),
                              ex.args)
    # φ, hidden constraint and λ - consistent_lambda(...) at each time (one compilation
    # per problem, shared with the initial-value checks)
    per_time = [ex.consistency_residuals(t[i], q[i], p[i], lam[i]) for i in range(t.size)]
    return {
        "dq-f": float(np.max(np.abs(np.asarray(dq_f)))),
        "dp-g": float(np.max(np.abs(np.asarray(dp_g)))),
        "phi": max(r["phi"] for r in per_time),
        "hidden": max(r["hidden"] for r in per_time),
        "lam-consistent": max(r["lam"] for r in per_time),
    }


def _random_times(ex: Example, seed: int, n: int = N_TIMES) -> np.ndarray:
    rng = np.random.default_rng(seed)
    t0, t1 = ex.t_span
    return np.sort(rng.uniform(t0, t1, n))


# ---------------------------------------------------------------------------- registry
def test_registry_lists_every_name():
    assert list(EXAMPLES) == ALL_NAMES
    listed = list_examples()
    assert [name for name, _ in listed] == ALL_NAMES
    for _, description in listed:
        assert isinstance(description, str) and description
    for name in ALL_NAMES:
        ex = get_example(name)
        assert isinstance(ex, Example)
        assert ex.name == name
        assert ex.description


def test_unknown_name_lists_valid_names():
    with pytest.raises(ValueError) as info:
        get_example("no-such-example")
    message = str(info.value)
    assert "no-such-example" in message
    for name in ALL_NAMES:
        assert name in message


def test_unknown_parameter_is_rejected():
    with pytest.raises(TypeError):
        get_example("knife-edge", omgea=2.0)


def test_registry_factories_match_public_factories():
    np.testing.assert_array_equal(get_example("particle-harmonic").q0,
                                  nonholonomic_particle("harmonic").q0)
    assert get_example("particle-harmonic").args.stiffness == 1.0
    assert get_example("particle").args.stiffness == 0.0
    assert get_example("falling-disk").exact is not None
    assert get_example("falling-disk-general").exact is None
    assert get_example("contact").args.kappa == 0.0
    assert get_example("contact-nonreversible").args.kappa == 1.0
    assert get_example("contact").problem is contact_oscillator(False).problem


# ------------------------------------------------------------------ initial values
@pytest.mark.parametrize("name", ALL_NAMES)
def test_initial_values_consistent_and_finite(name):
    ex = _example(name)
    assert ex.t_span[0] == 0.0 and ex.t_span[1] > 0.0
    for a, shape in ((ex.q0, (ex.n,)), (ex.p0, (ex.n,)), (ex.lam0, (ex.m,))):
        assert isinstance(a, np.ndarray) and a.dtype == np.float64 and a.shape == shape
        assert np.all(np.isfinite(a))
        assert not a.flags.writeable
    res = ex.consistency_residuals()
    assert res["phi"] <= 1e-14
    assert res["hidden"] <= 1e-13
    assert res["lam"] <= 1e-13
    assert "energy" in ex.invariants
    values = ex.invariant_values(np.zeros(1), ex.q0[None], ex.p0[None])
    for v in values.values():
        assert v.shape == (1,) and np.isfinite(v[0])


@pytest.mark.parametrize("name", ALL_NAMES)
def test_default_t_span(name):
    ex = _example(name)
    expected = 2.0 if name in CLOSED_FORM else 100.0
    assert ex.t_span == (0.0, expected)
    assert get_example(name, t_end=3.5).t_span == (0.0, 3.5)


def test_lambda0_is_not_trivially_zero():
    # The consistency test above would be weak if every λ0 vanished. (The default
    # sleigh starts at rest, v0 = 0, where λ = I m v ω / (I + m a²) vanishes.)
    for name in ALL_NAMES:
        if name != "sleigh":
            assert np.max(np.abs(_example(name).lam0)) > 0.1, name
    assert abs(chaplygin_sleigh(v0=0.5).lam0[0]) > 0.1


def test_consistency_detects_wrong_lambda0():
    ex = _example("knife-edge")
    bad = Example(
        name="bad", problem=ex.problem, t_span=ex.t_span, q0=ex.q0, p0=ex.p0,
        lam0=ex.lam0 + 1e-3, args=ex.args, invariants=ex.invariants,
    )
    res = bad.consistency_residuals()
    assert res["hidden"] > 1e-4 and res["lam"] > 1e-4


# ------------------------------------------------------------------- closed forms
@pytest.mark.parametrize("case", CASES, ids=_case_id)
def test_exact_solution_satisfies_dae(case):
    ex = _get(case)
    t = _random_times(ex, seed=zlib.crc32(_case_id(case).encode()))
    defects = _max_defects(ex, ex.exact, t)
    assert defects["dq-f"] <= TOL_DAE, defects
    assert defects["dp-g"] <= TOL_DAE, defects
    assert defects["phi"] <= 1e-14, defects
    assert defects["lam-consistent"] <= 1e-12, defects
    assert defects["hidden"] <= 1e-12, defects


@pytest.mark.parametrize("case", CASES, ids=_case_id)
def test_exact_solution_starts_at_initial_values(case):
    ex = _get(case)
    q, p, lam = ex.exact(ex.t0)
    np.testing.assert_allclose(q, ex.q0, rtol=0, atol=1e-15)
    np.testing.assert_allclose(p, ex.p0, rtol=0, atol=1e-15)
    np.testing.assert_allclose(lam, ex.lam0, rtol=0, atol=1e-15)


@pytest.mark.parametrize("case", CASES, ids=_case_id)
def test_first_integrals_conserved_on_exact_solution(case):
    ex = _get(case)
    t = np.linspace(*ex.t_span, 41)
    q, p, _ = ex.exact(t)
    values = ex.invariant_values(t, q, p)
    assert set(values) == set(ex.invariants)
    for key, v in values.items():
        scale = max(1.0, abs(v[0]))
        assert np.max(np.abs(v - v[0])) <= 1e-12 * scale, key


@functools.partial(jax.jit, static_argnums=(0, 1))
def _invariant_rates(problem, invariant_fns, t, q, p, args):
    """Project random (q, p) onto φ = 0, take the consistent λ and return, per state, the
    constraint residual after projection and dI/dt = I_t + I_q f + I_p g for each I."""

    def one(t, q, p):
        for _ in range(2):  # φ is affine in p for these problems: one step is exact
            jac = jax.jacfwd(lambda pp: problem.phi(t, q, pp, args))(p)
            p = p - jac.T @ jnp.linalg.solve(jac @ jac.T, problem.phi(t, q, p, args))
        m = problem.phi(t, q, p, args).shape[0]
        lam = lobattodae.consistent_lambda(problem, t, q, p, jnp.zeros(m), args)
        dq, dp = problem.f(t, q, p, args), problem.g(t, q, p, lam, args)
        rates = [
            jax.jvp(lambda tt, qq, pp, fn=fn: fn(tt, qq, pp, args), (t, q, p),
                    (jnp.ones_like(t), dq, dp))[1]
            for fn in invariant_fns
        ]
        return problem.phi(t, q, p, args), jnp.stack(rates), lam

    return jax.vmap(one)(t, q, p)


@pytest.mark.parametrize("name", [n for n in ALL_NAMES if n not in CLOSED_FORM])
def test_invariants_are_first_integrals_of_the_dae(name):
    """dI/dt = 0 along the DAE vector field at random consistent states: the first
    integrals of the examples without a closed form are checked here (those with one are
    checked along the exact solution)."""
    ex = _example(name)
    rng = np.random.default_rng(zlib.crc32(name.encode()))
    k = 5
    q = ex.q0 + rng.uniform(-0.5, 0.5, (k, ex.n))
    p = ex.p0 + rng.uniform(-0.5, 0.5, (k, ex.n))
    t = rng.uniform(*ex.t_span, k)
    keys = tuple(ex.invariants)
    fns = tuple(ex.invariants[key] for key in keys)
    phi, rates, lam = _invariant_rates(
        ex.problem, fns, *(jnp.asarray(a) for a in (t, q, p)), ex.args)
    assert np.max(np.abs(np.asarray(phi))) <= 1e-13
    assert np.min(np.max(np.abs(np.asarray(lam)), axis=1)) > 1e-3  # the constraint acts
    assert np.all(np.abs(np.asarray(rates)) <= 1e-12), dict(zip(keys, np.asarray(rates).T))


def test_dae_check_detects_wrong_solutions():
    """The defects used above are large for slightly wrong "solutions"."""
    for name in CLOSED_FORM:
        ex = _example(name)
        t = _random_times(ex, seed=1)

        def flipped_lam(s, ex=ex):
            q, p, lam = ex.exact(s)
            return q, p, -lam

        def scaled_p(s, ex=ex):
            q, p, lam = ex.exact(s)
            return q, p * (1.0 + 1e-6), lam

        def slow_q(s, ex=ex):
            q, p, lam = ex.exact(0.999 * s)
            return q, ex.exact(s)[1], lam

        d = _max_defects(ex, flipped_lam, t)
        assert d["dp-g"] > 1e-2 and d["lam-consistent"] > 1e-2, (name, d)
        d = _max_defects(ex, scaled_p, t)
        assert max(d["dq-f"], d["dp-g"]) > 1e-8, (name, d)
        d = _max_defects(ex, slow_q, t)
        assert d["dq-f"] > 1e-4, (name, d)


def test_problem_reads_parameters_from_args():
    # One problem object per family; the parameters live in args.
    assert knife_edge(omega=3.0, g=2.0).problem is knife_edge().problem
    assert falling_rolling_disk(True).problem is falling_rolling_disk(False).problem
    # The free particle's exact solution is not a solution with a harmonic potential.
    free = _example("particle")
    harmonic = Example(
        name="particle-with-spring", problem=free.problem, t_span=free.t_span,
        q0=free.q0 + np.array([0.5, 0.0, 0.0]), p0=free.p0, lam0=free.lam0,
        args=free.args._replace(stiffness=1.0), invariants=free.invariants,
    )

    def shifted(s):
        q, p, lam = free.exact(s)
        return q + np.array([0.5, 0.0, 0.0]), p, lam

    t = _random_times(free, seed=3)
    assert _max_defects(harmonic, shifted, t)["dp-g"] > 0.1


def test_parameter_override_changes_exact_solution():
    default = _example("knife-edge")
    other = knife_edge(omega=2.0)
    q1, p1, lam1 = default.exact(1.3)
    q2, p2, lam2 = other.exact(1.3)
    assert abs(q1[2] - 1.3) < 1e-15 and abs(q2[2] - 2.6) < 1e-15
    assert np.max(np.abs(q1 - q2)) > 0.1 and abs(lam1[0] - lam2[0]) > 0.01
    assert other.p0[2] == 2.0  # p_θ = J ω
    defects = _max_defects(other, other.exact, _random_times(other, seed=5))
    assert defects["dq-f"] <= TOL_DAE and defects["dp-g"] <= TOL_DAE


def test_exact_shapes_and_vectorisation():
    for name in CLOSED_FORM:
        ex = _example(name)
        q, p, lam = ex.exact(0.7)
        assert q.shape == (ex.n,) and p.shape == (ex.n,) and lam.shape == (ex.m,)
        t = np.array([1.9, 0.1, 0.7, 0.7, 1.2])
        Q, P, L = ex.exact(t)
        assert Q.shape == (5, ex.n) and P.shape == (5, ex.n) and L.shape == (5, ex.m)
        for i, ti in enumerate(t):
            qi, pi, li = ex.exact(ti)
            np.testing.assert_allclose(Q[i], qi, rtol=0, atol=1e-15 * max(1, np.abs(qi).max()))
            np.testing.assert_allclose(P[i], pi, rtol=0, atol=1e-15 * max(1, np.abs(pi).max()))
            np.testing.assert_allclose(L[i], li, rtol=0, atol=1e-15 * max(1, np.abs(li).max()))
        with pytest.raises(ValueError):
            ex.exact(np.zeros((2, 2)))


def test_closed_form_values_from_problems_md():
    # Particle: λ0 = 1 for v = c = 1 at y0 = 0.
    assert _example("particle").lam0[0] == pytest.approx(1.0, abs=1e-15)
    # Knife edge, θ0 = v0 = 0, m = g = ω = 1: v(t) = cos t - 1, λ = v + cos t.
    q, p, lam = _example("knife-edge").exact(np.pi)
    assert p[0] == pytest.approx(2.0, abs=1e-14)  # m v cos θ = (-2)(-1)
    assert lam[0] == pytest.approx(-3.0, abs=1e-14)
    # Vertical disk: contact point on a circle of radius R ω_θ / ω_φ = 1/2.
    q, _, _ = _example("vertical-disk").exact(np.linspace(0, 2, 9))
    np.testing.assert_allclose(np.hypot(q[:, 0], q[:, 1] - 0.5), 0.5, rtol=0, atol=1e-15)
    # Falling disk: the steady spin rate of PROBLEMS.md.
    ex = _example("falling-disk")
    omega_s = steady_spin_rate(ex.args, 0.3, 1.0)
    assert omega_s == pytest.approx(0.452491005290865, abs=1e-14)
    assert ex.exact(1.0)[0][4] == pytest.approx(omega_s, abs=1e-15)
    # Sleigh: v = v_max tanh(k v_max t) with E = 1, v_max = √2, k = 1/2.
    _, p, lam = _example("sleigh").exact(2.0)
    v = math.sqrt(2) * math.tanh(math.sqrt(2) / 2 * 2.0)
    w = math.sqrt(1.0) / math.cosh(math.sqrt(2) / 2 * 2.0)
    assert p[2] == pytest.approx(w, abs=1e-15)
    assert lam[0] == pytest.approx(v * w / 2, abs=1e-15)


# ---------------------------------------------------------------------------- sleigh
def _sleigh_reference(m, inertia, a, theta0, v0, omega0, t_end):
    """x(t_end), y(t_end) by mpmath quadrature at 30 digits (x0 = y0 = 0)."""
    mp = mpmath.mp
    with mpmath.workdps(30):
        m, inertia, a = mp.mpf(m), mp.mpf(inertia), mp.mpf(a)
        theta0, v0, omega0 = mp.mpf(theta0), mp.mpf(v0), mp.mpf(omega0)
        big_i = inertia + m * a**2
        energy = (m * v0**2 + big_i * omega0**2) / 2
        v_max, w_max = mp.sqrt(2 * energy / m), mp.sqrt(2 * energy / big_i)
        rate = m * a / big_i * v_max
        tau0 = mp.atanh(v0 / v_max)
        sig = mp.sign(omega0)

        def state(t):
            tau = rate * t + tau0
            th = theta0 + sig * w_max / rate * (mp.atan(mp.sinh(tau)) - mp.atan(mp.sinh(tau0)))
            return v_max * mp.tanh(tau), sig * w_max * mp.sech(tau), th

        def xdot(t):
            v, w, th = state(t)
            return v * mp.cos(th) - a * w * mp.sin(th)

        def ydot(t):
            v, w, th = state(t)
            return v * mp.sin(th) + a * w * mp.cos(th)

        return float(mp.quad(xdot, [0, t_end])), float(mp.quad(ydot, [0, t_end]))


@pytest.mark.parametrize(
    "params",
    [dict(), dict(m=2.0, I=0.5, a=0.7, theta0=0.2, v0=0.3, omega0=-1.5)],
    ids=["default", "override"],
)
def test_sleigh_quadrature_against_mpmath(params):
    ex = chaplygin_sleigh(**params)
    full = dict(m=1.0, I=1.0, a=1.0, theta0=0.0, v0=0.0, omega0=1.0) | params
    t = np.array([0.3, 1.1, 2.0, 3.7])
    q, _, _ = ex.exact(t)
    for i, ti in enumerate(t):
        x_ref, y_ref = _sleigh_reference(full["m"], full["I"], full["a"], full["theta0"],
                                         full["v0"], full["omega0"], ti)
        assert abs(q[i, 0] - x_ref) <= 2e-15 * max(1.0, abs(x_ref))
        assert abs(q[i, 1] - y_ref) <= 2e-15 * max(1.0, abs(y_ref))


def test_sleigh_long_times_and_negative_times():
    ex = _example("sleigh")
    t = np.array([-1.5, 0.0, 50.0, 400.0])
    q, p, lam = ex.exact(t)
    assert np.all(np.isfinite(q)) and np.all(np.isfinite(p)) and np.all(np.isfinite(lam))
    # For large t the sleigh moves straight on at v_max = √2 (θ → const).
    assert p[-1, 2] == pytest.approx(0.0, abs=1e-100)
    assert np.hypot(p[-1, 0], p[-1, 1]) == pytest.approx(math.sqrt(2), abs=1e-14)
    # Backward in time the formulas still solve the DAE.
    t_neg = -_random_times(ex, seed=2)
    defects = _max_defects(ex, ex.exact, t_neg)
    assert defects["dq-f"] <= TOL_DAE and defects["dp-g"] <= TOL_DAE


# ------------------------------------------------------------------- falling disk
def test_falling_disk_mass_matrix_from_kinetic_energy():
    """M(q) of PROBLEMS.md is the Hessian of the rigid-body kinetic energy, and μ q' = 0
    is exactly 'contact point at rest'."""
    ex = falling_rolling_disk(m=1.3, R=0.7, g=1.1, I1=0.3, I3=0.45)
    m, R, _, I1, I3 = ex.args

    @jax.jit
    def check(q, qd):
        def geometry(q, qd):
            theta, phi = q[2], q[3]
            ez = jnp.array([0.0, 0.0, 1.0])
            axis = jnp.cos(theta) * jnp.array([-jnp.sin(phi), jnp.cos(phi), 0.0]) - jnp.sin(
                theta) * ez
            tangent = jnp.array([jnp.cos(phi), jnp.sin(phi), 0.0])
            up = jnp.array([-jnp.sin(theta) * jnp.sin(phi), jnp.sin(theta) * jnp.cos(phi),
                            jnp.cos(theta)])
            centre = lambda q: jnp.array([q[0], q[1], 0.0]) + R * jnp.array(  # noqa: E731
                [-jnp.sin(q[2]) * jnp.sin(q[3]), jnp.sin(q[2]) * jnp.cos(q[3]),
                 jnp.cos(q[2])])
            v_centre = jax.jvp(centre, (q,), (qd,))[1]
            omega = qd[3] * ez - qd[2] * tangent + qd[4] * axis
            return v_centre, omega, axis, up

        def kinetic(qd):
            v, w, axis, _ = geometry(q, qd)
            w3 = w @ axis
            return 0.5 * m * v @ v + 0.5 * (I1 * (w @ w - w3**2) + I3 * w3**2)

        hess = jax.hessian(kinetic)(jnp.zeros(5))
        mass = ex.problem.mass_matrix(0.0, q, ex.args)
        mu = ex.problem.constraint_matrix(0.0, q, ex.args)
        # a rolling velocity: solve μ q' = 0 for (x', y') given the rest
        qd_roll = qd.at[0].set(R * jnp.cos(q[3]) * qd[4]).at[1].set(R * jnp.sin(q[3]) * qd[4])
        v, w, _, up = geometry(q, qd_roll)
        contact_velocity = v - jnp.cross(w, R * up)
        return hess - mass, mu @ qd_roll, contact_velocity

    rng = np.random.default_rng(7)
    for _ in range(4):
        q = jnp.asarray(rng.normal(size=5))
        qd = jnp.asarray(rng.normal(size=5))
        dm, constraint, contact = check(q, qd)
        assert np.max(np.abs(dm)) <= 1e-14
        assert np.max(np.abs(constraint)) <= 1e-15
        assert np.max(np.abs(contact)) <= 1e-15


def test_falling_disk_steady_requires_nonzero_heading_rate():
    with pytest.raises(ValueError):
        falling_rolling_disk(Omega=0.0)


def test_falling_disk_general_initial_velocity():
    ex = falling_rolling_disk(False, theta_rate0=0.25, spin_rate0=0.7, phi0=0.4)
    qdot = np.asarray(ex.problem.f(0.0, jnp.asarray(ex.q0), jnp.asarray(ex.p0), ex.args))
    expected = [math.cos(0.4) * 0.7, math.sin(0.4) * 0.7, 0.25, 1.0, 0.7]
    np.testing.assert_allclose(qdot, expected, rtol=0, atol=1e-15)


# ------------------------------------------------------------ explicit equations
def _random_state(n, m, seed):
    rng = np.random.default_rng(seed)
    return (jnp.asarray(rng.uniform(0, 1)), *(jnp.asarray(rng.normal(size=k))
                                              for k in (n, n, m)))


@functools.partial(jax.jit, static_argnums=0)
def _f_g_phi(problem, t, q, p, lam, args):
    return problem.f(t, q, p, args), problem.g(t, q, p, lam, args), problem.phi(t, q, p, args)


def test_explicit_equations_particle_and_contact():
    """f, g, φ against the equations of PROBLEMS.md written out by hand."""
    ex = nonholonomic_particle("harmonic", stiffness=1.7)
    t, q, p, lam = _random_state(3, 1, seed=11)
    x, y, _ = q
    k = 1.7
    f, g, phi = _f_g_phi(ex.problem, t, q, p, lam, ex.args)
    np.testing.assert_allclose(f, p, rtol=0, atol=1e-15)
    np.testing.assert_allclose(g, [-k * x - y * lam[0], -k * y, lam[0]], rtol=0, atol=1e-15)
    np.testing.assert_allclose(phi, [p[2] - y * p[0]], rtol=0, atol=1e-15)

    for reversible in (True, False):
        ex = contact_oscillator(reversible, epsilon=0.4)
        t, q, p, lam = _random_state(3, 1, seed=12)
        x, y, z = q
        kap = 0.0 if reversible else 1.0
        v = p + jnp.array([0.0, 0.0, -kap * jnp.sin(z)])  # q' = p + ∇S, S = κ cos z
        f, g, phi = _f_g_phi(ex.problem, t, q, p, lam, ex.args)
        np.testing.assert_allclose(f, v, rtol=0, atol=1e-15)
        # -∂H/∂q with H = ½(|q|² + ε x² z² + |p + ∇S|²), ∂/∂z ∇S_z = -κ cos z
        dhdq = jnp.array([x + 0.4 * x * z**2, y, z + 0.4 * x**2 * z - v[2] * kap * jnp.cos(z)])
        np.testing.assert_allclose(g, -dhdq + lam[0] * jnp.array([1.0, 0.0, y]),
                                   rtol=0, atol=1e-14)
        np.testing.assert_allclose(phi, [v[0] + y * v[2]], rtol=0, atol=1e-15)


def test_contact_initial_values():
    for reversible in (True, False):
        ex = contact_oscillator(reversible)
        x0, y0, z0 = ex.q0
        assert x0 > 0 and y0 == 0.0 and z0 == 0.5
        inv = ex.invariant_values(np.zeros(1), ex.q0[None], ex.p0[None])
        assert inv["energy"][0] == pytest.approx(1.5, abs=1e-15)
        assert inv["H_y"][0] == pytest.approx(0.5, abs=1e-15)
        qdot = ex.problem.f(0.0, jnp.asarray(ex.q0), jnp.asarray(ex.p0), ex.args)
        np.testing.assert_allclose(qdot, [0.0, 1.0, 0.0], rtol=0, atol=1e-15)
    ex = contact_oscillator(True, z0=0.0, epsilon=0.3)
    assert ex.q0[0] == pytest.approx(math.sqrt(2.0), abs=1e-15)
    with pytest.raises(ValueError):
        contact_oscillator(z0=1.5)  # z0² > 2 (H - H_y)


# ------------------------------------------------------------- Example record itself
def test_example_validation():
    ex = _example("knife-edge")
    base = dict(name="x", problem=ex.problem, t_span=(0.0, 1.0), q0=ex.q0, p0=ex.p0,
                lam0=ex.lam0, args=ex.args, invariants=ex.invariants)
    Example(**base)
    with pytest.raises(ValueError):
        Example(**(base | dict(p0=np.zeros(4))))
    with pytest.raises(ValueError):
        Example(**(base | dict(q0=np.array([np.nan, 0.0, 0.0]))))
    with pytest.raises(ValueError):
        Example(**(base | dict(t_span=(1.0, 0.0))))
    with pytest.raises(ValueError):
        Example(**(base | dict(invariants={"p_theta": ex.invariants["p_theta"]})))
    with pytest.raises(ValueError):
        Example(**(base | dict(expected_order_overrides={"mu": {2: None}})))
    with pytest.raises(ValueError):
        Example(**(base | dict(expected_order_overrides={"lam": {1: None}})))
    with pytest.raises(TypeError):
        Example(**(base | dict(problem=object())))
    with pytest.raises(Exception):
        ex.name = "other"  # frozen


def test_expected_orders():
    assert [lobattodae.lobatto_pair(s).order()["q"] for s in (2, 3, 4, 5, 6)] == [2, 4, 6, 8, 10]
    assert [lobattodae.lobatto_pair(s).order()["lam"] for s in (2, 3, 4, 5, 6)] == [2, 2, 4, 4, 6]
    knife = _example("knife-edge")
    assert knife.expected_order("lam", 2) == 2  # exact only at even step indices
    assert knife.expected_order("lam", 3) == 2
    assert knife.expected_order("q", 2) == 2
    exact_lam = Example(**{**{f: getattr(knife, f) for f in (
        "name", "problem", "t_span", "q0", "p0", "lam0", "args", "invariants")},
        "expected_order_overrides": {"lam": {2: None}}})
    assert exact_lam.expected_order("lam", 2) is None
    assert exact_lam.expected_order("lam", 4) == 4
    disk = _example("vertical-disk")
    assert disk.expected_order("p", 2) == 4 and disk.expected_order("p", 4) == 8
    assert disk.expected_order("p", 3) == 4 and disk.expected_order("q", 4) == 6
    assert _example("sleigh").expected_order("lam", 5) == 4
    with pytest.raises(ValueError, match="component must be one of"):
        disk.expected_order("x", 3)


@pytest.mark.parametrize(
    "factory, kwargs",
    [
        (knife_edge, dict(m=0.0)),
        (chaplygin_sleigh, dict(a=-1.0)),
        (vertical_rolling_disk, dict(R=float("nan"))),
        (nonholonomic_particle, dict(potential="quartic")),
        (falling_rolling_disk, dict(t_end=-1.0)),
    ],
)
def test_invalid_parameters_raise(factory, kwargs):
    with pytest.raises(ValueError):
        factory(**kwargs)
