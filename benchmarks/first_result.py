"""First result in a fresh process: import, compilation and run, as a new user meets them.

Each case runs ``--repeats`` times in a new interpreter pinned to one CPU (``--pin-cpu``, default
0), with one XLA thread (``--all-cpus``: on every CPU, with XLA's default threads, as a user's
process runs; XLA then compiles a program's kernels in parallel), and prints the wall time from before ``import lobattodae`` to the
result, and where it went: the imports (jax and lobattodae), and JAX's three compilation phases
summed over the process's programs (tracing to a jaxpr, lowering to StableHLO, XLA's compilation;
from ``jax.monitoring``):

* ``knife-edge``: the knife edge, s = 4, adaptive (rtol = atol = 1e-8), to the end of its span;
* ``falling-disk``: the falling disk, s = 4, adaptive (rtol = atol = 1e-8), to the end of its span;
* ``native-knife-edge``, ``native-falling-disk``: the same runs of the problems' twins written
  with ``lobattodae.mechanics`` (``mechanics.systems.knife_edge()``, ``falling_disk()``), natively
  (``model.native(4).solve``: the model built, its C generated and compiled, each attempt a native
  call; with ``--cache cold`` the compiled library is not kept either);
* ``andrews``: Andrews' squeezer (7 bodies, 6 holonomic constraints; the external test set),
  s = 5, adaptive (rtol = atol = 1e-8), to t = 0.03; ``native-andrews``: the same run of its
  twin written with ``lobattodae.mechanics`` (``testset.andrews.model()``), natively;
* ``bicycle``: the Whipple bicycle at 5 m/s, s = 4, 1000 constant steps over 10 s (the time
  after the model is built; SymPy and code generation are timed apart);
* ``models``: building the knife edge, the falling disk, Andrews' squeezer (its Lagrangian twin)
  and the Whipple bicycle with ``lobattodae.mechanics`` (each the user's SymPy and
  ``from_lagrangian``; with ``--cache warm`` the derivation comes from the model cache);
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

    .venv/bin/python benchmarks/first_result.py                       # ~4 min
    .venv/bin/python benchmarks/first_result.py --src /tmp/old/src --src src
"""

from __future__ import annotations

import os
import sys
import tempfile

from lib import cli
from lib.output import BENCHMARKS, child_env, child_result, python_child

#: diffrax's first result on a problem's index-1 ODE (``setup`` defines ode, t_end, q0, p0).
DOPRI8 = """
import sys; sys.path.insert(0, "benchmarks")
{setup}
t1 = time.perf_counter()
from lib.baselines import Diffrax
y, nacc, nsteps, ok = Diffrax(ode).final(t_end, ode.from_qp(q0, p0), 1e-8)
assert ok
done(f"Dopri8 first result {{time.perf_counter() - t1:.2f}} s (import diffrax + compile + run)")
"""
CASES = {
    "knife-edge": """
ex = L.examples.get_example("knife-edge")
sol = L.solve(ex.problem, L.LobattoIIIAIIIB(stages=4), ex.t_span, ex.q0, ex.p0, args=ex.args, rtol=1e-8, atol=1e-8)
done(f"first result {time.perf_counter() - t0:.2f} s")
""",
    "falling-disk": """
ex = L.examples.get_example("falling-disk")
sol = L.solve(ex.problem, L.LobattoIIIAIIIB(stages=4), ex.t_span, ex.q0, ex.p0, args=ex.args, rtol=1e-8, atol=1e-8)
done(f"first result {time.perf_counter() - t0:.2f} s")
""",
    "native-knife-edge": """
from lobattodae import mechanics
ex = L.examples.get_example("knife-edge")
model = mechanics.systems.knife_edge()
sol = model.native(4).solve(ex.t_span, ex.q0, ex.p0, args=model.args(**ex.args._asdict()), rtol=1e-8, atol=1e-8)
done(f"first result {time.perf_counter() - t0:.2f} s")
""",
    "native-falling-disk": """
from lobattodae import mechanics
ex = L.examples.get_example("falling-disk")
model = mechanics.systems.falling_disk()
sol = model.native(4).solve(ex.t_span, ex.q0, ex.p0, args=model.args(**ex.args._asdict()), rtol=1e-8, atol=1e-8)
done(f"first result {time.perf_counter() - t0:.2f} s")
""",
    "andrews": """
import sys; sys.path.insert(0, "benchmarks")
from testset import andrews
S = andrews.build()
t1 = time.perf_counter()
sol = L.solve(S.problem, L.LobattoIIIAIIIB(stages=5), S.t_span, S.q0, S.p0, args=S.args, rtol=1e-8, atol=1e-8)
done(f"first result {time.perf_counter() - t0:.2f} s (solve {time.perf_counter() - t1:.2f} s)")
""",
    "native-andrews": """
import sys; sys.path.insert(0, "benchmarks")
from testset import andrews
t1 = time.perf_counter()
model = andrews.model()
S = andrews.build()
t2 = time.perf_counter()
sol = L.solve(model.problem, model.native(5), S.t_span, S.q0, S.p0, args=model.args(**andrews.PARAMS), rtol=1e-8,
              atol=1e-8)
done(f"first result {time.perf_counter() - t0:.2f} s (model {t2 - t1:.2f} s, then C and solve {time.perf_counter() - t2:.2f} s)")
""",
    "models": """
import sys; sys.path.insert(0, "benchmarks")
from lobattodae import mechanics
from lobattodae.mechanics import bicycle as bike
from testset import andrews
times = []
for name, build in (("knife edge", mechanics.systems.knife_edge), ("falling disk", mechanics.systems.falling_disk),
                    ("Andrews", andrews.model), ("bicycle", bike.whipple_bicycle)):
    t1 = time.perf_counter()
    build()
    times.append(f"{name} {time.perf_counter() - t1:.2f}")
done("models built (SymPy and lobattodae.mechanics, after the imports): " + ", ".join(times) + " s")
""",
    "bicycle": """
from lobattodae.mechanics import bicycle as bike
model = bike.whipple_bicycle()
args = model.args()
q0, p0 = bike.upright_state(model, 5.0, args, roll_rate=0.5)
t1 = time.perf_counter()
PHASES.clear()  # the model's own compilations (its mass matrix, the initial state) are not the solve's
sol = L.solve(model.problem, L.LobattoIIIAIIIB(stages=4), (0.0, 10.0), q0, p0, n_steps=1000, args=args)
done(f"first result {time.perf_counter() - t1:.2f} s after the model (import and model {t1 - t0:.2f} s)")
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
done(f"with the event {t1 - t0:.2f} s, then without it {time.perf_counter() - t1:.2f} s")
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
done(f"first result {first:.2f} s; then t_eval 50, 500, interpolated, dense_output, "
     f"save_every 10, 'final': " + ", ".join(f"{x:.2f}" for x in times[1:]) + f" s; all {time.perf_counter() - t0:.2f} s")
""",
}
#: Every child starts with this: the clock, a listener for JAX's compilation phases, the imports.
PREAMBLE = """
import time; t0 = time.perf_counter()
import collections
import sys
import jax.monitoring
PHASES = collections.Counter()
_PHASE = {"/jax/core/compile/jaxpr_trace_duration": "trace", "/jax/core/compile/jaxpr_to_mlir_module_duration": "lower",
          "/jax/core/compile/backend_compile_duration": "xla"}
jax.monitoring.register_event_duration_secs_listener(
    lambda name, secs, **kw: PHASES.update({_PHASE[name]: secs}) if name in _PHASE else None)
import lobattodae as L
if "--all-cpus" not in sys.argv:
    L.set_cpu_threads(1)
IMPORTS = time.perf_counter() - t0
from lib.output import print_result
def done(text):
    print_result({"text": text, "imports": IMPORTS, **{k: PHASES[k] for k in ("trace", "lower", "xla")}})
"""


def run(case: str, src: str, cache: str | None, all_cpus: bool = False) -> str:
    """One fresh process of ``case`` with the lobattodae of ``src``: its line, and where the time went."""
    root = os.path.dirname(BENCHMARKS)
    warm = {} if cache is None else {  # a persistent cache of its own per source tree
        "LOBATTODAE_NO_CACHE": None, "LOBATTODAE_CACHE_DIR": os.path.join(cache, os.path.abspath(src).strip("/"))}
    env = child_env(no_cache=cache is None, PYTHONPATH=os.pathsep.join([os.path.abspath(src), root, BENCHMARKS]), **warm)
    r = child_result(python_child(PREAMBLE + CASES[case], *(["--all-cpus"] if all_cpus else [])), env, timeout=600)
    if "error" in r:
        sys.exit(f"{case} with {src}: {r['error']}")
    return (f"{r['text']}  [imports {r['imports']:.2f}, tracing {r['trace']:.2f}, lowering {r['lower']:.2f}, "
            f"XLA {r['xla']:.2f} s]")


def main() -> None:
    parser = cli.parser(__doc__, "pin_cpu", pin_cpu={"default": 0})
    parser.add_argument("--case", choices=sorted(CASES), nargs="+", default=sorted(CASES))
    parser.add_argument("--src", action="append", help="the src directory to import (repeatable; default src)")
    parser.add_argument("--cache", choices=("cold", "warm"), default="cold")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--all-cpus", action="store_true",
                        help="run the children on every CPU with XLA's default threads (no --pin-cpu)")
    opts = parser.parse_args()
    if opts.all_cpus:
        opts.pin_cpu = None
    opts = cli.start(opts)  # the children inherit the CPU
    sources = opts.src or ["src"]
    with tempfile.TemporaryDirectory() as tmp:
        cache = tmp if opts.cache == "warm" else None
        for case in opts.case:
            if cache is not None:
                for src in sources:
                    run(case, src, cache, opts.all_cpus)  # fills the cache
            for _ in range(opts.repeats):  # alternating between the sources
                for src in sources:
                    print(f"{case:<13} {src:<20} {opts.cache}: {run(case, src, cache, opts.all_cpus)}", flush=True)


if __name__ == "__main__":
    main()
