"""Opt-in persistent compilation cache (JAX's on-disk cache of compiled XLA executables)."""

from __future__ import annotations

import os
from pathlib import Path

import jax

__all__ = ["enable_compilation_cache", "default_cache_dir", "cache_switched_off"]

#: Environment variable naming the cache directory (used by the CLI and as the default here).
CACHE_ENV = "LOBATTODAE_CACHE_DIR"
#: Set to 1 to keep the CLI from using the cache.
NO_CACHE_ENV = "LOBATTODAE_NO_CACHE"


def cache_switched_off() -> bool:
    """True when ``LOBATTODAE_NO_CACHE`` is set to anything but ``""`` or ``"0"``."""
    return os.environ.get(NO_CACHE_ENV, "") not in ("", "0")


def default_cache_dir() -> Path:
    """``$LOBATTODAE_CACHE_DIR``, else ``$XDG_CACHE_HOME/lobattodae`` (``~/.cache/lobattodae``)."""
    if os.environ.get(CACHE_ENV):
        return Path(os.environ[CACHE_ENV]).expanduser()
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "lobattodae"


def enable_compilation_cache(directory: str | os.PathLike | None = None) -> Path:
    """Keep compiled step loops on disk, so that a new process skips XLA compilation.

    A ``solve`` compiles its step loop on the first call for each problem, method and shape
    (seconds on a small CPU, most of it XLA compilation; ``benchmarks/RESULTS.md``); later
    calls in the same process reuse it. With the cache on, a *new* process loads the
    executable from disk instead (what remains is tracing). This switches on JAX's persistent compilation cache for the
    whole process (``jax_compilation_cache_dir``), for every entry however fast it compiled.
    The ``lobattodae`` command line uses it unless ``LOBATTODAE_NO_CACHE=1``; ``import
    lobattodae`` calls it when ``LOBATTODAE_CACHE_DIR`` is set (no code change needed).

    Parameters
    ----------
    directory : path, optional
        Where to keep the cache (created if missing); default :func:`default_cache_dir`.

    Returns
    -------
    Path
        The cache directory.
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
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
    jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)
    return path
