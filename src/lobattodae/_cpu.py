"""The size of XLA's CPU thread pool (opt-in; one thread is fastest for small systems).

XLA:CPU runs a compiled program as a graph of small kernels and hands kernels that could run
concurrently to its thread pool. A step of lobattodae is a long chain of tiny kernels
(systems of 10 to 100 unknowns), so the hand-offs cost more than the concurrency gains: with
a one-thread pool a step runs 1.5–2.1× faster on the 2-core test machine (falling disk 2.0×),
and a ``jax.vmap`` batch 1.1× (``benchmarks/cpu_threads.py``, ``benchmarks/RESULTS.md``). jaxlib reads the
pool size from ``$PJRT_NPROC`` (else ``$NPROC``, else the number of CPUs) once, when JAX
creates its CPU backend at the process's first computation, so this is a process-wide
setting: it also slows large dense operations elsewhere in the process (a 2000×2000 matrix
product: 46 → 91 ms on the 2-core machine), which is why it is
not the default of the library (it is the default of the ``lobattodae`` command line).
Sharding over several forced CPU devices needs a larger pool (``docs/ensembles.md``).
"""

from __future__ import annotations

import os

__all__ = ["set_cpu_threads", "one_thread_unless_set", "cpu_pool_size", "THREADS_ENV"]

#: Read by jaxlib when it creates the CPU client (before ``NPROC``).
THREADS_ENV = "PJRT_NPROC"


def cpu_pool_size() -> int:
    """The threads of XLA's CPU pool as jaxlib sizes it: ``$PJRT_NPROC``, else ``$NPROC``
    (the first that is set to an integer; at least 1), else the CPUs this process may run on."""
    for name in (THREADS_ENV, "NPROC"):
        try:
            return max(1, int(os.environ.get(name, "")))
        except ValueError:
            continue
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # pragma: no cover - not Linux
        return os.cpu_count() or 1


def _backend_started() -> bool:
    try:
        from jax._src import xla_bridge
    except ImportError:  # pragma: no cover - a JAX without this module: cannot tell
        return False
    started = getattr(xla_bridge, "backends_are_initialized", None)
    return bool(started()) if started is not None else False


def set_cpu_threads(n: int = 1) -> None:
    """Give XLA's CPU thread pool ``n`` threads (sets ``$PJRT_NPROC``).

    Call it before the process's first JAX computation (``import jax`` and ``import
    lobattodae`` are fine). ``n = 1`` is the fastest setting for single trajectories and
    ``vmap`` batches on CPU. The setting is process-wide: it slows large dense computations
    elsewhere in the same process (``docs/getting-started.md``).

    Parameters
    ----------
    n : int
        Threads of XLA's CPU pool (default 1).

    Raises
    ------
    ValueError
        ``n`` is not a positive integer.
    RuntimeError
        JAX has already started its backends with a different setting: the pool cannot be
        resized any more. Call this first thing, or start Python with ``PJRT_NPROC=n``.
    """
    if isinstance(n, bool) or not isinstance(n, int) or n < 1:
        raise ValueError(f"n must be a positive integer (threads of XLA's CPU pool); got {n!r}.")
    if os.environ.get(THREADS_ENV) == str(n):
        return
    if _backend_started():
        raise RuntimeError(
            f"set_cpu_threads({n}) comes too late: JAX has already started its CPU backend with "
            f"{THREADS_ENV}={os.environ.get(THREADS_ENV, '(unset)')}. Call it before the first JAX "
            f"computation of the process, or start Python with {THREADS_ENV}={n}."
        )
    os.environ[THREADS_ENV] = str(n)


def one_thread_unless_set() -> None:
    """The command line's default: a one-thread pool, unless ``$PJRT_NPROC`` or ``$NPROC``
    says otherwise or JAX has already started (the command line called from Python)."""
    if not any(os.environ.get(k) for k in (THREADS_ENV, "NPROC")) and not _backend_started():
        os.environ[THREADS_ENV] = "1"
