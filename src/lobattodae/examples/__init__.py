"""Test problems for nonholonomic mechanics: the problems of PROBLEMS.md with consistent
initial values, first integrals and, where known, exact solutions.

>>> from lobattodae.examples import get_example, list_examples
>>> ex = get_example("knife-edge", omega=2.0)
>>> q, p, lam = ex.exact(ex.t_end)
"""

from ._base import Example
from ._contact import ContactParams, contact_oscillator
from ._knife_edge import KnifeEdgeParams, knife_edge
from ._particle import ParticleParams, nonholonomic_particle
from ._registry import EXAMPLES, get_example, list_examples
from ._rolling_disk import (
    FallingDiskParams,
    VerticalDiskParams,
    falling_rolling_disk,
    steady_spin_rate,
    vertical_rolling_disk,
)
from ._sleigh import SleighParams, chaplygin_sleigh

__all__ = [
    "EXAMPLES",
    "ContactParams",
    "Example",
    "FallingDiskParams",
    "KnifeEdgeParams",
    "ParticleParams",
    "SleighParams",
    "VerticalDiskParams",
    "chaplygin_sleigh",
    "contact_oscillator",
    "falling_rolling_disk",
    "get_example",
    "knife_edge",
    "list_examples",
    "nonholonomic_particle",
    "steady_spin_rate",
    "vertical_rolling_disk",
]
