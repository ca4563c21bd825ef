"""Models kept across processes: what :func:`~lobattodae.mechanics.from_lagrangian` derives, by its inputs.

Building a model is SymPy's work: the mass matrix, the constraints' coefficients and the
Euler–Lagrange terms by differentiation, then the JAX code written from them with common
subexpressions eliminated. It takes 0.1 s for the knife edge, about 1 s for Andrews' squeezer
(7 coordinates) and seconds for the Whipple bicycle, in every process that builds the model. So
:func:`~lobattodae.mechanics.from_lagrangian` keeps what it derived (the model's symbolic parts,
parameters and generated source) in ``<cache>/models`` (:func:`lobattodae.default_cache_dir`),
named by a hash of its inputs (every argument, written out by :func:`sympy.srepr`), of the
package's code that derives and writes models, and of the SymPy and Python versions; a later
process given the same inputs restores the model from there instead of deriving it again (its
functions by executing the kept source, which passed the generator's check when it was written:
:func:`~lobattodae.mechanics._codegen.load_module`).

Off with ``LOBATTODAE_NO_CACHE=1`` (as the compilation caches); an entry that cannot be read
or restored is derived again and rewritten; a directory that cannot be written is left alone.
Like the native libraries next to it, the directory is trusted: an entry is a pickle.
"""

from __future__ import annotations

import contextlib
import functools
import hashlib
import os
import pickle
import sys
import tempfile
from collections.abc import Mapping
from pathlib import Path

import numpy as np
import sympy as sp

from .._cache import cache_switched_off, default_cache_dir

__all__ = ["load", "model_key", "store"]

#: The package's modules whose code decides what a model is (a change to any of them is a new key).
_SOURCES = ("_builders.py", "_model.py", "_codegen.py", "_parsing.py", "_model_cache.py")


@functools.cache
def _generator() -> str:
    """A digest of the deriving code, SymPy's and Python's versions."""
    here = Path(__file__).parent
    digest = hashlib.sha256()
    for name in _SOURCES:
        digest.update((here / name).read_bytes())
    digest.update(f"{sp.__version__} {sys.version_info[:2]} {pickle.HIGHEST_PROTOCOL}".encode())
    return digest.hexdigest()


def _canonical(x) -> str:
    """A text that determines ``x``: SymPy objects by :func:`sympy.srepr` (names, assumptions and
    structure), mappings and sequences entry by entry in their order (a dict's order is the
    constraints' order), arrays by their entries, other values by ``repr``."""
    if isinstance(x, (sp.Basic, sp.MatrixBase)):
        return sp.srepr(x)
    if isinstance(x, Mapping):
        return "{" + ",".join(f"{_canonical(k)}:{_canonical(v)}" for k, v in x.items()) + "}"
    if isinstance(x, np.ndarray):
        return _canonical(x.tolist())
    if isinstance(x, (list, tuple)):
        return "[" + ",".join(_canonical(v) for v in x) + "]"
    return f"{type(x).__name__}:{x!r}"


def model_key(kind: str, inputs: Mapping) -> str | None:
    """The cache key of a model built by ``kind`` from ``inputs`` (None when the cache is off)."""
    if cache_switched_off():
        return None
    try:
        text = f"{_generator()}\0{kind}\0{_canonical(inputs)}"
    except Exception:  # noqa: BLE001 - inputs SymPy cannot write out: not kept (the builder judges them)
        return None
    return hashlib.sha256(text.encode()).hexdigest()[:32]


def _path(key: str) -> Path:
    return default_cache_dir() / "models" / f"{key}.pkl"


def load(key: str | None) -> dict | None:
    """The state stored under ``key``, or None (no key, no entry, or one that cannot be read)."""
    if key is None:
        return None
    try:
        with open(_path(key), "rb") as fh:
            state = pickle.load(fh)  # noqa: S301 - the user's own cache directory (see the module docstring)
    except Exception:  # noqa: BLE001 - missing, truncated, or from an incompatible version: derive again
        return None
    return state if isinstance(state, dict) else None


def store(key: str | None, state: dict) -> None:
    """Write ``state`` under ``key`` atomically; nothing when the cache is off or cannot be written."""
    if key is None:
        return
    path, tmp = _path(key), None
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=path.parent, suffix=".tmp")
        with os.fdopen(fd, "wb") as fh:
            pickle.dump(state, fh, protocol=pickle.HIGHEST_PROTOCOL)
        os.replace(tmp, path)
    except Exception:  # noqa: BLE001 - a read-only or full disk, an unpicklable expression: not kept
        if tmp is not None:
            with contextlib.suppress(OSError):
                os.unlink(tmp)
