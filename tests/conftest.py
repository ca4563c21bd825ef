"""Test configuration and the fixtures shared by several test files (functions and constants
are in ``helpers.py``).

The hypothesis profiles: the default ("ci") is derandomized, so every run draws the same cases,
CI is reproducible and a failure seen once is seen again. Random exploration is one variable
away:

    HYPOTHESIS_PROFILE=explore .venv/bin/python -m pytest tests/test_property.py

draws fresh cases on every run (and test_property.py draws 5x as many); a failure it finds should become a
deterministic regression test.

The example fixtures are module-scoped: built once per test file (``make test`` runs whole files
per process), and JAX's caches are emptied after each file.
"""

import os
import sys
import uuid

import jax
import pytest
from hypothesis import settings

import lobattodae as L
from lobattodae._chunks import CHUNK
from lobattodae.examples import get_example

from helpers import MODEL_SOURCE, RUN_STAGES, RUN_STEPS, Pendulum, cli_method

settings.register_profile("ci", derandomize=True, database=None, deadline=None)
settings.register_profile("explore", derandomize=False, database=None, deadline=None)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "ci"))

# The CLI switches on JAX's persistent compilation cache for its process; tests call
# ``main([...])`` in-process, so keep it off here (tests/test_cli.py checks it in a subprocess).
os.environ.setdefault("LOBATTODAE_NO_CACHE", "1")


@pytest.fixture(autouse=True, scope="module")
def _empty_jax_caches_after_each_module():
    """Compiled programs of a module are not kept alive for the rest of the run: the suite
    compiles hundreds of loops (gradients, ensembles, every example and s), and a full run in
    one process once crashed inside XLA's compiler late in the run (a segmentation fault in a
    compile that passes on its own; 2026-11-23)."""
    yield
    jax.clear_caches()


# -- the examples -----------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def knife():
    return get_example("knife-edge")


@pytest.fixture(scope="module")
def sleigh():
    return get_example("sleigh")


@pytest.fixture(scope="module")
def particle():
    return get_example("particle")


@pytest.fixture(scope="module")
def contact():
    return get_example("contact")


@pytest.fixture(scope="module")
def pendulum():
    """The Cartesian pendulum (``helpers.Pendulum``; needs SymPy)."""
    pytest.importorskip("sympy")
    return Pendulum()


# -- the command line -------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def particle_direct():
    """The run of ``lobattodae run --example particle --stages RUN_STAGES --n-steps RUN_STEPS``, by
    ``solve`` (compiled as ``run`` compiles it)."""
    ex = get_example("particle")
    sol = L.solve(ex.problem, cli_method(RUN_STAGES), ex.t_span, ex.q0, ex.p0,
                  n_steps=RUN_STEPS, args=ex.args, chunk_size=CHUNK)
    assert sol.success
    return ex, sol


@pytest.fixture
def model_module(tmp_path, monkeypatch):
    """A module of model factories in a temporary directory, the current directory of the test
    (``lobattodae run --model NAME:FACTORY`` imports it from there, as ``python -m`` would)."""
    name = f"usermodels_{uuid.uuid4().hex[:10]}"
    (tmp_path / f"{name}.py").write_text(MODEL_SOURCE)
    (tmp_path / f"{name}_broken.py").write_text("import missing_dependency_xyz\n")
    (tmp_path / f"{name}_syntax.py").write_text("def f(:\n")
    monkeypatch.chdir(tmp_path)
    yield name
    for key in [k for k in sys.modules if k.startswith(name)]:
        del sys.modules[key]
    assert str(tmp_path) not in sys.path  # the CLI took the directory off sys.path again
