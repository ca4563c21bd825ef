"""Ensemble block files: one ``.npz`` per block of trajectories, that cannot lie.

:func:`lobattodae.ensemble` with ``out_dir`` writes each block of trajectories to its own file
``ensemble-p<process, 5 digits>-b<block, 6 digits>.npz`` (:func:`file_name`), and
:func:`lobattodae.load_ensemble` reads them back. A block file is an uncompressed ``.npz`` with
the entries

``meta``      0-d unicode string: JSON of the run's identity and settings (``format``
              :data:`FILE_FORMAT`, ``version`` :data:`FILE_VERSION`, the problem's and args'
              fingerprints, ...) and of the block (``run``, ``block_digest``, ``block``,
              ``start``, ``stop``, the process, ...);
``index``     int64, the block's trajectories' positions in the global batch;
``q``, ``p``, ``lam``, ``status`` and, for error-controlled runs, ``t``, ``n_rows``,
``n_steps``, ``n_rejected``, ``n_roundoff_limited``: the results, trajectory-major;
``digests``   0-d unicode string: JSON ``{entry: SHA-256 of its name, dtype, shape and C-order
              bytes}`` for every other entry.

Every block is written by the library's one atomic writer
(:func:`lobattodae._io.atomic.write_npz`: a unique temporary file, fsynced, renamed over the
block's name, the directory fsynced). Every array read is checked against its digest, so a
bit flip, or a block rewritten with valid zip CRCs, is refused (:class:`EnsembleFileError`,
naming the file) and recomputed by ``if_exists="resume"`` (:func:`resumable`, with a warning).
Only regular files are opened: a FIFO or directory named like a block is refused, never waited
on. Version 2 added ``digests``, version 3 ``n_roundoff_limited``; files of other versions are
refused with the version named.
"""

from __future__ import annotations

import glob
import hashlib
import json
import os
import re
import stat
import warnings
import zipfile
from collections.abc import Sequence
from typing import BinaryIO

import numpy as np

from .._errors import LobattoDAEInputError
from . import atomic
from .archive import Reader, read_npy, stored_members

__all__ = [
    "FILE_FORMAT",
    "FILE_VERSION",
    "FILE_GLOB",
    "EnsembleFileError",
    "file_name",
    "block_files",
    "own_files",
    "block_digest",
    "write_block",
    "read_block",
    "read_meta",
    "resumable",
    "not_regular_error",
]

#: The ``format`` in the ``meta`` of every block file.
FILE_FORMAT = "lobattodae-ensemble"
#: 2: every file has a ``digests`` entry (SHA-256 of each array); version 1 files had none.
#: 3: error-controlled runs save ``n_roundoff_limited``.
FILE_VERSION = 3
#: The names of block files, as a :mod:`glob` pattern.
FILE_GLOB = "ensemble-p*-b*.npz"

_FILE_RE = re.compile(r"^ensemble-p(\d+)-b(\d+)\.npz$")
#: Everything NumPy's and zipfile's readers may raise on a damaged file.
_READ_ERRORS = Reader.ERRORS  # everything parsing a damaged or foreign archive may raise


class EnsembleFileError(LobattoDAEInputError):
    """An ensemble file cannot be used: unreadable, damaged (an array does not match the digest
    written with it), not a regular file, or of another format or version.

    Attributes
    ----------
    path : str
        The file.
    """

    def __init__(self, message: str, path: str | None = None):
        super().__init__(message)
        self.path = path


def file_name(process: int, block: int) -> str:
    """The name of one block's file: ``ensemble-p<process, 5 digits>-b<block, 6 digits>.npz``."""
    return f"ensemble-p{process:05d}-b{block:06d}.npz"


def block_files(directory: str) -> list[str]:
    """The block files of every process in ``directory``, sorted."""
    paths = sorted(glob.glob(os.path.join(glob.escape(directory), FILE_GLOB)))
    return [p for p in paths if _FILE_RE.match(os.path.basename(p))]


def own_files(out_dir: str, process: int) -> list[str]:
    """The block files of the process ``process`` in ``out_dir``, sorted."""
    return sorted(glob.glob(os.path.join(glob.escape(out_dir), f"ensemble-p{process:05d}-b*.npz")))


def block_digest(run_digest: str, a: int, b: int, block_inputs: Sequence[np.ndarray]) -> str:
    """SHA-256 of the run, the block's trajectories ``a .. b-1`` and their inputs: a block file
    with this ``block_digest`` in its meta holds exactly this block's results."""
    h = hashlib.sha256(f"{run_digest}:{a}:{b}:".encode())
    for x in block_inputs:
        x = np.ascontiguousarray(x)
        h.update(f"{x.dtype.str}:{x.shape}:".encode())
        h.update(x.tobytes())
    return h.hexdigest()


def write_block(path: str, arrays: dict) -> None:
    """Write ``arrays`` and their digests (the entry ``digests``) to ``path``, atomically and
    durably (:func:`lobattodae._io.atomic.write_npz`)."""
    arrays = {name: np.asarray(x) for name, x in arrays.items()}
    digests = {name: _array_digest(name, x) for name, x in arrays.items()}
    atomic.write_npz(path, {**arrays, "digests": np.asarray(json.dumps(digests, sort_keys=True))})


def read_block(path: str, names: Sequence[str] | None = None) -> tuple[dict, dict]:
    """``(meta, arrays)`` of one block file, each array read checked against its digest:
    ``names`` (default: all of them) besides ``meta``. Raises :class:`EnsembleFileError`."""
    with _open_regular(path) as fh:
        try:
            with zipfile.ZipFile(fh) as zf:  # each member read by read_npy: no header's sizes trusted
                members = stored_members(zf, os.fstat(fh.fileno()).st_size)
                files = set(members)
                if "meta" not in files:
                    raise _file_error(path, "is not a lobattodae ensemble file (no 'meta' entry)",
                                      "remove it from the directory")
                raw_meta = read_npy(zf.read(members["meta"]))
                meta = json.loads(str(raw_meta))
                if not isinstance(meta, dict) or meta.get("format") != FILE_FORMAT:
                    raise _file_error(path, "is not a lobattodae ensemble file (format "
                                      f"{meta.get('format') if isinstance(meta, dict) else None!r})",
                                      "remove it from the directory")
                if meta.get("version") != FILE_VERSION:
                    raise _file_error(path, f"was written in ensemble file version {meta.get('version')!r}; this "
                                      f"lobattodae reads version {FILE_VERSION}", "run the ensemble again")
                if "digests" not in files:
                    raise _file_error(path, "is damaged: it has no 'digests' entry")
                digests = json.loads(str(read_npy(zf.read(members["digests"]))))
                if not isinstance(digests, dict) or set(digests) != files - {"digests"}:
                    raise _file_error(path, "is damaged: its 'digests' entry does not list its arrays")
                arrays = {"meta": raw_meta}
                for name in (sorted(digests) if names is None else names):
                    if name not in arrays:
                        if name not in files:
                            raise _file_error(path, f"is damaged: it has no entry {name!r}")
                        arrays[name] = read_npy(zf.read(members[name]))
                for name, x in arrays.items():
                    if _array_digest(name, x) != digests[name]:
                        raise _file_error(path, f"is damaged: its entry {name!r} does not match the digest "
                                          "written with it")
        except EnsembleFileError:
            raise
        except _READ_ERRORS as exc:  # json.JSONDecodeError is a ValueError
            raise _file_error(path, f"is damaged or cannot be read as an ensemble file ({type(exc).__name__}: "
                              f"{exc})") from exc
    del arrays["meta"]
    return meta, arrays


def read_meta(path: str) -> dict:
    """The ``meta`` of one block file, its digest checked."""
    return read_block(path, ())[0]


def resumable(path: str, digest: str) -> int | None:
    """The number of failed trajectories in the block file ``path`` if it is complete, intact
    (every array matches its digest) and of this run (``digest``); else None: computed again.
    A file that cannot be used is named in a warning; one that is not a regular file is refused."""
    try:
        meta, arrays = read_block(path)
    except EnsembleFileError as exc:
        if os.path.exists(path) and not os.path.isfile(path):  # not a regular file: never replaced
            raise
        what = exc.args[0].split("; ")[0]  # the file and what is wrong with it, without the fix
        warnings.warn(f"{what}; with if_exists='resume' the block is computed again and the file replaced.",
                      RuntimeWarning, stacklevel=2)
        return None
    if meta.get("block_digest") != digest or "status" not in arrays:  # another run's block
        return None
    return int(np.count_nonzero(arrays["status"] != 0))


def not_regular_error(path: str, mode: int) -> EnsembleFileError:
    """The error for a block's path that holds something other than a regular file (``mode``:
    its :attr:`os.stat_result.st_mode`)."""
    return EnsembleFileError(f"ensemble file '{path}' is not a regular file ({_kind(mode)}); remove it or use "
                             "another out_dir.", path)


def _array_digest(name: str, x: np.ndarray) -> str:
    """SHA-256 of one array of a block file: its name, dtype, shape and C-order bytes."""
    x = np.ascontiguousarray(x)
    h = hashlib.sha256(f"{FILE_FORMAT}:{name}:{x.dtype.str}:{x.shape}:".encode())
    h.update(x.tobytes())
    return h.hexdigest()


def _file_error(path: str, what: str, fix: str = "delete it and run that block again (if_exists='resume' "
                                                 "recomputes missing blocks)") -> EnsembleFileError:
    return EnsembleFileError(f"ensemble file '{path}' {what}; {fix}.", path)


def _kind(mode: int) -> str:
    for test, name in ((stat.S_ISDIR, "a directory"), (stat.S_ISFIFO, "a FIFO (named pipe)"),
                       (stat.S_ISSOCK, "a socket"), (stat.S_ISCHR, "a character device"),
                       (stat.S_ISBLK, "a block device")):
        if test(mode):
            return name
    return "not a plain file"


def _open_regular(path: str) -> BinaryIO:
    """``path`` opened for reading if it is a regular file (a FIFO would block ``open`` until a
    writer comes); anything else raises :class:`EnsembleFileError`."""
    try:
        info = os.stat(path)
    except OSError as exc:
        raise _file_error(path, f"cannot be read ({type(exc).__name__}: {exc})") from exc
    if not stat.S_ISREG(info.st_mode):
        raise not_regular_error(path, info.st_mode)
    # O_NONBLOCK: should it have become a FIFO since, open() returns at once (and fstat refuses it)
    flags = os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_CLOEXEC", 0) | getattr(os, "O_BINARY", 0)
    try:
        fd = os.open(path, flags)
    except OSError as exc:
        raise _file_error(path, f"cannot be read ({type(exc).__name__}: {exc})") from exc
    mode = os.fstat(fd).st_mode
    if not stat.S_ISREG(mode):
        os.close(fd)
        raise not_regular_error(path, mode)
    return os.fdopen(fd, "rb")
