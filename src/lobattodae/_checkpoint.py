"""Checkpoint files: an explicit, versioned format for resuming long runs bit for bit.

A checkpoint holds everything a run needs to continue exactly where it stopped: who the run
is (``meta``), how far it got (``counters``), the loop state (``state/...``) and the output
rows computed so far (``rows/...``).  The private loop carry is *not* the file format: the
state is stored under readable names derived from its NamedTuple field names, and the layout
of the file is written down here and guarded by :data:`VERSION` and :data:`STATE_FINGERPRINT`.

File schema (version 3)
-----------------------
An uncompressed ``.npz`` archive (:func:`numpy.savez`, every member stored, no pickled
objects: it loads with ``allow_pickle=False``).  Its entries, each a ``.npy`` member named
``<key>.npy``:

``__format__``    0-d unicode string, always :data:`FORMAT` (``"lobattodae-checkpoint"``).
``__version__``   0-d integer, :data:`VERSION` of the writer.
``meta``          0-d unicode string: JSON of a dict, the identity of the run (problem, method,
                  args, t_span, step, initial values, ... as the caller chooses; often digests
                  from :func:`fingerprint_arrays` / :func:`fingerprint_callable`).  A resume is
                  accepted only if it equals the caller's dict (after a JSON round trip).
``counters``      0-d unicode string: JSON of a dict ``str -> int | float`` (steps done,
                  recoveries, resets, ...).
``state/<name>``  one array per leaf of the loop-state pytree, ``<name>`` the dotted path of
                  NamedTuple field names (``"y.q"``, ``"stepper.jacobian.inverse"``); see
                  :func:`state_fields`.  Shapes must match the resuming run's state exactly;
                  dtypes are cast (safely only) to the state's dtypes.
``rows/<name>``   one array per recorded output quantity, the computed prefix of the run.

Nothing else may be in the archive.

Version policy
--------------
Bump :data:`VERSION` whenever the state pytree changes (a field added, removed, renamed,
or a dtype or rank changed) or the meaning of any entry changes, and record the new
:func:`schema_fingerprint` of the state in :data:`STATE_FINGERPRINT`; a test compares the
two, so changing the state without bumping the version fails.  Files of any other version,
older or newer, are never migrated or half-read: :func:`load` raises :class:`CheckpointError`
naming both versions and telling the user to delete the file or restart without resume.
(Version 1 is the ad-hoc ``leaf_{i}`` layout of lobattodae 0.1; it is recognised as such.)

Atomic writes
-------------
:func:`save` writes to a fresh temporary file with a unique name in the target's directory
(created exclusively, so no existing file or symlink is ever followed or overwritten), flushes
and fsyncs it, then renames it over the target with :func:`os.replace`.  A reader therefore
sees either the previous complete checkpoint or the new complete one, never a partial file,
even if the process is killed mid-write; on any error (including ``KeyboardInterrupt``) the
temporary file is removed and the previous checkpoint is left as it was.  Concurrent saves to
the same path do not interfere: the last rename wins.

Errors
------
Every problem with a file handed to :func:`load` (unreadable, truncated, damaged, not an
archive, not ours, wrong version, another run, wrong shapes) raises :class:`CheckpointError`
(a :class:`~lobattodae.LobattoDAEInputError`, hence a :class:`ValueError`) with one message
that names the file and says what to do.  A missing file is not an error of :func:`load`'s
contract: ask :func:`exists` first and decide.
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import inspect
import io
import json
import math
import numbers
import os
import stat
import struct
import tempfile
import types
import zipfile
import zlib
from collections.abc import Mapping, Sequence
from typing import Any

import jax
import jax.numpy as jnp
import jax.tree_util as jtu
import numpy as np

from ._errors import LobattoDAEInputError

__all__ = [
    "FORMAT",
    "VERSION",
    "STATE_FINGERPRINT",
    "CheckpointError",
    "state_fields",
    "schema_fingerprint",
    "save",
    "load",
    "exists",
    "fingerprint_arrays",
    "fingerprint_callable",
]

FORMAT = "lobattodae-checkpoint"
VERSION = 3

# schema_fingerprint(<the loop's State template>) for the current VERSION.  The loop records
# it here once the State exists; a test asserts the two agree, so that changing the State
# without bumping VERSION (and updating this constant) fails.  None: not recorded yet.
STATE_FINGERPRINT: str | None = "9c12e42f9122523c"  # schema_fingerprint(lobattodae._loop.State) of VERSION

_STATE = "state/"
_ROWS = "rows/"
_HEADER_KEYS = ("__format__", "__version__", "meta", "counters")
_MAX_NPY_HEADER = 100_000

_RESTART = "delete it or restart without resume"


class CheckpointError(LobattoDAEInputError):
    """A checkpoint file cannot be used to resume: corrupt, foreign, another version or run.

    Attributes
    ----------
    path : str
        The checkpoint file, as given.
    """


# --------------------------------------------------------------------------------------------
# state schema


def _key_name(entry: Any) -> str:
    for attr in ("name", "key", "idx"):  # GetAttrKey, DictKey / FlattenedIndexKey, SequenceKey
        if hasattr(entry, attr):
            return str(getattr(entry, attr))
    return str(entry).strip(".[]'\"")


def _leaf_dtype_shape(leaf: Any) -> tuple[np.dtype, tuple[int, ...]]:
    if hasattr(leaf, "dtype") and hasattr(leaf, "shape"):  # arrays, jax.ShapeDtypeStruct
        return np.dtype(leaf.dtype), tuple(int(d) for d in leaf.shape)
    arr = np.asarray(leaf)
    return arr.dtype, arr.shape


def _flatten_named(tree: Any) -> tuple[list[tuple[str, Any]], Any]:
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
    named, _ = _flatten_named(template)
    out = []
    for name, leaf in named:
        dtype, shape = _leaf_dtype_shape(leaf)
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
# writing


def _counters_json(counters: Mapping[str, Any]) -> str:
    if not isinstance(counters, Mapping):
        raise TypeError(f"checkpoint counters must be a dict; got {type(counters).__name__}.")
    clean: dict[str, int | float] = {}
    for key, value in counters.items():
        if not isinstance(key, str):
            raise TypeError(f"checkpoint counter names must be strings; got {key!r}.")
        if isinstance(value, numbers.Integral):
            clean[key] = int(value)
        elif isinstance(value, numbers.Real):
            clean[key] = float(value)
        else:
            raise TypeError(f"checkpoint counter {key!r} must be an int or a float; got {value!r}.")
    return json.dumps(clean, sort_keys=True)


def _plain_array(value: Any, what: str) -> np.ndarray:
    arr = np.asarray(value)
    if arr.dtype.hasobject:
        raise TypeError(f"checkpoint entry {what!r} is not a numeric array (dtype {arr.dtype}); "
                        "checkpoints hold no Python objects.")
    return arr


def _default_file_mode() -> int | None:
    """``0o666 & ~umask`` as for a file created by ``open``, read without changing the umask."""
    try:
        with open("/proc/self/status", encoding="ascii") as fh:
            for line in fh:
                if line.startswith("Umask:"):
                    return 0o666 & ~int(line.split()[1], 8)
    except (OSError, ValueError, IndexError):
        pass
    return None


def save(
    path: str | os.PathLike,
    *,
    meta: Mapping[str, Any],
    counters: Mapping[str, Any],
    state: Any,
    rows: Mapping[str, Any],
) -> None:
    """Write a checkpoint atomically (see the module docstring for the format and guarantee).

    ``meta`` must be JSON-serialisable; ``counters`` maps names to ints or floats; ``state`` is
    a pytree of arrays (JAX or numpy; converted with :func:`numpy.asarray`); ``rows`` maps
    names to arrays.  Bad arguments raise :class:`TypeError` before anything is written;
    I/O errors (:class:`OSError`) propagate, leaving any previous checkpoint untouched.
    """
    target = os.fspath(path)
    payload: dict[str, np.ndarray] = {
        "__format__": np.asarray(FORMAT),
        "__version__": np.asarray(VERSION, dtype=np.int64),
        "meta": np.asarray(json.dumps(dict(meta), sort_keys=True, allow_nan=True)),
        "counters": np.asarray(_counters_json(counters)),
    }
    named, _ = _flatten_named(state)
    for name, leaf in named:
        payload[_STATE + name] = _plain_array(leaf, _STATE + name)
    for name, value in rows.items():
        if not isinstance(name, str) or not name:
            raise TypeError(f"checkpoint row names must be non-empty strings; got {name!r}.")
        payload[_ROWS + name] = _plain_array(value, _ROWS + name)

    directory, base = os.path.split(target)
    fd, tmp = tempfile.mkstemp(prefix=f".{base}.", suffix=".tmp", dir=directory or None)
    try:
        with os.fdopen(fd, "wb") as fh:
            mode = _default_file_mode()
            if mode is not None and hasattr(os, "fchmod"):
                os.fchmod(fh.fileno(), mode)
            np.savez(fh, **payload)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, target)
    except BaseException:
        try:
            os.unlink(tmp)
        except OSError:
            pass
        raise
    _fsync_directory(directory or os.curdir)


def _fsync_directory(directory: str) -> None:
    """Make the rename durable (best effort; not possible on every platform)."""
    try:
        fd = os.open(directory, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


# --------------------------------------------------------------------------------------------
# reading


def exists(path: str | os.PathLike) -> bool:
    """Whether anything is at ``path`` (a file, a directory, even a dangling symlink).

    Deliberately broader than "a valid checkpoint": whatever sits there, :func:`load` either
    reads it or says clearly why it cannot, instead of a run silently starting afresh.
    """
    return os.path.lexists(os.fspath(path))


class _Reader:
    """Reads and checks one ``.npy`` member at a time; every failure is a CheckpointError."""

    # Everything parsing a damaged or foreign file may raise.
    _ERRORS = (zipfile.BadZipFile, zipfile.LargeZipFile, OSError, EOFError, ValueError, KeyError,
               IndexError, TypeError, OverflowError, struct.error, zlib.error, NotImplementedError,
               RuntimeError, SyntaxError)

    def __init__(self, path: str, zf: zipfile.ZipFile, file_size: int):
        self.path = path
        self.zf = zf
        self.members: dict[str, zipfile.ZipInfo] = {}
        for info in zf.infolist():
            if not info.filename.endswith(".npy"):
                raise self.corrupt(f"unexpected archive member {info.filename!r}")
            key = info.filename[: -len(".npy")]
            if key in self.members:
                raise self.corrupt(f"duplicate entry {key!r}")
            if info.compress_type != zipfile.ZIP_STORED or info.flag_bits & 0x1:
                raise self.corrupt(f"entry {key!r} is compressed or encrypted")
            if info.file_size > file_size:
                raise self.corrupt(f"entry {key!r} is larger than the file")
            self.members[key] = info

    def corrupt(self, reason: str) -> CheckpointError:
        return _error(self.path, _corrupt_message(self.path, reason))

    def has(self, key: str) -> bool:
        return key in self.members

    def array(self, key: str) -> np.ndarray:
        if key not in self.members:
            raise self.corrupt(f"missing entry {key!r}")
        try:
            data = self.zf.read(self.members[key])  # verifies the CRC
            return _parse_npy(data)
        except self._ERRORS as exc:
            raise self.corrupt(f"entry {key!r} is damaged: {_describe(exc)}") from exc

    def text(self, key: str) -> str:
        arr = self.array(key)
        if arr.ndim != 0 or arr.dtype.kind != "U":
            raise self.corrupt(f"entry {key!r} is not a string")
        return str(arr.item())

    def json_dict(self, key: str) -> dict:
        raw = self.text(key)
        try:
            value = json.loads(raw)
        except (ValueError, RecursionError) as exc:
            raise self.corrupt(f"entry {key!r} is not valid JSON: {_describe(exc)}") from exc
        if not isinstance(value, dict):
            raise self.corrupt(f"entry {key!r} is not a JSON object")
        return value


def _parse_npy(data: bytes) -> np.ndarray:
    """Parse a ``.npy`` blob without pickles and without trusting its header's sizes."""
    fp = io.BytesIO(data)
    version = np.lib.format.read_magic(fp)
    if version == (1, 0):
        shape, fortran, dtype = np.lib.format.read_array_header_1_0(fp, max_header_size=_MAX_NPY_HEADER)
    elif version == (2, 0):
        shape, fortran, dtype = np.lib.format.read_array_header_2_0(fp, max_header_size=_MAX_NPY_HEADER)
    else:
        raise ValueError(f"unsupported .npy version {version}")
    if dtype.hasobject:
        raise ValueError("it holds Python objects (pickled data)")
    count = math.prod(shape)
    offset = fp.tell()
    if offset + count * dtype.itemsize != len(data):
        raise ValueError(f"{len(data) - offset} data bytes for shape {shape} of {dtype}")
    flat = np.frombuffer(data, dtype=dtype, count=count, offset=offset)
    arr = flat.reshape(shape[::-1]).transpose() if fortran else flat.reshape(shape)
    return np.array(arr, copy=True, order="K")


def _describe(exc: BaseException) -> str:
    text = str(exc).strip()
    return f"{type(exc).__name__}: {text}" if text else type(exc).__name__


def _display(path: str | os.PathLike) -> str:
    return os.fsdecode(os.fspath(path))


def _error(path: str, message: str) -> CheckpointError:
    err = CheckpointError(message)
    err.path = path
    return err


def _corrupt_message(path: str, reason: str) -> str:
    return f"checkpoint '{path}' is corrupt or not a lobattodae checkpoint ({reason}); {_RESTART}."


def _version_error(path: str, version: int) -> CheckpointError:
    age = "an older" if version < VERSION else "a newer"
    return _error(
        path,
        f"checkpoint '{path}' has checkpoint format version {version} (written by {age} lobattodae), "
        f"but this lobattodae reads and writes version {VERSION}; {_RESTART}.",
    )


def _same_json(a: Any, b: Any) -> bool:
    # == makes 1 and 1.0 equal; the canonical text makes NaN equal to NaN.
    return a == b or json.dumps(a, sort_keys=True) == json.dumps(b, sort_keys=True)


def _check_format_and_version(r: _Reader) -> None:
    if not r.has("__format__"):
        legacy = _legacy_version(r)
        if legacy is not None:
            raise _version_error(r.path, legacy)
        raise r.corrupt("no '__format__' entry")
    fmt = r.text("__format__")
    if fmt != FORMAT:
        raise r.corrupt(f"format {fmt!r}, expected {FORMAT!r}")
    arr = r.array("__version__")
    if arr.ndim != 0 or arr.dtype.kind not in "iu":
        raise r.corrupt("entry '__version__' is not an integer")
    version = int(arr)
    if version != VERSION:
        raise _version_error(r.path, version)


def _legacy_version(r: _Reader) -> int | None:
    """Version 1 (lobattodae 0.1): ``meta`` holds ``"format": "lobattodae-checkpoint-1"``."""
    if not (r.has("meta") and r.has("leaf_0")):
        return None
    try:
        fmt = r.json_dict("meta").get("format")
    except CheckpointError:
        return None
    if isinstance(fmt, str) and fmt.startswith(FORMAT + "-") and fmt[len(FORMAT) + 1:].isdigit():
        return int(fmt[len(FORMAT) + 1:])
    return None


def load(
    path: str | os.PathLike,
    *,
    meta: Mapping[str, Any],
    state_template: Any,
    row_names: Sequence[str],
) -> tuple[dict[str, int | float], Any, dict[str, np.ndarray]]:
    """Read a checkpoint written by :func:`save` for the run identified by ``meta``.

    Returns ``(counters, state, rows)``: ``state`` has the pytree structure of
    ``state_template`` with JAX arrays of the template leaves' dtypes and exactly their
    shapes; ``rows`` maps each of ``row_names`` to the stored numpy array.

    Raises
    ------
    CheckpointError
        For every problem with the file: it cannot be read, is damaged or truncated, is not a
        lobattodae checkpoint, has another format version, belongs to another run (``meta``
        differs), or its state does not fit ``state_template``.  Also when nothing is at
        ``path``; call :func:`exists` first to tell that case apart.
    """
    shown = _display(path)
    target = os.fspath(path)
    try:
        info = os.stat(target)
    except FileNotFoundError as exc:
        if os.path.islink(target):
            raise _error(shown, _corrupt_message(shown, "it is a symbolic link to a missing file")) from exc
        raise _error(shown, f"checkpoint '{shown}' does not exist; check exists() before load().") from exc
    except OSError as exc:
        raise _error(shown, f"checkpoint '{shown}' cannot be read ({_describe(exc)}); "
                            f"fix its permissions, {_RESTART}.") from exc
    if stat.S_ISDIR(info.st_mode):
        raise _error(shown, _corrupt_message(shown, "it is a directory"))
    if not stat.S_ISREG(info.st_mode):
        raise _error(shown, _corrupt_message(shown, "it is not a regular file"))
    if info.st_size == 0:
        raise _error(shown, _corrupt_message(shown, "empty file"))
    try:
        fh = open(target, "rb")
    except OSError as exc:
        raise _error(shown, f"checkpoint '{shown}' cannot be read ({_describe(exc)}); "
                            f"fix its permissions, {_RESTART}.") from exc
    with fh:
        try:
            zf = zipfile.ZipFile(fh)
        except _Reader._ERRORS as exc:
            reason = "not a readable .npz archive"
            raise _error(shown, _corrupt_message(shown, f"{reason}: {_describe(exc)}")) from exc
        with zf:
            return _load_from(_Reader(shown, zf, info.st_size), meta, state_template, row_names)


def _load_from(r: _Reader, meta: Mapping[str, Any], state_template: Any, row_names: Sequence[str]):
    _check_format_and_version(r)

    expected = json.loads(json.dumps(dict(meta), sort_keys=True))
    saved = r.json_dict("meta")
    diff = sorted(k for k in set(saved) | set(expected)
                  if k not in saved or k not in expected or not _same_json(saved[k], expected[k]))
    if diff:
        raise _error(
            r.path,
            f"checkpoint '{r.path}' belongs to a different run (differs in: {', '.join(diff)}); "
            "resume with the same problem, method, args, t_span, step and initial values, or delete it.",
        )

    counters = r.json_dict("counters")
    for key, value in counters.items():
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise r.corrupt(f"counter {key!r} is not a number")

    named, treedef = _flatten_named(state_template)
    row_names = list(row_names)
    wanted = set(_HEADER_KEYS) | {_STATE + n for n, _ in named} | {_ROWS + n for n in row_names}
    missing = sorted(wanted - set(r.members))
    if missing:
        raise r.corrupt(f"missing entries: {', '.join(missing)}")
    unexpected = sorted(set(r.members) - wanted)
    if unexpected:
        raise r.corrupt(f"unexpected entries: {', '.join(unexpected)}")

    leaves = []
    for name, leaf in named:
        key = _STATE + name
        dtype, shape = _leaf_dtype_shape(leaf)
        arr = r.array(key)
        if arr.shape != shape:
            raise r.corrupt(f"entry {key!r} has shape {arr.shape}, expected {shape}")
        if not np.can_cast(arr.dtype, dtype, casting="safe"):
            raise r.corrupt(f"entry {key!r} has dtype {arr.dtype}, expected {dtype}")
        leaves.append(jnp.asarray(arr.astype(dtype, copy=False)))
    state = jtu.tree_unflatten(treedef, leaves)
    rows = {name: r.array(_ROWS + name) for name in row_names}
    return counters, state, rows


# --------------------------------------------------------------------------------------------
# fingerprints for run identities


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
    followed to the wrapped function; other callables contribute their type or name only.

    Best effort, not a proof of equality: the digest depends on the Python version (bytecode
    changes between versions), does not see library code, mutable objects the function reads,
    or values of objects reached through attributes, and two different functions can only
    differ if their code or captured values differ.
    """
    return f"{_qualname(fn)}#{_callable_token(fn, set())[:16]}"
