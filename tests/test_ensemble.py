"""Ensembles (issue #11): ``lobattodae.ensemble`` against ``jax.vmap`` of the entry points, on
one device (bit for bit) and on four forced CPU devices (round-off), blocks with padding,
streaming to ``.npz`` files and resuming, input errors, and two processes under
``jax.distributed`` (slow).

Ensemble files that cannot lie, and ensemble inputs checked as ``solve`` checks them (issue #30):

* Every block file carries a SHA-256 digest of each of its arrays: a bit flip inside a block, or
  a block rewritten with a valid zip CRC, is refused by :func:`load_ensemble` with an error that
  names the file, and recomputed (with a warning) by ``if_exists="resume"``; blocks are written
  by the checkpoint's atomic writer (unique temporary file, fsync, rename).
* ``lam0`` of the wrong width, badly batched ``args``, ``args=None``, a wrong ``controller``,
  ``t_eval`` or ``rtol`` that ``solve`` refuses, and inconsistent initial values raise our
  errors, naming the argument, before anything is compiled.

The pytest process has one CPU device; the multi-device runs are subprocesses with
``XLA_FLAGS=--xla_force_host_platform_device_count=4`` set before JAX is imported.
"""

import json
import os
import socket
import subprocess
import sys
import types
import warnings
import zipfile

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import lobattodae as L
from lobattodae import _ensemble, _ensemble_inputs
from lobattodae._io import atomic

#: Trajectories of the test batch: not a multiple of 2 or 4 devices, nor of the block size.
BATCH = 5
BLOCK = 2
N_STEPS = 20
H = 0.05
#: Sharded over several devices, XLA compiles a partitioned program whose rewrites differ in
#: the last bits from the one-device program (_ensemble.ensemble, "Reproducibility"); over
#: 20 steps the differences measured 2e-16 in q and p and 1.2e-14 in λ (|λ| ≈ 1).
ROUND_OFF = 1e-12
#: Wall-time limit of a subprocess (compilation on a busy 2-core machine included).
SUBPROCESS_TIMEOUT = 600
#: the runs of the tests of block files and inputs: 4 steps of three trajectories
SMALL_STEPS = 4


@pytest.fixture(scope="module")
def method():
    return L.LobattoIIIAIIIB(stages=2)


@pytest.fixture(scope="module")
def batch(knife):
    """BATCH consistent initial values (random headings and momenta, projected onto φ = 0) and a
    per-trajectory in-plane gravity g (λ0 is consistent with each trajectory's g)."""
    rng = np.random.default_rng(11)
    q0 = np.tile(knife.q0, (BATCH, 1))
    q0[:, 2] += 0.3 * rng.standard_normal(BATCH)
    p0 = knife.p0 + 0.2 * rng.standard_normal((BATCH, knife.p0.size))
    g = np.linspace(0.5, 1.5, BATCH)

    def consistent(q, p, g):
        args = knife.args._replace(g=g)
        jp = jax.jacfwd(lambda pp: knife.problem.phi(0.0, q, pp, args))(p)
        p = p - jp.T @ jnp.linalg.solve(jp @ jp.T, knife.problem.phi(0.0, q, p, args))
        return p, L.consistent_lambda(knife.problem, 0.0, q, p, jnp.zeros(1), args)

    p0, lam0 = jax.vmap(consistent)(jnp.asarray(q0), jnp.asarray(p0), jnp.asarray(g))
    return q0, np.asarray(p0), np.asarray(lam0), g


@pytest.fixture(scope="module")
def batched_args(knife, batch):
    return knife.args._replace(g=batch[3]), type(knife.args)(m=False, J=False, g=True)


@pytest.fixture(scope="module")
def reference(knife, method, batch):
    """Plain ``jax.vmap`` of ``integrate`` over the initial values and g: every row."""
    q0, p0, lam0, g = batch
    run = jax.vmap(lambda q, p, lam, g: L.integrate(knife.problem, method, 0.0, H, N_STEPS, q, p, lam,
                                                     knife.args._replace(g=g)))
    return jax.tree_util.tree_map(np.asarray, run(q0, p0, lam0, g))


@pytest.fixture(scope="module")
def final(knife, method, batch, batched_args):
    """The ensemble's final states on this process's one device, in blocks of BLOCK (the last padded)."""
    q0, p0, lam0, _ = batch
    args, flags = batched_args
    before = _ensemble._run_block._cache_size()
    result = L.ensemble(knife.problem, method, q0, p0, lam0, args, batch_args=flags, h=H, n_steps=N_STEPS,
                        block_size=BLOCK)
    return result, _ensemble._run_block._cache_size() - before


def test_one_device_is_bit_for_bit_vmap(final, reference):
    result, compilations = final
    assert compilations == 1  # three blocks (2, 2, 1 + 1 padding), one compiled program
    np.testing.assert_array_equal(result.index, np.arange(BATCH))
    for field in ("q", "p", "lam"):
        np.testing.assert_array_equal(getattr(result, field), getattr(reference, field)[:, -1])
    np.testing.assert_array_equal(result.status, reference.status)
    assert np.all(result.status == L.Result.SUCCESSFUL)
    assert result.t is None and result.n_steps is None  # constant steps: on the grid t0 + k h
    # the batched g matters: trajectories with another g end elsewhere
    assert np.max(np.abs(result.q[0] - result.q[-1])) > 1e-3


def test_new_numbers_do_not_recompile(knife, method, batch, batched_args, final):
    q0, p0, lam0, _ = batch
    args, flags = batched_args
    before = _ensemble._run_block._cache_size()
    again = L.ensemble(knife.problem, method, q0[::-1], p0[::-1], lam0[::-1], args._replace(g=args.g[::-1]),
                       batch_args=flags, t0=0.5, h=-H, n_steps=N_STEPS, block_size=BLOCK)
    assert _ensemble._run_block._cache_size() == before
    assert not np.array_equal(again.q, final[0].q)


def test_memory_mapped_inputs(knife, method, batch, batched_args, final, tmp_path):
    """Inputs may be memory maps (``ensemble`` reads one block of rows at a time)."""
    args, flags = batched_args
    maps = []
    for name, x in zip(("q0", "p0", "lam0", "g"), batch):
        np.save(tmp_path / f"{name}.npy", x)
        maps.append(np.load(tmp_path / f"{name}.npy", mmap_mode="r"))
    result = L.ensemble(knife.problem, method, *maps[:3], args._replace(g=maps[3]), batch_args=flags, h=H,
                        n_steps=N_STEPS, block_size=BLOCK)
    for field in ("q", "p", "lam", "status"):
        np.testing.assert_array_equal(getattr(result, field), getattr(final[0], field))


def test_streaming_files_resume_and_load(knife, method, batch, batched_args, final, tmp_path, monkeypatch):
    q0, p0, lam0, _ = batch
    args, flags = batched_args
    run = dict(batch_args=flags, h=H, n_steps=N_STEPS, block_size=BLOCK, out_dir=tmp_path)
    files = L.ensemble(knife.problem, method, q0, p0, lam0, args, **run)
    names = [os.path.basename(p) for p in files.paths]
    assert names == ["ensemble-p00000-b000000.npz", "ensemble-p00000-b000001.npz", "ensemble-p00000-b000002.npz"]
    assert (files.start, files.stop, files.n_failed, files.n_skipped) == (0, BATCH, 0, 0)
    loaded = L.load_ensemble(tmp_path)
    for field in ("index", "q", "p", "lam", "status"):
        np.testing.assert_array_equal(getattr(loaded, field), getattr(final[0], field))
    with np.load(files.paths[2]) as z:  # the last block: one trajectory (padded to BLOCK on the device)
        meta = json.loads(str(z["meta"]))
        assert (meta["start"], meta["stop"], meta["padded_block"], meta["n_devices"]) == (4, 5, 2, 1)
        np.testing.assert_array_equal(z["index"], [4])

    with pytest.raises(L.LobattoDAEInputError, match="already holds 3 ensemble file.*if_exists='overwrite'"):
        L.ensemble(knife.problem, method, q0, p0, lam0, args, **run)

    # resume: complete blocks of the same run are kept, nothing is integrated ...
    def no_run(*a, **k):
        raise AssertionError("a complete block was integrated again")

    with monkeypatch.context() as patch:
        patch.setattr(_ensemble, "_run_block", no_run)
        kept = L.ensemble(knife.problem, method, q0, p0, lam0, args, if_exists="resume", **run)
    assert kept.n_skipped == 3 and kept.paths == files.paths
    # ... a missing block is computed again, the same bits ...
    with np.load(files.paths[1]) as z:
        block_1 = z["q"].copy()
    os.unlink(files.paths[1])
    with pytest.raises(L.LobattoDAEInputError, match="incomplete: 2 of 5 trajectories are missing \\(first: 2\\)"):
        L.load_ensemble(tmp_path)
    resumed = L.ensemble(knife.problem, method, q0, p0, lam0, args, if_exists="resume", **run)
    assert resumed.n_skipped == 2
    with np.load(files.paths[1]) as z:
        np.testing.assert_array_equal(z["q"], block_1)
    # ... and other numbers are another run: every block is recomputed
    other = L.ensemble(knife.problem, method, q0, p0, lam0, args, if_exists="resume", **{**run, "h": H / 2})
    assert other.n_skipped == 0
    assert not np.array_equal(L.load_ensemble(tmp_path).q, final[0].q)

    # the loader reads single blocks, a subset of fields, and refuses mixed runs
    part = L.load_ensemble(files.paths[1], fields=("q", "status"))
    np.testing.assert_array_equal(part.index, [2, 3])
    assert part.p is None and part.q.shape == (2, 3)
    stray = tmp_path / "stray"
    stray.mkdir()
    L.ensemble(knife.problem, method, q0, p0, lam0, args, **{**run, "out_dir": stray, "h": 2 * H})
    os.replace(stray / "ensemble-p00000-b000000.npz", tmp_path / "ensemble-p00001-b000000.npz")
    with pytest.raises(L.LobattoDAEInputError, match="2 different ensemble runs"):
        L.load_ensemble(tmp_path)
    with pytest.raises(L.LobattoDAEInputError, match="incomplete: 2 of 5 trajectories are missing"):
        L.load_ensemble(stray)
    (tmp_path / "empty").mkdir()
    with pytest.raises(L.LobattoDAEInputError, match="holds no ensemble files"):
        L.load_ensemble(tmp_path / "empty")
    with pytest.raises(L.LobattoDAEInputError, match="fields must be among"):
        L.load_ensemble(files.paths[0], fields=("x",))
    # a truncated file (a crash outside the atomic write) is named, and resume replaces it
    with open(files.paths[0], "r+b") as fh:
        fh.truncate(100)
    with pytest.raises(L.LobattoDAEInputError, match="cannot be read as an ensemble file"):
        L.load_ensemble(files.paths[0])
    repaired = L.ensemble(knife.problem, method, q0, p0, lam0, args, if_exists="resume", **{**run, "h": H / 2})
    assert repaired.n_skipped == 2
    L.load_ensemble(files.paths[0])


def test_adaptive_is_bit_for_bit_one_trajectory_at_a_time_on_a_cpu(knife, method, batch):
    """On CPU devices the error-controlled trajectories run one after the other (``lax.map``;
    ``_ensemble._in_turn``): each is, bit for bit, the single jitted ``integrate_adaptive``."""
    assert jax.devices()[0].platform == "cpu"
    q0, p0, _, _ = batch
    # λ0 consistent with the shared args (g = 1; the batch's λ0 is for its per-trajectory g): ensemble
    # checks every trajectory's initial values as solve does
    lam0 = np.asarray(jax.vmap(lambda q, p: L.consistent_lambda(knife.problem, 0.0, q, p, jnp.zeros(1),
                                                                knife.args))(q0, p0))
    options = dict(rtol=1e-3, atol=1e-5, max_steps=512)
    result = L.ensemble(knife.problem, method, q0, p0, lam0, knife.args, t_span=(0.0, 1.0), **options)
    single = jax.jit(lambda q, p, lam: L.integrate_adaptive(knife.problem, method, (0.0, 1.0), q, p, lam, knife.args,
                                                            **options))
    ref = jax.tree_util.tree_map(lambda *x: np.stack(x), *(single(*x) for x in zip(q0, p0, lam0)))
    last = np.asarray(ref.n_rows) - 1
    rows = np.arange(BATCH)
    for field in ("t", "q", "p", "lam"):
        np.testing.assert_array_equal(getattr(result, field), np.asarray(getattr(ref, field))[rows, last])
    for field in ("n_rows", "n_steps", "n_rejected", "status"):
        np.testing.assert_array_equal(getattr(result, field), np.asarray(getattr(ref, field)))
    np.testing.assert_array_equal(result.t, 1.0)
    assert np.all(result.status == L.Result.SUCCESSFUL) and np.all(result.n_steps > 10)
    # new numbers (interval, tolerances, step bounds) reuse the compiled block
    before = _ensemble._run_block._cache_size()
    again = L.ensemble(knife.problem, method, q0, p0, lam0, knife.args, t_span=(0.5, 1.2), rtol=1e-4, atol=1e-6,
                       first_step=0.01, max_step=0.2, max_steps=512)
    assert _ensemble._run_block._cache_size() == before
    np.testing.assert_array_equal(again.t, 1.2)
    assert np.all(again.status == L.Result.SUCCESSFUL) and np.all(again.n_steps >= 4)  # max_step 0.2 over 0.7


_SHARDED = """
import json, os, sys
import numpy as np
import jax
assert len(jax.devices()) == 4, jax.devices()
import lobattodae as L
from lobattodae import _ensemble
from lobattodae.examples import get_example

data = np.load(sys.argv[1])
out = sys.argv[2]
ex = get_example("knife-edge")
method = L.LobattoIIIAIIIB(stages=2)
args = ex.args._replace(g=data["g"])
flags = type(ex.args)(m=False, J=False, g=True)
seen = []
run_block = _ensemble._run_block

def spy(plan, *xs):
    result = run_block(plan, *xs)
    seen.append(sorted(d.id for d in result.q.sharding.device_set))
    return result

_ensemble._run_block = spy
kw = dict(batch_args=flags, h={h}, n_steps={n}, save="all", block_size=3)
full = L.ensemble(ex.problem, method, data["q0"], data["p0"], data["lam0"], args, **kw)
files = L.ensemble(ex.problem, method, data["q0"], data["p0"], data["lam0"], args, out_dir=out, **kw)
compilations = run_block._cache_size()
loaded = L.load_ensemble(out)
np.savez(os.path.join(out, "result.npz"), **{{f: getattr(full, f) for f in ("index", "q", "p", "lam", "status")}},
         **{{"loaded_" + f: getattr(loaded, f) for f in ("index", "q", "status")}})
print("ENSEMBLE " + json.dumps({{"devices": seen, "paths": [os.path.basename(p) for p in files.paths],
                                "compilations": compilations}}))
"""


def _subprocess_env(devices: int) -> dict:
    """``devices`` forced CPU devices, and XLA's CPU thread pool larger than that (NPROC): with as
    many devices as pool threads ``ensemble`` would use fewer devices (``_guard_cpu_pool``)."""
    env = dict(os.environ)
    env["XLA_FLAGS"] = f"--xla_force_host_platform_device_count={devices}"
    env["JAX_PLATFORMS"] = "cpu"
    env["NPROC"] = str(2 * devices)
    env.pop("PJRT_NPROC", None)  # it would take precedence over NPROC
    return env


def test_four_devices_agree_with_vmap(batch, reference, tmp_path):
    q0, p0, lam0, g = batch
    np.savez(tmp_path / "in.npz", q0=q0, p0=p0, lam0=lam0, g=g)
    script = tmp_path / "sharded.py"
    script.write_text(_SHARDED.format(h=H, n=N_STEPS))
    out = tmp_path / "out"
    proc = subprocess.run([sys.executable, str(script), str(tmp_path / "in.npz"), str(out)], env=_subprocess_env(4),
                          capture_output=True, text=True, timeout=SUBPROCESS_TIMEOUT)
    assert proc.returncode == 0, proc.stderr[-3000:]
    report = json.loads(next(line for line in proc.stdout.splitlines() if line.startswith("ENSEMBLE "))[9:])
    # 5 trajectories in blocks of 3 and 2, each padded to 4: every block on all four devices, one program
    assert report["devices"] == [[0, 1, 2, 3]] * 4
    assert report["compilations"] == 1
    assert report["paths"] == ["ensemble-p00000-b000000.npz", "ensemble-p00000-b000001.npz"]
    with np.load(out / "result.npz") as z:
        np.testing.assert_array_equal(z["index"], np.arange(BATCH))
        np.testing.assert_array_equal(z["status"], reference.status)
        for field in ("q", "p", "lam"):
            assert z[field].shape == getattr(reference, field).shape
            np.testing.assert_allclose(z[field], getattr(reference, field), rtol=0, atol=ROUND_OFF)
        np.testing.assert_array_equal(z["loaded_index"], np.arange(BATCH))
        np.testing.assert_allclose(z["loaded_q"], reference.q, rtol=0, atol=ROUND_OFF)


_PROCESS = """
import json, os, sys
import numpy as np
import jax
jax.distributed.initialize(coordinator_address="localhost:" + sys.argv[3], num_processes=2,
                           process_id=int(sys.argv[4]))
import lobattodae as L
from lobattodae.examples import get_example

data = {{name: np.load(os.path.join(sys.argv[1], name + ".npy"), mmap_mode="r") for name in ("q0", "p0", "lam0", "g")}}
ex = get_example("knife-edge")
method = L.LobattoIIIAIIIB(stages=2)
args = ex.args._replace(g=data["g"])
flags = type(ex.args)(m=False, J=False, g=True)
files = L.ensemble(ex.problem, method, data["q0"], data["p0"], data["lam0"], args, batch_args=flags,
                   h={h}, n_steps={n}, block_size=2, out_dir=sys.argv[2])
with np.load(files.paths[0]) as z:
    n_devices = json.loads(str(z["meta"]))["n_devices"]
print("ENSEMBLE", jax.process_index(), jax.process_count(), n_devices, files.start, files.stop, len(files.paths),
      flush=True)
if jax.process_index() == 0:  # after ensemble's barrier every process's files are there
    loaded = L.load_ensemble(sys.argv[2])
    np.savez(os.path.join(sys.argv[2], "..", "loaded.npz"), index=loaded.index, q=loaded.q, p=loaded.p,
             lam=loaded.lam, status=loaded.status)
jax.distributed.shutdown()
"""


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("localhost", 0))
        return s.getsockname()[1]


@pytest.mark.slow  # 17-40 s on the 2-core machine (two JAX processes, each compiling)
def test_two_processes_on_localhost(batch, reference, tmp_path):
    """Two processes (``jax.distributed``, two CPU devices each) split the batch, write their own
    files and meet at the barrier; process 0 then loads the complete run."""
    for name, x in zip(("q0", "p0", "lam0", "g"), batch):  # the global batch, memory-mapped by both processes
        np.save(tmp_path / f"{name}.npy", x)
    script = tmp_path / "process.py"
    script.write_text(_PROCESS.format(h=H, n=N_STEPS))
    out, port = tmp_path / "out", str(_free_port())
    procs = [
        subprocess.Popen([sys.executable, str(script), str(tmp_path), str(out), port, str(i)],
                         env=_subprocess_env(2), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        for i in range(2)
    ]
    outputs = [p.communicate(timeout=SUBPROCESS_TIMEOUT) for p in procs]
    for p, (stdout, stderr) in zip(procs, outputs):
        assert p.returncode == 0, stderr[-3000:]
    # process 0: trajectories 0..1 (one block), process 1: 2..4 (blocks of 2 and 1), 2 devices each
    lines = sorted(line for stdout, _ in outputs for line in stdout.splitlines() if line.startswith("ENSEMBLE "))
    assert lines == ["ENSEMBLE 0 2 2 0 2 1", "ENSEMBLE 1 2 2 2 5 2"]
    assert sorted(os.listdir(out)) == ["ensemble-p00000-b000000.npz", "ensemble-p00001-b000000.npz",
                                       "ensemble-p00001-b000001.npz"]
    with np.load(tmp_path / "loaded.npz") as z:
        np.testing.assert_array_equal(z["index"], np.arange(BATCH))
        np.testing.assert_array_equal(z["status"], reference.status)
        for field in ("q", "p", "lam"):
            np.testing.assert_allclose(z[field], getattr(reference, field)[:, -1], rtol=0, atol=ROUND_OFF)


# -- input errors: raised before anything is compiled ---------------------------------------------------
def _bad_inputs(knife, batch, batched_args):
    q0, p0, lam0, _ = batch
    args, flags = batched_args
    fixed = dict(h=H, n_steps=N_STEPS)
    adaptive = dict(h=None, n_steps=None, t_span=(0.0, 1.0))
    return [
        (dict(q0=q0[0]), L.ShapeError, r"q0 must be a batch of shape \(B, n\).*got shape \(3,\).*q0\[None\]"),
        (dict(p0=p0[:, :2]), L.ShapeError, r"p0 must have the shape of q0, \(5, 3\).*got \(5, 2\)"),
        (dict(lam0=lam0[:4]), L.ShapeError, r"lam0 must have one row per trajectory, like q0 \(5 rows\)"),
        (dict(q0=q0 + 0j), L.ShapeError, "q0 must hold real numbers"),
        (dict(q0=q0[:0], p0=p0[:0], lam0=lam0[:0]), L.ShapeError, "holds no trajectories"),
        (dict(args=args._replace(g=args.g[:3])), L.ShapeError,
         r"args\.g is batched \(batch_args\) and must have one entry per trajectory.*\(5, like q0\); got shape \(3,\)"),
        (dict(args=args._replace(g=1.0)), L.ShapeError, r"args\.g is batched.*got shape \(\)"),
        (dict(batch_args=(True, False)), L.LobattoDAEInputError, "batch_args must be True, False or a pytree"),
        (dict(batch_args=type(knife.args)(0, 0, 1)), L.LobattoDAEInputError, r"batch_args must hold bools.*args\.m"),
        (dict(h=None, n_steps=None), L.LobattoDAEInputError, "give either h and n_steps"),
        (dict(t_span=(0.0, 1.0)), L.LobattoDAEInputError, "not both"),
        (dict(rtol=1e-6), L.LobattoDAEInputError, "rtol applies to error-controlled runs"),
        (dict(n_steps=0), L.LobattoDAEInputError, "n_steps must be a positive integer"),
        (dict(h=0.0), L.LobattoDAEInputError, "h must be nonzero"),
        (dict(h=float("nan")), L.LobattoDAEInputError, "h must be a finite number"),
        (dict(adaptive, t_span=(0.0,)), L.LobattoDAEInputError, r"t_span must be a pair \(t0, t1\)"),
        (dict(adaptive, rtol=-1.0), L.LobattoDAEInputError, "rtol must be a positive finite number"),
        (dict(adaptive, t_eval=[[0.5]]), L.LobattoDAEInputError, "t_eval must be a non-empty 1-D"),
        (dict(adaptive, max_steps=0), L.LobattoDAEInputError, "max_steps must be a positive integer"),
        (dict(adaptive, t0=0.0), L.LobattoDAEInputError, "t0 is t_span\\[0\\]"),
        (dict(block_size=0), L.LobattoDAEInputError, "block_size must be a positive integer"),
        (dict(block_size=2.5), L.LobattoDAEInputError, "block_size must be a positive integer"),
        (dict(save="last"), L.LobattoDAEInputError, r"save must be one of \('final', 'all'\)"),
        (dict(if_exists="append"), L.LobattoDAEInputError, "if_exists must be one of"),
        (dict(devices=[]), L.LobattoDAEInputError, "devices must name at least one device"),
        (dict(devices=["cpu:7"]), L.LobattoDAEInputError, r"devices must be devices of this process \(jax.local_"),
    ], dict(q0=q0, p0=p0, lam0=lam0, args=args, batch_args=flags, **fixed)


def test_input_errors_name_the_argument_and_the_fix(knife, method, batch, batched_args):
    cases, good = _bad_inputs(knife, batch, batched_args)
    before = _ensemble._run_block._cache_size()
    for change, error, message in cases:
        kw = {**good, **change}
        with pytest.raises(error, match=message):
            L.ensemble(knife.problem, method, kw.pop("q0"), kw.pop("p0"), kw.pop("lam0"), kw.pop("args"), **kw)
    assert _ensemble._run_block._cache_size() == before


def test_cpu_meshes_keep_a_free_pool_thread(monkeypatch):
    """As many CPU devices as XLA's CPU pool has threads can deadlock jaxlib's batched LU (seen:
    2 forced devices, 2 cores, 64 trajectories per device): default devices keep one thread free."""
    cpus = [types.SimpleNamespace(platform="cpu", id=i) for i in range(4)]
    monkeypatch.delenv("PJRT_NPROC", raising=False)
    monkeypatch.setenv("NPROC", "2")
    with pytest.warns(RuntimeWarning, match="shards over 1 of the 4 local CPU devices.*PJRT_NPROC=8"):
        assert _ensemble_inputs.guard_cpu_pool(cpus, explicit=False) == cpus[:1]
    with pytest.warns(RuntimeWarning, match=r"can deadlock.*at most 1 device\(s\)"):
        assert _ensemble_inputs.guard_cpu_pool(cpus, explicit=True) == cpus
    monkeypatch.setenv("NPROC", "4")
    with pytest.warns(RuntimeWarning, match="shards over 3 of the 4"):
        assert _ensemble_inputs.guard_cpu_pool(cpus, explicit=False) == cpus[:3]
    monkeypatch.setenv("NPROC", "5")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert _ensemble_inputs.guard_cpu_pool(cpus, explicit=False) == cpus
        assert _ensemble_inputs.guard_cpu_pool(cpus[:1], explicit=False) == cpus[:1]
        gpus = [types.SimpleNamespace(platform="gpu", id=i) for i in range(8)]
        monkeypatch.setenv("NPROC", "2")
        assert _ensemble_inputs.guard_cpu_pool(gpus, explicit=False) == gpus
    monkeypatch.setenv("PJRT_NPROC", "1")  # jaxlib reads it before NPROC (set_cpu_threads sets it)
    with pytest.warns(RuntimeWarning, match="shards over 1 of the 4 local CPU devices"):
        assert _ensemble_inputs.guard_cpu_pool(cpus, explicit=False) == cpus[:1]
    monkeypatch.setenv("PJRT_NPROC", "6")
    assert _ensemble_inputs.guard_cpu_pool(cpus, explicit=False) == cpus


# -- block files that cannot lie (issue #30) ----------------------------------------------------------
@pytest.fixture(scope="module")
def small_batch(knife):
    """Three consistent trajectories (headings 0, 0.2, 0.4; momenta along the blade)."""
    heading = np.array([0.0, 0.2, 0.4])
    q0 = np.tile(knife.q0, (3, 1))
    q0[:, 2] = heading
    speed = np.array([0.5, 0.7, 0.9])
    p0 = np.stack([speed * np.cos(heading), speed * np.sin(heading), np.full(3, 0.3)], axis=1)
    lam0 = np.stack([np.asarray(L.consistent_lambda(knife.problem, 0.0, q, p, np.zeros(1), knife.args))
                     for q, p in zip(q0, p0)])
    return q0, p0, lam0


def _small_run(knife, method, small_batch, **kw):
    q0, p0, lam0 = small_batch
    return L.ensemble(knife.problem, method, q0, p0, lam0, knife.args, h=H, n_steps=SMALL_STEPS, block_size=BLOCK,
                      **kw)


def _member_data(path, name):
    """(offset, size) of the stored bytes of ``name.npy`` inside the .npz ``path``."""
    with zipfile.ZipFile(path) as zf:
        info = zf.getinfo(name + ".npy")
    with open(path, "rb") as fh:
        fh.seek(info.header_offset)
        header = fh.read(30)
    start = info.header_offset + 30 + int.from_bytes(header[26:28], "little") + int.from_bytes(header[28:30], "little")
    return start, info.compress_size


def _flip_bit_in_q(path):
    start, size = _member_data(path, "q")
    with open(path, "r+b") as fh:
        fh.seek(start + size - 1)
        byte = fh.read(1)[0]
        fh.seek(start + size - 1)
        fh.write(bytes([byte ^ 0x01]))


def _rewrite_with_changed_q(path):
    """The file rewritten by NumPy (valid CRCs) with one number of q changed, the rest kept."""
    with np.load(path, allow_pickle=False) as z:
        arrays = {name: z[name] for name in z.files}
    arrays["q"] = arrays["q"].copy()
    arrays["q"][0, 0] += 1e-3
    np.savez(path, **arrays)


@pytest.mark.parametrize("damage", [_flip_bit_in_q, _rewrite_with_changed_q], ids=["bit-flip", "valid-crc"])
def test_a_damaged_block_is_refused_on_load_and_recomputed_on_resume(knife, method, small_batch, tmp_path, damage):
    files = _small_run(knife, method, small_batch, out_dir=tmp_path)
    good = L.load_ensemble(tmp_path)
    damage(files.paths[0])
    for source in (tmp_path, files.paths[0], files):
        with pytest.raises(L.LobattoDAEInputError, match="ensemble-p00000-b000000.npz.*damaged") as info:
            L.load_ensemble(source)
        assert isinstance(info.value, _ensemble.EnsembleFileError)
        assert info.value.path == files.paths[0]
    L.load_ensemble(files.paths[1])  # the intact block still loads
    with pytest.warns(RuntimeWarning, match="ensemble-p00000-b000000.npz.*damaged.*computed again"):
        resumed = _small_run(knife, method, small_batch, out_dir=tmp_path, if_exists="resume")
    assert resumed.n_skipped == 1  # only the intact block is kept
    again = L.load_ensemble(tmp_path)
    for field in ("index", "q", "p", "lam", "status"):
        np.testing.assert_array_equal(getattr(again, field), getattr(good, field))


def test_every_array_of_a_block_is_covered_by_its_digest(knife, method, small_batch, tmp_path):
    files = _small_run(knife, method, small_batch, out_dir=tmp_path)
    with np.load(files.paths[0], allow_pickle=False) as z:
        digests = json.loads(str(z["digests"]))
        assert sorted(digests) == sorted(n for n in z.files if n != "digests")
        meta = json.loads(str(z["meta"]))
    assert meta["version"] == _ensemble.FILE_VERSION >= 2
    # a changed meta (another run's block_digest) is damage too, not another run
    with np.load(files.paths[0], allow_pickle=False) as z:
        arrays = {name: z[name] for name in z.files}
    arrays["meta"] = np.asarray(json.dumps({**meta, "block": 7}))
    np.savez(files.paths[0], **arrays)
    with pytest.raises(L.LobattoDAEInputError, match="damaged.*'meta'"):
        L.load_ensemble(files.paths[0], fields=("status",))


def test_load_names_a_block_whose_archive_is_damaged(knife, method, small_batch, tmp_path):
    files = _small_run(knife, method, small_batch, out_dir=tmp_path)
    start, size = _member_data(files.paths[1], "status")
    with open(files.paths[1], "r+b") as fh:  # inside a member's data: zipfile's CRC check fails
        fh.seek(start + size - 1)
        fh.write(b"\xff")
    with pytest.raises(L.LobattoDAEInputError, match="ensemble-p00000-b000001.npz") as info:
        L.load_ensemble(tmp_path)
    assert not isinstance(info.value, zipfile.BadZipFile)


def test_blocks_are_written_by_the_checkpoint_writer(knife, method, small_batch, tmp_path, monkeypatch):
    written, synced = [], []
    real_write, real_fsync = atomic.write_npz, os.fsync

    def write(target, payload, **kw):
        written.append(os.path.basename(target))
        return real_write(target, payload, **kw)

    monkeypatch.setattr(atomic, "write_npz", write)
    monkeypatch.setattr(os, "fsync", lambda fd: (synced.append(fd), real_fsync(fd))[1])
    _small_run(knife, method, small_batch, out_dir=tmp_path)
    assert written == ["ensemble-p00000-b000000.npz", "ensemble-p00000-b000001.npz"]
    assert len(synced) >= 2
    assert sorted(os.listdir(tmp_path)) == written  # no temporary file left


def test_a_directory_named_like_a_block_is_refused(knife, method, small_batch, tmp_path):
    (tmp_path / "ensemble-p00000-b000000.npz").mkdir()
    for if_exists in ("resume", "overwrite"):
        with pytest.raises(L.LobattoDAEInputError, match="ensemble-p00000-b000000.npz.*not a regular file"):
            _small_run(knife, method, small_batch, out_dir=tmp_path, if_exists=if_exists)


# -- inputs checked as solve checks them (issue #30) ----------------------------------------------
def _solve_message(knife, method, **kw):
    with pytest.raises(L.LobattoDAEInputError) as info:
        L.solve(knife.problem, method, kw.pop("t_span", (0.0, 1.0)), knife.q0, knife.p0, args=knife.args, **kw)
    return str(info.value)


@pytest.mark.parametrize("t_span, t_eval", [
    ((0.0, 1.0), [0.5, 0.2]),  # unsorted
    ((0.0, 1.0), [0.5, 2.0]),  # beyond t1
    ((0.0, 1.0), [-0.5, 0.5]),  # before t0
    ((1.0, 0.0), [0.2, 0.5]),  # backwards span, increasing t_eval
])
def test_t_eval_is_refused_as_solve_refuses_it(knife, method, small_batch, t_span, t_eval):
    q0, p0, lam0 = small_batch
    expected = _solve_message(knife, method, t_span=t_span, t_eval=t_eval)
    with pytest.raises(L.LobattoDAEInputError) as info:
        L.ensemble(knife.problem, method, q0, p0, lam0, knife.args, t_span=t_span, t_eval=t_eval)
    assert str(info.value) == expected


def test_rtol_is_refused_as_solve_refuses_it(knife, method, small_batch):
    q0, p0, lam0 = small_batch
    expected = _solve_message(knife, method, rtol=1e-20)
    with pytest.raises(L.LobattoDAEInputError) as info:
        L.ensemble(knife.problem, method, q0, p0, lam0, knife.args, t_span=(0.0, 1.0), rtol=1e-20)
    assert str(info.value) == expected


def _bad_as_solve(knife, small_batch):
    q0, p0, lam0 = small_batch
    flags = type(knife.args)(m=False, J=False, g=True)
    p_off = p0.copy()
    p_off[1] += [0.3, -0.4, 0.0]  # across the blade: φ ≠ 0
    lam_off = lam0.copy()
    lam_off[2] += 0.5
    fixed = dict(h=H, n_steps=SMALL_STEPS)
    return [
        (dict(lam0=np.zeros((3, 2))), L.ShapeError, r"lam0 must have shape \(B, m\) = \(3, 1\).*got shape \(3, 2\)"),
        (dict(args=knife.args._replace(g=np.ones((3, 2))), batch_args=flags), L.ProblemFunctionError,
         r"trajectory 0.*args\.g is batched: trajectory k gets args\.g\[k\], of shape \(2,\)"),
        (dict(args=knife.args._replace(g=np.ones(3))), L.ProblemFunctionError,
         r"trajectory 0.*args\.g has shape \(3,\).*not marked in batch_args"),
        (dict(args=None), L.ProblemFunctionError, "args is None, but the problem's functions read args"),
        (dict(fixed, h=None, n_steps=None, t_span=(0.0, 1.0), controller="pi"), L.LobattoDAEInputError,
         "controller must be lobattodae.PIController"),
        (dict(p0=p_off), L.InconsistentInitialValuesError, r"trajectory 1 \(row 1 of q0, p0, lam0\).*constraint"),
        (dict(lam0=lam_off), L.InconsistentInitialValuesError,
         r"trajectory 2 \(row 2 of q0, p0, lam0\).*lam0 violates the hidden constraint"),
    ], dict(q0=q0, p0=p0, lam0=lam0, args=knife.args, **fixed)


def test_bad_inputs_are_our_errors_naming_the_argument(knife, method, small_batch):
    cases, good = _bad_as_solve(knife, small_batch)
    before = _ensemble._run_block._cache_size()
    for change, error, message in cases:
        kw = {**good, **change}
        with pytest.raises(error, match=message):
            L.ensemble(knife.problem, method, kw.pop("q0"), kw.pop("p0"), kw.pop("lam0"), kw.pop("args"), **kw)
    assert _ensemble._run_block._cache_size() == before  # refused before anything was compiled


def test_consistent_inputs_still_run(knife, method, small_batch):
    res = _small_run(knife, method, small_batch)
    assert (res.status == 0).all()
    # s = 2 at the default rtol 1e-8 needs ~4000 steps per unit of time: a looser tolerance
    adaptive = L.ensemble(knife.problem, method, *small_batch, knife.args, t_span=(1.0, 0.0), t_eval=[0.75, 0.25],
                          rtol=1e-5, atol=1e-5, save="all")
    assert (adaptive.status == 0).all()
    np.testing.assert_array_equal(adaptive.t, np.tile([0.75, 0.25], (3, 1)))
