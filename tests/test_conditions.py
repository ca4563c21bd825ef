"""Tests of the order conditions, hypotheses and stability (lobattodae.conditions: _conditions,
_condition_checks, _tableau_report), and of the table of simplifying assumptions behind them
(``_conditions._ASSUMPTIONS``), row by row."""

from __future__ import annotations

import dataclasses
import inspect
import json

import numpy as np
import pytest
from numpy.polynomial import Legendre, Polynomial

from lobattodae import _conditions as cond
from lobattodae import conditions
from lobattodae._conditions import _ASSUMPTIONS, _test_polynomial
from lobattodae.conditions import (
    DEFAULT_TOL,
    TableauReport,
    b_error,
    c_error,
    c_hat_c_error,
    cc_hat_error,
    check_tableau,
    conjugacy_error,
    d_error,
    d_hat_d_error,
    dd_hat_error,
    hypotheses,
    max_order,
    max_order_b,
    max_order_c,
    r_infinity,
    satisfies_b,
    satisfies_c,
    satisfies_c_hat_c,
    satisfies_cc_hat,
    satisfies_d,
    satisfies_d_hat_d,
    satisfies_dd_hat,
    stability_function,
)
from lobattodae._tableau import LobattoPair, lobatto_pair

S_TABLE = range(2, 9)


def expected_table(s):
    """The assumptions the s-stage Lobatto IIIA-IIIB pair satisfies (and not at k + 1).

    Paper, section 2: B(2s-2), C(s), D(s-2), C_hat(s-2), D_hat(s), CC_hat(s), DD_hat(s),
    C_hatC(s-2), D_hatD(s-2). The pair conditions start at k = 2, so for s = 2 the
    value s - 2 = 0 is reported as 1 ("no nontrivial k holds").
    """
    return dict(
        B=2 * s - 2,
        C=s,
        D=s - 2,
        C_hat=s - 2,
        D_hat=s,
        CC_hat=s,
        DD_hat=s,
        C_hatC=max(s - 2, 1),
        D_hatD=max(s - 2, 1),
    )


def _checks(pair):
    """(name, satisfies(k), residual(k) in both bases) for every assumption."""
    a, a_hat, b, c = pair.a, pair.a_hat, pair.b, pair.c
    return {
        "B": (lambda k: satisfies_b(b, c, k), lambda k, **kw: b_error(b, c, k, **kw)),
        "C": (lambda k: satisfies_c(a, c, k), lambda k, **kw: c_error(a, c, k, **kw)),
        "D": (lambda k: satisfies_d(a, b, c, k), lambda k, **kw: d_error(a, b, c, k, **kw)),
        "C_hat": (
            lambda k: satisfies_c(a_hat, c, k),
            lambda k, **kw: c_error(a_hat, c, k, **kw),
        ),
        "D_hat": (
            lambda k: satisfies_d(a_hat, b, c, k),
            lambda k, **kw: d_error(a_hat, b, c, k, **kw),
        ),
        "CC_hat": (
            lambda k: satisfies_cc_hat(a, a_hat, c, k),
            lambda k, **kw: cc_hat_error(a, a_hat, c, k, **kw),
        ),
        "DD_hat": (
            lambda k: satisfies_dd_hat(a, a_hat, b, c, k),
            lambda k, **kw: dd_hat_error(a, a_hat, b, c, k, **kw),
        ),
        "C_hatC": (
            lambda k: satisfies_c_hat_c(a, a_hat, c, k),
            lambda k, **kw: c_hat_c_error(a, a_hat, c, k, **kw),
        ),
        "D_hatD": (
            lambda k: satisfies_d_hat_d(a, a_hat, b, c, k),
            lambda k, **kw: d_hat_d_error(a, a_hat, b, c, k, **kw),
        ),
    }


# ------------------------------------------------------------------ the assumption table


@pytest.mark.parametrize("s", S_TABLE)
def test_assumption_table_exact(s):
    report = check_tableau(lobatto_pair(s))
    got = {name: getattr(report, name) for name in expected_table(s)}
    assert got == expected_table(s)


@pytest.mark.parametrize("s", S_TABLE)
def test_assumptions_hold_at_k_and_fail_at_next_k(s):
    pair = lobatto_pair(s)
    for name, k in expected_table(s).items():
        holds, residual = _checks(pair)[name]
        assert holds(k), (name, k)
        assert not holds(k + 1), (name, k + 1)
        # Both forms of the residual agree, with a clear gap for s <= 8 (measured: at most
        # 1.3e-15 when satisfied; when violated at least 6.5e-9 in the paper's monomial
        # form and 7.7e-5 in the shifted Legendre form used for the decisions).
        for basis, violated in (("monomial", 1e-9), ("legendre", 1e-5)):
            assert residual(k, basis=basis) <= 4e-15, (name, k, basis)
            assert residual(k + 1, basis=basis) >= violated, (name, k + 1, basis)


@pytest.mark.parametrize("s", range(9, 17))
def test_assumption_table_large_s(s):
    # The decisions use the shifted Legendre form, which keeps the gap clear for large s
    # (the monomial residual of B(2s-1) is already below 1e-12 at s = 12).
    report = check_tableau(lobatto_pair(s))
    assert {name: getattr(report, name) for name in expected_table(s)} == expected_table(s)


# ------------------------------------------------ literal values of the paper's residuals


def test_residuals_literal_values_s3():
    # s = 3 (Simpson): hand-computed residuals of the first violated assumptions.
    pair = lobatto_pair(3)
    a, a_hat, b, c = pair.a, pair.a_hat, pair.b, pair.c
    # B(5): sum b c^4 = 2/3 * 1/16 + 1/6 = 5/24, minus 1/5.
    assert b_error(b, c, 5) == pytest.approx(1 / 120, abs=1e-16)
    # C(4): row c = 1/2: 1/3 * 1/8 - 1/24 = 0 against c^4/4 = 1/64.
    assert c_error(a, c, 4) == pytest.approx(1 / 64, abs=1e-16)
    # D(2): j = 2: 2/3 * 1/2 * 1/3 + 1/6 * 2/3 = 2/9 against b_2 (1 - 1/4) / 2 = 1/4.
    assert d_error(a, b, c, 2) == pytest.approx(1 / 36, abs=1e-16)
    # C_hatC(3): m = 2: (A_hat A 1)_i against c_i^2 / 2; m = 3: (A_hat A c)_i against
    # c_i^3 / 6. Both fail for s = 3 (C_hatC holds only trivially, at k = 1).
    m2 = np.max(np.abs(a_hat @ a @ np.ones(3) - c**2 / 2))
    m3 = np.max(np.abs(a_hat @ a @ c - c**3 / 6))
    direct = max(m2, m3)
    assert min(m2, m3) > 1e-3
    assert c_hat_c_error(a, a_hat, c, 3) == pytest.approx(direct, abs=1e-16)
    # vacuous k
    assert b_error(b, c, 0) == 0.0
    assert cc_hat_error(a, a_hat, c, 1) == 0.0
    assert d_hat_d_error(a, a_hat, b, c, 1) == 0.0


def _brute_force(a, a_hat, b, c, k):
    """The paper's equations with explicit loops, one index at a time."""
    s = len(b)
    rng = range(s)
    out = {}
    out["B"] = max(
        (abs(sum(b[i] * c[i] ** (m - 1) for i in rng) - 1 / m) for m in range(1, k + 1)),
        default=0.0,
    )
    out["C"] = max(
        (
            abs(sum(a[i, j] * c[j] ** (m - 1) for j in rng) - c[i] ** m / m)
            for i in rng
            for m in range(1, k + 1)
        ),
        default=0.0,
    )
    out["D"] = max(
        (
            abs(sum(b[i] * c[i] ** (m - 1) * a[i, j] for i in rng) - b[j] * (1 - c[j] ** m) / m)
            for j in rng
            for m in range(1, k + 1)
        ),
        default=0.0,
    )

    def pair_c(x, y):
        return max(
            (
                abs(
                    sum(x[i, j] * y[j, l] * c[l] ** (m - 2) for j in rng for l in rng)
                    - c[i] ** m / (m * (m - 1))
                )
                for i in rng
                for m in range(2, k + 1)
            ),
            default=0.0,
        )

    def pair_d(x, y):
        return max(
            (
                abs(
                    sum(b[i] * c[i] ** (m - 2) * x[i, j] * y[j, l] for i in rng for j in rng)
                    - b[l] / (m * (m - 1)) * ((m - 1) - (m * c[l] - c[l] ** m))
                )
                for l in rng
                for m in range(2, k + 1)
            ),
            default=0.0,
        )

    out["CC_hat"] = pair_c(a, a_hat)
    out["C_hatC"] = pair_c(a_hat, a)
    out["DD_hat"] = pair_d(a, a_hat)
    out["D_hatD"] = pair_d(a_hat, a)
    return out


@pytest.mark.parametrize("k", [0, 1, 2, 3, 4])
def test_index_placement_against_brute_force(k):
    # A random, non-symmetric "pair" distinguishes every index placement.
    rng = np.random.default_rng(1234)
    s = 4
    a = rng.normal(size=(s, s))
    a_hat = rng.normal(size=(s, s))
    b = rng.uniform(0.1, 1.0, size=s)
    c = rng.uniform(0.0, 1.0, size=s)
    ref = _brute_force(a, a_hat, b, c, k)
    got = {
        "B": b_error(b, c, k),
        "C": c_error(a, c, k),
        "D": d_error(a, b, c, k),
        "CC_hat": cc_hat_error(a, a_hat, c, k),
        "C_hatC": c_hat_c_error(a, a_hat, c, k),
        "DD_hat": dd_hat_error(a, a_hat, b, c, k),
        "D_hatD": d_hat_d_error(a, a_hat, b, c, k),
    }
    for name in ref:
        assert got[name] == pytest.approx(ref[name], rel=1e-12, abs=1e-14), name
    if k >= 2:  # the swapped pair conditions genuinely differ on this data
        assert abs(got["CC_hat"] - got["C_hatC"]) > 1e-3
        assert abs(got["DD_hat"] - got["D_hatD"]) > 1e-3


def test_bad_basis_rejected():
    pair = lobatto_pair(3)
    with pytest.raises(ValueError, match="basis must be 'monomial' or 'legendre'"):
        b_error(pair.b, pair.c, 2, basis="chebyshev")


def test_max_order_helper():
    assert max_order(lambda k: k <= 5, first=1, cap=10) == 5
    assert max_order(lambda k: True, first=1, cap=10) == 10
    assert max_order(lambda k: False, first=1, cap=10) == 0
    assert max_order(lambda k: False, first=2, cap=10) == 1
    pair = lobatto_pair(3)
    assert max_order_b(pair.b, pair.c, cap=2) == 2
    assert max_order_c(pair.a, pair.c) == 3


# ------------------------------------------------------- hypotheses, conjugacy, stability


@pytest.mark.parametrize("s", S_TABLE)
def test_hypotheses_and_conjugacy(s):
    pair = lobatto_pair(s)
    hyp = hypotheses(pair)
    assert hyp.H1 and hyp.H2 and hyp.H3 and hyp.H1_prime and hyp.H2_prime
    assert 1.0 <= hyp.H2_condition < 1e3
    assert conjugacy_error(pair.a, pair.a_hat, pair.b) <= 1e-15


@pytest.mark.parametrize("s", S_TABLE)
def test_r_infinity_and_predicted_orders(s):
    pair = lobatto_pair(s)
    r_inf = r_infinity(pair.a)
    assert r_inf == pytest.approx((-1) ** (s - 1), abs=1e-13)
    assert r_infinity(pair.a, pair.b) == r_inf
    # the exact limit agrees with R(z) evaluated far out on the negative axis
    assert stability_function(pair.a, pair.b, -1e8) == pytest.approx(r_inf, abs=1e-5)
    report = check_tableau(pair)
    assert report.r_infinity == r_inf
    lam = s if s % 2 == 0 else s - 1
    assert (report.order_q, report.order_p, report.order_lam) == (2 * s - 2, 2 * s - 2, lam)


@pytest.mark.parametrize("s", [2, 3, 4])
def test_stability_function_approximates_exp(s):
    # IIIA has classical order 2s - 2: |R(z) - e^z| = O(z^{2s-1}).
    pair = lobatto_pair(s)
    z = np.array([0.02, -0.02, 0.02j])
    err = np.abs(stability_function(pair.a, pair.b, z) - np.exp(z))
    assert np.all(err <= 0.02 ** (2 * s - 1) + 1e-15)
    assert stability_function(pair.a, pair.b, 0.0) == 1.0
    # s = 2 is the trapezoidal rule: R(z) = (1 + z/2) / (1 - z/2)
    if s == 2:
        assert stability_function(pair.a, pair.b, -3.0) == pytest.approx(-0.5 / 2.5)


def _gauss_pair(s):
    x, w = np.polynomial.legendre.leggauss(s)
    c, b = (x + 1) / 2, w / 2
    vander = np.vander(c, increasing=True)
    rhs = np.array([[ci ** (k + 1) / (k + 1) for k in range(s)] for ci in c])
    a = np.linalg.solve(vander.T, rhs.T).T
    a_hat = b[None, :] * (1 - a.T / b[:, None])  # Gauss is self-conjugate
    return LobattoPair(s=s, c=c, b=b, a=a, a_hat=a_hat)


def test_gauss_legendre_fails_hypotheses():
    pair = _gauss_pair(3)
    report = check_tableau(pair)
    assert not report.H1 and not report.H3 and not report.H1_prime and not report.H2_prime
    assert report.conjugacy_residual < 1e-14  # conjugate, but H1-H3 fail...
    assert (report.order_q, report.order_p, report.order_lam) == (None, None, None)
    assert (report.B, report.C, report.D) == (6, 3, 3)
    # ... and R(inf) comes from the invertible-A formula: (-1)^s for Gauss.
    assert report.r_infinity == pytest.approx(-1.0, abs=1e-12)


def test_perturbed_tableau_fails():
    pair = lobatto_pair(4)
    a = np.array(pair.a)
    a[2, 1] += 1e-6
    bad = LobattoPair(s=4, c=pair.c, b=pair.b, a=a, a_hat=pair.a_hat)
    assert not satisfies_c(bad.a, bad.c, 4)
    assert not satisfies_c(bad.a, bad.c, 1)  # row sums no longer equal c
    assert c_error(bad.a, bad.c, 4) > 1e-7
    assert conjugacy_error(bad.a, bad.a_hat, bad.b) > 1e-8
    report = check_tableau(bad)
    assert report.C == 0 and report.conjugacy_residual > 1e-8
    assert report.order_q is None and report.order_lam is None
    # the good tableau passes the very same checks
    assert satisfies_c(pair.a, pair.c, 4) and check_tableau(pair).C == 4


def test_non_conjugate_pair_breaks_h1_prime():
    # IIIA paired with itself: H1-H3 hold for A, but A_hat = A is not the conjugate.
    pair = lobatto_pair(3)
    bad = LobattoPair(s=3, c=pair.c, b=pair.b, a=pair.a, a_hat=pair.a)
    hyp = hypotheses(bad)
    assert hyp.H1 and hyp.H3 and not hyp.H1_prime and not hyp.H2_prime
    assert conjugacy_error(bad.a, bad.a_hat, bad.b) > 1e-2
    assert check_tableau(bad).order_p is None


def test_r_infinity_unbounded_and_undetermined():
    # H1 but not stiffly accurate with b_1 != b_tilde A_tilde^{-1} alpha: |R(z)| -> inf.
    a = np.array([[0.0, 0.0], [0.5, 0.5]])
    assert r_infinity(a, np.array([1.0, 0.0])) == np.inf
    # singular A without H1 structure: the limit is not determined by the formula
    assert np.isnan(r_infinity(np.array([[1.0, 0.0], [1.0, 0.0]])))


# ------------------------------------------------------------------------------ report


def test_report_format_and_dict():
    report = check_tableau(lobatto_pair(3))
    assert isinstance(report, TableauReport)
    text = str(report)
    assert text == report.format()
    assert "s = 3" in text
    assert "B(4)  C(3)  D(1)" in text
    assert "CC_hat(3)  DD_hat(3)  C_hatC(1)  D_hatD(1)" in text
    assert "lambda : 2" in text
    d = report.to_dict()
    assert d["B"] == 4 and d["order_lam"] == 2 and d["H2"] is True
    assert json.loads(json.dumps(d)) == d
    assert set(d) == {
        "s", "B", "C", "D", "C_hat", "D_hat", "CC_hat", "DD_hat", "C_hatC", "D_hatD",
        "H1", "H2", "H3", "H1_prime", "H2_prime", "H2_condition", "conjugacy_residual",
        "r_infinity", "order_q", "order_p", "order_lam",
    }  # fmt: skip


def test_tolerance_is_honoured():
    assert 1e-14 < DEFAULT_TOL < 1e-12
    pair = lobatto_pair(4)
    assert max_order_b(pair.b, pair.c) == 6
    assert max_order_b(pair.b, pair.c, tol=1.0) == 4 * 4 + 2  # everything "holds": cap
    assert not satisfies_b(pair.b, pair.c, 7)
    assert satisfies_b(pair.b, pair.c, 7, tol=1.0)


# -- the table of simplifying assumptions --------------------------------------------------------------
# Each row of ``_ASSUMPTIONS`` is checked on its own, one test polynomial at a time, so that a
# wrong chain order, a wrong ``first``/degree shift or a wrong right-hand side in the table
# shows up even where the public wrappers would still look plausible.
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
