r"""The nonlinear Whipple bicycle and its benchmark linearisation (Meijaard et al. 2007).

The model of J. P. Meijaard, J. M. Papadopoulos, A. Ruina & A. L. Schwab, "Linearized dynamics
equations for the balance and steer of a bicycle: a benchmark and review", Proc. R. Soc. A 463
(2007) 1955–1982, doi:10.1098/rspa.2007.1857 (cited below as MPRS): four rigid bodies, the
rear wheel R, the rear frame B with the rider rigidly attached, the front frame H (fork and
handlebar) and the front wheel F, hinged at the rear axle, the steering axis and the front
axle; both wheels are knife edges rolling without slip on flat level ground. No friction, no
rider input: the system is conservative.

Conventions (MPRS Sect. 2): a right-handed global frame with ``x`` forward, ``y`` to the
right and ``z`` *down*; the ground is ``z = 0``. In the reference configuration (upright,
straight ahead, both wheels on the ground) the rear contact point is the origin, the front
contact is at ``(w, 0, 0)``, the steering axis (tilted back by ``λ`` from the vertical) meets
the ground at ``(w + c, 0, 0)`` (``c`` the trail), the wheel centres are at ``(0, 0, −rR)`` and
``(w, 0, −rF)``, the mass centres of B and H at ``(xB, 0, zB)`` and ``(xH, 0, zH)`` (``zB``,
``zH`` negative: above the ground), and the inertia matrices of B and H are given in these
global axes,

.. math::

    I_B = \begin{pmatrix} I_{Bxx} & 0 & I_{Bxz} \\ 0 & I_{Byy} & 0 \\ I_{Bxz} & 0 & I_{Bzz}\end{pmatrix},
    \qquad T_{\rm rot} = \tfrac12 ω^T I ω

(``I_{Bxz}`` is the matrix entry, i.e. ``−∫ x z dm``); the wheels are axisymmetric, with
``I_{Rxx} = I_{Rzz}``, ``I_{Fxx} = I_{Fzz}``.

Coordinates ``q = (x, y, ψ, φ, θ, δ, θ_R, θ_F)``: the rear contact point ``(x, y, 0)``, the
rear frame's yaw ``ψ`` (about the global ``z``), roll ``φ`` (about the yawed ``x`` axis,
positive leaning to the right) and pitch ``θ`` (about the rolled ``y`` axis), the steer
angle ``δ`` (about the steering axis, pointing down, so positive steers to the right), and
the wheels' rotations relative to the rear frame (``θ_R``, about the rear axle) and to the
front frame (``θ_F``, about the front axle). Rolling forward at speed ``v`` has
``θ̇_R = −v/rR`` (MPRS: ``v = −θ̇_R rR``).

Constraints (8 coordinates, 7-dimensional configuration space, 3 velocity degrees of
freedom, as in MPRS):

* holonomic, ``ψ_F(φ, θ, δ) = 0``: the front wheel touches the ground. With ``a`` the front
  axle direction and ``n`` the global ``z`` axis, the front contact point (the wheel's lowest
  point) is ``C_F + rF (n − (n·a) a)/√(1 − (n·a)²)``, so its height condition reads
  ``ψ_F = n·C_F + rF √(1 − (n·a)²) = 0``; lobattodae keeps it exactly (projection) and its
  derivative as a row of φ;
* nonholonomic (4): the material points of both wheels at their contacts have no horizontal
  velocity, ``v_C + ω_wheel × (contact − C) = 0`` along the yawed ``x`` and ``y`` axes (the
  vertical components vanish identically for the rear wheel, and are ``ψ̇_F`` for the front).

Lagrangian ``L = T − V``, ``T = Σ ½ m v_G² + ½ ωᵀ I ω`` over the four bodies,
``V = −g Σ m z_G`` (``z`` down). All 26 parameters are SymPy symbols (names as in MPRS
Table 1, ``lam`` for ``λ``); the defaults are the benchmark bicycle of MPRS Table 1.

The linearisation about upright straight rolling gives MPRS eq. (5.1),

.. math::

    M \ddot{\mathbf q} + v C_1 \dot{\mathbf q} + (g K_0 + v^2 K_2)\mathbf q = \mathbf f,
    \qquad \mathbf q = (φ, δ),\quad \mathbf f = (T_φ, T_δ),

computed here from the generated nonlinear model with JAX derivatives (:func:`linearize`),
never from the formulas of MPRS Appendix A.
"""

from __future__ import annotations

import functools
import weakref
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import sympy as sp
from sympy.physics.mechanics import ReferenceFrame, Vector, dynamicsymbols

from .. import _compile
from ._builders import from_lagrangian
from ._model import LagrangianModel

__all__ = [
    "BENCHMARK",
    "BenchmarkMatrices",
    "COORDINATES",
    "eigenvalues",
    "linearize",
    "state_matrix",
    "upright_state",
    "weave_capsize_speeds",
    "whipple_bicycle",
]

T = dynamicsymbols._t

#: The coordinate names of :func:`whipple_bicycle`, in the order of ``q``.
COORDINATES = ("x", "y", "yaw", "roll", "pitch", "steer", "theta_R", "theta_F")
_ROLL, _PITCH, _STEER, _THR = 3, 4, 5, 6

#: The benchmark bicycle, MPRS Table 1 (SI units; the values there are exact).
BENCHMARK = {
    "w": 1.02, "c": 0.08, "lam": np.pi / 10, "g": 9.81,
    "rR": 0.3, "mR": 2.0, "IRxx": 0.0603, "IRyy": 0.12,
    "xB": 0.3, "zB": -0.9, "mB": 85.0, "IBxx": 9.2, "IBxz": 2.4, "IByy": 11.0, "IBzz": 2.8,
    "xH": 0.9, "zH": -0.7, "mH": 4.0, "IHxx": 0.05892, "IHxz": -0.00756, "IHyy": 0.06, "IHzz": 0.00708,
    "rF": 0.35, "mF": 3.0, "IFxx": 0.1405, "IFyy": 0.28,
}


def _rigid_body_energy(mass, vel, omega, inertia):
    """``½ m v·v + ½ ωᵀ I ω`` with ``vel`` and ``omega`` columns of components in orthonormal
    frames and ``inertia`` the body-frame inertia matrix."""
    return sp.Rational(1, 2) * mass * (vel.T * vel)[0, 0] + sp.Rational(1, 2) * (omega.T * inertia * omega)[0, 0]


class _Kinematics(NamedTuple):
    """Frames and points of the model (SymPy), shared by :func:`whipple_bicycle` and the
    numeric :func:`_geometry` (the drawing of :func:`lobattodae.animate`)."""

    N: ReferenceFrame   # ground, z down
    Y: ReferenceFrame   # yawed
    A: ReferenceFrame   # yawed and rolled
    B: ReferenceFrame   # rear frame (pitched)
    H: ReferenceFrame   # front frame (B steered about the steering axis)
    P: Vector           # rear contact (position vectors from the ground origin)
    CR: Vector          # rear wheel centre
    GB: Vector          # rear frame mass centre
    Sax: Vector         # where the steering axis meets the ground in the reference configuration
    CF: Vector          # front wheel centre
    GH: Vector          # front frame mass centre


def _kinematics(coords, S) -> _Kinematics:
    """The frames and points of MPRS (module docstring) for coordinates ``coords`` (functions of
    time for the model, plain symbols for :func:`_geometry`) and parameter symbols ``S``."""
    x, y, yaw, roll, pitch, steer = coords[:6]
    w, c, lam, rR, rF = S["w"], S["c"], S["lam"], S["rR"], S["rF"]
    # Frames: N ground (z down), Y yawed, A yawed and rolled, B rear frame (pitched),
    # H front frame: B turned by δ about the steering axis d = sin λ B.x + cos λ B.z
    # (B -> tilted by λ about y -> steered about z -> tilted back), so H = B at δ = 0.
    N = ReferenceFrame("N")
    Y = N.orientnew("Y", "Axis", [yaw, N.z])
    A = Y.orientnew("A", "Axis", [roll, Y.x])
    B = A.orientnew("B", "Axis", [pitch, A.y])
    Bt = B.orientnew("Bt", "Axis", [lam, B.y])
    Ht = Bt.orientnew("Ht", "Axis", [steer, Bt.z])
    H = Ht.orientnew("H", "Axis", [-lam, Ht.y])

    # Points (position vectors from the ground origin).
    P = x * N.x + y * N.y                                    # rear contact
    CR = P - rR * A.z                                        # rear wheel centre
    GB = CR + S["xB"] * B.x + (S["zB"] + rR) * B.z           # rear frame mass centre
    Sax = CR + (w + c) * B.x + rR * B.z                      # steering axis meets the ground (reference)
    CF = Sax - c * H.x - rF * H.z                            # front wheel centre
    GH = Sax + (S["xH"] - w - c) * H.x + S["zH"] * H.z       # front frame mass centre
    return _Kinematics(N, Y, A, B, H, P, CR, GB, Sax, CF, GH)


def _front_contact_direction(K: _Kinematics):
    """``(u, √(1 − (n·a)²))``: the unit vector ``u = (n − (n·a) a)/√(1 − (n·a)²)`` from the
    front wheel centre to its lowest point (``a`` the front axle ``H.y``, ``n`` the global
    ``z``), and the root, so that the contact's height condition is ``n·C_F + rF √(…) = 0``."""
    s = K.H.y.dot(K.N.z)
    root = sp.sqrt(1 - s**2)
    return (K.N.z - s * K.H.y) / root, root


@functools.lru_cache(maxsize=None)
def whipple_bicycle() -> LagrangianModel:
    r"""The nonlinear Whipple bicycle of MPRS (module docstring) as a :class:`LagrangianModel`.

    Coordinates ``(x, y, yaw, roll, pitch, steer, theta_R, theta_F)`` (:data:`COORDINATES`),
    multipliers: 4 nonholonomic (rear wheel longitudinal and lateral, front wheel
    longitudinal and lateral, along the yawed ground axes) and 1 holonomic (the front
    contact's height ``ψ_F = 0``). Parameters: the 26 symbols of MPRS Table 1 (``w, c, lam, g,
    rR, mR, IRxx, IRyy, xB, zB, mB, IBxx, IBxz, IByy, IBzz, xH, zH, mH, IHxx, IHxz, IHyy, IHzz,
    rF, mF, IFxx, IFyy``) with the benchmark values as defaults (:data:`BENCHMARK`).
    Built once per process (cached).

    Returns
    -------
    LagrangianModel
        The model (8 coordinates, 5 multipliers); ``model.problem`` for
        :func:`lobattodae.solve`, ``model.args()`` the benchmark parameters.
    """
    x, y, yaw, roll, pitch, steer, thr, thf = dynamicsymbols(" ".join(COORDINATES))
    coords = [x, y, yaw, roll, pitch, steer, thr, thf]
    S = {name: sp.Symbol(name) for name in BENCHMARK}
    g, rR, rF = S["g"], S["rR"], S["rF"]
    mR, mB, mH, mF = S["mR"], S["mB"], S["mH"], S["mF"]

    K = _kinematics(coords, S)
    N, Y, A, B, H = K.N, K.Y, K.A, K.B, K.H
    CR, GB, CF, GH = K.CR, K.GB, K.CF, K.GH

    # Angular velocities, body-frame components.
    wB = B.ang_vel_in(N)
    wH = H.ang_vel_in(N)
    wBc = wB.to_matrix(B)
    wHc = wH.to_matrix(H)
    wRc = wBc + sp.Matrix([0, thr.diff(T), 0])
    wFc = wHc + sp.Matrix([0, thf.diff(T), 0])

    def vel(point):
        # Components in the rear frame B: much shorter than in the ground frame.
        return point.dt(N).to_matrix(B)

    vCR, vGB, vCF, vGH = vel(CR), vel(GB), vel(CF), vel(GH)
    IB = sp.Matrix([[S["IBxx"], 0, S["IBxz"]], [0, S["IByy"], 0], [S["IBxz"], 0, S["IBzz"]]])
    IH = sp.Matrix([[S["IHxx"], 0, S["IHxz"]], [0, S["IHyy"], 0], [S["IHxz"], 0, S["IHzz"]]])
    IR = sp.diag(S["IRxx"], S["IRyy"], S["IRxx"])
    IF = sp.diag(S["IFxx"], S["IFyy"], S["IFxx"])
    T_kin = (_rigid_body_energy(mR, vCR, wRc, IR) + _rigid_body_energy(mB, vGB, wBc, IB)
             + _rigid_body_energy(mH, vGH, wHc, IH) + _rigid_body_energy(mF, vCF, wFc, IF))
    V = -g * (mR * CR.dot(N.z) + mB * GB.dot(N.z) + mH * GH.dot(N.z) + mF * CF.dot(N.z))
    L = T_kin - V

    # Rolling without slip. Rear: the contact is rR·A.z below the centre.
    omega_R = wB + thr.diff(T) * B.y
    slip_R = CR.dt(N) + omega_R.cross(rR * A.z)
    # Front: the lowest point of the wheel, u = (n − (n·a) a)/√(1 − (n·a)²).
    omega_F = wH + thf.diff(T) * H.y
    u, root = _front_contact_direction(K)
    slip_F = CF.dt(N) + omega_F.cross(rF * u)
    psi_F = CF.dot(N.z) + rF * root
    nonholonomic = {
        "rear longitudinal": slip_R.dot(Y.x),
        "rear lateral": slip_R.dot(Y.y),
        "front longitudinal": slip_F.dot(Y.x),
        "front lateral": slip_F.dot(Y.y),
    }
    model = from_lagrangian(L, coords, T, nonholonomic=nonholonomic, holonomic={"front contact": psi_F},
                            name="Whipple bicycle", defaults=dict(BENCHMARK))
    _PROBLEMS.add(model.problem)
    return model


#: The problems :func:`whipple_bicycle` has built (weakly held): :func:`lobattodae.animate` and
#: :func:`lobattodae.plot` recognise a bicycle run by the identity of its problem, as they do
#: the examples' (the cache of :func:`whipple_bicycle` may be cleared; this set forgets nothing
#: that is still alive).
_PROBLEMS: weakref.WeakSet = weakref.WeakSet()


def _is_whipple_problem(problem) -> bool:
    """Whether ``problem`` is the problem of a model built by :func:`whipple_bicycle`."""
    return problem in _PROBLEMS  # False for objects that cannot be weakly referenced


# ----------------------------------------------------------------------------- geometry
#: The points and directions of :func:`_geometry`, in this order.
_GEOMETRY = ("rear contact", "rear centre", "rear axle", "rear spoke", "front contact", "front centre",
             "front axle", "front spoke", "steering axis ground", "steering axis", "front frame x",
             "rear frame mass centre")


@functools.lru_cache(maxsize=None)
def _geometry_function():
    """``(q, params) -> (12, 3)`` array of :data:`_GEOMETRY` in ground components, lambdified
    from the model's own frames and points (:func:`_kinematics`, :func:`_front_contact_direction`)
    with plain symbols for the coordinates. Built once per process (about 0.3 s)."""
    q = sp.symbols(" ".join(COORDINATES))
    S = {name: sp.Symbol(name) for name in BENCHMARK}
    K = _kinematics(q, S)
    u, _ = _front_contact_direction(K)
    R = K.B.orientnew("R", "Axis", [q[_THR], K.B.y])    # rear wheel: turned by θ_R about the rear axle
    F = K.H.orientnew("F", "Axis", [q[7], K.H.y])       # front wheel: turned by θ_F about the front axle
    vectors = {
        "rear contact": K.CR + S["rR"] * K.A.z,         # the rear no-slip condition's contact point
        "rear centre": K.CR,
        "rear axle": K.B.y,
        "rear spoke": R.z,                              # material: along B.z (down, upright) at θ_R = 0
        "front contact": K.CF + S["rF"] * u,            # the front contact of ψ_F and the front no-slip condition
        "front centre": K.CF,
        "front axle": K.H.y,
        "front spoke": F.z,
        "steering axis ground": K.Sax,
        "steering axis": sp.sin(S["lam"]) * K.B.x + sp.cos(S["lam"]) * K.B.z,   # d, pointing down
        "front frame x": K.H.x,
        "rear frame mass centre": K.GB,
    }
    assert tuple(vectors) == _GEOMETRY
    rows = sp.Matrix([list(vectors[k].to_matrix(K.N)) for k in _GEOMETRY])
    params = sorted({str(sym) for sym in rows.free_symbols} - set(COORDINATES))
    fn = sp.lambdify([q, [S[p] for p in params]], rows, modules="numpy", cse=True)
    return fn, tuple(params)


def _geometry(q, args) -> dict[str, np.ndarray]:
    r"""The bicycle's points and directions at one configuration ``q`` (8 coordinates) with the
    parameters ``args`` (a :meth:`LagrangianModel.args` dict), from the model's kinematics
    (:func:`_kinematics`): ``{name: array (3,)}`` for the names of :data:`_GEOMETRY`, ground
    components in MPRS axes (``z`` down). The contacts are the points the constraints use:
    ``rear contact = C_R + rR A.z`` (on the ground by construction) and ``front contact =
    C_F + rF u``, whose ``z`` is ``ψ_F``; ``steering axis`` is the unit vector
    ``d = sin λ B.x + cos λ B.z`` through ``steering axis ground``; the spokes are the wheels'
    material ``z`` axes (``B.z``, ``H.z`` turned by ``θ_R``, ``θ_F`` about the axles)."""
    fn, params = _geometry_function()
    values = np.asarray(fn(np.asarray(q, dtype=float), [float(args[p]) for p in params]), dtype=float)
    return dict(zip(_GEOMETRY, values))


# ----------------------------------------------------------------------------- states
#: The chart of the constraint manifold {ψ_F = 0, φ = 0} used by :func:`state_matrix`:
#: seven positions (x, y, ψ, φ, δ, θ_R, θ_F; the pitch solves ψ_F = 0) and the three
#: independent rates (φ̇, δ̇, θ̇_R).
CHART = ("x", "y", "yaw", "roll", "steer", "theta_R", "theta_F", "roll_rate", "steer_rate", "theta_R_rate")
_CHART_POS = np.array([0, 1, 2, _ROLL, _STEER, _THR, 7])
_CHART_RATES = np.array([_ROLL, _STEER, _THR])


@functools.lru_cache(maxsize=None)
def _compiled(model):
    """jit-compiled helpers (one set per model): ``ψ_F`` with its pitch derivative, and the
    first derivatives used by :func:`state_matrix`.

    Only first derivatives of the generated functions are compiled, each once: ``(f, g)``
    (``f_and_g``, one linear solve) in ``(q, p, λ)``, ``(μ, ν)`` (``constraint_terms``) and
    ``ψ_F`` in ``q``. ``φ = μ f + ν`` and the λ-dependence of ``g = ∂L/∂q + μᵀλ`` are assembled
    from them in NumPy (XLA compiles a Jacobian of ``g`` alone in about 15 s on this model,
    one of the hidden constraint as much again; see ``docs/bicycle.md``).
    """
    prob = model.problem

    def pitch_newton(q, args):
        val, der = jax.jvp(lambda th: prob.position_constraint(0.0, q.at[_PITCH].set(th), args)[0],
                           (q[_PITCH],), (jnp.ones(()),))
        return val, der

    def first_derivatives(q, p, args):
        lam0 = jnp.zeros(model.m)
        fg = lambda qq, pp: prob.f_and_g(0.0, qq, pp, lam0, args)  # noqa: E731
        f, g0 = fg(q, p)
        (fq, fp), (gq, gp) = jax.jacfwd(fg, argnums=(0, 1))(q, p)
        terms = lambda qq: model._fns["constraint_terms"](0.0, qq, args)  # noqa: E731
        mu, nu = terms(q)
        mu_q, nu_q = jax.jacfwd(terms)(q)
        psi_q = jax.jacfwd(lambda qq: prob.position_constraint(0.0, qq, args))(q)
        return dict(f=f, g0=g0, fq=fq, fp=fp, gq0=gq, gp=gp, mu=mu, nu=nu, mu_q=mu_q, nu_q=nu_q, sq=psi_q,
                    M=prob.mass_matrix(0.0, q, args))

    return _compile.jit(pitch_newton), _compile.jit(first_derivatives)


def _upright_qp(model, v, args, roll=0.0, steer=0.0, roll_rate=0.0, steer_rate=0.0):
    pitch_newton = _compiled(model)[0]
    q = np.zeros(model.n)
    q[_ROLL], q[_STEER] = roll, steer
    for _ in range(50):  # Newton's method on ψ_F(pitch) = 0
        val, der = (float(x) for x in pitch_newton(jnp.asarray(q), args))
        q[_PITCH] -= val / der
        if abs(val) <= 1e-15 * (1.0 + float(args["rR"])):
            break
    rates = {"roll": roll_rate, "steer": steer_rate, "theta_R": -v / float(args["rR"])}
    qdot = model.complete_velocities(0.0, q, rates, args)
    return q, model.momenta(0.0, q, qdot, args)


def upright_state(model: LagrangianModel, v: float, args: dict | None = None, *, roll: float = 0.0,
                  steer: float = 0.0, roll_rate: float = 0.0, steer_rate: float = 0.0):
    r"""Consistent initial values ``(q0, p0)`` of :func:`whipple_bicycle` rolling at speed ``v``.

    The rear contact at the origin heading along ``x`` (``x = y = ψ = 0``, wheel angles 0),
    the given roll ``φ`` and steer ``δ``; the pitch solves the holonomic constraint
    ``ψ_F(φ, θ, δ) = 0`` (Newton's method, to round-off; ``θ = 0`` upright for the benchmark
    geometry). The independent rates are ``(φ̇, δ̇, θ̇_R) = (roll_rate, steer_rate, −v/rR)``;
    the other five (``ẋ, ẏ, ψ̇, θ̇, θ̇_F``) follow from the four no-slip conditions and
    ``ψ̇_F = 0`` (:meth:`LagrangianModel.complete_velocities`), and ``p0 = M q̇0``. With the
    defaults: upright steady rolling, a relative equilibrium.

    Parameters
    ----------
    model : LagrangianModel
        The model of :func:`whipple_bicycle`.
    v : float
        Forward speed (m/s): the rear wheel turns at ``θ̇_R = −v/rR``.
    args : dict, optional
        Its parameters (:meth:`LagrangianModel.args`; default ``model.args()``: the benchmark
        bicycle).
    roll, steer : float, optional
        Roll ``φ`` and steer ``δ`` angles (rad; default 0).
    roll_rate, steer_rate : float, optional
        Their rates (rad/s; default 0): e.g. a roll-rate kick.

    Returns
    -------
    q0, p0 : numpy.ndarray, shape (8,)
    """
    args = model.args() if args is None else args
    return _upright_qp(model, v, args, roll, steer, roll_rate, steer_rate)


def _linear_data(model, v, args):
    r"""``f_q, f_p, g_q, g_p, g_λ, φ_q, φ_p, ψ_q`` at upright rolling at speed ``v``.

    ``φ = μ(q) f + ν(q)`` gives ``φ_q = (∂μ/∂q)·f + μ f_q + ν_q``, ``φ_p = μ f_p``;
    ``g = g|_{λ=0} + μᵀλ`` gives ``g_λ = μᵀ`` and ``g_q = g_q|_{λ=0} + Σ_j λ_j ∂μ_j/∂q``; λ solves
    the hidden constraint ``φ_q f + φ_p g = 0`` (what :func:`lobattodae.consistent_lambda`
    computes; ``g`` is affine in λ, so this is one linear solve)."""
    q, p = _upright_qp(model, v, args)
    d = {k: np.asarray(val) for k, val in _compiled(model)[1](jnp.asarray(q), jnp.asarray(p), args).items()}
    f, mu, mu_q = d["f"], d["mu"], d["mu_q"]  # mu_q[j, i, k] = ∂μ_ji/∂q_k
    cq = np.einsum("jik,i->jk", mu_q, f) + mu @ d["fq"] + d["nu_q"]
    cp = mu @ d["fp"]
    gl = mu.T
    lam = -np.linalg.solve(cp @ gl, cq @ f + cp @ d["g0"])
    gq = d["gq0"] + np.einsum("jik,j->ik", mu_q, lam)
    return dict(q=q, p=p, lam=lam, fq=d["fq"], fp=d["fp"], gq=gq, gp=d["gp"], gl=gl, cq=cq, cp=cp, sq=d["sq"],
                M=d["M"])


def _chart_matrices(d):
    r"""The linearised DAE at a relative equilibrium, in the chart :data:`CHART`.

    With ``z = (δq, δp)`` and ``δλ`` eliminated by differentiating the linearised constraint
    ``φ_q δq + φ_p δp = 0`` once, ``δz' = Ã δz``. ``T`` (16×10) maps chart perturbations to
    ``δz`` (pitch from ``ψ_q δq = 0``, momenta from the constraint and the independent rates),
    ``R`` (10×16) reads the chart variables off ``δz``; ``R T = I`` and the chart's matrix is
    ``R Ã T``. Returns ``(R Ã T, T, R, Ã)``.
    """
    fq, fp, gq, gp, gl, cq, cp, sq = (np.asarray(d[k]) for k in ("fq", "fp", "gq", "gp", "gl", "cq", "cp", "sq"))
    n = fq.shape[0]
    lam_z = -np.linalg.solve(cp @ gl, np.hstack([cq @ fq + cp @ gq, cq @ fp + cp @ gp]))
    At = np.block([[fq, fp], [gq, gp]]) + np.vstack([np.zeros((n, 2 * n)), gl @ lam_z])
    K = np.vstack([cp, fp[_CHART_RATES]])
    T = np.zeros((2 * n, len(CHART)))
    for k in range(len(CHART)):
        dq, du = np.zeros(n), np.zeros(3)
        if k < 7:
            dq[_CHART_POS[k]] = 1.0
            dq[_PITCH] = -sq[0, _CHART_POS[k]] / sq[0, _PITCH]
        else:
            du[k - 7] = 1.0
        dp = np.linalg.solve(K, np.concatenate([-cq @ dq, du - fq[_CHART_RATES] @ dq]))
        T[:n, k], T[n:, k] = dq, dp
    R = np.zeros((len(CHART), 2 * n))
    R[np.arange(7), _CHART_POS] = 1.0
    R[7:, :n], R[7:, n:] = fq[_CHART_RATES], fp[_CHART_RATES]
    return R @ At @ T, T, R, At


_LATERAL = np.array([3, 4, 7, 8])  # roll, steer, roll rate, steer rate in CHART


def state_matrix(model: LagrangianModel, v: float, args: dict | None = None, *, full: bool = False) -> np.ndarray:
    r"""The state matrix of the linearisation about upright straight rolling at speed ``v``.

    At the upright state (:func:`upright_state`; ``λ`` from the hidden constraint as in
    :func:`lobattodae.consistent_lambda`, one linear solve since ``g`` is affine in ``λ``) the
    first derivatives of the generated ``f``, ``g``,
    ``φ`` and ``ψ_F`` are taken by forward-mode JAX differentiation. The linearised DAE

    .. math::

        δq' = f_q δq + f_p δp, \quad δp' = g_q δq + g_p δp + g_λ δλ, \quad
        0 = φ_q δq + φ_p δp, \quad 0 = ψ_q δq

    is reduced to an ODE by differentiating the third equation once
    (``δλ = −(φ_p g_λ)⁻¹ [φ_q(f_q δq + f_p δp) + φ_p(g_q δq + g_p δp)]``) and written in the
    chart :data:`CHART` of the constraint manifold: seven positions (the pitch follows from
    ``ψ_q δq = 0``) and the independent rates ``(φ̇, δ̇, θ̇_R)`` (the other rates from
    ``φ = 0``). Steady rolling is a relative equilibrium: the motion only advances the cyclic
    coordinates ``x, θ_R, θ_F``, on which ``f, g, φ`` do not depend, so this linearisation
    (second derivatives of ``φ`` along the motion vanish) is exact and constant in time.

    Returns the 4×4 block for ``(φ, δ, φ̇, δ̇)``,

    .. math::

        A(v) = \begin{pmatrix} 0 & I \\ -M^{-1}(g K_0 + v^2 K_2) & -v M^{-1} C_1 \end{pmatrix}

    (MPRS eq. 5.1), or with ``full=True`` the 10×10 matrix in the chart (the lateral block
    is decoupled from the other chart variables, which :func:`linearize` checks).

    Parameters
    ----------
    model : LagrangianModel
        The model of :func:`whipple_bicycle`.
    v : float
        Forward speed (m/s).
    args : dict, optional
        Its parameters (:meth:`LagrangianModel.args`; default ``model.args()``: the benchmark
        bicycle).
    full : bool, optional
        Return the 10×10 matrix in the chart :data:`CHART` instead of the lateral 4×4 block.

    Returns
    -------
    numpy.ndarray, shape (4, 4) or (10, 10)
        ``A(v)``: ``x' = A(v) x`` for ``x = (φ, δ, φ̇, δ̇)`` (or the chart variables).
    """
    args = model.args() if args is None else args
    J = _chart_matrices(_linear_data(model, v, args))[0]
    return J if full else J[np.ix_(_LATERAL, _LATERAL)]


def _reduced_mass(model, args):
    r"""``SᵀM S`` at the upright configuration, ``S = ∂q̇/∂(φ̇, δ̇, θ̇_R)`` (3×3)."""
    d = _linear_data(model, 0.0, args)
    T = _chart_matrices(d)[1]
    fp, M = np.asarray(d["fp"]), np.asarray(d["M"])
    S = fp @ T[model.n:, 7:]  # the rate columns have δq = 0
    return S.T @ M @ S


class BenchmarkMatrices(NamedTuple):
    """``M, C1, K0, K2`` of MPRS eq. (5.1), 2×2 arrays for ``(φ, δ)``.

    ``M q̈ + v C1 q̇ + (g K0 + v² K2) q = f`` for ``q = (φ, δ)`` and the roll and steer
    torques ``f = (T_φ, T_δ)``.

    Attributes
    ----------
    M : numpy.ndarray, shape (2, 2)
        The mass matrix.
    C1 : numpy.ndarray, shape (2, 2)
        The velocity-dependent damping-like matrix (multiplied by ``v``).
    K0 : numpy.ndarray, shape (2, 2)
        The gravity-dependent stiffness matrix (multiplied by ``g``).
    K2 : numpy.ndarray, shape (2, 2)
        The velocity-dependent stiffness matrix (multiplied by ``v²``).
    """

    M: np.ndarray
    C1: np.ndarray
    K0: np.ndarray
    K2: np.ndarray


def linearize(model: LagrangianModel, args: dict | None = None) -> BenchmarkMatrices:
    r"""The benchmark matrices ``M, C1, K0, K2`` of MPRS eq. (5.1) from the nonlinear model.

    ``M`` is the reduced mass matrix: with ``q̇ = S(q) u`` the velocities allowed by the
    constraints as functions of the independent rates ``u = (φ̇, δ̇, θ̇_R)``, the reduced
    (Lagrange–d'Alembert) equations are ``SᵀM_q S u̇ + … = Sᵀ F``; for a roll torque ``T_φ`` and a
    steer torque ``T_δ`` (``F = T_φ e_φ + T_δ e_δ``) the right-hand side is ``(T_φ, T_δ, 0)``,
    so ``M = (SᵀM_q S)`` restricted to ``(φ, δ)`` at the upright configuration (``S`` by JAX
    differentiation of the velocity solve). With the state matrix ``A(v)`` of
    :func:`state_matrix`, ``g K0 + v² K2 = −M A₂₁(v)`` and ``v C1 = −M A₂₂(v)``, so
    ``K0 = −M A₂₁(0)/g``, ``K2 = −M (A₂₁(1) − A₂₁(0))``, ``C1 = −M A₂₂(1)``. Only the model's
    structure (quadratic dependence on ``v``) is used; :func:`linearize` checks it by
    comparing with ``A(v)`` at a third speed, and that the lateral block is decoupled.

    Parameters
    ----------
    model : LagrangianModel
        The model of :func:`whipple_bicycle`.
    args : dict, optional
        Its parameters (:meth:`LagrangianModel.args`; default ``model.args()``: the benchmark
        bicycle).

    Returns
    -------
    BenchmarkMatrices
        ``M, C1, K0, K2`` (2×2 each).

    Raises
    ------
    RuntimeError
        If the linearisation does not have the benchmark structure (quadratic in ``v``, the
        lateral block decoupled): a model other than the Whipple bicycle.
    """
    args = model.args() if args is None else args
    Mred = _reduced_mass(model, args)
    M = Mred[:2, :2]
    J0 = state_matrix(model, 0.0, args, full=True)
    J1 = state_matrix(model, 1.0, args, full=True)
    a0, a1 = J0[np.ix_(_LATERAL, _LATERAL)], J1[np.ix_(_LATERAL, _LATERAL)]
    g = float(args["g"])
    K0 = -M @ a0[2:, :2] / g
    K2 = -M @ (a1[2:, :2] - a0[2:, :2])
    C1 = -M @ a1[2:, 2:]
    # Checks: the structure assumed above, at v = 3.
    J3 = state_matrix(model, 3.0, args, full=True)
    a3 = J3[np.ix_(_LATERAL, _LATERAL)]
    scale = np.abs(a3).max()
    pred = np.block([[np.zeros((2, 2)), np.eye(2)],
                     [-np.linalg.solve(M, g * K0 + 9.0 * K2), -3.0 * np.linalg.solve(M, C1)]])
    others = np.setdiff1d(np.arange(len(CHART)), _LATERAL)
    coupling = np.abs(J3[np.ix_(_LATERAL, others)]).max()
    if np.abs(pred - a3).max() > 1e-9 * scale or coupling > 1e-9 * scale or np.abs(Mred[:2, 2]).max() > 1e-9 * np.abs(M).max():
        raise RuntimeError(  # pragma: no cover - a wrong model
            "the linearisation does not have the benchmark structure: "
            f"|A(3) − A(M, C1, K0, K2)| = {np.abs(pred - a3).max():.3g}, lateral coupling {coupling:.3g}")
    return BenchmarkMatrices(M, C1, K0, K2)


def eigenvalues(model: LagrangianModel, v: float, args: dict | None = None) -> np.ndarray:
    r"""The four eigenvalues of the lateral state matrix :func:`state_matrix` at speed ``v``
    (MPRS Table 2 and Fig. 3: weave pair, capsize, castor).

    Parameters
    ----------
    model : LagrangianModel
        The model of :func:`whipple_bicycle`.
    v : float
        Forward speed (m/s).
    args : dict, optional
        Its parameters (:meth:`LagrangianModel.args`; default ``model.args()``: the benchmark
        bicycle).

    Returns
    -------
    numpy.ndarray, shape (4,), complex
        Sorted by real part, then imaginary part.
    """
    ev = np.linalg.eigvals(state_matrix(model, v, args))
    return ev[np.lexsort((ev.imag, ev.real))]


def _weave_real_part(model, v, args):
    """Real part of the oscillatory (weave) pair (NaN where all four are real)."""
    ev = np.linalg.eigvals(state_matrix(model, v, args))
    cplx = ev[np.abs(ev.imag) > 1e-9]
    return float(cplx.real.max()) if cplx.size else np.nan


def _capsize_eigenvalue(model, v, args):
    """The largest real eigenvalue (the capsize mode above the weave speed)."""
    ev = np.linalg.eigvals(state_matrix(model, v, args))
    real = ev[np.abs(ev.imag) <= 1e-9]
    return float(real.real.max())


def weave_capsize_speeds(model: LagrangianModel, args: dict | None = None, *, weave_bracket=(3.0, 5.0),
                         capsize_bracket=(5.0, 8.0), xtol: float = 1e-12) -> tuple[float, float]:
    r"""The weave speed ``v_w`` and the capsize speed ``v_c`` (MPRS Sect. 5 and Table 2):
    the speeds where the real part of the weave pair, and the capsize eigenvalue, cross zero;
    ``v_w < v < v_c`` is the self-stable range. Brent's method (:func:`scipy.optimize.brentq`,
    ``xtol``) on the eigenvalues of :func:`state_matrix` inside the given brackets.

    Parameters
    ----------
    model : LagrangianModel
        The model of :func:`whipple_bicycle`.
    args : dict, optional
        Its parameters (:meth:`LagrangianModel.args`; default ``model.args()``: the benchmark
        bicycle).
    weave_bracket, capsize_bracket : tuple of float, optional
        Speeds (m/s) between which the weave pair's real part, and the capsize eigenvalue,
        change sign (defaults (3, 5) and (5, 8): the benchmark bicycle's).
    xtol : float, optional
        Absolute tolerance of the speeds (m/s).

    Returns
    -------
    v_w, v_c : float
        The weave and capsize speeds (m/s).

    Raises
    ------
    ValueError
        From :func:`scipy.optimize.brentq`, if a bracket does not contain a sign change.
    """
    from scipy.optimize import brentq

    args = model.args() if args is None else args
    vw = brentq(lambda v: _weave_real_part(model, v, args), *weave_bracket, xtol=xtol, rtol=4 * np.finfo(float).eps)
    vc = brentq(lambda v: _capsize_eigenvalue(model, v, args), *capsize_bracket, xtol=xtol, rtol=4 * np.finfo(float).eps)
    return vw, vc
