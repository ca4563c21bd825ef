"""Long runs that lose nothing: checkpoint and resume of ``solve`` and of ``lobattodae run``.

* Interrupted (Ctrl-C, SIGTERM, at random moments) or stopped at a periodic checkpoint, a run
  resumes bit for bit; a resume refuses another run's checkpoint, a damaged one, and a path
  where something else is.
* Checkpoints are incremental (issue #13): each save appends the rows since the last one.
* A checkpoint that cannot be written mid-run (issue #30): a full disk or a read-only
  directory ends ``solve`` with our error, naming the file and the fix, and the computed
  prefix is kept (the error's ``.solution``, or returned with ``throw=False``); the checkpoint
  on disk stays valid and resumes bit for bit. Before: the raw ``OSError`` escaped and the
  prefix was lost.

The file format itself is tested in ``test_io_checkpoint.py``.
"""

import errno
import json
import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

import lobattodae as L
from lobattodae._chunks import CHUNK as RUN_CHUNK
from lobattodae._io import atomic, checkpoint
from lobattodae.examples import get_example

from helpers import RUN_STAGES, RUN_STEPS, cli_method, run_cli, solve_example, stiff_particle

N, CHUNK = 3000, 512
#: the short run of the tests of failed saves
SHORT_N, SHORT_CHUNK, SHORT_EVERY = 96, 16, 16
#: s = 3 under error control
METHOD = L.LobattoIIIAIIIB(stages=3)


@pytest.fixture(scope="module")
def long_run():
    """3000 constant steps of the knife edge (s = 3, Λ₁ consistent) in chunks of 512, uninterrupted."""
    ex = get_example("knife-edge")
    method = L.LobattoIIIAIIIB(stages=3, lam_start="consistent")
    kw = dict(n_steps=N, args=ex.args, chunk_size=CHUNK)
    ref = L.solve(ex.problem, method, (0.0, 30.0), ex.q0, ex.p0, **kw)
    return ex, method, kw, ref


@pytest.fixture(scope="module")
def short_run():
    """96 constant steps of the knife edge (s = 2) in chunks of 16, uninterrupted."""
    ex = get_example("knife-edge")
    method = L.LobattoIIIAIIIB(stages=2)
    kw = dict(n_steps=SHORT_N, args=ex.args, chunk_size=SHORT_CHUNK)
    ref = L.solve(ex.problem, method, (0.0, 3.0), ex.q0, ex.p0, **kw)
    return ex, method, kw, ref


class _StopAfter:
    """A progress callback that simulates Ctrl-C after a number of chunks."""

    def __init__(self, chunks):
        self.left = chunks

    def __call__(self, done, total):
        self.left -= 1
        if self.left == 0:
            raise KeyboardInterrupt


# -- interrupt, resume -------------------------------------------------------------------------------
def test_interrupt_returns_prefix_and_resume_is_bitwise_identical(long_run, tmp_path):
    ex, method, kw, ref = long_run
    path = tmp_path / "run.npz"
    part = L.solve(ex.problem, method, (0.0, 30.0), ex.q0, ex.p0, checkpoint=path, checkpoint_every=1024,
                   progress=_StopAfter(3), **kw)
    assert not part.success and part.result == L.Result.INTERRUPTED
    assert len(part.t) == 3 * CHUNK + 1 and "Interrupted after 1536 of 3000 steps" in part.message
    np.testing.assert_array_equal(part.q, ref.q[: len(part.t)])
    assert path.exists()
    full = L.solve(ex.problem, method, (0.0, 30.0), ex.q0, ex.p0, checkpoint=path, resume=True, **kw)
    assert full.success
    for name in ("t", "q", "p", "lam"):
        np.testing.assert_array_equal(getattr(full, name), getattr(ref, name))
    np.testing.assert_array_equal(full.stats["newton_iterations"], ref.stats["newton_iterations"])
    np.testing.assert_array_equal(full.stats["constraint_residual"], ref.stats["constraint_residual"])


def test_periodic_checkpoint_resume_bitwise(long_run, tmp_path):
    ex, method, kw, ref = long_run
    path = tmp_path / "run.npz"
    # a run that stops at the 2048-step checkpoint (simulating a crash right after it)
    L.solve(ex.problem, method, (0.0, 30.0), ex.q0, ex.p0, checkpoint=path, checkpoint_every=2048,
            progress=_StopAfter(5), **kw)
    with np.load(path) as data:
        assert json.loads(str(data["counters"]))["done"] == 5 * CHUNK
    full = L.solve(ex.problem, method, (0.0, 30.0), ex.q0, ex.p0, checkpoint=path, resume=True, **kw)
    np.testing.assert_array_equal(full.q, ref.q)
    np.testing.assert_array_equal(full.lam, ref.lam)


def test_ctrl_c_before_the_first_chunk_returns_the_initial_point(knife, monkeypatch, tmp_path):
    """The first chunk also builds the loop state; a Ctrl-C that arrives before it (during
    validation or compilation) still returns the initial point with status INTERRUPTED, and a
    checkpoint written then resumes to the uninterrupted numbers."""
    import contextlib

    import lobattodae._solve as S

    ref = solve_example(knife, METHOD, n_steps=40)
    monkeypatch.setattr(S, "deferred_interrupts", lambda: contextlib.nullcontext(lambda: True))
    path = tmp_path / "run.npz"
    sol = solve_example(knife, METHOD, n_steps=40, checkpoint=path)
    assert sol.result == L.Result.INTERRUPTED and sol.stats["n_steps"] == 0
    np.testing.assert_array_equal(sol.t, [knife.t_span[0]])
    np.testing.assert_array_equal(sol.q, np.asarray(knife.q0, np.float64)[None])
    monkeypatch.undo()
    full = solve_example(knife, METHOD, n_steps=40, checkpoint=path, resume=True)
    for name in ("t", "q", "p", "lam"):
        np.testing.assert_array_equal(getattr(full, name), getattr(ref, name))


@pytest.fixture
def ctrl_c_enabled():
    """Ctrl-C handled as in a terminal, also when pytest runs as a background job (which
    ignores SIGINT, and solve then leaves it ignored)."""
    import signal

    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    yield
    signal.signal(signal.SIGINT, previous)


def test_adaptive_resume_is_bitwise_identical(sleigh, tmp_path, ctrl_c_enabled):
    ref = solve_example(sleigh, METHOD, rtol=1e-9, atol=1e-9, chunk_size=16, t_span=(0.0, 20.0))

    class Stop:
        def __init__(self):
            self.calls = 0

        def __call__(self, done, total):
            self.calls += 1
            if self.calls == 3:
                import os
                import signal

                os.kill(os.getpid(), signal.SIGINT)

    path = tmp_path / "run.npz"
    part = solve_example(sleigh, METHOD, rtol=1e-9, atol=1e-9, chunk_size=16, t_span=(0.0, 20.0), checkpoint=path,
                         progress=Stop())
    assert part.result == L.Result.INTERRUPTED and len(part.t) < len(ref.t)
    full = solve_example(sleigh, METHOD, rtol=1e-9, atol=1e-9, chunk_size=16, t_span=(0.0, 20.0), checkpoint=path,
                         resume=True)
    np.testing.assert_array_equal(full.t, ref.t)
    np.testing.assert_array_equal(full.q, ref.q)
    np.testing.assert_array_equal(full.lam, ref.lam)


# -- what a resume refuses ---------------------------------------------------------------------------
def test_resume_rejects_a_different_run(long_run, tmp_path):
    ex, method, kw, _ = long_run
    path = tmp_path / "run.npz"
    L.solve(ex.problem, method, (0.0, 30.0), ex.q0, ex.p0, checkpoint=path, progress=_StopAfter(1), **kw)
    other = L.LobattoIIIAIIIB(stages=4, lam_start="consistent")
    with pytest.raises(L.LobattoDAEInputError, match="different run.*method"):
        L.solve(ex.problem, other, (0.0, 30.0), ex.q0, ex.p0, checkpoint=path, resume=True, **kw)


def test_resume_without_path_is_an_error(long_run):
    ex, method, kw, _ = long_run
    with pytest.raises(L.LobattoDAEInputError, match="checkpoint=PATH"):
        L.solve(ex.problem, method, (0.0, 30.0), ex.q0, ex.p0, resume=True, **kw)


def test_resume_rejects_changed_args_and_problem(long_run, tmp_path):
    ex, method, kw, _ = long_run
    path = tmp_path / "run.npz"
    L.solve(ex.problem, method, (0.0, 30.0), ex.q0, ex.p0, checkpoint=path, progress=_StopAfter(1), **kw)
    changed = dict(kw, args=ex.args._replace(g=ex.args.g * 1.01))
    with pytest.raises(L.LobattoDAEInputError, match="different run.*args"):
        L.solve(ex.problem, method, (0.0, 30.0), ex.q0, ex.p0, checkpoint=path, resume=True, **changed)
    other = L.NonholonomicSystem(lambda t, q, p, a: 0.5 * p @ p + a.m * a.g * q[0], ex.problem.constraint_matrix)
    with pytest.raises(L.LobattoDAEInputError, match="different run.*problem"):
        L.solve(other, method, (0.0, 30.0), ex.q0, ex.p0, checkpoint=path, resume=True, **kw)


def test_corrupted_checkpoint_is_refused_with_one_clear_error(long_run, tmp_path):
    ex, method, kw, _ = long_run
    path = tmp_path / "run.npz"
    L.solve(ex.problem, method, (0.0, 30.0), ex.q0, ex.p0, checkpoint=path, progress=_StopAfter(1), **kw)
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])
    with pytest.raises(L.LobattoDAEInputError, match="corrupt or not a lobattodae checkpoint.*restart without resume"):
        L.solve(ex.problem, method, (0.0, 30.0), ex.q0, ex.p0, checkpoint=path, resume=True, **kw)


def test_checkpoint_in_a_missing_directory_is_refused_before_the_work(long_run, tmp_path):
    ex, method, kw, _ = long_run
    with pytest.raises(L.LobattoDAEInputError, match="does not exist"):
        L.solve(ex.problem, method, (0.0, 30.0), ex.q0, ex.p0, checkpoint=tmp_path / "nope" / "run.npz", **kw)


def test_something_else_where_the_rows_go_is_refused_before_the_work(long_run, tmp_path):
    ex, method, kw, _ = long_run
    (tmp_path / "run.npz.rows").write_text("not a directory")
    with pytest.raises(L.LobattoDAEInputError, match="its rows go to the directory .*run.npz.rows', and something else"):
        L.solve(ex.problem, method, (0.0, 30.0), ex.q0, ex.p0, checkpoint=tmp_path / "run.npz", **kw)
    assert not (tmp_path / "run.npz").exists()


def test_checkpoint_of_a_failed_run_resumes_to_the_same_failure(tmp_path):
    prob = stiff_particle()
    path = tmp_path / "fail.npz"
    kw = dict(n_steps=20, args=100.0, throw=False, checkpoint=path)
    first = L.solve(prob, L.LobattoIIIAIIIB(stages=2), (0, 6), np.zeros(3), np.array([1.0, 1.0, 0.0]), **kw)
    assert not first.success and path.exists()
    again = L.solve(prob, L.LobattoIIIAIIIB(stages=2), (0, 6), np.zeros(3), np.array([1.0, 1.0, 0.0]), resume=True,
                    **kw)
    assert again.status == first.status and again.stats["failed_step"] == first.stats["failed_step"]
    np.testing.assert_array_equal(again.q, first.q)


# -- interrupts at random moments ---------------------------------------------------------------------
def _interrupted(run, delay):
    """``run()`` with Ctrl-C (SIGINT) sent after ``delay`` seconds; its result, or None when the
    interrupt landed before solve took over Ctrl-C (validation, set-up)."""
    armed = [True]

    def alarm(*_):
        if armed[0]:
            os.kill(os.getpid(), signal.SIGINT)

    previous = signal.signal(signal.SIGALRM, alarm)
    result = None
    try:
        signal.setitimer(signal.ITIMER_REAL, delay)
        try:
            result = run()
        except KeyboardInterrupt:
            pass
        finally:
            armed[0] = False
            signal.setitimer(signal.ITIMER_REAL, 0)
    except KeyboardInterrupt:  # delivered while disarming
        pass
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, previous)
    return result


@pytest.mark.parametrize("seed", range(4))
def test_interrupts_at_random_moments_resume_bit_for_bit(long_run, tmp_path, seed):
    """Ctrl-C at a random moment (before the loop starts, inside a chunk, between chunks or
    while a checkpoint is written), then a resume: the result equals the uninterrupted run
    bit for bit. (Inside solve the first Ctrl-C only sets a flag, so the step count, the state
    and the rows are always saved together. A second, raw KeyboardInterrupt can land inside
    JAX's own callbacks, which no library can make safe; it is not simulated here.)"""
    ex, method, kw, ref = long_run
    kw = dict(kw, chunk_size=64)
    path = tmp_path / "run.npz"
    delay = np.random.default_rng(seed).uniform(0.01, 0.3)
    solve = lambda **more: L.solve(ex.problem, method, (0.0, 30.0), ex.q0, ex.p0, checkpoint=path,  # noqa: E731
                                   checkpoint_every=64, **kw, **more)
    part = _interrupted(solve, delay)
    assert part is None or part.result in (L.Result.INTERRUPTED, L.Result.SUCCESSFUL)
    full = solve(resume=True)
    assert full.success
    for name in ("t", "q", "p", "lam"):
        np.testing.assert_array_equal(getattr(full, name), getattr(ref, name))


# -- incremental checkpoints (issue #13) ----------------------------------------------------------------
def _crossing(t, q, p, args):
    """An event of the knife edge: y = -1 (crossed a few times on t <= 30)."""
    return q[1] + 1.0


def _assert_same_solution(a, b, dense=False, events=False):
    for name in ("t", "q", "p", "lam"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
    for key in ("newton_iterations", "residual_norm", "constraint_residual", "multiplier_drift", "lam_resync"):
        np.testing.assert_array_equal(a.stats[key], b.stats[key])
    if dense:
        for x, y in zip(a.sol.steps, b.sol.steps):
            np.testing.assert_array_equal(x, y)
    if events:
        for name in ("t_events", "q_events", "p_events", "lam_events"):
            for x, y in zip(getattr(a, name), getattr(b, name)):
                np.testing.assert_array_equal(x, y)


def _segment_sizes(path):
    directory = checkpoint.rows_directory(path)
    return {f: os.path.getsize(os.path.join(directory, f)) for f in sorted(os.listdir(directory))}


def test_periodic_checkpoints_write_each_row_once(long_run, tmp_path):
    """Incremental checkpoints (issue #13): with save_every, each periodic save appends only the
    rows since the previous one; the files already written are not touched, and all segments
    together are the size of one dump of the rows (plus a small overhead per file)."""
    ex, method, kw, _ = long_run
    kw = dict(kw, save_every=10)
    ref = L.solve(ex.problem, method, (0.0, 30.0), ex.q0, ex.p0, **kw)
    path, once = tmp_path / "run.npz", tmp_path / "once.npz"
    seen = {}

    def snapshot(done, total):  # the files after the second chunk's save, as they were then
        if done == 2 * CHUNK:
            directory = checkpoint.rows_directory(path)
            for f in os.listdir(directory):
                st = os.stat(os.path.join(directory, f))
                seen[f] = (st.st_ino, st.st_mtime_ns, open(os.path.join(directory, f), "rb").read())

    sol = L.solve(ex.problem, method, (0.0, 30.0), ex.q0, ex.p0, checkpoint=path, checkpoint_every=CHUNK,
                  progress=snapshot, **kw)
    L.solve(ex.problem, method, (0.0, 30.0), ex.q0, ex.p0, checkpoint=once, **kw)  # one save, at the end
    _assert_same_solution(sol, ref)
    many_sizes, once_sizes = _segment_sizes(path), _segment_sizes(once)
    assert len(many_sizes) == -(-N // CHUNK) and len(once_sizes) == 1
    assert len(seen) == 1  # the snapshot ran before the second save: it saw the first segment
    directory = checkpoint.rows_directory(path)
    for f, (ino, mtime, blob) in seen.items():
        st = os.stat(os.path.join(directory, f))
        assert (st.st_ino, st.st_mtime_ns) == (ino, mtime) and open(os.path.join(directory, f), "rb").read() == blob
    total, single = sum(many_sizes.values()), sum(once_sizes.values())
    per_file = 5000  # zip64 and .npy headers of 13 entries (measured 3.9 kB), whatever the rows before
    assert single <= total <= single + per_file * len(many_sizes)
    assert abs(os.path.getsize(path) - os.path.getsize(once)) < 200  # the main files hold no rows
    resumed = L.solve(ex.problem, method, (0.0, 30.0), ex.q0, ex.p0, checkpoint=path, resume=True, **kw)
    _assert_same_solution(resumed, ref)


def test_crash_between_segment_and_commit_resumes_bit_for_bit(long_run, tmp_path, monkeypatch):
    """The process dies after a save wrote its row segment but before the main file (simulated:
    the third main-file write fails): the resume starts from the second save, ignores the
    orphan segment, and gives the uninterrupted run bit for bit."""
    ex, method, kw, ref = long_run
    path = tmp_path / "run.npz"
    real, mains = atomic.write_npz, []

    def dies_on_third_commit(target, payload):
        if os.fspath(target) == os.fspath(path):
            mains.append(target)
            if len(mains) == 3:
                raise OSError("simulated crash before the commit")
        real(target, payload)

    monkeypatch.setattr(atomic, "write_npz", dies_on_third_commit)
    # the failed save ends the run with our error (the tests of failed saves below), the cause chained
    with pytest.raises(L.CheckpointWriteError, match="simulated crash") as info:
        L.solve(ex.problem, method, (0.0, 30.0), ex.q0, ex.p0, checkpoint=path, checkpoint_every=CHUNK, **kw)
    assert isinstance(info.value.__cause__, OSError)
    monkeypatch.undo()
    with np.load(path) as data:
        assert json.loads(str(data["counters"]))["done"] == 2 * CHUNK
        assert json.loads(str(data["segments"]))["count"] == 2
    assert len(_segment_sizes(path)) == 3  # two committed, one orphan
    full = L.solve(ex.problem, method, (0.0, 30.0), ex.q0, ex.p0, checkpoint=path, resume=True, **kw)
    _assert_same_solution(full, ref)
    with np.load(path) as data:
        assert json.loads(str(data["segments"]))["count"] == len(_segment_sizes(path)) == 3


@pytest.mark.parametrize("damage", ["missing", "truncated"])
def test_damaged_row_segment_is_refused_with_one_clear_error(long_run, tmp_path, damage):
    ex, method, kw, _ = long_run
    path = tmp_path / "run.npz"
    L.solve(ex.problem, method, (0.0, 30.0), ex.q0, ex.p0, checkpoint=path, checkpoint_every=CHUNK,
            progress=_StopAfter(3), **kw)
    names = sorted(_segment_sizes(path))
    assert len(names) == 3
    segment = os.path.join(checkpoint.rows_directory(path), names[1])
    if damage == "missing":
        os.unlink(segment)
    else:
        blob = open(segment, "rb").read()
        with open(segment, "wb") as fh:
            fh.write(blob[: len(blob) // 2])
    with pytest.raises(L.CheckpointError) as info:  # public, and a LobattoDAEInputError
        L.solve(ex.problem, method, (0.0, 30.0), ex.q0, ex.p0, checkpoint=path, resume=True, **kw)
    assert isinstance(info.value, L.LobattoDAEInputError)
    msg = str(info.value)
    assert msg.startswith(f"checkpoint '{path}' is corrupt or not a lobattodae checkpoint (row segment '{segment}'")
    assert msg.endswith("; delete it or restart without resume.")
    assert ("is missing" in msg) == (damage == "missing")


def test_fresh_run_over_an_old_checkpoint_does_not_mix_in_its_segments(long_run, tmp_path):
    """A run without resume replaces the checkpoint: once it has saved, the old segments are
    gone, and a resume continues the new run only (also when the old run had more rows)."""
    ex, method, kw, ref = long_run
    path = tmp_path / "run.npz"
    other = dict(kw, args=ex.args._replace(g=ex.args.g * 1.01))  # another run (same compiled loop)
    L.solve(ex.problem, method, (0.0, 30.0), ex.q0, ex.p0, checkpoint=path, checkpoint_every=CHUNK, **other)
    old = set(_segment_sizes(path))
    assert len(old) == -(-N // CHUNK)
    L.solve(ex.problem, method, (0.0, 30.0), ex.q0, ex.p0, checkpoint=path, checkpoint_every=CHUNK,
            progress=_StopAfter(2), **kw)
    now = set(_segment_sizes(path))
    assert len(now) == 2 and not now & old
    full = L.solve(ex.problem, method, (0.0, 30.0), ex.q0, ex.p0, checkpoint=path, resume=True, **kw)
    _assert_same_solution(full, ref)


def test_dense_output_and_event_rows_are_checkpointed_incrementally(long_run, tmp_path):
    """Dense-output rows and event rows are rows too: each save appends only the new ones, and
    an interrupted run resumes to the same continuous extension and the same event zeros."""
    ex, method, kw, _ = long_run
    kw = dict(kw, dense_output=True, events=[_crossing])
    ref = L.solve(ex.problem, method, (0.0, 30.0), ex.q0, ex.p0, **kw)
    assert len(ref.t_events[0]) >= 2
    path = tmp_path / "run.npz"
    part = L.solve(ex.problem, method, (0.0, 30.0), ex.q0, ex.p0, checkpoint=path, checkpoint_every=CHUNK,
                   progress=_StopAfter(4), **kw)
    assert part.result == L.Result.INTERRUPTED
    directory = checkpoint.rows_directory(path)
    dense_rows, event_rows = [], []
    for f in sorted(os.listdir(directory)):
        with np.load(os.path.join(directory, f)) as seg:
            dense_rows.append(len(seg["rows/dense"]))
            event_rows.append(len(seg["rows/event_rows"]))
            assert len(seg["rows/event_index"]) == event_rows[-1]
    assert dense_rows == [CHUNK] * 4  # each segment: the dense rows of its chunk only
    assert sum(event_rows) == np.sum(ref.t_events[0] <= part.t[-1])
    full = L.solve(ex.problem, method, (0.0, 30.0), ex.q0, ex.p0, checkpoint=path, resume=True, **kw)
    _assert_same_solution(full, ref, dense=True, events=True)
    np.testing.assert_array_equal(full.sol(np.linspace(0, 30, 7))[0], ref.sol(np.linspace(0, 30, 7))[0])


@pytest.mark.slow
def test_many_random_interrupts_resume_bit_for_bit(tmp_path):
    """200 trials of the random-interrupt test (issue #13), each with one to three Ctrl-C at
    random moments (each attempt resuming the last), then a resume to the end; with save_every,
    dense output and an event, so that every kind of row goes through the incremental
    checkpoints. Every trial equals the uninterrupted run bit for bit."""
    ex = get_example("knife-edge")
    method = L.LobattoIIIAIIIB(stages=3, lam_start="consistent")
    kw = dict(n_steps=960, args=ex.args, chunk_size=32, save_every=3, dense_output=True, events=[_crossing])
    ref = L.solve(ex.problem, method, (0.0, 9.6), ex.q0, ex.p0, **kw)
    assert len(ref.t_events[0]) >= 1
    path = tmp_path / "run.npz"

    def solve(**more):
        return L.solve(ex.problem, method, (0.0, 9.6), ex.q0, ex.p0, checkpoint=path, checkpoint_every=64, **kw,
                       **more)

    start = time.perf_counter()
    solve()  # an uninterrupted checkpointed run: how long the interrupts have to land in
    duration = time.perf_counter() - start
    rng = np.random.default_rng(13)
    statuses = []
    for trial in range(200):
        for f in (path, *[os.path.join(checkpoint.rows_directory(path), x) for x in _segment_sizes(path)]):
            os.unlink(f)
        for attempt in range(int(rng.integers(1, 4))):
            part = _interrupted(lambda: solve(resume=True), float(rng.uniform(0.0, duration)))
            statuses.append(None if part is None else part.result)
        full = solve(resume=True)
        assert full.success, trial
        _assert_same_solution(full, ref, dense=True, events=True)
    # the interrupts landed inside runs and after runs had finished (measured about half each)
    assert statuses.count(L.Result.INTERRUPTED) > 100
    assert statuses.count(L.Result.SUCCESSFUL) > 20


# -- a checkpoint that cannot be written (issue #30) ---------------------------------------------------
def _failing_writes(monkeypatch, after: int, code: int):
    """Let ``after`` file writes of checkpoint saves succeed, then fail every one with ``code``."""
    real, calls = atomic.write_npz, {"n": 0}

    def write(target, payload):
        calls["n"] += 1
        if calls["n"] > after:
            raise OSError(code, os.strerror(code), target)
        return real(target, payload)

    monkeypatch.setattr(atomic, "write_npz", write)


def _checkpointed(short_run, path, **kw):
    ex, method, base, _ = short_run
    return L.solve(ex.problem, method, (0.0, 3.0), ex.q0, ex.p0, checkpoint=path, checkpoint_every=SHORT_EVERY,
                   **base, **kw)


@pytest.mark.parametrize("code, fix", [(errno.ENOSPC, "free space on that disk"),
                                       (errno.EROFS, "make the directory writable again")])
def test_a_failed_save_mid_run_raises_our_error_with_the_prefix(short_run, tmp_path, monkeypatch, code, fix):
    ref = short_run[3]
    path = tmp_path / "run.npz"
    _failing_writes(monkeypatch, after=4, code=code)  # two saves (segment + main file each), then the disk fails
    with pytest.raises(L.CheckpointWriteError) as info:
        _checkpointed(short_run, path)
    err = info.value
    assert isinstance(err, L.LobattoDAEInputError) and isinstance(err.__cause__, OSError)
    assert err.path == str(path) and err.errno == code
    msg = str(err)
    assert f"cannot write the checkpoint '{path}'" in msg and os.strerror(code) in msg and fix in msg
    assert "holds the run up to step 32" in msg and "resume=True" in msg and ".solution" in msg
    part = err.solution  # the computed prefix: the chunk whose save failed included
    assert not part.success and part.result == L.Result.INTERRUPTED and part.status == -1
    assert len(part.t) == 3 * SHORT_CHUNK + 1 and np.all(np.isfinite(part.q))
    np.testing.assert_array_equal(part.q, ref.q[: len(part.t)])
    # the checkpoint on disk is the last committed one: it resumes, bit for bit
    monkeypatch.undo()
    full = _checkpointed(short_run, path, resume=True)
    assert full.success
    for name in ("t", "q", "p", "lam"):
        np.testing.assert_array_equal(getattr(full, name), getattr(ref, name))


def test_with_throw_false_the_prefix_is_returned_with_the_reason(short_run, tmp_path, monkeypatch):
    path = tmp_path / "run.npz"
    _failing_writes(monkeypatch, after=0, code=errno.ENOSPC)  # the first save fails: nothing committed
    sol = _checkpointed(short_run, path, throw=False)
    assert not sol.success and sol.result == L.Result.INTERRUPTED and len(sol.t) == SHORT_CHUNK + 1
    assert "No space left on device" in sol.message and "no checkpoint of this run was committed" in sol.message
    assert "returned" in sol.message and not path.exists()


def test_a_failed_final_save_keeps_the_finished_run(short_run, tmp_path, monkeypatch):
    # no periodic saves: only the final one, after the end was reached, fails
    ex, method, base, ref = short_run
    path = tmp_path / "run.npz"
    _failing_writes(monkeypatch, after=0, code=errno.ENOSPC)
    with pytest.raises(L.CheckpointWriteError, match="The run itself ended") as info:
        L.solve(ex.problem, method, (0.0, 3.0), ex.q0, ex.p0, checkpoint=path, **base)
    sol = info.value.solution
    assert sol.success and sol.result == L.Result.SUCCESSFUL and len(sol.t) == SHORT_N + 1
    np.testing.assert_array_equal(sol.q, ref.q)


@pytest.mark.skipif(not hasattr(os, "geteuid") or os.geteuid() == 0,
                    reason="root writes into read-only directories")
def test_a_directory_made_read_only_mid_run(short_run, tmp_path):
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
            _checkpointed(short_run, path, progress=read_only_after_two_chunks)
    finally:
        for d in (directory, directory / "run.npz.rows"):
            os.chmod(d, 0o755)
    assert len(info.value.solution.t) == 3 * SHORT_CHUNK + 1
    assert L.solve(short_run[0].problem, short_run[1], (0.0, 3.0), short_run[0].q0, short_run[0].p0, checkpoint=path,
                   checkpoint_every=SHORT_EVERY, resume=True, **short_run[2]).success


# -- the command line ----------------------------------------------------------------------------------
#: A run long enough to be stopped in the middle (particle, s = 3, with the step h = 0.04 of
#: the runs above: some 30 ms per chunk of RUN_CHUNK steps), checkpointed after every chunk.
SIGTERM_STEPS = 16 * RUN_CHUNK


SIGTERM_T1 = SIGTERM_STEPS * 2.0 / RUN_STEPS


def test_sigterm_stops_a_run_cleanly_and_resume_finishes_bit_for_bit(tmp_path, capsys):
    """SIGTERM to `lobattodae run --checkpoint` acts like the first Ctrl-C: the run stops at
    the end of the chunk, the checkpoint and the prefix are written, exit code 1; `--resume`
    then reaches the end with the numbers of an uninterrupted run, bit for bit."""
    ckpt, prefix, final = tmp_path / "run.npz", tmp_path / "prefix.npz", tmp_path / "final.npz"
    argv = ["run", "--example", "particle", "--stages", str(RUN_STAGES), "--n-steps", str(SIGTERM_STEPS),
            "--t1", str(SIGTERM_T1), "--checkpoint", str(ckpt), "--checkpoint-every", str(RUN_CHUNK)]
    proc = subprocess.Popen([sys.executable, "-m", "lobattodae", *argv, "--save", str(prefix)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 120
        while not ckpt.exists() and proc.poll() is None and time.monotonic() < deadline:
            time.sleep(0.005)
        assert ckpt.exists(), "no checkpoint after the first chunk"
        proc.send_signal(signal.SIGTERM)
        out, err = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    assert proc.returncode == 1, (out, err)
    assert "Traceback" not in err, err
    assert out.startswith("Interrupted after "), out
    assert f"checkpoint: {ckpt} (continue with the same command and --resume)" in out
    with np.load(prefix) as z:
        n_done = len(z["t"]) - 1
        assert int(z["status"]) == int(L.Result.INTERRUPTED)
        prefix_q = z["q"].copy()
    assert 0 < n_done < SIGTERM_STEPS and n_done % RUN_CHUNK == 0, n_done  # stopped at a chunk's end
    # resume in-process (shares the compilation with the uninterrupted reference below)
    code, out, err = run_cli([*argv, "--resume", "--no-progress", "--save", final], capsys)
    assert code == 0, (out, err)
    assert f"steps: {SIGTERM_STEPS} of {SIGTERM_STEPS}" in out
    ex = get_example("particle")
    ref = L.solve(ex.problem, cli_method(RUN_STAGES), (ex.t_span[0], SIGTERM_T1), ex.q0, ex.p0,
                  n_steps=SIGTERM_STEPS, args=ex.args, chunk_size=RUN_CHUNK)
    with np.load(final) as z:
        for key in ("t", "q", "p", "lam"):
            np.testing.assert_array_equal(z[key], getattr(ref, key), err_msg=key)
    np.testing.assert_array_equal(prefix_q, ref.q[: n_done + 1])


def test_run_model_with_checkpoint_and_resume(model_module, particle_direct, tmp_path, capsys):
    _, sol = particle_direct
    ck, f1, f2 = tmp_path / "run.npz", tmp_path / "a.npz", tmp_path / "b.npz"
    base = ["run", "--model", f"{model_module}:as_dict", "--stages", RUN_STAGES, "--n-steps", RUN_STEPS,
            "--no-progress", "--checkpoint", ck, "--checkpoint-every", 20]
    code, out, err = run_cli(base + ["--save", f1], capsys)
    assert code == 0, err
    assert ck.exists() and f"checkpoint: {ck}" in out
    code, out, err = run_cli(base + ["--resume", "--save", f2], capsys)
    assert code == 0, err
    with np.load(f1) as a, np.load(f2) as b:
        np.testing.assert_array_equal(a["q"], b["q"])
        np.testing.assert_allclose(a["q"], sol.q, rtol=0, atol=1e-12)
