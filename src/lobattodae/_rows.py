"""The layout of what a run records: step-point rows, event rows, and their host-side blocks.

One place owns these widths. The compiled loop (:mod:`lobattodae._loop`) writes each row as
one float vector and one int32 vector (:func:`pack_row`: two buffer updates per row instead
of ten) into buffers made by :func:`row_buffers`, and each zero of an event function as
``(t, q, p, λ)`` (:func:`event_row`, :func:`event_buffers`); the host unpacks them
(:func:`unpack_rows`, :func:`split_event_rows`) and collects chunks in :class:`Rows`
(immutable blocks, merged now and then), which a checkpoint stores under :data:`ROW_FIELDS`.
The dense output's rows are :func:`lobattodae._dense.pack_dense`'s.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

__all__ = [
    "MERGE",
    "ROW_FIELDS",
    "Record",
    "Rows",
    "event_buffers",
    "event_row",
    "event_width",
    "pack_row",
    "row_buffers",
    "split_event_rows",
    "unpack_rows",
]


class Record(NamedTuple):
    """One output row per accepted step (the step ending at ``t``)."""

    t: jax.Array
    q: jax.Array
    p: jax.Array
    lam: jax.Array
    iterations: jax.Array  # Newton iterations of the step
    n_jacobians: jax.Array
    residual_norm: jax.Array  # max-norm of the last Newton residual
    constraint: jax.Array  # ‖φ(t, q, p)‖∞
    drift: jax.Array  # ‖λ − λ(t, q, p)‖∞
    resync: jax.Array  # the step started from λ(t_n, q_n, p_n) ("auto")


#: The fields of a :class:`Record` in its float vector (in this order) and in its int32 vector.
_FLOAT_FIELDS = ("t", "q", "p", "lam", "residual_norm", "constraint", "drift")
_INT_FIELDS = ("iterations", "n_jacobians", "resync")
_INT_DTYPES = {"iterations": np.int32, "n_jacobians": np.int32, "resync": np.bool_}


def _float_sizes(n: int, m: int) -> dict[str, int]:
    return {"t": 1, "q": n, "p": n, "lam": m, "residual_norm": 1, "constraint": 1, "drift": 1}


def pack_row(row: Record):
    """``(floats, ints)``: the row as one float vector (width ``2n + m + 4``) and one int32 vector."""
    floats = jnp.concatenate([jnp.atleast_1d(getattr(row, f)) for f in _FLOAT_FIELDS])
    ints = jnp.stack([jnp.asarray(getattr(row, f)).astype(jnp.int32) for f in _INT_FIELDS])
    return floats, ints


def row_buffers(capacity: int, n: int, m: int, dtype):
    """Empty (NaN) buffers for ``capacity`` packed rows."""
    width = sum(_float_sizes(n, m).values())
    return jnp.full((capacity, width), jnp.nan, dtype), jnp.zeros((capacity, len(_INT_FIELDS)), jnp.int32)


def unpack_rows(floats, ints, n: int, m: int) -> Record:
    """Packed rows (``(k, 2n + m + 4)`` floats, ``(k, 3)`` ints) as a :class:`Record` of columns."""
    out, i = {}, 0
    for f, size in _float_sizes(n, m).items():
        block = floats[:, i : i + size]
        out[f] = block if f in ("q", "p", "lam") else block[:, 0]
        i += size
    for j, f in enumerate(_INT_FIELDS):
        out[f] = ints[:, j].astype(bool) if f == "resync" else ints[:, j]
    return Record(**out)


def event_width(n: int, m: int) -> int:
    """The width of an event row ``(t, q, p, λ)``."""
    return 1 + 2 * n + m


def event_row(t, q, p, lam):
    """The event row of a zero at ``t`` with the state ``(q, p, λ)`` there (``t``: a scalar, or a
    column of k times with (k, ·) states)."""
    return jnp.concatenate([jnp.atleast_1d(t) if jnp.ndim(q) == 1 else t[:, None], q, p, lam], axis=-1)


def event_buffers(capacity: int, n: int, m: int, dtype):
    """Empty buffers for ``capacity`` event rows and the index of their event functions."""
    return jnp.full((capacity, event_width(n, m)), jnp.nan, dtype), jnp.zeros((capacity,), jnp.int32)


def split_event_rows(rows: np.ndarray, n: int):
    """Event rows as their columns ``(t, q, p, λ)``."""
    return rows[:, 0], rows[:, 1 : 1 + n], rows[:, 1 + n : 1 + 2 * n], rows[:, 1 + 2 * n :]


# -- host side ---------------------------------------------------------------------------------------
#: Recorded chunks are merged into one block every this many: few NumPy objects, and each
#: row is copied once more, not once per chunk.
MERGE = 32


class Rows(NamedTuple):
    """Output rows of one kind, immutable: NumPy blocks, each a tuple of fields (arrays with
    the same number of rows). Appending returns a new value; the trailing unmerged blocks are
    merged into one every :data:`MERGE` appends. ``saved``: the first rows, already in the
    checkpoint (a save writes only the rows after them)."""

    empty: tuple  # the fields with no rows (dtypes and trailing shapes)
    blocks: tuple = ()
    merged: int = 0  # the first blocks are merged ones; the others are recent chunks
    count: int = 0
    saved: int = 0

    @classmethod
    def of_records(cls, n: int, m: int) -> Rows:
        """No step-point rows yet (the :class:`Record` fields, unpacked)."""
        sizes = _float_sizes(n, m)
        empty = {f: np.zeros((0, sizes[f]) if f in ("q", "p", "lam") else 0, np.float64) for f in _FLOAT_FIELDS}
        empty.update({f: np.zeros(0, _INT_DTYPES[f]) for f in _INT_FIELDS})
        return cls(tuple(empty[f] for f in Record._fields))

    @classmethod
    def of_events(cls, n: int, m: int) -> Rows:
        """No event rows yet: ``(event_rows, event_index)``."""
        return cls((np.zeros((0, event_width(n, m)), np.float64), np.zeros(0, np.int32)))

    @classmethod
    def of_dense(cls, width: int) -> Rows:
        """No dense-output rows yet (packed steps of ``width`` numbers)."""
        return cls((np.zeros((0, width), np.float64),))

    def append(self, block: tuple) -> Rows:
        k = len(block[0])
        if not k:
            return self
        block = tuple(np.asarray(x, e.dtype) for x, e in zip(block, self.empty, strict=True))
        blocks, merged = self.blocks + (block,), self.merged
        if len(blocks) - merged >= MERGE:
            blocks, merged = blocks[:merged] + (_cat(blocks[merged:]),), merged + 1
        return self._replace(blocks=blocks, merged=merged, count=self.count + k)

    def since(self, start: int) -> tuple:
        """The fields of the rows from ``start`` on, concatenated (only the blocks holding them
        are read)."""
        parts, first = [], self.count
        for block in reversed(self.blocks):
            if first <= start:
                break
            first -= len(block[0])
            parts.append(block if first >= start else tuple(x[start - first:] for x in block))
        return _cat(parts[::-1]) if parts else self.empty

    def all(self) -> tuple:
        return self.since(0)

    def unsaved(self) -> tuple:
        return self.since(self.saved)


def _cat(blocks) -> tuple:
    return blocks[0] if len(blocks) == 1 else tuple(np.concatenate(xs) for xs in zip(*blocks))


#: The names of the row fields in a checkpoint, per kind of rows.
ROW_FIELDS = {"rows": Record._fields, "dense": ("dense",), "events": ("event_rows", "event_index")}
