"""Validation of the competitors of ``lib.baselines`` and ``lib.mclachlan`` (issue #4).

On the knife edge (closed form, T = 10), every baseline's max-norm error of q(T) must fall by
at least 100× over its range of tolerances (step counts for McLachlan-Perlmutter):

* scipy DOP853 and Radau on the hand-written NumPy reduced ODE (``lib.odes.knife_edge``);
* diffrax Dopri8 and Kvaerno5 on its JAX form (``lib.baselines.Diffrax``);
* SUNDIALS IDA on the index-2 DAE (``lib.odes.jax_dae``), λ excluded from the error test; and,
  for the record, with λ in the error test, where it crawls (step sizes ~1e-5, abandoned after
  10 s; informational);
* McLachlan-Perlmutter (eq. 4.18), which must show order 2, also on the sleigh and the falling
  disk (T = 2).

Before, the reduced ODE is checked against the problem's own vector field, and its λ
(``−sin θ p'_x + cos θ (p'_y + m g)``, from ``p' = μᵀλ + (0, −m g, 0)``) against the exact λ.

    PYTHONPATH=src .venv/bin/python benchmarks/baselines.py [--quick]

Writes ``benchmarks/results/baselines_validation[_quick].json``; exit status 1 when a check
fails.
"""

from __future__ import annotations

import sys
import time

import numpy as np

from lib import cli
from lib.baselines import IDA, Diffrax, ida_available, scipy_solve
from lib.mclachlan import McLachlanPerlmutter
from lib.odes import jax_dae, knife_edge, validate_ode
from lib.output import log, results_path, write_json
from lobattodae.examples import get_example

T = 10.0


def falls(errs) -> bool:
    """Finite, and down by two orders of magnitude over the range."""
    return bool(np.all(np.isfinite(errs)) and errs[-1] < 1e-2 * errs[0])


def orders(hs, errs) -> list[float]:
    hs, errs = np.asarray(hs, float), np.asarray(errs, float)
    return list(np.log(errs[:-1] / errs[1:]) / np.log(hs[:-1] / hs[1:]))


def check(name: str, settings: list[str], errs, ok: bool, **extra) -> dict:
    log(f"  {name:50s} {'OK ' if ok else 'FAIL'}")
    for st, e in zip(settings, errs):
        log(f"      {st:>12s}  err_q = {e:.3e}")
    if "observed_order" in extra:
        log("      observed orders: " + ", ".join(f"{o:.3f}" for o in extra["observed_order"]))
    if any(extra.get("messages", [])):
        log("      messages: " + "; ".join(msg for msg in extra["messages"] if msg))
    return {name: {"settings": settings, "err_q": [float(e) for e in errs], "ok": ok, **extra}}


def mclachlan(name: str, t_end: float, steps: list[int], n_record: int, tolerance: float) -> dict:
    ex = get_example(name, t_end=t_end)
    q_exact = ex.exact(np.array([t_end]))[0][0]
    mp = McLachlanPerlmutter(ex.problem, ex.args, ex.q0.size, ex.lam0.size)
    runs = [mp.integrate((0.0, t_end), ex.q0, ex.p0, ex.lam0, N, n_record=n_record) for N in steps]
    errs = [np.max(np.abs(r["q_final"] - q_exact)) for r in runs]
    o = orders([r["h"] for r in runs], errs)
    label = "McLachlan-Perlmutter (4.18)" + ("" if name == "knife-edge" else f" on {name}")
    return check(label, [f"N={N}" for N in steps], errs, bool(abs(o[-1] - 2.0) < tolerance), observed_order=o,
                 newton_iterations_mean=[r["newton_iterations_mean"] for r in runs])


def validate(quick: bool) -> dict:
    ex = get_example("knife-edge", t_end=T)
    n, m = ex.q0.size, ex.lam0.size
    q_exact = ex.exact(np.array([T]))[0][0]
    y0 = np.r_[ex.q0, ex.p0]
    ode = knife_edge(ex.args)
    qe, pe, le = ex.exact(np.array([0.7]))
    pdot = ode.rhs(0.7, np.r_[qe[0], pe[0]])[n:]
    th, mg = qe[0][2], float(ex.args.m) * float(ex.args.g)
    out = {"problem": "knife-edge", "T": T, "ode_validation": validate_ode(ode, ex.problem, ex.args, ex.q0, ex.p0),
           "lambda_elimination_error": float(abs(-np.sin(th) * pdot[0] + np.cos(th) * (pdot[1] + mg) - le[0][0])),
           "checks": {}}
    log(f"Validation of the baselines on the knife edge, T = {T} (max-norm error of q(T)):")
    log(f"  reduced ODE against the problem's vector field: {out['ode_validation']}")
    log(f"  λ of the reduced ODE vs exact λ at t = 0.7: {out['lambda_elimination_error']:.2e}")
    tols = [1e-4, 1e-6, 1e-8, 1e-10] if quick else [1e-4, 1e-6, 1e-8, 1e-10, 1e-12]
    labels = [f"tol={t:g}" for t in tols]
    checks = out["checks"]
    for method in ("DOP853", "Radau"):
        runs = [scipy_solve(ode, method, (0.0, T), y0, tol) for tol in tols]
        errs = [np.max(np.abs(r.y[:n, -1] - q_exact)) if r.success else np.nan for r in runs]
        checks.update(check(f"scipy {method}", labels, errs, falls(errs)))
    for solver in ("Dopri8", "Kvaerno5"):
        dfx = Diffrax(ode, solver)
        errs = [np.max(np.abs(dfx.final(T, y0, tol)[0][:n] - q_exact)) for tol in tols]
        checks.update(check(f"diffrax {solver}", labels, errs, falls(errs)))
    ok_ida, out["ida_available"] = ida_available()
    if ok_ida:
        ida = IDA(jax_dae(ex.problem, ex.args, n, m))
        for excluded in (True, False):
            settings = tols if excluded else tols[:3]
            runs = [ida.solve((0.0, T), ex.q0, ex.p0, ex.lam0, tol, exclude_lambda=excluded,
                              time_limit=None if excluded else (3.0 if quick else 10.0)) for tol in settings]
            errs = [np.max(np.abs(r.y[-1, :n] - q_exact)) if r.success else np.nan for r in runs]
            checks.update(check(f"IDA (λ {'excluded from' if excluded else 'included in'} error test)",
                                [f"tol={t:g}" for t in settings], errs, falls(errs),
                                messages=["" if r.success else r.message for r in runs], informational=not excluded))
    checks.update(mclachlan("knife-edge", T, [100, 200, 400, 800] if quick else [100, 200, 400, 800, 1600, 3200],
                            100, 0.15))
    for name in ("sleigh", "falling-disk"):  # order 2 on a short interval
        checks.update(mclachlan(name, 2.0, [20, 40, 80, 160] if quick else [20, 40, 80, 160, 320], 20, 0.2))
    return out


def main(argv=None) -> int:
    a = cli.start(cli.parser(__doc__, "quick").parse_args(argv))
    t0 = time.perf_counter()
    out = validate(a.quick)
    out.update(quick=a.quick, wall_seconds=time.perf_counter() - t0)
    write_json(out, results_path("baselines_validation" + ("_quick" if a.quick else "") + ".json"))
    checks = [c["ok"] or c.get("informational") for c in out["checks"].values()]
    return 0 if all(checks) and out["ode_validation"]["ok"] else 1


if __name__ == "__main__":
    sys.exit(main())
