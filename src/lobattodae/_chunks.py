"""The host-side chunk driver of :func:`~lobattodae.solve`: the compiled loop run in chunks,
the state between them on the host.

:func:`start_host` makes a run's state and runs its first chunk in one compiled call;
:func:`run_host` runs each further chunk from the state the previous one returned;
:func:`init_host` only makes the state (a checkpoint's template, a recovered step).

How the state travels. The state is a pytree of about fifty small arrays. Handing it to a compiled function and back
costs a few microseconds per array on each side: about 170 µs per call, a dozen steps of the
Chaplygin sleigh. So :func:`~lobattodae.solve` passes it as two vectors, every float64 leaf
in one and every int32 and bool leaf (as 0/1) in the other.
:class:`StatePacking` records the layout (static: it is part of the compiled function's
signature); the host unpacks with NumPy, into views of the two vectors.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from . import _compile
from ._controllers import ControlOptions
from ._loop import Chunk, Output, Recording, State, init_state, run
from ._dense import dense_size
from ._rows import Rows, unpack_rows

__all__ = ["CHUNK", "Progress", "StatePacking", "init_host", "recording_of", "run_host", "start_host"]

#: Step attempts per compiled chunk in :func:`~lobattodae.solve` (a fixed length: a new number
#: of steps never recompiles; a short run stops early and leaves the rest of the buffers unused).
CHUNK = 2048

_KINDS = {np.dtype(np.float64): "f", np.dtype(np.int32): "i", np.dtype(np.bool_): "b"}


@dataclass(frozen=True)
class StatePacking:
    """The layout of a pytree packed as ``(floats, ints)``: its structure, and the shape and kind
    (``"f"`` float64, ``"i"`` int32, ``"b"`` bool) of each leaf, in leaf order."""

    treedef: Any
    shapes: tuple[tuple[int, ...], ...]
    kinds: tuple[str, ...]

    @classmethod
    def of(cls, tree) -> StatePacking:
        """The layout of ``tree`` (arrays or ``jax.ShapeDtypeStruct`` leaves)."""
        leaves, treedef = jax.tree_util.tree_flatten(tree)
        kinds = []
        for x in leaves:
            kind = _KINDS.get(np.dtype(x.dtype))
            if kind is None:  # a programming error: the loop state is float64, int32 and bool
                raise TypeError(f"cannot pack a state leaf of dtype {x.dtype}")
            kinds.append(kind)
        return cls(treedef, tuple(tuple(x.shape) for x in leaves), tuple(kinds))

    @functools.cached_property
    def _slots(self) -> tuple[tuple[bool, int, int, tuple[int, ...], bool], ...]:
        """Per leaf: (in floats?, start, stop, shape, bool?)."""
        slots, i_f, i_i = [], 0, 0
        for shape, kind in zip(self.shapes, self.kinds):
            size = math.prod(shape)
            if kind == "f":
                slots.append((True, i_f, i_f + size, shape, False))
                i_f += size
            else:
                slots.append((False, i_i, i_i + size, shape, kind == "b"))
                i_i += size
        return tuple(slots)

    def pack(self, tree, xp=jnp):
        """``tree -> (floats, ints)`` (``xp``: ``jax.numpy`` inside a trace, ``numpy`` on the host)."""
        leaves = jax.tree_util.tree_leaves(tree)
        floats = [xp.ravel(x) for x, k in zip(leaves, self.kinds, strict=True) if k == "f"]
        ints = [xp.ravel(x) for x, k in zip(leaves, self.kinds) if k != "f"]
        return (xp.concatenate(floats).astype(np.float64) if floats else xp.zeros(0, np.float64),
                xp.concatenate(ints).astype(np.int32) if ints else xp.zeros(0, np.int32))

    def empty(self) -> tuple[np.ndarray, np.ndarray]:
        """Zero ``(floats, ints)`` of this layout's sizes (NumPy)."""
        sizes = [0, 0]
        for in_floats, _, stop, _, _ in self._slots:
            sizes[not in_floats] = max(sizes[not in_floats], stop)
        return np.zeros(sizes[0], np.float64), np.zeros(sizes[1], np.int32)

    def unpack(self, floats, ints):
        """``(floats, ints) -> tree`` (JAX or NumPy arrays; on the host, NumPy views and scalars)."""
        leaves = []
        for in_floats, start, stop, shape, boolean in self._slots:
            source = floats if in_floats else ints
            x = source[start] if shape == () else source[start:stop].reshape(shape)
            leaves.append(x != 0 if boolean else x)
        return jax.tree_util.tree_unflatten(self.treedef, leaves)


@_compile.jit(static_argnames=("problem", "method", "controller", "output", "packing"))
def _init_packed(problem, method, controller, output, packing, t0, t1, options, q0, p0, lam0, args):
    return packing.pack(init_state(problem, method, controller, output, t0, t1, options, q0, p0, lam0, args))


@_compile.jit(static_argnames=("problem", "method", "controller", "output", "packing", "length"))
def _run_packed(problem, method, controller, output, packing, fresh, floats, ints, start, lam_hidden, args, length,
                recording):
    """:func:`run` from the packed state, or (``fresh``) from the state :func:`init_state` makes of
    ``start = (t0, t1, options, q0, p0, lam0)`` and ``lam_hidden`` (λ(t0, q0, p0), which the
    caller computed when it validated the initial values: the program holds no hidden-constraint
    solve for the start): a run's first chunk needs no call of its own to initialise, and every
    chunk runs the same compiled program."""
    state = jax.lax.cond(fresh, lambda: init_state(problem, method, controller, output, *start, args, lam_hidden),
                         lambda: packing.unpack(floats, ints))
    state, chunk = run(problem, method, controller, output, state, args, length, recording)
    return packing.pack(state), chunk


def recording_of(length: int, every=1, t_eval=None, k_eval=0, step_to_t_eval=None, dense=False) -> Recording:
    """The :class:`~lobattodae._loop.Recording` of a chunk of ``length`` attempts as host
    arrays of fixed dtypes and shapes (one compiled signature for every choice): the window of
    ``length`` output times from the ``k_eval``-th on (NaN-padded; a chunk writes at most
    ``length`` rows, so it never needs more), and the switches: rows at the times whenever
    ``t_eval`` is given, stepping onto them (default: the same) and dense data."""
    window = np.full(length, np.nan)
    if t_eval is not None:
        part = np.asarray(t_eval, np.float64)[k_eval: k_eval + length]
        window[: len(part)] = part
    given = t_eval is not None
    return Recording(
        np.asarray(min(int(every), np.iinfo(np.int32).max), np.int32), window, np.asarray(k_eval, np.int32),
        np.asarray(given), np.asarray(given if step_to_t_eval is None else step_to_t_eval),
        np.asarray(bool(dense)),
    )


_PACKINGS: dict = {}
#: Layouts kept at most (one per problem object, method, controller, output and shapes).
_PACKINGS_MAX = 256


def _state_packing(problem, method, controller, output, t0, t1, options, q0, p0, lam0, args) -> StatePacking:
    """The layout of the loop state, traced once per problem, method, controller, output and
    shapes (of the values and of ``args``)."""
    leaves, treedef = jax.tree_util.tree_flatten(args)
    key = (problem, method, controller, output, q0.shape, lam0.shape, treedef,
           tuple((np.shape(x), x.dtype if hasattr(x, "dtype") else np.result_type(x)) for x in leaves))
    packing = _PACKINGS.get(key)
    if packing is None:
        # λ(t0) given (its shape is λ0's): the layout needs no trace of the hidden-constraint solve
        shapes = jax.eval_shape(functools.partial(init_state, problem, method, controller, output),
                                t0, t1, options, q0, p0, lam0, args, lam0)
        if len(_PACKINGS) >= _PACKINGS_MAX:
            _PACKINGS.clear()
        packing = _PACKINGS[key] = StatePacking.of(shapes)
    return packing


def _start(t0, t1, options: ControlOptions, q0, p0, lam0) -> tuple:
    """``(t0, t1, options, q0, p0, lam0)`` as host arrays of fixed dtypes: one compiled signature
    whatever Python or NumPy types the caller used."""
    t0, t1, q0, p0, lam0 = (np.asarray(x, np.float64) for x in (t0, t1, q0, p0, lam0))
    options = ControlOptions(np.asarray(options.n, np.int32), *(np.asarray(x, np.float64) for x in options[1:]))
    return t0, t1, options, q0, p0, lam0


def to_host(tree):
    """The arrays of ``tree`` as NumPy arrays, as ``jax.device_get`` returns them.

    On the CPU each is read directly (``np.asarray``): ``jax.device_get`` first starts an
    asynchronous copy of every array, which on the CPU copies nothing and costs ~17 µs per array,
    ~120 µs for the seven of a chunk (jax 0.10: 6 against 124 µs). On accelerators the
    asynchronous copies overlap, and ``jax.device_get`` is used."""
    leaves = jax.tree_util.tree_leaves(tree)  # one compiled call's outputs: all on the same devices
    if leaves and isinstance(leaves[0], jax.Array) and {d.platform for d in leaves[0].devices()} == {"cpu"}:
        return jax.tree_util.tree_map(np.asarray, tree)
    return jax.device_get(tree)


def init_host(problem, method, controller, output: Output, t0, t1, options: ControlOptions, q0, p0, lam0,
              args) -> tuple[State, StatePacking]:
    """:func:`init_state`, compiled, with the state returned to the host (NumPy arrays) and the
    layout to hand to :func:`run_host` with it."""
    start = _start(t0, t1, options, q0, p0, lam0)
    packing = _state_packing(problem, method, controller, output, *start, args)
    packed = _init_packed(problem, method, controller, output, packing, *start, args)
    return packing.unpack(*to_host(packed)), packing


def start_host(problem, method, controller, output: Output, t0, t1, options: ControlOptions, q0, p0, lam0, args,
               length: int, recording: Recording | None = None, *, lam_hidden) -> tuple[State, Chunk, StatePacking]:
    """:func:`init_host` and the first :func:`run_host` in one compiled call (one dispatch and
    one state transfer less: most of a short run's fixed cost); returns the state after the
    chunk, the chunk and the layout to hand to :func:`run_host` for the next chunks.
    ``lam_hidden``: λ(t0, q0, p0) from the hidden constraint (validation computes it)."""
    start = _start(t0, t1, options, q0, p0, lam0)
    packing = _state_packing(problem, method, controller, output, *start, args)
    packed = packing.empty()
    return *_run_chunk(problem, method, controller, output, packing, True, packed, start, args, length,
                       recording, np.asarray(lam_hidden, np.float64)), packing


def run_host(problem, method, controller, output: Output, packing: StatePacking, state: State, args, length: int,
             recording: Recording | None = None) -> tuple[State, Chunk]:
    """:func:`run`, compiled once per (problem, method, controller, output, shapes, length), from
    and to a state on the host: it travels packed (:class:`StatePacking`), two arrays
    instead of fifty, which is most of the cost of a short chunk's dispatch. ``recording``
    (:func:`recording_of`; default: every step point) is data: any choice runs the same
    program."""
    n, m = np.shape(state.q)[-1], np.shape(state.lam)[-1]
    unused = _start(0.0, 0.0, ControlOptions(0, 0.0, 0.0, 0.0, 0.0), np.zeros(n), np.zeros(n), np.zeros(m))
    return _run_chunk(problem, method, controller, output, packing, False, packing.pack(state, np), unused, args,
                      length, recording, np.zeros(m))


def _run_chunk(problem, method, controller, output, packing, fresh, packed, start, args, length, recording,
               lam_hidden):
    """One compiled chunk; its output comes to the host in one transfer, and the rows are
    unpacked there (NumPy views)."""
    recording = recording_of(length) if recording is None else recording
    out = _run_packed(problem, method, controller, output, packing, np.asarray(fresh), *packed, start, lam_hidden,
                      args, length, recording)
    packed, chunk = to_host(out)
    n, m = start[3].shape[-1], start[5].shape[-1]
    return packing.unpack(*packed), chunk._replace(rows=unpack_rows(*chunk.rows, n, m))


# -- a run on the host -----------------------------------------------------------------------------
class Progress(NamedTuple):
    """How far a run got: replaced as a whole (one assignment), so that an interrupt can never
    see a state that does not belong to its rows."""

    state: State
    rows: Rows  # the output rows (Record fields)
    dense: Rows | None  # packed dense-output rows (dense_output=True)
    events: Rows | None  # (event_rows, event_index) (with events)
    recoveries: int
    segments: Any = None  # _io.checkpoint.Segments of the last checkpoint written or read

    @classmethod
    def start(cls, state: State, dense: bool, events: bool, recoveries: int = 0) -> Progress:
        """No rows yet (their shapes from ``state``); ``dense``, ``events``: whether the run
        records dense-output data and event zeros."""
        n, m, (pieces, s) = state.q.shape[-1], state.lam.shape[-1], state.last.V.shape[:2]
        dense = Rows.of_dense(dense_size(pieces, s, n, m)) if dense else None
        events = Rows.of_events(n, m) if events else None
        return cls(state, Rows.of_records(n, m), dense, events, recoveries)

    def kinds(self):
        """``(name, rows)`` of each kind of rows the run records."""
        kinds = (("rows", self.rows), ("dense", self.dense), ("events", self.events))
        return [(kind, rows) for kind, rows in kinds if rows is not None]

    def with_chunk(self, chunk) -> Progress:
        """The run with the rows, dense-output data and event zeros of a chunk (NumPy) appended.

        The used rows are copied out of the chunk's buffers, so that the buffers (up to
        ``chunk_size`` rows each) are freed: with ``save_every`` a chunk uses few of them."""

        def used(x, k):
            return np.array(x[:k])

        rows, dense, events = self.rows, self.dense, self.events
        rows = rows.append(tuple(used(x, int(chunk.n_rows)) for x in chunk.rows))
        if dense is not None:
            dense = dense.append((used(chunk.dense, int(chunk.n_dense)),))
        if events is not None:
            e = int(chunk.n_events)
            events = events.append((used(chunk.event_rows, e), used(chunk.event_index, e)))
        return self._replace(rows=rows, dense=dense, events=events)
