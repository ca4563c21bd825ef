"""Studies of the mechanics models (``-m slow``): orders and long runs of the rigid bodies
oriented by unit quaternions (``mechanics._systems3d``; the models and their references:
``tests/test_rigid.py``), and ψ between the step points of the Cartesian pendulum
(``tests/test_holonomic.py``).
"""

from __future__ import annotations

import numpy as np
import pytest

sp = pytest.importorskip("sympy")

import lobattodae  # noqa: E402
from lobattodae.mechanics import body_angular_velocity, rotation_matrix  # noqa: E402
from lobattodae.mechanics import systems as systems3d  # noqa: E402

from helpers import (  # noqa: E402
    EXACT,
    SPHERE_Q0,
    SPHERE_W0,
    SUSLOV_Q0,
    SUSLOV_W0,
    body_omega,
    fitted_order,
    max_abs,
    quaternion_exactness,
    suslov_reference,
    tilted,
)

METHOD = lobattodae.LobattoIIIAIIIB(stages=3)


# -- rigid bodies: the order, long runs ------------------------------------------------------------
@pytest.mark.slow
@pytest.mark.parametrize("stages", [2, 3])
def test_suslov_order(stages):
    model = systems3d.suslov()
    args = model.args()
    q0, p0 = systems3d.suslov_state(model, args, SUSLOV_Q0, SUSLOV_W0)
    method = lobattodae.LobattoIIIAIIIB(stages=stages)
    I = systems3d.suslov_inertia(args)
    a = np.array([float(args[k]) for k in ("a1", "a2", "a3")])
    w0 = body_angular_velocity(q0, model.velocities(0.0, q0, p0, args))
    w_ref, Q_ref = suslov_reference(I, a, q0, w0, 5.0, [5.0])
    ns = [25, 50, 100, 200] if stages == 3 else [50, 100, 200, 400]
    errs = []
    for n in ns:
        sol = lobattodae.solve(model.problem, method, (0.0, 5.0), q0, p0, n_steps=n, args=args)
        errs.append(max_abs(sol.q[-1] - Q_ref[-1]))
    order = fitted_order(ns, errs)
    assert abs(order - (2 * stages - 2)) < 0.3, (order, errs)


@pytest.mark.slow
@pytest.mark.parametrize("factory", ["suslov", "chaplygin_sphere"])
def test_long_run_exact_constraints_and_bounded_energy(factory):
    """10⁴ steps: |Q·Q − 1|, ‖φ‖ ≤ 1e-13 at every step point, energy error bounded."""
    if factory == "suslov":
        model = systems3d.suslov()
        args = model.args()
        q0, p0 = systems3d.suslov_state(model, args, SUSLOV_Q0, SUSLOV_W0)
        first = 0
    else:
        model = systems3d.chaplygin_sphere()
        args = model.args()
        q0, p0 = systems3d.chaplygin_sphere_state(model, args, SPHERE_Q0, SPHERE_W0, (0.3, -0.2))
        first = 2
    sol = lobattodae.solve(model.problem, METHOD, (0.0, 1000.0), q0, p0, n_steps=10_000, args=args)
    assert sol.success
    norm, phi = quaternion_exactness(model, sol, args, first=first)
    assert norm < EXACT and phi < EXACT
    dH = model.energy(sol.t, sol.q, sol.p, args) - model.energy(0.0, q0, p0, args)
    half = len(dH) // 2
    assert max_abs(dH) < 1e-4  # measured 2026-11-25: 1.8e-5 (Suslov, h = 0.1), 1.5e-6 (sphere)
    # no drift: the second half's error is not much larger than the first half's
    assert max_abs(dH[half:]) < 3 * max_abs(dH[:half]) + 1e-12


@pytest.mark.slow
def test_rattleback_spin_directions():
    """Kane & Levinson's rattleback, 20 s, h = 1e-3: spun at −5 rad/s it reverses within
    3 s; spun at +5 rad/s it keeps its sense for several times longer (without dissipation it
    eventually reverses too). Energy error at the integration-error level, exactness."""
    model = systems3d.rattleback()
    args = model.args()
    Q0 = tilted(0.5, 0.5)
    first_reversal = {}
    for spin0 in (-5.0, 5.0):
        w0 = rotation_matrix(Q0).T @ np.array([0.0, 0.0, spin0])
        q0, p0 = systems3d.rattleback_state(model, args, Q0, w0)
        sol = lobattodae.solve(model.problem, METHOD, (0.0, 20.0), q0, p0, n_steps=20_000, args=args)
        assert sol.success
        w, _, R = body_omega(model, sol, args, first=2)
        spin = np.einsum("nij,nj->ni", R, w)[:, 2]
        flipped = np.flatnonzero(np.sign(spin) != np.sign(spin0))
        first_reversal[spin0] = sol.t[flipped[0]] if flipped.size else np.inf
        H = model.energy(sol.t, sol.q, sol.p, args)
        assert max_abs(H - H[0]) < 3e-5 * H[0]  # measured: 1.3e-5 H0 (−5 rad/s), 6e-8 H0 (+5 rad/s)
        norm, phi = quaternion_exactness(model, sol, args, first=2)
        assert norm < EXACT and phi < EXACT
    assert first_reversal[-5.0] < 3.0
    assert first_reversal[5.0] > 3 * first_reversal[-5.0]


# -- the Cartesian pendulum: ψ between the step points -------------------------------------------------
@pytest.mark.slow
def test_dense_output_leaves_psi_by_the_interpolation_error(pendulum):
    """Between step points the dense output interpolates the unprojected stages: ψ there is
    not round-off but falls with the step size, at least like the dense output's order s
    (measured, s = 3: 1.2e-6, 1.1e-7, 7.7e-9 at h = 0.04, 0.02, 0.01, slope 3.6)."""
    pe = pendulum
    method = lobattodae.LobattoIIIAIIIB(stages=3)
    worst = []
    for n in (50, 100, 200):
        h = 2.0 / n
        t_eval = (np.arange(n) + 0.5) * h
        sol = lobattodae.solve(pe.model.problem, method, (0.0, 2.0), pe.q0, pe.p0, n_steps=n, args=pe.args, t_eval=t_eval)
        worst.append(max_abs(pe.model.holonomic_residual(sol.t, sol.q, pe.args)))
    assert worst[0] < 1e-5 and worst[0] > 1e3 * EXACT, worst
    assert fitted_order((50, 100, 200), worst) >= 3 - 0.3, worst
