"""Result codes of the Newton solve and of a whole integration.

Codes are small integers so that they can live inside compiled loops; each has a
user-facing message.
"""

from __future__ import annotations

import enum

__all__ = ["Result"]


class Result(enum.IntEnum):
    """Outcome of a step (and of a solve: the first non-successful step's code).

    An ``IntEnum``: the codes live inside compiled loops as integers (``IntegrateResult.status``)
    and ``Solution.result`` holds the member; ``member.message`` is the sentence users see.

    Attributes
    ----------
    SUCCESSFUL : 0
        The end of the integration interval was reached.
    MAX_ITERATIONS : 1
        Newton's method did not converge within ``max_iterations``.
    DIVERGED : 2
        Newton's method stopped contracting.
    NONFINITE : 3
        NaN or inf in the stage equations or their Jacobian.
    INTERRUPTED : 4
        Ctrl-C (or SIGTERM in the command line); the computed prefix is returned.
    STEP_SIZE_TOO_SMALL : 5
        Adaptive steps fell below ``1e-14·max(|t|, |t1 - t0|)``.
    MAX_STEPS : 6
        The step limit ``max_steps`` was reached before the end of the interval.
    EVENT : 7
        A terminal event ended the run (a success).
    EVENT_NOT_FINITE : 8
        An event function returned NaN or inf; the run stopped at that step point.
    DENSITY_NOT_POSITIVE : 9
        The step density of :class:`~lobattodae.ReversibleStepSize` (or its rate along the
        flow) was not positive and finite; the run stopped at that step point.
    INVALID_T_EVAL : 10
        ``t_eval`` given to :func:`~lobattodae.integrate_adaptive` under a JAX transformation
        (where it cannot be checked first) has a NaN, a time outside ``t_span`` or is not
        sorted in the direction of integration; its rows are not to be trusted.
    ROUNDOFF_LIMITED : 11
        The end of the interval was reached (a success), but rtol asked more of the steps than
        their round-off allows: the steps that passed only by the round-off floor
        (``stats["n_roundoff_limited"]``, ``PIController``'s ``ROUNDOFF_FLOOR``) may add up to
        more than rtol, so the error may exceed it. Set by the end of an error-controlled run
        that would otherwise be ``SUCCESSFUL``, where ``n_roundoff_limited · ROUNDOFF_FLOOR >
        rtol``.
    success : bool
        Of a member: True for ``SUCCESSFUL``, ``EVENT`` and ``ROUNDOFF_LIMITED`` (the run
        reached its end).
    message : str
        Of a member: the sentence users see.
    """

    SUCCESSFUL = 0
    MAX_ITERATIONS = 1
    DIVERGED = 2
    NONFINITE = 3
    INTERRUPTED = 4
    STEP_SIZE_TOO_SMALL = 5
    MAX_STEPS = 6
    EVENT = 7
    EVENT_NOT_FINITE = 8
    DENSITY_NOT_POSITIVE = 9
    INVALID_T_EVAL = 10
    ROUNDOFF_LIMITED = 11

    @property
    def success(self) -> bool:
        """True for a run that reached its end: the end of the interval or a terminal event."""
        return self in REACHED_END

    @property
    def message(self) -> str:
        return _MESSAGES[self]


#: The results of a run that reached its end (``Result.success``; for arrays of codes:
#: ``np.isin(status, REACHED_END)``).
REACHED_END = (Result.SUCCESSFUL, Result.EVENT, Result.ROUNDOFF_LIMITED)

_MESSAGES = {
    Result.SUCCESSFUL: "The solver successfully reached the end of the integration interval.",
    Result.MAX_ITERATIONS: (
        "Newton's method did not converge within the iteration limit "
        "(try a smaller step size or a larger max_iterations)."
    ),
    Result.DIVERGED: (
        "Newton's method diverged (the iteration stopped contracting); "
        "try a smaller step size."
    ),
    Result.NONFINITE: (
        "Non-finite values (NaN/inf) appeared in the stage equations or their Jacobian; "
        "the step is too large for the problem or the problem functions overflow."
    ),
    Result.INTERRUPTED: "The integration was interrupted; the computed prefix is returned.",
    Result.STEP_SIZE_TOO_SMALL: (
        "The step size fell below 1e-14·max(|t|, |t1 - t0|) (the error test or Newton's method kept "
        "failing); the problem may be singular there, or the tolerances are too tight."
    ),
    Result.MAX_STEPS: "The step limit (max_steps) was reached before the end of the interval.",
    Result.EVENT: "A terminal event occurred.",
    Result.EVENT_NOT_FINITE: (
        "An event function returned a non-finite value (NaN/inf) at the step point or a node of the step, so "
        "its zeros can no longer be located; the run stopped there. Make the event function finite along the "
        "solution."
    ),
    Result.DENSITY_NOT_POSITIVE: (
        "The step density of ReversibleStepSize was not positive and finite there (σ <= 0, NaN or inf, or "
        "its rate of change along the flow NaN/inf), so it sets no step size; the run stopped at that step "
        "point. Give a density that is positive and finite along the solution (e.g. add a floor, σ + c)."
    ),
    Result.INVALID_T_EVAL: (
        "t_eval has a NaN, a time outside t_span, or is not sorted in the direction of integration, so some "
        "of its rows are missing or wrong; give finite times within t_span, sorted (increasing for t1 > t0)."
    ),
    Result.ROUNDOFF_LIMITED: (
        "The end of the integration interval was reached, but rtol asked the steps for less than their round-off: "
        "the steps that passed only by the round-off floor may add up to more than rtol, so the error may exceed "
        "it. Use more stages (a higher order takes fewer steps) or a looser rtol."
    ),
}
