"""The one atomic writer (lobattodae._io.atomic): durable, all or nothing, never through a link,
and the writer of both checkpoints and ensemble blocks."""

import errno
import json
import os
import stat

import numpy as np
import pytest

import lobattodae as L
from lobattodae._io import atomic, checkpoint, ensemble_files
from lobattodae.examples import get_example

ARRAYS = {"a": np.arange(4.0), "b": np.asarray("text")}


def _read(path):
    with np.load(path, allow_pickle=False) as z:
        return {name: z[name] for name in z.files}


def _same(got, want):
    return list(got) == list(want) and all(got[k].dtype == want[k].dtype and got[k].tobytes() == want[k].tobytes()
                                           for k in want)


def test_round_trip(tmp_path):
    path = tmp_path / "x.npz"
    atomic.write_npz(path, ARRAYS)
    assert _same(_read(path), ARRAYS)
    assert os.listdir(tmp_path) == ["x.npz"]


def test_the_file_then_the_directory_are_fsynced(tmp_path, monkeypatch):
    """The data reach the disk before the rename, and the rename before the writer returns."""
    events, real_fsync, real_replace = [], os.fsync, os.replace
    monkeypatch.setattr(os, "fsync", lambda fd: (events.append(stat.S_IFMT(os.fstat(fd).st_mode)), real_fsync(fd))[1])
    monkeypatch.setattr(os, "replace", lambda a, b: (events.append("replace"), real_replace(a, b))[1])
    atomic.write_npz(tmp_path / "x.npz", ARRAYS)
    assert events == [stat.S_IFREG, "replace", stat.S_IFDIR]


def test_a_new_file_gets_the_mode_open_would_give(tmp_path):
    old = os.umask(0o027)
    try:
        atomic.write_npz(tmp_path / "x.npz", ARRAYS)
    finally:
        os.umask(old)
    assert stat.S_IMODE(os.stat(tmp_path / "x.npz").st_mode) == 0o640  # not mkstemp's 0o600


def test_a_symlink_at_the_target_is_refused(tmp_path):
    victim = tmp_path / "victim.npz"
    victim.write_bytes(b"precious")
    link = tmp_path / "x.npz"
    link.symlink_to(victim)
    with pytest.raises(OSError, match=r"'.*x\.npz'.*symbolic link.*remove the link") as info:
        atomic.write_npz(link, ARRAYS)
    assert info.value.errno == errno.ELOOP
    assert link.is_symlink() and victim.read_bytes() == b"precious"
    assert sorted(os.listdir(tmp_path)) == ["victim.npz", "x.npz"]


@pytest.mark.parametrize("error", [OSError(errno.ENOSPC, "No space left on device"), KeyboardInterrupt()])
@pytest.mark.parametrize("stage", ["write", "rename"])
def test_a_failure_leaves_the_old_file_and_no_temporary_file(tmp_path, monkeypatch, error, stage):
    path = tmp_path / "x.npz"
    atomic.write_npz(path, ARRAYS)
    before = path.read_bytes()
    seen = []
    if stage == "write":
        real_savez = np.savez

        def savez(fh, **arrays):  # half of the new file is written, then the disk fills up
            real_savez(fh, **arrays)
            fh.truncate(fh.tell() // 2)
            seen.extend(name for name in os.listdir(tmp_path) if atomic.is_temporary(name))
            raise error

        monkeypatch.setattr(np, "savez", savez)
    else:
        def replace(src, dst):
            seen.append(os.path.basename(src))
            raise error

        monkeypatch.setattr(os, "replace", replace)
    with pytest.raises(type(error)):
        atomic.write_npz(path, {"a": np.zeros(1000)})
    monkeypatch.undo()
    assert len(seen) == 1 and atomic.is_temporary(seen[0])  # there was a temporary file ...
    assert os.listdir(tmp_path) == ["x.npz"]  # ... and it is gone
    assert path.read_bytes() == before and _same(_read(path), ARRAYS)


def test_is_temporary_knows_only_the_writers_names():
    assert atomic.is_temporary(".run.npz.k2j4_x.tmp")
    assert not any(atomic.is_temporary(name) for name in ("run.npz", "000001-0123456789abcdef.npz", ".hidden",
                                                             "notes.tmp"))


def test_checkpoints_and_ensemble_blocks_are_written_by_it(tmp_path, monkeypatch):
    written, real = [], atomic.write_npz

    def write(target, arrays):
        written.append(os.path.relpath(target, tmp_path))
        real(target, arrays)

    monkeypatch.setattr(atomic, "write_npz", write)
    checkpoint.save(tmp_path / "run.npz", meta={}, counters={}, state={"x": np.zeros(2)},
                    rows={"t": np.arange(3.0)})
    block = str(tmp_path / ensemble_files.file_name(0, 0))
    ensemble_files.write_block(block, {"meta": np.asarray("{}"), "index": np.arange(2)})
    (segment,) = os.listdir(tmp_path / "run.npz.rows")
    assert written == [os.path.join("run.npz.rows", segment), "run.npz", "ensemble-p00000-b000000.npz"]
    assert sorted(json.loads(str(_read(block)["digests"]))) == ["index", "meta"]  # with the block's digests


def test_a_checkpoint_at_a_symlink_is_refused_before_anything_is_written(tmp_path):
    victim = tmp_path / "victim.npz"
    victim.write_bytes(b"precious")
    link = tmp_path / "run.npz"
    link.symlink_to(victim)
    with pytest.raises(checkpoint.CheckpointError, match=r"'.*run\.npz': it is a symbolic link.*real path") as info:
        checkpoint.save(link, meta={}, counters={}, state={"x": np.zeros(2)}, rows={"t": np.arange(3.0)})
    assert info.value.path == str(link)
    ex = get_example("knife-edge")
    for resume in (False, True):  # solve refuses it before any work
        with pytest.raises(L.CheckpointError, match="it is a symbolic link"):
            L.solve(ex.problem, L.LobattoIIIAIIIB(stages=2), (0.0, 0.1), ex.q0, ex.p0, n_steps=4, args=ex.args,
                    checkpoint=link, resume=resume)
    assert sorted(os.listdir(tmp_path)) == ["run.npz", "victim.npz"] and victim.read_bytes() == b"precious"
