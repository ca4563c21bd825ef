r"""A planar four-bar linkage built with SymPy's joints framework, converted with ``from_system``.

Source
------
SymPy's tutorial *A four bar linkage* (docs.sympy.org, Physics > Mechanics tutorials,
``four_bar_linkage_example``): three links of an open chain joined by
:class:`~sympy.physics.mechanics.PinJoint` s with relative angles q1, q2, q3 and speeds u1, u2,
u3, uniform rods of central inertia ``m l²/12``, the loop closed by two holonomic
constraints, and a :class:`~sympy.physics.mechanics.System` for the book-keeping. Written
here from that description (no code copied), with the ground as the fixed body: a crank
(length l1, ground–crank joint at O, angle q1), a coupler (l2, angle q2 relative to the crank),
a rocker (l3, q3 relative to the coupler); the rocker's free end is held at ``O + l4 N.x``
(``System.add_holonomic_constraints``), q1, u1 independent, q2, q3, u2, u3 dependent; and,
unlike the tutorial, masses as parameters and gravity ``−g N.y``
(``System.apply_uniform_gravity``). The ``System`` goes to
:func:`lobattodae.mechanics.from_system` unchanged: n = 3, m = 2, both constraints kept as
position constraints.

Grashof crank-rocker (shortest link the crank, adjacent to the ground: 0.3 + 1.0 ≤ 1.0 + 0.8),
so the crank turns through full revolutions: l = (0.3, 1.0, 0.8, 1.0), m = (0.5, 1.0, 0.8),
g = 9.81; the crank starts at q1 = 0.3 rad with u1 = 4 rad/s, q2, q3 from the loop closure
(Newton to round-off) and u2, u3 from its velocity form.

Reference
---------
SymPy's *own* equations of motion: ``System.form_eoms()`` (Kane's method with the dependent
speeds), ``mass_matrix_full · ẏ = forcing_full`` for y = (q1, q2, q3, u1, u2, u3),
lambdified with NumPy and integrated with ``scipy.integrate.solve_ivp``: DOP853 with rtol =
atol = 1e-13 (the stored values) and Radau with rtol = atol = 1e-13 (the check: they agree to
2.5e-12 in the measure of ``error``, so ``ref_accuracy = 3e-12``; the ODE's loop closure
drifts to 5e-13 by T = 5). The joints' kinematic
equations are q̇ = u, so the momenta are ``p = ∂T/∂u`` with T the bodies' kinetic energy
(SymPy's ``RigidBody.kinetic_energy``), independently of lobattodae's conversion.
:func:`compute_reference` regenerates the stored numbers (DOP853: about 1.5 s; Radau: ~12 s).

This problem was added after the error control and its constants were settled: nothing of
the solver was tuned on it (a hold-out).
"""

from __future__ import annotations

import functools

import numpy as np

from ._types import FastTest, Setup, TestProblem

PARAMS = {"l1": 0.3, "l2": 1.0, "l3": 0.8, "l4": 1.0, "m1": 0.5, "m2": 1.0, "m3": 0.8, "g": 9.81}
Q1_0 = 0.3
U1_0 = 4.0
T_END = 5.0
T_REF = (1.0, 2.0, 5.0)


@functools.cache
def system():
    """The SymPy model: ``(system, symbols)``; its equations not yet formed."""
    import sympy as sp
    from sympy.physics.mechanics import (
        PinJoint,
        Point,
        ReferenceFrame,
        RigidBody,
        System,
        dynamicsymbols,
        inertia,
    )

    q = list(dynamicsymbols("q1:4"))
    u = list(dynamicsymbols("u1:4"))
    par = sp.symbols(" ".join(PARAMS), positive=True)
    l1, l2, l3, l4, m1, m2, m3, g = par
    N = ReferenceFrame("N")
    O = Point("O")
    O.set_vel(N, 0)
    ground = RigidBody("ground", O, N)

    def rod(name, m, length):
        frame, centre = ReferenceFrame(f"{name}_frame"), Point(f"{name}_centre")
        return RigidBody(name, centre, frame, m, (inertia(frame, 0, 0, m * length**2 / 12), centre))

    crank, coupler, rocker = rod("crank", m1, l1), rod("coupler", m2, l2), rod("rocker", m3, l3)
    joints = (
        PinJoint("ground_crank", ground, crank, coordinates=q[0], speeds=u[0], joint_axis=N.z,
                 child_point=-l1 / 2 * crank.frame.x),
        PinJoint("crank_coupler", crank, coupler, coordinates=q[1], speeds=u[1], joint_axis=crank.frame.z,
                 parent_point=l1 / 2 * crank.frame.x, child_point=-l2 / 2 * coupler.frame.x),
        PinJoint("coupler_rocker", coupler, rocker, coordinates=q[2], speeds=u[2], joint_axis=coupler.frame.z,
                 parent_point=l2 / 2 * coupler.frame.x, child_point=-l3 / 2 * rocker.frame.x),
    )
    sys_ = System.from_newtonian(ground)
    sys_.add_joints(*joints)
    gap = rocker.masscenter.locatenew("rocker_end", l3 / 2 * rocker.frame.x).pos_from(O) - l4 * N.x
    sys_.add_holonomic_constraints(gap.dot(N.x), gap.dot(N.y))
    sys_.q_ind, sys_.q_dep = q[:1], q[1:]
    sys_.u_ind, sys_.u_dep = u[:1], u[1:]
    sys_.apply_uniform_gravity(-g * N.y)
    sys_.validate_system()
    return sys_, {"q": q, "u": u, "params": list(par), "N": N}


@functools.cache
def _numeric():
    """NumPy functions from SymPy's equations: rhs(y), the loop closure ψ(q) and its Jacobian,
    and the momenta p(q, u)."""
    import sympy as sp

    sys_, s = system()
    q, u, par = s["q"], s["u"], s["params"]
    pv = list(PARAMS.values())
    sys_.form_eoms()
    mm = sp.lambdify((q, u, par), sys_.mass_matrix_full, "numpy", cse=True)
    ff = sp.lambdify((q, u, par), sys_.forcing_full, "numpy", cse=True)

    def rhs(t, yv):
        return np.linalg.solve(np.asarray(mm(yv[:3], yv[3:], pv), float),
                               np.asarray(ff(yv[:3], yv[3:], pv), float).ravel())

    psi = sp.Matrix(list(sys_.holonomic_constraints))
    psi_fn = sp.lambdify((q, par), psi, "numpy")
    psi_q_fn = sp.lambdify((q, par), psi.jacobian(q), "numpy")
    kinetic = sum(body.kinetic_energy(s["N"]) for body in sys_.bodies)
    dT_du = sp.lambdify((q, u, par), sp.Matrix([kinetic]).jacobian(u).T, "numpy", cse=True)

    def closure(qv):
        return np.asarray(psi_fn(qv, pv), float).ravel(), np.asarray(psi_q_fn(qv, pv), float)

    def momenta(qv, uv):
        return np.asarray(dT_du(qv, uv, pv), float).ravel()

    return rhs, closure, momenta


def initial_state() -> tuple[np.ndarray, np.ndarray]:
    """``(q0, u0)``: q2, q3 on the loop closure (Newton from an assembled guess), u2, u3 on its
    velocity form ψ_q u = 0 (q̇ = u)."""
    _, closure, _ = _numeric()
    q0 = np.array([Q1_0, 0.5, 3.9])  # the assembly with the coupler above the ground link
    for _ in range(20):
        r, jac = closure(q0)
        q0[1:] -= np.linalg.solve(jac[:, 1:], r)
        if np.max(np.abs(r)) < 1e-16:
            break
    _, jac = closure(q0)
    u_dep = np.linalg.solve(jac[:, 1:], -jac[:, 0] * U1_0)
    return q0, np.concatenate([[U1_0], u_dep])


def compute_reference(method="DOP853", tol=1e-13, t_eval=T_REF):
    """Integrate SymPy's equations with scipy; returns ``(t, q (k, 3), p (k, 3), u (k, 3))``."""
    from scipy.integrate import solve_ivp

    rhs, _, momenta = _numeric()
    q0, u0 = initial_state()
    sol = solve_ivp(rhs, (0.0, T_END), np.concatenate([q0, u0]), method=method, rtol=tol, atol=tol,
                    t_eval=list(t_eval))
    if not sol.success:
        raise RuntimeError(sol.message)
    Y = sol.y.T
    return sol.t, Y[:, :3], np.array([momenta(y[:3], y[3:]) for y in Y]), Y[:, 3:]


@functools.cache
def model():
    """The lobattodae model from the System (``from_system``), built once."""
    from lobattodae import mechanics

    return mechanics.from_system(system()[0], name="SymPy four-bar linkage")


@functools.cache
def build() -> Setup:
    mdl = model()
    _, _, momenta = _numeric()
    q0, u0 = initial_state()
    return Setup(problem=mdl.problem, q0=q0, p0=momenta(q0, u0), args=mdl.args(**PARAMS), t_span=(0.0, T_END))


# Stored reference: compute_reference("DOP853", 1e-13) (scipy 1.17.1, sympy 1.14.0); rows t = 1, 2, 5.
# Radau at rtol = atol = 1e-13 agrees to 1.0e-13, 3.5e-13, 2.5e-12 in the measure of ``error``;
# the loop closure of the stored rows: |ψ| ≤ 4.1e-14, 6.6e-14, 5.2e-13.
Q_REF = (
    (-4.000958807424206, 4.5260269793017605, 4.613321145486689),
    (-0.33166579765551096, 1.3813513597433449, 3.939351078195609),
    (0.5471169731223307, 0.152130490673623, 3.9862193428855988),
)
P_REF = (
    (0.15901210721143358, -0.026250778541174562, -0.042810405652114386),
    (0.17041561520380616, 0.7903418006594622, -0.2203688447657974),
    (0.053662304946194034, 0.018237992623365305, 0.00449732476811902),
)

PROBLEM = TestProblem(
    "fourbar", "SymPy tutorial 'A four bar linkage' (joints framework: three PinJoints, the loop closed by two "
    "holonomic constraints in a System), with masses and uniform gravity; converted by "
    "lobattodae.mechanics.from_system", build, T_REF, Q_REF, P_REF, ref_accuracy=3e-12,
    test=FastTest(stages=4, n_steps=800, bound=1.2e-9),
    mechanics=lambda: (model(), build().args))
