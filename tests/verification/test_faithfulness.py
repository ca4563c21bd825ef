"""Error control users can trust (issue #25): on problems we did not write, the global error
follows rtol.

The default run checks every problem of ``benchmarks/testset`` at one tolerance against its
published or independently computed reference; ``-m slow`` runs the whole grid of
``benchmarks/faithfulness.py`` (s = 2..6, rtol = 1e-4..1e-12) and asserts the contract: error
≤ 30 × max(rtol, reference accuracy) in every run that does not warn of round-off, never above
1000 × rtol; a log-log slope outside [0.8, 1.2] (fitted over the runs above both floors) is
reported as an expected failure.
"""

import math
import pathlib
import sys

import numpy as np
import pytest

import lobattodae as L

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1]))
from benchmarks import faithfulness as F  # noqa: E402
from benchmarks.testset import PROBLEMS  # noqa: E402

#: One setting per problem for the default run: s = 4, rtol = 1e-8 (the long problems at 1e-6,
#: to stay fast).
QUICK_RTOL = {True: 1e-6, False: 1e-8}


@pytest.mark.parametrize("name", sorted(PROBLEMS))
def test_error_follows_rtol_at_one_tolerance(name):
    entry = PROBLEMS[name]
    rtol = QUICK_RTOL[entry.long]
    r = F.run_one(entry, 4, rtol)
    assert r["success"], r["message"]
    assert r["ratio"] <= F.FAITHFUL, r
    # and at the end of a plain run, whose steps do not land on the reference times (measured
    # 0.0003-1.25 x at these settings)
    assert r["end_ratio"] <= F.FAITHFUL, r
    # the constraint is kept at every step point and every returned row
    assert r["max_constraint_residual"] < 1e-12, r


def test_the_embedded_estimate_is_not_faithful_on_the_squeezer():
    """Why the default changed: the cheap O(h^s) estimate with its fitted tolerance map returns
    SUCCESS with errors far above rtol on Andrews' squeezer (measured 2.5e-5 at rtol 1e-8,
    s = 4), where step doubling stays within 1.5 x rtol."""
    entry = PROBLEMS["andrews"]
    setup = entry.build()
    sol = L.solve(setup.problem, L.LobattoIIIAIIIB(stages=4), setup.t_span, setup.q0, setup.p0, args=setup.args,
                  rtol=1e-8, atol=1e-8, controller=L.PIController(estimate="embedded"), save_every="final")
    assert sol.success
    from benchmarks.testset import error

    assert error(entry, sol.t[-1], sol.q[-1], sol.p[-1]) > 100 * 1e-8


def test_the_squeezer_stays_faithful_where_richardson_is_outside_its_range():
    """At s = 6, rtol 1e-6, Andrews' longest steps are just outside Richardson's asymptotic
    range (the whole step's error only 50-470 x the halves', not 1,024 x: the estimate is
    3-400 x too small). The compared whole step, started from its own extrapolation, fails
    Newton there and the attempt is retried shorter; predicted from the half steps it converged
    and the error reached 92 x rtol (benchmarks/RESULTS.md, 2026-11-28). This setting guards
    that: measured 0.28 x rtol."""
    r = F.run_one(PROBLEMS["andrews"], 6, 1e-6)
    assert r["success"], r["message"]
    assert r["ratio"] <= F.FAITHFUL, r


def test_the_four_bar_step_over_its_turning_point_is_checked():
    """The hold-out four-bar linkage at s = 6, without t_eval rows: a step over the crank's
    turning point passes with Richardson's divisor 1023 where the whole and halved steps' errors
    differ tens of times (at rtol 1e-4 until 2026-11-29: h = 0.30, errors 28 times apart, end point
    47 x off). The check of large steps (PIController(check_large_steps), on by default) retries
    it with h/2; switched off, the defect is back. Measured with the PI rule's hysteresis fixed
    (2026-11-29) at rtol 3e-4: 0.0043 x with 3 checks, 424 x unchecked (at 1e-4: 0.0057 x against
    26 x)."""
    from benchmarks.testset import error

    entry = PROBLEMS["fourbar"]
    setup = entry.build()

    def end_ratio(check):
        sol = L.solve(setup.problem, L.LobattoIIIAIIIB(stages=6), setup.t_span, setup.q0, setup.p0, args=setup.args,
                      rtol=3e-4, atol=3e-4, save_every="final", controller=L.PIController(check_large_steps=check))
        assert sol.success
        return error(entry, sol.t[-1], sol.q[-1], sol.p[-1]) / 3e-4, sol.stats["n_checked"]

    ratio, checked = end_ratio(True)
    assert ratio <= F.FAITHFUL and checked >= 1
    ratio, checked = end_ratio(False)
    assert ratio > F.FAITHFUL and checked == 0


def test_a_long_run_keeps_its_end_point_above_round_off():
    """The knife edge over T = 1000 at s = 6, rtol 1e-12 (1,667 steps of h ≈ 0.6): its angle grows
    steadily to 700, and every step rounded ``θ + h θ'`` and ``t + h`` with one sign, so the end
    point was 57 x off (θ by 4.5e-11, carried into the momenta) without a warning. With the
    increments summed with compensation and steps that the time grid holds, θ ends within an
    ulp of 700 (1.1e-13) and the end point at 1.6 x."""
    from benchmarks.testset import error
    from benchmarks.testset.knife_edge import exact

    entry = PROBLEMS["knife-edge"]
    setup = entry.build()
    sol = L.solve(setup.problem, L.LobattoIIIAIIIB(stages=6), setup.t_span, setup.q0, setup.p0, args=setup.args,
                  rtol=1e-12, atol=1e-12, save_every="final")
    assert sol.success and sol.t[-1] == 1000.0
    assert error(entry, sol.t[-1], sol.q[-1], sol.p[-1]) <= F.FAITHFUL * 1e-12
    assert abs(sol.q[-1][2] - exact(1000.0)[0][2]) <= 4 * np.spacing(700.0)


def test_the_verdict_lists_warned_runs_apart_but_never_above_1000x():
    """The contract as ``F.verdict`` reads it: above 30 x a run that did not warn is a violation,
    one that warned of round-off is not (it said so); above 1000 x rtol a run that returned
    SUCCESSFUL is one (stored before 2026-11-29, a warned run did), one that returned
    ROUNDOFF_LIMITED is not (its status says so)."""
    row = dict(problem="p", s=4, rtol=1e-10, success=True, status=0)
    ok = dict(row, error=2e-9, ratio=20.0, roundoff_warned=False)
    unwarned = dict(row, error=5e-9, ratio=50.0, roundoff_warned=False)
    warned = dict(row, error=5e-9, ratio=50.0, roundoff_warned=True)
    legacy = dict(row, error=5e-9, ratio=50.0)  # stored before the flag: counts as unwarned
    huge = dict(row, error=2e-7, ratio=2000.0, roundoff_warned=True)
    assert F.verdict([ok, warned]) == []
    assert len(F.verdict([unwarned])) == 1 and len(F.verdict([legacy])) == 1
    assert [v for v in F.verdict([huge]) if "1000 x rtol" in v]
    assert F.verdict([dict(huge, status=int(L.Result.ROUNDOFF_LIMITED))]) == []
    assert "did not warn: largest 50.00 x" in F.summary([ok, unwarned, warned])
    # the end point of the plain run counts the same way; read back from JSON, NaN is a string
    end = dict(ok, end_error=5e-9, end_ratio=50.0, end_warned=False)
    assert len(F.verdict([end])) == 1 and "end point" in F.verdict([end])[0]
    assert F.verdict([dict(end, end_warned=True)]) == []
    assert F.verdict([dict(ok, end_error="nan", end_ratio="nan", end_warned=False)]) == []
    assert "end points of plain runs that did not warn: largest 50.00 x" in F.summary([end])


def test_the_slope_is_fitted_above_both_floors():
    """``F.slope`` fits log error against log rtol over the rows above 30 x the reference's
    accuracy whose run did not warn of round-off: a run at the round-off floor says its error
    is round-off's and cannot flatten or steepen the fit."""
    rows = [dict(rtol=r, error=3.0 * r, roundoff_warned=False) for r in (1e-4, 1e-6, 1e-8)]
    floor = [dict(rtol=1e-10, error=5e-9, roundoff_warned=True), dict(rtol=1e-12, error=5e-9, roundoff_warned=True)]
    assert F.slope(rows + floor, 1e-16) == pytest.approx(1.0)
    assert F.slope(rows + [dict(r, roundoff_warned=False) for r in floor], 1e-16) < 0.7  # unflagged: 0.62
    assert math.isnan(F.slope(rows, 1e-7))  # only 3e-4 lies above 30 x 1e-7: nothing to fit
    assert math.isnan(F.slope(rows[:1] + floor, 1e-16))


def test_runs_whose_steps_rtol_did_not_set_are_told_apart():
    """``F.rtol_set``: a run with more than a quarter of its steps held beyond the Richardson
    radius, or a tenth of its attempts failed solves, was not sized by rtol; the second fit
    leaves it out, the contract's keeps it (rows from before the counters count as set by rtol)."""
    def row(rtol, error, unresolved=0, failed=0):
        return dict(rtol=rtol, error=error, n_steps=100, n_rejected=failed, n_unresolved=unresolved,
                    n_failed_solves=failed, roundoff_warned=False)

    assert F.rtol_set(row(1e-4, 1e-9, unresolved=25)) and not F.rtol_set(row(1e-4, 1e-9, unresolved=26))
    assert F.rtol_set(row(1e-4, 1e-9, failed=11)) and not F.rtol_set(row(1e-4, 1e-9, failed=12))
    assert F.rtol_set({k: v for k, v in row(1e-4, 1.0).items() if not k.startswith("n_u")})
    # a flat start held by stability, then errors that follow rtol
    rows = [row(1e-4, 1e-9, unresolved=80), row(1e-6, 1e-9, unresolved=60)] + [row(r, r) for r in (1e-8, 1e-10)]
    assert F.slope(rows, 1e-16) < 0.7
    assert F.slope(rows, 1e-16, only_rtol_set=True) == pytest.approx(1.0)


@pytest.mark.slow
@pytest.mark.parametrize("name", sorted(PROBLEMS))
def test_faithfulness_grid(name):
    """The contract over the whole grid: every run succeeds, every error within 30 × max(rtol,
    the reference's accuracy) unless the run warned that rtol asks for less than the steps'
    round-off, none above 1000 × rtol, at the reference times and at the end of a plain run
    (``F.verdict``). Then the slope band 0.8-1.2: missed
    where errors stay far below rtol (13 of 44 (problem, s) pairs in the stored grid of
    2026-11-29; in 12 of them runs whose steps rtol did not set, ``F.slope_misses``), reported as
    an expected failure, not hidden."""
    rows, slopes = F.grid([name], F.STAGES, F.RTOLS)
    assert all(r["success"] for r in rows), [r for r in rows if not r["success"]]
    assert np.all(np.isfinite([r["error"] for r in rows]))
    bad = F.verdict(rows)
    assert not bad, bad
    flat = [f"{k}: slope {v:.2f}" for k, v in slopes.items() if math.isfinite(v) and not F.SLOPE[0] <= v <= F.SLOPE[1]]
    if flat:
        pytest.xfail(f"slope band {F.SLOPE} missed: {F.slope_misses(rows, slopes)}")
