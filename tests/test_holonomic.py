"""Holonomic constraints ψ(t, q) = 0 kept exactly: the projection after each step
(``lobattodae._projection``), on the Cartesian pendulum and double pendulum.

References are independent: the angle ODEs of the pendulums solved by scipy's DOP853 at
rtol = atol = 1e-13 (the pendulum's: ``helpers.Pendulum``, fixture ``pendulum``). Orders are
fitted over the points above the round-off plateau. The study of ψ between step points is in
``tests/verification/test_mechanics_studies.py``.
"""

from __future__ import annotations

import dataclasses
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

sp = pytest.importorskip("sympy")
from scipy.integrate import solve_ivp  # noqa: E402

import lobattodae as L  # noqa: E402
from lobattodae import (  # noqa: E402
    InconsistentInitialValuesError,
    PartitionedDAE,
    ProblemDefinitionError,
    ShapeError,
)
from lobattodae.mechanics import systems  # noqa: E402

from helpers import EXACT, fitted_order, max_abs  # noqa: E402

REF_TOL = 1e-13


# ----------------------------------------------------------------------------- the systems
class DoublePendulum:
    """The Cartesian double pendulum and the classical angle ODE of the double pendulum."""

    par = dict(m1=1.0, m2=0.7, g=9.81, l1=1.0, l2=0.8)
    th0, om0 = (0.5, -0.3), (0.2, 0.6)

    def __init__(self):
        self.model = systems.cartesian_double_pendulum()
        self.args = self.model.args(**self.par)
        self.mass = np.array([self.par["m1"], self.par["m1"], self.par["m2"], self.par["m2"]])
        self.q0, v0 = self._cartesian(np.array(self.th0), np.array(self.om0))
        self.model.check(0.0, self.q0, self.args)
        self.p0 = self.model.momenta(0.0, self.q0, v0, self.args)

    def _cartesian(self, th, om):
        l1, l2 = self.par["l1"], self.par["l2"]
        a, b = th
        wa, wb = om
        x1, y1 = l1 * np.sin(a), -l1 * np.cos(a)
        vx1, vy1 = l1 * np.cos(a) * wa, l1 * np.sin(a) * wa
        q = np.stack([x1, y1, x1 + l2 * np.sin(b), y1 - l2 * np.cos(b)], -1)
        v = np.stack([vx1, vy1, vx1 + l2 * np.cos(b) * wb, vy1 + l2 * np.sin(b) * wb], -1)
        return q, v

    def reference(self, t_end):
        m1, m2, g, l1, l2 = (self.par[k] for k in ("m1", "m2", "g", "l1", "l2"))

        def rhs(t, y):
            a, b, wa, wb = y
            d = a - b
            den = 2 * m1 + m2 - m2 * math.cos(2 * d)
            acc_a = (-g * (2 * m1 + m2) * math.sin(a) - m2 * g * math.sin(a - 2 * b)
                     - 2 * math.sin(d) * m2 * (wb**2 * l2 + wa**2 * l1 * math.cos(d))) / (l1 * den)
            acc_b = 2 * math.sin(d) * (wa**2 * l1 * (m1 + m2) + g * (m1 + m2) * math.cos(a)
                                       + wb**2 * l2 * m2 * math.cos(d)) / (l2 * den)
            return [wa, wb, acc_a, acc_b]

        ref = solve_ivp(rhs, (0.0, t_end), [*self.th0, *self.om0], method="DOP853", rtol=REF_TOL, atol=REF_TOL,
                        dense_output=True)

        def states(t):
            y = ref.sol(t)
            q, v = self._cartesian(y[:2], y[2:])
            return q, self.mass * v

        return states


@pytest.fixture(scope="module")
def double_pendulum():
    return DoublePendulum()


def _assert_exact(model, sol, args):
    """ψ and φ at every row of the solution: round-off."""
    psi = model.holonomic_residual(sol.t, sol.q, args)
    assert psi.shape == (len(sol.t), model.n_holonomic)
    assert max_abs(psi) <= EXACT, max_abs(psi)
    assert max_abs(model.constraint_residual(sol.t, sol.q, sol.p, args)) <= EXACT


# ----------------------------------------------------------------------------- exactness and orders
#: (system, s, step counts on [0, T]); s = 4, 5 under -m slow
ORDER_CASES = [
    ("pendulum", 2, (50, 100, 200, 400)),
    ("pendulum", 3, (25, 50, 100, 200)),
    pytest.param("pendulum", 4, (10, 20, 40, 80), marks=pytest.mark.slow),
    pytest.param("pendulum", 5, (10, 20, 40), marks=pytest.mark.slow),
    ("double", 2, (40, 80, 160, 320)),
    ("double", 3, (20, 40, 80, 160)),
    pytest.param("double", 4, (16, 32, 64), marks=pytest.mark.slow),
    pytest.param("double", 5, (8, 16, 24), marks=pytest.mark.slow),
]


@pytest.mark.parametrize("system, stages, ns", ORDER_CASES)
def test_psi_exact_at_every_step_and_orders_kept(system, stages, ns, request):
    """Constant steps: ψ = 0 and φ = 0 to round-off at every step point, and q, p still converge
    with order 2s − 2 against the angle ODE (the projection keeps the method's order)."""
    sysm = request.getfixturevalue("pendulum" if system == "pendulum" else "double_pendulum")
    t_end = 2.0 if system == "pendulum" else 1.0
    states = sysm.reference(t_end)
    method = L.LobattoIIIAIIIB(stages=stages)
    eq, ep = [], []
    for n in ns:
        sol = L.solve(sysm.model.problem, method, (0.0, t_end), sysm.q0, sysm.p0, n_steps=n, args=sysm.args)
        assert sol.success
        _assert_exact(sysm.model, sol, sysm.args)
        q_ref, p_ref = states(sol.t)
        eq.append(max_abs(sol.q - q_ref))
        ep.append(max_abs(sol.p - p_ref))
    expected = 2 * stages - 2
    assert fitted_order(ns, eq) >= expected - 0.3, (eq, fitted_order(ns, eq))
    assert fitted_order(ns, ep) >= expected - 0.3, (ep, fitted_order(ns, ep))


def test_adaptive_steps_keep_psi_exact(double_pendulum):
    """Error-controlled steps (rejections included): ψ = 0 at every accepted step point, and the
    solution meets its tolerance against the angle ODE."""
    dp = double_pendulum
    sol = L.solve(dp.model.problem, L.LobattoIIIAIIIB(stages=3), (0.0, 3.0), dp.q0, dp.p0, rtol=1e-8, atol=1e-8,
                  args=dp.args)
    assert sol.success and len(sol.t) > 20
    _assert_exact(dp.model, sol, dp.args)
    q_ref, _ = dp.reference(3.0)(sol.t)
    assert max_abs(sol.q - q_ref) < 1e-5


def test_terminal_event_ends_on_the_constraint(pendulum):
    """A terminal event re-takes the step to end at the zero: that step is projected too, so the
    final state satisfies ψ = 0 to round-off (adaptive steps, s = 4)."""
    pe = pendulum

    def bottom(t, q, p, args):  # the bob passes under the pivot
        return q[0]

    bottom.terminal = True
    sol = L.solve(pe.model.problem, L.LobattoIIIAIIIB(stages=4), (0.0, 5.0), pe.q0, pe.p0, rtol=1e-9, atol=1e-9,
                  args=pe.args, events=[bottom])
    assert sol.result == L.Result.EVENT
    # the zero is located on the dense output (order s between step points), so the final x is
    # the dense output's error, not round-off
    assert abs(sol.q[-1, 0]) < 1e-7 and sol.t[-1] == sol.t_events[0][0]
    _assert_exact(pe.model, sol, pe.args)
    # the bottom is reached at the time the angle ODE gives
    ref = solve_ivp(lambda t, y: [y[1], -(pe.g / pe.ell) * math.sin(y[0])], (0.0, 5.0), [pe.th0, pe.om0],
                    method="DOP853", rtol=REF_TOL, atol=REF_TOL, events=lambda t, y: y[0])
    assert abs(sol.t[-1] - ref.t_events[0][0]) < 1e-7, sol.t[-1] - ref.t_events[0][0]


# ----------------------------------------------------------------------------- long runs
def test_long_run_energy_and_psi_with_and_without_projection(pendulum):
    """10⁴ steps (s = 3, h = 0.02, t ∈ [0, 200]). With the projection ψ stays at round-off and the
    energy error stays small (it grows slowly and linearly: the projected step is not symmetric;
    docs/mechanics.md). The same problem without ``position_constraint`` keeps a ψ error of
    the size of the integration error, over 10⁵ times larger."""
    pe = pendulum
    method = L.LobattoIIIAIIIB(stages=3)
    plain = dataclasses.replace(pe.model.problem, position_constraint=None)
    runs = {}
    for label, problem in (("projected", pe.model.problem), ("plain", plain)):
        sol = L.solve(problem, method, (0.0, 200.0), pe.q0, pe.p0, n_steps=10_000, args=pe.args)
        assert sol.success
        energy = pe.model.energy(sol.t, sol.q, sol.p, pe.args)
        runs[label] = (max_abs(pe.model.holonomic_residual(sol.t, sol.q, pe.args)), np.abs(energy - energy[0]))
    psi, dev = runs["projected"]
    psi_plain, dev_plain = runs["plain"]
    assert psi <= EXACT
    assert psi_plain > 1e5 * max(psi, 1e-16) and psi_plain > 1e-9, (psi, psi_plain)
    energy0 = 0.5 * pe.mass * (pe.ell * pe.om0) ** 2 - pe.mass * pe.g * pe.ell * math.cos(pe.th0)
    assert dev.max() < 3e-7 * abs(energy0), dev.max()  # measured 2.2e-7 (|E| = 7.3)
    tenth = len(dev) // 10
    # no faster than linear growth: the last tenth at most ~ (time ratio) times the first
    assert dev[-tenth:].max() < 4 * dev[:tenth].max(), (dev[:tenth].max(), dev[-tenth:].max())
    # the unprojected symmetric step keeps bounded energy errors of the same size
    assert dev.max() < 3 * dev_plain.max()


# ----------------------------------------------------------------------------- derivatives
def test_gradient_through_integrate_matches_finite_differences(pendulum):
    """``jax.grad`` of the final x through ``lobattodae.integrate`` with respect to θ0 and ℓ
    (initial values consistent for every θ0, ℓ), against central differences; and the
    derivative of ψ(q_N) vanishes (the projection is differentiated, not only the step)."""
    pe = pendulum
    problem, method = pe.model.problem, L.LobattoIIIAIIIB(stages=3)
    base = pe.args

    def final(theta):
        th0, ell = theta
        args = dict(base, l=ell)
        q0 = ell * jnp.array([jnp.sin(th0), -jnp.cos(th0)])
        p0 = L.project_momenta(problem, 0.0, q0, jnp.array([0.4, 0.2]), args)
        lam0 = L.consistent_lambda(problem, 0.0, q0, p0, jnp.zeros(1), args)
        r = L.integrate(problem, method, 0.0, 0.05, 20, q0, p0, lam0, args)
        q = r.q[-1]
        return q[0], jnp.sum(q**2) - ell**2

    theta = jnp.array([0.6, 1.3])
    grad, grad_psi = jax.jit(jax.jacrev(final))(theta)
    fd = np.array([(final(theta + 1e-5 * e)[0] - final(theta - 1e-5 * e)[0]) / 2e-5 for e in np.eye(2)])
    np.testing.assert_allclose(grad, fd, rtol=1e-6, atol=1e-6 * max_abs(fd))
    assert abs(final(theta)[1]) <= EXACT
    assert max_abs(grad_psi) <= 1e-12, grad_psi


# ----------------------------------------------------------------------------- the generic problem
def _hand_pendulum(position_constraint):
    """The pendulum as a plain PartitionedDAE (no mass matrix): q' = p/m, p' = −m g e_y + 2 q λ,
    φ = 2 qᵀp/m, ψ = |q|² − ℓ²."""
    return PartitionedDAE(
        f=lambda t, q, p, a: p / a["m"],
        g=lambda t, q, p, lam, a: jnp.array([0.0, -a["m"] * a["g"]]) + 2.0 * q * lam[0],
        phi=lambda t, q, p, a: jnp.atleast_1d(2.0 * jnp.dot(q, p) / a["m"]),
        name="hand-written pendulum",
        position_constraint=position_constraint,
    )


def test_generic_partitioned_dae_is_projected_like_the_generated_model(pendulum):
    """A hand-written PartitionedDAE with ``position_constraint`` (direction D_pf ψ_qᵀ = ψ_qᵀ/m)
    gives the generated model's solution and keeps ψ at round-off."""
    pe = pendulum
    hand = _hand_pendulum(lambda t, q, a: jnp.atleast_1d(jnp.sum(q**2) - a["l"] ** 2))
    method = L.LobattoIIIAIIIB(stages=3)
    a = L.solve(hand, method, (0.0, 1.0), pe.q0, pe.p0, n_steps=50, args=pe.args)
    b = L.solve(pe.model.problem, method, (0.0, 1.0), pe.q0, pe.p0, n_steps=50, args=pe.args)
    np.testing.assert_allclose(a.q, b.q, rtol=0, atol=1e-13)
    np.testing.assert_allclose(a.p, b.p, rtol=0, atol=1e-12)
    _assert_exact(pe.model, a, pe.args)


def test_no_position_constraint_adds_nothing_to_the_step(pendulum, monkeypatch):
    """Without ψ the projection is a static branch not taken: tracing a step never reaches it
    (the step is the unprojected method, at no cost); with ψ it does."""
    from lobattodae import _stepper

    def unreachable(*a, **k):
        raise AssertionError("projection reached")

    monkeypatch.setattr(_stepper, "project_step_end", unreachable)
    pe = pendulum
    method = L.LobattoIIIAIIIB(stages=3)
    plain = dataclasses.replace(pe.model.problem, position_constraint=None)
    q, p, lam = jnp.asarray(pe.q0), jnp.asarray(pe.p0), jnp.zeros(1)
    jax.make_jaxpr(lambda q, p, lam: method.step(plain, 0.0, q, p, lam, 0.01, pe.args))(q, p, lam)
    with pytest.raises(AssertionError, match="projection reached"):
        jax.make_jaxpr(lambda q, p, lam: method.step(pe.model.problem, 0.0, q, p, lam, 0.01, pe.args))(q, p, lam)


def test_bad_position_constraints_are_refused_with_the_fix(pendulum):
    pe = pendulum
    with pytest.raises(ProblemDefinitionError, match=r"position_constraint must be a function psi\(t, q, args\)"):
        _hand_pendulum(0.0)
    method = L.LobattoIIIAIIIB(stages=2)
    cases = [
        (lambda t, q, a: jnp.sum(q**2) - a["l"] ** 2, r"must return a 1-D array of shape \(k,\).*returned shape \(\)"),
        (lambda t, q, a: jnp.stack([q, q]), r"must return a 1-D array of shape \(k,\).*returned shape \(2, 2\)"),
        (lambda t, q, a: q, r"1 ≤ k ≤ m = 1.*returned shape \(2,\)"),
        (lambda t, q, a: jnp.atleast_1d(q[0]).astype(jnp.int32), r"must return floating-point values"),
    ]
    for psi, match in cases:
        with pytest.raises(ShapeError, match=match):
            L.solve(_hand_pendulum(psi), method, (0.0, 0.1), pe.q0, pe.p0, n_steps=2, args=pe.args)
    with pytest.raises(L.ProblemFunctionError, match="position_constraint"):
        L.solve(_hand_pendulum(lambda t, q, a: jnp.atleast_1d(a["missing"])), method, (0.0, 0.1), pe.q0, pe.p0,
                n_steps=2, args=pe.args)
    # q0 off the constraint: named, with the fix
    good = _hand_pendulum(lambda t, q, a: jnp.atleast_1d(jnp.sum(q**2) - a["l"] ** 2))
    q_off = 1.01 * pe.q0
    p_off = pe.p0 * 1.01  # still tangent: φ = 0
    with pytest.raises(InconsistentInitialValuesError, match=r"violates the holonomic constraint.*Fix q0"):
        L.solve(good, method, (0.0, 0.1), q_off, p_off, n_steps=2, args=pe.args)


def test_project_initial_moves_q0_onto_the_position_constraint(pendulum):
    """project_initial=True puts an off-constraint q0 on ψ = 0 to round-off, along ψ_qᵀ (here
    f = p/m, so D_p f ψ_qᵀ ∝ q: radially, as the steps' projection moves their end points), then
    p0 onto φ = 0; from 1e-3 and from 1e-9 off alike, and a q0 with no nearby solution is
    refused with the reason."""
    pe = pendulum
    model = _hand_pendulum(lambda t, q, a: jnp.atleast_1d(jnp.sum(q**2) - a["l"] ** 2))
    ell = pe.args["l"]
    for off in (1e-3, 1e-9):
        q_off = (1.0 + off) * pe.q0
        sol = L.solve(model, L.LobattoIIIAIIIB(stages=3), (0.0, 0.1), q_off, pe.p0, n_steps=4, args=pe.args,
                      project_initial=True)
        q0 = np.asarray(sol.q[0])
        assert abs(np.sum(q0**2) - ell**2) <= 4e-16 * ell**2
        np.testing.assert_allclose(q0, pe.q0 * ell / np.linalg.norm(pe.q0), rtol=0, atol=1e-15)
        assert abs(float(np.dot(q0, np.asarray(sol.p[0])))) <= 1e-15
    q, p, _ = L.validate_initial_values(model, 0.0, 1.001 * pe.q0, pe.p0, args=pe.args, project=True)
    np.testing.assert_allclose(np.sum(q**2), ell**2, rtol=1e-15)
    # no q with |q| = ℓ near the origin along a radial step from 0: refused, not NaN
    with pytest.raises(InconsistentInitialValuesError, match=r"projecting q0 onto the holonomic constraint failed"):
        L.solve(model, L.LobattoIIIAIIIB(stages=3), (0.0, 0.1), np.zeros(2), np.zeros(2), n_steps=2,
                args=pe.args, project_initial=True)


# ----------------------------------------------------------------------------- dense output
def test_projected_dense_output_keeps_psi_phi_and_the_accuracy(pendulum):
    """``sol.sol(t, project=True)`` puts interpolated values on ψ = 0 and φ = 0 (round-off, where
    the interpolant misses ψ by ~1e-7) and moves them by about their own error: still as close
    to the reference as the interpolant."""
    pe = pendulum
    sol = L.solve(pe.model.problem, L.LobattoIIIAIIIB(stages=3), (0.0, 2.0), pe.q0, pe.p0, n_steps=100, args=pe.args,
                  dense_output=True)
    t = (np.arange(100) + 0.5) * 0.02
    q, p, _ = sol.sol(t)
    qp, pp, lamp = sol.sol(t, project=True)
    phi = jax.vmap(lambda tt, qq, pq: pe.model.problem.phi(tt, qq, pq, pe.args))
    assert max_abs(pe.model.holonomic_residual(t, q, pe.args)) > 1e-8
    assert max_abs(pe.model.holonomic_residual(t, qp, pe.args)) < EXACT
    assert max_abs(phi(jnp.asarray(t), jnp.asarray(qp), jnp.asarray(pp))) < EXACT
    hidden = jax.vmap(lambda tt, qq, pq, ll: L.hidden_constraint(pe.model.problem, tt, qq, pq, ll, pe.args))
    assert max_abs(hidden(jnp.asarray(t), jnp.asarray(qp), jnp.asarray(pp), jnp.asarray(lamp))) < 1e-10
    q_ref, p_ref = pe.reference(2.0)(t)
    assert max_abs(qp - q_ref) < 2 * max_abs(q - q_ref) and max_abs(pp - p_ref) < 2 * max_abs(p - p_ref)


# ----------------------------------------------------------------------------- checkpoint and resume
@pytest.mark.slow
def test_checkpoint_resume_with_projection_is_bitwise(pendulum, tmp_path):
    pe = pendulum
    method = L.LobattoIIIAIIIB(stages=3)
    kw = dict(n_steps=2000, args=pe.args, chunk_size=256)
    ref = L.solve(pe.model.problem, method, (0.0, 20.0), pe.q0, pe.p0, **kw)
    path = tmp_path / "run.npz"
    calls = {"left": 3}

    def stop(done, total):
        calls["left"] -= 1
        if calls["left"] == 0:
            raise KeyboardInterrupt

    part = L.solve(pe.model.problem, method, (0.0, 20.0), pe.q0, pe.p0, checkpoint=path, checkpoint_every=256,
                   progress=stop, **kw)
    assert not part.success
    full = L.solve(pe.model.problem, method, (0.0, 20.0), pe.q0, pe.p0, checkpoint=path, resume=True, **kw)
    np.testing.assert_array_equal(full.q, ref.q)
    np.testing.assert_array_equal(full.p, ref.p)
    _assert_exact(pe.model, full, pe.args)
