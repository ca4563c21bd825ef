"""The host-side chunk driver (lobattodae._chunks): the loop state packed into two vectors comes back unchanged."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import lobattodae as L
from lobattodae._controllers import ControlOptions, PIController
from lobattodae._chunks import StatePacking, init_host
from lobattodae._loop import Output
from lobattodae.examples import get_example

from helpers import assert_bitwise_equal


def test_a_mixed_tree_round_trips_on_the_host_and_in_a_trace():
    tree = {"f": jnp.arange(6.0).reshape(2, 3), "i": jnp.asarray([3, -4], jnp.int32), "b": jnp.asarray([True, False]),
            "scalar": jnp.asarray(2.5), "k": jnp.asarray(7, jnp.int32), "flag": jnp.asarray(True)}
    packing = StatePacking.of(tree)
    floats, ints = packing.pack(tree, np)
    assert floats.dtype == np.float64 and floats.shape == (7,) and ints.dtype == np.int32 and ints.shape == (6,)
    assert_bitwise_equal(packing.unpack(floats, ints), tree)
    assert_bitwise_equal(jax.jit(lambda t: packing.unpack(*packing.pack(t)))(tree), tree)


def test_the_loop_state_round_trips():
    """The adaptive loop state (float64, int32 and bool leaves of every rank) survives
    pack → unpack bit for bit, and its layout is the one init_host reports."""
    ex = get_example("falling-disk-general")
    state, packing = init_host(ex.problem, L.LobattoIIIAIIIB(stages=3), PIController(), Output(), 0.0, 1.0,
                               ControlOptions(1, 1e-8, 1e-10, 0.0, np.inf), ex.q0, ex.p0, ex.lam0, ex.args)
    assert StatePacking.of(state) == packing
    kinds = set(packing.kinds)
    assert kinds == {"f", "i", "b"}
    assert_bitwise_equal(packing.unpack(*packing.pack(state, np)), state)


def test_unsupported_dtypes_are_refused():
    with pytest.raises(TypeError, match="float32"):
        StatePacking.of({"x": jnp.zeros(2, jnp.float32)})
