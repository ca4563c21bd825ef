"""Event functions and their settings checked at set-up (issue #30): bool values, NaN values,
``terminal`` and ``direction`` of every kind a user may pass."""

import math

import jax.numpy as jnp
import numpy as np
import pytest

import lobattodae as L
from lobattodae._events import as_events
from lobattodae.examples import get_example

METHOD = L.LobattoIIIAIIIB(stages=2)


@pytest.fixture(scope="module")
def sleigh():
    return get_example("sleigh")


def _solve(sleigh, events, t_span=(0.0, 1.0), **kw):
    return L.solve(sleigh.problem, METHOD, t_span, sleigh.q0, sleigh.p0, args=sleigh.args, rtol=1e-6, atol=1e-6,
                   events=events, **kw)


def _heading(t, q, p, args):
    return q[2] - 0.4


# -- values ---------------------------------------------------------------------------------------------
@pytest.mark.parametrize("value", [
    lambda t, q, p, args: q[2] > 0.4,
    lambda t, q, p, args: np.bool_(True),
    lambda t, q, p, args: True,
], ids=["jax-bool", "numpy-bool", "python-bool"])
def test_a_bool_valued_event_function_is_refused_at_set_up(sleigh, value):
    with pytest.raises(L.LobattoDAEInputError, match=r"event function '<lambda>' returns a bool.*q\[0\] - 0\.5"):
        _solve(sleigh, value)


def test_a_nan_event_value_at_t0_is_refused(sleigh):
    with pytest.raises(L.LobattoDAEInputError, match="not finite at t0"):
        _solve(sleigh, lambda t, q, p, args: q[0] * math.nan)


@pytest.mark.parametrize("terminal", [True, False])
def test_a_nan_event_value_after_t0_stops_the_run_with_its_status(sleigh, terminal):
    def nan_later(t, q, p, args):
        return jnp.where(t > 0.5, jnp.nan, 1.0) + 0.0 * q[0]

    nan_later.terminal = terminal
    sol = _solve(sleigh, nan_later, throw=False)
    assert not sol.success and sol.result == L.Result.EVENT_NOT_FINITE
    assert "event function returned a non-finite value" in sol.message
    assert 0.5 < sol.t[-1] < 1.0 and np.all(np.isfinite(sol.q))


# -- settings -------------------------------------------------------------------------------------------
def _with(**attrs):
    def event(t, q, p, args):
        return q[2] - 0.4

    for name, value in attrs.items():
        setattr(event, name, value)
    return event


@pytest.mark.parametrize("attrs, message", [
    (dict(terminal=10**12), r"events\[0\]\.terminal must be True/False or an integer from 0 to 2147483647.*"
                            r"1000000000000"),
    (dict(terminal=-1), r"events\[0\]\.terminal must be .*got -1"),
    (dict(terminal=2.5), r"events\[0\]\.terminal must be .*got 2\.5"),
    (dict(terminal="yes"), r"events\[0\]\.terminal must be .*got 'yes'"),
    (dict(direction="x"), r"events\[0\]\.direction must be a number.*got 'x'"),
    (dict(direction=math.nan), r"events\[0\]\.direction must be a number.*got nan"),
    (dict(direction=None), r"events\[0\]\.direction must be a number.*got None"),
])
def test_bad_event_attributes_are_refused_with_our_error(sleigh, attrs, message):
    with pytest.raises(L.LobattoDAEInputError, match=message):
        as_events([_with(**attrs)])
    with pytest.raises(L.LobattoDAEInputError, match=message):
        _solve(sleigh, [_with(**attrs)])


@pytest.mark.parametrize("kw, message", [
    (dict(terminal=10**12), r"Event\.terminal must be True/False or an integer from 0 to 2147483647"),
    (dict(terminal=-1), r"Event\.terminal must be .*got -1"),
    (dict(terminal=2.5), r"Event\.terminal must be .*got 2\.5"),
    (dict(direction="x"), r"Event\.direction must be a number.*got 'x'"),
    (dict(direction=math.nan), r"Event\.direction must be a number.*got nan"),
])
def test_bad_event_fields_are_refused_with_our_error(kw, message):
    with pytest.raises(L.LobattoDAEInputError, match=message):
        L.Event(_heading, **kw)


def test_an_event_needs_a_callable():
    with pytest.raises(L.LobattoDAEInputError, match="Event needs a callable"):
        L.Event(0.4)


@pytest.mark.parametrize("terminal", [np.int64(1), np.int32(1), np.bool_(True), True, 1])
def test_numpy_integers_and_bools_are_accepted_as_terminal(terminal):
    for event in (as_events(_with(terminal=terminal))[0], L.Event(_heading, terminal=terminal)):
        assert event.terminal == 1 and type(event.terminal) is int
    assert L.Event(_heading, terminal=terminal) == L.Event(_heading, terminal=1)  # one compiled loop


def test_a_numpy_integer_terminal_stops_the_run(sleigh):
    """Normalised as above, so one run stands for all of them (each run compiles a loop)."""
    sol = _solve(sleigh, _with(terminal=np.int64(1)))
    assert sol.result == L.Result.EVENT and abs(sol.q[-1, 2] - 0.4) < 1e-6


@pytest.mark.parametrize("direction, expected", [(np.float32(-2.0), -2.0), (np.int64(1), 1.0), (0, 0.0),
                                                 (math.inf, math.inf)])
def test_numeric_directions_are_accepted(direction, expected):
    for event in (as_events(_with(direction=direction))[0], L.Event(_heading, direction=direction)):
        assert event.direction == expected and type(event.direction) is float
