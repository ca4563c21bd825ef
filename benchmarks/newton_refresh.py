"""When to refresh a reused Newton Jacobian (issue #10): step cost under two settings of
``lobattodae._newton``'s ``REFRESH_PREDICTED`` and ``REFRESH_ITERATIONS``.

A reused Jacobian is refreshed when its contraction predicts more than ``REFRESH_PREDICTED``
further iterations, and in any case after ``REFRESH_ITERATIONS``; the right values depend on
what a refresh costs against an iteration. Each setting runs in its own fresh process (the
constants are read when the step is traced), with XLA's CPU pool at one thread
(:func:`lobattodae.set_cpu_threads`); the settings alternate, ``--rounds`` times, and each case
reports the best of its rounds.

Cases: ``method.step`` in a jitted ``fori_loop`` of constant steps (knife edge s = 5,
h = 0.2; sleigh s = 5, h = 1; falling disk s = 3 and s = 5 at h = 0.05, s = 5 at h = 0.25),
``solve`` with error control (sleigh to T = 1000, s = 5, tol 1e-11; falling disk to T = 200,
s = 5, tol 1e-10), and ``solve`` of the particle at tiny constant steps (s = 3,
h = 60/24576, where increments sit just above round-off). Per case: time, Newton iterations
and Jacobians per step (attempt).

Usage::

    PYTHONPATH=src .venv/bin/python benchmarks/newton_refresh.py [--settings 4,8 8,12] [--rounds 2]

Writes ``benchmarks/results/newton_refresh.json``.
"""

from __future__ import annotations

import sys
import time

from lib import cli
from lib.output import child_env, child_result, md_table, python_child, results_path, run_meta, write_json

CHILD = r"""
import sys
import jax
import lobattodae as L
from lobattodae import _newton
from lib.output import print_result
from lib.timing import best_of

L.set_cpu_threads(1)
_newton.REFRESH_PREDICTED, _newton.REFRESH_ITERATIONS = float(sys.argv[1]), int(sys.argv[2])
from lobattodae.examples import get_example

res = {}
for name, s, h, n in [("knife-edge", 5, 0.2, 5000), ("sleigh", 5, 1.0, 1000), ("falling-disk-general", 3, 0.05, 2000),
                      ("falling-disk-general", 5, 0.05, 2000), ("falling-disk-general", 5, 0.25, 2000)]:
    ex = get_example(name)
    m = L.LobattoIIIAIIIB(stages=s)

    def loop(q, p, lam, ex=ex, m=m, h=h, n=n):
        st = m.init(ex.problem, 0.0, q, p, lam, ex.args, h)

        def body(i, c):
            q, p, lam, st, its, jacs = c
            q1, p1, l1, info, st1 = m.step(ex.problem, i * h, q, p, lam, h, ex.args, st)
            return q1, p1, l1, st1, its + info.iterations, jacs + info.n_jacobians

        return jax.lax.fori_loop(0, n, body, (q, p, lam, st, 0, 0))

    f = jax.jit(loop)
    tm = best_of(lambda: f(ex.q0, ex.p0, ex.lam0), 5, first=True)
    res[f"{name}, s = {s}, h = {h:g} (step loop)"] = {"s_per_step": tm.best / n, "newton": float(tm.result[4]) / n,
                                                     "jacobians": float(tm.result[5]) / n}
solves = [("sleigh", 5, (0.0, 1000.0), dict(rtol=1e-11, atol=1e-11)),
          ("falling-disk-general", 5, (0.0, 200.0), dict(rtol=1e-10, atol=1e-10)),
          ("particle", 3, (0.0, 6.0), dict(n_steps=2458))]
for name, s, span, kw in solves:
    ex = get_example(name)
    m = L.LobattoIIIAIIIB(stages=s)
    tm = best_of(lambda: L.solve(ex.problem, m, span, ex.q0, ex.p0, args=ex.args, lam0=ex.lam0, save_every="final",
                                 **kw), 5, first=True)
    st = tm.result.stats
    na = int(st["n_steps"]) + int(st.get("n_rejected", 0))
    res[f"{name}, s = {s}, solve {', '.join(f'{k} = {v:g}' for k, v in kw.items())}"] = {
        "s_per_step": tm.best / na, "newton": float(st["n_newton"]) / na, "jacobians": float(st["n_jacobians"]) / na,
        "solve_s": tm.best}
print_result(res)
"""


def run_child(predicted: float, iterations: int) -> dict:
    r = child_result(python_child(CHILD, str(predicted), str(iterations)), child_env(no_cache=False, PJRT_NPROC=None))
    if "error" in r:
        raise SystemExit(f"the child process failed: {r['error']}")
    return r


def main(argv=None) -> int:
    ap = cli.parser(__doc__)
    ap.add_argument("--settings", nargs="+", default=["4,8", "8,12"], help="REFRESH_PREDICTED,REFRESH_ITERATIONS")
    ap.add_argument("--rounds", type=int, default=2)
    a = ap.parse_args(argv)
    settings = [(float(x.split(",")[0]), int(x.split(",")[1])) for x in a.settings]
    t0 = time.perf_counter()
    meta = run_meta()
    rounds = {f"{p:g},{i}": [] for p, i in settings}
    for r in range(a.rounds):
        for p, i in settings:
            rounds[f"{p:g},{i}"].append(run_child(p, i))
            print(f"round {r + 1}/{a.rounds}: ({p:g}, {i}) done", flush=True)
    best = {key: {case: min((rd[case] for rd in rs), key=lambda v: v["s_per_step"]) for case in rs[0]}
            for key, rs in rounds.items()}
    keys = list(best)
    rows = []
    for case in best[keys[0]]:
        row = [case]
        for key in keys:
            v = best[key][case]
            row.append(f"{1e6 * v['s_per_step']:.1f} µs, {v['newton']:.2f} it, {v['jacobians']:.2f} J")
        row.append(f"{best[keys[0]][case]['s_per_step'] / best[keys[-1]][case]['s_per_step']:.2f}")
        rows.append(row)
    print(md_table(["case (per step)"] + [f"({k})" for k in keys] + [f"({keys[0]}) / ({keys[-1]})"], rows))
    write_json({**meta, "seconds": time.perf_counter() - t0, "rounds": rounds, "best": best},
               results_path("newton_refresh.json"))
    return 0


if __name__ == "__main__":
    sys.exit(main())
