r"""The vertical rolling disk: closed form.

Source: ``shared/PROBLEMS.md`` §4 (Bloch, *Nonholonomic Mechanics and Control*, Sect. 1.4);
the problem object is the library's ``lobattodae.examples.vertical_rolling_disk``
(``q = (x, y, φ, θ)``: contact point, heading, rolling angle;
``H = (p_x²+p_y²)/(2m) + p_φ²/(2J) + p_θ²/(2I)``, ``x' = R cos φ θ'``, ``y' = R sin φ θ'``).

Reference: the closed form re-implemented here from PROBLEMS.md: ``φ = φ0 + ω_φ t``,
``θ = θ0 + ω_θ t``, ``x = x0 + ρ(sin φ − sin φ0)``, ``y = y0 − ρ(cos φ − cos φ0)`` with
``ρ = R ω_θ/ω_φ``, ``p = (m R ω_θ cos φ, m R ω_θ sin φ, J ω_φ, I ω_θ)``; exact to round-off.
"""

from __future__ import annotations

import numpy as np
from lobattodae import examples

from ._types import FastTest, closed_form

PARAMS = dict(m=1.3, R=0.7, I=0.4, J=0.9)
INIT = dict(omega_phi=1.5, omega_theta=2.5, x0=0.2, y0=-0.1, phi0=0.3, theta0=0.1)
T_END = 100.0
T_REF = (10.0, 50.0, 100.0)


def exact(t):
    """``(q, p)`` of the closed form at t (scalar or array; arrays give shape (N, 4))."""
    t = np.asarray(t, dtype=float)
    m, R, I, J = (PARAMS[k] for k in ("m", "R", "I", "J"))  # noqa: E741
    wp, wt, x0, y0, ph0, th0 = (INIT[k] for k in ("omega_phi", "omega_theta", "x0", "y0", "phi0", "theta0"))
    ph, th = ph0 + wp * t, th0 + wt * t
    rho = R * wt / wp
    x = x0 + rho * (np.sin(ph) - np.sin(ph0))
    y = y0 - rho * (np.cos(ph) - np.cos(ph0))
    q = np.stack([x, y, ph, th], -1)
    p = np.stack([m * R * wt * np.cos(ph), m * R * wt * np.sin(ph), J * wp + 0 * t, I * wt + 0 * t], -1)
    return q, p


PROBLEM = closed_form(
    "vertical-disk", "shared/PROBLEMS.md §4 (vertical rolling disk; Bloch, Nonholonomic Mechanics and Control, "
    "Sect. 1.4); problem: lobattodae.examples.vertical_rolling_disk", examples.vertical_rolling_disk, PARAMS, INIT,
    exact, t_end=T_END, t_ref=T_REF, ref_accuracy=1e-15, test=FastTest(stages=4, n_steps=400, bound=8e-8))
