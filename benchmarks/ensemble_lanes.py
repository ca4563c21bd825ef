"""How ``ensemble`` should run a device's trajectories on the CPU: vmapped (in lockstep) or one
after the other (``lax.map``), against a loop of single-trajectory calls; per trajectory, after
compilation.

B trajectories (s = 3, consistent initial momenta scaled by 1 + 0.01 i) of examples and of the
particle chain (``lib.problems.particle_chain``), constant steps (h = 0.05; a loop of
``integrate`` calls) and error control (rtol = atol = 1e-8; a loop of ``solve`` calls). The
library picks vmapped for constant steps and one after the other for error control on CPUs
(``lobattodae._ensemble._in_turn``); this script forces each and reports the three. One process
per (problem, mode), best of ``--repeats``. Writes ``benchmarks/results/ensemble_lanes.json``.

    PYTHONPATH=src python benchmarks/ensemble_lanes.py [--batch 16] [--pin-cpu 1]
"""

from __future__ import annotations

import sys
import time

from lib import cli
from lib.output import (
    child_env,
    child_result,
    log,
    md_table,
    python_child,
    results_path,
    run_meta,
    write_json,
)

CHILD = r"""
import sys, time
import jax.numpy as jnp
import numpy as np
import lobattodae as L
from lobattodae import _ensemble
from lib.output import print_result
from lib.problems import particle_chain
L.set_cpu_threads(1)
name, mode, batch, repeats = sys.argv[1], sys.argv[2], int(sys.argv[3]), int(sys.argv[4])
if name.startswith("chain"):
    problem, q0, p0, args = particle_chain(int(name[5:]))
    m, n_steps, t_end = len(q0) // 3, 100, 5.0
else:
    ex = L.examples.get_example(name)
    problem, q0, p0, args, m, n_steps, t_end = ex.problem, ex.q0, ex.p0, ex.args, ex.m, 200, 10.0
method = L.LobattoIIIAIIIB(stages=3)
q = np.tile(q0, (batch, 1))
p = np.tile(p0, (batch, 1)) * (1 + 0.01 * np.arange(batch)[:, None])
lam = np.stack([np.asarray(L.consistent_lambda(problem, 0.0, a, b, jnp.zeros(m), args)) for a, b in zip(q, p)])
adaptive = mode == "adaptive"
kw = dict(t_span=(0.0, t_end), rtol=1e-8, atol=1e-8) if adaptive else dict(h=0.05, n_steps=n_steps)


def loop():
    if adaptive:
        return [L.solve(problem, method, (0.0, t_end), a, b, args=args, rtol=1e-8, atol=1e-8, save_every="final")
                for a, b in zip(q, p)]
    return [L.integrate(problem, method, 0.0, 0.05, n_steps, a, b, c, args).q.block_until_ready()
            for a, b, c in zip(q, p, lam)]


out = {"unknowns": method.n_unknowns(len(q0), m)}
for label, turn in (("vmapped", False), ("in_turn", True), ("loop", None)):
    if turn is None:
        call = loop
    else:
        _ensemble._in_turn = lambda adaptive, devices, turn=turn: turn
        call = lambda: L.ensemble(problem, method, q, p, lam, args, **kw)
    call()
    best = float("inf")
    for _ in range(repeats):
        start = time.perf_counter()
        call()
        best = min(best, time.perf_counter() - start)
    out[label] = 1e3 * best / batch
print_result(out)
"""

CASES = ("knife-edge", "sleigh", "vertical-disk", "falling-disk", "chain2", "chain5", "chain14")


def main(argv=None) -> int:
    ap = cli.parser(__doc__, "pin_cpu")
    ap.add_argument("--batch", type=int, default=16)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--case", nargs="+", default=list(CASES), choices=CASES)
    ap.add_argument("--mode", nargs="+", default=["constant", "adaptive"], choices=["constant", "adaptive"])
    ns = cli.start(ap.parse_args(argv))  # the children inherit the CPU affinity
    rows, out = [], {}
    for mode in ns.mode:
        for case in ns.case:
            r = child_result(python_child(CHILD, case, mode, str(ns.batch), str(ns.repeats)), child_env())
            if "error" in r:
                log(f"{case} {mode}: {r['error']}")
                return 1
            out[f"{case}/{mode}"] = r
            pick = "in_turn" if mode == "adaptive" else "vmapped"
            rows.append([case, r["unknowns"], mode, f"{r['vmapped']:.2f}", f"{r['in_turn']:.2f}", f"{r['loop']:.2f}",
                         f"{r[pick] / r['loop']:.2f}"])
            log(md_table(["problem", "unknowns", "steps", "vmapped", "in turn", "loop", "library's pick / loop"], rows[-1:]))
    log(md_table(["problem", "unknowns", "steps", "vmapped, ms/traj", "in turn, ms/traj", "loop, ms/traj",
                  "library's pick / loop"], rows))
    write_json({**run_meta(batch=ns.batch, repeats=ns.repeats), "results": out}, results_path("ensemble_lanes") + ".json")
    return 0


if __name__ == "__main__":
    started = time.perf_counter()
    code = main()
    log(f"({time.perf_counter() - started:.0f} s)")
    sys.exit(code)
