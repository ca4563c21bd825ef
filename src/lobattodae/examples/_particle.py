"""The nonholonomic particle (PROBLEMS.md, section 1)."""

from __future__ import annotations

from typing import NamedTuple

import jax.numpy as jnp
import numpy as np

from .._problem import NonholonomicSystem
from ._base import Example, finite, t_span_to, vectorised

__all__ = ["ParticleParams", "nonholonomic_particle"]


class ParticleParams(NamedTuple):
    """The parameters of :func:`nonholonomic_particle` (its ``args``).

    Attributes
    ----------
    stiffness : float
        The spring constant of ``V = stiffness/2 · (x² + y²)`` (0 for the free particle).
    """

    stiffness: float


def _hamiltonian(t, q, p, args):
    return 0.5 * jnp.dot(p, p) + 0.5 * args.stiffness * (q[0] ** 2 + q[1] ** 2)


def _constraint_matrix(t, q, args):
    # z' = y x'  <=>  (-y, 0, 1) · q' = 0
    y = q[1]
    return jnp.stack([-y, jnp.zeros_like(y), jnp.ones_like(y)])[None, :]


PROBLEM = NonholonomicSystem(_hamiltonian, _constraint_matrix, name="nonholonomic particle")


def _energy(t, q, p, args):
    return _hamiltonian(t, q, p, args)


def _p_y(t, q, p, args):
    return p[1]


def _px_sqrt(t, q, p, args):
    return p[0] * jnp.sqrt(1.0 + q[1] ** 2)


def _free_exact(x0, y0, z0, c, v):
    def core(t):
        """Exact solution of the free nonholonomic particle."""
        y = y0 + v * t
        r = np.sqrt(1.0 + y**2)
        r0 = np.sqrt(1.0 + y0**2)
        if v != 0.0:
            x = x0 + (c / v) * (np.arcsinh(y) - np.arcsinh(y0))
            z = z0 + (c / v) * (r - r0)
        else:
            x = x0 + c * t / r0
            z = z0 + y0 * c * t / r0
        q = np.stack([x, y, z], axis=-1)
        p = np.stack([c / r, np.full_like(t, v), y * c / r], axis=-1)
        lam = (v * c / r**3)[:, None]
        return q, p, lam

    return vectorised(core)


def nonholonomic_particle(
    potential: str = "free",
    *,
    x0: float = 0.0,
    y0: float = 0.0,
    z0: float = 0.0,
    c: float = 1.0,
    v: float = 1.0,
    stiffness: float = 1.0,
    t_end: float | None = None,
) -> Example:
    r"""The nonholonomic particle: ``q = (x, y, z)``, ``H = ½|p|² + V(x, y)``, ``z' = y x'``.

    ``μ(q) = (-y, 0, 1)``. For ``V = 0`` the exact solution is (with ``r = √(1+y²)``)
    ``y = y0 + v t``, ``x = x0 + (c/v)(asinh y - asinh y0)``, ``z = z0 + (c/v)(r - r0)``,
    ``p = (c/r, v, y c/r)``, ``λ = v c / r³``.

    Parameters
    ----------
    potential : {"free", "harmonic"}
        ``"free"``: V = 0, with a closed form and first integrals H, ``p_y`` and
        ``x'√(1+y²)``. ``"harmonic"``: ``V = stiffness/2 · (x² + y²)``, no closed form,
        only H is conserved (a long-run case).
    x0, y0, z0 : float
        Initial position (default 0, 0, 0).
    c : float
        ``c = x'(0) √(1 + y0²)`` (default 1).
    v : float
        ``v = y'(0)`` (default 1).
    stiffness : float
        Spring constant of the harmonic potential (default 1; ignored for ``"free"``).
    t_end : float, optional
        End of ``t_span = (0, t_end)``; default 2 (free) or 100 (harmonic).

    Returns
    -------
    Example
        ``"particle"`` (free, with the exact solution) or ``"particle-harmonic"``.

    Raises
    ------
    ValueError
        An unknown ``potential``, a parameter that is not finite, or ``t_end`` not positive.
    """
    x0, y0, z0, c, v = (finite(k, val) for k, val in
                        (("x0", x0), ("y0", y0), ("z0", z0), ("c", c), ("v", v)))
    r0 = np.sqrt(1.0 + y0**2)
    q0 = np.array([x0, y0, z0])
    p0 = np.array([c / r0, v, y0 * c / r0])
    if potential == "free":
        args = ParticleParams(stiffness=0.0)
        exact = _free_exact(x0, y0, z0, c, v)
        lam0 = exact(0.0)[2]
        return Example(
            name="particle",
            problem=PROBLEM,
            t_span=t_span_to(2.0 if t_end is None else t_end),
            q0=q0,
            p0=p0,
            lam0=lam0,
            args=args,
            invariants={"energy": _energy, "p_y": _p_y, "px_sqrt_1_plus_y2": _px_sqrt},
            exact=exact,
            description="free nonholonomic particle z' = y x' (n=3, m=1), closed form",
            notes="Nonlinear in q; a clean test of all three components' orders.",
        )
    if potential == "harmonic":
        args = ParticleParams(stiffness=finite("stiffness", stiffness))
        # λ from the hidden constraint: d/dt(p_z - y p_x) = λ(1 + y²) - v p_x + y·stiffness·x
        lam0 = np.array([(v * p0[0] - y0 * args.stiffness * x0) / (1.0 + y0**2)])
        return Example(
            name="particle-harmonic",
            problem=PROBLEM,
            t_span=t_span_to(100.0 if t_end is None else t_end),
            q0=q0,
            p0=p0,
            lam0=lam0,
            args=args,
            invariants={"energy": _energy},
            exact=None,
            description="nonholonomic particle in V = (x²+y²)/2, no closed form (long runs)",
            notes="Only the energy is conserved; use for long-time energy behaviour.",
        )
    raise ValueError(f"potential must be 'free' or 'harmonic'; got {potential!r}")
