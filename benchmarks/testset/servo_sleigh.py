r"""A wheeled robot with a stiff velocity servo: the Chaplygin sleigh driven by high-gain
feedback (the stiff problem).

Definition (this test set; the model is the Chaplygin sleigh of Bloch, *Nonholonomic
Mechanics and Control*, Sect. 1.7, with actuation): a rigid body of mass m and inertia I
about its centre of mass (x, y), heading θ, a knife edge (a fixed wheel) at distance a
behind the centre of mass, constraint ``−sin θ x' + cos θ y' − a θ' = 0``. Motors apply a
forward force F at the centre of mass and a torque τ, proportional controllers with high
gains that track commanded body velocities:

    F = −c_v (v − v_c(t)),   τ = −c_ω (ω − ω_c(t)),
    v = cos θ x' + sin θ y' (forward speed),   ω = θ',
    v_c(t) = 1 + ½ sin t,   ω_c(t) = 0.8 cos(t/2),

c_v = c_ω = 10⁴, m = 2, I = 0.3, a = 0.4. The velocity errors decay at the rates
c_v/m = 5·10³ and c_ω/(I + m a²) ≈ 1.6·10⁴ while the motion itself varies on a time scale of
1: a stiff problem (stiffness ratio ≈ 10⁵ over T = 10). Two initial states (x = y = θ = 0):
``servo-sleigh`` starts on the commands (v = 1, ω = 0.8; a smooth solution, the velocity
errors are O(1/c) from the start), ``servo-sleigh-rest`` starts at rest, so its first
~10⁻³ s are a fast transient (v and ω jump to the commands).

As a lobattodae problem: ``q = (x, y, θ)``, ``p = (m x', m y', I θ')``,
``q' = (p_x/m, p_y/m, p_θ/I)``, ``p' = (F cos θ, F sin θ, τ) + μᵀλ``,
``φ = μ q'`` with ``μ = (−sin θ, cos θ, −a)`` (a :class:`lobattodae.PartitionedDAE`).

Reference: the reduced ODE in body velocities, written by hand in NumPy (no lobattodae
code): with the lateral velocity of the centre of mass a ω fixed by the constraint,
Newton-Euler in the body frame gives

    x' = v cos θ − a ω sin θ,   y' = v sin θ + a ω cos θ,   θ' = ω,
    v' = a ω² + F/m,   ω' = (τ − m a v ω)/(I + m a²),

integrated with ``scipy.integrate.solve_ivp(method="Radau", rtol=1e-13, atol=1e-13)`` (stored
values) and checked against DOP853 (an explicit method, which the stiffness forces to ~10⁵
steps), LSODA and BDF at the same tolerance and Radau at 1e-12; ``p = (m x', m y', I ω)``.
:func:`compute_reference` regenerates the numbers.
"""

from __future__ import annotations

import functools

import jax.numpy as jnp
import numpy as np

import lobattodae as L

from ._types import FastTest, Setup, TestProblem

PARAMS = dict(m=2.0, I=0.3, a=0.4, c_v=1e4, c_w=1e4)
T_END = 10.0
T_REF = (1.0, 2.0, 5.0, 10.0)
#: Initial body states (x, y, θ, v, ω): on the commands (a smooth solution; the velocity
#: errors start at O(1/c)) and at rest (a stiff initial transient of duration ~1e-3).
Y0_SMOOTH = (0.0, 0.0, 0.0, 1.0, 0.8)
Y0_REST = (0.0, 0.0, 0.0, 0.0, 0.0)


def v_command(t, xp=np):
    return 1.0 + 0.5 * xp.sin(t)


def w_command(t, xp=np):
    return 0.8 * xp.cos(0.5 * t)


# ----------------------------------------------------------------------------- reference ODE
def body_rhs(t, y, P=PARAMS):
    """The reduced ODE y = (x, y, θ, v, ω) (NumPy, for scipy)."""
    m, I, a, cv, cw = P["m"], P["I"], P["a"], P["c_v"], P["c_w"]  # noqa: E741
    th, v, w = y[2], y[3], y[4]
    F = -cv * (v - v_command(t))
    tau = -cw * (w - w_command(t))
    c, s = np.cos(th), np.sin(th)
    return np.array([
        v * c - a * w * s,
        v * s + a * w * c,
        w,
        a * w * w + F / m,
        (tau - m * a * v * w) / (I + m * a * a),
    ])


def body_jac(t, y, P=PARAMS):
    m, I, a, cv, cw = P["m"], P["I"], P["a"], P["c_v"], P["c_w"]  # noqa: E741
    th, v, w = y[2], y[3], y[4]
    c, s = np.cos(th), np.sin(th)
    big = I + m * a * a
    J = np.zeros((5, 5))
    J[0, 2], J[0, 3], J[0, 4] = -v * s - a * w * c, c, -a * s
    J[1, 2], J[1, 3], J[1, 4] = v * c - a * w * s, s, a * c
    J[2, 4] = 1.0
    J[3, 3], J[3, 4] = -cv / m, 2 * a * w
    J[4, 3], J[4, 4] = -m * a * w / big, (-cw - m * a * v) / big
    return J


def body_to_qp(y, P=PARAMS):
    """``(q, p)`` from body states (rows)."""
    y = np.atleast_2d(y)
    m, I, a = P["m"], P["I"], P["a"]  # noqa: E741
    th, v, w = y[:, 2], y[:, 3], y[:, 4]
    xd = v * np.cos(th) - a * w * np.sin(th)
    yd = v * np.sin(th) + a * w * np.cos(th)
    return y[:, :3].copy(), np.stack([m * xd, m * yd, I * w], -1)


def compute_reference(y0=Y0_SMOOTH, method="Radau", tol=1e-13, times=T_REF):
    """Integrate the reduced ODE from the body state ``y0`` with scipy; returns ``(q, p)`` at
    ``times`` and scipy's result."""
    from scipy.integrate import solve_ivp

    kw = dict(jac=body_jac) if method in ("Radau", "BDF", "LSODA") else {}
    sol = solve_ivp(body_rhs, (0.0, T_END), np.array(y0, dtype=float), method=method, rtol=tol, atol=tol,
                    t_eval=list(times), **kw)
    if not sol.success:
        raise RuntimeError(sol.message)
    q, p = body_to_qp(sol.y.T)
    return q, p, sol


# ----------------------------------------------------------------------------- the DAE
def _mu(q, a):
    return jnp.stack([-jnp.sin(q[2]), jnp.cos(q[2]), -a * jnp.ones_like(q[2])])


def _f(t, q, p, args):
    return jnp.stack([p[0] / args["m"], p[1] / args["m"], p[2] / args["I"]])


def _g(t, q, p, lam, args):
    qd = _f(t, q, p, args)
    c, s = jnp.cos(q[2]), jnp.sin(q[2])
    v = c * qd[0] + s * qd[1]
    force = -args["c_v"] * (v - v_command(t, jnp))
    torque = -args["c_w"] * (qd[2] - w_command(t, jnp))
    return jnp.stack([force * c, force * s, torque]) + _mu(q, args["a"]) * lam[0]


def _phi(t, q, p, args):
    return (_mu(q, args["a"]) @ _f(t, q, p, args))[None]


@functools.cache
def problem():
    """The DAE, one object for both initial states (one compilation serves both)."""
    return L.PartitionedDAE(f=_f, g=_g, phi=_phi, name="servo-driven sleigh")


def _setup(y0) -> Setup:
    q0, p0 = body_to_qp(np.array(y0, dtype=float))
    args = {k: jnp.asarray(v) for k, v in PARAMS.items()}
    return Setup(problem=problem(), q0=q0[0], p0=p0[0], args=args, t_span=(0.0, T_END))


@functools.cache
def build_smooth() -> Setup:
    return _setup(Y0_SMOOTH)


@functools.cache
def build_rest() -> Setup:
    return _setup(Y0_REST)


# Stored references: compute_reference(y0, "Radau", 1e-13) (scipy 1.17.1), rows t = 1, 2, 5, 10.
# Disagreement (measure of ``error``) with DOP853 / LSODA / BDF at rtol = atol = 1e-13 and with
# Radau at 1e-12: smooth start 4.2e-14 / 5.6e-12 / 5.8e-12 / 5.6e-13; start at rest
# 6.5e-14 / 3.4e-12 / 5.8e-12 / 3.0e-13.
SMOOTH_Q_REF = (
    (0.9866385436898688, 0.7608093838989499, 0.7670117510266444),
    (1.473995795621405, 2.1591753236779994, 1.346232747721311),
    (1.88698312532802, 4.704611680676096, 0.9575035664485219),
    (4.348501524783041, 0.6665206802463035, -1.534162263884382),
)
SMOOTH_P_REF = (
    (1.6560610889381315, 2.3762671930186223, 0.2105994452120085),
    (0.3107820883307635, 2.913355608436153, 0.12966372316563765),
    (1.018473196073073, 0.5562640777053711, -0.19226200879260597),
    (0.23472535545043163, -1.4485298305960186, 0.06806782563099845),
)
REST_Q_REF = (
    (0.9864762629226238, 0.7607406033856631, 0.7669621647645334),
    (1.4739028539949393, 2.15908237522113, 1.346183161459196),
    (1.8870164018681475, 4.704498250592063, 0.957453980186397),
    (4.348334564458327, 0.6662851976300652, -1.5342118501464914),
)
REST_P_REF = (
    (1.6561789171100096, 2.3761850722180555, 0.21059944521200857),
    (0.31092655036346134, 2.913340194332382, 0.12966372316563765),
    (1.0185007778774224, 0.5562135747428079, -0.19226200879260416),
    (0.23465352798203676, -1.4485414679681974, 0.0680678256309984),
)

_SOURCE = ("this test set (benchmarks/testset/servo_sleigh.py): Chaplygin sleigh (Bloch, Nonholonomic "
           "Mechanics and Control, Sect. 1.7) driven by high-gain velocity servos, c = 1e4")

PROBLEM_SMOOTH = TestProblem(
    "servo-sleigh", _SOURCE + "; starts on the commanded velocities", build_smooth, T_REF, SMOOTH_Q_REF, SMOOTH_P_REF,
    ref_accuracy=1e-13, stiff=True, test=FastTest(stages=3, n_steps=1600, bound=1.4e-4))
PROBLEM_REST = TestProblem(
    "servo-sleigh-rest", _SOURCE + "; starts at rest (stiff initial transient)", build_rest, T_REF, REST_Q_REF,
    REST_P_REF, ref_accuracy=1e-13, stiff=True, test=FastTest(stages=3, n_steps=6400, bound=1e-6))
