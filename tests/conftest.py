"""Test configuration: hypothesis profiles; JAX's caches emptied after each test module.

The default profile ("ci") is derandomized: every run draws the same cases, so CI is
reproducible and a failure seen once is seen again. Random exploration is one variable away:

    HYPOTHESIS_PROFILE=explore .venv/bin/python -m pytest tests/test_property.py

draws fresh cases on every run (and test_property.py draws 5x as many); a failure it finds should become a
deterministic regression test.
"""

import os

import jax
import pytest
from hypothesis import settings

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
