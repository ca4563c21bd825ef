"""The compiled integration loop: step → controller → result → record.

One ``lax.while_loop`` whose body always reads in that order:

1. **step**: the method takes a step of the size the controller proposes;
2. **controller**: accepts or rejects it and proposes where the next step goes
   (:class:`ConstantStepSize` here; adaptive controllers implement the same three methods);
3. **result**: the first failure is kept in ``State.result`` and ends the loop;
4. **record**: an accepted step writes one row of the output buffer.

Everything that changes from run to run (initial values, ``t_span``, the number of steps,
``args``) is traced, so a loop is compiled once per (problem, method, controller, shapes,
buffer length). ``integrate`` is the pure entry point on top of it (jit/vmap-able);
:func:`~lobattodae.solve` runs it in chunks of :data:`CHUNK` rows.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp

from ._results import Result
from ._stepper import LobattoIIIAIIIB, StepperState

__all__ = ["CHUNK", "ConstantStepSize", "IntegrateResult", "Record", "State", "init_state", "integrate", "run"]

#: Rows per compiled chunk in :func:`~lobattodae.solve` (a fixed length: a new number of steps
#: never recompiles; a short run stops early and leaves the rest of the buffer unused).
CHUNK = 2048


class ConstantState(NamedTuple):
    """Step k of n on ``[t0, t1]``: ``t_k = t0 + k h``, ``h = (t1 - t0) / n``, ``t_n = t1``."""

    k: jax.Array  # int32
    n: jax.Array  # int32
    t0: jax.Array
    t1: jax.Array


@dataclass(frozen=True)
class ConstantStepSize:
    """``n`` equal steps from ``t0`` to ``t1`` (negative h when ``t1 < t0``); every step
    whose stage equations are solved is accepted."""

    def init(self, t0, t1, n) -> ConstantState:
        return ConstantState(jnp.asarray(0, jnp.int32), jnp.asarray(n, jnp.int32), t0, t1)

    @staticmethod
    def _time(st: ConstantState, k):
        h = (st.t1 - st.t0) / st.n
        return jnp.where(k >= st.n, st.t1, st.t0 + k * h)

    def proposal(self, st: ConstantState):
        """``(t, h)``: where the next step starts and how long it is."""
        t = self._time(st, st.k)
        return t, self._time(st, st.k + 1) - t

    def adapt(self, st: ConstantState, succeeded) -> tuple[jax.Array, ConstantState]:
        """``(accept, next state)`` after a step."""
        return succeeded, st._replace(k=st.k + succeeded.astype(jnp.int32))

    def done(self, st: ConstantState):
        return st.k >= st.n

    def time(self, st: ConstantState):
        """The time of the current step point."""
        return self._time(st, st.k)


class Record(NamedTuple):
    """One output row per accepted step (the step ending at ``t``)."""

    t: jax.Array
    q: jax.Array
    p: jax.Array
    lam: jax.Array
    iterations: jax.Array  # Newton iterations of the step
    n_jacobians: jax.Array
    residual_norm: jax.Array  # max-norm of the last Newton residual
    constraint: jax.Array  # ‖φ(t, q, p)‖∞
    drift: jax.Array  # ‖λ − λ(t, q, p)‖∞
    resync: jax.Array  # the step started from λ(t_n, q_n, p_n) ("auto")


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
    # outcome and counters
    result: jax.Array  # int32 Result: SUCCESSFUL while running, else the first failure's code
    n_accepted: jax.Array  # int32
    n_newton: jax.Array  # int32, Newton iterations over all steps
    n_jacobians: jax.Array  # int32


def init_state(problem, method: LobattoIIIAIIIB, controller, t0, t1, n, q0, p0, lam0, args) -> State:
    """The loop state at ``t0`` (λ0 must be consistent; nothing is validated here)."""
    ctrl = controller.init(t0, t1, n)
    _, h = controller.proposal(ctrl)
    zero = jnp.asarray(0, jnp.int32)
    return State(
        q=q0, p=p0, lam=lam0,
        stepper=method.init(problem, t0, q0, p0, lam0, args, h),
        controller=ctrl,
        result=jnp.asarray(Result.SUCCESSFUL, jnp.int32),
        n_accepted=zero, n_newton=zero, n_jacobians=zero,
    )


_FLOAT_FIELDS = ("t", "q", "p", "lam", "residual_norm", "constraint", "drift")
_INT_FIELDS = ("iterations", "n_jacobians", "resync")


def _pack_row(row: Record):
    """One float and one int32 vector per row: two buffer updates per step instead of ten."""
    floats = jnp.concatenate([jnp.atleast_1d(getattr(row, f)) for f in _FLOAT_FIELDS])
    ints = jnp.stack([getattr(row, f).astype(jnp.int32) for f in _INT_FIELDS])
    return floats, ints


def _unpack_rows(floats, ints, n: int, m: int) -> Record:
    sizes = {"t": 1, "q": n, "p": n, "lam": m, "residual_norm": 1, "constraint": 1, "drift": 1}
    out, i = {}, 0
    for f in _FLOAT_FIELDS:
        block = floats[:, i : i + sizes[f]]
        out[f] = block if f in ("q", "p", "lam") else block[:, 0]
        i += sizes[f]
    for j, f in enumerate(_INT_FIELDS):
        out[f] = ints[:, j].astype(bool) if f == "resync" else ints[:, j]
    return Record(**out)


def run(problem, method: LobattoIIIAIIIB, controller, state: State, args, length: int):
    """Advance ``state`` by at most ``length`` accepted steps (fewer when the controller is
    done or a step fails); return ``(state, records, n_records)``.

    Rows past ``n_records`` are NaN. A failed step ends the loop with ``state.result`` set
    and ``state`` left at the last step point.
    """

    def running(carry):
        st, _, i = carry
        return (st.result == Result.SUCCESSFUL) & ~controller.done(st.controller) & (i < length)

    def body(carry):
        st, rec, i = carry
        # 1. step
        t, h = controller.proposal(st.controller)
        q1, p1, lam1, info, stepper = method.step(problem, t, st.q, st.p, st.lam, h, args, st.stepper)
        ok = info.result == Result.SUCCESSFUL
        # 2. controller
        accept, ctrl = controller.adapt(st.controller, ok)
        # 3. result
        result = jnp.where(ok, st.result, info.result).astype(jnp.int32)
        # 4. record
        t1 = controller.time(ctrl)
        row = Record(
            t1, q1, p1, lam1, info.iterations, info.n_jacobians, info.residual_norm,
            jnp.max(jnp.abs(problem.phi(t1, q1, p1, args))), info.drift, info.resync,
        )
        floats, ints = _pack_row(row)
        rec = (rec[0].at[i].set(jnp.where(accept, floats, jnp.nan)), rec[1].at[i].set(ints))
        keep = functools.partial(jnp.where, accept)
        new = State(
            q=keep(q1, st.q), p=keep(p1, st.p), lam=keep(lam1, st.lam),
            stepper=jax.tree_util.tree_map(keep, stepper, st.stepper),
            controller=ctrl,
            result=result,
            n_accepted=st.n_accepted + accept.astype(jnp.int32),
            n_newton=st.n_newton + info.iterations,
            n_jacobians=st.n_jacobians + info.n_jacobians,
        )
        return new, rec, i + accept.astype(jnp.int32)

    n, m = state.q.shape[-1], state.lam.shape[-1]
    buffers = (jnp.full((length, 2 * n + m + 4), jnp.nan, state.q.dtype), jnp.zeros((length, 3), jnp.int32))
    state, (floats, ints), i = jax.lax.while_loop(running, body, (state, buffers, jnp.asarray(0, jnp.int32)))
    return state, _unpack_rows(floats, ints, n, m), i


@functools.partial(jax.jit, static_argnames=("problem", "method", "controller", "length"))
def run_compiled(problem, method, controller, state, args, length):
    """:func:`run`, compiled once per (problem, method, controller, shapes, length)."""
    return run(problem, method, controller, state, args, length)


@functools.partial(jax.jit, static_argnames=("problem", "method", "controller"))
def init_compiled(problem, method, controller, t0, t1, n, q0, p0, lam0, args):
    return init_state(problem, method, controller, t0, t1, n, q0, p0, lam0, args)


class IntegrateResult(NamedTuple):
    """What :func:`integrate` returns (unpacks as ``q, p, lam, status``)."""

    q: jax.Array  # (n_steps + 1, n)
    p: jax.Array  # (n_steps + 1, n)
    lam: jax.Array  # (n_steps + 1, m)
    status: jax.Array  # int32 Result code: 0 on success, else the first failure's code


def _integrate(problem, method, n_steps, t0, h, q0, p0, lam0, args):
    controller = ConstantStepSize()
    state = init_state(problem, method, controller, t0, t0 + n_steps * h, n_steps, q0, p0, lam0, args)
    state, rec, _ = run(problem, method, controller, state, args, n_steps)
    return IntegrateResult(
        jnp.concatenate([q0[None], rec.q]),
        jnp.concatenate([p0[None], rec.p]),
        jnp.concatenate([lam0[None], rec.lam]),
        state.result,
    )


_integrate_compiled = jax.jit(_integrate, static_argnums=(0, 1, 2))


def integrate(problem, method: LobattoIIIAIIIB, t0, h, n_steps: int, q0, p0, lam0, args=None) -> IntegrateResult:
    """Pure, jit/vmap-able integration of ``n_steps`` steps of size ``h`` (no input checks).

    The building block for batched use: ``jax.vmap(integrate, ...)`` over initial values or
    ``args``. The initial values must be consistent (see :func:`consistent_lambda`); nothing
    is validated here. Compiled once per (problem, method, n_steps, shapes): reuse one problem
    object and pass parameters through ``args``.

    Returns
    -------
    IntegrateResult
        ``(q, p, lam, status)``: time-major arrays with ``n_steps + 1`` rows (row 0 is the
        initial value) and the :class:`Result` code (0 on success, else the first failure's
        code). The rows after a failed step are NaN.
    """
    if isinstance(n_steps, bool) or not isinstance(n_steps, int) or n_steps < 1:
        from ._errors import LobattoDAEInputError

        raise LobattoDAEInputError(f"n_steps must be a positive integer (it sets the output shape); got {n_steps!r}.")
    dtype = jnp.float64
    cast = functools.partial(jnp.asarray, dtype=dtype)
    return _integrate_compiled(problem, method, n_steps, cast(t0), cast(h), cast(q0), cast(p0), cast(lam0), args)
