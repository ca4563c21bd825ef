"""How lobattodae's programs are compiled: ``jax.jit`` with XLA options chosen for compile time.

A step of lobattodae is a program of a few hundred small kernels (fusions). XLA:CPU compiles
each fusion through its MLIR fusion emitters by default, which build a fresh MLIR context and
pass pipeline per kernel: for programs of many small kernels that setup, not the code, is most
of the compile time. XLA's older elemental emitters compile the same fusions in about half the
time and run them as fast (``benchmarks/RESULTS.md``, 2026-11-27 (night): an error-controlled
attempt on the sleigh 2.9 → 1.5 s to compile, 255 against 261 µs to run; the knife edge's first
result 6.3–7.1 → 3.7 s, Andrews' squeezer 18 → 12.5 s; run times of whole solves within 3 %).
So every program the library compiles is compiled with :data:`COMPILER_OPTIONS`:

* only where the installed XLA knows the options (checked once per process, at the first
  compilation): jax 0.10 does; the XLA of jax 0.11.2 has dropped the elemental emitters, and
  there the programs compile with XLA's defaults;
* not where the user chose for themselves: an option named in ``$XLA_FLAGS`` is left to it.

The options are per program: other programs of the process keep XLA's defaults. Users who
``jax.jit`` :func:`~lobattodae.integrate` or :func:`~lobattodae.integrate_adaptive` inside a
program of their own can pass ``compiler_options=lobattodae.compiler_options()`` to it.
"""

from __future__ import annotations

import functools
import os

import jax

__all__ = ["COMPILER_OPTIONS", "compiler_options", "jit"]

#: XLA options of every program the library compiles (see the module docstring).
COMPILER_OPTIONS = {"xla_cpu_use_fusion_emitters": False}


@functools.cache
def _supported() -> bool:
    """Whether this process's XLA accepts :data:`COMPILER_OPTIONS` (one tiny compilation)."""
    try:
        jax.jit(lambda x: x, compiler_options=dict(COMPILER_OPTIONS)).lower(0.0).compile()
    except Exception:  # noqa: BLE001 - an XLA without the options, or a jax.jit without the keyword
        return False
    return True


def compiler_options() -> dict:
    """The XLA options lobattodae compiles its programs with, for ``jax.jit(..., compiler_options=...)``.

    ``{"xla_cpu_use_fusion_emitters": False}`` (XLA:CPU's elemental emitters: about half the
    compile time for the many small kernels of a step, the same run time), without the options
    that ``$XLA_FLAGS`` sets, and empty where the installed XLA does not know them.

    Returns
    -------
    dict
        Option names to values; pass it as ``compiler_options`` of ``jax.jit`` when you compile
        a program that calls :func:`~lobattodae.integrate` or
        :func:`~lobattodae.integrate_adaptive`.
    """
    if not _supported():
        return {}
    flags = os.environ.get("XLA_FLAGS", "")
    return {k: v for k, v in COMPILER_OPTIONS.items() if k not in flags}


try:  # whether a call runs at the top level, not inside a trace (jit, vmap, grad)
    from jax._src.core import trace_state_clean as _top_level
except ImportError:  # pragma: no cover - other JAX internals: never pass the options
    def _top_level() -> bool:
        return False


class _Compiled:
    """``jax.jit(fn, **kwargs)``, compiled with :func:`compiler_options` when called at the top
    level. Inside a trace (the user's ``jit``, ``vmap`` or ``grad``) JAX refuses options on a
    nested ``jit``: the call goes to a plain ``jax.jit`` and becomes part of the enclosing
    program, compiled with that program's options. The options are decided at the first call,
    when the backend exists: deciding at import would start JAX's backend before the user
    could size its thread pool (:func:`~lobattodae.set_cpu_threads`)."""

    def __init__(self, fn, kwargs):
        self._fn, self._kwargs = fn, kwargs
        self._plain = jax.jit(fn, **kwargs)
        self._tuned = None
        functools.update_wrapper(self, fn)

    def _get(self):
        if not _top_level():
            return self._plain
        if self._tuned is None:
            options = compiler_options()
            self._tuned = jax.jit(self._fn, compiler_options=options, **self._kwargs) if options else self._plain
        return self._tuned

    def __call__(self, *args, **kwargs):
        return self._get()(*args, **kwargs)

    def lower(self, *args, **kwargs):
        return self._get().lower(*args, **kwargs)

    def _cache_size(self) -> int:
        """Programs compiled so far (what the tests of "no recompilation" count)."""
        tuned = 0 if self._tuned in (None, self._plain) else self._tuned._cache_size()
        return self._plain._cache_size() + tuned


def jit(fn=None, **kwargs):
    """``jax.jit`` with the library's :func:`compiler_options`; usable as a decorator, with or
    without keyword arguments (``static_argnums``, ``static_argnames``, ...)."""
    if fn is None:
        return functools.partial(jit, **kwargs)
    return _Compiled(fn, kwargs)
