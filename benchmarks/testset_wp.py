r"""Work-precision diagrams on the external test set (``benchmarks/testset``): the test set's
error measure against wall time and against the requested tolerance.

For every problem of ``testset.PROBLEMS`` (default: ``andrews``; ``--problems all`` runs
every problem) and every solver, tol = 1e-4 ... 1e-12 in decades (``--half-decades``: in
half decades); rtol = atol = tol everywhere. Every point: a first call (``first_call_time``:
compilation + run for the first tolerance of a jitted solver, the run alone afterwards), then
the best of 3 further calls (``time``; a call longer than ``--repeat-limit`` = 5 s is not
repeated). A solver stops tightening once a call takes longer than ``--budget`` = 20 s, or
its next call is predicted to take more than 3x that, or its error has not halved over
three settings once it is within 3x of the reference's own accuracy (``lib.sweeps.Sweep``).

Error: ``testset.error`` -- max over the compared components (q, and p where the entry
compares p) and the reference times of ``|y − y_ref| / (1 + |y_ref|)``.

Solvers (``lib.baselines``; XLA's CPU pool is one thread for every solver of the process)
-------
* **lobattodae** ``solve(problem, LobattoIIIAIIIB(stages=s), t_span, q0, p0, args=...,
  rtol=tol, atol=tol)`` for s = 3, 4, 5, 6, ``save_every="final"`` when the only reference
  time is the end of the interval, else ``t_eval=t_ref``; the whole ``solve`` call is timed.
* **lobattodae native** (``native s=...``), for the problems that have a ``lobattodae.mechanics``
  model of their equations (``TestProblem.mechanics``: the four-bar linkage and the rolling disc
  as converted from SymPy, Andrews' squeezer and the slider crank as their Lagrangian twins; the
  crank's model carries momenta where the problem carries velocities, converted by
  ``TestProblem.mechanics_momenta``): ``solve(model.problem,
  model.native(s), ...)`` with the same options, each attempt one call into the model's
  generated C (its compilation, once per model and s, is outside the timings: a warm-up call).
* **diffrax Dopri8** and **diffrax Kvaerno5** on the index-1 ODE of the problem
  (``lib.odes.testset_ode``), ``PIDController(rtol=tol, atol=tol)`` (default coefficients),
  ``SaveAt(ts=t_ref)``, ``max_steps`` = 10⁶, jitted once per problem and solver.
* **scipy DOP853** and **scipy Radau** (default finite-difference Jacobian) on the same ODE's
  plain Python/NumPy right-hand side; ``t_eval=t_ref`` only when there are reference times
  before the end; skipped where no NumPy right-hand side was written (a JAX-compiled one
  called from NumPy would not be how a scipy user works).
* **SUNDIALS IDA** on the index-2 form ``y = (q, p, λ)``, residual ``[q' − f, p' − g(λ), φ]``
  from the problem's own JAX functions, AOT-compiled and called from NumPy
  (``lib.odes.jax_dae``), λ excluded from the error test, when scikit-sundae is importable
  (``--no-ida`` skips it).

The table: wall time at error 1e-8 on each solver's Pareto front (log time interpolated
linearly in log error between the two bracketing points; ``lib.sweeps.time_at``), for
lobattodae the best s (and natively the best s), and the ratios ours(best s)/Dopri8, /DOP853,
/Radau (< 1: ours is faster), natively against Dopri8 too. The same table from process CPU times is printed too (the machine is shared: wall
time ≫ CPU time means other processes held the cores).

Usage (repository root)::

    PYTHONPATH=src .venv/bin/python benchmarks/testset_wp.py [--problems andrews ...|all] [--half-decades]
        [--pin-cpu 0]
    PYTHONPATH=src .venv/bin/python benchmarks/testset_wp.py --replot

Writes ``benchmarks/results/testset_wp.json`` (``--problems`` merges into it) and
``benchmarks/results/testset_wp_<name>.png``.
"""

from __future__ import annotations

import math
import os
import sys
import time

import numpy as np

import lobattodae as L
from lib import cli
from lib.baselines import IDA, Diffrax, ida_available, scipy_solve
from lib.odes import jax_dae, testset_ode
from lib.output import fmt, loadavg, log, md_table, merged, pyplot, read_json, results_path, run_meta, save_figure, \
    write_json
from lib.sweeps import Sweep, decades, half_decades, solution_point, time_at
from testset import PROBLEMS, error

TARGET = 1e-8
STAGES = (3, 4, 5, 6)
SOLVERS = ("lobattodae", "native", "Dopri8", "Kvaerno5", "DOP853", "Radau", "IDA")
MAX_STEPS = 1_000_000


# ==================================================================================== solvers
def _output_plan(entry, setup):
    """(t_ref inside t_span, sorted; True if the end of the interval is the only one)."""
    t0, t1 = map(float, setup.t_span)
    ts = sorted(float(t) for t in entry.t_ref if min(t0, t1) < t <= max(t0, t1))
    return ts, len(ts) == 1 and math.isclose(ts[0], t1, rel_tol=1e-12, abs_tol=1e-12)


def _sweep(label, entry, opts) -> Sweep:
    return Sweep(label, budget=opts.budget, repeats=opts.repeats, repeat_limit=opts.repeat_limit,
                 floor=3 * entry.ref_accuracy)


def run_lobattodae(entry, setup, s, tols, opts, native=False):
    """``solve`` with ``LobattoIIIAIIIB(stages=s)``, or (``native``) with the native step of the
    problem's ``lobattodae.mechanics`` model (``entry.mechanics``), whose C is compiled here, before
    the sweep."""
    problem, method, args, p0 = setup.problem, L.LobattoIIIAIIIB(stages=s), setup.args, setup.p0
    to_problem = None
    if native:
        model, args = entry.mechanics()
        problem, method = model.problem, model.native(s)
        if entry.mechanics_momenta is not None:  # the model's momenta are not the problem's p
            to_model, to_problem = entry.mechanics_momenta
            p0 = to_model(setup.t_span[0], setup.q0, setup.p0)
    ts, final_only = _output_plan(entry, setup)
    kw = {"save_every": "final"} if final_only else {"t_eval": ts}

    def call(tol):
        return L.solve(problem, method, setup.t_span, setup.q0, p0, args=args, rtol=tol, atol=tol, throw=False, **kw)

    def measure(sol):
        t, q, p = np.asarray(sol.t), np.asarray(sol.q), np.asarray(sol.p)
        return error(entry, t, q, p if to_problem is None else to_problem(t, q, p))

    def post(sol):
        return solution_point(sol, measure)

    return _sweep(f"lobattodae {'native ' if native else ''}s={s}", entry, opts).run(tols, call, post, first_call=True)


def run_diffrax(entry, setup, ode, solver: str, tols, opts):
    ts, _ = _output_plan(entry, setup)
    dfx = Diffrax(ode, solver, max_steps=MAX_STEPS)
    y0 = ode.from_qp(setup.q0, setup.p0)

    def post(out):
        ys, nacc, nsteps, ok = out
        p = {"ok": ok, "steps": nacc, "rejected": nsteps - nacc}
        if ok and np.all(np.isfinite(ys)):
            p["error"] = error(entry, np.asarray(ts), *ode.to_qp(ys))
        else:
            p.update(error=math.inf, message="diffrax: not successful (max_steps or step size)")
        return p

    return _sweep(f"diffrax {solver}", entry, opts).run(
        tols, lambda tol: dfx.at(ts, y0, tol, t0=setup.t_span[0]), post, first_call=True)


def run_scipy(entry, setup, ode, method: str, tols, opts):
    ts, final_only = _output_plan(entry, setup)
    y0 = ode.from_qp(setup.q0, setup.p0)

    def post(r):
        p = {"ok": bool(r.success), "nfev": int(r.nfev), "njev": int(r.njev),
             "steps": (len(r.t) - 1) if final_only else None}
        if r.success:
            Y = r.y.T[-1:] if final_only else r.y.T
            p["error"] = error(entry, r.t[-1:] if final_only else r.t, *ode.to_qp(Y))
        else:
            p.update(error=math.inf, message=str(r.message)[:300])
        return p

    return _sweep(f"scipy {method}", entry, opts).run(
        tols, lambda tol: scipy_solve(ode, method, setup.t_span, y0, tol, None if final_only else ts), post,
        first_call=True)


def run_ida(entry, setup, tols, opts):
    import jax.numpy as jnp

    problem, args = setup.problem, setup.args
    n = int(np.size(setup.q0))
    t0 = jnp.asarray(float(setup.t_span[0]))
    m = int(np.size(problem.phi(t0, jnp.asarray(setup.q0), jnp.asarray(setup.p0), args)))
    lam0 = np.asarray(L.consistent_lambda(problem, t0, jnp.asarray(setup.q0), jnp.asarray(setup.p0),
                                          jnp.zeros(m), args, iterations=3))
    ida = IDA(jax_dae(problem, args, n, m))
    ts, final_only = _output_plan(entry, setup)
    span = (float(setup.t_span[0]), float(setup.t_span[1])) if final_only else [float(setup.t_span[0])] + ts

    def post(r):
        # with output times IDA returns only those rows: its step count is not known then
        p = {"ok": bool(r.success), "steps": r.n_steps if final_only else None, "nfev": r.nfev, "njev": r.njev}
        t = np.atleast_1d(r.t)
        if r.success and np.isclose(t[-1], setup.t_span[1]):
            p["error"] = error(entry, t, r.y[:, :n], r.y[:, n:2 * n])
        else:
            p.update(error=math.inf, message=r.message[:300])
        return p

    return _sweep("SUNDIALS IDA", entry, opts).run(tols, lambda tol: ida.solve(span, setup.q0, setup.p0, lam0, tol),
                                                   post, first_call=True)


# =================================================================================== driver
def run_problem(entry, opts, save) -> dict:
    t_start = time.perf_counter()
    setup = entry.build()
    tols = half_decades(1e-4, 1e-12) if opts.half_decades else decades(1e-4, 1e-12)
    out = {"source": entry.source, "t_span": list(setup.t_span), "t_ref": list(entry.t_ref),
           "compare": entry.compare, "ref_accuracy": entry.ref_accuracy, "tols": tols,
           "loadavg_start": loadavg(), "sweeps": {}}
    ode = None
    if any(s in opts.solvers for s in ("Dopri8", "Kvaerno5", "DOP853", "Radau")):
        ode = testset_ode(entry)
        out["ode"] = {"how": ode.how, "validation": ode.validation}
        log(f"  index-1 ODE: {ode.how}; validation: {ode.validation or 'none (it is the problem itself)'}")
        if not ode.validation.get("ok", True):
            log("  VALIDATION FAILED: the ODE solvers are skipped")
            ode = None
    sw = out["sweeps"]
    if "lobattodae" in opts.solvers:
        for s in opts.stages:
            sw[f"s={s}"] = run_lobattodae(entry, setup, s, tols, opts)
            save(out)
    if "native" in opts.solvers and entry.mechanics is not None:
        for s in opts.native_stages:
            sw[f"native s={s}"] = run_lobattodae(entry, setup, s, tols, opts, native=True)
            save(out)
    for solver in ("Dopri8", "Kvaerno5") if ode is not None else ():
        if solver in opts.solvers:
            sw[solver] = run_diffrax(entry, setup, ode, solver, tols, opts)
            save(out)
    for method in ("DOP853", "Radau") if ode is not None else ():
        if method not in opts.solvers:
            continue
        if ode.rhs is None:
            sw[method] = {"label": f"scipy {method}", "points": [], "stopped": "",
                          "skipped": "no hand-written NumPy right-hand side for this problem"}
            continue
        sw[method] = run_scipy(entry, setup, ode, method, tols, opts)
        save(out)
    if "IDA" in opts.solvers:
        ok, out["ida"] = ida_available()
        if ok:
            sw["IDA"] = run_ida(entry, setup, tols, opts)
    out["summary"] = summarize(out)
    out["loadavg_end"] = opts.meta["loadavg_end"] = loadavg()
    out["seconds"] = time.perf_counter() - t_start
    return out


# ================================================================================== summary
def summarize(entry_out: dict, key: str = "time") -> dict:
    t = {k: time_at(v["points"], TARGET, time=key) for k, v in entry_out["sweeps"].items()}

    def best_of(prefix):
        times = {k: v for k, v in t.items() if k.startswith(prefix) and v is not None}
        best = min(times, key=times.get) if times else None
        return best, times.get(best) if best else None

    best, tb = best_of("s=")
    native_best, tn = best_of("native s=")

    def ratio(ours, other):
        return ours / t[other] if ours is not None and t.get(other) else None

    return {"key": key, "time_at_1e-8": t, "ours_best_s": best, "ours": tb,
            "ours_over": {k: ratio(tb, k) for k in ("Dopri8", "Kvaerno5", "DOP853", "Radau", "IDA")},
            "native_best_s": native_best, "native": tn,
            "native_over": {k: ratio(tn, k) for k in ("Dopri8", "DOP853", "Radau")}}


def _fmt_s(x: float | None) -> str:
    return "–" if x is None else f"{x:.3g} s" if x >= 1 else f"{1e3 * x:.3g} ms"


def table(out: dict, key: str = "time") -> str:
    rows = []
    for name, e in out["problems"].items():
        sm = summarize(e, key)
        t, r = sm["time_at_1e-8"], sm["ours_over"]
        ours = [f"s={s}: {_fmt_s(t[f's={s}'])}" for s in STAGES if f"s={s}" in t]
        native = [f"{k[7:]}: {_fmt_s(v)}" for k, v in t.items() if k.startswith("native s=")]
        rows.append([name, "; ".join(ours), sm["ours_best_s"] or "not reached", "; ".join(native) or "–"]
                    + [_fmt_s(t.get(k)) for k in ("Dopri8", "Kvaerno5", "DOP853", "Radau", "IDA")]
                    + [fmt(r[k], ".2g") for k in ("Dopri8", "DOP853", "Radau", "Kvaerno5", "IDA")]
                    + [fmt(sm.get("native_over", {}).get("Dopri8"), ".2g")])
    return md_table(["problem", "lobattodae", "best", "natively", "Dopri8", "Kvaerno5", "DOP853", "Radau", "IDA",
                     "ours/Dopri8", "ours/DOP853", "ours/Radau", "ours/Kvaerno5", "ours/IDA", "native/Dopri8"], rows)


# ===================================================================================== plot
STYLE = {"s=3": ("#9ecae1", "o"), "s=4": ("#4292c6", "s"), "s=5": ("#08519c", "D"), "s=6": ("#3f007d", "p"),
         "Dopri8": ("#d62728", "v"), "Kvaerno5": ("#8c564b", "X"), "DOP853": ("#ff7f0e", "^"),
         "Radau": ("#2ca02c", "<"), "IDA": ("#9467bd", "P")}
LABEL = {"Dopri8": "diffrax Dopri8 (jit, JAX rhs)", "Kvaerno5": "diffrax Kvaerno5 (jit, JAX rhs)",
         "DOP853": "scipy DOP853 (NumPy rhs)", "Radau": "scipy Radau (NumPy rhs, FD Jacobian)",
         "IDA": "SUNDIALS IDA (index 2, JAX residual)"}


def plot(name: str, e: dict, path: str, meta: dict) -> None:
    plt = pyplot()
    fig, (ax, ax2) = plt.subplots(1, 2, figsize=(14, 6.4))
    floor = float(e["ref_accuracy"])
    for key, sw in e["sweeps"].items():
        pts = [p for p in sw["points"] if math.isfinite(float(p["error"])) and math.isfinite(float(p["time"]))]
        if not pts:
            continue
        native = key.startswith("native ")
        color, marker = STYLE.get(key[7:] if native else key, ("black", "x"))
        label = f"lobattodae {key}" if key.startswith(("s=", "native ")) else LABEL.get(key, key)
        lw = 2.0 if key.startswith(("s=", "native ")) else 1.4
        err = [max(float(p["error"]), 1e-16) for p in pts]
        style = "--" if native else "-"
        ax.loglog([p["time"] for p in pts], err, style, color=color, marker=marker, ms=5, lw=lw, label=label,
                  mfc="none" if native else color)
        ax2.loglog([p["tol"] for p in pts], err, style, color=color, marker=marker, ms=5, lw=lw,
                   mfc="none" if native else color)
    tl = np.array([1e-13, 1e-3])
    ax2.loglog(tl, tl, "k--", lw=1, label="error = rtol")
    ax2.loglog(tl, 30 * tl, "k:", lw=1, label="error = 30·rtol")
    errs = [float(p["error"]) for sw in e["sweeps"].values() for p in sw["points"]
            if math.isfinite(float(p["error"])) and float(p["error"]) > 0]
    lo = max(min(errs + [floor]) / 3, 1e-16) if errs else 1e-14
    hi = min(max(errs + [1e-3]) * 3, 10.0) if errs else 1.0
    for a in (ax, ax2):
        a.axhspan(1e-17, floor, color="0.88", zorder=0)
        a.axhline(TARGET, color="gray", lw=1, ls=":")
        a.grid(True, which="major", alpha=0.3)
        a.set_ylabel("error  max |y − y_ref| / (1 + |y_ref|)")
        a.set_ylim(lo, hi)
        a.text(0.005, TARGET, " 1e-8", transform=a.get_yaxis_transform(), va="bottom", color="gray", fontsize=8)
        a.text(0.005, floor, " reference accuracy", transform=a.get_yaxis_transform(), va="top",
               color="0.4", fontsize=8)
    ax2.set_xlim(3e-13, 3e-4)
    ax2.invert_xaxis()
    ax.set_title(f"{name}: error at t = {', '.join(f'{t:g}' for t in e['t_ref'])} vs wall time")
    ax.set_xlabel("wall time per solve [s] (best of 3 after a warm-up call; compilation excluded)")
    ax2.set_title("error vs requested tolerance (rtol = atol)")
    ax2.set_xlabel("rtol = atol")
    fig.legend(*ax.get_legend_handles_labels(), loc="lower center", ncol=5, fontsize=8.5, frameon=False,
               bbox_to_anchor=(0.5, 0.03))
    ax2.legend(fontsize=8, loc="upper right")
    la = e.get("loadavg_start") or ["?"]
    machine = meta.get("machine", {})
    fig.text(0.01, 0.005, f"{machine.get('cpu', '')}, {machine.get('cpu_count', '?')} CPUs, load average {la[0]} at "
             f"start, {e.get('loadavg_end', ['?'])[0]} at end; XLA CPU pool 1 thread; "
             + (f"process pinned to CPU {meta['pin_cpu']}; " if meta.get("pin_cpu") is not None else "process not pinned; ")
             + "lobattodae: whole solve() call (dashed, open markers: natively); shaded: below the reference's own accuracy",
             fontsize=7, color="gray")
    fig.tight_layout(rect=(0, 0.11, 1, 1))
    save_figure(fig, path)


# ===================================================================================== main
def main(argv=None) -> int:
    ap = cli.parser(__doc__, "replot", "pin_cpu", "cpu_threads", cpu_threads={"default": 1})
    ap.add_argument("--problems", nargs="+", default=["andrews"], help="names of testset.PROBLEMS, or 'all'")
    ap.add_argument("--solvers", nargs="+", default=list(SOLVERS), choices=SOLVERS)
    ap.add_argument("--stages", nargs="+", type=int, default=list(STAGES))
    ap.add_argument("--native-stages", nargs="+", type=int, default=[4, 5, 6],
                    help="s of the native sweeps (problems with a lobattodae.mechanics model)")
    ap.add_argument("--half-decades", action="store_true", help="tolerances in half decades (default: decades)")
    ap.add_argument("--no-ida", action="store_true", help="skip SUNDIALS IDA")
    ap.add_argument("--budget", type=float, default=20.0, help="stop a sweep after a call this long [s]")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--repeat-limit", type=float, default=5.0, help="a call longer than this is not repeated [s]")
    ap.add_argument("--tag", default="", help="suffix of the output names: testset_wp<tag>.json, testset_wp<tag>_<name>.png")
    ap.add_argument("--out", default=None, help="the JSON (default benchmarks/results/testset_wp<tag>.json)")
    a = cli.start(ap.parse_args(argv))
    a.out = a.out or results_path(f"testset_wp{a.tag}.json")
    if a.no_ida:
        a.solvers = [s for s in a.solvers if s != "IDA"]
    png = lambda name: os.path.join(os.path.dirname(os.path.abspath(a.out)), f"testset_wp{a.tag}_{name}.png")  # noqa: E731
    if a.replot:
        out = read_json(a.out)
        for name, e in out["problems"].items():
            plot(name, e, png(name), e.get("meta", out.get("meta", {})))
        log(table(out, "time") + "\n\n" + table(out, "cpu_time"))
        return 0

    names = list(PROBLEMS) if a.problems == ["all"] else a.problems
    for nm in names:
        if nm not in PROBLEMS:
            ap.error(f"unknown problem {nm!r}; known: {', '.join(PROBLEMS)}")
    start = time.perf_counter()
    a.meta = meta = run_meta(ida=ida_available()[1], budget_s=a.budget, repeats=a.repeats,
                             repeat_limit_s=a.repeat_limit, solvers=a.solvers, stages=a.stages,
                             native_stages=a.native_stages, pin_cpu=a.pin_cpu,
                             cpu_affinity=a.cpus)
    log(f"testset_wp: {meta['command']}  (load average {meta['loadavg_start']})")
    for nm in names:
        log(f"\n=== {nm} ===")

        def save(e, nm=nm):  # after each sweep; each entry keeps the meta of the run that produced it
            write_json(merged(a.out, "problems", {nm: e}, meta), a.out, quiet=True)

        e = run_problem(PROBLEMS[nm], a, save)
        meta["wall_seconds"] = time.perf_counter() - start
        save(e)
        log(f"wrote {a.out}")
        plot(nm, e, png(nm), meta)
        log(f"  ({e['seconds']:.0f} s for {nm})")
    out = read_json(a.out)
    log(f"\nWall time at error {TARGET:g} (Pareto front, log-log interpolation); ours = lobattodae, best s:\n")
    log(table(out, "time"))
    log("\nThe same from the process CPU time of the best call:\n")
    log(table(out, "cpu_time"))
    log(f"\n({meta['wall_seconds']:.0f} s in all; load average {meta['loadavg_start']} -> {meta['loadavg_end']})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
