r"""Andrews' squeezing mechanism (seven rigid bodies, index 3).

Source
------
* E. Hairer, G. Wanner, *Solving Ordinary Differential Equations II*, 2nd ed., Springer
  1996, Section VII.7 ("Computation of multibody mechanisms"), eqs. (7.1)-(7.6): the
  mechanism of Manning/Schiehlen (Andrews' squeezer), q = (β, Θ, γ, Φ, δ, Ω, ε).
* F. Mazzia, C. Magherini, *Test Set for Initial Value Problem Solvers*, release 2.4,
  University of Bari (2008), problem "Andrews' squeezing mechanism" (andrews), index-3
  formulation; Fortran file ``andrews.f``: parameters, ``M(q)``, ``f(q, q')``,
  ``G(q) = g_q``, ``g(q)``, consistent initial values (``init``) and the reference solution
  at t = 0.03 (``solut``; computed by PSIDE with rtol = atol = 1e-14 on a Cray C90).

The test set writes the equations of motion as (its eqs. for y(1..27))

    q' = w,   M(q) w' = f(q, w) − G(q)ᵀ λ,   0 = g(q)                         (index 3)

with ``f`` containing the driving torque, the spring force and the velocity-dependent
(Coriolis) terms. Here they are a :class:`lobattodae.PartitionedDAE` in the momenta
``p = M(q) q'``:

    q' = M(q)⁻¹ p,
    p' = M w' + (dM/dt) w = f(q, w) − G(q)ᵀ λ + (D_q M(q)[w]) w,   w = M(q)⁻¹ p,
    0 = φ(q, p) = G(q) M(q)⁻¹ p                                               (index 2)

and the six position constraints ``g(q) = 0`` as ``position_constraint`` (projection).
The multiplier λ is the test set's λ (same sign, same scaling): the library's consistent
λ(0) must equal the test set's ``y(22..27)`` at t = 0 (tested).

Reference: ``q(0.03)`` and ``q'(0.03)`` from the test set's ``solut`` (16 significant
digits printed); ``p_ref = M(q_ref) q'_ref``. Angles are *not* reduced mod 2π (β grows to
15.8 rad); the reference compares the unreduced values, as the test set does.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np

import lobattodae as L

from ._index1 import end_state, kkt_acceleration
from ._types import FastTest, Setup, TestProblem

# ----------------------------------------------------------------------------- parameters
# Test Set for IVP Solvers, andrews.f (also Hairer & Wanner II, Table 7.1).
PARAMS = dict(
    m1=0.04325, m2=0.00365, m3=0.02373, m4=0.00706, m5=0.07050, m6=0.00706, m7=0.05498,
    xa=-0.06934, ya=-0.00227, xb=-0.03635, yb=0.03273, xc=0.014, yc=0.072, c0=4530.0,
    i1=2.194e-6, i2=4.410e-7, i3=5.255e-6, i4=5.667e-7, i5=1.169e-5, i6=5.667e-7, i7=1.912e-5,
    d=28e-3, da=115e-4, e=2e-2, ea=1421e-5, rr=7e-3, ra=92e-5, l0=7785e-5,
    ss=35e-3, sa=1874e-5, sb=1043e-5, sc=18e-3, sd=2e-2, ta=2308e-5, tb=916e-5,
    u=4e-2, ua=1228e-5, ub=449e-5, zf=2e-2, zt=4e-2, fa=1421e-5, mom=33e-3,
)

# Consistent initial values (test set, subroutine init; Hairer & Wanner II, (7.6)).
Q0 = (
    -0.0617138900142764496358948458001,
    0.0,
    0.455279819163070380255912382449,
    0.222668390165885884674473185609,
    0.487364979543842550225598953530,
    -0.222668390165885884674473185609,
    1.23054744454982119249735015568,
)
#: q''(0) = w'(0) and λ(0) of the test set (y(15..21), y(22..27) at t = 0).
W_DOT0 = (14222.4439199541138705911625887, -10666.8329399655854029433719415, 0.0, 0.0, 0.0, 0.0, 0.0)
LAM0 = (98.5668703962410896057654982170, -6.12268834425566265503114393122, 0.0, 0.0, 0.0, 0.0)

# Reference solution at t = 0.03 (test set, subroutine solut): y(1..7) = q, y(8..14) = q'.
T_END = 0.03
Q_REF = (
    0.1581077119629904e2, -0.1575637105984298e2, 0.4082224013073101e-1, -0.5347301163226948e0,
    0.5244099658805304e0, 0.5347301163226948e0, 0.1048080741042263e1,
)
QDOT_REF = (
    0.1139920302151208e4, -0.1424379294994111e4, 0.1103291221937134e2, 0.1929337464421385e2,
    0.5735699284790808e0, -0.1929337464421385e2, 0.3231791658026955e0,
)
#: ... and the test set's w'(0.03), λ(0.03) (not compared: the library's λ is of lower order).
W_DOT_REF = (
    -0.2463176316945196e5, 0.5185037701610329e5, 0.3241025686413781e6, 0.5667493645176213e6,
    0.1674362929479361e5, -0.5667493645176222e6, 0.9826520791458422e4,
)
LAM_REF = (
    0.1991753333731910e3, -0.2975531228015052e2, 0.2306654119098399e2, 0.3145271365475927e2,
    0.2264249232082739e2, 0.1161740700019673e2,
)


# ----------------------------------------------------------------------------- equations
def _xp(q):
    """The array module of q's entries: SymPy for symbols, ``jax.numpy`` for JAX arrays, else NumPy."""
    if isinstance(q, jax.Array):
        return jnp
    if isinstance(q, np.ndarray) and q.dtype != object:
        return np
    import sympy as sp

    return sp if any(isinstance(x, sp.Basic) for x in q) else np


def _stack(rows, xp):
    """Rows of entries as an array (a SymPy Matrix for SymPy entries)."""
    if xp.__name__ == "sympy":
        return xp.Matrix(rows)
    return xp.stack([xp.stack(r) for r in rows]) if isinstance(rows[0], list) else xp.stack(rows)


def mass_matrix(q, P=PARAMS):
    """M(q) (7×7), test set andrews.f (Hairer & Wanner II, (7.3)); works on NumPy, JAX and
    SymPy entries (``P`` then maps the parameters' names to symbols)."""
    xp = _xp(q)
    m1, m2, m4, m5, m6, m7 = P["m1"], P["m2"], P["m4"], P["m5"], P["m6"], P["m7"]
    rr, da, ra, e, ea, zt, zf, fa, u = P["rr"], P["da"], P["ra"], P["e"], P["ea"], P["zt"], P["zf"], P["fa"], P["u"]
    coth, siph, siom = xp.cos(q[1]), xp.sin(q[3]), xp.sin(q[5])
    m11 = m1 * ra**2 + m2 * (rr**2 - 2 * da * rr * coth + da**2) + P["i1"] + P["i2"]
    m21 = m2 * (da**2 - da * rr * coth) + P["i2"]
    m22 = m2 * da**2 + P["i2"]
    m33 = P["m3"] * (P["sa"] ** 2 + P["sb"] ** 2) + P["i3"]
    m44 = m4 * (e - ea) ** 2 + P["i4"]
    m54 = m4 * ((e - ea) ** 2 + zt * (e - ea) * siph) + P["i4"]
    m55 = (m4 * (zt**2 + 2 * zt * (e - ea) * siph + (e - ea) ** 2) + m5 * (P["ta"] ** 2 + P["tb"] ** 2)
           + P["i4"] + P["i5"])
    m66 = m6 * (zf - fa) ** 2 + P["i6"]
    m76 = m6 * ((zf - fa) ** 2 - u * (zf - fa) * siom) + P["i6"]
    m77 = (m6 * ((zf - fa) ** 2 - 2 * u * (zf - fa) * siom + u**2) + m7 * (P["ua"] ** 2 + P["ub"] ** 2)
           + P["i6"] + P["i7"])
    z = 0 if xp.__name__ == "sympy" else 0.0 * coth
    rows = [
        [m11, m21, z, z, z, z, z],
        [m21, m22, z, z, z, z, z],
        [z, z, m33 + z, z, z, z, z],
        [z, z, z, m44 + z, m54, z, z],
        [z, z, z, m54, m55, z, z],
        [z, z, z, z, z, m66 + z, m76],
        [z, z, z, z, z, m76, m77],
    ]
    return _stack(rows, xp)


def forces(q, w, P=PARAMS):
    """f(q, q') (7,): driving torque, spring and Coriolis terms (test set ``ff``)."""
    xp = jnp if isinstance(q, jax.Array) else np
    m2, m4, m6 = P["m2"], P["m4"], P["m6"]
    rr, da, e, ea, zt, zf, fa, u = P["rr"], P["da"], P["e"], P["ea"], P["zt"], P["zf"], P["fa"], P["u"]
    sc, sd = P["sc"], P["sd"]
    bep, thp, php, dep, omp, epp = w[0], w[1], w[3], w[4], w[5], w[6]
    sith, siga, coga, coph, coom = xp.sin(q[1]), xp.sin(q[2]), xp.cos(q[2]), xp.cos(q[3]), xp.cos(q[5])
    xd = sd * coga + sc * siga + P["xb"]
    yd = sd * siga - sc * coga + P["yb"]
    lang = xp.sqrt((xd - P["xc"]) ** 2 + (yd - P["yc"]) ** 2)
    force = -P["c0"] * (lang - P["l0"]) / lang
    fx, fy = force * (xd - P["xc"]), force * (yd - P["yc"])
    return xp.stack([
        P["mom"] - m2 * da * rr * thp * (thp + 2 * bep) * sith,
        m2 * da * rr * bep**2 * sith,
        fx * (sc * coga - sd * siga) + fy * (sd * coga + sc * siga),
        m4 * zt * (e - ea) * dep**2 * coph,
        -m4 * zt * (e - ea) * php * (php + 2 * dep) * coph,
        -m6 * u * (zf - fa) * epp**2 * coom,
        m6 * u * (zf - fa) * omp * (omp + 2 * epp) * coom,
    ])


def _loop_trig(q):
    """cos and sin of the angles of the loops in g and G: β, β+Θ, γ, Φ+δ, δ, Ω+ε, ε; NumPy for
    NumPy (also complex) input, ``jax.numpy`` for JAX, SymPy for symbols."""
    xp = _xp(q)
    return [(xp.cos(a), xp.sin(a)) for a in (q[0], q[0] + q[1], q[2], q[3] + q[4], q[4], q[5] + q[6], q[6])]


def constraints(q, P=PARAMS):
    """g(q) (6,): the three loops closed at the fixed points B and A (test set ``g``); NumPy, JAX
    or SymPy entries, as :func:`mass_matrix`."""
    xp = _xp(q)
    rr, d, ss, e, zt, zf, u = P["rr"], P["d"], P["ss"], P["e"], P["zt"], P["zf"], P["u"]
    (cobe, sibe), (cobeth, sibeth), (coga, siga), (cophde, siphde), (code, side), (coomep, siomep), (coep, siep) = \
        _loop_trig(q)
    return _stack([
        rr * cobe - d * cobeth - ss * siga - P["xb"],
        rr * sibe - d * sibeth + ss * coga - P["yb"],
        rr * cobe - d * cobeth - e * siphde - zt * code - P["xa"],
        rr * sibe - d * sibeth + e * cophde - zt * side - P["ya"],
        rr * cobe - d * cobeth - zf * coomep - u * siep - P["xa"],
        rr * sibe - d * sibeth - zf * siomep + u * coep - P["ya"],
    ], xp)


def constraint_jacobian(q, P=PARAMS):
    """G(q) = g_q(q) (6×7), as printed in the test set (``gp``)."""
    xp = jnp if isinstance(q, jax.Array) else np
    rr, d, ss, e, zt, zf, u = P["rr"], P["d"], P["ss"], P["e"], P["zt"], P["zf"], P["u"]
    (cobe, sibe), (cobeth, sibeth), (coga, siga), (cophde, siphde), (code, side), (coomep, siomep), (coep, siep) = \
        _loop_trig(q)
    z = 0.0 * sibe
    a1, a2 = -rr * sibe + d * sibeth, d * sibeth
    b1, b2 = rr * cobe - d * cobeth, -d * cobeth
    rows = [
        [a1, a2, -ss * coga, z, z, z, z],
        [b1, b2, -ss * siga, z, z, z, z],
        [a1, a2, z, -e * cophde, -e * cophde + zt * side, z, z],
        [b1, b2, z, -e * siphde, -e * siphde - zt * code, z, z],
        [a1, a2, z, z, z, zf * siomep, zf * siomep - u * coep],
        [b1, b2, z, z, z, -zf * coomep, -zf * coomep - u * siep],
    ]
    return xp.stack([xp.stack(r) for r in rows])


# ----------------------------------------------------------------------------- the DAE
def mass_solve(q, p):
    """M(q)⁻¹ p by the block structure of M: 2×2 blocks (β, Θ), (Φ, δ), (Ω, ε) and m33, solved
    in closed form (cheaper to compile and to differentiate than a general LU solve)."""
    M = mass_matrix(q)

    def block(i, j):
        a, b, d = M[i, i], M[i, j], M[j, j]
        det = a * d - b * b
        return (d * p[i] - b * p[j]) / det, (a * p[j] - b * p[i]) / det

    w0, w1 = block(0, 1)
    w3, w4 = block(3, 4)
    w5, w6 = block(5, 6)
    return jnp.stack([w0, w1, p[2] / M[2, 2], w3, w4, w5, w6])


def _f(t, q, p, args):
    return mass_solve(q, p)


def _g(t, q, p, lam, args):
    w = mass_solve(q, p)
    _, mdot = jax.jvp(mass_matrix, (q,), (w,))  # dM/dt = D_q M(q)[q']
    return forces(q, w) - constraint_jacobian(q).T @ lam + mdot @ w


def _phi(t, q, p, args):
    return constraint_jacobian(q) @ mass_solve(q, p)


def _psi(t, q, args):
    return constraints(q)


# ----------------------------------------------------------------------------- check of the reference
def index1_rhs(t, y):
    """The test set's equations as an ODE in y = (q, q') (NumPy only): q'' and λ from

        [M  Gᵀ] [q'']   [f(q, q')        ]
        [G  0 ] [ λ ] = [−(D_q(G(q) q')) q'],

    the second derivative of g(q) = 0 (its q-derivative term by a complex step, exact to
    round-off because G is analytic)."""
    q, w = y[:7], y[7:]
    curv = constraint_jacobian(q + 1e-30j * w).imag @ w / 1e-30
    return np.concatenate([w, kkt_acceleration(mass_matrix(q), constraint_jacobian(q), forces(q, w), curv)])


def scipy_reference(method="DOP853", tol=1e-14):
    """q(0.03), q'(0.03) of :func:`index1_rhs` by ``scipy.integrate.solve_ivp`` (an independent
    check of the published reference; the drift from g = 0 stays below 1e-14 here)."""
    y = end_state(index1_rhs, np.concatenate([Q0, np.zeros(7)]), T_END, method, tol)
    return y[:7], y[7:]


@functools.cache
def build() -> Setup:
    """The problem (built once), q0, p0 = M(q0)·0 = 0, args None, t_span (0, 0.03)."""
    problem = L.PartitionedDAE(f=_f, g=_g, phi=_phi, name="Andrews' squeezing mechanism",
                               position_constraint=_psi)
    q0 = np.array(Q0)
    return Setup(problem=problem, q0=q0, p0=np.zeros(7), args=None, t_span=(0.0, T_END))


# ----------------------------------------------------------------------------- the Lagrangian twin
@functools.cache
def model():
    """The same mechanism written as a user of :mod:`lobattodae.mechanics` writes it
    (:func:`~lobattodae.mechanics.from_lagrangian`), built once: the kinetic energy
    ``½ q'ᵀ M(q) q'`` with the published M (Hairer & Wanner II, (7.3)), the spring's potential
    ``½ c0 (l − l0)²`` with l the spring's length (its force in f is ``−∂V/∂γ``), the driving
    torque as the generalized force ``mom`` on β, and the six loop closures g(q) = 0 as holonomic
    constraints. The velocity-dependent terms of f are not entered: Lagrange's equations derive
    them from M; that they equal the published ones is checked at random states
    (``tests/test_testset.py``). Parameters: :data:`PARAMS` (``model.args(**PARAMS)``).
    Its momenta are ``M(q) q'``, those of :func:`build`, so one reference serves both, and it runs
    natively (``model().native(s)``: generated C)."""
    import sympy as sp
    from sympy.physics.mechanics import dynamicsymbols

    from lobattodae import mechanics

    t = sp.Symbol("t")
    q = dynamicsymbols("beta theta gamma phi delta omega epsilon")
    P = {name: sp.Symbol(name, real=True) for name in PARAMS}
    M = mass_matrix(q, P)
    qd = sp.Matrix([x.diff(t) for x in q])
    coga, siga = sp.cos(q[2]), sp.sin(q[2])
    xd = P["sd"] * coga + P["sc"] * siga + P["xb"]
    yd = P["sd"] * siga - P["sc"] * coga + P["yb"]
    length = sp.sqrt((xd - P["xc"]) ** 2 + (yd - P["yc"]) ** 2)
    lagrangian = (qd.T * M * qd)[0, 0] / 2 - P["c0"] * (length - P["l0"]) ** 2 / 2
    loops = constraints(q, P)
    return mechanics.from_lagrangian(lagrangian, q, t, holonomic=list(loops), forces={q[0]: P["mom"]},
                                     name="Andrews' squeezing mechanism (Lagrangian)", defaults=PARAMS)


def _p_ref():
    q = np.array(Q_REF)
    return tuple(float(v) for v in mass_matrix(q) @ np.array(QDOT_REF))


PROBLEM = TestProblem(
    "andrews", "Hairer & Wanner, Solving ODEs II (2nd ed. 1996), Sect. VII.7, eqs. (7.1)-(7.6); Mazzia & Magherini, "
    "Test Set for IVP Solvers, release 2.4 (Bari 2008), problem 'andrews' (andrews.f)", build, t_ref=(T_END,),
    q_ref=(Q_REF,), p_ref=(_p_ref(),), ref_accuracy=1e-10, test=FastTest(stages=5, n_steps=100, bound=1.7e-9),
    mechanics=lambda: (model(), model().args(**PARAMS)))
