"""Rejected attempts of error-controlled runs on the test set (issues #25, #26): how many
attempts the PI controller throws away, and what they cost.

For each problem of ``testset.PROBLEMS`` named, each s and each tolerance: ``solve`` with
rtol = atol = tol, ``save_every="final"``, one warm-up call and the best of 3 further calls
(a call longer than 2 s is not repeated); steps, rejected attempts, Newton iterations, the
error against the problem's reference (in units of tol) and the time. Every source tree given
with ``--src`` runs in its own fresh process with XLA's CPU pool at one thread (``--pin-cpu N``
pins them to one CPU), so that two commits compare in one run.

Usage (repository root)::

    git worktree add /tmp/before <commit>
    .venv/bin/python benchmarks/rejections.py --src /tmp/before/src --src src --pin-cpu 0 \\
        [--problems servo-sleigh servo-sleigh-rest] [--stages 5 6] [--tols 1e-6 1e-8 1e-10]

Writes ``benchmarks/results/rejections.json``.
"""

from __future__ import annotations

from lib import cli
from lib.output import md_table, results_path, rows_per_source, run_meta, write_json

CHILD = r"""
import sys, time, json
import lobattodae as L
from benchmarks.testset import PROBLEMS, error
from lib.output import print_result
L.set_cpu_threads(1)
problems, stages, tols = (json.loads(a) for a in sys.argv[1:4])
rows = []
for name in problems:
    entry = PROBLEMS[name]
    setup = entry.build()
    for s in stages:
        method = L.LobattoIIIAIIIB(stages=s)
        for tol in tols:
            def call():
                return L.solve(setup.problem, method, setup.t_span, setup.q0, setup.p0, args=setup.args,
                               save_every="final", rtol=tol, atol=tol, throw=False)
            sol = call()
            times = []
            for _ in range(3):
                t0 = time.perf_counter()
                sol = call()
                times.append(time.perf_counter() - t0)
                if times[-1] > 2.0:
                    break
            st = sol.stats
            rows.append({"problem": name, "s": s, "tol": tol, "success": bool(sol.success),
                         "error_over_tol": float(error(entry, sol.t[-1], sol.q[-1], sol.p[-1])) / tol,
                         "steps": int(st["n_steps"]), "rejected": int(st["n_rejected"]),
                         "newton": int(st["n_newton"]), "time_s": min(times)})
print_result({"rows": rows})
"""


def main() -> None:
    parser = cli.parser(__doc__, "pin_cpu")
    parser.add_argument("--src", action="append", help="the src directory to import (repeatable; default src)")
    parser.add_argument("--problems", nargs="+", default=["servo-sleigh", "servo-sleigh-rest"])
    parser.add_argument("--stages", nargs="+", type=int, default=[4, 5, 6])
    parser.add_argument("--tols", nargs="+", type=float, default=[1e-6, 1e-8, 1e-10])
    opts = cli.start(parser.parse_args())
    runs = rows_per_source(CHILD, [opts.problems, opts.stages, opts.tols], opts.src)
    table = []
    keys = [(r["problem"], r["s"], r["tol"]) for r in next(iter(runs.values()))]
    for i, (name, s, tol) in enumerate(keys):
        cells = [name, s, f"{tol:g}"]
        for rows in runs.values():
            r = rows[i]
            cells += [r["rejected"], r["steps"], f"{r['time_s'] * 1e3:.1f}", f"{r['error_over_tol']:.3f}"]
        table.append(cells)
    headers = ["problem", "s", "tol"]
    for src in runs:
        headers += [f"rejected ({src})", "steps", "ms", "error/tol"]
    print(md_table(headers, table))
    write_json({"meta": run_meta(sources=list(runs)), "runs": runs}, results_path("rejections.json"))


if __name__ == "__main__":
    main()
