"""Events between and at the nodes of a step (issues #30 item 4, #29 item 1).

A pair of zeros inside one step is found where the step's internal nodes (its stage points)
show the sign changes; a zero exactly at t0 follows scipy's ``solve_ivp`` rule (recorded when
the function then moves in the event's direction; a terminal one ends the run at t0); a zero
exactly at a step point or node is recorded once.

The problem is a particle under a constant force beside a trivial constraint (p[1] = 0):
x = t − t²/2, which the method (s = 3) and its dense output reproduce exactly, so event times
are exact and comparable with scipy's on the same ODE. The event functions read their
shift from ``args``: every test shares the compiled loops (one per event list).
"""

import numpy as np
import pytest
from scipy.integrate import solve_ivp

import lobattodae as L
from helpers import FALL, FALL_Q0, FALL_P0

METHOD = L.LobattoIIIAIIIB(stages=3)
Q0, P0 = FALL_Q0, FALL_P0


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


def _solve(events, args, t_span=(0.0, 4.0), n_steps=2):
    return L.solve(FALL, METHOD, t_span, Q0, P0, n_steps=n_steps, events=events, args=args, chunk_size=CHUNK)


# -- two zeros inside one step --------------------------------------------------------------------
def test_a_pair_of_zeros_inside_one_step_is_found_at_the_nodes():
    # steps [0, 2], [2, 4]; x − 0.375 is −0.375 at both ends of the first step and 0.125 at its
    # node t = 1: zeros at 0.5 (rising) and 1.5 (falling). Before: no sign change between the
    # step points, nothing found.
    sol = _solve(EACH_DIRECTION, _x_minus(0.375))
    assert sol.success and sol.result == L.Result.SUCCESSFUL
    both, rising, falling = sol.t_events
    np.testing.assert_allclose(both, [0.5, 1.5], atol=1e-13)
    np.testing.assert_allclose(rising, [0.5], atol=1e-13)
    np.testing.assert_allclose(falling, [1.5], atol=1e-13)
    np.testing.assert_allclose(sol.q_events[0][:, 0], [0.375, 0.375], atol=1e-13)


def test_the_kth_zero_stops_the_run_also_when_two_fall_in_one_step():
    # terminal=2: the second zero of the pair (1.5) ends the run, the first is recorded with it
    sol = _solve(L.Event(level, terminal=2), _x_minus(0.375))
    assert sol.success and sol.result == L.Result.EVENT and sol.status == 1
    np.testing.assert_allclose(sol.t_events[0], [0.5, 1.5], atol=1e-13)
    assert sol.t[-1] == pytest.approx(1.5, abs=1e-13) and abs(sol.q[-1, 0] - 0.375) < 1e-13


def test_a_zero_exactly_at_a_node_or_a_step_point_is_recorded_once():
    at = {"x": 0.0, "t": 1.0, "c": 1.0}  # t − 1: rising, zero exactly at t = 1
    for n_steps in (2, 4):  # t = 1 is the node of the first step, then a step point
        both, rising, falling = _solve(EACH_DIRECTION, at, n_steps=n_steps).t_events
        assert list(both) == [1.0] and list(rising) == [1.0] and len(falling) == 0, n_steps


def test_more_zeros_per_attempt_than_a_chunk_has_attempts_do_not_stall_the_loop():
    # one attempt can record (s - 1)·3 = 6 zeros here, a chunk of CHUNK = 2 attempts had room
    # for 2: the loop never ran and solve hung. The event buffer is now sized for an attempt.
    assert (METHOD.stages - 1) * len(EACH_DIRECTION) > CHUNK
    sol = _solve(EACH_DIRECTION, _x_minus(0.375), t_span=(0.0, 8.0), n_steps=4)
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
    sol = _solve(EACH_DIRECTION, _x_minus(0.0), t_span=(0.0, 3.0))
    for ours, direction in zip(sol.t_events, (0, 1, -1)):
        theirs = _scipy(direction, False).t_events[0]
        np.testing.assert_allclose(ours, theirs, atol=1e-9, err_msg=f"direction={direction}")
    assert list(sol.t_events[1]) == [0.0]  # exactly t0


def test_a_terminal_zero_at_t0_ends_the_run_at_t0_as_in_scipy():
    theirs = _scipy(0, True)
    assert theirs.status == 1 and list(theirs.t_events[0]) == [0.0]
    sol = _solve(L.Event(level, terminal=True), _x_minus(0.0), t_span=(0.0, 3.0))
    assert sol.success and sol.status == 1 and sol.result == L.Result.EVENT
    assert list(sol.t_events[0]) == [0.0] and list(sol.t) == [0.0] and sol.stats["n_steps"] == 0
    np.testing.assert_array_equal(sol.q_events[0], [Q0])
    np.testing.assert_array_equal(sol.p_events[0], [P0])


def test_the_zero_at_t0_counts_towards_terminal_as_in_scipy():
    theirs = _scipy(0, 2)
    sol = _solve(L.Event(level, terminal=2), _x_minus(0.0), t_span=(0.0, 3.0))
    assert sol.status == theirs.status == 1
    np.testing.assert_allclose(sol.t_events[0], theirs.t_events[0], atol=1e-9)
    assert sol.t[-1] == pytest.approx(2.0, abs=1e-13)
