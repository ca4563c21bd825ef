"""The hypotheses, conjugacy and stability of a partitioned Runge-Kutta pair, and the summary
:func:`check_tableau` that predicts the global orders from them (the paper's convergence
theorem) together with the simplifying assumptions of :mod:`lobattodae._conditions`.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from ._conditions import _ASSUMPTIONS, DEFAULT_TOL, _arrays, _max_order

__all__ = [
    "H2_CONDITION_LIMIT", "Hypotheses", "TableauReport", "check_tableau", "conjugacy_error", "hypotheses",
    "r_infinity", "stability_function",
]  # fmt: skip

#: A_tilde = (a_ij)_{i,j>=2} counts as invertible (H2) when its 2-norm condition number is below
#: this limit.
H2_CONDITION_LIMIT = 1e12


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
