"""The option records (lobattodae._options): one set of rules for every entry point.

The table: the same bad option, given to ``solve``, ``integrate_adaptive``, ``ensemble`` and
(where it has the option) the command line, is refused before any work with the same error
class and the same message.
"""

import math

import numpy as np
import pytest

import lobattodae as L
from lobattodae import _cli
from lobattodae._controllers import ATOL, RTOL, PIController
from lobattodae._options import (
    MAX_STEPS,
    STATIC_MAX_STEPS,
    AdaptiveSteps,
    ConstantSteps,
    Persistence,
    Saving,
    TimeSpan,
    steps_over,
)
from lobattodae.examples import get_example

# (id, keyword options, CLI arguments or None, the message)
CASES = [
    ("rtol zero", dict(rtol=0.0), ["--rtol", "0.0"], "rtol must be a positive finite number; got rtol=0.0."),
    ("rtol negative", dict(rtol=-1e-6), ["--rtol=-1e-6"], "rtol must be a positive finite number; got rtol=-1e-06."),
    ("rtol nan", dict(rtol=math.nan), ["--rtol", "nan"], "rtol must be a positive finite number; got rtol=nan."),
    ("rtol below float64", dict(rtol=1e-17), ["--rtol", "1e-17"],
     "rtol=1e-17 is below what float64 can deliver; use rtol >= 2.2e-14."),
    ("rtol a string", dict(rtol="1e-8"), None, "rtol must be a positive number; got '1e-8'."),
    ("atol negative", dict(atol=-1.0), ["--atol", "-1"], "atol must be a non-negative finite number; got atol=-1.0."),
    ("atol inf", dict(atol=math.inf), ["--atol", "inf"], "atol must be a non-negative finite number; got atol=inf."),
    ("first_step beyond the span", dict(first_step=5.0), None,
     "first_step=5 is longer than the interval |t1 - t0| = 1."),
    ("max_step zero", dict(max_step=0.0), None, "max_step must be a positive finite number; got max_step=0.0."),
    ("max_step needs more steps than max_steps", dict(max_step=1e-3, max_steps=100), None,
     "max_step=0.001 needs at least 1e+03 steps over |t1 - t0| = 1, more than max_steps=100; raise max_step (or max_steps)."),
    ("max_steps zero", dict(max_steps=0), None,
     "max_steps must be a positive integer up to 20,000,000 (the cap on step attempts); got 0."),
    ("max_steps a bool", dict(max_steps=True), None,
     "max_steps must be a positive integer up to 20,000,000 (the cap on step attempts); got True."),
    ("controller of the wrong type", dict(controller="pi"), None,
     "controller must be lobattodae.PIController(...) or lobattodae.ReversibleStepSize(...); got 'pi'."),
    ("t_eval unsorted", dict(t_eval=[0.5, 0.25]), ["--t-eval", "0.5", "0.25"],
     "t_eval must be sorted in the direction of integration (increasing for t1 > t0, decreasing for t1 < t0)."),
    ("t_eval outside t_span", dict(t_eval=[0.5, 2.0]), ["--t-eval", "0.5", "2.0"],
     "t_eval must lie within t_span = (0, 1); got values in [0.5, 2]."),
    ("t_eval with nan", dict(t_eval=[0.5, math.nan]), ["--t-eval", "0.5", "nan"],
     "t_eval contains NaN or inf; give finite times."),
    ("t_eval empty", dict(t_eval=[]), None, "t_eval must be a non-empty 1-D array of times; got shape (0,)."),
    ("t_eval_rows unknown", dict(t_eval=[0.5], t_eval_rows="bogus"), None,
     "t_eval_rows must be 'step' (error-controlled steps end on the t_eval times), 'interpolate' (rows from the "
     "dense output) or 'project' (interpolated rows moved onto the constraints); got 'bogus'."),
    ("t_eval_rows step without error control", dict(t_eval=[0.5], t_eval_rows="step", controller=L.ReversibleStepSize()),
     None, "t_eval_rows='step' needs error-controlled steps"),
]
SPAN = (0.0, 1.0)


@pytest.fixture(scope="module")
def particle():
    ex = get_example("particle")
    lam0 = np.asarray(L.consistent_lambda(ex.problem, SPAN[0], ex.q0, ex.p0, np.zeros(ex.m), ex.args))
    return ex, lam0


def _solve(particle, options):
    ex, _ = particle
    L.solve(ex.problem, L.LobattoIIIAIIIB(stages=3), SPAN, ex.q0, ex.p0, args=ex.args, **options)


def _integrate_adaptive(particle, options):
    ex, lam0 = particle
    L.integrate_adaptive(ex.problem, L.LobattoIIIAIIIB(stages=3), SPAN, ex.q0, ex.p0, lam0, ex.args, **options)


def _ensemble(particle, options):
    ex, lam0 = particle
    L.ensemble(ex.problem, L.LobattoIIIAIIIB(stages=3), ex.q0[None], ex.p0[None], lam0[None], ex.args, t_span=SPAN,
               **options)


ENTRY_POINTS = {"solve": _solve, "integrate_adaptive": _integrate_adaptive, "ensemble": _ensemble}


@pytest.mark.parametrize("entry", ENTRY_POINTS)
@pytest.mark.parametrize("case", CASES, ids=[c[0] for c in CASES])
def test_the_same_bad_option_gets_the_same_error_from_every_entry_point(particle, entry, case):
    _, options, _, message = case
    with pytest.raises(L.LobattoDAEInputError) as info:
        ENTRY_POINTS[entry](particle, options)
    assert type(info.value) is L.LobattoDAEInputError
    assert str(info.value).startswith(message), str(info.value)


CLI_CASES = [c for c in CASES if c[2] is not None]


@pytest.mark.parametrize("case", CLI_CASES, ids=[c[0] for c in CLI_CASES])
def test_the_command_line_refuses_it_with_the_same_message(case, capsys):
    _, _, argv, message = case
    code = _cli.main(["run", "--example", "particle", "--t1", "1", "--no-progress", *argv])
    err = capsys.readouterr().err
    assert code == 2, err
    assert err.strip() == f"lobattodae: error: {message}", err


def test_the_defaults_are_written_once():
    """Every entry point's defaults are the records' (and the controller's options)."""
    steps = AdaptiveSteps.over(TimeSpan.of(SPAN))
    assert (steps.rtol, steps.atol, steps.first_step, steps.max_step) == (RTOL, ATOL, 0.0, math.inf)
    assert steps.max_steps == MAX_STEPS and isinstance(steps.controller, PIController)
    assert steps.control == L._controllers.ControlOptions(1, RTOL, ATOL, 0.0, math.inf)
    import inspect

    sig = inspect.signature(L.integrate_adaptive).parameters
    assert (sig["rtol"].default, sig["atol"].default, sig["max_steps"].default) == (RTOL, ATOL, STATIC_MAX_STEPS)


def test_steps_over_picks_constant_or_adaptive_steps_and_refuses_options_of_the_other_kind():
    span = TimeSpan.of((0.0, 2.0))
    assert steps_over(span, n_steps=8) == ConstantSteps(8, 0.25)
    # dt: the largest step of at most dt that divides the interval
    assert steps_over(span, dt=0.3) == ConstantSteps(7, 2.0 / 7)
    assert isinstance(steps_over(span, rtol=1e-6), AdaptiveSteps)
    assert steps_over(span, n_steps=8, max_step=math.inf) == ConstantSteps(8, 0.25)  # no bound is no option
    for name, value, fix in (("rtol", 1e-6, "drop n_steps/dt"), ("max_step", 0.1, "use dt"),
                             ("max_steps", 10, "take n_steps"), ("controller", PIController(), "drop n_steps/dt")):
        with pytest.raises(L.LobattoDAEInputError, match=f"{name} applies to adaptive steps; .*{fix}"):
            steps_over(span, n_steps=8, **{name: value})
    with pytest.raises(L.LobattoDAEInputError, match="at most one of n_steps"):
        steps_over(span, n_steps=8, dt=0.1)


def test_constant_steps_on_a_grid_and_backwards():
    assert ConstantSteps.grid(None, -0.5, 4) == (0.0, ConstantSteps(4, -0.5))
    with pytest.raises(L.LobattoDAEInputError, match="h must be nonzero"):
        ConstantSteps.grid(0.0, 0.0, 4)
    with pytest.raises(L.LobattoDAEInputError, match="n_steps must be a positive integer"):
        ConstantSteps.grid(0.0, 0.1, 0)
    assert ConstantSteps.over(TimeSpan.of((1.0, 0.0)), n_steps=4) == ConstantSteps(4, -0.25)


def test_first_step_zero_means_automatic_everywhere():
    assert AdaptiveSteps.over(TimeSpan.of(SPAN), first_step=0.0).first_step == 0.0
    assert AdaptiveSteps.over(TimeSpan.of(SPAN), first_step=0.125).first_step == 0.125


def test_saving_decides_how_t_eval_rows_are_made():
    span = TimeSpan.of(SPAN)
    assert Saving.of(span, PIController(), t_eval=[0.5]).rows == "step"
    assert Saving.of(span, L.ReversibleStepSize(), t_eval=[0.5]).rows == "interpolate"
    assert Saving.of(span, PIController(), t_eval=[0.5], t_eval_rows="project").output.project_t_eval
    assert Saving.of(span, PIController()).output == L._loop.Output()
    events = Saving.of(span, PIController(), events=[lambda t, q, p, a: q[0]])
    assert events.output.land_on_events and len(events.events) == 1
    with pytest.raises(L.LobattoDAEInputError, match="give t_eval .* or save_every .*, not both"):
        Saving.of(span, PIController(), t_eval=[0.5], save_every=3)


def test_identities_change_with_what_makes_a_run_different():
    span = TimeSpan.of(SPAN)
    a = AdaptiveSteps.over(span, rtol=1e-6)
    assert a.identity() != AdaptiveSteps.over(span, rtol=1e-7).identity()
    assert a.identity() == AdaptiveSteps.over(span, rtol=1e-6).identity()
    s1 = Saving.of(span, PIController(), t_eval=[0.25, 0.5])
    assert s1.identity() != Saving.of(span, PIController(), t_eval=[0.25, 0.75]).identity()
    assert s1.identity() == Saving.of(span, PIController(), t_eval=np.array([0.25, 0.5])).identity()


def test_persistence_checks_the_file_before_any_work(tmp_path):
    with pytest.raises(L.LobattoDAEInputError, match="does not exist; create it first"):
        Persistence.of(tmp_path / "missing" / "run.npz")
    with pytest.raises(L.LobattoDAEInputError, match="resume=True needs the checkpoint file"):
        Persistence.of(resume=True)
    with pytest.raises(L.LobattoDAEInputError, match="checkpoint_every sets how often"):
        Persistence.of(checkpoint_every=10)
    (tmp_path / "run.npz.rows").write_text("not a directory")
    with pytest.raises(L.LobattoDAEInputError, match="something else is there"):
        Persistence.of(tmp_path / "run.npz")
    assert Persistence.of(tmp_path / "other.npz", 5, True) == Persistence(str(tmp_path / "other.npz"), 5, True)
