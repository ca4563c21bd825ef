"""The competitors, each set up as a competent user of it would.

* :class:`Diffrax` -- diffrax ``Dopri8`` or ``Kvaerno5`` (implicit; its default root finder,
  VeryChord with the controller's tolerances) on a :class:`~lib.odes.ReducedODE`'s JAX
  right-hand side, ``PIDController(rtol=tol, atol=tol, pcoeff, icoeff)``, ``dt0=None``,
  ``adjoint=ForwardMode()`` (no backward pass: a plain while loop), ``throw=False``; the whole
  ``diffeqsolve`` jit-compiled once per output layout, with the tolerance and the PID
  coefficients traced arguments (one compilation serves every setting).
* :func:`scipy_solve` -- ``scipy.integrate.solve_ivp`` (DOP853, Radau with its default
  finite-difference Jacobian) on the ODE's plain NumPy right-hand side, rtol = atol = tol.
* :class:`IDA` -- SUNDIALS IDA (variable-order BDF, scikit-sundae) on an index-2
  :class:`~lib.odes.DAEResidual` with its exact Jacobian, λ excluded from the error test.
"""

from __future__ import annotations

import math
import time
import warnings
from dataclasses import dataclass

import numpy as np

from .odes import DAEResidual, ReducedODE

#: diffrax's documented PID coefficient sets (pcoeff, icoeff): its default I controller, the PI
#: controller it suggests for smooth problems, and one of its "less sensitive" sets.
PID_SETS = [(0.0, 1.0), (0.4, 1.0), (0.3, 0.3)]


class Diffrax:
    """diffrax ``solver`` ("Dopri8" or "Kvaerno5") on ``ode``; see the module docstring.

    ``final`` saves y(t1) only (what is timed), ``at`` the given times, ``trajectory`` every
    step (for ‖φ‖ along the solution; compiled per buffer size)."""

    def __init__(self, ode: ReducedODE, solver: str = "Dopri8", max_steps: int = 10_000_000):
        import diffrax
        import jax

        self.ode, self.solver = ode, solver
        term = diffrax.ODETerm(ode.rhs_jax)
        method = {"Dopri8": diffrax.Dopri8, "Kvaerno5": diffrax.Kvaerno5}[solver]()

        def solve(t0, t1, y0, tol, pcoeff, icoeff, saveat, n_max):
            return diffrax.diffeqsolve(
                term, method, t0, t1, None, y0, args=ode.params,
                stepsize_controller=diffrax.PIDController(rtol=tol, atol=tol, pcoeff=pcoeff, icoeff=icoeff),
                saveat=saveat, max_steps=n_max, adjoint=diffrax.ForwardMode(), throw=False)

        def summary(sol):
            return sol.ys, sol.stats["num_accepted_steps"], sol.stats["num_steps"], \
                sol.result == diffrax.RESULTS.successful

        @jax.jit
        def final(t0, t1, y0, tol, pcoeff, icoeff):
            ys, *rest = summary(solve(t0, t1, y0, tol, pcoeff, icoeff, diffrax.SaveAt(t1=True), max_steps))
            return ys[-1], *rest

        @jax.jit
        def at(t0, ts, y0, tol, pcoeff, icoeff):
            return summary(solve(t0, ts[-1], y0, tol, pcoeff, icoeff, diffrax.SaveAt(ts=ts), max_steps))

        def trajectory(t0, t1, y0, tol, pcoeff, icoeff, n_max):
            sol = solve(t0, t1, y0, tol, pcoeff, icoeff, diffrax.SaveAt(t0=True, steps=True), n_max)
            return sol.ts, sol.ys

        self._final, self._at = final, at
        self._trajectory = jax.jit(trajectory, static_argnames="n_max")

    @staticmethod
    def _args(t0, y0, tol, pid):
        import jax.numpy as jnp

        return (jnp.float64(t0), jnp.asarray(y0, jnp.float64), jnp.float64(tol), jnp.float64(pid[0]),
                jnp.float64(pid[1]))

    def final(self, t1: float, y0, tol: float, pid=PID_SETS[0], t0: float = 0.0):
        """``(y(t1), accepted steps, steps, success)``."""
        import jax
        import jax.numpy as jnp

        t0_, y0_, *rest = self._args(t0, y0, tol, pid)
        yT, nacc, nsteps, ok = jax.block_until_ready(self._final(t0_, jnp.float64(t1), y0_, *rest))
        return np.asarray(yT), int(nacc), int(nsteps), bool(ok)

    def at(self, ts, y0, tol: float, pid=PID_SETS[0], t0: float = 0.0):
        """``(y at ts (rows), accepted steps, steps, success)``; ``ts`` after ``t0``, increasing."""
        import jax
        import jax.numpy as jnp

        t0_, y0_, *rest = self._args(t0, y0, tol, pid)
        ys, nacc, nsteps, ok = jax.block_until_ready(self._at(t0_, jnp.asarray(ts, jnp.float64), y0_, *rest))
        return np.asarray(ys), int(nacc), int(nsteps), bool(ok)

    def trajectory(self, t1: float, y0, tol: float, pid, n_steps_hint: int, t0: float = 0.0):
        """``(t, y)`` at every step; the buffer is sized from ``n_steps_hint`` (a power of two)."""
        import jax.numpy as jnp

        n_max = 1 << max(4, int(math.ceil(math.log2(max(n_steps_hint, 1) * 1.1 + 16))))
        t0_, y0_, *rest = self._args(t0, y0, tol, pid)
        ts, ys = self._trajectory(t0_, jnp.float64(t1), y0_, *rest, n_max)
        ts, ys = np.asarray(ts), np.asarray(ys)
        ok = np.isfinite(ts)
        return ts[ok], ys[ok]


def scipy_solve(ode: ReducedODE, method: str, t_span, y0, tol: float, t_eval=None):
    """``solve_ivp(ode.rhs, t_span, y0, method, rtol=tol, atol=tol)``; scipy's warning for rtol
    below 100 eps (it raises it) is silenced."""
    from scipy.integrate import solve_ivp

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return solve_ivp(ode.rhs, t_span, y0, method=method, rtol=tol, atol=tol,
                         **({} if t_eval is None else {"t_eval": t_eval}))


# ---------------------------------------------------------------------------------- IDA
def ida_available() -> tuple[bool, str]:
    try:
        import sksundae
        from sksundae.ida import IDA as _  # noqa: F401
    except ImportError as exc:
        return False, f"scikit-sundae not usable: {type(exc).__name__}: {exc}"
    return True, f"scikit-sundae {sksundae.__version__} (SUNDIALS {sksundae.SUNDIALS_VERSION})"


@dataclass
class IDAOutcome:
    t: np.ndarray
    y: np.ndarray  # (K, 2n+m)
    success: bool
    message: str
    nfev: int
    njev: int
    n_steps: int


class IDA:
    """SUNDIALS IDA on ``F(t, y, y') = [q' − f, p' − g(λ), φ] = 0``, ``y = (q, p, λ)``.

    λ is excluded from the local error test. scikit-sundae 1.2 passes ``algebraic_idx`` to
    ``IDASetId`` but never calls ``IDASetSuppressAlg``, so the exclusion is done with the
    per-component absolute tolerance: ``atol_λ = 1e30`` makes λ's error weight
    ``1/(rtol|λ| + atol_λ)`` vanish, which removes λ from the weighted RMS norm of the error
    test (and of the Newton convergence test; q and p are still tested). With
    ``exclude_lambda=False`` λ is error-controlled like q and p, for comparison (IDA crawls:
    step sizes ~1e-5). The Jacobian is ``∂F/∂y + c_j ∂F/∂y'``.
    """

    def __init__(self, dae: DAEResidual):
        self.dae, self.n, self.m = dae, dae.n, dae.m
        self._dres_dyp = np.diag(np.r_[np.ones(2 * dae.n), np.zeros(dae.m)])

    def resfn(self, t, y, yp, out):
        out[:] = self.dae.res(t, y, yp)

    def jacfn(self, t, y, yp, res, cj, JJ):
        JJ[:, :] = self.dae.jac_y(t, y) + cj * self._dres_dyp

    def consistent_yp(self, t0, y0):
        r = self.dae.res(float(t0), y0, np.zeros_like(y0))  # = [−f, −g, φ] at y' = 0
        return np.r_[-r[:2 * self.n], np.zeros(self.m)]

    def solve(self, t_span, q0, p0, lam0, tol: float, *, exclude_lambda: bool = True,
              max_num_steps: int = 10_000_000, time_limit: float | None = None) -> IDAOutcome:
        """rtol = atol = tol; ``t_span`` may list output times after its first. With
        ``time_limit`` IDA runs one internal step at a time and a run that crawls is abandoned
        after that many seconds."""
        from sksundae.ida import IDA as Solver

        n, m = self.n, self.m
        atol = np.r_[np.full(2 * n, tol), np.full(m, 1e30 if exclude_lambda else tol)]
        solver = Solver(self.resfn, jacfn=self.jacfn, algebraic_idx=list(range(2 * n, 2 * n + m)), rtol=tol,
                        atol=atol, max_num_steps=max_num_steps)
        y0 = np.r_[q0, p0, lam0].astype(float)
        yp0 = self.consistent_yp(t_span[0], y0)
        if time_limit is None:
            r = solver.solve(np.asarray(t_span, float), y0, yp0)
            return IDAOutcome(np.asarray(r.t), np.atleast_2d(r.y), bool(r.success), str(r.message), int(r.nfev),
                              int(r.njev), max(0, len(np.atleast_1d(r.t)) - 1))
        t1 = float(t_span[-1])
        solver.init_step(float(t_span[0]), y0, yp0)
        start = time.perf_counter()
        ts, ys = [float(t_span[0])], [y0]
        while True:
            r = solver.step(t1, method="onestep", tstop=t1)
            ts.append(float(np.ravel(r.t)[-1]))
            ys.append(np.atleast_2d(r.y)[-1].copy())
            done, late = (not r.success) or ts[-1] >= t1, time.perf_counter() - start > time_limit
            if done or late:
                msg = str(r.message)
                if late and not done:
                    msg = f"abandoned after {time_limit:g} s wall time at t = {ts[-1]:.4g} ({len(ts) - 1} steps)"
                return IDAOutcome(np.asarray(ts), np.asarray(ys), bool(r.success) and not late, msg, int(r.nfev),
                                  int(r.njev), len(ts) - 1)
