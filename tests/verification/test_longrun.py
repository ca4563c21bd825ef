"""Long runs: constraint and energy behaviour on the contact oscillator, with constant steps and
with the reversible step-size control.

The Lobatto IIIA-IIIB pair is symmetric, so on the reversible McLachlan-Perlmutter contact
oscillator its energy error stays bounded (no secular drift) over very long times, while on
the non-reversible variant (S = cos z) it drifts.

Measured (h = 2 sin(π/40) ≈ 0.157, the step of McLachlan & Perlmutter; 2-core machine):

=========================  ======  =========  ===========================  ==========  =====
problem                    s       lam_start  max|ΔH| first 10% / last 10%  slope·T     time
=========================  ======  =========  ===========================  ==========  =====
contact, 1e6 steps         2       previous   8.61e-3 / 8.61e-3             2.7e-7      22 s
contact, 1e6 steps         3       previous   1.55e-5 / 1.55e-5             5.6e-10     30 s
contact, 1e6 steps         3       consistent 6.59e-3 / 6.33e-2  (drift)    -6.3e-2     28 s
contact, 2e4 steps         3       previous   1.55e-5 / 1.55e-5             -3.5e-8     2 s
contact-nonrev., 2e4 steps 3       previous   1.67e-4 / 1.71e-3  (drift)    1.7e-3      1 s
=========================  ======  =========  ===========================  ==========  =====

``lam_start="consistent"`` re-solves Λ₁ from the hidden constraint at every step point; that
map is not symmetric (a step of h followed by a step of -h misses the start by 2e-4 for
s = 2, h = 0.15, against 1e-16 for the paper's ``"previous"``), so it loses the reversibility
and the energy drifts linearly on the reversible problem. Those tests are strict xfails.
"""

import math
import warnings

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import lobattodae as L
from lobattodae._reversible import ReversibleStepSize
from lobattodae._diagnostics import energy_error
from lobattodae.examples import get_example

from helpers import FIRST_STEP, energy_growth

H = 2.0 * math.sin(math.pi / 40)  # McLachlan & Perlmutter's step, N = 40
CHUNK = 4096
SHORT = 20_000
LONG = 1_000_000
CONSTRAINT_TOL = 1e-12

CONSISTENT_NOT_SYMMETRIC = (
    "lam_start='consistent' (Λ₁ re-solved from the hidden constraint at each step) is not a "
    "symmetric method: it loses reversibility and the energy drifts linearly on the reversible "
    "contact oscillator (s=3, 1e6 steps: max|ΔH| 6.6e-3 in the first 10%, 6.3e-2 in the last), "
    "while the paper's lam_start='previous' keeps it bounded (1.55e-5 throughout)"
)


def _run(name, s, n, lam_start):
    ex = get_example(name)
    method = L.LobattoIIIAIIIB(stages=s, lam_start=lam_start)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        sol = L.solve(ex.problem, method, (0.0, n * H), ex.q0, ex.p0, n_steps=n, args=ex.args,
                      chunk_size=CHUNK)
    assert sol.success and len(sol.t) == n + 1
    return sol, [w for w in caught if issubclass(w.category, RuntimeWarning)]


def _energy_drift(sol):
    """(max|ΔH| over the first 10 %, over the last 10 %, linear-fit slope × T)."""
    dh = energy_error(sol)
    k = len(dh) // 10
    first = float(np.max(np.abs(dh[:k])))
    last = float(np.max(np.abs(dh[-k:])))
    slope = float(np.polyfit(sol.t - sol.t[0], dh, 1)[0])
    return first, last, slope * (sol.t[-1] - sol.t[0])


def _assert_no_secular_drift(sol):
    first, last, slope_t = _energy_drift(sol)
    assert first > 0.0
    assert last / first < 2.0, f"energy error grows: {first:.2e} -> {last:.2e}"
    assert abs(slope_t) < 0.1 * first, f"linear trend {slope_t:.2e} over the run, oscillation {first:.2e}"


def _assert_constraint(sol):
    assert np.max(sol.stats["constraint_residual"]) <= CONSTRAINT_TOL


# ------------------------------------------------------------------------ short (default)
@pytest.fixture(scope="module")
def reversible_short():
    return _run("contact", 3, SHORT, "previous")


def test_reversible_energy_bounded_short(reversible_short):
    sol, warns = reversible_short
    _assert_constraint(sol)
    _assert_no_secular_drift(sol)
    assert not warns, [str(w.message) for w in warns]
    # the decoupled y oscillator's energy H_y is conserved too (bounded error)
    ex = get_example("contact")
    from lobattodae._diagnostics import invariant_error

    ey = invariant_error(sol, ex.invariants["H_y"])
    k = len(ey) // 10
    assert np.max(np.abs(ey[-k:])) < 2.0 * np.max(np.abs(ey[:k])) + 1e-14


def test_nonreversible_energy_drifts_short(reversible_short):
    """The same method on the non-reversible variant: the energy error grows ~linearly."""
    sol, _ = _run("contact-nonreversible", 3, SHORT, "previous")
    _assert_constraint(sol)
    first, last, slope_t = _energy_drift(sol)
    rev_first, rev_last, _ = _energy_drift(reversible_short[0])
    assert last / first > 5.0, (first, last)  # measured 10.3 (linear drift over 10× the time)
    assert slope_t > first, (slope_t, first)  # a trend larger than the early oscillation
    assert last > 100 * rev_last  # measured 1.7e-3 vs 1.55e-5


def test_lam_start_consistent_is_not_symmetric():
    """Why the 'consistent' variant drifts: one step forward and one back does not return."""
    ex = get_example("contact")
    q0, p0, lam0 = map(jnp.asarray, (ex.q0, ex.p0, ex.lam0))
    h = 0.15
    back = {}
    for lam_start in ("previous", "consistent"):
        m = L.LobattoIIIAIIIB(stages=2, lam_start=lam_start)
        step = jax.jit(lambda t, q, p, lam, dt, m=m: m.step(ex.problem, t, q, p, lam, dt, ex.args))  # one compile
        q1, p1, lam1, info, _ = step(0.0, q0, p0, lam0, h)
        qb, pb, _, info_b, _ = step(h, q1, p1, lam1, -h)
        assert int(info.result) == 0 and int(info_b.result) == 0
        back[lam_start] = float(jnp.max(jnp.abs(jnp.concatenate([qb - q0, pb - p0]))))
    assert back["previous"] < 1e-14
    assert back["consistent"] > 1e-6  # measured 2.1e-4


@pytest.mark.xfail(strict=True, reason=CONSISTENT_NOT_SYMMETRIC)
def test_reversible_energy_bounded_short_consistent():
    sol, _ = _run("contact", 3, SHORT, "consistent")
    _assert_constraint(sol)
    _assert_no_secular_drift(sol)


# -------------------------------------------------------------------------------- slow
@pytest.mark.slow
def test_long_run_reversible_energy_bounded():
    """1e6 steps (t ≈ 1.6e5) of the paper's scheme, s = 3: ‖φ‖ ≤ 1e-12 throughout and no
    secular energy drift (measured 1.55e-5 in both the first and the last 10 %)."""
    sol, warns = _run("contact", 3, LONG, "previous")
    _assert_constraint(sol)
    _assert_no_secular_drift(sol)
    assert not warns, [str(w.message) for w in warns]
    # the λ error estimate stays small (no weak instability of the |R(∞)| = 1 propagation)
    assert np.max(sol.stats["multiplier_drift"]) < 0.1


@pytest.mark.slow
@pytest.mark.xfail(strict=True, reason=CONSISTENT_NOT_SYMMETRIC)
def test_long_run_reversible_energy_bounded_consistent():
    sol, _ = _run("contact", 3, LONG, "consistent")
    _assert_constraint(sol)
    _assert_no_secular_drift(sol)


# -- the reversible step-size control (ReversibleStepSize; tests/test_reversible.py) ----------------
@pytest.mark.slow
def test_reversible_control_over_ten_to_the_fifth_steps(contact):
    """10⁵ steps of s = 3 (t up to 1.7·10⁴): measured max |ΔH| 4.19e-5 in every decade of time
    from t = 100 on (benchmarks/reversible.py: 4.18e-5 → 4.20e-5). Error control (PI, step
    doubling) given at least as many steps (rtol = 1e-2: 122,864 steps against 100,571) drifts
    linearly (×9.9 from the first tenth to the last) and ends at 3.2e-4, 7.6× the reversible
    control's bounded error (2026-11-27; at rtol = 1e-4 it takes 404,053 steps, still ×10.1)."""
    ex = contact
    t_end = 1.7e4
    rev = L.solve(ex.problem, L.LobattoIIIAIIIB(stages=3), (0.0, t_end), ex.q0, ex.p0, args=ex.args, save_every=50,
                  controller=ReversibleStepSize(), first_step=FIRST_STEP)
    pi = L.solve(ex.problem, L.LobattoIIIAIIIB(stages=3), (0.0, t_end), ex.q0, ex.p0, args=ex.args, save_every=50,
                 rtol=1e-2, atol=1e-2)
    assert rev.stats["n_steps"] > 100_000
    assert pi.stats["n_steps"] >= rev.stats["n_steps"]  # the comparison does not starve error control
    g_rev, top_rev = energy_growth(ex, rev)
    g_pi, top_pi = energy_growth(ex, pi)
    assert g_rev < 1.5 and top_rev < 1e-4
    assert g_pi > 5.0 and top_pi > 3 * top_rev
