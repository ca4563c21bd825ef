"""Lobatto IIIA and IIIB coefficients for any number of stages ``s >= 2``.

The s-stage Lobatto IIIA-IIIB pair (paper, section 2) consists of

* the Lobatto nodes ``c = (c_1, ..., c_s)`` on ``[0, 1]``: ``c_1 = 0``, ``c_s = 1`` and
  the ``s - 2`` roots of ``P'_{s-1}(2x - 1)``, where ``P_n`` is the Legendre polynomial;
* the Lobatto quadrature weights ``b = (b_1, ..., b_s)``;
* the Lobatto IIIA matrix ``A = (a_ij)``, the continuous collocation method defined by
  ``C(s)``: ``a_ij = int_0^{c_i} l_j(tau) dtau`` with ``l_j`` the Lagrange basis of ``c``;
* the Lobatto IIIB matrix ``A_hat = (a_hat_ij)``, its symplectic conjugate
  ``b_i a_hat_ij + b_j a_ji = b_i b_j`` (with ``b_hat = b``, ``c_hat = c``).

Everything is computed in float64 with NumPy, in well-conditioned ways. Measured maximum
absolute errors against a 50-digit reference for ``s = 2..16``: ``c``, ``b`` 1e-16,
``A`` 3e-16, ``A_hat`` 1.1e-15 (its formula amplifies the rounding of ``A`` by
``b_j / b_i``). The structural
facts (``c_1 = 0``, ``c_s = 1``, symmetric nodes and weights, ``a_1j = 0``, ``a_sj = b_j``,
``a_hat_is = 0``, ``a_hat_i1 = b_1``) are set exactly.
"""

from __future__ import annotations

import functools
import numbers
from dataclasses import dataclass

import numpy as np

__all__ = [
    "LobattoPair",
    "lagrange_basis",
    "lobatto_iiia",
    "lobatto_iiib",
    "lobatto_nodes",
    "lobatto_pair",
    "lobatto_weights",
]

#: Newton iterations used to polish the interior nodes (quadratic convergence from an
#: eigenvalue guess that is already accurate to ~1e-14; two would do).
_NEWTON_ITERATIONS = 4


def _check_stages(s: object) -> int:
    """Validate the number of stages and return it as a Python ``int``.

    Parameters
    ----------
    s : object
        Candidate number of stages.

    Returns
    -------
    int
        ``s`` as a plain integer.

    Raises
    ------
    TypeError
        If ``s`` is a bool or not an integer (e.g. a float such as ``3.0``).
    ValueError
        If ``s < 2``.
    """
    if isinstance(s, (bool, np.bool_)) or not isinstance(s, numbers.Integral):
        raise TypeError(
            "s (the number of stages) must be an integer >= 2, such as s=3; "
            f"got {s!r} of type {type(s).__name__}. Pass a plain int."
        )
    s = int(s)
    if s < 2:
        raise ValueError(
            "s must be an integer >= 2 (Lobatto IIIA-IIIB needs at least the two end "
            f"points 0 and 1); got s={s}. Use s=2 (order 2) or larger."
        )
    return s


def _legendre(n: int, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Evaluate ``P_n(x)`` and ``P_{n-1}(x)`` by the three-term recurrence.

    Parameters
    ----------
    n : int
        Degree, ``n >= 1``.
    x : ndarray
        Points in ``[-1, 1]``.

    Returns
    -------
    p_n, p_nm1 : ndarray
        ``P_n(x)`` and ``P_{n-1}(x)``.
    """
    x = np.asarray(x, dtype=np.float64)
    p_prev = np.ones_like(x)
    p = x.copy()
    for k in range(1, n):
        p_prev, p = p, ((2 * k + 1) * x * p - k * p_prev) / (k + 1)
    return p, p_prev


def _interior_lobatto_points(s: int) -> np.ndarray:
    """Roots of ``P'_{s-1}(x)`` on ``(-1, 1)``, sorted ascending.

    Golub-Welsch on the Jacobi polynomial ``P^{(1,1)}_{s-2}`` (whose roots are those of
    ``P'_{s-1}``) gives a starting guess; Newton's method on ``P'_{s-1}`` evaluated by the
    Legendre recurrence polishes it, and the result is symmetrised (``x_i = -x_{s-1-i}``).

    Parameters
    ----------
    s : int
        Number of Lobatto stages, ``s >= 2``.

    Returns
    -------
    ndarray, shape (s - 2,)
        The interior points on ``[-1, 1]``.
    """
    m = s - 2
    if m == 0:
        return np.zeros(0)
    # Symmetric Jacobi matrix of the monic (1,1)-Jacobi recurrence: zero diagonal,
    # off-diagonal sqrt(k (k + 2) / ((2k + 1)(2k + 3))).
    k = np.arange(1, m, dtype=np.float64)
    off = np.sqrt(k * (k + 2) / ((2 * k + 1) * (2 * k + 3)))
    x = np.linalg.eigvalsh(np.diag(off, 1) + np.diag(off, -1))
    n = s - 1
    for _ in range(_NEWTON_ITERATIONS):
        p, p_prev = _legendre(n, x)
        one_minus_x2 = (1.0 - x) * (1.0 + x)
        dp = n * (p_prev - x * p) / one_minus_x2  # P'_n
        d2p = (2.0 * x * dp - n * (n + 1) * p) / one_minus_x2  # P''_n (Legendre ODE)
        x = x - dp / d2p
    x = np.sort(x)
    x = 0.5 * (x - x[::-1])  # exact antisymmetry
    if m % 2 == 1:
        x[m // 2] = 0.0
    return x


def lobatto_nodes(s: int) -> np.ndarray:
    """Lobatto nodes ``c_1 < ... < c_s`` on ``[0, 1]``.

    ``c_1 = 0`` and ``c_s = 1`` exactly; ``c_2, ..., c_{s-1}`` are the roots of
    ``P'_{s-1}(2x - 1)``. The nodes are symmetric: for ``i <= s/2`` the node
    ``c_{s+1-i}`` is exactly the float64 value of ``1 - c_i``, and the middle node of an
    odd ``s`` is exactly ``1/2``.

    Parameters
    ----------
    s : int
        Number of stages, ``s >= 2``.

    Returns
    -------
    ndarray, shape (s,)
        The nodes, accurate to about ``1e-16``.

    Raises
    ------
    TypeError, ValueError
        If ``s`` is not an integer ``>= 2``.
    """
    s = _check_stages(s)
    x = _interior_lobatto_points(s)
    c = np.empty(s)
    c[0], c[-1] = 0.0, 1.0
    half = (s - 2) // 2
    # Lower half from (1 + x) / 2, upper half as 1 - (lower half), so the symmetry is exact.
    lower = 0.5 * (1.0 + x[:half])
    c[1 : 1 + half] = lower
    c[s - 1 - half : s - 1] = (1.0 - lower)[::-1]
    if s % 2 == 1:
        c[s // 2] = 0.5
    return c


def lobatto_weights(c: np.ndarray) -> np.ndarray:
    """Lobatto quadrature weights on ``[0, 1]`` for the nodes ``c``.

    Closed form ``b_j = 1 / (s (s - 1) P_{s-1}(2 c_j - 1)^2)``; symmetrised so that
    ``b_{s+1-j} = b_j`` exactly. ``B(2s - 2)`` holds: ``sum_i b_i c_i^{k-1} = 1/k`` for
    ``k = 1, ..., 2s - 2``.

    Parameters
    ----------
    c : array_like, shape (s,)
        Lobatto nodes, as returned by :func:`lobatto_nodes`.

    Returns
    -------
    ndarray, shape (s,)
        The weights ``b``.
    """
    c = np.asarray(c, dtype=np.float64)
    s = _check_stages(c.shape[0])
    p, _ = _legendre(s - 1, 2.0 * c - 1.0)
    b = 1.0 / (s * (s - 1) * p * p)
    return 0.5 * (b + b[::-1])


def lagrange_basis(c: np.ndarray, tau):
    """Lagrange basis ``l_j(tau) = prod_{k != j} (tau - c_k) / (c_j - c_k)``.

    The product form is evaluated factor by factor (each factor to relative accuracy
    ``eps``), which is well conditioned for Lobatto nodes. ``tau`` may be a NumPy or a JAX
    array (also a traced one): the predictor of the step evaluates the previous step's stage
    polynomial at the new stage times with it.

    Parameters
    ----------
    c : ndarray, shape (s,)
        Interpolation nodes (NumPy, constants).
    tau : array, shape (m,)
        Evaluation points.

    Returns
    -------
    array, shape (m, s)
        ``out[q, j] = l_j(tau_q)``, of the array type of ``tau``.
    """
    xp = np if isinstance(tau, np.ndarray) else _jnp()
    s = c.shape[0]
    cols = []
    for j in range(s):
        col = xp.ones_like(tau)
        for k in range(s):
            if k != j:
                col = col * ((tau - c[k]) / (c[j] - c[k]))
        cols.append(col)
    return xp.stack(cols, axis=-1)


def _jnp():
    import jax.numpy as jnp

    return jnp


def lobatto_iiia(c: np.ndarray) -> np.ndarray:
    """Lobatto IIIA coefficients ``A`` (continuous collocation) for the nodes ``c``.

    ``a_ij = int_0^{c_i} l_j(tau) dtau``, which is the unique solution of ``C(s)``:
    ``sum_j a_ij c_j^{k-1} = c_i^k / k`` for ``i = 1..s``, ``k = 1..s``. The integrals are
    computed exactly (up to rounding) by Gauss-Legendre quadrature on ``[0, c_i]`` with
    enough points for the degree ``s - 1`` integrand; this is well conditioned, unlike a
    monomial Vandermonde solve of ``C(s)``. Only the rows with ``c_i <= 1/2`` are
    integrated; the others follow from the symmetry of the Lobatto nodes,
    ``a_{s+1-i, s+1-j} = b_j - a_ij``, which therefore holds exactly. The first row is
    exactly 0 (H1) and the last row exactly ``b`` (H3).

    Parameters
    ----------
    c : array_like, shape (s,)
        Lobatto nodes, as returned by :func:`lobatto_nodes` (symmetric about 1/2).

    Returns
    -------
    ndarray, shape (s, s)
        The matrix ``A``.
    """
    c = np.asarray(c, dtype=np.float64)
    s = _check_stages(c.shape[0])
    b = lobatto_weights(c)
    t, w = np.polynomial.legendre.leggauss(s // 2 + 1)  # exact to degree s + 1 >= s - 1
    a = np.zeros((s, s))
    for i in range(1, (s + 1) // 2):  # rows with c_i <= 1/2 (the middle one for odd s)
        tau = 0.5 * c[i] * (1.0 + t)
        a[i] = 0.5 * c[i] * (w @ lagrange_basis(c, tau))
    for i in range(s // 2):  # mirror: a[s-1-i, s-1-j] = b[j] - a[i, j]
        a[s - 1 - i] = (b - a[i])[::-1]
    a[-1] = b
    return a


def lobatto_iiib(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Lobatto IIIB coefficients ``A_hat``, the symplectic conjugate of IIIA.

    ``a_hat_ij = b_j (1 - a_ji / b_i)``, i.e. ``b_i a_hat_ij + b_j a_ji = b_i b_j`` with
    ``b_hat = b``. The rounding error of ``a_ji`` is amplified by ``b_j / b_i`` (up to
    about ``s^2 / 10``), so ``A_hat`` is accurate to about ``1e-15`` for ``s <= 16`` when
    ``A`` is accurate to ``3e-16``. Because IIIA satisfies H1 (``a_1j = 0``) and H3
    (``a_sj = b_j``), the conjugate satisfies H1' (``a_hat_is = 0``) and H2'
    (``a_hat_i1 = b_1``); both are set exactly.

    Parameters
    ----------
    a : array_like, shape (s, s)
        Lobatto IIIA matrix.
    b : array_like, shape (s,)
        Weights.

    Returns
    -------
    ndarray, shape (s, s)
        The matrix ``A_hat``.

    Raises
    ------
    ValueError
        If ``b`` has fewer than 2 entries, or ``a`` is not of shape (s, s).
    """
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    s = _check_stages(b.shape[0])
    if a.shape != (s, s):
        raise ValueError(f"a must have shape ({s}, {s}) to match b; got {a.shape}.")
    a_hat = (b[None, :] / b[:, None]) * (b[:, None] - a.T)  # (b_j / b_i) (b_i - a_ji)
    a_hat[:, -1] = 0.0
    a_hat[:, 0] = b[0]
    return a_hat


def _frozen(x: object, shape: tuple[int, ...], name: str) -> np.ndarray:
    """Return a read-only float64 copy of ``x``, checking its shape and finiteness."""
    arr = np.array(x, dtype=np.float64, copy=True)
    if arr.shape != shape:
        raise ValueError(f"LobattoPair.{name} must have shape {shape}; got {arr.shape}.")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"LobattoPair.{name} contains non-finite values.")
    arr.setflags(write=False)
    return arr


@dataclass(frozen=True, eq=False, repr=False)
class LobattoPair:
    """Coefficients of the s-stage Lobatto IIIA-IIIB partitioned Runge-Kutta pair.

    A frozen, self-validating record of read-only NumPy float64 arrays. It is deliberately
    *not* a JAX pytree: it is a constant baked into traces. Build it with
    :func:`lobatto_pair`, which caches one instance per ``s``.

    Attributes
    ----------
    s : int
        Number of stages, ``s >= 2``.
    c : ndarray, shape (s,)
        Nodes, ``c_i = sum_j a_ij = sum_j a_hat_ij``.
    b : ndarray, shape (s,)
        Weights, shared by both methods (``b_hat = b``).
    a : ndarray, shape (s, s)
        Lobatto IIIA matrix ``A = (a_ij)``.
    a_hat : ndarray, shape (s, s)
        Lobatto IIIB matrix ``A_hat = (a_hat_ij)``.
    error_weights : ndarray, shape (s,)
        ``e = b - b̂`` of the embedded quadrature of the local error estimate (computed on
        first use).
    r_infinity : int
        ``R(∞) = (-1)^(s-1)`` of IIIA, the factor by which a λ error is carried per step.
    pade_coefficients : ndarray, shape (s,)
        ``c_j`` of IIIA's stability function ``R(z) = P(z) / P(−z)``, ``P(z) = Σ_j c_j z^j``
        (computed on first use).
    constraint_pade : tuple of ndarray
        ``(N, D)``, coefficients (lowest degree first) of the step's stability function on a mode
        that the constraint damps, ``R_c(z) = N(z) / D(z)``, the (s, s−2) Padé approximant of e^z
        (see :meth:`constraint_stability`).
    richardson_radius : float
        The largest ``|hμ|`` for which step doubling's Richardson ratio ``2^(2s−2)`` holds
        within a factor two for damped and oscillating linear modes (computed on first use).
    """

    s: int
    c: np.ndarray
    b: np.ndarray
    a: np.ndarray
    a_hat: np.ndarray

    def __post_init__(self) -> None:
        s = _check_stages(self.s)
        object.__setattr__(self, "s", s)
        object.__setattr__(self, "c", _frozen(self.c, (s,), "c"))
        object.__setattr__(self, "b", _frozen(self.b, (s,), "b"))
        object.__setattr__(self, "a", _frozen(self.a, (s, s), "a"))
        object.__setattr__(self, "a_hat", _frozen(self.a_hat, (s, s), "a_hat"))

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, LobattoPair):
            return NotImplemented
        return self.s == other.s and all(
            np.array_equal(getattr(self, f), getattr(other, f))
            for f in ("c", "b", "a", "a_hat")
        )

    def __hash__(self) -> int:
        return hash(("LobattoPair", self.s))

    def order(self) -> dict[str, int]:
        """Global orders for index-2 partitioned DAEs (the paper's Corollary).

        Returns
        -------
        dict
            ``{"q": 2s-2, "p": 2s-2, "lam": s}`` for even s and ``"lam": s-1`` for odd s.
        """
        s = self.s
        return {"q": 2 * s - 2, "p": 2 * s - 2, "lam": s if s % 2 == 0 else s - 1}

    @functools.cached_property
    def error_weights(self) -> np.ndarray:
        r"""``e = b - b̂`` of the embedded quadrature used for the local error estimate.

        ``b̂`` is the interpolatory rule on the first s-1 nodes (``b̂_s = 0``), exact for
        polynomials of degree ``s - 2``. So ``e`` annihilates them, ``Σ_j e_j c_j^(k-1) = 0`` for
        k = 1..s-1, and ``h Σ_j e_j V_j`` is a scaled (s-1)-th divided difference of the stage
        slopes: ``O(h^s)``, the local error of the embedded order-(s-1) formula (used by
        ``PIController(estimate="embedded")``). Read-only.
        """
        s, c = self.s, self.c
        b_hat = np.zeros(s)
        x, w = np.polynomial.legendre.leggauss(s)  # exact to degree 2s - 1 >= s - 2
        b_hat[: s - 1] = 0.5 * (w @ lagrange_basis(c[: s - 1], 0.5 * (1.0 + x)))
        out = self.b - b_hat
        out.setflags(write=False)
        return out

    def error_order(self) -> int:
        """The power of h in the local error estimate ``h Σ_j e_j (V_j, W_j)``.

        Returns
        -------
        int
            s.
        """
        return self.s

    def stability(self, z):
        """The stability function of Lobatto IIIA, ``R(z) = 1 + z bᵀ (I − zA)⁻¹ 1``.

        Parameters
        ----------
        z : array_like
            Complex (or real) arguments, any shape.

        Returns
        -------
        ndarray
            ``R(z)``, complex, of the shape of ``z``.
        """
        z = np.asarray(z, complex)
        flat = z.reshape(-1, 1, 1)
        stages = np.linalg.solve(np.eye(self.s) - flat * self.a, np.ones((flat.shape[0], self.s, 1)))
        return (1.0 + z.ravel() * (stages[:, :, 0] @ self.b)).reshape(z.shape)

    @functools.cached_property
    def pade_coefficients(self) -> np.ndarray:
        """``c_j`` of ``R(z) = P(z) / P(−z)``, ``P(z) = Σ_j c_j z^j``: Lobatto IIIA's stability
        function is the (s−1, s−1) Padé approximant of e^z, ``c_j = (2k−j)! k! / ((2k)! j! (k−j)!)``
        with k = s − 1 (lowest degree first). Read-only."""
        return _pade(self.s - 1, self.s - 1)[0]

    @functools.cached_property
    def constraint_pade(self) -> tuple[np.ndarray, np.ndarray]:
        r"""``(N, D)``: the coefficients (lowest degree first) of ``R_c(z) = N(z) / D(z)``, the
        (s, s−2) Padé approximant of e^z,

            N_j = (2s−2−j)! s! / ((2s−2)! j! (s−j)!),
            D_j = (−1)^j (2s−2−j)! (s−2)! / ((2s−2)! j! (s−2−j)!),

        the factor by which one step multiplies a mode that the constraint damps (see
        :meth:`constraint_stability`). Read-only."""
        return _pade(self.s, self.s - 2)

    def constraint_stability(self, z):
        r"""The step's stability function on a mode that the *constraint* damps, ``R_c(z)``.

        A mode ``y' = μ y`` of the ODE is multiplied by IIIA's :meth:`stability` (the diagonal
        (s−1, s−1) Padé approximant, bounded by 1 for Re z ≤ 0). A mode that the constraint
        force damps (the Chaplygin sleigh's turning rate on straight motion, decaying like
        ``e^(−k t)`` through λ) is multiplied by the (s, s−2) Padé approximant instead, which is
        unbounded, ``|R_c(z)| ~ |z|²``: for s = 2 the Taylor polynomial ``1 + z + z²/2`` of an
        explicit method, for every s exceeding 1 beyond ``−z`` = 2.0, 5.4, 9.6, 14.7, 20.6
        (s = 2..6). Identified on the sleigh, where one step's factor equals it to six digits
        for s = 2..7 and ``h k`` from 0.35 to 21 (``tests/test_stage_equations.py``).

        Parameters
        ----------
        z : array_like
            Complex (or real) arguments, any shape.

        Returns
        -------
        ndarray
            ``R_c(z)``, complex, of the shape of ``z``.
        """
        z = np.asarray(z, complex)
        num, den = self.constraint_pade
        return np.polyval(num[::-1], z) / np.polyval(den[::-1], z)

    @functools.cached_property
    def richardson_radius(self) -> float:
        r"""The largest r for which Richardson's divisor ``2^p − 1`` (p = 2s − 2) is within a factor
        two of the true ratio for every linear mode ``y' = μ y`` with ``|hμ| ≤ r``, damped (μ real
        negative) or oscillating (μ imaginary).

        For such a mode, a whole step and two half steps err by ``R(z) − e^z`` and
        ``R(z/2)² − e^z`` (z = hμ), so their difference is the half steps' error times

            D(z) = (R(z/2)² − R(z)) / (R(z/2)² − e^z),

        which tends to ``2^p − 1`` as z → 0 and leaves it once the step no longer resolves the
        mode (``|R(z)| → 1`` where ``e^z → 0``, or the phase of ``R(iy)`` runs away). A property of
        the tableau alone. Read-only.
        """
        d0 = 2.0 ** (2 * self.s - 2) - 1.0
        r = np.linspace(0.05, 100.0, 4000)
        radius = r[-1]
        for direction in (-1.0, 1j):
            z = direction * r
            half = self.stability(z / 2.0) ** 2
            err = half - np.exp(z)
            ratio = np.abs((half - self.stability(z)) / np.where(err == 0, 1.0, err))
            # where the half steps' error is at round-off the computed ratio is noise: that is the
            # asymptotic regime, where the ratio is d0
            noise = np.abs(err) <= 1e-11 * np.maximum(1.0, np.abs(np.exp(z)))
            off = ~noise & ((ratio < 0.5 * d0) | (ratio > 2.0 * d0))
            if off.any():
                radius = min(radius, r[np.argmax(off)])
        return float(radius)

    @property
    def r_infinity(self) -> int:
        """``R(∞) = (-1)^(s-1)`` of IIIA: the factor by which a λ error is carried per step."""
        return -1 if self.s % 2 == 0 else 1

    def __repr__(self) -> str:
        return f"LobattoPair(s={self.s})"


def _pade(k: int, m: int) -> tuple[np.ndarray, np.ndarray]:
    """``(N, D)``, read-only, lowest degree first: the (k, m) Padé approximant of e^z,
    ``N_j = (k+m−j)! k! / ((k+m)! j! (k−j)!)``, ``D_j = (−1)^j (k+m−j)! m! / ((k+m)! j! (m−j)!)``."""
    from math import factorial

    def coefficients(degree, sign):
        return np.array([sign**j * (factorial(k + m - j) * factorial(degree)
                                    / (factorial(k + m) * factorial(j) * factorial(degree - j)))
                         for j in range(degree + 1)])

    num, den = coefficients(k, 1.0), coefficients(m, -1.0)
    for x in (num, den):
        x.setflags(write=False)
    return num, den


@functools.lru_cache(maxsize=None)
def _build_pair(s: int) -> LobattoPair:
    c = lobatto_nodes(s)
    b = lobatto_weights(c)
    a = lobatto_iiia(c)
    a_hat = lobatto_iiib(a, b)
    return LobattoPair(s=s, c=c, b=b, a=a, a_hat=a_hat)


def lobatto_pair(s: int) -> LobattoPair:
    """The s-stage Lobatto IIIA-IIIB pair (cached).

    Parameters
    ----------
    s : int
        Number of stages, ``s >= 2``. The pair has order ``2s - 2`` in ``q`` and ``p`` for
        index-2 partitioned DAEs, and order ``s`` (even ``s``) or ``s - 1`` (odd ``s``) in
        the multiplier.

    Returns
    -------
    LobattoPair
        The coefficients ``c, b, A`` (IIIA) and ``A_hat`` (IIIB).

    Raises
    ------
    TypeError
        If ``s`` is not an integer (bools and floats are rejected).
    ValueError
        If ``s < 2``.

    Examples
    --------
    >>> pair = lobatto_pair(3)
    >>> pair.a[1] * 24
    array([ 5.,  8., -1.])
    """
    return _build_pair(_check_stages(s))
