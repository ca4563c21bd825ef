"""The XLA options of the library's programs (``lobattodae._compile``)."""

import jax
import jax.numpy as jnp
import pytest

import lobattodae as L
from lobattodae import _compile


@pytest.fixture
def fresh_probe():
    _compile._supported.cache_clear()
    yield
    _compile._supported.cache_clear()


def test_options_are_those_of_the_library_on_this_xla():
    assert L.compiler_options() == _compile.COMPILER_OPTIONS


def test_an_option_set_in_xla_flags_is_left_to_the_user(monkeypatch):
    monkeypatch.setenv("XLA_FLAGS", "--xla_cpu_use_fusion_emitters=true")
    assert "xla_cpu_use_fusion_emitters" not in L.compiler_options()


def test_the_wrapper_compiles_with_the_options(monkeypatch):
    # an option XLA does not know makes the compilation fail: so the wrapper passes them on
    monkeypatch.setattr(_compile, "compiler_options", lambda: {"xla_no_such_option_here": True})
    fn = _compile.jit(lambda x: 2.0 * x)
    with pytest.raises(Exception, match="xla_no_such_option_here"):
        fn(jnp.ones(3))


def test_an_xla_without_the_options_compiles_with_its_defaults(monkeypatch, fresh_probe):
    monkeypatch.setattr(_compile, "COMPILER_OPTIONS", {"xla_no_such_option_here": True})
    assert L.compiler_options() == {}
    fn = _compile.jit(lambda x, k: k * x, static_argnums=1)
    assert float(fn(jnp.ones(()), 3)) == 3.0
    assert fn.lower(jnp.ones(()), 3).compile() is not None


def test_inside_a_trace_the_call_joins_the_enclosing_program(monkeypatch):
    # JAX refuses options on a nested jit; inside jit, vmap and grad the plain jit is used
    monkeypatch.setattr(_compile, "compiler_options", lambda: {"xla_no_such_option_here": True})
    fn = _compile.jit(lambda x: jnp.sin(x) * x)
    x = jnp.linspace(0.0, 1.0, 3)
    expected = jnp.sin(x) * x
    assert jnp.allclose(jax.jit(fn)(x), expected)
    assert jnp.allclose(jax.vmap(fn)(x), expected)
    assert jnp.allclose(jax.vmap(jax.grad(fn))(x), jnp.cos(x) * x + jnp.sin(x))
