"""``solve``: integrate a partitioned index-2 DAE over an interval and return a :class:`~lobattodae.Solution`.

It reads in the order of the work: options (:class:`~lobattodae._options.RunOptions`, every
one checked, paths included) → checks of the problem and the initial values → compiled
chunks of the loop (:mod:`lobattodae._chunks`; the first also makes the loop state) with
progress, Ctrl-C, checkpoints and recovery of failed steps between them →
:func:`~lobattodae._solution.assemble` makes the :class:`~lobattodae.Solution`.
"""

from __future__ import annotations

import dataclasses
import errno
import os
import time
from typing import Any, Callable

import jax.numpy as jnp
import numpy as np

from . import _compile
from ._chunks import Progress, init_host, run_host, start_host
from ._controllers import ConstantStepSize, ControlOptions
from ._doubling import for_error_control
from ._errors import LobattoDAEInputError
from ._io import checkpoint as _checkpoint
from ._io import fingerprint_arrays, fingerprint_callable
from ._loop import Output, State
from ._options import RunOptions, concrete
from ._progress import ProgressBar, deferred_interrupts, progress_reporter
from ._results import Result
from ._rows import ROW_FIELDS, Record
from ._solution import Solution, assemble
from ._stepper import LobattoIIIAIIIB
from ._validate import check_float64, validate_and_residual

__all__ = ["solve"]

#: Automatic recovery retries a failed step as 2, 4, 8, 16 substeps (one compiled chunk of 16).
_RECOVERY_HALVINGS = 4


def solve(
    problem,
    method: LobattoIIIAIIIB,
    t_span,
    q0,
    p0,
    *,
    n_steps: int | None = None,
    dt: float | None = None,
    rtol: float | None = None,
    atol: float | None = None,
    first_step: float | None = None,
    max_step: float | None = None,
    controller=None,
    t_eval=None,
    dense_output: bool = False,
    events=None,
    save_every: int | str | None = None,
    lam0=None,
    args: Any = None,
    throw: bool = True,
    project_initial: bool = False,
    chunk_size: int | None = None,
    progress: bool | Callable[[float, float], None] = False,
    max_recoveries: int = 0,
    checkpoint: str | os.PathLike | None = None,
    checkpoint_every: int | None = None,
    resume: bool = False,
    t_eval_rows: str | None = None,
    max_steps: int | None = None,
) -> Solution:
    """Integrate a partitioned index-2 DAE from ``t_span[0]`` to ``t_span[1]``.

    Steps are chosen by error control (``rtol``, ``atol``) unless ``n_steps`` or ``dt`` asks
    for constant steps. The vocabulary follows scipy's ``solve_ivp``.

    Parameters
    ----------
    problem : PartitionedDAE, NonholonomicSystem or MechanicalSystem
        Reuse one problem object and pass parameters through ``args``: the compiled loop is
        cached per problem object, method, step-size rule, event functions and shapes, so new
        numbers (initial values, ``t_span``, tolerances, ``n_steps``, ``args`` values) do not
        recompile, nor does ``save_every``; the first run with ``t_eval`` or ``dense_output``
        compiles the loop that records them, once for every later ``t_eval`` and
        ``dense_output`` (``events`` and ``t_eval_rows="project"`` compile loops of their own).
    method : LobattoIIIAIIIB or NativeIntegrator
        The method; or, for a model of :mod:`lobattodae.mechanics`, its native program
        ``model.native(stages)`` (``problem`` then ``model.problem``): each step (under error
        control each attempt of step doubling) is one call into compiled C, everything else
        (controller, events, ``t_eval``, dense output, checkpoints) as with the method, the
        same steps to round-off (:meth:`~lobattodae.mechanics.NativeIntegrator.solve`).
    t_span : (float, float)
        ``(t0, t1)``; ``t1 < t0`` integrates backwards.
    q0, p0 : array_like, shape (n,)
        Consistent initial values, ``φ(t0, q0, p0) = 0``.
    n_steps, dt : int or float, optional
        Constant steps: their number, or a maximal step size (the step used is
        ``h = (t1 - t0) / ceil(|t1 - t0| / dt)``, reported in ``stats["h"]``).
    rtol, atol : float, optional
        Adaptive steps (default ``1e-8``, ``1e-10``): each step's own local error in q and p
        (estimated by step doubling) is kept below ``atol + rtol·|y|`` per unit of the
        interval, so that the global error follows rtol (:class:`~lobattodae.PIController`).
        λ is not error-controlled.
    first_step, max_step : float, optional
        Adaptive steps: the first step size (default, or 0: chosen from the initial slopes)
        and an upper bound on all of them (default: none).
    max_steps : int, optional
        Adaptive steps: the cap on step attempts (default 10⁷, at most
        2·10⁷), checked between compiled chunks of ``chunk_size`` attempts; reaching it ends
        the run with ``Result.MAX_STEPS`` (``success`` False) and the computed prefix. A
        ``max_step`` that would need more steps is refused up front.
    controller : PIController or ReversibleStepSize, optional
        The step-size rule of adaptive steps (default ``PIController()``);
        ``ReversibleStepSize()`` keeps the variable-step method symmetric for reversible
        problems (bounded energy errors over long times).
    t_eval : array_like, optional
        Output times (within ``t_span``, sorted in the direction of integration) instead of
        step points; memory is proportional to ``len(t_eval)``. ``t_eval=[t1]`` keeps the
        final state only.
    t_eval_rows : {"step", "interpolate", "project"}, optional
        How the ``t_eval`` rows are made. ``"step"`` (the default under error control): the
        steps are shortened to end on the requested times, so each row is a step point, as
        accurate as the run and on the constraint to round-off; a time between two steps
        the controller would take costs at most one extra step (the step after it resumes the
        size the controller had proposed). ``"interpolate"`` (the default for
        constant steps and ``ReversibleStepSize``, which keep their steps): rows from the
        dense output, no extra steps, accurate to order s between step points (at tight
        tolerances orders of magnitude less accurate than the step points, and ‖φ‖ at the
        interpolation error; ``stats["constraint_residual"]`` reports it). ``"project"``: the
        interpolated rows moved onto the constraints (ψ = 0 for position constraints, φ = 0,
        λ the consistent multiplier), still of order s, with ‖φ‖ at round-off.
    dense_output : bool
        Keep every step's continuous extension: ``sol.sol(t) -> (q, p, lam)``.
    events : callable, Event, or list of them, optional
        ``e(t, q, p, args) -> float``; zeros are located on the dense output and returned in
        ``t_events``, ``q_events``, ... (one array per function). Attributes as in scipy:
        ``e.terminal`` (True, or stop at the k-th zero) and ``e.direction`` (> 0: rising
        zeros only, < 0: falling only). A terminal zero ends the run with a final step onto
        it, so the final state satisfies the constraint to round-off; under error control
        the steps land on every other zero too (its row a step point, as accurate as the
        steps), with constant or reversible steps those rows come from the dense output. Sign changes are looked
        for between the step's nodes (step points and stage points), so two zeros inside one
        step are found when a node lies between them; closer pairs need a smaller
        ``max_step``/``dt``. A zero exactly at t0 counts as in
        scipy (when the function then moves in the event's direction; a terminal one ends the
        run at t0).
    save_every : int or 'final', optional
        Keep every k-th step point (and the last), or only the final one.
    lam0 : array_like, shape (m,), optional
        Initial multiplier. Computed from the hidden constraint when omitted; checked
        against it when given.
    args : pytree, optional
        Passed to the problem functions.
    throw : bool
        If True (default) a failed step raises :class:`NewtonFailure`; otherwise the computed
        prefix is returned with ``success=False`` and the reason in ``result``. A run that
        ends early at ``max_steps`` or on Ctrl-C returns its prefix either way.
    project_initial : bool
        Replace ``p0`` by its least-squares projection onto the constraint
        {p : φ(t0, q0, p) = 0} (always, to round-off) instead of rejecting inconsistent values;
        with a ``position_constraint``, ``q0`` is first moved onto ψ(t0, q) = 0 (as the steps'
        projection moves their end points; for a mechanical system in the kinetic metric).
    chunk_size : int, optional
        Step attempts per compiled chunk (default 2048); progress,
        Ctrl-C and checkpoints act between chunks.
    progress : bool or callable
        ``True`` shows a progress bar on stderr once the run has taken more than a second; a
        callable is called after each chunk as ``progress(steps_done, n_steps)`` (constant
        steps) or ``progress(t, t1)`` (adaptive). Ctrl-C returns the computed prefix with
        ``result`` ``INTERRUPTED`` at the end of the chunk (a second Ctrl-C stops at once).
    max_recoveries : int
        Constant steps only (off by default): a step whose Newton iteration fails is retried
        as 2, 4, 8 or 16 substeps, at most this many times per solve; ``stats["recoveries"]``
        counts them. Adaptive steps shrink a failed step by themselves.
    checkpoint : path, optional
        Write the loop state and the computed rows to this file every ``checkpoint_every``
        steps (at chunk boundaries), at the end, and on Ctrl-C. Each save writes only the
        rows since the previous one, appended as a segment file in the directory
        ``<checkpoint>.rows/`` next to it, and rewrites the small file itself (the state),
        atomically (a versioned format): bytes written grow with the rows
        kept (``save_every``), not with the number of saves. Keep (move, copy, delete) the
        file and its ``.rows`` directory together. Its directory must exist. A run without
        ``resume`` replaces an existing checkpoint (its segments are removed at the first save).
        A save that fails (a full disk, a directory made read-only) stops the run with
        :class:`~lobattodae.CheckpointWriteError`, which names the file and the fix and carries
        the computed prefix as ``.solution`` (with ``throw=False`` that prefix is returned,
        ``success`` False, the reason in ``message``); the checkpoint on disk stays the last
        one committed, intact, and resumes.
    checkpoint_every : int, optional
    resume : bool
        Continue from ``checkpoint`` if it exists. It must come from the same run (problem
        functions, method, ``args``, ``t_span``, steps or tolerances, output options, initial
        values). A resumed run gives the same numbers, bit for bit, as an uninterrupted one.

    Returns
    -------
    Solution
        The rows, how the run ended (``success``, ``status``, ``result``, ``message``) and
        ``stats``.

    Raises
    ------
    LobattoDAEInputError
        Bad input, before any work; the subclass says which kind: :class:`ShapeError`,
        :class:`ProblemFunctionError`, :class:`InconsistentInitialValuesError`,
        :class:`SingularConstraintError`, :class:`CheckpointError`.
    TypeError
        ``method`` is not a :class:`LobattoIIIAIIIB` (or a ``NativeIntegrator``).
    CheckpointWriteError
        A checkpoint could not be saved during the run and ``throw`` is True; it carries the
        computed prefix as ``.solution``.
    NewtonFailure
        A step failed (Newton's iteration, a step size too small, a non-finite value) and
        ``throw`` is True (the default), with ``.step``, ``.t`` and ``.reason``.
    """
    check_float64()
    _refuse_tracers(t_span=t_span, q0=q0, p0=p0, lam0=lam0, args=args, n_steps=n_steps, dt=dt, rtol=rtol, atol=atol)
    opt = RunOptions.check(
        method, t_span, n_steps, dt, rtol, atol, first_step, max_step, controller, t_eval, dense_output, events,
        save_every, chunk_size, max_recoveries, checkpoint, checkpoint_every, resume, t_eval_rows, max_steps,
    )
    # From here on a first Ctrl-C only asks the run to stop at the next chunk boundary (also
    # during validation and compilation), so it never lands inside JAX or between updates.
    with deferred_interrupts() as interrupted:
        return _run(problem, method, opt, q0, p0, lam0, args, throw, project_initial, progress, interrupted)


def _refuse_tracers(**inputs) -> None:
    """``solve`` runs Python between compiled chunks and returns NumPy: under ``jax.grad``,
    ``jit`` or ``vmap`` its inputs are tracers, which it cannot use. Say so, and where to go."""
    for name, value in inputs.items():
        if not concrete(value):
            raise LobattoDAEInputError(
                f"solve() was called with a traced {name} (inside jax.grad, jit, vmap or another JAX "
                "transformation); it runs Python between compiled chunks and returns NumPy arrays, so it "
                "cannot be transformed. Use the pure entry points instead: lobattodae.integrate (constant "
                "steps) or lobattodae.integrate_adaptive(..., differentiable=True) (variable steps), with "
                "lobattodae.consistent_lambda and lobattodae.project_momenta for initial values."
            )


def _run(problem, method, opt: RunOptions, q0, p0, lam0, args, throw, project_initial, progress, interrupted):
    """Validation, the loop state, the compiled chunks (progress, checkpoints, recovery), the
    Solution; ``interrupted()`` says whether Ctrl-C asked to stop."""
    method = for_error_control(method, opt.controller, problem, native=True)
    q0, p0, lam0, phi0, lam_hidden = validate_and_residual(problem, opt.t0, q0, p0, lam0, args,
                                                           project=project_initial)
    _check_events(opt.output.events, opt.t0, q0, p0, args)
    report = progress_reporter(progress, opt)
    controller, output = opt.controller, opt.output

    def initial():
        state, packing = init_host(problem, method, controller, output, opt.t0, opt.t1, opt.control, q0, p0, lam0, args)
        return _progress(opt, state), packing

    meta = _run_identity(problem, method, args, opt, q0, p0, lam0) if opt.checkpoint else None
    run = packing = None  # a fresh run computes its initial state in its first chunk's compiled call
    if opt.checkpoint and opt.resume and _checkpoint.exists(opt.checkpoint):
        run, packing = initial()
        run = _resume(opt, meta, run.state)
    failed = False
    start = time.perf_counter()
    last_saved = 0 if run is None else int(run.state.n_accepted)
    saved_t = opt.t0 if run is None else float(controller.time(run.state.controller))
    write_error, stopped_early = None, False  # an OSError of a checkpoint save; it stopped the run
    try:
        while not interrupted() and (run is None or not (opt.finished(run.state) or opt.capped(run.state))):
            if run is None:
                state, chunk, packing = start_host(problem, method, controller, output, opt.t0, opt.t1, opt.control, q0,
                                                   p0, lam0, args, opt.chunk, opt.recording(None),
                                                   lam_hidden=lam_hidden)
                run = _progress(opt, state)
            else:
                state, chunk = run_host(problem, method, controller, output, packing, run.state, args, opt.chunk,
                                        opt.recording(run.state))
            run = run.with_chunk(chunk)._replace(state=state)
            if int(state.result) not in (Result.SUCCESSFUL, Result.EVENT):
                recovered = None
                if run.recoveries < opt.max_recoveries:
                    recovered = _recover_step(problem, method, args, state)
                if recovered is None:
                    failed = True
                    break
                state, row = recovered
                run = run._replace(state=state, rows=run.rows.append(tuple(row)), recoveries=run.recoveries + 1)
            if report is not None:
                report(*opt.progress_numbers(run.state))
            done = int(run.state.n_accepted)
            if opt.checkpoint and opt.checkpoint_every and done - last_saved >= opt.checkpoint_every:
                try:
                    run = _save(opt.checkpoint, meta, run)
                except (OSError, _checkpoint.CheckpointError) as exc:  # the disk, not the run: stop here
                    write_error, stopped_early = exc, True
                    break
                last_saved, saved_t = done, float(controller.time(run.state.controller))
    except KeyboardInterrupt:  # a second Ctrl-C, or one outside the main thread's handler
        pass
    if run is None:  # interrupted before the first chunk
        run, _ = initial()
    if isinstance(report, ProgressBar):
        report.close()
    finished = opt.finished(run.state)
    if opt.checkpoint and write_error is None and (int(run.state.n_accepted) > last_saved or not finished):
        try:
            run = _save(opt.checkpoint, meta, run)
        except (OSError, _checkpoint.CheckpointError) as exc:
            write_error = exc
    elapsed = time.perf_counter() - start
    if write_error is None:
        return assemble(problem, method, args, opt, q0, p0, lam0, phi0, run, failed, finished, throw, elapsed)
    sol = assemble(problem, method, args, opt, q0, p0, lam0, phi0, run, failed, finished, False, elapsed)
    return _write_failed(opt, sol, write_error, float(controller.time(run.state.controller)),
                         last_saved if run.segments is not None else None, saved_t, stopped_early, throw)


def _write_failed(opt: RunOptions, sol: Solution, exc: Exception, t_now: float, saved_steps: int | None,
                  saved_t: float, stopped_early: bool, throw: bool) -> Solution:
    """The run whose checkpoint could not be written: :class:`~lobattodae.CheckpointWriteError`
    carrying the computed prefix (``throw``), or that prefix with the reason in its message.

    A failed periodic save stops the run (``stopped_early``: the result is ``INTERRUPTED``,
    ``success`` False; the disk would not take the next save either); a failed final save
    leaves the run's own result. The checkpoint on disk is the last one committed
    (``saved_steps`` steps; None: none of this run), intact."""
    path = opt.checkpoint
    code = getattr(exc, "errno", None)
    if code in (errno.ENOSPC, getattr(errno, "EDQUOT", None)):
        fix = "free space on that disk (or raise the quota)"
    elif code in (errno.EROFS, errno.EACCES, errno.EPERM):
        fix = "make the directory writable again (it may have been remounted read-only)"
    else:
        fix = "fix the cause"
    cause = f"{exc.strerror} (errno {exc.errno})" if isinstance(exc, OSError) and exc.strerror else str(exc)
    if saved_steps is None:
        on_disk = "no checkpoint of this run was committed"
        then = f"{fix} and run again, or choose another checkpoint path"
    else:
        on_disk = (f"the checkpoint on disk is intact and holds the run up to step {saved_steps:,} "
                   f"(t = {saved_t:.6g})")
        then = f"{fix} and continue from it with resume=True, or choose another checkpoint path"
    where = f"t = {t_now:.6g}, {sol.stats['n_steps']:,} steps"
    prefix = "in the error's .solution" if throw else "returned"
    stopped = f"The run stopped there ({where})" if stopped_early else f"The run itself ended ({where})"
    message = (f"cannot write the checkpoint '{path}': {cause}. {stopped}; {on_disk}. The computed prefix is "
               f"{prefix}. To go on, {then}.")
    # stopped early, the run is INTERRUPTED (success False): the message says why; a run that ended by
    # itself keeps its result and message, and this one is added
    own = not (stopped_early and sol.result == Result.INTERRUPTED)
    sol = dataclasses.replace(sol, message=f"{sol.message} {message}" if own else message)
    if throw:
        raise _checkpoint.CheckpointWriteError(message, path=path, solution=sol, errno=code) from exc
    return sol


def _check_events(events, t0, q0, p0, args) -> None:
    """Each event function must return one finite number at the initial point."""
    for i, ev in enumerate(events):
        try:
            value = np.asarray(ev.fn(jnp.asarray(t0), jnp.asarray(q0), jnp.asarray(p0), args), dtype=np.float64)
        except Exception as exc:  # noqa: BLE001 - the user's function, reported with its name
            raise LobattoDAEInputError(f"event function {ev.name!r} (events[{i}]) failed at t0: {exc}") from exc
        if value.size != 1:
            raise LobattoDAEInputError(
                f"event function {ev.name!r} (events[{i}]) must return one number; it returned shape {value.shape}."
            )
        if not np.isfinite(value).all():
            raise LobattoDAEInputError(f"event function {ev.name!r} (events[{i}]) is not finite at t0 ({float(value.ravel()[0])}).")


def _recover_step(problem, method, args, state: State):
    """Retry the failed (constant) step of ``state`` as 2^j substeps; return ``(state, row)``
    or None.

    The substeps start afresh (no reused Jacobian, no predictor history: those belong to the
    step size h), and so does the step after the recovered one. The row's statistics are the
    sums over the substeps.
    """
    controller = ConstantStepSize()
    ctrl = state.controller
    t_start, h = controller.proposal(ctrl)
    for j in range(1, _RECOVERY_HALVINGS + 1):
        sub, packing = init_host(
            problem, method, controller, Output(), t_start, t_start + h, ControlOptions(n=1 << j),
            state.q, state.p, state.lam, args,
        )
        sub, chunk = run_host(problem, method, controller, Output(), packing, sub, args, 1 << _RECOVERY_HALVINGS)
        count = int(chunk.n_rows)
        if int(sub.result) != Result.SUCCESSFUL or count != 1 << j:
            continue
        rows = Record(*(x[:count] for x in chunk.rows))
        row = rows._replace(
            **{f: getattr(rows, f)[-1:] for f in ("t", "q", "p", "lam", "constraint", "drift")},
            iterations=np.asarray([rows.iterations.sum()], np.int32),
            n_jacobians=np.asarray([rows.n_jacobians.sum()], np.int32),
            residual_norm=np.asarray([rows.residual_norm.max()]),
            resync=np.asarray([rows.resync.any()]),
        )
        ctrl = ctrl._replace(k=ctrl.k + 1)
        t_next, h_next = controller.proposal(ctrl)
        new = state._replace(
            q=sub.q, p=sub.p, lam=sub.lam,
            stepper=_init_stepper(problem, method, t_next, sub.q, sub.p, sub.lam, args, h_next),
            controller=ctrl,
            result=jnp.asarray(Result.SUCCESSFUL, jnp.int32),
            n_accepted=state.n_accepted + 1,
            n_newton=state.n_newton + sub.n_newton,
            n_jacobians=state.n_jacobians + sub.n_jacobians,
            max_constraint=jnp.maximum(state.max_constraint, sub.max_constraint),
            max_drift=jnp.maximum(state.max_drift, sub.max_drift),
        )
        return new, row
    return None


_init_stepper = _compile.jit(
    lambda problem, method, t, q, p, lam, args, h: method.init(problem, t, q, p, lam, args, h),
    static_argnums=(0, 1),
)


# -- checkpoints ----------------------------------------------------------------------------------
def _run_identity(problem, method, args, opt: RunOptions, q0, p0, lam0) -> dict:
    """What a checkpoint must match to be resumed: the problem's functions, the method, args,
    the time grid or tolerances, the output options and the initial values."""
    return {
        "problem": fingerprint_callable(problem),
        "method": repr(method),
        "args": fingerprint_arrays(args) if args is not None else None,
        "t_span": opt.span.identity(),
        "steps": opt.steps.identity(),
        "output": opt.saving.identity(),
        "initial_values": fingerprint_arrays(np.asarray(q0), np.asarray(p0), np.asarray(lam0)),
    }


def _save(path: str, meta: dict, run: Progress) -> Progress:
    """Commit a checkpoint of ``run``: its state and the rows since the last save (an
    incremental segment, :mod:`lobattodae._io.checkpoint`). Returns ``run`` with those rows
    marked saved."""
    new = {}
    for kind, rows in run.kinds():
        new.update(zip(ROW_FIELDS[kind], rows.unsaved()))
    counters = {"done": int(run.state.n_accepted), "rows": run.rows.count, "recoveries": run.recoveries}
    segments = _checkpoint.save(path, meta=meta, counters=counters, state=run.state, rows=new, previous=run.segments)
    marked = {kind: rows._replace(saved=rows.count) for kind, rows in run.kinds()}
    return run._replace(segments=segments, **marked)


def _progress(opt: RunOptions, state: State, recoveries: int = 0) -> Progress:
    """A run at ``state`` with no rows yet, of the kinds ``opt`` keeps."""
    return Progress.start(state, opt.saving.dense, bool(opt.saving.events), recoveries)


def _resume(opt: RunOptions, meta: dict, template: State) -> Progress:
    path = opt.checkpoint
    empty = _progress(opt, template)
    names = [name for kind, _ in empty.kinds() for name in ROW_FIELDS[kind]]
    counters, state, rows, segments = _checkpoint.load(path, meta=meta, state_template=template, row_names=names)
    count = int(counters.get("rows", -1))
    if count < 0 or any(len(rows[f]) != count for f in Record._fields):
        raise _checkpoint.CheckpointError(
            f"checkpoint '{path}' is corrupt or not a lobattodae checkpoint (it holds {len(rows['t'])} rows, its "
            f"counter says {count}); delete it or restart without resume."
        )
    if opt.saving.events and len(rows["event_rows"]) != len(rows["event_index"]):
        raise _checkpoint.CheckpointError(
            f"checkpoint '{path}' is corrupt or not a lobattodae checkpoint ({len(rows['event_rows'])} event rows, "
            f"{len(rows['event_index'])} event indices); delete it or restart without resume."
        )
    run = _progress(opt, state, int(counters.get("recoveries", 0)))._replace(segments=segments)
    loaded = {}
    for kind, empty_rows in run.kinds():
        fields = tuple(rows[name] for name in ROW_FIELDS[kind])
        loaded[kind] = empty_rows.append(fields)._replace(saved=len(fields[0]))
    return run._replace(**loaded)
