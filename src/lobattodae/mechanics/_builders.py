"""The builders of a :class:`~lobattodae.mechanics.LagrangianModel`: from a Lagrangian and
constraints written in SymPy (:func:`from_lagrangian`), from SymPy's ``LagrangesMethod``
(:func:`from_lagranges_method`), and the loads of SymPy's mechanics as generalised forces
(:func:`load_forces`)."""

from __future__ import annotations

import contextlib
from collections.abc import Mapping, Sequence

import numpy as np
import sympy as sp

from . import _model_cache
from ._model import RANK_TOL, LagrangianModel
from ._parsing import _Context, _err, _free_of, _labelled, _without

__all__ = ["from_lagrangian", "from_lagranges_method", "load_forces"]


def from_lagrangian(
    lagrangian,
    coordinates,
    t,
    *,
    nonholonomic=None,
    holonomic=None,
    forces=None,
    name: str | None = None,
    defaults: Mapping | None = None,
    simplify: bool = False,
) -> LagrangianModel:
    r"""Build a :class:`LagrangianModel` (and its :class:`~lobattodae.PartitionedDAE`) from a
    Lagrangian.

    Parameters
    ----------
    lagrangian : sympy.Expr
        ``L(t, q, q̇)``, quadratic in the velocities: ``½ q̇ᵀM(t, q)q̇ + a(t, q)ᵀq̇ − V(t, q)``
        with ``M`` symmetric positive definite.
    coordinates : list
        The generalized coordinates, functions of ``t``
        (:func:`sympy.physics.mechanics.dynamicsymbols`).
    t : sympy.Symbol
        The time symbol the coordinates depend on.
    nonholonomic : list or dict, optional
        Expressions ``c(t, q, q̇)`` (or ``Eq``), kept as ``c = 0``; each must be affine in the
        velocities: ``c = μ(t, q) q̇ + ν(t, q)``.
    holonomic : list or dict, optional
        Position constraints ``ψ(t, q) = 0``. They are differentiated once and kept at the
        velocity level, ``ψ_q q̇ + ψ_t = 0``, as rows of φ (index 2), and ψ itself is passed
        to the problem as ``position_constraint``: every step's end point is projected onto
        ``ψ = 0`` (in the kinetic metric, ``q ← q + M⁻¹ψ_qᵀκ``) and back onto ``φ = 0``, so
        both hold to round-off at every step point with the orders of q and p unchanged (the
        projected step is not symmetric; see ``docs/mechanics.md``). q0 must satisfy ψ
        (:meth:`LagrangianModel.check`); :meth:`LagrangianModel.holonomic_residual` evaluates ψ.
    forces : list or dict, optional
        Generalized (non-conservative) forces ``F_i(t, q, q̇)``, one per coordinate (a dict
        ``{coordinate: force}`` may leave out zeros); inputs as explicit functions of ``t``.
    name : str, optional
        For messages (default ``"LagrangianModel"``).
    defaults : dict, optional
        Default parameter values for :meth:`LagrangianModel.args`.
    simplify : bool
        Apply :func:`sympy.simplify` to ``M``, ``a``, ``V``, ``μ``, ``ν`` (slower to build,
        sometimes shorter code).

    Returns
    -------
    LagrangianModel
        The model; ``model.problem`` is the problem to pass to :func:`~lobattodae.solve`.

    Raises
    ------
    LobattoDAEInputError
        For a Lagrangian that is not quadratic in the velocities, a coordinate without
        kinetic energy, a constant mass matrix that is not positive definite, constraints
        that are not affine in the velocities, holonomic constraints with velocities,
        accelerations, undefined functions other than the coordinates, clashing symbol
        names, and malformed arguments; the message names the culprit.

    Notes
    -----
    The multipliers are ordered as ``model.constraint_labels``: nonholonomic constraints
    first, then holonomic ones; ``p' = ∂L/∂q + F + μᵀλ``.

    What is derived (the mass matrix, the constraints' coefficients, the generated code) is kept
    on disk by the inputs, so that a later process given the same ones restores the model
    instead of deriving it again (the Whipple bicycle: seconds; off with
    ``LOBATTODAE_NO_CACHE=1``; see ``docs/mechanics.md``, "Parameters and compilation").
    """
    key = _model_cache.model_key("from_lagrangian", {
        "lagrangian": lagrangian, "coordinates": coordinates, "t": t, "nonholonomic": nonholonomic,
        "holonomic": holonomic, "forces": forces, "name": name, "defaults": defaults, "simplify": simplify})
    kept = _model_cache.load(key)
    if kept is not None:
        with contextlib.suppress(Exception):  # an entry of another layout: derived again below
            return LagrangianModel._restore(kept)
    model = _derive(lagrangian, coordinates, t, nonholonomic, holonomic, forces, name, defaults, simplify)
    _model_cache.store(key, model._snapshot())
    return model


def _derive(lagrangian, coordinates, t, nonholonomic, holonomic, forces, name, defaults, simplify) -> LagrangianModel:
    """:func:`from_lagrangian`'s derivation (validation, M, a, V, μ, ν, F, ψ, the parameters)."""
    ctx = _Context(coordinates, t)
    name = "LagrangianModel" if name is None else str(name)
    L = ctx.internal(lagrangian, "the Lagrangian")
    q, v = ctx.q, ctx.v
    n = ctx.n

    # --- kinetic energy: L = ½ vᵀMv + aᵀv − V
    M = sp.zeros(n, n)
    for i in range(n):
        dLi = sp.diff(L, v[i])
        for j in range(i, n):
            entry = sp.diff(dLi, v[j])
            fixed = _without(entry, v)
            if fixed is None:
                raise _err(
                    f"{name}: the Lagrangian is not quadratic in the velocities: ∂²L/∂{ctx.names[i]}'∂"
                    f"{ctx.names[j]}' = {ctx.pretty((entry))} depends on the velocities. lobattodae."
                    "mechanics needs L = ½ q̇ᵀM(t,q)q̇ + a(t,q)ᵀq̇ − V(t,q)."
                )
            M[i, j] = M[j, i] = fixed
    for i in range(n):
        if M[i, i] == 0:
            raise _err(
                f"{name}: the coordinate {ctx.names[i]} has no kinetic energy (∂²L/∂{ctx.names[i]}'² = 0), "
                "so the mass matrix is singular. Give it kinetic energy, or eliminate it (a "
                "coordinate without inertia is not a dynamical coordinate)."
            )
    a = sp.Matrix([sp.diff(L, v[i]).xreplace(ctx.v_zero) for i in range(n)])
    V = -L.xreplace(ctx.v_zero)
    if simplify:
        M = M.applyfunc(sp.simplify)
        a = a.applyfunc(sp.simplify)
        V = sp.simplify(V)

    # --- constraints: μ v + ν = 0
    rows, offsets, labels, psis = [], [], [], []
    for label, expr in _labelled(nonholonomic, "nonholonomic"):
        c = ctx.internal(expr, f"the constraint {label}")
        row = []
        for i in range(n):
            coeff = _without(sp.diff(c, v[i]), v)
            if coeff is None:
                raise _err(
                    f"{name}: the constraint {label}: {ctx.pretty((c))} = 0 is not affine in the "
                    f"velocities (its coefficient of {ctx.names[i]}' depends on velocities). Constraints "
                    "must read μ(t, q) q̇ + ν(t, q) = 0."
                )
            row.append(coeff)
        if all(r == 0 for r in row):
            raise _err(
                f"{name}: the constraint {label}: {ctx.pretty((c))} = 0 contains no velocities. A "
                "position constraint ψ(t, q) = 0 belongs in holonomic=[...]."
            )
        rows.append(row)
        offsets.append(c.xreplace(ctx.v_zero))
        labels.append(f"{label} ({ctx.pretty(c, 60)} = 0)")
    hol = _labelled(holonomic, "holonomic")
    for label, expr in hol:
        psi = ctx.internal(expr, f"the constraint {label}")
        if not _free_of(psi, v):
            raise _err(
                f"{name}: the holonomic constraint {label}: {ctx.pretty((psi))} = 0 contains "
                "velocities; pass a velocity constraint in nonholonomic=[...]."
            )
        row = [sp.diff(psi, qi) for qi in q]
        if all(r == 0 for r in row):
            raise _err(
                f"{name}: the holonomic constraint {label}: {ctx.pretty((psi))} = 0 does not "
                "depend on the coordinates."
            )
        rows.append(row)
        offsets.append(sp.diff(psi, ctx.t))
        labels.append(f"{label} ({ctx.pretty(psi, 60)} = 0)")
        psis.append(psi)
    m = len(rows)
    if m == 0:
        raise _err(
            f"{name}: no constraints. lobattodae integrates constrained systems (index-2 DAEs "
            "with at least one multiplier): give nonholonomic=[...] or holonomic=[...]; an "
            "unconstrained Lagrangian system is an ODE (use a symplectic ODE integrator)."
        )
    mu = sp.Matrix(m, n, lambda j, i: rows[j][i]) if m else sp.zeros(0, n)
    nu = sp.Matrix(offsets) if m else sp.zeros(0, 1)
    if simplify and m:
        mu = mu.applyfunc(sp.simplify)
        nu = nu.applyfunc(sp.simplify)

    # --- forces
    F = sp.zeros(n, 1)
    if forces is not None:
        if isinstance(forces, Mapping):
            for key, expr in forces.items():
                i = ctx.label(key)
                F[i] = F[i] + ctx.internal(expr, f"the force on {ctx.names[i]}")
        else:
            if isinstance(forces, (sp.Basic, str)) or not isinstance(forces, (Sequence, sp.MatrixBase)):
                raise _err(f"{name}: forces must be a list with one generalized force per coordinate, or a dict; got {forces!r}.")
            flist = list(forces)
            if len(flist) != n:
                raise _err(
                    f"{name}: forces has {len(flist)} entries but there are {n} coordinates "
                    f"{list(ctx.names)}: give one generalized force per coordinate (0 where none), "
                    "or a dict {coordinate: force}."
                )
            for i, expr in enumerate(flist):
                F[i] = ctx.internal(expr, f"the force on {ctx.names[i]}")

    # --- parameters
    everything = [L, *M, *a, V, *mu, *nu, *F, *psis]
    symbols = set()
    for e in everything:
        symbols |= sp.sympify(e).free_symbols
    symbols -= set(q) | set(v) | {ctx.t}
    params: dict[str, sp.Symbol] = {}
    for s in sorted(symbols, key=lambda s: (s.name, sp.default_sort_key(s))):
        if s.name == ctx.t.name:
            raise _err(
                f"{name}: the symbol {s.name!r} {s.assumptions0 or ''} differs from the time symbol t "
                f"{ctx.t.assumptions0 or ''} the coordinates depend on (same name, other assumptions). "
                "Use one time symbol."
            )
        if s.name in ctx.names:
            raise _err(
                f"{name}: the symbol {s.name!r} has the name of the coordinate {s.name}(t): write "
                f"{s.name}(t) (the coordinate) or rename the parameter."
            )
        if s.name in params:
            raise _err(
                f"{name}: two different symbols are named {s.name!r} (different assumptions: "
                f"{params[s.name].assumptions0} vs {s.assumptions0}); use one symbol per parameter."
            )
        params[s.name] = s
    defaults = dict(defaults or {})
    bad = [k for k in defaults if (k.name if isinstance(k, sp.Symbol) else k) not in params]
    if bad:
        raise _err(f"{name}: defaults for unknown parameter(s) {bad}; the parameters are {list(params)}.")
    defaults = {(k.name if isinstance(k, sp.Symbol) else k): val for k, val in defaults.items()}

    # A constant mass matrix can be checked now.
    if not any(e.free_symbols for e in M):
        w = np.linalg.eigvalsh(np.array(M.tolist(), dtype=np.float64))
        if not w[0] > RANK_TOL * max(float(np.max(np.abs(w))), 1e-300):
            raise _err(
                f"{name}: the kinetic energy is not positive definite: the constant mass matrix "
                f"M = ∂²L/∂q̇² = {M.tolist()} has the eigenvalue {w[0]:.6g}. Check the signs of the "
                "kinetic terms (L = T − V)."
            )

    return LagrangianModel(
        name=name,
        ctx=ctx,
        params=params,
        defaults=defaults,
        parts_internal=(M, a, V, mu, nu, F, sp.Matrix(psis) if psis else sp.zeros(0, 1), L),
        labels=labels,
        n_holonomic=len(psis),
        lagrangian_user=ctx.user(L),
    )


def load_forces(kind: str, frame, loads, qdots, to_rates=None) -> list:
    r"""``F_i = Σ (∂v_P/∂q̇_i)·F + (∂ω_B/∂q̇_i)·τ`` over ``loads`` (``(Point, force)`` or
    ``(ReferenceFrame, torque)`` pairs), velocities in the inertial ``frame``; ``to_rates``
    substitutes speeds by their expressions in the coordinate rates (Kane-style models)."""
    from sympy.physics.mechanics import Point, ReferenceFrame

    forces = [sp.S.Zero] * len(qdots)
    for load in loads or []:
        obj, vec = load[0], load[1]
        if isinstance(obj, Point):
            vel = obj.vel(frame)
        elif isinstance(obj, ReferenceFrame):
            vel = obj.ang_vel_in(frame)
        else:
            raise _err(f"the {kind}'s load ({obj!r}, ...): the first item must be a Point or a ReferenceFrame.")
        v = vel.to_matrix(frame).xreplace(to_rates or {})
        f = vec.to_matrix(frame)
        for i, qd in enumerate(qdots):
            forces[i] += (v.diff(qd).T * f)[0, 0]
    return forces


def from_lagranges_method(method, *, name: str | None = None, defaults: Mapping | None = None,
                          simplify: bool = False) -> LagrangianModel:
    r"""Build a :class:`LagrangianModel` from a :class:`sympy.physics.mechanics.LagrangesMethod`.

    Uses its Lagrangian, coordinates, holonomic constraints (``hol_coneqs``, kept at the
    velocity and position levels as in :func:`from_lagrangian`), nonholonomic constraints
    (``nonhol_coneqs``) and its ``forcelist`` (generalized forces
    ``F_i = Σ ∂v/∂q̇_i · force`` in the inertial ``frame``, which must then be given).

    Note the sign: SymPy writes ``d/dt ∂L/∂q̇ − ∂L/∂q − F = −(∂c/∂q̇)ᵀλ_sympy``;
    lobattodae's ``λ`` is ``−λ_sympy``.

    Parameters
    ----------
    method : sympy.physics.mechanics.LagrangesMethod
        The system (its equations need not have been formed).
    name : str, optional
        For messages (default ``"LagrangianModel"``).
    defaults : dict, optional
        Default parameter values for :meth:`LagrangianModel.args`.
    simplify : bool, optional
        As in :func:`from_lagrangian`.

    Returns
    -------
    LagrangianModel
        The model; ``model.problem`` is the problem to pass to :func:`~lobattodae.solve`.

    Raises
    ------
    LobattoDAEInputError
        For anything that is not a ``LagrangesMethod`` (a ``KanesMethod`` is pointed to
        :func:`~lobattodae.mechanics.from_kanes_method`), a ``forcelist`` without an inertial
        frame, and everything :func:`from_lagrangian` refuses.
    """
    from sympy.physics.mechanics import KanesMethod, LagrangesMethod
    from sympy.physics.vector import dynamicsymbols

    if isinstance(method, KanesMethod):
        raise _err(
            "from_lagranges_method got a KanesMethod: convert it with mechanics.from_kanes_method(kane) "
            "(or a System with mechanics.from_system(system))."
        )
    if not isinstance(method, LagrangesMethod):
        raise _err(
            f"from_lagranges_method needs a sympy.physics.mechanics.LagrangesMethod; got "
            f"{type(method).__name__}. For a Lagrangian expression use from_lagrangian(L, coordinates, t)."
        )
    t = dynamicsymbols._t
    L = method._L[0]
    coords = list(method.q)
    hol = list(method._hol_coneqs)
    nonhol = list(method.coneqs)[len(hol):]
    qdots = [c.diff(t) for c in coords]
    forces = None
    flist = list(method.forcelist or [])
    if flist:
        frame = method.inertial
        if frame is None:
            raise _err(
                "the LagrangesMethod has a forcelist but no inertial frame: create it with "
                "LagrangesMethod(..., forcelist=..., frame=N)."
            )
        forces = load_forces("LagrangesMethod", frame, flist, qdots)
    return from_lagrangian(
        L, coords, t, nonholonomic=nonhol or None, holonomic=hol or None, forces=forces,
        name=name, defaults=defaults, simplify=simplify,
    )
