r"""Models from ``sympy.physics.mechanics`` objects built for Kane's method.

A :class:`~sympy.physics.mechanics.KanesMethod` (or a :class:`~sympy.physics.mechanics.System`)
describes a system by bodies, loads, generalized speeds ``u`` and kinematic differential
equations ``k_u u + k_q̇ q̇ + f_k = 0``. Kane's equations eliminate the constraint forces;
lobattodae keeps them as multipliers, so the conversion goes back to the Lagrangian form in
the coordinates:

    u(t, q, q̇) = −k_u⁻¹ (k_q̇ q̇ + f_k)                   (k_u square and invertible)
    L = Σ_bodies T_b(u(t, q, q̇)) − Σ_bodies V_b          (kinetic and potential energies)
    F_i = Σ_loads (∂v_P/∂q̇_i) · F_P + (∂ω_B/∂q̇_i) · τ_B  (generalized forces of the loads)
    ψ(t, q) = 0                                           (configuration constraints)
    c(t, q, q̇) = k_nh u(t, q, q̇) + f_nh = 0               (velocity constraints)

and hands these to :func:`~lobattodae.mechanics.from_lagrangian`. A :class:`KanesMethod`
requires a velocity constraint for every dependent speed, including the time derivatives of
its configuration constraints; those are already kept (``ψ`` is passed as holonomic), so the
velocity constraints that depend on them are dropped (tested numerically at random states).
"""

from __future__ import annotations

from typing import Mapping

import numpy as np
import sympy as sp

from ._builders import from_lagrangian, load_forces
from ._model import LagrangianModel
from ._parsing import _err

__all__ = ["from_kanes_method", "from_system"]


def from_kanes_method(method, *, name: str | None = None, defaults: Mapping | None = None,
                      simplify: bool = False) -> LagrangianModel:
    r"""Build a :class:`~lobattodae.mechanics.LagrangianModel` from a
    :class:`sympy.physics.mechanics.KanesMethod`.

    Uses its inertial frame, coordinates (independent and dependent), generalized speeds,
    kinematic differential equations, configuration constraints (holonomic), velocity
    constraints (nonholonomic, without those that are derivatives of the configuration
    constraints), ``bodies`` (kinetic energies and any ``potential_energy`` set on them) and
    ``forcelist``/``loads`` (generalized forces). The multipliers are lobattodae's: one per
    kept constraint, ``p' = ∂L/∂q + F + μᵀλ`` (Kane's method has none to compare with).

    Parameters
    ----------
    method : sympy.physics.mechanics.KanesMethod
        The system (its equations need not have been formed).
    name : str, optional
        For messages (default ``"LagrangianModel"``).
    defaults : dict, optional
        Default parameter values for :meth:`~lobattodae.mechanics.LagrangianModel.args`.
    simplify : bool, optional
        As in :func:`~lobattodae.mechanics.from_lagrangian`.

    Returns
    -------
    LagrangianModel
        The model; ``model.problem`` is the problem to pass to :func:`~lobattodae.solve`.

    Raises
    ------
    LobattoDAEInputError
        For anything that is not a ``KanesMethod``, a ``KanesMethod`` without bodies,
        auxiliary speeds, kinematic equations that do not determine the speeds from the
        coordinate rates (fewer speeds than coordinates, or ``k_u`` singular), or no
        constraint at all.
    """
    from sympy.physics.mechanics import KanesMethod

    if not isinstance(method, KanesMethod):
        raise _err(
            f"from_kanes_method needs a sympy.physics.mechanics.KanesMethod; got {type(method).__name__}. "
            "Use from_system for a System, from_lagranges_method for a LagrangesMethod."
        )
    if len(method._uaux):
        raise _err(
            "the KanesMethod has auxiliary speeds (u_auxiliary), which Kane's method uses to "
            "compute constraint forces; lobattodae computes them from its multipliers "
            "(model.constraint_forces). Build the KanesMethod without u_auxiliary."
        )
    try:
        kdes = [qd - rate for qd, rate in method.kindiffdict().items()]
    except AttributeError:  # built without kd_eqs
        kdes = []
    velocity = list(method._k_nh * method.u + method._f_nh) if method._k_nh.shape[0] else []
    return _convert(
        "KanesMethod", method._inertial, list(method.q), list(method.u), kdes,
        method.bodies, method.loads, list(method._f_h), velocity,
        name=name, defaults=defaults, simplify=simplify, drop_dependent=True,
    )


def from_system(system, *, name: str | None = None, defaults: Mapping | None = None,
                simplify: bool = False) -> LagrangianModel:
    r"""Build a :class:`~lobattodae.mechanics.LagrangianModel` from a
    :class:`sympy.physics.mechanics.System`.

    Uses ``system.frame``, ``q``, ``u``, ``kdes``, ``bodies``, ``loads`` (including those of
    ``apply_uniform_gravity`` and actuators added as loads), ``holonomic_constraints`` and
    ``nonholonomic_constraints`` (the latter are independent of the derivatives of the former
    by construction of a ``System``). Joints contribute through the bodies, coordinates,
    speeds and kinematic equations they add.

    Parameters
    ----------
    system : sympy.physics.mechanics.System
        The system (its equations need not have been formed).
    name : str, optional
        For messages (default ``"LagrangianModel"``).
    defaults : dict, optional
        Default parameter values for :meth:`~lobattodae.mechanics.LagrangianModel.args`.
    simplify : bool, optional
        As in :func:`~lobattodae.mechanics.from_lagrangian`.

    Returns
    -------
    LagrangianModel
        The model; ``model.problem`` is the problem to pass to :func:`~lobattodae.solve`.

    Raises
    ------
    LobattoDAEInputError
        For anything that is not a ``System``, a ``System`` with auxiliary speeds, and the
        cases of :func:`from_kanes_method` (no bodies, kinematic equations that do not
        determine the speeds, no constraint at all).
    """
    from sympy.physics.mechanics import System

    if not isinstance(system, System):
        raise _err(f"from_system needs a sympy.physics.mechanics.System; got {type(system).__name__}.")
    if len(system.u_aux):
        raise _err(
            "the System has auxiliary speeds (u_aux); lobattodae computes constraint forces from its "
            "multipliers (model.constraint_forces). Build the System without auxiliary speeds."
        )
    loads = list(system.loads) + [load for actuator in system.actuators for load in actuator.to_loads()]
    return _convert(
        "System", system.frame, list(system.q), list(system.u), list(system.kdes), system.bodies, loads,
        list(system.holonomic_constraints), list(system.nonholonomic_constraints),
        name=name, defaults=defaults, simplify=simplify, drop_dependent=False,
    )


def _speeds_in_rates(kind, q, u, kdes, t):
    r"""``u(t, q, q̇)`` from ``k_u u + k_q̇ q̇ + f_k = 0``, as a substitution dict."""
    if not kdes:
        raise _err(f"the {kind} has no kinematic differential equations: give kd_eqs (e.g. q' - u = 0 for each q).")
    if len(u) != len(q):
        raise _err(
            f"the {kind} has {len(u)} generalized speeds for {len(q)} coordinates; lobattodae needs the "
            "speeds to determine the coordinate rates one to one (as many speeds as coordinates, the "
            "dependent ones included). Add the dependent speeds with their velocity constraints."
        )
    kdes = sp.Matrix(kdes)
    k_u = kdes.jacobian(u)
    rest = kdes.xreplace(dict.fromkeys(u, 0))
    if any(sym in u for sym in k_u.atoms(sp.Function)):
        raise _err(f"the {kind}'s kinematic differential equations are not linear in the speeds {u}.")
    det = sp.simplify(k_u.det())
    if det == 0:
        raise _err(
            f"the {kind}'s kinematic differential equations do not determine the speeds from the coordinate "
            f"rates (∂kdes/∂u is singular: {sp.sstr(k_u)}); choose speeds that are independent combinations "
            "of the coordinate rates."
        )
    solved = k_u.LUsolve(-rest)
    # Simplify the short expressions of a typical speed map (u = R(q)ᵀq̇ needs sin² + cos² = 1).
    return {uk: sp.simplify(expr) if sp.count_ops(expr) <= 60 else expr for uk, expr in zip(u, solved)}


def _energies(kind, frame, bodies, to_rates):
    """Σ kinetic energies (in the coordinate rates) and Σ potential energies of the bodies."""
    if not bodies:
        raise _err(
            f"the {kind} has no bodies: lobattodae needs them for the kinetic energy. Pass bodies=[...] "
            "(Particle/RigidBody) when you build it."
        )
    kinetic = sum((body.kinetic_energy(frame) for body in bodies), sp.S.Zero).xreplace(to_rates)
    potential = sum((sp.sympify(body.potential_energy) for body in bodies), sp.S.Zero).xreplace(to_rates)
    return kinetic, potential


def _independent_rows(rows, kept, coords, t, n_trials: int = 3, seed: int = 0):
    r"""The entries of ``rows`` (velocity constraints) whose velocity coefficients are
    independent of ``kept`` and of the rows taken before them, at random numeric states."""
    qdots = [c.diff(t) for c in coords]
    every = sp.Matrix(kept + rows)
    if every.shape[0] == 0:
        return []
    jac = every.jacobian(qdots)
    symbols = sorted(jac.free_symbols - {t}, key=str)
    functions = list(coords)
    rng = np.random.default_rng(seed)
    fn = sp.lambdify([t, functions, symbols], jac, modules="numpy")
    samples = [
        np.asarray(fn(rng.uniform(0.1, 0.9), rng.uniform(-1.0, 1.0, len(functions)),
                      rng.uniform(0.5, 1.5, len(symbols))), dtype=float)
        for _ in range(n_trials)
    ]
    taken = list(range(len(kept)))
    independent = []
    for j in range(len(rows)):
        trial = taken + [len(kept) + j]
        if all(np.linalg.matrix_rank(a[trial]) == len(trial) for a in samples):
            taken = trial
            independent.append(rows[j])
    return independent


def _convert(kind, frame, q, u, kdes, bodies, loads, holonomic, velocity, *, name, defaults, simplify,
             drop_dependent):
    from sympy.physics.vector import dynamicsymbols

    t = dynamicsymbols._t
    qdots = [c.diff(t) for c in q]
    to_rates = _speeds_in_rates(kind, q, u, kdes, t)
    kinetic, potential = _energies(kind, frame, bodies, to_rates)
    forces = load_forces(kind, frame, loads, qdots, to_rates)
    nonholonomic = [sp.sympify(c).xreplace(to_rates) for c in velocity]
    if drop_dependent and holonomic and nonholonomic:
        differentiated = [sp.diff(psi, t) for psi in holonomic]
        nonholonomic = _independent_rows(nonholonomic, differentiated, q, t)
    return from_lagrangian(
        kinetic - potential, q, t,
        nonholonomic=nonholonomic or None,
        holonomic=holonomic or None,
        forces=forces if any(f != 0 for f in forces) else None,
        name=name if name is not None else f"{kind} model",
        defaults=defaults,
        simplify=simplify,
    )
