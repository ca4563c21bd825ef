"""Error control where the steps outgrow a damped mode (issue #25): a Chaplygin sleigh that settles.

The sleigh of ``lobattodae.examples`` started in straight motion at unit speed with an angular
velocity ω0 turns, and the constraint damps the turn until it moves in a straight line again.
Error-controlled steps then grow to hundreds of time units, far beyond the range where the
turning mode is resolved. For each ω0, s and rtol: ``solve`` over [0, 1000] with rtol = atol,
the error at every step point (relative to 1 + |y|, q and p) against 40,000 constant steps of
s = 6 evaluated by their dense output, the steps and the rejected attempts. Every source tree
given with ``--src`` runs in its own fresh process, so that two commits compare in one run.

Usage (repository root)::

    git worktree add /tmp/before <commit>
    .venv/bin/python benchmarks/settling_sleigh.py --src /tmp/before/src --src src --pin-cpu 0 \\
        [--omegas 0.1 1.0 0.01] [--stages 3 4 5 6] [--rtols 1e-6 1e-8 1e-10]

Writes ``benchmarks/results/settling_sleigh.json``.
"""

from __future__ import annotations

from lib import cli
from lib.output import md_table, results_path, rows_per_source, run_meta, write_json

CHILD = r"""
import sys, json
import numpy as np
import jax.numpy as jnp
import lobattodae as L
from lib.output import print_result
omegas, stages, rtols = (json.loads(a) for a in sys.argv[1:4])
ex = L.examples.get_example("sleigh")
a = ex.args
span = (0.0, 1000.0)
rows = []
for w0 in omegas:
    q0, p0 = jnp.zeros(3), jnp.asarray([a.m, a.m * a.a * w0, a.I * w0])
    ref = L.solve(ex.problem, L.LobattoIIIAIIIB(stages=6), span, q0, p0, args=a, n_steps=40000, dense_output=True)
    for s in stages:
        for tol in rtols:
            sol = L.solve(ex.problem, L.LobattoIIIAIIIB(stages=s), span, q0, p0, args=a, rtol=tol, atol=tol)
            y = np.hstack([sol.q, sol.p])
            y_ref = np.array([np.concatenate([np.asarray(u) for u in ref.sol(t)[:2]]) for t in sol.t])
            err = np.max(np.abs(y - y_ref) / (1 + np.abs(y_ref)), axis=1)
            rows.append({"omega0": w0, "s": s, "rtol": tol, "success": bool(sol.success),
                         "max_over_rtol": float(err.max() / tol), "at_t": float(sol.t[int(np.argmax(err))]),
                         "end_over_rtol": float(err[-1] / tol), "steps": int(sol.stats["n_steps"]),
                         "rejected": int(sol.stats["n_rejected"])})
print_result({"rows": rows})
"""


def main() -> None:
    parser = cli.parser(__doc__, "pin_cpu")
    parser.add_argument("--src", action="append", help="the src directory to import (repeatable; default src)")
    parser.add_argument("--omegas", nargs="+", type=float, default=[0.1, 1.0, 0.01])
    parser.add_argument("--stages", nargs="+", type=int, default=[3, 4, 5, 6])
    parser.add_argument("--rtols", nargs="+", type=float, default=[1e-6, 1e-8, 1e-10])
    opts = cli.start(parser.parse_args())
    runs = rows_per_source(CHILD, [opts.omegas, opts.stages, opts.rtols], opts.src)
    keys = [(r["omega0"], r["s"], r["rtol"]) for r in next(iter(runs.values()))]
    table = []
    for i, (w0, s, tol) in enumerate(keys):
        cells = [w0, s, f"{tol:g}"]
        for rows in runs.values():
            r = rows[i]
            cells += [f"{r['max_over_rtol']:.2g}", f"{r['end_over_rtol']:.2g}", r["steps"], r["rejected"]]
        table.append(cells)
    headers = ["ω0", "s", "rtol"]
    for src in runs:
        headers += [f"max step-point error / rtol ({src})", "end / rtol", "steps", "rejected"]
    print(md_table(headers, table))
    worst = {src: max(r["max_over_rtol"] for r in rows) for src, rows in runs.items()}
    above = {src: sum(r["max_over_rtol"] > 30 for r in rows) for src, rows in runs.items()}
    print("\nlargest step-point error / rtol:", worst, "  runs above 30 x rtol:", above)
    write_json({"meta": run_meta(sources=list(runs)), "runs": runs}, results_path("settling_sleigh.json"))


if __name__ == "__main__":
    main()
