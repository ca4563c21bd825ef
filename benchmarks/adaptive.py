"""Adaptive steps (issue #10) against diffrax Dopri8 at equal error, T = 1000.

For each problem: the largest rtol (= atol) at which lobattodae's error-controlled ``solve``
(keeping the final state only) reaches max|q(T) - q_exact| <= 1e-8, timed best of 3 with
``solve``'s whole fixed cost included; diffrax Dopri8 with a PID controller tuned the same way
(engine.py's ``wp_diffrax``, three PID settings, the best one reported). Run::

    .venv/bin/python benchmarks/adaptive.py [--quick]

Prints a table and writes benchmarks/results/adaptive.json.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(__file__))
import _common as C  # noqa: E402
import engine  # noqa: E402

import lobattodae as L  # noqa: E402
from lobattodae.examples import get_example  # noqa: E402


def ours(ex, T, q_exact, s, repeats, budget):
    method = L.LobattoIIIAIIIB(stages=s)

    def solve(tol):
        return L.solve(ex.problem, method, (0.0, T), ex.q0, ex.p0, args=ex.args, lam0=ex.lam0, rtol=tol, atol=tol,
                       save_every="final", throw=False)

    def err_of_tol(tol):
        sol = solve(tol)
        return float(np.max(np.abs(sol.q[-1] - q_exact))) if sol.success else math.inf

    srch = C.search_tolerance(err_of_tol, 1e-9, engine.TARGET_ERR, tol_min=1e-14, max_probes=10, budget_s=budget)
    if srch.best is None:
        return {"solver": f"lobattodae s={s}", "ok": False, "message": srch.message, "probes": srch.table()}
    tol = srch.best
    wall, times, sol = C.best_of(lambda: solve(tol), repeats)
    err = float(np.max(np.abs(sol.q[-1] - q_exact)))
    return {"solver": f"lobattodae s={s}", "ok": bool(err <= engine.TARGET_ERR), "tol": tol, "wall_s": wall,
            "all_s": times, "err_q": err, "steps": sol.stats["n_steps"], "rejected": sol.stats["n_rejected"],
            "max_phi": sol.stats["max_constraint_residual"], "probes": srch.table()}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--quick", action="store_true")
    a = ap.parse_args()
    T = 100.0 if a.quick else 1000.0
    repeats = 3
    wcfg = {"pids": engine.PID_SETS[:1] if a.quick else engine.PID_SETS, "tol_probes": 10, "probe_budget_s": 30.0}
    out = {"date": time.strftime("%Y-%m-%d"), "machine": C.machine_info(), "T": T, "problems": {}}
    for name in ("knife-edge", "falling-disk"):
        ex = get_example(name, t_end=T)
        q_exact = ex.exact(np.array([T]))[0][0]
        C.log(f"-- {name}, T = {T:g}")
        rows = [ours(ex, T, q_exact, s, repeats, 60.0) for s in (3, 4, 5)]
        for r in rows:
            C.log(f"   {r['solver']}: " + (f"tol {r['tol']:g} err {r['err_q']:.2e} {r['wall_s'] * 1e3:.1f} ms "
                                            f"{r['steps']} steps ({r['rejected']} rejected) max|φ| {r['max_phi']:.1e}"
                                            if r.get("ok") else r.get("message", "missed")))
        ode = C.reduced_ode(name, ex.args)
        dfx = engine.wp_diffrax(ode, T, np.r_[ex.q0, ex.p0], q_exact, wcfg, repeats)
        best = min((r for r in rows if r.get("ok")), key=lambda r: r["wall_s"], default=None)
        ratio = best["wall_s"] / dfx["best"]["wall_s"] if best and dfx.get("best") else None
        C.log(f"   => ours/Dopri8 = {ratio:.2f}" if ratio else "   => no ratio")
        out["problems"][name] = {"lobattodae": rows, "diffrax": dfx, "ratio_ours_over_dopri8": ratio}
    os.makedirs(os.path.join(os.path.dirname(__file__), "results"), exist_ok=True)
    with open(os.path.join(os.path.dirname(__file__), "results", "adaptive.json"), "w") as fh:
        json.dump(C.jsonable(out), fh, indent=1)


if __name__ == "__main__":
    main()
