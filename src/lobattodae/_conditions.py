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

from dataclasses import dataclass
from typing import Any, Callable

import numpy as np
from numpy.polynomial import Legendre, Polynomial

__all__ = [
    "DEFAULT_TOL", "b_error", "c_error", "d_error", "cc_hat_error", "c_hat_c_error", "dd_hat_error",
    "d_hat_d_error", "max_order",
]  # fmt: skip

#: Residual (shifted Legendre form) below which a simplifying assumption counts as
#: satisfied. For the Lobatto tableau with s <= 20, satisfied assumptions leave residuals
#: below 6e-15 and the first violated ones more than 1e-6 (more than 1e-4 for s <= 8).
DEFAULT_TOL = 1e3 * np.finfo(np.float64).eps

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
