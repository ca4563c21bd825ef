"""Error-controlled steps natively (``lobattodae.mechanics._native_loop``): each attempt of
step doubling one call into the model's C inside ``lobattodae.solve``'s loop, against the JAX
path's attempts on the same models."""

import numpy as np
import pytest
from scipy.optimize import brentq

import lobattodae as L
from lobattodae import LobattoDAEInputError, Result, examples, mechanics
from lobattodae.mechanics import _native

pytestmark = pytest.mark.skipif(_native.c_compiler() is None, reason="no C compiler on this machine")

COUNTS = ("n_steps", "n_rejected", "n_failed_solves", "n_checked", "n_unresolved", "lam_excursions")


@pytest.fixture(scope="module")
def sleigh():
    ex = examples.chaplygin_sleigh()
    model = mechanics.systems.chaplygin_sleigh()
    return model, ex, model.args(**ex.args._asdict())


@pytest.fixture(scope="module")
def disk():
    ex = examples.falling_rolling_disk(steady=False)
    model = mechanics.systems.falling_disk()
    return model, ex, model.args(**ex.args._asdict())


def _both(model, s, lam_start, t_span, q0, p0, args, **options):
    """The JAX path's run and the native one, with the same method and options."""
    method = L.LobattoIIIAIIIB(stages=s, lam_start=lam_start)
    native = model.native(s, lam_start=lam_start)
    return (L.solve(model.problem, method, t_span, q0, p0, args=args, **options),
            L.solve(model.problem, native, t_span, q0, p0, args=args, **options))


def test_the_sleigh_takes_the_same_steps_to_the_same_error(sleigh):
    """T = 1000, s = 5, rtol 1e-8 (the benchmark of issue #25, item 5): the same accepted and
    rejected attempts as the JAX doubling, the step points where its are (the controller reads
    estimates that differ by Newton's stopping only), the same error against the closed form."""
    model, ex, args = sleigh
    jax_sol, native_sol = _both(model, 5, "auto", (0.0, 1000.0), ex.q0, ex.p0, args, lam0=ex.lam0, rtol=1e-8,
                                atol=1e-8)
    assert native_sol.result == Result.SUCCESSFUL
    assert {k: native_sol.stats[k] for k in COUNTS} == {k: jax_sol.stats[k] for k in COUNTS}
    assert native_sol.stats["n_rejected"] >= 1  # rejections are selected back correctly
    # the first steps agree to round-off; once the sleigh runs straight its estimates are at
    # Newton's noise, where the two runs' step sizes part (by a few per cent; the same number of
    # them) without changing the error
    np.testing.assert_allclose(native_sol.t[:4], jax_sol.t[:4], rtol=1e-8)

    def error(sol):
        q, p, _ = ex.exact(sol.t)
        return max(np.abs(sol.q - q).max(), np.abs(sol.p - p).max())

    assert error(native_sol) <= 30 * 1e-8 and abs(error(native_sol) - error(jax_sol)) <= 0.05 * error(jax_sol)
    assert native_sol.stats["max_constraint_residual"] < 1e-14
    assert type(native_sol.method).__name__ == "NativeDoubling" and native_sol.method.stages == 5


@pytest.mark.parametrize("s, lam_start, options", [
    (3, "previous", {}),  # the carried multiplier: the half steps' drift monitor
    (4, "auto", dict(t_eval=np.linspace(0.0, 20.0, 9), dense_output=True)),
    (5, "consistent", dict(first_step=20.0)),  # whole steps that fail: their halves are not solved
])
def test_the_falling_disk_follows_the_jax_path(disk, s, lam_start, options):
    """The generated disk in general motion over (0, 20) at rtol 1e-7: the same counts (attempts,
    rejections, failed solves, Richardson checks, λ excursions), and the rows and the dense output
    of both runs within a small multiple of rtol of each other (t_eval rows: the same times)."""
    model, ex, args = disk
    jax_sol, native_sol = _both(model, s, lam_start, (0.0, 20.0), ex.q0, ex.p0, args, rtol=1e-7, atol=1e-7,
                                **options)
    assert native_sol.success
    assert {k: native_sol.stats[k] for k in COUNTS} == {k: jax_sol.stats[k] for k in COUNTS}
    if "first_step" in options:
        assert native_sol.stats["n_failed_solves"] >= 1
    assert native_sol.t.shape == jax_sol.t.shape
    if "t_eval" in options:
        np.testing.assert_array_equal(native_sol.t, options["t_eval"])
        np.testing.assert_allclose(native_sol.q, jax_sol.q, rtol=0, atol=1e-9)
        t = np.linspace(0.0, 20.0, 101)
        np.testing.assert_allclose(native_sol.sol(t)[0], jax_sol.sol(t)[0], rtol=0, atol=1e-8)
    else:
        np.testing.assert_allclose(native_sol.t, jax_sol.t, rtol=0, atol=1e-6)
    assert native_sol.stats["max_constraint_residual"] < 1e-14
    assert np.all(native_sol.stats["constraint_residual"] < 1e-14)


def test_a_terminal_event_lands_at_the_method_s_full_order(sleigh):
    """The sleigh's heading event (issue #25's test): located on the dense output and re-stepped
    onto by native attempts, |t_event − t*| ≤ 1e-10 at rtol 1e-10, s = 4, the state on φ = 0."""
    model, ex, args = sleigh
    target = 0.5

    def heading(t, q, p, args):
        return q[2] - target

    heading.terminal = True
    sol = model.native(4).solve((0.0, 10.0), ex.q0, ex.p0, lam0=ex.lam0, args=args, rtol=1e-10, atol=1e-10,
                                events=heading)
    assert sol.result == Result.EVENT and sol.success
    t_exact = brentq(lambda t: ex.exact(t)[0][2] - target, 0.01, 2.0, xtol=1e-15)
    assert abs(sol.t_events[0][0] - t_exact) <= 1e-10 and sol.t[-1] == sol.t_events[0][0]
    assert sol.stats["constraint_residual"][-1] <= 1e-15


def test_sympy_s_rolling_disc_under_error_control_keeps_the_contract():
    """A model nobody here wrote (SymPy's documented rolling disc, ``KanesMethod`` converted by
    ``from_kanes_method``; ``benchmarks/testset``): native error control at rtol 1e-8 takes the JAX
    path's steps and ends within 30 × rtol of the reference (scipy's DOP853 at 1e-13; measured
    2.1e-9 at s = 5, 4.1e-9 at s = 4, both paths alike)."""
    import pathlib
    import sys

    sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1]))
    from benchmarks.testset import PROBLEMS, error
    from benchmarks.testset import rolling_disc

    entry, setup = PROBLEMS["rolling-disc"], rolling_disc.build()
    model = rolling_disc.model()
    options = dict(args=setup.args, rtol=1e-8, atol=1e-8)
    native_sol = model.native(5).solve(setup.t_span, setup.q0, setup.p0, **options)
    jax_sol = L.solve(model.problem, L.LobattoIIIAIIIB(stages=5), setup.t_span, setup.q0, setup.p0, **options)
    assert native_sol.success and native_sol.stats["n_steps"] == jax_sol.stats["n_steps"]
    assert error(entry, native_sol.t, native_sol.q, native_sol.p) <= 30 * 1e-8
    assert native_sol.stats["max_constraint_residual"] < 1e-12


def test_holonomic_constraints_are_kept_by_the_projection():
    """The Cartesian pendulum (ψ = |q|² − l², projected after every sub-step): ψ and φ at
    round-off at every row, the same counts as the JAX path and the rows at the t_eval times
    equal to its to round-off."""
    model = mechanics.systems.cartesian_pendulum()
    args = model.args(m=0.7, g=9.81, l=1.3)
    q0 = np.array([1.3 * np.sin(0.6), -1.3 * np.cos(0.6)])
    p0 = model.momenta(0.0, q0, model.complete_velocities(0.0, q0, np.array([0.5, 0.5]), args), args)
    jax_sol, native_sol = _both(model, 4, "auto", (0.0, 5.0), q0, p0, args, rtol=1e-8, atol=1e-8,
                                t_eval=np.linspace(0.0, 5.0, 11))
    assert {k: native_sol.stats[k] for k in COUNTS} == {k: jax_sol.stats[k] for k in COUNTS}
    assert np.max(np.abs(model.holonomic_residual(0.0, native_sol.q, args))) < 1e-13
    assert native_sol.stats["max_constraint_residual"] < 1e-13
    np.testing.assert_allclose(native_sol.q, jax_sol.q, rtol=0, atol=1e-10)  # measured 4e-16


def test_backwards_in_time_natively_as_on_the_jax_path(disk):
    """t1 < t0: negative steps through the native attempt, the same counts and rows at the
    t_eval times as the JAX path, and back at the start to the error's size."""
    model, ex, args = disk
    forward = model.native(4).solve((0.0, 5.0), ex.q0, ex.p0, args=args, rtol=1e-9, atol=1e-9)
    times = np.linspace(5.0, 0.0, 6)
    jax_sol, native_sol = _both(model, 4, "auto", (5.0, 0.0), forward.q[-1], forward.p[-1], args, rtol=1e-9,
                                atol=1e-9, t_eval=times)
    assert native_sol.success and native_sol.stats["n_steps"] > 1
    assert {k: native_sol.stats[k] for k in COUNTS} == {k: jax_sol.stats[k] for k in COUNTS}
    np.testing.assert_allclose(native_sol.q, jax_sol.q, rtol=0, atol=1e-10)
    assert np.max(np.abs(native_sol.q[-1] - ex.q0)) < 1e-7


def test_a_checkpointed_run_resumes_to_the_same_numbers(sleigh, tmp_path):
    """The native attempt's state (Newton matrices, histories) rides in the checkpoint: a run
    stopped after its first chunk and resumed ends on the numbers of an uninterrupted one."""
    model, ex, args = sleigh
    native = model.native(4)
    options = dict(lam0=ex.lam0, args=args, rtol=1e-9, atol=1e-9, chunk_size=8)
    whole = native.solve((0.0, 50.0), ex.q0, ex.p0, **options)
    path = tmp_path / "run.ckpt"
    first = native.solve((0.0, 50.0), ex.q0, ex.p0, checkpoint=path, checkpoint_every=1, max_steps=8, **options)
    assert first.result == Result.MAX_STEPS and first.t[-1] < 50.0
    resumed = native.solve((0.0, 50.0), ex.q0, ex.p0, checkpoint=path, resume=True, **options)
    np.testing.assert_array_equal(resumed.t, whole.t)
    np.testing.assert_array_equal(resumed.q, whole.q)


# -- single steps: the loop's other controllers ----------------------------------------------------------
def test_constant_steps_in_the_loop_take_the_jax_path_s_steps(sleigh):
    """n_steps with t_eval (rows interpolated on the steps' dense output) and a terminal event: the
    loop's constant steps, each one native call: every row equal to the JAX path's to round-off,
    the λ policy's re-synchronisations at the same steps, the event at the same time; and a plain
    constant run through the loop equals the whole run in C."""
    model, ex, args = sleigh
    times = np.linspace(0.0, 50.0, 11)

    def heading(t, q, p, args):
        return q[2] - 0.5

    heading.terminal = True
    options = dict(lam0=ex.lam0, args=args, n_steps=1000, t_eval=times)
    jax_sol = L.solve(model.problem, L.LobattoIIIAIIIB(stages=4), (0.0, 50.0), ex.q0, ex.p0, **options)
    native_sol = model.native(4).solve((0.0, 50.0), ex.q0, ex.p0, **options)
    assert native_sol.success and native_sol.stats["lam_excursions"] >= 1  # "auto" re-synchronised
    assert {k: native_sol.stats[k] for k in ("n_steps", "lam_resets", "lam_excursions")} == \
        {k: jax_sol.stats[k] for k in ("n_steps", "lam_resets", "lam_excursions")}
    np.testing.assert_array_equal(native_sol.t, times)
    np.testing.assert_allclose(native_sol.q, jax_sol.q, rtol=0, atol=1e-12 * (1 + np.abs(jax_sol.q).max()))
    np.testing.assert_allclose(native_sol.p, jax_sol.p, rtol=0, atol=1e-12 * (1 + np.abs(jax_sol.p).max()))
    ev_jax = L.solve(model.problem, L.LobattoIIIAIIIB(stages=4), (0.0, 5.0), ex.q0, ex.p0, lam0=ex.lam0, args=args,
                     n_steps=100, events=heading)
    ev_native = model.native(4).solve((0.0, 5.0), ex.q0, ex.p0, lam0=ex.lam0, args=args, n_steps=100,
                                      events=heading)
    assert ev_native.result == Result.EVENT and abs(ev_native.t_events[0][0] - ev_jax.t_events[0][0]) < 1e-12
    # the loop's native steps against the whole run in C: the same program, the same rows
    loop = L.solve(model.problem, model.native(4), (0.0, 50.0), ex.q0, ex.p0, lam0=ex.lam0, args=args, n_steps=1000)
    whole = model.native(4).solve((0.0, 50.0), ex.q0, ex.p0, lam0=ex.lam0, args=args, n_steps=1000)
    np.testing.assert_allclose(loop.q, whole.q, rtol=0, atol=1e-13 * (1 + np.abs(whole.q).max()))
    assert loop.stats["lam_resets"] == whole.stats["lam_resets"]


def test_a_failed_constant_step_is_recovered_natively_as_on_the_jax_path(disk):
    """max_recoveries: the falling disk's steps of 4 fail and are retried as substeps (fresh
    native steppers over the sub-grid), with the JAX path's count and end point."""
    model, ex, args = disk
    jax_sol, native_sol = _both(model, 3, "auto", (0.0, 20.0), ex.q0, ex.p0, args, n_steps=5, max_recoveries=5)
    assert native_sol.success and native_sol.stats["recoveries"] == jax_sol.stats["recoveries"] >= 1
    np.testing.assert_allclose(native_sol.q[-1], jax_sol.q[-1], rtol=0, atol=1e-10)


@pytest.mark.parametrize("controller", [L.ReversibleStepSize(), L.PIController(estimate="embedded")],
                         ids=["reversible", "embedded"])
def test_the_other_controllers_take_native_single_steps(disk, controller):
    """Reversible control and the embedded estimate run the method's single steps: natively the
    same attempts as on the JAX path (the embedded estimate computed from the native stages)."""
    model, ex, args = disk
    options = dict(controller=controller, t_eval=np.linspace(0.0, 10.0, 6))
    if isinstance(controller, L.ReversibleStepSize):
        options["first_step"] = 0.1
    jax_sol, native_sol = _both(model, 5, "auto", (0.0, 10.0), ex.q0, ex.p0, args, **options)
    assert native_sol.success and type(native_sol.method).__name__ == "NativeStep"
    counts = ("n_steps", "n_rejected", "lam_excursions")
    assert {k: native_sol.stats[k] for k in counts} == {k: jax_sol.stats[k] for k in counts}
    np.testing.assert_allclose(native_sol.q, jax_sol.q, rtol=0, atol=1e-9)


def test_what_the_native_attempt_refuses_is_named(sleigh, disk):
    model, ex, args = sleigh
    native = model.native(3)
    for pure in (lambda: L.integrate_adaptive(model.problem, native, (0.0, 1.0), ex.q0, ex.p0, ex.lam0, args),
                 lambda: L.integrate(model.problem, native, 0.0, 0.1, 10, ex.q0, ex.p0, ex.lam0, args),
                 lambda: L.ensemble(model.problem, native, np.stack([ex.q0] * 2), np.stack([ex.p0] * 2),
                                    np.stack([ex.lam0] * 2), args, t0=0.0, h=0.1, n_steps=3)):
        with pytest.raises(LobattoDAEInputError, match="use its JAX method, native.method"):
            pure()
    with pytest.raises(LobattoDAEInputError, match="pass its problem"):
        disk_model, disk_ex, disk_args = disk
        L.solve(disk_model.problem, native, (0.0, 1.0), disk_ex.q0, disk_ex.p0, args=disk_args)
    with pytest.raises(LobattoDAEInputError, match="rtol"):  # solve's own refusal of both kinds of steps
        native.solve((0.0, 1.0), ex.q0, ex.p0, args=args, n_steps=10, rtol=1e-6)
    with pytest.raises(TypeError, match="model.native"):
        L.solve(model.problem, "LobattoIIIAIIIB", (0.0, 1.0), ex.q0, ex.p0, args=args)
