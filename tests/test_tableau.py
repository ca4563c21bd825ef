"""Tests of the Lobatto IIIA-IIIB coefficients (lobattodae._tableau)."""

from __future__ import annotations

import functools
import warnings
from fractions import Fraction
from math import sqrt

import mpmath
import numpy as np
import pytest

from lobattodae._tableau import (
    LobattoPair,
    lobatto_iiia,
    lobatto_iiib,
    lobatto_nodes,
    lobatto_pair,
    lobatto_weights,
)

S_ALL = range(2, 17)

# Achieved max |error| against the 50-digit reference for s = 2..16 (measured):
# c <= 1.0e-16, b <= 1.0e-16, A <= 3.0e-16, A_hat <= 1.1e-15. Asserted with a margin.
TOL_NODES = 2.5e-16
TOL_WEIGHTS = 2.5e-16
TOL_IIIA = 6e-16
TOL_IIIB = 2e-15


# --------------------------------------------------------------------------- literature


def test_s2_literature_values():
    pair = lobatto_pair(2)
    np.testing.assert_array_equal(pair.c, [0.0, 1.0])
    np.testing.assert_array_equal(pair.b, [0.5, 0.5])
    np.testing.assert_array_equal(pair.a, [[0.0, 0.0], [0.5, 0.5]])  # trapezoidal rule
    np.testing.assert_array_equal(pair.a_hat, [[0.5, 0.0], [0.5, 0.0]])


def test_s3_literature_values():
    pair = lobatto_pair(3)
    np.testing.assert_array_equal(pair.c, [0.0, 0.5, 1.0])
    np.testing.assert_allclose(pair.b, [1 / 6, 2 / 3, 1 / 6], rtol=0, atol=1e-16)
    a = [[0, 0, 0], [5 / 24, 1 / 3, -1 / 24], [1 / 6, 2 / 3, 1 / 6]]
    a_hat = [[1 / 6, -1 / 6, 0], [1 / 6, 1 / 3, 0], [1 / 6, 5 / 6, 0]]
    np.testing.assert_allclose(pair.a, a, rtol=0, atol=1e-15)
    np.testing.assert_allclose(pair.a_hat, a_hat, rtol=0, atol=1e-15)


def test_s4_literature_values():
    pair = lobatto_pair(4)
    r5 = sqrt(5.0)
    np.testing.assert_allclose(
        pair.c, [0, (5 - r5) / 10, (5 + r5) / 10, 1], rtol=0, atol=1e-16
    )
    np.testing.assert_allclose(pair.b, [1 / 12, 5 / 12, 5 / 12, 1 / 12], rtol=0, atol=1e-16)
    a = [
        [0, 0, 0, 0],
        [(11 + r5) / 120, (25 - r5) / 120, (25 - 13 * r5) / 120, (-1 + r5) / 120],
        [(11 - r5) / 120, (25 + 13 * r5) / 120, (25 + r5) / 120, (-1 - r5) / 120],
        [1 / 12, 5 / 12, 5 / 12, 1 / 12],
    ]
    a_hat = [
        [1 / 12, (-1 - r5) / 24, (-1 + r5) / 24, 0],
        [1 / 12, (25 + r5) / 120, (25 - 13 * r5) / 120, 0],
        [1 / 12, (25 + 13 * r5) / 120, (25 - r5) / 120, 0],
        [1 / 12, (11 - r5) / 24, (11 + r5) / 24, 0],
    ]
    np.testing.assert_allclose(pair.a, a, rtol=0, atol=1e-15)
    np.testing.assert_allclose(pair.a_hat, a_hat, rtol=0, atol=1e-15)


def test_s5_literature_nodes_and_weights():
    pair = lobatto_pair(5)
    r = sqrt(3 / 7)
    np.testing.assert_allclose(
        pair.c, [0, (1 - r) / 2, 0.5, (1 + r) / 2, 1], rtol=0, atol=1e-16
    )
    np.testing.assert_allclose(
        pair.b, [1 / 20, 49 / 180, 16 / 45, 49 / 180, 1 / 20], rtol=0, atol=1e-16
    )


# ----------------------------------------------------------- independent mpmath reference


def _legendre_coefficients(n: int) -> list[Fraction]:
    """Exact coefficients (lowest degree first) of P_n by Bonnet's recurrence."""
    p_prev, p = [Fraction(1)], [Fraction(0), Fraction(1)]
    if n == 0:
        return p_prev
    for k in range(1, n):
        x_p = [Fraction(0)] + p
        nxt = [Fraction(2 * k + 1, k + 1) * v for v in x_p]
        for i, v in enumerate(p_prev):
            nxt[i] -= Fraction(k, k + 1) * v
        p_prev, p = p, nxt
    return p


@functools.lru_cache(maxsize=None)
def _mp_reference(s: int):
    """50-digit Lobatto IIIA/IIIB: nodes by polynomial root finding of P'_{s-1}(2x - 1),
    A and b by exact integration of the Lagrange polynomials (polynomial arithmetic)."""
    with mpmath.workdps(50):
        coeffs = _legendre_coefficients(s - 1)
        deriv = [k * coeffs[k] for k in range(1, len(coeffs))]  # lowest degree first
        interior = []
        if s > 2:
            with warnings.catch_warnings():  # newer mpmath prefers asc=True; 1.3 lacks it
                warnings.simplefilter("ignore", DeprecationWarning)
                roots = mpmath.polyroots(  # coefficients highest degree first
                    [mpmath.mpf(v.numerator) / v.denominator for v in reversed(deriv)],
                    maxsteps=500,
                    extraprec=500,
                )
            interior = sorted(mpmath.re(x) for x in roots)
        x = [mpmath.mpf(-1)] + interior + [mpmath.mpf(1)]
        c = [(1 + xi) / 2 for xi in x]

        def lagrange(j):
            poly = [mpmath.mpf(1)]  # lowest degree first
            for k in range(s):
                if k != j:
                    d = c[j] - c[k]
                    new = [mpmath.mpf(0)] * (len(poly) + 1)
                    for i, v in enumerate(poly):
                        new[i + 1] += v / d
                        new[i] -= v * c[k] / d
                    poly = new
            return poly

        def integral(poly, upper):
            return sum(v * upper ** (m + 1) / (m + 1) for m, v in enumerate(poly))

        ell = [lagrange(j) for j in range(s)]
        a = [[integral(ell[j], c[i]) for j in range(s)] for i in range(s)]
        b = [integral(ell[j], mpmath.mpf(1)) for j in range(s)]
        a_hat = [[b[j] * (1 - a[j][i] / b[i]) for j in range(s)] for i in range(s)]

        def to_np(v):
            return np.array(v, dtype=object)

        return to_np(c), to_np(b), to_np(a), to_np(a_hat)


def _max_abs_error(approx: np.ndarray, exact: np.ndarray) -> float:
    with mpmath.workdps(50):
        diff = [abs(mpmath.mpf(float(x)) - y) for x, y in zip(approx.ravel(), exact.ravel())]
        return float(max(diff))


@pytest.mark.parametrize("s", S_ALL)
def test_against_mpmath_reference(s):
    c, b, a, a_hat = _mp_reference(s)
    pair = lobatto_pair(s)
    err_c = _max_abs_error(pair.c, c)
    err_b = _max_abs_error(pair.b, b)
    err_a = _max_abs_error(pair.a, a)
    err_a_hat = _max_abs_error(pair.a_hat, a_hat)
    assert err_c <= TOL_NODES, err_c
    assert err_b <= TOL_WEIGHTS, err_b
    assert err_a <= TOL_IIIA, err_a
    assert err_a_hat <= TOL_IIIB, err_a_hat
    assert max(err_c, err_b, err_a, err_a_hat) <= 5e-15


def test_reference_weights_match_closed_form():
    # The mpmath reference integrates the Lagrange basis; cross-check it against the
    # closed form b_j = 1 / (s (s-1) P_{s-1}(2 c_j - 1)^2) so the reference is trusted.
    s = 7
    c, b, _, _ = _mp_reference(s)
    with mpmath.workdps(50):
        for cj, bj in zip(c, b):
            closed = 1 / (s * (s - 1) * mpmath.legendre(s - 1, 2 * cj - 1) ** 2)
            assert abs(closed - bj) < mpmath.mpf(10) ** -40


def test_monomial_vandermonde_would_lose_accuracy():
    # Documents why IIIA is built in a well-conditioned basis: solving C(s) with the
    # monomial Vandermonde matrix leaves a perfect residual but a wrong A at s = 14.
    s = 14
    pair = lobatto_pair(s)
    _, _, a_ref, _ = _mp_reference(s)
    vander = np.vander(pair.c, increasing=True)  # vander[j, k] = c_j^k
    rhs = np.array([[ci ** (k + 1) / (k + 1) for k in range(s)] for ci in pair.c])
    a_vander = np.linalg.solve(vander.T, rhs.T).T
    assert np.max(np.abs(a_vander @ vander - rhs)) < 1e-15  # residual looks perfect
    assert _max_abs_error(a_vander, a_ref) > 1e-11  # ... yet A is off by ~3e-9
    assert _max_abs_error(pair.a, a_ref) < TOL_IIIA


# ------------------------------------------------------------------- structural facts


@pytest.mark.parametrize("s", S_ALL)
def test_structural_facts_exact(s):
    pair = lobatto_pair(s)
    c, b, a, a_hat = pair.c, pair.b, pair.a, pair.a_hat
    assert c[0] == 0.0 and c[-1] == 1.0
    assert np.all(np.diff(c) > 0)
    lower = np.arange(s // 2)  # c_{s+1-i} = 1 - c_i exactly (as computed in float64)
    np.testing.assert_array_equal(c[s - 1 - lower], 1.0 - c[lower])
    np.testing.assert_allclose(c[::-1], 1.0 - c, rtol=0, atol=1e-16)
    if s % 2 == 1:
        assert c[s // 2] == 0.5
    np.testing.assert_array_equal(b, b[::-1])
    assert np.all(b > 0)
    assert np.all(a[0] == 0.0)  # H1
    np.testing.assert_array_equal(a[-1], b)  # H3
    assert np.all(a_hat[:, -1] == 0.0)  # H1'
    assert np.all(a_hat[:, 0] == b[0])  # H2'
    assert abs(b.sum() - 1.0) <= 1e-15
    np.testing.assert_allclose(a.sum(axis=1), c, rtol=0, atol=1e-15)
    if s >= 3:  # C_hat(1) needs C_hat(s - 2) with s - 2 >= 1
        # A_hat's entries carry ~1e-15 error (b_j / b_i amplifies A's rounding); summed
        # over a row that reaches 5.2e-15 at s = 15.
        np.testing.assert_allclose(a_hat.sum(axis=1), c, rtol=0, atol=1e-14)
    else:
        # s = 2: IIIB = [[1/2, 0], [1/2, 0]] has row sums 1/2, not c = (0, 1); the
        # compatibility condition sum_j a_hat_ij = c_i of the paper fails (C_hat(0)).
        np.testing.assert_array_equal(a_hat.sum(axis=1), [0.5, 0.5])


@pytest.mark.parametrize("s", [2, 3, 4, 7, 12])
def test_building_blocks_compose(s):
    c = lobatto_nodes(s)
    b = lobatto_weights(c)
    a = lobatto_iiia(c)
    a_hat = lobatto_iiib(a, b)
    pair = lobatto_pair(s)
    for built, cached in [(c, pair.c), (b, pair.b), (a, pair.a), (a_hat, pair.a_hat)]:
        np.testing.assert_array_equal(built, cached)


# ---------------------------------------------------------------------- validation


@pytest.mark.parametrize("s", [1, 0, -3])
def test_too_few_stages_rejected(s):
    with pytest.raises(ValueError, match=r"s must be an integer >= 2.*got s=" + str(s)):
        lobatto_pair(s)


@pytest.mark.parametrize("s", [3.0, 2.5, "3", None, True, False, np.bool_(True)])
def test_non_integer_stages_rejected(s):
    with pytest.raises(TypeError, match="must be an integer >= 2"):
        lobatto_pair(s)


def test_numpy_integer_accepted():
    assert lobatto_pair(np.int64(3)) is lobatto_pair(3)
    assert type(lobatto_pair(np.int64(3)).s) is int


def test_lobatto_nodes_validates_too():
    with pytest.raises(ValueError, match="s must be an integer >= 2"):
        lobatto_nodes(1)


def test_arrays_read_only():
    pair = lobatto_pair(3)
    for name in ("c", "b", "a", "a_hat"):
        arr = getattr(pair, name)
        assert arr.dtype == np.float64
        with pytest.raises(ValueError, match="read-only"):
            arr[0] = 1.0
    with pytest.raises(AttributeError):
        pair.s = 4  # frozen dataclass


def test_constructor_copies_and_validates():
    c = np.array([0.0, 1.0])
    pair = LobattoPair(s=2, c=c, b=[0.5, 0.5], a=np.zeros((2, 2)), a_hat=np.zeros((2, 2)))
    c[0] = 7.0
    assert pair.c[0] == 0.0  # the pair holds its own copy
    with pytest.raises(ValueError, match="shape"):
        LobattoPair(s=3, c=[0, 1], b=[0.5, 0.5], a=np.zeros((2, 2)), a_hat=np.zeros((2, 2)))
    with pytest.raises(ValueError, match="non-finite"):
        LobattoPair(s=2, c=[0, np.nan], b=[0.5, 0.5], a=np.zeros((2, 2)), a_hat=np.zeros((2, 2)))
    with pytest.raises(ValueError, match="s must be an integer >= 2"):
        LobattoPair(s=1, c=[0], b=[1], a=[[0]], a_hat=[[0]])


def test_cached_eq_hash_repr():
    p3 = lobatto_pair(3)
    assert lobatto_pair(3) is p3
    assert repr(p3) == "LobattoPair(s=3)"
    copy = LobattoPair(s=3, c=p3.c, b=p3.b, a=p3.a, a_hat=p3.a_hat)
    assert copy == p3 and hash(copy) == hash(p3)
    other = np.array(p3.a)
    other[1, 1] += 1e-12
    assert LobattoPair(s=3, c=p3.c, b=p3.b, a=other, a_hat=p3.a_hat) != p3
    assert p3 != lobatto_pair(4)
    assert len({p3, copy, lobatto_pair(4)}) == 2


def test_not_a_jax_pytree():
    jax = pytest.importorskip("jax")
    pair = lobatto_pair(3)
    leaves = jax.tree_util.tree_leaves(pair)
    assert len(leaves) == 1 and leaves[0] is pair


@pytest.mark.parametrize("s", [2, 3, 4, 5, 6])
def test_stability_function_is_the_diagonal_pade_approximant(s):
    """Lobatto IIIA's R(z) is the (k, k) Padé approximant of e^z, k = s - 1:
    ``P(z) / P(-z)`` with ``P(z) = Σ_j (2k-j)! k! / ((2k)! j! (k-j)!) z^j``; so |R(iy)| = 1 and
    R(∞) = (-1)^(s-1)."""
    pair = lobatto_pair(s)
    coef = pair.pade_coefficients  # the closed form; stability() solves with the tableau
    assert coef[0] == 1.0 and coef.shape == (s,) and not coef.flags.writeable
    z = np.array([-7.0, -1.0, -0.1, 0.3 + 2j, 5j])
    pade = np.polyval(coef[::-1], z) / np.polyval(coef[::-1], -z)
    np.testing.assert_allclose(pair.stability(z), pade, rtol=1e-12)
    np.testing.assert_allclose(np.abs(pair.stability(1j * np.linspace(0.1, 50, 30))), 1.0, rtol=1e-12)
    assert abs(pair.stability(np.array([-1e9]))[0] - pair.r_infinity) < 1e-6


@pytest.mark.parametrize("s", [2, 3, 4, 5, 6])
def test_constraint_stability_is_the_s_s_minus_2_pade_approximant(s):
    """``R_c = N / D`` of degrees (s, s − 2) matches e^z to order 2s − 2: ``D(z) e^z − N(z)`` has no
    terms of degree ≤ 2s − 2 (the coefficients of D times those of e^z, against N's); s = 2 is
    the Taylor polynomial 1 + z + z²/2; R_c is unbounded (|R_c| > 1 at the stability limit)."""
    from math import factorial

    pair = lobatto_pair(s)
    num, den = pair.constraint_pade
    assert num.shape == (s + 1,) and den.shape == (s - 1,) and num[0] == den[0] == 1.0
    assert not num.flags.writeable and not den.flags.writeable
    series = np.array([1.0 / factorial(j) for j in range(2 * s - 1)])
    product = np.convolve(den, series)[: 2 * s - 1]
    np.testing.assert_allclose(product, np.concatenate([num, np.zeros(s - 2)]), rtol=1e-13, atol=1e-15)
    if s == 2:
        np.testing.assert_allclose(num, [1.0, 1.0, 0.5])
    limit = {2: 2.0, 3: 5.42, 4: 9.65, 5: 14.73, 6: 20.6}[s]  # docs/variable-steps.md §2, measured on the sleigh
    assert abs(pair.constraint_stability(-0.98 * limit)) < 1 < abs(pair.constraint_stability(-1.02 * limit))


@pytest.mark.parametrize("s", [2, 3, 4, 5, 6, 8])
def test_richardson_radius_bounds_where_the_asymptotic_ratio_holds(s):
    """Inside the radius the whole step's and the half steps' errors relate as 2^(2s-2) for damped
    and oscillating linear modes alike (within a factor two); just outside it they do not."""
    pair = lobatto_pair(s)
    r = pair.richardson_radius
    d0 = 2.0 ** (2 * s - 2) - 1.0

    def ratio(z):
        half = pair.stability(z / 2) ** 2
        return np.abs((half - pair.stability(z)) / (half - np.exp(z)))

    assert 2.0 < r < 10.0
    inside = np.linspace(0.6, 0.99, 12) * r
    for direction in (-1.0, 1j):
        d = ratio(direction * inside)
        above_noise = np.abs(pair.stability(direction * inside / 2) ** 2 - np.exp(direction * inside)) > 1e-9
        assert np.all((d[above_noise] > 0.5 * d0) & (d[above_noise] < 2.0 * d0))
    outside = min(ratio(-1.02 * r), ratio(1.02j * r))
    assert outside < 0.55 * d0 or max(ratio(-1.02 * r), ratio(1.02j * r)) > 1.9 * d0
    assert lobatto_pair(s + 1).richardson_radius > r  # higher order resolves more
