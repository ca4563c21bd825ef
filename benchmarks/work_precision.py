"""Work-precision benchmark at T = 1000 (issue #4).

For the Chaplygin sleigh, the knife edge and the falling rolling disk (steady rolling,
closed form) this measures the global error of q at the final time (max-norm, against
the exact solution) against wall time for

* lobattodae, s = 2..5, several constant step sizes,
* scipy ``solve_ivp`` DOP853 and Radau on the index-reduced ODE, over tolerances,
* diffrax Dopri8 (PID controller) on the index-reduced ODE, over tolerances,
* SUNDIALS IDA (scikit-sundae) on the index-2 DAE, λ excluded from the error test,
* the McLachlan-Perlmutter second-order nonholonomic integrator (eq. 4.18),

and records, for every run, max ‖φ‖∞ and max |H - H0| over all step points.

Timing: every compiled code path is called once first (reported as "compile+run"), then
the best of up to 3 calls is reported (a single call longer than 2 s is not repeated).
lobattodae's time is the wall time of the whole ``lobattodae.solve`` call (input
validation, λ0 check, compiled integration, assembling the Solution); the time spent in
the compiled integration loop alone (``stats['compile_and_run_time']``) is recorded too.

Usage::

    .venv/bin/python benchmarks/work_precision.py            # full (~10 min)
    .venv/bin/python benchmarks/work_precision.py --quick    # reduced (< 1 min)

Outputs ``benchmarks/results/work_precision[_quick].json``, ``wp_<problem>.png`` (error
and max ‖φ‖ vs wall time) and ``diag_<problem>.png`` (‖φ‖(t), |H - H0|(t) for one
representative setting of each solver: the one with error closest to 1e-8).
"""

from __future__ import annotations

import argparse
import datetime
import json
import math
import os
import platform
import sys
import time
import warnings
from dataclasses import asdict

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from baselines import (  # noqa: E402
    RESULTS_DIR,
    Diagnostics,
    IDABaseline,
    IndexReducedODE,
    McLachlanPerlmutter,
    RunRecord,
    binned_max,
    ida_available,
    source_revision,
    time_best,
)

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import lobattodae as L  # noqa: E402, N812
from lobattodae.examples import get_example  # noqa: E402

TARGET_ERR = 1e-8
TARGET_PHI = 1e-13


def config(quick: bool) -> dict:
    if quick:
        return {
            "T": 100.0,
            "problems": ["knife-edge", "sleigh"],
            "chunk": 512,
            "lobatto": {3: [1024, 4096], 5: [1024, 4096]},
            "lobatto_previous": {3: [1024], 5: [1024]},
            "dop853": [1e-6, 1e-10],
            "radau": [1e-6],
            "diffrax": [1e-6, 1e-10],
            "ida": [1e-6, 1e-9],
            "mp": [10_000, 100_000],
            "run_budget": 5.0,
            "repeats": 2,
        }
    return {
        "T": 1000.0,
        "problems": ["sleigh", "knife-edge", "falling-disk"],
        "chunk": None,  # lobattodae's default: next power of two >= N, at most 4096
        # powers of two: N is a multiple of the compiled chunk (4096) or a single chunk, so
        # no padded steps are computed (see step_cost.py, "chunk padding")
        "lobatto": {2: [4096, 16384, 65536], 3: [2048, 4096, 8192, 16384, 32768, 65536],
                    4: [1024, 2048, 4096, 8192, 16384, 32768], 5: [1024, 2048, 4096, 8192, 16384, 32768]},
        # the paper's scheme (lam_start="previous"), fewer step sizes
        "lobatto_previous": {2: [16384], 3: [8192, 32768], 4: [8192, 32768], 5: [8192, 32768]},
        "dop853": [1e-4, 1e-5, 1e-6, 1e-7, 1e-8, 1e-9, 1e-10, 1e-11, 1e-12, 1e-13, 3e-14],
        "radau": [1e-4, 1e-6, 1e-8, 1e-10],
        "diffrax": [1e-4, 1e-5, 1e-6, 1e-7, 1e-8, 1e-9, 1e-10, 1e-11, 1e-12, 1e-13, 3e-14],
        "ida": [1e-4, 1e-6, 1e-8, 1e-10, 1e-11],
        "mp": [10_000, 100_000, 1_000_000],
        "run_budget": 10.0,  # skip a setting predicted to take longer than this [s]
        "repeats": 3,
    }


def _series(diag, t, q, p, H0, t0, t1):
    phi, dH = diag(t, q, p, H0)
    tp, vp = binned_max(t, phi, t0, t1)
    th, vh = binned_max(t, dH, t0, t1)
    return float(np.max(phi)), float(np.max(dH)), {"t_phi": tp, "phi": vp, "t_dH": th, "dH": vh}


def _predicted(times):
    """Time of the next (tighter) tolerance, extrapolated from the last two runs."""
    if not times:
        return 0.0
    if len(times) == 1:
        return times[-1]
    return times[-1] * max(1.0, times[-1] / max(times[-2], 1e-9))


def _log(msg):
    print(msg, flush=True)


# --------------------------------------------------------------------------- per solver
def lobatto_variants():
    """``lam_start`` variants this version of lobattodae offers (feature-detected)."""
    try:
        L.LobattoIIIAIIIB(stages=3, lam_start="consistent")
        return ["previous", "consistent"]
    except TypeError:
        return [None]


def run_lobatto(ex, cfg, diag, q_exact, H0, records):
    T = cfg["T"]
    problem = ex.problem
    for variant in cfg["lam_start"]:
        plan = cfg["lobatto"] if variant != "previous" or len(cfg["lam_start"]) == 1 else cfg["lobatto_previous"]
        for s, Ns in plan.items():
            kw = {} if variant is None else {"lam_start": variant}
            method = L.LobattoIIIAIIIB(stages=s, **kw)
            label = f"lobattodae s={s}" + ("" if variant is None else f" ({variant} λ)")
            per_step = None
            compile_run = None
            warmed: set[int] = set()
            for N in Ns:
                if per_step is not None and per_step * N > cfg["run_budget"]:
                    _log(f"    {label} N={N}: skipped (predicted {per_step * N:.1f} s > budget)")
                    records.append(RunRecord(label, f"N={N}", math.nan, 0, None, math.nan, math.nan,
                                             math.nan, N, ok=False, message="skipped: predicted time over budget"))
                    continue
                caught = []

                def call():
                    with warnings.catch_warnings(record=True) as w:
                        warnings.simplefilter("always")
                        sol = L.solve(problem, method, (0.0, T), ex.q0, ex.p0, n_steps=N, lam0=ex.lam0,
                                      args=ex.args, throw=False, chunk_size=cfg["chunk"])
                    caught[:] = [str(x.message) for x in w]
                    return sol

                # warm-up whenever the compiled chunk length changes (the first N of each s is
                # reported as compile+run); lobattodae's default chunk: next power of two >= N,
                # at most 4096
                chunk = cfg["chunk"] or min(4096, max(16, 1 << (N - 1).bit_length()))
                first = None
                if chunk not in warmed:
                    t0 = time.perf_counter()
                    sol = call()
                    warmed.add(chunk)
                    if compile_run is None:
                        compile_run = first = time.perf_counter() - t0
                wall, reps, sol = time_best(call, cfg["repeats"])
                per_step = wall / N
                ok = bool(sol.success)
                err = float(np.max(np.abs(sol.q[-1] - q_exact))) if ok else math.nan
                max_phi, max_dH, ser = _series(diag, sol.t, sol.q, sol.p, H0, 0.0, T)
                its = sol.stats["newton_iterations"]
                msg = "" if ok else sol.message
                if caught:
                    msg = (msg + " | " if msg else "") + "warning: " + caught[0][:160]
                rec = RunRecord(
                    label, f"N={N}", wall, reps, first, err,
                    float(np.max(sol.stats["constraint_residual"])), max_dH, N,
                    extra={"h": T / N, "integrate_time": float(sol.stats["compile_and_run_time"]),
                           "newton_iterations_mean": float(np.mean(its)) if its.size else math.nan,
                           "n_jacobians": int(sol.stats["n_jacobians"]), "us_per_step": 1e6 * wall / N,
                           "lam_start": variant, "warned": bool(caught), "cpu": time_best.last_cpu},
                    series=ser, ok=ok, message=msg,
                )
                records.append(rec)
                _log(f"    {label} N={N:>6d}: err={err:.2e} wall={wall:.3f}s (x{reps}) "
                     f"integrate={rec.extra['integrate_time']:.3f}s  max|phi|={rec.max_phi:.1e} max|dH|={max_dH:.1e} "
                     f"newton={rec.extra['newton_iterations_mean']:.2f}"
                     + (f"  first call {first:.2f}s" if first else "") + ("" if ok else f"  FAILED: {sol.message}")
                     + ("  [λ-drift warning]" if caught else ""))


def run_scipy(ex, cfg, ode, diag, q_exact, H0, records, method, tols):
    T, n = cfg["T"], ex.q0.size
    y0 = np.r_[ex.q0, ex.p0]
    times: list[float] = []
    for tol in tols:
        if _predicted(times) > cfg["run_budget"]:
            _log(f"    scipy {method} tol={tol:g}: skipped (predicted {_predicted(times):.1f} s > budget)")
            records.append(RunRecord(f"scipy {method}", f"tol={tol:g}", math.nan, 0, None, math.nan, math.nan,
                                     math.nan, 0, ok=False, message="skipped: predicted time over budget"))
            break
        wall, reps, r = time_best(lambda: ode.solve_scipy(method, (0.0, T), y0, tol, tol), cfg["repeats"])
        times.append(wall)
        ok = bool(r.success)
        err = float(np.max(np.abs(r.y[:n, -1] - q_exact))) if ok else math.nan
        max_phi, max_dH, ser = _series(diag, r.t, r.y[:n].T, r.y[n:].T, H0, 0.0, T)
        rec = RunRecord(f"scipy {method}", f"tol={tol:g}", wall, reps, None, err, max_phi, max_dH, len(r.t) - 1,
                        extra={"nfev": int(r.nfev), "njev": int(getattr(r, "njev", 0) or 0), "cpu": time_best.last_cpu},
                        series=ser, ok=ok, message="" if ok else str(r.message))
        records.append(rec)
        _log(f"    scipy {method} tol={tol:g}: err={err:.2e} wall={wall:.3f}s (x{reps}) steps={len(r.t) - 1} "
             f"nfev={r.nfev} max|phi|={max_phi:.1e} max|dH|={max_dH:.1e}")


def run_diffrax(ex, cfg, ode, diag, q_exact, H0, records):
    T, n = cfg["T"], ex.q0.size
    y0 = np.r_[ex.q0, ex.p0]
    first = None
    for tol in cfg["diffrax"]:
        if first is None:
            t0 = time.perf_counter()
            ode.solve_diffrax((0.0, T), y0, tol, tol)
            first = time.perf_counter() - t0
            first_rec = first
        else:
            first_rec = None
        wall, reps, out = time_best(lambda: ode.solve_diffrax((0.0, T), y0, tol, tol), cfg["repeats"])
        yT, nsteps, nacc, code = out
        ok = int(code) == 0
        err = float(np.max(np.abs(np.asarray(yT)[:n] - q_exact))) if ok else math.nan
        ts, ys, nacc2, code2 = ode.trajectory_diffrax((0.0, T), y0, tol, tol)
        if int(code2) == 0:
            max_phi, max_dH, ser = _series(diag, ts, ys[:, :n], ys[:, n:], H0, 0.0, T)
        else:
            max_phi = max_dH = math.nan
            ser = {}
        rec = RunRecord("diffrax Dopri8", f"tol={tol:g}", wall, reps, first_rec, err, max_phi, max_dH, int(nacc),
                        extra={"num_steps": int(nsteps), "cpu": time_best.last_cpu}, series=ser, ok=ok,
                        message="" if ok else f"diffrax result code {int(code)}")
        records.append(rec)
        _log(f"    diffrax Dopri8 tol={tol:g}: err={err:.2e} wall={wall:.4f}s (x{reps}) steps={int(nacc)} "
             f"max|phi|={max_phi:.1e} max|dH|={max_dH:.1e}" + (f"  first call {first_rec:.2f}s" if first_rec else ""))


def run_ida(ex, cfg, diag, q_exact, H0, records):
    T, n, m = cfg["T"], ex.q0.size, ex.lam0.size
    ida = IDABaseline(ex.problem, ex.args, n, m)
    ida.solve((0.0, 1.0), ex.q0, ex.p0, ex.lam0, 1e-4, 1e-4)  # warm-up (eager JAX ops)
    times: list[float] = []
    for tol in cfg["ida"]:
        if _predicted(times) > cfg["run_budget"]:
            _log(f"    IDA tol={tol:g}: skipped (predicted {_predicted(times):.1f} s > budget)")
            records.append(RunRecord("SUNDIALS IDA", f"tol={tol:g}", math.nan, 0, None, math.nan, math.nan,
                                     math.nan, 0, ok=False, message="skipped: predicted time over budget"))
            break
        wall, reps, r = time_best(lambda: ida.solve((0.0, T), ex.q0, ex.p0, ex.lam0, tol, tol), cfg["repeats"])
        times.append(wall)
        ok = bool(r.success)
        err = float(np.max(np.abs(r.y[-1, :n] - q_exact))) if ok else math.nan
        max_phi, max_dH, ser = _series(diag, r.t, r.y[:, :n], r.y[:, n:2 * n], H0, 0.0, T)
        rec = RunRecord("SUNDIALS IDA", f"tol={tol:g}", wall, reps, None, err, max_phi, max_dH, r.n_steps,
                        extra={"nfev": r.nfev, "njev": r.njev, "lambda_in_error_test": False, "cpu": time_best.last_cpu},
                        series=ser, ok=ok, message="" if ok else r.message)
        records.append(rec)
        _log(f"    IDA tol={tol:g}: err={err:.2e} wall={wall:.3f}s (x{reps}) steps={r.n_steps} nfev={r.nfev} "
             f"max|phi|={max_phi:.1e} max|dH|={max_dH:.1e}" + ("" if ok else f" FAILED {r.message}"))


def run_mp(ex, cfg, diag, q_exact, H0, records):
    T, n, m = cfg["T"], ex.q0.size, ex.lam0.size
    mp = McLachlanPerlmutter(ex.problem, ex.args, n, m)
    first = None
    per_step = None
    for N in cfg["mp"]:
        if per_step is not None and per_step * N > cfg["run_budget"]:
            _log(f"    McLachlan-Perlmutter N={N}: skipped (predicted {per_step * N:.1f} s)")
            continue
        call = lambda: mp.integrate((0.0, T), ex.q0, ex.p0, ex.lam0, N, n_record=500)  # noqa: E731
        if first is None:
            t0 = time.perf_counter()
            call()
            first = time.perf_counter() - t0
            first_rec = first
        else:
            first_rec = None
        wall, reps, r = time_best(call, cfg["repeats"])
        per_step = wall / N
        ok = np.all(np.isfinite(r["q_final"])) and r["nonconverged_steps"] == 0
        err = float(np.max(np.abs(r["q_final"] - q_exact)))
        max_phi, max_dH, ser = _series(diag, r["t"], r["q"], r["p"], H0, 0.0, T)
        rec = RunRecord("McLachlan-Perlmutter", f"N={N}", wall, reps, first_rec, err, max_phi, max_dH, N,
                        extra={"h": r["h"], "newton_iterations_mean": r["newton_iterations_mean"],
                               "nonconverged_steps": r["nonconverged_steps"], "us_per_step": 1e6 * wall / N,
                               "diagnostics_sampled_every": N // 500, "cpu": time_best.last_cpu},
                        series=ser, ok=bool(ok), message="" if ok else "Newton did not converge on some steps")
        records.append(rec)
        _log(f"    McLachlan-Perlmutter N={N}: err={err:.2e} wall={wall:.3f}s (x{reps}) "
             f"max|phi|={max_phi:.1e} max|dH|={max_dH:.1e} newton={r['newton_iterations_mean']:.2f}"
             + (f"  first call {first_rec:.2f}s" if first_rec else ""))


# ------------------------------------------------------------------------------ analysis
def cheapest(records, solver_prefix, err_max, phi_max=None):
    best = None
    for r in records:
        if not r.solver.startswith(solver_prefix) or not r.ok or not np.isfinite(r.err_q):
            continue
        if r.err_q <= err_max and (phi_max is None or r.max_phi <= phi_max):
            if best is None or r.wall < best.wall:
                best = r
    return best


def targets(problem_name, records):
    lob = cheapest(records, "lobattodae", TARGET_ERR, TARGET_PHI)
    lob_any = cheapest(records, "lobattodae", TARGET_ERR)
    dop = cheapest(records, "scipy DOP853", TARGET_ERR)
    dfx = cheapest(records, "diffrax", TARGET_ERR)
    out = {"problem": problem_name, "err_target": TARGET_ERR, "phi_target": TARGET_PHI}
    for key, r in (("lobattodae", lob), ("lobattodae_ignoring_phi", lob_any), ("dop853", dop), ("diffrax", dfx)):
        out[key] = None if r is None else {"solver": r.solver, "setting": r.setting, "wall": r.wall,
                                           "err_q": r.err_q, "max_phi": r.max_phi}
    if lob and dop:
        out["speedup_vs_dop853"] = dop.wall / lob.wall
        out["met_10x_vs_dop853"] = dop.wall / lob.wall >= 10
    if lob and dfx:
        out["speedup_vs_diffrax"] = dfx.wall / lob.wall
        out["met_faster_than_diffrax"] = dfx.wall / lob.wall > 1
    return out


def plot(problem_name, records, T, path_wp, path_diag):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    families = []
    for r in records:
        if r.solver not in families:
            families.append(r.solver)
    cmap = plt.get_cmap("tab20")
    colors = {f: cmap(i % 20) for i, f in enumerate(families)}
    markers = {f: ("o" if f.startswith("lobattodae") else "s") for f in families}

    fig, axes = plt.subplots(1, 2, figsize=(12, 4.8), constrained_layout=True)
    for f in families:
        rs = [r for r in records if r.solver == f and r.ok and np.isfinite(r.wall)]
        if not rs:
            continue
        w = np.array([r.wall for r in rs])
        e = np.array([r.err_q for r in rs])
        ph = np.array([max(r.max_phi, 1e-17) for r in rs])
        o = np.argsort(w)
        ls = (":" if "previous" in f else "-") if f.startswith("lobattodae") else "--"
        axes[0].loglog(w[o], e[o], ls, marker=markers[f], color=colors[f], label=f, ms=5)
        axes[1].loglog(w[o], ph[o], ls, marker=markers[f], color=colors[f], label=f, ms=5)
    axes[0].axhline(TARGET_ERR, color="gray", lw=0.8, ls=":")
    axes[1].axhline(TARGET_PHI, color="gray", lw=0.8, ls=":")
    axes[0].set_xlabel("wall time after compilation [s]")
    axes[0].set_ylabel(f"max-norm error of q(T), T = {T:g}")
    axes[1].set_xlabel("wall time after compilation [s]")
    axes[1].set_ylabel("max ‖φ‖∞ over the run")
    axes[0].legend(fontsize=7)
    fig.suptitle(f"{problem_name}: work-precision at T = {T:g}")
    fig.savefig(path_wp, dpi=110)
    plt.close(fig)

    # representative setting per solver: error closest to 1e-8 (log scale); of lobattodae
    # only s = 3 and s = 5 (both λ variants), to keep the figure readable
    reps = []
    for f in families:
        if f.startswith("lobattodae") and not ("s=3" in f or "s=5" in f):
            continue
        rs = [r for r in records if r.solver == f and r.series and np.isfinite(r.err_q) and r.err_q > 0]
        if rs:
            reps.append(min(rs, key=lambda r: abs(math.log10(r.err_q) + 8)))
    fig, axes = plt.subplots(1, 2, figsize=(13, 6.2), constrained_layout=True)
    for r in reps:
        lab = f"{r.solver} {r.setting} (err {r.err_q:.1e})"
        axes[0].semilogy(r.series["t_phi"], np.maximum(r.series["phi"], 1e-18), color=colors[r.solver], label=lab, lw=1)
        axes[1].semilogy(r.series["t_dH"], np.maximum(r.series["dH"], 1e-18), color=colors[r.solver], label=lab, lw=1)
    axes[0].set_title("‖φ(q, p)‖∞ at the step points (max per time bin)")
    axes[1].set_title("|H − H0| at the step points (max per time bin)")
    for ax in axes:
        ax.set_xlabel("t")
    handles, labels = axes[0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="outside lower center", ncol=3, fontsize=7)
    fig.suptitle(f"{problem_name}: constraint and energy drift, one setting per solver")
    fig.savefig(path_diag, dpi=110)
    plt.close(fig)
    return [(r.solver, r.setting) for r in reps]


def sleigh_dynamics_note(ex, T):
    q, p, lam = ex.exact(np.array([0.0, 5.0, 10.0, 20.0, 50.0, T]))
    w = p[:, 2] / ex.args.I
    return {"t": [0, 5, 10, 20, 50, T], "omega": w.tolist(), "theta": q[:, 2].tolist(),
            "comment": "ω = θ' decays like sech(k v_max t): after t ≈ 50 the exact motion is a straight line "
                       "at speed v_max (x, y grow linearly), so the T = 1000 error is dominated by the "
                       "error in θ∞ and in the speed, accumulated during the turn."}


def replot(quick: bool):
    suffix = "_quick" if quick else ""
    with open(os.path.join(RESULTS_DIR, f"work_precision{suffix}.json")) as fh:
        out = json.load(fh)
    for name, entry in out["problems"].items():
        records = [RunRecord(**r) for r in entry["records"]]
        plot(name, records, entry["T"], os.path.join(RESULTS_DIR, f"wp_{name}{suffix}.png"),
             os.path.join(RESULTS_DIR, f"diag_{name}{suffix}.png"))
        _log(f"redrew the plots of {name}")


# ------------------------------------------------------------------------------------ main
def main(argv=None):
    ap = argparse.ArgumentParser(description="work-precision benchmark (issue #4)")
    ap.add_argument("--quick", action="store_true", help="reduced version (< 1 min)")
    ap.add_argument("--problems", nargs="*", help="subset of problems")
    ap.add_argument("--watchdog", type=float, default=1800.0,
                    help="abort with a traceback after this many seconds (0: off)")
    ap.add_argument("--replot", action="store_true",
                    help="only redraw the PNGs from the saved JSON (no benchmarking)")
    a = ap.parse_args(argv)
    if a.replot:
        return replot(a.quick)
    cfg = config(a.quick)
    if a.problems:
        cfg["problems"] = a.problems
    cfg["lam_start"] = lobatto_variants()
    T = cfg["T"]
    start = time.perf_counter()
    if a.watchdog > 0:  # a hung XLA call prints every thread's traceback and exits
        import faulthandler

        faulthandler.dump_traceback_later(a.watchdog, exit=True)
    jnp.zeros(1).block_until_ready()  # JAX backend initialisation is not charged to anyone
    ida_ok, ida_why = ida_available()
    meta = {
        "date": datetime.datetime.now().isoformat(timespec="seconds"),
        "machine": f"{platform.machine()}, {os.cpu_count()} cores, {platform.processor() or 'cpu'}",
        "python": platform.python_version(),
        "jax": jax.__version__,
        "lobattodae": L.__version__,
        "lobattodae_revision": source_revision(),
        "lobattodae_path": os.path.dirname(L.__file__),
        "ida": ida_why,
        "quick": a.quick,
        "loadavg_start": os.getloadavg(),
        "config": {k: (v if not isinstance(v, dict) else {str(kk): vv for kk, vv in v.items()}) for k, v in cfg.items()},
    }
    try:
        import diffrax
        import scipy

        meta["scipy"], meta["diffrax"] = scipy.__version__, diffrax.__version__
    except ImportError:
        pass
    out = {"meta": meta, "problems": {}}
    os.makedirs(RESULTS_DIR, exist_ok=True)
    suffix = "_quick" if a.quick else ""
    json_path = os.path.join(RESULTS_DIR, f"work_precision{suffix}.json")
    if a.problems and os.path.exists(json_path):
        # a subset of the problems: keep the other problems' saved results (each problem
        # entry records the run it came from in "meta")
        with open(json_path) as fh:
            saved = json.load(fh)
        for name, entry in saved.get("problems", {}).items():
            entry.setdefault("meta", saved.get("meta"))
            out["problems"][name] = entry

    for name in cfg["problems"]:
        _log(f"\n=== {name}, T = {T:g} ===")
        ex = get_example(name, t_end=T)
        n, m = ex.q0.size, ex.lam0.size
        q_exact = ex.exact(np.array([T]))[0][0]
        diag = Diagnostics(ex.problem, ex.args)
        H0 = diag.energy(0.0, ex.q0, ex.p0)
        records: list[RunRecord] = []
        t_prob = time.perf_counter()
        run_lobatto(ex, cfg, diag, q_exact, H0, records)
        ode = IndexReducedODE(ex.problem, ex.args, n, m)
        run_scipy(ex, cfg, ode, diag, q_exact, H0, records, "DOP853", cfg["dop853"])
        run_scipy(ex, cfg, ode, diag, q_exact, H0, records, "Radau", cfg["radau"])
        run_diffrax(ex, cfg, ode, diag, q_exact, H0, records)
        if ida_ok:
            run_ida(ex, cfg, diag, q_exact, H0, records)
        run_mp(ex, cfg, diag, q_exact, H0, records)
        wp_png = os.path.join(RESULTS_DIR, f"wp_{name}{suffix}.png")
        dg_png = os.path.join(RESULTS_DIR, f"diag_{name}{suffix}.png")
        reps = plot(name, records, T, wp_png, dg_png)
        for r in records:  # keep the time series of the plotted runs only (JSON size)
            if (r.solver, r.setting) not in reps:
                r.series = {}
        entry = {"meta": meta, "T": T, "n": n, "m": m, "q_exact_T": q_exact.tolist(), "H0": H0,
                 "records": [asdict(r) for r in records], "targets": targets(name, records),
                 "representatives": reps, "seconds": time.perf_counter() - t_prob,
                 "plots": [os.path.basename(wp_png), os.path.basename(dg_png)]}
        if name == "sleigh":
            entry["dynamics"] = sleigh_dynamics_note(ex, T)
        out["problems"][name] = entry
        _log(f"  ({entry['seconds']:.0f} s for {name})")
        with open(os.path.join(RESULTS_DIR, f"work_precision{suffix}.json"), "w") as fh:  # partial results
            json.dump(out, fh, default=float)

    # ---- table
    _log("\n" + "=" * 118)
    _log(f"{'problem':13s} {'solver':22s} {'setting':10s} {'err q(T)':>9s} {'wall [s]':>9s} {'1st call':>8s} "
         f"{'max|phi|':>9s} {'max|dH|':>9s} {'steps':>8s}  note")
    for name, entry in out["problems"].items():
        for r in entry["records"]:
            fc = f"{r['compile_and_run']:.2f}" if r["compile_and_run"] else ""
            _log(f"{name:13s} {r['solver']:22s} {r['setting']:10s} {r['err_q']:9.2e} {r['wall']:9.4f} {fc:>8s} "
                 f"{r['max_phi']:9.1e} {r['max_dH']:9.1e} {r['n_steps']:8d}  {r['message'][:40]}")
    _log("\nTargets (error <= 1e-8; lobattodae also max|phi| <= 1e-13):")
    for name, entry in out["problems"].items():
        tg = entry["targets"]
        def fmt(x):
            return "none reached the target" if x is None else f"{x['solver']} {x['setting']}: {x['wall']:.4f} s (err {x['err_q']:.1e}, max|phi| {x['max_phi']:.1e})"
        _log(f"  {name}: lobattodae {fmt(tg['lobattodae'])}")
        _log(f"  {name}: DOP853     {fmt(tg['dop853'])}")
        _log(f"  {name}: diffrax    {fmt(tg['diffrax'])}")
        if "speedup_vs_dop853" in tg:
            _log(f"  {name}: speed-up vs DOP853 {tg['speedup_vs_dop853']:.2f}x (target >= 10x: "
                 f"{'met' if tg['met_10x_vs_dop853'] else 'MISSED'})")
        if "speedup_vs_diffrax" in tg:
            _log(f"  {name}: speed-up vs diffrax {tg['speedup_vs_diffrax']:.2f}x (target > 1x: "
                 f"{'met' if tg['met_faster_than_diffrax'] else 'MISSED'})")
    meta["loadavg_end"] = os.getloadavg()
    meta["wall_seconds"] = time.perf_counter() - start
    path = os.path.join(RESULTS_DIR, f"work_precision{suffix}.json")
    with open(path, "w") as fh:
        json.dump(out, fh, default=float)
    _log(f"\nsaved {path} and the PNGs ({meta['wall_seconds']:.0f} s in all)")


if __name__ == "__main__":
    main()
