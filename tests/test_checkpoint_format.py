"""The checkpoint file format (lobattodae._checkpoint): schema, atomic writes, clear errors, fingerprints."""

import functools
import json
import os
import re
import subprocess
import sys
import textwrap
import threading
from dataclasses import dataclass
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from lobattodae import _checkpoint as C
from lobattodae._errors import LobattoDAEInputError


class Jac(NamedTuple):
    inverse: Any
    valid: Any


class Stepper(NamedTuple):
    jacobian: Jac
    slopes: Any


class Y(NamedTuple):
    q: Any
    p: Any


class State(NamedTuple):
    y: Y
    stepper: Stepper
    step: Any


def make_state(n=3, seed=0):
    rng = np.random.default_rng(seed)
    return State(
        y=Y(jnp.asarray(rng.standard_normal(n)), jnp.asarray(rng.standard_normal(n))),
        stepper=Stepper(Jac(jnp.asarray(rng.standard_normal((n, n))), jnp.asarray(True)),
                        jnp.asarray(rng.standard_normal((2, n)))),
        step=jnp.asarray(17, jnp.int32),
    )


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


def assert_bitwise_equal(a, b):
    la, ta = jax.tree_util.tree_flatten(a)
    lb, tb = jax.tree_util.tree_flatten(b)
    assert ta == tb
    for x, y in zip(la, lb):
        x, y = np.asarray(x), np.asarray(y)
        assert x.dtype == y.dtype and x.shape == y.shape
        assert x.tobytes() == y.tobytes()


def leftovers(directory, keep):
    return sorted(set(os.listdir(directory)) - set(keep))


# --------------------------------------------------------------------------------------------
# round trip and schema


def test_round_trip_is_bitwise(tmp_path):
    path = tmp_path / "run.npz"
    state, rows = make_state(), make_rows()
    state = state._replace(y=Y(state.y.q.at[0].set(-0.0), state.y.p.at[1].set(jnp.nan)))
    C.save(path, meta=META, counters=COUNTERS, state=state, rows=rows)
    counters, got, got_rows = C.load(path, meta=META, state_template=make_state(), row_names=ROW_NAMES)
    assert counters == COUNTERS and type(counters["done"]) is int and type(counters["elapsed"]) is float
    assert_bitwise_equal(got, state)
    assert all(isinstance(x, jax.Array) for x in jax.tree_util.tree_leaves(got))
    assert got.stepper.jacobian.valid.dtype == jnp.bool_ and got.step.dtype == jnp.int32
    assert list(got_rows) == ROW_NAMES
    for name in ROW_NAMES:
        assert got_rows[name].dtype == rows[name].dtype
        assert got_rows[name].tobytes() == rows[name].tobytes()
    assert leftovers(tmp_path, ["run.npz"]) == []


def test_round_trip_of_unusual_layouts(tmp_path):
    path = tmp_path / "run.npz"
    rows = {
        "fortran": np.asfortranarray(np.arange(12.0).reshape(3, 4)),
        "transposed": np.arange(6, dtype=np.int32).reshape(2, 3).T,
        "empty": np.zeros((0, 3)),
        "complex": np.array([1 + 2j, -0.0 - 1j]),
        "scalar": np.float64(2.5),
    }
    template = {"a": jnp.zeros((2, 0)), "b": (jnp.zeros(()), jnp.zeros(1, jnp.uint8))}
    C.save(path, meta={}, counters={}, state=template, rows=rows)
    counters, state, got = C.load(path, meta={}, state_template=template, row_names=list(rows))
    assert counters == {}
    assert_bitwise_equal(state, template)
    for name, value in rows.items():
        np.testing.assert_array_equal(got[name], value)
        assert got[name].dtype == np.asarray(value).dtype and got[name].flags.writeable


def test_file_schema_is_explicit(tmp_path):
    path = str(tmp_path / "run.npz")
    write(path)
    with np.load(path, allow_pickle=False) as data:
        keys = set(data.files)
        assert str(data["__format__"]) == C.FORMAT == "lobattodae-checkpoint"
        assert int(data["__version__"]) == C.VERSION == 3
        assert json.loads(str(data["meta"])) == META
        assert json.loads(str(data["counters"])) == COUNTERS
    assert keys == {
        "__format__", "__version__", "meta", "counters",
        "state/y.q", "state/y.p", "state/stepper.jacobian.inverse", "state/stepper.jacobian.valid",
        "state/stepper.slopes", "state/step", "rows/q", "rows/result", "rows/ok",
    }


def test_state_fields_are_dotted_names():
    assert C.state_fields(make_state(n=4)) == [
        ("y.q", "float64", (4,)),
        ("y.p", "float64", (4,)),
        ("stepper.jacobian.inverse", "float64", (4, 4)),
        ("stepper.jacobian.valid", "bool", ()),
        ("stepper.slopes", "float64", (2, 4)),
        ("step", "int32", ()),
    ]
    struct = jax.ShapeDtypeStruct((4,), jnp.float64)
    assert C.state_fields(Y(struct, np.zeros(2, np.int32))) == [("q", "float64", (4,)), ("p", "int32", (2,))]


def test_safe_dtype_casts_are_applied_on_load(tmp_path):
    path = tmp_path / "run.npz"
    state = make_state()
    write(path, state=state._replace(stepper=state.stepper._replace(slopes=np.ones((2, 3), np.int32))))
    _, got, _ = read(path)
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


@pytest.mark.parametrize("version, age", [(2, "an older"), (4, "a newer")])
def test_version_mismatch(tmp_path, monkeypatch, version, age):
    path = tmp_path / "run.npz"
    with monkeypatch.context() as m:
        m.setattr(C, "VERSION", version)
        write(path)
    with pytest.raises(C.CheckpointError) as info:
        read(path)
    msg = str(info.value)
    assert msg.startswith(f"checkpoint '{path}' has checkpoint format version {version} (written by {age} "), msg
    assert "this lobattodae reads and writes version 3" in msg
    assert "delete it or restart without resume" in msg


def test_legacy_leaf_layout_is_reported_as_version_1(tmp_path):
    path = tmp_path / "run.npz"
    legacy_meta = {"format": "lobattodae-checkpoint-1", "method": "x", "t0": 0.0}
    with open(path, "wb") as fh:
        np.savez(fh, meta=json.dumps(legacy_meta), done=3, recoveries=0, leaf_0=np.zeros(3), out_q=np.zeros((3, 2)))
    with pytest.raises(C.CheckpointError, match="has checkpoint format version 1 .* reads and writes version 3"):
        read(path)


def test_checkpoint_error_is_an_input_error():
    assert issubclass(C.CheckpointError, LobattoDAEInputError)
    assert issubclass(C.CheckpointError, ValueError)


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
    blob = path.read_bytes()
    for cut in range(1, len(blob), 13):
        bad.write_bytes(blob[:cut])
        expect_corrupt(bad, template=Y(jnp.zeros(2), jnp.zeros(2)), row_names=["q"])


def test_flipped_byte_in_data_fails_crc(tmp_path):
    path = tmp_path / "run.npz"
    rows = {"q": np.zeros((4000, 3))}  # the middle of the file is row data
    write(path, rows=rows)
    blob = bytearray(path.read_bytes())
    blob[len(blob) // 2] ^= 0x10
    path.write_bytes(bytes(blob))
    msg = expect_corrupt(path, row_names=["q"])
    assert "rows/q" in msg and "CRC" in msg


def test_flipped_bytes_anywhere_never_escape(tmp_path):
    path, bad = tmp_path / "run.npz", tmp_path / "bad.npz"
    template = Y(jnp.zeros(2), jnp.zeros(2, jnp.int32))
    write(path, state=template, rows={"q": np.zeros(2)})
    blob = path.read_bytes()
    for i in range(0, len(blob), 7):
        damaged = bytearray(blob)
        damaged[i] ^= 0xFF
        bad.write_bytes(bytes(damaged))
        try:
            _, state, rows = read(bad, template=template, row_names=["q"])
        except C.CheckpointError:
            continue
        # Bytes outside every checksum (timestamps, unused header fields) may be harmless.
        assert_bitwise_equal(state, template)
        assert rows["q"].tobytes() == np.zeros(2).tobytes()


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


def test_npz_with_pickled_object_entry(tmp_path):
    path = tmp_path / "run.npz"
    write(path)
    with np.load(path) as data:
        entries = {k: data[k] for k in data.files}
    entries["rows/q"] = np.array([{"x": 1}], dtype=object)
    np.savez(path, **entries)
    assert "rows/q" in expect_corrupt(path)


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
    write(path, counters={"done": 1})
    write(path, counters={"done": 2})
    assert read(path)[0] == {"done": 2}
    assert leftovers(tmp_path, ["run.npz"]) == []


def test_failed_conversion_leaves_nothing_behind(tmp_path):
    path = tmp_path / "run.npz"
    write(path, counters={"done": 1})

    class Unconvertible:
        def __array__(self, *args, **kwargs):
            raise RuntimeError("cannot convert")

    state = make_state()
    with pytest.raises(RuntimeError, match="cannot convert"):
        write(path, state=state._replace(step=Unconvertible()), counters={"done": 2})
    assert leftovers(tmp_path, ["run.npz"]) == []
    assert read(path)[0] == {"done": 1}


@pytest.mark.parametrize("error", [OSError("disk full"), KeyboardInterrupt()])
def test_failed_write_removes_temp_file_and_keeps_old_checkpoint(tmp_path, monkeypatch, error):
    path = tmp_path / "run.npz"
    write(path, counters={"done": 1})
    real_savez = np.savez

    def failing_savez(fh, **payload):
        real_savez(fh, **payload)
        raise error

    monkeypatch.setattr(np, "savez", failing_savez)
    with pytest.raises(type(error)):
        write(path, counters={"done": 2})
    monkeypatch.undo()
    assert leftovers(tmp_path, ["run.npz"]) == []
    assert read(path)[0] == {"done": 1}


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
    assert leftovers(tmp_path, ["run.npz", "victim.txt", "run.npz.tmp"]) == []


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
    counters, state, _ = read(path)
    assert counters["done"] == 4
    assert_bitwise_equal(state, states[counters["worker"]])
    assert leftovers(tmp_path, ["run.npz"]) == []


def test_new_file_gets_ordinary_permissions(tmp_path):
    path = tmp_path / "run.npz"
    write(path)
    umask = os.umask(0)
    os.umask(umask)
    assert os.stat(path).st_mode & 0o777 == 0o666 & ~umask


# --------------------------------------------------------------------------------------------
# fingerprints


class StateWithExtra(NamedTuple):
    y: Y
    stepper: Stepper
    step: Any
    extra: Any


class RenamedState(NamedTuple):
    y: Y
    stepper: Stepper
    steps: Any


def test_schema_fingerprint():
    fp = C.schema_fingerprint(make_state(n=3))
    assert re.fullmatch(r"[0-9a-f]{16}", fp)
    assert C.schema_fingerprint(make_state(n=3)) == fp
    assert C.schema_fingerprint(make_state(n=7)) == fp  # sizes are not part of the schema
    s = make_state()
    changed = [
        RenamedState(s.y, s.stepper, s.step),  # renamed field
        StateWithExtra(s.y, s.stepper, s.step, jnp.zeros(3)),  # added field
        s._replace(step=jnp.asarray(17, jnp.int64)),  # dtype
        s._replace(step=jnp.asarray([17], jnp.int32)),  # rank
        s._replace(y=s.y._replace(p=s.stepper.slopes)),  # rank of one field
        Y(s.y.q, s.y.p),  # removed fields
    ]
    fps = {C.schema_fingerprint(t) for t in changed}
    assert fp not in fps and len(fps) == len(changed)
    assert C.STATE_FINGERPRINT is None or re.fullmatch(r"[0-9a-f]{16}", C.STATE_FINGERPRINT)


def test_fingerprint_arrays():
    a, b = np.arange(3.0), {"k": np.int32(2), "v": (1.5, jnp.ones(2))}
    fp = C.fingerprint_arrays(a, b)
    assert re.fullmatch(r"[0-9a-f]{64}", fp)
    assert C.fingerprint_arrays(np.arange(3.0), {"k": np.int32(2), "v": (1.5, jnp.ones(2))}) == fp
    assert C.fingerprint_arrays(jnp.arange(3.0), b) == fp  # numpy and JAX arrays alike
    different = [
        (a + np.array([0, 0, 1e-12]), b),  # values
        (a.astype(np.float32), b),  # dtype
        (a.reshape(1, 3), b),  # shape
        (a,),  # fewer arguments
        ((a, b),),  # grouping
        (np.array([-0.0, 1.0, 2.0]), b),  # bit-exact
    ]
    for args in different:
        assert C.fingerprint_arrays(*args) != fp
    with pytest.raises(TypeError, match="cannot fingerprint"):
        C.fingerprint_arrays(object())


def square(x):
    return x * x


def test_fingerprint_callable_basics():
    f = lambda x: x + 1  # noqa: E731
    g = lambda x: x + 2  # noqa: E731
    h = lambda x: x * 2  # noqa: E731
    assert C.fingerprint_callable(f) == C.fingerprint_callable(f)
    assert len({C.fingerprint_callable(fn) for fn in (f, g, h)}) == 3
    fp = C.fingerprint_callable(square)
    assert fp.startswith(__name__ + ".square#") and re.fullmatch(r".*#[0-9a-f]{16}", fp)
    for _ in range(2000):  # the interpreter specialises hot bytecode; the fingerprint must not change
        square(3.0)
    assert C.fingerprint_callable(square) == fp


def test_fingerprint_callable_sees_closures_defaults_and_nested_code():
    def make(k):
        return lambda x: x + k

    assert C.fingerprint_callable(make(1.0)) == C.fingerprint_callable(make(1.0))
    assert C.fingerprint_callable(make(1.0)) != C.fingerprint_callable(make(2.0))

    def outer1(x):
        def inner(y):
            return y + 1
        return inner(x)

    def outer2(x):
        def inner(y):
            return y + 2
        return inner(x)

    assert outer1.__code__.co_code == outer2.__code__.co_code
    assert C.fingerprint_callable(outer1).split("#")[1] != C.fingerprint_callable(outer2).split("#")[1]

    def with_default(x, c=1.0):
        return x * c

    fp = C.fingerprint_callable(with_default)
    with_default.__defaults__ = (2.0,)
    assert C.fingerprint_callable(with_default) != fp


@dataclass(frozen=True)
class Problem:
    f: Any
    g: Any
    name: str = "p"


def test_fingerprint_callable_of_objects():
    f1 = lambda q: -q  # noqa: E731
    f2 = lambda q: q  # noqa: E731
    p1, p2 = Problem(f1, square), Problem(f2, square)
    assert C.fingerprint_callable(p1) == C.fingerprint_callable(Problem(f1, square))
    assert C.fingerprint_callable(p1) != C.fingerprint_callable(p2)
    assert C.fingerprint_callable(p1) != C.fingerprint_callable(Problem(f1, square, name="q"))
    assert C.fingerprint_callable(p1).startswith(__name__ + ".Problem#")

    part = functools.partial(square, 2.0)
    assert C.fingerprint_callable(part) == C.fingerprint_callable(functools.partial(square, 2.0))
    assert C.fingerprint_callable(part) != C.fingerprint_callable(functools.partial(square, 3.0))
    assert C.fingerprint_callable(jax.jit(square)) == C.fingerprint_callable(jax.jit(square))
    assert C.fingerprint_callable(np.sin) != C.fingerprint_callable(np.cos)

    def rec(n):  # recursion through a closure must terminate
        return 1 if n == 0 else n * rec(n - 1)

    C.fingerprint_callable(rec)


def test_fingerprint_callable_is_stable_across_processes(tmp_path):
    """No hash randomisation (frozenset constants, dict order) leaks into the fingerprint."""
    script = tmp_path / "fp.py"
    script.write_text(textwrap.dedent("""
        from lobattodae._checkpoint import fingerprint_callable, fingerprint_arrays

        def f(x, mode="a"):
            return x if mode in {"a", "b", "c", "d", "e", "f", "g"} else -x

        print(fingerprint_callable(f), fingerprint_arrays({"b": 1.0, "a": 2}))
    """))
    procs = [
        subprocess.Popen([sys.executable, str(script)], stdout=subprocess.PIPE, text=True, cwd=tmp_path,
                         env=dict(os.environ, PYTHONHASHSEED=str(seed), JAX_PLATFORMS="cpu"))
        for seed in (1, 2)
    ]
    outs = [p.communicate(timeout=60)[0] for p in procs]
    assert all(p.returncode == 0 for p in procs)
    assert outs[0] == outs[1] and outs[0].startswith("__main__.f#")
