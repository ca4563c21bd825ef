"""The native step of ``lobattodae.mechanics`` models (issue #26, item 4): generated C that takes
the library's steps, against ``lobattodae.integrate`` on the same models."""

import numpy as np
import pytest

import lobattodae as L
from lobattodae import LobattoDAEInputError, Result, examples, mechanics
from lobattodae.mechanics import _native

pytestmark = pytest.mark.skipif(_native.c_compiler() is None, reason="no C compiler on this machine")


def _jax_run(model, s, lam_start, h, n_steps, q0, p0, lam0, args):
    method = L.LobattoIIIAIIIB(stages=s, lam_start=lam_start)
    out = L.integrate(model.problem, method, 0.0, h, n_steps, q0, p0, lam0, args)
    return [np.asarray(x) for x in out[:3]]


def _assert_same_run(native, jax_rows, h):
    """Every row equal to round-off: 1e-12 relative for q and p; λ is solved for as Z = hλ, to
    Newton's tolerance in Z, so to 1e-12 / h."""
    for name, ours, theirs in zip(("q", "p", "lam"), native[:3], jax_rows):
        scale = 1.0 + np.max(np.abs(theirs))
        assert np.max(np.abs(ours - theirs)) <= (1e-12 / h if name == "lam" else 1e-12) * scale, name


@pytest.fixture(scope="module")
def disk():
    ex = examples.falling_rolling_disk(steady=False)
    model = mechanics.systems.falling_disk()
    return model, ex, model.args(**ex.args._asdict())


@pytest.mark.parametrize("s, lam_start", [(3, "auto"), (4, "previous"), (5, "consistent")])
def test_the_falling_disk_takes_the_library_s_steps(disk, s, lam_start):
    """The generated disk (5 coordinates, 2 multipliers, a mass matrix solved per evaluation):
    every row of 200 steps equal to the JAX path's to round-off, for each multiplier policy."""
    model, ex, args = disk
    out = model.native(s, lam_start=lam_start).integrate(0.0, 0.05, 200, ex.q0, ex.p0, ex.lam0, args)
    assert out.status == Result.SUCCESSFUL and out.n_newton >= 200 and out.n_jacobians >= 1
    _assert_same_run(out, _jax_run(model, s, lam_start, 0.05, 200, ex.q0, ex.p0, ex.lam0, args), 0.05)
    # the constraint holds at every step point
    assert np.max(np.abs(model.constraint_residual(0.0, out.q, out.p, args))) < 1e-13


def test_the_sleigh_resynchronises_its_multiplier_where_the_library_does():
    """The Chaplygin sleigh's multiplier drifts under the paper's scheme: lam_start="auto" starts
    some steps from the hidden constraint's λ, at the same steps as the JAX path (the rows agree
    to round-off only if the resets do)."""
    ex = examples.chaplygin_sleigh()
    model = mechanics.systems.chaplygin_sleigh()
    args = model.args(**ex.args._asdict())
    out = model.native(4).integrate(0.0, 0.05, 2000, ex.q0, ex.p0, ex.lam0, args)
    assert out.status == Result.SUCCESSFUL and out.lam_resets >= 1
    q, p, _ = _jax_run(model, 4, "auto", 0.05, 2000, ex.q0, ex.p0, ex.lam0, args)
    assert np.max(np.abs(out.q - q)) <= 1e-12 * (1 + np.max(np.abs(q)))
    assert np.max(np.abs(out.p - p)) <= 1e-12 * (1 + np.max(np.abs(p)))


def test_a_moving_constraint_and_its_hidden_multiplier():
    """The ball on a translating turntable: affine constraints with explicit time (ν(t, q)), so the
    hidden constraint's λ needs the generated ∂/∂t terms. λ0 left out is computed natively and
    equals the library's consistent_lambda; the run equals the JAX path's."""
    model = mechanics.systems.turntable_ball()
    args = model.args(m=1.0, r=0.5, Omega=0.8, Vx=0.3, Vy=-0.2)
    q0 = np.array([0.4, -0.1, 0.0, 0.0, 0.0])
    qd0 = model.complete_velocities(0.2, q0, np.array([0.3, -0.2, 0.5, 0.1, 0.2]), args)
    p0 = model.momenta(0.2, q0, qd0, args)
    out = model.native(4, lam_start="consistent").integrate(0.2, 0.02, 150, q0, p0, args=args)
    lam0 = np.asarray(L.consistent_lambda(model.problem, 0.2, q0, p0, np.zeros(2), args))
    assert np.max(np.abs(out.lam[0] - lam0)) <= 1e-13 * (1 + np.max(np.abs(lam0)))
    q, p, lam = (np.asarray(x) for x in L.integrate(model.problem, L.LobattoIIIAIIIB(stages=4, lam_start="consistent"),
                                                     0.2, 0.02, 150, q0, p0, lam0, args)[:3])
    _assert_same_run(out, (q, p, lam), 0.02)


def test_a_failed_step_keeps_the_computed_prefix(disk):
    """A step far too long for Newton (h = 40 on the disk) fails: the status says so, the rows
    before it are kept and the rest are NaN."""
    model, ex, args = disk
    out = model.native(3).integrate(0.0, 40.0, 5, ex.q0, ex.p0, ex.lam0, args)
    assert out.status in (Result.DIVERGED, Result.MAX_ITERATIONS, Result.NONFINITE)
    finite = np.all(np.isfinite(out.q), axis=1)
    assert finite[0] and not finite[-1]
    assert np.all(finite[: np.argmin(finite)]) and not np.any(finite[np.argmin(finite):])
    assert np.array_equal(out.q[0], ex.q0) and out.t[0] == 0.0


def test_save_every_keeps_the_same_points(disk):
    """``save_every=k`` keeps rows 0, k, 2k, ... and the last of the full run, with their times;
    ``"final"`` the first and the last."""
    model, ex, args = disk
    native = model.native(3)
    full = native.integrate(0.0, 0.05, 23, ex.q0, ex.p0, ex.lam0, args)
    some = native.integrate(0.0, 0.05, 23, ex.q0, ex.p0, ex.lam0, args, save_every=5)
    final = native.integrate(0.0, 0.05, 23, ex.q0, ex.p0, ex.lam0, args, save_every="final")
    kept = [0, 5, 10, 15, 20, 23]
    for a, b in zip(some[:3], full[:3]):
        np.testing.assert_array_equal(a, b[kept])
    np.testing.assert_allclose(some.t, 0.05 * np.array(kept), rtol=0, atol=1e-15)
    np.testing.assert_array_equal(final.q, full.q[[0, 23]])
    assert final.t[-1] == pytest.approx(23 * 0.05)
    assert some.n_newton == full.n_newton


def test_a_failed_step_with_save_every_ends_on_the_last_point_reached():
    """A particle pulled into the singularity of V = −1/x (L = ½ ẋ² + ½ ẏ² + 1/x, ẋ = ẏ) from
    x = 1: steps of 0.1 fail as x nears 0 (after 9 steps). With rows kept every 4 steps, the rows
    are those of the full run at 0, 4, 8, then the last point the run reached, then NaN."""
    import sympy as sp
    from sympy.physics.mechanics import dynamicsymbols

    t = sp.Symbol("t")
    x, y = dynamicsymbols("x y")
    model = mechanics.from_lagrangian(x.diff(t) ** 2 / 2 + y.diff(t) ** 2 / 2 + 1 / x, [x, y], t,
                                      nonholonomic=[x.diff(t) - y.diff(t)], name="fall into 1/x")
    native = model.native(3)
    full = native.integrate(0.0, 0.1, 30, [1.0, 0.0], [-0.5, -0.5], args={})
    out = native.integrate(0.0, 0.1, 30, [1.0, 0.0], [-0.5, -0.5], args={}, save_every=4)
    assert full.status != Result.SUCCESSFUL and out.status == full.status and out.q.shape == (9, 2)
    last = int(np.max(np.nonzero(np.all(np.isfinite(full.q), axis=1))))  # the last point reached
    assert 8 < last < 30 and last % 4
    kept = [0, 4, 8, last]
    np.testing.assert_array_equal(out.q[:4], full.q[kept])
    np.testing.assert_allclose(out.t[:4], 0.1 * np.array(kept), atol=1e-14)
    assert not np.any(np.isfinite(out.q[4:])) and not np.any(np.isfinite(out.t[4:]))


def test_solve_returns_the_solution_lobattodae_solve_returns(disk):
    """``native.solve`` against ``lobattodae.solve`` with the same constant steps: the same rows
    (to round-off), the same ``stats`` keys, shapes and counts that do not depend on Newton's
    path, and a Solution that the library's tools take."""
    model, ex, args = disk
    ours = model.native(3).solve((0.0, 10.0), ex.q0, ex.p0, n_steps=200, save_every=7, args=args)
    theirs = L.solve(model.problem, L.LobattoIIIAIIIB(stages=3), (0.0, 10.0), ex.q0, ex.p0, n_steps=200, save_every=7,
                     args=args)
    assert ours.success and ours.result == Result.SUCCESSFUL and ours.status == 0
    np.testing.assert_array_equal(ours.t, theirs.t)
    for a, b in ((ours.q, theirs.q), (ours.p, theirs.p)):
        assert np.max(np.abs(a - b)) <= 1e-12 * (1 + np.max(np.abs(b)))
    assert set(ours.stats) == set(theirs.stats) == set(L.STATS)
    for key in ("constraint_residual", "multiplier_drift", "newton_iterations", "residual_norm", "lam_resync"):
        assert np.shape(ours.stats[key]) == np.shape(theirs.stats[key]), key
    for key in ("n_steps", "n_rejected", "h", "failed_step", "lam_excursions", "lam_resets"):
        assert ours.stats[key] == theirs.stats[key], key
    assert ours.stats["max_constraint_residual"] < 1e-13 and ours.y.shape == theirs.y.shape
    np.testing.assert_allclose(L.energy_error(ours), L.energy_error(theirs), atol=1e-12)
    by_dt = model.native(3).solve((0.0, 10.0), ex.q0, ex.p0, dt=0.05, save_every="final", args=args)
    np.testing.assert_array_equal(by_dt.q[-1], ours.q[-1])


def test_solve_checks_the_initial_values_and_reports_a_failure(disk):
    model, ex, args = disk
    native = model.native(3)
    with pytest.raises(L.InconsistentInitialValuesError, match="violate the constraints"):
        native.solve((0.0, 1.0), ex.q0, np.asarray(ex.p0) + 0.1, n_steps=10, args=args)
    with pytest.raises(L.NewtonFailure, match=r"Step 0 \(t = 0, h = 40\) failed") as failure:
        native.solve((0.0, 200.0), ex.q0, ex.p0, n_steps=5, args=args)
    assert failure.value.step == 0
    sol = native.solve((0.0, 200.0), ex.q0, ex.p0, n_steps=5, args=args, throw=False)
    assert not sol.success and sol.stats["failed_step"] == 0 and sol.q.shape == (1, 5)


def test_solve_warns_of_a_drifting_multiplier_as_lobattodae_solve_does():
    """The sleigh under the paper's scheme (lam_start="previous"): λ leaves its band; both solves
    warn with the same advice and count the excursions alike (980 and 981 of 2000 steps: the
    drift they compare is λ's undamped error, which round-off feeds)."""
    ex = examples.chaplygin_sleigh()
    model = mechanics.systems.chaplygin_sleigh()
    args = model.args(**ex.args._asdict())
    with pytest.warns(RuntimeWarning, match="left its normal band.*lam_start='auto'"):
        ours = model.native(4, lam_start="previous").solve((0.0, 100.0), ex.q0, ex.p0, n_steps=2000, args=args)
    with pytest.warns(RuntimeWarning, match="left its normal band"):
        theirs = L.solve(model.problem, L.LobattoIIIAIIIB(stages=4, lam_start="previous"), (0.0, 100.0), ex.q0, ex.p0,
                         n_steps=2000, args=args)
    assert abs(ours.stats["lam_excursions"] - theirs.stats["lam_excursions"]) <= 0.01 * theirs.stats["lam_excursions"]
    assert theirs.stats["lam_excursions"] > 100
    assert "Warning: the multiplier" in ours.message


def test_sympy_s_rolling_disc_meets_its_reference():
    """A model nobody here wrote: the rolling disc of SymPy's documentation (``KanesMethod``,
    converted by ``from_kanes_method``; ``benchmarks/testset``), natively with the test set's
    constant steps (s = 5, 400 steps to T = 10), against its reference from scipy's DOP853 at
    1e-13: within the test set's bound for the JAX path, 1.2e-8."""
    import pathlib
    import sys

    sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1]))
    from benchmarks.testset import PROBLEMS, error
    from benchmarks.testset import rolling_disc

    entry, setup = PROBLEMS["rolling-disc"], rolling_disc.build()
    sol = rolling_disc.model().native(entry.test.stages).solve(setup.t_span, setup.q0, setup.p0, args=setup.args,
                                                               n_steps=entry.test.n_steps)
    assert sol.success and sol.stats["max_constraint_residual"] < 1e-12
    assert error(entry, sol.t, sol.q, sol.p) <= entry.test.bound


def test_holonomic_constraints_are_kept_by_the_library_s_projection():
    """The Cartesian pendulum (ψ = x² + y² − ℓ²): each step's end projected onto ψ = 0 and φ = 0
    as ``lobattodae._projection`` does, so ψ holds to round-off at every step point and the rows
    equal the JAX path's."""
    model = mechanics.systems.cartesian_pendulum()
    args = model.args(m=0.7, g=9.81, l=1.3)
    q0 = np.array([1.3 * np.sin(0.6), -1.3 * np.cos(0.6)])
    p0 = model.momenta(0.0, q0, model.complete_velocities(0.0, q0, np.array([0.5, 0.5]), args), args)
    out = model.native(4).integrate(0.0, 0.02, 300, q0, p0, args=args)
    assert out.status == Result.SUCCESSFUL
    assert np.max(np.abs(model.holonomic_residual(0.0, out.q, args))) < 1e-13
    assert np.max(np.abs(model.constraint_residual(0.0, out.q, out.p, args))) < 1e-13
    _assert_same_run(out, _jax_run(model, 4, "auto", 0.02, 300, q0, p0, out.lam[0], args), 0.02)


@pytest.mark.parametrize("change, match", [
    (dict(n_steps=0), "n_steps must be a positive integer"),
    (dict(h=0.0), "h nonzero"),
    (dict(h=float("nan")), "finite"),
    (dict(q0=np.zeros(4)), r"q0 must have shape \(5,\)"),
    (dict(p0=np.full(5, np.nan)), "p0 has non-finite entries"),
    (dict(lam0=np.zeros(3)), r"lam0 must have shape \(2,\)"),
    (dict(args={"m": 1.0}), "args has missing parameter"),
    (dict(save_every=0), "save_every must be a positive integer"),
    (dict(save_every="last"), "save_every must be a positive integer"),
])
def test_bad_input_is_named(disk, change, match):
    model, ex, args = disk
    call = dict(t0=0.0, h=0.05, n_steps=10, q0=ex.q0, p0=ex.p0, lam0=ex.lam0, args=args) | change
    with pytest.raises(LobattoDAEInputError, match=match):
        model.native(3).integrate(**call)


def test_options_are_validated_as_the_method_s():
    model = mechanics.systems.falling_disk()
    with pytest.raises(ValueError, match="lam_start"):
        model.native(3, lam_start="sometimes")
    with pytest.raises(ValueError, match="tol"):
        model.native(3, tol=2.0)


def test_one_integrator_per_method_and_the_library_is_reused(disk):
    """``model.native`` keeps its integrators; a new one for the same program loads the compiled
    library instead of compiling again."""
    model = disk[0]
    first = model.native(3)
    assert model.native(3) is first and model.native(3, lam_start="previous") is not first
    mtime = first.library.stat().st_mtime_ns
    again = _native.NativeIntegrator(model, L.LobattoIIIAIIIB(stages=3))
    assert again.library == first.library and again.library.stat().st_mtime_ns == mtime


def test_a_new_process_finds_the_library_without_generating_the_c(disk, monkeypatch):
    """The cache is named by the model and s, not by the generated C: a second integrator (as in a
    new process) loads the library and never calls the generator."""
    model = disk[0]
    first = model.native(4)
    monkeypatch.setattr(_native, "program_source", lambda *a: pytest.fail("the C was generated again"))
    again = _native.NativeIntegrator(model, L.LobattoIIIAIIIB(stages=4))
    assert again.library == first.library


def test_runs_in_threads_share_nothing(disk):
    """The C keeps no state between or across calls (ctypes releases the GIL during a run): four
    runs in threads equal the same runs one after the other."""
    from concurrent.futures import ThreadPoolExecutor

    model, ex, args = disk
    native = model.native(3)
    starts = [np.asarray(ex.p0) * (1 + 0.01 * k) for k in range(4)]

    def run(p0):
        return native.integrate(0.0, 0.05, 300, ex.q0, p0, args=args).q

    alone = [run(p0) for p0 in starts]
    with ThreadPoolExecutor(4) as pool:
        together = list(pool.map(run, starts))
    for a, b in zip(alone, together):
        np.testing.assert_array_equal(a, b)


def test_without_a_compiler_the_message_names_the_fix(monkeypatch):
    monkeypatch.delenv("CC", raising=False)
    monkeypatch.setattr(_native.shutil, "which", lambda name: None)
    model = mechanics.systems.knife_edge()
    with pytest.raises(LobattoDAEInputError, match="needs a C compiler.*set CC"):
        model.native(2, tol=3e-14)


def _damped_magnetic_knife_edge():
    """A knife edge in a magnetic field (a gyroscopic term a(q)ᵀq̇), with a drag force that is
    nonlinear in the velocities: every term of ∂g/∂p that the native step derives (∂M/∂q, ∂a/∂q,
    ∂F/∂q̇)."""
    import sympy as sp
    from sympy.physics.mechanics import dynamicsymbols

    t = sp.Symbol("t")
    x, y, th = dynamicsymbols("x y theta")
    m, J, B, c = sp.symbols("m J B c", positive=True)
    xd, yd, thd = (z.diff(t) for z in (x, y, th))
    lagrangian = (m * (xd**2 + yd**2) + (J + m * sp.sin(th) ** 2) * thd**2) / 2 + B * (x * yd - y * xd) / 2
    forces = {x: -c * xd * sp.sqrt(1 + xd**2), th: -c * thd * yd}
    return mechanics.from_lagrangian(lagrangian, [x, y, th], t, nonholonomic=[sp.sin(th) * xd - sp.cos(th) * yd],
                                     forces=forces, defaults={"m": 1.3, "J": 0.4, "B": 0.7, "c": 0.2})


@pytest.mark.parametrize("build", [mechanics.systems.falling_disk, mechanics.systems.turntable_ball,
                                   _damped_magnetic_knife_edge])
def test_newton_s_blocks_in_p_and_lambda_are_the_exact_derivatives(build):
    """The native Newton matrix takes its blocks in p and λ exactly (∂f/∂p = M⁻¹, ∂g/∂p =
    (∂g0/∂v) M⁻¹, ∂g/∂λ = μᵀ, ∂φ/∂p = μ M⁻¹): equal to JAX's derivatives of the model's own f,
    g and φ at random states, to round-off."""
    import ctypes

    import jax

    model = build()
    n, m = model.n, model.m
    args = model.args(**{name: 0.5 + 0.1 * i for i, name in enumerate(model.parameters)})
    k = np.array([float(args[name]) for name in model.parameters] or [0.0])
    lib = model.native(4)._lib
    pointer = ctypes.POINTER(ctypes.c_double)
    lib.derivatives_pl.argtypes = [ctypes.c_double, pointer, pointer, pointer, pointer, pointer]
    problem = model.problem
    rng = np.random.default_rng(3)
    for _ in range(4):
        t = float(rng.uniform(0.0, 2.0))
        q, p, lam = rng.normal(size=n), rng.normal(size=n), rng.normal(size=m)
        out = np.zeros(2 * n * n + 2 * n * m)
        lib.derivatives_pl(t, *(a.ctypes.data_as(pointer) for a in (q, p, lam, k, out)))
        fp, gp = out[: n * n].reshape(n, n), out[n * n: 2 * n * n].reshape(n, n)
        gl, pp = out[2 * n * n: 2 * n * n + n * m].reshape(n, m), out[2 * n * n + n * m:].reshape(m, n)
        exact = {
            "fp": jax.jacfwd(lambda p_: problem.f(t, q, p_, args))(p),
            "gp": jax.jacfwd(lambda p_: problem.g(t, q, p_, lam, args))(p),
            "gl": jax.jacfwd(lambda l_: problem.g(t, q, p, l_, args))(lam),
            "pp": jax.jacfwd(lambda p_: problem.phi(t, q, p_, args))(p),
        }
        for name, ours in (("fp", fp), ("gp", gp), ("gl", gl), ("pp", pp)):
            theirs = np.asarray(exact[name])
            assert np.max(np.abs(ours - theirs)) <= 1e-12 * (1 + np.max(np.abs(theirs))), name


def _compile_c(tmp_path, name, source):
    """``source`` as a shared library (the generator's compiler and flags), through ctypes."""
    import ctypes
    import subprocess

    c, lib = tmp_path / f"{name}.c", tmp_path / f"{name}.so"
    c.write_text("#include <math.h>\n#include <string.h>\n" + source)
    subprocess.run([_native.c_compiler(), *_native.CFLAGS, "-o", str(lib), str(c), "-lm"], check=True)
    return ctypes.CDLL(str(lib))


def _reference_lu(a):
    """LU with partial pivoting one pivot at a time, in Python floats (the same IEEE operations in
    the order of LAPACK's dgetf2, zero multipliers skipped): the factors' specification."""
    n = len(a)
    a = [list(map(float, row)) for row in a]
    piv = []
    for k in range(n):
        pv, big = k, abs(a[k][k])
        for i in range(k + 1, n):
            if abs(a[i][k]) > big:
                pv, big = i, abs(a[i][k])
        piv.append(pv)
        a[k], a[pv] = a[pv], a[k]
        inv = 1.0 / a[k][k]
        for i in range(k + 1, n):
            a[i][k] *= inv
        for j in range(k + 1, n):
            f = a[k][j]
            if f != 0.0:
                for i in range(k + 1, n):
                    a[i][j] -= f * a[i][k]
    return np.array(a), np.array(piv)


@pytest.mark.parametrize("nu", [5, 29, 40, 67])
def test_the_lu_factors_are_those_of_one_pivot_at_a_time(tmp_path, nu):
    """The native LU (two pivots per pass, a vectorised pivot search, an AVX-512 copy from 40
    unknowns) gives the bits of the plain algorithm, one pivot at a time, on matrices with many
    zeros (skipped multipliers) and ties for the pivot; its solve agrees with NumPy's."""
    import ctypes

    lib = _compile_c(tmp_path, f"lu{nu}", f"#define NU {nu}\n" + _native._LU_C + r"""
void lu(double *a, int *piv, double *b) { factor(a, piv); lu_solve(a, piv, b); }
""")
    pointer = ctypes.POINTER(ctypes.c_double)
    rng = np.random.default_rng(nu)
    for trial in range(3):
        # sparse, nonsingular (a permuted diagonal: pivoting moves rows), with ties for the pivot
        perm = np.eye(nu)[rng.permutation(nu) if trial else np.arange(nu)]
        a = rng.normal(size=(nu, nu)) * (rng.random((nu, nu)) < 0.4) + 3.0 * perm
        a[:, 0] = np.round(a[:, 0] * 2) / 2
        b = rng.normal(size=nu)
        factors, piv, x = np.asfortranarray(a.copy()), np.zeros(nu, np.int32), b.copy()
        lib.lu(factors.ctypes.data_as(pointer), piv.ctypes.data_as(ctypes.POINTER(ctypes.c_int)),
               x.ctypes.data_as(pointer))  # column-major storage: the Fortran order of `a`
        ref, ref_piv = _reference_lu(a)
        assert np.array_equal(piv, ref_piv)
        assert np.array_equal(factors, ref)
        assert np.max(np.abs(x - np.linalg.solve(a, b))) <= 1e-11 * (1 + np.max(np.abs(x)))


def _spd_with_structure(rng, pattern):
    n = len(pattern)
    sym = np.triu(rng.normal(size=(n, n)) * pattern, 1)
    return sym + sym.T + np.diag(1.0 + np.abs(sym + sym.T).sum(axis=1))  # diagonally dominant


@pytest.mark.parametrize("shape", ["diagonal", "blocks", "arrow", "tridiagonal", "dense", "large"])
def test_the_mass_solve_written_for_its_structure_is_the_elimination(tmp_path, shape):
    """``mass_solve_columns`` (the elimination written out for M's structure, fill-in included)
    gives what the loops of ``spd_solve_columns`` give (equal values, one and several columns,
    also with a structurally nonzero entry that is zero), and solves M X = B."""
    import ctypes

    n = {"large": 16}.get(shape, 7)
    pattern = {
        "diagonal": np.eye(n),
        "blocks": np.kron(np.eye(4), np.ones((2, 2)))[:n, :n],
        "arrow": np.eye(n) + (np.add.outer(np.arange(n), np.arange(n)) * 0 + 1) * (
            (np.arange(n)[:, None] == 0) | (np.arange(n)[None, :] == 0)),
        "tridiagonal": np.eye(n) + np.eye(n, k=1) + np.eye(n, k=-1),
        "dense": np.ones((n, n)),
        "large": np.ones((n, n)),
    }[shape] != 0
    source = _native.mass_solve_source(pattern.tolist())
    assert ("spd_solve_columns(NQ" in source) == (shape == "large")  # a large one keeps the loops
    lib = _compile_c(tmp_path, shape, f"#define NQ {n}\n" + _native._SPD_SOLVE_C + source + r"""
void both(double *m1, double *b1, double *m2, double *b2, int m) { mass_solve_columns(m1, b1, m); spd_solve_columns(NQ, m2, b2, m); }
""")
    pointer = ctypes.POINTER(ctypes.c_double)
    rng = np.random.default_rng(7)
    for cols in (1, 3):
        for trial in range(3):
            mm = _spd_with_structure(rng, pattern)
            if trial == 2 and pattern.sum() > n:  # a structural nonzero that is zero at this state
                i, j = np.argwhere(np.triu(pattern, 1))[0]
                mm[i, j] = mm[j, i] = 0.0
            b = rng.normal(size=(n, cols))
            m1, b1, m2, b2 = mm.copy(), b.copy(), mm.copy(), b.copy()
            lib.both(*(x.ctypes.data_as(pointer) for x in (m1, b1, m2, b2)), cols)
            assert np.all(b1 == b2)
            assert np.max(np.abs(mm @ b1 - b)) <= 1e-13 * (1 + np.max(np.abs(b)))
