"""What error control costs on the test set's mechanisms, against an estimate that costs nothing.

Issue #25 item 5 asks adaptive runs of the suite's multibody mechanisms to be no slower than
diffrax's Dopri8 at the same achieved error. Step doubling, the estimate the library keeps (each
attempt a whole step and two half steps, the halves kept), costs three stage solves per step of
size h. This script asks how much of the gap to Dopri8 that cost is, on each problem of the test
set that has a ``lobattodae.mechanics`` model (natively, ``model.native(s)``):

* **adaptive**: ``solve(model.problem, model.native(s), rtol=tol, atol=tol)``, as ``testset_wp.py``
  runs it;
* **oracle**: the same run's kept half steps replayed as given steps (its ``t_eval`` rows, which
  the adaptive run stepped onto, are step points of the replay too), one stage solve each, with
  no estimate at all (the method as error control runs it: ``lam_start="consistent"``, the same
  native single step that the loop's other controllers take). Its error is the adaptive run's
  (the same steps; they differ by Newton's tolerance), its time the least that *any* error
  estimate could give with these steps: what is left of the gap to Dopri8 is the stage solve's
  own cost, not the estimate's. A replayed step whose stage solve fails (the adaptive run had
  retried that attempt smaller) is taken again as two halves;
* **Dopri8**: ``benchmarks/lib/baselines.Diffrax`` on the problem's index-1 ODE, as ``testset_wp.py``.

Each at tolerances in half decades around the target error (Dopri8 over a wider range); each run
is timed once per round, all runs in every round (the best of the rounds: a load that drifts
weighs on all alike); the time at the target error is interpolated on each Pareto front
(``lib.sweeps.time_at``), and the ratios come from one run.

The replay is not a public controller: the script hands ``solve`` a controller of its own
through two of the library's private hooks (``AdaptiveSteps.check_controller`` and
``for_error_control``), so it measures the library's own loop and native step with nothing else
changed.

    PYTHONPATH=src .venv/bin/python benchmarks/oracle_steps.py --pin-cpu 1 --cpu-threads 1
    PYTHONPATH=src .venv/bin/python benchmarks/oracle_steps.py --problems andrews --stages 4 5
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

import lobattodae as L
from lib import cli
from lib.baselines import Diffrax
from lib.odes import testset_ode
from lib.output import fmt, log, md_table, merged, results_path, run_meta, write_json
from lib.sweeps import half_decades, time_at
from lib.timing import best_of
from testset import PROBLEMS, error
from testset_wp import _output_plan

TARGET = 1e-8
#: Problems of the test set with a ``lobattodae.mechanics`` model; the slider crank (1.3 s per
#: solve) only when asked for.
DEFAULT_PROBLEMS = ("andrews", "fourbar", "rolling-disc")


# ------------------------------------------------------------------------------------ the replay
class _Replay(NamedTuple):
    k: jax.Array  # the next grid time to reach is grid[k + 1]
    t: jax.Array
    halvings: jax.Array  # of the current grid step, after failed stage solves
    t_end: jax.Array


@dataclass(frozen=True)
class GivenSteps:
    """Steps onto the times of ``grid`` (increasing, from t0 to t1), in the controller protocol
    of the library's loop (:class:`lobattodae._controllers.ConstantStepSize`'s methods). A step
    whose stage solve fails is taken again as halves until it is through."""

    grid: tuple
    ends_on_rejection = False

    def _at(self, k):
        return jnp.asarray(self.grid)[jnp.minimum(k, len(self.grid) - 1)]

    def init(self, problem, method, t0, t1, q0, p0, lam0, args, options):
        return _Replay(jnp.asarray(0, jnp.int32), t0, jnp.asarray(0, jnp.int32), t1)

    def time(self, st):
        return st.t

    def proposal(self, st):
        end = self._at(st.k + 1)
        return st.t, jnp.minimum(end - st.t, (end - self._at(st.k)) / 2.0 ** st.halvings)

    def adapt(self, st, problem, args, report):
        ok = report.ok
        end = self._at(st.k + 1)
        t = jnp.where(ok, report.t + report.h, st.t)
        reached = ok & (jnp.abs(t - end) <= 1e-14 * jnp.abs(end))
        new = st._replace(k=st.k + reached.astype(jnp.int32), t=jnp.where(reached, end, t),
                          halvings=jnp.where(reached, 0, st.halvings + (~ok).astype(jnp.int32)))
        result = jnp.where(st.halvings > 30, L.Result.STEP_SIZE_TOO_SMALL, L.Result.SUCCESSFUL).astype(jnp.int32)
        return ok, new, result

    def done(self, st):
        return st.k >= len(self.grid) - 1

    def stop_at(self, st, t_stop):
        return st._replace(t_end=t_stop)


def _admit_replays():
    """Let ``solve`` take :class:`GivenSteps` (private hooks; see the module docstring): the
    controller check passes it, and the method runs single native steps under it."""
    from lobattodae import _options, _solve

    check, adapt = _options.AdaptiveSteps.check_controller, _solve.for_error_control

    def check_controller(controller):
        return controller if isinstance(controller, GivenSteps) else check(controller)

    def for_error_control(method, controller, problem=None, *, native=False):
        if isinstance(controller, GivenSteps):
            return method.single(method.method, problem)
        return adapt(method, controller, problem, native=native)

    _options.AdaptiveSteps.check_controller = staticmethod(check_controller)
    _solve.for_error_control = for_error_control


# ------------------------------------------------------------------------------------ the sweeps
def run_problem(name: str, stages, tols, dopri8_tols, repeats: int) -> dict:
    """Every run of ``name`` once (compiling; errors and counters), then ``repeats`` rounds in
    which each run is timed once, in the same order: each time is the best of its rounds, and the
    machine's load, which drifts over minutes, weighs on all of them alike."""
    entry = PROBLEMS[name]
    setup = entry.build()
    model, args = entry.mechanics()
    ts, final = _output_plan(entry, setup)  # the times the error is measured at, as testset_wp.py
    kw = {"save_every": "final"} if final else {"t_eval": ts}
    p0 = setup.p0 if entry.mechanics_momenta is None else entry.mechanics_momenta[0](setup.t_span[0], setup.q0,
                                                                                     setup.p0)

    def err(sol):
        if not sol.success:
            return math.inf
        t, q, p = np.asarray(sol.t), np.asarray(sol.q), np.asarray(sol.p)
        if entry.mechanics_momenta is not None:
            p = entry.mechanics_momenta[1](t, q, p)
        return float(error(entry, t, q, p))

    runs = {}  # (label, tol) -> (callable, row)
    for s in stages:
        adaptive, oracle = model.native(s), model.native(s, lam_start="consistent")
        for tol in tols:
            def run(tol=tol, adaptive=adaptive, **extra):
                return L.solve(model.problem, adaptive, setup.t_span, setup.q0, p0, args=args, rtol=tol, atol=tol,
                               throw=False, **extra)

            # where the kept half steps start (the dense output's pieces), and the end
            dense = run(**kw, dense_output=True).sol
            replay = GivenSteps(tuple(float(x) for x in np.unique(np.append(np.ravel(dense.steps.t0), dense.t1))))

            def replayed(replay=replay, oracle=oracle):
                return L.solve(model.problem, oracle, setup.t_span, setup.q0, p0, args=args, controller=replay,
                               throw=False, **kw)

            sa, so = run(**kw), replayed()
            runs[f"s={s}", tol] = (lambda run=run: run(**kw), dict(
                tol=tol, error=err(sa), steps=int(sa.stats["n_steps"]), rejected=int(sa.stats["n_rejected"]),
                newton=int(sa.stats["n_newton"]), jacobians=int(sa.stats["n_jacobians"])))
            runs[f"oracle s={s}", tol] = (replayed, dict(
                tol=tol, error=err(so), steps=int(so.stats["n_steps"]), rejected=int(so.stats["n_rejected"]),
                newton=int(so.stats["n_newton"]), jacobians=int(so.stats["n_jacobians"])))
    ode = testset_ode(entry)
    dfx = Diffrax(ode, "Dopri8")
    y0 = ode.from_qp(setup.q0, setup.p0)
    for tol in dopri8_tols:
        def dopri8(tol=tol):
            return dfx.at(ts, y0, tol, t0=setup.t_span[0])

        ys, nacc, nsteps, ok = dopri8()
        e = float(error(entry, np.asarray(ts), *ode.to_qp(ys))) if ok and np.all(np.isfinite(ys)) else math.inf
        runs["Dopri8", tol] = (dopri8, dict(tol=tol, error=e, steps=nacc, rejected=nsteps - nacc))

    best = dict.fromkeys(runs, math.inf)
    for _ in range(repeats):
        for key, (fn, _) in runs.items():
            best[key] = min(best[key], best_of(fn, 1).best)
    out = {"source": entry.source, "sweeps": {}}
    for (label, tol), (_, row) in runs.items():
        row["ms"] = best[label, tol] * 1e3
        out["sweeps"].setdefault(label, []).append(row)
        log(f"  {name} {label} tol={tol:.1e}: {row['ms']:.2f} ms, error {row['error']:.2e} ({row['steps']} steps, "
            f"{row['rejected']} rejected)")
    out["summary"] = summarize(out)
    return out


def summarize(res: dict) -> dict:
    """Times at the target error (ms) and their ratios to Dopri8's, per s."""
    def at(label):
        return time_at([dict(error=r["error"], time=r["ms"]) for r in res["sweeps"][label]], TARGET)

    d8 = at("Dopri8")
    summary = {"dopri8_ms": d8}
    for key in res["sweeps"]:
        if key.startswith("s="):
            a, o = at(key), at(f"oracle {key}")
            summary[key] = dict(adaptive_ms=a, oracle_ms=o,
                                adaptive_over_dopri8=None if a is None or d8 is None else a / d8,
                                oracle_over_dopri8=None if o is None or d8 is None else o / d8,
                                oracle_over_adaptive=None if a is None or o is None else o / a)
    return summary


def table(results: dict) -> str:
    rows = []
    for name, res in results.items():
        sm = res["summary"]
        for key in (k for k in res["sweeps"] if k.startswith("s=")):
            r = sm[key]
            rows.append([name, key, fmt(r["adaptive_ms"]), fmt(r["oracle_ms"]), fmt(sm["dopri8_ms"]),
                         fmt(r["adaptive_over_dopri8"], ".2f"), fmt(r["oracle_over_dopri8"], ".2f"),
                         fmt(r["oracle_over_adaptive"], ".2f")])
    return md_table(["problem", "s", "adaptive [ms]", "oracle [ms]", "Dopri8 [ms]", "adaptive / Dopri8",
                     "oracle / Dopri8", "oracle / adaptive"], rows)


def main() -> None:
    ap = cli.parser(__doc__, "pin_cpu", "cpu_threads", "watchdog")
    ap.add_argument("--problems", nargs="+", default=list(DEFAULT_PROBLEMS),
                    choices=[k for k, v in PROBLEMS.items() if v.mechanics is not None])
    ap.add_argument("--stages", nargs="+", type=int, default=[4, 5])
    ap.add_argument("--tols", nargs="+", type=float, default=[1e-6, 3e-7, 1e-7, 3e-8, 1e-8, 3e-9, 1e-9],
                    help="rtol = atol of the adaptive runs and of Dopri8 (default: half decades 1e-6 ... 1e-9)")
    ap.add_argument("--dopri8-tols", nargs="+", type=float, default=half_decades(1e-6, 1e-11),
                    help="Dopri8's rtol = atol (default: half decades 1e-6 ... 1e-11; it is more accurate than "
                         "its tolerance on some of these problems, less on others)")
    ap.add_argument("--repeats", type=int, default=5)
    args = cli.start(ap.parse_args())
    _admit_replays()
    start = time.perf_counter()
    results = {}
    for name in args.problems:
        log(f"{name}:")
        results[name] = run_problem(name, args.stages, args.tols, args.dopri8_tols, args.repeats)
    log(f"\ntime at error {TARGET:g} (interpolated on each Pareto front; ratios from this run):\n")
    log(table(results))
    path = results_path("oracle_steps.json")  # a run of some problems replaces only theirs
    out = merged(path, "results", results, run_meta(seconds=time.perf_counter() - start))
    write_json({**out, "target": TARGET}, path)


if __name__ == "__main__":
    main()
