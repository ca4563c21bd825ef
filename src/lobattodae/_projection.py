r"""Holonomic position constraints kept exactly: the projection after each step.

A problem may carry holonomic constraints ``ψ(t, q) = 0`` (k of them,
``PartitionedDAE.position_constraint``) whose velocity form ``ψ_q f + ψ_t = 0`` is among the
rows of φ. The Lobatto IIIA-IIIB step keeps φ, hence ``d/dt ψ``, at every step point, but ψ
itself only to the integration error. After the step ``(q̃_1, p̃_1, λ_1)`` has been computed,
the end point is projected (Hairer, Lubich & Wanner, *Geometric Numerical Integration*,
Sect. IV.4, standard projection) in two stages:

1. **positions**, along the constraint forces' directions mapped to velocities,

       q_1 = q̃_1 + D κ,    D = D_p f(t_1, q̃_1, p̃_1) ψ_q(t_1, q̃_1)ᵀ   (n×k),
       ψ(t_1, q̃_1 + D κ) = 0,

   solved for κ by POSITION_NEWTON_ITERATIONS Newton steps from κ = 0,
   ``κ ← κ − (ψ_q(t_1, q) D)⁻¹ ψ(t_1, q)`` with ``q = q̃_1 + D κ`` (the matrix re-evaluated
   at every iterate: quadratic convergence). For a mechanical system ``D_p f = M⁻¹``, so
   ``D = M⁻¹ ψ_qᵀ`` and the correction is the M-orthogonal (kinetic-metric) projection,
   independent of the coordinates. ``ψ_q D`` is the holonomic block of ``D_pφ D_λg``, which
   the index-2 assumption makes invertible.

2. **momenta**, by a constraint impulse, the one Gauss–Newton step

       p_1 = p̃_1 − G (D_pφ G)⁻¹ φ(t_1, q_1, p̃_1),    G = D_λ g(t_1, q_1, p̃_1, λ_1)   (n×m),

   exact for φ affine in p (every mechanical system; for a Lagrangian
   ``G = μᵀ``, ``D_pφ = μ M⁻¹``: the M⁻¹-metric projection onto ``φ = 0``). It restores
   ``φ(t_1, q_1, p_1) = 0``, which the position correction disturbed by O(|κ|).

The step's deviation ``ψ(t_1, q̃_1)`` is the local error of q, O(h^(2s-1)); Newton's iterates
then reach round-off in two steps (``δ → δ² → δ⁴``), the third is a margin for large steps.
The multiplier λ_1 is left as the step computed it. Projection after every step of a method of
order r keeps order r (HLW, Sect. IV.4: the projection moves the point by the local
error, so the projected map is again a method of order r). What it costs: the step is no longer
symmetric (a standard projection breaks time reversibility; on reversible problems the energy
error then need not stay bounded by symmetry alone; measured bounded on the pendulums in
``docs/mechanics.md``), and the dense output, which interpolates the unprojected stages,
satisfies ψ only to its interpolation error between step points (and to O(h^(2s-1)) at the
end of a step, where the solver stores the projected point instead).

Everything here is pure JAX (no loops that depend on values): it runs inside the step's
checkpointed completion, so ``jax.grad``, ``jvp`` and ``vmap`` differentiate through the
(converged) Newton iterations.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from ._linalg import small_solve, value_and_jacobian
from ._problem import consistent_lambda

__all__ = ["project_positions", "project_momenta_impulse", "project_row", "project_step_end",
           "POSITION_NEWTON_ITERATIONS"]

#: Newton steps for ``ψ(t_1, q̃_1 + D κ) = 0`` (quadratic convergence from an O(h^(2s-1)) start).
POSITION_NEWTON_ITERATIONS = 3


def project_positions(problem, t, q, p, args, iterations=POSITION_NEWTON_ITERATIONS):
    r"""``q_1 = q̃_1 + D κ`` with ``ψ(t, q_1) = 0`` (step 1 of the module docstring).

    ``D = D_p f(t, q̃, p̃) ψ_q(t, q̃)ᵀ``, κ from ``iterations`` Newton steps
    ``κ ← κ − (ψ_q(t, q̃ + Dκ) D)⁻¹ ψ(t, q̃ + Dκ)``.
    """
    psi = problem.position_constraint
    psi_q = jax.jacfwd(lambda qq: psi(t, qq, args))(q)  # (k, n)
    # D = D_p f ψ_qᵀ: one directional derivative of f in p per constraint
    f_p = jax.vmap(lambda v: jax.jvp(lambda pp: problem.f(t, q, pp, args), (p,), (v,))[1])
    direction = f_p(psi_q).T  # (n, k)

    def newton(_, kappa):
        residual, jac = value_and_jacobian(lambda kk: psi(t, q + direction @ kk, args), kappa)
        return kappa - small_solve(jac, residual)

    # a fixed number of steps in a loop: ψ and its Jacobian are compiled once, not once per step
    kappa = jax.lax.fori_loop(0, iterations, newton, jnp.zeros(psi_q.shape[0], q.dtype))
    return q + direction @ kappa


def project_momenta_impulse(problem, t, q, p, lam, args):
    r"""``p_1 = p̃ − G (D_pφ G)⁻¹ φ(t, q, p̃)``, ``G = D_λ g(t, q, p̃, λ)`` (step 2 of the
    module docstring)."""
    impulse = jax.jacfwd(lambda ll: problem.g(t, q, p, ll, args))(lam)  # G (n, m)
    phi, phi_g = value_and_jacobian(lambda cc: problem.phi(t, q, p + impulse @ cc, args), jnp.zeros_like(lam))
    return p - impulse @ small_solve(phi_g, phi)


def project_step_end(problem, t, q, p, lam, args):
    r"""The projected end point ``(q_1, p_1)`` of a step that ended at ``(q̃_1, p̃_1, λ_1)``:
    ``ψ(t, q_1) = 0`` and ``φ(t, q_1, p_1) = 0`` to round-off (see the module docstring)."""
    q1 = project_positions(problem, t, q, p, args)
    return q1, project_momenta_impulse(problem, t, q1, p, lam, args)


#: Impulse steps onto ``φ = 0`` for a row: the first is exact for φ affine in p (every mechanical
#: system), the second removes its round-off, or the nonlinearity of a general φ.
ROW_MOMENTUM_STEPS = 2


def project_row(problem, t, q, p, lam, args):
    r"""A state between step points moved onto the constraints: ``ψ(t, q) = 0`` (the position
    constraints, when the problem has them, step 1), ``φ(t, q, p) = 0`` (ROW_MOMENTUM_STEPS
    impulse steps, step 2) and λ the consistent multiplier, the root of the hidden constraint
    ``D_tφ + D_qφ f + D_pφ g = 0`` (:func:`~lobattodae.consistent_lambda`).

    For dense-output values (order s between step points, ``φ`` violated by the interpolation
    error): the projection moves them by that error, so they keep order s (a component that
    was more accurate, such as p of order s + 1 on the sleigh, follows q down to order s) and
    the constraints hold to round-off.
    """
    if getattr(problem, "position_constraint", None) is not None:
        q = project_positions(problem, t, q, p, args)
    for _ in range(ROW_MOMENTUM_STEPS):  # unrolled: a fixed, small number of steps
        p = project_momenta_impulse(problem, t, q, p, lam, args)
    return q, p, consistent_lambda(problem, t, q, p, lam, args)
