"""Observed orders for every example with a closed form, s = 2..5, per component.

The expectation is explicit: ``Example.expected_order(component, s)``, i.e. the paper's
Corollary (q, p: 2s-2; λ: s for even s, s-1 for odd s) unless the example records a known
deviation in ``expected_order_overrides`` (e.g. the vertical rolling disk's p converges with
order 2s for even s). ``None`` means "exact up to round-off": then every error of the study
must lie at round-off. The tolerance is 0.3 on the fitted order and is not loosened per case.

The sleigh and the steady falling disk are covered by ``tests/verification/test_orders.py`` and skipped
here (they are the most expensive studies).
"""

import numpy as np
import pytest

import lobattodae as L
from lobattodae._convergence import COMPONENTS, convergence_study
from lobattodae.examples import get_example, list_examples

TOL = 0.3
STAGES = (2, 3, 4, 5)
COVERED_ELSEWHERE = {"sleigh", "falling-disk"}  # tests/verification/test_orders.py
CLOSED_FORM = [name for name, _ in list_examples() if get_example(name).exact is not None]
NAMES = [name for name in CLOSED_FORM if name not in COVERED_ELSEWHERE]

#: (example, s, component) where the default study is known to measure a wrong order.
#: Particle, s = 5, p: the maximum p error over the grid is pre-asymptotic at the coarse steps
#: of the default grid (local slopes 10.3, 12.4, 9.8, 4.6 for n = 4→5→6→7→8 steps on [0, 2];
#: the location of the maximum moves between components and times) and then approaches 8
#: from below only slowly (6.96, 7.26, 7.44, 7.61, 7.66, 7.92 for n = 9→10→...→20), reaching
#: round-off (~1e-15) before settling: the fit gives 9.78 with the round-off floor at
#: 1e-12·(1+|p|), 7.10 with 1e-13·(1+|p|). No choice of n_steps fixes this. It is not
#: superconvergence: with y0 = -1 the same problem shows order 8.00 cleanly
#: (test_particle_s5_p_is_order_8_in_asymptotic_regime). docs/verification.md reports it too.
KNOWN_PREASYMPTOTIC = {("particle", 5, "p")}


def test_every_closed_form_example_is_covered():
    assert set(CLOSED_FORM) == set(NAMES) | COVERED_ELSEWHERE
    assert {"particle", "knife-edge", "vertical-disk"} <= set(NAMES)


def _cases():
    for name in NAMES:
        for s in STAGES:
            for comp in COMPONENTS:
                marks = ()
                if (name, s, comp) in KNOWN_PREASYMPTOTIC:
                    marks = pytest.mark.xfail(
                        strict=True,
                        reason="particle s=5 p: pre-asymptotic above the round-off floor, the fit misses 8 "
                        "(see KNOWN_PREASYMPTOTIC)",
                    )
                yield pytest.param(name, s, comp, marks=marks, id=f"{name}-s{s}-{comp}")


@pytest.fixture(scope="module")
def studies():
    return {}


def _study_for(name, cache):
    if name not in cache:
        ex = get_example(name)
        cache[name] = (ex, convergence_study(ex, stages=STAGES))
    return cache[name]


@pytest.mark.parametrize("name, s, comp", list(_cases()))
def test_observed_order(name, s, comp, studies):
    ex, st = _study_for(name, studies)
    expected = ex.expected_order(comp, s)
    errors = np.asarray(st.errors[s][comp])
    table = "  ".join(f"n={n}: {e:.1e}" for n, e in zip(st.n_steps[s], errors))
    if expected is None:
        assert np.all(errors <= st.floors[comp]), f"{name} s={s} {comp} should be exact: {table}"
        return
    obs = st.observed[s][comp]
    assert np.isfinite(obs), f"{name} s={s} {comp}: no points above the round-off floor: {table}"
    assert abs(obs - expected) <= TOL, f"{name} s={s} {comp}: observed {obs:.2f}, expected {expected}; {table}"


@pytest.mark.parametrize("name", NAMES)
def test_constraint_exact_and_errors_decrease(name, studies):
    ex, st = _study_for(name, studies)
    for s in STAGES:
        assert st.constraint_residual[s] <= 1e-12, (name, s)
        for comp in COMPONENTS:
            e = np.asarray(st.errors[s][comp])
            # coarsest vs finest step: the error must drop (by at least h-ratio^1 here)
            ratio = st.h[s][0] / st.h[s][-1]
            assert e[-1] <= max(e[0] / ratio, 10 * st.floors[comp]), (name, s, comp, e)


def test_overrides_are_real_superconvergence(studies):
    """Each recorded override is above the default order, and the study confirms it."""
    checked = 0
    for name in NAMES:
        ex = get_example(name)
        for comp, table in ex.expected_order_overrides.items():
            for s, order in table.items():
                if s not in STAGES:
                    continue
                _, st = _study_for(name, studies)
                default = L.LobattoIIIAIIIB(stages=s).order()[comp]
                if order is None:
                    assert np.all(np.asarray(st.errors[s][comp]) <= st.floors[comp])
                else:
                    assert order > default
                    assert st.observed[s][comp] > default + 1.0, (name, s, comp, st.observed[s][comp])
                checked += 1
    assert checked >= 2  # at least the vertical disk's p for s = 2 and 4


def test_particle_s5_p_is_order_8_in_asymptotic_regime():
    """Why particle s=5 p is an xfail above and not superconvergence: starting at y0 = -1
    (so that y runs through [-1, 1]) the p error is larger and in its asymptotic regime
    above the round-off floor, and the order is the Corollary's 8."""
    ex = get_example("particle", y0=-1.0)
    # chunk length 64 as in the default study for s = 5 (reuses its compilation)
    st = convergence_study(ex, stages=(5,), n_steps=(6, 8, 10, 12, 16, 64))
    for comp in ("q", "p"):
        assert abs(st.observed[5][comp] - 8) <= TOL, (comp, st.observed[5][comp], st.errors[5][comp])
    assert abs(st.observed[5]["lam"] - 4) <= TOL
