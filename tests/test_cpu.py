"""The CPU thread-pool setting (lobattodae._cpu): validation, timing, and its effect."""

import os
import subprocess
import sys
import textwrap

import pytest

import lobattodae as L
from lobattodae import _cpu

from helpers import subprocess_env

POOL_THREADS = """
import collections, os
def pool_threads():
    names = collections.Counter(open(f"/proc/self/task/{t}/comm").read().strip() for t in os.listdir("/proc/self/task"))
    return sum(v for k, v in names.items() if "XLAEigen" in k)
"""

needs_proc = pytest.mark.skipif(not os.path.isdir("/proc/self/task"), reason="counts threads through Linux's /proc")


def _python(code, **env):
    out = subprocess.run([sys.executable, "-c", textwrap.dedent(code)], env=subprocess_env(**env),
                         capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    return out.stdout.split()


@pytest.mark.parametrize("bad", [0, -2, 1.5, True, "1", None])
def test_set_cpu_threads_rejects_what_is_not_a_positive_integer(bad):
    with pytest.raises(ValueError, match="positive integer"):
        L.set_cpu_threads(bad)


def test_set_cpu_threads_after_the_backend_started_says_it_is_too_late(monkeypatch):
    import jax.numpy as jnp

    jnp.zeros(1).block_until_ready()  # this process's backend has started
    monkeypatch.setenv(_cpu.THREADS_ENV, "5")
    with pytest.raises(RuntimeError, match=r"too late.*PJRT_NPROC=5.*PJRT_NPROC=2"):
        L.set_cpu_threads(2)
    assert os.environ[_cpu.THREADS_ENV] == "5"
    L.set_cpu_threads(5)  # what it already is: nothing to do, no error


def test_one_thread_unless_set_leaves_a_started_backend_alone(monkeypatch):
    import jax.numpy as jnp

    jnp.zeros(1).block_until_ready()
    monkeypatch.delenv(_cpu.THREADS_ENV, raising=False)
    monkeypatch.delenv("NPROC", raising=False)
    _cpu.one_thread_unless_set()
    assert _cpu.THREADS_ENV not in os.environ


@needs_proc
@pytest.mark.parametrize("n", [1, 3])
def test_set_cpu_threads_sizes_xla_cpu_pool(n):
    """Called after ``import jax`` and ``import lobattodae`` but before the first computation,
    it decides how many threads XLA's CPU pool gets."""
    out = _python(POOL_THREADS + f"""
import jax.numpy as jnp, lobattodae as L
L.set_cpu_threads({n})
jnp.zeros(1).block_until_ready()
print(pool_threads())
""")
    assert out == [str(n)]


@needs_proc
def test_command_line_uses_one_thread_unless_told_otherwise():
    run = POOL_THREADS + """
from lobattodae import _cli
code = _cli.main(["run", "--example", "knife-edge", "--n-steps", "20", "--no-progress"])
print(code, pool_threads())
"""
    assert _python(run, LOBATTODAE_NO_CACHE="1")[-2:] == ["0", "1"]
    assert _python(run, LOBATTODAE_NO_CACHE="1", NPROC="3")[-2:] == ["0", "3"]


def test_cpu_pool_size_reads_the_variables_in_jaxlib_order(monkeypatch):
    monkeypatch.setenv("PJRT_NPROC", "3")
    monkeypatch.setenv("NPROC", "7")
    assert _cpu.cpu_pool_size() == 3
    monkeypatch.setenv("PJRT_NPROC", "not a number")
    assert _cpu.cpu_pool_size() == 7
    monkeypatch.delenv("PJRT_NPROC")
    monkeypatch.delenv("NPROC")
    assert _cpu.cpu_pool_size() == len(os.sched_getaffinity(0))
