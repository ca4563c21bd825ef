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

Each ``X(k)`` is one equation per test polynomial ``phi`` of degree ``m - first``,
``m = first..k`` (``first = 1`` for ``B, C, D`` and 2 for the pair assumptions): a
quadrature (B), a chain of matrices applied to ``phi(c)`` against an iterated integral
``int_0^{c_i}`` (C type), or ``(b phi(c))^T`` times a chain against ``b`` times an iterated
tail integral ``int_{c_l}^1`` (D type). The table :data:`_ASSUMPTIONS` holds, per
assumption, the arrays it uses, ``first`` and that residual; the public functions are thin
wrappers around the generic :func:`_error`, :func:`_satisfies` and :func:`_max_order`.

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
    "DEFAULT_TOL", "H2_CONDITION_LIMIT", "Hypotheses", "TableauReport", "check_tableau",
    "b_error", "c_error", "d_error", "cc_hat_error", "c_hat_c_error", "dd_hat_error",
    "d_hat_d_error",
    "satisfies_b", "satisfies_c", "satisfies_d", "satisfies_cc_hat", "satisfies_c_hat_c",
    "satisfies_dd_hat", "satisfies_d_hat_d",
    "max_order", "max_order_b", "max_order_c", "max_order_d", "max_order_cc_hat",
    "max_order_c_hat_c", "max_order_dd_hat", "max_order_d_hat_d",
    "conjugacy_error", "hypotheses", "r_infinity", "stability_function",
]  # fmt: skip

#: Residual (shifted Legendre form) below which a simplifying assumption counts as
#: satisfied. For the Lobatto tableau with s <= 20, satisfied assumptions leave residuals
#: below 6e-15 and the first violated ones more than 1e-6 (more than 1e-4 for s <= 8).
DEFAULT_TOL = 1e3 * np.finfo(np.float64).eps

#: A_tilde = (a_ij)_{i,j>=2} counts as invertible (H2) when its 2-norm condition number is below
#: this limit.
H2_CONDITION_LIMIT = 1e12

# Basis of the decisions: a violated condition keeps a Legendre residual O(1/s) for every s,
# while its monomial residual falls below any sensible tolerance (~1e-13 for B(2s-1), s = 12).
_DECISION_BASIS = "legendre"

# ----------------------------------------------------------------- the assumption table


def _arrays(*xs: Any) -> list[np.ndarray]:
    """The arguments as float64 arrays."""
    return [np.asarray(x, dtype=np.float64) for x in xs]


def _test_polynomial(basis: str, degree: int) -> Any:
    """``t^degree`` (paper) or ``P_degree(2t - 1)`` (shifted Legendre) on ``[0, 1]``.

    Both families span the same spaces, so every assumption ``X(k)`` is equivalent in
    either basis; the shifted Legendre polynomials are bounded by 1 on ``[0, 1]`` and keep
    the residual of the first violated ``k`` of order ``1/s`` instead of letting it drown
    in rounding error (``c^k`` is tiny for large ``k``).
    """
    if basis == "monomial":
        return Polynomial.basis(degree)
    if basis == "legendre":
        return Legendre.basis(degree, domain=[0.0, 1.0])
    raise ValueError(f"basis must be 'monomial' or 'legendre'; got {basis!r}.")


def _quadrature(x: dict[str, np.ndarray], phi: Any) -> np.ndarray:
    """B type: ``sum_i b_i phi(c_i) - int_0^1 phi`` (``phi = t^{m-1}``: ``1/m``)."""
    return np.atleast_1d(x["b"] @ phi(x["c"]) - phi.integ(lbnd=0.0)(1.0))


def _row(*chain: str) -> Callable[[dict[str, np.ndarray], Any], np.ndarray]:
    """C type, ``n = len(chain)`` matrices ``M_1 ... M_n``, residual per row ``i``.

    ``(M_1 ... M_n phi(c))_i - int_0^{c_i} int_0^{t_1} ... phi`` (``n``-fold); for
    ``phi = t^{m-n}`` the integral is ``c_i^m / m`` (C) or ``c_i^m / (m (m-1))`` (CC_hat).
    """

    def residual(x: dict[str, np.ndarray], phi: Any) -> np.ndarray:
        lhs = phi(x["c"])
        for name in reversed(chain):
            lhs = x[name] @ lhs
        return lhs - phi.integ(len(chain), lbnd=0.0)(x["c"])

    return residual


def _column(*chain: str) -> Callable[[dict[str, np.ndarray], Any], np.ndarray]:
    """D type, ``n = len(chain)`` matrices, residual per column ``l``.

    ``((b phi(c))^T M_1 ... M_n)_l - b_l int_{c_l}^1 int_{t_1}^1 ... phi`` (``n``-fold); for
    ``phi = t^{m-n}`` the integral is ``(1 - c_l^m) / m`` (D) or
    ``[(m-1) - (m c_l - c_l^m)] / (m (m-1))`` (DD_hat).
    """

    def residual(x: dict[str, np.ndarray], phi: Any) -> np.ndarray:
        b, c = x["b"], x["c"]
        lhs = b * phi(c)
        for name in chain:
            lhs = lhs @ x[name]
        big = phi.integ(lbnd=0.0)  # t -> int_0^t phi
        for _ in chain[1:]:
            big = (big(1.0) - big).integ(lbnd=0.0)  # integral from 0 of the tail int_t^1
        return lhs - b * (big(1.0) - big(c))

    return residual


@dataclass(frozen=True)
class _Assumption:
    """A simplifying assumption ``X(k)``, a row of :data:`_ASSUMPTIONS`.

    ``X(k)``: ``residual(arrays, phi) = 0`` for the test polynomials ``phi`` of degree
    ``m - first``, ``m = first..k`` (vacuous for ``k < first``).
    """

    args: tuple[str, ...]  # arrays it uses, in the order of the public functions' arguments
    first: int  # first nontrivial k, and the degree shift of the test polynomials
    residual: Callable[[dict[str, np.ndarray], Any], np.ndarray]


#: The simplifying assumptions (keys as in :class:`TableauReport`); ``C_hat`` and ``D_hat``
#: are ``C`` and ``D`` with ``a = A_hat``.
_ASSUMPTIONS: dict[str, _Assumption] = {
    "B": _Assumption(("b", "c"), 1, _quadrature),
    "C": _Assumption(("a", "c"), 1, _row("a")),
    "D": _Assumption(("a", "b", "c"), 1, _column("a")),
    "CC_hat": _Assumption(("a", "a_hat", "c"), 2, _row("a", "a_hat")),
    "C_hatC": _Assumption(("a", "a_hat", "c"), 2, _row("a_hat", "a")),
    "DD_hat": _Assumption(("a", "a_hat", "b", "c"), 2, _column("a", "a_hat")),
    "D_hatD": _Assumption(("a", "a_hat", "b", "c"), 2, _column("a_hat", "a")),
}


def _error(name: str, k: int, basis: str, **arrays: Any) -> float:
    """``max_{m = first..k} max |residual(test polynomial of degree m - first)|``."""
    row = _ASSUMPTIONS[name]
    x = dict(zip(row.args, _arrays(*(arrays[key] for key in row.args))))
    worst = 0.0
    for m in range(row.first, k + 1):
        res = row.residual(x, _test_polynomial(basis, m - row.first))
        worst = max(worst, float(np.max(np.abs(res))))
    return worst


def _satisfies(name: str, k: int, tol: float, **arrays: Any) -> bool:
    """Whether ``X(k)`` holds: its Legendre-form residual is at most ``tol``."""
    return _error(name, k, _DECISION_BASIS, **arrays) <= tol


def _max_order(name: str, cap: int | None, tol: float, **arrays: Any) -> int:
    """Largest ``k <= cap`` (default ``4s + 2``) with ``X(k)``; ``first - 1`` if none."""
    cap = 4 * np.asarray(arrays["c"]).shape[0] + 2 if cap is None else cap
    return max_order(
        lambda k: _satisfies(name, k, tol, **arrays), first=_ASSUMPTIONS[name].first, cap=cap
    )


def max_order(holds: Callable[[int], bool], *, first: int = 1, cap: int) -> int:
    """Largest ``k <= cap`` such that ``holds(k)``, scanning upward from ``first``.

    ``X(k)`` includes every index up to ``k``, so the scan stops at the first failure.

    Parameters
    ----------
    holds : callable
        ``k -> bool``, whether ``X(k)`` holds (e.g. ``lambda k: satisfies_b(b, c, k)``).
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


# ----------------------------------------------------------------------------- residuals


def b_error(b: Any, c: Any, k: int, *, basis: str = "monomial") -> float:
    """Residual of ``B(k)``: ``max_{m=1..k} |sum_i b_i c_i^{m-1} - 1/m|``.

    Parameters
    ----------
    b, c : array_like, shape (s,)
        Weights and nodes (``a, a_hat``, shape (s, s), in the other ``*_error`` functions).
    k : int
        Order of the assumption; ``k < 1`` is vacuous (residual 0); ``k < 2`` for the pair
        assumptions.
    basis : {"monomial", "legendre"}, optional
        ``"monomial"`` (default) evaluates the paper's equations literally. ``"legendre"``
        replaces ``c^{m-1}`` by the shifted Legendre polynomial ``P_{m-1}(2c - 1)`` and
        ``1/m`` by its integral over ``[0, 1]``: an equivalent, better scaled form (used
        by :func:`satisfies_b` and :func:`max_order_b`).

    Returns
    -------
    float
        The largest absolute residual.

    Raises
    ------
    ValueError
        If ``basis`` is neither ``"monomial"`` nor ``"legendre"``.
    """
    return _error("B", k, basis, b=b, c=c)


def c_error(a: Any, c: Any, k: int, *, basis: str = "monomial") -> float:
    """Residual of ``C(k)``: ``max_{i, m=1..k} |sum_j a_ij c_j^{m-1} - c_i^m / m|``.

    Apply it to ``A_hat`` for ``C_hat(k)``. Legendre form: ``P_{m-1}(2c - 1)`` against
    ``int_0^{c_i} P_{m-1}(2t - 1) dt``.

    Parameters
    ----------
    a : array_like, shape (s, s)
        The coefficient matrix ``A`` (pass ``A_hat`` for the hatted assumption).
    c : array_like, shape (s,)
        The nodes (``c_hat = c``).
    k : int
        Order of the assumption; ``k < 1`` is vacuous (residual 0).
    basis : {"monomial", "legendre"}, optional
        The test polynomials, as in :func:`b_error` (default ``"monomial"``: the paper's
        equations literally).

    Returns
    -------
    float
        The largest absolute residual.

    Raises
    ------
    ValueError
        If ``basis`` is neither ``"monomial"`` nor ``"legendre"``.
    """
    return _error("C", k, basis, a=a, c=c)


def d_error(a: Any, b: Any, c: Any, k: int, *, basis: str = "monomial") -> float:
    """Residual of ``D(k)``: ``max_{j, m=1..k} |sum_i b_i c_i^{m-1} a_ij - b_j (1 - c_j^m) / m|``.

    Apply it to ``A_hat`` (with ``b_hat = b``) for ``D_hat(k)``. Legendre form:
    ``P_{m-1}(2c - 1)`` against ``b_j int_{c_j}^1 P_{m-1}(2t - 1) dt``.

    Parameters
    ----------
    a : array_like, shape (s, s)
        The coefficient matrix ``A`` (pass ``A_hat`` for the hatted assumption).
    b : array_like, shape (s,)
        The weights (``b_hat = b``).
    c : array_like, shape (s,)
        The nodes (``c_hat = c``).
    k : int
        Order of the assumption; ``k < 1`` is vacuous (residual 0).
    basis : {"monomial", "legendre"}, optional
        The test polynomials, as in :func:`b_error` (default ``"monomial"``: the paper's
        equations literally).

    Returns
    -------
    float
        The largest absolute residual.

    Raises
    ------
    ValueError
        If ``basis`` is neither ``"monomial"`` nor ``"legendre"``.
    """
    return _error("D", k, basis, a=a, b=b, c=c)


def cc_hat_error(a: Any, a_hat: Any, c: Any, k: int, *, basis: str = "monomial") -> float:
    """Residual of ``CC_hat(k)``: ``sum_{j,l} a_ij a_hat_jl c_l^{m-2} = c_i^m / (m (m-1))``.

    Maximum over ``i = 1..s`` and ``m = 2..k``. Legendre form: ``P_{m-2}(2c - 1)`` against
    ``int_0^{c_i} int_0^t P_{m-2}(2u - 1) du dt``.

    Parameters
    ----------
    a, a_hat : array_like, shape (s, s)
        The coefficient matrices ``A`` and ``A_hat`` of the pair.
    c : array_like, shape (s,)
        The nodes (``c_hat = c``).
    k : int
        Order of the assumption; ``k < 2`` is vacuous (residual 0).
    basis : {"monomial", "legendre"}, optional
        The test polynomials, as in :func:`b_error` (default ``"monomial"``: the paper's
        equations literally).

    Returns
    -------
    float
        The largest absolute residual.

    Raises
    ------
    ValueError
        If ``basis`` is neither ``"monomial"`` nor ``"legendre"``.
    """
    return _error("CC_hat", k, basis, a=a, a_hat=a_hat, c=c)


def c_hat_c_error(a: Any, a_hat: Any, c: Any, k: int, *, basis: str = "monomial") -> float:
    """Residual of ``C_hatC(k)``: ``sum_{j,l} a_hat_ij a_jl c_l^{m-2} = c_i^m / (m (m-1))``.

    Maximum over ``i = 1..s`` and ``m = 2..k``; see :func:`cc_hat_error`.

    Parameters
    ----------
    a, a_hat : array_like, shape (s, s)
        The coefficient matrices ``A`` and ``A_hat`` of the pair.
    c : array_like, shape (s,)
        The nodes (``c_hat = c``).
    k : int
        Order of the assumption; ``k < 2`` is vacuous (residual 0).
    basis : {"monomial", "legendre"}, optional
        The test polynomials, as in :func:`b_error` (default ``"monomial"``: the paper's
        equations literally).

    Returns
    -------
    float
        The largest absolute residual.

    Raises
    ------
    ValueError
        If ``basis`` is neither ``"monomial"`` nor ``"legendre"``.
    """
    return _error("C_hatC", k, basis, a=a, a_hat=a_hat, c=c)


def dd_hat_error(a: Any, a_hat: Any, b: Any, c: Any, k: int, *, basis: str = "monomial") -> float:
    """Residual of ``DD_hat(k)``.

    ``sum_{i,j} b_i c_i^{m-2} a_ij a_hat_jl = b_l [(m-1) - (m c_l - c_l^m)] / (m (m-1))``,
    maximum over ``l = 1..s`` and ``m = 2..k``. Legendre form: ``P_{m-2}(2c - 1)`` against
    ``b_l int_{c_l}^1 int_tau^1 P_{m-2}(2u - 1) du dtau``.

    Parameters
    ----------
    a, a_hat : array_like, shape (s, s)
        The coefficient matrices ``A`` and ``A_hat`` of the pair.
    b : array_like, shape (s,)
        The weights (``b_hat = b``).
    c : array_like, shape (s,)
        The nodes (``c_hat = c``).
    k : int
        Order of the assumption; ``k < 2`` is vacuous (residual 0).
    basis : {"monomial", "legendre"}, optional
        The test polynomials, as in :func:`b_error` (default ``"monomial"``: the paper's
        equations literally).

    Returns
    -------
    float
        The largest absolute residual.

    Raises
    ------
    ValueError
        If ``basis`` is neither ``"monomial"`` nor ``"legendre"``.
    """
    return _error("DD_hat", k, basis, a=a, a_hat=a_hat, b=b, c=c)


def d_hat_d_error(a: Any, a_hat: Any, b: Any, c: Any, k: int, *, basis: str = "monomial") -> float:
    """Residual of ``D_hatD(k)``.

    ``sum_{i,j} b_hat_i c_i^{m-2} a_hat_ij a_jl
    = b_hat_l [(m-1) - (m c_l - c_l^m)] / (m (m-1))`` with ``b_hat = b``, maximum over
    ``l = 1..s`` and ``m = 2..k``; see :func:`dd_hat_error`.

    Parameters
    ----------
    a, a_hat : array_like, shape (s, s)
        The coefficient matrices ``A`` and ``A_hat`` of the pair.
    b : array_like, shape (s,)
        The weights (``b_hat = b``).
    c : array_like, shape (s,)
        The nodes (``c_hat = c``).
    k : int
        Order of the assumption; ``k < 2`` is vacuous (residual 0).
    basis : {"monomial", "legendre"}, optional
        The test polynomials, as in :func:`b_error` (default ``"monomial"``: the paper's
        equations literally).

    Returns
    -------
    float
        The largest absolute residual.

    Raises
    ------
    ValueError
        If ``basis`` is neither ``"monomial"`` nor ``"legendre"``.
    """
    return _error("D_hatD", k, basis, a=a, a_hat=a_hat, b=b, c=c)


# ------------------------------------------------------------------------------ yes / no


def satisfies_b(b: Any, c: Any, k: int, tol: float = DEFAULT_TOL) -> bool:
    """Whether ``B(k)`` holds: ``b_error(b, c, k, basis="legendre") <= tol``.

    Parameters
    ----------
    b : array_like, shape (s,)
        The weights (``b_hat = b``).
    c : array_like, shape (s,)
        The nodes (``c_hat = c``).
    k : int
        Order of the assumption.
    tol : float, optional
        The largest residual that counts as satisfied (default :data:`DEFAULT_TOL`).

    Returns
    -------
    bool
        True if ``B(k)`` holds to ``tol``.
    """
    return _satisfies("B", k, tol, b=b, c=c)


def satisfies_c(a: Any, c: Any, k: int, tol: float = DEFAULT_TOL) -> bool:
    """Whether ``C(k)`` holds: ``c_error(a, c, k, basis="legendre") <= tol``.

    Parameters
    ----------
    a : array_like, shape (s, s)
        The coefficient matrix ``A`` (pass ``A_hat`` for the hatted assumption).
    c : array_like, shape (s,)
        The nodes (``c_hat = c``).
    k : int
        Order of the assumption.
    tol : float, optional
        The largest residual that counts as satisfied (default :data:`DEFAULT_TOL`).

    Returns
    -------
    bool
        True if ``C(k)`` holds to ``tol``.
    """
    return _satisfies("C", k, tol, a=a, c=c)


def satisfies_d(a: Any, b: Any, c: Any, k: int, tol: float = DEFAULT_TOL) -> bool:
    """Whether ``D(k)`` holds: ``d_error(a, b, c, k, basis="legendre") <= tol``.

    Parameters
    ----------
    a : array_like, shape (s, s)
        The coefficient matrix ``A`` (pass ``A_hat`` for the hatted assumption).
    b : array_like, shape (s,)
        The weights (``b_hat = b``).
    c : array_like, shape (s,)
        The nodes (``c_hat = c``).
    k : int
        Order of the assumption.
    tol : float, optional
        The largest residual that counts as satisfied (default :data:`DEFAULT_TOL`).

    Returns
    -------
    bool
        True if ``D(k)`` holds to ``tol``.
    """
    return _satisfies("D", k, tol, a=a, b=b, c=c)


def satisfies_cc_hat(a: Any, a_hat: Any, c: Any, k: int, tol: float = DEFAULT_TOL) -> bool:
    """Whether ``CC_hat(k)`` holds: ``cc_hat_error(..., basis="legendre") <= tol``.

    Parameters
    ----------
    a, a_hat : array_like, shape (s, s)
        The coefficient matrices ``A`` and ``A_hat`` of the pair.
    c : array_like, shape (s,)
        The nodes (``c_hat = c``).
    k : int
        Order of the assumption.
    tol : float, optional
        The largest residual that counts as satisfied (default :data:`DEFAULT_TOL`).

    Returns
    -------
    bool
        True if ``CC_hat(k)`` holds to ``tol``.
    """
    return _satisfies("CC_hat", k, tol, a=a, a_hat=a_hat, c=c)


def satisfies_c_hat_c(a: Any, a_hat: Any, c: Any, k: int, tol: float = DEFAULT_TOL) -> bool:
    """Whether ``C_hatC(k)`` holds: ``c_hat_c_error(..., basis="legendre") <= tol``.

    Parameters
    ----------
    a, a_hat : array_like, shape (s, s)
        The coefficient matrices ``A`` and ``A_hat`` of the pair.
    c : array_like, shape (s,)
        The nodes (``c_hat = c``).
    k : int
        Order of the assumption.
    tol : float, optional
        The largest residual that counts as satisfied (default :data:`DEFAULT_TOL`).

    Returns
    -------
    bool
        True if ``C_hatC(k)`` holds to ``tol``.
    """
    return _satisfies("C_hatC", k, tol, a=a, a_hat=a_hat, c=c)


def satisfies_dd_hat(a: Any, a_hat: Any, b: Any, c: Any, k: int, tol: float = DEFAULT_TOL) -> bool:
    """Whether ``DD_hat(k)`` holds: ``dd_hat_error(..., basis="legendre") <= tol``.

    Parameters
    ----------
    a, a_hat : array_like, shape (s, s)
        The coefficient matrices ``A`` and ``A_hat`` of the pair.
    b : array_like, shape (s,)
        The weights (``b_hat = b``).
    c : array_like, shape (s,)
        The nodes (``c_hat = c``).
    k : int
        Order of the assumption.
    tol : float, optional
        The largest residual that counts as satisfied (default :data:`DEFAULT_TOL`).

    Returns
    -------
    bool
        True if ``DD_hat(k)`` holds to ``tol``.
    """
    return _satisfies("DD_hat", k, tol, a=a, a_hat=a_hat, b=b, c=c)


def satisfies_d_hat_d(
    a: Any, a_hat: Any, b: Any, c: Any, k: int, tol: float = DEFAULT_TOL
) -> bool:
    """Whether ``D_hatD(k)`` holds: ``d_hat_d_error(..., basis="legendre") <= tol``.

    Parameters
    ----------
    a, a_hat : array_like, shape (s, s)
        The coefficient matrices ``A`` and ``A_hat`` of the pair.
    b : array_like, shape (s,)
        The weights (``b_hat = b``).
    c : array_like, shape (s,)
        The nodes (``c_hat = c``).
    k : int
        Order of the assumption.
    tol : float, optional
        The largest residual that counts as satisfied (default :data:`DEFAULT_TOL`).

    Returns
    -------
    bool
        True if ``D_hatD(k)`` holds to ``tol``.
    """
    return _satisfies("D_hatD", k, tol, a=a, a_hat=a_hat, b=b, c=c)


# ---------------------------------------------------------------------------- max orders


def max_order_b(b: Any, c: Any, *, cap: int | None = None, tol: float = DEFAULT_TOL) -> int:
    """Largest ``p`` with ``B(p)``.

    Parameters
    ----------
    b : array_like, shape (s,)
        The weights (``b_hat = b``).
    c : array_like, shape (s,)
        The nodes (``c_hat = c``).
    cap : int, optional
        The largest order examined (default ``4s + 2``).
    tol : float, optional
        The largest residual that counts as satisfied (default :data:`DEFAULT_TOL`).

    Returns
    -------
    int
        ``p``; 0 if ``B(1)`` fails.
    """
    return _max_order("B", cap, tol, b=b, c=c)


def max_order_c(a: Any, c: Any, *, cap: int | None = None, tol: float = DEFAULT_TOL) -> int:
    """Largest ``q`` with ``C(q)``; pass ``A_hat`` for ``C_hat``.

    Parameters
    ----------
    a : array_like, shape (s, s)
        The coefficient matrix ``A`` (pass ``A_hat`` for the hatted assumption).
    c : array_like, shape (s,)
        The nodes (``c_hat = c``).
    cap : int, optional
        The largest order examined (default ``4s + 2``).
    tol : float, optional
        The largest residual that counts as satisfied (default :data:`DEFAULT_TOL`).

    Returns
    -------
    int
        ``q``; 0 if ``C(1)`` fails.
    """
    return _max_order("C", cap, tol, a=a, c=c)


def max_order_d(
    a: Any, b: Any, c: Any, *, cap: int | None = None, tol: float = DEFAULT_TOL
) -> int:
    """Largest ``r`` with ``D(r)``; pass ``A_hat`` for ``D_hat``.

    Parameters
    ----------
    a : array_like, shape (s, s)
        The coefficient matrix ``A`` (pass ``A_hat`` for the hatted assumption).
    b : array_like, shape (s,)
        The weights (``b_hat = b``).
    c : array_like, shape (s,)
        The nodes (``c_hat = c``).
    cap : int, optional
        The largest order examined (default ``4s + 2``).
    tol : float, optional
        The largest residual that counts as satisfied (default :data:`DEFAULT_TOL`).

    Returns
    -------
    int
        ``r``; 0 if ``D(1)`` fails.
    """
    return _max_order("D", cap, tol, a=a, b=b, c=c)


def max_order_cc_hat(
    a: Any, a_hat: Any, c: Any, *, cap: int | None = None, tol: float = DEFAULT_TOL
) -> int:
    """Largest ``Q`` with ``CC_hat(Q)``.

    Parameters
    ----------
    a, a_hat : array_like, shape (s, s)
        The coefficient matrices ``A`` and ``A_hat`` of the pair.
    c : array_like, shape (s,)
        The nodes (``c_hat = c``).
    cap : int, optional
        The largest order examined (default ``4s + 2``).
    tol : float, optional
        The largest residual that counts as satisfied (default :data:`DEFAULT_TOL`).

    Returns
    -------
    int
        ``Q``; 1 if ``CC_hat(2)`` already fails.
    """
    return _max_order("CC_hat", cap, tol, a=a, a_hat=a_hat, c=c)


def max_order_c_hat_c(
    a: Any, a_hat: Any, c: Any, *, cap: int | None = None, tol: float = DEFAULT_TOL
) -> int:
    """Largest ``Q_hat`` with ``C_hatC(Q_hat)``.

    Parameters
    ----------
    a, a_hat : array_like, shape (s, s)
        The coefficient matrices ``A`` and ``A_hat`` of the pair.
    c : array_like, shape (s,)
        The nodes (``c_hat = c``).
    cap : int, optional
        The largest order examined (default ``4s + 2``).
    tol : float, optional
        The largest residual that counts as satisfied (default :data:`DEFAULT_TOL`).

    Returns
    -------
    int
        ``Q_hat``; 1 if ``C_hatC(2)`` already fails.
    """
    return _max_order("C_hatC", cap, tol, a=a, a_hat=a_hat, c=c)


def max_order_dd_hat(
    a: Any, a_hat: Any, b: Any, c: Any, *, cap: int | None = None, tol: float = DEFAULT_TOL
) -> int:
    """Largest ``R`` with ``DD_hat(R)``.

    Parameters
    ----------
    a, a_hat : array_like, shape (s, s)
        The coefficient matrices ``A`` and ``A_hat`` of the pair.
    b : array_like, shape (s,)
        The weights (``b_hat = b``).
    c : array_like, shape (s,)
        The nodes (``c_hat = c``).
    cap : int, optional
        The largest order examined (default ``4s + 2``).
    tol : float, optional
        The largest residual that counts as satisfied (default :data:`DEFAULT_TOL`).

    Returns
    -------
    int
        ``R``; 1 if ``DD_hat(2)`` already fails.
    """
    return _max_order("DD_hat", cap, tol, a=a, a_hat=a_hat, b=b, c=c)


def max_order_d_hat_d(
    a: Any, a_hat: Any, b: Any, c: Any, *, cap: int | None = None, tol: float = DEFAULT_TOL
) -> int:
    """Largest ``R_hat`` with ``D_hatD(R_hat)``.

    Parameters
    ----------
    a, a_hat : array_like, shape (s, s)
        The coefficient matrices ``A`` and ``A_hat`` of the pair.
    b : array_like, shape (s,)
        The weights (``b_hat = b``).
    c : array_like, shape (s,)
        The nodes (``c_hat = c``).
    cap : int, optional
        The largest order examined (default ``4s + 2``).
    tol : float, optional
        The largest residual that counts as satisfied (default :data:`DEFAULT_TOL`).

    Returns
    -------
    int
        ``R_hat``; 1 if ``D_hatD(2)`` already fails.
    """
    return _max_order("D_hatD", cap, tol, a=a, a_hat=a_hat, b=b, c=c)


# ------------------------------------------------------------- conjugacy and hypotheses


def conjugacy_error(a: Any, a_hat: Any, b: Any) -> float:
    """Residual of symplectic conjugacy: ``max_{i,j} |b_i a_hat_ij + b_j a_ji - b_i b_j|``.

    Zero for the Lobatto IIIA-IIIB pair.

    Parameters
    ----------
    a, a_hat : array_like, shape (s, s)
        The coefficient matrices ``A`` and ``A_hat`` of the pair.
    b : array_like, shape (s,)
        The weights (``b_hat = b``).

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
    cond = _condition(a[1:, 1:])
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
        The coefficient matrix.
    b : array_like, shape (s,)
        The weights.
    z : complex or float, or array_like of them
        ``h lambda``.

    Returns
    -------
    complex or float, or numpy.ndarray
        ``R(z)``, with the shape of ``z`` (real if ``z`` is real).
    """
    a, b = _arrays(a, b)
    z = np.asarray(z)
    zf = z.reshape(-1)
    out = np.empty(zf.shape, dtype=np.result_type(zf.dtype, np.float64))
    eye, ones = np.eye(b.shape[0]), np.ones(b.shape[0])
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
    if _condition(a) < H2_CONDITION_LIMIT:  # A invertible
        return float(1.0 - b @ np.linalg.solve(a, np.ones(b.shape[0])))
    a_tilde, alpha, b_tilde = a[1:, 1:], a[1:, 0], b[1:]
    if not np.all(a[0] == 0.0) or _condition(a_tilde) >= H2_CONDITION_LIMIT:
        return float("nan")
    y0 = np.linalg.solve(a_tilde, alpha)  # A_tilde^{-1} alpha
    if abs(b[0] - b_tilde @ y0) > tol * max(1.0, float(np.max(np.abs(b)))):
        return float("inf")
    return float(1.0 - b_tilde @ np.linalg.solve(a_tilde, 1.0 + y0))


# ---------------------------------------------------------------------------------- report


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
        """The report as a plain dict.

        Returns
        -------
        dict
            Field name -> value (JSON-serialisable).
        """
        return asdict(self)

    def format(self) -> str:
        """A readable multi-line table (also ``str(report)``).

        Returns
        -------
        str
            The assumptions, hypotheses and predicted orders, one per line.
        """

        def yn(flag: bool) -> str:
            return "yes" if flag else "NO"

        def order(k: int | None) -> str:
            return "n/a" if k is None else str(k)

        return "\n".join([
            f"Lobatto IIIA-IIIB tableau check, s = {self.s}",
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
            f"  H2  A_tilde invertible     : {yn(self.H2)}   (cond = {self.H2_condition:.3e})",
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
        ])

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
    arrays = {"a": a, "a_hat": a_hat, "b": b, "c": c}
    orders = {name: _max_order(name, None, tol, **arrays) for name in _ASSUMPTIONS}
    hatted = dict(arrays, a=a_hat)  # C_hat and D_hat are C and D applied to A_hat
    orders |= {f"{name}_hat": _max_order(name, None, tol, **hatted) for name in ("C", "D")}
    hyp = hypotheses(pair)
    conj = conjugacy_error(a, a_hat, b)
    r_inf = r_infinity(a, b)
    # Global orders from the paper's convergence theorem (None where it does not apply).
    p, q, r = orders["B"], orders["C"], orders["D"]
    predicted = dict(order_q=None, order_p=None, order_lam=None)
    if hyp.H1 and hyp.H2 and hyp.H3 and conj <= tol:
        predicted.update(order_q=min(p, q + r + 1), order_p=min(p, 2 * q, q + r))
        if np.isfinite(r_inf) and abs(r_inf) <= 1.0 + tol:
            predicted["order_lam"] = q - 1 if abs(r_inf - 1.0) <= tol else q
    return TableauReport(
        s=int(pair.s), **orders, **asdict(hyp), conjugacy_residual=conj, r_infinity=r_inf,
        **predicted,
    )
