"""Constant-step convergence of lobattodae on the test set (the tables of README.md).

    .venv/bin/python -m benchmarks.testset.convergence [NAME ...] [--stages 4,5] [--steps 100,200]

For each problem and number of stages: ``error`` (max over the compared components and the
reference times) of ``lobattodae.solve(..., n_steps=N)`` for each N, the observed order
log2(e(N)/e(2N)), and the wall time of the run (the first run of a problem and s includes the
compilation).
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import time

if __package__ in (None, ""):  # run as a file
    sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", ".."))

import lobattodae as L  # noqa: E402

from benchmarks.testset import PROBLEMS, error  # noqa: E402

#: name -> (stages, step counts) of the README tables
DEFAULT_STUDY = {
    "andrews": ((4, 5), (50, 100, 200, 400, 800)),
    "caraxis": ((2, 3, 4, 5, 6), (50, 100, 200, 400, 800, 1600)),
    "crank": ((3, 4, 5, 6), (500, 1000, 2000, 4000, 8000)),
    "fekete": ((3, 4, 5, 6), (2000, 4000, 8000, 16000)),
    "rolling-disc": ((4, 5), (100, 200, 400, 800, 1600)),
    "fourbar": ((3, 4, 5, 6), (100, 200, 400, 800, 1600)),
    "vertical-disk": ((3, 4), (200, 400, 800, 1600)),
    "sleigh": ((3, 4), (500, 1000, 2000, 4000, 8000)),
    "knife-edge": ((3, 4), (1000, 2000, 4000, 8000, 16000)),
    "servo-sleigh": ((2, 3, 4, 5), (200, 400, 800, 1600, 3200, 6400, 12800)),
    "servo-sleigh-rest": ((2, 3, 4, 5), (400, 800, 1600, 3200, 6400, 12800)),
}


def run(name, stages, steps, out=print):
    entry = PROBLEMS[name]
    s = entry.build()
    out(f"## {name}  (T = {s.t_span[1]:g}, reference accuracy {entry.ref_accuracy:.0e}, compared: {entry.compare})")
    for st in stages:
        prev = None
        for n in steps:
            t0 = time.perf_counter()
            try:
                sol = L.solve(s.problem, L.LobattoIIIAIIIB(stages=st), s.t_span, s.q0, s.p0, args=s.args, n_steps=n)
                e = error(entry, sol.t, sol.q, sol.p)
                text = f"{e:.2e}"
            except L.SolverError as exc:
                e, text = None, f"failed ({type(exc).__name__}: {str(exc)[:70]})"
            dt = time.perf_counter() - t0
            order = f"{math.log2(prev / e):5.2f}" if prev and e and e > 0 else "  -  "
            out(f"s={st} N={n:6d} h={(s.t_span[1] - s.t_span[0]) / n:.3g}  error {text}  order {order}  {dt:6.2f} s")
            prev = e
    return None


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("names", nargs="*", help=f"problems (default all): {', '.join(PROBLEMS)}")
    ap.add_argument("--stages", help="comma-separated s (default: per problem)")
    ap.add_argument("--steps", help="comma-separated N (default: per problem)")
    a = ap.parse_args(argv)
    L.set_cpu_threads(1)
    for name in a.names or list(PROBLEMS):
        stages, steps = DEFAULT_STUDY[name]
        if a.stages:
            stages = tuple(int(x) for x in a.stages.split(","))
        if a.steps:
            steps = tuple(int(x) for x in a.steps.split(","))
        run(name, stages, steps)


if __name__ == "__main__":
    main()
