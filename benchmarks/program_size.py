"""The size of the compiled step program against s and n, and its compile time (issue #26, item 1).

One error-controlled attempt is what every adaptive run compiles at its core (step doubling:
the whole step and two half steps of the method, one traced step in a ``lax.scan``). For each
case this script lowers ``method.step`` of that attempt, compiles it, and records

* the StableHLO text size (what JAX hands to XLA),
* the optimised HLO: instructions, fusions (each a kernel XLA:CPU generates code for, and
  launches at run time) and copies,
* the compile time (XLA only; tracing and lowering apart),

with the XLA options the library compiles with (``lobattodae.compiler_options()``).

The counts are deterministic (the same on every machine with the same jax); the compile time
depends on the machine and its load: compare ratios within one run. Cases: the Chaplygin sleigh
(n = 3, m = 1) for s = 2..8, and the nonholonomic particle chain (n = 3 N_p, m = N_p) for
N_p = 2..20 at s = 3. Run from the repository root::

    PYTHONPATH=src .venv/bin/python benchmarks/program_size.py --pin-cpu 0    # ~5 min
    PYTHONPATH=src .venv/bin/python benchmarks/program_size.py --quick
"""

from __future__ import annotations

import os
import re
import time

os.environ.setdefault("LOBATTODAE_NO_CACHE", "1")  # compile every program, never read a cache

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

import lobattodae as L  # noqa: E402
from lib import cli  # noqa: E402
from lib.output import log, md_table, results_path, run_meta, write_json  # noqa: E402
from lib.problems import particle_chain  # noqa: E402
from lobattodae._compile import jit  # noqa: E402
from lobattodae._doubling import for_error_control  # noqa: E402

JSON_PATH = results_path("program_size.json")
QUICK_JSON_PATH = results_path("program_size_quick.json")
STAGES = (2, 3, 4, 5, 6, 8)
PARTICLES = (2, 5, 10, 20)


def _counts(hlo: str) -> dict:
    return {
        "instructions": sum(1 for line in hlo.splitlines() if re.match(r"\s+(ROOT )?%?[\w.\-]+ = ", line)),
        "fusions": len(re.findall(r"= \S+ fusion\(", hlo)),
        "copies": len(re.findall(r"= \S+ copy\(", hlo)),
    }


def measure(problem, q0, p0, args, stages: int) -> dict:
    """Lower and compile one error-controlled attempt of ``stages`` stages from ``(q0, p0)``."""
    q0, p0 = jnp.asarray(q0, jnp.float64), jnp.asarray(p0, jnp.float64)
    lam0 = L.consistent_lambda(problem, 0.0, q0, p0, jnp.zeros(problem.phi(0.0, q0, p0, args).shape[0]), args)
    method = for_error_control(L.LobattoIIIAIIIB(stages=stages), L.PIController())
    state = method.init(problem, 0.0, q0, p0, lam0, args, 0.01)

    def attempt(state, h):
        return method.step(problem, 0.0, q0, p0, lam0, h, args, state)

    t = time.perf_counter()
    lowered = jit(attempt).lower(state, 0.01)  # compiled as the library compiles (lobattodae._compile)
    trace = time.perf_counter() - t
    t = time.perf_counter()
    compiled = lowered.compile()
    compile_s = time.perf_counter() - t
    return {"s": stages, "n": int(q0.size), "m": int(lam0.size), "stablehlo_kB": len(lowered.as_text()) / 1e3,
            **_counts(compiled.as_text()), "trace_s": trace, "compile_s": compile_s}


def main() -> None:
    ap = cli.parser(__doc__, "quick", "pin_cpu")
    args = cli.start(ap.parse_args())
    stages, particles = ((2, 4, 8), (2, 10)) if args.quick else (STAGES, PARTICLES)
    jax.jit(lambda x: x + 1.0)(np.zeros(1))  # JAX's own start-up, outside the first measurement
    sleigh = L.examples.get_example("sleigh")
    rows = []
    for s in stages:
        rows.append({"case": "sleigh", **measure(sleigh.problem, sleigh.q0, sleigh.p0, sleigh.args, s)})
        log(f"sleigh s={s}: {rows[-1]}")
    for k in particles:
        problem, q0, p0, pargs = particle_chain(k)
        rows.append({"case": f"chain N_p={k}", **measure(problem, q0, p0, pargs, 3)})
        log(f"chain N_p={k}: {rows[-1]}")
    table = md_table(["case", "s", "n", "m", "StableHLO kB", "HLO instructions", "fusions", "copies", "compile s"],
                     [[r["case"], r["s"], r["n"], r["m"], f"{r['stablehlo_kB']:.0f}", r["instructions"], r["fusions"],
                       r["copies"], f"{r['compile_s']:.2f}"] for r in rows])
    print(table)
    write_json({"meta": run_meta(), "rows": rows}, QUICK_JSON_PATH if args.quick else JSON_PATH)


if __name__ == "__main__":
    main()
