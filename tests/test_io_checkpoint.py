"""The checkpoint file format (lobattodae._io.checkpoint, with the row segments of
lobattodae._io.segments): schema, incremental row segments, atomic writes, clear errors.

Resuming runs through ``solve`` is tested in ``test_resume.py``; the fingerprints in
``test_io_fingerprint.py``.
"""

import dataclasses
import json
import os
import re
import shutil
import threading

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import lobattodae as L
from lobattodae._errors import LobattoDAEInputError
from lobattodae._io import atomic
from lobattodae._io import checkpoint as C
from lobattodae.examples import get_example

from helpers import Y, assert_bitwise_equal, make_state


def make_rows(k=20, n=3, seed=1):
    rng = np.random.default_rng(seed)
    return {
        "q": rng.standard_normal((k, n)),
        "result": rng.integers(0, 5, k).astype(np.int32),
        "ok": rng.random(k) > 0.5,
    }


META = {"method": "LobattoIIIAIIIB(stages=3)", "t_span": [0.0, 10.0], "h": 0.01, "q0": "abc123"}


COUNTERS = {"done": 20, "recoveries": 1, "resets": 0, "elapsed": 1.25}


ROW_NAMES = ["q", "result", "ok"]


def write(path, state=None, rows=None, meta=META, counters=COUNTERS):
    C.save(path, meta=meta, counters=counters, state=make_state() if state is None else state,
           rows=make_rows() if rows is None else rows)


def read(path, meta=META, template=None, row_names=ROW_NAMES):
    return C.load(path, meta=meta, state_template=make_state() if template is None else template,
                  row_names=row_names)


def segment_files(path):
    """The files in the checkpoint's rows directory, sorted."""
    return sorted(os.listdir(C.rows_directory(path)))


def copy_checkpoint(src, dst):
    """A checkpoint is its main file and its rows directory."""
    shutil.copyfile(src, dst)
    shutil.rmtree(C.rows_directory(dst), ignore_errors=True)
    shutil.copytree(C.rows_directory(src), C.rows_directory(dst))


CORRUPT = r"is corrupt or not a lobattodae checkpoint \(.+\); delete it or restart without resume"


def expect_corrupt(path, **kw) -> str:
    """load must raise CheckpointError (and nothing else) with the corrupt message naming the path."""
    try:
        read(path, **kw)
    except C.CheckpointError as exc:
        msg = str(exc)
    else:  # pragma: no cover
        pytest.fail("load accepted a bad file")
    assert msg.startswith(f"checkpoint '{path}' "), msg
    assert re.search(CORRUPT, msg), msg
    assert "PosixPath" not in msg and "\n" not in msg
    return msg


def leftovers(directory, keep):
    return sorted(set(os.listdir(directory)) - set(keep))


# --------------------------------------------------------------------------------------------
# round trip and schema


def test_round_trip_is_bitwise(tmp_path):
    path = tmp_path / "run.npz"
    state, rows = make_state(), make_rows()
    state = state._replace(y=Y(state.y.q.at[0].set(-0.0), state.y.p.at[1].set(jnp.nan)))
    segments = C.save(path, meta=META, counters=COUNTERS, state=state, rows=rows)
    counters, got, got_rows, loaded = C.load(path, meta=META, state_template=make_state(), row_names=ROW_NAMES)
    assert loaded == dataclasses.replace(segments, tidy=False) and len(segments.files) == 1
    assert counters == COUNTERS and type(counters["done"]) is int and type(counters["elapsed"]) is float
    assert_bitwise_equal(got, state)
    assert all(isinstance(x, jax.Array) for x in jax.tree_util.tree_leaves(got))
    assert got.stepper.jacobian.valid.dtype == jnp.bool_ and got.step.dtype == jnp.int32
    assert list(got_rows) == ROW_NAMES
    for name in ROW_NAMES:
        assert got_rows[name].dtype == rows[name].dtype
        assert got_rows[name].tobytes() == rows[name].tobytes()
    assert leftovers(tmp_path, ["run.npz", "run.npz.rows"]) == []
    assert segment_files(path) == list(segments.files)


def test_round_trip_of_unusual_layouts(tmp_path):
    path = tmp_path / "run.npz"
    rows = {
        "fortran": np.asfortranarray(np.arange(12.0).reshape(3, 4)),
        "transposed": np.arange(6, dtype=np.int32).reshape(2, 3).T,
        "empty": np.zeros((0, 3)),
        "complex": np.array([1 + 2j, -0.0 - 1j]),
        "bool": np.array([True, False, True]),
    }
    template = {"a": jnp.zeros((2, 0)), "b": (jnp.zeros(()), jnp.zeros(1, jnp.uint8))}
    C.save(path, meta={}, counters={}, state=template, rows=rows)
    counters, state, got, _ = C.load(path, meta={}, state_template=template, row_names=list(rows))
    assert counters == {}
    assert_bitwise_equal(state, template)
    for name, value in rows.items():
        np.testing.assert_array_equal(got[name], value)
        assert got[name].dtype == np.asarray(value).dtype and got[name].flags.writeable


def test_file_schema_is_explicit(tmp_path):
    path = str(tmp_path / "run.npz")
    rows = make_rows()
    write(path, rows=rows)
    with np.load(path, allow_pickle=False) as data:
        keys = set(data.files)
        assert str(data["__format__"]) == C.FORMAT == "lobattodae-checkpoint"
        assert int(data["__version__"]) == C.VERSION == 13
        assert json.loads(str(data["meta"])) == META
        assert json.loads(str(data["counters"])) == COUNTERS
        segments = json.loads(str(data["segments"]))
    assert keys == {
        "__format__", "__version__", "meta", "counters", "segments",
        "state/y.q", "state/y.p", "state/stepper.jacobian.inverse", "state/stepper.jacobian.valid",
        "state/stepper.slopes", "state/step",
    }
    assert set(segments) == {"run", "count", "head", "fields"} and segments["count"] == 1
    assert re.fullmatch(r"[0-9a-f]{32}", segments["run"]) and re.fullmatch(r"[0-9a-f]{64}", segments["head"])
    assert segments["fields"] == [
        {"name": "q", "dtype": "<f8", "shape": [3], "rows": 20},
        {"name": "result", "dtype": "<i4", "shape": [], "rows": 20},
        {"name": "ok", "dtype": "|b1", "shape": [], "rows": 20},
    ]
    # the rows are in one segment file, named by its index and its chain digest
    (name,) = segment_files(path)
    assert name == f"000000-{segments['head'][:16]}.npz"
    with np.load(os.path.join(C.rows_directory(path), name), allow_pickle=False) as seg:
        assert set(seg.files) == {"__format__", "__version__", "segment", "rows/q", "rows/result", "rows/ok"}
        assert str(seg["__format__"]) == C.ROWS_FORMAT == "lobattodae-checkpoint-rows"
        assert int(seg["__version__"]) == 13
        info = json.loads(str(seg["segment"]))
        assert info["run"] == segments["run"] and info["index"] == 0
        for key in rows:
            assert seg["rows/" + key].tobytes() == rows[key].tobytes()
    # the chain: d_-1 from the run, d_0 from d_-1, the index and the rows (documented in the module)
    import hashlib

    seed = hashlib.sha256(f"lobattodae-checkpoint-rows:{segments['run']}".encode()).hexdigest()
    assert info["previous"] == seed
    h = hashlib.sha256(f"{seed}:0".encode())
    for key in ("q", "result", "ok"):
        h.update(f"|{key}|{rows[key].dtype.str}|{rows[key].shape}|".encode() + rows[key].tobytes())
    assert h.hexdigest() == segments["head"]


def test_safe_dtype_casts_are_applied_on_load(tmp_path):
    path = tmp_path / "run.npz"
    state = make_state()
    write(path, state=state._replace(stepper=state.stepper._replace(slopes=np.ones((2, 3), np.int32))))
    got = read(path).state
    assert got.stepper.slopes.dtype == jnp.float64
    np.testing.assert_array_equal(np.asarray(got.stepper.slopes), np.ones((2, 3)))


def test_save_accepts_str_and_pathlike(tmp_path):
    write(str(tmp_path / "a.npz"))
    write(tmp_path / "b.npz")
    read(tmp_path / "a.npz")
    read(str(tmp_path / "b.npz"))
    assert C.exists(tmp_path / "a.npz") and C.exists(str(tmp_path / "b.npz"))
    assert not C.exists(tmp_path / "c.npz")


def test_save_rejects_non_numeric_and_bad_counters(tmp_path):
    path = tmp_path / "run.npz"
    with pytest.raises(TypeError, match="counter 'done'"):
        write(path, counters={"done": "twenty"})
    with pytest.raises(TypeError, match="not a numeric array"):
        write(path, rows={"q": np.array([object()])})
    assert os.listdir(tmp_path) == []


# --------------------------------------------------------------------------------------------
# wrong run, wrong version


def test_meta_mismatch_lists_differing_keys(tmp_path):
    path = tmp_path / "run.npz"
    write(path)
    other = dict(META, h=0.02, q0="zzz", extra=1)
    with pytest.raises(C.CheckpointError) as info:
        read(path, meta=other)
    msg = str(info.value)
    assert msg.startswith(f"checkpoint '{path}' belongs to a different run (differs in: extra, h, q0); ")
    assert "resume with the same problem, method, args, t_span, step and initial values, or delete it" in msg
    # A JSON round trip is not a difference (tuple vs list, int vs float); the meta check comes
    # before the state check, so a run with another n is reported as another run.
    read(path, meta=dict(META, t_span=(0, 10.0)))
    with pytest.raises(C.CheckpointError, match=r"differs in: h\)"):
        read(path, meta=dict(META, h=0.5), template=make_state(n=5))


def test_meta_with_nan_matches_itself(tmp_path):
    path = tmp_path / "run.npz"
    meta = dict(META, tol=float("nan"))
    write(path, meta=meta)
    read(path, meta=meta)


@pytest.mark.parametrize("version, age", [(11, "an older"), (12, "an older"), (14, "a newer")])
def test_version_mismatch(tmp_path, monkeypatch, version, age):
    path = tmp_path / "run.npz"
    with monkeypatch.context() as m:
        m.setattr(C, "VERSION", version)
        write(path)
    with pytest.raises(C.CheckpointError) as info:
        read(path)
    msg = str(info.value)
    assert msg.startswith(f"checkpoint '{path}' has checkpoint format version {version} (written by {age} "), msg
    assert "this lobattodae reads and writes version 13" in msg
    assert "delete it or restart without resume" in msg


def test_legacy_leaf_layout_is_reported_as_version_1(tmp_path):
    path = tmp_path / "run.npz"
    legacy_meta = {"format": "lobattodae-checkpoint-1", "method": "x", "t0": 0.0}
    with open(path, "wb") as fh:
        np.savez(fh, meta=json.dumps(legacy_meta), done=3, recoveries=0, leaf_0=np.zeros(3), out_q=np.zeros((3, 2)))
    with pytest.raises(C.CheckpointError, match="has checkpoint format version 1 .* reads and writes version 13"):
        read(path)


def test_version_3_single_file_is_refused_with_the_version_message(tmp_path):
    """A file as lobattodae wrote it before incremental checkpoints: rows inside the main file."""
    path = tmp_path / "run.npz"
    np.savez(path, **{"__format__": C.FORMAT, "__version__": np.int64(3), "meta": json.dumps(META),
                      "counters": json.dumps(COUNTERS), "state/y.q": np.zeros(3), "rows/q": np.zeros((2, 3))})
    with pytest.raises(C.CheckpointError) as info:
        read(path)
    assert str(info.value) == (
        f"checkpoint '{path}' has checkpoint format version 3 (written by an older lobattodae), but this "
        "lobattodae reads and writes version 13; delete it or restart without resume."
    )


def test_checkpoint_error_is_an_input_error():
    assert issubclass(C.CheckpointError, LobattoDAEInputError)
    assert issubclass(C.CheckpointError, ValueError)


def test_state_schema_is_versioned():
    """Changing the loop State (a field, a dtype, a rank) without bumping the checkpoint VERSION
    and recording the new fingerprint fails here: the states of constant steps and of error
    control (the PI controller's memory and step doubling's state) together."""
    from lobattodae._controllers import ConstantStepSize, ControlOptions, PIController
    from lobattodae._chunks import init_host
    from lobattodae._doubling import for_error_control
    from lobattodae._io.fingerprint import schema_fingerprint
    from lobattodae._loop import Output

    ex = get_example("falling-disk-general")
    f64 = lambda x: jnp.asarray(x, jnp.float64)  # noqa: E731
    start = (f64(0.0), f64(1.0))
    fixed, _ = init_host(ex.problem, L.LobattoIIIAIIIB(stages=4), ConstantStepSize(), Output(), *start,
                         ControlOptions(n=10), f64(ex.q0), f64(ex.p0), f64(ex.lam0), ex.args)
    control = ControlOptions(rtol=f64(1e-8), atol=f64(1e-8), first_step=f64(0.0), max_step=f64(np.inf))
    # as solve runs it: the method adapted to the controller (step doubling's state)
    method = for_error_control(L.LobattoIIIAIIIB(stages=4), PIController())
    adaptive, _ = init_host(ex.problem, method, PIController(), Output(), *start, control,
                            f64(ex.q0), f64(ex.p0), f64(ex.lam0), ex.args)
    assert schema_fingerprint((fixed, adaptive)) == C.STATE_FINGERPRINT, (
        "the loop State changed: bump lobattodae._io.checkpoint.VERSION and record the new STATE_FINGERPRINT"
    )


# --------------------------------------------------------------------------------------------
# corrupt files: always CheckpointError with the clear message, never a raw exception


@pytest.mark.parametrize("fraction", [0.0, 0.01, 0.1, 0.5, 0.9, 0.99])
def test_truncated_file(tmp_path, fraction):
    path = tmp_path / "run.npz"
    write(path)
    blob = path.read_bytes()
    cut = max(1, int(len(blob) * fraction))
    path.write_bytes(blob[:cut])
    expect_corrupt(path)


def test_truncated_at_every_position(tmp_path):
    path, bad = tmp_path / "run.npz", tmp_path / "bad.npz"
    write(path, rows={"q": np.zeros((2, 3))}, state=Y(jnp.zeros(2), jnp.zeros(2)))
    copy_checkpoint(path, bad)  # intact segments: only the main file is cut
    read(bad, template=Y(jnp.zeros(2), jnp.zeros(2)), row_names=["q"])
    blob = path.read_bytes()
    for cut in range(1, len(blob), 13):
        bad.write_bytes(blob[:cut])
        expect_corrupt(bad, template=Y(jnp.zeros(2), jnp.zeros(2)), row_names=["q"])


def test_flipped_byte_in_data_fails_crc(tmp_path):
    path = tmp_path / "run.npz"
    rows = {"q": np.zeros((4000, 3))}  # the middle of the segment file is row data
    write(path, rows=rows)
    (name,) = segment_files(path)
    segment = tmp_path / "run.npz.rows" / name
    blob = bytearray(segment.read_bytes())
    blob[len(blob) // 2] ^= 0x10
    segment.write_bytes(bytes(blob))
    msg = expect_corrupt(path, row_names=["q"])
    assert f"row segment '{segment}'" in msg and "rows/q" in msg and "CRC" in msg


@pytest.mark.parametrize("which", ["main", "segment"])
def test_flipped_bytes_anywhere_never_escape(tmp_path, which):
    path, bad = tmp_path / "run.npz", tmp_path / "bad.npz"
    template = Y(jnp.zeros(2), jnp.zeros(2, jnp.int32))
    write(path, state=template, rows={"q": np.zeros(2)})
    copy_checkpoint(path, bad)
    (name,) = segment_files(bad)
    target = bad if which == "main" else tmp_path / "bad.npz.rows" / name
    blob = target.read_bytes()
    accepted = 0
    for i in range(0, len(blob), 7):
        damaged = bytearray(blob)
        damaged[i] ^= 0xFF
        target.write_bytes(bytes(damaged))
        try:
            _, state, rows, _ = read(bad, template=template, row_names=["q"])
        except C.CheckpointError:
            continue
        # Bytes outside every checksum (timestamps, unused header fields) may be harmless.
        accepted += 1
        assert_bitwise_equal(state, template)
        assert rows["q"].tobytes() == np.zeros(2).tobytes()
    target.write_bytes(blob)
    read(bad, template=template, row_names=["q"])  # the undamaged copy reads: the refusals were the damage
    assert accepted < len(blob) // 7 // 2


def test_empty_file(tmp_path):
    path = tmp_path / "run.npz"
    path.write_bytes(b"")
    assert "empty file" in expect_corrupt(path)


def test_text_file(tmp_path):
    path = tmp_path / "run.npz"
    path.write_text("this is not a checkpoint\n" * 10)
    expect_corrupt(path)


def test_plain_npy_and_pickle(tmp_path):
    path = tmp_path / "run.npz"
    with open(path, "wb") as fh:
        np.save(fh, np.arange(5))
    expect_corrupt(path)
    with open(path, "wb") as fh:
        np.save(fh, np.array([{"a": 1}], dtype=object), allow_pickle=True)
    expect_corrupt(path)


def test_directory_at_path(tmp_path):
    path = tmp_path / "run.npz"
    path.mkdir()
    assert C.exists(path)
    assert "directory" in expect_corrupt(path)


def test_foreign_npz_without_our_keys(tmp_path):
    path = tmp_path / "run.npz"
    np.savez(path, a=np.arange(3), b=np.ones(2))
    assert "__format__" in expect_corrupt(path)


@pytest.mark.parametrize("which", ["main", "segment"])
def test_npz_with_pickled_object_entry(tmp_path, which):
    path = tmp_path / "run.npz"
    write(path)
    target = path if which == "main" else os.path.join(C.rows_directory(path), segment_files(path)[0])
    key = "state/y.q" if which == "main" else "rows/q"
    with np.load(target) as data:
        entries = {k: data[k] for k in data.files}
    entries[key] = np.array([{"x": 1}], dtype=object)
    with open(target, "wb") as fh:
        np.savez(fh, **entries)
    assert key in expect_corrupt(path)


def test_foreign_format(tmp_path):
    path = tmp_path / "run.npz"
    np.savez(path, **{"__format__": "someone-elses-checkpoint", "__version__": 2, "meta": "{}", "counters": "{}"})
    assert "someone-elses-checkpoint" in expect_corrupt(path)


def test_wrong_state_shapes(tmp_path):
    path = tmp_path / "run.npz"
    write(path, state=make_state(n=4))
    assert "shape (4,), expected (3,)" in expect_corrupt(path)


def test_uncastable_dtype(tmp_path):
    path = tmp_path / "run.npz"
    state = make_state()
    write(path, state=state._replace(step=jnp.asarray(17.5)))
    assert "'state/step' has dtype float64, expected int32" in expect_corrupt(path)


def test_missing_and_unexpected_entries(tmp_path):
    path = tmp_path / "run.npz"
    write(path)
    assert "missing entries: rows/extra" in expect_corrupt(path, row_names=ROW_NAMES + ["extra"])
    assert "unexpected entries: rows/ok" in expect_corrupt(path, row_names=["q", "result"])
    template = Y(jnp.zeros(3), jnp.zeros(3))
    assert "missing entries: state/p, state/q" in expect_corrupt(path, template=template)


def test_bad_header_entries(tmp_path):
    path = tmp_path / "run.npz"
    base = {"__format__": C.FORMAT, "__version__": C.VERSION, "meta": json.dumps(META), "counters": "{}"}
    for key, value in [("__version__", float(C.VERSION)), ("meta", "{not json"), ("meta", "[1, 2]"),
                       ("counters", json.dumps({"done": "x"})), ("__format__", np.arange(3))]:
        np.savez(path, **dict(base, **{key: value}))
        expect_corrupt(path)


def test_dangling_symlink(tmp_path):
    path = tmp_path / "run.npz"
    path.symlink_to(tmp_path / "gone.npz")
    assert C.exists(path)
    assert "symbolic link" in expect_corrupt(path)


def test_missing_file_is_for_the_caller(tmp_path):
    path = tmp_path / "nothing.npz"
    assert not C.exists(path)
    with pytest.raises(C.CheckpointError, match="does not exist"):
        read(path)


# --------------------------------------------------------------------------------------------
# atomic writes


def test_save_replaces_previous_checkpoint(tmp_path):
    path = tmp_path / "run.npz"
    write(path, counters={"done": 1}, rows=make_rows(seed=1))
    new = make_rows(seed=2)
    segments = C.save(path, meta=META, counters={"done": 2}, state=make_state(), rows=new)
    counters, _, rows, _ = read(path)
    assert counters == {"done": 2} and all(rows[k].tobytes() == new[k].tobytes() for k in new)
    assert leftovers(tmp_path, ["run.npz", "run.npz.rows"]) == []
    assert segment_files(path) == list(segments.files)  # the replaced checkpoint's segment is gone


def test_failed_conversion_leaves_nothing_behind(tmp_path):
    path = tmp_path / "run.npz"
    write(path, counters={"done": 1})

    class Unconvertible:
        def __array__(self, *args, **kwargs):
            raise RuntimeError("cannot convert")

    state = make_state()
    before = segment_files(path)
    with pytest.raises(RuntimeError, match="cannot convert"):
        write(path, state=state._replace(step=Unconvertible()), counters={"done": 2})
    assert leftovers(tmp_path, ["run.npz", "run.npz.rows"]) == []
    assert segment_files(path) == before
    assert read(path)[0] == {"done": 1}


@pytest.mark.parametrize("error", [OSError("disk full"), KeyboardInterrupt()])
@pytest.mark.parametrize("failing", ["segment", "main"])
def test_failed_write_removes_temp_file_and_keeps_old_checkpoint(tmp_path, monkeypatch, error, failing):
    """A save writes the new segment, then the main file: a failure in either leaves the old
    checkpoint as it was (a new segment that was written is simply not listed)."""
    path = tmp_path / "run.npz"
    old = make_rows(seed=1)
    write(path, counters={"done": 1}, rows=old)
    before = segment_files(path)
    real_savez = np.savez
    calls = []

    def failing_savez(fh, **payload):
        real_savez(fh, **payload)
        calls.append(payload["__format__"].item())
        if len(calls) == (1 if failing == "segment" else 2):
            raise error

    monkeypatch.setattr(np, "savez", failing_savez)
    with pytest.raises(type(error)):
        write(path, counters={"done": 2}, rows=make_rows(seed=2))
    monkeypatch.undo()
    assert calls[-1] == (C.ROWS_FORMAT if failing == "segment" else C.FORMAT)
    assert leftovers(tmp_path, ["run.npz", "run.npz.rows"]) == []
    after = segment_files(path)
    assert after == before if failing == "segment" else (len(after) == 2 and set(before) < set(after))
    counters, _, rows, _ = read(path)
    assert counters == {"done": 1} and all(rows[k].tobytes() == old[k].tobytes() for k in old)
    write(path, counters={"done": 3})  # the next fresh save removes the unlisted segment
    assert len(segment_files(path)) == 1


def test_symlink_at_naive_temp_name_is_not_followed(tmp_path):
    path = tmp_path / "run.npz"
    victim = tmp_path / "victim.txt"
    victim.write_text("precious")
    naive_tmp = tmp_path / "run.npz.tmp"
    naive_tmp.symlink_to(victim)
    write(path)
    assert victim.read_text() == "precious"
    assert naive_tmp.is_symlink() and os.readlink(naive_tmp) == str(victim)
    read(path)
    assert leftovers(tmp_path, ["run.npz", "run.npz.rows", "victim.txt", "run.npz.tmp"]) == []


def test_concurrent_saves_to_the_same_path(tmp_path):
    path = tmp_path / "run.npz"
    errors = []
    states = [make_state(seed=s) for s in range(2)]

    def worker(k):
        try:
            for i in range(5):
                write(path, state=states[k], counters={"done": i, "worker": k})
        except BaseException as exc:  # pragma: no cover
            errors.append(exc)

    threads = [threading.Thread(target=worker, args=(k,)) for k in range(2)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert errors == []
    counters, state, _, segments = read(path)
    assert counters["done"] == 4
    assert_bitwise_equal(state, states[counters["worker"]])
    assert leftovers(tmp_path, ["run.npz", "run.npz.rows"]) == []
    assert segment_files(path) == list(segments.files)  # the last commit's segment, nothing else


def test_new_file_gets_ordinary_permissions(tmp_path):
    path = tmp_path / "run.npz"
    write(path)
    umask = os.umask(0)
    os.umask(umask)
    assert os.stat(path).st_mode & 0o777 == 0o666 & ~umask
    (name,) = segment_files(path)
    assert os.stat(tmp_path / "run.npz.rows" / name).st_mode & 0o777 == 0o666 & ~umask


# --------------------------------------------------------------------------------------------
# incremental rows: segments appended, never rewritten, chained to their main file


def append_saves(path, parts, state=None):
    """A fresh save of parts[0], then one incremental save per further part; the Segments of each."""
    out, previous = [], None
    for i, rows in enumerate(parts):
        previous = C.save(path, meta=META, counters={"done": i}, state=make_state() if state is None else state,
                          rows=rows, previous=previous)
        out.append(previous)
    return out


def concat_rows(parts):
    return {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}


def test_incremental_saves_append_segments_and_never_rewrite_them(tmp_path):
    path = tmp_path / "run.npz"
    parts = [make_rows(k=5 + i, seed=i) for i in range(6)]
    saved = append_saves(path, parts[:3])
    directory = C.rows_directory(path)
    first = {name: (os.stat(os.path.join(directory, name)), open(os.path.join(directory, name), "rb").read())
             for name in saved[-1].files}
    saved += append_saves_after(path, saved[-1], parts[3:])
    assert [len(s.files) for s in saved] == [1, 2, 3, 4, 5, 6]
    assert [s.counts[0] for s in saved] == list(np.cumsum([len(p["q"]) for p in parts]))
    assert segment_files(path) == list(saved[-1].files)
    for name, (st, blob) in first.items():  # written once: same inode, same time, same bytes
        now = os.stat(os.path.join(directory, name))
        assert (now.st_ino, now.st_mtime_ns, now.st_size) == (st.st_ino, st.st_mtime_ns, st.st_size)
        assert open(os.path.join(directory, name), "rb").read() == blob
    counters, _, rows, segments = read(path)
    assert counters == {"done": 2} and segments == dataclasses.replace(saved[-1], tidy=False)
    expected = concat_rows(parts)
    for name in ROW_NAMES:
        assert rows[name].dtype == expected[name].dtype and rows[name].tobytes() == expected[name].tobytes()


def append_saves_after(path, previous, parts):
    out = []
    for rows in parts:
        previous = C.save(path, meta=META, counters={"done": 2}, state=make_state(), rows=rows, previous=previous)
        out.append(previous)
    return out


def test_bytes_written_grow_with_the_rows_not_with_the_saves(tmp_path):
    """100 saves of 10 rows each write (up to a small per-segment overhead) what one save of the
    1000 rows writes; the main file stays the size of the state."""
    many, once = tmp_path / "many.npz", tmp_path / "once.npz"
    parts = [make_rows(k=10, seed=i) for i in range(100)]
    append_saves(many, parts)
    append_saves(once, [concat_rows(parts)])
    def size(path):
        return sum(os.path.getsize(os.path.join(C.rows_directory(path), f)) for f in segment_files(path))

    overhead = 2500  # bytes per segment file: zip64 and .npy headers of 6 entries, JSON in UTF-32 (measured 2.2 kB)
    assert len(segment_files(many)) == 100 and len(segment_files(once)) == 1
    assert size(once) <= size(many) <= size(once) + 100 * overhead
    row_bytes = sum(v.nbytes for v in concat_rows(parts).values())
    assert size(once) <= row_bytes + overhead
    assert abs(os.path.getsize(many) - os.path.getsize(once)) < 100  # the main file: no rows in it
    assert read(many)[2]["q"].tobytes() == read(once)[2]["q"].tobytes()


def test_a_save_without_new_rows_writes_no_segment(tmp_path):
    path = tmp_path / "run.npz"
    first = C.save(path, meta=META, counters={"done": 1}, state=make_state(), rows=make_rows())
    empty = {k: v[:0] for k, v in make_rows().items()}
    second = C.save(path, meta=META, counters={"done": 2}, state=make_state(), rows=empty, previous=first)
    assert second.files == first.files and second.head == first.head
    assert segment_files(path) == list(first.files)
    assert read(path)[0] == {"done": 2}
    # a fresh checkpoint with no rows at all keeps the fields' dtypes and shapes
    C.save(path, meta=META, counters={}, state=make_state(), rows=empty)
    assert segment_files(path) == []
    rows = read(path)[2]
    assert {k: (v.dtype, v.shape) for k, v in rows.items()} == {k: (v.dtype, v.shape) for k, v in empty.items()}


def test_appended_rows_must_continue_the_fields(tmp_path):
    path = tmp_path / "run.npz"
    first = C.save(path, meta=META, counters={}, state=make_state(), rows=make_rows())
    rows = make_rows()
    bad = [
        dict(rows, q=rows["q"][:, :2]),  # trailing shape
        dict(rows, result=rows["result"].astype(np.int64)),  # dtype
        {k: v for k, v in rows.items() if k != "ok"},  # a field missing
        dict(rows, extra=rows["q"]),  # a field added
    ]
    for new in bad:
        with pytest.raises(TypeError, match="must continue the checkpoint's fields"):
            C.save(path, meta=META, counters={}, state=make_state(), rows=new, previous=first)
    with pytest.raises(TypeError, match="0-d array"):
        C.save(path, meta=META, counters={}, state=make_state(), rows={"x": np.float64(2.5)})
    with pytest.raises(TypeError, match="not a numeric array"):
        C.save(path, meta=META, counters={}, state=make_state(), rows={"x": np.array(["a", "b"])})
    assert segment_files(path) == list(first.files)  # nothing was written
    read(path)
    # the order of the keys does not matter
    C.save(path, meta=META, counters={}, state=make_state(), rows=dict(reversed(list(rows.items()))), previous=first)


def test_crash_between_segment_and_main_file_keeps_the_last_commit(tmp_path, monkeypatch):
    """The main file is the commit point: a segment written by a save that died before its main
    file is not read, the run appends after the last commit, and the unlisted segment is
    replaced or removed."""
    path = tmp_path / "run.npz"
    parts = [make_rows(k=4, seed=i) for i in range(4)]
    saved = append_saves(path, parts[:2])
    real = atomic.write_npz

    def crash_on_main(target, payload):
        if os.fspath(target) == os.fspath(path):
            raise KeyboardInterrupt  # killed after the segment, before the commit
        real(target, payload)

    monkeypatch.setattr(atomic, "write_npz", crash_on_main)
    with pytest.raises(KeyboardInterrupt):
        C.save(path, meta=META, counters={"done": 99}, state=make_state(), rows=parts[2], previous=saved[-1])
    monkeypatch.undo()
    assert len(segment_files(path)) == 3  # the orphan is there, unlisted
    counters, _, rows, segments = read(path)
    assert counters == {"done": 1} and rows["q"].tobytes() == concat_rows(parts[:2])["q"].tobytes()
    # resuming appends other rows at the same index: the orphan is not mixed in, and goes away
    resumed = append_saves_after(path, segments, [parts[3]])[-1]
    assert segment_files(path) == list(resumed.files) and len(resumed.files) == 3
    rows = read(path)[2]
    assert rows["q"].tobytes() == concat_rows(parts[:2] + [parts[3]])["q"].tobytes()


def test_fresh_checkpoint_leaves_the_old_one_intact_until_it_commits(tmp_path, monkeypatch):
    path = tmp_path / "run.npz"
    old = [make_rows(k=3, seed=i) for i in range(3)]
    append_saves(path, old)
    real = atomic.write_npz
    monkeypatch.setattr(atomic, "write_npz",
                        lambda target, payload: (_ for _ in ()).throw(OSError("disk full"))
                        if os.fspath(target) == os.fspath(path) else real(target, payload))
    with pytest.raises(OSError, match="disk full"):
        write(path, rows=make_rows(k=2, seed=9))  # a fresh save dies before its commit
    monkeypatch.undo()
    assert len(segment_files(path)) == 4
    assert read(path)[2]["q"].tobytes() == concat_rows(old)["q"].tobytes()  # the old checkpoint reads
    new = make_rows(k=2, seed=10)
    segments = C.save(path, meta=META, counters={}, state=make_state(), rows=new)
    assert segment_files(path) == list(segments.files) and len(segments.files) == 1
    assert read(path)[2]["q"].tobytes() == new["q"].tobytes()


def test_missing_segment(tmp_path):
    path = tmp_path / "run.npz"
    saved = append_saves(path, [make_rows(k=3, seed=i) for i in range(3)])
    gone = tmp_path / "run.npz.rows" / saved[-1].files[1]
    gone.unlink()
    msg = expect_corrupt(path)
    assert f"row segment '{gone}' is missing" in msg
    shutil.rmtree(tmp_path / "run.npz.rows")
    assert "is missing" in expect_corrupt(path)


@pytest.mark.parametrize("fraction", [0.0, 0.3, 0.9, 0.999])
def test_truncated_segment(tmp_path, fraction):
    path = tmp_path / "run.npz"
    saved = append_saves(path, [make_rows(k=3, seed=i) for i in range(3)])
    segment = tmp_path / "run.npz.rows" / saved[-1].files[0]
    blob = segment.read_bytes()
    segment.write_bytes(blob[: int(len(blob) * fraction)])
    msg = expect_corrupt(path)
    assert f"row segment '{segment}'" in msg


def test_segment_of_another_run_or_stale_is_refused(tmp_path):
    """Segments are chained to their main file: a segment file with the right name but other
    rows (another checkpoint's, or an earlier run's) is refused, never mixed in."""
    path, other = tmp_path / "run.npz", tmp_path / "other.npz"
    saved = append_saves(path, [make_rows(k=3, seed=i) for i in range(2)])
    foreign = append_saves(other, [make_rows(k=3, seed=i + 5) for i in range(2)])
    directory = tmp_path / "run.npz.rows"
    original = (directory / saved[-1].files[1]).read_bytes()
    # another checkpoint's segment under this one's name
    shutil.copyfile(tmp_path / "other.npz.rows" / foreign[-1].files[1], directory / saved[-1].files[1])
    assert "does not belong to this checkpoint" in expect_corrupt(path)
    # the same run's rows, changed: a valid archive with the right run and index but other rows
    with np.load(tmp_path / "other.npz.rows" / foreign[-1].files[1]) as data:
        entries = {k: data[k] for k in data.files}
    with np.load(directory / saved[-1].files[0]) as data:
        run = json.loads(str(data["segment"]))["run"]
    info = json.loads(str(entries["segment"]))
    entries["segment"] = np.asarray(json.dumps(dict(info, run=run)))
    with open(directory / saved[-1].files[1], "wb") as fh:
        np.savez(fh, **entries)
    assert "are not the ones the checkpoint committed" in expect_corrupt(path)
    (directory / saved[-1].files[1]).write_bytes(original)
    read(path)


def test_segment_with_wrong_fields(tmp_path):
    path = tmp_path / "run.npz"
    saved = append_saves(path, [make_rows(k=3)])
    segment = tmp_path / "run.npz.rows" / saved[-1].files[0]
    with np.load(segment) as data:
        entries = {k: data[k] for k in data.files}
    for key, value, reason in [
        ("rows/q", np.zeros((3, 4)), "'rows/q' has shape (3, 4) of float64, expected (k, 3) of float64"),
        ("rows/result", np.zeros(3), "'rows/result' has shape (3,) of float64, expected (k) of int32"),
        ("rows/extra", np.zeros(3), "unexpected entries: rows/extra"),
        ("__format__", "lobattodae-checkpoint", "format 'lobattodae-checkpoint', expected"),
    ]:
        with open(segment, "wb") as fh:
            np.savez(fh, **dict(entries, **{key: value}))
        assert reason in expect_corrupt(path)


def test_malformed_segments_entry(tmp_path):
    path = tmp_path / "run.npz"
    write(path)
    with np.load(path) as data:
        entries = {k: data[k] for k in data.files}
    good = json.loads(str(entries["segments"]))
    field = good["fields"][0]
    for change in [{"run": "xyz"}, {"count": -1}, {"count": True}, {"head": "0" * 64}, {"fields": {}},
                   {"fields": [dict(field, dtype="O")]}, {"fields": [dict(field, dtype="<U3")]},
                   {"fields": [dict(field, shape=[-1])]}, {"fields": [dict(field, shape=[1] * 40)]},
                   {"fields": [field, field]}, {"fields": [dict(field, rows=2.5)]}, {"count": 2}]:
        with open(path, "wb") as fh:
            np.savez(fh, **dict(entries, segments=json.dumps(dict(good, **change))))
        expect_corrupt(path)
    with open(path, "wb") as fh:  # a row count that does not add up
        wrong = dict(good, fields=[dict(field, rows=21)] + good["fields"][1:])
        np.savez(fh, **dict(entries, segments=json.dumps(wrong)))
    assert "its segments hold 20 rows of 'q', its 'segments' entry says 21" in expect_corrupt(path)


def test_rows_directory_is_next_to_the_file(tmp_path):
    assert C.rows_directory(tmp_path / "run.npz") == str(tmp_path / "run.npz") + ".rows"
    assert C.rows_directory("run.npz") == "run.npz.rows"
