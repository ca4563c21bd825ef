"""Rigid bodies oriented by unit quaternions (``mechanics._rigid``) and three 3-D
nonholonomic systems (``mechanics._systems3d``), each against an independently derived
reduced ODE solved by scipy's DOP853 (rtol = atol = 1e-12) and against its first integrals.

References (written by hand, not from the Lagrangian; Suslov's in ``tests/helpers.py``, shared
with the studies):

* Suslov: ``I ω̇ = (Iω) × ω + λ a``, ``λ`` from ``aᵀω̇ = 0``; ``Q̇ = ½ E(Q)ᵀ ω``.
* Chaplygin sphere: ``K̇ = K × ω``, ``γ̇ = γ × ω``, ``K = (I + m r²(1 − γγᵀ)) ω``
  (plus ``−c (ω·γ) γ`` on ``K̇`` with spin damping).
* Rattleback: Newton–Euler about the centre of mass with the contact force eliminated,
  ``(I + m(|r|²1 − rrᵀ)) ω̇ = −ω×Iω − m r×(ω×ṙ) − m r×(ω×(ω×r)) + m g r×γ``, ``γ̇ = γ×ω``,
  ``ṙ = (∂r/∂γ) γ̇`` with ``r = r_P(γ)`` the contact point from the centre of mass.

The default tests (Suslov, Chaplygin sphere: one compiled solver each) take under a minute;
the rattleback (whose solver alone compiles in 15-35 s here) is ``slow``. The studies (the
order, the long runs of 10⁴ steps, both rattleback spin directions over 20 s; ``slow`` too) are
in ``tests/verification/test_mechanics_studies.py``.
"""

from __future__ import annotations

import numpy as np
import pytest

sp = pytest.importorskip("sympy")
from scipy.integrate import solve_ivp  # noqa: E402
from sympy.physics.mechanics import dynamicsymbols  # noqa: E402

import lobattodae  # noqa: E402
from lobattodae import LobattoDAEInputError  # noqa: E402
from lobattodae.mechanics import from_lagrangian  # noqa: E402
from lobattodae.mechanics import systems as systems3d  # noqa: E402
from lobattodae.mechanics import (  # noqa: E402
    body_angular_velocity,
    quaternion_body,
    quaternion_from_axis_angle,
    quaternion_multiply,
    quaternion_rates,
    rotation_matrix,
)

from helpers import (  # noqa: E402
    EXACT,
    RIGID_REF_TOL,
    SPHERE_Q0,
    SPHERE_W0,
    SUSLOV_Q0,
    SUSLOV_W0,
    body_omega,
    max_abs,
    quaternion_exactness,
    suslov_reference,
    tilted,
)

METHOD = lobattodae.LobattoIIIAIIIB(stages=3)
T = dynamicsymbols._t


# ----------------------------------------------------------------------------- references
def sphere_reference(args, Q0, w0, xy0, t_end, t_eval, c=0.0):
    """State (K, γ, Q, x, y, W): W = ∫ c (ω·γ)² dt, the work of the damping torque."""
    m, r = float(args["m"]), float(args["r"])
    Ic = np.diag([float(args["I1"]), float(args["I2"]), float(args["I3"])])

    def omega(K, g):
        return np.linalg.solve(Ic + m * r * r * (np.eye(3) - np.outer(g, g)), K)

    def rhs(t, y):
        K, g, Q = y[:3], y[3:6], y[6:10]
        w = omega(K, g)
        spin = w @ g
        ws = rotation_matrix(Q) @ w
        return np.concatenate([np.cross(K, w) - c * spin * g, np.cross(g, w), quaternion_rates(Q, w),
                               [r * ws[1], -r * ws[0], c * spin * spin]])

    g0 = rotation_matrix(Q0)[2]
    K0 = (Ic + m * r * r * (np.eye(3) - np.outer(g0, g0))) @ w0
    ref = solve_ivp(rhs, (0.0, t_end), np.concatenate([K0, g0, Q0, xy0, [0.0]]), method="DOP853",
                    rtol=RIGID_REF_TOL, atol=RIGID_REF_TOL, t_eval=t_eval)
    y = ref.y.T
    return {"K": y[:, :3], "gamma": y[:, 3:6], "Q": y[:, 6:10], "xy": y[:, 10:12], "work": y[:, 12]}


def sphere_K(args, w, gamma):
    m, r = float(args["m"]), float(args["r"])
    Ic = np.array([float(args["I1"]), float(args["I2"]), float(args["I3"])])
    return Ic * w + m * r * r * (w - np.sum(w * gamma, -1)[:, None] * gamma)


def rattleback_reference(args, Q0, w0, t_end, t_eval):
    m, g = float(args["m"]), float(args["g"])
    I = np.array([[float(args["A"]), float(args["D"]), 0.0], [float(args["D"]), float(args["B"]), 0.0],
                  [0.0, 0.0, float(args["C"])]])

    def rhs(t, y):
        w, gam, Q = y[:3], y[3:6], y[6:]
        r, _, jac = systems3d.rattleback_contact(gam, args)
        gdot = np.cross(gam, w)
        rdot = jac @ gdot
        A = I + m * (r @ r * np.eye(3) - np.outer(r, r))
        b = (-np.cross(w, I @ w) - m * np.cross(r, np.cross(w, rdot)) - m * np.cross(r, np.cross(w, np.cross(w, r)))
             + m * g * np.cross(r, gam))
        return np.concatenate([np.linalg.solve(A, b), gdot, quaternion_rates(Q, w)])

    g0 = rotation_matrix(Q0)[2]
    ref = solve_ivp(rhs, (0.0, t_end), np.concatenate([w0, g0, Q0]), method="DOP853", rtol=RIGID_REF_TOL,
                    atol=RIGID_REF_TOL, t_eval=t_eval)
    y = ref.y.T
    w, gam = y[:, :3], y[:, 3:6]
    r, zG, _ = systems3d.rattleback_contact(gam, args)
    energy = 0.5 * m * np.sum(np.cross(w, r) ** 2, 1) + 0.5 * np.einsum("ni,ij,nj->n", w, I, w) + m * g * zG
    return {"omega": w, "gamma": gam, "Q": y[:, 6:], "energy": energy}


# ----------------------------------------------------------------------------- 1. the quaternion helper
def test_quaternion_kinematics():
    rng = np.random.default_rng(3)
    for _ in range(5):
        Q = rng.normal(size=4)
        Q /= np.linalg.norm(Q)
        w = rng.normal(size=3)
        Qd = quaternion_rates(Q, w)
        assert abs(Q @ Qd) < 1e-15
        R = rotation_matrix(Q)
        assert max_abs(R @ R.T - np.eye(3)) < 1e-15 and abs(np.linalg.det(R) - 1) < 1e-14
        eps = 1e-6  # [ω_body]× = Rᵀ Ṙ, by central differences
        W = R.T @ (rotation_matrix(Q + eps * Qd) - rotation_matrix(Q - eps * Qd)) / (2 * eps)
        assert max_abs(np.array([W[2, 1], W[0, 2], W[1, 0]]) - w) < 1e-8
        assert max_abs(body_angular_velocity(Q, Qd) - w) < 1e-15
    a, b = quaternion_from_axis_angle([1, 2, 3], 0.7), quaternion_from_axis_angle([0, 1, -1], 1.1)
    assert max_abs(rotation_matrix(quaternion_multiply(a, b)) - rotation_matrix(a) @ rotation_matrix(b)) < 1e-15


def test_symbolic_kinematics_match_numeric():
    body = quaternion_body("Q", sp.symbols("A B C"))
    Qn = np.array([0.3, -0.5, 0.7, 0.2])
    Qn /= np.linalg.norm(Qn)
    Qdn = quaternion_rates(Qn, np.array([0.4, -1.2, 0.9]))
    subs = {}
    for c, qv, qd in zip(body.coordinates, Qn, Qdn):
        subs[c.diff(T)] = qd
        subs[c] = qv
    R = np.array(body.rotation.xreplace(subs), dtype=float)
    assert max_abs(R - rotation_matrix(Qn)) < 1e-15
    assert max_abs(np.array(body.omega_body.xreplace(subs), dtype=float).ravel() - [0.4, -1.2, 0.9]) < 1e-14
    assert max_abs(np.array(body.omega_space.xreplace(subs), dtype=float).ravel() - R @ [0.4, -1.2, 0.9]) < 1e-14
    assert max_abs(np.array(body.vertical.xreplace(subs), dtype=float).ravel() - R.T @ [0, 0, 1]) < 1e-15
    # on Q·Q̇ = 0 the regularised energy is the rotational energy
    vals = {"A": 1.0, "B": 2.0, "C": 3.0}
    diff = (body.kinetic_energy - body.rotational_energy).xreplace(subs).subs(vals)
    assert abs(float(diff)) < 1e-15


def test_mass_matrix_spectrum_is_4I_and_4J():
    """M = 4 Uᵀ diag(I, J) U with U orthogonal: eigenvalues 4·eig(I) and 4 tr(I)/3 at any
    unit Q (so cond(M) = cond(I)); the unregularised energy is refused (M singular)."""
    model = systems3d.suslov()
    args = model.args()
    I = systems3d.suslov_inertia(args)
    expected = np.sort(np.concatenate([4 * np.linalg.eigvalsh(I), [4 * np.trace(I) / 3]]))
    rng = np.random.default_rng(0)
    for _ in range(5):
        Q = rng.normal(size=4)
        Q /= np.linalg.norm(Q)
        w = np.linalg.eigvalsh(model.mass_matrix(0.0, Q, args))
        np.testing.assert_allclose(w, expected, rtol=1e-13)
    body = quaternion_body("Q", sp.symbols("A B C"))
    bad = from_lagrangian(body.rotational_energy, body.coordinates, T, holonomic=[body.norm_constraint])
    with pytest.raises(LobattoDAEInputError, match="not positive definite"):
        bad.check(0.0, np.array([1.0, 0, 0, 0]), bad.args(A=1.0, B=2.0, C=3.0))


# ----------------------------------------------------------------------------- 2. Suslov
@pytest.fixture(scope="module")
def suslov_run():
    model = systems3d.suslov()
    args = model.args()
    q0, p0 = systems3d.suslov_state(model, args, SUSLOV_Q0, SUSLOV_W0)
    sol = lobattodae.solve(model.problem, METHOD, (0.0, 20.0), q0, p0, n_steps=800, args=args)
    assert sol.success
    return model, args, q0, sol


def test_suslov_matches_reduced_equations(suslov_run):
    model, args, q0, sol = suslov_run
    I = systems3d.suslov_inertia(args)
    a = np.array([float(args[k]) for k in ("a1", "a2", "a3")])
    w, Q, _ = body_omega(model, sol, args)
    w_ref, Q_ref = suslov_reference(I, a, q0, w[0], 20.0, sol.t)
    err_w, err_Q = max_abs(w - w_ref), max_abs(Q - Q_ref)
    assert err_w < 2e-6 and err_Q < 2e-6, (err_w, err_Q)
    # the motion is not trivial: ω changes by O(1) (it tends to an equilibrium)
    assert max_abs(w[-1] - w[0]) > 0.3
    assert max_abs(w @ a) < EXACT
    H = model.energy(sol.t, sol.q, sol.p, args)
    assert max_abs(H - 0.5 * np.einsum("ni,ij,nj->n", w, I, w)) < 1e-13  # regularisation invisible
    assert max_abs(H - H[0]) < 1e-8
    norm, phi = quaternion_exactness(model, sol, args)
    assert norm < EXACT and phi < EXACT


# ----------------------------------------------------------------------------- 3. Chaplygin sphere
@pytest.fixture(scope="module")
def sphere_run():
    model = systems3d.chaplygin_sphere()
    args = model.args()
    q0, p0 = systems3d.chaplygin_sphere_state(model, args, SPHERE_Q0, SPHERE_W0, (0.3, -0.2))
    sol = lobattodae.solve(model.problem, METHOD, (0.0, 20.0), q0, p0, n_steps=800, args=args)
    assert sol.success
    return model, args, q0, sol


def test_chaplygin_sphere_integrals(sphere_run):
    model, args, _, sol = sphere_run
    w, _, R = body_omega(model, sol, args, first=2)
    gamma = R[:, 2, :]
    K = sphere_K(args, w, gamma)
    K_space = np.einsum("nij,nj->ni", R, K)
    assert max_abs(K_space - K_space[0]) < 1e-7  # constant in space, every component
    assert max_abs(np.sum(K * K, 1) - np.sum(K[0] ** 2)) < 1e-7
    assert max_abs(np.sum(K * gamma, 1) - K[0] @ gamma[0]) < 1e-7
    H = model.energy(sol.t, sol.q, sol.p, args)
    assert max_abs(H - 0.5 * np.sum(w * K, 1)) < 1e-13  # E = ½ ω·K for the rolling ball
    assert max_abs(H - H[0]) < 1e-8
    norm, phi = quaternion_exactness(model, sol, args, first=2)
    assert norm < EXACT and phi < EXACT


def test_chaplygin_sphere_matches_K_gamma_equations(sphere_run):
    model, args, q0, sol = sphere_run
    w, Q, R = body_omega(model, sol, args, first=2)
    ref = sphere_reference(args, q0[2:], w[0], q0[:2], 20.0, sol.t)
    errs = {
        "gamma": max_abs(R[:, 2, :] - ref["gamma"]),
        "K": max_abs(sphere_K(args, w, R[:, 2, :]) - ref["K"]),
        "Q": max_abs(Q - ref["Q"]),
        "xy": max_abs(sol.q[:, :2] - ref["xy"]),
    }
    assert max(errs.values()) < 2e-6, errs
    assert max_abs(sol.q[:, :2] - sol.q[0, :2]) > 0.5  # it rolls


def test_chaplygin_sphere_spin_damping():
    """τ = −c (ω·e_z) e_z: E(t) = E(0) − ∫ c ω_z² dt and K·e_z decreases by ∫ c ω_z dt
    (the reference integrates both along its own solution)."""
    model = systems3d.chaplygin_sphere()
    args = model.args(c=0.5)
    q0, p0 = systems3d.chaplygin_sphere_state(model, args, SPHERE_Q0, SPHERE_W0, (0.3, -0.2))
    sol = lobattodae.solve(model.problem, METHOD, (0.0, 20.0), q0, p0, n_steps=800, args=args)
    assert sol.success
    w, Q, R = body_omega(model, sol, args, first=2)
    ref = sphere_reference(args, q0[2:], w[0], q0[:2], 20.0, sol.t, c=float(args["c"]))
    H = model.energy(sol.t, sol.q, sol.p, args)
    assert max_abs(H - (H[0] - ref["work"])) < 1e-7
    assert ref["work"][-1] > 0.05 * H[0]  # the damping matters
    K = sphere_K(args, w, R[:, 2, :])
    assert max_abs(K - ref["K"]) < 2e-6
    K_space = np.einsum("nij,nj->ni", R, K)
    assert max_abs(K_space[:, :2] - K_space[0, :2]) < 1e-8  # horizontal part kept
    assert K_space[-1, 2] < 0.8 * K_space[0, 2]
    norm, phi = quaternion_exactness(model, sol, args, first=2)
    assert norm < EXACT and phi < EXACT


# ----------------------------------------------------------------------------- 4. rattleback
RB_T, RB_STEPS = 1.0, 1000


@pytest.fixture(scope="module")
def rattleback_run():
    """The spin in the unstable direction (−5 rad/s about the vertical), 0.5° roll and pitch."""
    model = systems3d.rattleback()
    args = model.args()
    Q0 = tilted(0.5, 0.5)
    w0 = rotation_matrix(Q0).T @ np.array([0.0, 0.0, -5.0])
    q0, p0 = systems3d.rattleback_state(model, args, Q0, w0)
    sol = lobattodae.solve(model.problem, METHOD, (0.0, RB_T), q0, p0, n_steps=RB_STEPS, args=args)
    assert sol.success
    return model, args, q0, w0, sol


@pytest.mark.slow  # the rattleback's solver compiles in 15-35 s: outside the 60 s default budget
def test_rattleback_matches_newton_euler(rattleback_run):
    model, args, q0, w0, sol = rattleback_run
    w, Q, R = body_omega(model, sol, args, first=2)
    ref = rattleback_reference(args, q0[2:], w0, RB_T, sol.t)
    err_w = max_abs(w - ref["omega"])
    err_g = max_abs(R[:, 2, :] - ref["gamma"])
    assert err_w < 1e-3 and err_g < 1e-5, (err_w, err_g)  # |ω| ~ 5, rocking at ~100 rad/s: h = 1e-3
    H = model.energy(sol.t, sol.q, sol.p, args)
    assert max_abs(H - ref["energy"]) < 1e-5
    assert max_abs(ref["energy"] - ref["energy"][0]) < 1e-10


@pytest.mark.slow
def test_rattleback_exactness_and_contact(rattleback_run):
    model, args, q0, w0, sol = rattleback_run
    w, Q, R = body_omega(model, sol, args, first=2)
    spin = np.einsum("nij,nj->ni", R, w)[:, 2]
    assert spin[0] == pytest.approx(-5.0)
    assert spin[-1] > spin[0] + 1.0  # the unstable spin is already decaying (reversal: slow test)
    H = model.energy(sol.t, sol.q, sol.p, args)
    assert max_abs(H - H[0]) < 1e-5 * H[0]
    norm, phi = quaternion_exactness(model, sol, args, first=2)
    assert norm < EXACT and phi < EXACT
    # the body's contact point is at rest: horizontally (the constraints, to round-off) and
    # vertically: ż_G = ∇_γ z_G · γ̇ (γ̇ = γ × ω, the gradient by central differences of
    # z_G(γ)) equals −(ω × R r_P)_z, which the Lagrangian never imposes
    v = model.velocities(sol.t, sol.q, sol.p, args)
    gamma = R[:, 2, :]
    rP, _, _ = systems3d.rattleback_contact(gamma, args)
    slip = np.einsum("nij,nj->ni", R, np.cross(w, rP))
    assert max_abs(v[:, :2] + slip[:, :2]) < EXACT
    gdot = np.cross(gamma, w)
    eps = 1e-6
    zdot = (systems3d.rattleback_contact(gamma + eps * gdot, args)[1]
            - systems3d.rattleback_contact(gamma - eps * gdot, args)[1]) / (2 * eps)
    assert max_abs(zdot) > 0.05  # it rocks
    assert max_abs(zdot + slip[:, 2]) < 1e-9


def test_bad_quaternion_bodies_are_refused_with_the_fix():
    with pytest.raises(LobattoDAEInputError, match="3 principal moments or a 3×3 matrix"):
        quaternion_body("Q", inertia=[1.0, 2.0])
    with pytest.raises(LobattoDAEInputError, match="must be symmetric"):
        quaternion_body("Q", inertia=sp.Matrix([[1, 0.1, 0], [0, 2, 0], [0, 0, 3]]))
    with pytest.raises(LobattoDAEInputError, match="regularization must be positive"):
        quaternion_body("Q", inertia=[1.0, 2.0, 3.0], regularization=0)
    body = quaternion_body("Q", inertia=[1.0, 2.0, 3.0])
    with pytest.raises(LobattoDAEInputError, match="'space' or 'body'"):
        body.torque_forces([0, 0, 1], frame="world")
