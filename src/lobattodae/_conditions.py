"""Order conditions, hypotheses and stability of a partitioned Runge-Kutta tableau.

Diagnostics at three levels (paper, section 2):

* ``*_error(..., k)``: the raw residual, the largest absolute deviation over every index
  the assumption ``X(k)`` requires;
* ``satisfies_*(..., k, tol)``: yes/no, ``*_error(..., basis="legendre") <= tol``;
* ``max_order_*(...)``: the largest ``k`` for which ``X(k)`` holds.

The simplifying assumptions, for a method ``(A, b, c)`` (and ``A_hat`` with
``b_hat = b``, ``c_hat = c`` for the pair assumptions):

* ``B(p)``: ``sum_i b_i c_i^{k-1} = 1/k``, ``k = 1..p``;
* ``C(q)``: ``sum_j a_ij c_j^{k-1} = c_i^k / k``, ``i = 1..s``, ``k = 1..q``;
* ``D(r)``: ``sum_i b_i c_i^{k-1} a_ij = b_j (1 - c_j^k) / k``, ``j = 1..s``, ``k = 1..r``;
* ``CC_hat(Q)``: ``sum_{j,l} a_ij a_hat_jl c_l^{k-2} = c_i^k / (k (k-1))``,
  ``i = 1..s``, ``k = 2..Q``;
* ``DD_hat(R)``: ``sum_{i,j} b_i c_i^{k-2} a_ij a_hat_jl
  = b_l [(k-1) - (k c_l - c_l^k)] / (k (k-1))``, ``l = 1..s``, ``k = 2..R``;
* ``C_hatC(Q_hat)`` and ``D_hatD(R_hat)``: the same with ``A`` and ``A_hat`` swapped.

``C_hat`` and ``D_hat`` are ``C`` and ``D`` applied to ``A_hat``.

The ``*_error`` functions evaluate these equations literally by default
(``basis="monomial"``). With ``basis="legendre"`` the test polynomials ``c^{m-1}``
(``c^{m-2}``) are replaced by shifted Legendre polynomials of the same degree and the
right-hand sides by the corresponding integrals. The two forms are equivalent (same
polynomial spaces), but in the monomial form the residual of the first violated
assumption shrinks like ``c^k`` and drowns in rounding error for ``s >= 12``; the
``satisfies_*`` and ``max_order_*`` decisions therefore use the Legendre form.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any, Callable

import numpy as np
from numpy.polynomial import Legendre, Polynomial

__all__ = [
    "DEFAULT_TOL",
    "H2_CONDITION_LIMIT",
    "Hypotheses",
    "TableauReport",
    "b_error",
    "c_error",
    "c_hat_c_error",
    "cc_hat_error",
    "check_tableau",
    "conjugacy_error",
    "d_error",
    "d_hat_d_error",
    "dd_hat_error",
    "hypotheses",
    "max_order",
    "max_order_b",
    "max_order_c",
    "max_order_c_hat_c",
    "max_order_cc_hat",
    "max_order_d",
    "max_order_d_hat_d",
    "max_order_dd_hat",
    "r_infinity",
    "satisfies_b",
    "satisfies_c",
    "satisfies_c_hat_c",
    "satisfies_cc_hat",
    "satisfies_d",
    "satisfies_d_hat_d",
    "satisfies_dd_hat",
    "stability_function",
]

#: Residual (shifted Legendre form) below which a simplifying assumption counts as
#: satisfied. For the Lobatto tableau with s <= 20, satisfied assumptions leave residuals
#: below 6e-15 and the first violated ones more than 1e-6 (more than 1e-4 for s <= 8).
DEFAULT_TOL = 1e3 * np.finfo(np.float64).eps

#: A_tilde = (a_ij)_{i,j>=2} counts as invertible (H2) when its 2-norm condition number is below
#: this limit.
H2_CONDITION_LIMIT = 1e12


def _arrays(*xs: Any) -> list[np.ndarray]:
    return [np.asarray(x, dtype=np.float64) for x in xs]


def _basis_poly(basis: str, n: int) -> Any:
    """Degree-``n`` test polynomial: ``t^n`` (paper) or ``P_n(2t - 1)`` (shifted Legendre).

    Both families span the same spaces, so every assumption ``X(k)`` is equivalent in
    either basis; the shifted Legendre polynomials are bounded by 1 on ``[0, 1]`` and keep
    the residual of the first violated ``k`` of order ``1/s`` instead of letting it drown
    in rounding error (``c^k`` is tiny for large ``k``).
    """
    if basis == "monomial":
        return Polynomial.basis(n)
    if basis == "legendre":
        return Legendre.basis(n, domain=[0.0, 1.0])
    raise ValueError(f"basis must be 'monomial' or 'legendre'; got {basis!r}.")


def _residual_b(b, c, phi):
    """``sum_i b_i phi(c_i) - int_0^1 phi``."""
    big_phi = phi.integ(lbnd=0.0)
    return np.atleast_1d(b @ phi(c) - big_phi(1.0))


def _residual_c(a, c, phi):
    """``sum_j a_ij phi(c_j) - int_0^{c_i} phi`` (C: phi = t^{m-1} gives c_i^m / m)."""
    return a @ phi(c) - phi.integ(lbnd=0.0)(c)


def _residual_d(a, b, c, phi):
    """``sum_i b_i phi(c_i) a_ij - b_j int_{c_j}^1 phi`` (D: b_j (1 - c_j^m) / m)."""
    big_phi = phi.integ(lbnd=0.0)
    return (b * phi(c)) @ a - b * (big_phi(1.0) - big_phi(c))


def _residual_pair_c(first, second, c, phi):
    """``sum_{j,l} first_ij second_jl phi(c_l) - int_0^{c_i} int_0^t phi``.

    With ``phi = t^{m-2}`` the double integral is ``c_i^m / (m (m-1))``.
    """
    return first @ (second @ phi(c)) - phi.integ(2, lbnd=0.0)(c)


def _residual_pair_d(first, second, b, c, phi):
    """``sum_{i,j} b_i phi(c_i) first_ij second_jl - b_l int_{c_l}^1 int_tau^1 phi``.

    With ``phi = t^{m-2}`` the double integral is ``[(m-1) - (m c_l - c_l^m)] / (m (m-1))``.
    """
    big_phi = phi.integ(lbnd=0.0)
    tail = big_phi(1.0) - big_phi  # tau -> int_tau^1 phi
    big_tail = tail.integ(lbnd=0.0)
    return ((b * phi(c)) @ first) @ second - b * (big_tail(1.0) - big_tail(c))


def _max_residual(residual: Callable[[Any], np.ndarray], first: int, k: int, shift: int,
                  basis: str) -> float:
    """``max_{m = first..k} max |residual(basis polynomial of degree m - shift)|``."""
    worst = 0.0
    for m in range(first, k + 1):
        res = residual(_basis_poly(basis, m - shift))
        worst = max(worst, float(np.max(np.abs(res))))
    return worst


# ----------------------------------------------------------------------------- residuals


def b_error(b: Any, c: Any, k: int, *, basis: str = "monomial") -> float:
    """Residual of ``B(k)``: ``max_{m=1..k} |sum_i b_i c_i^{m-1} - 1/m|``.

    Parameters
    ----------
    b, c : array_like, shape (s,)
        Weights and nodes.
    k : int
        Order of the assumption; ``k < 1`` is vacuous (residual 0).
    basis : {"monomial", "legendre"}, optional
        ``"monomial"`` (default) evaluates the paper's equations literally. ``"legendre"``
        replaces ``c^{m-1}`` by the shifted Legendre polynomial ``P_{m-1}(2c - 1)`` and
        ``1/m`` by its integral over ``[0, 1]``: an equivalent, better scaled form (used
        by :func:`satisfies_b` and :func:`max_order_b`).

    Returns
    -------
    float
        The largest absolute residual.
    """
    b, c = _arrays(b, c)
    return _max_residual(lambda phi: _residual_b(b, c, phi), 1, k, 1, basis)


def c_error(a: Any, c: Any, k: int, *, basis: str = "monomial") -> float:
    """Residual of ``C(k)``: ``max_{i, m=1..k} |sum_j a_ij c_j^{m-1} - c_i^m / m|``.

    Apply it to ``A_hat`` for ``C_hat(k)``.

    Parameters
    ----------
    a : array_like, shape (s, s)
        Coefficient matrix.
    c : array_like, shape (s,)
        Nodes.
    k : int
        Order of the assumption; ``k < 1`` is vacuous (residual 0).
    basis : {"monomial", "legendre"}, optional
        Test polynomials ``c^{m-1}`` (the paper's form, default) or ``P_{m-1}(2c - 1)``
        with right-hand side ``int_0^{c_i} P_{m-1}(2t - 1) dt`` (equivalent, better
        scaled); see :func:`b_error`.

    Returns
    -------
    float
        The largest absolute residual.
    """
    a, c = _arrays(a, c)
    return _max_residual(lambda phi: _residual_c(a, c, phi), 1, k, 1, basis)


def d_error(a: Any, b: Any, c: Any, k: int, *, basis: str = "monomial") -> float:
    """Residual of ``D(k)``: ``max_{j, m=1..k} |sum_i b_i c_i^{m-1} a_ij - b_j (1 - c_j^m) / m|``.

    Apply it to ``A_hat`` (with ``b_hat = b``) for ``D_hat(k)``.

    Parameters
    ----------
    a : array_like, shape (s, s)
        Coefficient matrix.
    b, c : array_like, shape (s,)
        Weights and nodes.
    k : int
        Order of the assumption; ``k < 1`` is vacuous (residual 0).
    basis : {"monomial", "legendre"}, optional
        Test polynomials ``c^{m-1}`` (the paper's form, default) or ``P_{m-1}(2c - 1)``
        with right-hand side ``b_j int_{c_j}^1 P_{m-1}(2t - 1) dt``; see :func:`b_error`.

    Returns
    -------
    float
        The largest absolute residual.
    """
    a, b, c = _arrays(a, b, c)
    return _max_residual(lambda phi: _residual_d(a, b, c, phi), 1, k, 1, basis)


def cc_hat_error(a: Any, a_hat: Any, c: Any, k: int, *, basis: str = "monomial") -> float:
    """Residual of ``CC_hat(k)``: ``sum_{j,l} a_ij a_hat_jl c_l^{m-2} = c_i^m / (m (m-1))``.

    Maximum over ``i = 1..s`` and ``m = 2..k``.

    Parameters
    ----------
    a, a_hat : array_like, shape (s, s)
        ``A`` and ``A_hat``.
    c : array_like, shape (s,)
        Nodes.
    k : int
        Order of the assumption; ``k < 2`` is vacuous (residual 0).
    basis : {"monomial", "legendre"}, optional
        Test polynomials ``c^{m-2}`` (the paper's form, default) or ``P_{m-2}(2c - 1)``
        with right-hand side ``int_0^{c_i} int_0^t P_{m-2}(2u - 1) du dt``; see
        :func:`b_error`.

    Returns
    -------
    float
        The largest absolute residual.
    """
    a, a_hat, c = _arrays(a, a_hat, c)
    return _max_residual(lambda phi: _residual_pair_c(a, a_hat, c, phi), 2, k, 2, basis)


def c_hat_c_error(a: Any, a_hat: Any, c: Any, k: int, *, basis: str = "monomial") -> float:
    """Residual of ``C_hatC(k)``: ``sum_{j,l} a_hat_ij a_jl c_l^{m-2} = c_i^m / (m (m-1))``.

    Maximum over ``i = 1..s`` and ``m = 2..k``.

    Parameters
    ----------
    a, a_hat : array_like, shape (s, s)
        ``A`` and ``A_hat``.
    c : array_like, shape (s,)
        Nodes.
    k : int
        Order of the assumption; ``k < 2`` is vacuous (residual 0).
    basis : {"monomial", "legendre"}, optional
        See :func:`cc_hat_error`.

    Returns
    -------
    float
        The largest absolute residual.
    """
    a, a_hat, c = _arrays(a, a_hat, c)
    return _max_residual(lambda phi: _residual_pair_c(a_hat, a, c, phi), 2, k, 2, basis)


def dd_hat_error(
    a: Any, a_hat: Any, b: Any, c: Any, k: int, *, basis: str = "monomial"
) -> float:
    """Residual of ``DD_hat(k)``.

    ``sum_{i,j} b_i c_i^{m-2} a_ij a_hat_jl = b_l [(m-1) - (m c_l - c_l^m)] / (m (m-1))``,
    maximum over ``l = 1..s`` and ``m = 2..k``.

    Parameters
    ----------
    a, a_hat : array_like, shape (s, s)
        ``A`` and ``A_hat``.
    b, c : array_like, shape (s,)
        Weights and nodes.
    k : int
        Order of the assumption; ``k < 2`` is vacuous (residual 0).
    basis : {"monomial", "legendre"}, optional
        Test polynomials ``c^{m-2}`` (the paper's form, default) or ``P_{m-2}(2c - 1)``
        with right-hand side ``b_l int_{c_l}^1 int_tau^1 P_{m-2}(2u - 1) du dtau`` (for
        ``c^{m-2}`` this double integral is ``[(m-1) - (m c_l - c_l^m)] / (m (m-1))``);
        see :func:`b_error`.

    Returns
    -------
    float
        The largest absolute residual.
    """
    a, a_hat, b, c = _arrays(a, a_hat, b, c)
    return _max_residual(
        lambda phi: _residual_pair_d(a, a_hat, b, c, phi), 2, k, 2, basis
    )


def d_hat_d_error(
    a: Any, a_hat: Any, b: Any, c: Any, k: int, *, basis: str = "monomial"
) -> float:
    """Residual of ``D_hatD(k)``.

    ``sum_{i,j} b_hat_i c_i^{m-2} a_hat_ij a_jl
    = b_hat_l [(m-1) - (m c_l - c_l^m)] / (m (m-1))`` with ``b_hat = b``, maximum over
    ``l = 1..s`` and ``m = 2..k``.

    Parameters
    ----------
    a, a_hat : array_like, shape (s, s)
        ``A`` and ``A_hat``.
    b, c : array_like, shape (s,)
        Weights (``b_hat = b``) and nodes.
    k : int
        Order of the assumption; ``k < 2`` is vacuous (residual 0).
    basis : {"monomial", "legendre"}, optional
        See :func:`dd_hat_error`.

    Returns
    -------
    float
        The largest absolute residual.
    """
    a, a_hat, b, c = _arrays(a, a_hat, b, c)
    return _max_residual(
        lambda phi: _residual_pair_d(a_hat, a, b, c, phi), 2, k, 2, basis
    )


# ------------------------------------------------------------------------------ yes / no
#
# The decisions use the shifted Legendre form of the residuals: equivalent to the paper's
# monomial form, but the residual of a violated condition stays O(1/s) for every s, while
# in the monomial form it falls below any sensible tolerance for s >= 12 (B(2s - 1) has a
# monomial residual ~1e-13 at s = 12).

_DECISION_BASIS = "legendre"


def satisfies_b(b: Any, c: Any, k: int, tol: float = DEFAULT_TOL) -> bool:
    """Whether ``B(k)`` holds: ``b_error(b, c, k, basis="legendre") <= tol``."""
    return b_error(b, c, k, basis=_DECISION_BASIS) <= tol


def satisfies_c(a: Any, c: Any, k: int, tol: float = DEFAULT_TOL) -> bool:
    """Whether ``C(k)`` holds: ``c_error(a, c, k, basis="legendre") <= tol``."""
    return c_error(a, c, k, basis=_DECISION_BASIS) <= tol


def satisfies_d(a: Any, b: Any, c: Any, k: int, tol: float = DEFAULT_TOL) -> bool:
    """Whether ``D(k)`` holds: ``d_error(a, b, c, k, basis="legendre") <= tol``."""
    return d_error(a, b, c, k, basis=_DECISION_BASIS) <= tol


def satisfies_cc_hat(a: Any, a_hat: Any, c: Any, k: int, tol: float = DEFAULT_TOL) -> bool:
    """Whether ``CC_hat(k)`` holds: ``cc_hat_error(..., basis="legendre") <= tol``."""
    return cc_hat_error(a, a_hat, c, k, basis=_DECISION_BASIS) <= tol


def satisfies_c_hat_c(a: Any, a_hat: Any, c: Any, k: int, tol: float = DEFAULT_TOL) -> bool:
    """Whether ``C_hatC(k)`` holds: ``c_hat_c_error(..., basis="legendre") <= tol``."""
    return c_hat_c_error(a, a_hat, c, k, basis=_DECISION_BASIS) <= tol


def satisfies_dd_hat(
    a: Any, a_hat: Any, b: Any, c: Any, k: int, tol: float = DEFAULT_TOL
) -> bool:
    """Whether ``DD_hat(k)`` holds: ``dd_hat_error(..., basis="legendre") <= tol``."""
    return dd_hat_error(a, a_hat, b, c, k, basis=_DECISION_BASIS) <= tol


def satisfies_d_hat_d(
    a: Any, a_hat: Any, b: Any, c: Any, k: int, tol: float = DEFAULT_TOL
) -> bool:
    """Whether ``D_hatD(k)`` holds: ``d_hat_d_error(..., basis="legendre") <= tol``."""
    return d_hat_d_error(a, a_hat, b, c, k, basis=_DECISION_BASIS) <= tol


# ---------------------------------------------------------------------------- max orders


def max_order(
    holds: Callable[[int], bool], *, first: int = 1, cap: int
) -> int:
    """Largest ``k <= cap`` such that ``holds(k)``, scanning upward from ``first``.

    ``X(k)`` includes every index up to ``k``, so the scan stops at the first failure.

    Parameters
    ----------
    holds : callable
        ``k -> bool``, whether ``X(k)`` holds (e.g.
        ``lambda k: satisfies_b(b, c, k)``).
    first : int, optional
        First nontrivial index of the assumption: 1 for ``B, C, D``; 2 for the pair
        assumptions ``CC_hat, DD_hat, C_hatC, D_hatD``.
    cap : int
        Largest ``k`` examined (the result is ``cap`` if every ``k`` up to it holds).

    Returns
    -------
    int
        The largest ``k`` with ``X(k)``; ``first - 1`` if even ``X(first)`` fails
        (0 for ``B, C, D``; 1 for the pair assumptions, meaning that no nontrivial ``k``
        holds, ``X(1)`` being vacuous).
    """
    k = first - 1
    while k < cap and holds(k + 1):
        k += 1
    return k


def _default_cap(c: Any) -> int:
    return 4 * np.asarray(c).shape[0] + 2


def max_order_b(b: Any, c: Any, *, cap: int | None = None, tol: float = DEFAULT_TOL) -> int:
    """Largest ``p`` with ``B(p)`` (0 if ``B(1)`` fails); ``cap`` defaults to ``4s + 2``."""
    cap = _default_cap(c) if cap is None else cap
    return max_order(lambda k: satisfies_b(b, c, k, tol), first=1, cap=cap)


def max_order_c(a: Any, c: Any, *, cap: int | None = None, tol: float = DEFAULT_TOL) -> int:
    """Largest ``q`` with ``C(q)`` (0 if ``C(1)`` fails); pass ``A_hat`` for ``C_hat``."""
    cap = _default_cap(c) if cap is None else cap
    return max_order(lambda k: satisfies_c(a, c, k, tol), first=1, cap=cap)


def max_order_d(
    a: Any, b: Any, c: Any, *, cap: int | None = None, tol: float = DEFAULT_TOL
) -> int:
    """Largest ``r`` with ``D(r)`` (0 if ``D(1)`` fails); pass ``A_hat`` for ``D_hat``."""
    cap = _default_cap(c) if cap is None else cap
    return max_order(lambda k: satisfies_d(a, b, c, k, tol), first=1, cap=cap)


def max_order_cc_hat(
    a: Any, a_hat: Any, c: Any, *, cap: int | None = None, tol: float = DEFAULT_TOL
) -> int:
    """Largest ``Q`` with ``CC_hat(Q)``; 1 means that ``CC_hat(2)`` already fails."""
    cap = _default_cap(c) if cap is None else cap
    return max_order(lambda k: satisfies_cc_hat(a, a_hat, c, k, tol), first=2, cap=cap)


def max_order_c_hat_c(
    a: Any, a_hat: Any, c: Any, *, cap: int | None = None, tol: float = DEFAULT_TOL
) -> int:
    """Largest ``Q_hat`` with ``C_hatC(Q_hat)``; 1 means that ``C_hatC(2)`` already fails."""
    cap = _default_cap(c) if cap is None else cap
    return max_order(lambda k: satisfies_c_hat_c(a, a_hat, c, k, tol), first=2, cap=cap)


def max_order_dd_hat(
    a: Any, a_hat: Any, b: Any, c: Any, *, cap: int | None = None, tol: float = DEFAULT_TOL
) -> int:
    """Largest ``R`` with ``DD_hat(R)``; 1 means that ``DD_hat(2)`` already fails."""
    cap = _default_cap(c) if cap is None else cap
    return max_order(lambda k: satisfies_dd_hat(a, a_hat, b, c, k, tol), first=2, cap=cap)


def max_order_d_hat_d(
    a: Any, a_hat: Any, b: Any, c: Any, *, cap: int | None = None, tol: float = DEFAULT_TOL
) -> int:
    """Largest ``R_hat`` with ``D_hatD(R_hat)``; 1 means that ``D_hatD(2)`` already fails."""
    cap = _default_cap(c) if cap is None else cap
    return max_order(
        lambda k: satisfies_d_hat_d(a, a_hat, b, c, k, tol), first=2, cap=cap
    )


# ------------------------------------------------------------- conjugacy and hypotheses


def conjugacy_error(a: Any, a_hat: Any, b: Any) -> float:
    """Residual of symplectic conjugacy: ``max_{i,j} |b_i a_hat_ij + b_j a_ji - b_i b_j|``.

    (With ``b_hat = b``.) Zero for the Lobatto IIIA-IIIB pair.

    Parameters
    ----------
    a, a_hat : array_like, shape (s, s)
        ``A`` and ``A_hat``.
    b : array_like, shape (s,)
        Shared weights.

    Returns
    -------
    float
        The largest absolute residual.
    """
    a, a_hat, b = _arrays(a, a_hat, b)
    res = b[:, None] * a_hat + b[None, :] * a.T - np.outer(b, b)
    return float(np.max(np.abs(res)))


@dataclass(frozen=True)
class Hypotheses:
    """Hypotheses H1-H3 on ``A`` and their consequences H1', H2' on ``A_hat``.

    Attributes
    ----------
    H1 : bool
        ``a_1j = 0`` for all ``j``.
    H2 : bool
        ``A_tilde = (a_ij)_{i,j >= 2}`` is invertible (condition number below
        :data:`H2_CONDITION_LIMIT`).
    H3 : bool
        ``a_sj = b_j`` for all ``j`` (stiffly accurate).
    H1_prime : bool
        ``a_hat_is = 0`` for all ``i``.
    H2_prime : bool
        ``a_hat_i1 = b_hat_1 = b_1`` for all ``i``.
    H2_condition : float
        2-norm condition number of ``A_tilde`` (``inf`` if singular).
    """

    H1: bool
    H2: bool
    H3: bool
    H1_prime: bool
    H2_prime: bool
    H2_condition: float


def _condition(m: np.ndarray) -> float:
    """2-norm condition number, ``inf`` for a singular (or non-finite) matrix."""
    with np.errstate(all="ignore"):
        cond = float(np.linalg.cond(m))
    return cond if np.isfinite(cond) else float("inf")


def _h2_condition(a: np.ndarray) -> float:
    """Condition number of ``A_tilde = (a_ij)_{i,j >= 2}``."""
    return _condition(a[1:, 1:])


def hypotheses(pair: Any, tol: float = 0.0) -> Hypotheses:
    """Check H1, H2, H3 (for ``A``) and H1', H2' (for ``A_hat``).

    Parameters
    ----------
    pair : LobattoPair or any object with attributes ``a``, ``a_hat``, ``b``
        The tableau pair.
    tol : float, optional
        Tolerance of the structural checks H1, H3, H1', H2'. The default 0 demands exact
        equality, which the Lobatto tableau provides (its structural entries are set
        exactly).

    Returns
    -------
    Hypotheses
        The five booleans and the condition number of ``A_tilde``.
    """
    a, a_hat, b = _arrays(pair.a, pair.a_hat, pair.b)
    cond = _h2_condition(a)
    return Hypotheses(
        H1=bool(np.all(np.abs(a[0]) <= tol)),
        H2=bool(cond < H2_CONDITION_LIMIT),
        H3=bool(np.all(np.abs(a[-1] - b) <= tol)),
        H1_prime=bool(np.all(np.abs(a_hat[:, -1]) <= tol)),
        H2_prime=bool(np.all(np.abs(a_hat[:, 0] - b[0]) <= tol)),
        H2_condition=cond,
    )


# ------------------------------------------------------------------------------ stability


def stability_function(a: Any, b: Any, z: Any) -> Any:
    """Stability function ``R(z) = 1 + z b^T (I - z A)^{-1} 1``.

    ``y_1 = R(h lambda) y_0`` for one step on ``y' = lambda y``.

    Parameters
    ----------
    a : array_like, shape (s, s)
        Coefficient matrix.
    b : array_like, shape (s,)
        Weights.
    z : complex or array_like
        Argument(s) ``h lambda``.

    Returns
    -------
    complex, float or ndarray
        ``R(z)``, with the shape of ``z`` (real if ``z`` is real).
    """
    a, b = _arrays(a, b)
    z = np.asarray(z)
    s = b.shape[0]
    zf = z.reshape(-1)
    dtype = np.result_type(zf.dtype, np.float64)
    out = np.empty(zf.shape, dtype=dtype)
    eye, ones = np.eye(s), np.ones(s)
    for n, zn in enumerate(zf):
        out[n] = 1.0 + zn * (b @ np.linalg.solve(eye - zn * a, ones))
    out = out.reshape(z.shape)
    return out[()] if out.ndim == 0 else out


def r_infinity(a: Any, b: Any = None, tol: float = 1e-10) -> float:
    """``R(infinity) = lim_{z -> infinity} R(z)``, computed exactly (no large-``z`` guess).

    With ``b`` omitted the method is taken to be stiffly accurate, ``b^T = e_s^T A`` (H3),
    so that ``R(z) = e_s^T (I - z A)^{-1} 1``.

    * ``A`` invertible: ``R(infinity) = 1 - b^T A^{-1} 1``.
    * ``A`` with zero first row (H1), ``A = [[0, 0], [alpha, A_tilde]]`` with ``A_tilde``
      invertible (H2): the first stage is ``Y_1 = y_0``, the others solve
      ``(I - z A_tilde) Y_tilde = 1 + z alpha``, i.e.
      ``Y_tilde = -A_tilde^{-1} alpha - z^{-1} A_tilde^{-1} (1 + A_tilde^{-1} alpha) + O(z^{-2})``,
      so ``R(z) = z (b_1 - b_tilde^T A_tilde^{-1} alpha)
      + 1 - b_tilde^T A_tilde^{-1} (1 + A_tilde^{-1} alpha) + O(1/z)``. The limit is finite
      iff the bracket multiplying ``z`` vanishes (it does under H3, where
      ``b_tilde^T = e_{s-1}^T A_tilde`` and ``b_1 = alpha_{s-1}``), and then
      ``R(infinity) = 1 - b_tilde^T A_tilde^{-1} (1 + A_tilde^{-1} alpha)``, which under H3
      is ``-e_{s-1}^T A_tilde^{-1} alpha``. For Lobatto IIIA it is ``(-1)^(s-1)``.

    Parameters
    ----------
    a : array_like, shape (s, s)
        Coefficient matrix.
    b : array_like, shape (s,), optional
        Weights; the last row of ``a`` if omitted.
    tol : float, optional
        Relative size below which the coefficient of ``z`` counts as zero.

    Returns
    -------
    float
        ``R(infinity)``; ``inf`` if ``|R(z)| -> infinity``; ``nan`` if ``A`` is singular
        without H1-H2 structure (the limit is not determined by this formula).
    """
    a = np.asarray(a, dtype=np.float64)
    b = a[-1].copy() if b is None else np.asarray(b, dtype=np.float64)
    s = b.shape[0]
    if _condition(a) < H2_CONDITION_LIMIT:  # A invertible
        return float(1.0 - b @ np.linalg.solve(a, np.ones(s)))
    if not np.all(a[0] == 0.0) or _h2_condition(a) >= H2_CONDITION_LIMIT:
        return float("nan")
    a_tilde, alpha = a[1:, 1:], a[1:, 0]
    b_tilde = b[1:]
    y0 = np.linalg.solve(a_tilde, alpha)  # A_tilde^{-1} alpha
    linear = b[0] - b_tilde @ y0
    if abs(linear) > tol * max(1.0, float(np.max(np.abs(b)))):
        return float("inf")
    return float(1.0 - b_tilde @ np.linalg.solve(a_tilde, 1.0 + y0))


# ---------------------------------------------------------------------------------- report


def _predicted_orders(
    p: int, q: int, r: int, r_inf: float, applicable: bool, tol: float
) -> tuple[int | None, int | None, int | None]:
    """Global orders from the paper's convergence theorem (None where it does not apply)."""
    if not applicable:
        return None, None, None
    order_q = min(p, q + r + 1)
    order_p = min(p, 2 * q, q + r)
    if not np.isfinite(r_inf) or abs(r_inf) > 1.0 + tol:
        order_lam = None
    elif abs(r_inf - 1.0) <= tol:
        order_lam = q - 1
    else:
        order_lam = q
    return order_q, order_p, order_lam


@dataclass(frozen=True)
class TableauReport:
    """Everything :func:`check_tableau` verifies about a IIIA-IIIB-type pair.

    Attributes
    ----------
    s : int
        Number of stages.
    B, C, D : int
        Largest ``p, q, r`` with ``B(p), C(q), D(r)`` for ``A`` (0: not even order 1).
    C_hat, D_hat : int
        Largest ``q_hat, r_hat`` with ``C_hat(q_hat), D_hat(r_hat)`` for ``A_hat``.
    CC_hat, DD_hat, C_hatC, D_hatD : int
        Largest ``Q, R, Q_hat, R_hat`` of the pair assumptions; these start at ``k = 2``,
        and 1 means that no nontrivial ``k`` holds.
    H1, H2, H3, H1_prime, H2_prime : bool
        The hypotheses (see :class:`Hypotheses`).
    H2_condition : float
        Condition number of ``A_tilde = (a_ij)_{i,j >= 2}``.
    conjugacy_residual : float
        ``max |b_i a_hat_ij + b_j a_ji - b_i b_j|``.
    r_infinity : float
        ``R_A(infinity)`` of the stability function of ``A``.
    order_q, order_p, order_lam : int or None
        Predicted global orders ``min(p, q + r + 1)``, ``min(p, 2q, q + r)`` and ``q``
        (``-1 <= R(infinity) < 1``) or ``q - 1`` (``R(infinity) = 1``), with
        ``p, q, r = B, C, D``. None where the theorem does not apply (H1-H3 or
        conjugacy violated, or ``|R(infinity)| > 1``).
    """

    s: int
    B: int
    C: int
    D: int
    C_hat: int
    D_hat: int
    CC_hat: int
    DD_hat: int
    C_hatC: int
    D_hatD: int
    H1: bool
    H2: bool
    H3: bool
    H1_prime: bool
    H2_prime: bool
    H2_condition: float
    conjugacy_residual: float
    r_infinity: float
    order_q: int | None
    order_p: int | None
    order_lam: int | None

    def to_dict(self) -> dict[str, Any]:
        """The report as a plain dict (JSON-serialisable)."""
        return asdict(self)

    def format(self) -> str:
        """A readable multi-line table."""

        def yn(flag: bool) -> str:
            return "yes" if flag else "NO"

        def order(k: int | None) -> str:
            return "n/a" if k is None else str(k)

        s = self.s
        rows = [
            f"Lobatto IIIA-IIIB tableau check, s = {s}",
            "",
            "Simplifying assumptions (largest k that holds)",
            f"  A      : B({self.B})  C({self.C})  D({self.D})",
            f"  A_hat  : C_hat({self.C_hat})  D_hat({self.D_hat})",
            f"  pair   : CC_hat({self.CC_hat})  DD_hat({self.DD_hat})"
            f"  C_hatC({self.C_hatC})  D_hatD({self.D_hatD})"
            "   (pair conditions start at k=2; 1 = none)",
            "",
            "Hypotheses",
            f"  H1  a_1j = 0               : {yn(self.H1)}",
            f"  H2  A_tilde invertible     : {yn(self.H2)}"
            f"   (cond = {self.H2_condition:.3e})",
            f"  H3  a_sj = b_j             : {yn(self.H3)}",
            f"  H1' a_hat_is = 0           : {yn(self.H1_prime)}",
            f"  H2' a_hat_i1 = b_1         : {yn(self.H2_prime)}",
            f"  symplectic conjugacy resid.: {self.conjugacy_residual:.3e}",
            f"  R(infinity)                : {self.r_infinity:+.15g}",
            "",
            "Predicted global orders (p = B, q = C, r = D)",
            f"  q      : {order(self.order_q)}",
            f"  p      : {order(self.order_p)}",
            f"  lambda : {order(self.order_lam)}",
        ]
        return "\n".join(rows)

    def __str__(self) -> str:
        return self.format()


def check_tableau(pair: Any, tol: float = DEFAULT_TOL) -> TableauReport:
    """Verify the simplifying assumptions, hypotheses and stability of a pair.

    Parameters
    ----------
    pair : LobattoPair or any object with attributes ``s``, ``c``, ``b``, ``a``, ``a_hat``
        The partitioned tableau (``b_hat = b``, ``c_hat = c``).
    tol : float, optional
        Residual threshold for the simplifying assumptions and for deciding
        ``R(infinity) = 1`` and conjugacy.

    Returns
    -------
    TableauReport
        For Lobatto: ``B = 2s-2``, ``C = s``, ``D = s-2``, ``C_hat = s-2``, ``D_hat = s``,
        ``CC_hat = DD_hat = s``, ``C_hatC = D_hatD = max(s-2, 1)``, all hypotheses true,
        ``R(infinity) = (-1)^(s-1)``, orders ``2s-2, 2s-2`` and ``s`` (even ``s``) or
        ``s-1`` (odd ``s``).
    """
    a, a_hat, b, c = _arrays(pair.a, pair.a_hat, pair.b, pair.c)
    kw = {"tol": tol}
    p = max_order_b(b, c, **kw)
    q = max_order_c(a, c, **kw)
    r = max_order_d(a, b, c, **kw)
    hyp = hypotheses(pair)
    conj = conjugacy_error(a, a_hat, b)
    r_inf = r_infinity(a, b)
    applicable = hyp.H1 and hyp.H2 and hyp.H3 and conj <= tol
    order_q, order_p, order_lam = _predicted_orders(p, q, r, r_inf, applicable, tol)
    return TableauReport(
        s=int(pair.s),
        B=p,
        C=q,
        D=r,
        C_hat=max_order_c(a_hat, c, **kw),
        D_hat=max_order_d(a_hat, b, c, **kw),
        CC_hat=max_order_cc_hat(a, a_hat, c, **kw),
        DD_hat=max_order_dd_hat(a, a_hat, b, c, **kw),
        C_hatC=max_order_c_hat_c(a, a_hat, c, **kw),
        D_hatD=max_order_d_hat_d(a, a_hat, b, c, **kw),
        H1=hyp.H1,
        H2=hyp.H2,
        H3=hyp.H3,
        H1_prime=hyp.H1_prime,
        H2_prime=hyp.H2_prime,
        H2_condition=hyp.H2_condition,
        conjugacy_residual=conj,
        r_infinity=r_inf,
        order_q=order_q,
        order_p=order_p,
        order_lam=order_lam,
    )
