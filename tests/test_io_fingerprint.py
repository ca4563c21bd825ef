"""Fingerprints (lobattodae._io.fingerprint): short, stable digests of what a saved run
depends on: the loop state's schema, arrays, and the problem's functions."""

import functools
import os
import re
import subprocess
import sys
import textwrap
from dataclasses import dataclass
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from lobattodae._io import checkpoint as C
from lobattodae._io import fingerprint as F

from helpers import Stepper, Y, make_state


def test_state_fields_are_dotted_names():
    assert F.state_fields(make_state(n=4)) == [
        ("y.q", "float64", (4,)),
        ("y.p", "float64", (4,)),
        ("stepper.jacobian.inverse", "float64", (4, 4)),
        ("stepper.jacobian.valid", "bool", ()),
        ("stepper.slopes", "float64", (2, 4)),
        ("step", "int32", ()),
    ]
    struct = jax.ShapeDtypeStruct((4,), jnp.float64)
    assert F.state_fields(Y(struct, np.zeros(2, np.int32))) == [("q", "float64", (4,)), ("p", "int32", (2,))]


class StateWithExtra(NamedTuple):
    y: Y
    stepper: Stepper
    step: Any
    extra: Any


class RenamedState(NamedTuple):
    y: Y
    stepper: Stepper
    steps: Any


def test_schema_fingerprint():
    fp = F.schema_fingerprint(make_state(n=3))
    assert re.fullmatch(r"[0-9a-f]{16}", fp)
    assert F.schema_fingerprint(make_state(n=3)) == fp
    assert F.schema_fingerprint(make_state(n=7)) == fp  # sizes are not part of the schema
    s = make_state()
    changed = [
        RenamedState(s.y, s.stepper, s.step),  # renamed field
        StateWithExtra(s.y, s.stepper, s.step, jnp.zeros(3)),  # added field
        s._replace(step=jnp.asarray(17, jnp.int64)),  # dtype
        s._replace(step=jnp.asarray([17], jnp.int32)),  # rank
        s._replace(y=s.y._replace(p=s.stepper.slopes)),  # rank of one field
        Y(s.y.q, s.y.p),  # removed fields
    ]
    fps = {F.schema_fingerprint(t) for t in changed}
    assert fp not in fps and len(fps) == len(changed)
    assert C.STATE_FINGERPRINT is None or re.fullmatch(r"[0-9a-f]{16}", C.STATE_FINGERPRINT)


def test_fingerprint_arrays():
    a, b = np.arange(3.0), {"k": np.int32(2), "v": (1.5, jnp.ones(2))}
    fp = F.fingerprint_arrays(a, b)
    assert re.fullmatch(r"[0-9a-f]{64}", fp)
    assert F.fingerprint_arrays(np.arange(3.0), {"k": np.int32(2), "v": (1.5, jnp.ones(2))}) == fp
    assert F.fingerprint_arrays(jnp.arange(3.0), b) == fp  # numpy and JAX arrays alike
    different = [
        (a + np.array([0, 0, 1e-12]), b),  # values
        (a.astype(np.float32), b),  # dtype
        (a.reshape(1, 3), b),  # shape
        (a,),  # fewer arguments
        ((a, b),),  # grouping
        (np.array([-0.0, 1.0, 2.0]), b),  # bit-exact
    ]
    for args in different:
        assert F.fingerprint_arrays(*args) != fp
    with pytest.raises(TypeError, match="cannot fingerprint"):
        F.fingerprint_arrays(object())


def square(x):
    return x * x


def test_fingerprint_callable_basics():
    f = lambda x: x + 1  # noqa: E731
    g = lambda x: x + 2  # noqa: E731
    h = lambda x: x * 2  # noqa: E731
    assert F.fingerprint_callable(f) == F.fingerprint_callable(f)
    assert len({F.fingerprint_callable(fn) for fn in (f, g, h)}) == 3
    fp = F.fingerprint_callable(square)
    assert fp.startswith(__name__ + ".square#") and re.fullmatch(r".*#[0-9a-f]{16}", fp)
    for _ in range(2000):  # the interpreter specialises hot bytecode; the fingerprint must not change
        square(3.0)
    assert F.fingerprint_callable(square) == fp


def test_fingerprint_callable_sees_closures_defaults_and_nested_code():
    def make(k):
        return lambda x: x + k

    assert F.fingerprint_callable(make(1.0)) == F.fingerprint_callable(make(1.0))
    assert F.fingerprint_callable(make(1.0)) != F.fingerprint_callable(make(2.0))

    def outer1(x):
        def inner(y):
            return y + 1
        return inner(x)

    def outer2(x):
        def inner(y):
            return y + 2
        return inner(x)

    assert outer1.__code__.co_code == outer2.__code__.co_code
    assert F.fingerprint_callable(outer1).split("#")[1] != F.fingerprint_callable(outer2).split("#")[1]

    def with_default(x, c=1.0):
        return x * c

    fp = F.fingerprint_callable(with_default)
    with_default.__defaults__ = (2.0,)
    assert F.fingerprint_callable(with_default) != fp


@dataclass(frozen=True)
class Problem:
    f: Any
    g: Any
    name: str = "p"


def test_fingerprint_callable_of_objects():
    f1 = lambda q: -q  # noqa: E731
    f2 = lambda q: q  # noqa: E731
    p1, p2 = Problem(f1, square), Problem(f2, square)
    assert F.fingerprint_callable(p1) == F.fingerprint_callable(Problem(f1, square))
    assert F.fingerprint_callable(p1) != F.fingerprint_callable(p2)
    assert F.fingerprint_callable(p1) != F.fingerprint_callable(Problem(f1, square, name="q"))
    assert F.fingerprint_callable(p1).startswith(__name__ + ".Problem#")

    part = functools.partial(square, 2.0)
    assert F.fingerprint_callable(part) == F.fingerprint_callable(functools.partial(square, 2.0))
    assert F.fingerprint_callable(part) != F.fingerprint_callable(functools.partial(square, 3.0))
    assert F.fingerprint_callable(jax.jit(square)) == F.fingerprint_callable(jax.jit(square))
    assert F.fingerprint_callable(np.sin) != F.fingerprint_callable(np.cos)

    def rec(n):  # recursion through a closure must terminate
        return 1 if n == 0 else n * rec(n - 1)

    F.fingerprint_callable(rec)


def test_fingerprint_callable_is_stable_across_processes(tmp_path):
    """No hash randomisation (frozenset constants, dict order) leaks into the fingerprint."""
    script = tmp_path / "fp.py"
    script.write_text(textwrap.dedent("""
        from lobattodae._io.fingerprint import fingerprint_callable, fingerprint_arrays

        def f(x, mode="a"):
            return x if mode in {"a", "b", "c", "d", "e", "f", "g"} else -x

        print(fingerprint_callable(f), fingerprint_arrays({"b": 1.0, "a": 2}))
    """))
    procs = [
        subprocess.Popen([sys.executable, str(script)], stdout=subprocess.PIPE, text=True, cwd=tmp_path,
                         env=dict(os.environ, PYTHONHASHSEED=str(seed), JAX_PLATFORMS="cpu"))
        for seed in (1, 2)
    ]
    outs = [p.communicate(timeout=60)[0] for p in procs]
    assert all(p.returncode == 0 for p in procs)
    assert outs[0] == outs[1] and outs[0].startswith("__main__.f#")
