"""Events: zeros of user functions e(t, q, p, args) along the solution (lobattodae._events,
``solve(..., events=...)``).

* Event functions and their settings checked at set-up (issue #30): bool values, NaN values,
  ``terminal`` and ``direction`` of every kind a user may pass.
* Zeros under error control (issue #10): landed on by re-stepping onto them (Newton in time),
  with direction, terminal, compiled once per event.
* Zeros between and at the nodes of a step (issues #30 item 4, #29 item 1): a pair of zeros
  inside one step is found where the step's internal nodes (its stage points) show the sign
  changes; a zero exactly at t0 follows scipy's ``solve_ivp`` rule (recorded when the function
  then moves in the event's direction; a terminal one ends the run at t0); a zero exactly at a
  step point or node is recorded once. The problem is a particle under a constant force beside
  a trivial constraint (p[1] = 0): x = t − t²/2, which the method (s = 3) and its dense output
  reproduce exactly, so event times are exact and comparable with scipy's on the same ODE. The
  event functions read their shift from ``args``: those tests share the compiled loops (one per
  event list).
"""

import math

import jax.numpy as jnp
import numpy as np
import pytest
from scipy.integrate import solve_ivp
from scipy.optimize import brentq

import lobattodae as L
from lobattodae._events import as_events

from helpers import FALL, FALL_P0, FALL_Q0, solve_example

#: s = 3: exact for x = t − t²/2 (the falling particle), between steps too
METHOD = L.LobattoIIIAIIIB(stages=3)
LOOSE_METHOD = L.LobattoIIIAIIIB(stages=2)
Q0, P0 = FALL_Q0, FALL_P0


def _loose(sleigh, events, t_span=(0.0, 1.0), **kw):
    return L.solve(sleigh.problem, LOOSE_METHOD, t_span, sleigh.q0, sleigh.p0, args=sleigh.args, rtol=1e-6, atol=1e-6,
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
        _loose(sleigh, value)


def test_a_nan_event_value_at_t0_is_refused(sleigh):
    with pytest.raises(L.LobattoDAEInputError, match="not finite at t0"):
        _loose(sleigh, lambda t, q, p, args: q[0] * math.nan)


@pytest.mark.parametrize("terminal", [True, False])
def test_a_nan_event_value_after_t0_stops_the_run_with_its_status(sleigh, terminal):
    def nan_later(t, q, p, args):
        return jnp.where(t > 0.5, jnp.nan, 1.0) + 0.0 * q[0]

    nan_later.terminal = terminal
    sol = _loose(sleigh, nan_later, throw=False)
    assert not sol.success and sol.result == L.Result.EVENT_NOT_FINITE
    assert "event function returned a non-finite value" in sol.message
    assert 0.5 < sol.t[-1] < 1.0 and np.all(np.isfinite(sol.q))


def test_events_must_return_one_finite_number(sleigh):
    with pytest.raises(L.LobattoDAEInputError, match="must return one number"):
        solve_example(sleigh, METHOD, events=lambda t, q, p, args: q)
    with pytest.raises(L.LobattoDAEInputError, match="not finite"):
        solve_example(sleigh, METHOD, events=lambda t, q, p, args: q[0] / 0.0 * 0.0)


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
        _loose(sleigh, [_with(**attrs)])


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
    sol = _loose(sleigh, _with(terminal=np.int64(1)))
    assert sol.result == L.Result.EVENT and abs(sol.q[-1, 2] - 0.4) < 1e-6


@pytest.mark.parametrize("direction, expected", [(np.float32(-2.0), -2.0), (np.int64(1), 1.0), (0, 0.0),
                                                 (math.inf, math.inf)])
def test_numeric_directions_are_accepted(direction, expected):
    for event in (as_events(_with(direction=direction))[0], L.Event(_heading, direction=direction)):
        assert event.direction == expected and type(event.direction) is float


# -- zeros under error control ---------------------------------------------------------------------------
@pytest.mark.parametrize("s, bound", [(3, 1e-9), (4, 1e-10)])
def test_terminal_event_on_the_sleigh_heading_matches_the_closed_form(sleigh, s, bound):
    """The zero located on the dense output is refined by re-stepping onto it (Newton in time),
    so the event time is as accurate as a step point (measured at rtol 1e-10 on (0, 10): s = 3
    1.5e-12, s = 4 5.4e-15; located on the dense output alone, as before: 6.2e-9 and 3.8e-9)."""
    target = 0.5

    def heading(t, q, p, args):
        return q[2] - target

    heading.terminal = True
    sol = solve_example(sleigh, L.LobattoIIIAIIIB(stages=s), rtol=1e-10, atol=1e-10, events=heading)
    assert sol.result == L.Result.EVENT and sol.success
    t_exact = brentq(lambda t: sleigh.exact(t)[0][2] - target, 0.01, 2.0, xtol=1e-15)
    assert abs(sol.t_events[0][0] - t_exact) < bound
    assert sol.t[-1] == sol.t_events[0][0]
    # the final state is a step point of the method: the constraint at round-off
    assert sol.stats["constraint_residual"][-1] <= 1e-15
    assert abs(sol.q[-1, 2] - target) < bound


def test_non_terminal_zeros_are_step_points_under_error_control(sleigh):
    """Under error control the steps land on every zero (re-stepped onto it, Newton in time), so
    a recorded zero is a step point: its time as accurate as the steps (measured rtol 1e-10:
    |t - t*| = 5.1e-12 (s = 3) and 1.4e-14 (s = 4) against 1.2e-9 and 2.2e-9 located on the dense
    output, for 7 and 1 extra steps), its state on φ = 0 to round-off (5e-10 and 8e-10 before),
    and the run goes on to the end. Several zeros in what would be one step are each
    landed on, none twice (sin(40 t): zeros at kπ/40, 26 on [0, 2])."""
    target = 0.5

    def heading(t, q, p, args):
        return q[2] - target

    def clock(t, q, p, args):
        return jnp.sin(40.0 * t)

    sol = solve_example(sleigh, L.LobattoIIIAIIIB(stages=4), rtol=1e-10, atol=1e-10, events=[heading, clock])
    assert sol.result == L.Result.SUCCESSFUL and sol.t[-1] == sleigh.t_span[1]
    t_exact = brentq(lambda t: sleigh.exact(t)[0][2] - target, 0.01, 2.0, xtol=1e-15)
    (t_heading,), q_heading = sol.t_events[0], sol.q_events[0][0]
    assert abs(t_heading - t_exact) < 1e-10 and abs(q_heading[2] - target) < 1e-10
    phi = sleigh.problem.phi(t_heading, q_heading, sol.p_events[0][0], sleigh.args)
    assert float(jnp.max(jnp.abs(phi))) <= 1e-15
    assert np.any(np.isclose(sol.t, t_heading, rtol=0, atol=0))  # a step point of the run
    k = np.arange(0, int(2.0 * 40 / np.pi) + 1)  # the zero at t0 counts, as in solve_ivp
    np.testing.assert_allclose(sol.t_events[1], k * np.pi / 40, rtol=0, atol=1e-12)
    q, p, _ = sleigh.exact(sol.t[-1])
    assert max(np.abs(sol.q[-1] - q).max(), np.abs(sol.p[-1] - p).max()) < 1e-8


def test_solving_again_with_the_same_event_function_does_not_recompile(sleigh):
    """The loop is cached per Event(fn, terminal, direction): equal fields, one compilation."""
    import jax.monitoring

    compiles = []

    def listener(name, secs, **kw):
        if name.endswith("backend_compile_duration"):
            compiles.append(name)

    def heading(t, q, p, args):
        return q[2] - 0.4

    heading.terminal = True
    jax.monitoring.register_event_duration_secs_listener(listener)
    try:
        first = solve_example(sleigh, METHOD, rtol=1e-8, atol=1e-8, events=heading)
        n_first = len(compiles)
        again = [solve_example(sleigh, METHOD, rtol=r, atol=r, events=heading) for r in (1e-8, 1e-9)]
        bare = solve_example(sleigh, METHOD, rtol=1e-8, atol=1e-8, events=L.Event(heading, terminal=1))
    finally:
        jax.monitoring.unregister_event_duration_listener(listener)
    assert n_first > 0 and len(compiles) == n_first
    assert all(s.result == L.Result.EVENT for s in [first, *again, bare])
    assert bare.t_events[0][0] == first.t_events[0][0] == again[0].t_events[0][0]


def test_non_terminal_events_with_direction(sleigh):
    def x_rising(t, q, p, args):
        return p[1] - 1.1

    x_rising.direction = 1.0

    def x_falling(t, q, p, args):
        return p[1] - 1.1

    x_falling.direction = -1.0
    sol = solve_example(sleigh, METHOD, rtol=1e-10, atol=1e-10, events=[x_rising, x_falling], dense_output=True)
    assert sol.result == L.Result.SUCCESSFUL
    te = np.linspace(0, 2, 20001)
    pe = sleigh.exact(te)[1][:, 1] - 1.1
    ups = te[1:][(pe[:-1] < 0) & (pe[1:] >= 0)]
    downs = te[1:][(pe[:-1] > 0) & (pe[1:] <= 0)]
    assert len(sol.t_events[0]) == len(ups) and len(sol.t_events[1]) == len(downs)
    np.testing.assert_allclose(sol.t_events[0], ups, atol=2e-4)
    for t_ev, p_ev in zip(sol.t_events[0], sol.p_events[0]):
        assert abs(p_ev[1] - 1.1) < 1e-8


# -- two zeros inside one step (the falling particle) ----------------------------------------------------
def level(t, q, p, a):
    """a["x"]·x + a["t"]·t − a["c"]: x(t) − c, or t − c (a zero exactly at a chosen time)."""
    return a["x"] * q[0] + a["t"] * t - a["c"]


#: every direction, record only: one compiled loop for the tests that use it
EACH_DIRECTION = [L.Event(level, 0, 0.0), L.Event(level, 0, 1.0), L.Event(level, 0, -1.0)]


def _x_minus(c):
    return {"x": 1.0, "t": 0.0, "c": float(c)}


#: Two attempts per compiled chunk: fewer than the zeros one attempt can record with three
#: events ((s - 1)·3 = 6), the case that once hung (and one compiled loop per event list).
CHUNK = 2


def _fall(events, args, t_span=(0.0, 4.0), n_steps=2):
    return L.solve(FALL, METHOD, t_span, Q0, P0, n_steps=n_steps, events=events, args=args, chunk_size=CHUNK)


def test_a_pair_of_zeros_inside_one_step_is_found_at_the_nodes():
    # steps [0, 2], [2, 4]; x − 0.375 is −0.375 at both ends of the first step and 0.125 at its
    # node t = 1: zeros at 0.5 (rising) and 1.5 (falling). Before: no sign change between the
    # step points, nothing found.
    sol = _fall(EACH_DIRECTION, _x_minus(0.375))
    assert sol.success and sol.result == L.Result.SUCCESSFUL
    both, rising, falling = sol.t_events
    np.testing.assert_allclose(both, [0.5, 1.5], atol=1e-13)
    np.testing.assert_allclose(rising, [0.5], atol=1e-13)
    np.testing.assert_allclose(falling, [1.5], atol=1e-13)
    np.testing.assert_allclose(sol.q_events[0][:, 0], [0.375, 0.375], atol=1e-13)


def test_the_kth_zero_stops_the_run_also_when_two_fall_in_one_step():
    # terminal=2: the second zero of the pair (1.5) ends the run, the first is recorded with it
    sol = _fall(L.Event(level, terminal=2), _x_minus(0.375))
    assert sol.success and sol.result == L.Result.EVENT and sol.status == 1
    np.testing.assert_allclose(sol.t_events[0], [0.5, 1.5], atol=1e-13)
    assert sol.t[-1] == pytest.approx(1.5, abs=1e-13) and abs(sol.q[-1, 0] - 0.375) < 1e-13


def test_a_zero_exactly_at_a_node_or_a_step_point_is_recorded_once():
    at = {"x": 0.0, "t": 1.0, "c": 1.0}  # t − 1: rising, zero exactly at t = 1
    for n_steps in (2, 4):  # t = 1 is the node of the first step, then a step point
        both, rising, falling = _fall(EACH_DIRECTION, at, n_steps=n_steps).t_events
        assert list(both) == [1.0] and list(rising) == [1.0] and len(falling) == 0, n_steps


def test_more_zeros_per_attempt_than_a_chunk_has_attempts_do_not_stall_the_loop():
    # one attempt can record (s - 1)·3 = 6 zeros here, a chunk of CHUNK = 2 attempts had room
    # for 2: the loop never ran and solve hung. The event buffer is now sized for an attempt.
    assert (METHOD.stages - 1) * len(EACH_DIRECTION) > CHUNK
    sol = _fall(EACH_DIRECTION, _x_minus(0.375), t_span=(0.0, 8.0), n_steps=4)
    assert sol.success and sol.stats["n_steps"] == 4
    np.testing.assert_allclose(sol.t_events[0], [0.5, 1.5], atol=1e-13)


# -- zeros at t0: scipy's rule ------------------------------------------------------------------
def _scipy(direction, terminal, t1=3.0):
    def x(t, y):
        return y[0]

    x.direction, x.terminal = direction, terminal
    return solve_ivp(lambda t, y: [y[1], -1.0], (0.0, t1), [0.0, 1.0], events=x, rtol=1e-10, atol=1e-12)


def test_zeros_at_t0_are_recorded_as_scipy_records_them():
    # x = t − t²/2: a zero at t0 = 0 (rising) and at t = 2 (falling, inside the second step).
    # Before: the zero at t0 was never recorded.
    sol = _fall(EACH_DIRECTION, _x_minus(0.0), t_span=(0.0, 3.0))
    for ours, direction in zip(sol.t_events, (0, 1, -1)):
        theirs = _scipy(direction, False).t_events[0]
        np.testing.assert_allclose(ours, theirs, atol=1e-9, err_msg=f"direction={direction}")
    assert list(sol.t_events[1]) == [0.0]  # exactly t0


def test_a_terminal_zero_at_t0_ends_the_run_at_t0_as_in_scipy():
    theirs = _scipy(0, True)
    assert theirs.status == 1 and list(theirs.t_events[0]) == [0.0]
    sol = _fall(L.Event(level, terminal=True), _x_minus(0.0), t_span=(0.0, 3.0))
    assert sol.success and sol.status == 1 and sol.result == L.Result.EVENT
    assert list(sol.t_events[0]) == [0.0] and list(sol.t) == [0.0] and sol.stats["n_steps"] == 0
    np.testing.assert_array_equal(sol.q_events[0], [Q0])
    np.testing.assert_array_equal(sol.p_events[0], [P0])


def test_the_zero_at_t0_counts_towards_terminal_as_in_scipy():
    theirs = _scipy(0, 2)
    sol = _fall(L.Event(level, terminal=2), _x_minus(0.0), t_span=(0.0, 3.0))
    assert sol.status == theirs.status == 1
    np.testing.assert_allclose(sol.t_events[0], theirs.t_events[0], atol=1e-9)
    assert sol.t[-1] == pytest.approx(2.0, abs=1e-13)
