"""Assertions shared by several test modules."""

import jax
import numpy as np


def assert_bitwise_equal(a, b):
    """Two pytrees with the same structure, and leaves equal in dtype, shape and every bit."""
    la, ta = jax.tree_util.tree_flatten(a)
    lb, tb = jax.tree_util.tree_flatten(b)
    assert ta == tb
    for x, y in zip(la, lb):
        x, y = np.asarray(x), np.asarray(y)
        assert x.dtype == y.dtype and x.shape == y.shape, (x.dtype, y.dtype, x.shape, y.shape)
        assert x.tobytes() == y.tobytes()
