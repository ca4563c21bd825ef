"""Checkpoint files: an explicit, versioned format for resuming long runs bit for bit.

A checkpoint holds everything a run needs to continue exactly where it stopped: who the run
is (``meta``), how far it got (``counters``), the loop state (``state/...``) and the output
rows computed so far.  The private loop carry is *not* the file format: the state is stored
under readable names derived from its NamedTuple field names, and the layout of the files is
written down here and guarded by :data:`VERSION` and :data:`STATE_FINGERPRINT`.

Two parts: a small main file and append-only row segments (since version 4)
----------------------------------------------------------------------------
A long run is checkpointed many times while its rows keep growing.  Version 3 rewrote all
rows at every save, O(saves × rows) bytes in all (3.6 GiB for 10⁶ steps saved every 10⁴,
terabytes for 10⁸).  Version 4 writes each row once:

* the **main file** ``path`` holds the meta, the counters, the loop state and a short
  description of the rows (``segments``); it is rewritten, atomically, at every save, and its
  rename is the commit point of the save;
* the rows live in **segment files** in the sidecar directory ``<path>.rows/``
  (:func:`rows_directory`): each save that has new rows writes one segment holding only
  those, and a segment is never changed after it is written.

Bytes written are O(rows) + O(saves × state), and each save costs O(new rows + state).
A save writes its segment first (atomically, like the main file), then the main file; a crash
in between leaves a segment that no main file lists, which loading ignores, and which the
first save of the next writer (the resumed run) removes, or replaces if it saves the same
rows again.  Alternatives considered: one rows file appended in place, with the
committed length in the main file (a torn append must be truncated on resume, and one
damaged append poisons everything after it); HDF5 or zarr (new dependencies, and neither
gives this commit point by itself).

Segments are chained to their main file by SHA-256, so nothing else can be mixed in:
``d₋₁ = sha256("lobattodae-checkpoint-rows:" + run)`` with ``run`` 32 random hex digits
drawn by the first save of a fresh checkpoint, and ``d_i = sha256(d_{i-1}, i, the fields of
segment i: name, dtype, shape and C-order bytes)``.  Segment ``i`` stores ``d_{i-1}`` and is
named after ``d_i``; the main file stores the last digest.  :func:`load` walks the chain from
the main file back to ``d₋₁``, recomputing every digest, so a segment that is missing,
truncated, damaged, left over from an earlier run or a crashed save, or belongs to another
checkpoint is reported, never read.  Because names follow contents, a save never overwrites a
listed segment with different rows, and a fresh run started over an old checkpoint (a new
``run``) leaves the old checkpoint intact until its own main file is committed.

File schema (since version 4; versions 5 and 6 changed only the loop state)
---------------------------------------------------------------------------
Every file is an uncompressed ``.npz`` archive (:func:`numpy.savez`, every member stored, no
pickled objects: it loads with ``allow_pickle=False``) of ``.npy`` members named
``<key>.npy``.  The **main file** ``path`` holds exactly:

``__format__``    0-d unicode string, always :data:`FORMAT` (``"lobattodae-checkpoint"``).
``__version__``   0-d integer, :data:`VERSION` of the writer.
``meta``          0-d unicode string: JSON of a dict, the identity of the run (problem, method,
                  args, t_span, step, initial values, ... as the caller chooses; often digests
                  from :func:`fingerprint_arrays` / :func:`fingerprint_callable`).  A resume is
                  accepted only if it equals the caller's dict (after a JSON round trip).
``counters``      0-d unicode string: JSON of a dict ``str -> int | float`` (steps done,
                  recoveries, resets, ...).
``segments``      0-d unicode string: JSON of ``{"run": run, "count": k, "head": d_{k-1},
                  "fields": [{"name", "dtype", "shape", "rows"}, ...]}``: the committed
                  segments ``0 .. k-1`` (``head`` is ``d₋₁`` when k = 0) and, per row field in
                  order, its dtype (:attr:`numpy.dtype.str`, numbers and booleans only), its
                  shape without the leading row axis and its number of rows so far.
``state/<name>``  one array per leaf of the loop-state pytree, ``<name>`` the dotted path of
                  NamedTuple field names (``"y.q"``, ``"stepper.jacobian.inverse"``); see
                  :func:`state_fields`.  Shapes must match the resuming run's state exactly;
                  dtypes are cast (safely only) to the state's dtypes.

**Segment** ``i`` is the file ``<path>.rows/<i, 6 digits or more>-<first 16 hex digits of
d_i>.npz`` and holds exactly ``__format__`` (:data:`ROWS_FORMAT`), ``__version__``,
``segment`` (JSON ``{"run": run, "index": i, "previous": d_{i-1}}``) and ``rows/<name>`` for
every field (its rows from this save, first axis; possibly none).  The rows of a field are
the concatenation of its arrays over segments ``0 .. k-1``.  Nothing else may be in either
kind of file; other files in the directory are not part of the checkpoint.

To move or copy a checkpoint, move or copy ``path`` and ``<path>.rows/`` together.

Version policy
--------------
Bump :data:`VERSION` whenever the state pytree changes (a field added, removed, renamed,
or a dtype or rank changed) or the meaning or layout of any entry or file changes, and record
the new :func:`schema_fingerprint` of the state in :data:`STATE_FINGERPRINT`; a test compares
the two, so changing the state without bumping the version fails.  Files of any other
version, older or newer, are never migrated or half-read: :func:`load` raises
:class:`CheckpointError` naming both versions and telling the user to delete the file or
restart without resume.  (Version 1 is the ad-hoc ``leaf_{i}`` layout of lobattodae 0.1; it
is recognised as such.  Version 3 is the single-file layout with ``rows/<name>`` entries in
the main file, rewritten whole at every save.)

Atomic writes
-------------
Every file (segment or main) is written to a fresh temporary file with a unique name in its
target's directory (created exclusively, so no existing file or symlink is ever followed or
overwritten), flushed and fsynced, then renamed over the target with :func:`os.replace`, and
the directory is fsynced; the segment is durable before the main file that lists it is
renamed.  A reader therefore sees either the previous complete checkpoint or the new
complete one, never a partial file, even if the process is killed mid-write; on any error
(including ``KeyboardInterrupt``) the temporary file is removed and the previous checkpoint
is left usable.  Saves to one path hold an exclusive lock on its rows directory
(:func:`fcntl.flock`, where the platform has it), so concurrent saves do not interfere: the
last commit wins, with its segments intact.  After its commit, the first save of each writer
(``previous`` None or from :func:`load`) removes the segment files the committed main file
does not list and temporary files of interrupted saves.  Two runs *appending* to one
checkpoint at the same time are not supported (a fresh save removes the other's segments;
loading then reports the checkpoint as corrupt, it never mixes rows).  The rows directory
must not be a symbolic link: :func:`save` and :func:`load` refuse one with a
:class:`CheckpointError` (:func:`check_rows_directory`), and a save locks, lists and cleans the
directory through a handle opened without following links, so no file is ever deleted
through a link.

Errors
------
Every problem with a checkpoint handed to :func:`load` (unreadable, truncated, damaged, not an
archive, not ours, wrong version, another run, wrong shapes, a segment missing, damaged or
not part of the chain) raises :class:`CheckpointError` (a
:class:`~lobattodae.LobattoDAEInputError`, hence a :class:`ValueError`) with one message that
names the file and says what to do.  A missing main file is not an error of :func:`load`'s
contract: ask :func:`exists` first and decide.
"""

from __future__ import annotations

import contextlib
import dataclasses
import errno
import functools
import hashlib
import inspect
import io
import json
import math
import numbers
import os
import re
import secrets
import stat
import struct
import tempfile
import types
import zipfile
import zlib
from collections.abc import Iterator, Mapping, Sequence
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import jax.tree_util as jtu
import numpy as np

from ._errors import LobattoDAEInputError

try:
    import fcntl
except ImportError:  # pragma: no cover - not on Windows: saves are not locked there
    fcntl = None

__all__ = [
    "FORMAT",
    "ROWS_FORMAT",
    "VERSION",
    "STATE_FINGERPRINT",
    "CheckpointError",
    "CheckpointWriteError",
    "Segments",
    "Checkpoint",
    "state_fields",
    "schema_fingerprint",
    "save",
    "load",
    "exists",
    "rows_directory",
    "check_rows_directory",
    "fingerprint_arrays",
    "fingerprint_callable",
]

FORMAT = "lobattodae-checkpoint"
#: ``__format__`` of a row segment file.
ROWS_FORMAT = "lobattodae-checkpoint-rows"
VERSION = 6

# schema_fingerprint(<the loop's State template>) for the current VERSION.  The loop records
# it here once the State exists; a test asserts the two agree, so that changing the State
# without bumping VERSION (and updating this constant) fails.  None: not recorded yet.
STATE_FINGERPRINT: str | None = "2f840729bf4110bf"  # schema_fingerprint(lobattodae._loop.State) of VERSION

_STATE = "state/"
_ROWS = "rows/"
_SEGMENTS = "segments"
_HEADER_KEYS = ("__format__", "__version__", "meta", "counters", _SEGMENTS)
_SEGMENT_KEYS = ("__format__", "__version__", "segment")
_MAX_NPY_HEADER = 100_000
_ROWS_SUFFIX = ".rows"
#: A segment file's name: its index and the first 16 hex digits of its chain digest.
_SEGMENT_NAME = re.compile(r"[0-9]{6,}-[0-9a-f]{16}\.npz")
_RUN = re.compile(r"[0-9a-f]{32}")
_DIGEST = re.compile(r"[0-9a-f]{64}")
#: Row fields hold numbers: booleans, integers, floats, complex numbers.
_ROW_KINDS = "biufc"
#: Sanity bounds on what a file may claim: the size of an axis, the rank of a row field.
_MAX_DIM = 2**40
_MAX_RANK = 31

_RESTART = "delete it or restart without resume"


class CheckpointError(LobattoDAEInputError):
    """A checkpoint file cannot be used to resume: corrupt, foreign, another version or run.

    Attributes
    ----------
    path : str
        The checkpoint file, as given.
    """


class CheckpointWriteError(LobattoDAEInputError):
    """A checkpoint could not be written during a run (a full disk, a directory made read-only,
    a quota): :func:`lobattodae.solve` stops there. The checkpoint on disk is the last one
    committed, intact (a save is atomic), and the message says how far it holds the run.

    Attributes
    ----------
    path : str
        The checkpoint file, as given.
    solution : Solution or None
        The computed prefix, everything the run had computed when the write failed (more than
        the checkpoint holds); set by :func:`lobattodae.solve`.
    errno : int or None
        The operating system's error number (``errno.ENOSPC``, ``errno.EROFS``, ...).
    """

    def __init__(self, message: str, *, path: str, solution: Any = None, errno: int | None = None):
        super().__init__(message)
        self.path = path
        self.solution = solution
        self.errno = errno


@dataclasses.dataclass(frozen=True)
class Segments:
    """The rows a checkpoint on disk holds, as :func:`save` and :func:`load` return them: pass
    it to the next :func:`save` of the same path, which then writes only the new rows.

    Attributes
    ----------
    run : str
        32 hex digits drawn by the first save of a fresh checkpoint (the seed of the chain).
    files : tuple of str
        The committed segment files in :func:`rows_directory`, oldest first.
    head : str
        The chain digest after the last committed segment (the seed when there is none).
    fields : tuple of (str, str, tuple of int)
        ``(name, dtype.str, shape without the row axis)`` of each row field, in order.
    counts : tuple of int
        The rows of each field so far.
    tidy : bool
        The writer that made it has removed the leftovers in the rows directory.
    """

    run: str
    files: tuple[str, ...]
    head: str
    fields: tuple[tuple[str, str, tuple[int, ...]], ...]
    counts: tuple[int, ...]
    tidy: bool = False


class Checkpoint(NamedTuple):
    """What :func:`load` returns."""

    counters: dict  # str -> int | float
    state: Any  # the state pytree, JAX arrays
    rows: dict  # field name -> all its rows (numpy)
    segments: Segments  # for the next save of the resumed run


def rows_directory(path: str | os.PathLike) -> str:
    """The sidecar directory of the checkpoint ``path`` that holds its row segments: ``<path>.rows``."""
    return os.fsdecode(os.fspath(path)) + _ROWS_SUFFIX


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
# the chain of row segments


def _seed(run: str) -> str:
    """``d₋₁``: the chain digest before the first segment of the run ``run``."""
    return hashlib.sha256(f"{ROWS_FORMAT}:{run}".encode()).hexdigest()


def _chain(previous: str, index: int, fields: Sequence[tuple[str, str, tuple[int, ...]]],
           arrays: Mapping[str, np.ndarray]) -> str:
    """``d_i`` from ``d_{i-1}``, the index and the rows of segment ``i`` (C-order bytes)."""
    h = hashlib.sha256(f"{previous}:{index}".encode())
    for name, _, _ in fields:
        arr = np.ascontiguousarray(arrays[name])
        h.update(f"|{name}|{arr.dtype.str}|{arr.shape}|".encode())
        h.update(arr.data)
    return h.hexdigest()


def _segment_name(index: int, digest: str) -> str:
    return f"{index:06d}-{digest[:16]}.npz"


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


def _describe_fields(fields: Sequence[tuple[str, str, tuple[int, ...]]]) -> str:
    return ", ".join(f"{name} {np.dtype(dtype).name} (k{''.join(f', {d}' for d in shape)})"
                     for name, dtype, shape in fields)


def _check_rows(rows: Mapping[str, Any], previous: Segments | None):
    """The new rows as arrays, and the fields they continue (checked against ``previous``)."""
    if not isinstance(rows, Mapping):
        raise TypeError(f"checkpoint rows must be a dict of arrays; got {type(rows).__name__}.")
    new: dict[str, np.ndarray] = {}
    for name, value in rows.items():
        if not isinstance(name, str) or not name:
            raise TypeError(f"checkpoint row names must be non-empty strings; got {name!r}.")
        arr = _plain_array(value, _ROWS + name)
        if arr.dtype.kind not in _ROW_KINDS:
            raise TypeError(f"checkpoint entry {_ROWS + name!r} is not a numeric array (dtype {arr.dtype}); "
                            "rows hold numbers and booleans.")
        if arr.ndim == 0:
            raise TypeError(f"checkpoint entry {_ROWS + name!r} is a 0-d array; rows need a first axis that "
                            "counts them.")
        new[name] = arr
    fields = tuple((name, arr.dtype.str, tuple(int(d) for d in arr.shape[1:])) for name, arr in new.items())
    if previous is not None:
        if sorted(fields) != sorted(previous.fields):
            raise TypeError("checkpoint rows must continue the checkpoint's fields "
                            f"({_describe_fields(previous.fields)}); got {_describe_fields(fields)}.")
        fields = previous.fields
    return new, fields


def _segments_json(run: str, count: int, head: str, fields, counts) -> str:
    return json.dumps({
        "run": run, "count": count, "head": head,
        "fields": [{"name": name, "dtype": dtype, "shape": list(shape), "rows": rows}
                   for (name, dtype, shape), rows in zip(fields, counts)],
    })


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
    previous: Segments | None = None,
) -> Segments:
    """Commit a checkpoint atomically: the new rows as one segment, then the main file (see the
    module docstring for the format and the guarantees).

    ``meta`` must be JSON-serialisable; ``counters`` maps names to ints or floats; ``state`` is
    a pytree of arrays (JAX or numpy; converted with :func:`numpy.asarray`); ``rows`` maps
    field names to arrays of numbers whose first axis counts rows.  With ``previous=None`` they
    are all the rows of a fresh checkpoint, which replaces whatever is at ``path`` (its
    segments are removed once the new main file is committed).  Otherwise ``previous`` is what
    the last :func:`save` or :func:`load` of this path returned, and ``rows`` holds only the
    rows produced since, field by field with the same names, dtypes and trailing shapes; they
    are appended.  Without new rows no segment is written.

    Returns the :class:`Segments` to pass to the next save.  Bad arguments raise
    :class:`TypeError` before anything is written; I/O errors (:class:`OSError`) propagate,
    leaving the previous checkpoint usable.
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
    new, fields = _check_rows(rows, previous)
    if previous is None:
        run = secrets.token_hex(16)
        files, head, counts = (), _seed(run), (0,) * len(fields)
    else:
        run, files, head, counts = previous.run, previous.files, previous.head, previous.counts
    segment = None
    if any(len(arr) for arr in new.values()):
        index = len(files)
        segment_payload = {
            "__format__": np.asarray(ROWS_FORMAT),
            "__version__": np.asarray(VERSION, dtype=np.int64),
            "segment": np.asarray(json.dumps({"run": run, "index": index, "previous": head}, sort_keys=True)),
            **{_ROWS + name: new[name] for name, _, _ in fields},
        }
        head = _chain(head, index, fields, new)
        segment = _segment_name(index, head)
        files = files + (segment,)
    counts = tuple(count + len(new[name]) for count, (name, _, _) in zip(counts, fields))
    payload[_SEGMENTS] = np.asarray(_segments_json(run, len(files), head, fields, counts))

    directory = rows_directory(target)
    check_rows_directory(target)
    try:
        os.mkdir(directory)  # not makedirs: a missing directory of ``path`` is the caller's error
    except FileExistsError:
        pass
    with _rows_directory_handle(target, directory) as dir_fd, _locked(directory, dir_fd):
        if segment is not None:
            _write_atomic(os.path.join(directory, segment), segment_payload)
            _fsync_directory(directory, dir_fd)
        _write_atomic(target, payload)
        _fsync_directory(os.path.dirname(target) or os.curdir)
        if previous is None or not previous.tidy:
            _remove_leftovers(directory, files, dir_fd)
    return Segments(run, files, head, fields, counts, tidy=True)


def _link_error(path: str, directory: str) -> CheckpointError:
    return _error(
        path,
        f"cannot use the checkpoint '{path}': its rows directory '{directory}' is a symbolic link, and "
        "lobattodae never writes, reads or deletes row segments through a link (a fresh save removes the "
        "segment files it finds there). Put the real directory at that path, or choose another checkpoint path.",
    )


def check_rows_directory(path: str | os.PathLike) -> None:
    """Refuse (:class:`CheckpointError`, naming it) a rows directory of the checkpoint ``path``
    that is a symbolic link; :func:`save` and :func:`load` call it, and a caller may call it
    before the work (nothing there yet is fine)."""
    shown = _display(path)
    directory = rows_directory(path)
    if os.path.islink(directory):
        raise _link_error(shown, directory)


#: Whether the rows directory can be listed and cleaned through a handle opened without following links.
_DIR_FD = (
    hasattr(os, "O_DIRECTORY") and hasattr(os, "O_NOFOLLOW") and os.unlink in os.supports_dir_fd
    and os.scandir in os.supports_fd
)


@contextlib.contextmanager
def _rows_directory_handle(path: str, directory: str) -> Iterator[int | None]:
    """A handle of the rows directory opened without following a link (None where the platform
    cannot work relative to one: then its path is used, after :func:`check_rows_directory`)."""
    if not _DIR_FD:
        check_rows_directory(path)
        yield None
        return
    try:
        fd = os.open(directory, os.O_RDONLY | os.O_DIRECTORY | os.O_NOFOLLOW | getattr(os, "O_CLOEXEC", 0))
    except OSError as exc:
        if os.path.islink(directory) or exc.errno == errno.ELOOP:
            raise _link_error(_display(path), directory) from None
        if exc.errno == errno.ENOTDIR:
            raise _error(_display(path), f"cannot write the checkpoint '{_display(path)}': its rows go to the "
                                         f"directory '{directory}', and something else is there; remove it or "
                                         "choose another checkpoint path.") from None
        raise
    try:
        yield fd
    finally:
        os.close(fd)


def _write_atomic(target: str, payload: Mapping[str, np.ndarray]) -> None:
    """Write ``payload`` as an ``.npz`` to a fresh temporary file, fsync it, rename it over ``target``.

    The temporary file has a unique name and is created exclusively (no existing file or link
    is followed); the rename replaces a link at ``target``, it does not follow it."""
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


@contextlib.contextmanager
def _locked(directory: str, dir_fd: int | None = None) -> Iterator[None]:
    """Hold an exclusive advisory lock on ``directory`` (where :mod:`fcntl` exists; best effort),
    through its handle ``dir_fd`` when given (the lock is released when that is closed)."""
    fd = None
    if fcntl is not None:
        if dir_fd is not None:
            fd = os.dup(dir_fd)
        else:
            try:
                fd = os.open(directory, os.O_RDONLY)
            except OSError:
                fd = None
    try:
        if fd is not None:
            try:
                fcntl.flock(fd, fcntl.LOCK_EX)
            except OSError:
                pass
        yield
    finally:
        if fd is not None:
            os.close(fd)  # releases the lock


def _remove_leftovers(directory: str, keep: Sequence[str], dir_fd: int | None = None) -> None:
    """Remove the segment files in ``directory`` that are not in ``keep`` and the temporary
    files of interrupted saves (best effort: a file that cannot be removed stays, unread);
    relative to its handle ``dir_fd`` when given, so never through a link."""
    keep = set(keep)
    try:
        with os.scandir(directory if dir_fd is None else dir_fd) as entries:
            names = [e.name for e in entries if e.is_file(follow_symlinks=False)]
    except OSError:
        return
    for name in names:
        stale = _SEGMENT_NAME.fullmatch(name) is not None and name not in keep
        temporary = name.startswith(".") and name.endswith(".tmp")
        if stale or temporary:
            try:
                if dir_fd is None:
                    os.unlink(os.path.join(directory, name))
                else:
                    os.unlink(name, dir_fd=dir_fd)
            except OSError:
                pass


def _fsync_directory(directory: str, dir_fd: int | None = None) -> None:
    """Make the rename durable (best effort; not possible on every platform)."""
    if dir_fd is not None:
        try:
            os.fsync(dir_fd)
        except OSError:
            pass
        return
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
    """Reads and checks one ``.npy`` member at a time; every failure is a CheckpointError
    about the checkpoint ``path`` (``part``: which of its files, when not the main one)."""

    # Everything parsing a damaged or foreign file may raise.
    _ERRORS = (zipfile.BadZipFile, zipfile.LargeZipFile, OSError, EOFError, ValueError, KeyError,
               IndexError, TypeError, OverflowError, struct.error, zlib.error, NotImplementedError,
               RuntimeError, SyntaxError)

    def __init__(self, path: str, zf: zipfile.ZipFile, file_size: int, part: str | None = None):
        self.path = path
        self.part = part
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
        return _error(self.path, _corrupt_message(self.path, f"{self.part}: {reason}" if self.part else reason))

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


@contextlib.contextmanager
def _open_archive(target: str, shown: str, part: str | None = None) -> Iterator[_Reader]:
    """A :class:`_Reader` of the archive ``target``: the main file (``part`` None) or one of
    its segments (``part`` names it in messages)."""

    def corrupt(main_reason: str, part_reason: str) -> CheckpointError:
        return _error(shown, _corrupt_message(shown, f"{part} {part_reason}" if part else main_reason))

    def unreadable(exc: OSError) -> CheckpointError:
        if part:
            return corrupt("", f"cannot be read ({_describe(exc)})")
        return _error(shown,
                      f"checkpoint '{shown}' cannot be read ({_describe(exc)}); fix its permissions, {_RESTART}.")

    try:
        info = os.stat(target)
    except FileNotFoundError as exc:
        if part:
            raise corrupt("", "is missing") from exc
        if os.path.islink(target):
            raise corrupt("it is a symbolic link to a missing file", "") from exc
        raise _error(shown, f"checkpoint '{shown}' does not exist; check exists() before load().") from exc
    except OSError as exc:
        raise unreadable(exc) from exc
    if stat.S_ISDIR(info.st_mode):
        raise corrupt("it is a directory", "is a directory")
    if not stat.S_ISREG(info.st_mode):
        raise corrupt("it is not a regular file", "is not a regular file")
    if info.st_size == 0:
        raise corrupt("empty file", "is an empty file")
    try:
        fh = open(target, "rb")
    except OSError as exc:
        raise unreadable(exc) from exc
    with fh:
        try:
            zf = zipfile.ZipFile(fh)
        except _Reader._ERRORS as exc:
            reason = f"not a readable .npz archive: {_describe(exc)}"
            raise corrupt(reason, f"is {reason}") from exc
        with zf:
            yield _Reader(shown, zf, info.st_size, part)


def load(
    path: str | os.PathLike,
    *,
    meta: Mapping[str, Any],
    state_template: Any,
    row_names: Sequence[str],
) -> Checkpoint:
    """Read a checkpoint written by :func:`save` for the run identified by ``meta``.

    Returns a :class:`Checkpoint` ``(counters, state, rows, segments)``: ``state`` has the
    pytree structure of ``state_template`` with JAX arrays of the template leaves' dtypes and
    exactly their shapes; ``rows`` maps each of ``row_names`` to all its rows (numpy, read from
    the committed segments); ``segments`` is for the next :func:`save` of the resumed run.

    Raises
    ------
    CheckpointError
        For every problem with the checkpoint: a file cannot be read, is damaged or truncated,
        is not a lobattodae checkpoint, has another format version, belongs to another run
        (``meta`` differs), its state does not fit ``state_template``, its fields are not
        ``row_names``, or a row segment is missing, damaged or not part of its chain.  Also
        when nothing is at ``path``; call :func:`exists` first to tell that case apart.
    """
    shown = _display(path)
    target = os.fspath(path)
    with _open_archive(target, shown) as r:
        counters, state, stored = _load_from(r, meta, state_template, row_names)
    rows, segments = _load_rows(target, shown, stored, row_names)
    return Checkpoint(counters, state, rows, segments)


def _is_count(value: Any) -> bool:
    return isinstance(value, int) and not isinstance(value, bool) and 0 <= value <= _MAX_DIM


def _row_dtype(text: Any) -> np.dtype | None:
    """The dtype a ``segments`` field names, if it is one that rows may have."""
    if not isinstance(text, str):
        return None
    try:
        dtype = np.dtype(text)
    except _Reader._ERRORS:
        return None
    if dtype.kind not in _ROW_KINDS or dtype.shape != () or dtype.fields is not None or dtype.str != text:
        return None
    return dtype


def _segments_entry(r: _Reader):
    """``(run, count, head, fields, counts)`` from the main file's ``segments`` entry."""
    value = r.json_dict(_SEGMENTS)

    def malformed(what: str) -> CheckpointError:
        return r.corrupt(f"entry {_SEGMENTS!r} is malformed ({what})")

    run, count, head, fields = (value.get(k) for k in ("run", "count", "head", "fields"))
    if not (isinstance(run, str) and _RUN.fullmatch(run)):
        raise malformed("run")
    if not _is_count(count):
        raise malformed("count")
    if not (isinstance(head, str) and _DIGEST.fullmatch(head)) or (count == 0 and head != _seed(run)):
        raise malformed("head")
    if not isinstance(fields, list):
        raise malformed("fields")
    parsed, counts, seen = [], [], set()
    for field in fields:
        if not isinstance(field, dict):
            raise malformed("fields")
        name, dtype, shape, rows = (field.get(k) for k in ("name", "dtype", "shape", "rows"))
        if not isinstance(name, str) or not name or name in seen:
            raise malformed(f"field name {name!r}")
        seen.add(name)
        if _row_dtype(dtype) is None:
            raise malformed(f"dtype of {name!r}")
        if not isinstance(shape, list) or len(shape) > _MAX_RANK or not all(_is_count(d) for d in shape):
            raise malformed(f"shape of {name!r}")
        if not _is_count(rows):
            raise malformed(f"row count of {name!r}")
        parsed.append((name, dtype, tuple(shape)))
        counts.append(rows)
    return run, count, head, tuple(parsed), tuple(counts)


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
    wanted = set(_HEADER_KEYS) | {_STATE + n for n, _ in named}
    stored = _segments_entry(r) if r.has(_SEGMENTS) else None
    stored_names = [name for name, _, _ in stored[3]] if stored else []
    missing = set(wanted - set(r.members))
    unexpected = set(set(r.members) - wanted)
    if stored:
        missing |= {_ROWS + n for n in row_names if n not in stored_names}
        unexpected |= {_ROWS + n for n in stored_names if n not in row_names}
    if missing:
        raise r.corrupt(f"missing entries: {', '.join(sorted(missing))}")
    if unexpected:
        raise r.corrupt(f"unexpected entries: {', '.join(sorted(unexpected))}")

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
    return counters, state, stored


def _read_segment(r: _Reader, run: str, index: int, fields) -> tuple[str, dict[str, np.ndarray]]:
    """``(d_{i-1}, rows)`` of segment ``index``, every entry checked against ``fields``."""
    fmt = r.text("__format__")
    if fmt != ROWS_FORMAT:
        raise r.corrupt(f"format {fmt!r}, expected {ROWS_FORMAT!r}")
    version = r.array("__version__")
    if version.ndim != 0 or version.dtype.kind not in "iu" or int(version) != VERSION:
        raise r.corrupt(f"entry '__version__' is not {VERSION}")
    info = r.json_dict("segment")
    previous = info.get("previous")
    own = info.get("index")
    if (info.get("run") != run or not isinstance(own, int) or isinstance(own, bool) or own != index
            or not (isinstance(previous, str) and _DIGEST.fullmatch(previous))):
        raise r.corrupt("it does not belong to this checkpoint (another run's, or a stale one)")
    wanted = set(_SEGMENT_KEYS) | {_ROWS + name for name, _, _ in fields}
    missing, unexpected = sorted(wanted - set(r.members)), sorted(set(r.members) - wanted)
    if missing:
        raise r.corrupt(f"missing entries: {', '.join(missing)}")
    if unexpected:
        raise r.corrupt(f"unexpected entries: {', '.join(unexpected)}")
    arrays = {}
    for name, dtype, shape in fields:
        arr = r.array(_ROWS + name)
        if arr.ndim == 0 or arr.shape[1:] != shape or arr.dtype.str != dtype:
            want = f"(k{''.join(f', {d}' for d in shape)}) of {np.dtype(dtype)}"
            raise r.corrupt(f"entry {_ROWS + name!r} has shape {arr.shape} of {arr.dtype}, expected {want}")
        arrays[name] = arr
    return previous, arrays


def _load_rows(target: str, shown: str, stored, row_names: Sequence[str]):
    """All rows of the committed segments (walking the chain back from the main file's head),
    and the :class:`Segments` a resumed run appends to."""
    run, count, head, fields, counts = stored
    directory, shown_directory = rows_directory(target), rows_directory(shown)
    if os.path.islink(directory):
        raise _link_error(shown, shown_directory)
    parts: dict[str, list[np.ndarray]] = {name: [] for name, _, _ in fields}
    files = []
    digest = head
    for index in range(count - 1, -1, -1):
        name = _segment_name(index, digest)
        part = f"row segment '{os.path.join(shown_directory, name)}'"
        with _open_archive(os.path.join(directory, name), shown, part) as r:
            previous, arrays = _read_segment(r, run, index, fields)
        if _chain(previous, index, fields, arrays) != digest or (index == 0 and previous != _seed(run)):
            raise r.corrupt("its rows are not the ones the checkpoint committed (a stale segment, or another run's)")
        for field, _, _ in fields:
            parts[field].append(arrays[field])
        files.append(name)
        digest = previous
    rows = {}
    for (name, dtype, shape), total in zip(fields, counts):
        blocks = parts[name][::-1]
        if not blocks:
            arr = np.zeros((0,) + shape, np.dtype(dtype))
        else:
            arr = blocks[0] if len(blocks) == 1 else np.concatenate(blocks)
        if len(arr) != total:
            raise _error(shown, _corrupt_message(
                shown, f"its segments hold {len(arr)} rows of {name!r}, its 'segments' entry says {total}"))
        rows[name] = arr
    segments = Segments(run, tuple(files[::-1]), head, fields, counts)
    return {name: rows[name] for name in row_names}, segments


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
