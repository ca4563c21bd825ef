"""Problems that only the benchmarks use."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

import lobattodae as L


def particle_chain(n_particles: int, omega: float = 1.0, kappa: float = 0.5):
    """A chain of ``n_particles`` nonholonomic particles ``q_i = (x_i, y_i, z_i)``,
    ``z_i' = y_i x_i'``, each in a harmonic well and coupled to its neighbours by springs in
    (x, y): ``n = 3 N_p``, ``m = N_p``, ``M = I``. Returns ``(problem, q0, p0, args)`` with
    consistent ``(q0, p0)``."""

    def hamiltonian(t, q, p, args):
        r = q.reshape(-1, 3)
        x, y = r[:, 0], r[:, 1]
        kin = 0.5 * jnp.dot(p, p)
        pot = 0.5 * omega**2 * (jnp.dot(x, x) + jnp.dot(y, y))
        pot += 0.5 * kappa * (jnp.sum(jnp.diff(x) ** 2) + jnp.sum(jnp.diff(y) ** 2))
        return kin + pot

    def constraint_matrix(t, q, args):
        r = q.reshape(-1, 3)
        k = r.shape[0]
        rows = jnp.arange(k)
        mu = jnp.zeros((k, 3 * k), q.dtype)
        return mu.at[rows, 3 * rows].set(-r[:, 1]).at[rows, 3 * rows + 2].set(1.0)

    problem = L.NonholonomicSystem(hamiltonian, constraint_matrix, name=f"particle chain N_p={n_particles}")
    i = np.arange(n_particles)
    x, y, z = 0.3 * np.sin(1.3 * i + 0.2), 0.4 * np.cos(0.7 * i), np.zeros(n_particles)
    px, py = 0.5 + 0.2 * np.cos(i), 0.3 * np.sin(2.1 * i + 0.5)
    pz = y * px  # φ = -y p_x + p_z = 0 (M = I)
    q0 = np.stack([x, y, z], 1).ravel()
    p0 = np.stack([px, py, pz], 1).ravel()
    return problem, q0, p0, None


def consistent_batch(ex, batch: int, seed: int = 0):
    """``batch`` consistent initial values of the example ``ex``: its q0, random momenta about its
    p0 projected onto the constraint, and λ0 solved for."""
    rng = np.random.default_rng(seed)
    q0 = np.tile(ex.q0, (batch, 1))
    p0 = ex.p0 + 0.05 * rng.standard_normal((batch, ex.p0.size))

    def project(q, p):
        phi = lambda pp: ex.problem.phi(0.0, q, pp, ex.args)  # noqa: E731
        jp = jax.jacfwd(phi)(p)
        return p - jp.T @ jnp.linalg.solve(jp @ jp.T, phi(p))

    p0 = jax.vmap(project)(jnp.asarray(q0), jnp.asarray(p0))
    lam0 = jax.vmap(lambda q, p: L.consistent_lambda(ex.problem, 0.0, q, p, jnp.zeros(ex.m), ex.args))(
        jnp.asarray(q0), p0
    )
    return jnp.asarray(q0), p0, lam0
