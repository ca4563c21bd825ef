"""The gallery's scripts (docs/examples/*.py, shown on the pages under docs/gallery/) run, and
what they compute is right (issue #28).

Every script is run by a test: the turntable here in the default suite; the ensemble sweep,
the rattleback and the two bicycle scripts here under ``-m slow`` (each compiles a solver for
30 s to 2 minutes on the 2-core machine); ``disk_stability`` and ``sleigh_identification`` in
``tests/test_docs_examples.py`` and ``falling_disk_touchdown`` in
``tests/test_examples_scripts.py`` (default suite). :func:`test_every_script_is_on_a_page_and_run_by_a_test`
keeps it that way for scripts added later.
"""

import math
import re

import numpy as np
import pytest

import lobattodae as L

from helpers import EXAMPLES_DIR, ROOT
from helpers import load_example_script as _load  # the test below looks for _load("NAME") in test files

GALLERY_DIR = ROOT / "docs" / "gallery"


# ----------------------------------------------------------------------------- every script
def test_every_script_is_on_a_page_and_run_by_a_test():
    """Each docs/examples/NAME.py is included by a gallery page (``--8<-- "docs/examples/NAME.py"``)
    and loaded by a test file (``_load("NAME")``)."""
    scripts = sorted(p.stem for p in EXAMPLES_DIR.glob("*.py"))
    pages = "\n".join(p.read_text(encoding="utf-8") for p in GALLERY_DIR.glob("*.md"))
    tests = "\n".join(p.read_text(encoding="utf-8") for p in (ROOT / "tests").glob("test_*.py"))
    assert scripts
    for name in scripts:
        assert f'--8<-- "docs/examples/{name}.py"' in pages, f"docs/examples/{name}.py is on no gallery page"
        assert re.search(rf'_load\("{name}"\)', tests), f"docs/examples/{name}.py is run by no test"


# ----------------------------------------------------------------------------- turntable
#: The centre against the closed form at every step point (measured ≤ 3.0e-11 with s = 3, 500
#: steps per period, 2026-11-27; the error of s = 3 falls like h⁴).
TURNTABLE_TOL = 1e-9


@pytest.fixture(scope="module")
def turntable():
    script = _load("turntable_ball")
    return script, script.main(figure=False)


def test_turntable_balls_follow_the_closed_form_and_come_back_after_7pi_over_omega(turntable):
    script, runs = turntable
    assert len(runs) == len(script.BALLS) == 5
    assert math.isclose(script.PERIOD, 7 * math.pi / script.OMEGA, rel_tol=1e-15)
    for r in runs:
        assert r.t[-1] == pytest.approx(script.PERIOD, rel=1e-14)
        assert r.max_error < TURNTABLE_TOL, (r.ball.label, r.max_error)
        # back at the start after one period of 2Ω/7 (relative to the table's moving centre)
        assert r.return_distance < TURNTABLE_TOL, (r.ball.label, r.return_distance)
        # ... having gone round a circle of the closed form's radius: half a period later it is
        # a diameter away
        half = len(r.t) // 2
        v = np.array([r.ball.Vx, r.ball.Vy])
        across = np.hypot(*(r.xy[half] - v * r.t[half] - r.xy[0]))
        assert across == pytest.approx(2 * r.radius, rel=1e-6)
        assert r.radius > 0.05
        assert r.max_phi < 1e-13
        # the Tait–Bryan chart stays clear of its singularity at β = π/2
        assert r.max_beta < 1.3


def test_turntable_ball_is_not_back_after_one_turn_of_the_table(turntable):
    """The centre's period is that of 2Ω/7, not the table's 2π/Ω: at t = 2π/Ω the computed
    centre is far from its start (about 1.56 radii: the chord of 2π·2/7)."""
    script, runs = turntable
    for r in runs:
        k = int(np.argmin(np.abs(r.t - 2 * math.pi / script.OMEGA)))
        v = np.array([r.ball.Vx, r.ball.Vy])
        chord = 2 * r.radius * math.sin(script.RATE * r.t[k] / 2)
        assert np.hypot(*(r.xy[k] - v * r.t[k] - r.xy[0])) == pytest.approx(chord, rel=1e-6)
        assert chord > 1.5 * r.radius


def test_turntable_ball_placed_on_the_table_circles_a_point_beyond_the_centre(turntable):
    """A ball set down at rest on the table (ẋ = Ω ẑ × x0) circles the point −(5/2) x0, with
    radius (7/2)|x0|, as the closed form's circle centre x0 + ẑ × w0/ω_c says."""
    _, runs = turntable
    r = next(r for r in runs if r.ball.label == "placed at rest on the table")
    x0 = np.array([r.ball.x0, r.ball.y0])
    centre = r.xy[:-1].mean(axis=0)  # the step points cover one period uniformly (the last is the first)
    np.testing.assert_allclose(centre, -2.5 * x0, atol=1e-9)
    np.testing.assert_allclose(np.hypot(*(r.xy - centre).T), 3.5 * np.hypot(*x0), rtol=1e-8)


# ----------------------------------------------------------------------------- ensemble sweep
@pytest.mark.slow  # compiles the ensemble's loop and a solve: about 40 s on the 2-core machine
def test_disk_ensemble_sweep():
    script = _load("disk_ensemble")
    r = script.main(short=True)
    g = r.grid
    assert g.ratio.size == len(script.BODIES) * script.SPEED_RATIOS_SHORT.size * script.TILTS_SHORT.size
    assert np.all(r.status == L.Result.SUCCESSFUL)
    assert r.max_phi < 1e-13
    # the ensemble's rows are those of one solve per trajectory (round-off, amplified by the
    # unstable run's growth: measured 6.5e-12 there, ≤ 6e-14 elsewhere)
    assert len(r.solve_checks) == 3
    for c in r.solve_checks:
        assert c.max_difference < 1e-10, c
    small, large = script.TILTS_SHORT
    for b in range(len(script.BODIES)):
        def at(ratio, tilt, b=b):
            k = np.flatnonzero((g.body == b) & np.isclose(g.ratio, ratio) & (g.tilt == tilt))
            return int(k[0])

        # above v_c the largest tilt is θ0 (x² + 1)/(x² − 1) (measured 1.6e-4 at x = 1.3 and
        # 5.3e-6 at x = 2 for θ0 = 0.003) ...
        assert r.linear_error[at(1.3, small)] < 5e-4
        assert r.linear_error[at(2.0, small)] < 2e-5
        # ... up to the nonlinear terms, O(θ0²): ten times θ0, a hundred times the difference
        for x in (1.3, 2.0):
            ratio = r.linear_error[at(x, large)] / r.linear_error[at(x, small)]
            assert 60 < ratio < 140, (x, ratio)
        # below v_c upright rolling is unstable: from 0.003 rad the tilt grows past 0.5 rad
        assert r.amplification[at(0.7, small)] * small > 0.5
        assert np.all(np.isnan(r.linear_error[g.ratio < script.LINEAR_FROM]))


# ----------------------------------------------------------------------------- rattleback
@pytest.mark.slow  # the rattleback's solver compiles in 15-35 s (up to 80 s on a loaded machine)
def test_rattleback_spin_reverses_in_one_sense_only():
    script = _load("rattleback")
    runs = script.main(short=True)
    wrong, preferred = runs
    assert (wrong.spin0, preferred.spin0) == (-script.SPIN, script.SPIN)
    for r in runs:
        assert r.t[-1] == pytest.approx(script.T_END_SHORT)
        assert r.spin[0] == pytest.approx(r.spin0, rel=1e-12)
        # no slip, no friction: the energy is conserved up to the integration error (measured
        # 1.3e-5 H0 spun at −5 rad/s, 3.3e-8 H0 at +5), the constraints at round-off
        assert np.max(np.abs(r.energy_error)) < 3e-5 * r.energy0
        assert r.max_phi < 1e-13 and r.max_norm_error < 1e-13
    # spun the wrong way it reverses within 3 s (2.76 s) and then spins the other way ...
    assert 2.0 < wrong.first_reversal < 3.0
    assert wrong.spin.max() > 2.0
    assert np.all(wrong.spin[wrong.t < 2.0] < 0)
    # ... which it keeps (it reverses too, at about 11.5 s, after the short run's 4 s)
    assert math.isinf(preferred.first_reversal) and preferred.spin.min() > 4.0
    # the start: 0.5° of roll and 0.5° of pitch tilt the body's z axis by 0.707°
    tilt0 = math.acos(math.cos(math.radians(script.ROLL_DEG)) * math.cos(math.radians(script.PITCH_DEG)))
    for r in runs:
        assert r.tilt[0] == pytest.approx(tilt0, rel=1e-9)


def test_first_sign_change_interpolates():
    script = _load("rattleback")
    t = np.linspace(0.0, 1.0, 11)
    assert script.first_sign_change(t, 0.35 - t) == pytest.approx(0.35)
    assert script.first_sign_change(t, t - 0.55) == pytest.approx(0.55)
    assert math.isinf(script.first_sign_change(t, 1.0 + t))


# ----------------------------------------------------------------------------- bicycle
@pytest.mark.slow  # builds the bicycle and compiles its s = 4 loop: about 2 minutes
def test_bicycle_benchmark_script():
    script = _load("bicycle_benchmark")
    out = script.main(["--no-figure"])
    for name in ("M", "C1", "K0", "K2"):
        np.testing.assert_allclose(out["matrices"][name], script.PUBLISHED[name], rtol=0, atol=1e-11)
    assert out["weave"] == pytest.approx(script.PUBLISHED["weave"], rel=1e-12)
    assert out["capsize"] == pytest.approx(script.PUBLISHED["capsize"], rel=1e-12)
    ref = np.array(script.PUBLISHED["eig5"])
    for e in out["eig5"]:
        assert np.min(np.abs(ref - e)) < 1e-10 * abs(e)
    runs = {run["v"]: run for run in out["runs"]}
    assert set(runs) == {5.0, 4.6, 3.0}
    for run in runs.values():
        assert run["phi"] < 1e-13 and run["psi"] < 1e-13
        assert run["dH"] < 1e-8 * run["H0"]
    # self-stable speeds: the weave decays at about its linear rate, the kick dies out
    for v in (5.0, 4.6):
        assert runs[v]["rate"] < 0 and runs[v]["rate"] == pytest.approx(runs[v]["lam_w"].real, rel=0.15)
        assert runs[v]["roll_end"] < 0.05 * runs[v]["roll_max"]
    # below the weave speed the weave grows at its linear rate
    assert runs[3.0]["lam_w"].real > 0
    assert runs[3.0]["rate"] == pytest.approx(runs[3.0]["lam_w"].real, rel=0.02)


@pytest.mark.slow  # the same compile, plus writing an 80-frame GIF
def test_bicycle_animation_script(tmp_path):
    from PIL import Image

    script = _load("bicycle_animation")
    out = script.main(["--out", str(tmp_path / "bicycle.gif")])
    assert out["out"] == tmp_path / "bicycle.gif"
    with Image.open(out["out"]) as gif:
        assert gif.n_frames == out["frames"] == script.FRAMES
    assert out["phi"] < 1e-13 and out["psi"] < 1e-13
    assert out["energy_error"] < 1e-8 * out["energy0"]
    # the bicycle leans and steers (0.116 and 0.134 rad) and travels about 4.6 m/s × 3.95 s
    assert 0.05 < out["roll_max"] < 0.2 and 0.05 < out["steer_max"] < 0.2
    assert out["travelled"] == pytest.approx(4.6 * 3.95, rel=0.03)
