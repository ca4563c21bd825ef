"""``ensemble`` against a loop of ``solve`` calls on the CPU (issue #26's targets): the cost
per trajectory after compilation, and the first call (compilation included) of each.

B trajectories of the knife edge (s = 3, perturbed consistent initial momenta), constant steps
(200 steps of h = 0.05) and error control (T = 10, rtol = atol = 1e-8). Each of the four
(mode, driver) settings runs in a fresh process without the persistent compilation cache: the
first call (one ``solve``, or the whole ``ensemble``), then the best of ``--repeats`` further
calls (the loop of B ``solve`` calls, or one ``ensemble``), per trajectory. The targets: the
ensemble at least as fast per trajectory as the loop, its first call at most 2x one
``solve``'s. Writes ``benchmarks/results/ensemble_vs_solve.json``.

    PYTHONPATH=src python benchmarks/ensemble_vs_solve.py [--batch 64] [--pin-cpu 1]
"""

from __future__ import annotations

import sys
import time

from lib import cli
from lib.output import child_env, child_result, log, md_table, python_child, results_path, run_meta, write_json

CHILD = r"""
import sys, time
import numpy as np
import lobattodae as L
from lib.output import print_result
L.set_cpu_threads(1)
mode, driver, batch, repeats = sys.argv[1], sys.argv[2], int(sys.argv[3]), int(sys.argv[4])
ex = L.examples.get_example("knife-edge")
method = L.LobattoIIIAIIIB(stages=3)
rng = np.random.default_rng(0)
q0 = np.tile(ex.q0, (batch, 1))
p0 = np.tile(ex.p0, (batch, 1)) * (1 + 0.01 * rng.standard_normal((batch, 1)))
lam0 = np.stack([np.asarray(L.consistent_lambda(ex.problem, 0.0, q, p, np.zeros(len(ex.lam0)), ex.args))
                 for q, p in zip(q0, p0)])
adaptive = mode == "adaptive"
if driver == "ensemble":
    kw = dict(t_span=(0.0, 10.0), rtol=1e-8, atol=1e-8) if adaptive else dict(h=0.05, n_steps=200)
    call = lambda: L.ensemble(ex.problem, method, q0, p0, lam0, ex.args, **kw)
    first = call
else:
    kw = dict(rtol=1e-8, atol=1e-8) if adaptive else dict(n_steps=200)
    one = lambda i: L.solve(ex.problem, method, (0.0, 10.0), q0[i], p0[i], args=ex.args, save_every="final", **kw)
    first = lambda: one(0)
    call = lambda: [one(i) for i in range(batch)]
start = time.perf_counter()
first()
first_call = time.perf_counter() - start
best = float("inf")
for _ in range(repeats):
    start = time.perf_counter()
    call()
    best = min(best, time.perf_counter() - start)
print_result({"first_call_s": first_call, "per_trajectory_ms": 1e3 * best / batch})
"""


def main(argv=None) -> int:
    ap = cli.parser(__doc__, "pin_cpu")
    ap.add_argument("--batch", type=int, default=64)
    ap.add_argument("--repeats", type=int, default=3)
    ns = cli.start(ap.parse_args(argv))  # the children inherit the CPU affinity
    rows, out = [], {}
    for mode in ("constant", "adaptive"):
        got = {}
        for driver in ("solve", "ensemble"):
            r = child_result(python_child(CHILD, mode, driver, str(ns.batch), str(ns.repeats)), child_env())
            if "error" in r:
                log(f"{mode} {driver}: {r['error']}")
                return 1
            got[driver] = r
        out[mode] = got
        s, e = got["solve"], got["ensemble"]
        rows.append([mode, f"{s['per_trajectory_ms']:.2f}", f"{e['per_trajectory_ms']:.2f}",
                     f"{e['per_trajectory_ms'] / s['per_trajectory_ms']:.2f}", f"{s['first_call_s']:.2f}",
                     f"{e['first_call_s']:.2f}", f"{e['first_call_s'] / s['first_call_s']:.2f}"])
    log(md_table(["steps", "loop of solve, ms/traj", "ensemble, ms/traj", "ratio (target ≤ 1)",
                  "first solve, s", "first ensemble, s", "ratio (target ≤ 2)"], rows))
    write_json({**run_meta(batch=ns.batch, repeats=ns.repeats), "results": out}, results_path("ensemble_vs_solve") + ".json")
    return 0


if __name__ == "__main__":
    started = time.perf_counter()
    code = main()
    log(f"({time.perf_counter() - started:.0f} s)")
    sys.exit(code)
