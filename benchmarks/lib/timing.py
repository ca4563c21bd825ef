"""The timer of the benchmarks, pinning to one CPU, and counting XLA compilations."""

from __future__ import annotations

import contextlib
import logging
import math
import os
import re
import time
from typing import Any, Callable, NamedTuple

import jax


class Timing(NamedTuple):
    """What :func:`best_of` measured.

    ``best``: the best wall time [s]; ``times``: every timed call's; ``cpu``: the process CPU
    time of the best call (wall ≫ CPU: other processes held the cores); ``result``: what the
    best call returned; ``first``: the wall time of the first, untimed-for-best call (compilation
    and run) when one was asked for, else None."""

    best: float
    times: list
    cpu: float
    result: Any
    first: float | None


def best_of(fn: Callable[[], Any], repeats: int = 3, *, limit: float = math.inf, first: bool = False) -> Timing:
    """The best of ``repeats`` calls of ``fn`` (at least one), each waited for with
    ``jax.block_until_ready``. A call longer than ``limit`` seconds ends the repeats (long
    benchmarks stay in their budget); ``first=True`` makes one call before the timed ones and
    reports its time apart (compilation)."""
    first_s = None
    if first:
        t0 = time.perf_counter()
        jax.block_until_ready(fn())
        first_s = time.perf_counter() - t0
    times, best, cpu, result = [], math.inf, math.nan, None
    for _ in range(max(1, repeats)):
        c0, t0 = time.process_time(), time.perf_counter()
        out = jax.block_until_ready(fn())
        dt, dc = time.perf_counter() - t0, time.process_time() - c0
        times.append(dt)
        if dt < best:
            best, cpu, result = dt, dc, out
        if dt > limit:
            break
    return Timing(best, times, cpu, result, first_s)


def pin_cpu(cpu: int | None) -> list[int]:
    """Runs this process (and the threads it starts later) on CPU ``cpu`` alone; None leaves
    the affinity as it is. Call it before the first JAX computation: XLA's threads inherit the
    affinity they are started with. Returns the CPUs the process may use."""
    if cpu is not None:
        os.sched_setaffinity(0, {cpu})
    return sorted(os.sched_getaffinity(0))


class _CompileLog(logging.Handler):
    _pattern = re.compile(r"Finished XLA compilation of (.*) in ([0-9.eE+-]+) sec")

    def __init__(self):
        super().__init__(level=logging.DEBUG)
        self.compiles: list[tuple[str, float]] = []
        self.traces = 0

    def emit(self, record):
        msg = record.getMessage()
        m = self._pattern.search(msg)
        if m:
            self.compiles.append((m.group(1), float(m.group(2))))
        elif msg.startswith("Finished tracing"):
            self.traces += 1

    def summary(self) -> dict:
        return {"xla_compilations": len(self.compiles),
                "xla_compile_s": round(sum(s for _, s in self.compiles), 4),
                "tracings": self.traces,
                "largest": [f"{n} {s:.2f}s" for n, s in sorted(self.compiles, key=lambda c: -c[1])[:3]]}


@contextlib.contextmanager
def count_compiles():
    """Counts the XLA compilations (and tracings) inside the block, through
    ``jax_log_compiles``; yields a handler whose ``summary()`` is a dict of them."""
    handler = _CompileLog()
    logger = logging.getLogger("jax")
    old_level, old_flag = logger.level, jax.config.jax_log_compiles
    logger.addHandler(handler)
    logger.setLevel(logging.DEBUG)
    jax.config.update("jax_log_compiles", True)
    try:
        yield handler
    finally:
        jax.config.update("jax_log_compiles", old_flag)
        logger.setLevel(old_level)
        logger.removeHandler(handler)
