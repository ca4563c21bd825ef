"""Assertions and set-ups shared by several test modules."""

import os

import jax
import numpy as np


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
