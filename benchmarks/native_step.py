"""The native step of ``lobattodae.mechanics`` against the JAX path (issue #26, item 4).

Issue #26: "prototype an optional native step for models from ``lobattodae.mechanics`` ...,
measure it against the JAX path, and keep it only if ≥ 2× faster per step with results equal
to round-off". Three parts, every ratio from one run of this script:

* ``per-step``: constant steps of the generated Chaplygin sleigh and falling disk
  (``mechanics.systems``; the initial values and parameters of ``lobattodae.examples``), s = 3…6,
  and of the Whipple bicycle (s = 4, h = 0.01, upright at 5 m/s; not with ``--quick``),
  ``model.native(s).integrate`` against ``jax.jit(lobattodae.integrate)`` (the same method,
  ``lam_start="auto"``), interleaved, best of ``--repeats``; the largest difference of every row
  of q and p, relative to 1 + their size.
* ``adaptive``: error-controlled runs (rtol = atol, ``save_every="final"``): ``lobattodae.solve``
  with the method (the JAX path's attempts) against ``lobattodae.solve(model.problem,
  model.native(s), ...)`` (each attempt of step doubling one native call in the same loop),
  interleaved, best of ``--repeats``; the steps and Newton counts of both, and how far their end
  points differ. On the sleigh (T = 1000), diffrax's Dopri8 on the index-1 ODE (jitted, each of
  ``lib.baselines.PID_SETS``, best) at the native run's error of q(T).
* ``first-result``: fresh processes, no caches (``LOBATTODAE_NO_CACHE=1``, an empty cache
  directory): the falling disk from ``mechanics.systems`` (s = 4, 2000 constant steps) and the
  Whipple bicycle (s = 4, 1000 steps over 10 s), by ``model.native(4).integrate`` and by
  ``lobattodae.solve(..., n_steps=...)``; the time from ``import lobattodae`` and the time after
  the model is built; and the native path again in a new process with the same cache directory
  (it loads the compiled library without generating the C).

Usage (repository root)::

    PYTHONPATH=src .venv/bin/python benchmarks/native_step.py --pin-cpu 1 [--part per-step adaptive first-result]

Writes ``benchmarks/results/native_step.json`` (a part run alone replaces that part).
"""

from __future__ import annotations

import os
import sys
import tempfile
import time

import numpy as np

import lobattodae as L
from lib import cli
from lib.baselines import PID_SETS, Diffrax
from lib.odes import reduced_ode
from lib.output import (BENCHMARKS, child_env, child_result, loadavg, log, md_table, python_child, read_json,
                        results_path, run_meta, write_json)
from lib.sweeps import time_at
from lobattodae import examples, mechanics
from lobattodae.mechanics import _native

PARTS = ("per-step", "adaptive", "first-result")


class _Start:
    """Initial values and parameters: ``q0, p0, lam0, args``."""

    def __init__(self, q0, p0, lam0, args):
        self.q0, self.p0, self.lam0, self.args = q0, p0, lam0, args


def pairs(bicycle: bool = False):
    """``name -> (start, generated model, args)``: the sleigh and the falling disk with the
    initial values and parameters of ``lobattodae.examples``, and (``bicycle``) the Whipple
    bicycle upright at 5 m/s with a roll rate of 0.5 rad/s."""
    out = {}
    for name, ex, model in (("sleigh", examples.chaplygin_sleigh(), mechanics.systems.chaplygin_sleigh()),
                            ("falling disk", examples.falling_rolling_disk(steady=False),
                             mechanics.systems.falling_disk())):
        out[name] = (_Start(ex.q0, ex.p0, ex.lam0, ex.args), model, model.args(**ex.args._asdict()))
    if bicycle:
        from lobattodae.mechanics import bicycle as bike

        model = bike.whipple_bicycle()
        args = model.args()
        q0, p0 = bike.upright_state(model, 5.0, args, roll_rate=0.5)
        lam0 = np.asarray(L.consistent_lambda(model.problem, 0.0, q0, p0, np.zeros(model.m), args))
        out["Whipple bicycle"] = (_Start(q0, p0, lam0, args), model, args)
    return out


# ------------------------------------------------------------------------------ per step
def per_step(repeats: int, quick: bool) -> list[dict]:
    import jax

    cases = {"sleigh": [(0.05, 2000), (0.5, 200)], "falling disk": [(0.05, 2000), (0.2, 500)],
             "Whipple bicycle": [(0.01, 1000)]}
    rows = []
    for name, (ex, model, args) in pairs(bicycle=not quick).items():
        for s in ([4] if name == "Whipple bicycle" else [3, 5] if quick else [3, 4, 5, 6]):
            method = L.LobattoIIIAIIIB(stages=s)
            native = model.native(s)
            for h, n_steps in cases[name]:
                jitted = jax.jit(lambda q0, p0, lam0, args, h=h, n=n_steps, m=method: L.integrate(
                    model.problem, m, 0.0, h, n, q0, p0, lam0, args)[:3])

                def jax_call():
                    return [np.asarray(x) for x in jax.block_until_ready(jitted(ex.q0, ex.p0, ex.lam0, args))]

                def native_call():
                    return native.integrate(0.0, h, n_steps, ex.q0, ex.p0, ex.lam0, args)

                ours, theirs = native_call(), jax_call()
                if ours.status != L.Result.SUCCESSFUL or not np.all(np.isfinite(theirs[0])):
                    log(f"{name} s={s} h={h}: a step failed (native {ours.status.name}); not timed")
                    continue
                diff = max(float(np.max(np.abs(a - b)) / (1 + np.max(np.abs(b)))) for a, b in zip(ours[:2], theirs[:2]))
                best = {"native": np.inf, "jax": np.inf}
                for _ in range(repeats):
                    for key, fn in (("native", native_call), ("jax", jax_call)):
                        t0 = time.perf_counter()
                        fn()
                        best[key] = min(best[key], time.perf_counter() - t0)
                row = dict(problem=name, s=s, h=h, n_steps=n_steps, native_us=best["native"] / n_steps * 1e6,
                           jax_us=best["jax"] / n_steps * 1e6, ratio=best["jax"] / best["native"], row_diff=diff,
                           newton=ours.n_newton, jacobians=ours.n_jacobians, lam_resets=ours.lam_resets)
                log(f"{name:12s} s={s} h={h:<5g} native {row['native_us']:7.2f} µs/step, jax {row['jax_us']:7.2f}: "
                    f"{row['ratio']:.2f} x  (rows differ by {diff:.1e}; {ours.n_newton} iterations, "
                    f"{ours.n_jacobians} matrices)")
                rows.append(row)
    return rows


# ----------------------------------------------------------------------------- adaptive
def adaptive(repeats: int, quick: bool) -> list[dict]:
    """``lobattodae.solve`` with error control, the JAX path's attempts against the native ones
    (``solve(model.problem, model.native(s), ...)``), interleaved, best of ``repeats`` after a
    compiling call; on the sleigh Dopri8 at the same error of q(T)."""
    cases = [("sleigh", 1000.0, 5, 1e-8), ("sleigh", 1000.0, 6, 1e-7), ("falling disk", 100.0, 5, 1e-8),
             ("falling disk", 100.0, 6, 1e-8)]
    if quick:
        cases = cases[:1] + cases[2:3]
    rows = []
    for name, T, s, tol in cases:
        ex, model, args = pairs()[name]
        paths = {"jax": L.LobattoIIIAIIIB(stages=s), "native": model.native(s)}

        def call(path):
            return L.solve(model.problem, paths[path], (0.0, T), ex.q0, ex.p0, args=args, lam0=ex.lam0, rtol=tol,
                           atol=tol, save_every="final")

        sols = {path: call(path) for path in paths}
        best = {path: np.inf for path in paths}
        for _ in range(repeats):
            for path in paths:
                best[path] = min(best[path], _timed(lambda: call(path)))
        row = dict(problem=name, T=T, s=s, rtol=tol, jax_ms=best["jax"] * 1e3, native_ms=best["native"] * 1e3,
                   ratio=best["jax"] / best["native"])
        for path, sol in sols.items():
            row[f"{path}_stats"] = {k: int(sol.stats[k]) for k in ("n_steps", "n_rejected", "n_newton", "n_jacobians")}
        q_jax, q_native = (np.asarray(sols[path].q[-1]) for path in paths)
        row["end_diff"] = float(np.max(np.abs(q_native - q_jax)) / (1 + np.max(np.abs(q_jax))))
        if name == "sleigh":
            q_ref = examples.chaplygin_sleigh().exact(np.array([T]))[0][0]
            row["error"] = float(np.max(np.abs(q_jax - q_ref)))
            row["native_error"] = float(np.max(np.abs(q_native - q_ref)))
            row["dopri8_ms_at_error"], row["dopri8_points"] = dopri8_at(ex, T, q_ref, row["native_error"], repeats)
        attempts = sum(row["native_stats"][k] for k in ("n_steps", "n_rejected"))
        log(f"{name:12s} T={T:g} s={s} rtol={tol:g}: {attempts} attempts; solve {row['jax_ms']:.2f} ms, natively "
            f"{row['native_ms']:.2f} ms: {row['ratio']:.2f} x; end points differ by {row['end_diff']:.1e}"
            + (f"; error {row['native_error']:.2e} (JAX {row['error']:.2e}), Dopri8 at that error "
               f"{row['dopri8_ms_at_error'] or float('nan'):.2f} ms" if name == "sleigh" else ""))
        rows.append(row)
    return rows


def dopri8_at(ex, T, q_ref, error, repeats):
    """Dopri8's time (ms) at ``error`` of q(T) on its Pareto front over the PID sets, and its points."""
    ode = reduced_ode("sleigh", ex.args)
    dfx = Diffrax(ode)
    y0 = np.r_[ex.q0, ex.p0]
    points = []
    for pid in PID_SETS:
        dfx.final(T, y0, 1e-8, pid)  # compiles
        for tol in [10.0 ** (-k / 2) for k in range(12, 27)]:
            (yT, _, nsteps, ok) = dfx.final(T, y0, tol, pid)
            if not ok:
                continue
            secs = min(_timed(lambda: dfx.final(T, y0, tol, pid)) for _ in range(repeats))
            points.append(dict(pid=list(pid), tol=tol, steps=nsteps, error=float(np.max(np.abs(yT[:3] - q_ref))),
                               time=secs))
    t = time_at(points, error)
    return (None if t is None else t * 1e3), points


def _timed(fn) -> float:
    t0 = time.perf_counter()
    fn()
    return time.perf_counter() - t0


# -------------------------------------------------------------------------- first result
FIRST = """
import time; t0 = time.perf_counter()
import sys
import numpy as np
import lobattodae as L
L.set_cpu_threads(1)
from lobattodae import examples, mechanics
from lib.output import print_result
path, case = sys.argv[1], sys.argv[2]
if case == "falling disk":
    ex = examples.falling_rolling_disk(steady=False)
    model = mechanics.systems.falling_disk()
    args, q0, p0, lam0, s, h, n = model.args(**ex.args._asdict()), ex.q0, ex.p0, ex.lam0, 4, 0.05, 2000
else:
    from lobattodae.mechanics import bicycle as bike
    model = bike.whipple_bicycle()
    args = model.args()
    q0, p0 = bike.upright_state(model, 5.0, args, roll_rate=0.5)
    lam0, s, h, n = None, 4, 0.01, 1000
t1 = time.perf_counter()
if path == "native":
    q = model.native(s).integrate(0.0, h, n, q0, p0, lam0, args).q[-1]
else:
    sol = L.solve(model.problem, L.LobattoIIIAIIIB(stages=s), (0.0, n * h), q0, p0, args=args, lam0=lam0, n_steps=n,
                  save_every="final")
    q = np.asarray(sol.q[-1])
t2 = time.perf_counter()
print_result({"total": t2 - t0, "after_model": t2 - t1, "q": q})
"""
#: The first-result cases: the falling disk (s = 4, 2000 steps of 0.05) and the Whipple bicycle
#: (s = 4, 1000 steps of 0.01 from upright at 5 m/s, as ``first_result.py --case bicycle``).
FIRST_CASES = ("falling disk", "bicycle")


def first_result(repeats: int, cases) -> list[dict]:
    """Fresh processes, each with an empty cache directory; the native path then once more with
    the same directory ("native, warm": a new process that finds the compiled library and the
    derived model, ``lobattodae.mechanics._model_cache``)."""
    rows = []
    for case in cases:
        for _ in range(repeats):
            for path in ("native", "jax"):
                with tempfile.TemporaryDirectory() as cache:
                    env = child_env(no_cache=True, LOBATTODAE_CACHE_DIR=cache,
                                    PYTHONPATH=os.pathsep.join([os.path.abspath("src"), BENCHMARKS]))
                    if path == "native":  # the native library's cache on, in the empty directory: a cold start
                        env.pop("LOBATTODAE_NO_CACHE")
                        env["JAX_ENABLE_COMPILATION_CACHE"] = "false"
                    for label in ((path, "native, warm") if path == "native" else (path,)):
                        r = child_result(python_child(FIRST, path, case), env, timeout=900)
                        if "error" in r:
                            sys.exit(f"first result ({case}, {label}): {r['error']}")
                        rows.append(dict(case=case, path=label, **r))
                        log(f"first result, {case}, {label:12s}: {r['total']:.2f} s "
                            f"({r['after_model']:.2f} s after the model)")
    return rows


def merged_parts(path: str, out: dict) -> dict:
    """``out`` over what ``path`` holds: the parts not run now are kept (each with its own meta)."""
    old = read_json(path, {}) or {}
    for key in ("per_step", "adaptive", "first_result"):
        if key in out:
            old[key] = out[key]
            old[f"{key}_meta"] = out["meta"]
    return old


def main(argv=None):
    parser = cli.parser(__doc__, "quick", "pin_cpu")
    parser.add_argument("--part", nargs="+", choices=PARTS, default=list(PARTS))
    parser.add_argument("--repeats", type=int, default=None)
    parser.add_argument("--first-cases", nargs="+", choices=FIRST_CASES, default=list(FIRST_CASES))
    opts = cli.start(parser.parse_args(argv))
    L.set_cpu_threads(1)
    repeats = opts.repeats or (3 if opts.quick else 5)
    out = {"meta": run_meta(repeats=repeats, pin_cpu=opts.pin_cpu, compiler=_native.c_compiler(),
                            cflags=list(_native.CFLAGS))}
    if "per-step" in opts.part:
        out["per_step"] = per_step(repeats, opts.quick)
        log("\n" + md_table(["problem", "s", "h", "native µs/step", "JAX µs/step", "JAX / native", "rows differ"],
                            [[r["problem"], r["s"], r["h"], r["native_us"], r["jax_us"], r["ratio"], r["row_diff"]]
                             for r in out["per_step"]]))
    if "adaptive" in opts.part:
        out["adaptive"] = adaptive(repeats, opts.quick)
    if "first-result" in opts.part:
        out["first_result"] = first_result(min(repeats, 3), opts.first_cases)
    out["meta"]["loadavg_end"] = loadavg()
    path = results_path(f"native_step{'_quick' if opts.quick else ''}.json")
    write_json(merged_parts(path, out), path)


if __name__ == "__main__":
    main()
