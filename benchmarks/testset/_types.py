"""The records of the test set: :class:`TestProblem` and :class:`Setup`, and :func:`error`."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Callable, NamedTuple

import numpy as np

__all__ = ["Setup", "TestProblem", "error", "reference_at"]


class Setup(NamedTuple):
    """What :meth:`TestProblem.build` returns.

    ``problem`` is built once per process and cached (compiled code is cached per problem
    object), ``q0``/``p0`` are consistent initial values (``φ = 0``, and ``ψ = 0`` where the
    problem has position constraints), ``args`` is passed to ``lobattodae.solve``.
    """

    problem: Any
    q0: np.ndarray
    p0: np.ndarray
    args: Any
    t_span: tuple[float, float]


@dataclass(frozen=True)
class TestProblem:
    """One problem of the external test set.

    Attributes
    ----------
    name, source : str
        Registry key; citation (paper / test set, equation numbers).
    build : callable
        ``build() -> Setup``; returns the same object (same ``problem``) on every call.
    t_ref : tuple of float
        The times at which reference values are known.
    q_ref, p_ref : tuple of tuples
        Reference values of all components of q (and p) at each ``t_ref``; ``p_ref`` is None
        where only q is published (then only q is compared).
    compare : str
        ``"qp"`` (q and p compared) or ``"q"`` (q only).
    ref_accuracy : float
        The reference's own accuracy, in the measure of :func:`error`.
    long, stiff : bool
        ``long``: the interval is at least 1000 long; ``stiff``: the problem has fast
        decaying modes (step sizes far above their time scale are of interest).
    reference : callable or None
        ``reference(t) -> (q, p)`` for closed forms (any t); None for tabulated references.
    test_t_end : float or None
        End of the shorter interval the fast test uses (must be one of ``t_ref``); None:
        the test runs over the full ``t_span``.
    test_stages, test_n_steps, test_bound : int, int, float
        The fast test: a constant-step run with this many stages and steps must have
        ``error <= test_bound`` (the bound is justified in README.md by the measured errors).
    notes : str
    """

    __test__ = False  # not a pytest test class

    name: str
    source: str
    build: Callable[[], Setup]
    t_ref: tuple
    q_ref: tuple
    p_ref: tuple | None
    compare: str
    ref_accuracy: float
    long: bool
    stiff: bool
    reference: Callable | None = None
    test_t_end: float | None = None
    test_stages: int = 4
    test_n_steps: int = 100
    test_bound: float = 1e-6
    notes: str = field(default="", repr=False)

    def __post_init__(self):
        if self.compare not in ("q", "qp"):
            raise ValueError(f"compare must be 'q' or 'qp'; got {self.compare!r}")
        if self.compare == "qp" and self.p_ref is None:
            raise ValueError(f"{self.name}: compare='qp' needs p_ref")
        if len(self.q_ref) != len(self.t_ref):
            raise ValueError(f"{self.name}: one row of q_ref per t_ref")

    @property
    def t_end(self) -> float:
        return float(self.build().t_span[1])

    @property
    def y_ref(self) -> tuple:
        """The compared reference values, one row per ``t_ref``: q, followed by p where p is
        compared."""
        if self.compare == "q":
            return tuple(tuple(row) for row in self.q_ref)
        return tuple(tuple(q) + tuple(p) for q, p in zip(self.q_ref, self.p_ref))

    @property
    def n_compared(self) -> int:
        return len(self.q_ref[0]) * (2 if self.compare == "qp" else 1)


def reference_at(entry: TestProblem, t_ref: float) -> tuple[np.ndarray, np.ndarray | None]:
    """``(q_ref, p_ref)`` at one of ``entry.t_ref`` (p_ref None when not compared)."""
    times = np.asarray(entry.t_ref, dtype=float)
    hits = np.flatnonzero(np.isclose(times, t_ref, rtol=1e-12, atol=1e-12))
    if not hits.size:
        raise KeyError(f"{entry.name}: no reference at t = {t_ref!r}; reference times {entry.t_ref}")
    k = int(hits[0])
    q = np.asarray(entry.q_ref[k], dtype=float)
    p = np.asarray(entry.p_ref[k], dtype=float) if entry.compare == "qp" else None
    return q, p


def error(entry: TestProblem, t, q, p) -> float:
    """Max over the compared components and the reference times inside ``t`` of
    ``|y − y_ref| / (1 + |y_ref|)``.

    ``t`` is a time (then ``q``, ``p`` have shape (n,)) or the times of a trajectory (then
    shape (N, n)); every reference time that occurs among them is compared (at least one
    must). Only q is compared when ``entry.compare == "q"`` (``p`` may then be None).
    """
    t = np.atleast_1d(np.asarray(t, dtype=float))
    q = np.asarray(q, dtype=float).reshape(t.size, -1)
    p = None if p is None else np.asarray(p, dtype=float).reshape(t.size, -1)
    worst, found = 0.0, 0
    for tr in entry.t_ref:
        rows = np.flatnonzero(np.isclose(t, tr, rtol=1e-12, atol=1e-12))
        if not rows.size:
            continue
        found += 1
        i = int(rows[-1])
        q_ref, p_ref = reference_at(entry, tr)
        pairs = [(q[i], q_ref)]
        if p_ref is not None:
            if p is None:
                raise ValueError(f"{entry.name}: p is compared; pass p")
            pairs.append((p[i], p_ref))
        for y, y_ref in pairs:
            worst = max(worst, float(np.max(np.abs(y - y_ref) / (1.0 + np.abs(y_ref)))))
    if not found:
        raise ValueError(f"{entry.name}: none of the reference times {entry.t_ref} is among the given times")
    return worst
