"""Yes/no checks of the simplifying assumptions and the largest order that holds.

``satisfies_*(..., k, tol)`` decides ``X(k)`` from the residual in the shifted Legendre form
(``*_error(..., basis="legendre") <= tol``); ``max_order_*(...)`` is the largest ``k`` for
which ``X(k)`` holds. Both are thin wrappers around the assumption table of
:mod:`lobattodae._conditions`, where the assumptions and the two forms of their residuals are
written out.
"""

from __future__ import annotations

from typing import Any

from ._conditions import DEFAULT_TOL, _max_order, _satisfies

__all__ = [
    "satisfies_b", "satisfies_c", "satisfies_d", "satisfies_cc_hat", "satisfies_c_hat_c",
    "satisfies_dd_hat", "satisfies_d_hat_d",
    "max_order_b", "max_order_c", "max_order_d", "max_order_cc_hat", "max_order_c_hat_c",
    "max_order_dd_hat", "max_order_d_hat_d",
]  # fmt: skip


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
