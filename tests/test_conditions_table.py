"""Tests of the table of simplifying assumptions behind lobattodae._conditions.

Each row of ``_ASSUMPTIONS`` is checked on its own, one test polynomial at a time, so that a
wrong chain order, a wrong ``first``/degree shift or a wrong right-hand side in the table
shows up even where the public wrappers would still look plausible.
"""

from __future__ import annotations

import dataclasses
import inspect

import numpy as np
import pytest
from numpy.polynomial import Legendre, Polynomial

from lobattodae import _conditions as cond
from lobattodae import conditions
from lobattodae._conditions import _ASSUMPTIONS, DEFAULT_TOL, _test_polynomial
from lobattodae.conditions import TableauReport
from lobattodae._tableau import lobatto_pair

PAIR_NAMES = ("CC_hat", "C_hatC", "DD_hat", "D_hatD")
# report name -> (table row, the matrix passed as ``a``)
REPORTED = {name: (name, "a") for name in _ASSUMPTIONS} | {
    "C_hat": ("C", "a_hat"),
    "D_hat": ("D", "a_hat"),
}


def lobatto_orders(s):
    """../shared/DESIGN.md: B(2s-2), C(s), D(s-2) for A; C_hat(s-2), D_hat(s) for A_hat;
    CC_hat(s), DD_hat(s), C_hatC(s-2), D_hatD(s-2), and none of them at the next k."""
    return dict(B=2 * s - 2, C=s, D=s - 2, C_hat=s - 2, D_hat=s,
                CC_hat=s, DD_hat=s, C_hatC=s - 2, D_hatD=s - 2)  # fmt: skip


def _inputs(pair, matrix="a"):
    return {"a": np.asarray(getattr(pair, matrix)), "a_hat": np.asarray(pair.a_hat),
            "b": np.asarray(pair.b), "c": np.asarray(pair.c)}  # fmt: skip


def _row_residual(row, x, degree, basis):
    return float(np.max(np.abs(row.residual(x, _test_polynomial(basis, degree)))))


def _random_data(seed=2024, s=5):
    rng = np.random.default_rng(seed)
    return {"a": rng.normal(size=(s, s)), "a_hat": rng.normal(size=(s, s)),
            "b": rng.uniform(0.1, 1.0, s), "c": rng.uniform(0.0, 1.0, s)}  # fmt: skip


def test_table_shape():
    assert set(_ASSUMPTIONS) == {"B", "C", "D", *PAIR_NAMES}
    assert set(REPORTED) == set(lobatto_orders(3))
    assert set(REPORTED) <= {f.name for f in dataclasses.fields(TableauReport)}
    for name, row in _ASSUMPTIONS.items():
        assert row.first == (2 if name in PAIR_NAMES else 1), name
        assert row.args[-1] == "c" and len(set(row.args)) == len(row.args), name
    assert _ASSUMPTIONS["B"].args == ("b", "c")


@pytest.mark.parametrize("s", range(2, 9))
def test_each_row_vanishes_up_to_design_order_and_fails_next(s):
    """Per test polynomial: zero for m = first..k, clearly nonzero at m = k + 1."""
    pair = lobatto_pair(s)
    for reported, k in lobatto_orders(s).items():
        name, matrix = REPORTED[reported]
        row = _ASSUMPTIONS[name]
        x = {key: _inputs(pair, matrix)[key] for key in row.args}
        top = max(k, row.first - 1)  # s = 2: C_hatC(0), D_hatD(0) hold only vacuously
        for basis, violated in (("monomial", 1e-9), ("legendre", 1e-5)):
            for m in range(row.first, top + 1):
                assert _row_residual(row, x, m - row.first, basis) <= 4e-15, (reported, m, basis)
            bad = _row_residual(row, x, top + 1 - row.first, basis)
            assert bad >= violated, (reported, top + 1, basis)


@pytest.mark.parametrize("s", range(2, 9))
def test_generic_functions_agree_with_design_orders(s):
    pair = lobatto_pair(s)
    for reported, k in lobatto_orders(s).items():
        name, matrix = REPORTED[reported]
        x = _inputs(pair, matrix)
        first = _ASSUMPTIONS[name].first
        assert cond._max_order(name, None, DEFAULT_TOL, **x) == max(k, first - 1), reported
        assert cond._satisfies(name, max(k, first - 1), DEFAULT_TOL, **x), reported
        assert not cond._satisfies(name, max(k, first - 1) + 1, DEFAULT_TOL, **x), reported


def test_rows_are_the_papers_equations():
    """Monomial test polynomial ``t^{m-first}`` against the closed forms of the docstring."""
    x = _random_data()
    a, ah, b, c = x["a"], x["a_hat"], x["b"], x["c"]

    def pair_d(p, q, m):
        return (b * c ** (m - 2)) @ p @ q - b * ((m - 1) - (m * c - c**m)) / (m * (m - 1))

    closed = {
        "B": lambda m: np.atleast_1d(b @ c ** (m - 1) - 1 / m),
        "C": lambda m: a @ c ** (m - 1) - c**m / m,
        "D": lambda m: (b * c ** (m - 1)) @ a - b * (1 - c**m) / m,
        "CC_hat": lambda m: a @ ah @ c ** (m - 2) - c**m / (m * (m - 1)),
        "C_hatC": lambda m: ah @ a @ c ** (m - 2) - c**m / (m * (m - 1)),
        "DD_hat": lambda m: pair_d(a, ah, m),
        "D_hatD": lambda m: pair_d(ah, a, m),
    }
    for name, row in _ASSUMPTIONS.items():
        for m in range(row.first, 7):
            got = row.residual(x, Polynomial.basis(m - row.first))
            np.testing.assert_allclose(got, closed[name](m), rtol=1e-12, atol=1e-13,
                                       err_msg=f"{name}, m = {m}")  # fmt: skip
    # the swapped rows differ on these data, so a swapped chain would be caught
    for one, other in (("CC_hat", "C_hatC"), ("DD_hat", "D_hatD")):
        assert np.max(np.abs(closed[one](3) - closed[other](3))) > 1e-3


def test_legendre_rows_are_combinations_of_monomial_rows():
    """Each residual is linear in the test polynomial, so both bases span the same equations."""
    x = _random_data(7)
    for name, row in _ASSUMPTIONS.items():
        for degree in range(6):
            coef = Legendre.basis(degree, domain=[0.0, 1.0]).convert(kind=Polynomial).coef
            combo = sum(cj * row.residual(x, Polynomial.basis(j)) for j, cj in enumerate(coef))
            got = row.residual(x, Legendre.basis(degree, domain=[0.0, 1.0]))
            np.testing.assert_allclose(got, combo, rtol=1e-10, atol=1e-10, err_msg=name)


def test_public_wrappers_delegate_to_their_row():
    """Every ``*_error``, ``satisfies_*``, ``max_order_*`` uses its row's arrays and range."""
    x = _random_data(11)
    suffix = {"B": "b", "C": "c", "D": "d", "CC_hat": "cc_hat", "C_hatC": "c_hat_c",
              "DD_hat": "dd_hat", "D_hatD": "d_hat_d"}  # fmt: skip
    for name, row in _ASSUMPTIONS.items():
        error = getattr(conditions, f"{suffix[name]}_error")
        satisfies = getattr(conditions, f"satisfies_{suffix[name]}")
        max_order = getattr(conditions, f"max_order_{suffix[name]}")
        assert list(inspect.signature(error).parameters) == [*row.args, "k", "basis"]
        assert list(inspect.signature(satisfies).parameters) == [*row.args, "k", "tol"]
        assert list(inspect.signature(max_order).parameters) == [*row.args, "cap", "tol"]
        args = [x[key] for key in row.args]
        assert error(*args, row.first - 1) == 0.0  # vacuous below ``first``...
        assert error(*args, row.first) > 1e-3  # ... but not at ``first`` on random data
        for k in range(row.first, 5):
            for basis in ("monomial", "legendre"):
                direct = max(
                    _row_residual(row, x, m - row.first, basis) for m in range(row.first, k + 1)
                )
                assert error(*args, k, basis=basis) == direct, (name, k, basis)
            assert satisfies(*args, k, tol=10.0) == (error(*args, k, basis="legendre") <= 10.0)
        assert max_order(*args) == row.first - 1
        assert max_order(*args, tol=np.inf, cap=6) == 6


def test_decisions_use_the_legendre_form():
    # s = 12: the monomial residual of B(2s - 1) is below the tolerance, the Legendre one is not.
    pair = lobatto_pair(12)
    k = 2 * 12 - 1
    assert cond.b_error(pair.b, pair.c, k) < DEFAULT_TOL
    assert cond.b_error(pair.b, pair.c, k, basis="legendre") > 1e-6
    assert not conditions.satisfies_b(pair.b, pair.c, k)
    assert conditions.max_order_b(pair.b, pair.c) == 2 * 12 - 2
