"""Convergence studies: global errors over step sizes and observed orders per component."""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from typing import Any, Callable, Mapping, Sequence

import numpy as np

from ._errors import LobattoDAEInputError
from ._solve import solve
from ._stepper import LobattoIIIAIIIB

__all__ = ["N_FIT", "ConvergenceStudy", "convergence_study", "default_step_counts", "fit_window", "observed_order", "order_text"]

COMPONENTS = ("q", "p", "lam")
#: Errors below PLATEAU_REL[c] * (1 + max |c|) are treated as round-off and not fitted. The
#: round-off level of q and p is ~1e-15 relative; λ = Λ_s is solved through Z = hΛ, so its
#: round-off level grows like eps / h.
PLATEAU_REL = {"q": 1e-13, "p": 1e-13, "lam": 1e-11}


#: How many of the smallest step sizes above the round-off floor an order fit uses.
N_FIT = 4


def fit_window(h: Sequence[float], err: Sequence[float], floor: float = 0.0, n_fit: int = N_FIT) -> np.ndarray:
    """The indices of the points :func:`observed_order` fits: of the points with a finite
    ``err > floor`` (above the round-off plateau), the ``n_fit`` smallest step sizes (the
    asymptotic regime; coarse steps can be pre-asymptotic), in increasing h.

    Parameters
    ----------
    h, err, floor, n_fit
        As for :func:`observed_order`.

    Returns
    -------
    numpy.ndarray of int
        Indices into ``h`` and ``err`` (fewer than ``n_fit`` where fewer points lie above the floor).
    """
    h = np.asarray(h, float)
    err = np.asarray(err, float)
    keep = np.flatnonzero(np.isfinite(err) & (err > floor) & (err > 0))
    return keep[np.argsort(h[keep], kind="stable")][:n_fit]


def observed_order(h: Sequence[float], err: Sequence[float], floor: float = 0.0, n_fit: int = N_FIT) -> float:
    """Observed order: least-squares slope of ``log err`` against ``log h``.

    Only points with ``err > floor`` (above the round-off plateau) are used, and of those the
    ``n_fit`` smallest step sizes (the asymptotic regime; coarse steps can be pre-asymptotic):
    :func:`fit_window`.

    Parameters
    ----------
    h : sequence of float
        Step sizes.
    err : sequence of float
        The global error for each step size; NaN (a failed run) and 0 are left out.
    floor : float, optional
        Errors at or below it count as round-off and are left out (default 0).
    n_fit : int, optional
        How many of the smallest remaining step sizes the fit uses (default :data:`N_FIT`).

    Returns
    -------
    float
        The fitted slope; NaN when fewer than two points lie above the floor (the component
        is exact, or at round-off for every step size).
    """
    keep = fit_window(h, err, floor, n_fit)
    if keep.size < 2:
        return float("nan")
    slope, _ = np.polyfit(np.log(np.asarray(h, float)[keep]), np.log(np.asarray(err, float)[keep]), 1)
    return float(slope)


def order_text(observed: float, errors: Sequence[float], floor: float) -> str:
    """An observed order as the table shows it: the fitted value; ``"exact"`` only where the
    order is NaN because every error is at the round-off floor (the component is exact); and
    ``"n/a"`` where it is NaN for want of points (fewer than two step counts with errors
    above the floor, or failed runs, whose NaN errors are no evidence of exactness)."""
    if np.isfinite(observed):
        return f"{observed:.2f}"
    errors = np.asarray(errors, float).ravel()
    errors = errors[np.isfinite(errors)]
    if errors.size and np.all(errors <= floor):
        return "exact"
    return "n/a"


def default_step_counts(stages: int, t_span_length: float = 2.0) -> tuple[int, ...]:
    """Step counts for a study of an s-stage method on a problem of O(1) time scale.

    Wide enough that q and p of high-order methods reach the round-off plateau while λ (of
    lower order) is still resolved in its asymptotic regime.
    """
    if stages == 2:
        counts = (16, 24, 32, 48, 64, 96, 128, 192, 256)
    elif stages == 3:
        counts = (8, 12, 16, 24, 32, 48, 64, 96, 128)
    else:
        counts = (4, 5, 6, 8, 10, 12, 16, 24, 32, 48, 64)
    scale = max(1.0, t_span_length / 2.0)
    return tuple(int(round(n * scale)) for n in counts)


@dataclass(frozen=True)
class ConvergenceStudy:
    """Errors and observed orders of a convergence study.

    Attributes
    ----------
    name : str
    stages : tuple of int
    n_steps : dict s -> array of step counts
    h : dict s -> array of step sizes
    errors : dict s -> dict component -> array of global errors (max over the grid of the
        max-norm error against the exact solution; at the final time against a reference)
    reference : str
        What the errors are measured against: ``"exact"`` (the exact solution) or
        ``"reference"`` (a finer run with one more stage).
    floors : dict component -> round-off floor used in the fits
    observed : dict s -> dict component -> fitted order (NaN: none could be fitted; the table
        says "exact" only where every error is at the round-off floor, see :func:`order_text`)
    expected : dict s -> dict component -> order predicted by the paper's Corollary, or the
        example's recorded superconvergent order (None: exact to round-off)
    constraint_residual : dict s -> max ‖φ‖∞ over all runs with s stages
    notes : str
        A remark printed under the table (empty: none).
    """

    name: str
    stages: tuple[int, ...]
    n_steps: Mapping[int, np.ndarray]
    h: Mapping[int, np.ndarray]
    errors: Mapping[int, Mapping[str, np.ndarray]]
    floors: Mapping[str, float]
    observed: Mapping[int, Mapping[str, float]]
    expected: Mapping[int, Mapping[str, int]]
    constraint_residual: Mapping[int, float]
    reference: str = "exact"
    notes: str = field(default="")

    def table(self, more: str = "give more step counts (n_steps)") -> str:
        """Observed vs theoretical orders, one row per s, as text.

        Parameters
        ----------
        more : str, optional
            The advice printed under ``n/a`` orders (the command line names its own option).

        Returns
        -------
        str
            The table, with a legend for ``n/a`` and ``exact`` entries and the notes.
        """
        lines = [
            f"Convergence study: {self.name} (errors against the {self.reference} solution)",
            f"{'s':>3} | {'q obs':>6} {'theory':>6} | {'p obs':>6} {'theory':>6} | "
            f"{'lam obs':>7} {'theory':>6} | {'max|phi|':>9}",
            "-" * 74,
        ]
        used: set[str] = set()
        for s in self.stages:
            o = {
                c: order_text(self.observed[s][c], self.errors[s][c], self.floors.get(c, 0.0))
                for c in COMPONENTS
            }
            e = {c: ("exact" if self.expected[s][c] is None else self.expected[s][c]) for c in COMPONENTS}
            used.update(o.values())
            lines.append(
                f"{s:>3} | {o['q']:>6} {e['q']:>6} | {o['p']:>6} {e['p']:>6} | "
                f"{o['lam']:>7} {e['lam']:>6} | {self.constraint_residual[s]:9.1e}"
            )
        if "n/a" in used:
            lines.append(
                "n/a: no order can be fitted (fewer than two step counts with errors above round-off, "
                f"or failed runs); {more}"
            )
        if "exact" in used:
            lines.append("exact: every error is at the round-off floor")
        if self.notes:
            lines.append(f"note: {self.notes}")
        return "\n".join(lines)

    def __str__(self) -> str:
        return self.table()

    def to_dict(self) -> dict[str, Any]:
        """The study as plain Python data that :mod:`json` can write.

        Returns
        -------
        dict
            ``name``, ``reference``, ``stages``, ``floors``, ``notes`` and, under ``runs``, per
            number of stages (as a string key) the step counts, step sizes, errors, observed
            and expected orders and the largest constraint residual; NaN and infinite numbers
            become None.
        """

        def conv(x):
            if isinstance(x, np.ndarray):
                return [conv(v) for v in x.tolist()]
            if isinstance(x, float) and not np.isfinite(x):
                return None
            return x

        return {
            "name": self.name,
            "reference": self.reference,
            "stages": list(self.stages),
            "runs": {
                str(s): {
                    "n_steps": conv(np.asarray(self.n_steps[s])),
                    "h": conv(np.asarray(self.h[s], float)),
                    "errors": {c: conv(np.asarray(self.errors[s][c], float)) for c in COMPONENTS},
                    "observed_order": {c: conv(float(self.observed[s][c])) for c in COMPONENTS},
                    "expected_order": dict(self.expected[s]),
                    "max_constraint_residual": float(self.constraint_residual[s]),
                }
                for s in self.stages
            },
            "floors": {c: float(v) for c, v in self.floors.items()},
            "notes": self.notes,
        }

    def to_json(self, path) -> None:
        """Write :meth:`to_dict` to a JSON file.

        Parameters
        ----------
        path : str or path-like
            The file to write (replaced if it exists).
        """
        with open(path, "w") as fh:
            json.dump(self.to_dict(), fh, indent=2)


def convergence_study(
    problem,
    t_span=None,
    q0=None,
    p0=None,
    *,
    stages: Sequence[int] = (2, 3, 4, 5),
    n_steps: Sequence[int] | Mapping[int, Sequence[int]] | None = None,
    exact: Callable | None = None,
    lam0=None,
    args: Any = None,
    method_options: Mapping[str, Any] | None = None,
    name: str | None = None,
    plateau: float | Mapping[str, float] | None = None,
) -> ConvergenceStudy:
    """Run ``solve`` for each number of stages and step count and fit the observed orders.

    ``problem`` may be an :class:`~lobattodae.examples.Example` (then ``t_span``, initial
    values, ``args`` and the exact solution are taken from it) or a problem object with
    explicit ``t_span, q0, p0``.

    With ``exact(t) -> (q, p, lam)`` the error is the maximum over all grid points of the
    max-norm error. Without it, a reference is computed with ``max(stages) + 1`` stages and
    four times the finest step count, and errors are measured at the final time.
    Errors below ``plateau[c] * (1 + max|c|)`` (per component c; a float applies to all)
    count as round-off and are left out of the fits. A run whose Newton iteration fails (a
    step too large for the problem) is recorded with NaN errors and left out of the fits.

    Parameters
    ----------
    problem : Example, PartitionedDAE, NonholonomicSystem or MechanicalSystem
        The problem; an :class:`~lobattodae.examples.Example` also supplies every argument
        below that is left as None, and its expected orders.
    t_span : (float, float), optional
        ``(t0, t1)``; required without an Example.
    q0, p0 : array_like, shape (n,), optional
        Consistent initial values; required without an Example.
    stages : sequence of int, optional
        The numbers of stages s to study (default 2 to 5).
    n_steps : sequence of int, or dict s -> sequence of int, optional
        The step counts, for every s or per s (default: a range for each s wide enough
        that q and p reach the round-off plateau while λ is still resolved).
    exact : callable, optional
        ``exact(t) -> (q, p, lam)`` at an array of times; without it the errors are
        measured against a reference run.
    lam0 : array_like, shape (m,), optional
        Initial multiplier (default: from the hidden constraint).
    args : pytree, optional
        Passed to the problem functions.
    method_options : dict, optional
        Keyword arguments of :class:`~lobattodae.LobattoIIIAIIIB` other than ``stages``.
    name : str, optional
        The study's name (default: the Example's, or the problem's ``name`` attribute).
    plateau : float or dict component -> float, optional
        Relative round-off levels of q, p and λ (default ``PLATEAU_REL``).

    Returns
    -------
    ConvergenceStudy
        Errors, observed orders and the orders expected from the theory (or recorded by
        the Example), per number of stages.

    Raises
    ------
    LobattoDAEInputError
        ``t_span``, ``q0`` or ``p0`` missing without an Example, ``stages`` empty, or bad
        input found by :func:`~lobattodae.solve` (shapes, inconsistent initial values).
    ValueError
        Every run failed, or a number of stages below 2 or a bad ``method_options`` value
        (refused by :class:`~lobattodae.LobattoIIIAIIIB`).
    TypeError
        An unknown ``method_options`` keyword.
    NewtonFailure
        The reference run (without ``exact``) failed.
    """
    expected_order = None
    if hasattr(problem, "problem") and hasattr(problem, "q0"):
        ex = problem
        expected_order = getattr(ex, "expected_order", None)
        problem = ex.problem
        t_span = ex.t_span if t_span is None else t_span
        q0 = ex.q0 if q0 is None else q0
        p0 = ex.p0 if p0 is None else p0
        lam0 = ex.lam0 if lam0 is None else lam0
        args = ex.args if args is None else args
        exact = ex.exact if exact is None else exact
        name = ex.name if name is None else name
    if t_span is None or q0 is None or p0 is None:
        raise LobattoDAEInputError("convergence_study needs t_span, q0 and p0 (or an Example).")
    stages = tuple(int(s) for s in stages)
    if not stages:
        raise LobattoDAEInputError("stages must list at least one number of stages.")
    opts = dict(method_options or {})
    length = float(t_span[1]) - float(t_span[0])

    def counts_for(s):
        if n_steps is None:
            return np.asarray(default_step_counts(s, length))
        if isinstance(n_steps, Mapping):
            return np.asarray(n_steps[s])
        return np.asarray(n_steps)

    runs: dict[int, list] = {}
    for s in stages:
        method = LobattoIIIAIIIB(stages=s, **opts)
        counts = counts_for(s)
        chunk = 1 << (int(max(counts)) - 1).bit_length()  # one compilation per s
        runs[s] = [
            solve(problem, method, t_span, q0, p0, n_steps=int(n), lam0=lam0, args=args, chunk_size=chunk, throw=False)
            for n in counts
        ]

    if exact is not None:
        reference = "exact"

        def err(sol):
            qe, pe, le = exact(sol.t)
            le = np.asarray(le).reshape(sol.lam.shape)
            return {
                "q": float(np.max(np.abs(sol.q - qe))),
                "p": float(np.max(np.abs(sol.p - pe))),
                "lam": float(np.max(np.abs(sol.lam - le))),
            }

        ref_scale = None
    else:
        reference = "reference"
        s_ref = max(stages) + 1
        n_ref = 4 * int(max(max(counts_for(s)) for s in stages))
        ref = solve(problem, LobattoIIIAIIIB(stages=s_ref, **opts), t_span, q0, p0, n_steps=n_ref, lam0=lam0, args=args)

        def err(sol):
            return {
                "q": float(np.max(np.abs(sol.q[-1] - ref.q[-1]))),
                "p": float(np.max(np.abs(sol.p[-1] - ref.p[-1]))),
                "lam": float(np.max(np.abs(sol.lam[-1] - ref.lam[-1]))),
            }

        ref_scale = ref

    any_sol = next((sol for s in stages for sol in runs[s] if sol.success), None)
    if any_sol is None:
        raise ValueError("every run of the convergence study failed; use more steps (n_steps).")
    sample = ref_scale if ref_scale is not None else any_sol
    if plateau is None:
        plateau = PLATEAU_REL
    rel = {c: float(plateau[c]) if isinstance(plateau, Mapping) else float(plateau) for c in COMPONENTS}
    floors = {c: rel[c] * (1.0 + float(np.max(np.abs(getattr(sample, c))))) for c in COMPONENTS}

    h_out, n_out, e_out, obs, expct, cres = {}, {}, {}, {}, {}, {}
    for s in stages:
        sols = runs[s]
        n_out[s] = np.asarray([len(sol.t) - 1 for sol in sols])
        h_out[s] = np.asarray([sol.stats["h"] for sol in sols])
        nan = {c: float("nan") for c in COMPONENTS}
        errs = [err(sol) if sol.success else nan for sol in sols]
        e_out[s] = {c: np.asarray([e[c] for e in errs]) for c in COMPONENTS}
        obs[s] = {c: observed_order(h_out[s], e_out[s][c], floors[c]) for c in COMPONENTS}
        expct[s] = {
            c: (expected_order(c, s) if expected_order is not None else LobattoIIIAIIIB(stages=s).order()[c])
            for c in COMPONENTS
        }
        cres[s] = float(max(np.max(sol.stats["constraint_residual"]) for sol in sols if sol.success))
    return ConvergenceStudy(
        name=name or getattr(problem, "name", "problem"),
        stages=stages,
        n_steps=n_out,
        h=h_out,
        errors=e_out,
        floors=floors,
        observed=obs,
        expected=expct,
        constraint_residual=cres,
        reference=reference,
    )
