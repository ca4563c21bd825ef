r"""The flexible slider crank: a rigid crank driving an elastic connecting rod (index 2).

Source
------
* B. Simeon, "Modelling a flexible slider crank mechanism by a mixed system of DAEs and
  PDEs", *Math. Modelling of Systems* 2 (1996) 1-18.
* F. Mazzia, C. Magherini, *Test Set for Initial Value Problem Solvers*, release 2.4,
  University of Bari (2008), problem "Slider crank" (crank), index-2 DAE of dimension 24;
  Fortran file ``crank.f`` (revision ``crank.F,v 1.2 2006/10/02``, B. Simeon 1998):
  parameters, the finite-element matrices of the rod, ``RESMBS`` (mass matrix, forces,
  constraints), the initial values "close to smooth motion" and the reference solution at
  t = 0.1 (``SOLN``, 16 digits). The equations and numbers were read from the copies of
  ``crank.f`` distributed with the R package deSolve (``Ex_crank.f``) and with Cash's MEBDFI
  driver (``cranki.f``).

The positions are ``q = (φ₁, φ₂, x₃, q₁, q₂, q₃, q₄)``: the crank angle, the rod's angle, the
slider's position and four elastic coordinates of the rod (two lateral modal functions, two
longitudinal nodes of a quadratic ansatz). The test set writes

    q' = v,   M(q) v' = F(q, v) − G(q)ᵀ λ,   0 = G(q) v − (0, 0, Ω)              (index 2)

with the crank driven at Ω = 150 by the constraint φ₁ = Ω t, a state-dependent 7 × 7 mass
matrix M that couples the rigid and elastic motions, Coriolis and centrifugal forces F, the
rod's stiffness ``K q`` (steel, E = 2·10¹¹: the undamped elastic modes oscillate at
1.3·10³–2.5·10⁴ s⁻¹, purely imaginary eigenvalues; no damping and the linear stiffness term, the test
set's defaults ``ipar = (0, 0)``) and G = ∂ψ/∂q of the three position constraints

    ψ(t, q) = (l₁ sin φ₁ + (l₂ + q₄) sin φ₂,  x₃ − l₁ cos φ₁ − (l₂ + q₄) cos φ₂,  φ₁ − Ω t).

Here it is a :class:`lobattodae.PartitionedDAE` in the velocities ``p = v``:

    q' = p,   p' = M(q)⁻¹ (F(q, p) − G(q)ᵀ λ),   0 = φ(t, q, p) = G(q) p − (0, 0, Ω)

with ``ψ`` as ``position_constraint`` (projection after every step). λ is the test set's λ.

Why it is here: the smooth solution is accompanied by high-frequency elastic oscillations
whose amplitude the initial values keep small ("close to smooth motion"); an error-controlled
step long against their period (h ω ≫ 1) lies beyond the step's resolved range on an
*oscillating*, undamped mode, where Richardson's estimate assumes a ratio of errors the method
does not have (the imaginary-axis branch of ``StepDoubling``'s divisor; measured in README.md:
faithful, and Richardson's divisor alone would have been too).

The test set's initial values are printed to nine digits and are consistent only to that
accuracy (‖G v − (0, 0, Ω)‖ ≈ 1e-8, ψ₂ ≈ 2e-10); :func:`build` projects them onto ψ = 0 and
φ = 0 (x₃ from ψ₂ = 0, a change of 2e-10; v by the smallest change in the mass matrix's
metric, 4e-8), as a DAE code's first step does.

Reference: the test set's published y(0.1) (``SOLN``) is not accurate enough in the elastic
velocities to judge an error control: scipy's DOP853 (at 1e-13 and at its floor 2.2e-14) and
Radau (1e-12, 1e-13) on the index-1 form, and lobattodae's own constant steps (s = 6, 2,000
steps), agree with each other to 1e-10 or better and with the published positions to 4.4e-11,
but differ from the published v(0.1) by up to 6.3e-7 (q̇₄, of size 1.1e-3; from the raw
unprojected initial values by the same amount, so it is not the projection). The reference here is
therefore scipy's DOP853 at its floor (:data:`Q_REF`, :data:`V_REF`; ``ref_accuracy`` 2e-11 over
its 6e-12 agreement with Radau); the published values are kept as ``PUBLISHED_*``.
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
# Test Set for IVP Solvers, crank.f (RESMBS's data set). π is the file's eight-digit value.
PI = 3.1415927
M2, M3 = 0.151104, 0.075552  # rod, slider (the crank's mass enters only with gravity, zero here)
L1, L2 = 0.15, 0.30
J1, J2 = 0.002727, 0.0045339259
EE, BB, HH, RHO = 0.20e12, 0.0080, 0.0080, 7870.0
OMEGA = 150.0


def _rod_matrices():
    """The rod's finite-element data of ``RESMBS``: MQ, KQ, BQ (4 × 4) and c1, c2, c12, c21 (4,)."""
    facm, fack, facb = RHO * BB * HH * L2, EE * BB * HH / L2, BB * HH * L2
    mq = facm * np.array([[0.5, 0, 0, 0], [0, 0.5, 0, 0], [0, 0, 8.0, 1.0], [0, 0, 1.0, 2.0]])
    kq = fack * np.array([
        [PI**4 / 24.0 * (HH / L2) ** 2, 0, 0, 0],
        [0, PI**4 * 2.0 / 3.0 * (HH / L2) ** 2, 0, 0],
        [0, 0, 16.0 / 3.0, -8.0 / 3.0],
        [0, 0, -8.0 / 3.0, 7.0 / 3.0],
    ])
    b13, b14, b24 = -16.0 / PI**3, 8.0 / PI**3 - 1.0 / PI, 0.5 / PI
    bq = facb * np.array([[0, 0, b13, b14], [0, 0, 0, b24], [-b13, 0, 0, 0], [-b14, -b24, 0, 0]])
    c1 = facb * np.array([0, 0, 2.0 / 3.0, 1.0 / 6.0])
    c2 = facb * np.array([2.0 / PI, 0, 0, 0])
    c12 = L2 * facb * np.array([0, 0, 1.0 / 3.0, 1.0 / 6.0])
    c21 = L2 * facb * np.array([1.0 / PI, -0.5 / PI, 0, 0])
    return mq, kq, bq, c1, c2, c12, c21


MQ, KQ, BQ, C1, C2, C12, C21 = _rod_matrices()

T_END = 0.1
#: Initial values "close to smooth motion" (``INIT``): q, v; and v'(0), λ(0) (consistent for
#: the linear stiffness term without damping).
Q0 = (0.0, 0.0, 0.450016933, 0.0, 0.0, 0.103339863e-04, 0.169327969e-04)
V0 = (150.0, -74.9957670, -0.268938672e-05, 0.444896105, 0.463434311e-02, -0.178591076e-05, -0.268938672e-05)
W0 = (0.0, -1.344541576008661e-03, -5.062194923138079e03, -6.833142732779555e-05, 1.449382650173157e-08,
      -4.268463211410861e00, 2.098334687947376e-01)
LAM0 = (-6.397251492537153e-08, 3.824589508329281e02, -4.376060460948886e-09)

#: The published y(0.1) (``SOLN``): q, v; and w = v', λ. Its positions agree with the
#: reference below to 4.4e-11, its elastic velocities only to 6.3e-7 (see the module docstring).
PUBLISHED_Q = (1.500000000000000e01, -3.311734987910881e-01, 1.697373326718410e-01, 1.893192460247178e-04,
               2.375751865617931e-05, -5.323907988763734e-06, -8.363283141616840e-06)
PUBLISHED_V = (1.500000000000000e02, 6.025346682645789e01, -8.753116989887888e00, -3.005536801092212e-02,
               -5.500488291932075e-03, 4.978243404809343e-04, 1.104933470696396e-03)
PUBLISHED_W = (0.0, 6.488722210234531e03, 2.167924253080623e03, 3.391435115267547e01, 1.699107480197843e-01,
               -1.415799354959001e00, 9.903251655235532e-01)
PUBLISHED_LAM = (-6.232893262533717e01, -1.637910131687472e02, 2.529853213732781e01)

#: The reference q(0.1), v(0.1): :func:`scipy_reference` with DOP853 at rtol 2.2e-14 (scipy's
#: floor), atol 1e-14, from :func:`consistent_initial_values` (10 s on one core). Radau at
#: rtol = atol = 1e-13 agrees to 6.9e-13 in q and 6.0e-12 in v, DOP853 at 1e-13 to 1.1e-14 and
#: 1.5e-10 (2026-11-28).
Q_REF = (15.000000000000034, -0.3311734988255816, 0.1697373326399928, 1.893192899702355e-04,
         2.3757512499823975e-05, -5.323896770562423e-06, -8.36331327918019e-06)
V_REF = (150.0, 60.25346755131043, -8.753116326711423, -0.030055413997005377, -0.0055004318021413,
         4.974111829280788e-04, 1.1055599866899566e-03)


# ----------------------------------------------------------------------------- equations
def _xp(x):
    return jnp if isinstance(x, jax.Array) else np


def mass_matrix(q):
    """M(q) (7 × 7, symmetric): rigid crank and slider, the rod's rigid and elastic motion and
    their coupling (``RESMBS``, "Compute mass matrix"); NumPy or JAX."""
    xp = _xp(q)
    e = q[3:]
    s12, c12 = xp.sin(q[0] - q[1]), xp.cos(q[0] - q[1])
    m12 = 0.5 * L1 * L2 * M2 * c12 + RHO * L1 * (s12 * (C2 @ e) + c12 * (C1 @ e))
    m22 = J2 + e @ MQ @ e + 2.0 * RHO * (C12 @ e)
    row1 = RHO * L1 * (-s12 * C1 + c12 * C2)  # M[0, 3:]
    row2 = RHO * C21 + RHO * (e @ BQ)  # M[1, 3:]
    z = 0.0 * s12
    top = xp.stack([
        xp.stack([J1 + M2 * L1 * L1 + z, m12, z]),
        xp.stack([m12, m22, z]),
        xp.stack([z, z, M3 + z]),
    ])
    coupling = xp.stack([row1, row2, xp.zeros(4) + z])
    return xp.concatenate([
        xp.concatenate([top, coupling], axis=1),
        xp.concatenate([coupling.T, xp.asarray(MQ) + z], axis=1),
    ])


def forces(q, v):
    """F(q, v) (7,): centrifugal and Coriolis terms of the rigid and elastic motion and the
    rod's elastic force −K q (``RESMBS``, "Forces"; gravity is zero in the test set)."""
    xp = _xp(q)
    e, ed = q[3:], v[3:]
    v1, v2 = v[0], v[1]
    s12, c12 = xp.sin(q[0] - q[1]), xp.cos(q[0] - q[1])
    f1 = (-0.5 * L1 * L2 * M2 * v2 * v2 * s12
          + RHO * L1 * v2 * v2 * (-s12 * (C1 @ e) + c12 * (C2 @ e))
          - 2.0 * RHO * L1 * v2 * (c12 * (C1 @ ed) + s12 * (C2 @ ed)))
    f2 = (0.5 * L1 * L2 * M2 * v1 * v1 * s12
          + RHO * L1 * v1 * v1 * (s12 * (C1 @ e) - c12 * (C2 @ e))
          - 2.0 * RHO * v2 * (C12 @ ed) - 2.0 * v2 * (ed @ MQ @ e) - RHO * (ed @ BQ @ ed))
    fe = (v2 * v2 * (MQ @ e)
          + RHO * (v2 * v2 * C12 + L1 * v1 * v1 * (c12 * C1 + s12 * C2) + 2.0 * v2 * (BQ @ ed))
          - KQ @ e)
    return xp.concatenate([xp.stack([f1, f2, 0.0 * f1]), fe])


def constraint_jacobian(q):
    """G(q) = ∂ψ/∂q (3 × 7): the rod's end on the slider's line and the crank's drive."""
    xp = _xp(q)
    c1, s1, c2, s2 = xp.cos(q[0]), xp.sin(q[0]), xp.cos(q[1]), xp.sin(q[1])
    arm = L2 + q[6]
    z, one = 0.0 * c1, 1.0 + 0.0 * c1
    return xp.stack([
        xp.stack([L1 * c1, arm * c2, z, z, z, z, s2]),
        xp.stack([L1 * s1, arm * s2, one, z, z, z, -c2]),
        xp.stack([one, z, z, z, z, z, z]),
    ])


def position_constraints(t, q):
    """ψ(t, q) (3,)."""
    xp = _xp(q)
    arm = L2 + q[6]
    return xp.stack([L1 * xp.sin(q[0]) + arm * xp.sin(q[1]),
                     q[2] - L1 * xp.cos(q[0]) - arm * xp.cos(q[1]),
                     q[0] - OMEGA * t])


_DRIVE = np.array([0.0, 0.0, OMEGA])


def _f(t, q, p, args):
    return p


def _g(t, q, p, lam, args):
    return jnp.linalg.solve(mass_matrix(q), forces(q, p) - constraint_jacobian(q).T @ lam)


def _phi(t, q, p, args):
    return constraint_jacobian(q) @ p - _DRIVE


def _psi(t, q, args):
    return position_constraints(t, q)


# ----------------------------------------------------------------------------- initial values
def consistent_initial_values(q=Q0, v=V0):
    """The test set's nine-digit initial values projected onto ψ(0, q) = 0 (x₃ solved: the
    other positions already satisfy ψ₁ = ψ₃ = 0 exactly) and G(q) v = (0, 0, Ω) (the smallest
    change of v in the metric of M(q): v − M⁻¹Gᵀ(G M⁻¹ Gᵀ)⁻¹(G v − (0, 0, Ω)))."""
    q = np.array(q, dtype=float)
    v = np.array(v, dtype=float)
    q[2] += -position_constraints(0.0, q)[1]
    M, G = mass_matrix(q), constraint_jacobian(q)
    MiGt = np.linalg.solve(M, G.T)
    v = v - MiGt @ np.linalg.solve(G @ MiGt, G @ v - _DRIVE)
    return q, v


# ----------------------------------------------------------------------------- check of the reference
def index1_rhs(t, y):
    """The test set's index-1 form as an ODE in y = (q, v) (NumPy only): v' and λ from

        [M  Gᵀ] [v']   [F(q, v)                 ]
        [G  0 ] [λ ] = [−(d/dt G(q)) v at fixed v],

    the derivative of G(q) v = (0, 0, Ω) (its q-derivative by a complex step, exact to
    round-off: G is analytic)."""
    q, v = y[:7], y[7:]
    curv = constraint_jacobian(q + 1e-30j * v).imag @ v / 1e-30
    return np.concatenate([v, kkt_acceleration(mass_matrix(q), constraint_jacobian(q), forces(q, v), curv)])


def scipy_reference(method="DOP853", tol=1e-14, projected=True):
    """q(0.1), v(0.1) of :func:`index1_rhs` by ``scipy.integrate.solve_ivp`` from the test set's
    initial values (``projected``: after :func:`consistent_initial_values`)."""
    q0, v0 = consistent_initial_values() if projected else (np.array(Q0), np.array(V0))
    y = end_state(index1_rhs, np.concatenate([q0, v0]), T_END, method, tol)
    return y[:7], y[7:]


@functools.cache
def build() -> Setup:
    """The problem (built once), the projected initial values, args None, t_span (0, 0.1)."""
    problem = L.PartitionedDAE(f=_f, g=_g, phi=_phi, name="flexible slider crank", position_constraint=_psi)
    q0, v0 = consistent_initial_values()
    return Setup(problem=problem, q0=q0, p0=v0, args=None, t_span=(0.0, T_END))


# ----------------------------------------------------------------------------- the Lagrangian twin
@functools.cache
def model():
    """The same mechanism written as a user of :mod:`lobattodae.mechanics` writes it
    (:func:`~lobattodae.mechanics.from_lagrangian`), built once: the kinetic energy ½ vᵀ M(q) v of
    the test set's mass matrix (its entries written out in SymPy, the rod's finite-element
    matrices as numbers), the rod's elastic energy ½ eᵀ K e, and the three position constraints
    ψ(t, q) = 0, the drive φ₁ = Ω t among them. The Coriolis, centrifugal and elastic forces of
    the test set's F are not entered: Lagrange's equations derive them; that they equal the
    published ones is checked at random states (``tests/test_testset.py``). Its momenta are
    p = M(q) v where the test set's problem carries v (:data:`PROBLEM`'s ``mechanics_momenta``
    converts), and it runs natively (``model().native(s)``: generated C)."""
    import sympy as sp
    from sympy.physics.mechanics import dynamicsymbols

    from lobattodae import mechanics

    t = sp.Symbol("t")
    q = dynamicsymbols("phi1 phi2 x3 e1 e2 e3 e4")
    e = sp.Matrix(q[3:])
    mq, kq, bq, c1, c2, c12, c21 = (sp.Matrix(a) for a in (MQ, KQ, BQ, C1, C2, C12, C21))  # vectors as columns
    s12, co12 = sp.sin(q[0] - q[1]), sp.cos(q[0] - q[1])
    dot = lambda a, b: (a.T * b)[0, 0]  # noqa: E731
    m12 = 0.5 * L1 * L2 * M2 * co12 + RHO * L1 * (s12 * dot(c2, e) + co12 * dot(c1, e))
    m22 = J2 + (e.T * mq * e)[0, 0] + 2.0 * RHO * dot(c12, e)
    row1 = RHO * L1 * (-s12 * c1 + co12 * c2)
    row2 = RHO * c21 + RHO * (bq.T * e)
    M = sp.zeros(7, 7)
    M[0, 0], M[0, 1], M[1, 0], M[1, 1], M[2, 2] = J1 + M2 * L1 * L1, m12, m12, m22, M3
    for k in range(4):
        M[0, 3 + k] = M[3 + k, 0] = row1[k]
        M[1, 3 + k] = M[3 + k, 1] = row2[k]
        for j in range(4):
            M[3 + k, 3 + j] = mq[k, j]
    v = sp.Matrix([x.diff(t) for x in q])
    lagrangian = (v.T * M * v)[0, 0] / 2 - (e.T * kq * e)[0, 0] / 2
    arm = L2 + q[6]
    loops = [L1 * sp.sin(q[0]) + arm * sp.sin(q[1]), q[2] - L1 * sp.cos(q[0]) - arm * sp.cos(q[1]),
             q[0] - OMEGA * t]
    return mechanics.from_lagrangian(lagrangian, q, t, holonomic=loops, name="flexible slider crank (Lagrangian)")


def _momenta(t, q, v):
    """The twin's momenta p = M(q) v from the test set's velocities (one point or rows)."""
    q, v = np.asarray(q, float), np.asarray(v, float)
    if q.ndim == 1:
        return mass_matrix(q) @ v
    return np.stack([mass_matrix(qk) @ vk for qk, vk in zip(q, v)])


def _velocities(t, q, p):
    """The test set's velocities v = M(q)⁻¹ p from the twin's momenta (one point or rows)."""
    q, p = np.asarray(q, float), np.asarray(p, float)
    if q.ndim == 1:
        return np.linalg.solve(mass_matrix(q), p)
    return np.stack([np.linalg.solve(mass_matrix(qk), pk) for qk, pk in zip(q, p)])


PROBLEM = TestProblem(
    "crank", "Simeon, Math. Modelling of Systems 2 (1996); Mazzia & Magherini, Test Set for IVP Solvers, "
    "release 2.4 (Bari 2008), problem 'crank' (crank.f), index 2, initial values close to smooth motion",
    build, t_ref=(T_END,), q_ref=(Q_REF,), p_ref=(V_REF,), ref_accuracy=2e-11,
    test=FastTest(stages=5, n_steps=2000, bound=4.5e-9), stiff=True,
    mechanics=lambda: (model(), model().args()), mechanics_momenta=(_momenta, _velocities))
