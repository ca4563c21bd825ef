"""First result in a fresh process: import, compilation and run, as a new user meets them.

Each case runs ``--repeats`` times in a new interpreter pinned to one CPU (``--cpu``, default 0;
``taskset``, when available), with one XLA thread, and prints the wall time from before ``import lobattodae`` to
the result:

* ``knife-edge``: the knife edge, s = 4, adaptive (rtol = atol = 1e-8), to the end of its span;
* ``falling-disk``: the falling disk, s = 4, adaptive (rtol = atol = 1e-8), to the end of its span;
* ``andrews``: Andrews' squeezer (7 bodies, 6 holonomic constraints; the external test set),
  s = 5, adaptive (rtol = atol = 1e-8), to t = 0.03;
* ``bicycle``: the Whipple bicycle at 5 m/s, s = 4, 1000 constant steps over 10 s (the time
  after the model is built; SymPy and code generation are timed apart);
* ``dopri8-knife-edge``, ``dopri8-andrews``: diffrax's Dopri8 (PID, jitted, as
  ``benchmarks/lib/baselines.py`` sets it up) on the index-1 form of the same problems, at the
  same tolerance, for scale: the time from ``import diffrax`` to its first result;
* ``sleigh-event``: the sleigh, s = 4, adaptive, with a heading event (then, in the same
  process, the same run without the event: the second compilation alone).
* ``output-options``: the sleigh, s = 4, adaptive, then in the same process the same run with
  each output option in turn (``t_eval`` of 50 and 500 times, stepped onto and interpolated,
  ``dense_output``, ``save_every``): the time of each first call, compilation included.

``--cache cold`` (default) runs with ``LOBATTODAE_NO_CACHE=1``; ``--cache warm`` uses a
persistent compilation cache in a temporary directory, filled by one run first.
``--src DIR`` runs another checkout's ``src`` (e.g. a ``git worktree`` of an earlier commit), so
that before and after are measured in one session, alternating.

Run from the repository root::

    .venv/bin/python benchmarks/first_result.py                       # ~1 min
    .venv/bin/python benchmarks/first_result.py --src /tmp/old/src --src src
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile

#: diffrax's first result on a problem's index-1 ODE (``setup`` defines ode, t_end, q0, p0).
DOPRI8 = """
import sys; sys.path.insert(0, "benchmarks")
{setup}
t1 = time.perf_counter()
from lib.baselines import Diffrax
y, nacc, nsteps, ok = Diffrax(ode).final(t_end, ode.from_qp(q0, p0), 1e-8)
assert ok
print(f"Dopri8 first result {{time.perf_counter() - t1:.2f}} s (import diffrax + compile + run)")
"""
CASES = {
    "knife-edge": """
ex = L.examples.get_example("knife-edge")
sol = L.solve(ex.problem, L.LobattoIIIAIIIB(stages=4), ex.t_span, ex.q0, ex.p0, args=ex.args, rtol=1e-8, atol=1e-8)
print(f"first result {time.perf_counter() - t0:.2f} s")
""",
    "falling-disk": """
ex = L.examples.get_example("falling-disk")
sol = L.solve(ex.problem, L.LobattoIIIAIIIB(stages=4), ex.t_span, ex.q0, ex.p0, args=ex.args, rtol=1e-8, atol=1e-8)
print(f"first result {time.perf_counter() - t0:.2f} s")
""",
    "andrews": """
import sys; sys.path.insert(0, "benchmarks")
from testset import andrews
S = andrews.build()
t1 = time.perf_counter()
sol = L.solve(S.problem, L.LobattoIIIAIIIB(stages=5), S.t_span, S.q0, S.p0, args=S.args, rtol=1e-8, atol=1e-8)
print(f"first result {time.perf_counter() - t0:.2f} s (solve {time.perf_counter() - t1:.2f} s)")
""",
    "bicycle": """
from lobattodae.mechanics import bicycle as bike
model = bike.whipple_bicycle()
args = model.args()
q0, p0 = bike.upright_state(model, 5.0, args, roll_rate=0.5)
t1 = time.perf_counter()
sol = L.solve(model.problem, L.LobattoIIIAIIIB(stages=4), (0.0, 10.0), q0, p0, n_steps=1000, args=args)
print(f"first result {time.perf_counter() - t1:.2f} s after the model (import and model {t1 - t0:.2f} s)")
""",
    "dopri8-knife-edge": DOPRI8.format(setup="""
from lib.odes import knife_edge
ex = L.examples.get_example("knife-edge")
ode, t_end, q0, p0 = knife_edge(ex.args), ex.t_span[1], ex.q0, ex.p0"""),
    "dopri8-andrews": DOPRI8.format(setup="""
from lib.odes import andrews as andrews_ode
from testset import andrews
S = andrews.build()
ode, t_end, q0, p0 = andrews_ode(andrews.PROBLEM), S.t_span[1], S.q0, S.p0"""),
    "sleigh-event": """
ex = L.examples.get_example("sleigh")
def heading(t, q, p, args): return q[2] - 0.5
sol = L.solve(ex.problem, L.LobattoIIIAIIIB(stages=4), ex.t_span, ex.q0, ex.p0, args=ex.args, rtol=1e-8, atol=1e-8,
              events=heading)
t1 = time.perf_counter()
sol = L.solve(ex.problem, L.LobattoIIIAIIIB(stages=4), ex.t_span, ex.q0, ex.p0, args=ex.args, rtol=1e-8, atol=1e-8)
print(f"with the event {t1 - t0:.2f} s, then without it {time.perf_counter() - t1:.2f} s")
""",
    "output-options": """
import numpy as np
ex = L.examples.get_example("sleigh")
(a, b), m = ex.t_span, L.LobattoIIIAIIIB(stages=4)
times, first = [], None
for kw in ({}, {"t_eval": np.linspace(a, b, 50)}, {"t_eval": np.linspace(a, b, 500)},
           {"t_eval": np.linspace(a, b, 50), "t_eval_rows": "interpolate"}, {"dense_output": True},
           {"save_every": 10}, {"save_every": "final"}):
    t1 = time.perf_counter()
    sol = L.solve(ex.problem, m, ex.t_span, ex.q0, ex.p0, args=ex.args, rtol=1e-8, atol=1e-8, **kw)
    times.append(time.perf_counter() - t1)
    first = first or time.perf_counter() - t0
print(f"first result {first:.2f} s; then t_eval 50, 500, interpolated, dense_output, "
      f"save_every 10, 'final': " + ", ".join(f"{x:.2f}" for x in times[1:]) + f" s; all {time.perf_counter() - t0:.2f} s")
""",
}
PREAMBLE = "import time; t0 = time.perf_counter()\nimport lobattodae as L\nL.set_cpu_threads(1)\n"


def run(case: str, src: str, env: dict, cpu: int = 0) -> str:
    pin = ["taskset", "-c", str(cpu)] if shutil.which("taskset") else []
    proc = subprocess.run([*pin, sys.executable, "-c", PREAMBLE + CASES[case]], capture_output=True, text=True,
                          env={**env, "PYTHONPATH": os.path.abspath(src)}, timeout=600)
    if proc.returncode:
        raise SystemExit(proc.stderr)
    return proc.stdout.strip()


def environment(base: dict, cache: str, warm: bool, src: str) -> dict:
    """The child's environment: no persistent cache, or one of its own per source tree."""
    if warm:
        return dict(base, LOBATTODAE_CACHE_DIR=os.path.join(cache, os.path.abspath(src).strip("/")))
    return dict(base, LOBATTODAE_NO_CACHE="1")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--case", choices=sorted(CASES), nargs="+", default=sorted(CASES))
    parser.add_argument("--src", action="append", help="the src directory to import (repeatable; default src)")
    parser.add_argument("--cache", choices=("cold", "warm"), default="cold")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--cpu", type=int, default=0, help="the CPU every child process is pinned to")
    opts = parser.parse_args()
    sources = opts.src or ["src"]
    warm = opts.cache == "warm"
    base = {k: v for k, v in os.environ.items() if k not in ("LOBATTODAE_NO_CACHE", "LOBATTODAE_CACHE_DIR")}
    with tempfile.TemporaryDirectory() as cache:
        for case in opts.case:
            if warm:
                for src in sources:
                    run(case, src, environment(base, cache, warm, src), opts.cpu)  # fills the cache
            for _ in range(opts.repeats):  # alternating between the sources
                for src in sources:
                    print(f"{case:<13} {src:<20} {opts.cache}: {run(case, src, environment(base, cache, warm, src), opts.cpu)}")


if __name__ == "__main__":
    main()
