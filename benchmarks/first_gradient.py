"""The first gradient through ``integrate`` against the first forward call, and the gradient
against the forward solve (issue #26's targets: at most 2x and 3x).

The knife edge, s = 4, 200 constant steps of h = 0.05 from initial momenta projected from a
parameter (``project_momenta``, ``consistent_lambda``); the loss is ``Σ q_N²``, differentiated
with respect to p0 with the default ``checkpoints="auto"``. Each of the two (forward, gradient)
runs in a fresh process without the persistent compilation cache, ``--repeats`` times
alternating: the first call (tracing and compilation included), then the best of 5 calls.

    PYTHONPATH=src python benchmarks/first_gradient.py --pin-cpu 1
"""

from __future__ import annotations

import sys

from lib import cli
from lib.output import child_env, child_result, log, md_table, python_child, results_path, run_meta, write_json

CHILD = r"""
import sys, time
import jax, jax.numpy as jnp
import lobattodae as L
from lib.output import print_result
L.set_cpu_threads(1)
ex = L.examples.get_example("knife-edge")
method = L.LobattoIIIAIIIB(stages=4)
q0 = jnp.asarray(ex.q0)
def loss(p):
    p0 = L.project_momenta(ex.problem, 0.0, q0, p, ex.args)
    lam0 = L.consistent_lambda(ex.problem, 0.0, q0, p0, jnp.asarray(ex.lam0), ex.args)
    return jnp.sum(L.integrate(ex.problem, method, 0.0, 0.05, 200, q0, p0, lam0, ex.args).q[-1] ** 2)
f = jax.jit(loss) if sys.argv[1] == "forward" else jax.jit(jax.grad(loss))
p = jnp.asarray(ex.p0)
start = time.perf_counter()
jax.block_until_ready(f(p))
first = time.perf_counter() - start
best = float("inf")
for k in range(5):
    start = time.perf_counter()
    jax.block_until_ready(f(p * (1 + 1e-4 * (k + 1))))
    best = min(best, time.perf_counter() - start)
print_result({"first_call_s": first, "call_ms": 1e3 * best})
"""


def main(argv=None) -> int:
    ap = cli.parser(__doc__, "pin_cpu")
    ap.add_argument("--repeats", type=int, default=2)
    ns = cli.start(ap.parse_args(argv))  # the children inherit the CPU affinity
    runs = {"forward": [], "gradient": []}
    for _ in range(ns.repeats):
        for kind in runs:
            r = child_result(python_child(CHILD, kind), child_env())
            if "error" in r:
                log(f"{kind}: {r['error']}")
                return 1
            runs[kind].append(r)
    fwd, grad = (min(r["first_call_s"] for r in runs[k]) for k in runs)
    fwd_ms, grad_ms = (min(r["call_ms"] for r in runs[k]) for k in runs)
    log(md_table(["", "forward", "gradient", "ratio"],
                 [["first call, s", f"{fwd:.2f}", f"{grad:.2f}", f"{grad / fwd:.2f} (target ≤ 2)"],
                  ["after compilation, ms", f"{fwd_ms:.2f}", f"{grad_ms:.2f}", f"{grad_ms / fwd_ms:.2f} (target ≤ 3)"]]))
    write_json({**run_meta(repeats=ns.repeats), "runs": runs}, results_path("first_gradient") + ".json")
    return 0


if __name__ == "__main__":
    sys.exit(main())
