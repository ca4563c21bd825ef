"""Assertions and set-ups shared by several test modules."""

import os

import jax
import jax.numpy as jnp
import numpy as np

import lobattodae as L


def subprocess_env(**extra):
    """This process's environment for a child Python, without the variables that size XLA's
    CPU pool (``PJRT_NPROC``, ``NPROC``; ``set_cpu_threads`` may have set one here), plus
    ``extra``."""
    base = {k: v for k, v in os.environ.items() if k not in ("PJRT_NPROC", "NPROC")}
    return {**base, **extra}


def assert_bitwise_equal(a, b):
    """Two pytrees with the same structure, and leaves equal in dtype, shape and every bit."""
    la, ta = jax.tree_util.tree_flatten(a)
    lb, tb = jax.tree_util.tree_flatten(b)
    assert ta == tb
    for x, y in zip(la, lb):
        x, y = np.asarray(x), np.asarray(y)
        assert x.dtype == y.dtype and x.shape == y.shape, (x.dtype, y.dtype, x.shape, y.shape)
        assert x.tobytes() == y.tobytes()


#: x'' = -1 with x(0) = 0, x'(0) = 1 (FALL_Q0, FALL_P0), beside a second coordinate held at rest by
#: φ = p[1] (q[1], p[1] stay exactly 0): an ODE that solve_ivp solves too, in the DAE's clothes.
FALL = L.PartitionedDAE(
    f=lambda t, q, p, a: p,
    g=lambda t, q, p, lam, a: jnp.stack([-1.0 + 0.0 * q[0], lam[0]]),
    phi=lambda t, q, p, a: p[1:2],
    name="falling particle",
)
FALL_Q0, FALL_P0 = np.zeros(2), np.array([1.0, 0.0])
