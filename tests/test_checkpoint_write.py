"""A checkpoint that cannot be written mid-run (issue #30): a full disk or a read-only
directory ends ``solve`` with our error, naming the file and the fix, and the computed prefix
is kept (the error's ``.solution``, or returned with ``throw=False``); the checkpoint on disk
stays valid and resumes bit for bit. Before: the raw ``OSError`` escaped and the prefix was
lost."""

import errno
import os

import numpy as np
import pytest

import lobattodae as L
from lobattodae._io import atomic
from lobattodae.examples import get_example

N, CHUNK, EVERY = 96, 16, 16


@pytest.fixture(scope="module")
def setup():
    ex = get_example("knife-edge")
    method = L.LobattoIIIAIIIB(stages=2)
    kw = dict(n_steps=N, args=ex.args, chunk_size=CHUNK)
    ref = L.solve(ex.problem, method, (0.0, 3.0), ex.q0, ex.p0, **kw)
    return ex, method, kw, ref


def _failing_writes(monkeypatch, after: int, code: int):
    """Let ``after`` file writes of checkpoint saves succeed, then fail every one with ``code``."""
    real, calls = atomic.write_npz, {"n": 0}

    def write(target, payload):
        calls["n"] += 1
        if calls["n"] > after:
            raise OSError(code, os.strerror(code), target)
        return real(target, payload)

    monkeypatch.setattr(atomic, "write_npz", write)


def _solve(setup, path, **kw):
    ex, method, base, _ = setup
    return L.solve(ex.problem, method, (0.0, 3.0), ex.q0, ex.p0, checkpoint=path, checkpoint_every=EVERY,
                   **base, **kw)


@pytest.mark.parametrize("code, fix", [(errno.ENOSPC, "free space on that disk"),
                                       (errno.EROFS, "make the directory writable again")])
def test_a_failed_save_mid_run_raises_our_error_with_the_prefix(setup, tmp_path, monkeypatch, code, fix):
    ref = setup[3]
    path = tmp_path / "run.npz"
    _failing_writes(monkeypatch, after=4, code=code)  # two saves (segment + main file each), then the disk fails
    with pytest.raises(L.CheckpointWriteError) as info:
        _solve(setup, path)
    err = info.value
    assert isinstance(err, L.LobattoDAEInputError) and isinstance(err.__cause__, OSError)
    assert err.path == str(path) and err.errno == code
    msg = str(err)
    assert f"cannot write the checkpoint '{path}'" in msg and os.strerror(code) in msg and fix in msg
    assert "holds the run up to step 32" in msg and "resume=True" in msg and ".solution" in msg
    part = err.solution  # the computed prefix: the chunk whose save failed included
    assert not part.success and part.result == L.Result.INTERRUPTED and part.status == -1
    assert len(part.t) == 3 * CHUNK + 1 and np.all(np.isfinite(part.q))
    np.testing.assert_array_equal(part.q, ref.q[: len(part.t)])
    # the checkpoint on disk is the last committed one: it resumes, bit for bit
    monkeypatch.undo()
    full = _solve(setup, path, resume=True)
    assert full.success
    for name in ("t", "q", "p", "lam"):
        np.testing.assert_array_equal(getattr(full, name), getattr(ref, name))


def test_with_throw_false_the_prefix_is_returned_with_the_reason(setup, tmp_path, monkeypatch):
    path = tmp_path / "run.npz"
    _failing_writes(monkeypatch, after=0, code=errno.ENOSPC)  # the first save fails: nothing committed
    sol = _solve(setup, path, throw=False)
    assert not sol.success and sol.result == L.Result.INTERRUPTED and len(sol.t) == CHUNK + 1
    assert "No space left on device" in sol.message and "no checkpoint of this run was committed" in sol.message
    assert "returned" in sol.message and not path.exists()


def test_a_failed_final_save_keeps_the_finished_run(setup, tmp_path, monkeypatch):
    # no periodic saves: only the final one, after the end was reached, fails
    ex, method, base, ref = setup
    path = tmp_path / "run.npz"
    _failing_writes(monkeypatch, after=0, code=errno.ENOSPC)
    with pytest.raises(L.CheckpointWriteError, match="The run itself ended") as info:
        L.solve(ex.problem, method, (0.0, 3.0), ex.q0, ex.p0, checkpoint=path, **base)
    sol = info.value.solution
    assert sol.success and sol.result == L.Result.SUCCESSFUL and len(sol.t) == N + 1
    np.testing.assert_array_equal(sol.q, ref.q)


@pytest.mark.skipif(not hasattr(os, "geteuid") or os.geteuid() == 0,
                    reason="root writes into read-only directories")
def test_a_directory_made_read_only_mid_run(setup, tmp_path):
    directory = tmp_path / "out"
    directory.mkdir()
    path = directory / "run.npz"
    calls = {"n": 0}

    def read_only_after_two_chunks(done, total):
        calls["n"] += 1
        if calls["n"] == 3:  # before the third save
            for d in (directory, directory / "run.npz.rows"):
                os.chmod(d, 0o555)

    try:
        with pytest.raises(L.CheckpointWriteError, match="make the directory writable again") as info:
            _solve(setup, path, progress=read_only_after_two_chunks)
    finally:
        for d in (directory, directory / "run.npz.rows"):
            os.chmod(d, 0o755)
    assert len(info.value.solution.t) == 3 * CHUNK + 1
    assert L.solve(setup[0].problem, setup[1], (0.0, 3.0), setup[0].q0, setup[0].p0, checkpoint=path,
                   checkpoint_every=EVERY, resume=True, **setup[2]).success
