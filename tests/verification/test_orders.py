"""Observed orders of the Lobatto IIIA-IIIB scheme on nonlinear nonholonomic problems.

The paper's Corollary: q, p ~ h^(2s-2); λ ~ h^s (s even), h^(s-1) (s odd). Orders are fitted
above the round-off plateau (see ``observed_order``), on the maximum error over the grid.
"""

import numpy as np
import pytest

from lobattodae import LobattoIIIAIIIB
from lobattodae._convergence import convergence_study
from lobattodae.examples import get_example

TOL = 0.3
STAGES = (2, 3, 4, 5)


@pytest.fixture(scope="module", params=["sleigh", "falling-disk"])
def study(request):
    # The sleigh (n=3) and the steady rolling of the tilted disk (n=5, configuration-
    # dependent mass matrix): nonlinear, closed-form solutions, no superconvergence.
    ex = get_example(request.param)
    return ex, convergence_study(ex, stages=STAGES)


def _expected(ex, comp, s):
    return ex.expected_order(comp, s)


@pytest.mark.parametrize("s", STAGES)
@pytest.mark.parametrize("comp", ["q", "p", "lam"])
def test_observed_order_matches_corollary(study, s, comp):
    ex, st = study
    expected = _expected(ex, comp, s)
    assert expected == LobattoIIIAIIIB(stages=s).order()[comp]  # no override for these problems
    obs = st.observed[s][comp]
    assert np.isfinite(obs), f"{ex.name} s={s} {comp}: no points above the round-off plateau"
    assert abs(obs - expected) <= TOL, f"{ex.name} s={s} {comp}: observed {obs:.2f}, theory {expected}"


def test_constraint_exact_at_every_step(study):
    _, st = study
    for s in STAGES:
        assert st.constraint_residual[s] <= 1e-12


def test_consistent_restart_keeps_qp_orders_and_raises_lambda_order():
    """lam_start='consistent': q, p keep 2s-2; λ reaches order s also for odd s."""
    ex = get_example("sleigh")
    st = convergence_study(ex, stages=(3, 4), method_options={"lam_start": "consistent"})
    for s in (3, 4):
        assert abs(st.observed[s]["q"] - (2 * s - 2)) <= TOL
        assert abs(st.observed[s]["p"] - (2 * s - 2)) <= TOL
        assert abs(st.observed[s]["lam"] - s) <= TOL
