"""lobattodae: high-order Lobatto IIIA-IIIB integrators for partitioned index-2 DAEs.

Public namespaces: this module, :mod:`lobattodae.examples` (test problems),
:mod:`lobattodae.conditions` (simplifying assumptions and hypotheses of RK pairs) and
:mod:`lobattodae.mechanics` (models from SymPy; the ``lobattodae[mechanics]`` extra), each
also an attribute of this module, imported on first use (``lobattodae.examples.knife_edge()``
after ``import lobattodae``).

Importing lobattodae switches JAX to float64 (``jax_enable_x64``): the methods are
designed for, and tested in, double precision. With ``LOBATTODAE_CACHE_DIR`` set it also
switches on JAX's persistent compilation cache there (see :func:`enable_compilation_cache`).
"""

import jax as _jax

_jax.config.update("jax_enable_x64", True)

from ._cache import enable_compilation_cache  # noqa: E402
from ._compile import compiler_options  # noqa: E402
from ._io import CheckpointError, CheckpointWriteError, EnsembleFileError  # noqa: E402
from ._tableau_report import TableauReport, check_tableau  # noqa: E402
from ._cpu import set_cpu_threads  # noqa: E402
from ._convergence import ConvergenceStudy, convergence_study, observed_order  # noqa: E402
from ._diagnostics import constraint_residual, energy_error, invariant_error, invariant_values  # noqa: E402
from ._errors import (  # noqa: E402
    InconsistentInitialValuesError,
    LobattoDAEInputError,
    NewtonFailure,
    ProblemDefinitionError,
    ProblemFunctionError,
    ShapeError,
    SingularConstraintError,
    SolverError,
)
from ._validate import validate_initial_values  # noqa: E402
from ._linalg import spd_solve  # noqa: E402
from ._animation import animate  # noqa: E402
from ._plotting import plot, plot_convergence, plot_solution  # noqa: E402
from ._problem import (  # noqa: E402
    MechanicalSystem,
    NonholonomicSystem,
    PartitionedDAE,
    consistent_lambda,
    hidden_constraint,
    project_momenta,
)
from ._results import Result  # noqa: E402
from ._integrate import AdaptiveResult, IntegrateResult, integrate, integrate_adaptive  # noqa: E402
from ._controllers import PIController  # noqa: E402
from ._reversible import ReversibleStepSize  # noqa: E402
from ._dense import DenseOutput  # noqa: E402
from ._events import Event  # noqa: E402
from ._solution import STATS, Solution  # noqa: E402
from ._solve import solve  # noqa: E402
from ._ensemble import EnsembleFiles, EnsembleResult, ensemble, load_ensemble  # noqa: E402
from ._stepper import LobattoIIIAIIIB, StepInfo, StepperState  # noqa: E402
from ._tableau import LobattoPair, lobatto_iiia, lobatto_iiib, lobatto_nodes, lobatto_pair, lobatto_weights  # noqa: E402

__version__ = "0.1.0"

#: Subpackages reachable as attributes without their own import (``lobattodae.examples``
#: after ``import lobattodae``), loaded on first use: ``mechanics`` needs SymPy (the
#: ``lobattodae[mechanics]`` extra) and says so when it is missing.
_SUBMODULES = ("conditions", "examples", "mechanics")


def __getattr__(name):
    if name in _SUBMODULES:
        import importlib

        return importlib.import_module(f"{__name__}.{name}")
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__():
    return sorted(set(globals()) | set(_SUBMODULES))


# The persistent compilation cache, on by default (lobattodae._cache): LOBATTODAE_NO_CACHE=1 keeps it off.
from ._cache import enable_default_cache as _enable_default_cache  # noqa: E402

_enable_default_cache()

__all__ = [
    "AdaptiveResult",
    "CheckpointError",
    "CheckpointWriteError",
    "EnsembleFileError",
    "DenseOutput",
    "Event",
    "PIController",
    "ReversibleStepSize",
    "integrate_adaptive",
    "EnsembleFiles",
    "EnsembleResult",
    "ensemble",
    "load_ensemble",
    "ConvergenceStudy",
    "TableauReport",
    "check_tableau",
    "constraint_residual",
    "convergence_study",
    "energy_error",
    "invariant_error",
    "invariant_values",
    "observed_order",
    "animate",
    "plot",
    "plot_convergence",
    "plot_solution",
    "InconsistentInitialValuesError",
    "IntegrateResult",
    "LobattoDAEInputError",
    "LobattoIIIAIIIB",
    "LobattoPair",
    "MechanicalSystem",
    "NewtonFailure",
    "NonholonomicSystem",
    "PartitionedDAE",
    "ProblemDefinitionError",
    "ProblemFunctionError",
    "Result",
    "STATS",
    "ShapeError",
    "SingularConstraintError",
    "Solution",
    "SolverError",
    "StepInfo",
    "StepperState",
    "consistent_lambda",
    "compiler_options",
    "enable_compilation_cache",
    "hidden_constraint",
    "integrate",
    "lobatto_iiia",
    "lobatto_iiib",
    "lobatto_nodes",
    "lobatto_pair",
    "lobatto_weights",
    "project_momenta",
    "set_cpu_threads",
    "solve",
    "spd_solve",
    "validate_initial_values",
]
