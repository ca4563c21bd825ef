"""The :class:`Example` record and shared helpers for the example problems."""

from __future__ import annotations

import math
import types
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from .. import _compile
from .._tableau import lobatto_pair
from .._problem import consistent_lambda, hidden_constraint

__all__ = ["Example", "COMPONENTS"]

#: Solution components whose convergence orders are tracked.
COMPONENTS = ("q", "p", "lam")

#: The quadrature used for closed forms that need one (the Chaplygin sleigh's x, y):
#: a composite Gauss-Legendre rule with this many nodes per panel (exact for polynomials of
#: degree 39); panels are short compared with the distance to the nearest complex
#: singularity of the integrand, so the rule is accurate to round-off.
GAUSS_NODES = 20


def _vector(x: Any, name: str) -> np.ndarray:
    a = np.array(x, dtype=np.float64)
    if a.ndim != 1:
        raise ValueError(f"{name} must be a 1-D array; got shape {a.shape}")
    if not np.all(np.isfinite(a)):
        raise ValueError(f"{name} must be finite; got {a}")
    a.setflags(write=False)
    return a


@dataclass(frozen=True, eq=False)
class Example:
    """A test problem with consistent initial values, parameters, first integrals and,
    where known, the exact solution.

    Parameters
    ----------
    name : str
        Registry name (CLI-friendly), e.g. ``"knife-edge"``.
    problem : NonholonomicSystem or MechanicalSystem or PartitionedDAE
        The DAE. The user functions read every physical parameter from ``args``, and the
        problem object is shared by all examples of the same family, so one compiled
        solver serves every parameter value.
    t_span : tuple of float
        ``(t0, t_end)``; every example starts at ``t0 = 0``.
    q0, p0 : ndarray, shape (n,)
        Initial values with ``φ(t0, q0, p0) = 0``.
    lam0 : ndarray, shape (m,)
        Consistent multiplier: the hidden constraint holds at ``(t0, q0, p0, lam0)``.
    args : pytree
        Parameters passed as ``args`` to the problem functions (a NamedTuple of floats).
    invariants : Mapping[str, callable]
        First integrals ``I(t, q, p, args) -> scalar`` in ``jax.numpy`` (vmappable over a
        trajectory); always contains ``"energy"``.
    exact : callable or None
        ``exact(t) -> (q, p, lam)``. For an array ``t`` of shape ``(N,)`` the results are
        time-major NumPy arrays of shapes ``(N, n)``, ``(N, n)``, ``(N, m)``; for a scalar
        ``t`` they are 1-D. ``None`` where no closed form is known.
    description : str
        One line, for listings.
    notes : str
        Free-form remarks (known superconvergence, suitable uses).
    expected_order_overrides : Mapping[str, Mapping[int, float or None]]
        Known deviations from the proven orders (``LobattoPair.order()``), per component (``"q"``, ``"p"``,
        ``"lam"``) and number of stages ``s``, for the error measured as the maximum over
        all step points of a constant-step run over ``t_span``: a number is the (higher)
        order observed, ``None`` means the component is exact up to round-off for that
        ``s`` (no order can be measured). Only cases that were checked are listed; see
        ``notes`` for effects that depend on how the error is measured.
    """

    name: str
    problem: Any
    t_span: tuple[float, float]
    q0: np.ndarray
    p0: np.ndarray
    lam0: np.ndarray
    args: Any
    invariants: Mapping[str, Callable[..., Any]]
    exact: Callable[[Any], tuple[np.ndarray, np.ndarray, np.ndarray]] | None = None
    description: str = ""
    notes: str = ""
    expected_order_overrides: Mapping[str, Mapping[int, float | None]] = field(
        default_factory=dict
    )

    def __post_init__(self) -> None:
        if not isinstance(self.name, str) or not self.name:
            raise ValueError(f"name must be a non-empty string; got {self.name!r}")
        for attr in ("f", "g", "phi"):
            if not callable(getattr(self.problem, attr, None)):
                raise TypeError(
                    f"Example {self.name!r}: problem must define f, g and phi "
                    f"(a PartitionedDAE, NonholonomicSystem or MechanicalSystem); got "
                    f"{type(self.problem).__name__}"
                )
        try:
            t0, t1 = (float(v) for v in self.t_span)
        except (TypeError, ValueError):
            raise ValueError(
                f"Example {self.name!r}: t_span must be a pair of floats; got {self.t_span!r}"
            ) from None
        if not (math.isfinite(t0) and math.isfinite(t1) and t1 > t0):
            raise ValueError(
                f"Example {self.name!r}: t_span must be finite with t_end > t0; got {(t0, t1)}"
            )
        object.__setattr__(self, "t_span", (t0, t1))
        q0 = _vector(self.q0, "q0")
        p0 = _vector(self.p0, "p0")
        lam0 = _vector(self.lam0, "lam0")
        if q0.shape != p0.shape:
            raise ValueError(
                f"Example {self.name!r}: q0 and p0 must have the same shape; got "
                f"{q0.shape} and {p0.shape}"
            )
        object.__setattr__(self, "q0", q0)
        object.__setattr__(self, "p0", p0)
        object.__setattr__(self, "lam0", lam0)
        invariants = dict(self.invariants)
        if "energy" not in invariants:
            raise ValueError(f"Example {self.name!r}: invariants must contain 'energy'")
        for key, fn in invariants.items():
            if not callable(fn):
                raise TypeError(f"Example {self.name!r}: invariant {key!r} is not callable")
        object.__setattr__(self, "invariants", types.MappingProxyType(invariants))
        if self.exact is not None and not callable(self.exact):
            raise TypeError(f"Example {self.name!r}: exact must be callable or None")
        overrides = {}
        for comp, table in dict(self.expected_order_overrides).items():
            if comp not in COMPONENTS:
                raise ValueError(
                    f"Example {self.name!r}: expected_order_overrides keys must be in "
                    f"{COMPONENTS}; got {comp!r}"
                )
            checked = {}
            for s, order in dict(table).items():
                lobatto_pair(s)  # validates s
                if order is not None and not (isinstance(order, (int, float)) and order > 0):
                    raise ValueError(
                        f"Example {self.name!r}: order override for {comp}, s={s} must be "
                        f"a positive number or None; got {order!r}"
                    )
                checked[int(s)] = order
            overrides[comp] = types.MappingProxyType(checked)
        object.__setattr__(
            self, "expected_order_overrides", types.MappingProxyType(overrides)
        )

    # ------------------------------------------------------------------ properties
    @property
    def n(self) -> int:
        """Dimension of q and p."""
        return int(self.q0.shape[0])

    @property
    def m(self) -> int:
        """Number of constraints (dimension of λ)."""
        return int(self.lam0.shape[0])

    @property
    def t0(self) -> float:
        """Initial time, ``t_span[0]``."""
        return self.t_span[0]

    @property
    def t_end(self) -> float:
        """Final time, ``t_span[1]``."""
        return self.t_span[1]

    @property
    def has_exact(self) -> bool:
        """Whether the exact solution is known (``exact`` is not None)."""
        return self.exact is not None

    # --------------------------------------------------------------------- methods
    def expected_order(self, component: str, s: int) -> float | None:
        """The order expected for ``component`` with the s-stage pair on this example.

        Parameters
        ----------
        component : {"q", "p", "lam"}
            The solution component.
        s : int
            The number of stages, ``s >= 2``.

        Returns
        -------
        float or None
            The method's proven order (``LobattoPair.order()``) unless
            ``expected_order_overrides`` says otherwise; ``None`` means "exact up to
            round-off, no order measurable".

        Raises
        ------
        ValueError
            An unknown ``component``, or ``s < 2``.
        TypeError
            ``s`` is not an integer.
        """
        if component not in COMPONENTS:
            raise ValueError(f"component must be one of {COMPONENTS}; got {component!r}")
        default = lobatto_pair(s).order()[component]
        table = self.expected_order_overrides.get(component, {})
        return table.get(int(s), default)

    def consistency_residuals(self, t=None, q=None, p=None, lam=None) -> dict[str, float]:
        """How consistent a state is: max-norm residuals of ``φ(t, q, p)`` (key
        ``"phi"``), of the hidden constraint at ``(t, q, p, lam)`` (``"hidden"``) and
        of ``lam`` minus :func:`~lobattodae.consistent_lambda` (``"lam"``).

        Compiled once per problem and shapes.

        Parameters
        ----------
        t : float, optional
            Time (default ``t0``).
        q, p : array_like, shape (n,), optional
            The state (default ``q0``, ``p0``).
        lam : array_like, shape (m,), optional
            The multiplier (default ``lam0``).

        Returns
        -------
        dict
            ``{"phi": ..., "hidden": ..., "lam": ...}``, floats; without arguments the
            residuals of the initial values ``(t0, q0, p0, lam0)``.
        """
        t = self.t0 if t is None else t
        q = self.q0 if q is None else q
        p = self.p0 if p is None else p
        lam = self.lam0 if lam is None else lam
        t, q, p, lam = (jnp.asarray(a, dtype=jnp.float64) for a in (t, q, p, lam))
        phi, hid, lam_c = _residuals(self.problem, t, q, p, lam, self.args)
        return {
            "phi": float(jnp.max(jnp.abs(phi), initial=0.0)),
            "hidden": float(jnp.max(jnp.abs(hid), initial=0.0)),
            "lam": float(jnp.max(jnp.abs(lam_c - lam), initial=0.0)),
        }

    def invariant_values(self, t, q, p) -> dict[str, np.ndarray]:
        """The first integrals along a trajectory.

        Parameters
        ----------
        t : array_like, shape (N,)
            Times.
        q, p : array_like, shape (N, n)
            The trajectory, time-major (e.g. ``sol.q``, ``sol.p`` of a
            :class:`~lobattodae.Solution`).

        Returns
        -------
        dict
            Name (``"energy"`` and the others of ``invariants``) -> NumPy array of shape
            ``(N,)``.

        Raises
        ------
        ValueError
            The shapes do not fit together.
        """
        t = jnp.asarray(t, dtype=jnp.float64)
        q = jnp.asarray(q, dtype=jnp.float64)
        p = jnp.asarray(p, dtype=jnp.float64)
        if not (t.ndim == 1 and q.ndim == 2 and q.shape == p.shape and q.shape[0] == t.size):
            raise ValueError(
                "invariant_values expects t of shape (N,) and q, p of shape (N, n); got "
                f"{t.shape}, {q.shape}, {p.shape}"
            )
        return {
            key: np.asarray(_invariant_along(fn, t, q, p, self.args))
            for key, fn in self.invariants.items()
        }

    def __repr__(self) -> str:
        return (
            f"Example(name={self.name!r}, n={self.n}, m={self.m}, t_span={self.t_span}, "
            f"exact={'yes' if self.has_exact else 'no'}, args={self.args!r})"
        )


# ------------------------------------------------------------------------- helpers
def vectorised(core: Callable[[np.ndarray], tuple[np.ndarray, ...]]) -> Callable:
    """Wrap ``core(t: (N,)) -> (q, p, lam)`` so that a scalar ``t`` gives 1-D arrays."""

    def exact(t):
        tt = np.asarray(t, dtype=np.float64)
        if tt.ndim > 1:
            raise ValueError(f"exact(t) takes a scalar or a 1-D array; got shape {tt.shape}")
        scalar = tt.ndim == 0
        q, p, lam = core(np.atleast_1d(tt))
        # (+ 0.0 turns -0.0 into 0.0, for tidy printing)
        q, p, lam = (np.ascontiguousarray(a, dtype=np.float64) + 0.0 for a in (q, p, lam))
        if scalar:
            return q[0], p[0], lam[0]
        return q, p, lam

    exact.__doc__ = core.__doc__
    return exact


@_compile.jit(static_argnums=0)
def _residuals(problem, t, q, p, lam, args):
    phi = problem.phi(t, q, p, args)
    hid = hidden_constraint(problem, t, q, p, lam, args)
    return phi, hid, consistent_lambda(problem, t, q, p, lam, args)


@_compile.jit(static_argnums=0)
def _invariant_along(fn, t, q, p, args):
    return jax.vmap(fn, in_axes=(0, 0, 0, None))(t, q, p, args)


# Compiled once per problem object (problems hash by identity) and shapes; the
# parameters in ``args`` are traced, so every parameter value reuses the compilation.
_consistent_lambda = _compile.jit(consistent_lambda, static_argnums=0)


def consistent_lambda0(problem, q0, p0, args, m: int) -> np.ndarray:
    """λ0 from the hidden constraint at ``t0 = 0`` (one Newton step is exact for
    nonholonomic systems; two more are harmless)."""
    lam = _consistent_lambda(
        problem,
        jnp.asarray(0.0),
        jnp.asarray(q0, dtype=jnp.float64),
        jnp.asarray(p0, dtype=jnp.float64),
        jnp.zeros(m, dtype=jnp.float64),
        args,
    )
    return np.asarray(lam, dtype=np.float64)


def positive(name: str, value: float) -> float:
    value = float(value)
    if not (math.isfinite(value) and value > 0):
        raise ValueError(f"{name} must be a positive finite number; got {value}")
    return value


def finite(name: str, value: float) -> float:
    value = float(value)
    if not math.isfinite(value):
        raise ValueError(f"{name} must be finite; got {value}")
    return value


def t_span_to(t_end: float) -> tuple[float, float]:
    return (0.0, positive("t_end", t_end))


def cumulative_integral(rate: Callable[[np.ndarray], np.ndarray], t: np.ndarray,
                        panel: float) -> np.ndarray:
    """``∫_0^t rate(s) ds`` for every entry of ``t`` (shape ``(N,)``).

    ``rate`` maps times of shape ``(K,)`` to values of shape ``(K, d)``. The sorted
    distinct times (and 0) are joined by composite Gauss-Legendre panels of length at
    most ``panel``; the pieces are summed cumulatively in extended precision, so the cost
    is linear in ``N`` plus the length of the interval.
    """
    t = np.asarray(t, dtype=np.float64)
    nodes = np.unique(np.concatenate([t, [0.0]]))
    i0 = int(np.searchsorted(nodes, 0.0))
    a, b = nodes[:-1], nodes[1:]
    x, w = np.polynomial.legendre.leggauss(GAUSS_NODES)
    d = np.asarray(rate(np.zeros(1))).shape[1]
    cum = np.zeros((nodes.size, d), dtype=np.longdouble)
    if a.size:
        counts = np.maximum(1, np.ceil((b - a) / panel).astype(np.int64))
        gap = np.repeat(np.arange(a.size), counts)
        starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
        j = np.arange(gap.size) - np.repeat(starts, counts)
        lo = a[gap] + (b[gap] - a[gap]) * (j / counts[gap])
        hi = np.where(
            j + 1 == counts[gap], b[gap], a[gap] + (b[gap] - a[gap]) * ((j + 1) / counts[gap])
        )
        half = 0.5 * (hi - lo)
        mid = 0.5 * (hi + lo)
        s = (mid[:, None] + half[:, None] * x[None, :]).reshape(-1)
        vals = np.asarray(rate(s), dtype=np.float64).reshape(gap.size, x.size, d)
        pieces = np.einsum("k,pkd->pd", w, vals) * half[:, None]
        per_gap = np.add.reduceat(pieces.astype(np.longdouble), starts, axis=0)
        cum[i0 + 1 :] = np.cumsum(per_gap[i0:], axis=0)
        if i0 > 0:
            cum[:i0] = -np.cumsum(per_gap[:i0][::-1], axis=0)[::-1]
    return cum[np.searchsorted(nodes, t)].astype(np.float64)
