"""lobattodae._doubling: the step-doubling estimate of a step's own local error."""

import warnings

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import lobattodae as L
from lobattodae._doubling import StepDoubling, for_error_control
from lobattodae._results import Result
from lobattodae.examples import get_example


def _one_step(ex, s, h, t0=0.3):
    q0, p0, lam0 = (jnp.asarray(x) for x in ex.exact(t0))
    doubling = StepDoubling(L.LobattoIIIAIIIB(stages=s, lam_start="consistent"))
    q1, p1, lam1, info, _ = jax.jit(lambda h: doubling.step(ex.problem, t0, q0, p0, lam0, h, ex.args))(h)
    qe, pe, _ = ex.exact(t0 + h)
    true = np.concatenate([np.asarray(q1) - qe, np.asarray(p1) - pe])
    return np.asarray(info.error), true, info


@pytest.mark.parametrize("s", [2, 3, 4])
def test_the_estimate_is_asymptotically_the_local_error(knife, s):
    """From exact initial values the error of the kept half steps is the local error; the
    estimate's ratio to it tends to 1 as h → 0 (measured at h = 0.4, 0.2: s = 2 0.88, 0.93;
    s = 3 1.06, 1.03; s = 4 0.977, 0.990; the error itself falls like h^(2s-1))."""
    ratios, sizes = [], []
    for h in (0.4, 0.2):
        est, true, info = _one_step(knife, s, h)
        assert int(info.result) == 0
        ratios.append(np.linalg.norm(est) / np.linalg.norm(true))
        sizes.append(np.linalg.norm(true))
    assert abs(ratios[-1] - 1) < 0.15, ratios
    assert abs(ratios[-1] - 1) <= abs(ratios[0] - 1) + 0.02, ratios
    observed = np.log2(sizes[0] / sizes[1])
    assert abs(observed - (2 * s - 1)) < 0.6, observed


def test_the_kept_result_is_two_half_steps_of_the_method(knife):
    """The solution the run continues from is that of two plain steps of h/2 (bit for bit), and the
    dense output has two pieces that meet at the midpoint."""
    method = L.LobattoIIIAIIIB(stages=3, lam_start="consistent")
    q0, p0, lam0 = (jnp.asarray(x) for x in knife.exact(0.0))
    h = 0.25
    q1, p1, lam1, info, _ = StepDoubling(method).step(knife.problem, 0.0, q0, p0, lam0, h, knife.args)
    qa, pa, la, _, st = method.step(knife.problem, 0.0, q0, p0, lam0, h / 2, knife.args)
    qb, pb, lb, _, _ = method.step(knife.problem, h / 2, qa, pa, la, h / 2, knife.args, st)
    np.testing.assert_allclose(q1, qb, rtol=0, atol=1e-15)
    np.testing.assert_allclose(p1, pb, rtol=0, atol=1e-15)
    np.testing.assert_array_equal(info.dense.t0, [0.0, h / 2])
    np.testing.assert_allclose(info.dense.q0[1], qa, atol=1e-15)


def test_a_failed_whole_step_ends_the_attempt_without_solving_the_halves(knife):
    """A whole step whose stage solve fails rejects the attempt whatever the half steps do: they
    are not solved (the attempt's Newton iterations and Jacobians are the whole step's own) and
    the retry takes half the size."""
    method = L.LobattoIIIAIIIB(stages=4, lam_start="consistent", max_iterations=2)
    q0, p0, lam0 = (jnp.asarray(x) for x in knife.exact(0.0))
    h = 4.0  # two iterations cannot converge the whole step from constant stages
    _, _, _, whole, _ = method.step(knife.problem, 0.0, q0, p0, lam0, h, knife.args)
    assert int(whole.result) != Result.SUCCESSFUL
    _, _, _, info, _ = StepDoubling(method).step(knife.problem, 0.0, q0, p0, lam0, h, knife.args)
    assert int(info.result) == int(whole.result)
    assert int(info.iterations) == int(whole.iterations) and int(info.n_jacobians) == int(whole.n_jacobians)
    assert float(info.retry) == 0.5


def test_for_error_control_is_the_one_place_the_method_is_adapted():
    m = L.LobattoIIIAIIIB(stages=4)
    doubled = for_error_control(m, L.PIController())
    assert isinstance(doubled, StepDoubling) and doubled.lam_start == "consistent" and doubled.pieces == 2
    embedded = for_error_control(m, L.PIController(estimate="embedded"))
    assert isinstance(embedded, L.LobattoIIIAIIIB) and embedded.lam_start == "consistent"
    assert for_error_control(m, L.ReversibleStepSize()) is m
    assert for_error_control(L.LobattoIIIAIIIB(lam_start="previous"), L.PIController()).lam_start == "previous"


def test_stability_limited_steps_are_caught_on_the_long_sleigh():
    """The sleigh's turning mode is damped by the constraint; steps beyond the stability limit
    amplify it (docs/variable-steps.md §2). The embedded estimate let them through (s = 4, rtol
    1e-8, T = 1000: error 4.8e-7, 48 x rtol); step doubling rejects them. Where each rejection
    falls depends on round-off (the order of a sum changes the step sequence): over s = 4, 5
    and rtol 1e-7..1e-9 the error was measured between 2e-13 and 1.1e-8 (here 6e-12 with 8
    rejections, then 1.1e-8 with 9 after the tableau products were summed in another order),
    always within the tolerance's reach, so the bound is 3 x rtol, 16 x below the embedded
    estimate's failure."""
    ex = get_example("sleigh")
    sol = L.solve(ex.problem, L.LobattoIIIAIIIB(stages=4), (0.0, 1000.0), ex.q0, ex.p0, args=ex.args, rtol=1e-8,
                  atol=1e-8, save_every="final")
    q, p, _ = ex.exact(1000.0)
    err = max(np.max(np.abs(sol.q[-1] - q) / (1 + np.abs(q))), np.max(np.abs(sol.p[-1] - p) / (1 + np.abs(p))))
    assert sol.success and err < 3e-8, err
    assert sol.stats["n_rejected"] > 0
    assert sol.stats["n_roundoff_limited"] == 0 and "Warning" not in sol.message


def _sleigh_at_rest_turning(ex, omega):
    """The sleigh moving straight at unit speed along x, with angular velocity ``omega`` (p
    consistent with the blade's constraint): the turning mode that the constraint damps."""
    a = ex.args
    return jnp.zeros(3), jnp.asarray([a.m, a.m * a.a * omega, a.I * omega])


def _turning_sleigh_step(omega, h, s):
    """The sleigh, the error-controlled runs' method (``lam_start="consistent"``) and the start
    ``(t0, q0, p0, λ0, h)`` of one step of size h from straight motion turning at ``omega``."""
    ex = get_example("sleigh")
    q0, p0 = _sleigh_at_rest_turning(ex, omega)
    lam0 = L.consistent_lambda(ex.problem, 0.0, q0, p0, jnp.zeros(1), args=ex.args)
    return ex, L.LobattoIIIAIIIB(stages=s, lam_start="consistent"), (0.0, q0, p0, lam0, h)


def _fine_flow(ex, method, t0, q0, p0, lam0, h):
    """``(q, p)`` after 2000 steps of ``method`` over h: the exact flow to round-off."""
    step = jax.jit(lambda t, q, p, lam, hh: method.step(ex.problem, t, q, p, lam, hh, ex.args)[:3])

    def fine(k, c):
        q, p, lam = c
        t = t0 + k * h / 2000
        return step(t, q, p, L.consistent_lambda(ex.problem, t, q, p, lam, args=ex.args), h / 2000)

    return jax.jit(lambda: jax.lax.fori_loop(0, 2000, fine, (q0, p0, lam0)))()[:2]


def test_a_step_beyond_the_damped_modes_reach_is_not_divided_by_richardsons_ratio():
    """One error-controlled step of h = 118 (s = 5) from straight motion with a turning mode of
    1e-10: the exact flow damps it (e^(-54)), the method, far outside its resolved range, carries
    and amplifies it: the kept half steps err by 3.2e-8. Richardson's divisor 2^8 - 1 assumes the
    asymptotic ratio of the two errors and gave 2.0e-10, 161 x too small. The estimate sees that
    the error lies along a mode with |h μ| far beyond ``richardson_radius`` and divides by the
    linear theory's ratio there instead: 7.7e-9 (0.24 x the true error; the DAE's mode is not the
    scalar test equation), 39 x larger, enough to reject the step at any tolerance it would pass
    wrongly."""
    ex, method, (t0, q0, p0, lam0, h) = _turning_sleigh_step(omega=1e-10, h=118.0, s=5)
    q1, p1, _, info, _ = jax.jit(lambda: StepDoubling(method).step(ex.problem, t0, q0, p0, lam0, h, ex.args))()
    qf, pf = _fine_flow(ex, method, t0, q0, p0, lam0, h)
    true = np.max(np.abs(np.concatenate([q1 - qf, p1 - pf])))
    estimate = np.max(np.abs(info.error))
    assert int(info.result) == 0 and true > 1e-8, true  # the step is bad ...
    assert 1 / 6 < estimate / true < 3, (estimate, true)  # ... and the estimate says so (was 1/161)


def test_a_step_whose_two_results_agree_but_both_amplify_the_damped_mode_is_rejected():
    """s = 4 from straight motion at unit speed with a turning rate of 1e-8 (k = 0.5): one step
    multiplies a mode that the constraint damps by the (s, s-2) Padé function R_c(z), z = -k h,
    and near h = 68 the two half steps amplify it as much as the whole step (R_c(z/2)² = R_c(z),
    |R_c| ≈ 52): the two results agree to 0.4 % while both are ~50 times the mode off. Read with
    the diagonal Padé function of ODE modes the difference was divided by 9 (share 0.11), an
    estimate 3,600 times too small at the step a settling sleigh took there (error 42 x rtol at
    its end). The constraint's force moves the momenta here (the sleigh has no applied force), so
    its theory is asked too, and the estimate is within a factor three of the true error."""
    ex, method, (t0, q0, p0, lam0, h) = _turning_sleigh_step(omega=1e-8, h=68.0, s=4)
    q1, p1, _, info, _ = jax.jit(lambda: StepDoubling(method).step(ex.problem, t0, q0, p0, lam0, h, ex.args))()
    q_whole, p_whole, _, _, _ = jax.jit(lambda: method.step(ex.problem, t0, q0, p0, lam0, h, ex.args))()
    exact = np.concatenate(_fine_flow(ex, method, t0, q0, p0, lam0, h))
    half_error = np.max(np.abs(np.concatenate([q1, p1]) - exact))
    whole_error = np.max(np.abs(np.concatenate([q_whole, p_whole]) - exact))
    difference = np.max(np.abs(np.concatenate([q1 - q_whole, p1 - p_whole])))
    assert int(info.result) == 0 and half_error > 1e-7 and difference < 0.05 * half_error, (
        half_error, whole_error, difference)
    estimate = np.max(np.abs(info.error))
    assert 1 / 3 < estimate / half_error < 3, (estimate, half_error)
    assert float(info.share) > 1.0, float(info.share)


@pytest.mark.parametrize("s", [4, 5, 6])
def test_every_step_point_is_faithful_on_a_sleigh_that_settles(s):
    """The sleigh started turning (ω = 0.1) settles into straight motion; at rtol = 1e-8 its steps
    grow to hundreds of time units, far beyond the turning mode's resolved range. Dividing every
    difference by Richardson's ratio, the error at step points reached 85 x rtol (s = 5) and
    7.7 x (s = 4); over s = 3..6, rtol 1e-6..1e-10 and three initial turns 10 of 36 runs
    exceeded 30 x (up to 251 x; ``benchmarks/settling_sleigh.py``). Now: 0.43, 0.41, 0.05 x for
    s = 4, 5, 6, with 65, 30, 18 steps (56, 28, 18 before). The reference: 20,000 constant steps
    of s = 6."""
    ex = get_example("sleigh")
    q0, p0 = _sleigh_at_rest_turning(ex, 0.1)
    span = (0.0, 1000.0)
    sol = L.solve(ex.problem, L.LobattoIIIAIIIB(stages=s), span, q0, p0, args=ex.args, rtol=1e-8, atol=1e-8)
    ref = L.solve(ex.problem, L.LobattoIIIAIIIB(stages=6), span, q0, p0, args=ex.args, n_steps=20000,
                  t_eval=sol.t)
    y, y_ref = np.hstack([sol.q, sol.p]), np.hstack([ref.q, ref.p])
    err = np.max(np.abs(y - y_ref) / (1 + np.abs(y_ref)))
    assert sol.success and err < 3e-8, err
    assert sol.stats["n_steps"] < 150  # the turning mode does not hold the steps at its stability limit


def test_tight_tolerances_on_long_runs_do_not_collapse_the_steps():
    """The error per unit step of T = 1000 at rtol 1e-12 asks a step for less than its round-off;
    without the floor (ROUNDOFF_FLOOR) the step size fell to 2e-12 at t = 372 and the run failed
    (STEP_SIZE_TOO_SMALL); with it: 9,467 steps, none rejected, error 3.6e-11 relative. The
    run cannot meet rtol = 1e-12 and says so: nearly every step passed only by the floor."""
    ex = get_example("knife-edge")
    with pytest.warns(RuntimeWarning, match="asked for less than their round-off") as caught:
        sol = L.solve(ex.problem, L.LobattoIIIAIIIB(stages=4), (0.0, 1000.0), ex.q0, ex.p0, args=ex.args, rtol=1e-12,
                      atol=1e-12, save_every="final", throw=False)
    assert caught[0].filename == __file__  # the warning points at the caller of solve
    assert sol.success and sol.result == L.Result.ROUNDOFF_LIMITED and sol.status == 0, sol.message
    assert sol.stats["n_roundoff_limited"] > 0.9 * sol.stats["n_steps"]
    assert sol.message.startswith("The end of the integration interval was reached, but")
    assert "looser rtol" in sol.message
    q, p, _ = ex.exact(1000.0)
    assert np.max(np.abs(sol.q[-1] - q) / (1 + np.abs(q))) < 1e-9
    assert sol.stats["n_rejected"] < 0.1 * sol.stats["n_steps"]


def test_the_roundoff_count_and_status_are_the_same_from_every_entry_point(tmp_path):
    """``integrate_adaptive`` (where a run may be under jit and cannot warn) and ``ensemble``
    (which warns, as solve does) report the steps that passed only by the round-off floor, the
    same count as ``solve``'s stats, and the same status, ``ROUNDOFF_LIMITED``: knife edge,
    T = 50, rtol = 1e-13 (about half the steps; as many attempts are rejected)."""
    ex = get_example("knife-edge")
    q0, p0 = np.asarray(ex.q0), np.asarray(ex.p0)
    lam0 = np.asarray(L.consistent_lambda(ex.problem, 0.0, q0, p0, np.zeros(1), ex.args))
    method, span, tight = L.LobattoIIIAIIIB(stages=3), (0.0, 50.0), dict(rtol=1e-13, atol=1e-13)
    with pytest.warns(RuntimeWarning, match="asked for less than their round-off"):
        sol = L.solve(ex.problem, method, span, q0, p0, args=ex.args, save_every="final", **tight)
    count, limited = sol.stats["n_roundoff_limited"], L.Result.ROUNDOFF_LIMITED
    assert count > 0.3 * sol.stats["n_steps"] and sol.result == limited and sol.success
    r = L.integrate_adaptive(ex.problem, method, span, q0, p0, lam0, ex.args, max_steps=16384, **tight)
    assert int(r.status) == limited and int(r.n_steps) == sol.stats["n_steps"]
    assert int(r.n_roundoff_limited) == count
    d = L.integrate_adaptive(ex.problem, method, span, q0, p0, lam0, ex.args, max_steps=16384, differentiable=True,
                             **tight)
    assert int(d.status) == limited and int(d.n_roundoff_limited) == count
    batch = [np.stack([x, x]) for x in (q0, p0, lam0)]
    with pytest.warns(RuntimeWarning, match=r"2 of 2 trajectories \(first: 0\).*less than their round-off") as caught:
        e = L.ensemble(ex.problem, method, *batch, ex.args, t_span=span, max_steps=16384, **tight)
    assert caught[0].filename == __file__  # the warning points at the caller of ensemble
    np.testing.assert_array_equal(e.n_roundoff_limited, [count, count])
    np.testing.assert_array_equal(e.status, [limited, limited])
    with pytest.warns(RuntimeWarning, match=r"2 of 2 trajectories \(first: 0\)"):
        files = L.ensemble(ex.problem, method, *batch, ex.args, t_span=span, max_steps=16384, out_dir=tmp_path, **tight)
    assert files.n_failed == 0  # limited by round-off, but each reached its end
    loaded = L.load_ensemble(tmp_path)
    np.testing.assert_array_equal(loaded.n_roundoff_limited, [count, count])
    np.testing.assert_array_equal(loaded.status, [limited, limited])
    # at an ordinary tolerance: none, and no warning
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        normal = L.ensemble(ex.problem, method, *batch, ex.args, t_span=span, rtol=1e-8, atol=1e-8)
    np.testing.assert_array_equal(normal.n_roundoff_limited, [0, 0])
    np.testing.assert_array_equal(normal.status, [L.Result.SUCCESSFUL] * 2)
    assert int(L.integrate_adaptive(ex.problem, method, span, q0, p0, lam0, ex.args, rtol=1e-8, atol=1e-8,
                                    controller=L.ReversibleStepSize()).n_roundoff_limited) == 0


def test_the_constraints_theory_is_asked_only_where_lambda_moves_the_forces():
    """The share of a difference along a real mode with z = −34 (s = 4): IIIA's theory divides by
    about 9; the constraint's, where R_c(z/2)² ≈ R_c(z), says the error is about fifty times the
    difference (53 here; capped at 2^(2s-2) - 1 = 63). Which one is read depends on what changes the force on
    p along the difference: λ alone (the sleigh) or the applied forces (a damper)."""
    doubling = StepDoubling(L.LobattoIIIAIIIB(stages=4))
    h, mu = 68.0, -0.5
    diff = jnp.asarray([0.0, 1e-9])
    slopes = mu * diff
    y1 = jnp.zeros(2)
    (by_lam, resolved), (applied, _) = (doubling._share(h, diff, slopes, y1, through_lam=through)
                                        for through in (slopes, jnp.zeros(2)))
    by_lam, applied = float(by_lam), float(applied)
    assert not bool(resolved)  # |z| = 34, beyond the radius 4.5
    z = h * mu
    pair = doubling.pair
    ode = abs((pair.stability(z / 2) ** 2 - pair.stability(z)) / (pair.stability(z / 2) ** 2 - np.exp(z)))
    rc = pair.constraint_stability
    constrained = abs((rc(z / 2) ** 2 - rc(z)) / (rc(z / 2) ** 2 - np.exp(z)))
    assert applied == pytest.approx(1.0 / ode, rel=1e-9) and applied < 1.0
    assert by_lam == pytest.approx(1.0 / constrained, rel=1e-9) and 30.0 < by_lam < 63.0
