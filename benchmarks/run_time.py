"""Run time of one `solve` per problem once compiled, and what its Newton solves did.

Each case is solved once (compilation), then ``--repeats`` times; the best wall time is
printed with the steps, rejections, Newton iterations and Newton matrices (Jacobian
evaluations) of the run:

* ``knife-edge``: s = 4, adaptive (rtol = atol = 1e-8), T = 1000;
* ``falling-disk``: s = 5, adaptive, T = 100;
* ``sleigh``: s = 6, adaptive, T = 1000;
* ``andrews``: Andrews' squeezer (the external test set), s = 5, adaptive, to t = 0.03;
* ``crank``: the flexible slider crank (the external test set), s = 6, adaptive, to t = 0.1;
* ``bicycle``: the Whipple bicycle at 5 m/s, s = 4, 1000 constant steps over 10 s;
* ``native-sleigh``: the sleigh as a ``lobattodae.mechanics`` model natively
  (``model.native(5)``), adaptive, T = 1000; ``native-andrews``: Andrews' squeezer's Lagrangian
  twin natively (``model.native(4)``), adaptive, to t = 0.03;
* ``native-sleigh-start``, ``native-andrews-start``: the same runs over one step (T = 1e-3,
  1e-7): what every ``solve`` costs before and after its steps (validation, the compiled call,
  the ``Solution``).

Every case runs in a new interpreter with one XLA thread, pinned with this process to one CPU
(``--pin-cpu``); ``--src DIR`` (repeatable) imports another checkout's ``src``, alternating, so
that before and after are measured in one session::

    .venv/bin/python benchmarks/run_time.py --pin-cpu 1 --src /tmp/old/src --src src --rounds 2
"""

from __future__ import annotations

import os
import sys

from lib import cli
from lib.output import BENCHMARKS, child_env, child_result, python_child

CHILD = r"""
import sys, time
import lobattodae as L
from lib.output import print_result
L.set_cpu_threads(1)

def build(case):
    if case in ("andrews", "crank"):
        import importlib
        S = importlib.import_module("testset." + case).build()
        return S.problem, S.q0, S.p0, S.args, S.t_span, {"andrews": 5, "crank": 6}[case], dict(rtol=1e-8, atol=1e-8)
    if case.startswith("native-"):
        if case.startswith("native-andrews"):
            from testset import andrews
            S = andrews.build()
            model, args = andrews.PROBLEM.mechanics()
            q0, p0, t_end, s = S.q0, S.p0, 0.03, 4
        else:
            from native_step import pairs
            ex, model, args = pairs()["sleigh"]
            q0, p0, t_end, s = ex.q0, ex.p0, 1000.0, 5
        if case.endswith("-start"):
            t_end = 1e-7 if "andrews" in case else 1e-3
        return model.problem, q0, p0, args, (0.0, t_end), model.native(s), dict(rtol=1e-8, atol=1e-8)
    if case == "bicycle":
        from lobattodae.mechanics import bicycle as bike
        model = bike.whipple_bicycle()
        args = model.args()
        q0, p0 = bike.upright_state(model, 5.0, args, roll_rate=0.5)
        return model.problem, q0, p0, args, (0.0, 10.0), 4, dict(n_steps=1000)
    s, t_end = {"knife-edge": (4, 1000.0), "falling-disk": (5, 100.0), "sleigh": (6, 1000.0)}[case]
    ex = L.examples.get_example(case)
    return ex.problem, ex.q0, ex.p0, ex.args, (ex.t_span[0], t_end), s, dict(rtol=1e-8, atol=1e-8)

case, repeats = sys.argv[1], int(sys.argv[2])
problem, q0, p0, args, span, s, kw = build(case)
method = L.LobattoIIIAIIIB(stages=s) if isinstance(s, int) else s  # or a model's native integrator
s = method.stages
run = lambda: L.solve(problem, method, span, q0, p0, args=args, save_every="final", **kw)  # noqa: E731
sol = run()
times = []
for _ in range(repeats):
    t = time.perf_counter()
    sol = run()
    times.append(time.perf_counter() - t)
st = sol.stats
print_result({"s": s, "ms": 1e3 * min(times), "steps": int(st["n_steps"]), "rejected": int(st["n_rejected"]),
              "newton": int(st["n_newton"]), "matrices": int(st["n_jacobians"])})
"""
CASES = ("knife-edge", "falling-disk", "sleigh", "andrews", "crank", "bicycle", "native-sleigh", "native-andrews",
         "native-sleigh-start", "native-andrews-start")


def main() -> None:
    parser = cli.parser(__doc__, "pin_cpu", pin_cpu={"default": 1})
    parser.add_argument("--case", choices=CASES, nargs="+", default=list(CASES))
    parser.add_argument("--src", action="append", help="the src directory to import (repeatable; default src)")
    parser.add_argument("--repeats", type=int, default=5, help="timed solves per process (the best is printed)")
    parser.add_argument("--rounds", type=int, default=1, help="processes per case and source, alternating")
    opts = cli.start(parser.parse_args())  # the children inherit the CPU
    root = os.path.dirname(BENCHMARKS)
    for case in opts.case:
        for _ in range(opts.rounds):
            for src in opts.src or ["src"]:
                env = child_env(no_cache=False, PYTHONPATH=os.pathsep.join([os.path.abspath(src), root, BENCHMARKS]))
                r = child_result(python_child(CHILD, case, str(opts.repeats)), env, timeout=1200)
                if "error" in r:
                    sys.exit(f"{case} with {src}: {r['error']}")
                print(f"{case:<21} {src:<20} s={r['s']} run {r['ms']:8.2f} ms  steps {r['steps']} rejected "
                      f"{r['rejected']} newton {r['newton']} matrices {r['matrices']}", flush=True)


if __name__ == "__main__":
    main()
