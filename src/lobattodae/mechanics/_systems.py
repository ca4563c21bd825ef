r"""Mechanical systems built with :func:`~lobattodae.mechanics.from_lagrangian`.

Each factory returns a :class:`~lobattodae.mechanics.LagrangianModel`, built once per
process and argument values (cached), so its problem object, and the solver compiled for
it, are reused. Parameters have defaults (``model.args()`` works without arguments;
keywords override them). The tests in ``tests/test_mechanics.py`` check each system against
an independent solution (closed form, hand-written example or a reduced ODE).
"""

from __future__ import annotations

import functools

import numpy as np
import sympy as sp
from sympy.physics.mechanics import dynamicsymbols

from ._bicycle import whipple_bicycle
from ._builders import from_lagrangian
from ._model import LagrangianModel
from ._systems3d import (
    RATTLEBACK_KANE_LEVINSON,
    chaplygin_sphere,
    chaplygin_sphere_state,
    rattleback,
    rattleback_contact,
    rattleback_state,
    suslov,
    suslov_inertia,
    suslov_state,
)

__all__ = [
    "RATTLEBACK_KANE_LEVINSON",
    "cartesian_double_pendulum",
    "cartesian_pendulum",
    "chaplygin_sleigh",
    "chaplygin_sphere",
    "chaplygin_sphere_state",
    "differential_drive",
    "falling_disk",
    "knife_edge",
    "rattleback",
    "rattleback_contact",
    "rattleback_state",
    "suslov",
    "suslov_inertia",
    "suslov_state",
    "turntable_ball",
    "turntable_ball_centre",
    "whipple_bicycle",
]

T = dynamicsymbols._t


@functools.lru_cache(maxsize=None)
def chaplygin_sleigh() -> LagrangianModel:
    r"""The Chaplygin sleigh, as :func:`lobattodae.examples.chaplygin_sleigh`.

    ``q = (x, y, θ)`` (centre of mass, heading), ``L = ½ m (ẋ² + ẏ²) + ½ I θ̇²``, knife edge
    at distance ``a`` behind the centre of mass: ``−sin θ ẋ + cos θ ẏ − a θ̇ = 0``.
    Parameters ``m, I, a`` (defaults 1).

    Returns
    -------
    LagrangianModel
        The model (3 coordinates, 1 multiplier), built once per process.
    """
    x, y, th = dynamicsymbols("x y theta")
    m, inertia, a = sp.symbols("m I a")
    L = sp.Rational(1, 2) * m * (x.diff(T) ** 2 + y.diff(T) ** 2) + sp.Rational(1, 2) * inertia * th.diff(T) ** 2
    c = -sp.sin(th) * x.diff(T) + sp.cos(th) * y.diff(T) - a * th.diff(T)
    return from_lagrangian(L, [x, y, th], T, nonholonomic=[c], name="Chaplygin sleigh (Lagrangian)",
                           defaults={"m": 1.0, "I": 1.0, "a": 1.0})


@functools.lru_cache(maxsize=None)
def knife_edge() -> LagrangianModel:
    r"""The knife edge on an inclined plane, as :func:`lobattodae.examples.knife_edge`.

    ``q = (x, y, θ)``, ``L = ½ m (ẋ² + ẏ²) + ½ J θ̇² − m g y``, ``−sin θ ẋ + cos θ ẏ = 0``.
    Parameters ``m, J, g`` (defaults 1).

    Returns
    -------
    LagrangianModel
        The model (3 coordinates, 1 multiplier), built once per process.
    """
    x, y, th = dynamicsymbols("x y theta")
    m, J, g = sp.symbols("m J g")
    L = (sp.Rational(1, 2) * m * (x.diff(T) ** 2 + y.diff(T) ** 2) + sp.Rational(1, 2) * J * th.diff(T) ** 2
         - m * g * y)
    c = -sp.sin(th) * x.diff(T) + sp.cos(th) * y.diff(T)
    return from_lagrangian(L, [x, y, th], T, nonholonomic=[c], name="knife edge (Lagrangian)",
                           defaults={"m": 1.0, "J": 1.0, "g": 1.0})


@functools.lru_cache(maxsize=None)
def falling_disk() -> LagrangianModel:
    r"""A thin disk rolling without slipping on a plane, free to tilt, derived from its geometry.

    The same system as :func:`lobattodae.examples.falling_rolling_disk` (hand-written there as a
    ``MechanicalSystem``), derived here with ``sympy.physics.mechanics`` vectors: ``q = (x, y,
    θ, φ, ψ)`` (contact point, tilt from the vertical, heading, spin). Frames: ``A`` turned by
    ``φ`` about the vertical, ``B`` tilted by ``−θ`` about ``A.x`` (the rolling direction), the
    disk turned by ``ψ`` about its axle ``B.y``; centre ``C = P + R B.z`` above the contact
    point ``P = (x, y, 0)``.

    ``L = ½ m |v_C|² + ½ (I1 (ω·B.x)² + I1 (ω·B.z)² + I3 (ω·B.y)²) − m g R cos θ``; rolling:
    the material point of the disk at ``P`` has zero horizontal velocity,
    ``ẋ − R cos φ ψ̇ = 0``, ``ẏ − R sin φ ψ̇ = 0``. Parameters ``m, R, g, I1, I3`` (defaults
    1, 1, 1, 1/4, 1/2: a uniform thin disk, as the example).

    Returns
    -------
    LagrangianModel
        The model (5 coordinates, 2 multipliers), built once per process.
    """
    from sympy.physics.mechanics import Point, ReferenceFrame

    x, y, th, ph, ps = dynamicsymbols("x y theta phi psi")
    m, R, g, I1, I3 = sp.symbols("m R g I1 I3")
    ground = ReferenceFrame("N")
    heading = ground.orientnew("A", "Axis", [ph, ground.z])
    tilted = heading.orientnew("B", "Axis", [-th, heading.x])
    disk = tilted.orientnew("D", "Axis", [ps, tilted.y])
    origin = Point("O")
    contact = origin.locatenew("P", x * ground.x + y * ground.y)
    centre = contact.locatenew("C", R * tilted.z)
    v = centre.pos_from(origin).dt(ground)
    w = disk.ang_vel_in(ground)
    kinetic = sp.Rational(1, 2) * (m * v.dot(v) + I1 * (w.dot(tilted.x) ** 2 + w.dot(tilted.z) ** 2)
                                   + I3 * w.dot(tilted.y) ** 2)
    potential = m * g * centre.pos_from(origin).dot(ground.z)
    slip = v + w.cross(-R * tilted.z)  # velocity of the disk's material point at P
    rolling = {"rolling x": slip.dot(ground.x), "rolling y": slip.dot(ground.y)}
    return from_lagrangian(kinetic - potential, [x, y, th, ph, ps], T, nonholonomic=rolling,
                           name="falling rolling disk (Lagrangian)",
                           defaults={"m": 1.0, "R": 1.0, "g": 1.0, "I1": 0.25, "I3": 0.5})


@functools.lru_cache(maxsize=None)
def turntable_ball() -> LagrangianModel:
    r"""A homogeneous ball rolling without slipping on a rotating, translating turntable.

    Coordinates ``q = (x, y, α, β, γ)``: the ball's centre and its orientation
    ``R = R_x(α) R_y(β) R_z(γ)`` (Tait–Bryan angles). The angular velocity in the lab frame is
    ``ω = (α̇ + γ̇ sin β, β̇ cos α − γ̇ sin α cos β, β̇ sin α + γ̇ cos α cos β)``, so
    ``|ω|² = α̇² + β̇² + γ̇² + 2 α̇ γ̇ sin β`` and ``M`` is positive definite for
    ``|β| < π/2`` (the chart is singular at ``β = ±π/2``: keep runs away from it; starting
    from ``β = 0``, ``β`` stays small while the ball has rolled through less than about a
    radian about the lab's y axis). Because the ball is homogeneous only ``ω`` enters ``L``:

    ``L = ½ m (ẋ² + ẏ²) + ½ I |ω|²``, ``I = (2/5) m r²``.

    The table turns at the constant rate ``Ω`` about its centre ``c(t) = (Vx t, Vy t)``, which
    moves at constant velocity. Rolling: the contact point ``(x, y, 0)`` of the ball (centre
    minus ``r ẑ``) moves with the table, ``ẋ + ω × (−r ẑ) = V + Ω ẑ × (x − c(t))``:

    ``ẋ − r ω_y − Vx + Ω (y − Vy t) = 0``, ``ẏ + r ω_x − Vy − Ω (x − Vx t) = 0``

    (affine and explicitly time-dependent). The centre moves on a circle, relative to the
    table's centre, at the angular frequency ``2Ω/7`` (:func:`turntable_ball_centre`).
    Parameters ``m, r, Omega, Vx, Vy`` (defaults 1, 1, 1, 0, 0).

    Returns
    -------
    LagrangianModel
        The model (5 coordinates, 2 multipliers), built once per process.
    """
    x, y, al, be, ga = dynamicsymbols("x y alpha beta gamma")
    m, r, Om, Vx, Vy = sp.symbols("m r Omega Vx Vy")
    d = {s: s.diff(T) for s in (x, y, al, be, ga)}
    wx = d[al] + d[ga] * sp.sin(be)
    wy = d[be] * sp.cos(al) - d[ga] * sp.sin(al) * sp.cos(be)
    wz = d[be] * sp.sin(al) + d[ga] * sp.cos(al) * sp.cos(be)
    inertia = sp.Rational(2, 5) * m * r**2
    L = sp.Rational(1, 2) * m * (d[x] ** 2 + d[y] ** 2) + sp.Rational(1, 2) * inertia * (wx**2 + wy**2 + wz**2)
    rolling = {
        "x": d[x] - r * wy - Vx + Om * (y - Vy * T),
        "y": d[y] + r * wx - Vy - Om * (x - Vx * T),
    }
    return from_lagrangian(L, [x, y, al, be, ga], T, nonholonomic=rolling, name="ball on a turntable", simplify=True,
                           defaults={"m": 1.0, "r": 1.0, "Omega": 1.0, "Vx": 0.0, "Vy": 0.0})


def turntable_ball_centre(t, x0, y0, vx0, vy0, Omega, Vx=0.0, Vy=0.0):
    r"""The closed-form motion of the ball's centre on the turntable of :func:`turntable_ball`.

    With ``w = ẋ − V`` the centre's velocity relative to the table's translation, rolling
    and the Newton–Euler equations (``m ẍ = F``, ``I ω̇ = −r ẑ × F``) give
    ``(1 + m r²/I) ẇ = Ω ẑ × w``, i.e. ``ẇ = ω_c ẑ × w`` with ``ω_c = Ω I/(I + m r²) = 2Ω/7``:
    ``w`` turns at the rate ``ω_c``, and ``x(t) = x0 + V t − ẑ × (w(t) − w(0))/ω_c``. The
    centre moves on a circle of radius ``|w(0)|/ω_c`` about ``x0 + ẑ × w(0)/ω_c``, which moves
    with the table at ``V``; neither depends on ``m`` or ``r``.

    Parameters
    ----------
    t : float or array_like
        Times.
    x0, y0 : float
        The centre at ``t = 0``.
    vx0, vy0 : float
        The centre's velocity at ``t = 0``.
    Omega : float
        The table's rate of turn (rad per unit time).
    Vx, Vy : float, optional
        The table centre's constant velocity (default 0: the table turns in place about the
        origin).

    Returns
    -------
    x, y, vx, vy : numpy.ndarray
        The centre and its velocity, each shaped like ``t``.
    """
    t = np.asarray(t, dtype=np.float64)
    wc = 2.0 * Omega / 7.0
    w0x, w0y = vx0 - Vx, vy0 - Vy
    c, s = np.cos(wc * t), np.sin(wc * t)
    wx, wy = c * w0x - s * w0y, s * w0x + c * w0y
    if wc == 0.0:
        px, py = x0 + w0x * t, y0 + w0y * t
    else:
        px = x0 + (wy - w0y) / wc
        py = y0 - (wx - w0x) / wc
    return px + Vx * t, py + Vy * t, wx + Vx, wy + Vy


@functools.lru_cache(maxsize=None)
def differential_drive(torques: tuple | None = None) -> LagrangianModel:
    r"""A differential-drive robot driven by wheel torques.

    Coordinates ``q = (x, y, θ, φ_r, φ_l)``: the axle's midpoint, the heading and the wheel
    angles. The chassis' centre of mass is at distance ``d`` ahead of the axle (mass ``m``,
    moment of inertia ``I`` about its centre of mass); each wheel (radius ``ρ``, at ``±b`` from
    the midpoint) has spin inertia ``Jw``:

    ``L = ½ m [(ẋ − d θ̇ sin θ)² + (ẏ + d θ̇ cos θ)²] + ½ I θ̇² + ½ Jw (φ̇_r² + φ̇_l²)``.

    Constraints: no sideways slip ``−sin θ ẋ + cos θ ẏ = 0``, rolling
    ``cos θ ẋ + sin θ ẏ ± b θ̇ − ρ φ̇_{r,l} = 0``. Forces on the wheels: motor torques minus
    viscous damping, ``F_{φ_r} = τ_r(t) − c φ̇_r``, ``F_{φ_l} = τ_l(t) − c φ̇_l``, with (default)
    ``τ_r = B + A sin(w t)``, ``τ_l = B − A sin(w t)``.

    Model parameters ``m, I, d, b, rho, Jw, c, A, B, w`` (defaults 1, 0.5, 0.3, 0.4, 0.2,
    0.01, 0.05, 0.2, 0.1, 2; ``A, B, w`` only with the default torques).

    Parameters
    ----------
    torques : tuple of 2 sympy.Expr, optional
        ``(τ_r, τ_l)``: other motor torques, SymPy expressions in
        ``t = dynamicsymbols._t``, the coordinates and parameter symbols (new symbols become
        parameters without defaults). Default: the sinusoidal torques above.

    Returns
    -------
    LagrangianModel
        The model (5 coordinates, 3 multipliers), built once per process and ``torques``.
    """
    x, y, th, pr, pl = dynamicsymbols("x y theta phi_r phi_l")
    m, inertia, dd, b, rho, Jw, c, A, B, w = sp.symbols("m I d b rho Jw c A B w")
    xd, yd, thd, prd, pld = (s.diff(T) for s in (x, y, th, pr, pl))
    L = (sp.Rational(1, 2) * m * ((xd - dd * thd * sp.sin(th)) ** 2 + (yd + dd * thd * sp.cos(th)) ** 2)
         + sp.Rational(1, 2) * inertia * thd**2 + sp.Rational(1, 2) * Jw * (prd**2 + pld**2))
    forward = sp.cos(th) * xd + sp.sin(th) * yd
    constraints = {
        "no slip": -sp.sin(th) * xd + sp.cos(th) * yd,
        "right wheel": forward + b * thd - rho * prd,
        "left wheel": forward - b * thd - rho * pld,
    }
    if torques is None:
        torques = (B + A * sp.sin(w * T), B - A * sp.sin(w * T))
    tau_r, tau_l = torques
    forces = {pr: tau_r - c * prd, pl: tau_l - c * pld}
    defaults = {"m": 1.0, "I": 0.5, "d": 0.3, "b": 0.4, "rho": 0.2, "Jw": 0.01, "c": 0.05,
                "A": 0.2, "B": 0.1, "w": 2.0}
    model = from_lagrangian(L, [x, y, th, pr, pl], T, nonholonomic=constraints, forces=forces,
                            name="differential drive", simplify=True)
    model.defaults.update({k: v for k, v in defaults.items() if k in model.parameters})
    return model


@functools.lru_cache(maxsize=None)
def cartesian_pendulum() -> LagrangianModel:
    r"""A planar pendulum in Cartesian coordinates, with a holonomic constraint.

    ``q = (x, y)`` (bob), ``L = ½ m (ẋ² + ẏ²) − m g y``, ``ψ = x² + y² − ℓ² = 0``. The
    integrator keeps ``ψ̇ = 2 x ẋ + 2 y ẏ = 0`` (a row of φ) and, by projecting every step's
    end point, ``ψ`` itself to round-off (see ``holonomic_residual``). With
    ``x = ℓ sin θ``, ``y = −ℓ cos θ``: ``θ̈ = −(g/ℓ) sin θ``. Parameters ``m, g, l``
    (defaults 1, 9.81, 1).

    Returns
    -------
    LagrangianModel
        The model (2 coordinates, 1 multiplier: the rod), built once per process.
    """
    x, y = dynamicsymbols("x y")
    m, g, ell = sp.symbols("m g l")
    L = sp.Rational(1, 2) * m * (x.diff(T) ** 2 + y.diff(T) ** 2) - m * g * y
    return from_lagrangian(L, [x, y], T, holonomic=[x**2 + y**2 - ell**2], name="Cartesian pendulum",
                           defaults={"m": 1.0, "g": 9.81, "l": 1.0})


@functools.lru_cache(maxsize=None)
def cartesian_double_pendulum() -> LagrangianModel:
    r"""A planar double pendulum in Cartesian coordinates, with two holonomic constraints.

    ``q = (x1, y1, x2, y2)`` (the bobs, masses ``m1, m2``),
    ``L = ½ m1 (ẋ1² + ẏ1²) + ½ m2 (ẋ2² + ẏ2²) − g (m1 y1 + m2 y2)``, rods
    ``ψ1 = x1² + y1² − ℓ1² = 0``, ``ψ2 = (x2 − x1)² + (y2 − y1)² − ℓ2² = 0``, both kept to
    round-off (as in :func:`cartesian_pendulum`). With ``x1 = ℓ1 sin θ1``,
    ``y1 = −ℓ1 cos θ1``, ``x2 = x1 + ℓ2 sin θ2``, ``y2 = y1 − ℓ2 cos θ2`` it is the classical
    double pendulum in the angles (a chaotic system for large energies). Parameters
    ``m1, m2, g, l1, l2`` (defaults 1, 1, 9.81, 1, 1).

    Returns
    -------
    LagrangianModel
        The model (4 coordinates, 2 multipliers: the rods), built once per process.
    """
    x1, y1, x2, y2 = dynamicsymbols("x1 y1 x2 y2")
    m1, m2, g, l1, l2 = sp.symbols("m1 m2 g l1 l2")
    d = {c: c.diff(T) for c in (x1, y1, x2, y2)}
    L = (sp.Rational(1, 2) * m1 * (d[x1] ** 2 + d[y1] ** 2) + sp.Rational(1, 2) * m2 * (d[x2] ** 2 + d[y2] ** 2)
         - g * (m1 * y1 + m2 * y2))
    rods = {"rod 1": x1**2 + y1**2 - l1**2, "rod 2": (x2 - x1) ** 2 + (y2 - y1) ** 2 - l2**2}
    return from_lagrangian(L, [x1, y1, x2, y2], T, holonomic=rods, name="Cartesian double pendulum",
                           defaults={"m1": 1.0, "m2": 1.0, "g": 9.81, "l1": 1.0, "l2": 1.0})
