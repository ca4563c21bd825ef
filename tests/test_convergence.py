"""Convergence studies (lobattodae._convergence): observed orders fitted above the round-off
plateau, and the table, which says n/a, not "exact", for orders it could not fit.

The order studies themselves (every example, s = 2..5) are in ``tests/verification/``.
"""

import numpy as np
import pytest

from lobattodae._convergence import ConvergenceStudy, observed_order, order_text


def test_observed_order_ignores_plateau_and_coarse_points():
    h = np.array([0.4, 0.2, 0.1, 0.05, 0.025, 0.0125])
    err = 3.0 * h**4
    err[0] *= 10.0  # pre-asymptotic coarse point: not among the finest above the floor
    err[-1] = 1e-15  # round-off plateau
    assert observed_order(h, err, floor=1e-13) == pytest.approx(4.0, abs=1e-9)
    assert np.isnan(observed_order(h, np.full_like(h, 1e-16), floor=1e-13))


def test_convergence_order_text_exact_only_at_the_round_off_floor():
    """order_text: the one rule, used by the CLI's table too."""
    # a fitted order
    assert order_text(3.987, [1e-3, 1e-4], 1e-13) == "3.99"
    # NaN because every error is at round-off: the component is exact
    assert order_text(float("nan"), [1e-16, 2e-16], 1e-13) == "exact"
    assert order_text(float("nan"), [1e-16], 1e-13) == "exact"
    # NaN for want of points above the floor: not "exact"
    assert order_text(float("nan"), [1e-4], 1e-13) == "n/a"
    assert order_text(float("nan"), [1e-4, 1e-16], 1e-13) == "n/a"
    # failed runs (NaN errors) are no evidence of exactness
    assert order_text(float("nan"), [float("nan"), float("nan")], 1e-13) == "n/a"


def _study(errors: dict, n_steps) -> ConvergenceStudy:
    floors = {"q": 1e-13, "p": 1e-13, "lam": 1e-11}
    h = np.asarray([2.0 / n for n in n_steps])
    return ConvergenceStudy(
        name="test", stages=(2,), n_steps={2: np.asarray(n_steps)}, h={2: h},
        errors={2: {c: np.asarray(e, float) for c, e in errors.items()}}, floors=floors,
        observed={2: {c: observed_order(h, errors[c], floors[c]) for c in errors}},
        expected={2: {"q": 2, "p": 2, "lam": None}}, constraint_residual={2: 1e-16},
    )


def test_table_single_step_count_is_na_not_exact():
    st_ = _study({"q": [1e-3], "p": [2e-3], "lam": [1e-4]}, [16])
    row = next(line for line in st_.table().splitlines() if line.strip().startswith("2 |"))
    cols = row.split("|")
    assert cols[1].split()[0] == "n/a" and cols[2].split()[0] == "n/a" and cols[3].split()[0] == "n/a", row
    assert "n/a: no order can be fitted" in st_.table()


def test_table_exact_only_at_round_off():
    st_ = _study({"q": [1e-16, 2e-16], "p": [1e-3, 2.5e-4], "lam": [float("nan"), float("nan")]}, [16, 32])
    row = next(line for line in st_.table().splitlines() if line.strip().startswith("2 |"))
    cols = row.split("|")
    assert cols[1].split()[0] == "exact"  # every q error at round-off
    assert cols[2].split()[0] == "2.00"
    assert cols[3].split()[0] == "n/a"  # failed runs are no evidence of exactness
    assert order_text(float("nan"), [1e-4, 1e-16], 1e-13) == "n/a"
