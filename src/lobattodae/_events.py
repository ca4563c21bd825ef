r"""Events: zeros of user functions ``e(t, q, p, args)`` along the solution, located in the
compiled loop.

After every accepted step the event functions are evaluated at the new step point. A sign
change (filtered by ``direction``) between the two step points is located on the step's
dense output (:mod:`lobattodae._dense`) by the Illinois variant of regula falsi, safeguarded
by bisection, to ``|Δθ| ≤ THETA_TOL`` in the step's scaled time θ: the zero of the dense
output to round-off, so an event time is as accurate as the dense output (order s between
step points, ``docs/variable-steps.md``). A *terminal* event does not take the dense value: the loop rejects the
step and re-takes it to end exactly at the located time, so that the final state is a
step point of the method (``φ = 0`` to round-off) and the run ends there.

Settings and values are checked when the run is set up: ``terminal`` must be a bool or an
integer in ``[0, 2**31 - 1]`` (NumPy integers too), ``direction`` a number that is not NaN
(:class:`Event` and :func:`as_events`), and an event function must return a number, not a
bool (:func:`event_values`, traced when the loop is set up: a bool has no sign change to
locate, so its zeros would never be found). A value that is NaN at t0 is refused by
:func:`lobattodae.solve`; one that becomes non-finite later ends the run at that step point
with ``Result.EVENT_NOT_FINITE`` (the loop checks, :func:`lobattodae._loop.attempt`).
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

__all__ = ["Event", "EventState", "as_events", "crossings", "event_values", "locate"]

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

    ``terminal``: 0 (record only), or stop the run at the k-th zero (``True`` means 1).
    ``direction``: record zeros where ``fn`` increases (> 0), decreases (< 0) or both (0),
    in the direction of integration. Events compare equal when their fields do, so solving again
    with the same function reuses the compiled loop.
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
    terminal event the loop is stepping to (-1: none)."""

    values: jax.Array  # (E,)
    counts: jax.Array  # (E,) int32
    stopping: jax.Array  # int32


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


def crossings(events: tuple[Event, ...], v0, v1):
    """(E,) bool: a zero between two step points, in each event's direction."""
    if not events:
        return jnp.zeros((0,), bool)
    direction = jnp.asarray([ev.direction for ev in events], v0.dtype)
    up = (v0 < 0) & (v1 >= 0)
    down = (v0 > 0) & (v1 <= 0)
    return jnp.where(direction > 0, up, jnp.where(direction < 0, down, up | down))


def locate(pair: LobattoPair, event: Event, step: DenseStep, args, v0, v1):
    """The time of the zero of ``event`` in the step, between values ``v0`` (θ = 0) and ``v1``
    (θ = 1) of opposite signs, on the dense output."""

    start, length = span(step)

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
    return start + theta * length
