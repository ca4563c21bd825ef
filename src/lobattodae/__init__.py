"""lobattodae: high-order Lobatto IIIA-IIIB integrators for partitioned index-2 DAEs.

Importing lobattodae switches JAX to float64 (``jax_enable_x64``): the methods are
designed for, and tested in, double precision.
"""

import jax as _jax

_jax.config.update("jax_enable_x64", True)

from ._errors import (  # noqa: E402
    InconsistentInitialValuesError,
    LobattoDAEInputError,
    NewtonFailure,
    ShapeError,
    SingularConstraintError,
    SolverError,
)
from ._initial import validate_initial_values  # noqa: E402
from ._problem import (  # noqa: E402
    MechanicalSystem,
    NonholonomicSystem,
    PartitionedDAE,
    consistent_lambda,
    hidden_constraint,
)
from ._results import Result  # noqa: E402
from ._solve import Solution, integrate, solve  # noqa: E402
from ._stepper import LobattoIIIAIIIB, StepInfo, StepperState  # noqa: E402
from ._tableau import LobattoPair, lobatto_pair  # noqa: E402

__version__ = "0.1.0"

__all__ = [
    "InconsistentInitialValuesError",
    "LobattoDAEInputError",
    "LobattoIIIAIIIB",
    "LobattoPair",
    "MechanicalSystem",
    "NewtonFailure",
    "NonholonomicSystem",
    "PartitionedDAE",
    "Result",
    "ShapeError",
    "SingularConstraintError",
    "Solution",
    "SolverError",
    "StepInfo",
    "StepperState",
    "consistent_lambda",
    "hidden_constraint",
    "integrate",
    "lobatto_pair",
    "solve",
    "validate_initial_values",
]
