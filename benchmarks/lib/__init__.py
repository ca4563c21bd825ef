"""The benchmarks' one library: what every script in ``benchmarks/`` composes.

=================  ===========================================================================
``timing``         the timer (best of k, process CPU time, a first call apart), pinning to a CPU,
                   counting XLA compilations
``cli``            the shared command-line options (``--quick``, ``--pin-cpu``, ``--cpu-threads``,
                   ``--watchdog``) and the process setup they ask for
``output``         logging, the machine and run record, JSON, Markdown tables, figures, child
                   processes
``sweeps``         settings swept with budget and floor rules, Pareto fronts, searches for the
                   cheapest setting that meets an error
``odes``           the reduced index-1 ODEs of the competitors (NumPy for scipy, JAX for diffrax)
                   and the NumPy index-2 residuals for IDA, validated against the problems' own
                   functions
``falling_disk``   the falling disk in SymPy (its mass matrix, once), for ``odes`` and the
                   reference
``references``     references without a closed form (the falling disk in extended precision)
``baselines``      the fair competitors: diffrax Dopri8/Kvaerno5 jitted once with a PID
                   controller, scipy DOP853/Radau on NumPy right-hand sides, SUNDIALS IDA
``mclachlan``      McLachlan and Perlmutter's second-order nonholonomic integrator
``problems``       problems that only the benchmarks use (the particle chain)
=================  ===========================================================================

Scripts run as ``python benchmarks/<script>.py`` have ``benchmarks/`` on ``sys.path`` and import
``lib`` and ``testset`` as top-level packages. lobattodae is imported from the installed
package or, failing that, from ``src/``.
"""

import os
import sys

try:
    import lobattodae  # noqa: F401  (float64 on before anything else touches JAX)
except ImportError:  # pragma: no cover  (a checkout without the package installed)
    sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "src"))
    import lobattodae  # noqa: F401
