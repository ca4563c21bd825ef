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
                  from :mod:`lobattodae._io.fingerprint`).  A resume is accepted only if it
                  equals the caller's dict (after a JSON round trip).
``counters``      0-d unicode string: JSON of a dict ``str -> int | float`` (steps done,
                  recoveries, resets, ...).
``segments``      0-d unicode string: JSON of ``{"run": run, "count": k, "head": d_{k-1},
                  "fields": [{"name", "dtype", "shape", "rows"}, ...]}``: the committed
                  segments ``0 .. k-1`` (``head`` is ``d₋₁`` when k = 0) and, per row field in
                  order, its dtype (:attr:`numpy.dtype.str`, numbers and booleans only), its
                  shape without the leading row axis and its number of rows so far.
``state/<name>``  one array per leaf of the loop-state pytree, ``<name>`` the dotted path of
                  NamedTuple field names (``"y.q"``, ``"stepper.jacobian.inverse"``); see
                  :func:`~lobattodae._io.fingerprint.state_fields`.  Shapes must match the
                  resuming run's state exactly; dtypes are cast (safely only) to the state's
                  dtypes.

**Segment** ``i`` is the file ``<path>.rows/<i, 6 digits or more>-<first 16 hex digits of
d_i>.npz`` and holds exactly ``__format__`` (:data:`ROWS_FORMAT`), ``__version__``,
``segment`` (JSON ``{"run": run, "index": i, "previous": d_{i-1}}``) and ``rows/<name>`` for
every field (its rows from this save, first axis; possibly none).  The rows of a field are
the concatenation of its arrays over segments ``0 .. k-1``.  Nothing else may be in either
kind of file; other files in the directory are not part of the checkpoint.

To move or copy a checkpoint, move or copy ``path`` and ``<path>.rows/`` together.

Version policy
--------------
Bump :data:`VERSION` whenever the state pytree changes (a field added, removed, renamed, or a
dtype or rank changed) or the meaning or layout of any entry or file changes, and record the
new :func:`~lobattodae._io.fingerprint.schema_fingerprint` of the state in
:data:`STATE_FINGERPRINT`; a test compares the two, so changing the state without bumping the
version fails.  Files of any other version, older or newer, are never migrated or half-read:
:func:`load` raises :class:`CheckpointError` naming both versions and telling the user to
delete the file or restart without resume.  (Version 1 is the ad-hoc ``leaf_{i}`` layout of
lobattodae 0.1; it is recognised as such.  Version 3 is the single-file layout with
``rows/<name>`` entries in the main file, rewritten whole at every save.  Version 7 keeps the
reused inverse Jacobian flattened, ``stepper.jacobian.inverse`` of shape (N²,) instead of
(N, N).  Version 8 adds ``controller.n_floored`` to the state of error-controlled runs.
Version 9 keeps step doubling's two inverse Jacobians stacked in the state of
error-controlled runs, ``stepper.jacobians.inverse`` of shape (2, N²).  Version 10 adds the
round-off level Newton measured, ``stepper.jacobian.floor`` (``stepper.jacobians.floor``).
Version 11 adds the check of large steps to the PI controller's state: ``controller.h_last``,
``controller.err_last``, ``controller.checking``, ``controller.n_checked``,
``controller.radius``.  Version 12 adds the rounding error of the step point kept for
compensated summation, ``stepper.compensation`` (``stepper.half.compensation`` under error
control).  Version 13 adds two counters to the PI controller's state, ``controller.n_failed_solves``
and ``controller.n_unresolved``.)

Atomic writes
-------------
Every file, segment or main, is written by :func:`lobattodae._io.atomic.write_npz` (a unique
temporary file created exclusively, fsynced, renamed over the target, the directory fsynced;
on any error the temporary file is removed), and the segment is durable before the main file
that lists it is renamed.  A reader therefore sees either the previous complete checkpoint or
the new complete one, even if the process is killed mid-write.  Saves to one path hold an
exclusive lock on its rows directory (:func:`fcntl.flock`, where the platform has it), so
concurrent saves do not interfere: the last commit wins, with its segments intact.  After its
commit, the first save of each writer (``previous`` None or from :func:`load`) removes the
segment files the committed main file does not list and temporary files of interrupted saves.
Two runs *appending* to one checkpoint at the same time are not supported (a fresh save
removes the other's segments; loading then reports the checkpoint as corrupt, it never mixes
rows).  Neither ``path`` nor its rows directory may be a symbolic link: :func:`save` refuses
either with a :class:`CheckpointError` (:func:`check_links`), :func:`load` a linked rows
directory, and a save locks, lists and cleans the directory through a handle opened without
following links, so no file is ever written or deleted through a link.

Errors
------
Every problem with a checkpoint handed to :func:`load` (unreadable, truncated, damaged, not an
archive, not ours, wrong version, another run, wrong shapes, a segment missing, damaged or
not part of the chain) raises :class:`CheckpointError` (a
:class:`~lobattodae.LobattoDAEInputError`, hence a :class:`ValueError`) with one message that
names the file and says what to do (:mod:`lobattodae._io.archive`).  A missing main file is
not an error of :func:`load`'s contract: ask :func:`exists` first and decide.
"""

from __future__ import annotations

import json
import numbers
import os
import secrets
from collections.abc import Mapping, Sequence
from typing import Any, NamedTuple

import jax.numpy as jnp
import jax.tree_util as jtu
import numpy as np

from .._errors import LobattoDAEInputError
from . import atomic
from .archive import (
    RESTART,
    CheckpointError,
    Reader,
    checkpoint_error,
    corrupt_message,
    display,
    open_archive,
)
from .fingerprint import leaf_dtype_shape, named_leaves
from .segments import (
    ROWS_FORMAT,
    SEGMENTS_ENTRY,
    Segments,
    chain,
    check_rows,
    check_rows_directory,
    is_digest,
    link_error,
    locked,
    open_rows_directory,
    parse_segments,
    remove_leftovers,
    rows_directory,
    seed,
    segment_name,
    segments_json,
)

__all__ = [
    "FORMAT",
    "ROWS_FORMAT",
    "VERSION",
    "STATE_FINGERPRINT",
    "CheckpointError",
    "CheckpointWriteError",
    "Segments",
    "Checkpoint",
    "save",
    "load",
    "exists",
    "rows_directory",
    "check_links",
]

FORMAT = "lobattodae-checkpoint"
VERSION = 13

# schema_fingerprint(<the loop's State templates>) for the current VERSION: the States of constant
# steps and of error control together; a test asserts the two agree, so that changing the State
# without bumping VERSION (and updating this constant) fails.  None: not recorded yet.
STATE_FINGERPRINT: str | None = "e0416ba094e06351"  # schema_fingerprint of the States (constant, PI) of VERSION

_STATE = "state/"
_ROWS = "rows/"
_HEADER_KEYS = ("__format__", "__version__", "meta", "counters", SEGMENTS_ENTRY)
_SEGMENT_KEYS = ("__format__", "__version__", "segment")


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


class Checkpoint(NamedTuple):
    """What :func:`load` returns."""

    counters: dict  # str -> int | float
    state: Any  # the state pytree, JAX arrays
    rows: dict  # field name -> all its rows (numpy)
    segments: Segments  # for the next save of the resumed run


# --------------------------------------------------------------------------------------------
# writing


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
    :class:`TypeError` before anything is written, a symbolic link at ``path`` or at its rows
    directory :class:`CheckpointError` (:func:`check_links`); I/O errors (:class:`OSError`)
    propagate, leaving the previous checkpoint usable.
    """
    target = os.fspath(path)
    payload: dict[str, np.ndarray] = {
        "__format__": np.asarray(FORMAT),
        "__version__": np.asarray(VERSION, dtype=np.int64),
        "meta": np.asarray(json.dumps(dict(meta), sort_keys=True, allow_nan=True)),
        "counters": np.asarray(_counters_json(counters)),
    }
    named, _ = named_leaves(state)
    for name, leaf in named:
        payload[_STATE + name] = _plain_array(leaf, _STATE + name)
    new, fields = check_rows(rows, previous)
    if previous is None:
        run = secrets.token_hex(16)
        files, head, counts = (), seed(run), (0,) * len(fields)
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
        head = chain(head, index, fields, new)
        segment = segment_name(index, head)
        files = files + (segment,)
    counts = tuple(count + len(new[name]) for count, (name, _, _) in zip(counts, fields))
    payload[SEGMENTS_ENTRY] = np.asarray(segments_json(run, len(files), head, fields, counts))

    directory = rows_directory(target)
    check_links(target)
    try:
        os.mkdir(directory)  # not makedirs: a missing directory of ``path`` is the caller's error
    except FileExistsError:
        pass
    with open_rows_directory(target, directory) as dir_fd, locked(directory, dir_fd):
        if segment is not None:
            atomic.write_npz(os.path.join(directory, segment), segment_payload)
        atomic.write_npz(target, payload)
        if previous is None or not previous.tidy:
            remove_leftovers(directory, files, dir_fd)
    return Segments(run, files, head, fields, counts, tidy=True)


def check_links(path: str | os.PathLike) -> None:
    """Refuse (:class:`CheckpointError`, naming it) a checkpoint ``path`` or rows directory that
    is a symbolic link; :func:`save` calls it, and a caller may call it before the work
    (nothing there yet is fine)."""
    if os.path.islink(path):
        shown = display(path)
        raise checkpoint_error(
            shown,
            f"cannot use the checkpoint '{shown}': it is a symbolic link, and a save renames a new file over the "
            "checkpoint, which would replace the link, not the file it points to. Give the file's real path, or "
            "choose another checkpoint path.",
        )
    check_rows_directory(path)


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


# --------------------------------------------------------------------------------------------
# reading


def exists(path: str | os.PathLike) -> bool:
    """Whether anything is at ``path`` (a file, a directory, even a dangling symlink).

    Deliberately broader than "a valid checkpoint": whatever sits there, :func:`load` either
    reads it or says clearly why it cannot, instead of a run silently starting afresh.
    """
    return os.path.lexists(os.fspath(path))


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
    shown = display(path)
    target = os.fspath(path)
    with open_archive(target, shown) as r:
        counters, state, stored = _load_from(r, meta, state_template, row_names)
    rows, segments = _load_rows(target, shown, stored, row_names)
    return Checkpoint(counters, state, rows, segments)


def _version_error(path: str, version: int) -> CheckpointError:
    age = "an older" if version < VERSION else "a newer"
    return checkpoint_error(
        path,
        f"checkpoint '{path}' has checkpoint format version {version} (written by {age} lobattodae), "
        f"but this lobattodae reads and writes version {VERSION}; {RESTART}.",
    )


def _same_json(a: Any, b: Any) -> bool:
    # == makes 1 and 1.0 equal; the canonical text makes NaN equal to NaN.
    return a == b or json.dumps(a, sort_keys=True) == json.dumps(b, sort_keys=True)


def _check_format_and_version(r: Reader) -> None:
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


def _legacy_version(r: Reader) -> int | None:
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


def _load_from(r: Reader, meta: Mapping[str, Any], state_template: Any, row_names: Sequence[str]):
    _check_format_and_version(r)

    expected = json.loads(json.dumps(dict(meta), sort_keys=True))
    saved = r.json_dict("meta")
    diff = sorted(k for k in set(saved) | set(expected)
                  if k not in saved or k not in expected or not _same_json(saved[k], expected[k]))
    if diff:
        raise checkpoint_error(
            r.path,
            f"checkpoint '{r.path}' belongs to a different run (differs in: {', '.join(diff)}); "
            "resume with the same problem, method, args, t_span, step and initial values, or delete it.",
        )

    counters = r.json_dict("counters")
    for key, value in counters.items():
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise r.corrupt(f"counter {key!r} is not a number")

    named, treedef = named_leaves(state_template)
    wanted = set(_HEADER_KEYS) | {_STATE + n for n, _ in named}
    stored = parse_segments(r) if r.has(SEGMENTS_ENTRY) else None
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
        dtype, shape = leaf_dtype_shape(leaf)
        arr = r.array(key)
        if arr.shape != shape:
            raise r.corrupt(f"entry {key!r} has shape {arr.shape}, expected {shape}")
        if not np.can_cast(arr.dtype, dtype, casting="safe"):
            raise r.corrupt(f"entry {key!r} has dtype {arr.dtype}, expected {dtype}")
        leaves.append(jnp.asarray(arr.astype(dtype, copy=False)))
    state = jtu.tree_unflatten(treedef, leaves)
    return counters, state, stored


def _read_segment(r: Reader, run: str, index: int, fields) -> tuple[str, dict[str, np.ndarray]]:
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
            or not is_digest(previous)):
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
        raise link_error(shown, shown_directory)
    parts: dict[str, list[np.ndarray]] = {name: [] for name, _, _ in fields}
    files = []
    digest = head
    for index in range(count - 1, -1, -1):
        name = segment_name(index, digest)
        part = f"row segment '{os.path.join(shown_directory, name)}'"
        with open_archive(os.path.join(directory, name), shown, part) as r:
            previous, arrays = _read_segment(r, run, index, fields)
        if chain(previous, index, fields, arrays) != digest or (index == 0 and previous != seed(run)):
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
            raise checkpoint_error(shown, corrupt_message(
                shown, f"its segments hold {len(arr)} rows of {name!r}, its 'segments' entry says {total}"))
        rows[name] = arr
    segments = Segments(run, tuple(files[::-1]), head, fields, counts)
    return {name: rows[name] for name in row_names}, segments
