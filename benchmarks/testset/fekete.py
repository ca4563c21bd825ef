r"""The Fekete problem: 20 charged particles on the unit sphere, damped, 60 coordinates, 20
holonomic constraints, T = 1000.

Source
------
* F. Mazzia, C. Magherini, *Test Set for Initial Value Problem Solvers*, release 2.4,
  University of Bari (2008), problem "Fekete" (fekete), stabilized index-2 formulation of
  dimension 160 (after E. Hairer, G. Wanner and the computation of Fekete points on the
  sphere: equilibria of the repulsion ``Σ log |x_i − x_j|``); Fortran file ``fekete.f``
  (revision ``fekete.F,v 1.2 2006/10/02``): the right-hand side ``fekfunc``, the initial
  values ``fekinit`` and the reference solution at t = 1000 (``feksoln``, 16 digits, computed
  with RADAU5 at rtol = atol = h0 = 1e-12). Equations and numbers were read from the copy
  distributed with the R package deTestSet.

The test set integrates, for particles ``x_i ∈ ℝ³`` with velocities ``v_i`` (i = 1..20),

    x_i' = v_i + 2 μ_i x_i,
    v_i' = −α v_i + 2 λ_i x_i + Σ_{j≠i} (x_i − x_j) / |x_i − x_j|²,   α = 1/2,
    0 = |x_i|² − 1,   0 = 2 x_i · v_i,

where μ (the stabilizing multiplier of the velocity constraint) vanishes on the exact
solution. Here the underlying mechanical system is a :class:`lobattodae.PartitionedDAE` in
``q = x`` (60 coordinates) and ``p = v``:

    q' = p,   p' = −α p + 2 λ ∘ x + F(q),   0 = φ(q, p) = (2 x_i · v_i)_i       (index 2)

with ``ψ = (|x_i|² − 1)_i`` as ``position_constraint`` (projection after every step). λ is
the test set's λ (``y(121..140)``); the reference has λ_i = −4.75 for every particle at
equilibrium.

The damping takes the particles to an equilibrium, but the repulsion and the constraint
forces exert no torque, so the total angular momentum decays like e^(−αt) and the final
orientation of the configuration is the integral of the angular velocity: errors of the
transient are not forgotten, and the reference at t = 1000 tests them.

Reference: y(1000) of ``feksoln`` (positions; velocities, of size 1e-16, compared with 0).
Its accuracy is not stated beyond RADAU5's tolerance; :func:`scipy_reference` checks it
independently: scipy's DOP853 (1e-13) and Radau (1e-12) on the index-1 ODE, their final
positions normalised onto the spheres, agree with it to 2.5e-12 and 2.7e-12, hence
``ref_accuracy = 5e-12``.
"""

from __future__ import annotations

import functools
import math

import jax.numpy as jnp
import numpy as np

import lobattodae as L

from ._index1 import end_state
from ._types import FastTest, Setup, TestProblem

ALPHA = 0.5
N_PARTICLES = 20
T_END = 1000.0


def initial_positions() -> np.ndarray:
    """``fekinit``: four rings of 3, 7, 6 and 4 particles at latitudes 3π/8, π/8, −2π/15,
    −3π/10, each turned by its own offset. Shape (20, 3)."""
    rings = ((3, 3 * math.pi / 8, math.pi / 13), (7, math.pi / 8, math.pi / 29),
             (6, -2 * math.pi / 15, math.pi / 7), (4, -3 * math.pi / 10, math.pi / 17))
    out = []
    for count, beta, offset in rings:
        for k in range(1, count + 1):
            a = 2 * math.pi * (k if count != 4 else k - 1) / count + offset
            out.append((math.cos(a) * math.cos(beta), math.sin(a) * math.cos(beta), math.sin(beta)))
    return np.array(out)


#: y(1000) of ``feksoln``: positions (20 × 3, row-major as y(1..60)).
X_REF = (
    -0.4070263380333202, 0.3463758772791802, 0.8451942450030429, 0.7752934752521549e-01, -0.2628662719972299,
    0.9617122871829146, 0.7100577833343567, 0.1212948055586120, 0.6936177005172217, 0.2348267744557627,
    0.7449277976923311, 0.6244509285956391, -0.4341114738782885, 0.8785430442262876, 0.1992720444237660,
    -0.9515059600312596, 0.2203508762787005, 0.2146669498274008, -0.6385191643609878, -0.4310833259390688,
    0.6375425027722121, -0.1464175087914336, -0.9380871635228862, 0.3139337298744690, 0.5666974065069942,
    -0.6739221885076542, 0.4740073135462156, 0.9843259538440293, -0.1696995357819996, -0.4800504290609090e-01,
    0.1464175087914331, 0.9380871635228875, -0.3139337298744656, -0.7092757549979014, 0.5264062637139616,
    -0.4688542938854929, -0.8665731819284478, -0.4813878059756024, -0.1315929352982178, -0.2347897778700538,
    -0.8594340408013130, -0.4541441287957579, 0.5530976940074118, -0.7674370265615124, -0.3242273140037833,
    0.7711050969896927, 0.6357041816577034, 0.3573685519777001e-01, 0.7103951209379591, 0.2403570431280519,
    -0.6614886725910596, -0.3038208738735660e-01, 0.4501923293640461, -0.8924145871442046, -0.5772996158107093,
    -0.1766763414971813, -0.7971892020969544, 0.2414481766969039, -0.3416456818373135, -0.9082846503446250,
)
#: the reference's velocities are below 3e-16 and its λ_i = −4.75 (to 16 digits).
LAM_REF = -4.75


def forces(x, xp=np):
    """``F_i = Σ_{j≠i} (x_i − x_j)/|x_i − x_j|²`` for x of shape (20, 3) (NumPy or JAX)."""
    d = x[:, None, :] - x[None, :, :]
    r2 = xp.sum(d * d, axis=-1) + xp.eye(x.shape[0])  # the diagonal (d = 0) divides by 1
    return xp.sum(d / r2[..., None], axis=1)


# ----------------------------------------------------------------------------- the DAE
def _f(t, q, p, args):
    return p


def _g(t, q, p, lam, args):
    x = q.reshape(N_PARTICLES, 3)
    return (-ALPHA * p.reshape(N_PARTICLES, 3) + 2.0 * lam[:, None] * x + forces(x, jnp)).reshape(-1)


def _phi(t, q, p, args):
    return 2.0 * jnp.sum(q.reshape(N_PARTICLES, 3) * p.reshape(N_PARTICLES, 3), axis=1)


def _psi(t, q, args):
    return jnp.sum(q.reshape(N_PARTICLES, 3) ** 2, axis=1) - 1.0


# ----------------------------------------------------------------------------- check of the reference
def index1_rhs(t, y):
    """The test set's equations as an ODE in y = (x, v) (NumPy only), λ from the hidden
    constraint ``d/dt (x_i · v_i) = 0``: ``|v_i|² + x_i·(−α v_i + F_i) + 2 λ_i |x_i|² = 0``."""
    n = 3 * N_PARTICLES
    x, v = y[:n].reshape(-1, 3), y[n:].reshape(-1, 3)
    F = forces(x)
    lam = -(np.sum(v * v, axis=1) + np.sum(x * (F - ALPHA * v), axis=1)) / (2.0 * np.sum(x * x, axis=1))
    return np.concatenate([v.reshape(-1), (-ALPHA * v + 2.0 * lam[:, None] * x + F).reshape(-1)])


def scipy_reference(method="DOP853", tol=1e-13):
    """x(1000), v(1000) of :func:`index1_rhs` by ``scipy.integrate.solve_ivp``, the positions
    normalised onto the unit spheres at the end: the index-1 ODE drifts off ``|x_i| = 1``
    (DOP853 at 1e-13: by 5.7e-10 over T = 1000), which the test set's index-2 formulation and
    lobattodae's projection do not."""
    y0 = np.concatenate([initial_positions().reshape(-1), np.zeros(3 * N_PARTICLES)])
    y = end_state(index1_rhs, y0, T_END, method, tol)
    n = 3 * N_PARTICLES
    x = y[:n].reshape(-1, 3)
    return (x / np.linalg.norm(x, axis=1)[:, None]).reshape(-1), y[n:]


@functools.cache
def build() -> Setup:
    """The problem (built once), q0 = ``fekinit``'s positions, p0 = 0, args None, t_span (0, 1000)."""
    problem = L.PartitionedDAE(f=_f, g=_g, phi=_phi, name="Fekete problem", position_constraint=_psi)
    return Setup(problem=problem, q0=initial_positions().reshape(-1), p0=np.zeros(3 * N_PARTICLES), args=None,
                 t_span=(0.0, T_END))


PROBLEM = TestProblem(
    "fekete", "Mazzia & Magherini, Test Set for IVP Solvers, release 2.4 (Bari 2008), problem 'fekete' (fekete.f)",
    build, t_ref=(T_END,), q_ref=(X_REF,), p_ref=((0.0,) * (3 * N_PARTICLES),), ref_accuracy=5e-12,
    test=FastTest(stages=5, n_steps=2000, bound=2e-8), long=True)
