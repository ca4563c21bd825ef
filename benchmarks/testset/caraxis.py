r"""The car axis: a multibody system with a time-dependent (rheonomic) constraint, index 3.

Source
------
* F. Mazzia, C. Magherini, *Test Set for Initial Value Problem Solvers*, release 2.4,
  University of Bari (2008), problem "Car axis problem" (caraxis), index-3 formulation of
  dimension 10; Fortran file ``caraxis.f`` (revision ``caraxis.F,v 1.2 2006/10/02``):
  parameters, right-hand side ``carfunc``, initial values and the reference solution at
  t = 3 (``carsoln``, 16 digits). The model is from P. Rentrop, "Numerical treatment of
  mechanical systems ...": the left wheel is at the origin's level on a bumpy road, the
  right end of the axis follows the road excitation ``y_b(t) = r sin(ω t)``.
  The equations and numbers were read from the copy of ``caraxis.f`` and ``ex_caraxis.R``
  distributed with the R package deTestSet (K. Soetaert, F. Mazzia).

The test set writes, with ``q = (x_l, y_l, x_r, y_r)`` (the left wheel and the right end of
the axis), ``k = M ε² / 2``, ``L_l = |q_l|``, ``L_r = |q_r − (x_b, y_b)|``,

    q' = u,
    k u' = F(t, q) + G(t, q)ᵀ λ,
    0 = ψ(t, q) = (x_b x_l + y_b y_l,  (x_l − x_r)² + (y_l − y_r)² − L²),

``F = ((L₀ − L_l) x_l / L_l, (L₀ − L_l) y_l / L_l − k g, (L₀ − L_r)(x_r − x_b)/L_r,
(L₀ − L_r)(y_r − y_b)/L_r − k g)`` (two springs of rest length L₀), ``G = ∂ψ/∂q`` and
``y_b = r sin(ω t)``, ``x_b = √(L² − y_b²)``; ε = 10⁻², M = 10, L = 1, L₀ = 0.5, r = 0.1,
ω = 10, g = 1. The springs over the small mass k = 5·10⁻⁴ make the problem mildly stiff
(frequencies up to ≈ 45 s⁻¹) and the first constraint depends on t.

Here it is a :class:`lobattodae.PartitionedDAE` in the velocities ``p = u`` (not the
momenta k u, which are of size 10⁻⁴ and would hide velocity errors in the test set's error
measure; the method is invariant under that rescaling of p):

    q' = p,   p' = (F(t, q) + G(t, q)ᵀ λ) / k,
    0 = φ(t, q, p) = ψ_t(t, q) + G(t, q) p                                   (index 2)

with ``ψ`` as ``position_constraint`` (projection after every step). λ is the test set's λ.

Reference: y(3) from ``carsoln`` (q, u; λ too, :data:`LAM_REF`). The test set does not state
its accuracy in the file; :func:`scipy_reference` checks it independently (the index-1 ODE
by ``scipy.integrate.solve_ivp``): DOP853 at 1e-13 and Radau at 1e-12 agree with it to
2.2e-13 in q and 4.3e-12 in u (and to each other better than that), hence
``ref_accuracy = 5e-12``.
"""

from __future__ import annotations

import functools

import jax.numpy as jnp
import numpy as np

import lobattodae as L

from ._index1 import end_state, kkt_acceleration
from ._types import FastTest, Setup, TestProblem

PARAMS = dict(eps=1e-2, M=10.0, L=1.0, L0=0.5, r=0.1, w=10.0, g=1.0)

T_END = 3.0
#: Initial values of the test set (consistent: ψ = 0 and ψ' = 0 at t = 0).
Q0 = (0.0, 0.5, 1.0, 0.5)
U0 = (-0.5, 0.0, -0.5, 0.0)
Y_REF = (
    0.4934557842755629e-01, 0.4969894602303324e+00, 0.1041742524885400e+01, 0.3739110272652214e+00,
    -0.7705836840321485e-01, 0.7446866596327776e-02, 0.1755681574942899e-01, 0.7703410437794031e+00,
    -0.4736886750784630e-02, -0.1104680411345730e-02,
)
Q_REF, U_REF, LAM_REF = Y_REF[:4], Y_REF[4:8], Y_REF[8:]


def _xp(*values):
    return np if all(isinstance(v, (float, int, np.ndarray, np.generic, complex)) for v in values) else jnp


def road(t, P=PARAMS, xp=np):
    """``(x_b, y_b, x_b', y_b')``: the right end's support on the road at time t."""
    yb = P["r"] * xp.sin(P["w"] * t)
    xb = xp.sqrt(P["L"] ** 2 - yb * yb)
    ybd = P["r"] * P["w"] * xp.cos(P["w"] * t)
    return xb, yb, -yb * ybd / xb, ybd


def mass(P=PARAMS):
    """k = M ε² / 2."""
    return P["M"] * P["eps"] ** 2 / 2.0


def forces(t, q, P=PARAMS, xp=np):
    """F(t, q): the two springs and gravity (test set ``carfunc``, without the λ terms)."""
    xb, yb, _, _ = road(t, P, xp)
    xl, yl, xr, yr = q[0], q[1], q[2], q[3]
    ll = xp.sqrt(xl * xl + yl * yl)
    lr = xp.sqrt((xr - xb) ** 2 + (yr - yb) ** 2)
    kg = mass(P) * P["g"]
    return xp.stack([
        (P["L0"] - ll) * xl / ll,
        (P["L0"] - ll) * yl / ll - kg,
        (P["L0"] - lr) * (xr - xb) / lr,
        (P["L0"] - lr) * (yr - yb) / lr - kg,
    ])


def constraints(t, q, P=PARAMS, xp=np):
    """ψ(t, q) (2,)."""
    xb, yb, _, _ = road(t, P, xp)
    return xp.stack([xb * q[0] + yb * q[1], (q[0] - q[2]) ** 2 + (q[1] - q[3]) ** 2 - P["L"] ** 2])


def constraint_jacobian(t, q, P=PARAMS, xp=np):
    """G(t, q) = ∂ψ/∂q (2×4), as the λ terms of ``carfunc`` print it."""
    xb, yb, _, _ = road(t, P, xp)
    dx, dy = 2.0 * (q[0] - q[2]), 2.0 * (q[1] - q[3])
    z = 0.0 * dx
    return xp.stack([xp.stack([xb + z, yb + z, z, z]), xp.stack([dx, dy, -dx, -dy])])


def constraint_rate(t, q, P=PARAMS, xp=np):
    """ψ_t(t, q) (2,): only the first constraint moves with the road."""
    _, _, xbd, ybd = road(t, P, xp)
    return xp.stack([xbd * q[0] + ybd * q[1], 0.0 * q[0]])


# ----------------------------------------------------------------------------- the DAE
def _f(t, q, p, args):
    return p


def _g(t, q, p, lam, args):
    return (forces(t, q, xp=jnp) + constraint_jacobian(t, q, xp=jnp).T @ lam) / mass()


def _phi(t, q, p, args):
    return constraint_rate(t, q, xp=jnp) + constraint_jacobian(t, q, xp=jnp) @ p


def _psi(t, q, args):
    return constraints(t, q, xp=jnp)


# ----------------------------------------------------------------------------- check of the reference
def index1_rhs(t, y, P=PARAMS):
    """The test set's equations as an ODE in y = (q, u) (NumPy only): u' and λ from

        [k I  Gᵀ] [u']   [F(t, q)                        ]
        [G    0 ] [λ ] = [−(d/dt)(ψ_t + G u) at fixed u   ],

    the second derivative of ψ = 0; the right-hand side's derivative along (1, u) in (t, q) by
    a complex step (exact to round-off: ψ is analytic)."""
    q, u = y[:4], y[4:]
    h = 1e-30
    rate = lambda tt, qq: constraint_rate(tt, qq, P) + constraint_jacobian(tt, qq, P) @ u  # noqa: E731
    curv = rate(t + 1j * h, q + 1j * h * u).imag / h
    acc = kkt_acceleration(mass(P) * np.eye(4), constraint_jacobian(t, q, P), forces(t, q, P), curv)
    return np.concatenate([u, acc])


def scipy_reference(method="DOP853", tol=1e-13):
    """q(3), u(3) of :func:`index1_rhs` by ``scipy.integrate.solve_ivp``: an independent check of
    the published reference."""
    y = end_state(index1_rhs, np.concatenate([Q0, U0]), T_END, method, tol)
    return y[:4], y[4:]


@functools.cache
def build() -> Setup:
    """The problem (built once), q0, p0 = u0, args None, t_span (0, 3)."""
    problem = L.PartitionedDAE(f=_f, g=_g, phi=_phi, name="car axis", position_constraint=_psi)
    return Setup(problem=problem, q0=np.array(Q0), p0=np.array(U0), args=None, t_span=(0.0, T_END))


PROBLEM = TestProblem(
    "caraxis", "Mazzia & Magherini, Test Set for IVP Solvers, release 2.4 (Bari 2008), problem 'caraxis' "
    "(caraxis.f); model of Rentrop et al.", build, t_ref=(T_END,), q_ref=(Q_REF,), p_ref=(U_REF,),
    ref_accuracy=5e-12, test=FastTest(stages=5, n_steps=200, bound=2e-8))
