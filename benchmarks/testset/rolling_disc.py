r"""A rolling disc from SymPy's documentation, converted with ``from_kanes_method``.

Source
------
SymPy documentation, *Physics > Mechanics > Examples > A rolling disc* ("A rolling disc,
with Kane's method", ``rollingdisc_example_kane``): an infinitely thin disc of mass m and
radius r rolling without slip on the plane z = 0; yaw q1 (about N.z, frame Y), lean q2
(about Y.x, frame L), spin q3 (about L.y, frame R); the centre of mass is r·L.z above the
contact point C; central inertia ``inertia(L, m r²/4, m r²/2, m r²/4)``; generalized speeds
``ω_R/N = u1 L.x + u2 L.y + u3 L.z`` with the kinematic equations
``(ω_R/N − ω_R/N(q̇)) · L_i = 0``; gravity ``−m g Y.z`` at the centre of mass.

The documentation's version keeps the contact point fixed (``C.set_vel(N, 0)``) and has no
constraints; lobattodae needs the rolling constraints explicitly. As in SymPy's own
rolling-disc test of ``KanesMethod`` with dependent speeds
(``sympy/physics/mechanics/tests/test_kane5.py``), the contact point is given coordinates
``x, y`` (``C = O + x N.x + y N.y``) and dependent speeds ``u4 = x'``, ``u5 = y'``; the
centre of mass moves with ``v_C + ω_L/N × r L.z``, and the two velocity constraints say
that the disc's material point at C has zero horizontal velocity,
``(v_C + ω_L/N × r L.z − ω_R/N × r L.z) · N.x = · N.y = 0``.
So the KanesMethod is built with ``q_ind = [q1, q2, q3, x, y]``, ``u_ind = [u1, u2, u3]``,
``u_dependent = [u4, u5]``, ``velocity_constraints`` (the two rolling conditions),
``bodies = [disc]``, ``forcelist = [(Dmc, −m g Y.z)]``. It is written here from that
description (no code copied).

Reference
---------
SymPy's *own* equations of motion, ``KanesMethod.mass_matrix_full · ẏ = forcing_full``
(y = (q1, q2, q3, x, y, u1..u5), 10 states), lambdified with NumPy and integrated with
``scipy.integrate.solve_ivp``: DOP853 with rtol = atol = 1e-13 (the stored values) and Radau
with rtol = atol = 1e-13 (the check; their difference gives ``ref_accuracy``). The momenta
are computed from SymPy's speeds by ``p = (∂u/∂q̇)ᵀ ∂T/∂u`` with T the disc's kinetic
energy (SymPy's ``RigidBody.kinetic_energy``), independently of lobattodae's conversion.
:func:`compute_reference` regenerates the stored numbers (DOP853: about 1 s; Radau: ~25 s).

Parameters g = 9.81, r = 0.26, m = 3.43 (SymPy's test values). Initial state: yaw 0, lean
q2 = 0.3 rad, spin angle 0, contact point at the origin, ``u1 = 0.5`` (lean rate),
``u2 = 9`` (spin about the axle L.y), ``u3 = 1`` (about L.z), u4, u5 from the constraints: a
leaning, wobbling disc that rolls in loops and does not fall over within T = 10
(q2 stays between 0.29 and 0.54 rad).
"""

from __future__ import annotations

import functools

import numpy as np

from ._types import FastTest, Setup, TestProblem

PARAMS = {"g": 9.81, "r": 0.26, "m": 3.43}
Q0 = (0.0, 0.3, 0.0, 0.0, 0.0)
U0_IND = (0.5, 9.0, 1.0)
T_END = 10.0
T_REF = (1.0, 2.0, 5.0, 10.0)


@functools.cache
def kanes_method():
    """The SymPy model: ``(kane, symbols)``; ``kanes_equations`` already formed."""
    import sympy as sp
    from sympy.physics.mechanics import (KanesMethod, Point, ReferenceFrame, RigidBody, cross,
                                         dynamicsymbols, inertia)

    t = dynamicsymbols._t
    q1, q2, q3, x, y = dynamicsymbols("q1 q2 q3 x y")
    u1, u2, u3, u4, u5 = dynamicsymbols("u1 u2 u3 u4 u5")
    r, m, g = sp.symbols("r m g")
    q = [q1, q2, q3, x, y]
    qd = [c.diff(t) for c in q]

    # frames as in the documentation: yaw about N.z, lean about Y.x, spin about L.y
    N = ReferenceFrame("N")
    Y = N.orientnew("Y", "Axis", [q1, N.z])
    Lf = Y.orientnew("L", "Axis", [q2, Y.x])
    R = Lf.orientnew("R", "Axis", [q3, Lf.y])
    w_qd = R.ang_vel_in(N)
    R.set_ang_vel(N, u1 * Lf.x + u2 * Lf.y + u3 * Lf.z)
    kd = [(R.ang_vel_in(N) - w_qd).dot(e) for e in (Lf.x, Lf.y, Lf.z)]
    kd += [x.diff(t) - u4, y.diff(t) - u5]
    rates = sp.solve(kd, qd, dict=True)[0]  # q̇(q, u)

    O = Point("O")
    O.set_vel(N, 0)
    C = O.locatenew("C", x * N.x + y * N.y)
    C.set_vel(N, u4 * N.x + u5 * N.y)
    Dmc = C.locatenew("Dmc", r * Lf.z)
    v_centre = C.vel(N) + cross(Lf.ang_vel_in(N), r * Lf.z)
    Dmc.set_vel(N, v_centre.subs(rates))
    contact = Dmc.vel(N) + cross(R.ang_vel_in(N), -r * Lf.z)  # material point at C
    rolling = [sp.simplify(contact.dot(N.x).subs(rates)), sp.simplify(contact.dot(N.y).subs(rates))]

    I_disc = inertia(Lf, m * r**2 / 4, m * r**2 / 2, m * r**2 / 4)
    disc = RigidBody("disc", Dmc, R, m, (I_disc, Dmc))
    loads = [(Dmc, -m * g * Y.z)]
    kane = KanesMethod(N, q_ind=q, u_ind=[u1, u2, u3], kd_eqs=kd, u_dependent=[u4, u5],
                       velocity_constraints=rolling, bodies=[disc], forcelist=loads)
    kane.kanes_equations()
    syms = dict(t=t, q=q, u=[u1, u2, u3, u4, u5], qd=qd, params=[g, r, m], disc=disc, N=N,
                rolling=rolling, rates=rates)
    return kane, syms


@functools.cache
def _numeric():
    """NumPy functions from SymPy's equations: rhs(y), u_dep(q, u_ind), qdot(q, u), p(q, u)."""
    import sympy as sp

    kane, s = kanes_method()
    q, u, par = s["q"], s["u"], s["params"]
    pv = [PARAMS["g"], PARAMS["r"], PARAMS["m"]]
    mm = sp.lambdify((q, u, par), kane.mass_matrix_full, "numpy", cse=True)
    ff = sp.lambdify((q, u, par), kane.forcing_full, "numpy", cse=True)

    def rhs(t, yv):
        return np.linalg.solve(np.asarray(mm(yv[:5], yv[5:], pv), float),
                               np.asarray(ff(yv[:5], yv[5:], pv), float).ravel())

    # dependent speeds from the velocity constraints (linear in u4, u5)
    rol = sp.Matrix(s["rolling"])
    a_dep = rol.jacobian(u[3:])
    b_dep = rol.xreplace(dict.fromkeys(u[3:], 0))
    a_fn = sp.lambdify((q, u[:3], par), a_dep, "numpy", cse=True)
    b_fn = sp.lambdify((q, u[:3], par), b_dep, "numpy", cse=True)

    def u_dep(qv, ui):
        return np.linalg.solve(np.asarray(a_fn(qv, ui, pv), float), -np.asarray(b_fn(qv, ui, pv), float).ravel())

    qdot_expr = sp.Matrix([s["rates"][c] for c in s["qd"]])
    qdot_fn = sp.lambdify((q, u, par), qdot_expr, "numpy", cse=True)
    # p = ∂T/∂q̇ = (∂u/∂q̇)ᵀ ∂T/∂u, with u = W(q) q̇ the inverse of q̇ = K(q) u
    T = s["disc"].kinetic_energy(s["N"])
    dT_du = sp.Matrix([T]).jacobian(u).T
    K = qdot_expr.jacobian(u)
    dTdu_fn = sp.lambdify((q, u, par), dT_du, "numpy", cse=True)
    K_fn = sp.lambdify((q, u, par), K, "numpy", cse=True)

    def qdot(qv, uv):
        return np.asarray(qdot_fn(qv, uv, pv), float).ravel()

    def momenta(qv, uv):
        W = np.linalg.inv(np.asarray(K_fn(qv, uv, pv), float))
        return W.T @ np.asarray(dTdu_fn(qv, uv, pv), float).ravel()

    return rhs, u_dep, qdot, momenta


def initial_speeds():
    _, u_dep, _, _ = _numeric()
    ui = np.array(U0_IND)
    return np.concatenate([ui, u_dep(np.array(Q0), ui)])


def compute_reference(method="DOP853", tol=1e-13, t_eval=T_REF):
    """Integrate SymPy's equations with scipy; returns ``(t, q (k, 5), p (k, 5), u (k, 5))``."""
    from scipy.integrate import solve_ivp

    rhs, _, _, momenta = _numeric()
    y0 = np.concatenate([Q0, initial_speeds()])
    sol = solve_ivp(rhs, (0.0, T_END), y0, method=method, rtol=tol, atol=tol, t_eval=list(t_eval))
    if not sol.success:
        raise RuntimeError(sol.message)
    Y = sol.y.T
    p = np.array([momenta(yk[:5], yk[5:]) for yk in Y])
    return sol.t, Y[:, :5], p, Y[:, 5:]


@functools.cache
def model():
    """The lobattodae model from the KanesMethod (``from_kanes_method``), built once."""
    from lobattodae import mechanics

    kane, _ = kanes_method()
    return mechanics.from_kanes_method(kane, name="SymPy rolling disc")


@functools.cache
def build() -> Setup:
    mdl = model()
    args = mdl.args(**PARAMS)
    _, _, qdot, momenta = _numeric()
    q0 = np.array(Q0)
    u0 = initial_speeds()
    p0 = momenta(q0, u0)
    return Setup(problem=mdl.problem, q0=q0, p0=p0, args=args, t_span=(0.0, T_END))


# Stored reference: compute_reference("DOP853", 1e-13) (scipy 1.17.1, sympy 1.14.0); rows
# t = 1, 2, 5, 10. Radau at rtol = atol = 1e-13 agrees to 1.3e-13, 1.1e-13, 8.0e-13, 1.6e-12
# in the measure of ``error`` (the spin angle q3 reaches 97 rad).
Q_REF = (
    (-1.119247871137941, 0.36768824305618303, 9.621395964457307, 1.8168946372483206, -1.4175496783547892),
    (-2.3531100417010284, 0.468869902418028, 19.288574467380364, 1.0884691523621952, -3.6386184697064445),
    (-6.408168519912075, 0.41502644242853304, 48.498249135179826, -0.21664342515620894, 0.029976918061979965),
    (-12.304744314884868, 0.5244600958268006, 96.74417849195368, -0.4957075442524195, 0.027820106799888573),
)
P_REF = (
    (1.111703115155409, 0.4267343363891086, 1.0413231561005574, 2.392854317333571, -7.741994634877325),
    (1.3159325724267765, 0.42283065500860395, 1.0502100696654952, -6.5179463113900855, -4.911841413348959),
    (1.2056131076299583, -0.46755103959447, 1.0436570922400483, 8.129620990183872, 0.30544765152429737),
    (1.4352645704194609, 0.19488153093816293, 1.061490087922509, 8.021698856816517, 1.610593647326546),
)

PROBLEM = TestProblem(
    "rolling-disc", "SymPy documentation, Physics/Mechanics examples, 'A rolling disc, with Kane's method' "
    "(rollingdisc_example_kane), with the contact point's coordinates, dependent speeds and rolling velocity "
    "constraints as in sympy/physics/mechanics/tests/test_kane5.py; converted by "
    "lobattodae.mechanics.from_kanes_method", build, T_REF, Q_REF, P_REF, ref_accuracy=2e-12,
    test=FastTest(stages=5, n_steps=400, bound=1.2e-8),
    mechanics=lambda: (model(), build().args))
