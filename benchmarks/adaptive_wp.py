"""Work-precision diagrams of adaptive steps (issue #10): error of q(T) against wall time.

Problems, T = 1000 (``--quick``: T = 100):

* ``sleigh`` -- the Chaplygin sleigh (``get_example("sleigh")``); reference: its closed
  form (x, y from the example's Gauss-Legendre quadrature, accurate to round-off).
* ``falling-disk-general`` -- the falling rolling disk in general nutating motion; no closed
  form. Reference: ``lib.references.falling_disk`` (the reduced ODE in 80-bit extended
  precision, Gauss-Legendre s = 5, h = 0.05, compensated summation; the same with h = 0.1
  bounds its error, ``ref_diff``), computed once and cached in
  ``results/adaptive_wp_reference.json``. Float64 solvers cannot get much closer than ~1e-9
  on this problem at T = 1000: round-off is amplified ~1e7 (two float64 runs that differ only
  in rounding differ by ~1e-9 at T = 1000, by ~7e-12 at T = 100), so every curve has a floor
  there.

Solvers (every point: best of up to 3 calls after a warm-up call of the same solver; a
call longer than ``REPEAT_LIMIT_S`` = 5 s is not repeated; a solver stops tightening once
one call takes longer than ``--budget`` seconds (default 20) or its next call is predicted
to take > 3x that, once its error stops falling below 1e-6 (best error not improved 2x over
three settings: the round-off floor; a plateau above 1e-6 is saturation at loose tolerances,
not a floor) or drops below 2e-13; ``lib.sweeps.Sweep``):

* **lobattodae adaptive**, s = 3 … 6 (``LobattoIIIAIIIB(stages=s)``; ``--stages`` for others): ``solve`` with
  rtol = atol = tol, ``save_every="final"``, ``lam0`` given, ``throw=False``; the wall time
  of the whole ``solve`` call (validation, compiled loop, building the ``Solution``). The
  loop alone is in ``loop_s`` (``stats["compile_and_run_time"]``). max ‖φ‖∞ over every
  step point from ``stats["max_constraint_residual"]``; steps, rejected steps, Newton
  iterations and Jacobians from ``stats``. tol = 1e-2 ... 1e-13 in half decades.
* **lobattodae constant steps**, s = 4, 5 and 6 (``n_steps`` = 250·2^(k/2)); the s with the
  smaller time at error 1e-8 is plotted ("best s").
* **lobattodae reversible control**, s = 5, falling disk only (it has the reversing symmetry
  ``(q, p) -> (q, -p)``): ``ReversibleStepSize()`` (density ‖(f, g)‖, Hairer & Söderlind)
  with the symmetric scheme, ``first_step`` = 0.5·2^(-k/2) (it fixes ε = h₀ σ(y₀)).
* **scipy DOP853** (rtol = atol = tol, 1e-3 ... 2.3e-14 = scipy's floor) on the index-reduced
  ODE with a plain Python/NumPy right-hand side (``lib.odes``: by hand for the sleigh,
  SymPy-generated for the disk), validated against the problem's own vector field; every
  step is kept (the default), and max ‖φ‖ is evaluated on them.
* **diffrax Dopri8** on the same ODE in ``jax.numpy``, ``PIDController(rtol = atol = tol)``,
  jit-compiled once (``lib.baselines.Diffrax``), for each of ``lib.baselines.PID_SETS``
  (diffrax's documented coefficient sets), tol = 1e-3 ... 1e-15; the set with the smallest
  time at error 1e-8 is plotted (the others are in the JSON). ‖φ‖ over every step is
  recomputed (untimed) for its point closest to 1e-8.
* **SUNDIALS IDA** on the index-2 DAE, ``y = (q, p, λ)``, λ excluded from the error test
  (``lib.baselines.IDA``), with the residual and exact Jacobian in plain Python/NumPy
  (``lib.odes.numpy_dae``; validated against the problem's residual), tol = 1e-3 ... 1e-12.

Error: max over the components of |q(T) - q_ref| (max-norm, absolute; |q| reaches ~1.4e3
on the sleigh, ~1.0e3 on the disk, whose heading angle grows). Time at error 1e-8: on each
solver's Pareto front (points not beaten in both error and time), log time interpolated
linearly in log error between the two points bracketing 1e-8.

``--cpu-threads 1`` gives XLA's CPU thread pool one thread for the whole process
(:func:`lobattodae.set_cpu_threads`), which speeds up lobattodae and leaves the other
solvers as they are; every solver runs under the same setting.

Usage (repository root)::

    PYTHONPATH=src .venv/bin/python benchmarks/adaptive_wp.py [--quick] [--problems sleigh] [--cpu-threads 1]
    PYTHONPATH=src .venv/bin/python benchmarks/adaptive_wp.py --replot

Writes ``benchmarks/results/adaptive_wp[_quick].json`` (``--problems`` merges into it) and
``benchmarks/results/awp_sleigh[_quick].png``, ``awp_falling-disk[_quick].png``.
"""

from __future__ import annotations

import math
import sys
import time

import numpy as np

import lobattodae as L
from lib import cli, references
from lib.baselines import IDA, PID_SETS, Diffrax, ida_available, scipy_solve
from lib.odes import numpy_dae, reduced_ode, validate_dae, validate_ode
from lib.output import loadavg, log, md_table, merged, pyplot, read_json, results_path, run_meta, save_figure, \
    write_json
from lib.sweeps import Sweep, half_decades, solution_point, time_at
from lib.timing import best_of
from lobattodae.examples import get_example

PROBLEMS = ("sleigh", "falling-disk-general")
#: Problems with a reversing symmetry (q, p) -> (q, -p), on which reversible step-size control applies.
REVERSIBLE = ("falling-disk-general",)
PNG_NAME = {"sleigh": "awp_sleigh", "falling-disk-general": "awp_falling-disk"}
TARGET = 1e-8
REPEAT_LIMIT_S = 5.0
LOW_ERR = 2e-13
#: Errors that stop falling above this are not a round-off floor: at loose tolerances on the
#: falling disk (T = 1000) the phase is lost and the error saturates at O(1..100) for several
#: settings before it starts to fall (s = 4, 5 adaptive, Dopri8), so the sweep goes on there.
FLOOR_ABOVE = 1e-6
#: This file's names of a sweep point's measurements (the sweep's ``error``, ``time``, ``cpu_time``).
NAMES = {"error": "err", "time": "wall_s", "cpu_time": "cpu_s"}


#: The adaptive runs' s (``--stages`` for others: s = 7, 8 were no faster on the sleigh at error
#: 1e-8, ``RESULTS.md`` 2026-11-29 08:26).
STAGES = (3, 4, 5, 6)


def config(quick: bool) -> dict:
    if quick:
        return {"T": 100.0, "repeats": 1, "stages": [3, 5], "const_stages": [5],
                "lob_tols": [1e-2, 1e-4, 1e-6, 1e-8, 1e-10], "const_N": [64, 256, 1024],
                "dop_tols": [1e-3, 1e-5, 1e-7, 1e-9, 1e-11], "dfx_tols": [1e-3, 1e-5, 1e-7, 1e-9, 1e-11],
                "pids": PID_SETS[:1], "ida_tols": [1e-3, 1e-5, 1e-7], "ref_h": (0.1, 0.05),
                "rev_stages": [5], "rev_h0": [0.4, 0.2, 0.1]}
    return {"T": 1000.0, "repeats": 3, "stages": list(STAGES), "const_stages": [4, 5, 6],
            "lob_tols": half_decades(1e-2, 1e-13), "const_N": [int(round(250 * 2 ** (k / 2))) for k in range(0, 15)],
            "dop_tols": half_decades(1e-3, 1e-13) + [2.3e-14], "dfx_tols": half_decades(1e-3, 1e-15),
            "pids": PID_SETS, "ida_tols": half_decades(1e-3, 1e-12), "ref_h": (0.1, 0.05),
            "rev_stages": [5], "rev_h0": [round(0.5 * 2 ** (-k / 2), 4) for k in range(0, 9)]}


def reference(name: str, ex, T: float, cfg: dict) -> dict:
    if name == "sleigh":
        return {"q_ref": ex.exact(np.array([T]))[0][0], "how": "closed form (x, y by the example's quadrature)"}
    return references.cached(results_path("adaptive_wp_reference.json"), f"{name} T={T:g} h={cfg['ref_h'][1]:g}",
                             lambda h: references.falling_disk(ex, T, h), cfg["ref_h"])


def sweep(label, settings, call, post, warm, cfg, budget, setting="tol") -> dict:
    """:class:`lib.sweeps.Sweep` with this benchmark's rules, its points in this file's names."""
    out = Sweep(label, budget=budget, repeats=cfg["repeats"], repeat_limit=REPEAT_LIMIT_S, floor=FLOOR_ABOVE,
                low=LOW_ERR, setting=setting).run(settings, call, post, warm=warm)
    out["points"] = [{NAMES.get(k, k): v for k, v in p.items()} for p in out["points"]]
    return out


# ------------------------------------------------------------------------- the solvers
def lobattodae_sweep(label, ex, T, q_ref, cfg, budget, s, settings, options, warm, setting="tol", **fixed) -> dict:
    """``solve`` with ``options(x)`` for each setting x (and ``fixed``), ``save_every="final"``,
    error of q(T); ``solve`` with ``options(warm)`` compiles first."""
    method = L.LobattoIIIAIIIB(stages=s)

    def call(x):
        return L.solve(ex.problem, method, (0.0, T), ex.q0, ex.p0, args=ex.args, lam0=ex.lam0, save_every="final",
                       throw=False, **options(x), **fixed)

    def post(sol):
        return solution_point(sol, lambda sol: np.max(np.abs(np.asarray(sol.q[-1]) - q_ref)))

    return sweep(label, settings, call, post, lambda: call(warm), cfg, budget, setting)


def dop853(ode, T, y0, q_ref, cfg, budget):
    n = ode.n

    def post(r):
        return {"error": float(np.max(np.abs(r.y[:n, -1] - q_ref))) if r.success else math.inf,
                "ok": bool(r.success), "message": "" if r.success else str(r.message)[:200], "steps": len(r.t) - 1,
                "nfev": int(r.nfev), "max_phi": float(np.max(np.abs(ode.phi(r.y[:n].T, r.y[n:].T))))}

    def call(tol):
        return scipy_solve(ode, "DOP853", (0.0, T), y0, tol)

    return sweep("scipy DOP853", cfg["dop_tols"], call, post, lambda: call(1e-6), cfg, budget)


def dopri8(ode, T, y0, q_ref, cfg, budget):
    n = ode.n
    dfx = Diffrax(ode)
    compile_s = best_of(lambda: dfx.final(T, y0, 1e-6, PID_SETS[0]), 1).best  # the first call compiles

    def post(out):
        yT, nacc, nsteps, ok = out
        return {"error": float(np.max(np.abs(yT[:n] - q_ref))) if ok else math.inf, "ok": ok, "steps": nacc,
                "rejected": nsteps - nacc}

    sweeps = []
    for pid in cfg["pids"]:
        sw = sweep(f"diffrax Dopri8 PID(p={pid[0]:g}, i={pid[1]:g})", cfg["dfx_tols"],
                   lambda tol, pid=pid: dfx.final(T, y0, tol, pid), post, None, cfg, budget)
        sw["pid"] = pid
        sw["time_at_1e-8"] = time_at(sw["points"], TARGET, "err", "wall_s")
        sweeps.append(sw)
    timed = [s for s in sweeps if s["time_at_1e-8"] is not None]
    best = min(timed, key=lambda s: s["time_at_1e-8"]) if timed else sweeps[0]
    # ‖φ‖ at every step of the point closest to 1e-8 (untimed; compiles a saving variant)
    pts = [p for p in best["points"] if math.isfinite(p["err"]) and p["err"] > 0 and math.isfinite(p["wall_s"])]
    if pts:
        p = min(pts, key=lambda p: abs(math.log(p["err"] / TARGET)))
        ts, ys = dfx.trajectory(T, y0, p["tol"], best["pid"], p["steps"] + p["rejected"])
        p["max_phi"] = float(np.max(np.abs(ode.phi(ys[:, :n], ys[:, n:]))))
        best["phi_at"] = p["tol"]
        log(f"    {best['label']}: tol {p['tol']:g}: max|φ| over {len(ts)} step points {p['max_phi']:.1e}")
    return {"compile_s": compile_s, "sweeps": sweeps, "best_pid": best["pid"], "best": best}


def ida(dae, phi, T, ex, q_ref, cfg, budget):
    n = dae.n
    solver = IDA(dae)

    def call(tol):
        return solver.solve((0.0, T), ex.q0, ex.p0, ex.lam0, tol)

    def post(r):
        ok = r.success and abs(float(r.t[-1]) - T) <= 1e-9 * T
        return {"error": float(np.max(np.abs(r.y[-1, :n] - q_ref))) if ok else math.inf, "ok": bool(ok),
                "message": "" if ok else r.message[:200], "steps": r.n_steps, "nfev": r.nfev, "njev": r.njev,
                "max_phi": float(np.max(np.abs(phi(r.y[:, :n], r.y[:, n:2 * n]))))}

    return sweep("SUNDIALS IDA", cfg["ida_tols"], call, post, lambda: call(1e-4), cfg, budget)


# ------------------------------------------------------------------------------ driver
def run_problem(name: str, cfg: dict, budget: float) -> dict:
    T = cfg["T"]
    t_start = time.perf_counter()
    entry = {"T": T, "loadavg_start": loadavg()}
    ex = get_example(name, t_end=T)
    ref = reference(name, ex, T, cfg)
    q_ref = ref["q_ref"]
    entry["reference"] = {k: (v.tolist() if isinstance(v, np.ndarray) else v) for k, v in ref.items()}
    y0 = np.r_[ex.q0, ex.p0]
    ode = reduced_ode(name, ex.args)
    val = validate_ode(ode, ex.problem, ex.args, ex.q0, ex.p0)
    dae = numpy_dae(name, ex.args)
    val_dae = validate_dae(dae, ex.problem, ex.args, ex.q0, ex.p0, ex.lam0)
    entry["reduced_ode"] = {"how": ode.how, "validation": val}
    entry["ida_dae"] = {"how": dae.how, "validation": val_dae}
    log(f"  reduced ODE ({ode.how}): validation {'OK' if val['ok'] else 'FAILED'} "
        f"(rhs {val['rhs_numpy_rel_err']:.1e}/{val['rhs_jax_rel_err']:.1e}, φ {val['phi_rel_err']:.1e}); "
        f"IDA residual ({dae.how}): {'OK' if val_dae['ok'] else 'FAILED'} "
        f"(res {val_dae['res_rel_err']:.1e}, jac {val_dae['jac_rel_err']:.1e})")
    runs: dict = {}
    for s in cfg["stages"]:
        runs[f"adaptive s={s}"] = lobattodae_sweep(f"lobattodae adaptive s={s}", ex, T, q_ref, cfg, budget, s,
                                                   cfg["lob_tols"], lambda tol: {"rtol": tol, "atol": tol}, 1e-6)
    for s in cfg["const_stages"]:
        runs[f"constant s={s}"] = lobattodae_sweep(f"lobattodae constant s={s}", ex, T, q_ref, cfg, budget, s,
                                                   cfg["const_N"], lambda n: {"n_steps": int(n)}, cfg["const_N"][0],
                                                   "N")
    for s in cfg["rev_stages"] if name in REVERSIBLE else ():
        # the symmetric scheme's control (default density ‖(f, g)‖); first_step sets ε = h₀ σ(y₀)
        runs[f"reversible s={s}"] = lobattodae_sweep(f"lobattodae reversible s={s}", ex, T, q_ref, cfg, budget, s,
                                                     cfg["rev_h0"], lambda h0: {"first_step": h0}, cfg["rev_h0"][0],
                                                     "first_step", controller=L.ReversibleStepSize())
    if val["ok"]:
        runs["DOP853"] = dop853(ode, T, y0, q_ref, cfg, budget)
        runs["Dopri8"] = dopri8(ode, T, y0, q_ref, cfg, budget)
    ok_ida, entry["ida"] = ida_available()
    if ok_ida and val_dae["ok"]:
        runs["IDA"] = ida(dae, ode.phi, T, ex, q_ref, cfg, budget)
    entry["runs"] = runs
    entry["summary"] = summarize(runs)
    entry["loadavg_end"] = loadavg()
    entry["seconds"] = time.perf_counter() - t_start
    return entry


def curve(runs, key):
    r = runs.get(key)
    if r is None:
        return None
    return r["best"] if key == "Dopri8" else r


def summarize(runs) -> dict:
    t = {key: time_at(curve(runs, key)["points"], TARGET, "err", "wall_s") for key in runs}

    def fastest(*kinds):
        reached = {k: v for k, v in t.items() if k.startswith(kinds) and v is not None}
        return min(reached, key=reached.get) if reached else None

    def ratio(a, b):
        a, b = t.get(a) if a else None, t.get(b) if b else None
        return a / b if a is not None and b is not None else None

    best_ad, best_co, best_any = fastest("adaptive"), fastest("constant"), fastest("adaptive", "constant", "reversible")
    return {"time_at_1e-8": t, "ours": best_ad, "ours_constant": best_co,
            "ours_over_dopri8": ratio(best_ad, "Dopri8"), "ours_over_dop853": ratio(best_ad, "DOP853"),
            "ours_over_ida": ratio(best_ad, "IDA"), "constant_over_dopri8": ratio(best_co, "Dopri8"),
            "adaptive_over_constant": ratio(best_ad, best_co), "ours_any": best_any,
            "any_over_dopri8": ratio(best_any, "Dopri8"), "any_over_dop853": ratio(best_any, "DOP853")}


STYLE = {"adaptive s=3": ("#9ecae1", "o", "-"), "adaptive s=4": ("#4292c6", "s", "-"),
         "adaptive s=5": ("#08306b", "D", "-"), "adaptive s=6": ("#6a51a3", "p", "-"),
         "adaptive s=7": ("#bcbddc", "h", "-"), "adaptive s=8": ("#54278f", "H", "-"),
         "reversible s=5": ("#2ca02c", "*", "-."), "DOP853": ("#ff7f0e", "^", "-"),
         "Dopri8": ("#d62728", "v", "-"), "IDA": ("#9467bd", "P", "-")}


def _label(key: str, c: dict) -> str:
    if key == "Dopri8":
        return f"diffrax Dopri8, PID(p={c['pid'][0]:g}, i={c['pid'][1]:g})"
    if key in ("DOP853", "IDA"):
        return {"DOP853": "scipy DOP853 (NumPy rhs)", "IDA": "SUNDIALS IDA (index 2, NumPy residual)"}[key]
    kind = key.split()[0]
    return f"lobattodae {key}" + {"adaptive": "", "constant": " (n_steps)", "reversible": " (ReversibleStepSize)"}[kind]


def plot(name: str, entry: dict, path: str) -> None:
    plt = pyplot()
    runs, sm = entry["runs"], entry["summary"]
    fig, (ax, ax2) = plt.subplots(1, 2, figsize=(13, 5.2), gridspec_kw={"width_ratios": [3, 2]})
    keys = [k for k in runs if k.startswith("adaptive")] + ([sm["ours_constant"]] if sm.get("ours_constant") else []) \
        + [k for k in runs if k.startswith("reversible")] + [k for k in ("DOP853", "Dopri8", "IDA") if k in runs]
    for key in keys:
        c = curve(runs, key)
        pts = [p for p in c["points"] if math.isfinite(float(p["err"])) and math.isfinite(float(p["wall_s"]))
               and float(p["err"]) > 0]
        if not pts:
            continue
        color, marker, ls = STYLE.get(key, ("black", "x", "--"))
        label = _label(key, c)
        ax.loglog([p["wall_s"] for p in pts], [max(p["err"], 1e-16) for p in pts], ls, color=color, marker=marker,
                  ms=5, label=label)
        ph = [(p["wall_s"], p["max_phi"]) for p in pts if isinstance(p.get("max_phi"), float)]
        if ph:
            ax2.loglog(*zip(*ph), ls, color=color, marker=marker, ms=5, label=label)
    ax.axhline(TARGET, color="gray", lw=1, ls=":")
    ax.text(ax.get_xlim()[0], TARGET, " 1e-8", va="bottom", color="gray", fontsize=8)
    ax2.axhline(1e-13, color="gray", lw=1, ls=":")
    if "ref_diff" in entry["reference"]:
        ax.axhspan(1e-17, max(entry["reference"]["ref_diff"], 1e-16), color="0.9", zorder=0)
    ax.set_ylim(top=1e-1)
    title = {"sleigh": "Chaplygin sleigh", "falling-disk-general": "falling disk, general motion"}[name]
    ax.set_title(f"{title}, T = {entry['T']:g}: error of q(T)")
    ax.set_xlabel("wall time per solve [s] (best of 3, compilation excluded)")
    ax.set_ylabel("max |q(T) − q_ref|")
    ax2.set_title("max ‖φ‖∞ over the step points")
    ax2.set_xlabel("wall time [s]")
    ax.legend(fontsize=7.5, loc="lower left")
    ax.grid(True, which="major", alpha=0.3)
    ax2.grid(True, which="major", alpha=0.3)
    la = entry.get("loadavg_start")
    pool = (entry.get("meta", {}).get("cpu_threads") or {}).get("PJRT_NPROC")
    fig.text(0.01, 0.005, f"2-core shared x86_64, load average at start {la[0] if la else '?'}, "
             f"XLA CPU pool: {pool + ' thread(s)' if pool else 'default'}; "
             "lobattodae: whole solve() call; Dopri8 ‖φ‖ at one tolerance only", fontsize=7, color="gray")
    fig.tight_layout(rect=(0, 0.02, 1, 1))
    save_figure(fig, path)


def ratio_table(out: dict) -> str:
    rows = []
    for name, e in out["problems"].items():
        sm = e["summary"]
        t = sm["time_at_1e-8"]
        ms = lambda k: "–" if k is None or t.get(k) is None else f"{1e3 * t[k]:.1f} ms"  # noqa: E731
        run = lambda k: f"{sm[k]} ({ms(sm[k])})" if sm.get(k) else "–"  # noqa: E731
        r = lambda k: "–" if sm.get(k) is None else f"{sm[k]:.2f}"  # noqa: E731
        rows.append([name, run("ours") if sm["ours"] else "not reached", run("ours_constant"), ms("Dopri8"),
                     ms("DOP853"), ms("IDA"), r("ours_over_dopri8"), r("ours_over_dop853"), r("ours_over_ida"),
                     r("adaptive_over_constant"), run("ours_any"), r("any_over_dopri8"), r("any_over_dop853")])
    return md_table(["problem", "ours adaptive (best s)", "ours constant", "Dopri8", "DOP853", "IDA",
                     "adaptive/Dopri8", "adaptive/DOP853", "adaptive/IDA", "adaptive/constant",
                     "best of ours", "best/Dopri8", "best/DOP853"], rows)


def main(argv=None) -> int:
    ap = cli.parser(__doc__, "quick", "replot", "pin_cpu", "cpu_threads", "watchdog",
                    quick={"help": "T = 100, fewer settings, 1 call each"})
    ap.add_argument("--problems", nargs="+", choices=PROBLEMS, default=list(PROBLEMS))
    ap.add_argument("--budget", type=float, default=20.0, help="stop a solver's sweep after a call this long [s]")
    ap.add_argument("--stages", type=int, nargs="+", help=f"the adaptive runs' s (default {' '.join(map(str, STAGES))})")
    a = cli.start(ap.parse_args(argv))
    suffix = "_quick" if a.quick else ""
    path = results_path(f"adaptive_wp{suffix}.json")
    if a.replot:
        out = read_json(path)
        for name, e in out["problems"].items():
            plot(name, e, results_path(f"{PNG_NAME[name]}{suffix}.png"))
        log(ratio_table(out))
        return 0
    cfg = config(a.quick)
    if a.stages:
        cfg["stages"] = sorted(set(a.stages))
    start = time.perf_counter()
    meta = run_meta(ida=ida_available()[1], budget_s=a.budget, repeat_limit_s=REPEAT_LIMIT_S, config=cfg,
                    pin_cpu=a.pin_cpu)
    log(f"adaptive_wp: {meta['command']}  (load average {meta['loadavg_start']})")
    for name in a.problems:
        log(f"\n=== {name}, T = {cfg['T']:g} ===")
        e = run_problem(name, cfg, a.budget)
        out = merged(path, "problems", {name: e}, meta)
        write_json(out, path)  # after each problem
        plot(name, out["problems"][name], results_path(f"{PNG_NAME[name]}{suffix}.png"))
        log(f"  ({e['seconds']:.0f} s for {name})")
    meta["loadavg_end"] = loadavg()
    meta["wall_seconds"] = time.perf_counter() - start
    out = merged(path, "problems", {}, meta)
    write_json(out, path)
    log("\nWall time at max|q(T) − q_ref| = 1e-8 (interpolated on each solver's Pareto front, log-log):\n")
    log(ratio_table(read_json(path)))
    log(f"\n({meta['wall_seconds']:.0f} s in all)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
