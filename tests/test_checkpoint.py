"""Long runs that lose nothing: checkpoint/resume bit for bit, interruption, automatic recovery."""

import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import lobattodae as L
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
    assert not part.success and part.status == L.Result.INTERRUPTED
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


@pytest.mark.parametrize("seed", range(4))
def test_interrupts_at_random_moments_resume_bit_for_bit(setup, tmp_path, seed):
    """Ctrl-C at a random moment (before the loop starts, inside a chunk, between chunks or
    while a checkpoint is written), then a resume: the result equals the uninterrupted run
    bit for bit. (Inside solve the first Ctrl-C only sets a flag, so the step count, the state
    and the rows are always saved together. A second, raw KeyboardInterrupt can land inside
    JAX's own callbacks, which no library can make safe; it is not simulated here.)"""
    import os
    import signal

    ex, method, kw, ref = setup
    kw = dict(kw, chunk_size=64)
    path = tmp_path / "run.npz"
    delay = np.random.default_rng(seed).uniform(0.01, 0.3)
    previous = signal.signal(signal.SIGALRM, lambda *a: os.kill(os.getpid(), signal.SIGINT))
    try:
        signal.setitimer(signal.ITIMER_REAL, delay)
        try:
            part = L.solve(ex.problem, method, (0.0, 30.0), ex.q0, ex.p0, checkpoint=path, checkpoint_every=64, **kw)
            assert part.status in (L.Result.INTERRUPTED, L.Result.SUCCESSFUL)
        except KeyboardInterrupt:  # landed before solve took over Ctrl-C (validation, set-up)
            pass
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, previous)
    full = L.solve(ex.problem, method, (0.0, 30.0), ex.q0, ex.p0, checkpoint=path, resume=True, **kw)
    assert full.success
    for name in ("t", "q", "p", "lam"):
        np.testing.assert_array_equal(getattr(full, name), getattr(ref, name))


def test_state_schema_is_versioned():
    """Changing the loop State (a field, a dtype, a rank) without bumping the checkpoint VERSION
    and recording the new fingerprint fails here."""
    from lobattodae import _checkpoint
    from lobattodae._controllers import ConstantStepSize, ControlOptions
    from lobattodae._loop import Output, init_compiled

    ex = get_example("falling-disk-general")
    f64 = lambda x: jnp.asarray(x, jnp.float64)  # noqa: E731
    state = init_compiled(ex.problem, L.LobattoIIIAIIIB(stages=4), ConstantStepSize(), Output(), f64(0.0), f64(1.0),
                          ControlOptions(n=10), f64(ex.q0), f64(ex.p0), f64(ex.lam0), ex.args)
    assert _checkpoint.schema_fingerprint(state) == _checkpoint.STATE_FINGERPRINT, (
        "the loop State changed: bump _checkpoint.VERSION and record the new STATE_FINGERPRINT"
    )
