"""Fingerprints: short, stable digests of what a saved run depends on.

* The **schema** of a state pytree (:func:`state_fields`, :func:`schema_fingerprint`): the dotted
  names, dtypes and ranks of its leaves. A checkpoint stores its state under these names, and
  :data:`~lobattodae._io.checkpoint.STATE_FINGERPRINT` records the schema of the loop's state
  for the current format version, so that changing the state without a new version fails a test.
* **Numbers** (:func:`fingerprint_arrays`): SHA-256 of the dtypes, shapes and bytes of arrays
  and pytrees of them, bit-exact, for ``args`` and initial values.
* **Code** (:func:`fingerprint_callable`): a best-effort identity of a Python callable from its
  bytecode, constants, closures and defaults, so that a resume with other functions is refused.

A checkpoint and an ensemble file put these digests into their ``meta``, the identity of the
run, instead of the values themselves.
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import inspect
import json
import types
from typing import Any

import jax
import jax.tree_util as jtu
import numpy as np

__all__ = [
    "named_leaves",
    "leaf_dtype_shape",
    "state_fields",
    "schema_fingerprint",
    "fingerprint_arrays",
    "fingerprint_callable",
]


# --------------------------------------------------------------------------------------------
# the schema of a state


def _key_name(entry: Any) -> str:
    for attr in ("name", "key", "idx"):  # GetAttrKey, DictKey / FlattenedIndexKey, SequenceKey
        if hasattr(entry, attr):
            return str(getattr(entry, attr))
    return str(entry).strip(".[]'\"")


def leaf_dtype_shape(leaf: Any) -> tuple[np.dtype, tuple[int, ...]]:
    """The dtype and shape of a leaf: an array, a :class:`jax.ShapeDtypeStruct` or a scalar."""
    if hasattr(leaf, "dtype") and hasattr(leaf, "shape"):  # arrays, jax.ShapeDtypeStruct
        return np.dtype(leaf.dtype), tuple(int(d) for d in leaf.shape)
    arr = np.asarray(leaf)
    return arr.dtype, arr.shape


def named_leaves(tree: Any) -> tuple[list[tuple[str, Any]], Any]:
    """``([(name, leaf), ...], treedef)`` of a pytree, each leaf named as in :func:`state_fields`.

    Raises
    ------
    ValueError
        Two leaves get the same name.
    """
    path_leaves, treedef = jtu.tree_flatten_with_path(tree)
    named = []
    seen: set[str] = set()
    for path, leaf in path_leaves:
        name = ".".join(_key_name(k) for k in path) or "root"
        if name in seen:
            raise ValueError(f"state pytree has two leaves named {name!r}; rename a field.")
        seen.add(name)
        named.append((name, leaf))
    return named, treedef


def state_fields(template: Any) -> list[tuple[str, str, tuple[int, ...]]]:
    """``(name, dtype, shape)`` of every leaf of a state pytree, in flattening order.

    ``name`` joins the path's NamedTuple field names (dict keys, sequence indices) with dots,
    e.g. ``"stepper.jacobian.inverse"``; a bare array is called ``"root"``.  ``dtype`` is the
    numpy dtype name (``"float64"``, ``"int32"``, ``"bool"``).  Leaves may be arrays, numpy
    or Python scalars, or :class:`jax.ShapeDtypeStruct`; ``None`` subtrees have no leaves.
    """
    named, _ = named_leaves(template)
    out = []
    for name, leaf in named:
        dtype, shape = leaf_dtype_shape(leaf)
        out.append((name, dtype.name, shape))
    return out


def schema_fingerprint(template: Any) -> str:
    """A short stable digest (16 hex digits of sha256) of the state's schema.

    It covers the leaves' names, dtypes and ranks, in order, but not their sizes, which
    depend on the problem (n, m, stages): the same State code gives the same fingerprint
    for every problem, and a renamed, added, removed, retyped or reshaped-in-rank field
    changes it.
    """
    schema = [[name, dtype, len(shape)] for name, dtype, shape in state_fields(template)]
    blob = json.dumps(schema, separators=(",", ":")).encode()
    return hashlib.sha256(blob).hexdigest()[:16]


# --------------------------------------------------------------------------------------------
# numbers and code


def _is_array_like(value: Any) -> bool:
    return isinstance(value, (np.ndarray, np.generic, jax.Array))


def _array_leaf_update(h: Any, leaf: Any) -> None:
    if callable(leaf):
        h.update(b"callable:" + fingerprint_callable(leaf).encode())
        return
    arr = np.asarray(leaf)
    if arr.dtype.hasobject:
        raise TypeError(f"cannot fingerprint a leaf of type {type(leaf).__name__}; use arrays or numbers.")
    arr = np.ascontiguousarray(arr)
    h.update(f"array:{arr.dtype.str}:{arr.shape}:".encode())
    h.update(arr.tobytes())


def fingerprint_arrays(*arrays_or_pytrees: Any) -> str:
    """sha256 (hex) of the dtypes, shapes and bytes of all leaves of the arguments.

    For numbers a run's identity depends on (``args`` values, initial values): the caller puts
    the digest into ``meta`` instead of long lists.  Bit-exact: ``0.0`` and ``-0.0``, ``1``
    and ``1.0`` (int64 vs float64) differ.  Callable leaves enter via
    :func:`fingerprint_callable`; other non-numeric leaves raise :class:`TypeError`.
    """
    h = hashlib.sha256()
    for tree in arrays_or_pytrees:
        leaves = jtu.tree_leaves(tree)
        h.update(f"arg:{len(leaves)}:".encode())
        for leaf in leaves:
            _array_leaf_update(h, leaf)
    return h.hexdigest()


def _qualname(obj: Any) -> str:
    module = getattr(obj, "__module__", None) or "?"
    name = getattr(obj, "__qualname__", None) or getattr(obj, "__name__", None) or type(obj).__qualname__
    return f"{module}.{name}"


def _code_token(code: types.CodeType) -> str:
    """Bytecode, constants and names, nested code objects included; no line numbers."""
    h = hashlib.sha256()
    h.update(code.co_code)
    h.update(repr((code.co_argcount, code.co_kwonlyargcount, code.co_flags)).encode())
    h.update(repr(code.co_names).encode())
    h.update(repr(code.co_varnames).encode())
    h.update(repr(code.co_freevars).encode())
    for const in code.co_consts:
        h.update(b"|" + _const_token(const).encode())
    return h.hexdigest()


def _const_token(const: Any) -> str:
    if isinstance(const, types.CodeType):
        return "code:" + _code_token(const)
    if isinstance(const, tuple):
        return "(" + ",".join(_const_token(c) for c in const) + ")"
    if isinstance(const, frozenset):  # iteration order depends on hash randomisation
        return "{" + ",".join(sorted(_const_token(c) for c in const)) + "}"
    return f"{type(const).__name__}:{const!r}"


def _value_token(value: Any, seen: set[int]) -> str:
    """A stable token for a value a function depends on (closure cell, default, field)."""
    if value is None or isinstance(value, (bool, int, float, complex, str, bytes)):
        return f"{type(value).__name__}:{value!r}"
    if _is_array_like(value):
        try:
            return "array:" + fingerprint_arrays(value)
        except TypeError:
            return "type:" + _qualname(type(value))
    if isinstance(value, (tuple, list)):
        return "(" + ",".join(_value_token(v, seen) for v in value) + ")"
    if isinstance(value, dict):
        items = sorted((repr(k), _value_token(v, seen)) for k, v in value.items())
        return "{" + ",".join(f"{k}:{v}" for k, v in items) + "}"
    if isinstance(value, (types.ModuleType, type)):
        return "ref:" + (value.__name__ if isinstance(value, types.ModuleType) else _qualname(value))
    if callable(value) or (dataclasses.is_dataclass(value) and id(value) not in seen):
        return "callable:" + _callable_token(value, seen)
    return "type:" + _qualname(type(value))


def _callable_token(fn: Any, seen: set[int]) -> str:
    if id(fn) in seen:
        return "recursive:" + _qualname(fn)
    seen = seen | {id(fn)}
    parts: list[str] = []
    stand_in = getattr(fn, "__fingerprint_as__", None)
    if stand_in is not None:  # a wrapper that asks to be taken for what it wraps
        return _callable_token(stand_in, seen)
    if inspect.ismethod(fn):
        parts += ["method", _callable_token(fn.__func__, seen), _value_token(fn.__self__, seen)]
    elif isinstance(fn, functools.partial):
        parts += ["partial", _callable_token(fn.func, seen), _value_token(fn.args, seen),
                  _value_token(dict(fn.keywords), seen)]
    elif isinstance(fn, types.FunctionType):
        parts += ["function", _qualname(fn), _code_token(fn.__code__),
                  _value_token(fn.__defaults__, seen), _value_token(fn.__kwdefaults__, seen)]
        for cell in fn.__closure__ or ():
            try:
                parts.append(_value_token(cell.cell_contents, seen))
            except ValueError:  # empty cell
                parts.append("empty")
        for name in fn.__code__.co_names:
            if name not in fn.__globals__:
                continue
            value = fn.__globals__[name]
            # Module-level constants and the user's own helper functions; not library objects.
            if isinstance(value, types.FunctionType) and value.__module__ != fn.__module__:
                continue
            if isinstance(value, (types.FunctionType, bool, int, float, complex, str)) or _is_array_like(value):
                parts.append(f"global:{name}=" + _value_token(value, seen))
    elif hasattr(fn, "__wrapped__"):  # jax.jit, functools.wraps
        parts += ["wrapped", _qualname(fn), _callable_token(fn.__wrapped__, seen)]
    elif dataclasses.is_dataclass(fn) and not isinstance(fn, type):
        parts += ["dataclass", _qualname(type(fn))]
        for field in dataclasses.fields(fn):
            parts.append(f"{field.name}=" + _value_token(getattr(fn, field.name, None), seen))
    elif isinstance(fn, type) or not hasattr(type(fn), "__call__") or inspect.isbuiltin(fn):
        parts += ["named", _qualname(fn)]
    else:  # an instance of a class with __call__
        parts += ["object", _qualname(type(fn))]
        call = getattr(type(fn), "__call__", None)
        if isinstance(call, types.FunctionType):
            parts.append(_callable_token(call, seen))
    return hashlib.sha256("\n".join(parts).encode()).hexdigest()


def fingerprint_callable(fn: Any) -> str:
    """A best-effort identity of a Python callable, for checking that a resume uses the same code.

    Returns ``"<module>.<qualname>#<16 hex digits>"``.  For functions the digest covers the
    bytecode (``co_code``), constants, names and variable names, recursively through nested
    code objects (not line numbers: moving a function or editing comments keeps it), plus
    defaults, closure values and the module-level constants and same-module helper functions
    it refers to.  Bound methods combine the function with their instance; for
    :func:`functools.partial` the function and the bound arguments; for dataclass instances
    (e.g. a problem holding ``f``, ``g``, ``phi``) the type name and all fields, callables
    among them fingerprinted recursively; ``jax.jit`` and ``functools.wraps`` wrappers are
    followed to the wrapped function; an object with a ``__fingerprint_as__`` attribute is
    fingerprinted as that attribute's value (the library's jitted problem functions: as the
    function given); other callables contribute their type or name only.

    Best effort, not a proof of equality: the digest depends on the Python version (bytecode
    changes between versions), does not see library code, mutable objects the function reads,
    or values of objects reached through attributes, and two different functions can only
    differ if their code or captured values differ.
    """
    return f"{_qualname(fn)}#{_callable_token(fn, set())[:16]}"
