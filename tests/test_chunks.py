"""The host-side chunk driver (lobattodae._chunks): the loop state packed into two vectors comes
back unchanged, and a run in chunks gives the numbers of one run."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import lobattodae as L
from lobattodae._controllers import ConstantStepSize, ControlOptions, PIController
from lobattodae._chunks import StatePacking, init_host, recording_of, run_host, start_host
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


# -- runs in chunks -------------------------------------------------------------------------------------
def _sixty_steps(knife):
    """``(t0, t1, options, q0, p0, lam0)`` of 60 constant steps of the knife edge on [0, 3]."""
    f64 = lambda x: jnp.asarray(x, jnp.float64)  # noqa: E731
    return f64(0.0), f64(3.0), ControlOptions(n=60), f64(knife.q0), f64(knife.p0), f64(knife.lam0)


def _hidden(knife):
    """λ(t0, q0, p0) of the knife edge's start (what solve's validation hands to start_host)."""
    return np.asarray(L.consistent_lambda(knife.problem, 0.0, jnp.asarray(knife.q0), jnp.asarray(knife.p0),
                                          jnp.asarray(knife.lam0), knife.args, iterations=1))


def test_chunks_give_the_same_numbers_as_one_run(knife):
    m = L.LobattoIIIAIIIB(stages=3)
    c = ConstantStepSize()
    out = Output()
    state, packing = init_host(knife.problem, m, c, out, *_sixty_steps(knife), knife.args)
    whole, chunk = run_host(knife.problem, m, c, out, packing, state, knife.args, 64)
    rec = chunk.rows
    assert int(chunk.n_rows) == 60 and np.all(np.isnan(np.asarray(rec.q[60:])))
    part = state
    rows = []
    for _ in range(4):
        part, r = run_host(knife.problem, m, c, out, packing, part, knife.args, 16)
        rows.append(np.asarray(r.rows.q)[: int(r.n_rows)])
    np.testing.assert_array_equal(np.concatenate(rows), np.asarray(rec.q)[:60])
    np.testing.assert_array_equal(np.asarray(part.q), np.asarray(whole.q))


def test_the_first_chunk_initialises_the_state_it_would_get_from_init_host(knife):
    """start_host (init and first chunk in one compiled call) gives the numbers, bit for bit,
    of init_host followed by run_host, and hands on a state the next run_host continues from."""
    m = L.LobattoIIIAIIIB(stages=3)
    c = ConstantStepSize()
    out = Output()
    start = _sixty_steps(knife)
    state, packing = init_host(knife.problem, m, c, out, *start, knife.args)
    ref_state, ref = run_host(knife.problem, m, c, out, packing, state, knife.args, 64)
    first, chunk, packing2 = start_host(knife.problem, m, c, out, *start, knife.args, 32, lam_hidden=_hidden(knife))
    assert packing2 == packing and int(chunk.n_rows) == 32 and int(first.n_accepted) == 32
    rest, chunk2 = run_host(knife.problem, m, c, out, packing2, first, knife.args, 64)
    for f in ("t", "q", "p", "lam", "iterations"):
        got = np.concatenate([getattr(chunk.rows, f)[:32], getattr(chunk2.rows, f)[: int(chunk2.n_rows)]])
        np.testing.assert_array_equal(got, np.asarray(getattr(ref.rows, f))[:60])
    np.testing.assert_array_equal(np.asarray(rest.q), np.asarray(ref_state.q))


def test_a_sparse_output_chunk_runs_its_whole_length(knife):
    """With save_every=50 a 32-attempt chunk runs every attempt it may and keeps no row, and
    the next keeps exactly the 50th row of the sixty steps and the last; the recording is data,
    so both run the program of every step point."""
    m = L.LobattoIIIAIIIB(stages=3)
    c = ConstantStepSize()
    start = _sixty_steps(knife)
    state, chunk, packing = start_host(knife.problem, m, c, Output(), *start, knife.args, 32, recording_of(32, 50),
                                       lam_hidden=_hidden(knife))
    _, full, _ = start_host(knife.problem, m, c, Output(), *start, knife.args, 64, lam_hidden=_hidden(knife))
    assert int(state.n_accepted) == 32 and int(chunk.n_rows) == 0
    state, chunk = run_host(knife.problem, m, c, Output(), packing, state, knife.args, 32, recording_of(32, 50))
    assert int(state.n_accepted) == 60 and int(chunk.n_rows) == 2  # the 50th step point and the last
    np.testing.assert_array_equal(chunk.rows.q[:2], full.rows.q[[49, 59]])
