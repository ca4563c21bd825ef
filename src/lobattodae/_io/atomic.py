"""The one atomic writer of lobattodae's files: checkpoints and ensemble blocks.

:func:`write_npz` writes an uncompressed ``.npz`` archive so that whoever opens ``target`` finds
either the file that was there before or the complete new one, never a part of it, even if the
process is killed or the machine loses power in the middle:

1. a fresh temporary file ``.<name>.<random>.tmp`` is created in the target's directory with
   :func:`tempfile.mkstemp` (``O_CREAT | O_EXCL``, and ``O_NOFOLLOW`` where it exists), so no
   existing file or symbolic link is ever opened, followed or overwritten; it is given the mode a
   plain ``open`` would give (``0o666 & ~umask``) instead of mkstemp's ``0o600``;
2. the arrays are written (:func:`numpy.savez`), flushed and fsynced (:func:`os.fsync`);
3. the temporary file is renamed over ``target`` (:func:`os.replace`, atomic on POSIX and Windows);
4. the directory is fsynced, so that the rename itself survives a power loss (best effort: not
   every platform can open a directory).

On any failure before the rename, ``KeyboardInterrupt`` included, the temporary file is removed
and ``target`` is left as it was; a name left by a process that died in between is recognised by
:func:`is_temporary`, for the owner of the directory to clean up.

A symbolic link at ``target`` is refused: the rename would replace the link with a file, and the
file it points to would silently stop being updated. The check precedes the write, so a link made
between the two is replaced, never followed: nothing is ever written through a link.
"""

from __future__ import annotations

import contextlib
import errno
import os
import tempfile
from collections.abc import Mapping

import numpy as np

__all__ = ["write_npz", "is_temporary"]

_TEMPORARY_SUFFIX = ".tmp"


def write_npz(target: str | os.PathLike, arrays: Mapping[str, np.ndarray]) -> None:
    """Write ``arrays`` to ``target`` as an uncompressed ``.npz``, atomically and durably.

    Parameters
    ----------
    target : str or os.PathLike
        The file to create or replace; its directory must exist.
    arrays : mapping of str to numpy.ndarray
        The archive's members, written in this order (as :func:`numpy.savez` keyword arguments).

    Raises
    ------
    OSError
        ``errno.ELOOP`` if ``target`` is a symbolic link (nothing is written); any error of the
        file system (a full disk, a read-only directory), after which ``target`` is unchanged and
        no temporary file is left.
    """
    target = os.fspath(target)
    if os.path.islink(target):
        raise OSError(errno.ELOOP, f"cannot write '{os.fsdecode(target)}': it is a symbolic link, and lobattodae "
                                   "replaces files, never links; remove the link or give the file's real path")
    directory, name = os.path.split(target)
    fd, temporary = tempfile.mkstemp(prefix=f".{name}.", suffix=_TEMPORARY_SUFFIX, dir=directory or None)
    try:
        with os.fdopen(fd, "wb") as fh:
            mode = _default_file_mode()
            if mode is not None and hasattr(os, "fchmod"):
                os.fchmod(fh.fileno(), mode)
            np.savez(fh, **arrays)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(temporary, target)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(temporary)
        raise
    _fsync_directory(directory or os.curdir)


def _fsync_directory(directory: str | os.PathLike) -> None:
    """Make the renames in ``directory`` durable (best effort: a platform that cannot open or
    fsync a directory is left alone)."""
    try:
        fd = os.open(directory, os.O_RDONLY | getattr(os, "O_DIRECTORY", 0))
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def is_temporary(name: str) -> bool:
    """Whether the file name ``name`` is one of :func:`write_npz`'s temporary files."""
    return name.startswith(".") and name.endswith(_TEMPORARY_SUFFIX)


def _default_file_mode() -> int | None:
    """``0o666 & ~umask``, the mode of a file made by ``open``, read without changing the umask
    (which would race with other threads); None where ``/proc`` does not say."""
    try:
        with open("/proc/self/status", encoding="ascii") as fh:
            for line in fh:
                if line.startswith("Umask:"):
                    return 0o666 & ~int(line.split()[1], 8)
    except (OSError, ValueError, IndexError):
        pass
    return None
