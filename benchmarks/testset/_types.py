"""The records of the test set (:class:`TestProblem`, :class:`Setup`, :class:`FastTest`), the
declaration of a closed-form problem (:func:`closed_form`), and :func:`error`."""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import Any, Callable, NamedTuple

import numpy as np

__all__ = ["FastTest", "Setup", "TestProblem", "closed_form", "error", "reference_at"]


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


class FastTest(NamedTuple):
    """The test suite's constant-step run of a problem: ``stages``, ``n_steps`` over the whole
    interval, and the bound its error must meet (justified in README.md by the measured
    errors)."""

    stages: int
    n_steps: int
    bound: float


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
    ref_accuracy : float
        The reference's own accuracy, in the measure of :func:`error`.
    test : FastTest
        The test suite's constant-step run.
    compare : str
        ``"qp"`` (q and p compared, the default) or ``"q"`` (q only).
    long, stiff : bool
        ``long``: the interval is at least 1000 long; ``stiff``: the problem has fast
        modes, decaying or oscillating (step sizes far above their time scale are of interest).
    reference : callable or None
        ``reference(t) -> (q, p)`` for closed forms (any t); None for tabulated references.
    mechanics : callable or None
        ``mechanics() -> (model, args)``: the same equations as a ``lobattodae.mechanics`` model
        (the problem itself where it was converted from SymPy, else a twin written with
        ``from_lagrangian``), with the same q (and p, unless ``mechanics_momenta``), so that it
        runs natively (``model.native(s)``) against the same reference; None where there is none.
    mechanics_momenta : pair of callables or None
        ``(to_model, to_problem)``, each ``(t, q, p) -> p``, where the model's momenta are not the
        problem's ``p`` (the slider crank carries velocities): the model's initial momenta from
        the problem's, and the problem's ``p`` from the model's results (rows allowed); None where
        they are the same.
    """

    __test__ = False  # not a pytest test class

    name: str
    source: str
    build: Callable[[], Setup]
    t_ref: tuple
    q_ref: tuple
    p_ref: tuple | None
    ref_accuracy: float
    test: FastTest
    compare: str = "qp"
    long: bool = False
    stiff: bool = False
    reference: Callable | None = None
    mechanics: Callable | None = None
    mechanics_momenta: tuple | None = None

    def __post_init__(self):
        if self.compare not in ("q", "qp"):
            raise ValueError(f"compare must be 'q' or 'qp'; got {self.compare!r}")
        if self.compare == "qp" and self.p_ref is None:
            raise ValueError(f"{self.name}: compare='qp' needs p_ref")
        if len(self.q_ref) != len(self.t_ref):
            raise ValueError(f"{self.name}: one row of q_ref per t_ref")


def closed_form(name: str, source: str, example: Callable, params: dict, init: dict, exact: Callable, *,
                t_end: float, t_ref: tuple, ref_accuracy: float, test: FastTest, long: bool = False,
                q_ref: tuple | None = None, p_ref: tuple | None = None) -> TestProblem:
    """A problem of ``lobattodae.examples`` whose reference is a closed form written here:
    the problem is ``example(**params, **init)`` (built once), it starts at ``exact(0)`` and runs
    to ``t_end``; the references at ``t_ref`` are ``exact(t_ref)`` unless given (stored values of
    a slow ``exact``)."""

    @functools.cache
    def build() -> Setup:
        ex = example(**params, **init)
        q0, p0 = exact(0.0)
        return Setup(problem=ex.problem, q0=q0, p0=p0, args=ex.args, t_span=(0.0, t_end))

    if q_ref is None:
        q, p = exact(np.array(t_ref))
        q_ref, p_ref = tuple(map(tuple, q)), tuple(map(tuple, p))
    return TestProblem(name, source, build, t_ref, q_ref, p_ref, ref_accuracy, test, long=long, reference=exact)


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
