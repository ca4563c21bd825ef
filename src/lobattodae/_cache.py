"""The persistent compilation cache (JAX's on-disk cache of compiled XLA executables).

On by default since 2026-11-27 (issue #26): ``import lobattodae`` switches it on in a user
cache directory (:func:`default_cache_dir`) for compilations of at least
:data:`DEFAULT_MIN_COMPILE_TIME` seconds (lobattodae's step loops take seconds; small jitted
functions of the user's own are not stored), at most :data:`DEFAULT_MAX_SIZE` bytes (least
recently used entries are evicted; JAX needs the ``filelock`` package for the bound, without it
the cache is unbounded). Measured: the first result of a new process on the knife
edge (s = 4, adaptive) 6.0-6.3 s without, 2.0-2.4 s with a warm cache (2 loaded cores).
Off with ``LOBATTODAE_NO_CACHE=1``; left alone when the process has configured JAX's own cache
directory; silently off when the directory cannot be created."""

from __future__ import annotations

import os
from pathlib import Path

import jax

__all__ = ["enable_compilation_cache", "enable_default_cache", "default_cache_dir", "cache_switched_off"]

#: Environment variable naming the cache directory (used by the CLI and as the default here).
CACHE_ENV = "LOBATTODAE_CACHE_DIR"
#: Set to 1 to keep ``import lobattodae`` and the CLI from using the cache.
NO_CACHE_ENV = "LOBATTODAE_NO_CACHE"
#: The default cache stores compilations that took at least this long (JAX's own default), unless
#: the user set JAX's own variable for it (:data:`MIN_COMPILE_TIME_ENV`).
DEFAULT_MIN_COMPILE_TIME = 1.0
MIN_COMPILE_TIME_ENV = "JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS"
#: The default cache's size bound in bytes (JAX evicts the least recently used entries).
DEFAULT_MAX_SIZE = 1 << 30
#: File name suffixes of a JAX cache entry and of its access time (``jax._src.lru_cache``).
_CACHE_SUFFIX, _ATIME_SUFFIX = "-cache", "-atime"


def cache_switched_off() -> bool:
    """True when ``LOBATTODAE_NO_CACHE`` is set to anything but ``""`` or ``"0"``."""
    return os.environ.get(NO_CACHE_ENV, "") not in ("", "0")


def default_cache_dir() -> Path:
    """``$LOBATTODAE_CACHE_DIR``, else ``$XDG_CACHE_HOME/lobattodae`` (``~/.cache/lobattodae``)."""
    if os.environ.get(CACHE_ENV):
        return Path(os.environ[CACHE_ENV]).expanduser()
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "lobattodae"


def enable_compilation_cache(directory: str | os.PathLike | None = None, *, min_compile_time: float = 0.0,
                             max_size: int = DEFAULT_MAX_SIZE) -> Path:
    """Keep compiled step loops on disk, so that a new process skips XLA compilation.

    A ``solve`` compiles its step loop on the first call for each problem, method and shape
    (most of the first call's time is XLA compilation; measured on the
    [benchmarks page](../benchmarks/index.md)); later calls in the same process reuse it.
    With the cache on, a *new* process loads the executable from disk instead (what remains
    is tracing). This switches on JAX's persistent compilation cache for the whole process
    (``jax_compilation_cache_dir``). ``import lobattodae`` already does (compilations of a
    second or more, at most 1 GiB, in the user cache directory; every compilation in
    ``$LOBATTODAE_CACHE_DIR`` when that is set); call this to choose the directory or to
    store every entry, however fast it compiled (the ``lobattodae`` command line does; both
    bounded to 1 GiB by default).
    ``LOBATTODAE_NO_CACHE=1`` keeps the library and the command line from switching it on.

    Parameters
    ----------
    directory : path, optional
        Where to keep the cache (created if missing); default ``$LOBATTODAE_CACHE_DIR``, else
        ``$XDG_CACHE_HOME/lobattodae`` (``~/.cache/lobattodae``).
    min_compile_time : float
        Store only compilations that took at least this many seconds (0: every one).
    max_size : int
        Bound on the cache's size in bytes, least recently used entries evicted (default 1 GiB;
        -1: none, for a directory of its own: JAX keeps no access times without a bound, and a
        bounded process sharing the directory then cannot evict). JAX needs the ``filelock``
        package for the bound; without it the bound is dropped (-1).

    Returns
    -------
    Path
        The cache directory.

    Raises
    ------
    ValueError
        The directory cannot be created.
    """
    path = Path(directory).expanduser() if directory is not None else default_cache_dir()
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ValueError(
            f"cannot create the compilation cache directory {str(path)!r} ({exc}); "
            f"pass a writable directory or set {CACHE_ENV}."
        ) from exc
    jax.config.update("jax_compilation_cache_dir", str(path))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", float(min_compile_time))
    jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)
    if max_size >= 0 and not _have_filelock():  # JAX bounds the size only with the filelock package
        max_size = -1
    if max_size >= 0:
        _add_missing_access_times(path)
    jax.config.update("jax_compilation_cache_max_size", int(max_size))
    return path


def _add_missing_access_times(path: Path) -> None:
    """Give every entry of a bounded cache the access-time file JAX's eviction reads.

    JAX's bounded cache keeps ``<key>-cache`` and ``<key>-atime`` (8 bytes, little-endian
    nanoseconds) per entry; an unbounded one writes no ``-atime``. An entry without one (left by
    an unbounded process in the same directory) makes every later eviction fail, and JAX warns
    at every cache write. Such entries get their file's modification time as access time."""
    try:
        names = set(os.listdir(path))
        for name in names:
            if name.endswith(_CACHE_SUFFIX) and name[: -len(_CACHE_SUFFIX)] + _ATIME_SUFFIX not in names:
                stamp = (path / name).stat().st_mtime_ns
                (path / (name[: -len(_CACHE_SUFFIX)] + _ATIME_SUFFIX)).write_bytes(stamp.to_bytes(8, "little"))
    except OSError:  # a cache we cannot tidy stays as it is: JAX only warns
        pass


def _have_filelock() -> bool:
    import importlib.util

    return importlib.util.find_spec("filelock") is not None


def enable_default_cache() -> Path | None:
    """What ``import lobattodae`` does: the cache on in the user cache directory (compilations of
    DEFAULT_MIN_COMPILE_TIME seconds or more, or as long as ``$JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS``
    says where the user set it; DEFAULT_MAX_SIZE bytes at most), or in
    ``$LOBATTODAE_CACHE_DIR`` for every compilation when that is set; nothing when
    ``LOBATTODAE_NO_CACHE`` is set or JAX's cache directory is already configured. Returns the
    directory, or None where the cache stays off (an unwritable default directory too)."""
    if cache_switched_off() or jax.config.jax_compilation_cache_dir:
        return None
    if os.environ.get(CACHE_ENV):  # the user chose the directory (an unwritable one is an error), and
        return enable_compilation_cache(os.environ[CACHE_ENV])  # everything is kept, as the CLI does
    min_time = DEFAULT_MIN_COMPILE_TIME
    if os.environ.get(MIN_COMPILE_TIME_ENV):  # the user's choice, read by JAX at its import
        min_time = float(jax.config.jax_persistent_cache_min_compile_time_secs)
    try:
        return enable_compilation_cache(min_compile_time=min_time, max_size=DEFAULT_MAX_SIZE)
    except ValueError:
        return None
