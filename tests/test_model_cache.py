"""Models kept across processes (lobattodae.mechanics._model_cache): from_lagrangian restores
what it derived for the same inputs, and only for the same inputs."""

import os
import subprocess
import sys

import jax.numpy as jnp
import numpy as np
import pytest
import sympy as sp
from sympy.physics.mechanics import dynamicsymbols

from lobattodae.mechanics import _builders, _model_cache, from_lagrangian

T = sp.Symbol("t")


@pytest.fixture
def cache(tmp_path, monkeypatch):
    """The model cache on, in a directory of the test's own (the suite runs with it off)."""
    monkeypatch.delenv("LOBATTODAE_NO_CACHE", raising=False)
    monkeypatch.setenv("LOBATTODAE_CACHE_DIR", str(tmp_path))
    return tmp_path / "models"


def _inputs(mass):
    """A rolling disk on a rod: one nonholonomic and one holonomic constraint, a force."""
    x, y, th, ph = dynamicsymbols("x y theta phi")
    r, k = sp.symbols("r k", positive=True)
    v = [c.diff(T) for c in (x, y, th, ph)]
    lagrangian = mass * (v[0] ** 2 + v[1] ** 2) / 2 + v[2] ** 2 / 4 + r**2 * v[3] ** 2 / 2 - k * y**2 / 2
    constraints = {"rolling": v[0] - r * sp.cos(th) * v[3], "pin": y - sp.sin(th)}
    return lagrangian, [x, y, th, ph], constraints


def _build(mass=sp.Symbol("m", positive=True)):
    lagrangian, coords, constraints = _inputs(mass)
    return from_lagrangian(lagrangian, coords, T, nonholonomic={"rolling": constraints["rolling"]},
                           holonomic={"pin": constraints["pin"]},
                           forces={coords[3]: sp.Symbol("tau")}, name="cached", defaults={"k": 2.0})


def _same_functions(a, b):
    rng = np.random.default_rng(0)
    q, p, lam = (jnp.asarray(rng.standard_normal(n)) for n in (4, 4, 2))
    args = a.args(m=1.3, r=0.4, tau=0.2)
    for name in ("f", "g", "phi"):
        fa, fb = getattr(a.problem, name), getattr(b.problem, name)
        inputs = (0.3, q, p, lam, args) if name == "g" else (0.3, q, p, args)
        np.testing.assert_array_equal(fa(*inputs), fb(*inputs))


def test_a_model_is_restored_for_the_same_inputs(cache, monkeypatch):
    first = _build()
    assert len(list(cache.glob("*.pkl"))) == 1

    def derive(*args, **kwargs):
        raise AssertionError("derived again although kept")

    monkeypatch.setattr(_builders, "_derive", derive)
    second = _build()
    assert second is not first and second.source == first.source
    for attr in ("name", "parameters", "defaults", "constraint_labels", "coordinate_names", "n", "m", "n_holonomic"):
        assert getattr(second, attr) == getattr(first, attr)
    assert second.symbolic == first.symbolic
    _same_functions(first, second)
    args = second.args(m=1.0, r=0.5, tau=0.0)
    np.testing.assert_allclose(second.holonomic_residual(0.0, [0.0, 0.0, 0.0, 0.0], args), 0.0)


def test_other_inputs_are_derived_again(cache):
    _build()
    _build(mass=sp.Symbol("m"))  # the same names, other assumptions on a parameter
    _build()
    assert len(list(cache.glob("*.pkl"))) == 2
    # a dict's order is the constraints' (and multipliers') order: part of the key
    keys = {_model_cache.model_key("from_lagrangian", {"nonholonomic": dict(order)})
            for order in ((("a", 1), ("b", 2)), (("b", 2), ("a", 1)))}
    assert len(keys) == 2


def test_a_damaged_entry_is_derived_again_and_rewritten(cache):
    first = _build()
    (entry,) = cache.glob("*.pkl")
    entry.write_bytes(b"not a pickle")
    second = _build()
    _same_functions(first, second)
    assert entry.read_bytes() != b"not a pickle"


def test_switched_off_or_unwritable_leaves_nothing(tmp_path, monkeypatch):
    monkeypatch.setenv("LOBATTODAE_CACHE_DIR", str(tmp_path))
    monkeypatch.setenv("LOBATTODAE_NO_CACHE", "1")
    _build()
    assert not (tmp_path / "models").exists()
    monkeypatch.delenv("LOBATTODAE_NO_CACHE")
    blocker = tmp_path / "file"
    blocker.write_text("")
    monkeypatch.setenv("LOBATTODAE_CACHE_DIR", str(blocker))  # models/ cannot be created under a file
    assert _build().n == 4


def test_a_new_process_restores_the_model(cache):
    """The point of the cache: a second interpreter finds the model without deriving it."""
    script = (
        "import sys, sympy as sp\n"
        "from lobattodae.mechanics import _builders, systems\n"
        "def refuse(*a, **k):\n"
        "    raise SystemExit('derived')\n"
        "if sys.argv[1] == 'second':\n"
        "    _builders._derive = refuse\n"
        "print(systems.knife_edge().source[-60:])\n"
    )
    env = {k: v for k, v in os.environ.items() if k != "LOBATTODAE_NO_CACHE"}
    env["LOBATTODAE_CACHE_DIR"] = str(cache.parent)
    outputs = [subprocess.run([sys.executable, "-c", script, which], capture_output=True, text=True, env=env,
                              timeout=300) for which in ("first", "second")]
    assert [o.returncode for o in outputs] == [0, 0], outputs[1].stderr[-2000:]
    assert outputs[0].stdout == outputs[1].stdout


def test_bad_input_gets_the_builders_error_with_the_cache_on(cache):
    """The key is computed before anything is checked: a bad input still meets from_lagrangian's
    own message, and nothing is kept for it."""
    from lobattodae import LobattoDAEInputError

    x, y = dynamicsymbols("x y")
    with pytest.raises(LobattoDAEInputError, match="not quadratic in the velocities"):
        from_lagrangian(x.diff(T) ** 4 + y.diff(T) ** 2, [x, y], T, nonholonomic=[x.diff(T) - y.diff(T)])
    with pytest.raises(LobattoDAEInputError, match="no constraints"):
        from_lagrangian(x.diff(T) ** 2 + y.diff(T) ** 2, [x, y], T)
    assert not cache.exists() or not list(cache.glob("*.pkl"))
