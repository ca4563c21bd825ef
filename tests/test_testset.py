"""The external test set (benchmarks/testset): definitions, initial values, and a constant-step
run of each problem against its reference (references from outside lobattodae: published test
set values, SymPy + scipy, closed forms, mpmath, scipy Radau; see benchmarks/testset/README.md).

Each constant-step run's bound is about twice the error measured for that (s, N) in the
README's convergence tables, where the error falls at the method's order 2s − 2; losing one
order would exceed it by far.
"""

import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import lobattodae as L
from lobattodae.mechanics import _native

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from benchmarks.testset import PROBLEMS, TestProblem, error  # noqa: E402
from benchmarks.testset import andrews, caraxis, crank, fekete, fourbar, knife_edge, rolling_disc, servo_sleigh, sleigh, vertical_disk  # noqa: E402

NAMES = list(PROBLEMS)


def test_registry():
    assert NAMES == ["andrews", "caraxis", "crank", "fekete", "rolling-disc", "fourbar", "vertical-disk", "sleigh",
                     "knife-edge", "servo-sleigh", "servo-sleigh-rest"]
    for name, entry in PROBLEMS.items():
        assert isinstance(entry, TestProblem) and entry.name == name
        assert entry.source and entry.ref_accuracy > 0 and entry.test.bound > 0
        first, second = entry.build(), entry.build()
        assert first.problem is second.problem  # built once: compiled code is reused
        assert entry.long == (first.t_span[1] - first.t_span[0] >= 1000)
        n = first.q0.shape[0]
        assert first.p0.shape == (n,)
        assert all(len(row) == n for row in entry.q_ref)
        assert entry.p_ref is None or all(len(row) == n for row in entry.p_ref)
        assert max(entry.t_ref) <= first.t_span[1]
    assert PROBLEMS["servo-sleigh"].build().problem is PROBLEMS["servo-sleigh-rest"].build().problem
    assert [e.name for e in PROBLEMS.values() if e.long] == ["fekete", "sleigh", "knife-edge"]
    assert [e.name for e in PROBLEMS.values() if e.stiff] == ["crank", "servo-sleigh", "servo-sleigh-rest"]
    assert [e.name for e in PROBLEMS.values() if e.mechanics] == ["andrews", "crank", "rolling-disc", "fourbar"]
    assert [e.name for e in PROBLEMS.values() if e.mechanics_momenta] == ["crank"]


def test_every_problem_has_a_convergence_study():
    from benchmarks.testset.convergence import DEFAULT_STUDY

    assert list(DEFAULT_STUDY) == NAMES


def test_error_measure():
    entry = PROBLEMS["knife-edge"]
    t = np.array(entry.t_ref)
    q, p = np.array(entry.q_ref), np.array(entry.p_ref)
    assert error(entry, t, q, p) == 0.0
    q2 = q.copy()
    q2[1, 0] += 1e-6 * (1 + abs(q[1, 0]))
    assert error(entry, t, q2, p) == pytest.approx(1e-6, rel=1e-6)
    assert error(entry, t[-1], q[-1], p[-1]) == 0.0  # one time
    with pytest.raises(ValueError):
        error(entry, [3.0], q[:1], p[:1])  # no reference time


@pytest.mark.parametrize("name", NAMES)
def test_initial_values_are_consistent(name):
    s = PROBLEMS[name].build()
    q0, p0 = jnp.asarray(s.q0), jnp.asarray(s.p0)
    t0 = s.t_span[0]
    phi = np.asarray(s.problem.phi(t0, q0, p0, s.args))
    assert np.max(np.abs(phi)) <= 1e-14 * (1 + np.max(np.abs(s.p0)))
    psi = getattr(s.problem, "position_constraint", None)
    if psi is not None:
        assert np.max(np.abs(np.asarray(psi(t0, q0, s.args)))) <= 1e-15
    if PROBLEMS[name].reference is not None:  # closed forms start at their own t = 0 values
        q_ex, p_ex = PROBLEMS[name].reference(t0)
        np.testing.assert_allclose(s.q0, q_ex, atol=1e-15)
        np.testing.assert_allclose(s.p0, p_ex, atol=1e-15)


@pytest.mark.parametrize("name", NAMES)
def test_constant_steps_reach_the_reference(name):
    entry = PROBLEMS[name]
    s = entry.build()
    sol = L.solve(s.problem, L.LobattoIIIAIIIB(stages=entry.test.stages), s.t_span, s.q0, s.p0,
                  args=s.args, n_steps=entry.test.n_steps)
    assert sol.success
    err = error(entry, sol.t, sol.q, sol.p)
    assert err <= entry.test.bound, (name, err)
    assert err >= entry.ref_accuracy / 100  # compared with a reference, not with itself


# ----------------------------------------------------------------------------- Andrews
def test_andrews_matches_the_published_initial_data():
    """The library's consistent λ(0) and the accelerations q''(0) = M⁻¹(f − Gᵀλ) equal the test
    set's y(15..27) at t = 0; G is the Jacobian of g."""
    s = andrews.build()
    q0, p0 = jnp.asarray(s.q0), jnp.asarray(s.p0)
    lam0 = L.consistent_lambda(s.problem, 0.0, q0, p0, jnp.zeros(6), None)
    np.testing.assert_allclose(lam0, andrews.LAM0, rtol=1e-13, atol=1e-12)
    G = andrews.constraint_jacobian(s.q0)
    np.testing.assert_allclose(jax.jacfwd(andrews.constraints)(q0), G, atol=1e-16)
    acc = np.linalg.solve(andrews.mass_matrix(s.q0), andrews.forces(s.q0, np.zeros(7)) - G.T @ np.array(andrews.LAM0))
    np.testing.assert_allclose(acc, andrews.W_DOT0, rtol=1e-13, atol=1e-9)
    # the published end point satisfies the constraints and their velocity form
    q_ref = np.array(andrews.Q_REF)
    assert np.max(np.abs(andrews.constraints(q_ref))) < 1e-12
    assert np.max(np.abs(andrews.constraint_jacobian(q_ref) @ np.array(andrews.QDOT_REF))) < 1e-9


def test_andrews_published_reference_agrees_with_scipy():
    """The published q(0.03) agrees with an independent scipy DOP853 solution of the index-1
    form to its stated accuracy (ref_accuracy = 1e-10; measured 8.5e-11, q' 2.7e-8)."""
    q, qdot = andrews.scipy_reference("DOP853", 1e-13)
    q_ref, qdot_ref = np.array(andrews.Q_REF), np.array(andrews.QDOT_REF)
    assert np.max(np.abs(q - q_ref) / (1 + np.abs(q_ref))) < PROBLEMS["andrews"].ref_accuracy
    assert np.max(np.abs(qdot - qdot_ref) / (1 + np.abs(qdot_ref))) < 5e-8


def test_andrews_lagrangian_twin_has_the_published_equations():
    """The mechanism written with lobattodae.mechanics (M, the spring's potential, the torque; the
    Coriolis terms left to Lagrange's equations) has the published f and g at random states (its λ
    the test set's with the opposite sign), and natively (generated C, constant steps) it ends where
    the test set's problem does, within the fast test's bound of the published reference."""
    mdl, args = PROBLEMS["andrews"].mechanics()
    s = andrews.build()
    assert (mdl.n, mdl.m, mdl.n_holonomic) == (7, 6, 6)
    rng = np.random.default_rng(3)
    for _ in range(3):
        q = jnp.asarray(np.array(andrews.Q0) + 0.5 * rng.standard_normal(7))
        p = jnp.asarray(andrews.mass_matrix(np.asarray(q)) @ (100.0 * rng.standard_normal(7)))
        lam = jnp.asarray(50.0 * rng.standard_normal(6))
        np.testing.assert_allclose(mdl.problem.f(0.0, q, p, args), s.problem.f(0.0, q, p, None), rtol=1e-13, atol=1e-12)
        g_twin, g_set = mdl.problem.g(0.0, q, p, -lam, args), s.problem.g(0.0, q, p, lam, None)
        np.testing.assert_allclose(g_twin, g_set, rtol=1e-12, atol=1e-12 * float(jnp.max(jnp.abs(g_set))))
        np.testing.assert_allclose(mdl.problem.position_constraint(0.0, q, args), andrews.constraints(q), atol=1e-16)
    if _native.c_compiler() is None:
        pytest.skip("no C compiler on this machine: the native run is not tried")
    entry = PROBLEMS["andrews"]
    native = mdl.native(entry.test.stages).solve(s.t_span, s.q0, s.p0, n_steps=entry.test.n_steps, args=args)
    ours = L.solve(s.problem, L.LobattoIIIAIIIB(stages=entry.test.stages), s.t_span, s.q0, s.p0,
                   n_steps=entry.test.n_steps)
    assert error(entry, np.asarray(native.t), np.asarray(native.q), np.asarray(native.p)) < entry.test.bound
    np.testing.assert_allclose(native.q[-1], ours.q[-1], rtol=0, atol=1e-12 * (1 + float(jnp.max(jnp.abs(ours.q[-1])))))


# ----------------------------------------------------------------------------- car axis
def test_caraxis_equations_are_the_test_sets():
    """G is the Jacobian of ψ and ψ_t its time derivative; the published end point lies on
    ψ = 0 and ψ' = 0; and the library's accelerations with the consistent λ solve the test set's
    index-1 system at a random state (the multiplier of ``carfunc``, same sign)."""
    t, q = 1.234, jnp.array([0.05, 0.49, 1.04, 0.37])
    np.testing.assert_allclose(jax.jacfwd(caraxis.constraints, argnums=1)(t, q, xp=jnp),
                               caraxis.constraint_jacobian(t, q, xp=jnp), atol=1e-15)
    np.testing.assert_allclose(jax.jacfwd(caraxis.constraints)(t, q, xp=jnp), caraxis.constraint_rate(t, q, xp=jnp),
                               atol=1e-15)
    q_ref, u_ref = np.array(caraxis.Q_REF), np.array(caraxis.U_REF)
    assert np.max(np.abs(caraxis.constraints(3.0, q_ref))) < 1e-14
    # ψ' to the published velocities' accuracy (8.5e-12; they differ from scipy's by 4.3e-12)
    assert np.max(np.abs(caraxis.constraint_rate(3.0, q_ref) + caraxis.constraint_jacobian(3.0, q_ref) @ u_ref)) < 2e-11
    # at the reference state: the consistent λ of the DAE is the published λ(3) to that value's
    # accuracy (the λ of scipy's DOP853 and Radau end states both differ from it by 1.6e-10 and
    # 8.0e-11), and u' is the index-1 ODE's
    s = caraxis.build()
    qj, uj = jnp.asarray(q_ref), jnp.asarray(u_ref)
    lam = L.consistent_lambda(s.problem, 3.0, qj, uj, jnp.zeros(2), None)
    np.testing.assert_allclose(lam, caraxis.LAM_REF, rtol=0, atol=3e-10)
    np.testing.assert_allclose(s.problem.g(3.0, qj, uj, lam, None), caraxis.index1_rhs(3.0, np.r_[q_ref, u_ref])[4:],
                               rtol=1e-12, atol=1e-12)


def test_caraxis_published_reference_agrees_with_scipy():
    """The published y(3) agrees with an independent scipy DOP853 solution of the index-1 form
    to ref_accuracy (measured: q 2.2e-13, u 4.3e-12)."""
    q, u = caraxis.scipy_reference("DOP853", 1e-13)
    for y, y_ref in ((q, caraxis.Q_REF), (u, caraxis.U_REF)):
        y_ref = np.array(y_ref)
        assert np.max(np.abs(y - y_ref) / (1 + np.abs(y_ref))) < PROBLEMS["caraxis"].ref_accuracy


# ----------------------------------------------------------------------------- slider crank
def test_crank_equations_are_the_test_sets():
    """G is the Jacobian of ψ and M is symmetric positive definite; at the (projected) initial
    values the library's consistent λ(0) and accelerations equal the test set's y(22..24) and
    y(15..21) to the accuracy of its nine-digit initial values (measured: 1.2e-7 of λ₂ = 382;
    1.6e-6 of w₃ = −5062); the projection moved the initial values by less than that."""
    s = crank.build()
    q0, p0 = jnp.asarray(s.q0), jnp.asarray(s.p0)
    np.testing.assert_allclose(jax.jacfwd(lambda q: crank.position_constraints(0.0, q))(q0),
                               crank.constraint_jacobian(s.q0), atol=1e-16)
    M = crank.mass_matrix(s.q0)
    np.testing.assert_array_equal(M, M.T)
    assert np.linalg.eigvalsh(M).min() > 0
    assert np.max(np.abs(s.q0 - np.array(crank.Q0))) < 1e-9 and np.max(np.abs(s.p0 - np.array(crank.V0))) < 1e-7
    lam0 = L.consistent_lambda(s.problem, 0.0, q0, p0, jnp.zeros(3), None)
    np.testing.assert_allclose(lam0, crank.LAM0, rtol=0, atol=5e-7)
    np.testing.assert_allclose(s.problem.g(0.0, q0, p0, lam0, None), crank.W0, rtol=1e-9, atol=5e-7)
    # the index-1 form of the check below gives the same accelerations
    np.testing.assert_allclose(crank.index1_rhs(0.0, np.r_[s.q0, s.p0])[7:], crank.W0, rtol=1e-9, atol=5e-7)


def test_crank_reference_agrees_with_scipy_and_the_published_positions():
    """The stored reference (DOP853 at scipy's floor) is reproduced by DOP853 at rtol 1e-13
    (measured 1.5e-10 in v) and agrees with the published q(0.1) to 4.4e-11; the published
    v(0.1) differs from it by 6.3e-7 (why it is not the reference)."""
    q, v = crank.scipy_reference("DOP853", 1e-13)
    rel = lambda y, y_ref: np.max(np.abs(y - np.array(y_ref)) / (1 + np.abs(np.array(y_ref))))  # noqa: E731
    assert rel(q, crank.Q_REF) < 1e-13 and rel(v, crank.V_REF) < 3e-10
    assert rel(np.array(crank.PUBLISHED_Q), crank.Q_REF) < 1e-10
    assert 1e-7 < rel(np.array(crank.PUBLISHED_V), crank.V_REF) < 1e-6


# ----------------------------------------------------------------------------- Fekete
def test_fekete_equations_are_the_test_sets():
    """The repulsion against a loop over pairs; the library's consistent λ(0) is ``fekinit``'s
    λ_i = −x_i·F_i/2; at the published end point the constraints hold, the forces are radial
    (an equilibrium) and the consistent λ is the published −4.75."""
    x = fekete.initial_positions()
    loop = np.array([sum((x[i] - x[j]) / np.sum((x[i] - x[j]) ** 2) for j in range(20) if j != i) for i in range(20)])
    np.testing.assert_allclose(fekete.forces(x), loop, rtol=1e-14, atol=1e-14)
    s = fekete.build()
    lam0 = L.consistent_lambda(s.problem, 0.0, jnp.asarray(s.q0), jnp.asarray(s.p0), jnp.zeros(20), None)
    np.testing.assert_allclose(lam0, -np.sum(x * loop, axis=1) / 2, rtol=1e-13, atol=1e-13)
    x_ref = np.array(fekete.X_REF).reshape(20, 3)
    assert np.max(np.abs(np.sum(x_ref**2, axis=1) - 1)) < 1e-14
    f_ref = fekete.forces(x_ref)
    tangential = f_ref - np.sum(f_ref * x_ref, axis=1)[:, None] * x_ref
    assert np.max(np.abs(tangential)) < 1e-10
    lam = L.consistent_lambda(s.problem, 1000.0, jnp.asarray(x_ref.reshape(-1)), jnp.zeros(60), jnp.zeros(20), None)
    np.testing.assert_allclose(lam, fekete.LAM_REF, rtol=1e-13)


def test_fekete_published_reference_agrees_with_scipy():
    """The published x(1000) agrees with scipy DOP853 on the index-1 ODE (final positions
    normalised onto the spheres; measured 2.5e-12) to ref_accuracy."""
    x, v = fekete.scipy_reference("DOP853", 1e-13)
    x_ref = np.array(fekete.X_REF)
    assert np.max(np.abs(x - x_ref) / (1 + np.abs(x_ref))) < PROBLEMS["fekete"].ref_accuracy
    assert np.max(np.abs(v)) < 1e-11  # at rest


def test_crank_lagrangian_twin_has_the_published_equations():
    """The slider crank written with lobattodae.mechanics (the test set's mass matrix, the rod's
    elastic energy, the three position constraints; its Coriolis, centrifugal and elastic forces
    left to Lagrange's equations) has the test set's F: at random states its f gives v from
    p = M v and its g (λ = 0) equals d/dt (M v) = M v' + Ṁ v with the test set's v'; natively
    (constant steps) it ends where the test set's problem does, within the fast test's bound."""
    entry = PROBLEMS["crank"]
    mdl, args = entry.mechanics()
    to_model, to_problem = entry.mechanics_momenta
    s = crank.build()
    assert (mdl.n, mdl.m, mdl.n_holonomic, mdl.parameters) == (7, 3, 3, ())
    rng = np.random.default_rng(5)
    for _ in range(3):
        q = np.array(s.q0) + 0.3 * rng.standard_normal(7)
        v = np.array(s.p0) + 10.0 * rng.standard_normal(7)
        p = to_model(0.0, q, v)
        np.testing.assert_allclose(mdl.problem.f(0.0, jnp.asarray(q), jnp.asarray(p), args), v, rtol=1e-13,
                                   atol=1e-12 * np.max(np.abs(v)))
        acc = np.asarray(s.problem.g(0.0, jnp.asarray(q), jnp.asarray(v), jnp.zeros(3), None))
        _, mdot = jax.jvp(crank.mass_matrix, (jnp.asarray(q),), (jnp.asarray(v),))
        expected = crank.mass_matrix(q) @ acc + np.asarray(mdot) @ v
        np.testing.assert_allclose(mdl.problem.g(0.0, jnp.asarray(q), jnp.asarray(p), jnp.zeros(3), args), expected,
                                   rtol=1e-12, atol=1e-12 * np.max(np.abs(expected)))
    if _native.c_compiler() is None:
        pytest.skip("no C compiler on this machine: the native run is not tried")
    native = mdl.native(entry.test.stages).solve(s.t_span, s.q0, to_model(0.0, s.q0, s.p0), n_steps=entry.test.n_steps,
                                                 args=args)
    t, q = np.asarray(native.t), np.asarray(native.q)
    assert error(entry, t, q, to_problem(t, q, np.asarray(native.p))) < entry.test.bound
    ours = L.solve(s.problem, L.LobattoIIIAIIIB(stages=entry.test.stages), s.t_span, s.q0, s.p0,
                   n_steps=entry.test.n_steps)
    np.testing.assert_allclose(q[-1], ours.q[-1], rtol=0, atol=1e-12 * (1 + float(jnp.max(jnp.abs(ours.q[-1])))))


# ----------------------------------------------------------------------------- rolling disc
def test_rolling_disc_reference_and_conversion():
    """SymPy's equations reproduce the stored reference at t = 1, 2 (DOP853), and the momenta
    computed from SymPy's speeds equal those of lobattodae's converted model."""
    t, q, p, u = rolling_disc.compute_reference("DOP853", 1e-13, t_eval=(1.0, 2.0))
    np.testing.assert_allclose(q, np.array(rolling_disc.Q_REF)[:2], rtol=0, atol=1e-12)
    np.testing.assert_allclose(p, np.array(rolling_disc.P_REF)[:2], rtol=0, atol=1e-12)
    mdl, s = rolling_disc.model(), rolling_disc.build()
    _, _, qdot, momenta = rolling_disc._numeric()
    for qk, uk in zip(q, u):
        np.testing.assert_allclose(mdl.momenta(1.0, qk, qdot(qk, uk), s.args), momenta(qk, uk), rtol=1e-13, atol=1e-13)
        np.testing.assert_allclose(mdl.constraint_residual(1.0, qk, momenta(qk, uk), s.args), 0.0, atol=1e-11)


# ----------------------------------------------------------------------------- four-bar linkage
def test_fourbar_reference_and_conversion():
    """SymPy's own equations (System.form_eoms) reproduce the stored reference at t = 1
    (DOP853), the initial state closes the loop, and the converted model's momenta and
    constraints agree with SymPy's speeds and loop closure along the reference."""
    _, q, p, u = fourbar.compute_reference("DOP853", 1e-13, t_eval=(1.0,))
    np.testing.assert_allclose(q, np.array(fourbar.Q_REF)[:1], rtol=0, atol=1e-12)
    np.testing.assert_allclose(p, np.array(fourbar.P_REF)[:1], rtol=0, atol=1e-12)
    mdl, s = fourbar.model(), fourbar.build()
    assert (mdl.n, mdl.m, mdl.n_holonomic) == (3, 2, 2)
    _, closure, momenta = fourbar._numeric()
    assert np.max(np.abs(closure(s.q0)[0])) < 1e-15
    for qk, uk in zip(q, u):  # q' = u for pin joints
        np.testing.assert_allclose(mdl.momenta(1.0, qk, uk, s.args), momenta(qk, uk), rtol=1e-13, atol=1e-13)
        np.testing.assert_allclose(mdl.constraint_residual(1.0, qk, momenta(qk, uk), s.args), 0.0, atol=1e-11)
        psi = np.asarray(s.problem.position_constraint(1.0, jnp.asarray(qk), s.args))
        np.testing.assert_allclose(psi, closure(qk)[0], rtol=0, atol=1e-15)


# ----------------------------------------------------------------------------- closed forms
def test_closed_forms_agree_with_the_library_examples():
    """Two independent implementations of PROBLEMS.md: ours (references) and the examples'."""
    from lobattodae.examples import chaplygin_sleigh, knife_edge as lib_knife, vertical_rolling_disk

    t = np.array([0.0, 0.7, 10.0, 100.0])
    for mod, factory in ((knife_edge, lib_knife), (vertical_disk, vertical_rolling_disk)):
        ex = factory(**mod.PARAMS, **mod.INIT)
        q_lib, p_lib, _ = ex.exact(t)
        q, p = mod.exact(t)
        np.testing.assert_allclose(q, q_lib, rtol=1e-13, atol=1e-13)
        np.testing.assert_allclose(p, p_lib, rtol=1e-13, atol=1e-13)
    ex = chaplygin_sleigh(**sleigh.PARAMS, **sleigh.INIT)
    q_lib, p_lib, _ = ex.exact(np.array(sleigh.T_REF))
    np.testing.assert_allclose(np.array(sleigh.Q_REF), q_lib, rtol=1e-14, atol=1e-14)
    np.testing.assert_allclose(np.array(sleigh.P_REF), p_lib, rtol=1e-14, atol=1e-14)


@pytest.mark.parametrize("mod", [knife_edge, vertical_disk])
def test_closed_forms_solve_the_equations(mod):
    """q' = f(q, p) and φ = 0 along the closed form (central differences, h = 1e-5)."""
    s = mod.PROBLEM.build()
    for t in (0.3, 5.0, 77.0):
        q, p = mod.exact(t)
        (qa, _), (qb, _) = mod.exact(t - 1e-5), mod.exact(t + 1e-5)
        f = np.asarray(s.problem.f(t, jnp.asarray(q), jnp.asarray(p), s.args))
        np.testing.assert_allclose((qb - qa) / 2e-5, f, rtol=1e-8, atol=1e-8)
        assert abs(float(s.problem.phi(t, jnp.asarray(q), jnp.asarray(p), s.args)[0])) < 1e-13


@pytest.mark.slow
def test_sleigh_reference_recomputed():
    q, p = sleigh.compute_reference(times=(10.0,))
    np.testing.assert_array_equal(q[0], sleigh.Q_REF[0])
    np.testing.assert_array_equal(p[0], sleigh.P_REF[0])


# ----------------------------------------------------------------------------- stiff problem
def test_servo_sleigh_dae_is_the_reference_ode():
    """At random consistent states the DAE's accelerations (with the consistent λ) equal the
    hand-written body-velocity ODE's, and the stored reference is reproduced by Radau."""
    s = servo_sleigh.build_smooth()
    prm = servo_sleigh.PARAMS
    rng = np.random.default_rng(1)
    for _ in range(4):
        y = rng.normal(size=5)
        t = float(rng.uniform(0, 10))
        q, p = (a[0] for a in servo_sleigh.body_to_qp(y))
        qj, pj = jnp.asarray(q), jnp.asarray(p)
        assert abs(float(s.problem.phi(t, qj, pj, s.args)[0])) < 1e-14
        lam = L.consistent_lambda(s.problem, t, qj, pj, jnp.zeros(1), s.args)
        pdot = np.asarray(s.problem.g(t, qj, pj, lam, s.args))
        ydot = servo_sleigh.body_rhs(t, y)
        th, v, w = y[2], y[3], y[4]
        c, sn = np.cos(th), np.sin(th)
        # p = m (v e1 + a w e2), e1 = (c, s), e2 = (−s, c), p_θ = I w
        xdd = ydot[3] * c - v * sn * w - prm["a"] * (ydot[4] * sn + w * w * c)
        ydd = ydot[3] * sn + v * c * w + prm["a"] * (ydot[4] * c - w * w * sn)
        expected = np.array([prm["m"] * xdd, prm["m"] * ydd, prm["I"] * ydot[4]])
        np.testing.assert_allclose(pdot, expected, rtol=1e-10, atol=1e-9 * (1 + np.abs(expected).max()))
    q, p, _ = servo_sleigh.compute_reference(servo_sleigh.Y0_SMOOTH, "Radau", 1e-13, times=(1.0,))
    np.testing.assert_allclose(q[0], servo_sleigh.SMOOTH_Q_REF[0], rtol=0, atol=1e-13)
    np.testing.assert_allclose(p[0], servo_sleigh.SMOOTH_P_REF[0], rtol=0, atol=1e-13)
