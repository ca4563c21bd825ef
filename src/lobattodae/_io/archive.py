"""Reading one file of a checkpoint, its main file or a row segment, without trusting it.

Every failure is a :class:`CheckpointError` with one message that names the checkpoint, the
file (for a segment) and the reason, and says what to do; never a raw exception of
:mod:`zipfile` or NumPy. :func:`open_archive` refuses what is not a regular, non-empty zip
archive; :class:`Reader` refuses members that are not ``.npy``, repeated, compressed, encrypted or
larger than the file, and reads each member with its CRC checked.

A member is parsed by :func:`read_npy`: NumPy reads the ``.npy`` header
(:func:`numpy.lib.format.read_array_header_1_0` / ``_2_0``, at most :data:`MAX_NPY_HEADER`
bytes; version 3.0, which :func:`numpy.savez` writes only for non-Latin-1 field names, is
refused) and builds the array (:func:`numpy.lib.format.read_array`, ``allow_pickle=False``),
after two checks of ours: the dtype holds no Python objects, and the header's shape and dtype
account for exactly the bytes that follow it. ``np.load(..., allow_pickle=False)`` alone does
not do: it allocates what the header claims before reading (a 200-byte member claiming
``shape (2**40,)`` asks for 8 TiB and raises :class:`MemoryError`), and it ignores bytes after
the array.
"""

from __future__ import annotations

import contextlib
import io
import json
import math
import os
import stat
import struct
import zipfile
import zlib
from collections.abc import Iterator

import numpy as np

from .._errors import LobattoDAEInputError

__all__ = ["CheckpointError", "Reader", "open_archive", "read_npy", "checkpoint_error", "corrupt_message",
           "display", "RESTART", "MAX_NPY_HEADER"]

#: The largest ``.npy`` header read (NumPy's own default is 10,000 bytes).
MAX_NPY_HEADER = 100_000
#: What every message about a checkpoint that cannot be used ends with.
RESTART = "delete it or restart without resume"

_HEADER_READERS = {(1, 0): np.lib.format.read_array_header_1_0, (2, 0): np.lib.format.read_array_header_2_0}


class CheckpointError(LobattoDAEInputError):
    """A checkpoint file cannot be used to resume: corrupt, foreign, another version or run.

    Attributes
    ----------
    path : str
        The checkpoint file, as given.
    """


def checkpoint_error(path: str, message: str) -> CheckpointError:
    """A :class:`CheckpointError` about the checkpoint ``path``."""
    err = CheckpointError(message)
    err.path = path
    return err


def corrupt_message(path: str, reason: str) -> str:
    """The message for the checkpoint ``path`` that is corrupt or foreign for ``reason``."""
    return f"checkpoint '{path}' is corrupt or not a lobattodae checkpoint ({reason}); {RESTART}."


def _describe(exc: BaseException) -> str:
    """``"Type: message"`` of an exception, for a message about a file."""
    text = str(exc).strip()
    return f"{type(exc).__name__}: {text}" if text else type(exc).__name__


def display(path: str | os.PathLike) -> str:
    """A path as messages show it (never ``PosixPath(...)``)."""
    return os.fsdecode(os.fspath(path))


def read_npy(data: bytes) -> np.ndarray:
    """The array of one ``.npy`` member, without pickles and without trusting its header's sizes.

    Raises
    ------
    ValueError
        An unsupported ``.npy`` version, a header that is too long or malformed, Python objects,
        or a data size that is not the one the header's shape and dtype give (among the errors
        of :attr:`Reader.ERRORS` that NumPy's header reader may raise).
    """
    fp = io.BytesIO(data)
    version = np.lib.format.read_magic(fp)
    if version not in _HEADER_READERS:
        raise ValueError(f"unsupported .npy version {version}")
    shape, _, dtype = _HEADER_READERS[version](fp, max_header_size=MAX_NPY_HEADER)
    if dtype.hasobject:
        raise ValueError("it holds Python objects (pickled data)")
    size = len(data) - fp.tell()
    if size != math.prod(shape) * dtype.itemsize:
        raise ValueError(f"{size} data bytes for shape {shape} of {dtype}")
    fp.seek(0)
    return np.lib.format.read_array(fp, allow_pickle=False, max_header_size=MAX_NPY_HEADER)


def stored_members(zf: zipfile.ZipFile, file_size: int) -> dict[str, zipfile.ZipInfo]:
    """The ``.npy`` members of an archive as NumPy's ``savez`` writes them (stored, not compressed
    or encrypted, none larger than the file), by name without the suffix.

    Raises
    ------
    ValueError
        A member that is not a ``.npy`` file, a duplicate, a compressed or encrypted one, or one
        that claims more bytes than the file has (the reason is the message).
    """
    members: dict[str, zipfile.ZipInfo] = {}
    for info in zf.infolist():
        if not info.filename.endswith(".npy"):
            raise ValueError(f"unexpected archive member {info.filename!r}")
        key = info.filename[: -len(".npy")]
        if key in members:
            raise ValueError(f"duplicate entry {key!r}")
        if info.compress_type != zipfile.ZIP_STORED or info.flag_bits & 0x1:
            raise ValueError(f"entry {key!r} is compressed or encrypted")
        if info.file_size > file_size:
            raise ValueError(f"entry {key!r} is larger than the file")
        members[key] = info
    return members


class Reader:
    """The members of one checkpoint archive, read and checked one at a time; every failure is a
    :class:`CheckpointError` about the checkpoint ``path`` (``part``: which of its files, when not
    the main one)."""

    #: Everything parsing a damaged or foreign file may raise.
    ERRORS = (zipfile.BadZipFile, zipfile.LargeZipFile, OSError, EOFError, ValueError, KeyError, IndexError,
              TypeError, OverflowError, struct.error, zlib.error, NotImplementedError, RuntimeError, SyntaxError)

    def __init__(self, path: str, zf: zipfile.ZipFile, file_size: int, part: str | None = None):
        self.path = path
        self.part = part
        self.zf = zf
        try:
            self.members = stored_members(zf, file_size)
        except ValueError as exc:
            raise self.corrupt(str(exc)) from None

    def corrupt(self, reason: str) -> CheckpointError:
        """The error for a checkpoint that is corrupt for ``reason``."""
        where = f"{self.part}: {reason}" if self.part else reason
        return checkpoint_error(self.path, corrupt_message(self.path, where))

    def has(self, key: str) -> bool:
        """Whether the archive has the member ``key``."""
        return key in self.members

    def array(self, key: str) -> np.ndarray:
        """The member ``key``, its CRC checked (:func:`read_npy`)."""
        if key not in self.members:
            raise self.corrupt(f"missing entry {key!r}")
        try:
            return read_npy(self.zf.read(self.members[key]))  # zipfile verifies the CRC
        except self.ERRORS as exc:
            raise self.corrupt(f"entry {key!r} is damaged: {_describe(exc)}") from exc

    def text(self, key: str) -> str:
        """The member ``key``, a 0-d unicode string."""
        arr = self.array(key)
        if arr.ndim != 0 or arr.dtype.kind != "U":
            raise self.corrupt(f"entry {key!r} is not a string")
        return str(arr.item())

    def json_dict(self, key: str) -> dict:
        """The member ``key``, a string holding a JSON object."""
        raw = self.text(key)
        try:
            value = json.loads(raw)
        except (ValueError, RecursionError) as exc:
            raise self.corrupt(f"entry {key!r} is not valid JSON: {_describe(exc)}") from exc
        if not isinstance(value, dict):
            raise self.corrupt(f"entry {key!r} is not a JSON object")
        return value


@contextlib.contextmanager
def open_archive(target: str, shown: str, part: str | None = None) -> Iterator[Reader]:
    """A :class:`Reader` of the archive ``target``: the main file of the checkpoint ``shown``
    (``part`` None) or one of its segments (``part`` names it in messages)."""

    def corrupt(main_reason: str, part_reason: str) -> CheckpointError:
        return checkpoint_error(shown, corrupt_message(shown, f"{part} {part_reason}" if part else main_reason))

    def unreadable(exc: OSError) -> CheckpointError:
        if part:
            return corrupt("", f"cannot be read ({_describe(exc)})")
        return checkpoint_error(
            shown, f"checkpoint '{shown}' cannot be read ({_describe(exc)}); fix its permissions, {RESTART}.")

    try:
        info = os.stat(target)
    except FileNotFoundError as exc:
        if part:
            raise corrupt("", "is missing") from exc
        if os.path.islink(target):
            raise corrupt("it is a symbolic link to a missing file", "") from exc
        raise checkpoint_error(shown, f"checkpoint '{shown}' does not exist; check exists() before load().") from exc
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
        except Reader.ERRORS as exc:
            reason = f"not a readable .npz archive: {_describe(exc)}"
            raise corrupt(reason, f"is {reason}") from exc
        with zf:
            yield Reader(shown, zf, info.st_size, part)
