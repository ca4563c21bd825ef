"""The row segments of a checkpoint: their chain of digests, their names and their directory.

The format is described in :mod:`lobattodae._io.checkpoint`; this module holds what concerns the
rows alone:

* the **chain** (:func:`seed`, :func:`chain`) that ties every segment to the main file that
  lists it, and the segment's file name (:func:`segment_name`), which follows its digest;
* the ``segments`` entry of the main file (:func:`segments_json`, :func:`parse_segments`) and
  the :class:`Segments` record a save hands to the next;
* the **rows directory** ``<path>.rows`` (:func:`rows_directory`), never used through a symbolic
  link: :func:`check_rows_directory` refuses one, and a save locks (:func:`locked`), lists and
  cleans (:func:`remove_leftovers`) it through a handle opened without following links
  (:func:`open_rows_directory`), so no file is ever deleted through a link.
"""

from __future__ import annotations

import contextlib
import dataclasses
import errno
import hashlib
import json
import os
import re
from collections.abc import Iterator, Mapping, Sequence
from typing import Any

import numpy as np

from .archive import CheckpointError, Reader, checkpoint_error, display
from .atomic import is_temporary

try:
    import fcntl
except ImportError:  # pragma: no cover - not on Windows: saves are not locked there
    fcntl = None

__all__ = [
    "ROWS_FORMAT",
    "Segments",
    "rows_directory",
    "check_rows_directory",
    "link_error",
    "open_rows_directory",
    "locked",
    "remove_leftovers",
    "seed",
    "chain",
    "segment_name",
    "check_rows",
    "is_digest",
    "SEGMENTS_ENTRY",
    "segments_json",
    "parse_segments",
]

#: ``__format__`` of a row segment file.
ROWS_FORMAT = "lobattodae-checkpoint-rows"
#: Row fields hold numbers: booleans, integers, floats, complex numbers.
_ROW_KINDS = "biufc"

#: The main file's entry that lists the committed segments.
SEGMENTS_ENTRY = "segments"

_ROWS_SUFFIX = ".rows"
#: A segment file's name: its index and the first 16 hex digits of its chain digest.
_SEGMENT_NAME = re.compile(r"[0-9]{6,}-[0-9a-f]{16}\.npz")
_RUN = re.compile(r"[0-9a-f]{32}")
_DIGEST = re.compile(r"[0-9a-f]{64}")
#: Sanity bounds on what a file may claim: the size of an axis, the rank of a row field.
_MAX_DIM = 2**40
_MAX_RANK = 31
#: Whether the rows directory can be listed and cleaned through a handle opened without following links.
_DIR_FD = (
    hasattr(os, "O_DIRECTORY") and hasattr(os, "O_NOFOLLOW") and os.unlink in os.supports_dir_fd
    and os.scandir in os.supports_fd
)

Field = tuple[str, str, tuple[int, ...]]


@dataclasses.dataclass(frozen=True)
class Segments:
    """The rows a checkpoint on disk holds, as :func:`~lobattodae._io.checkpoint.save` and
    :func:`~lobattodae._io.checkpoint.load` return them: pass it to the next save of the same
    path, which then writes only the new rows.

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
    fields: tuple[Field, ...]
    counts: tuple[int, ...]
    tidy: bool = False


def rows_directory(path: str | os.PathLike) -> str:
    """The sidecar directory of the checkpoint ``path`` that holds its row segments: ``<path>.rows``."""
    return os.fsdecode(os.fspath(path)) + _ROWS_SUFFIX


# --------------------------------------------------------------------------------------------
# the chain


def seed(run: str) -> str:
    """``d₋₁``: the chain digest before the first segment of the run ``run``."""
    return hashlib.sha256(f"{ROWS_FORMAT}:{run}".encode()).hexdigest()


def chain(previous: str, index: int, fields: Sequence[Field], arrays: Mapping[str, np.ndarray]) -> str:
    """``d_i`` from ``d_{i-1}``, the index and the rows of segment ``i`` (C-order bytes)."""
    h = hashlib.sha256(f"{previous}:{index}".encode())
    for name, _, _ in fields:
        arr = np.ascontiguousarray(arrays[name])
        h.update(f"|{name}|{arr.dtype.str}|{arr.shape}|".encode())
        h.update(arr.data)
    return h.hexdigest()


def segment_name(index: int, digest: str) -> str:
    """The file name of segment ``index`` whose chain digest is ``digest``."""
    return f"{index:06d}-{digest[:16]}.npz"


# --------------------------------------------------------------------------------------------
# the rows of a save and the ``segments`` entry of the main file


def _describe_fields(fields: Sequence[Field]) -> str:
    return ", ".join(f"{name} {np.dtype(dtype).name} (k{''.join(f', {d}' for d in shape)})"
                     for name, dtype, shape in fields)


def check_rows(rows: Mapping[str, Any],
               previous: Segments | None) -> tuple[dict[str, np.ndarray], tuple[Field, ...]]:
    """The new rows of a save as arrays, and the fields they continue.

    Raises
    ------
    TypeError
        ``rows`` is not a dict of arrays of numbers with a row axis, or (with ``previous``) its
        fields are not those of the checkpoint: the same names, dtypes and trailing shapes.
    """
    if not isinstance(rows, Mapping):
        raise TypeError(f"checkpoint rows must be a dict of arrays; got {type(rows).__name__}.")
    new: dict[str, np.ndarray] = {}
    for name, value in rows.items():
        if not isinstance(name, str) or not name:
            raise TypeError(f"checkpoint row names must be non-empty strings; got {name!r}.")
        arr = np.asarray(value)
        if arr.dtype.kind not in _ROW_KINDS:
            raise TypeError(f"checkpoint entry 'rows/{name}' is not a numeric array (dtype {arr.dtype}); "
                            "rows hold numbers and booleans.")
        if arr.ndim == 0:
            raise TypeError(f"checkpoint entry 'rows/{name}' is a 0-d array; rows need a first axis that "
                            "counts them.")
        new[name] = arr
    fields = tuple((name, arr.dtype.str, tuple(int(d) for d in arr.shape[1:])) for name, arr in new.items())
    if previous is not None:
        if sorted(fields) != sorted(previous.fields):
            raise TypeError("checkpoint rows must continue the checkpoint's fields "
                            f"({_describe_fields(previous.fields)}); got {_describe_fields(fields)}.")
        fields = previous.fields
    return new, fields


def segments_json(run: str, count: int, head: str, fields: Sequence[Field], counts: Sequence[int]) -> str:
    """The ``segments`` entry: the run, the committed segments, and per field its rows so far."""
    return json.dumps({
        "run": run, "count": count, "head": head,
        "fields": [{"name": name, "dtype": dtype, "shape": list(shape), "rows": rows}
                   for (name, dtype, shape), rows in zip(fields, counts)],
    })


def parse_segments(r: Reader) -> tuple[str, int, str, tuple[Field, ...], tuple[int, ...]]:
    """``(run, count, head, fields, counts)`` from the main file's ``segments`` entry, each checked."""
    value = r.json_dict(SEGMENTS_ENTRY)

    def malformed(what: str) -> CheckpointError:
        return r.corrupt(f"entry {SEGMENTS_ENTRY!r} is malformed ({what})")

    run, count, head, fields = (value.get(k) for k in ("run", "count", "head", "fields"))
    if not (isinstance(run, str) and _RUN.fullmatch(run)):
        raise malformed("run")
    if not _is_count(count):
        raise malformed("count")
    if not is_digest(head) or (count == 0 and head != seed(run)):
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


def is_digest(value: Any) -> bool:
    """Whether ``value`` is a chain digest (64 hex digits)."""
    return isinstance(value, str) and _DIGEST.fullmatch(value) is not None


def _is_count(value: Any) -> bool:
    return isinstance(value, int) and not isinstance(value, bool) and 0 <= value <= _MAX_DIM


def _row_dtype(text: Any) -> np.dtype | None:
    """The dtype a ``segments`` field names, if it is one that rows may have."""
    if not isinstance(text, str):
        return None
    try:
        dtype = np.dtype(text)
    except Reader.ERRORS:
        return None
    if dtype.kind not in _ROW_KINDS or dtype.shape != () or dtype.fields is not None or dtype.str != text:
        return None
    return dtype


# --------------------------------------------------------------------------------------------
# the rows directory


def link_error(path: str, directory: str) -> CheckpointError:
    """The error for the checkpoint ``path`` whose rows directory is a symbolic link."""
    return checkpoint_error(
        path,
        f"cannot use the checkpoint '{path}': its rows directory '{directory}' is a symbolic link, and "
        "lobattodae never writes, reads or deletes row segments through a link (a fresh save removes the "
        "segment files it finds there). Put the real directory at that path, or choose another checkpoint path.",
    )


def check_rows_directory(path: str | os.PathLike) -> None:
    """Refuse (:class:`CheckpointError`, naming it) a rows directory of the checkpoint ``path``
    that is a symbolic link (nothing there yet is fine)."""
    directory = rows_directory(path)
    if os.path.islink(directory):
        raise link_error(display(path), directory)


@contextlib.contextmanager
def open_rows_directory(path: str, directory: str) -> Iterator[int | None]:
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
            raise link_error(display(path), directory) from None
        if exc.errno == errno.ENOTDIR:
            raise checkpoint_error(display(path), f"cannot write the checkpoint '{display(path)}': its rows go to "
                                                  f"the directory '{directory}', and something else is there; remove "
                                                  "it or choose another checkpoint path.") from None
        raise
    try:
        yield fd
    finally:
        os.close(fd)


@contextlib.contextmanager
def locked(directory: str, dir_fd: int | None = None) -> Iterator[None]:
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


def remove_leftovers(directory: str, keep: Sequence[str], dir_fd: int | None = None) -> None:
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
        if (_SEGMENT_NAME.fullmatch(name) is not None and name not in keep) or is_temporary(name):
            try:
                if dir_fd is None:
                    os.unlink(os.path.join(directory, name))
                else:
                    os.unlink(name, dir_fd=dir_fd)
            except OSError:
                pass
