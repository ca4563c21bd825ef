"""The Chaplygin sleigh (PROBLEMS.md, section 3)."""

from __future__ import annotations

from typing import NamedTuple

import jax.numpy as jnp
import numpy as np

from .._problem import NonholonomicSystem
from ._base import Example, cumulative_integral, finite, positive, t_span_to, vectorised

__all__ = ["SleighParams", "chaplygin_sleigh"]


class SleighParams(NamedTuple):
    """The parameters of :func:`chaplygin_sleigh` (its ``args``).

    Attributes
    ----------
    m : float
        Mass.
    I : float
        Moment of inertia about the centre of mass.
    a : float
        The distance of the knife edge's contact point behind the centre of mass.
    """

    m: float
    I: float  # noqa: E741
    a: float


def _hamiltonian(t, q, p, args):
    return (p[0] ** 2 + p[1] ** 2) / (2.0 * args.m) + p[2] ** 2 / (2.0 * args.I)


def _constraint_matrix(t, q, args):
    th = q[2]
    return jnp.stack([-jnp.sin(th), jnp.cos(th), -args.a * jnp.ones_like(th)])[None, :]


PROBLEM = NonholonomicSystem(_hamiltonian, _constraint_matrix, name="Chaplygin sleigh")


def _energy(t, q, p, args):
    return _hamiltonian(t, q, p, args)


def _sech(x):
    e = np.exp(-np.abs(x))
    return 2.0 * e / (1.0 + e * e)


def _gd(x):
    """Gudermannian ``atan(sinh x)``, written without overflow."""
    return 2.0 * np.arctan(np.tanh(0.5 * x))


def _exact(params: SleighParams, theta0, v0, omega0, x0, y0):
    m, inertia, a = params
    if omega0 == 0.0:

        def core0(t):
            """Exact solution of the Chaplygin sleigh (straight-line motion)."""
            zero = np.zeros_like(t)
            c, s = np.cos(theta0), np.sin(theta0)
            q = np.stack([x0 + v0 * c * t, y0 + v0 * s * t, np.full_like(t, theta0)], -1)
            p = np.stack([m * v0 * c + zero, m * v0 * s + zero, zero], -1)
            return q, p, zero[:, None]

        return vectorised(core0)

    big_i = inertia + m * a**2
    energy = 0.5 * m * v0**2 + 0.5 * big_i * omega0**2
    v_max = np.sqrt(2.0 * energy / m)
    w_max = np.sqrt(2.0 * energy / big_i)
    k = m * a / big_i
    rate = k * v_max
    tau0 = np.arctanh(v0 / v_max)
    sigma = np.sign(omega0)
    rho = w_max / rate  # = sqrt(1 + I/(m a²))

    def body(t):
        tau = rate * t + tau0
        v = v_max * np.tanh(tau)
        w = sigma * w_max * _sech(tau)
        th = theta0 + sigma * rho * (_gd(tau) - _gd(tau0))
        return v, w, th

    def velocity(t):
        v, w, th = body(t)
        c, s = np.cos(th), np.sin(th)
        return np.stack([v * c - a * w * s, v * s + a * w * c], axis=-1)

    panel = 0.25 / max(1.0, rate, w_max)

    def core(t):
        """Exact solution of the Chaplygin sleigh; x, y by composite Gauss-Legendre
        quadrature of x', y' (accurate to round-off)."""
        v, w, th = body(t)
        xy = cumulative_integral(velocity, t, panel)
        vel = velocity(t)
        q = np.stack([x0 + xy[:, 0], y0 + xy[:, 1], th], axis=-1)
        p = np.stack([m * vel[:, 0], m * vel[:, 1], inertia * w], axis=-1)
        lam = (inertia * m * v * w / big_i)[:, None]
        return q, p, lam

    return vectorised(core)


def chaplygin_sleigh(
    *,
    m: float = 1.0,
    I: float = 1.0,  # noqa: E741
    a: float = 1.0,
    theta0: float = 0.0,
    v0: float = 0.0,
    omega0: float = 1.0,
    x0: float = 0.0,
    y0: float = 0.0,
    t_end: float = 2.0,
) -> Example:
    r"""The Chaplygin sleigh: a rigid body on a plane with a knife edge at distance ``a``
    behind its centre of mass.

    ``q = (x, y, θ)`` (centre of mass, heading), ``H = (p_x²+p_y²)/(2m) + p_θ²/(2I)``,
    constraint ``-sin θ x' + cos θ y' - a θ' = 0``. With
    ``E = ½ m v0² + ½ (I + m a²) ω0²``, ``v_max = √(2E/m)``, ``ω_max = √(2E/(I+ma²))``,
    ``k = m a/(I + m a²)`` and ``τ = k v_max t + artanh(v0/v_max)``: forward speed
    ``v = v_max tanh τ``, ``θ' = ω = sign(ω0) ω_max sech τ``,
    ``θ = θ0 + sign(ω0) √(1 + I/(m a²)) (gd τ - gd τ(0))``,
    ``λ = I m v ω / (I + m a²)``; x, y by quadrature of
    ``x' = v cos θ - a ω sin θ``, ``y' = v sin θ + a ω cos θ``.

    Parameters
    ----------
    m, I, a : float
        Mass, moment of inertia about the centre of mass, distance of the contact point
        behind the centre of mass (defaults 1, 1, 1; all positive).
    theta0 : float
        Initial heading (default 0).
    v0, omega0 : float
        Initial forward speed and turning rate (default 0, 1).
    x0, y0 : float
        Initial position of the centre of mass (default 0, 0).
    t_end : float
        End of ``t_span = (0, t_end)`` (default 2).

    Returns
    -------
    Example
        ``"sleigh"``, with the exact solution and the energy as first integral.

    Raises
    ------
    ValueError
        ``m``, ``I``, ``a`` or ``t_end`` not positive and finite, or another parameter not
        finite.
    """
    params = SleighParams(m=positive("m", m), I=positive("I", I), a=positive("a", a))
    theta0, v0, omega0, x0, y0 = (finite(k, val) for k, val in (
        ("theta0", theta0), ("v0", v0), ("omega0", omega0), ("x0", x0), ("y0", y0)))
    exact = _exact(params, theta0, v0, omega0, x0, y0)
    q0, p0, lam0 = exact(0.0)
    return Example(
        name="sleigh",
        problem=PROBLEM,
        t_span=t_span_to(t_end),
        q0=q0,
        p0=p0,
        lam0=lam0,
        args=params,
        invariants={"energy": _energy},
        exact=exact,
        description="Chaplygin sleigh (n=3, m=1), closed form up to a quadrature",
        notes=(
            "The motion tends to straight-line motion at speed v_max; x, y of the exact "
            "solution come from a composite 20-point Gauss-Legendre quadrature."
        ),
    )
