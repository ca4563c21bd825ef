r"""The Chaplygin sleigh over T = 1000 (the long problem): closed form plus a 30-digit
quadrature.

Source: ``shared/PROBLEMS.md`` §3 (Chaplygin sleigh; Bloch, *Nonholonomic Mechanics and
Control*, Sect. 1.7; Fedorov & Zenkov); the problem object is the library's
``lobattodae.examples.chaplygin_sleigh`` (``q = (x, y, θ)``, centre of mass and heading,
knife edge a behind the centre of mass, ``H = (p_x²+p_y²)/(2m) + p_θ²/(2I)``, constraint
``−sin θ x' + cos θ y' − a θ' = 0``).

Reference, re-implemented here from PROBLEMS.md in mpmath at 30 digits: with
``E = ½ m v0² + ½ (I + m a²) ω0²``, ``v_max = √(2E/m)``, ``ω_max = √(2E/(I + m a²))``,
``k = m a/(I + m a²)``, ``τ = k v_max t + artanh(v0/v_max)``, σ = sign ω0,
``ρ = √(1 + I/(m a²))``: ``v = v_max tanh τ``, ``ω = σ ω_max sech τ``,
``θ = θ0 + σ ρ (gd τ − gd τ(0))`` (``gd τ = atan sinh τ``), ``x' = v cos θ − a ω sin θ``,
``y' = v sin θ + a ω cos θ``, ``p = (m x', m y', I ω)``. θ and p are closed form; x and y
are ``mpmath.quad`` (tanh-sinh) integrals of x', y' over [0, t], split into panels of
length 1 (30 digits requested; the quadrature's own error estimate is below 1e-25). All six
components are compared. :func:`compute_reference` regenerates the stored values (≈ 10 s).
"""

from __future__ import annotations

import numpy as np
from lobattodae import examples

from ._types import FastTest, closed_form

PARAMS = dict(m=1.5, I=0.8, a=0.6)
INIT = dict(theta0=0.1, v0=0.2, omega0=1.2, x0=0.0, y0=0.0)
T_END = 1000.0
T_REF = (10.0, 100.0, 1000.0)


def _body(mp, t):
    """v, ω, θ (mpmath numbers) at t."""
    m, I, a = (mp.mpf(PARAMS[k]) for k in ("m", "I", "a"))  # noqa: E741
    th0, v0, w0 = (mp.mpf(INIT[k]) for k in ("theta0", "v0", "omega0"))
    big = I + m * a**2
    energy = m * v0**2 / 2 + big * w0**2 / 2
    vmax, wmax = mp.sqrt(2 * energy / m), mp.sqrt(2 * energy / big)
    rate = m * a / big * vmax
    tau0 = mp.atanh(v0 / vmax)
    sigma = mp.sign(w0)
    rho = mp.sqrt(1 + I / (m * a**2))
    tau = rate * t + tau0
    v = vmax * mp.tanh(tau)
    w = sigma * wmax * mp.sech(tau)
    th = th0 + sigma * rho * (mp.atan(mp.sinh(tau)) - mp.atan(mp.sinh(tau0)))
    return v, w, th


def _velocity(mp, t):
    a = mp.mpf(PARAMS["a"])
    v, w, th = _body(mp, t)
    return v * mp.cos(th) - a * w * mp.sin(th), v * mp.sin(th) + a * w * mp.cos(th), w, th


def exact_mp(t, dps=30):
    """``(q, p)`` as float arrays, computed in mpmath with ``dps`` digits."""
    import mpmath

    with mpmath.workdps(dps):
        t = mpmath.mpf(t)
        panels = [mpmath.mpf(0)] + [mpmath.mpf(k) for k in range(1, int(mpmath.floor(t)) + 1)]
        if panels[-1] != t:
            panels.append(t)
        x = mpmath.mpf(INIT["x0"]) + mpmath.quad(lambda s: _velocity(mpmath, s)[0], panels)
        y = mpmath.mpf(INIT["y0"]) + mpmath.quad(lambda s: _velocity(mpmath, s)[1], panels)
        xd, yd, w, th = _velocity(mpmath, t)
        m, I = mpmath.mpf(PARAMS["m"]), mpmath.mpf(PARAMS["I"])  # noqa: E741
        q = np.array([float(x), float(y), float(th)])
        p = np.array([float(m * xd), float(m * yd), float(I * w)])
    return q, p


def exact(t, dps=30):
    """``(q, p)`` at t (scalar, or an array: shapes (N, 3)) by :func:`exact_mp` (slow for
    large t: the quadrature costs about 0.05 s per unit of time)."""
    if np.ndim(t) == 0:
        return exact_mp(float(t), dps)
    rows = [exact_mp(float(tk), dps) for tk in np.asarray(t, dtype=float)]
    return np.array([r[0] for r in rows]), np.array([r[1] for r in rows])


def compute_reference(times=T_REF, dps=30):
    rows = [exact_mp(t, dps) for t in times]
    return np.array([r[0] for r in rows]), np.array([r[1] for r in rows])


# compute_reference() with 30 digits (mpmath 1.3.0), rounded to float64; 40 digits give the
# same doubles. Rows: t = 10, 100, 1000.
Q_REF = (
    (-5.945579706433145, 9.022919025043267, 2.2983244538105225),
    (-74.9657891591409, 86.35370608064164, 2.2994800706480234),
    (-765.1755492147373, 859.6547387477369, 2.2994800706480234),
)
P_REF = (
    (-1.149459948067741, 1.2896281901851034, 7.1511975695239015e-04),
    (-1.1503496000926607, 1.2888350544451588, 4.1682007303731848e-34),
    (-1.1503496000926607, 1.2888350544451588, 0.0),
)

PROBLEM = closed_form(
    "sleigh", "shared/PROBLEMS.md §3 (Chaplygin sleigh; Bloch, Nonholonomic Mechanics and Control, Sect. 1.7); "
    "problem: lobattodae.examples.chaplygin_sleigh", examples.chaplygin_sleigh, PARAMS, INIT, exact, t_end=T_END,
    t_ref=T_REF, q_ref=Q_REF, p_ref=P_REF, ref_accuracy=1e-16, long=True,
    test=FastTest(stages=4, n_steps=4000, bound=5e-8))
