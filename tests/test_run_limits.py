"""Work caps and options that used to be ignored (issue #30): adaptive runs stop at max_steps
with a clear status, impossible step bounds are refused up front, checkpoint_every needs a
checkpoint."""

import numpy as np
import pytest

import lobattodae as L
from lobattodae._cli import main
from lobattodae.examples import get_example


@pytest.fixture(scope="module")
def sleigh():
    return get_example("sleigh")


def _solve(ex, **kw):
    return L.solve(ex.problem, L.LobattoIIIAIIIB(stages=3), (0.0, 2.0), ex.q0, ex.p0, args=ex.args, **kw)


def test_adaptive_runs_stop_at_max_steps_with_the_prefix(sleigh):
    sol = _solve(sleigh, rtol=1e-12, atol=1e-12, max_steps=10, chunk_size=8, throw=False)
    assert sol.result == L.Result.MAX_STEPS and not sol.success
    assert "max_steps=10" in sol.message
    # checked between chunks: the run stops after the chunk that reached the cap
    assert 10 <= sol.stats["n_steps"] + sol.stats["n_rejected"] <= 16
    assert 0 < sol.t[-1] < 2.0 and np.all(np.isfinite(sol.q))


def test_default_cap_refuses_a_max_step_that_needs_more_steps(sleigh):
    """solve(..., max_step=1e-12) over (0, 2) used to start a run of 2e12 steps."""
    with pytest.raises(L.LobattoDAEInputError, match=r"max_step=1e-12 needs at least 2e\+12 steps"):
        _solve(sleigh, max_step=1e-12)


@pytest.mark.parametrize("kw, match", [
    (dict(max_steps=0), "max_steps must be a positive integer"),
    (dict(max_steps=True), "max_steps must be a positive integer"),
    (dict(max_steps=10**9), "max_steps must be a positive integer up to"),
    (dict(n_steps=4, max_steps=3), "max_steps applies to adaptive steps"),
    (dict(checkpoint_every=5), "checkpoint_every sets how often the checkpoint file is written"),
])
def test_bad_limits_are_refused(sleigh, kw, match):
    with pytest.raises(L.LobattoDAEInputError, match=match):
        _solve(sleigh, **kw)


def test_cli_refuses_checkpoint_every_without_checkpoint(capsys):
    assert main(["run", "--example", "sleigh", "--checkpoint-every", "5"]) == 2
    assert "--checkpoint-every needs --checkpoint FILE" in capsys.readouterr().err
