"""Diagnostics of a :class:`~lobattodae.Solution`: invariants, energy, constraint, multipliers."""

from __future__ import annotations

from typing import Any, Callable

import jax
import jax.numpy as jnp
import numpy as np

from . import _compile

__all__ = ["invariant_values", "invariant_error", "energy_error", "constraint_residual"]


#: Points evaluated per vectorised batch along a trajectory.
_BATCH = 1024


def _over_trajectory(fn, sol) -> np.ndarray:
    """``fn(t_k, q_k, p_k)`` for every k, in vmapped batches (bounded memory for long runs)."""
    run = _compile.jit(lambda t, q, p: jax.lax.map(lambda x: fn(*x), (t, q, p), batch_size=_BATCH))
    return np.asarray(run(jnp.asarray(sol.t), jnp.asarray(sol.q), jnp.asarray(sol.p)))


def invariant_values(sol, invariant: Callable[..., Any]) -> np.ndarray:
    """``I(t_k, q_k, p_k, args)`` along the solution, shape (N+1,). Vectorised with ``vmap``.

    Parameters
    ----------
    sol : Solution
    invariant : callable
        ``I(t, q, p, args) -> scalar``, written with ``jax.numpy``.

    Returns
    -------
    ndarray, shape (N+1,)
        One value per row of ``sol``.
    """
    return _over_trajectory(lambda t, q, p: invariant(t, q, p, sol.args), sol)


def invariant_error(sol, invariant: Callable[..., Any]) -> np.ndarray:
    """``I(t_k) - I(t_0)`` along the solution.

    Parameters
    ----------
    sol : Solution
    invariant : callable
        ``I(t, q, p, args) -> scalar``.

    Returns
    -------
    ndarray, shape (N+1,)
    """
    v = invariant_values(sol, invariant)
    return v - v[0]


def energy_error(sol) -> np.ndarray:
    """``H(t_k, q_k, p_k) - H(t_0, q_0, p_0)`` for a Hamiltonian problem.

    Parameters
    ----------
    sol : Solution
        Of a :class:`NonholonomicSystem` or :class:`MechanicalSystem`.

    Returns
    -------
    ndarray, shape (N+1,)

    Raises
    ------
    TypeError
        The problem has no Hamiltonian (use :func:`invariant_error` with your energy).
    """
    problem = sol.problem
    if not hasattr(problem, "hamiltonian"):
        raise TypeError(
            f"energy_error needs a problem with a Hamiltonian (NonholonomicSystem or MechanicalSystem); "
            f"got {type(problem).__name__}. Use invariant_error with your own energy function."
        )
    return invariant_error(sol, problem.hamiltonian)


def constraint_residual(sol) -> np.ndarray:
    """``‖φ(t_k, q_k, p_k)‖∞`` recomputed along the solution, shape (N+1,).

    Parameters
    ----------
    sol : Solution

    Returns
    -------
    ndarray, shape (N+1,)
        One value per row (``sol.stats["constraint_residual"]`` has the same, from the run).
    """
    problem = sol.problem
    return _over_trajectory(lambda t, q, p: jnp.max(jnp.abs(problem.phi(t, q, p, sol.args))), sol)
