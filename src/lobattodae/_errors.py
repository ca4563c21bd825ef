"""Exceptions raised by lobattodae.

Every error raised for bad *input* is a :class:`ValueError` subclass (or a
:class:`TypeError` for arguments of the wrong kind); every error raised because the
*solver* failed on valid input is a :class:`RuntimeError` subclass.  Messages name
the problem and say what to do about it.
"""

from __future__ import annotations

__all__ = [
    "LobattoDAEInputError",
    "ShapeError",
    "InconsistentInitialValuesError",
    "ProblemFunctionError",
    "ProblemDefinitionError",
    "SingularConstraintError",
    "SolverError",
    "NewtonFailure",
]


class LobattoDAEInputError(ValueError):
    """Base class for invalid input (problem definition, initial values, options)."""


class ShapeError(LobattoDAEInputError):
    """An array has the wrong shape or dtype, or a user function returned one."""


class ProblemFunctionError(LobattoDAEInputError):
    """A function of the problem (f, g, φ, H, μ, M, V) raised an exception when called; the
    original exception is chained as ``__cause__``."""


class ProblemDefinitionError(LobattoDAEInputError, TypeError):
    """A problem object was constructed with a function missing or not callable (e.g.
    ``NonholonomicSystem(H)`` without the constraint matrix). Also a :class:`TypeError`, which
    is what Python raises for a missing constructor argument."""


class InconsistentInitialValuesError(LobattoDAEInputError):
    """The initial values violate the constraint φ(t0, q0, p0) = 0 or the hidden constraint."""


class SingularConstraintError(LobattoDAEInputError):
    """``D_p φ · D_λ g`` is singular: the DAE is not of index 2 at the initial point."""


class SolverError(RuntimeError):
    """Base class for failures of the integrator on valid input."""


class NewtonFailure(SolverError):
    """The Newton iteration for the stage equations failed at some step.

    Attributes
    ----------
    step : int
        Index of the failed step (0-based: step ``k`` goes from ``t[k]`` to ``t[k+1]``).
    t : float
        Time at the start of the failed step.
    reason : str
        The cause (divergence, stagnation, iteration limit, non-finite values).
    """

    def __init__(self, message: str, *, step: int, t: float, reason: str):
        super().__init__(message)
        self.step = step
        self.t = t
        self.reason = reason
