"""The McLachlan-Perlmutter contact oscillator and its non-reversible variant
(PROBLEMS.md, section 6)."""

from __future__ import annotations

import math
from typing import NamedTuple

import jax.numpy as jnp
import numpy as np

from .._problem import NonholonomicSystem
from ._base import Example, consistent_lambda0, finite, positive, t_span_to

__all__ = ["ContactParams", "contact_oscillator"]


class ContactParams(NamedTuple):
    """The parameters of :func:`contact_oscillator` (its ``args``).

    Attributes
    ----------
    epsilon : float
        Coupling ε.
    kappa : float
        The amplitude of ``S = kappa·cos z`` (``kappa = 0``: the reversible
        McLachlan-Perlmutter oscillator; 1: the non-reversible variant).
    """

    epsilon: float
    kappa: float


def _grad_s(q, args):
    z = q[2]
    zero = jnp.zeros_like(z)
    return jnp.stack([zero, zero, -args.kappa * jnp.sin(z)])


def _hamiltonian(t, q, p, args):
    x, z = q[0], q[2]
    u = p + _grad_s(q, args)
    return 0.5 * (jnp.dot(q, q) + args.epsilon * x**2 * z**2 + jnp.dot(u, u))


def _constraint_matrix(t, q, args):
    # x' + y z' = 0
    y = q[1]
    return jnp.stack([jnp.ones_like(y), jnp.zeros_like(y), y])[None, :]


PROBLEM = NonholonomicSystem(_hamiltonian, _constraint_matrix, name="contact oscillator")


def _energy(t, q, p, args):
    return _hamiltonian(t, q, p, args)


def _energy_y(t, q, p, args):
    # y decouples (∇S has no y component): y'' = -y, y' = p_y.
    return 0.5 * (q[1] ** 2 + p[1] ** 2)


def contact_oscillator(
    reversible: bool = True,
    *,
    epsilon: float = 0.3,
    energy: float = 1.5,
    energy_y: float = 0.5,
    z0: float = 0.5,
    t_end: float = 100.0,
) -> Example:
    r"""McLachlan & Perlmutter's contact oscillator (J. Nonlinear Sci. 16, 2006,
    Example 5.2), or a non-reversible variant.

    ``q = (x, y, z)``, constraint ``x' + y z' = 0`` (``μ = (1, 0, y)``),
    ``H = ½(|q|² + ε x² z² + |p + ∇S(q)|²)`` with ``S = 0`` (reversible, i.e.
    ``H = ½|p|² + ½|q|² + (ε/2) x² z²``) or ``S = cos z`` (non-reversible; then
    ``q' = p + ∇S`` and ``φ = μ(q)(p + ∇S)``). ``y`` decouples, ``y'' = -y``; H and
    ``H_y = ½(y² + y'²)`` are conserved. No closed form.

    Initial values: ``q0 = (x0, 0, z0)``, ``q'(0) = (0, √(2 H_y), 0)`` (so
    ``p0 = (0, √(2 H_y), 0)`` for the reversible and ``p0 = (0, √(2 H_y), sin z0)`` for
    the non-reversible system, which satisfies ``φ = 0``), with ``x0 > 0`` such that
    ``H = energy``: ``x0² (1 + ε z0²) = 2 (energy - energy_y) - z0²``.

    Parameters
    ----------
    reversible : bool
        ``S = 0`` (default) or ``S = cos z``.
    epsilon : float
        Coupling ε (default 0.3).
    energy, energy_y : float
        Total energy H and the energy ``H_y`` of the y oscillator (default 1.5, 0.5).
    z0 : float
        Initial z (default 0.5; needs ``z0² < 2 (energy - energy_y)``).
    t_end : float
        End of ``t_span = (0, t_end)`` (default 100). McLachlan & Perlmutter use the
        step ``h = 2 sin(π/N)`` with N = 15 or 40.

    Returns
    -------
    Example
        The oscillator, named ``"contact"`` or ``"contact-nonreversible"``.

    Raises
    ------
    ValueError
        A parameter that is not finite, ``energy_y`` or ``t_end`` not positive, or no
        ``x0 > 0`` with ``H = energy`` (``z0² ≥ 2 (energy - energy_y)``, or
        ``1 + ε z0² ≤ 0``).
    """
    epsilon = finite("epsilon", epsilon)
    energy = finite("energy", energy)
    energy_y = positive("energy_y", energy_y)
    z0 = finite("z0", z0)
    rest = 2.0 * (energy - energy_y) - z0**2
    denom = 1.0 + epsilon * z0**2
    if not (rest > 0.0 and denom > 0.0):
        raise ValueError(
            "no initial x0 > 0 with H = energy: need z0**2 < 2*(energy - energy_y) and "
            f"1 + epsilon*z0**2 > 0; got energy={energy}, energy_y={energy_y}, z0={z0}, "
            f"epsilon={epsilon}"
        )
    x0 = math.sqrt(rest / denom)
    kappa = 0.0 if reversible else 1.0
    params = ContactParams(epsilon=epsilon, kappa=kappa)
    q0 = np.array([x0, 0.0, z0])
    p0 = np.array([0.0, math.sqrt(2.0 * energy_y), kappa * math.sin(z0)])
    lam0 = consistent_lambda0(PROBLEM, q0, p0, params, 1)
    if reversible:
        name = "contact"
        description = "McLachlan-Perlmutter contact oscillator (reversible), no closed form"
        notes = (
            "Reversible: reversible integrators keep the energy bounded (no drift) over "
            "long times. Step h = 2 sin(pi/N), N = 15 or 40, in the original paper."
        )
    else:
        name = "contact-nonreversible"
        description = "contact oscillator with S = cos z (not reversible), no closed form"
        notes = (
            "Breaks the reversibility: the energy of (reversible) Lobatto IIIA-IIIB "
            "drifts on this problem; shown honestly, not a bug."
        )
    return Example(
        name=name,
        problem=PROBLEM,
        t_span=t_span_to(t_end),
        q0=q0,
        p0=p0,
        lam0=lam0,
        args=params,
        invariants={"energy": _energy, "H_y": _energy_y},
        exact=None,
        description=description,
        notes=notes,
    )
