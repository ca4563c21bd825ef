r"""Three-dimensional nonholonomic rigid bodies, oriented by unit quaternions.

Each factory returns a :class:`~lobattodae.mechanics.LagrangianModel` built with
:func:`~lobattodae.mechanics.quaternion_body` (coordinates ``Q0..Q3``, the norm
``Q·Q − 1 = 0`` kept to round-off as a holonomic constraint, no singular orientation),
cached per process and arguments. Parameters are SymPy symbols with defaults
(``model.args()`` works without arguments). ``*_state`` helpers turn a physical initial
state (orientation, angular velocity) into consistent ``(q0, p0)``.

The tests in ``tests/test_rigid.py`` check each system against an independently derived
reduced ODE (Euler–Poincaré–Suslov equations in ω; the Chaplygin sphere's equations in
``(K, γ)``; the Newton–Euler equations of a rolling body in ``(ω, γ)``) solved by scipy,
and against its first integrals. See ``docs/rigid-bodies.md``.
"""

from __future__ import annotations

import functools

import numpy as np
import sympy as sp
from sympy.physics.mechanics import dynamicsymbols

from ._builders import from_lagrangian
from ._model import LagrangianModel
from ._rigid import quaternion_body, quaternion_rates, rotation_matrix

__all__ = [
    "suslov",
    "suslov_state",
    "chaplygin_sphere",
    "chaplygin_sphere_state",
    "rattleback",
    "rattleback_state",
    "rattleback_contact",
    "RATTLEBACK_KANE_LEVINSON",
]

T = dynamicsymbols._t


def _unit(Q):
    Q = np.asarray(Q, dtype=float)
    return Q / np.linalg.norm(Q)


# ----------------------------------------------------------------------------- Suslov
@functools.lru_cache(maxsize=None)
def suslov() -> LagrangianModel:
    r"""The Suslov problem: a rigid body about a fixed point with ``⟨ω, a⟩ = 0``.

    ``q = (Q0, Q1, Q2, Q3)`` (orientation), ``L = ½ ωᵀ I ω`` (regularised, see
    :func:`~lobattodae.mechanics.quaternion_body`) with the full inertia tensor about the
    fixed point, ``I = [[I11, I12, I13], [I12, I22, I23], [I13, I23, I33]]`` (body frame),
    and the nonholonomic constraint that the body angular velocity be orthogonal to a
    body-fixed vector ``a = (a1, a2, a3)``: ``aᵀ ω_body = aᵀ 2E(Q) Q̇ = 0``; holonomic
    ``Q·Q − 1 = 0``. Reduced equations (Suslov 1902): ``I ω̇ = (Iω) × ω + λ a``,
    ``aᵀω = 0``. With ``a = e3`` and ``I13``, ``I23`` not both zero the motion is not
    stationary: ω tends to an equilibrium line as ``t → ±∞`` (a nonholonomic system need
    not preserve volume). Energy ``½ ωᵀIω`` is conserved.

    Parameters ``I11, I22, I33, I12, I13, I23, a1, a2, a3``
    (defaults 2, 3, 4, 0, 0.3, 0.2, 0, 0, 1).

    Returns
    -------
    LagrangianModel
        The model (4 coordinates; 2 multipliers: the constraint and ``|Q| = 1``), built once per process.
    """
    names = "I11 I22 I33 I12 I13 I23"
    I11, I22, I33, I12, I13, I23 = sp.symbols(names)
    a = sp.Matrix(sp.symbols("a1 a2 a3"))
    inertia = sp.Matrix([[I11, I12, I13], [I12, I22, I23], [I13, I23, I33]])
    body = quaternion_body("Q", inertia, T)
    constraint = (a.T * body.omega_body)[0, 0]
    return from_lagrangian(
        body.kinetic_energy, body.coordinates, T, nonholonomic={"<omega, a>": constraint},
        holonomic={"|Q|": body.norm_constraint}, name="Suslov problem",
        defaults={"I11": 2.0, "I22": 3.0, "I33": 4.0, "I12": 0.0, "I13": 0.3, "I23": 0.2,
                  "a1": 0.0, "a2": 0.0, "a3": 1.0},
    )


def suslov_state(model, args, Q0, omega0):
    r"""``(q0, p0)`` for :func:`suslov` from an orientation ``Q0`` (normalised here) and a body
    angular velocity ``omega0``, whose component along ``a`` is removed (in the metric of
    ``I``: ``ω ← ω − I⁻¹a (aᵀω)/(aᵀI⁻¹a)``, the velocity the constraint impulse leaves).

    Parameters
    ----------
    model : LagrangianModel
        The model of :func:`suslov`.
    args : dict
        Its parameters (``model.args(...)``).
    Q0 : array_like, shape (4,)
        The orientation, a quaternion (scalar first; normalised here).
    omega0 : array_like, shape (3,)
        The body angular velocity (its component along ``a`` is removed).

    Returns
    -------
    q0 : numpy.ndarray, shape (4,)
        The unit quaternion.
    p0 : numpy.ndarray, shape (4,)
        The momenta of the consistent velocities (``model.momenta``).
    """
    Q0 = _unit(Q0)
    I = suslov_inertia(args)
    a = np.array([float(args[k]) for k in ("a1", "a2", "a3")])
    w = np.asarray(omega0, dtype=float)
    Ia = np.linalg.solve(I, a)
    w = w - Ia * (a @ w) / (a @ Ia)
    qd = quaternion_rates(Q0, w)
    return Q0, model.momenta(0.0, Q0, qd, args)


def suslov_inertia(args) -> np.ndarray:
    """The inertia tensor of :func:`suslov` from its ``args``.

    Parameters
    ----------
    args : dict
        The model's parameters (``model.args(...)``).

    Returns
    -------
    numpy.ndarray, shape (3, 3)
        ``[[I11, I12, I13], [I12, I22, I23], [I13, I23, I33]]`` (body frame).
    """
    g = {k: float(args[k]) for k in ("I11", "I22", "I33", "I12", "I13", "I23")}
    return np.array([[g["I11"], g["I12"], g["I13"]], [g["I12"], g["I22"], g["I23"]], [g["I13"], g["I23"], g["I33"]]])


# ----------------------------------------------------------------------------- Chaplygin sphere
@functools.lru_cache(maxsize=None)
def chaplygin_sphere() -> LagrangianModel:
    r"""The Chaplygin sphere: a dynamically asymmetric ball rolling without slipping on a plane.

    The centre of mass is at the geometric centre; principal moments ``I1, I2, I3`` about it
    (body axes), mass ``m``, radius ``r``. ``q = (x, y, Q0..Q3)`` (centre, orientation),
    ``L = ½ m (ẋ² + ẏ²) + ½ ωᵀ diag(I1, I2, I3) ω`` (regularised). Rolling: the contact
    point ``centre − r e_z`` is at rest, ``ẋ − r ω_y = 0``, ``ẏ + r ω_x = 0`` with
    ``ω = ω_space = 2 G(Q) Q̇``; holonomic ``Q·Q − 1 = 0``.

    Integrals (for ``c = 0``): the energy, and the angular momentum about the contact point
    ``K = Iω + m r² (ω − (ω·γ)γ)`` (body frame, ``γ = Rᵀe_z``), which is constant in space:
    ``R K`` (so ``|K|²`` and ``K·γ``) is conserved; in the body frame ``K̇ = K × ω``,
    ``γ̇ = γ × ω`` (Chaplygin 1903).

    A velocity-dependent torque: viscous damping of the spin about the vertical,
    ``τ = −c (ω·e_z) e_z`` (generalized forces ``2 Gᵀτ`` on ``Q̇``; default ``c = 0``, no
    damping, so one compiled solver serves both). With ``c > 0`` the energy decreases at the
    rate ``c ω_z²`` and ``K·e_z`` at the rate ``c ω_z`` (neither gravity nor the contact force
    has a moment about the contact point), while the horizontal part of ``R K`` stays.

    Parameters ``m, r, I1, I2, I3, c`` (defaults 1, 1, 0.3, 0.4, 0.5, 0).

    Returns
    -------
    LagrangianModel
        The model (6 coordinates; 3 multipliers: rolling and ``|Q| = 1``), built once per process.
    """
    x, y = dynamicsymbols("x y")
    m, r, I1, I2, I3, c = sp.symbols("m r I1 I2 I3 c")
    body = quaternion_body("Q", (I1, I2, I3), T)
    w = body.omega_space
    xd, yd = x.diff(T), y.diff(T)
    L = sp.Rational(1, 2) * m * (xd**2 + yd**2) + body.kinetic_energy
    rolling = {"x": xd - r * w[1], "y": yd + r * w[0]}
    forces = body.torque_forces([0, 0, -c * w[2]], frame="space")
    return from_lagrangian(L, [x, y, *body.coordinates], T, nonholonomic=rolling,
                           holonomic={"|Q|": body.norm_constraint}, forces=forces, name="Chaplygin sphere",
                           defaults={"m": 1.0, "r": 1.0, "I1": 0.3, "I2": 0.4, "I3": 0.5, "c": 0.0})


def chaplygin_sphere_state(model, args, Q0, omega0_body, xy0=(0.0, 0.0)):
    r"""``(q0, p0)`` for :func:`chaplygin_sphere` from an orientation ``Q0`` (normalised), the
    body angular velocity ``omega0_body`` and the centre ``xy0``; the centre's velocity follows
    from rolling, ``v = −ω × (−r e_z)``.

    Parameters
    ----------
    model : LagrangianModel
        The model of :func:`chaplygin_sphere`.
    args : dict
        Its parameters (``model.args(...)``).
    Q0 : array_like, shape (4,)
        The orientation, a quaternion (scalar first; normalised here).
    omega0_body : array_like, shape (3,)
        The angular velocity in the body frame.
    xy0 : array_like, shape (2,), optional
        The centre's horizontal position (default the origin).

    Returns
    -------
    q0 : numpy.ndarray, shape (6,)
        ``(x, y, Q0, Q1, Q2, Q3)``.
    p0 : numpy.ndarray, shape (6,)
        The momenta of the consistent velocities (``model.momenta``).
    """
    Q0 = _unit(Q0)
    w_b = np.asarray(omega0_body, dtype=float)
    w_s = rotation_matrix(Q0) @ w_b
    r = float(args["r"])
    q0 = np.concatenate([np.asarray(xy0, dtype=float), Q0])
    qd = np.concatenate([[r * w_s[1], -r * w_s[0]], quaternion_rates(Q0, w_b)])
    return q0, model.momenta(0.0, q0, qd, args)


# ----------------------------------------------------------------------------- rattleback
#: Kane & Levinson (1982), "Realistic mathematical modeling of the rattleback",
#: Int. J. Non-Linear Mech. 17, 175–186: ellipsoid semi-axes a = 20 cm, b = 3 cm, c = 2 cm,
#: centre of mass h = 1 cm below the ellipsoid's centre, m = 1 kg, central moments
#: A = 2, B = 16, C = 17 kg·cm² and product of inertia D = −0.2 kg·cm² (in SI units here).
RATTLEBACK_KANE_LEVINSON = {
    "a": 0.20, "b": 0.03, "c": 0.02, "h": 0.01, "m": 1.0, "g": 9.81,
    "A": 2.0e-4, "B": 1.6e-3, "C": 1.7e-3, "D": -2.0e-5,
}


def _rattleback_contact_symbolic(gamma, a, b, c, h):
    """``(r_P, z_G)``: contact point from the centre of mass (body frame) and the height of
    the centre of mass, for the body-frame vertical ``gamma``."""
    Dg = sp.diag(a**2, b**2, c**2)
    s = sp.sqrt((gamma.T * Dg * gamma)[0, 0])
    rP = -Dg * gamma / s + sp.Matrix([0, 0, h])
    zG = s - h * gamma[2]
    return rP, zG


@functools.lru_cache(maxsize=None)
def rattleback() -> LagrangianModel:
    r"""A rattleback: an ellipsoid-bottomed rigid body rolling without slipping on a plane.

    Body frame: the ellipsoid ``x²/a² + y²/b² + z²/c² = 1`` (centre ``O``) in its principal
    axes of curvature, ``z`` up when at rest; the centre of mass ``G`` at ``O − h e_z``. The
    central inertia tensor is ``[[A, D, 0], [D, B, 0], [0, 0, C]]``: ``D ≠ 0`` turns the
    principal axes of inertia about ``z`` relative to the axes of curvature, which causes the
    spin reversal. Coordinates ``q = (x, y, Q0..Q3)``: ``G``'s horizontal position and the
    orientation.

    Contact geometry (a function of the orientation only): with the body-frame vertical
    ``γ = Rᵀe_z`` and ``Dg = diag(a², b², c²)``, the contact point is where the outward normal
    is ``−γ``: ``O − Dg γ / √(γᵀDgγ)``, so from ``G``

    ``r_P = −Dg γ/√(γᵀDgγ) + h e_z``,   ``z_G = −γ·r_P = √(γᵀDgγ) − h γ_z``.

    ``L = ½ m (ẋ² + ẏ² + ż_G²) + ½ ωᵀIω − m g z_G`` (``ż_G = ∇_Q z_G · Q̇``; rotation
    regularised). Rolling (the contact point of the body at rest), horizontal components:
    ``(ẋ, ẏ) + (ω × R r_P)_{x,y} = 0`` (``ω = ω_space``); the vertical component holds by
    construction of ``z_G``. Holonomic ``Q·Q − 1 = 0``. No dissipation: the energy
    ``½ m |v_G|² + ½ ωᵀIω + m g z_G`` is conserved.

    Parameters ``a, b, c, h, m, g, A, B, C, D``, defaults
    :data:`RATTLEBACK_KANE_LEVINSON` (Kane & Levinson 1982).

    Returns
    -------
    LagrangianModel
        The model (6 coordinates; 3 multipliers: rolling and ``|Q| = 1``), built once per process.
    """
    x, y = dynamicsymbols("x y")
    a, b, c, h, m, g, A, B, C, D = sp.symbols("a b c h m g A B C D")
    inertia = sp.Matrix([[A, D, 0], [D, B, 0], [0, 0, C]])
    body = quaternion_body("Q", inertia, T)
    rP, zG = _rattleback_contact_symbolic(body.vertical, a, b, c, h)
    zGd = zG.diff(T)
    xd, yd = x.diff(T), y.diff(T)
    L = sp.Rational(1, 2) * m * (xd**2 + yd**2 + zGd**2) + body.kinetic_energy - m * g * zG
    slip = body.omega_space.cross(body.rotation * rP)
    rolling = {"x": xd + slip[0], "y": yd + slip[1]}
    return from_lagrangian(L, [x, y, *body.coordinates], T, nonholonomic=rolling,
                           holonomic={"|Q|": body.norm_constraint}, name="rattleback",
                           defaults=dict(RATTLEBACK_KANE_LEVINSON))


def rattleback_contact(gamma, args):
    r"""The contact geometry of :func:`rattleback` for body-frame verticals ``γ``.

    Parameters
    ----------
    gamma : array_like, shape (3,) or (N, 3)
        ``γ = Rᵀ e_z``, the upward unit vector in body coordinates (the third row of the
        rotation matrix).
    args : dict
        The model's parameters (``a, b, c, h`` are used).

    Returns
    -------
    r_P : numpy.ndarray, shape (3,) or (N, 3)
        The contact point from the centre of mass, in the body frame.
    z_G : numpy.ndarray, shape () or (N,)
        The height of the centre of mass above the plane.
    dr_P : numpy.ndarray, shape (3, 3) or (N, 3, 3)
        The Jacobian ``∂r_P/∂γ``.
    """
    gamma = np.asarray(gamma, dtype=float)
    Dg = np.array([float(args["a"]) ** 2, float(args["b"]) ** 2, float(args["c"]) ** 2])
    h = float(args["h"])
    Dgam = Dg * gamma
    s = np.sqrt(np.sum(gamma * Dgam, -1))[..., None]
    rP = -Dgam / s + np.array([0.0, 0.0, h])
    zG = s[..., 0] - h * gamma[..., 2]
    jac = -np.eye(3) * Dg / s[..., None] + Dgam[..., :, None] * Dgam[..., None, :] / s[..., None] ** 3
    return rP, zG, jac


def rattleback_state(model, args, Q0, omega0_body, xy0=(0.0, 0.0)):
    r"""``(q0, p0)`` for :func:`rattleback` from an orientation ``Q0`` (normalised), the body
    angular velocity and ``G``'s horizontal position; ``G``'s velocity from rolling,
    ``v_G = −ω × R r_P``.

    Parameters
    ----------
    model : LagrangianModel
        The model of :func:`rattleback`.
    args : dict
        Its parameters (``model.args(...)``).
    Q0 : array_like, shape (4,)
        The orientation, a quaternion (scalar first; normalised here).
    omega0_body : array_like, shape (3,)
        The angular velocity in the body frame (for a spin ``s`` about the vertical:
        ``rotation_matrix(Q0).T @ (0, 0, s)``).
    xy0 : array_like, shape (2,), optional
        ``G``'s horizontal position (default the origin).

    Returns
    -------
    q0 : numpy.ndarray, shape (6,)
        ``(x, y, Q0, Q1, Q2, Q3)``.
    p0 : numpy.ndarray, shape (6,)
        The momenta of the consistent velocities (``model.momenta``).
    """
    Q0 = _unit(Q0)
    R = rotation_matrix(Q0)
    w_b = np.asarray(omega0_body, dtype=float)
    rP, _, _ = rattleback_contact(R[2], args)
    vG = -R @ np.cross(w_b, rP)
    q0 = np.concatenate([np.asarray(xy0, dtype=float), Q0])
    qd = np.concatenate([vG[:2], quaternion_rates(Q0, w_b)])
    return q0, model.momenta(0.0, q0, qd, args)
