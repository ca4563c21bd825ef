"""How the loop state travels between the host and the compiled chunks of :func:`~lobattodae.solve`.

The state is a pytree of about fifty small arrays. Handing it to a compiled function and back
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
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

__all__ = ["StatePacking"]

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
