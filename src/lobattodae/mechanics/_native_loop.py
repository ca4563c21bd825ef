r"""A model's native program inside :func:`lobattodae.solve`'s loop: each step, or each attempt
of step doubling, one XLA FFI call into the model's generated C (:mod:`._native`).

An error-controlled attempt of step doubling (:mod:`lobattodae._doubling`: the whole step
``ỹ_1 = Φ_h(y_0)``, the two half steps ``y_1 = Φ_{h/2}(Φ_{h/2}(y_0))`` that are kept, and the
vector fields the estimate's share reads) is the part of a run that costs: on the JAX path
XLA:CPU runs it as hundreds of tiny kernels (about 100 µs on the Chaplygin sleigh, where the
same attempt in C takes 25 µs; ``benchmarks/RESULTS.md``, 2026-11-29 12:45). Here the whole
attempt is one call (:class:`NativeDoubling`, the handler ``lobattodae_attempt`` below), while
the rest of the run stays the library's JAX: the share of the difference that is the error
(:meth:`StepDoubling._share`), the controller, the λ drift monitor, events, ``t_eval``, dense
output and recording. The loop's other controllers (constant steps, reversible control, the
embedded estimate) take single steps (:class:`NativeStep`, the handler ``lobattodae_step``), the
multiplier policy and the embedded estimate applied around the call by the method's own code.
The steps are those of the JAX path up to where Newton stops below its tolerance.

**State.** The loop carries the handler's memory as two opaque float64 buffers: Newton's
matrices (LU factors, the step sizes and round-off levels they were made with; under step
doubling one set for the whole step and one for the half steps, the half steps' made from the
whole step's blocks where it needed a new matrix: ``half_matrix`` in the C below), kept from every
attempt whatever became of it, as the JAX path keeps its Jacobian factorisation; and the predictors' histories (the last stage slopes
and their correction), selected back after a rejected attempt like the JAX state
(:meth:`after_rejection`), together with the compensation of the summed step ends.

**Limits.** The FFI call has no derivative: gradients stay with the JAX path
(:func:`lobattodae.integrate_adaptive` with the model's :class:`~lobattodae.LobattoIIIAIIIB`);
it runs on the CPU, and under ``vmap`` one lane after the other.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from .._dense import joined, one_piece
from .._doubling import NOISE, MethodSteps, StepDoubling
from .._results import Result
from .. import _stage_equations as se
from .._problem import consistent_lambda
from .._stepper import RETRY_FACTOR, LamMonitor, StepInfo, _fresh_monitor, as_step_arrays

__all__ = ["ATTEMPT_C", "NativeDoubling", "NativeDoublingState", "NativeStep", "NativeStepState", "tableau_array"]


def tableau_array(pair) -> np.ndarray:
    """The C programs' ``Tab`` of a :class:`~lobattodae.LobattoPair`: IIIA's a_ij, IIIB's â_ij, b, c."""
    return np.ascontiguousarray(np.concatenate([pair.a.ravel(), pair.a_hat.ravel(), pair.b, pair.c]), np.float64)

#: The FFI handler (appended to the model's program; needs XLA's FFI header, ``jax.ffi.include_dir()``).
ATTEMPT_C = r"""
#include "xla/ffi/api/c_api.h"

/* What an error-controlled run keeps between attempts: Newton's matrices of the whole step and of
   the half steps (kept from every attempt), and their predictors' histories (selected by the loop). */
typedef struct { Solver whole, half; } AttemptNewton;
typedef struct { History whole, half; } AttemptHistory;
long attempt_newton_doubles(void) { return (long)((sizeof(AttemptNewton) + 7) / 8); }
long attempt_history_doubles(void) { return (long)((sizeof(AttemptHistory) + 7) / 8); }
long step_newton_doubles(void) { return (long)((sizeof(Solver) + 7) / 8); }
long step_history_doubles(void) { return (long)((sizeof(History) + 7) / 8); }

/* A half step's Newton matrix from the whole step's blocks: those of its stages at
   tau_j = offset + c_j/2 of the whole step interpolated from the whole step's (Lagrange over its
   nodes c; the constraint rows' over c_2..c_s, where they are made), then assembled with h/2 and
   factorised: no differences. Made where the whole step of the same attempt needed a new matrix
   (its kept one was stale there, and so would the half steps' be): on the falling disk 9-13 %
   less time per error-controlled run, Andrews' squeezer 5-15 %, the sleigh within the noise at
   s = 5 and up to 10 % more at s = 6 (benchmarks/RESULTS.md, 2026-11-29 19:45). It starts as a kept matrix, under the rules of one. */
static void half_matrix(const Tab *tb, const Solver *whole, double offset, double h_half, Solver *half) {
  Blocks *hb = &half->blocks; const Blocks *wb = &whole->blocks;
  for (int j = 0; j < S; j++) {
    const double tau = offset + 0.5*tb->C[j];
    double l[S], lc[S];
    basis(tb, 0, tau, l); basis(tb, 1, tau, lc);
#define INTERP(field, rows, cols, w) for (int r = 0; r < rows; r++) for (int c = 0; c < cols; c++) { \
      double a = 0.0; for (int kk = 0; kk < S; kk++) a += w[kk]*wb->field[kk][r][c]; hb->field[j][r][c] = a; }
    INTERP(fq, NQ, NQ, l) INTERP(fp, NQ, NQ, l) INTERP(gq, NQ, NQ, l) INTERP(gp, NQ, NQ, l) INTERP(gl, NQ, NM, l)
    INTERP(pq, NM, NQ, lc) INTERP(pp, NM, NQ, lc)
#undef INTERP
  }
  newton_assemble(tb, h_half, hb, half->lu, half->piv);
  half->have_lu = 1; half->h_lu = h_half; half->have_blocks = 0;
}

static double max_abs_diff(const double *a, const double *b, int n) {
  double d = 0.0; for (int j = 0; j < n; j++) d = fmax(d, fabs(a[j] - b[j])); return d;
}

/* XLA's handshake: a call that asks for the handler's metadata (the FFI API version it was built
   with) is answered here, and only the execution stage runs the handler. */
static int executing(XLA_FFI_CallFrame* frame) {
  if (frame->extension_start && frame->extension_start->type == XLA_FFI_Extension_Metadata) {
    XLA_FFI_Metadata_Extension* ext = (XLA_FFI_Metadata_Extension*)frame->extension_start;
    ext->metadata->api_version.major_version = XLA_FFI_API_MAJOR;
    ext->metadata->api_version.minor_version = XLA_FFI_API_MINOR;
    ext->metadata->traits = 0;
    return 0;
  }
  return frame->stage == XLA_FFI_ExecutionStage_EXECUTE;
}

#define ARG(i) (((XLA_FFI_Buffer*)frame->args.args[i])->data)
#define RET(i) (((XLA_FFI_Buffer*)frame->rets.rets[i])->data)

/* One attempt of step doubling from (t0, q0, p0), h (lobattodae._doubling.StepDoubling.step):
     the whole step   ỹ_1 = Φ_h(y_0),                     started from λ_0 (its own Newton matrix, predictor);
     the half steps   y_1 = Φ_{h/2}(Φ_{h/2}(y_0)),         the first from λ_0, the second from λ_{1/2};
   λ_0, λ_{1/2} the hidden constraint's λ(t, q, p) (options[0] = 1, lam_start="consistent") or the
   carried multipliers (0, "previous": λ_0 the input, λ_{1/2} the first half's Λ_s). A whole step that
   fails is the attempt's result and the half steps are not solved. Then the estimate's vector fields
   (f, g) on the constraint manifold at ỹ_1 and y_1 (each with its own hidden λ) and at y_1 with ỹ_1's.
   Arguments: t0, h, q0, p0, lam0, k (parameters), options (consistent, extrapolate, max_iterations),
   tol, tableau, Newton matrices, histories, compensation. Results: q1, p1, lam1, ỹ_1, fields (3, 2n),
   ints (result, Newton iterations, Newton matrices, whole step failed), reals (last residual norm, the
   half steps' drifts ‖λ − λ(t, q, p)‖∞), the half steps' stage slopes V, W and multipliers Λ (2, S, ·),
   (q, p, λ)_{1/2}, and the new Newton matrices, histories and compensation (aliased to their arguments). */
XLA_FFI_Error* lobattodae_attempt(XLA_FFI_CallFrame* frame) {
  if (!executing(frame)) return NULL;
  const double t0 = *(const double*)ARG(0), h = *(const double*)ARG(1);
  const double *q0 = ARG(2), *p0 = ARG(3), *lam0 = ARG(4), *k = ARG(5);
  const int *options = ARG(6);
  const int consistent = options[0], extrapolate = options[1], maxit = options[2];
  const double tol = *(const double*)ARG(7);
  Tab tb; memcpy(&tb, ARG(8), sizeof tb);
  double *q1 = RET(0), *p1 = RET(1), *l1 = RET(2), *yw = RET(3), *fields = RET(4);
  int *ints = RET(5); double *reals = RET(6), *V = RET(7), *W = RET(8), *Lm = RET(9), *ymid = RET(10);
  AttemptNewton *nw = RET(11); AttemptHistory *hs = RET(12); double *comp = RET(13);
  if ((void*)nw != ARG(9)) memcpy(nw, ARG(9), sizeof(AttemptNewton));
  if ((void*)hs != ARG(10)) memcpy(hs, ARG(10), sizeof(AttemptHistory));
  if ((void*)comp != ARG(11)) memcpy(comp, ARG(11), sizeof(double)*2*NQ);
  nw->whole.hs = hs->whole; nw->half.hs = hs->half;
  long stats[2] = {0, 0};
  double start[NM], rn = 0.0, res_max = 0.0, comp_w[2*NQ], lw[NM], hid_w[NM], hid_1[NM], hid_m[NM];
  double *qw = yw, *pw = yw + NQ, *qm = ymid, *pm = ymid + NQ, *lm = ymid + 2*NQ;
  if (consistent) model_lambda(t0, q0, p0, k, start); else memcpy(start, lam0, sizeof start);
  memset(V, 0, sizeof(double)*2*S*NQ); memset(W, 0, sizeof(double)*2*S*NQ); memset(Lm, 0, sizeof(double)*2*S*NM);
  reals[1] = reals[2] = 0.0;
  memcpy(comp_w, comp, sizeof comp_w);
  int result = step(&nw->whole, &tb, extrapolate, tol, maxit, t0, h, q0, p0, start, comp_w, k, qw, pw, lw, &rn, stats);
  res_max = rn;
  const int whole_failed = result != 0;
  if (whole_failed) { memcpy(qw, q0, sizeof(double)*NQ); memcpy(pw, p0, sizeof(double)*NQ); }
  else {
    double comp_h[2*NQ];
    memcpy(comp_h, comp, sizeof comp_h);
    const int interpolate = nw->whole.have_blocks && nw->whole.blocks_t == t0 && nw->whole.blocks_h == h;
    if (interpolate) { half_matrix(&tb, &nw->whole, 0.0, 0.5*h, &nw->half); stats[1]++; }
    result = step(&nw->half, &tb, extrapolate, tol, maxit, t0, 0.5*h, q0, p0, start, comp_h, k, qm, pm, lm, &rn, stats);
    res_max = fmax(res_max, rn);
    if (!result) {
      memcpy(V, nw->half.hs.Vh, sizeof(double)*S*NQ); memcpy(W, nw->half.hs.Wh, sizeof(double)*S*NQ);
      memcpy(Lm, nw->half.hs.Lh, sizeof(double)*S*NM);
      model_lambda(t0 + 0.5*h, qm, pm, k, hid_m);
      reals[1] = max_abs_diff(lm, hid_m, NM);
      if (interpolate) { half_matrix(&tb, &nw->whole, 0.5, 0.5*h, &nw->half); stats[1]++; }
      result = step(&nw->half, &tb, extrapolate, tol, maxit, t0 + 0.5*h, 0.5*h, qm, pm, consistent ? hid_m : lm,
                    comp_h, k, q1, p1, l1, &rn, stats);
      res_max = fmax(res_max, rn);
      if (!result) {
        memcpy(V + S*NQ, nw->half.hs.Vh, sizeof(double)*S*NQ); memcpy(W + S*NQ, nw->half.hs.Wh, sizeof(double)*S*NQ);
        memcpy(Lm + S*NM, nw->half.hs.Lh, sizeof(double)*S*NM);
        memcpy(comp, comp_h, sizeof comp_h);
      }
    }
  }
  if (result) {   /* not kept: the start point, so that what follows stays finite */
    memcpy(q1, q0, sizeof(double)*NQ); memcpy(p1, p0, sizeof(double)*NQ); memcpy(l1, start, sizeof(double)*NM);
    memcpy(qm, q0, sizeof(double)*NQ); memcpy(pm, p0, sizeof(double)*NQ); memcpy(lm, start, sizeof(double)*NM);
  }
  model_lambda(t0 + h, qw, pw, k, hid_w); model_lambda(t0 + h, q1, p1, k, hid_1);
  model_fg(t0 + h, qw, pw, hid_w, k, fields, fields + NQ, NULL);
  model_fg(t0 + h, q1, p1, hid_1, k, fields + 2*NQ, fields + 3*NQ, NULL);
  model_fg(t0 + h, q1, p1, hid_w, k, fields + 4*NQ, fields + 5*NQ, NULL);
  if (!result) reals[2] = max_abs_diff(l1, hid_1, NM);
  hs->whole = nw->whole.hs; hs->half = nw->half.hs;
  ints[0] = result; ints[1] = (int)stats[0]; ints[2] = (int)stats[1]; ints[3] = whole_failed;
  reals[0] = res_max;
  return NULL;
}

/* One step of the method (lobattodae.LobattoIIIAIIIB.step) from (t0, q0, p0) with the start
   multiplier Λ_1 = lam_start (the policy is applied by the caller), for the loop's other
   controllers (constant steps, reversible control, the embedded estimate). Arguments: t0, h, q0,
   p0, lam_start, k, options (extrapolate, max_iterations), tol, tableau, Newton's matrix, the
   history, compensation. Results: q1, p1, lam1, λ(t1, q1, p1), ints (result, Newton iterations,
   Newton matrices), the last residual norm, the stage slopes V, W and multipliers Λ, and the new
   Newton matrix, history and compensation (aliased to their arguments). */
XLA_FFI_Error* lobattodae_step(XLA_FFI_CallFrame* frame) {
  if (!executing(frame)) return NULL;
  const double t0 = *(const double*)ARG(0), h = *(const double*)ARG(1);
  const double *q0 = ARG(2), *p0 = ARG(3), *start = ARG(4), *k = ARG(5);
  const int *options = ARG(6);
  const double tol = *(const double*)ARG(7);
  Tab tb; memcpy(&tb, ARG(8), sizeof tb);
  double *q1 = RET(0), *p1 = RET(1), *l1 = RET(2), *hidden = RET(3);
  int *ints = RET(4); double *res = RET(5), *V = RET(6), *W = RET(7), *Lm = RET(8);
  Solver *nw = RET(9); History *hs = RET(10); double *comp = RET(11);
  if ((void*)nw != ARG(9)) memcpy(nw, ARG(9), sizeof(Solver));
  if ((void*)hs != ARG(10)) memcpy(hs, ARG(10), sizeof(History));
  if ((void*)comp != ARG(11)) memcpy(comp, ARG(11), sizeof(double)*2*NQ);
  nw->hs = *hs;
  long stats[2] = {0, 0};
  double rn = 0.0;
  const int result = step(nw, &tb, options[0], tol, options[1], t0, h, q0, p0, start, comp, k, q1, p1, l1, &rn, stats);
  if (result) {   /* not kept: the start point, so that what follows stays finite */
    memcpy(q1, q0, sizeof(double)*NQ); memcpy(p1, p0, sizeof(double)*NQ); memcpy(l1, start, sizeof(double)*NM);
    memset(V, 0, sizeof(double)*S*NQ); memset(W, 0, sizeof(double)*S*NQ); memset(Lm, 0, sizeof(double)*S*NM);
  } else {
    memcpy(V, nw->hs.Vh, sizeof(double)*S*NQ); memcpy(W, nw->hs.Wh, sizeof(double)*S*NQ);
    memcpy(Lm, nw->hs.Lh, sizeof(double)*S*NM);
  }
  model_lambda(t0 + h, q1, p1, k, hidden);
  *hs = nw->hs;
  ints[0] = result; ints[1] = (int)stats[0]; ints[2] = (int)stats[1];
  *res = rn;
  return NULL;
}
"""


def _parameters(names, args, dtype):
    """The C program's ``k``: the model's parameters from ``args`` in its order (one zero when none)."""
    return jnp.stack([jnp.asarray(args[name], dtype) for name in names] or [jnp.zeros((), dtype)])


def _after_rejection(kept, new, old):
    """The state the next attempt starts from: ``new``'s Newton matrices (a factorisation stays an
    approximation of the Jacobian near the same point, as :meth:`LobattoIIIAIIIB.after_rejection
    <lobattodae.LobattoIIIAIIIB.after_rejection>` keeps it), everything else ``new`` where the
    attempt was ``kept``, else ``old``."""
    rest = jax.tree_util.tree_map(lambda x, y: jnp.where(kept, x, y), new._replace(newton=None),
                                  old._replace(newton=None))
    return rest._replace(newton=new.newton)


class NativeDoublingState(NamedTuple):
    """What the loop carries for :class:`NativeDoubling` between attempts."""

    newton: jax.Array  # (attempt_newton_doubles,): Newton's matrices, kept from every attempt
    history: jax.Array  # (attempt_history_doubles,): the predictors' histories, selected by ``kept``
    compensation: jax.Array  # (2n,): what the step point lost to rounding (compensated summation)
    monitor: LamMonitor  # the λ drift monitor of the half steps (lam_start="previous")


@dataclass(frozen=True)
class NativeDoubling(StepDoubling):
    """:class:`~lobattodae._doubling.StepDoubling` whose attempt is one call into a model's
    native program (see the module docstring); made by
    :meth:`NativeIntegrator.doubling <lobattodae.mechanics.NativeIntegrator.doubling>`.

    ``target`` names the registered FFI handler, ``parameters`` the model's parameters in the
    order of the C program's ``k``, ``sizes`` the doubles of the two state buffers (Newton's
    matrices, the histories).
    """

    target: str = ""
    parameters: tuple = ()
    sizes: tuple = (0, 0)

    def init(self, problem, t0, q0, p0, lam0, args=None, h=None, lam_hidden=None) -> NativeDoublingState:
        dtype = jnp.asarray(q0).dtype
        n = jnp.shape(q0)[-1]
        return NativeDoublingState(jnp.zeros((self.sizes[0],), dtype), jnp.zeros((self.sizes[1],), dtype),
                                   jnp.zeros((2 * n,), dtype), _fresh_monitor(dtype, jnp.asarray(0, jnp.int32)))

    def after_rejection(self, kept, new: NativeDoublingState, old: NativeDoublingState) -> NativeDoublingState:
        """Newton's matrices from the attempt, whatever became of it; the rest from before a
        rejected one (as :meth:`StepDoubling.after_rejection`)."""
        return _after_rejection(kept, new, old)

    def step(self, problem, t0, q0, p0, lam0, h, args=None, state: NativeDoublingState | None = None):
        """An attempt as :meth:`StepDoubling.step` makes it, in one native call."""
        t0, q0, p0, lam0, h = as_step_arrays(t0, q0, p0, lam0, h)
        if state is None:
            state = self.init(problem, t0, q0, p0, lam0, args, h)
        dtype = q0.dtype
        n, m, s = q0.shape[-1], lam0.shape[-1], self.stages
        k = _parameters(self.parameters, args, dtype)
        out = jax.ShapeDtypeStruct
        shapes = [out((n,), dtype), out((n,), dtype), out((m,), dtype), out((2 * n,), dtype), out((3, 2 * n), dtype),
                  out((4,), jnp.int32), out((3,), dtype), out((2, s, n), dtype), out((2, s, n), dtype),
                  out((2, s, m), dtype), out((2 * n + m,), dtype), out(state.newton.shape, dtype),
                  out(state.history.shape, dtype), out((2 * n,), dtype)]
        call = jax.ffi.ffi_call(self.target, shapes, vmap_method="sequential",
                                input_output_aliases={9: 11, 10: 12, 11: 13})
        options = jnp.asarray([self.lam_start != "previous", self.method._use_extrapolation,
                               self.method.max_iterations], jnp.int32)
        stop = jax.lax.stop_gradient
        q1, p1, lam1, y_whole, fields, ints, reals, V, W, Lam, y_mid, newton, history, compensation = call(
            stop(t0), stop(h), stop(q0), stop(p0), stop(lam0), stop(k), options, jnp.asarray(self.method.tol, dtype),
            jnp.asarray(tableau_array(self.pair), dtype), state.newton, state.history, state.compensation)
        y1 = jnp.concatenate([q1, p1])
        diff = y1 - y_whole
        noise = NOISE * self.method.tol * (1.0 + jnp.abs(y1))
        share, resolved = self._share(h, diff, fields[1] - fields[0], y1, fields[1] - fields[2])
        error = share * jnp.sign(diff) * jnp.maximum(jnp.abs(diff) - noise, 0.0)
        whole_failed = ints[3] != 0
        # the λ drift monitor of the kept half steps, updated by each of them as on the JAX path
        monitor, _ = self.method._watch(state.monitor, reals[1], y_mid[2 * n:], False)
        monitor, _ = self.method._watch(monitor, reals[2], lam1, False)
        half = jnp.asarray(0.5, dtype) * h
        dense = joined(one_piece(t0, half, q0, p0, V[0], W[0], Lam[0]),
                       one_piece(t0 + half, half, y_mid[:n], y_mid[n:2 * n], V[1], W[1], Lam[1]))
        info = StepInfo(ints[0], ints[1], reals[0], ints[2], reals[2], jnp.asarray(False), error, dense,
                        jnp.where(whole_failed, 0.5, RETRY_FACTOR).astype(dtype), share, resolved)
        return q1, p1, lam1, info, NativeDoublingState(newton, history, compensation, monitor)


class NativeStepState(NamedTuple):
    """What the loop carries for :class:`NativeStep` between steps (the roles of
    :class:`~lobattodae._stepper.StepperState`'s fields)."""

    newton: jax.Array  # (step_newton_doubles,): Newton's matrix, kept from every attempt
    history: jax.Array  # (step_history_doubles,): the predictor's history
    compensation: jax.Array  # (2n,)
    lam_hidden: jax.Array  # (m,): λ(t_n, q_n, p_n), from the hidden constraint
    resync: jax.Array  # bool: the next step starts from lam_hidden (lam_start="auto")
    monitor: LamMonitor


@dataclass(frozen=True)
class NativeStep(MethodSteps):
    """:class:`~lobattodae.LobattoIIIAIIIB`'s single steps as the loop takes them under its other
    controllers (constant steps, :class:`~lobattodae.ReversibleStepSize`, the embedded estimate of
    :class:`~lobattodae.PIController`), each one call into a model's native program; the
    multiplier policy, the λ drift monitor, the dense output and the embedded estimate are the
    method's own (:meth:`~lobattodae.LobattoIIIAIIIB.start_multiplier`, ``_watch``, ``_error_estimate``)
    around the call. Made by :meth:`NativeIntegrator.single
    <lobattodae.mechanics.NativeIntegrator.single>`."""

    target: str = ""
    parameters: tuple = ()
    sizes: tuple = (0, 0)
    pieces = 1

    def init(self, problem, t0, q0, p0, lam0, args=None, h=None, lam_hidden=None) -> NativeStepState:
        dtype = jnp.asarray(q0).dtype
        n = jnp.shape(q0)[-1]
        if lam_hidden is None:
            lam_hidden = consistent_lambda(problem, jnp.asarray(t0, dtype), jnp.asarray(q0, dtype),
                                           jnp.asarray(p0, dtype), jnp.asarray(lam0, dtype), args, iterations=1)
        return NativeStepState(jnp.zeros((self.sizes[0],), dtype), jnp.zeros((self.sizes[1],), dtype),
                               jnp.zeros((2 * n,), dtype), jnp.asarray(lam_hidden, dtype), jnp.asarray(False),
                               _fresh_monitor(dtype, jnp.asarray(0, jnp.int32)))

    def after_rejection(self, kept, new: NativeStepState, old: NativeStepState) -> NativeStepState:
        """Newton's matrix from the attempt, whatever became of it; the rest from before a rejected one."""
        return _after_rejection(kept, new, old)

    def step(self, problem, t0, q0, p0, lam0, h, args=None, state: NativeStepState | None = None):
        """A step as :meth:`~lobattodae.LobattoIIIAIIIB.step` takes it, in one native call."""
        t0, q0, p0, lam0, h = as_step_arrays(t0, q0, p0, lam0, h)
        if state is None:
            state = self.init(problem, t0, q0, p0, lam0, args, h)
        dtype = q0.dtype
        n, m, s = q0.shape[-1], lam0.shape[-1], self.stages
        start = self.method.start_multiplier(lam0, state)
        out = jax.ShapeDtypeStruct
        shapes = [out((n,), dtype), out((n,), dtype), out((m,), dtype), out((m,), dtype), out((3,), jnp.int32),
                  out((), dtype), out((s, n), dtype), out((s, n), dtype), out((s, m), dtype),
                  out(state.newton.shape, dtype), out(state.history.shape, dtype), out((2 * n,), dtype)]
        call = jax.ffi.ffi_call(self.target, shapes, vmap_method="sequential",
                                input_output_aliases={9: 9, 10: 10, 11: 11})
        options = jnp.asarray([self.method._use_extrapolation, self.method.max_iterations], jnp.int32)
        stop = jax.lax.stop_gradient
        q1, p1, lam1, lam_hidden, ints, residual, V, W, Lam, newton, history, compensation = call(
            stop(t0), stop(h), stop(q0), stop(p0), stop(start), stop(_parameters(self.parameters, args, dtype)),
            options, jnp.asarray(self.method.tol, dtype), jnp.asarray(tableau_array(self.pair), dtype), state.newton,
            state.history, state.compensation)
        drift = jnp.max(jnp.abs(lam1 - lam_hidden))
        monitor, excursion = self.method._watch(state.monitor, drift, lam1, state.resync)
        new_state = NativeStepState(newton, history, compensation, lam_hidden,
                                    jnp.logical_and(excursion, self.lam_start == "auto"), monitor)
        error = self.method._error_estimate(se.StageParams(t0, h, q0, p0, start, args), se.Stages(None, None, Lam, V, W))
        info = StepInfo(ints[0], ints[1], residual, ints[2], drift, state.resync, error,
                        one_piece(t0, h, q0, p0, V, W, Lam), jnp.asarray(RETRY_FACTOR, dtype))
        return q1, p1, lam1, info, new_state
