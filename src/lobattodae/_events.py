r"""Events: zeros of user functions ``e(t, q, p, args)`` along the solution, located in the
compiled loop.

After every accepted step the event functions are evaluated at the new step point and at the
step's internal nodes ``t_n + c_i h`` (the stage points of each piece: Q_i and the IIIA
momenta p̃_i, read from the step's dense output, :mod:`lobattodae._dense`; no stage equation
is solved again). The nodes cut the step into sub-intervals; every sub-interval whose end
values show a sign change (filtered by ``direction``, in the direction of integration) holds
a zero, which is located on the dense output by the Illinois variant of regula falsi,
safeguarded by bisection, to ``|Δθ| ≤ THETA_TOL`` in the sub-interval's scaled time θ: the
zero of the dense output to round-off, so an event time is as accurate as the dense output
(order s between step points, ``docs/variable-steps.md``). So a pair of zeros inside one
step (a function that crosses and comes back) is found whenever a node lies between the two
zeros, and every zero the nodes reveal is recorded (several per step and event). A
*terminal* event does not take the dense value: the loop rejects the step and re-takes it to
end exactly at the located time (refined by Newton in time), so that the final state is a
step point of the method (``φ = 0`` to round-off) and the run ends there; with ``terminal=k``
the k-th zero counts, also when several fall in one step. Under error control every other
zero is landed on the same way and the run goes on from it (``Output.land_on_events``,
:func:`lobattodae._loop._events`): its row is a step point, as accurate as the steps.

Zeros at the nodes, as scipy's ``solve_ivp`` decides them: a zero exactly at ``t0`` is
recorded when the function then moves in the event's ``direction`` (any way for 0), and a
terminal one ends the run at ``t0`` (no step kept, ``Result.EVENT``); a zero exactly at a
later step point or node belongs to the sub-interval that ends on it and is recorded once
(scipy would record it again from the next step).

Not found: two zeros between the same two adjacent nodes (the values there have the same
sign, so nothing shows), which includes a function that only touches zero (a near-tangent
zero) between nodes. The user's lever is ``max_step`` (adaptive steps) or ``dt`` (constant
steps): with steps shorter than the shortest gap between two zeros a node lies between any
two of them (the step points are nodes; s = 2 with constant steps has no others), so every
zero where the function changes sign is found. A zero where it only touches zero is found
only where a node lands on it.

Settings and values are checked when the run is set up: ``terminal`` must be a bool or an
integer in ``[0, 2**31 - 1]`` (NumPy integers too), ``direction`` a number that is not NaN
(:class:`Event` and :func:`as_events`), and an event function must return a number, not a
bool (:func:`event_values`, traced when the loop is set up: a bool has no sign change to
locate, so its zeros would never be found). A value that is NaN at t0 is refused by
:func:`lobattodae.solve`; one that becomes non-finite later (at a step point or a node) ends
the run at that step point with ``Result.EVENT_NOT_FINITE`` (the loop checks,
:func:`lobattodae._loop.attempt`).
"""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass
from typing import Any, Callable, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from ._dense import DenseStep, evaluate, span
from ._errors import LobattoDAEInputError
from ._tableau import LobattoPair

__all__ = ["Event", "EventState", "as_events", "crossings", "event_values", "locate", "locate_all", "node_times",
           "node_values"]

#: Root-finding tolerance in the step's scaled time θ ∈ [0, 1].
THETA_TOL = 4 * 2.220446049250313e-16
#: Iteration cap of the root finder (bisection alone would reach THETA_TOL in 51).
MAX_ROOT_ITERATIONS = 80
#: The largest ``terminal``: occurrences are counted in int32.
MAX_TERMINAL = 2**31 - 1


def _terminal(value, what: str) -> int:
    """``terminal`` as a Python int: a bool (True is 1) or an integer in [0, MAX_TERMINAL]."""
    if isinstance(value, (bool, np.bool_)):
        return int(value)
    if isinstance(value, numbers.Integral) and 0 <= int(value) <= MAX_TERMINAL:
        return int(value)
    raise LobattoDAEInputError(
        f"{what}.terminal must be True/False or an integer from 0 to {MAX_TERMINAL} (0: record only; k: stop at "
        f"the k-th zero); got {value!r}."
    )


def _direction(value, what: str) -> float:
    """``direction`` as a Python float: any real number but NaN (its sign is what counts)."""
    if isinstance(value, numbers.Real) and not math.isnan(float(value)):
        return float(value)
    raise LobattoDAEInputError(
        f"{what}.direction must be a number: > 0 for zeros where the function increases, < 0 where it "
        f"decreases, 0 for both; got {value!r}."
    )


@dataclass(frozen=True)
class Event:
    """An event function ``fn(t, q, p, args) -> scalar`` and what its zeros do.

    Events compare equal when their fields do, so solving again with the same function reuses
    the compiled loop.

    Parameters
    ----------
    fn : callable
        ``fn(t, q, p, args) -> float``, a number (not a bool) whose zeros are the events.
    terminal : bool or int, optional
        0 (default: record only), or stop the run at the k-th zero (``True`` means 1); an
        integer from 0 to ``2**31 - 1``.
    direction : float, optional
        Record zeros where ``fn`` increases (> 0), decreases (< 0) or both (0, the default),
        in the direction of integration.

    Raises
    ------
    LobattoDAEInputError
        ``fn`` is not callable, ``terminal`` is not a bool or an integer in range, or
        ``direction`` is not a number (or is NaN).
    """

    fn: Callable[..., Any]
    terminal: int = 0
    direction: float = 0.0

    def __post_init__(self):
        if not callable(self.fn):
            raise LobattoDAEInputError(f"Event needs a callable e(t, q, p, args) -> float; got {self.fn!r}.")
        # normalised (np.int64(1) and True are 1): equal settings, equal events, one compiled loop
        object.__setattr__(self, "terminal", _terminal(self.terminal, "Event"))
        object.__setattr__(self, "direction", _direction(self.direction, "Event"))

    @property
    def name(self) -> str:
        return getattr(self.fn, "__name__", repr(self.fn))


def as_events(events) -> tuple[Event, ...]:
    """Normalise ``events`` (None, a callable or a list of them, scipy style: the attributes
    ``terminal`` and ``direction`` are read from each function) into :class:`Event` records."""
    if events is None:
        return ()
    if isinstance(events, Event) or (callable(events) and not isinstance(events, (list, tuple))):
        events = [events]
    if not isinstance(events, (list, tuple)):
        raise LobattoDAEInputError(f"events must be a callable or a list of callables; got {type(events).__name__}.")
    out = []
    for i, ev in enumerate(events):
        if isinstance(ev, Event):
            out.append(ev)
            continue
        if not callable(ev):
            raise LobattoDAEInputError(f"events[{i}] must be a callable e(t, q, p, args) -> float; got {ev!r}.")
        terminal = _terminal(getattr(ev, "terminal", False), f"events[{i}]")
        direction = _direction(getattr(ev, "direction", 0.0), f"events[{i}]")
        out.append(Event(ev, terminal, direction))
    return tuple(out)


class EventState(NamedTuple):
    """The event functions at the current step point, how often each has fired, and the
    event whose zero the loop is stepping to (-1: none): a terminal one (``stopping``, the run
    ends there) or, under error control, any other (``landing``, the zero becomes a step point)."""

    values: jax.Array  # (E,)
    counts: jax.Array  # (E,) int32
    stopping: jax.Array  # int32
    landing: jax.Array  # int32


def event_values(events: tuple[Event, ...], t, q, p, args, dtype):
    """(E,) the event functions at one point. An event function returning a bool is refused
    (when the loop is traced, i.e. set up): its values 0 and 1 never change sign."""
    if not events:
        return jnp.zeros((0,), dtype)
    values = []
    for ev in events:
        value = ev.fn(t, q, p, args)
        if jnp.asarray(value).dtype == jnp.bool_:
            raise LobattoDAEInputError(
                f"event function {ev.name!r} returns a bool; an event is a zero of a continuous function, located "
                "where its sign changes, and a bool (0 or 1) never changes sign. Return a number that crosses zero "
                "there instead, e.g. q[0] - 0.5 rather than q[0] > 0.5."
            )
        values.append(jnp.asarray(value, dtype).reshape(()))
    return jnp.stack(values)


def crossings(events: tuple[Event, ...], v0, v1, closed_start=False):
    """Bool, the shape of ``v0``: a zero between two nodes, in each event's direction (the last
    axis is the event's).

    A zero exactly at the end node counts (it belongs to the interval that ends on it); one
    exactly at the start node only with ``closed_start`` (scipy's rule at ``t0``: the zero
    counts when the function then moves in the event's direction)."""
    if not events:
        return jnp.zeros(jnp.shape(v0), bool)
    direction = jnp.asarray([ev.direction for ev in events], v0.dtype)
    at_start = closed_start & (v0 == 0)
    up = ((v0 < 0) | at_start) & (v1 >= 0)
    down = ((v0 > 0) | at_start) & (v1 <= 0)
    return jnp.where(direction > 0, up, jnp.where(direction < 0, down, up | down))


def node_times(pair: LobattoPair, step: DenseStep, t1):
    """``(N + 1,)`` the nodes of a step in the direction of integration: its start, the stage
    points ``t_k + c_i h_k`` of each piece k (the end of a piece is the start of the next) and
    its end ``t1`` (where the run puts it: exactly the controller's time)."""
    c = jnp.asarray(pair.c[1:], step.h.dtype)
    inner = (step.t0[:, None] + c[None, :] * step.h[:, None]).ravel()[:-1]
    return jnp.concatenate([step.t0[:1], inner, jnp.reshape(t1, (1,))])


def node_values(events: tuple[Event, ...], pair: LobattoPair, step: DenseStep, args, t_inner, dtype):
    """``(len(t_inner), E)`` the event functions at the step's internal nodes, from its dense
    output (at a node: the stage values Q_i and the IIIA momenta p̃_i)."""
    if t_inner.shape[0] == 0:
        return jnp.zeros((0, len(events)), dtype)

    def at(t):
        q, p, _ = evaluate(pair, step, t)
        return event_values(events, t, q, p, args, dtype)

    return jax.vmap(at)(t_inner)


def locate(pair: LobattoPair, event: Event, step: DenseStep, args, v0, v1, t_a=None, t_b=None):
    """The time of the zero of ``event`` in ``[t_a, t_b]`` (default: the whole step), between
    values ``v0`` (at ``t_a``) and ``v1`` (at ``t_b``) of opposite signs, on the dense output."""

    start, length = span(step)
    if t_a is not None:
        start, length = t_a, t_b - t_a

    def value(theta):
        t = start + theta * length
        q, p, _ = evaluate(pair, step, t)
        return jnp.asarray(event.fn(t, q, p, args), v0.dtype).reshape(())

    def cond(c):
        a, b, fa, fb, _, k = c
        return (b - a > THETA_TOL) & (fa != 0) & (fb != 0) & (k < MAX_ROOT_ITERATIONS)

    def body(c):
        a, b, fa, fb, side, k = c
        secant = (a * fb - b * fa) / (fb - fa)
        bisect = (k % 4 == 3) | ~((secant > a) & (secant < b))  # safeguard against stalling
        x = jnp.where(bisect, 0.5 * (a + b), secant)
        fx = value(x)
        left = jnp.sign(fx) == jnp.sign(fa)  # the root is in [x, b]
        # Illinois: halve the value kept at the end that stays twice in a row
        fb_new = jnp.where(left & (side == 1), 0.5 * fb, fb)
        fa_new = jnp.where(~left & (side == -1), 0.5 * fa, fa)
        a, fa = jnp.where(left, x, a), jnp.where(left, fx, fa_new)
        b, fb = jnp.where(left, b, x), jnp.where(left, fb_new, fx)
        return a, b, fa, fb, jnp.where(left, 1, -1), k + 1

    zero, one = jnp.asarray(0.0, v0.dtype), jnp.asarray(1.0, v0.dtype)
    a, b, fa, fb, _, _ = jax.lax.while_loop(cond, body, (zero, one, v0, v1, jnp.asarray(0), jnp.asarray(0)))
    theta = jnp.where(fa == 0, a, jnp.where(fb == 0, b, jnp.where(jnp.abs(fa) <= jnp.abs(fb), a, b)))
    # the ends exactly (start + 1·length can differ from t_b in the last bit)
    return jnp.where(theta == 0, start, jnp.where(theta == 1, start + length if t_b is None else t_b,
                                                   start + theta * length))


def locate_all(events: tuple[Event, ...], pair: LobattoPair, step: DenseStep, args, nodes, values, found):
    """``(N, E)`` the times of the zeros marked in ``found`` (sub-interval k between ``nodes[k]``
    and ``nodes[k + 1]``, event j; ``values`` at the nodes, ``(N + 1, E)``); unmarked entries
    hold the sub-interval's end. One root finder per marked zero (none in a step without)."""
    n_sub, n_ev = found.shape
    branches = [
        lambda ta, tb, va, vb, ev=ev: locate(pair, ev, step, args, va, vb, ta, tb) for ev in events
    ]

    def body(c):
        pending, times = c
        flat = jnp.argmax(pending.ravel())
        k, j = flat // n_ev, flat % n_ev
        t = jax.lax.switch(j, branches, nodes[k], nodes[k + 1], values[k, j], values[k + 1, j])
        return pending.at[k, j].set(False), times.at[k, j].set(t)

    times = jnp.broadcast_to(nodes[1:, None], (n_sub, n_ev))
    _, times = jax.lax.while_loop(lambda c: jnp.any(c[0]), body, (found, times))
    return times
