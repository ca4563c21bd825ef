"""An external test set for lobattodae: problems whose references no code of this library
produced.

``PROBLEMS`` maps a name to a :class:`TestProblem`; ``entry.build()`` gives the problem (one
object per process, so compiled code is reused), consistent initial values, ``args`` and
``t_span``; :func:`error` measures a solution against the reference. See README.md for the
sources, the references and their accuracy, and the measured convergence
(``python -m benchmarks.testset.convergence`` reproduces it).

>>> import lobattodae as L
>>> from benchmarks.testset import PROBLEMS, error
>>> entry = PROBLEMS["andrews"]
>>> s = entry.build()
>>> sol = L.solve(s.problem, L.LobattoIIIAIIIB(stages=5), s.t_span, s.q0, s.p0, args=s.args, n_steps=200)
>>> error(entry, sol.t, sol.q, sol.p) < 2e-10
True
"""

from __future__ import annotations

import lobattodae  # noqa: F401  (float64 before anything else touches JAX)

from . import andrews, caraxis, crank, fekete, fourbar, knife_edge, rolling_disc, servo_sleigh, sleigh, vertical_disk
from ._types import FastTest, Setup, TestProblem, closed_form, error, reference_at

__all__ = ["PROBLEMS", "FastTest", "Setup", "TestProblem", "closed_form", "error", "reference_at"]

#: name -> TestProblem, in the order of README.md.
PROBLEMS: dict[str, TestProblem] = {
    entry.name: entry
    for entry in (
        andrews.PROBLEM,
        caraxis.PROBLEM,
        crank.PROBLEM,
        fekete.PROBLEM,
        rolling_disc.PROBLEM,
        fourbar.PROBLEM,
        vertical_disk.PROBLEM,
        sleigh.PROBLEM,
        knife_edge.PROBLEM,
        servo_sleigh.PROBLEM_SMOOTH,
        servo_sleigh.PROBLEM_REST,
    )
}
