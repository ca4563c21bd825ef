"""The compiled integration loop: step → controller → result → record.

One ``lax.while_loop`` whose body always reads in that order:

1. **step**: the method takes a step of the size the controller proposes;
2. **controller**: accepts or rejects it and proposes where the next step goes
   (:mod:`lobattodae._controllers`); a zero of a terminal event inside the step turns the
   step into a rejection and moves the end of the run onto the zero (:mod:`lobattodae._events`);
3. **result**: the first failure is kept in ``State.result`` and ends the loop;
4. **record**: an accepted step writes what :class:`Output` asks for: its step point (every
   ``every``-th one), the rows of ``t_eval`` it passed (from its dense output), the zeros of
   the event functions in it, its dense-output data.

Everything that changes from run to run (initial values, ``t_span``, tolerances, ``args``,
and what is recorded: the :class:`Recording` of ``t_eval`` times, ``save_every`` and the dense
output) is traced, so a loop is compiled once per (problem, method, controller, what it can
record (:class:`Output`: the events above all), shapes, buffer length). :func:`~lobattodae.integrate` and
:func:`~lobattodae.integrate_adaptive` are the pure entry points on top of it (jit/vmap-able,
:mod:`lobattodae._integrate`); :func:`~lobattodae.solve` runs it in chunks
(:mod:`lobattodae._chunks`). The layout of the recorded rows is :mod:`lobattodae._rows`'.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp

from ._controllers import END_STRETCH, ControlOptions, StepReport
from ._dense import DenseStep, dense_size, empty_dense_step, evaluate, pack_dense
from ._events import Event, EventState, crossings, event_values, locate_all, node_times, node_values
from ._projection import project_row
from ._results import Result
from ._rows import Record, event_buffers, event_row, pack_row, row_buffers
from ._stepper import LobattoIIIAIIIB, StepperState

__all__ = ["Attempt", "Chunk", "Output", "Recording", "State", "Steps", "attempt", "init_state", "run", "scan_run"]

#: An event's zero that the loop steps onto (a terminal one, or any under error control) is
#: refined (the step taken again onto ``t - v/v'``) until the Newton update in time is below this
#: fraction of ``max(|t|, |h|)``, at most MAX_EVENT_REFINEMENTS times: the state there lies on the
#: zero to the accuracy of a step point.
EVENT_TIME_RTOL = 1e-13
MAX_EVENT_REFINEMENTS = 4


@dataclass(frozen=True)
class Output:
    """What the compiled loop can record (static: it is part of the program).

    ``t_eval``: rows at given times instead of step points, taken from the dense output or,
    with ``step_to_t_eval``, at step points that the steps are shortened to land on
    (:func:`clip_to_outputs`); ``dense``: each accepted step's dense-output data; ``events``:
    the event functions whose zeros are recorded. Which of the rows, the stepping onto the
    times and the dense data a run uses is chosen by its :class:`Recording` (traced): one
    program serves them all (:attr:`lobattodae._options.Saving.output` says which programs
    :func:`~lobattodae.solve` compiles).
    """

    t_eval: bool = False
    dense: bool = False
    events: tuple[Event, ...] = ()
    step_to_t_eval: bool = False  # error-controlled steps may end on the t_eval times (T_EVAL_ROWS)
    project_t_eval: bool = False  # interpolated t_eval rows are moved onto the constraints (T_EVAL_ROWS)
    land_on_events: bool = False  # error control: every zero becomes a step point (see _events)


class Recording(NamedTuple):
    """What one run of the loop records, among what its :class:`Output` can (traced: a new
    choice runs the same compiled program).

    ``every``: keep every k-th step point (and the last); ``t_eval``: output times in the
    direction of integration, NaN-padded, the first of them the ``offset``-th of the run (a
    window: the rows a chunk can write are at most its length, so a window of that length
    serves any number of times); ``at_t_eval``, ``step_to_t_eval``, ``dense``: which of the
    output's capabilities are on (each only where the :class:`Output` has it)."""

    every: Any = 1
    t_eval: Any = None
    offset: Any = 0
    at_t_eval: Any = True
    step_to_t_eval: Any = True
    dense: Any = True


class State(NamedTuple):
    """Everything the loop carries (and a checkpoint stores)."""

    # the solution at the current step point
    q: jax.Array
    p: jax.Array
    lam: jax.Array
    # the method's memory: reused Jacobian, predictor, λ policy
    stepper: StepperState
    # the step-size controller's memory (where the next step goes)
    controller: Any
    # the last accepted step's dense output (t_eval rows and events across chunk boundaries)
    last: DenseStep
    events: EventState
    k_eval: jax.Array  # int32, the next t_eval row
    event_refinements: jax.Array  # int32, re-steps onto the current event zero after the first
    # outcome and counters
    result: jax.Array  # int32 Result: SUCCESSFUL while running, else the first failure's code
    n_accepted: jax.Array  # int32
    n_rejected: jax.Array  # int32, attempts the controller did not keep (terminal re-steps excluded)
    n_newton: jax.Array  # int32, Newton iterations over all steps
    n_jacobians: jax.Array  # int32
    max_constraint: jax.Array  # max ‖φ‖∞ over the step points so far
    max_drift: jax.Array  # max ‖λ − λ(t, q, p)‖∞ over the step points so far


def init_state(problem, method: LobattoIIIAIIIB, controller, output: Output, t0, t1, options: ControlOptions,
               q0, p0, lam0, args, lam_hidden=None) -> State:
    """The loop state at ``t0`` (λ0 must be consistent; nothing is validated here). ``lam_hidden``:
    λ(t0, q0, p0) from the hidden constraint when the caller has it (else computed)."""
    dtype = q0.dtype
    ctrl = controller.init(problem, method, t0, t1, q0, p0, lam0, args, options.cast(dtype))
    _, h = controller.proposal(ctrl)
    zero = jnp.asarray(0, jnp.int32)
    n_events = len(output.events)
    return State(
        q=q0, p=p0, lam=lam0,
        stepper=method.init(problem, t0, q0, p0, lam0, args, h, lam_hidden),
        controller=ctrl,
        last=empty_dense_step(t0, q0, p0, lam0, method.stages, method.pieces),
        events=EventState(
            event_values(output.events, t0, q0, p0, args, dtype),
            jnp.zeros((n_events,), jnp.int32), jnp.asarray(-1, jnp.int32), jnp.asarray(-1, jnp.int32),
        ),
        k_eval=zero,
        event_refinements=zero,
        result=jnp.asarray(Result.SUCCESSFUL, jnp.int32),
        n_accepted=zero, n_rejected=zero, n_newton=zero, n_jacobians=zero,
        max_constraint=jnp.max(jnp.abs(problem.phi(t0, q0, p0, args)), initial=0.0),
        max_drift=jnp.asarray(0.0, dtype),
    )


class Chunk(NamedTuple):
    """What one :func:`run` recorded (rows past the counts are NaN / unused)."""

    rows: Any  # (floats, ints) packed rows (_pack_row) from run; a Record of them from run_host
    n_rows: jax.Array
    dense: Any  # (length, D) packed DenseStep rows, or None
    n_dense: jax.Array
    event_rows: Any  # (capacity, 1 + 2n + m): t, q, p, lam of each zero found, or None
    event_index: Any  # (capacity,) int32: which event function
    n_events: jax.Array


def _row(problem, args, t, q, p, lam, info=None) -> Record:
    zero = jnp.asarray(0, jnp.int32)
    return Record(
        t, q, p, lam,
        zero if info is None else info.iterations,
        zero if info is None else info.n_jacobians,
        jnp.zeros((), q.dtype) if info is None else info.residual_norm,
        jnp.max(jnp.abs(problem.phi(t, q, p, args)), initial=0.0),
        jnp.zeros((), q.dtype) if info is None else info.drift,
        jnp.asarray(False) if info is None else info.resync,
    )


class Attempt(NamedTuple):
    """What one pass of steps 1-3 of the loop body produced (before recording)."""

    t1: jax.Array  # where the step ended
    q1: jax.Array
    p1: jax.Array
    lam1: jax.Array
    info: Any  # the stepper's StepInfo
    kept: jax.Array  # bool: accepted and not turned into a re-step to a terminal zero
    finished: jax.Array  # bool: kept, and the controller is done
    final_event: jax.Array  # bool: finished on a terminal event's zero (t1, q1, p1, lam1: the final row)
    constraint: jax.Array  # ‖φ(t1, q1, p1)‖∞
    found: jax.Array  # (N, n_events) bool: zeros found in the step (N sub-intervals between its nodes)
    times: jax.Array  # (N, n_events) their times
    final_index: jax.Array  # int32: the terminal event whose zero ends the run (with final_event)
    landed: jax.Array  # bool: kept, and the step ended on a zero of event ``landed_index`` (a step point)
    landed_index: jax.Array  # int32


def clip_to_outputs(t, h, t_eval):
    """``h``, shortened so that the step ends on the first output time after t, if it passes
    one (``t_eval`` sorted in the direction of integration, NaN-padded): the output row is
    then a step point, as accurate as the steps."""
    direction = jnp.sign(h)
    keys = jnp.where(jnp.isnan(t_eval), jnp.inf, direction * t_eval)
    k = jnp.minimum(jnp.searchsorted(keys, direction * t, side="right"), t_eval.shape[0] - 1)
    rest = t_eval[k] - t
    # as at the end of the interval, a step that would stop just short of the time is stretched to it
    reaches = jnp.isfinite(keys[k]) & (direction * rest > 0) & (jnp.abs(rest) <= (1.0 + END_STRETCH) * jnp.abs(h))
    return jnp.where(reaches, rest, h)


def attempt(problem, method: LobattoIIIAIIIB, controller, output: Output, st: State, args,
            t_eval=None, step_to_t_eval=True) -> tuple[State, Attempt]:
    """Steps 1-3 of the loop body: step, controller (and terminal events), result.

    Returns the state after the attempt (the step point moves only when the step is kept)
    and what the recording step needs. With ``output.step_to_t_eval`` and ``step_to_t_eval``
    (traced) the proposed step ends on the next time of ``t_eval`` it would pass.
    """
    dtype = st.q.dtype
    events = output.events
    n_ev = len(events)
    pair = method.pair
    # 1. step
    t, h = controller.proposal(st.controller)
    if output.step_to_t_eval:
        h = jnp.where(step_to_t_eval, clip_to_outputs(t, h, t_eval), h)
    direction = jnp.sign(h)
    q1, p1, lam1, info, stepper = method.step(problem, t, st.q, st.p, st.lam, h, args, st.stepper)
    ok = info.result == Result.SUCCESSFUL
    # 2. controller (and terminal events, which turn the step into a re-step to the zero)
    report = StepReport(
        ok, info.result, t, h, jnp.concatenate([st.q, st.p]), jnp.concatenate([q1, p1]), info.error, q1, p1, lam1,
        info.retry, info.share, info.resolved,
    )
    accept, ctrl, result = controller.adapt(st.controller, problem, args, report)
    t1 = jnp.where(accept, controller.time(ctrl), t + h)
    ev = _events(events, pair, direction, st, info.dense, t1, q1, p1, accept, args, dtype, output.land_on_events)
    ev_state, stop, again = ev.state, ev.stop, ev.again
    stopped = controller.stop_at(st.controller, ev.t_stop)
    ctrl = jax.tree_util.tree_map(lambda a, b: jnp.where(stop, a, b), stopped, ctrl)
    if output.land_on_events:
        landing = controller.step_to(st.controller, ev.t_land)
        ctrl = jax.tree_util.tree_map(lambda a, b: jnp.where(ev.land, a, b), landing, ctrl)
    kept = accept & ~stop & ~ev.land
    finished = kept & controller.done(ctrl)
    final_event = (finished & (st.events.stopping >= 0)) | ev.at_start
    final_index = jnp.where(ev.at_start, ev_state.stopping, st.events.stopping)
    # a run that ends on a terminal zero at the step's start: its final row is the step point
    t1, q1, p1, lam1 = (jnp.where(ev.at_start, a, b) for a, b in zip((t, st.q, st.p, st.lam), (t1, q1, p1, lam1)))
    # 3. result
    result = jnp.where(final_event & (result == Result.SUCCESSFUL), Result.EVENT, result)
    if n_ev:  # an event whose value is not finite can no longer be located: stop, never run on blind
        blind = kept & ~ev.finite
        result = jnp.where(blind & (result == Result.SUCCESSFUL), Result.EVENT_NOT_FINITE, result)
    result = jnp.where(st.result != Result.SUCCESSFUL, st.result, result).astype(jnp.int32)
    constraint = jnp.max(jnp.abs(problem.phi(t1, q1, p1, args)), initial=0.0)
    keep = functools.partial(jnp.where, kept)
    # An attempt that is not kept is retried from the state before it (the method's, less its
    # Jacobian factorisation: method.after_rejection), unless the controller ends the run on it and
    # no event can turn it into a re-step: then the method's state of the step before is never read
    # again, and selecting it (the predictor's stages) is skipped.
    retried = not (controller.ends_on_rejection and not n_ev)
    new = State(
        q=keep(q1, st.q), p=keep(p1, st.p), lam=keep(lam1, st.lam),
        stepper=method.after_rejection(kept, stepper, st.stepper) if retried else stepper,
        controller=ctrl,
        # only t_eval rows and events read the last step's dense output: keep the loop lean otherwise
        last=jax.tree_util.tree_map(keep, info.dense, st.last) if output.t_eval or n_ev else st.last,
        events=ev_state._replace(
            counts=ev_state.counts + (final_event & (jnp.arange(n_ev) == final_index)).astype(jnp.int32)
        ),
        k_eval=st.k_eval,
        event_refinements=jnp.where(ev.begins, 0, st.event_refinements + again.astype(jnp.int32)),
        result=result,
        n_accepted=st.n_accepted + kept.astype(jnp.int32),
        n_rejected=st.n_rejected + (~accept).astype(jnp.int32),
        n_newton=st.n_newton + info.iterations,
        n_jacobians=st.n_jacobians + info.n_jacobians,
        max_constraint=jnp.where(kept, jnp.maximum(st.max_constraint, constraint), st.max_constraint),
        max_drift=jnp.where(kept, jnp.maximum(st.max_drift, info.drift), st.max_drift),
    )
    return new, Attempt(t1, q1, p1, lam1, info, kept, finished, final_event, constraint, ev.found, ev.times,
                        final_index, ev.landed, ev.target)


def _events(events, pair, direction, st: State, step: DenseStep, t1, q1, p1, accept, args, dtype, land_on_zeros):
    """The event functions at the new point, the zeros found in the step (with their times:
    ``(N, E)``, one entry per sub-interval between the step's nodes and event), and whether the
    step becomes a re-step onto one of them.

    A terminal zero turns the step into a re-step that ends there (``stop``; the run ends). With
    ``land_on_zeros`` (error control) so does every other zero (``land``): the run lands on it
    and goes on, and its row is that step point, as accurate as the steps, instead of a value of
    the dense output. Either re-step is refined by Newton in time (``again``) until it ends on the
    zero to EVENT_TIME_RTOL.

    Returns an :class:`_EventStep`."""
    n_ev = len(events)
    if not n_ev:
        false = jnp.asarray(False)
        none = jnp.asarray(-1, jnp.int32)
        return _EventStep(st.events, jnp.zeros((0, 0), bool), jnp.zeros((0, 0), dtype), false, t1, false, false,
                          jnp.asarray(True), false, t1, false, none, false)
    v0 = st.events.values
    v1 = event_values(events, t1, q1, p1, args, dtype)
    nodes = node_times(pair, step, t1)
    values = jnp.concatenate([v0[None], node_values(events, pair, step, args, nodes[1:-1], dtype), v1[None]])
    n_sub = nodes.shape[0] - 1
    stopping = st.events.stopping >= 0
    landing = st.events.landing >= 0
    re_step = stopping | landing  # this attempt steps onto the zero of event ``target``
    target = jnp.where(stopping, st.events.stopping, st.events.landing)
    index = jnp.arange(n_ev)
    # scipy's rule at t0: a zero exactly there counts (when the function then moves in the
    # event's direction); at a later step point it was counted by the step that ended on it
    at_t0 = (jnp.arange(n_sub) == 0)[:, None] & (st.n_accepted == 0)
    found = crossings(events, values[:-1], values[1:], at_t0) & accept
    # on a re-step onto a zero, that zero (in the last sub-interval) is recorded at the step's end instead
    found = found & ~((jnp.arange(n_sub) == n_sub - 1)[:, None] & re_step & (index == target)[None, :])
    times = locate_all(events, pair, step, args, nodes, values, found)
    terminal = jnp.asarray([ev.terminal for ev in events], jnp.int32)
    # the k-th zero of an event with terminal=k stops the run, also when several are in the step
    nth = st.events.counts[None, :] + jnp.cumsum(found, axis=0, dtype=jnp.int32)
    is_stop = found & (terminal > 0)[None, :] & (nth >= terminal[None, :]) & ~stopping
    first = jnp.argmin(jnp.where(is_stop, direction * times, jnp.inf).ravel())
    j_stop = (first % n_ev).astype(jnp.int32)
    t_first = times.ravel()[first]
    if land_on_zeros:  # the first zero of an ordinary step, unless a terminal one comes first
        # (a zero at the step's start, scipy's rule at t0, is a step point already)
        is_land = found & ~is_stop & ~re_step & (times != nodes[0])
        first_land = jnp.argmin(jnp.where(is_land, direction * times, jnp.inf).ravel())
        t_land = times.ravel()[first_land]
        land = jnp.any(is_land) & (direction * t_land < jnp.where(jnp.any(is_stop), direction * t_first, jnp.inf))
        j_land = (first_land % n_ev).astype(jnp.int32)
    else:
        land, t_land, j_land = jnp.asarray(False), t1, jnp.asarray(-1, jnp.int32)
    # the re-step onto a zero located on the dense output ends where the event is not yet zero to
    # the step points' accuracy: one Newton step in time, and the step is taken again
    j_now = jnp.maximum(target, 0)
    t_newton = jax.lax.cond(re_step & accept, lambda: _newton_time(events, pair, step, args, j_now, v1[j_now], t1),
                            lambda: t1)
    t_prev = t1 - jnp.sum(step.h)
    t_newton = jnp.clip(t_newton, jnp.minimum(t_prev, 2 * t1 - t_prev), jnp.maximum(t_prev, 2 * t1 - t_prev))
    off = jnp.abs(t_newton - t1) > EVENT_TIME_RTOL * jnp.maximum(jnp.abs(t1), jnp.abs(t1 - t_prev))
    again = re_step & accept & off & (t_newton != t_prev) & (st.event_refinements < MAX_EVENT_REFINEMENTS)
    stop = (jnp.any(is_stop) & ~land) | (again & stopping)
    land = land | (again & landing)
    kept = accept & ~stop & ~land
    landed = landing & kept  # the re-step ended on its zero: a step point, recorded as the event's row
    # a terminal zero exactly at the step's start (scipy's rule at t0) ends the run there, on the
    # step point, without a step; the other zeros there are recorded with it
    at_start = stop & ~again & (t_first == nodes[0])
    others = (jnp.arange(n_sub * n_ev) != first).reshape(n_sub, n_ev)
    record = found & (kept | (at_start & (times == nodes[0]) & others))
    # the zero landed on is exactly zero at its step point: the next step must not find it again
    values_now = jnp.where(landed & (index == target), 0.0, v1)
    begins = (stop | land) & ~again  # a new zero to step onto: its refinements are counted afresh
    new = EventState(
        jnp.where(kept, values_now, v0),
        st.events.counts + jnp.sum(record, axis=0, dtype=jnp.int32) + (landed & (index == target)).astype(jnp.int32),
        jnp.where(stop & ~again, j_stop, st.events.stopping),
        # a re-step onto a zero that the controller rejects gives the landing up: the zero is still
        # ahead, and the next step that contains it lands on it afresh
        jnp.where(land & ~again, j_land, jnp.where(landed | stop | (landing & ~accept), -1, st.events.landing)),
    )
    return _EventStep(new, record, times, stop, jnp.where(again, t_newton, t_first), again, at_start,
                      jnp.all(jnp.isfinite(values)), land, jnp.where(again, t_newton, t_land), landed,
                      target.astype(jnp.int32), begins)


class _EventStep(NamedTuple):
    """What :func:`_events` found in one attempt."""

    state: EventState  # after the attempt
    found: jax.Array  # (N, E) bool: zeros to record (sub-interval k between nodes, event j)
    times: jax.Array  # (N, E) their times
    stop: jax.Array  # bool: a terminal zero (or a refinement) turns the step into a re-step ...
    t_stop: jax.Array  # ... ending here
    again: jax.Array  # bool: the re-step is a refinement onto the zero
    at_start: jax.Array  # bool: the terminal zero is the step's start: the run ends there
    finite: jax.Array  # bool: every value at the step's nodes is finite
    land: jax.Array  # bool: a zero that does not stop the run turns the step into a re-step ...
    t_land: jax.Array  # ... ending here
    landed: jax.Array  # bool: the step is kept and ends on the zero of event ``target``
    target: jax.Array  # int32: the event whose zero this attempt stepped onto (-1: none)
    begins: jax.Array  # bool: a new zero to step onto (stop or land, not a refinement)


def _newton_time(events, pair, step: DenseStep, args, j, value, t1):
    """``t1 - v(t1) / v'(t1)`` for event j, whose value at the step's end ``t1`` is ``value``; the
    slope from the step's dense output (accurate near its end, where the zero is)."""

    def slope(k):
        def v(t):
            q, p, _ = evaluate(pair, step, t)
            return jnp.asarray(events[k].fn(t, q, p, args), value.dtype).reshape(())

        return jax.jvp(v, (t1,), (jnp.ones_like(t1),))[1]

    dv = jax.lax.switch(j, [functools.partial(slope, k) for k in range(len(events))])
    usable = jnp.isfinite(dv) & (dv != 0) & jnp.isfinite(value)
    return jnp.where(usable, t1 - value / jnp.where(usable, dv, 1.0), t1)


def _step_record(a: Attempt) -> Record:
    info = a.info
    return Record(a.t1, a.q1, a.p1, a.lam1, info.iterations, info.n_jacobians, info.residual_norm, a.constraint,
                  info.drift, info.resync)


def run(problem, method: LobattoIIIAIIIB, controller, output: Output, state: State, args, length: int,
        recording: Recording = Recording(), max_attempts: int | None = None):
    """Advance ``state`` by at most ``max_attempts`` step attempts (default ``length``); return
    ``(state, Chunk)``, recording what ``recording`` asks for.

    The loop also stops when the controller is done, a step fails, or the buffers are full
    (``length`` rows; with t_eval rows a step can pass several times, the rest are written by
    the next call, which starts by writing the rows its state has passed). A failed step ends
    the loop with ``state.result`` set and ``state`` left at the last step point.
    """
    dtype = state.q.dtype
    n, m = state.q.shape[-1], state.lam.shape[-1]
    n_ev = len(output.events)
    pair = method.pair
    # an attempt records at most one zero per event and sub-interval between the step's nodes
    n_sub = method.pieces * (method.stages - 1)
    ev_capacity = max(length, n_sub * n_ev + 1)
    direction = jnp.sign(controller.proposal(state.controller)[1])
    rec = recording
    t_eval = jnp.full((1,), jnp.nan, dtype) if rec.t_eval is None else jnp.asarray(rec.t_eval, dtype)
    every, offset = jnp.asarray(rec.every, jnp.int32), jnp.asarray(rec.offset, jnp.int32)
    # the capabilities of the program that this run uses (Python False: not compiled in)
    at_t_eval = output.t_eval and rec.at_t_eval
    step_to_t_eval = output.step_to_t_eval and rec.step_to_t_eval
    dense_on = output.dense and rec.dense
    max_attempts = length if max_attempts is None else max_attempts

    def unwritten(st):
        """``(in_window, te)``: the first t_eval row not yet written, the window's entry
        ``k_eval - offset``, and whether the window holds it."""
        k = st.k_eval - offset
        return k < t_eval.shape[0], t_eval[jnp.clip(k, 0, t_eval.shape[0] - 1)]

    def pending(st, n_rows):
        """A t_eval row the run has passed and not yet written."""
        in_window, te = unwritten(st)
        t_now = controller.time(st.controller)
        return at_t_eval & in_window & (direction * (te - t_now) <= 0) & (n_rows < length)

    def next_time(st):
        """The next output time (as a 1-vector; NaN: none in the window): the rows up to the
        step point are written at the end of each attempt, so it is the first one not written."""
        in_window, te = unwritten(st)
        return jnp.where(in_window, te, jnp.nan)[None]

    def flush(st, rows, n_rows, step: DenseStep, info=None):
        """Write the t_eval rows up to the current step point from ``step``'s dense output."""
        if not output.t_eval:
            return st, rows, n_rows
        t_now = controller.time(st.controller)

        def body(c):
            k, rows, i = c
            te = t_eval[k - offset]
            at_end = te == t_now
            q, p, lam = evaluate(pair, step, te)
            if output.project_t_eval:
                q, p, lam = project_row(problem, te, q, p, lam, args)
            q, p, lam = (jnp.where(at_end, a, b) for a, b in zip((st.q, st.p, st.lam), (q, p, lam)))
            floats, ints = pack_row(_row(problem, args, te, q, p, lam, info))
            return k + 1, (rows[0].at[i].set(floats), rows[1].at[i].set(ints)), i + 1

        def cond(c):
            k, _, i = c
            return pending(st._replace(k_eval=k), i)

        k, rows, n_rows = jax.lax.while_loop(cond, body, (st.k_eval, rows, n_rows))
        return st._replace(k_eval=k), rows, n_rows

    def running(carry):
        st, buf, attempts = carry
        rows, n_rows, dense, n_dense, ev_rows, ev_idx, n_events = buf
        return (
            (st.result == Result.SUCCESSFUL) & ~controller.done(st.controller) & (attempts < max_attempts)
            & (n_rows < length) & (n_events + n_sub * n_ev + 1 <= ev_capacity) & ~pending(st, n_rows)
        )

    def body(carry):
        st, buf, attempts = carry
        rows, n_rows, dense, n_dense, ev_rows, ev_idx, n_events = buf
        # 1.-3. step, controller, result
        new, a = attempt(problem, method, controller, output, st, args, next_time(st), step_to_t_eval)
        # 4. record
        if output.t_eval:
            new, rows, n_rows = flush(new, rows, n_rows, new.last, a.info)
        save = a.kept & jnp.logical_not(at_t_eval) & ((new.n_accepted % every == 0) | a.finished)
        floats, ints = pack_row(_step_record(a))
        at = jnp.where(save, n_rows, length)
        rows = (rows[0].at[at].set(floats, mode="drop"), rows[1].at[at].set(ints, mode="drop"))
        n_rows = n_rows + save.astype(jnp.int32)
        if output.dense:
            at = jnp.where(a.kept & dense_on, n_dense, length)
            dense = dense.at[at].set(pack_dense(a.info.dense), mode="drop")
            n_dense = n_dense + (a.kept & dense_on).astype(jnp.int32)
        if n_ev:
            ev_rows, ev_idx, n_events = _write_events(ev_rows, ev_idx, n_events, a)
        return new, (rows, n_rows, dense, n_dense, ev_rows, ev_idx, n_events), attempts + 1

    def _write_events(ev_rows, ev_idx, n_events, a: Attempt):
        drop = ev_rows.shape[0]
        for j in range(n_ev):
            found, times = a.found[:, j], a.times[:, j]

            def event_rows(times=times):
                q, p, lam = jax.vmap(lambda tt: evaluate(pair, a.info.dense, tt))(times)
                return event_row(times, q, p, lam)

            # the states only where a zero was found (most steps have none); the buffers outside the cond
            rows = jax.lax.cond(jnp.any(found), event_rows, lambda: jnp.zeros((n_sub, ev_rows.shape[1]), dtype))
            at = jnp.where(found, n_events + jnp.cumsum(found, dtype=jnp.int32) - 1, drop)
            ev_rows = ev_rows.at[at].set(rows, mode="drop")
            ev_idx = ev_idx.at[at].set(j, mode="drop")
            n_events = n_events + jnp.sum(found, dtype=jnp.int32)
        # a zero the steps ended on (terminal, or landed on under error control): the step point itself
        row = event_row(a.t1, a.q1, a.p1, a.lam1)
        at_point = a.final_event | a.landed
        at = jnp.where(at_point, n_events, drop)
        ev_rows = ev_rows.at[at].set(row, mode="drop")
        ev_idx = ev_idx.at[at].set(jnp.where(a.final_event, a.final_index, a.landed_index), mode="drop")
        return ev_rows, ev_idx, n_events + at_point.astype(jnp.int32)

    rows = row_buffers(length, n, m, dtype)
    zero = jnp.asarray(0, jnp.int32)
    state, rows, n_rows = flush(state, rows, zero, state.last)
    d_size = dense_size(method.pieces, method.stages, n, m)
    dense = jnp.full((length, d_size), jnp.nan, dtype) if output.dense else None
    ev_rows, ev_idx = event_buffers(ev_capacity, n, m, dtype) if n_ev else (None, None)
    buf = (rows, n_rows, dense, zero, ev_rows, ev_idx, zero)
    state, buf, _ = jax.lax.while_loop(running, body, (state, buf, zero))
    (floats, ints), n_rows, dense, n_dense, ev_rows, ev_idx, n_events = buf
    return state, Chunk((floats, ints), n_rows, dense, n_dense, ev_rows, ev_idx, n_events)


class Steps(NamedTuple):
    """Per-attempt output of :func:`scan_run` (rows of attempts that were not kept are NaN)."""

    t: jax.Array  # (length,)
    q: jax.Array  # (length, n)
    p: jax.Array  # (length, n)
    lam: jax.Array  # (length, m)
    kept: jax.Array  # (length,) bool
    dense: Any  # (length, D) packed DenseStep rows (with ``dense=True``), else None


def scan_run(problem, method: LobattoIIIAIIIB, controller, state: State, args, length: int,
             checkpoints: int | None = None, dense: bool = False, t_eval=None) -> tuple[State, Steps]:
    """The loop body of :func:`run` (steps 1-3, :func:`attempt`) as a ``lax.scan`` of exactly
    ``length`` attempts, recording each attempt's step point as a scan output.

    A fixed trip count is what reverse-mode differentiation needs (a ``while_loop`` cannot be
    transposed); attempts after the controller is done or a step failed are skipped by a
    ``lax.cond`` (under ``vmap`` the skipped ones are computed and discarded). Memory for the
    backward pass: each attempt keeps its loop state and solved stages (Newton's root, tagged
    ``ROOT_NAME``), everything else (the stage Jacobian at the root, f and g at the stages)
    is recomputed from them, not Newton's iterations: O(length × state). With
    ``checkpoints=k`` the attempts are split into k segments of which only the starts are
    kept; a segment is recomputed, Newton included, in the backward pass: O(k + length/k)
    states for about one more forward solve (k ≈ √length gives O(√length)).
    """
    dtype = state.q.dtype
    n, m = state.q.shape[-1], state.lam.shape[-1]
    d_size = dense_size(method.pieces, method.stages, n, m)
    nan = functools.partial(jnp.full, fill_value=jnp.nan, dtype=dtype)

    def go(st):
        new, a = attempt(problem, method, controller, Output(step_to_t_eval=t_eval is not None), st, args, t_eval)
        row = Steps(a.t1, a.q1, a.p1, a.lam1, a.kept, pack_dense(a.info.dense) if dense else None)
        masked = jax.tree_util.tree_map(lambda x: jnp.where(a.kept, x, jnp.nan), row._replace(kept=None))
        return new, masked._replace(kept=a.kept)

    def idle(st):
        return st, Steps(nan(()), nan((n,)), nan((n,)), nan((m,)), jnp.asarray(False), nan((d_size,)) if dense else None)

    def body(st, i):
        # the segments may round the trip count up: attempts past ``length`` are skipped, so the
        # final state (and its status) is that of ``length`` attempts
        live = (st.result == Result.SUCCESSFUL) & ~controller.done(st.controller) & (i < length)
        return jax.lax.cond(live, go, idle, st)

    if checkpoints is None or checkpoints >= length:
        return jax.lax.scan(body, state, jnp.arange(length))
    inner = -(-length // checkpoints)

    @jax.checkpoint
    def segment(st, first):
        return jax.lax.scan(body, st, first + jnp.arange(inner))

    state, steps = jax.lax.scan(segment, state, inner * jnp.arange(checkpoints))
    return state, jax.tree_util.tree_map(lambda x: x.reshape((-1,) + x.shape[2:])[:length], steps)
