r"""The knife edge (skate) on an inclined plane, T = 1000: closed form.

Source: ``shared/PROBLEMS.md`` §2 (after Bloch, *Nonholonomic Mechanics and Control*,
Sect. 1.6, and McLachlan & Perlmutter, J. Nonlinear Sci. 16 (2006)); the problem object is
the library's ``lobattodae.examples.knife_edge`` (``H = (p_x²+p_y²)/(2m) + p_θ²/(2J) + m g y``,
constraint ``−sin θ x' + cos θ y' = 0``).

Reference: the closed form, re-implemented here in NumPy from PROBLEMS.md (not the
library's ``exact``): with ω = θ' constant and v the speed along the blade,
``θ = θ0 + ωt``, ``v = v0 + (g/ω)(cos θ − cos θ0)``,
``x = x0 + [g(sin 2θ0 − 4 sin θ cos θ0 + sin 2θ)/2 + ω(g t − 2 v0 sin θ0 + 2 v0 sin θ)]/(2ω²)``,
``y = y0 + [−(g/2)(cos θ − cos θ0)² + ω v0 (cos θ0 − cos θ)]/ω²``,
``p = (m v cos θ, m v sin θ, J ω)``. Accuracy: round-off of the formulas (x grows to
g T/(2ω) ≈ 570; relative 1e-15).
"""

from __future__ import annotations

import numpy as np
from lobattodae import examples

from ._types import FastTest, closed_form

PARAMS = dict(m=2.0, J=0.5, g=0.8)
INIT = dict(omega=0.7, theta0=0.2, v0=0.5, x0=0.1, y0=-0.3)
T_END = 1000.0
T_REF = (10.0, 100.0, 1000.0)


def exact(t):
    """``(q, p)`` of the closed form at t (scalar or array; arrays give shape (N, 3))."""
    t = np.asarray(t, dtype=float)
    m, J, g = PARAMS["m"], PARAMS["J"], PARAMS["g"]
    w, th0, v0, x0, y0 = (INIT[k] for k in ("omega", "theta0", "v0", "x0", "y0"))
    th = th0 + w * t
    c, s, c0, s0 = np.cos(th), np.sin(th), np.cos(th0), np.sin(th0)
    v = v0 + (g / w) * (c - c0)
    x = x0 + (0.5 * g * (np.sin(2 * th0) - 4 * s * c0 + np.sin(2 * th)) + w * (g * t - 2 * v0 * s0 + 2 * v0 * s)) / (2 * w**2)
    y = y0 + (-0.5 * g * (c - c0) ** 2 + w * v0 * (c0 - c)) / w**2
    q = np.stack([x, y, th], -1)
    p = np.stack([m * v * c, m * v * s, J * w + 0 * t], -1)
    return q, p


PROBLEM = closed_form(
    "knife-edge", "shared/PROBLEMS.md §2 (knife edge on an inclined plane; Bloch, Nonholonomic Mechanics and "
    "Control, Sect. 1.6); problem: lobattodae.examples.knife_edge", examples.knife_edge, PARAMS, INIT, exact,
    t_end=T_END, t_ref=T_REF, ref_accuracy=1e-15, long=True, test=FastTest(stages=4, n_steps=4000, bound=3.7e-8))
