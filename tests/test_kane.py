"""Models from sympy.physics.mechanics KanesMethod and System objects (lobattodae.mechanics._kane)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import sympy as sp
from sympy.physics.mechanics import (
    KanesMethod,
    Particle,
    Point,
    ReferenceFrame,
    RigidBody,
    System,
    dynamicsymbols,
    inertia,
)

import lobattodae
from lobattodae import LobattoDAEInputError, mechanics

T = dynamicsymbols._t


def _states(n, m, count=4, seed=0):
    rng = np.random.default_rng(seed)
    for _ in range(count):
        yield rng.uniform(-1, 1), rng.normal(size=n), rng.normal(size=n), rng.normal(size=m)


def _assert_same_problem(a, b, args_a, args_b, n, m, seed=0):
    for t, q, p, lam in _states(n, m, seed=seed):
        np.testing.assert_allclose(a.problem.f(t, q, p, args_a), b.problem.f(t, q, p, args_b), rtol=1e-13, atol=1e-13)
        np.testing.assert_allclose(a.problem.g(t, q, p, lam, args_a), b.problem.g(t, q, p, lam, args_b),
                                   rtol=1e-13, atol=1e-13)
        np.testing.assert_allclose(a.problem.phi(t, q, p, args_a), b.problem.phi(t, q, p, args_b),
                                   rtol=1e-13, atol=1e-13)


def _sleigh_frames():
    """The Chaplygin sleigh in Kane's style: speeds along and across the heading frame."""
    x, y, th = dynamicsymbols("x y theta")
    u1, u2, u3 = dynamicsymbols("u1 u2 u3")
    m, I, a = sp.symbols("m I a")
    N = ReferenceFrame("N")
    A = N.orientnew("A", "Axis", [th, N.z])
    A.set_ang_vel(N, u3 * N.z)
    O = Point("O")
    O.set_vel(N, 0)
    G = O.locatenew("G", x * N.x + y * N.y)
    G.set_vel(N, u1 * A.x + u2 * A.y)
    P = G.locatenew("P", -a * A.x)
    P.v2pt_theory(G, N, A)
    body = RigidBody("sleigh", G, A, m, (inertia(A, 0, 0, I), G))
    kdes = [x.diff(T) - (u1 * sp.cos(th) - u2 * sp.sin(th)),
            y.diff(T) - (u1 * sp.sin(th) + u2 * sp.cos(th)),
            th.diff(T) - u3]
    blade = P.vel(N).dot(A.y)  # u2 - a u3: no sideways slip at the knife edge
    return dict(q=[x, y, th], u=[u1, u2, u3], N=N, O=O, body=body, kdes=kdes, blade=blade)


def _sleigh_kane():
    s = _sleigh_frames()
    u1, u2, u3 = s["u"]
    kane = KanesMethod(s["N"], q_ind=s["q"], u_ind=[u1, u3], kd_eqs=s["kdes"], u_dependent=[u2],
                       velocity_constraints=[s["blade"]], bodies=[s["body"]], forcelist=[])
    return kane, s


def test_kanes_method_sleigh_is_the_lagrangian_sleigh():
    kane, _ = _sleigh_kane()
    model = mechanics.from_kanes_method(kane, name="Kane sleigh")
    reference = mechanics.systems.chaplygin_sleigh()
    assert model.parameters == reference.parameters
    args = model.args(m=1.3, I=0.7, a=0.4)
    _assert_same_problem(model, reference, args, reference.args(m=1.3, I=0.7, a=0.4), 3, 1)


def test_kanes_method_model_reproduces_kanes_equations():
    """The DAE's accelerations equal those of SymPy's own Kane equations at a state."""
    kane, s = _sleigh_kane()
    model = mechanics.from_kanes_method(kane)
    kane.kanes_equations(kane.bodies, kane.loads)
    rhs = kane.rhs()  # [q'; u'] in q, u (all speeds, the dependent one included)
    x, y, th = s["q"]
    u = s["u"]
    values = {sp.Symbol("m"): 1.3, sp.Symbol("I"): 0.7, sp.Symbol("a"): 0.4}
    args = model.args(m=1.3, I=0.7, a=0.4)
    q0 = np.array([0.3, -0.2, 0.9])
    u1, u3 = 0.8, -1.1
    speeds = {u[0]: u1, u[1]: 0.4 * u3, u[2]: u3}  # u2 = a u3
    state = {x: q0[0], y: q0[1], th: q0[2], **speeds, **values}
    kane_rhs = np.array([float(e.xreplace(state)) for e in rhs])
    qd0 = kane_rhs[:3]
    p0 = model.momenta(0.0, q0, qd0, args)
    lam0 = lobattodae.consistent_lambda(model.problem, 0.0, q0, p0, jnp.zeros(1), args)
    pd0 = model.problem.g(0.0, q0, p0, lam0, args)
    _, qdd = jax.jvp(lambda q, p: model.problem.f(0.0, q, p, args), (jnp.asarray(q0), p0), (jnp.asarray(qd0), pd0))
    # q'' from Kane: differentiate the kinematic equations q' = K(q) u along the motion.
    kd = kane.kindiffdict()
    qdot_exprs = sp.Matrix([kd[c.diff(T)] for c in s["q"]])
    udot = {c.diff(T): sp.Float(v) for c, v in zip(kane.u, kane_rhs[3:])}  # kane.u: independent first
    qdot = {c.diff(T): sp.Float(v) for c, v in zip(s["q"], qd0)}
    qdd_kane = [float(e.diff(T).xreplace(udot).xreplace(qdot).xreplace(state)) for e in qdot_exprs]
    np.testing.assert_allclose(qdd, qdd_kane, rtol=1e-12, atol=1e-12)


def test_system_sleigh_and_gravity_load():
    """A System with a nonholonomic constraint and uniform gravity (a load, not a potential)."""
    x, y, th = dynamicsymbols("x y theta")
    ux, uy, w = dynamicsymbols("u_x u_y omega")
    m, J, g = sp.symbols("m J g")
    N = ReferenceFrame("N")
    O = Point("O")
    O.set_vel(N, 0)
    A = N.orientnew("A", "Axis", [th, N.z])
    A.set_ang_vel(N, w * N.z)
    G = O.locatenew("G", x * N.x + y * N.y)
    G.set_vel(N, ux * N.x + uy * N.y)
    blade = RigidBody("blade", G, A, m, (inertia(A, 0, 0, J), G))
    system = System(N, O)
    system.add_coordinates(x, y, th)
    system.add_speeds(ux, uy, w)
    system.add_kdes(x.diff(T) - ux, y.diff(T) - uy, th.diff(T) - w)
    system.add_bodies(blade)
    system.add_loads((G, -m * g * N.y))
    system.add_nonholonomic_constraints(-sp.sin(th) * ux + sp.cos(th) * uy)
    model = mechanics.from_system(system, name="knife edge (System)")
    reference = mechanics.systems.knife_edge()
    values = dict(m=1.2, J=0.8, g=9.81)
    _assert_same_problem(model, reference, model.args(**values), reference.args(**values), 3, 1, seed=3)


def test_kanes_method_drops_velocity_constraints_that_differentiate_configuration_constraints():
    """Kane's method asks for ψ̇ as a velocity constraint; ψ itself is kept, so ψ̇ is dropped."""
    x, y = dynamicsymbols("x y")
    ux, uy = dynamicsymbols("u_x u_y")
    m, g, ell = sp.symbols("m g l")
    N = ReferenceFrame("N")
    O = Point("O")
    O.set_vel(N, 0)
    P = O.locatenew("P", x * N.x + y * N.y)
    P.set_vel(N, ux * N.x + uy * N.y)
    bob = Particle("bob", P, m)
    bob.potential_energy = m * g * y
    kane = KanesMethod(N, q_ind=[x], u_ind=[ux], kd_eqs=[x.diff(T) - ux, y.diff(T) - uy], q_dependent=[y],
                       configuration_constraints=[x**2 + y**2 - ell**2], u_dependent=[uy],
                       velocity_constraints=[x * ux + y * uy], bodies=[bob], forcelist=[])
    model = mechanics.from_kanes_method(kane)
    assert model.m == 1 and model.n_holonomic == 1
    reference = mechanics.systems.cartesian_pendulum()
    values = dict(m=0.9, g=9.81, l=1.1)
    _assert_same_problem(model, reference, model.args(**values), reference.args(**values), 2, 1, seed=5)


def test_kane_conversion_errors():
    with pytest.raises(LobattoDAEInputError, match="needs a sympy.physics.mechanics.KanesMethod"):
        mechanics.from_kanes_method(object())
    with pytest.raises(LobattoDAEInputError, match="needs a sympy.physics.mechanics.System"):
        mechanics.from_system(object())
    s = _sleigh_frames()
    u1, u2, u3 = s["u"]
    no_bodies = KanesMethod(s["N"], q_ind=s["q"], u_ind=[u1, u3], kd_eqs=s["kdes"], u_dependent=[u2],
                            velocity_constraints=[s["blade"]])
    with pytest.raises(LobattoDAEInputError, match="no bodies"):
        mechanics.from_kanes_method(no_bodies)
    aux = dynamicsymbols("u_aux")
    with_aux = KanesMethod(s["N"], q_ind=s["q"], u_ind=[u1, u3], kd_eqs=s["kdes"], u_dependent=[u2],
                           velocity_constraints=[s["blade"]], u_auxiliary=[aux], bodies=[s["body"]])
    with pytest.raises(LobattoDAEInputError, match="auxiliary speeds"):
        mechanics.from_kanes_method(with_aux)
    x, y, th = s["q"]
    redundant = KanesMethod(s["N"], q_ind=s["q"], u_ind=[u1, u3],
                            kd_eqs=[x.diff(T) - u1, y.diff(T) - u1, th.diff(T) - u3], u_dependent=[u2],
                            velocity_constraints=[u2], bodies=[s["body"]])
    with pytest.raises(LobattoDAEInputError, match="do not determine the speeds"):
        mechanics.from_kanes_method(redundant)
