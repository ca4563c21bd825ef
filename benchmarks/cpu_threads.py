"""Step cost with XLA's default CPU thread pool against a one-thread pool (issue #10).

XLA:CPU hands kernels that could run concurrently to its thread pool; lobattodae's steps are
chains of tiny kernels, for which the hand-offs cost more than they gain
(:mod:`lobattodae._cpu`). The pool size is fixed when JAX starts its CPU backend, so each
setting runs in its own fresh process (``PJRT_NPROC`` unset, or ``PJRT_NPROC=1`` as
:func:`lobattodae.set_cpu_threads` sets it); the two alternate, ``--rounds`` times, and each
case reports the best of its rounds.

Cases (time per step of ``jax.jit(integrate)`` over ``N`` constant steps, compiled first;
best of 3 calls per process): the knife edge (s = 5, h = 0.2), the Chaplygin sleigh (s = 5,
h = 1), the falling disk in general motion (s = 3 and s = 5 at h = 0.05, s = 5 at h = 0.25),
a ``vmap`` batch of 64 falling disks (s = 3, h = 0.05, per trajectory-step), and diffrax's
Dopri8 on the falling disk's index-reduced ODE (per step; tolerance 1e-12, PID (0, 1)), which
shows that the setting is ours, not the other solvers'.

Usage::

    PYTHONPATH=src .venv/bin/python benchmarks/cpu_threads.py [--rounds 3]

Writes ``benchmarks/results/cpu_threads.json``.
"""

from __future__ import annotations

import json
import sys
import time

from lib import cli
from lib.output import child_env, child_result, md_table, python_child, results_path, run_meta, write_json

CASES = [
    # (label, example, stages, h, steps, batch)
    ("knife edge, s = 5, h = 0.2", "knife-edge", 5, 0.2, 5000, None),
    ("sleigh, s = 5, h = 1", "sleigh", 5, 1.0, 1000, None),
    ("falling disk, s = 3, h = 0.05", "falling-disk-general", 3, 0.05, 2000, None),
    ("falling disk, s = 5, h = 0.05", "falling-disk-general", 5, 0.05, 2000, None),
    ("falling disk, s = 5, h = 0.25", "falling-disk-general", 5, 0.25, 2000, None),
    ("falling disk x 64 (vmap), s = 3, h = 0.05", "falling-disk-general", 3, 0.05, 300, 64),
]

CHILD = r"""
import json, sys
import numpy as np
import jax
import lobattodae as L
from lobattodae.examples import get_example
from lib.baselines import Diffrax
from lib.odes import reduced_ode
from lib.output import print_result
from lib.timing import best_of

out = {}
for label, name, s, h, n, batch in json.loads(sys.argv[1]):
    ex = get_example(name)
    m = L.LobattoIIIAIIIB(stages=s)
    run = lambda q, p, l: L.integrate(ex.problem, m, 0.0, h, n, q, p, l, ex.args, checkpoints=None)
    if batch is None:
        f, inputs = jax.jit(run), (ex.q0, ex.p0, ex.lam0)
    else:
        scale = 1.0 + 1e-3 * np.arange(batch)[:, None]
        q0, p0 = np.tile(ex.q0, (batch, 1)), np.tile(ex.p0, (batch, 1)) * scale
        lam0 = np.stack([np.asarray(L.consistent_lambda(ex.problem, 0.0, q, p, ex.lam0, ex.args)) for q, p in zip(q0, p0)])
        f, inputs = jax.jit(jax.vmap(run)), (q0, p0, lam0)
    out[label] = best_of(lambda: f(*inputs), 3, first=True).best / (n * (batch or 1))
ex = get_example("falling-disk-general")
dfx = Diffrax(reduced_ode("falling-disk-general", ex.args))
y0 = np.r_[ex.q0, ex.p0]
tm = best_of(lambda: dfx.final(100.0, y0, 1e-12, (0.0, 1.0)), 3, first=True)
out["diffrax Dopri8, falling disk (per step)"] = tm.best / tm.result[2]
print_result(out)
"""


def run_child(one_thread: bool) -> dict:
    r = child_result(python_child(CHILD, json.dumps(CASES)), child_env(no_cache=False, PJRT_NPROC="1" if one_thread
                                                                        else None, NPROC=None))
    if "error" in r:
        raise SystemExit(f"the child process failed: {r['error']}")
    return r


def main(argv=None) -> int:
    ap = cli.parser(__doc__)
    ap.add_argument("--rounds", type=int, default=3)
    a = ap.parse_args(argv)
    t0 = time.perf_counter()
    meta = run_meta()
    rounds: dict = {"default": [], "one thread": []}
    for r in range(a.rounds):
        for key, one in (("default", False), ("one thread", True)):
            rounds[key].append(run_child(one))
            print(f"round {r + 1}/{a.rounds}: {key} done", flush=True)
    best = {key: {label: min(rd[label] for rd in rs) for label in rs[0]} for key, rs in rounds.items()}
    rows = []
    for label in best["default"]:
        d, o = best["default"][label], best["one thread"][label]
        rows.append([label, f"{1e6 * d:.1f}", f"{1e6 * o:.1f}", f"{d / o:.2f}"])
    print(md_table(["case (µs per step)", "default pool", "one thread", "default / one thread"], rows))
    write_json({**meta, "seconds": time.perf_counter() - t0, "rounds": rounds, "best_s_per_step": best},
               results_path("cpu_threads.json"))
    return 0


if __name__ == "__main__":
    sys.exit(main())
