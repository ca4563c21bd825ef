"""lobattodae.mechanics: Lagrangian models against hand-written problems, closed forms and
independently derived reduced ODEs (scipy, rtol = atol = 1e-12)."""

from __future__ import annotations

import math

import jax.numpy as jnp
import numpy as np
import pytest

sp = pytest.importorskip("sympy")
from scipy.integrate import solve_ivp  # noqa: E402
from sympy.physics.mechanics import dynamicsymbols  # noqa: E402

import lobattodae  # noqa: E402
from lobattodae import LobattoDAEInputError, mechanics  # noqa: E402
from lobattodae.examples import chaplygin_sleigh, falling_rolling_disk, knife_edge  # noqa: E402
from lobattodae.mechanics import systems  # noqa: E402

from helpers import max_abs  # noqa: E402

METHOD = lobattodae.LobattoIIIAIIIB(stages=3)
T = dynamicsymbols._t


def _random_states(n, m, count=5, seed=0):
    rng = np.random.default_rng(seed)
    for _ in range(count):
        yield rng.uniform(-1, 1), rng.normal(size=n), rng.normal(size=n), rng.normal(size=m)


def _solve(model, t_span, q0, p0, n_steps, args):
    sol = lobattodae.solve(model.problem, METHOD, t_span, q0, p0, n_steps=n_steps, args=args)
    assert sol.success
    return sol


# ----------------------------------------------------------------------------- 1. examples
@pytest.mark.parametrize(
    "factory, example, params",
    [
        (systems.chaplygin_sleigh, chaplygin_sleigh, dict(m=1.3, I=0.7, a=0.4)),
        (systems.knife_edge, knife_edge, dict(m=1.3, J=0.7, g=0.9)),
        (systems.falling_disk, falling_rolling_disk, dict(steady=False, m=1.3, R=0.8, g=9.81, I1=0.3, I3=0.45)),
    ],
)
def test_generated_functions_equal_hand_written(factory, example, params):
    model = factory()
    ex = example(**params)
    args = model.args(**ex.args._asdict())
    def same(gen, hand):
        # equal to round-off relative to the vector's size: an entry formed by cancellation
        # (the falling disk's g: terms of 4e3 summing to 2e2) differs in its last digits
        # between two programs that order the operations differently
        np.testing.assert_allclose(gen, hand, rtol=0, atol=1e-14 * max(1.0, np.max(np.abs(hand))))

    for t, q, p, lam in _random_states(model.n, model.m):
        for gen, hand in (
            (model.problem.f(t, q, p, args), ex.problem.f(t, q, p, ex.args)),
            (model.problem.g(t, q, p, lam, args), ex.problem.g(t, q, p, lam, ex.args)),
            (model.problem.phi(t, q, p, args), ex.problem.phi(t, q, p, ex.args)),
        ):
            same(gen, hand)
        v, w = model.problem.f_and_g(t, q, p, lam, args)
        same(w, ex.problem.g(t, q, p, lam, ex.args))
        np.testing.assert_allclose(model.energy(t, q, p, args), ex.invariants["energy"](t, q, p, ex.args),
                                   rtol=1e-13, atol=1e-14)


def test_generated_sleigh_solve_matches_hand_written():
    ex = chaplygin_sleigh(m=1.3, I=0.7, a=0.4, v0=0.5, omega0=1.0, theta0=0.3)
    model = systems.chaplygin_sleigh()
    args = model.args(**ex.args._asdict())
    hand = lobattodae.solve(ex.problem, METHOD, ex.t_span, ex.q0, ex.p0, n_steps=40, args=ex.args)
    gen = _solve(model, ex.t_span, ex.q0, ex.p0, 40, args)
    for a, b in ((gen.q, hand.q), (gen.p, hand.p), (gen.lam, hand.lam)):
        assert max_abs(a - b) < 1e-12
    q_exact, _, _ = ex.exact(gen.t)
    assert max_abs(gen.q - q_exact) < 1e-6  # and both are right (s = 3, h = 0.05)


def test_models_are_cached_and_hashable():
    assert systems.chaplygin_sleigh() is systems.chaplygin_sleigh()
    problem = systems.chaplygin_sleigh().problem
    assert hash(problem) == id(problem) or isinstance(hash(problem), int)
    assert problem == problem and problem != systems.knife_edge().problem
    assert "def f_and_g" in systems.chaplygin_sleigh().source


# ----------------------------------------------------------------------------- 2. turntable
def test_turntable_ball_moves_on_the_closed_form_circle_at_order_four():
    """Affine, time-dependent constraints (the table also translates): the centre turns at
    2Ω/7 about the moving table centre; the error of s = 3 falls like h⁴."""
    model = systems.turntable_ball()
    om, vx, vy = 1.0, 0.2, -0.1
    args = model.args(Omega=om, Vx=vx, Vy=vy, m=2.0, r=1.0)
    x0, y0, u0x, u0y, wz0 = 0.3, 0.2, 0.1, 0.2, 0.2
    q0 = np.array([x0, y0, 0.0, 0.0, 0.0])
    alpha, gamma = model.coordinates[2], model.coordinates[4]
    # ẋ, ẏ, γ̇ (= ω_z at the identity) given; α̇, β̇ from rolling.
    qd0 = model.complete_velocities(0.0, q0, {"x": u0x, "y": u0y, gamma: wz0}, args)
    assert qd0[[0, 1, 4]].tolist() == [u0x, u0y, wz0]
    assert max_abs(model.constraint_terms(0.0, q0, args)[0] @ qd0 + model.constraint_terms(0.0, q0, args)[1]) < 1e-14
    assert alpha in model.coordinates
    p0 = model.momenta(0.0, q0, qd0, args)
    t_end = 5.0  # the centre turns through 2Ω/7·t_end ≈ 1.4 rad about the table's centre
    errors = []
    for n in (20, 40):
        sol = _solve(model, (0.0, t_end), q0, p0, n, args)
        x, y, _, _ = systems.turntable_ball_centre(sol.t, x0, y0, u0x, u0y, om, vx, vy)
        errors.append(max(max_abs(sol.q[:, 0] - x), max_abs(sol.q[:, 1] - y)))
        assert max_abs(model.constraint_residual(sol.t, sol.q, sol.p, args)) < 1e-13
        assert max_abs(sol.q[:, 3]) < 1.0  # β stays clear of the chart's singularity at π/2
    order = math.log2(errors[0] / errors[1])
    assert errors[1] < 2e-7
    assert 3.6 < order < 4.5, (errors, order)
    # The centre's angular frequency about the table centre is 2Ω/7, not Ω.
    x, y, _, _ = systems.turntable_ball_centre(np.array([2 * math.pi / (2 * om / 7)]), x0, y0, u0x, u0y, om, 0, 0)
    assert abs(x[0] - x0) < 1e-12 and abs(y[0] - y0) < 1e-12


def test_turntable_closed_form_is_a_solution_of_the_newton_euler_equations():
    """The closed form itself: w = ẋ − V satisfies (1 + m r²/I) ẇ = Ω ẑ × w with I = 2/5 m r²."""
    t = np.linspace(0.0, 3.0, 7)
    om, vx, vy = 1.5, 0.3, -0.2
    x, y, u, w = systems.turntable_ball_centre(t, 0.5, 0.2, 0.1, 0.4, om, vx, vy)
    eps = 1e-6
    _, _, u1, w1 = systems.turntable_ball_centre(t + eps, 0.5, 0.2, 0.1, 0.4, om, vx, vy)
    _, _, u2, w2 = systems.turntable_ball_centre(t - eps, 0.5, 0.2, 0.1, 0.4, om, vx, vy)
    du, dw = (u1 - u2) / (2 * eps), (w1 - w2) / (2 * eps)
    np.testing.assert_allclose(3.5 * du, -om * (w - vy), atol=1e-8)
    np.testing.assert_allclose(3.5 * dw, om * (u - vx), atol=1e-8)
    x1, y1, _, _ = systems.turntable_ball_centre(t + eps, 0.5, 0.2, 0.1, 0.4, om, vx, vy)
    x2, y2, _, _ = systems.turntable_ball_centre(t - eps, 0.5, 0.2, 0.1, 0.4, om, vx, vy)
    np.testing.assert_allclose((x1 - x2) / (2 * eps), u, atol=1e-8)
    np.testing.assert_allclose((y1 - y2) / (2 * eps), w, atol=1e-8)


# ----------------------------------------------------------------------------- 3. robot
def _differential_drive_reduced(par):
    """The reduced ODE in (x, y, θ, φ_r, φ_l, v, ω), derived by hand (Newton–Euler of the
    chassis in its own frame plus the wheels' spin inertia, projected on the allowed motions):

        ẋ = v cos θ, ẏ = v sin θ, θ̇ = ω, φ̇_r = (v + bω)/ρ, φ̇_l = (v − bω)/ρ,
        (m + 2Jw/ρ²) v̇ = m d ω² + (τ_r + τ_l)/ρ,
        (I + m d² + 2Jw b²/ρ²) ω̇ = −m d v ω + b (τ_r − τ_l)/ρ,

    with τ_{r,l} = B ± A sin(w t) − c φ̇_{r,l}."""
    m, inertia, d, b, rho, jw, c, a, bb, w = (par[k] for k in ("m", "I", "d", "b", "rho", "Jw", "c", "A", "B", "w"))

    def rhs(t, s):
        x, y, th, pr, pl, v, om = s
        dpr, dpl = (v + b * om) / rho, (v - b * om) / rho
        tr = bb + a * math.sin(w * t) - c * dpr
        tl = bb - a * math.sin(w * t) - c * dpl
        dv = (m * d * om**2 + (tr + tl) / rho) / (m + 2 * jw / rho**2)
        dom = (-m * d * v * om + b * (tr - tl) / rho) / (inertia + m * d**2 + 2 * jw * b**2 / rho**2)
        return [v * math.cos(th), v * math.sin(th), om, dpr, dpl, dv, dom]

    return rhs


def test_differential_drive_with_time_dependent_torques_matches_reduced_ode():
    model = systems.differential_drive()
    par = dict(m=1.2, I=0.4, d=0.25, b=0.35, rho=0.15, Jw=0.02, c=0.03, A=0.3, B=0.05, w=2.5)
    args = model.args(**par)
    th0, v0, om0 = 0.3, 0.4, -0.5
    b, rho = par["b"], par["rho"]
    qd0 = np.array([v0 * math.cos(th0), v0 * math.sin(th0), om0, (v0 + b * om0) / rho, (v0 - b * om0) / rho])
    q0 = np.array([0.1, -0.2, th0, 0.0, 0.0])
    # complete_velocities from the forward speed and turning rate alone reproduces qd0
    np.testing.assert_allclose(
        model.complete_velocities(0.0, q0, qd0 + np.array([0.1, -0.1, 0.0, 0.2, 0.0]), args, fixed=["theta"])[2], om0)
    p0 = model.momenta(0.0, q0, qd0, args)
    t_end = 3.0
    ref = solve_ivp(_differential_drive_reduced(par), (0.0, t_end), [*q0, v0, om0], method="DOP853",
                    rtol=1e-12, atol=1e-12, dense_output=True)
    errors = []
    for n in (60, 120):
        sol = _solve(model, (0.0, t_end), q0, p0, n, args)
        s = ref.sol(sol.t).T
        qdot = model.velocities(sol.t, sol.q, sol.p, args)
        err_q = max_abs(sol.q - s[:, :5])
        err_v = max(max_abs(qdot[:, 2] - s[:, 6]), max_abs(qdot[:, 0] * np.cos(sol.q[:, 2]) + qdot[:, 1] * np.sin(sol.q[:, 2]) - s[:, 5]))
        errors.append(max(err_q, err_v))
    assert errors[1] < 1e-7, errors
    assert 3.5 < math.log2(errors[0] / errors[1]) < 4.6, errors


def test_feedback_torque_on_the_sleigh_matches_its_reduced_ode():
    """A state-feedback input (PD heading control τ = −kp (θ − θr) − kd θ̇, a generalized force
    in θ) against the sleigh's reduced ODE in (x, y, θ, u, ω), derived by hand: the velocity of
    the centre of mass is u along the heading and a ω across it, m u̇ = m a ω²,
    (I + m a²) ω̇ = −m a u ω + τ. The heading settles on θr; the error falls like h⁴."""
    x, y, th = dynamicsymbols("x y theta")
    m, inertia, a, kp, kd, thr = sp.symbols("m I a k_p k_d theta_r")
    L = m * (x.diff(T) ** 2 + y.diff(T) ** 2) / 2 + inertia * th.diff(T) ** 2 / 2
    blade = -sp.sin(th) * x.diff(T) + sp.cos(th) * y.diff(T) - a * th.diff(T)
    model = mechanics.from_lagrangian(L, [x, y, th], T, nonholonomic=[blade],
                                      forces={th: -kp * (th - thr) - kd * th.diff(T)}, name="steered sleigh")
    par = dict(m=1.3, I=0.6, a=0.4, k_p=2.0, k_d=1.5, theta_r=1.0)
    args = model.args(**par)
    u0, om0 = 0.8, 0.0
    q0 = np.zeros(3)
    qd0 = np.array([u0, par["a"] * om0, om0])
    p0 = model.momenta(0.0, q0, qd0, args)

    def reduced(t, s):
        _, _, theta, u, om = s
        tau = -par["k_p"] * (theta - par["theta_r"]) - par["k_d"] * om
        return [u * math.cos(theta) - par["a"] * om * math.sin(theta), u * math.sin(theta) + par["a"] * om * math.cos(theta),
                om, par["a"] * om**2, (-par["m"] * par["a"] * u * om + tau) / (par["I"] + par["m"] * par["a"] ** 2)]

    t_end = 8.0
    ref = solve_ivp(reduced, (0.0, t_end), [0.0, 0.0, 0.0, u0, om0], method="DOP853", rtol=1e-12, atol=1e-12,
                    dense_output=True)
    errors = []
    for n in (80, 160):
        sol = _solve(model, (0.0, t_end), q0, p0, n, args)
        errors.append(max_abs(sol.q - ref.sol(sol.t).T[:, :3]))
        assert max_abs(model.constraint_residual(sol.t, sol.q, sol.p, args)) < 1e-13
    assert errors[1] < 1e-6, errors
    assert 3.5 < math.log2(errors[0] / errors[1]) < 4.6, errors
    assert abs(sol.q[-1, 2] - par["theta_r"]) < 0.02  # the controller has turned the sleigh


# ----------------------------------------------------------------------------- 4. pendulum
def test_cartesian_pendulum_against_the_angle_ode_with_exact_holonomic_constraint():
    """ψ = x² + y² − ℓ² is passed to the problem (``position_constraint``) and kept to round-off
    at every step point by the projection; ψ̇ (a row of φ) too; the angle converges like h⁴."""
    model = systems.cartesian_pendulum()
    g, ell = 9.81, 1.3
    args = model.args(m=0.7, g=g, l=ell)
    assert model.problem.position_constraint is not None
    th0 = 0.6
    q0 = np.array([ell * math.sin(th0), -ell * math.cos(th0)])
    qd0 = model.complete_velocities(0.0, q0, np.array([0.5, 0.5]), args)  # tangential part
    om0 = (q0[0] * qd0[1] - q0[1] * qd0[0]) / ell**2  # θ̇, from ẋ = ℓ cos θ θ̇, ẏ = ℓ sin θ θ̇
    np.testing.assert_allclose(qd0, [ell * math.cos(th0) * om0, ell * math.sin(th0) * om0], atol=1e-14)
    model.check(0.0, q0, args)
    p0 = model.momenta(0.0, q0, qd0, args)
    ref = solve_ivp(lambda t, s: [s[1], -(g / ell) * math.sin(s[0])], (0.0, 2.0), [th0, om0],
                    method="DOP853", rtol=1e-12, atol=1e-12, dense_output=True)
    errors = []
    for n in (100, 200):
        sol = _solve(model, (0.0, 2.0), q0, p0, n, args)
        theta = np.arctan2(sol.q[:, 0], -sol.q[:, 1])
        errors.append(max_abs(theta - ref.sol(sol.t)[0]))
        psi = model.holonomic_residual(sol.t, sol.q, args)
        assert psi.shape == (n + 1, 1)
        assert max_abs(psi) < 1e-13  # ψ = 0 exactly (it drifted by 5.4e-8 before the projection)
        assert max_abs(model.constraint_residual(sol.t, sol.q, sol.p, args)) < 1e-13  # ψ̇ = 0 exactly
    assert errors[0] < 1e-7 and errors[1] < errors[0] / 12, errors


# ----------------------------------------------------------------------------- 6. energy
def test_energy_conserved_by_conservative_model_with_linear_constraints():
    """The differential drive without torques or damping: linear, time-independent
    constraints, non-diagonal M; s = 3 keeps the energy to a bounded O(h⁴) error."""
    model = systems.differential_drive()
    args = model.args(A=0.0, B=0.0, c=0.0)
    q0 = np.array([0.0, 0.0, 0.2, 0.0, 0.0])
    qd0 = model.complete_velocities(0.0, q0, {"theta": 0.8, "x": 0.5 * math.cos(0.2)}, args)
    p0 = model.momenta(0.0, q0, qd0, args)
    sol = _solve(model, (0.0, 200.0), q0, p0, 2000, args)
    energy = model.energy(sol.t, sol.q, sol.p, args)
    dev = np.abs(energy - energy[0])
    assert dev.max() < 1e-6 * energy[0], dev.max()
    first, last = dev[: len(dev) // 10].max(), dev[-len(dev) // 10:].max()
    assert last < 3 * first + 1e-14, (first, last)  # no drift
    # the problem carries its Hamiltonian, so the library's diagnostics work on it
    np.testing.assert_allclose(np.abs(lobattodae.energy_error(sol)).max(), dev.max(), rtol=1e-6, atol=1e-15)


# ----------------------------------------------------------------------------- gyroscopic a(q)
def test_gyroscopic_terms_against_a_hand_written_hamiltonian():
    """A charged particle in a magnetic field B ẑ with the constraint ż = y ẋ: the vector
    potential gives a ≠ 0 (p = m q̇ + a), checked against H = |p − a|²/(2m) + V by autodiff."""
    x, y, z = dynamicsymbols("x y z")
    m, bf, k = sp.symbols("m B k")
    xd, yd, zd = (s.diff(T) for s in (x, y, z))
    L = m * (xd**2 + yd**2 + zd**2) / 2 + bf / 2 * (x * yd - y * xd) - k * (x**2 + y**2) / 2
    model = mechanics.from_lagrangian(L, [x, y, z], T, nonholonomic=[zd - y * xd], name="magnetic particle")
    args = model.args(m=1.4, B=0.8, k=0.3)

    def hamiltonian(t, q, p, a):
        vec = jnp.array([-a["B"] / 2 * q[1], a["B"] / 2 * q[0], 0.0])
        return jnp.sum((p - vec) ** 2) / (2 * a["m"]) + a["k"] * (q[0] ** 2 + q[1] ** 2) / 2

    hand = lobattodae.NonholonomicSystem(hamiltonian, lambda t, q, a: jnp.array([[-q[1], 0.0, 1.0]]))
    for t, q, p, lam in _random_states(3, 1, seed=3):
        np.testing.assert_allclose(model.problem.f(t, q, p, args), hand.f(t, q, p, args), rtol=1e-13, atol=1e-14)
        np.testing.assert_allclose(model.problem.g(t, q, p, lam, args), hand.g(t, q, p, lam, args), rtol=1e-13, atol=1e-14)
        np.testing.assert_allclose(model.problem.phi(t, q, p, args), hand.phi(t, q, p, args), rtol=1e-13, atol=1e-14)
        np.testing.assert_allclose(model.energy(t, q, p, args), hamiltonian(t, q, p, args), rtol=1e-13)
        qd = model.velocities(t, q, p, args)
        np.testing.assert_allclose(model.momenta(t, q, qd, args), p, rtol=1e-13, atol=1e-14)
        np.testing.assert_allclose(model.constraint_forces(t, q, p, lam, args), [-q[1] * lam[0], 0.0, lam[0]], atol=1e-15)


# ----------------------------------------------------------------------------- LagrangesMethod
def test_from_lagranges_method_matches_from_lagrangian():
    from sympy.physics.mechanics import KanesMethod, LagrangesMethod, Particle, Point, ReferenceFrame

    x, y = dynamicsymbols("x y")
    m, g, ell, c = sp.symbols("m g l c")
    N = ReferenceFrame("N")
    O = Point("O")
    O.set_vel(N, 0)
    P = O.locatenew("P", x * N.x + y * N.y)
    P.set_vel(N, x.diff(T) * N.x + y.diff(T) * N.y)
    bob = Particle("bob", P, m)
    bob.potential_energy = m * g * y
    from sympy.physics.mechanics import Lagrangian

    lag = Lagrangian(N, bob)
    lm = LagrangesMethod(lag, [x, y], hol_coneqs=[x**2 + y**2 - ell**2],
                         forcelist=[(P, -c * (x.diff(T) * N.x + y.diff(T) * N.y))], frame=N)
    from_lm = mechanics.from_lagranges_method(lm, name="damped pendulum")
    direct = mechanics.from_lagrangian(lag, [x, y], T, holonomic=[x**2 + y**2 - ell**2],
                                       forces=[-c * x.diff(T), -c * y.diff(T)])
    args = direct.args(m=0.9, g=9.81, l=1.1, c=0.2)
    assert from_lm.parameters == direct.parameters
    for t, q, p, lam in _random_states(2, 1, seed=5):
        for a, b in (
            (from_lm.problem.f(t, q, p, args), direct.problem.f(t, q, p, args)),
            (from_lm.problem.g(t, q, p, lam, args), direct.problem.g(t, q, p, lam, args)),
            (from_lm.problem.phi(t, q, p, args), direct.problem.phi(t, q, p, args)),
            (from_lm.problem.position_constraint(t, q, args), direct.problem.position_constraint(t, q, args)),
        ):
            np.testing.assert_allclose(a, b, rtol=1e-14, atol=1e-14)
    # SymPy's own equations agree, with λ_lobattodae = −λ_sympy: evaluate eom at a state.
    eom = lm.form_lagranges_equations()
    t0, q0, p0, lam0 = next(_random_states(2, 1, seed=7))
    qd0 = direct.velocities(t0, q0, p0, args)
    qdd = np.asarray(direct.problem.g(t0, q0, p0, lam0, args)) / 0.9  # M = m I
    subs = {x: q0[0], y: q0[1], x.diff(T): qd0[0], y.diff(T): qd0[1], x.diff(T, 2): qdd[0], y.diff(T, 2): qdd[1],
            lm.lam_vec[0]: -lam0[0], m: 0.9, g: 9.81, ell: 1.1, c: 0.2}
    residual = [float(e.xreplace(subs)) for e in eom]
    assert max(abs(r) for r in residual) < 1e-12, residual

    kane = KanesMethod(N, q_ind=[x], u_ind=[y])
    with pytest.raises(LobattoDAEInputError, match="from_kanes_method"):
        mechanics.from_lagranges_method(kane)
    with pytest.raises(LobattoDAEInputError, match="LagrangesMethod"):
        mechanics.from_lagranges_method(lag)


# ----------------------------------------------------------------------------- 5. bad input
X, Y, TH = dynamicsymbols("x y theta")
XD, YD, THD = (s.diff(T) for s in (X, Y, TH))
M_, I_ = sp.symbols("m I")
L_OK = M_ * (XD**2 + YD**2) / 2 + I_ * THD**2 / 2


@pytest.mark.parametrize(
    "kwargs, match",
    [
        (dict(lagrangian=L_OK + XD**4), r"not quadratic in the velocities.*x'"),
        (dict(lagrangian=L_OK + sp.sqrt(1 + YD**2)), r"not quadratic.*y'"),
        (dict(lagrangian=M_ * (XD**2 + YD**2) / 2), r"coordinate theta has no kinetic energy"),
        (dict(lagrangian=XD**2 / 2 - YD**2 / 2 + THD**2 / 2), r"not positive definite.*eigenvalue -1"),
        (dict(nonholonomic=[XD**2 - YD]), r"constraint nonholonomic\[0\].*not affine in the velocities"),
        (dict(nonholonomic={"blade": sp.sin(XD) + YD}), r"constraint nonholonomic blade.*not affine"),
        (dict(nonholonomic=[X - Y]), r"nonholonomic\[0\].*contains no velocities.*holonomic"),
        (dict(holonomic=[X * XD]), r"holonomic constraint holonomic\[0\].*contains velocities"),
        (dict(lagrangian=L_OK + sp.Function("u")(T) * X), r"undefined function\(s\) u\(t\)"),
        (dict(nonholonomic=[XD - sp.Function("w")(T)]), r"nonholonomic\[0\].*undefined function\(s\) w\(t\)"),
        (dict(lagrangian=L_OK + X.diff(T, 2) * X), r"acceleration"),
        (dict(lagrangian=L_OK + sp.Symbol("x") * X), r"symbol 'x' has the name of the coordinate"),
        (dict(lagrangian=L_OK + sp.Symbol("m", positive=True) * X), r"two different symbols are named 'm'"),
        (dict(forces=[1, 2]), r"forces has 2 entries but there are 3 coordinates"),
        (dict(coordinates=[X, sp.Function("y")(sp.Symbol("s")), TH]), r"y\(s\) is not a function of the time symbol t"),
        (dict(coordinates=[X, X, TH]), r"duplicates"),
        (dict(nonholonomic=None), r"no constraints"),
    ],
)
def test_bad_models_are_refused_with_named_culprits(kwargs, match):
    call = dict(lagrangian=L_OK, coordinates=[X, Y, TH], nonholonomic=[-sp.sin(TH) * XD + sp.cos(TH) * YD])
    call.update(kwargs)
    with pytest.raises(LobattoDAEInputError, match=match):
        mechanics.from_lagrangian(call.pop("lagrangian"), call.pop("coordinates"), T, **call)


def test_bad_args_and_states_are_refused_with_names():
    model = systems.chaplygin_sleigh()
    model_nodefaults = mechanics.from_lagrangian(L_OK, [X, Y, TH], T, nonholonomic=[-sp.sin(TH) * XD + sp.cos(TH) * YD])
    with pytest.raises(LobattoDAEInputError, match=r"no value for the parameter\(s\) \['m'\]"):
        model_nodefaults.args(I=1.0)
    with pytest.raises(LobattoDAEInputError, match=r"unknown parameter\(s\) 'aa' \(did you mean 'a'\?\).*\['I', 'a', 'm'\]"):
        model.args(aa=2.0)
    with pytest.raises(LobattoDAEInputError, match=r"parameter 'a' must be finite"):
        model.args(a=float("nan"))
    with pytest.raises(LobattoDAEInputError, match=r"missing parameter\(s\) \['a'\]"):
        model.velocities(0.0, np.zeros(3), np.zeros(3), {"m": 1.0, "I": 1.0})
    # a mass matrix that is not positive definite at the state (a negative inertia value)
    with pytest.raises(LobattoDAEInputError, match=r"not positive definite.*theta'"):
        model.momenta(0.0, np.zeros(3), np.zeros(3), model.args(I=-1.0))
    # dependent constraints, named
    dep = mechanics.from_lagrangian(
        L_OK, [X, Y, TH], T,
        nonholonomic={"blade": -sp.sin(TH) * XD + sp.cos(TH) * YD, "twice": 2 * (-sp.sin(TH) * XD + sp.cos(TH) * YD),
                      "spin": THD - 1})
    a = dep.args(m=1.0, I=1.0)
    with pytest.raises(LobattoDAEInputError, match=r"constraints \[.*blade.*twice.*\] are linearly dependent"):
        dep.complete_velocities(0.0, np.zeros(3), np.zeros(3), a)
    with pytest.raises(LobattoDAEInputError, match=r"linearly dependent"):
        dep.check(0.0, np.zeros(3), a)
    # fixing too many velocities
    sleigh_args = model.args()
    with pytest.raises(LobattoDAEInputError, match=r"every velocity is fixed.*nonholonomic\[0\]"):
        model.complete_velocities(0.0, np.zeros(3), {"x": 1.0, "y": 1.0, "theta": 1.0}, sleigh_args)
    knife = systems.knife_edge()  # at θ = 0 the blade constraint reads ẏ = 0: ẏ cannot be fixed
    with pytest.raises(LobattoDAEInputError, match=r"with the velocities of \['y'\] fixed, the constraints \[.*nonholonomic\[0\]"):
        knife.complete_velocities(0.0, np.zeros(3), {"y": 1.0}, knife.args())
    with pytest.raises(LobattoDAEInputError, match=r"'z' is not one of the coordinates"):
        model.complete_velocities(0.0, np.zeros(3), {"z": 1.0}, sleigh_args)
    # a position that violates a holonomic constraint
    pend = systems.cartesian_pendulum()
    with pytest.raises(LobattoDAEInputError, match=r"violates the holonomic constraint.*-l\*\*2 \+ x\*\*2 \+ y\*\*2 = 0.*ψ = \[-0.75\]"):
        pend.check(0.0, np.array([0.5, 0.0]), pend.args())


def test_complete_velocities_projects_in_the_kinetic_metric():
    model = systems.differential_drive()
    args = model.args()
    rng = np.random.default_rng(1)
    q = rng.normal(size=5)
    guess = rng.normal(size=5)
    qd = model.complete_velocities(0.0, q, guess, args)
    mu, nu = model.constraint_terms(0.0, q, args)
    assert max_abs(mu @ qd + nu) < 1e-13
    # M-orthogonality: the correction is M⁻¹μᵀ·something, i.e. M (qd − guess) ∈ range(μᵀ)
    M = model.mass_matrix(0.0, q, args)
    corr = M @ (qd - guess)
    coef, *_ = np.linalg.lstsq(mu.T, corr, rcond=None)
    assert max_abs(mu.T @ coef - corr) < 1e-12


def test_input_forms_equations_dicts_and_symbol_keys():
    """Eq constraints, dict forces keyed by coordinate, Symbol keys in args, explicit time."""
    k, w = sp.symbols("k w")
    model = mechanics.from_lagrangian(
        L_OK, [X, Y, TH], T, nonholonomic=[sp.Eq(YD, sp.sin(w * T) * XD)],
        forces={TH: -k * THD, "x": sp.cos(w * T)}, name="forms")
    assert model.parameters == ("I", "k", "m", "w")
    args = model.args({M_: 2.0, "I": 0.5}, k=0.1, w=3.0)
    t, q, qd = 0.7, np.array([0.1, 0.2, 0.3]), np.array([0.4, 0.5, 0.6])
    np.testing.assert_allclose(model.generalized_forces(t, q, qd, args), [math.cos(2.1), 0.0, -0.06], atol=1e-15)
    mu, nu = model.constraint_terms(t, q, args)
    np.testing.assert_allclose(mu, [[-math.sin(2.1), 1.0, 0.0]], atol=1e-15)
    assert nu.tolist() == [0.0]
    p = model.momenta(t, q, qd, args)
    np.testing.assert_allclose(p, [0.8, 1.0, 0.3], atol=1e-15)
    np.testing.assert_allclose(model.velocities(t, q, p, args), qd, atol=1e-15)
    np.testing.assert_allclose(model.lagrangian(t, q, qd, args), 0.5 * 2.0 * (0.16 + 0.25) + 0.25 * 0.36)
    assert model.symbolic.constraint_matrix == sp.Matrix([[-sp.sin(w * T), 1, 0]])
    with pytest.raises(LobattoDAEInputError, match="same name but other assumptions"):
        mechanics.from_lagrangian(L_OK, [X, Y, TH], sp.Symbol("t", real=True))
