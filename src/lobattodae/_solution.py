"""The result of :func:`~lobattodae.solve`: :class:`Solution`, its ``stats`` keys and scipy's
status codes, and :func:`assemble`, which makes one from a run's rows and final state.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ._chunks import Progress
from ._controllers import ROUNDOFF_FLOOR, PIController, roundoff_may_exceed
from ._reversible import ReversibleStepSize
from ._dense import DenseOutput, stacked
from ._errors import NewtonFailure
from ._loop import State
from ._options import RunOptions
from ._results import Result
from ._rows import Record, split_event_rows

__all__ = ["SCIPY_STATUS", "STATS", "Solution", "assemble"]

#: The keys of ``Solution.stats`` (the one place they are documented). "Rows" are the output
#: rows after the initial one: step points (every ``save_every``-th) or ``t_eval`` times.
STATS = {
    "newton_iterations": "(rows,) Newton iterations of the step that produced each row",
    "residual_norm": "(rows,) max-norm of that step's last Newton residual",
    "constraint_residual": "(N+1,) ‖φ(t_k, q_k, p_k)‖∞ at the output rows (with t_eval: between steps, on the dense output)",
    "multiplier_drift": "(N+1,) ‖λ_k − λ(t_k, q_k, p_k)‖∞ of the step that produced each row",
    "lam_resync": "(rows,) bool: that step started from λ(t_k, q_k, p_k) (lam_start='auto' re-synchronised λ)",
    "lam_resets": "number of re-synchronisations of λ in the output rows (lam_start='auto')",
    "lam_excursions": "steps where the drift left its normal band (re-synchronised with 'auto', only counted otherwise)",
    "max_constraint_residual": "max ‖φ‖∞ over every step point (saved or not) and every row returned (t_eval rows "
                               "lie between step points)",
    "max_multiplier_drift": "max ‖λ − λ(t, q, p)‖∞ over every step point",
    "n_jacobians": "Newton Jacobian evaluations (each with one factorisation)",
    "n_newton": "Newton iterations in all",
    "n_steps": "accepted steps",
    "n_rejected": "rejected step attempts (error test or Newton failure; adaptive steps)",
    "h": "the constant step size, or None for adaptive steps",
    "n_clamped": "ReversibleStepSize: steps whose control variable ρ was clamped (MAX_DENSITY_CHANGE), each one "
                 "unsymmetric, so 0 for a reversible run; None for other step-size rules",
    "n_roundoff_limited": "PIController (step doubling): accepted steps whose error passed the test only because no "
                          "step is asked for less than its round-off (ROUNDOFF_FLOOR); None for other step-size rules",
    "n_checked": "PIController (step doubling): attempts rejected to check their estimate on a step of half the "
                 "size (counted in n_rejected; PIController(check_large_steps)); None for other step-size rules",
    "n_failed_solves": "PIController: attempts rejected because a stage solve failed (Newton did not converge, or "
                       "values not finite); counted in n_rejected; None for other step-size rules",
    "n_unresolved": "PIController (step doubling): accepted steps whose estimate lay along modes beyond the "
                    "tableau's richardson_radius, whose size the method's stability set rather than its accuracy "
                    "(where most steps are such, the error can be far below rtol); None for other step-size rules",
    "failed_step": "index of the failed step, or None",
    "recoveries": "failed steps retried as substeps (max_recoveries, constant steps)",
    "compile_and_run_time": "wall time of the integration loop, compilation included (s)",
}


@dataclass(frozen=True, eq=False)
class Solution:
    """The result of :func:`solve` (time-major NumPy arrays, with scipy's views beside them).

    Attributes
    ----------
    t : ndarray, shape (k,)
        The initial time and the kept step points, or the ``t_eval`` times.
    q, p : ndarray, shape (k, n)
    lam : ndarray, shape (k, m)
        The multiplier λ_k at t_k (λ_0 is the consistent initial value).
    success : bool
        The run reached the end of the interval or a terminal event.
    result : Result
        ``SUCCESSFUL``, ``EVENT`` (a terminal event), ``ROUNDOFF_LIMITED`` (the end was reached but
        rtol asked the steps for less than their round-off, see :class:`Result`) or the reason the
        run stopped early.
    message : str
        The reason in words (``result.message``).
    stats : dict
        Counters and per-row diagnostics; the keys are documented in :data:`STATS`
        (``lobattodae.STATS``). When the solve stopped early the arrays hold the computed prefix.
    t_events, q_events, p_events, lam_events : list of ndarray or None
        One array per event function: the times and states of its zeros (None without
        events).
    sol : DenseOutput or None
        ``sol(t) -> (q, p, lam)`` between the step points (``dense_output=True``);
        ``sol(t, layout="scipy")`` returns scipy's stacked ``(2n + m, k)`` layout.
    problem, method, args
        What was solved, for diagnostics.
    y : ndarray, shape (2n + m, k)
        ``[q; p; λ]`` stacked as ``scipy.integrate.solve_ivp`` lays out ``y``, one column per
        time (a view computed on access, like the five below).
    y_events : list of ndarray or None
        One (k_j, 2n + m) array per event function, the rows ``[q, p, λ]`` at its zeros, as
        ``solve_ivp``'s ``y_events`` (None without events).
    status : int
        scipy's status: 0 the end of the interval was reached, 1 a terminal event, −1 the run
        stopped early (the reason is ``result``).
    nfev : int
        Evaluations of the right-hand side (f, g) at a stage point in Newton's iterations
        (``stats["n_newton"]`` × s).
    njev : int
        Jacobians of the stage equations (``stats["n_jacobians"]``).
    nlu : int
        LU factorisations, one per Jacobian (``stats["n_jacobians"]``).

    Examples
    --------
    >>> sol = L.solve(problem, L.LobattoIIIAIIIB(stages=4), (0.0, 2.0), q0, p0)  # doctest: +SKIP
    >>> sol.y.shape                       # (2n + m, k), as solve_ivp lays it out  # doctest: +SKIP
    >>> sol.status, sol.result.name       # 0, 'SUCCESSFUL'  # doctest: +SKIP
    """

    t: np.ndarray
    q: np.ndarray
    p: np.ndarray
    lam: np.ndarray
    success: bool
    result: Result
    message: str
    stats: dict = field(repr=False)
    problem: Any = field(repr=False, default=None)
    method: Any = field(repr=False, default=None)
    args: Any = field(repr=False, default=None)
    t_events: list | None = field(repr=False, default=None)
    q_events: list | None = field(repr=False, default=None)
    p_events: list | None = field(repr=False, default=None)
    lam_events: list | None = field(repr=False, default=None)
    sol: DenseOutput | None = field(repr=False, default=None)

    # -- scipy's views -------------------------------------------------------------------------
    @property
    def status(self) -> int:
        """scipy's status: 0 the end of the interval was reached, 1 a terminal event, −1 the run
        stopped early (the reason is :attr:`result`)."""
        return SCIPY_STATUS.get(self.result, -1)

    @property
    def y(self) -> np.ndarray:
        """``[q; p; λ]`` stacked as ``solve_ivp`` lays out ``y``: shape (2n + m, k), one column per time."""
        return stacked(self.q, self.p, self.lam).T

    @property
    def y_events(self) -> list | None:
        """One (k_j, 2n + m) array per event function, the rows ``[q, p, λ]`` at its zeros (None
        without events), as ``solve_ivp``'s ``y_events``."""
        if self.t_events is None:
            return None
        return [stacked(q, p, lam) for q, p, lam in zip(self.q_events, self.p_events, self.lam_events)]

    @property
    def nfev(self) -> int:
        """Evaluations of the right-hand side (f, g) at a stage point in Newton's iterations
        (s per iteration: ``stats["n_newton"]`` × s)."""
        return self.stats["n_newton"] * self.method.stages

    @property
    def njev(self) -> int:
        """Jacobians of the stage equations (``stats["n_jacobians"]``)."""
        return self.stats["n_jacobians"]

    @property
    def nlu(self) -> int:
        """LU factorisations: one per Jacobian (``stats["n_jacobians"]``)."""
        return self.stats["n_jacobians"]

    def __repr__(self) -> str:
        return (
            f"Solution(success={self.success}, result={self.result.name}, n_steps={self.stats['n_steps']}, "
            f"t=[{self.t[0]:g}, {self.t[-1]:g}], max constraint residual="
            f"{self.stats['max_constraint_residual']:.2e})"
        )


#: ``Result`` → scipy's ``status``: 0 the end was reached (``ROUNDOFF_LIMITED`` too), 1 a terminal event; every
#: other result is −1.
SCIPY_STATUS = {Result.SUCCESSFUL: 0, Result.ROUNDOFF_LIMITED: 0, Result.EVENT: 1}


def assemble(problem, method, args, opt: RunOptions, q0, p0, lam0, phi0, run: Progress, failed, finished, throw,
              elapsed):
    out = Record(*run.rows.all())
    state = run.state
    # Non-finite values reported as success would be a bug upstream; never let them through.
    finite = np.all(np.isfinite(out.q), axis=1) & np.all(np.isfinite(out.p), axis=1) & np.all(np.isfinite(out.lam), axis=1)
    failed_step, result = None, Result.SUCCESSFUL
    if not np.all(finite):
        n_ok = int(np.flatnonzero(~finite)[0])
        failed_step, result = n_ok, Result.NONFINITE
        out = Record(*(x[:n_ok] for x in out))
    elif failed or not Result(int(state.result)).success:  # failed here, or in the run resumed from
        failed_step, result = int(state.n_accepted), Result(int(state.result))
    elif not finished and opt.capped(state):
        result = Result.MAX_STEPS
    elif not finished:
        result = Result.INTERRUPTED
    elif int(state.result) == Result.EVENT:
        result = Result.EVENT
    pi = isinstance(opt.controller, PIController)
    floored = int(state.controller.n_floored) if pi else None
    roundoff = bool(floored) and roundoff_may_exceed(floored, float(opt.control.rtol))
    if result == Result.SUCCESSFUL and roundoff:
        result = Result.ROUNDOFF_LIMITED
    with_initial = opt.t_eval is None
    t = np.concatenate([[opt.t0], out.t]) if with_initial else out.t

    def column(x0, rows):
        return np.vstack([x0[None], rows]) if with_initial else rows

    def scalar(x0, rows):
        return np.concatenate([[x0], rows]) if with_initial else rows

    excursions = int(state.stepper.monitor.excursions)
    stats = {
        "newton_iterations": out.iterations,
        "residual_norm": out.residual_norm,
        "constraint_residual": scalar(phi0, out.constraint),
        "multiplier_drift": scalar(0.0, out.drift),
        "lam_resync": out.resync,
        "lam_resets": int(np.count_nonzero(out.resync)),
        "lam_excursions": excursions,
        "max_constraint_residual": max(float(state.max_constraint), float(np.max(out.constraint, initial=0.0))),
        "max_multiplier_drift": float(state.max_drift),
        "n_jacobians": int(state.n_jacobians),
        "n_newton": int(state.n_newton),
        "n_steps": int(state.n_accepted),
        "n_rejected": int(state.n_rejected),
        "h": opt.h,
        "n_clamped": int(state.controller.n_clamped) if isinstance(opt.controller, ReversibleStepSize) else None,
        "n_roundoff_limited": floored,
        "n_checked": int(state.controller.n_checked) if isinstance(opt.controller, PIController) else None,
        "n_failed_solves": int(state.controller.n_failed_solves) if pi else None,
        "n_unresolved": int(state.controller.n_unresolved) if pi and opt.controller.estimate == "doubling" else None,
        "failed_step": failed_step,
        "recoveries": run.recoveries,
        "compile_and_run_time": elapsed,
    }
    events = _event_lists(opt, run, q0.shape[-1], lam0.shape[-1])
    sol = None
    if opt.saving.dense:
        (dense,) = run.dense.all()
        sol = DenseOutput(method.pair, dense, method.pieces, q0.shape[-1], lam0.shape[-1], opt.t0, problem, args)
    success = result.success and failed_step is None
    message = result.message
    if roundoff:
        roundoff_note = (
            f"{floored} of the {int(state.n_accepted)} steps asked for less than their round-off: rtol="
            f"{float(opt.control.rtol):.3g} shared over this interval asks each of them for a local error below "
            f"{ROUNDOFF_FLOOR:g}·(1 + |y|), which they were allowed instead, up to {floored * ROUNDOFF_FLOOR:.1e} in all; "
            "the error may exceed rtol. Use more stages (a higher order takes fewer steps) or a looser rtol."
        )
        if result == Result.ROUNDOFF_LIMITED:
            message = f"The end of the integration interval was reached, but {roundoff_note}"
    if failed_step is not None:
        tf, hf = (float(x) for x in opt.controller.proposal(state.controller))
        tried = f" (after {run.recoveries} recovered steps; max_recoveries={opt.max_recoveries})" if opt.max_recoveries else ""
        message = f"Step {failed_step} (t = {tf:.6g}, h = {hf:.3g}) failed{tried}: {result.message}"
        if result == Result.STEP_SIZE_TOO_SMALL:
            message += _zero_scale_hint(opt, state)
        if throw:
            raise NewtonFailure(message, step=failed_step, t=tf, reason=result.name.lower())
    elif result == Result.MAX_STEPS:
        t_now = float(opt.controller.time(state.controller))
        message = (f"The step limit max_steps={opt.max_steps:,} was reached at t = {t_now:.6g}, before the end of the "
                   "interval; the computed prefix is returned. Raise max_steps, or loosen the tolerances.")
    elif result == Result.INTERRUPTED:
        t_now = float(opt.controller.time(state.controller))
        of = f" of {opt.n}" if opt.n is not None else ""
        message = f"Interrupted after {int(state.n_accepted)}{of} steps (t = {t_now:.6g}); the computed prefix is returned."
    if method.lam_start == "previous" and excursions:
        note = drift_note(excursions, float(state.max_drift), out.t, out.drift, opt.t0)
        message = f"{message} Warning: {note}"
        warnings.warn(note, RuntimeWarning, stacklevel=4)  # the caller of solve
    if roundoff:
        if result != Result.ROUNDOFF_LIMITED:  # a run that also stopped for another reason
            message = f"{message} Warning: {roundoff_note}"
        warnings.warn(roundoff_note, RuntimeWarning, stacklevel=4)  # the caller of solve
    return Solution(
        t, column(q0, out.q), column(p0, out.p), column(lam0, out.lam),
        bool(success), result, message, stats, problem, method, args, *events, sol,
    )


def _zero_scale_hint(opt: RunOptions, state: State) -> str:
    """The likely cause of a step size that collapsed under ``atol=0``: a component that is 0 at
    the step point has the error scale ``atol + rtol·|y| = 0``, which no error passes."""
    if not opt.adaptive or not isinstance(opt.controller, PIController) or float(opt.control.atol) != 0.0:
        return ""
    zero = [f"{name}[{i}]" for name, y in (("q", state.q), ("p", state.p)) for i in np.flatnonzero(np.asarray(y) == 0)]
    if not zero:
        return ""
    shown = ", ".join(zero[:4]) + (", ..." if len(zero) > 4 else "")
    return (f" Cause: atol=0 and {shown} = 0 there, so the error scale atol + rtol·|y| of that component is 0 "
            "and no step with an error in it passes the test; give a positive atol (an absolute accuracy for "
            "components that pass through or stay at 0, e.g. atol=1e-12).")


def _event_lists(opt: RunOptions, run: Progress, n: int, m: int):
    """``(t_events, q_events, p_events, lam_events)``: one array per event function (or Nones)."""
    if not opt.saving.events:
        return None, None, None, None
    rows, index = run.events.all()
    out = ([], [], [], [])
    for j in range(len(opt.saving.events)):
        mine = rows[index == j]
        mine = mine[np.argsort(mine[:, 0] * np.sign(opt.t1 - opt.t0), kind="stable")]
        for lst, part in zip(out, split_event_rows(mine, n)):
            lst.append(part)
    return out


def drift_note(excursions: int, max_drift: float, t: np.ndarray, drift: np.ndarray, t0: float) -> str:
    """The warning of a run with ``lam_start="previous"`` whose multiplier left its band
    (``t``, ``drift``: the output rows after the initial one)."""
    k = _first_excursion(drift)
    first = t[min(k, len(t) - 1)] if len(t) else t0
    return (
        f"the multiplier λ_k left its normal band around the hidden constraint in {excursions} steps "
        f"(‖λ_k − λ(q_k, p_k)‖∞ up to {max_drift:.2e}, first at t ≈ {first:.6g}). "
        "With lam_start='previous' (the paper's scheme) λ errors are carried with |R(∞)| = 1 and can grow, and with "
        "them the errors in q and p. Use lam_start='auto' (re-synchronise when λ drifts) or 'consistent', or a "
        "smaller step."
    )


def _first_excursion(drift: np.ndarray) -> int:
    """Index of the largest growth of the drift over its early level (for the message only)."""
    if drift.size == 0:
        return 0
    early = float(np.max(drift[: min(len(drift), 10)]))
    above = np.flatnonzero(drift > 10 * early)
    return int(above[0]) if above.size else int(np.argmax(drift))
