"""The pure entry points: :func:`integrate` (constant steps) and :func:`integrate_adaptive`
(error-controlled or reversible steps), jit/vmap/grad-able, and their result records.

Both run the compiled loop of :mod:`lobattodae._loop` in one call: :func:`integrate` as a
``lax.scan`` of ``n_steps`` steps, :func:`integrate_adaptive` as the ``while_loop`` of
:func:`~lobattodae._loop.run` or, with ``differentiable=True``, as a scan of ``max_steps``
attempts (:func:`~lobattodae._loop.scan_run`). Options given as numbers are checked by the
rules of :mod:`lobattodae._options`, the same as :func:`~lobattodae.solve`'s.
"""

from __future__ import annotations

import functools
import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from . import _compile
from ._controllers import ConstantStepSize, ControlOptions, PIController, roundoff_may_exceed
from ._dense import evaluate, unpack_dense
from ._doubling import for_error_control
from ._errors import LobattoDAEInputError
from ._loop import Output, Recording, init_state, run, scan_run
from ._controllers import ATOL, RTOL
from ._options import (
    STATIC_MAX_STEPS,
    AdaptiveSteps,
    TimeSpan,
    check_count,
    check_max_steps,
    check_t_eval,
    concrete,
    t_eval_output,
    t_eval_rows_mode,
)
from ._projection import project_row
from ._results import Result
from ._rows import unpack_rows
from ._stepper import LobattoIIIAIIIB
from ._validate import check_method

__all__ = ["AUTO_CHECKPOINT_BYTES", "AdaptiveResult", "IntegrateResult", "integrate", "integrate_adaptive",
           "kept_bytes", "resolve_checkpoints"]


class IntegrateResult(NamedTuple):
    """What :func:`integrate` returns (unpacks as ``q, p, lam, status``).

    Attributes
    ----------
    q, p : jax.Array, shape (n_steps + 1, n)
        Time-major; row 0 is the initial value, the rows after a failed step are NaN.
    lam : jax.Array, shape (n_steps + 1, m)
    status : jax.Array, int32
        The :class:`Result` code: 0 on success, else the first failure's code.
    """

    q: jax.Array  # (n_steps + 1, n)
    p: jax.Array  # (n_steps + 1, n)
    lam: jax.Array  # (n_steps + 1, m)
    status: jax.Array  # int32 Result code: 0 on success, else the first failure's code


def _with_initial(x0, rows):
    return jnp.concatenate([x0[None], rows])


def _integrate(problem, method, n_steps, checkpoints, t0, h, q0, p0, lam0, args):
    controller = ConstantStepSize()
    options = ControlOptions(n=n_steps)
    state = init_state(problem, method, controller, Output(), t0, t0 + n_steps * h, options, q0, p0, lam0, args)
    state, steps = scan_run(problem, method, controller, state, args, n_steps, checkpoints)
    return IntegrateResult(_with_initial(q0, steps.q), _with_initial(p0, steps.p), _with_initial(lam0, steps.lam), state.result)


_integrate_compiled = _compile.jit(_integrate, static_argnums=(0, 1, 2, 3))


#: ``checkpoints="auto"`` (the default of the differentiable entry points): reverse mode keeps
#: every attempt while that takes at most AUTO_CHECKPOINT_BYTES per trajectory (:func:`kept_bytes`),
#: and splits longer scans into ``round(√length)`` checkpointed segments, O(√length) memory. Kept
#: steps are the faster gradient and the faster compilation (2026-11-27, benchmarks/gradients.py,
#: 2000 steps: 1.05-1.3x faster on the sleigh and the falling disk; knife edge, 200-1000 steps:
#: 1.3x, and the first gradient 6.5 s against 8.6 s), so segments are for memory only; the bound
#: is per trajectory because a ``vmap`` of B trajectories keeps B times as much. The forward pass
#: runs the same attempts bit for bit either way.
AUTO_CHECKPOINT_BYTES = 2 << 20


def kept_bytes(method, n: int, m: int) -> int:
    """An upper estimate of what reverse mode keeps per attempt when it keeps every one: the state
    and each Newton solve's stage solution, ``(s + 1)(2n + m)`` float64 values per solve (two
    half steps and the whole step under step doubling), times 3 for what XLA keeps besides them
    (measured 1.9-2.9 on the sleigh and the falling disk, ``memory_analysis``)."""
    solves = 2 * method.pieces - 1
    return 3 * 8 * solves * (method.stages + 1) * (2 * n + m)


def resolve_checkpoints(checkpoints, length: int, per_attempt: int) -> int | None:
    """The number of checkpointed segments of a scan of ``length`` attempts: ``checkpoints`` as
    given (a positive integer, or None for none), or for ``"auto"`` the rule above
    (``per_attempt``: :func:`kept_bytes`)."""
    if checkpoints == "auto":
        return int(round(math.sqrt(length))) if length * per_attempt > AUTO_CHECKPOINT_BYTES else None
    if checkpoints is not None and (isinstance(checkpoints, bool) or not isinstance(checkpoints, (int, np.integer))
                                    or checkpoints < 1):
        raise LobattoDAEInputError(
            f"checkpoints must be 'auto' (the default: √length segments where keeping every step would take "
            f"more than {AUTO_CHECKPOINT_BYTES >> 20} MiB), None (keep every "
            f"step for reverse mode) or a positive integer number of segments; got {checkpoints!r}."
        )
    return None if checkpoints is None else int(checkpoints)


def integrate(problem, method: LobattoIIIAIIIB, t0, h, n_steps: int, q0, p0, lam0, args=None, *,
              checkpoints: int | str | None = "auto") -> IntegrateResult:
    """Pure, jit/vmap/grad-able integration of ``n_steps`` steps of size ``h`` (initial values not checked).

    The building block for batched use: ``jax.vmap(integrate, ...)`` over initial values or
    ``args``. The initial values must be consistent (see :func:`consistent_lambda`); nothing
    is validated here. Compiled once per (problem, method, n_steps, checkpoints, shapes):
    reuse one problem object and pass parameters through ``args``. ``h < 0`` integrates
    backwards.

    Differentiable in every mode (``jax.grad``, ``vjp``, ``jvp``, ``jacfwd``, ``jacrev``)
    with respect to ``t0``, ``h``, ``q0``, ``p0``, ``lam0`` and the float leaves of ``args``:
    the derivatives are those of the discrete map (the exact stage solutions, by the implicit
    function theorem; Newton's iterations are never differentiated). Reverse mode keeps each
    step's state and stages with ``checkpoints=None``, O(n_steps × state) memory;
    ``checkpoints=k`` keeps k segment starts instead and recomputes each segment in the
    backward pass (O(k + n_steps/k) memory, Newton's iterations run again). The default
    ``"auto"`` keeps every step while that is at most 2 MiB per trajectory (:data:`AUTO_CHECKPOINT_BYTES`;
    about 2,500 steps of a system with 2n + m = 7 at s = 4), the faster gradient and the faster
    compilation, and takes k = round(√n_steps) beyond: O(√n_steps) memory (see the
    [benchmarks page](../benchmarks/index.md)). The forward values do not depend on
    ``checkpoints``.

    Parameters
    ----------
    problem : PartitionedDAE, NonholonomicSystem or MechanicalSystem
    method : LobattoIIIAIIIB
    t0, h : float
        Initial time and step size.
    n_steps : int
        Number of steps (static: it sets the output's shape).
    q0, p0 : array_like, shape (n,)
    lam0 : array_like, shape (m,)
        Consistent initial values (:func:`consistent_lambda`, :func:`project_momenta`).
    args : pytree, optional
        Passed to the problem functions.
    checkpoints : "auto", int or None
        Reverse-mode memory: see above.

    Returns
    -------
    IntegrateResult
        ``(q, p, lam, status)``: time-major arrays with ``n_steps + 1`` rows (row 0 is the
        initial value) and the :class:`Result` code (0 on success, else the first failure's
        code). The rows after a failed step are NaN.

    Raises
    ------
    LobattoDAEInputError
        ``n_steps`` is not a positive integer, or ``checkpoints`` is not ``"auto"``, None or
        a positive integer; ``method`` is a model's ``NativeIntegrator`` (pass its ``method``).
    TypeError
        ``method`` is not a :class:`LobattoIIIAIIIB`.
    """
    check_method(method)
    check_count("n_steps", n_steps)
    checkpoints = resolve_checkpoints(checkpoints, n_steps, kept_bytes(method, np.shape(q0)[-1], np.shape(lam0)[-1]))
    cast = functools.partial(jnp.asarray, dtype=jnp.float64)
    return _integrate_compiled(problem, method, n_steps, checkpoints, cast(t0), cast(h), cast(q0), cast(p0), cast(lam0),
                               args)


class AdaptiveResult(NamedTuple):
    """What :func:`integrate_adaptive` returns.

    Attributes
    ----------
    t : jax.Array, shape (rows,)
        The step points (row 0: t0) or the ``t_eval`` times.
    q, p : jax.Array, shape (rows, n)
    lam : jax.Array, shape (rows, m)
    n_rows : jax.Array, int32
        The valid rows (the rest are NaN).
    n_steps, n_rejected : jax.Array, int32
        Accepted steps and rejected attempts.
    status : jax.Array, int32
        The :class:`Result` code (``MAX_STEPS`` when ``max_steps`` ran out first,
        ``ROUNDOFF_LIMITED`` when the end was reached but rtol asked the steps for less than
        their round-off, see ``n_roundoff_limited``).
    n_roundoff_limited : jax.Array, int32
        Accepted steps that passed the error test only because no step is asked for a local
        error below its round-off, 1e-13 relative to ``1 + |y|`` (:class:`~lobattodae.PIController`;
        0 for controllers without that floor). When ``n_roundoff_limited · 1e-13 > rtol`` the
        tolerance asks for less than the steps resolve over the interval and the error may
        exceed rtol: ``status`` is then ``ROUNDOFF_LIMITED`` (here and in
        :func:`~lobattodae.solve`, which also warns).
    """

    t: jax.Array  # (rows,) step points (row 0: t0) or the t_eval times
    q: jax.Array  # (rows, n)
    p: jax.Array  # (rows, n)
    lam: jax.Array  # (rows, m)
    n_rows: jax.Array  # int32: the valid rows (the rest are NaN)
    n_steps: jax.Array  # int32: accepted steps
    n_rejected: jax.Array  # int32
    status: jax.Array  # int32 Result code (MAX_STEPS when max_steps ran out first)
    n_roundoff_limited: jax.Array  # int32: accepted steps that passed only by the round-off floor


def _integrate_adaptive(problem, method, controller, max_steps, differentiable, checkpoints, rows, t0, t1, q0, p0,
                        lam0, args, options, t_eval):
    output = t_eval_output(rows)
    state = init_state(problem, method, controller, output, t0, t1, options, q0, p0, lam0, args)
    if differentiable:
        out = _adaptive_scan(problem, method, controller, max_steps, checkpoints, state, t0, q0, p0, lam0, args, t_eval,
                             rows)
        status = _roundoff_status(_t_eval_status(out.status, t0, t1, t_eval), out.n_roundoff_limited, options.rtol)
        return out._replace(status=status.astype(jnp.int32))
    length = max_steps if t_eval is None else t_eval.shape[0]
    state, chunk = run(problem, method, controller, output, state, args, length, Recording(t_eval=t_eval),
                       max_attempts=max_steps)
    rec = unpack_rows(*chunk.rows, q0.shape[-1], lam0.shape[-1])
    reached = controller.done(state.controller) | (t_eval is not None and chunk.n_rows == length)  # every row written
    status = jnp.where((state.result == Result.SUCCESSFUL) & ~reached, Result.MAX_STEPS, state.result)
    status = _t_eval_status(status, t0, t1, t_eval)
    status = _roundoff_status(status, _roundoff_limited(state), options.rtol).astype(jnp.int32)
    if t_eval is None:
        return AdaptiveResult(
            _with_initial(t0, rec.t), _with_initial(q0, rec.q), _with_initial(p0, rec.p), _with_initial(lam0, rec.lam),
            chunk.n_rows + 1, state.n_accepted, state.n_rejected, status, _roundoff_limited(state),
        )
    return AdaptiveResult(rec.t, rec.q, rec.p, rec.lam, chunk.n_rows, state.n_accepted, state.n_rejected, status,
                          _roundoff_limited(state))


def _roundoff_limited(state):
    """The controller's count of steps passed only by the round-off floor (0 without one)."""
    count = getattr(state.controller, "n_floored", None)
    return jnp.asarray(0 if count is None else count, jnp.int32)


def _roundoff_status(status, n_roundoff_limited, rtol):
    """``status``, or ``Result.ROUNDOFF_LIMITED`` for a run that would succeed but whose steps
    passed only by the round-off floor may add up to more than rtol (``solve``'s test)."""
    return jnp.where((status == Result.SUCCESSFUL) & roundoff_may_exceed(n_roundoff_limited, rtol),
                     Result.ROUNDOFF_LIMITED, status)


def _t_eval_status(status, t0, t1, t_eval):
    """``status``, or ``Result.INVALID_T_EVAL`` for a run that would succeed with a ``t_eval``
    that has a NaN, a time outside ``[t0, t1]`` or is not sorted in the direction of
    integration (checked in the graph: under jit/vmap it cannot be refused before the run)."""
    if t_eval is None:
        return status
    direction = jnp.where(t1 >= t0, 1.0, -1.0)
    s = direction * (t_eval - t0)
    valid = jnp.all(jnp.isfinite(t_eval)) & jnp.all((s >= 0) & (s <= direction * (t1 - t0)))
    valid = valid & jnp.all(direction * jnp.diff(t_eval) >= 0)
    return jnp.where((status == Result.SUCCESSFUL) & ~valid, Result.INVALID_T_EVAL, status)


def _adaptive_scan(problem, method, controller, max_steps, checkpoints, state, t0, q0, p0, lam0, args, t_eval,
                   rows):
    """:func:`integrate_adaptive` through :func:`scan_run` (reverse-mode differentiable).

    The accepted steps are moved to the front of the output (a scatter, which differentiates
    like a gather); ``t_eval`` rows are read from the accepted steps' dense output after the
    loop, each from the step that contains its time.
    """
    state, steps = scan_run(problem, method, controller, state, args, max_steps, checkpoints, dense=t_eval is not None,
                            t_eval=t_eval if rows == "step" else None)
    n_rows = jnp.sum(steps.kept.astype(jnp.int32))
    at = jnp.where(steps.kept, jnp.cumsum(steps.kept) - 1, max_steps)

    def front(x):
        return jnp.full_like(x, jnp.nan).at[at].set(x, mode="drop")

    status = jnp.where((state.result == Result.SUCCESSFUL) & ~controller.done(state.controller), Result.MAX_STEPS,
                       state.result).astype(jnp.int32)
    if t_eval is None:
        rows = [_with_initial(x0, front(x)) for x0, x in ((t0, steps.t), (q0, steps.q), (p0, steps.p), (lam0, steps.lam))]
        return AdaptiveResult(*rows, n_rows + 1, state.n_accepted, state.n_rejected, status,
                              _roundoff_limited(state))
    n, m = q0.shape[-1], lam0.shape[-1]
    dense = unpack_dense(front(steps.dense), method.pieces, method.stages, n, m)
    ends = front(steps.t)
    direction = jnp.sign(ends[0] - t0)
    # the step containing t: the first accepted one that ends at or after it
    k = jnp.sum((direction * (ends[None, :] - t_eval[:, None]) < 0) & (jnp.arange(max_steps) < n_rows), axis=1)
    inside = k < n_rows
    k = jnp.minimum(k, max_steps - 1)
    pick = jax.tree_util.tree_map(lambda x: x[k], dense)
    q, p, lam = jax.vmap(lambda st, tt: evaluate(method.pair, st, tt))(pick, t_eval)
    if rows == "project":
        q, p, lam = jax.vmap(lambda tt, *x: project_row(problem, tt, *x, args))(t_eval, q, p, lam)
    nan = functools.partial(jnp.where, inside[:, None])
    return AdaptiveResult(jnp.where(inside, t_eval, jnp.nan), nan(q, jnp.nan), nan(p, jnp.nan), nan(lam, jnp.nan),
                          jnp.sum(inside.astype(jnp.int32)), state.n_accepted, state.n_rejected, status,
                          _roundoff_limited(state))


_integrate_adaptive_compiled = _compile.jit(_integrate_adaptive, static_argnums=(0, 1, 2, 3, 4, 5, 6))


def integrate_adaptive(problem, method: LobattoIIIAIIIB, t_span, q0, p0, lam0, args=None, *, rtol=RTOL, atol=ATOL,
                       first_step=0.0, max_step=math.inf, max_steps: int = STATIC_MAX_STEPS, t_eval=None,
                       controller=PIController(), differentiable: bool = False,
                       checkpoints: int | str | None = "auto", t_eval_rows: str | None = None) -> AdaptiveResult:
    """Pure, jit/vmap-able integration with error-controlled (or reversible) step sizes.

    The same loop and controllers as :func:`~lobattodae.solve` without the input checks, for
    batched use (``jax.vmap`` over initial values, ``args``, tolerances or ``t_span``). At most
    ``max_steps`` step attempts (a static bound: it sizes the output); running out of them is
    the status ``Result.MAX_STEPS``, never a silent truncation. ``t_span = (t0, t1)`` with
    ``t1 < t0`` integrates backwards.

    Forward-mode derivatives (``jax.jvp``, ``jacfwd``) always work. Reverse mode (``jax.grad``,
    ``vjp``, ``jacrev``) needs ``differentiable=True``: the loop then runs as a fixed-length
    scan of ``max_steps`` attempts (those after the end are skipped, but under ``vmap`` every
    lane computes all of them, so keep ``max_steps`` close to what the run needs), and
    ``checkpoints`` trades memory for recomputation as in :func:`integrate`. The derivatives
    are those of the discrete map along the step sequence the run chose: the step-size
    choices are not differentiated (only the last step, clipped to end on ``t1``, moves with
    ``t_span``; ``docs/gradients.md``).

    Parameters
    ----------
    problem : PartitionedDAE, NonholonomicSystem or MechanicalSystem
    method : LobattoIIIAIIIB
    t_span : (float, float)
    q0, p0 : array_like, shape (n,)
    lam0 : array_like, shape (m,)
        Consistent initial values.
    args : pytree, optional
    rtol, atol, first_step, max_step : float
        As in :func:`~lobattodae.solve` (``first_step=0``: chosen automatically).
    max_steps : int
        Step attempts at most (static: it sizes the output without ``t_eval``).
    t_eval : array_like, optional
        Output times instead of step points.
    controller : PIController or ReversibleStepSize
    differentiable : bool
        Run as a fixed-length scan, so that reverse mode works (see above).
    checkpoints : "auto", int or None
        Reverse-mode memory with ``differentiable=True``, as in :func:`integrate`.
    t_eval_rows : {"step", "interpolate", "project"}, optional
        As in :func:`~lobattodae.solve`.

    Returns
    -------
    AdaptiveResult
        ``(t, q, p, lam, n_rows, n_steps, n_rejected, status, n_roundoff_limited)``: without ``t_eval`` the step
        points (row 0 is the initial value; ``max_steps + 1`` rows, those past ``n_rows`` NaN),
        with ``t_eval`` (an array, sorted in the direction of integration) one row per time.
        ``t_eval_rows`` as in :func:`~lobattodae.solve` (default: error-controlled steps end
        on the ``t_eval`` times). ``t_span`` and ``t_eval`` given as numbers are checked as
        :func:`~lobattodae.solve` checks them (:class:`~lobattodae.LobattoDAEInputError`); traced
        ones (under ``jit``/``vmap``) that have a NaN, a time outside ``t_span`` or are unsorted
        give the status ``Result.INVALID_T_EVAL`` instead of success.

    Raises
    ------
    LobattoDAEInputError
        Options :func:`~lobattodae.solve` would refuse, checked before the run: always
        ``max_steps`` (a positive integer up to ``2·10⁷``), ``controller``, ``checkpoints``,
        ``differentiable`` (a bool) and ``t_eval_rows``; where ``t_span`` is concrete (not
        traced under ``jit``/``vmap``) also ``t_span``, and ``t_eval`` and ``rtol``, ``atol``,
        ``first_step``, ``max_step`` where they are concrete too; a model's ``NativeIntegrator``
        as ``method`` (pass its ``method``).
    """
    _check_options(t_span, rtol, atol, first_step, max_step, controller, max_steps, t_eval)
    if not isinstance(differentiable, bool):
        raise LobattoDAEInputError(f"differentiable must be True or False; got {differentiable!r}.")
    rows = t_eval_rows_mode(t_eval_rows, controller, t_eval is not None)
    method = for_error_control(method, controller)
    checkpoints = resolve_checkpoints(checkpoints, max_steps, kept_bytes(method, np.shape(q0)[-1], np.shape(lam0)[-1]))
    cast = functools.partial(jnp.asarray, dtype=jnp.float64)
    t0, t1 = (cast(x) for x in t_span)
    options = ControlOptions(1, rtol, atol, first_step, max_step)
    t_eval = None if t_eval is None else cast(t_eval)
    return _integrate_adaptive_compiled(
        problem, method, controller, max_steps, differentiable, checkpoints if differentiable else None, rows, t0,
        t1, cast(q0), cast(p0), cast(lam0), args, options, t_eval,
    )


def _check_options(t_span, rtol, atol, first_step, max_step, controller, max_steps, t_eval) -> None:
    """:func:`~lobattodae.solve`'s rules (:mod:`lobattodae._options`) for the options of
    :func:`integrate_adaptive`: the static ones always, the numbers where they are concrete
    (traced ones, under ``jit``/``vmap``, cannot be refused before the run: a traced ``t_eval``
    that is invalid gives ``Result.INVALID_T_EVAL``)."""
    check_max_steps(max_steps)
    AdaptiveSteps.check_controller(controller)
    if not concrete(t_span):
        return
    span = TimeSpan.of(t_span)
    if concrete(t_eval):
        check_t_eval(t_eval, span.t0, span.t1)
    if concrete(rtol, atol, first_step, max_step):
        AdaptiveSteps.over(span, rtol, atol, first_step, max_step, controller, max_steps)
