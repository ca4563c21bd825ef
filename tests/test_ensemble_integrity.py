"""Ensemble files that cannot lie, and ensemble inputs checked as ``solve`` checks them (issue #30).

* Every block file carries a SHA-256 digest of each of its arrays: a bit flip inside a block, or
  a block rewritten with a valid zip CRC, is refused by :func:`load_ensemble` with an error that
  names the file, and recomputed (with a warning) by ``if_exists="resume"``; blocks are written
  by the checkpoint's atomic writer (unique temporary file, fsync, rename).
* ``lam0`` of the wrong width, badly batched ``args``, ``args=None``, a wrong ``controller``,
  ``t_eval`` or ``rtol`` that ``solve`` refuses, and inconsistent initial values raise our
  errors, naming the argument, before anything is compiled.
"""

import json
import os
import zipfile

import numpy as np
import pytest

import lobattodae as L
from lobattodae import _ensemble
from lobattodae._io import atomic
from lobattodae.examples import get_example

H, N_STEPS, BLOCK = 0.05, 4, 2


@pytest.fixture(scope="module")
def knife():
    return get_example("knife-edge")


@pytest.fixture(scope="module")
def method():
    return L.LobattoIIIAIIIB(stages=2)


@pytest.fixture(scope="module")
def batch(knife):
    """Three consistent trajectories (headings 0, 0.2, 0.4; momenta along the blade)."""
    heading = np.array([0.0, 0.2, 0.4])
    q0 = np.tile(knife.q0, (3, 1))
    q0[:, 2] = heading
    speed = np.array([0.5, 0.7, 0.9])
    p0 = np.stack([speed * np.cos(heading), speed * np.sin(heading), np.full(3, 0.3)], axis=1)
    lam0 = np.stack([np.asarray(L.consistent_lambda(knife.problem, 0.0, q, p, np.zeros(1), knife.args))
                     for q, p in zip(q0, p0)])
    return q0, p0, lam0


def _run(knife, method, batch, **kw):
    q0, p0, lam0 = batch
    return L.ensemble(knife.problem, method, q0, p0, lam0, knife.args, h=H, n_steps=N_STEPS, block_size=BLOCK,
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


# -- digests --------------------------------------------------------------------------------------------
@pytest.mark.parametrize("damage", [_flip_bit_in_q, _rewrite_with_changed_q], ids=["bit-flip", "valid-crc"])
def test_a_damaged_block_is_refused_on_load_and_recomputed_on_resume(knife, method, batch, tmp_path, damage):
    files = _run(knife, method, batch, out_dir=tmp_path)
    good = L.load_ensemble(tmp_path)
    damage(files.paths[0])
    for source in (tmp_path, files.paths[0], files):
        with pytest.raises(L.LobattoDAEInputError, match="ensemble-p00000-b000000.npz.*damaged") as info:
            L.load_ensemble(source)
        assert isinstance(info.value, _ensemble.EnsembleFileError)
        assert info.value.path == files.paths[0]
    L.load_ensemble(files.paths[1])  # the intact block still loads
    with pytest.warns(RuntimeWarning, match="ensemble-p00000-b000000.npz.*damaged.*computed again"):
        resumed = _run(knife, method, batch, out_dir=tmp_path, if_exists="resume")
    assert resumed.n_skipped == 1  # only the intact block is kept
    again = L.load_ensemble(tmp_path)
    for field in ("index", "q", "p", "lam", "status"):
        np.testing.assert_array_equal(getattr(again, field), getattr(good, field))


def test_every_array_of_a_block_is_covered_by_its_digest(knife, method, batch, tmp_path):
    files = _run(knife, method, batch, out_dir=tmp_path)
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


def test_load_names_a_block_whose_archive_is_damaged(knife, method, batch, tmp_path):
    files = _run(knife, method, batch, out_dir=tmp_path)
    start, size = _member_data(files.paths[1], "status")
    with open(files.paths[1], "r+b") as fh:  # inside a member's data: zipfile's CRC check fails
        fh.seek(start + size - 1)
        fh.write(b"\xff")
    with pytest.raises(L.LobattoDAEInputError, match="ensemble-p00000-b000001.npz") as info:
        L.load_ensemble(tmp_path)
    assert not isinstance(info.value, zipfile.BadZipFile)


def test_blocks_are_written_by_the_checkpoint_writer(knife, method, batch, tmp_path, monkeypatch):
    written, synced = [], []
    real_write, real_fsync = atomic.write_npz, os.fsync

    def write(target, payload, **kw):
        written.append(os.path.basename(target))
        return real_write(target, payload, **kw)

    monkeypatch.setattr(atomic, "write_npz", write)
    monkeypatch.setattr(os, "fsync", lambda fd: (synced.append(fd), real_fsync(fd))[1])
    _run(knife, method, batch, out_dir=tmp_path)
    assert written == ["ensemble-p00000-b000000.npz", "ensemble-p00000-b000001.npz"]
    assert len(synced) >= 2
    assert sorted(os.listdir(tmp_path)) == written  # no temporary file left


def test_a_directory_named_like_a_block_is_refused(knife, method, batch, tmp_path):
    (tmp_path / "ensemble-p00000-b000000.npz").mkdir()
    for if_exists in ("resume", "overwrite"):
        with pytest.raises(L.LobattoDAEInputError, match="ensemble-p00000-b000000.npz.*not a regular file"):
            _run(knife, method, batch, out_dir=tmp_path, if_exists=if_exists)


# -- inputs ---------------------------------------------------------------------------------------------
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
def test_t_eval_is_refused_as_solve_refuses_it(knife, method, batch, t_span, t_eval):
    q0, p0, lam0 = batch
    expected = _solve_message(knife, method, t_span=t_span, t_eval=t_eval)
    with pytest.raises(L.LobattoDAEInputError) as info:
        L.ensemble(knife.problem, method, q0, p0, lam0, knife.args, t_span=t_span, t_eval=t_eval)
    assert str(info.value) == expected


def test_rtol_is_refused_as_solve_refuses_it(knife, method, batch):
    q0, p0, lam0 = batch
    expected = _solve_message(knife, method, rtol=1e-20)
    with pytest.raises(L.LobattoDAEInputError) as info:
        L.ensemble(knife.problem, method, q0, p0, lam0, knife.args, t_span=(0.0, 1.0), rtol=1e-20)
    assert str(info.value) == expected


def _bad(knife, batch):
    q0, p0, lam0 = batch
    flags = type(knife.args)(m=False, J=False, g=True)
    p_off = p0.copy()
    p_off[1] += [0.3, -0.4, 0.0]  # across the blade: φ ≠ 0
    lam_off = lam0.copy()
    lam_off[2] += 0.5
    fixed = dict(h=H, n_steps=N_STEPS)
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


def test_bad_inputs_are_our_errors_naming_the_argument(knife, method, batch):
    cases, good = _bad(knife, batch)
    before = _ensemble._run_block._cache_size()
    for change, error, message in cases:
        kw = {**good, **change}
        with pytest.raises(error, match=message):
            L.ensemble(knife.problem, method, kw.pop("q0"), kw.pop("p0"), kw.pop("lam0"), kw.pop("args"), **kw)
    assert _ensemble._run_block._cache_size() == before  # refused before anything was compiled


def test_consistent_inputs_still_run(knife, method, batch):
    res = _run(knife, method, batch)
    assert (res.status == 0).all()
    # s = 2 at the default rtol 1e-8 needs ~4000 steps per unit of time: a looser tolerance
    adaptive = L.ensemble(knife.problem, method, *batch, knife.args, t_span=(1.0, 0.0), t_eval=[0.75, 0.25],
                          rtol=1e-5, atol=1e-5, save="all")
    assert (adaptive.status == 0).all()
    np.testing.assert_array_equal(adaptive.t, np.tile([0.75, 0.25], (3, 1)))
