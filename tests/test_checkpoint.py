"""Long runs that lose nothing: checkpoint/resume bit for bit, interruption, automatic recovery."""

import json
import os
import signal
import time

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import lobattodae as L
from lobattodae._io import atomic, checkpoint
from lobattodae.examples import get_example

N, CHUNK = 3000, 512


@pytest.fixture(scope="module")
def setup():
    ex = get_example("knife-edge")
    method = L.LobattoIIIAIIIB(stages=3, lam_start="consistent")
    kw = dict(n_steps=N, args=ex.args, chunk_size=CHUNK)
    ref = L.solve(ex.problem, method, (0.0, 30.0), ex.q0, ex.p0, **kw)
    return ex, method, kw, ref


class _StopAfter:
    """A progress callback that simulates Ctrl-C after a number of chunks."""

    def __init__(self, chunks):
        self.left = chunks

    def __call__(self, done, total):
        self.left -= 1
        if self.left == 0:
            raise KeyboardInterrupt


def test_interrupt_returns_prefix_and_resume_is_bitwise_identical(setup, tmp_path):
    ex, method, kw, ref = setup
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


def test_periodic_checkpoint_resume_bitwise(setup, tmp_path):
    ex, method, kw, ref = setup
    path = tmp_path / "run.npz"
    # a run that stops at the 2048-step checkpoint (simulating a crash right after it)
    L.solve(ex.problem, method, (0.0, 30.0), ex.q0, ex.p0, checkpoint=path, checkpoint_every=2048,
            progress=_StopAfter(5), **kw)
    with np.load(path) as data:
        assert json.loads(str(data["counters"]))["done"] == 5 * CHUNK
    full = L.solve(ex.problem, method, (0.0, 30.0), ex.q0, ex.p0, checkpoint=path, resume=True, **kw)
    np.testing.assert_array_equal(full.q, ref.q)
    np.testing.assert_array_equal(full.lam, ref.lam)


def test_resume_rejects_a_different_run(setup, tmp_path):
    ex, method, kw, _ = setup
    path = tmp_path / "run.npz"
    L.solve(ex.problem, method, (0.0, 30.0), ex.q0, ex.p0, checkpoint=path, progress=_StopAfter(1), **kw)
    other = L.LobattoIIIAIIIB(stages=4, lam_start="consistent")
    with pytest.raises(L.LobattoDAEInputError, match="different run.*method"):
        L.solve(ex.problem, other, (0.0, 30.0), ex.q0, ex.p0, checkpoint=path, resume=True, **kw)


def test_resume_without_path_is_an_error(setup):
    ex, method, kw, _ = setup
    with pytest.raises(L.LobattoDAEInputError, match="checkpoint=PATH"):
        L.solve(ex.problem, method, (0.0, 30.0), ex.q0, ex.p0, resume=True, **kw)


def _stiff_particle():
    return L.NonholonomicSystem(
        lambda t, q, p, a: 0.5 * p @ p + a * q[0] ** 4,
        lambda t, q, a: jnp.array([[-q[1], 0.0, 1.0]]),
    )


def test_automatic_recovery_retries_failed_steps_as_substeps():
    prob = _stiff_particle()
    q0, p0 = np.zeros(3), np.array([1.0, 1.0, 0.0])
    method = L.LobattoIIIAIIIB(stages=2)
    plain = L.solve(prob, method, (0, 6), q0, p0, n_steps=20, args=100.0, throw=False)
    assert not plain.success and plain.stats["recoveries"] == 0
    rec = L.solve(prob, method, (0, 6), q0, p0, n_steps=20, args=100.0, max_recoveries=20)
    assert rec.success and rec.stats["recoveries"] >= 1
    assert len(rec.t) == 21 and np.max(rec.stats["constraint_residual"]) < 1e-12
    # the recovered solution is a solution: the recovered step lands near a fine run, and
    # the energy stays near its initial value (the plain run could not get past step k)
    k = plain.stats["failed_step"]
    np.testing.assert_array_equal(rec.q[: k + 1], plain.q)  # identical up to the failed step
    assert not np.array_equal(rec.q[k + 1], rec.q[k])
    # the recovered step is the same method on 2, 4, 8 or 16 substeps from (t_k, q_k, p_k, λ_k)
    run = jax.jit(lambda m, h: L.integrate(prob, method, rec.t[k], h, 16, rec.q[k], rec.p[k], rec.lam[k], 100.0))
    candidates = []
    for m in (2, 4, 8, 16):
        q, _, _, _ = run(m, (rec.t[k + 1] - rec.t[k]) / m)
        candidates.append(np.max(np.abs(np.asarray(q[m]) - rec.q[k + 1])))
    assert min(candidates) < 1e-12


def test_recovery_budget_is_respected():
    prob = _stiff_particle()
    sol = L.solve(prob, L.LobattoIIIAIIIB(stages=3), (0, 6), np.zeros(3), np.array([1.0, 1.0, 0.0]), n_steps=20,
                  args=100.0, max_recoveries=1, throw=False)
    assert sol.stats["recoveries"] <= 1
    with pytest.raises(L.LobattoDAEInputError, match="max_recoveries"):
        L.solve(prob, L.LobattoIIIAIIIB(stages=3), (0, 6), np.zeros(3), np.array([1.0, 1.0, 0.0]), n_steps=20,
                args=100.0, max_recoveries=-1)


def test_checkpoint_of_a_failed_run_resumes_to_the_same_failure(tmp_path):
    prob = _stiff_particle()
    path = tmp_path / "fail.npz"
    kw = dict(n_steps=20, args=100.0, throw=False, checkpoint=path)
    first = L.solve(prob, L.LobattoIIIAIIIB(stages=2), (0, 6), np.zeros(3), np.array([1.0, 1.0, 0.0]), **kw)
    assert not first.success and path.exists()
    again = L.solve(prob, L.LobattoIIIAIIIB(stages=2), (0, 6), np.zeros(3), np.array([1.0, 1.0, 0.0]), resume=True,
                    **kw)
    assert again.status == first.status and again.stats["failed_step"] == first.stats["failed_step"]
    np.testing.assert_array_equal(again.q, first.q)


def test_resume_rejects_changed_args_and_problem(setup, tmp_path):
    ex, method, kw, _ = setup
    path = tmp_path / "run.npz"
    L.solve(ex.problem, method, (0.0, 30.0), ex.q0, ex.p0, checkpoint=path, progress=_StopAfter(1), **kw)
    changed = dict(kw, args=ex.args._replace(g=ex.args.g * 1.01))
    with pytest.raises(L.LobattoDAEInputError, match="different run.*args"):
        L.solve(ex.problem, method, (0.0, 30.0), ex.q0, ex.p0, checkpoint=path, resume=True, **changed)
    other = L.NonholonomicSystem(lambda t, q, p, a: 0.5 * p @ p + a.m * a.g * q[0], ex.problem.constraint_matrix)
    with pytest.raises(L.LobattoDAEInputError, match="different run.*problem"):
        L.solve(other, method, (0.0, 30.0), ex.q0, ex.p0, checkpoint=path, resume=True, **kw)


def test_corrupted_checkpoint_is_refused_with_one_clear_error(setup, tmp_path):
    ex, method, kw, _ = setup
    path = tmp_path / "run.npz"
    L.solve(ex.problem, method, (0.0, 30.0), ex.q0, ex.p0, checkpoint=path, progress=_StopAfter(1), **kw)
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])
    with pytest.raises(L.LobattoDAEInputError, match="corrupt or not a lobattodae checkpoint.*restart without resume"):
        L.solve(ex.problem, method, (0.0, 30.0), ex.q0, ex.p0, checkpoint=path, resume=True, **kw)


def test_checkpoint_in_a_missing_directory_is_refused_before_the_work(setup, tmp_path):
    ex, method, kw, _ = setup
    with pytest.raises(L.LobattoDAEInputError, match="does not exist"):
        L.solve(ex.problem, method, (0.0, 30.0), ex.q0, ex.p0, checkpoint=tmp_path / "nope" / "run.npz", **kw)


def test_something_else_where_the_rows_go_is_refused_before_the_work(setup, tmp_path):
    ex, method, kw, _ = setup
    (tmp_path / "run.npz.rows").write_text("not a directory")
    with pytest.raises(L.LobattoDAEInputError, match="its rows go to the directory .*run.npz.rows', and something else"):
        L.solve(ex.problem, method, (0.0, 30.0), ex.q0, ex.p0, checkpoint=tmp_path / "run.npz", **kw)
    assert not (tmp_path / "run.npz").exists()


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
def test_interrupts_at_random_moments_resume_bit_for_bit(setup, tmp_path, seed):
    """Ctrl-C at a random moment (before the loop starts, inside a chunk, between chunks or
    while a checkpoint is written), then a resume: the result equals the uninterrupted run
    bit for bit. (Inside solve the first Ctrl-C only sets a flag, so the step count, the state
    and the rows are always saved together. A second, raw KeyboardInterrupt can land inside
    JAX's own callbacks, which no library can make safe; it is not simulated here.)"""
    ex, method, kw, ref = setup
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


def test_periodic_checkpoints_write_each_row_once(setup, tmp_path):
    """Incremental checkpoints (issue #13): with save_every, each periodic save appends only the
    rows since the previous one; the files already written are not touched, and all segments
    together are the size of one dump of the rows (plus a small overhead per file)."""
    ex, method, kw, _ = setup
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


def test_crash_between_segment_and_commit_resumes_bit_for_bit(setup, tmp_path, monkeypatch):
    """The process dies after a save wrote its row segment but before the main file (simulated:
    the third main-file write fails): the resume starts from the second save, ignores the
    orphan segment, and gives the uninterrupted run bit for bit."""
    ex, method, kw, ref = setup
    path = tmp_path / "run.npz"
    real, mains = atomic.write_npz, []

    def dies_on_third_commit(target, payload):
        if os.fspath(target) == os.fspath(path):
            mains.append(target)
            if len(mains) == 3:
                raise OSError("simulated crash before the commit")
        real(target, payload)

    monkeypatch.setattr(atomic, "write_npz", dies_on_third_commit)
    # the failed save ends the run with our error (tests/test_checkpoint_write.py), the cause chained
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
def test_damaged_row_segment_is_refused_with_one_clear_error(setup, tmp_path, damage):
    ex, method, kw, _ = setup
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


def test_fresh_run_over_an_old_checkpoint_does_not_mix_in_its_segments(setup, tmp_path):
    """A run without resume replaces the checkpoint: once it has saved, the old segments are
    gone, and a resume continues the new run only (also when the old run had more rows)."""
    ex, method, kw, ref = setup
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


def test_dense_output_and_event_rows_are_checkpointed_incrementally(setup, tmp_path):
    """Dense-output rows and event rows are rows too: each save appends only the new ones, and
    an interrupted run resumes to the same continuous extension and the same event zeros."""
    ex, method, kw, _ = setup
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


def test_state_schema_is_versioned():
    """Changing the loop State (a field, a dtype, a rank) without bumping the checkpoint VERSION
    and recording the new fingerprint fails here."""
    from lobattodae._controllers import ConstantStepSize, ControlOptions
    from lobattodae._chunks import init_host
    from lobattodae._io.fingerprint import schema_fingerprint
    from lobattodae._loop import Output

    ex = get_example("falling-disk-general")
    f64 = lambda x: jnp.asarray(x, jnp.float64)  # noqa: E731
    state, _ = init_host(ex.problem, L.LobattoIIIAIIIB(stages=4), ConstantStepSize(), Output(), f64(0.0), f64(1.0),
                         ControlOptions(n=10), f64(ex.q0), f64(ex.p0), f64(ex.lam0), ex.args)
    assert schema_fingerprint(state) == checkpoint.STATE_FINGERPRINT, (
        "the loop State changed: bump lobattodae._io.checkpoint.VERSION and record the new STATE_FINGERPRINT"
    )
