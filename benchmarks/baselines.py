"""Baseline integrators that lobattodae is compared against (issue #4).

Every baseline solves the same nonholonomic Hamiltonian problems as lobattodae
(``q' = H_p``, ``p' = -H_q + μ(q)ᵀλ``, ``0 = φ = μ(q) H_p``):

* :class:`IndexReducedODE` -- λ eliminated through the hidden constraint
  (``lobattodae.consistent_lambda`` with one Newton iteration from λ = 0, which is exact
  because g is affine in λ), giving an ODE ``y' = F(t, y)`` for ``y = (q, p)``.
  Provides AOT-compiled NumPy-callable ``rhs(t, y)`` and ``jac(t, y)`` for
  ``scipy.integrate.solve_ivp`` (DOP853, Radau) and a jit-compiled diffrax Dopri8 solve
  with a PID step-size controller.
* :class:`IDABaseline` -- SUNDIALS IDA (via scikit-sundae) on the index-2 DAE form,
  ``y = (q, p, λ)``, residual ``[q' - f, p' - g, φ]``, λ excluded from the local error
  test (see the class docstring for how).
* :class:`McLachlanPerlmutter` -- the second-order nonholonomic integrator of
  McLachlan & Perlmutter (J. Nonlinear Sci. 16, 2006, eq. 4.18), in JAX, one Newton
  solve per step, the whole run in one compiled ``lax`` loop.

Run ``python benchmarks/baselines.py [--quick]`` to validate every baseline against the
closed-form knife-edge solution (errors must decrease with the tolerance / step size;
the McLachlan-Perlmutter method must show order 2). Results go to
``benchmarks/results/baselines_validation.json``.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time
from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np

try:  # the package may not be installed: fall back to the source tree
    import lobattodae as L  # noqa: N812
except ImportError:  # pragma: no cover
    sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "src"))
    import lobattodae as L  # noqa: N812

import jax  # noqa: E402  (lobattodae switched on float64)
import jax.numpy as jnp  # noqa: E402

RESULTS_DIR = os.path.join(os.path.dirname(os.path.abspath(__file__)), "results")

__all__ = [
    "IndexReducedODE",
    "IDABaseline",
    "IDANumpy",
    "McLachlanPerlmutter",
    "RunRecord",
    "time_best",
    "binned_max",
    "ida_available",
]


# ----------------------------------------------------------------------------- helpers
def time_best(fn: Callable[[], Any], repeats: int = 3, single_run_limit: float = 2.0):
    """Best wall time of up to ``repeats`` calls of ``fn`` (already warmed up).

    When one call takes longer than ``single_run_limit`` seconds no further repeats are
    made (to keep long benchmarks inside their time budget). Returns
    ``(best_seconds, n_repeats, result_of_the_best_call)``; ``time_best.last_cpu`` holds the process
    CPU time of the best call (wall ≫ CPU means the machine was busy with other work).
    """
    best = math.inf
    out = None
    k = 0
    for k in range(1, repeats + 1):
        c0 = time.process_time()
        t0 = time.perf_counter()
        out = fn()
        dt = time.perf_counter() - t0
        dc = time.process_time() - c0
        if dt < best:
            best, time_best.last_cpu, best_out = dt, dc, out
        if dt > single_run_limit:
            break
    return best, k, best_out


time_best.last_cpu = math.nan


def source_revision() -> str:
    """``git describe`` of the working tree lobattodae is imported from (+ '-dirty' if src/ has
    uncommitted changes), so that numbers can be matched to the code that produced them."""
    import subprocess

    root = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..")
    try:
        rev = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=root, capture_output=True,
                             text=True, timeout=10).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "src"], cwd=root, capture_output=True,
                               text=True, timeout=10).stdout.strip()
        return rev + ("-dirty" if dirty else "")
    except Exception:  # pragma: no cover
        return "unknown"


def binned_max(t: np.ndarray, v: np.ndarray, t0: float, t1: float, bins: int = 250):
    """Max of ``v`` over ``bins`` equal time bins (for compact plots of ‖φ‖(t), |H-H0|(t))."""
    t = np.asarray(t, float)
    v = np.abs(np.asarray(v, float))
    edges = np.linspace(t0, t1, bins + 1)
    idx = np.clip(np.searchsorted(edges, t, side="right") - 1, 0, bins - 1)
    out = np.full(bins, np.nan)
    np.fmax.at(out, idx, v)
    centers = 0.5 * (edges[1:] + edges[:-1])
    ok = np.isfinite(out)
    return [float(f"{x:.5g}") for x in centers[ok]], [float(f"{x:.3g}") for x in out[ok]]


@dataclass
class RunRecord:
    """One solver run at one setting (what work_precision.py tabulates)."""

    solver: str
    setting: str
    wall: float  # best wall time after compilation / warm-up [s]
    repeats: int
    compile_and_run: float | None  # first call (compile + run) [s], None if nothing compiles
    err_q: float  # max-norm error of q at the final time
    max_phi: float  # max ‖φ‖∞ over all step points
    max_dH: float  # max |H - H0| over all step points
    n_steps: int
    extra: dict = field(default_factory=dict)
    series: dict = field(default_factory=dict)  # binned ‖φ‖(t), |H-H0|(t)
    ok: bool = True
    message: str = ""


def _energy_fn(problem, args):
    return jax.jit(jax.vmap(lambda t, q, p: problem.hamiltonian(t, q, p, args)))


def _phi_fn(problem, args):
    return jax.jit(jax.vmap(lambda t, q, p: jnp.max(jnp.abs(problem.phi(t, q, p, args)))))


class Diagnostics:
    """Vectorised ‖φ‖∞ and H along a trajectory (jit-compiled once per problem)."""

    def __init__(self, problem, args):
        self.problem, self.args = problem, args
        self._H = _energy_fn(problem, args)
        self._phi = _phi_fn(problem, args)

    def __call__(self, t, q, p, H0):
        t = jnp.asarray(np.asarray(t, float))
        q = jnp.asarray(np.asarray(q, float))
        p = jnp.asarray(np.asarray(p, float))
        phi = np.asarray(self._phi(t, q, p))
        dH = np.abs(np.asarray(self._H(t, q, p)) - H0)
        return phi, dH

    def energy(self, t, q, p):
        return float(self.problem.hamiltonian(jnp.asarray(float(t)), jnp.asarray(q), jnp.asarray(p), self.args))


# ------------------------------------------------------------------ index-reduced ODE
class IndexReducedODE:
    """λ(t, q, p) eliminated by the hidden constraint: ``y' = F(t, y)``, ``y = (q, p)``.

    ``consistent_lambda`` with one Newton iteration from zeros is exact for the
    nonholonomic systems (g is affine in λ). ``rhs`` and ``jac`` are ahead-of-time
    compiled XLA executables called from NumPy (one dispatch per call, no retracing).
    """

    def __init__(self, problem, args, n: int, m: int):
        self.problem, self.args, self.n, self.m = problem, args, n, m

        def F(t, y):
            q, p = y[:n], y[n:]
            lam = L.consistent_lambda(problem, t, q, p, jnp.zeros(m, y.dtype), args, iterations=1)
            return jnp.concatenate([problem.f(t, q, p, args), problem.g(t, q, p, lam, args)])

        self.F = F
        ts = jax.ShapeDtypeStruct((), jnp.float64)
        ys = jax.ShapeDtypeStruct((2 * n,), jnp.float64)
        t0 = time.perf_counter()
        self._rhs = jax.jit(F).lower(ts, ys).compile()
        self._jac = jax.jit(jax.jacfwd(F, argnums=1)).lower(ts, ys).compile()
        self.compile_time = time.perf_counter() - t0
        self._diffrax = None

    def lam(self, t, q, p):
        return L.consistent_lambda(self.problem, t, q, p, jnp.zeros(self.m), self.args, iterations=1)

    # NumPy-callable wrappers for scipy -------------------------------------------------
    def rhs(self, t, y):
        return np.asarray(self._rhs(np.float64(t), y))

    def jac(self, t, y):
        return np.asarray(self._jac(np.float64(t), y))

    def solve_scipy(self, method: str, t_span, y0, rtol: float, atol: float):
        from scipy.integrate import solve_ivp

        kw = {"jac": self.jac} if method in ("Radau", "BDF", "LSODA") else {}
        return solve_ivp(self.rhs, t_span, np.asarray(y0, float), method=method, rtol=rtol, atol=atol, **kw)

    # diffrax Dopri8 -------------------------------------------------------------------
    def _build_diffrax(self):
        import diffrax

        term = diffrax.ODETerm(lambda t, y, a: self.F(t, y))
        solver = diffrax.Dopri8()

        def run(t0, t1, y0, rtol, atol, saveat, max_steps):
            return diffrax.diffeqsolve(
                term, solver, t0, t1, None, y0,
                stepsize_controller=diffrax.PIDController(rtol=rtol, atol=atol),
                saveat=saveat, max_steps=max_steps, adjoint=diffrax.ForwardMode(), throw=False,
            )

        @jax.jit
        def final(t0, t1, y0, rtol, atol):
            sol = run(t0, t1, y0, rtol, atol, diffrax.SaveAt(t1=True), 10_000_000)
            return sol.ys[-1], sol.stats["num_steps"], sol.stats["num_accepted_steps"], sol.result._value

        @jax.jit
        def steps(t0, t1, y0, rtol, atol):
            sol = run(t0, t1, y0, rtol, atol, diffrax.SaveAt(steps=True, t0=True), 1 << 17)
            return sol.ts, sol.ys, sol.stats["num_accepted_steps"], sol.result._value

        self._diffrax = (final, steps)

    def solve_diffrax(self, t_span, y0, rtol, atol):
        """``(y(t1), num_steps, num_accepted, result_code)``; jit-compiled once."""
        if self._diffrax is None:
            self._build_diffrax()
        out = self._diffrax[0](float(t_span[0]), float(t_span[1]), jnp.asarray(y0, jnp.float64), rtol, atol)
        return jax.block_until_ready(out)

    def trajectory_diffrax(self, t_span, y0, rtol, atol):
        """All accepted step points (for ‖φ‖ and H diagnostics; at most 2^17 steps)."""
        if self._diffrax is None:
            self._build_diffrax()
        ts, ys, nacc, res = self._diffrax[1](float(t_span[0]), float(t_span[1]), jnp.asarray(y0, jnp.float64), rtol, atol)
        ts, ys = np.asarray(ts), np.asarray(ys)
        ok = np.isfinite(ts)
        return ts[ok], ys[ok], int(nacc), int(res)


# ------------------------------------------------------------------------- SUNDIALS IDA
def ida_available() -> tuple[bool, str]:
    try:
        import sksundae  # noqa: F401
        from sksundae.ida import IDA  # noqa: F401

        return True, f"scikit-sundae {sksundae.__version__} (SUNDIALS {sksundae.SUNDIALS_VERSION})"
    except Exception as exc:  # pragma: no cover
        return False, f"scikit-sundae not usable: {type(exc).__name__}: {exc}"


class IDABaseline:
    """SUNDIALS IDA (variable-order BDF) on the index-2 form ``y = (q, p, λ)``:

    ``F(t, y, y') = [q' - f(t,q,p), p' - g(t,q,p,λ), φ(t,q,p)] = 0``.

    λ is excluded from the local error test. scikit-sundae 1.2 passes ``algebraic_idx``
    to ``IDASetId`` but never calls ``IDASetSuppressAlg``, so the exclusion is done with
    the per-component absolute tolerance: ``atol_λ = 1e30`` makes λ's error weight
    ``1/(rtol|λ| + atol_λ)`` vanish, which removes λ from the weighted RMS norm of the
    error test (and of the Newton convergence test; q and p are still tested).
    With ``exclude_lambda=False`` λ is error-controlled like q and p, for comparison.
    The residual and its Jacobian ``∂F/∂y + c_j ∂F/∂y'`` are AOT-compiled JAX functions.
    """

    def __init__(self, problem, args, n: int, m: int):
        self.problem, self.args, self.n, self.m = problem, args, n, m

        def res(t, y, yp):
            q, p, lam = y[:n], y[n:2 * n], y[2 * n:]
            return jnp.concatenate([
                yp[:n] - problem.f(t, q, p, args),
                yp[n:2 * n] - problem.g(t, q, p, lam, args),
                problem.phi(t, q, p, args),
            ])

        N = 2 * n + m
        ts = jax.ShapeDtypeStruct((), jnp.float64)
        ys = jax.ShapeDtypeStruct((N,), jnp.float64)
        self._res = jax.jit(res).lower(ts, ys, ys).compile()
        self._jac = jax.jit(jax.jacfwd(res, argnums=1)).lower(ts, ys, ys).compile()
        self._dres_dyp = np.diag(np.r_[np.ones(2 * n), np.zeros(m)])
        self.N = N

    def resfn(self, t, y, yp, out):
        out[:] = np.asarray(self._res(np.float64(t), y, yp))

    def jacfn(self, t, y, yp, res, cj, JJ):
        JJ[:, :] = np.asarray(self._jac(np.float64(t), y, yp)) + cj * self._dres_dyp

    def consistent_yp(self, t0, q0, p0, lam0):
        t = jnp.asarray(float(t0))
        q, p, lam = jnp.asarray(q0), jnp.asarray(p0), jnp.asarray(lam0)
        return np.concatenate([np.asarray(self.problem.f(t, q, p, self.args)),
                               np.asarray(self.problem.g(t, q, p, lam, self.args)), np.zeros(self.m)])

    def solve(self, t_span, q0, p0, lam0, rtol, atol, exclude_lambda=True, max_num_steps=10_000_000,
              time_limit=None):
        from sksundae.ida import IDA

        n, m = self.n, self.m
        atol_vec = np.r_[np.full(2 * n, atol), np.full(m, 1e30 if exclude_lambda else atol)]
        solver = IDA(
            self.resfn, jacfn=self.jacfn, algebraic_idx=list(range(2 * n, 2 * n + m)),
            rtol=rtol, atol=atol_vec, max_num_steps=max_num_steps,
        )
        y0 = np.r_[q0, p0, lam0].astype(float)
        yp0 = self.consistent_yp(t_span[0], q0, p0, lam0)
        if time_limit is None:
            r = solver.solve(np.asarray(t_span, float), y0, yp0)
            return IDAOutcome(np.asarray(r.t), np.atleast_2d(r.y), bool(r.success), str(r.message),
                              int(r.nfev), int(r.njev), max(0, len(np.atleast_1d(r.t)) - 1))
        # one internal step at a time, so that a run that crawls can be abandoned
        t1 = float(t_span[1])
        solver.init_step(float(t_span[0]), y0, yp0)
        start = time.perf_counter()
        ts, ys = [float(t_span[0])], [y0]
        while True:
            r = solver.step(t1, method="onestep", tstop=t1)
            t_now = float(np.ravel(r.t)[-1])
            ts.append(t_now)
            ys.append(np.atleast_2d(r.y)[-1].copy())
            done = (not r.success) or t_now >= t1
            late = time.perf_counter() - start > time_limit
            if done or late:
                msg = str(r.message)
                ok = bool(r.success) and not late
                if late and not done:
                    msg = f"abandoned after {time_limit:g} s wall time at t = {t_now:.4g} ({len(ts) - 1} steps)"
                return IDAOutcome(np.asarray(ts), np.asarray(ys), ok, msg, int(r.nfev), int(r.njev), len(ts) - 1)


class IDANumpy(IDABaseline):
    """:class:`IDABaseline` with the residual and its Jacobian written in plain
    Python/NumPy (``_common.NumpyDAE``: by hand for the sleigh, SymPy-generated for the
    falling disk) instead of AOT-compiled JAX: no XLA dispatch per callback, as a user of
    IDA would write it. Same tolerances and the same exclusion of λ from the error test."""

    def __init__(self, dae):  # noqa: D107  (IDABaseline.__init__ builds JAX functions: not called)
        self.dae, self.n, self.m = dae, dae.n, dae.m
        self.N = 2 * dae.n + dae.m
        self._dres_dyp = np.diag(np.r_[np.ones(2 * dae.n), np.zeros(dae.m)])

    def resfn(self, t, y, yp, out):
        out[:] = self.dae.res(t, y, yp)

    def jacfn(self, t, y, yp, res, cj, JJ):
        JJ[:, :] = self.dae.jac_y(t, y) + cj * self._dres_dyp

    def consistent_yp(self, t0, q0, p0, lam0):
        y = np.r_[q0, p0, lam0].astype(float)
        r = self.dae.res(float(t0), y, np.zeros(self.N))  # = [−f, −g, φ] at y' = 0
        return np.r_[-r[:2 * self.n], np.zeros(self.m)]


@dataclass
class IDAOutcome:
    t: np.ndarray
    y: np.ndarray  # (K, 2n+m)
    success: bool
    message: str
    nfev: int
    njev: int
    n_steps: int


# --------------------------------------------------------------- McLachlan-Perlmutter
class McLachlanPerlmutter:
    r"""The second-order nonholonomic integrator of McLachlan & Perlmutter (2006), eq. 4.18.

    For ``H = ½ pᵀM⁻¹p + V(q)`` with constant M and constraints ``μ(q) q' = 0`` it is
    position Störmer-Verlet with the constraint force ``μ(q_{1/2})ᵀλ`` taken at the
    midpoint and the constraint imposed at the end of the step:

    .. math::

        q_{1/2} &= q_0 + \tfrac h2 H_p(q_0, p_0),\\
        p_1 &= p_0 - \tfrac h2 \big(H_q(q_{1/2}, p_0) + H_q(q_{1/2}, p_1)\big)
               + h\, μ(q_{1/2})^T λ,\\
        q_1 &= q_{1/2} + \tfrac h2 H_p(q_1, p_1),\\
        0 &= μ(q_1)\, H_p(q_1, p_1) \;(= φ(q_1, p_1)).

    This is the statement of eq. 4.18 as implemented in O. Verdier's ``odelab``
    (``odelab.scheme.constrained.McLachlan``); for constant M, ``H_q`` does not depend on
    p and the average is just ``V'(q_{1/2})``. For a configuration-dependent M (falling
    disk) the same formulas are used with ``H_p = M(q)⁻¹p`` and the averaged ``H_q``
    (the scheme stays symmetric, hence second order).

    Unknowns ``(q_1, p_1, hλ)`` (``2n + m``), full Newton with an autodiff Jacobian,
    started from an explicit Euler predictor and the previous λ; stops when the scaled
    increment is ≤ ``tol`` or after ``max_iter`` iterations. One compiled loop runs the
    whole integration; ``n_record`` equally spaced points are returned.
    """

    def __init__(self, problem, args, n: int, m: int, tol: float = 1e-14, max_iter: int = 12):
        self.problem, self.args, self.n, self.m = problem, args, n, m
        self.tol, self.max_iter = tol, max_iter
        Hp = lambda t, q, p: problem.f(t, q, p, args)  # noqa: E731
        Hq = jax.grad(lambda t, q, p: problem.hamiltonian(t, q, p, args), argnums=1)
        mu = lambda t, q: problem.constraint_matrix(t, q, args)  # noqa: E731

        def step(t0, q0, p0, lam0, h):
            th, t1 = t0 + 0.5 * h, t0 + h
            qh = q0 + 0.5 * h * Hp(t0, q0, p0)
            hq0 = Hq(th, qh, p0)
            muh = mu(th, qh)

            def residual(x):
                q1, p1, z = x[:n], x[n:2 * n], x[2 * n:]
                v1 = Hp(t1, q1, p1)
                return jnp.concatenate([
                    q1 - qh - 0.5 * h * v1,
                    p1 - p0 + 0.5 * h * (hq0 + Hq(th, qh, p1)) - muh.T @ z,
                    mu(t1, q1) @ v1,
                ])

            x0 = jnp.concatenate([qh + 0.5 * h * Hp(t0, q0, p0),
                                  p0 + h * (-hq0 + muh.T @ lam0), h * lam0])

            def cond(c):
                x, k, nrm = c
                return jnp.logical_and(k < max_iter, nrm > 1.0)

            def body(c):
                x, k, _ = c
                J = jax.jacfwd(residual)(x)
                dx = jnp.linalg.solve(J, residual(x))
                x = x - dx
                nrm = jnp.max(jnp.abs(dx) / (tol * (1.0 + jnp.abs(x))))
                return x, k + 1, nrm

            x, k, nrm = jax.lax.while_loop(cond, body, (x0, jnp.asarray(0), jnp.asarray(jnp.inf)))
            return x[:n], x[n:2 * n], x[2 * n:] / h, k, nrm <= 1.0

        self.step = step

        def run(t0, h, q0, p0, lam0, n_inner, n_record):
            def inner(i, c):
                q, p, lam, its, bad, t = c
                q1, p1, lam1, k, ok = step(t, q, p, lam, h)
                return q1, p1, lam1, its + k, bad + (~ok).astype(jnp.int32), t + h

            def outer(c, _):
                q, p, lam, its, bad, t = jax.lax.fori_loop(0, n_inner, inner, c)
                return (q, p, lam, its, bad, t), (q, p, t)

            c0 = (q0, p0, lam0, jnp.asarray(0), jnp.asarray(0, jnp.int32), t0)
            c, (qs, ps, ts) = jax.lax.scan(outer, c0, None, length=n_record)
            return c, qs, ps, ts

        self._run = jax.jit(run, static_argnames=("n_record",))

    def integrate(self, t_span, q0, p0, lam0, n_steps: int, n_record: int = 500):
        """``n_steps`` (a multiple of ``n_record``) constant steps; returns a dict with the
        recorded ``t, q, p`` (n_record + 1 points), ``q_final, p_final``, Newton stats.
        Time is kept as ``t0 + k h`` accumulated in the loop (t enters only through
        the problem functions, which are autonomous here)."""
        n_record = min(n_record, n_steps)
        if n_steps % n_record:
            raise ValueError("n_steps must be a multiple of n_record")
        t0, t1 = map(float, t_span)
        h = (t1 - t0) / n_steps
        c, qs, ps, ts = self._run(jnp.asarray(t0), jnp.asarray(h), jnp.asarray(q0, jnp.float64),
                                  jnp.asarray(p0, jnp.float64), jnp.asarray(lam0, jnp.float64),
                                  jnp.asarray(n_steps // n_record), n_record)
        jax.block_until_ready(c)
        q, p, lam, its, bad, _ = c
        t = np.r_[t0, t0 + h * n_steps // n_record * np.arange(1, n_record + 1)]
        return {
            "t": t,
            "q": np.vstack([np.asarray(q0, float)[None], np.asarray(qs)]),
            "p": np.vstack([np.asarray(p0, float)[None], np.asarray(ps)]),
            "q_final": np.asarray(q), "p_final": np.asarray(p), "lam_final": np.asarray(lam),
            "newton_iterations_mean": float(its) / n_steps,
            "nonconverged_steps": int(bad),
            "h": h,
        }


# ------------------------------------------------------------------------- validation
def _observed_orders(hs, errs):
    hs, errs = np.asarray(hs, float), np.asarray(errs, float)
    return [float(np.log(errs[i] / errs[i + 1]) / np.log(hs[i] / hs[i + 1])) for i in range(len(hs) - 1)]


def validate(quick: bool = False) -> dict:
    """Errors of every baseline on the knife edge (closed form) must decrease."""
    from lobattodae.examples import get_example

    T = 10.0
    ex = get_example("knife-edge", t_end=T)
    problem, args = ex.problem, ex.args
    n, m = ex.q0.size, ex.lam0.size
    q_ex = ex.exact(np.array([T]))[0][0]
    y0 = np.r_[ex.q0, ex.p0]
    out: dict[str, Any] = {"problem": "knife-edge", "T": T, "checks": {}}
    report = []

    def record(name, settings, errs, expect_decrease=True, extra=None):
        errs = [float(e) for e in errs]
        finite = [e for e in errs if np.isfinite(e)]
        # must be finite and fall by at least two orders of magnitude over the range
        ok = len(finite) == len(errs) and (not expect_decrease or errs[-1] < 1e-2 * errs[0])
        out["checks"][name] = {"settings": settings, "err_q": errs, "ok": bool(ok), **(extra or {})}
        report.append((name, settings, errs, ok, extra))

    # index-reduced ODE: check λ elimination against the exact λ first
    ode = IndexReducedODE(problem, args, n, m)
    qe, pe, le = ex.exact(np.array([0.7]))
    lam_red = np.asarray(ode.lam(jnp.asarray(0.7), jnp.asarray(qe[0]), jnp.asarray(pe[0])))
    out["lambda_elimination_error"] = float(np.max(np.abs(lam_red - le[0])))

    tols = [1e-4, 1e-6, 1e-8, 1e-10] if quick else [1e-4, 1e-6, 1e-8, 1e-10, 1e-12]
    for method in ("DOP853", "Radau"):
        errs = []
        for tol in tols:
            r = ode.solve_scipy(method, (0.0, T), y0, tol, tol)
            errs.append(np.max(np.abs(r.y[:n, -1] - q_ex)) if r.success else np.nan)
        record(f"scipy {method}", [f"tol={t:g}" for t in tols], errs)

    errs = []
    for tol in tols:
        yT, *_ = ode.solve_diffrax((0.0, T), y0, tol, tol)
        errs.append(np.max(np.abs(np.asarray(yT)[:n] - q_ex)))
    record("diffrax Dopri8", [f"tol={t:g}" for t in tols], errs)

    ok_ida, why = ida_available()
    out["ida_available"] = why
    if ok_ida:
        ida = IDABaseline(problem, args, n, m)
        for excl in (True, False):
            errs, msgs = [], []
            for tol in (tols if excl else tols[:3]):
                try:
                    r = ida.solve((0.0, T), ex.q0, ex.p0, ex.lam0, tol, tol, exclude_lambda=excl,
                                  time_limit=None if excl else (3.0 if quick else 10.0))
                    errs.append(np.max(np.abs(r.y[-1, :n] - q_ex)) if r.success else np.nan)
                    msgs.append(r.message if not r.success else "")
                except Exception as exc:  # report, never hide
                    errs.append(np.nan)
                    msgs.append(f"{type(exc).__name__}: {exc}")
            record(f"IDA (λ {'excluded from' if excl else 'included in'} error test)",
                   [f"tol={t:g}" for t in (tols if excl else tols[:3])], errs,
                   extra={"messages": msgs, "informational": not excl})

    mp = McLachlanPerlmutter(problem, args, n, m)
    Ns = [100, 200, 400, 800] if quick else [100, 200, 400, 800, 1600, 3200]
    errs, hs, its = [], [], []
    for N in Ns:
        r = mp.integrate((0.0, T), ex.q0, ex.p0, ex.lam0, N, n_record=100)
        errs.append(np.max(np.abs(r["q_final"] - q_ex)))
        hs.append(r["h"])
        its.append(r["newton_iterations_mean"])
    orders = _observed_orders(hs, errs)
    record("McLachlan-Perlmutter (4.18)", [f"N={N}" for N in Ns], errs,
           extra={"observed_order": orders, "newton_iterations_mean": its})
    out["checks"]["McLachlan-Perlmutter (4.18)"]["ok"] = bool(abs(orders[-1] - 2.0) < 0.15)

    # the MP method also on the sleigh and the falling disk (order check, short interval)
    for name, Tn in (("sleigh", 2.0), ("falling-disk", 2.0)):
        exn = get_example(name, t_end=Tn)
        qn = exn.exact(np.array([Tn]))[0][0]
        mpn = McLachlanPerlmutter(exn.problem, exn.args, exn.q0.size, exn.lam0.size)
        Nn = [20, 40, 80, 160] if quick else [20, 40, 80, 160, 320]
        e2, h2 = [], []
        for N in Nn:
            r = mpn.integrate((0.0, Tn), exn.q0, exn.p0, exn.lam0, N, n_record=20)
            e2.append(np.max(np.abs(r["q_final"] - qn)))
            h2.append(r["h"])
        o2 = _observed_orders(h2, e2)
        record(f"McLachlan-Perlmutter (4.18) on {name}", [f"N={N}" for N in Nn], e2, extra={"observed_order": o2})
        out["checks"][f"McLachlan-Perlmutter (4.18) on {name}"]["ok"] = bool(abs(o2[-1] - 2.0) < 0.2)

    print(f"Validation of the baselines on the knife edge, T = {T} (max-norm error of q(T)):")
    print(f"  λ eliminated by consistent_lambda vs exact λ at t=0.7: {out['lambda_elimination_error']:.2e}")
    for name, settings, errs, ok, extra in report:
        print(f"  {name:50s} {'OK ' if out['checks'][name]['ok'] else 'FAIL'}")
        for s_, e in zip(settings, errs):
            print(f"      {s_:>12s}  err_q = {e:.3e}")
        if extra and "observed_order" in extra:
            print("      observed orders: " + ", ".join(f"{o:.3f}" for o in extra["observed_order"]))
        if extra and "messages" in extra and any(extra["messages"]):
            print("      messages: " + "; ".join(msg for msg in extra["messages"] if msg))
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true", help="fewer tolerances / step sizes (< 1 min)")
    a = ap.parse_args(argv)
    t0 = time.perf_counter()
    out = validate(quick=a.quick)
    out["quick"] = a.quick
    out["wall_seconds"] = time.perf_counter() - t0
    os.makedirs(RESULTS_DIR, exist_ok=True)
    path = os.path.join(RESULTS_DIR, "baselines_validation" + ("_quick" if a.quick else "") + ".json")
    with open(path, "w") as fh:
        json.dump(out, fh, indent=1)
    print(f"saved {path}  ({out['wall_seconds']:.1f} s)")
    return 0 if all(c["ok"] or c.get("informational") for c in out["checks"].values()) else 1


if __name__ == "__main__":
    sys.exit(main())
