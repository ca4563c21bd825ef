"""The worked examples of docs/gradients.md run (their short forms) and get the right answers:
the sleigh's parameters recovered by least squares through the solver, the stability
threshold of the upright rolling disk from the Jacobian of the flow map."""

import math

import numpy as np
import pytest

from helpers import load_example_script as _load  # test_gallery.py looks for _load("NAME")

#: Estimates must lie within this many standard errors of the truth (the noise draw is fixed;
#: measured in the short run: at most 1.5 over the seven parameters, 0.83 for a).
MAX_STANDARD_ERRORS = 3.0
#: ... and the standard errors must be small, so that the check above means something
#: (short run: 1.9 % for a, 2.2 % for I).
MAX_RELATIVE_STDERR = 0.05
#: χ²/dof of the short fit (26 degrees of freedom: 99.9 % of draws fall in this range).
CHI2_DOF_RANGE = (0.4, 2.0)
#: The short bisection stops at a bracket of relative width 1e-12, and the discrete map's
#: threshold is the exact one for every step size (measured: 3.5e-14 and 2.3e-13).
THRESHOLD_REL_TOL = 1e-11
#: The nontrivial multipliers at v = 0.75 √(gR) against exp(±iντ) of the linearised equations
#: (5 steps of s = 4 over τ; measured 7.8e-8, order 6 in h).
ROTATION_REL_TOL = 1e-6


@pytest.fixture(scope="module")
def sleigh_script():
    return _load("sleigh_identification")


@pytest.fixture(scope="module")
def identification(sleigh_script):
    return sleigh_script.main(short=True)


@pytest.fixture(scope="module")
def disk_script():
    return _load("disk_stability")


@pytest.fixture(scope="module")
def stability(disk_script):
    return disk_script.main(short=True)


def test_identification_recovers_the_sleigh_parameters(sleigh_script, identification):
    fit = identification.fit
    truth = sleigh_script.truth()
    assert fit.success and fit.lm_steps > 1
    z = fit.error / fit.stderr
    assert np.all(np.abs(z) <= MAX_STANDARD_ERRORS), dict(zip(sleigh_script.NAMES, z))
    # a and I: well determined, and the fit moved far from the starting guesses
    for k, guess in ((0, sleigh_script.GUESS_A), (1, sleigh_script.GUESS_I)):
        assert fit.stderr[k] <= MAX_RELATIVE_STDERR * truth[k]
        assert abs(guess - truth[k]) > 10 * fit.stderr[k]
    assert CHI2_DOF_RANGE[0] < fit.chi2_dof < CHI2_DOF_RANGE[1]


def test_identification_data_and_model(sleigh_script, identification):
    # the integrator's own error at the true parameters is far below the noise
    assert identification.model_error < 0.1 * sleigh_script.SIGMA.min()
    assert identification.n_samples == sleigh_script.N_STEPS_SHORT // sleigh_script.EVERY_SHORT + 1
    # the mass is not identifiable: m ∂r/∂m + I ∂r/∂I = 0 (exact scaling invariance)
    assert identification.fit.mass_degeneracy < 1e-12


def test_disk_threshold_is_the_classical_one(disk_script, stability):
    g, r = disk_script.GRAVITY, disk_script.RADIUS
    # the closed form of the script's derivation is the classical v² = gR/3 (uniform disk) and
    # v² = gR/4 (thin ring); the bisection on the multipliers finds both
    assert math.isclose(stability.disk.exact, math.sqrt(g * r / 3), rel_tol=1e-15)
    assert math.isclose(stability.ring.exact, math.sqrt(g * r / 4), rel_tol=1e-15)
    assert abs(stability.disk.speed - math.sqrt(g * r / 3)) <= THRESHOLD_REL_TOL * stability.disk.speed
    assert abs(stability.ring.speed - math.sqrt(g * r / 4)) <= THRESHOLD_REL_TOL * stability.ring.speed


def test_disk_multipliers_match_the_linear_theory(disk_script, stability):
    check = stability.check
    assert check.rotation_error < ROTATION_REL_TOL
    # conservative and stable: every multiplier on the unit circle; two are exactly 1
    assert check.unit_circle < 1e-8
    assert check.trivial < 1e-12
    assert np.min(np.abs(np.imag(check.multipliers))) < 1e-12 < np.max(np.imag(check.multipliers))
    # at the threshold all four collide at 1 (ill-conditioned: only to about ε^(1/3))
    assert np.max(np.abs(stability.multipliers_at_threshold - 1.0)) < 1e-3


def test_disk_below_the_threshold_is_unstable(disk_script):
    ex = disk_script.rolling_disk()
    method = disk_script.L.LobattoIIIAIIIB(stages=disk_script.STAGES)
    v = 0.8 * math.sqrt(disk_script.GRAVITY * disk_script.RADIUS / 3)
    jac = disk_script.monodromy(v, ex.args, ex.problem, method, disk_script.N_STEPS_SHORT)
    mu = np.linalg.eigvals(np.asarray(jac))
    growth = math.exp(math.sqrt(-disk_script.linear_frequency_squared(ex.args, v)) * disk_script.TAU)
    assert disk_script.stability_indicator(jac) > 0
    assert abs(np.max(np.abs(mu)) - growth) < 1e-6 * growth
