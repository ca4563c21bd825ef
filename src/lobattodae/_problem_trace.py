"""The problem's functions traced before a run (``jax.eval_shape``: nothing is compiled), and
``args`` checked, so that a mistake becomes a message that names it and the fix.

A failure while tracing is explained (:func:`function_error`): a field missing from ``args``, an
``args`` leaf of the wrong kind, or ``q0``/``p0`` of a length the problem's functions do not
accept (the lengths they do accept are found by tracing them at other lengths). The output
shapes of f, g and φ are checked against n and m (:func:`check_output_shapes`).
"""

from __future__ import annotations

import functools
import math
from collections.abc import Mapping
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from ._errors import LobattoDAEInputError, ProblemFunctionError, ShapeError
from ._problem import _HamiltonianMixin, plain_calls

__all__ = ["check_args", "function_error", "length_hint", "output_signature", "short"]

#: When q0/p0 do not fit the problem, the lengths near len(q0) that are tried to say which
#: length the problem's functions do accept (PartitionedDAE: no constraint matrix to read it from).
_LENGTH_SEARCH = 4
#: A constraint matrix that fails for q of length n is traced with up to this many more entries.
_LENGTH_PROBE = 8


def short(x: Any, limit: int = 60) -> str:
    text = repr(x)
    return text if len(text) <= limit else text[: limit - 3] + "..."


# -- args ---------------------------------------------------------------------------------
def _args_name(path) -> str:
    return "args" + jax.tree_util.keystr(tuple(path))


@functools.lru_cache(maxsize=None)
def _dtype_kind(dtype) -> tuple[bool, bool]:
    """(numeric or boolean, inexact) for the dtype of an args leaf, decided by JAX's dtype lattice
    once per dtype (a model's args has dozens of leaves of one dtype, checked at every call)."""
    numeric = bool(jnp.issubdtype(dtype, jnp.number) or jnp.issubdtype(dtype, jnp.bool_))
    return numeric, bool(jnp.issubdtype(dtype, jnp.inexact))


def _leaf_problem(path, leaf: Any) -> str | None:
    """Why ``leaf`` (at key path ``path`` of args) cannot be an args leaf, or None."""
    hint = (
        "args leaves must be numbers or numeric arrays: JAX traces args, so strings, None and other "
        "objects cannot be passed through it (fix such settings in the problem's functions instead, "
        "e.g. with functools.partial or a closure)."
    )
    if isinstance(leaf, jax.core.Tracer):
        return None
    if isinstance(leaf, (np.ndarray, np.generic, jax.Array)):
        dtype = leaf.dtype
    elif isinstance(leaf, (str, bytes)):
        return f"{_args_name(path)} is the string {short(leaf)}: {hint}"
    elif isinstance(leaf, (bool, int, float, complex)):
        if isinstance(leaf, int) and not isinstance(leaf, bool) and not -(2**63) <= leaf < 2**63:
            return f"{_args_name(path)} = {short(leaf)} does not fit in a 64-bit integer; pass it as a float."
        dtype = np.asarray(leaf).dtype
    else:
        return f"{_args_name(path)} is of type {type(leaf).__name__} ({short(leaf)}): {hint}"
    numeric, inexact = _dtype_kind(dtype)
    if not numeric:
        return f"{_args_name(path)} is an array of dtype {dtype} ({short(leaf)}): {hint}"
    if inexact:
        arr = np.asarray(leaf)
        # a scalar through math.isfinite: ~10 x faster than the array reduction
        finite = math.isfinite(arr) if arr.ndim == 0 and dtype.kind == "f" else bool(np.isfinite(arr).all())
        if not finite:
            bad = int(np.count_nonzero(~np.isfinite(arr)))
            value = f"= {arr.item()}" if arr.size == 1 else f"has {bad} NaN or inf entries"
            return (
                f"{_args_name(path)} {value}: args values must be finite (a NaN or inf there makes everything "
                f"computed from them, λ0 and every step, non-finite). Give {_args_name(path)} a finite value."
            )
    return None


def check_args(args: Any) -> None:
    """Every leaf of the ``args`` pytree must be a finite number or numeric array.

    Raises :class:`ShapeError` naming the leaf by its path (``args.m``, ``args['k']``,
    ``args[0]``) for a string, an object, a non-numeric array or a NaN/inf value.
    """
    try:
        leaves = jax.tree_util.tree_flatten_with_path(args)[0]
    except Exception as exc:  # a custom pytree whose flatten fails
        raise ShapeError(f"args cannot be flattened as a JAX pytree ({type(exc).__name__}: {exc}).") from exc
    for path, leaf in leaves:
        problem = _leaf_problem(path, leaf)
        if problem is not None:
            raise ShapeError(problem)


def _nodes(tree: Any, path: tuple = ()) -> list[tuple[tuple, Any]]:
    """Every node of a pytree (containers, leaves and None) with its key path, root first."""
    out = [(path, tree)]
    if tree is None or jax.tree_util.treedef_is_leaf(jax.tree_util.tree_structure(tree)):
        return out
    try:
        children = jax.tree_util.tree_flatten_with_path(tree, is_leaf=lambda x: x is not tree)[0]
    except Exception:
        return out
    for sub, child in children:
        out.extend(_nodes(child, path + tuple(sub)))
    return out


def _is_leaf(x: Any) -> bool:
    return x is not None and jax.tree_util.treedef_is_leaf(jax.tree_util.tree_structure(x))


def _keys_text(node: Any) -> str:
    if isinstance(node, Mapping):
        return f" (its keys: {sorted(map(str, node))})"
    fields = getattr(type(node), "_fields", None) or getattr(type(node), "__dataclass_fields__", None)
    if fields:
        return f" (its fields: {list(fields)})"
    return ""


def _args_failure(exc: Exception, seen: Any) -> str | None:
    """If ``exc``, raised by a problem function called with args ``seen``, is about args (a
    missing field or key, args None or too short, a None value), say so; else None."""
    nodes = _nodes(seen)
    by_id = {id(node): (path, node) for path, node in nodes}
    text = str(exc)
    if isinstance(exc, AttributeError) and getattr(exc, "name", None) is not None:
        field, obj = exc.name, getattr(exc, "obj", None)
        if seen is None and obj is None:
            return (
                f"args is None, but the problem's functions read args.{field}: pass args=... with a field "
                f"'{field}' (a NamedTuple, a dataclass registered as a pytree, or a dict read as args['{field}'])."
            )
        if id(obj) in by_id:
            path, node = by_id[id(obj)]
            where = _args_name(path)
            if _is_leaf(node):
                return (
                    f"{where} is a single number or array, but the problem's functions read {where}.{field}: "
                    f"pass a container with a field '{field}' there (e.g. a NamedTuple)."
                )
            if isinstance(node, Mapping) and field in node:
                return (
                    f"the problem's functions read {where}.{field} (an attribute), but {where} is a "
                    f"{type(node).__name__}{_keys_text(node)}: read {where}['{field}'] in the functions, or pass "
                    f"a container with a field '{field}' (a NamedTuple, or a dataclass registered as a pytree)."
                )
            if isinstance(node, (Mapping, list)) or type(node) is tuple:
                return (
                    f"the field '{field}' is missing from {where}: the problem's functions read {where}.{field}, "
                    f"but {where} is a {type(node).__name__}{_keys_text(node)}. Pass a container with a field "
                    f"'{field}' (a NamedTuple, or a dataclass registered as a pytree)."
                )
            return (
                f"the field '{field}' is missing from {where}{_keys_text(node)}: the problem's functions "
                f"read {where}.{field}. Add '{field}' to args."
            )
        for path, node in nodes:
            if node is None and obj is None:
                return f"{_args_name(path)} is None, but the problem's functions read {_args_name(path)}.{field}."
        return None
    if isinstance(exc, KeyError) and len(exc.args) == 1:
        key = exc.args[0]
        try:
            hash(key)
        except TypeError:
            return None
        lacking = [(path, node) for path, node in nodes if isinstance(node, Mapping) and key not in node]
        if lacking:
            path, node = lacking[0]
            where = _args_name(path)
            return (
                f"the key {key!r} is missing from {where}{_keys_text(node)}: the problem's functions read "
                f"{where}[{key!r}]. Add {key!r} to args."
            )
        return None
    if isinstance(exc, TypeError):
        if seen is None and "NoneType" in text and "subscriptable" in text:
            return (
                "args is None, but the problem's functions index it (args[...]): pass args=... with the "
                "values they read."
            )
        if isinstance(seen, (list, tuple)) and "indices must be integers" in text:
            return (
                f"args is a {type(seen).__name__}, but the problem's functions read it by name (args['...']): "
                "pass a dict (or a NamedTuple read as args.name)."
            )
        if isinstance(seen, jax.core.Tracer) and "string indexing" in text:
            return (
                "args is a single number or array, but the problem's functions read it by name (args['...']): "
                "pass a dict with those keys."
            )
        nones = [path for path, node in nodes if node is None]
        if "NoneType" in text and nones:
            names = ", ".join(_args_name(p) for p in nones[:4])
            return (
                f"{names} is None: args leaves must be numbers or numeric arrays, and the problem's functions "
                "compute with it."
            )
        complex_leaves = [
            path
            for path, node in nodes
            if _is_leaf(node) and jnp.issubdtype(getattr(node, "dtype", float), jnp.complexfloating)
        ]
        if "complex" in text and complex_leaves:
            names = ", ".join(_args_name(p) for p in complex_leaves[:4])
            return f"{names} is complex: the problem's functions must return real values; pass real numbers in args."
        sequences = [
            path for path, node in nodes[1:] if isinstance(node, (list, tuple)) and not hasattr(node, "_fields")
        ]
        if sequences and any(w in text for w in ("sequence", "'list'", "'tuple'")):
            names = ", ".join(_args_name(p) for p in sequences[:4])
            return (
                f"{names} is a Python list or tuple (a container in args, not an array), and the problem's "
                "functions compute with it: pass a number or a numeric array (np.asarray(...)) instead."
            )
        return None
    if isinstance(exc, IndexError) and isinstance(seen, (list, tuple)) and "index out of range" in text:
        return (
            f"args has {len(seen)} entries, but the problem's functions read an entry beyond them: "
            "pass args with every value the functions read."
        )
    return None


# -- tracing the problem's functions --------------------------------------------------------
def function_error(name: str, exc: Exception, seen: Any = ...) -> ProblemFunctionError:
    about_args = None if seen is ... else _args_failure(exc, seen)
    if about_args is not None:
        err = ProblemFunctionError(
            f"{about_args} ({name} raised {type(exc).__name__}: {exc}; the original traceback is chained "
            "above.)"
        )
        err.about_args = True
        return err
    if isinstance(exc, jax.errors.ConcretizationTypeError):
        # JAX's text points at our tracing wrapper's arguments and suggests static arguments,
        # which users of solve cannot set: say what to change in the function instead.
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else ""
        return ProblemFunctionError(
            f"calling {name} at the initial point (t0, q0, p0, args) raised {type(exc).__name__} ({first}): "
            "the function uses the value of t, q, p, lam or an args value in Python control flow (if, while, "
            "bool(), int(), float()). The problem's functions are traced by JAX: write such a branch with "
            "jnp.where or jax.lax.cond (the original traceback is chained above)."
        )
    return ProblemFunctionError(
        f"calling {name} at the initial point (t0, q0, p0, args) raised {type(exc).__name__}: {exc} "
        "(the error comes from the problem's function; the original traceback is chained above)."
    )


def _trace(fn, name: str, *a):
    """``jax.eval_shape`` of a user function (nothing is compiled); a failure becomes a
    :class:`ProblemFunctionError` that says what is wrong with args when that is the cause."""
    seen = []

    def call(*b):
        seen.append(b[-1])  # the args the function saw (its containers, for the message)
        return fn(*b)

    try:
        with plain_calls():
            return jax.eval_shape(call, *a)
    except Exception as exc:  # re-raised with context: the user's function failed
        raise function_error(name, exc, seen[-1] if seen else ...) from exc


def _shape_of(fn, name: str, expected: tuple[int, ...] | None, *a):
    """Shape and dtype of a user function's output, found by tracing (nothing is compiled)."""
    out = _trace(fn, name, *a)
    if not hasattr(out, "shape"):
        raise ShapeError(f"{name} must return a single array; it returned {type(out).__name__}.")
    if expected is not None and out.shape != expected:
        err = ShapeError(f"{name} must return an array of shape {expected}; it returned shape {out.shape}.")
        if len(expected) == 1 and len(out.shape) == 1 and out.shape[0] >= 1:
            _mark_length(err, out.shape[0], name, out.shape, expected)
        raise err
    if not jnp.issubdtype(out.dtype, jnp.floating):
        raise ShapeError(f"{name} must return floating-point values; it returned dtype {out.dtype}.")
    if out.dtype != jnp.float64:
        raise ShapeError(
            f"{name} returned {out.dtype}, not float64: lobattodae computes in float64; "
            "do not cast to float32 inside the problem functions."
        )
    return out


def _mark_length(err: ShapeError, length: int, name: str, shape, expected, extra: str = "") -> None:
    """Note on ``err`` that the function ``name`` returned ``shape``, which suggests that the
    problem's functions are written for q of length ``length`` (checked by the caller)."""
    err.length = length
    err.mismatch = (name, tuple(shape), tuple(expected), extra)


def _matrix_shape(fn, name: str, *a) -> tuple[int, ...]:
    out = _trace(fn, name, *a)
    if not hasattr(out, "shape"):
        raise ShapeError(f"{name} must return a single array; it returned {type(out).__name__}.")
    return tuple(out.shape)


def _check_output_shapes(problem, n: int, t, q, p, args) -> int:
    """Trace M, μ, φ, f and g once (nothing is compiled) and check what they return; return m."""
    mass = getattr(problem, "mass_matrix", None)
    if callable(mass):  # first: f, g and φ all solve with M
        shape = _matrix_shape(mass, "mass_matrix(t, q, args)", t, q, args)
        if shape != (n, n):
            err = ShapeError(
                f"mass_matrix(t, q, args) must return an array of shape {(n, n)} (n = {n}, the length of q0 "
                f"and p0); it returned shape {shape}."
            )
            if len(shape) == 2 and shape[0] == shape[1] and shape[0] >= 1:
                _mark_length(err, shape[0], "mass_matrix(t, q, args)", shape, (n, n))
            raise err
    if isinstance(problem, _HamiltonianMixin):
        shape = _matrix_shape(problem.constraint_matrix, "constraint_matrix(t, q, args)", t, q, args)
        if len(shape) != 2 or shape[0] < 1:
            raise ShapeError(
                f"constraint_matrix(t, q, args) must return a 2-D array of shape (m, n) = (m, {n}), one row "
                "per constraint (for a single constraint jnp.array([[...]]) or mu[None, :]); it returned "
                f"shape {shape}."
            )
        if shape[1] != n:
            err = ShapeError(
                f"constraint_matrix(t, q, args) returned shape {shape} ({shape[0]} constraint(s) on {shape[1]} "
                f"coordinates), but q0 and p0 have length {n}: it must return shape (m, n) = {(shape[0], n)}, "
                "one column per coordinate."
            )
            name = "constraint_matrix(t, q, args)"
            _mark_length(err, shape[1], name, shape, (shape[0], n), ", one column per coordinate")
            raise err
    phi_s = _shape_of(problem.phi, "phi(t, q, p, args)", None, t, q, p, args)
    if len(phi_s.shape) != 1 or phi_s.shape[0] < 1:
        raise ShapeError(f"phi(t, q, p, args) must return a 1-D array of shape (m,), m ≥ 1; got shape {phi_s.shape}.")
    m = phi_s.shape[0]
    if m > n:
        raise ShapeError(f"there are more constraints (m={m}) than degrees of freedom (n={n}).")
    _shape_of(problem.f, "f(t, q, p, args)", (n,), t, q, p, args)
    lam = jax.ShapeDtypeStruct((m,), jnp.float64)
    _shape_of(problem.g, "g(t, q, p, lam, args)", (n,), t, q, p, lam, args)
    _check_position_constraint_shape(problem, m, t, q, args)
    return m


def _check_position_constraint_shape(problem, m: int, t, q, args) -> None:
    """ψ = ``position_constraint(t, q, args)``, when the problem has one, must return (k,) with
    1 ≤ k ≤ m: each holonomic constraint has its velocity form among the m rows of φ (that it
    is callable was checked when the problem was built)."""
    psi = getattr(problem, "position_constraint", None)
    if psi is None:
        return
    name = "position_constraint(t, q, args)"
    shape = _shape_of(psi, name, None, t, q, args).shape
    if len(shape) != 1 or not 1 <= shape[0] <= m:
        raise ShapeError(
            f"{name} must return a 1-D array of shape (k,), one entry per holonomic constraint ψ_i(t, q) = 0, "
            f"with 1 ≤ k ≤ m = {m} (the velocity form ψ_q f + ψ_t of each is a row of phi); it returned shape "
            f"{shape}. Return jnp.array([psi_1, ...]) (jnp.atleast_1d for a single constraint), or pass "
            "position_constraint=None."
        )


@functools.lru_cache(maxsize=256)
def _cached_output_shapes(problem, n: int, args_treedef, args_avals) -> int:
    return _check_output_shapes(problem, n, *_abstract_inputs(n, args_treedef, args_avals))


def _abstract_inputs(n: int, args_treedef, args_avals):
    args = jax.tree_util.tree_unflatten(
        args_treedef, [jax.ShapeDtypeStruct(shape, dtype, weak_type=weak) for shape, dtype, weak in args_avals]
    )
    vec = jax.ShapeDtypeStruct((n,), jnp.float64)
    return jax.ShapeDtypeStruct((), jnp.float64), vec, vec, args


@functools.lru_cache(maxsize=None)
def _array_result_type(dtype):
    """``jnp.result_type`` of an array leaf, which depends only on its dtype (a weak type is always
    the default one of its kind): decided once per dtype (4 µs a leaf otherwise, at every call)."""
    return jnp.result_type(np.empty((), dtype))


def _aval(x) -> tuple:
    """(shape, dtype as JAX computes with it, whether a Python scalar) of an args leaf."""
    if isinstance(x, (np.ndarray, np.generic, jax.Array)):
        return np.shape(x), _array_result_type(x.dtype), False
    return np.shape(x), jnp.result_type(x), True


def _cache_key(problem, args):
    """``(treedef, avals)`` of args for the caches, or None where args or problem is unhashable."""
    leaves, treedef = jax.tree_util.tree_flatten(args)
    try:
        avals = tuple(_aval(x) for x in leaves)
        hash((problem, treedef, avals))
    except TypeError:
        return None
    return treedef, avals


def _signature(problem, n: int, args) -> int:
    key = _cache_key(problem, args)
    if key is None:
        vec = jnp.zeros(n)
        return _check_output_shapes(problem, n, jnp.asarray(0.0), vec, vec, args)
    return _cached_output_shapes(problem, n, *key)


def _works_with(problem, n: int, args) -> bool:
    try:
        _signature(problem, n, args)
    except LobattoDAEInputError:
        return False
    return True


_LENGTH_CACHE: dict = {}


def _accepted_lengths(problem, n: int, args, first: int | None) -> list[int]:
    """Lengths k ≠ n of q and p with which the problem's functions trace and return consistent
    shapes. Tried: the length a function's output suggests (``first``, the columns of the
    constraint matrix, the size of the mass matrix), then, for a general PartitionedDAE, the
    lengths within ``_LENGTH_SEARCH`` of n. Cached per problem, n and abstract args."""
    key = _cache_key(problem, args)
    ckey = None if key is None else (problem, n, first, *key)
    if ckey is not None and ckey in _LENGTH_CACHE:
        return _LENGTH_CACHE[ckey]
    direct = [] if first is None else [first]
    t = jax.ShapeDtypeStruct((), jnp.float64)
    for attr, axis in (("constraint_matrix", 1), ("mass_matrix", 0)):
        fn = getattr(problem, attr, None)
        if not callable(fn):
            continue
        for k in range(max(n, 1), n + _LENGTH_PROBE + 1):  # a function indexing q[k-1] fails for shorter q
            try:
                shape = jax.eval_shape(fn, t, jax.ShapeDtypeStruct((k,), jnp.float64), args).shape
            except Exception:
                continue
            if len(shape) == 2 and shape[axis] >= 1:
                direct.append(shape[axis])
            break
    found = []
    for k in dict.fromkeys(direct):
        if k != n and k >= 1 and _works_with(problem, k, args):
            found.append(k)
    if not found and not isinstance(problem, _HamiltonianMixin):
        tried = set(direct)
        for k in range(max(1, n - _LENGTH_SEARCH), n + _LENGTH_SEARCH + 1):
            if k != n and k not in tried and _works_with(problem, k, args):
                found.append(k)
    if ckey is not None:
        if len(_LENGTH_CACHE) > 256:
            _LENGTH_CACHE.clear()
        _LENGTH_CACHE[ckey] = found
    return found


def _lengths_text(ks: list[int]) -> str:
    return " or ".join(str(k) for k in ks[:3])


def output_signature(problem, n: int, args) -> int:
    """``m``, after checking the shapes and dtypes M, μ, f, g and φ return for these input shapes.

    Tracing the user's functions costs ~10 ms, so the result is cached per (problem, n,
    abstract args); a second ``solve`` of the same problem does not trace them again.
    Problems or args that cannot be cached (unhashable) are traced each time. When the
    functions do not accept q and p of length n but do accept another length, the error says
    so: q0 and p0 (or the function that fixed the other length) are wrong.
    """
    try:
        return _signature(problem, n, args)
    except (ShapeError, ProblemFunctionError) as err:
        if getattr(err, "about_args", False):
            raise
        ks = _accepted_lengths(problem, n, args, getattr(err, "length", None))
        if not ks:
            raise
        k = _lengths_text(ks)
        if isinstance(err, ProblemFunctionError):
            msg = (
                f"q0 and p0 have length {n}, but the problem's functions expect length {k}: they fail for "
                f"q, p of length {n} and work for length {k}. Pass q0 and p0 of length {k}. "
                f"(With length {n}: {err})"
            )
        elif getattr(err, "mismatch", None) is not None and ks[0] == err.length:
            name, shape, expected, extra = err.mismatch
            msg = (
                f"q0 and p0 have length {n}, but {name} returned shape {shape}: the problem's functions are "
                f"written for n = {err.length} coordinates. If so, pass q0 and p0 of length {err.length}; otherwise "
                f"{name} must return an array of shape {expected}{extra}."
            )
        else:
            msg = (
                f"{err} The problem's functions are consistent with n = {k}: if the system has {k} "
                f"coordinates, q0 and p0 have the wrong length (pass arrays of length {k}); otherwise fix "
                "the function named."
            )
        raise ShapeError(msg) from err


def length_hint(problem, nq: int, np_: int, args) -> str:
    """For q0 and p0 of different lengths: which one the problem accepts, if that is clear."""
    if min(nq, np_) < 1:
        return ""
    try:
        ok_q, ok_p = _works_with(problem, nq, args), _works_with(problem, np_, args)
    except Exception:  # a hint only; never mask the error it explains
        return ""
    if ok_q and not ok_p:
        return f" The problem's functions work with n = {nq}: p0 has the wrong length."
    if ok_p and not ok_q:
        return f" The problem's functions work with n = {np_}: q0 has the wrong length."
    return ""
