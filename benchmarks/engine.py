"""Engine benchmark (issue #9): the step loop against its speed limit and its competitors.

Six parts, all measured in one run of this script (absolute times on the shared 2-core
machines move by 2x from run to run: compare the RATIOS, each measured within one run,
best of >= 3 calls unless ``--quick``):

1. ``c_limit`` -- the C speed limit. ``<repo>/../shared/limit/knife_edge_c.c`` (the
   library's scheme written by hand in C for the knife edge) is built with
   ``gcc -O2 -march=native`` into a temporary directory and run as
   ``knife_edge_c 5 5000 1000 1`` (s = 5, N = 5000, T = 1000, Jacobian reuse), best of 3.
   lobattodae solves the same problem (knife edge, m = J = g = ω = 1, θ0 = v0 = 0) with the
   step loop already compiled: whole ``solve`` calls with the default method
   (``lam_start="auto"``: the paper's scheme plus the λ drift monitor, which the C code does
   not have), ``solve`` with ``lam_start="previous"`` (the C code's own scheme, Λ1 = λ0: the
   like-for-like row), and ``jax.jit(integrate)`` (the loop alone, default method), best of 7
   after a first (compiling) call; and the native step of the generated model
   (``mechanics.systems.knife_edge().native(s)``, generated C compiled at first use).
   Reported: µs/step of each, ours/C, and the errors against the closed form (max over q and
   p at T, as the C program prints, and over q alone).
2. ``work_precision`` -- cheapest run with max-norm error of q(T) <= 1e-8 at T = 1000, knife
   edge and falling disk in steady rolling (``falling-disk``). lobattodae s = 3, 4, 5
   (both ``lam_start`` variants where offered), constant steps: the smallest N meeting the
   error, found by a search over N (a probe, a prediction from the order 2s-2, then
   bisection to 3 %). diffrax Dopri8, jitted once, ``PIDController(rtol=atol=tol)``, the
   tolerance searched (steps of 10, then bisection in log tol to a factor 1.5) for each of
   a few PID coefficient sets from diffrax's documentation, the fastest kept. scipy
   ``solve_ivp(method="DOP853")``, tolerance searched likewise. Both ODE solvers integrate
   the index-reduced ODE (λ eliminated through the hidden constraint) written as a user
   of each would: a plain Python/NumPy right-hand side for scipy (knife edge by hand; the
   falling disk generated with SymPy ``lambdify``), the same formulas in ``jax.numpy`` for
   diffrax, both validated against the problem's own vector field to 1e-12 relative
   before timing (``lib.odes``; the solvers are ``lib.baselines``). Wall times after compilation, best of 3; ratios
   ours/diffrax and DOP853/ours; max ‖φ‖ over each solution (for the ODE solvers φ is
   evaluated on every output step).
3. ``first_call`` -- a fresh process with ``LOBATTODAE_NO_CACHE=1`` and no
   ``LOBATTODAE_CACHE_DIR`` (nor ``JAX_COMPILATION_CACHE_DIR``): ``import lobattodae``,
   the first ``solve`` (tracing + compilation + run) and a second one, for the falling
   disk and the knife edge (s = 3, 1000 steps); XLA compilations counted with
   ``jax_log_compiles``. Best of 3 processes (1 with ``--quick``).
4. ``recompile`` -- one process, knife edge, s = 3: ``solve`` with n_steps = 1000, 1000
   again, 1500, 3000, 777, another t_span, other ``args`` values (twice), other initial
   values; then ``integrate`` called eagerly (not under jit) twice with the same shapes.
   Each call's wall time and the XLA compilations it triggered.
5. ``size`` -- a chain of N_p nonholonomic particles in Cartesian coordinates
   (``lib.problems.particle_chain``, n = 3 N_p, m = N_p), n = 6, 21, 60, 120, 240 (n must be a
   multiple of 3: 21 stands for the 20 of the issue), s = 3, h = 0.05, 512 steps (128 for
   n > 60): µs per step (whole ``solve``, best of 3, and the compiled loop alone from
   ``stats["compile_and_run_time"]`` when present), Newton Jacobians and iterations per step,
   and each n's time per step over n = 6's (issue #26's target: n = 60 / n = 6 ≤ 20).
6. ``threading`` -- the knife edge (s = 5, N = 5000, T = 1000) and the n = 60 chain timed in
   subprocesses with the default XLA CPU settings, with XLA's single-thread flags (each
   candidate flag is first tried in a throw-away process: an unknown XLA flag aborts the
   process; the ones accepted by the installed jaxlib are used), and pinned to one CPU
   with ``taskset -c 0`` when available.

Usage (from the repository root)::

    .venv/bin/python benchmarks/engine.py               # full (~15-25 min on 2 cores)
    .venv/bin/python benchmarks/engine.py --quick       # smoke test (~2 min)
    .venv/bin/python benchmarks/engine.py --only c_limit,work_precision

Prints the machine, the exact command, the load average before and after, a line per
measurement and a Markdown summary; writes ``benchmarks/results/engine[_quick].json``
(with a timestamp and the git revision; ``--only`` updates the parts it ran in an
existing file). Exit status 1 when a part failed (its error is in the JSON and printed).
"""

from __future__ import annotations

import json
import math
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
import traceback
import warnings

import jax
import jax.numpy as jnp
import numpy as np

import lobattodae as L
from lib import cli
from lib.baselines import PID_SETS, Diffrax, scipy_solve
from lib.odes import reduced_ode, validate_ode
from lib.output import ROOT, child_env, child_result, loadavg, log, md_table, python_child, results_path, \
    run_meta, with_parts, write_json
from lib.problems import particle_chain
from lib.sweeps import search_min_steps, search_tolerance
from lib.timing import best_of, count_compiles
from lobattodae.examples import get_example

LIMIT_DIR = os.path.join(ROOT, "..", "shared", "limit")
TARGET_ERR = 1e-8
PARTS = ["c_limit", "work_precision", "first_call", "recompile", "size", "threading"]
#: Calls of lobattodae per row of part 1 (best of them): a call takes 0.05 s, and the best of 3
#: moved by 5 % from run to run on the 2-core machine.
C_LIMIT_REPEATS = 7
#: The start multipliers compared in part 2.
LAM_STARTS = ["auto", "previous", "consistent"]


def config(quick: bool) -> dict:
    if quick:
        return {
            "repeats": 2,
            "c_limit": {"s": 5, "N": 5000, "T": 1000.0, "c_repeats": 3},
            "wp": {"T": 100.0, "problems": ["knife-edge", "falling-disk"], "stages": [5], "variants": ["previous"],
                   "pids": PID_SETS[:1], "lob_probes": 2, "tol_probes": 4, "probe_budget_s": 5.0},
            "first_call": {"processes": 1, "cases": [("knife-edge", 3, 1000, 100.0)]},
            "recompile": {"T": 100.0},
            "size": {"n": [6, 21], "N": 128, "h": 0.05},
            "threading": {"knife": (5, 1000, 200.0), "chain_n": None, "chain_N": 128},
        }
    return {
        "repeats": 3,
        "c_limit": {"s": 5, "N": 5000, "T": 1000.0, "c_repeats": 3},
        "wp": {"T": 1000.0, "problems": ["knife-edge", "falling-disk"], "stages": [5, 4, 3], "variants": LAM_STARTS,
               "pids": PID_SETS, "lob_probes": 9, "tol_probes": 10, "probe_budget_s": 30.0},
        "first_call": {"processes": 3, "cases": [("falling-disk", 3, 1000, 50.0), ("knife-edge", 3, 1000, 100.0)]},
        "recompile": {"T": 100.0},
        "size": {"n": [6, 21, 60, 120, 240], "N": 512, "N_large": 128, "h": 0.05},
        "threading": {"knife": (5, 5000, 1000.0), "chain_n": 60, "chain_N": 256},
    }


# ------------------------------------------------------------------------------ helpers
def run_solve(problem, method, t_span, q0, p0, n_steps, args, lam0=None):
    """``lobattodae.solve`` with warnings recorded (returned), not printed."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        kw = {} if lam0 is None else {"lam0": lam0}
        sol = L.solve(problem, method, t_span, q0, p0, n_steps=n_steps, args=args, **kw)
    return sol, [str(w.message)[:200] for w in caught]


def newton_mean(sol):
    its = sol.stats.get("newton_iterations")
    return float(np.mean(its)) if its is not None and np.size(its) else None


def loop_us(sol, n: int) -> float | None:
    """µs per step in the compiled loop, where ``solve`` reports its time."""
    loop = sol.stats.get("compile_and_run_time")
    return None if loop is None else 1e6 * float(loop) / n


# ================================================================= 1. the C speed limit
_C_LINE = re.compile(r"jacobians (\d+)\s+s=(\d+) N=(\d+) T=(\S+) err (\S+) \|phi\| (\S+) lam_err (\S+)\s+(\S+) s\s+"
                     r"(\S+) us/step\s+(\S+) newton it/step")


def c_runs(s: int, N: int, T: float, repeats: int) -> tuple[list[dict], dict]:
    """The C program built with gcc into a temporary directory and run ``repeats`` times."""
    src = os.path.abspath(os.path.join(LIMIT_DIR, "knife_edge_c.c"))
    if not os.path.exists(src):
        raise FileNotFoundError(f"{src} not found (expected <repo>/../shared/limit/knife_edge_c.c)")
    if shutil.which("gcc") is None:
        raise RuntimeError("gcc not found: cannot build the C speed limit")
    gcc = subprocess.run(["gcc", "--version"], capture_output=True, text=True, timeout=30).stdout.splitlines()[0]
    with tempfile.TemporaryDirectory() as tmp:
        exe = os.path.join(tmp, "knife_edge_c")
        build = ["gcc", "-O2", "-march=native", "-o", exe, src, "-lm"]
        r = subprocess.run(build, capture_output=True, text=True, timeout=120)
        if r.returncode != 0:
            raise RuntimeError(f"building the C limit failed: {' '.join(build)}\n{r.stderr}")
        runs = []
        for _ in range(repeats):
            r = subprocess.run([exe, str(s), str(N), f"{T:g}", "1"], capture_output=True, text=True, timeout=300)
            m = _C_LINE.search(r.stdout)
            if r.returncode != 0 or not m:
                raise RuntimeError(f"knife_edge_c failed or printed something unexpected: {r.stdout}{r.stderr}")
            runs.append({"us_per_step": float(m.group(9)), "seconds": float(m.group(8)), "err": float(m.group(5)),
                         "phi": float(m.group(6)), "lam_err": float(m.group(7)), "jacobians": int(m.group(1)),
                         "newton_per_step": float(m.group(10)), "stdout": r.stdout.strip()})
    return runs, {"source": src, "gcc": gcc, "c_build": " ".join(build[:4] + ["knife_edge_c", "knife_edge_c.c", "-lm"])}


def part_c_limit(cfg: dict, repeats: int) -> dict:
    c = cfg["c_limit"]
    s, N, T = c["s"], c["N"], c["T"]
    runs, build = c_runs(s, N, T, c["c_repeats"])
    out: dict = {"s": s, "N": N, "T": T, **build}
    best_c = min(runs, key=lambda x: x["us_per_step"])
    out["c"] = {"us_per_step": best_c["us_per_step"], "all_us_per_step": [x["us_per_step"] for x in runs],
                "err_qp": best_c["err"], "phi": best_c["phi"], "jacobians": best_c["jacobians"],
                "newton_per_step": best_c["newton_per_step"], "stdout": best_c["stdout"]}
    log(f"  C ({out['c_build']}): {best_c['stdout']}")
    log(f"     best of {len(runs)}: {best_c['us_per_step']:.2f} µs/step (all: "
        + ", ".join(f"{x['us_per_step']:.2f}" for x in runs) + ")")

    # --- lobattodae on the same problem
    ex = get_example("knife-edge", m=1.0, J=1.0, g=1.0, omega=1.0, theta0=0.0, v0=0.0, x0=0.0, y0=0.0, t_end=T)
    same = (np.allclose(ex.q0, [0, 0, 0]) and np.allclose(ex.p0, [0, 0, 1]) and np.allclose(ex.lam0, [1.0]))
    out["same_initial_values_as_c"] = bool(same)
    if not same:
        raise RuntimeError(f"knife-edge example does not start where the C code does: q0={ex.q0}, p0={ex.p0}, "
                           f"lam0={ex.lam0} (C: q0=0, p0=(0,0,1), λ0=1)")
    method = L.LobattoIIIAIIIB(stages=s)
    out["method"], out["lam_start"] = repr(method), method.lam_start
    qe, pe, _ = ex.exact(np.array([T]))
    qe, pe = qe[0], pe[0]

    def errs(q, p):
        q, p = np.asarray(q), np.asarray(p)
        return float(max(np.max(np.abs(q - qe)), np.max(np.abs(p - pe)))), float(np.max(np.abs(q - qe)))

    tm = best_of(lambda: run_solve(ex.problem, method, (0.0, T), ex.q0, ex.p0, N, ex.args), max(C_LIMIT_REPEATS, repeats),
                 first=True)
    sol, warns = tm.result
    e_qp, e_q = errs(sol.q[-1], sol.p[-1])
    out["solve"] = {"first_call_s": tm.first, "wall_s": tm.best, "all_s": tm.times, "us_per_step": 1e6 * tm.best / N,
                    "us_per_step_in_loop": loop_us(sol, N), "err_qp": e_qp, "err_q": e_q,
                    "max_phi": float(np.max(sol.stats["constraint_residual"])), "newton_per_step": newton_mean(sol),
                    "jacobians": sol.stats.get("n_jacobians"), "warnings": warns[:2]}
    log(f"  lobattodae solve: first call {tm.first:.2f} s, then {1e6 * tm.best / N:.2f} µs/step "
        f"(best of {len(tm.times)}: " + ", ".join(f"{x:.3f}" for x in tm.times) + " s)"
        + ("" if loop_us(sol, N) is None else f", compiled loop {loop_us(sol, N):.2f} µs/step")
        + f"; err(q,p) {e_qp:.2e}, err(q) {e_q:.2e}, Newton {out['solve']['newton_per_step'] or math.nan:.2f}/step, "
        f"Jacobians {out['solve']['jacobians']}")

    # the C code's own scheme (Λ1 = λ0, no drift monitor): the like-for-like row
    previous = L.LobattoIIIAIIIB(stages=s, lam_start="previous")
    tp = best_of(lambda: run_solve(ex.problem, previous, (0.0, T), ex.q0, ex.p0, N, ex.args),
                 max(C_LIMIT_REPEATS, repeats), first=True)
    e_qp_p, e_q_p = errs(tp.result[0].q[-1], tp.result[0].p[-1])
    out["solve_previous"] = {"first_call_s": tp.first, "wall_s": tp.best, "all_s": tp.times,
                             "us_per_step": 1e6 * tp.best / N, "err_qp": e_qp_p, "err_q": e_q_p}
    log(f"  lobattodae solve, lam_start='previous': {1e6 * tp.best / N:.2f} µs/step (best of {len(tp.times)}); "
        f"err(q,p) {e_qp_p:.2e}")

    # the loop alone: jax.jit(integrate), compiled by a first call
    h = T / N
    integ = jax.jit(lambda q0, p0, lam0, args: L.integrate(ex.problem, method, 0.0, h, N, q0, p0, lam0, args))
    q0, p0, lam0 = (jnp.asarray(x, jnp.float64) for x in (ex.q0, ex.p0, ex.lam0))
    ti = best_of(lambda: integ(q0, p0, lam0, ex.args), max(C_LIMIT_REPEATS, repeats), first=True)
    q, p, lam, status = ti.result
    e_qp_i, e_q_i = errs(q[-1], p[-1])
    out["integrate_jit"] = {"first_call_s": ti.first, "wall_s": ti.best, "all_s": ti.times,
                            "us_per_step": 1e6 * ti.best / N, "err_qp": e_qp_i, "err_q": e_q_i, "status": int(status)}
    log(f"  lobattodae jax.jit(integrate): first call {ti.first:.2f} s, then {1e6 * ti.best / N:.2f} µs/step "
        f"(best of {len(ti.times)}); err(q,p) {e_qp_i:.2e}, status {int(status)}")
    # the native step of the generated model (lobattodae.mechanics: the same Lagrangian and constraint)
    from lobattodae import mechanics
    from lobattodae.mechanics import _native

    if _native.c_compiler() is not None:
        model = mechanics.systems.knife_edge()
        margs = model.args(m=1.0, J=1.0, g=1.0)
        native = model.native(s)
        tn = best_of(lambda: native.integrate(0.0, h, N, ex.q0, ex.p0, ex.lam0, margs), max(C_LIMIT_REPEATS, repeats),
                     first=True)
        e_qp_n, e_q_n = errs(tn.result.q[-1], tn.result.p[-1])
        out["native"] = {"first_call_s": tn.first, "wall_s": tn.best, "all_s": tn.times, "us_per_step": 1e6 * tn.best / N,
                         "err_qp": e_qp_n, "err_q": e_q_n, "newton_per_step": tn.result.n_newton / N,
                         "jacobians": tn.result.n_jacobians}
        log(f"  lobattodae native (mechanics.systems.knife_edge().native): first call {tn.first:.2f} s (C generated "
            f"and compiled), then {1e6 * tn.best / N:.2f} µs/step; err(q,p) {e_qp_n:.2e}")
    cu = best_c["us_per_step"]
    if "native" in out:
        out["ratio_native_over_c"] = out["native"]["us_per_step"] / cu
        log(f"  => native/C: {out['ratio_native_over_c']:.2f}x")
    out["ratio_solve_over_c"] = out["solve"]["us_per_step"] / cu
    out["ratio_integrate_over_c"] = out["integrate_jit"]["us_per_step"] / cu
    out["ratio_solve_previous_over_c"] = out["solve_previous"]["us_per_step"] / cu
    log(f"  => ours/C: solve {out['ratio_solve_over_c']:.2f}x, solve with the C code's scheme "
        f"{out['ratio_solve_previous_over_c']:.2f}x, jit(integrate) {out['ratio_integrate_over_c']:.2f}x")
    return out


# ============================================================= 2. work-precision, 1e-8
def _initial_n(s: int, T: float) -> int:
    """First probe of the N search: h = 0.2 (s=5), 0.08 (s=4), 0.015 (s=3) -- near the
    knife edge's answer at T = 1000; the order-based second probe corrects it."""
    h = {2: 0.002, 3: 0.015, 4: 0.08, 5: 0.2, 6: 0.35}.get(s, 0.2)
    return max(16, int(round(T / h)))


def wp_lobatto(ex, T, q_exact, s, variant, wcfg, repeats) -> dict:
    method = L.LobattoIIIAIIIB(stages=s, lam_start=variant)
    label = f"lobattodae s={s} ({variant} λ)"

    def err_of_n(n):
        try:
            sol, _ = run_solve(ex.problem, method, (0.0, T), ex.q0, ex.p0, n, ex.args, lam0=ex.lam0)
        except L.SolverError as exc:  # a failed Newton solve: N does not meet the target
            log(f"      probe N={n}: {type(exc).__name__}: {str(exc)[:120]}")
            return math.inf  # (any other exception -- a broken API -- propagates)
        e = float(np.max(np.abs(sol.q[-1] - q_exact))) if sol.success else math.inf
        log(f"      probe N={n}: err {e:.2e}")
        return e

    srch = search_min_steps(err_of_n, _initial_n(s, T), 2 * s - 2, TARGET_ERR,
                            max_probes=wcfg["lob_probes"], budget_s=wcfg["probe_budget_s"])
    rec = {"solver": label, "s": s, "lam_start": variant, "probes": srch.table()}
    if srch.best is None:
        rec.update(ok=False, message=srch.message)
        log(f"    {label}: {srch.message}")
        return rec
    N = srch.best
    # compiled already by the search unless its last probe used another chunk length
    tm = best_of(lambda: run_solve(ex.problem, method, (0.0, T), ex.q0, ex.p0, N, ex.args, lam0=ex.lam0), repeats,
                 first=True)
    sol, warns = tm.result
    err = float(np.max(np.abs(sol.q[-1] - q_exact)))
    loop = sol.stats.get("compile_and_run_time")
    rec.update(ok=bool(err <= TARGET_ERR), setting=f"N={N}", N=N, wall_s=tm.best, all_s=tm.times, err_q=err,
               max_phi=float(np.max(sol.stats["constraint_residual"])), us_per_step=1e6 * tm.best / N,
               loop_s=None if loop is None else float(loop), newton_per_step=newton_mean(sol),
               jacobians=sol.stats.get("n_jacobians"), warnings=warns[:2])
    log(f"    {label}: N={N} err {err:.2e} wall {tm.best:.3f} s ({1e6 * tm.best / N:.1f} µs/step) "
        f"max|φ| {rec['max_phi']:.1e}" + ("  [warning: " + warns[0][:80] + "]" if warns else ""))
    return rec


def wp_diffrax(ode, T, y0, q_exact, wcfg, repeats) -> dict:
    n = ode.n
    dfx = Diffrax(ode)
    compile_s = best_of(lambda: dfx.final(T, y0, 1e-6, PID_SETS[0]), 1).best  # the first call compiles
    recs = []
    for pid in wcfg["pids"]:
        def err_of_tol(tol, pid=pid):
            yT, nacc, nsteps, ok = dfx.final(T, y0, tol, pid)
            return float(np.max(np.abs(yT[:n] - q_exact))) if ok else math.inf

        srch = search_tolerance(err_of_tol, 1e-10, TARGET_ERR, tol_min=1e-15, max_probes=wcfg["tol_probes"],
                                budget_s=wcfg["probe_budget_s"])
        rec = {"solver": f"diffrax Dopri8 PID(p={pid[0]:g}, i={pid[1]:g})", "pid": pid, "probes": srch.table()}
        recs.append(rec)
        if srch.best is None:
            rec.update(ok=False, message=srch.message)
            log(f"    {rec['solver']}: {srch.message}")
            continue
        tol = srch.best
        tm = best_of(lambda: dfx.final(T, y0, tol, pid), repeats)
        yT, nacc, nsteps, ok = tm.result
        err = float(np.max(np.abs(yT[:n] - q_exact)))
        ts, ys = dfx.trajectory(T, y0, tol, pid, nsteps)
        phi = float(np.max(np.abs(ode.phi(ys[:, :n], ys[:, n:]))))
        rec.update(ok=bool(ok and err <= TARGET_ERR), setting=f"tol={tol:g}", tol=tol, wall_s=tm.best, all_s=tm.times,
                   err_q=err, max_phi=phi, steps=nacc, steps_tried=nsteps, phi_points=len(ts))
        log(f"    {rec['solver']}: rtol=atol={tol:g} err {err:.2e} wall {tm.best:.4f} s, {nacc} steps "
            f"({nsteps} tried), max|φ| {phi:.1e}")
    good = [r for r in recs if r.get("ok")]
    return {"compile_s": compile_s, "runs": recs, "best": min(good, key=lambda r: r["wall_s"]) if good else None}


def wp_scipy(ode, T, y0, q_exact, wcfg, repeats) -> dict:
    n = ode.n

    def err_of_tol(tol):
        r = scipy_solve(ode, "DOP853", (0.0, T), y0, tol)
        return float(np.max(np.abs(r.y[:n, -1] - q_exact))) if r.success else math.inf

    srch = search_tolerance(err_of_tol, 1e-10, TARGET_ERR, tol_min=2.3e-14, max_probes=wcfg["tol_probes"],
                            budget_s=wcfg["probe_budget_s"])
    rec = {"solver": "scipy DOP853", "rhs": ode.how, "probes": srch.table()}
    if srch.best is None:
        rec.update(ok=False, message=srch.message)
        log(f"    scipy DOP853: {srch.message}")
        return rec
    tol = srch.best
    tm = best_of(lambda: scipy_solve(ode, "DOP853", (0.0, T), y0, tol), repeats)
    r = tm.result
    err = float(np.max(np.abs(r.y[:n, -1] - q_exact)))
    phi = float(np.max(np.abs(ode.phi(r.y[:n].T, r.y[n:].T))))
    rec.update(ok=bool(r.success and err <= TARGET_ERR), setting=f"tol={tol:g}", tol=tol, wall_s=tm.best,
               all_s=tm.times, err_q=err, max_phi=phi, steps=len(r.t) - 1, nfev=int(r.nfev))
    log(f"    scipy DOP853: rtol=atol={tol:g} err {err:.2e} wall {tm.best:.3f} s, {len(r.t) - 1} steps, "
        f"{r.nfev} RHS calls, max|φ| {phi:.1e}")
    return rec


def _guarded(errors: list, label: str, fn, *args):
    """``fn(*args)``, or None with the exception recorded in ``errors`` (a part goes on)."""
    try:
        return fn(*args)
    except Exception as exc:
        errors.append(f"{label}: {type(exc).__name__}: {exc}")
        log("    FAILED " + errors[-1])
        return None


def part_work_precision(cfg: dict, repeats: int) -> dict:
    wcfg = cfg["wp"]
    T = wcfg["T"]
    out: dict = {"T": T, "target_err_q": TARGET_ERR, "variants": wcfg["variants"], "problems": {}}
    for name in wcfg["problems"]:
        log(f"  -- {name}, T = {T:g}")
        ex = get_example(name, t_end=T)
        q_exact = ex.exact(np.array([T]))[0][0]
        y0 = np.r_[ex.q0, ex.p0]
        res: dict = {"lobattodae": [], "errors": []}
        out["problems"][name] = res
        # competitors' right-hand sides, validated first
        ode = reduced_ode(name, ex.args)
        val = validate_ode(ode, ex.problem, ex.args, ex.q0, ex.p0)
        res["reduced_ode"] = {"how": ode.how, "build_s": ode.build_seconds, "validation": val}
        log(f"    index-reduced ODE: {ode.how}; validation vs the problem's vector field: "
            f"rhs {val['rhs_numpy_rel_err']:.1e} (NumPy), {val['rhs_jax_rel_err']:.1e} (JAX), φ {val['phi_rel_err']:.1e} "
            f"relative -> {'OK' if val['ok'] else 'FAILED'}")
        for s in wcfg["stages"]:
            for variant in wcfg["variants"]:
                rec = _guarded(res["errors"], f"lobattodae s={s} {variant}", wp_lobatto, ex, T, q_exact, s, variant,
                               wcfg, repeats)
                if rec is not None:
                    res["lobattodae"].append(rec)
        if val["ok"]:
            for key, fn in (("diffrax", wp_diffrax), ("dop853", wp_scipy)):
                res[key] = _guarded(res["errors"], key, fn, ode, T, y0, q_exact, wcfg, repeats)
        else:
            res["errors"].append("index-reduced ODE does not match the problem's vector field: ODE solvers not run")
        out.setdefault("errors", []).extend(f"{name}: {e}" for e in res["errors"])
        good = [r for r in res["lobattodae"] if r.get("ok")]
        ours = min(good, key=lambda r: r["wall_s"]) if good else None
        s5 = [r for r in good if r["s"] == 5]
        ours5 = min(s5, key=lambda r: r["wall_s"]) if s5 else None
        dfx = (res.get("diffrax") or {}).get("best")
        dop = res.get("dop853") if (res.get("dop853") or {}).get("ok") else None
        res["summary"] = sm = {
            "ours_best": _brief(ours), "ours_s5": _brief(ours5), "diffrax": _brief(dfx), "dop853": _brief(dop),
            "ours_over_diffrax": ours["wall_s"] / dfx["wall_s"] if ours and dfx else None,
            "dop853_over_ours": dop["wall_s"] / ours["wall_s"] if ours and dop else None,
            "ours_s5_over_diffrax": ours5["wall_s"] / dfx["wall_s"] if ours5 and dfx else None,
            "dop853_over_ours_s5": dop["wall_s"] / ours5["wall_s"] if ours5 and dop else None,
        }
        log(f"    => cheapest lobattodae: {_fmt_brief(sm['ours_best'])}; diffrax: {_fmt_brief(sm['diffrax'])}; "
            f"DOP853: {_fmt_brief(sm['dop853'])}; ours/diffrax {_fx(sm['ours_over_diffrax'])}, "
            f"DOP853/ours {_fx(sm['dop853_over_ours'])}")
    return out


def _brief(r):
    if not r:
        return None
    return {k: r.get(k) for k in ("solver", "setting", "wall_s", "err_q", "max_phi", "us_per_step", "steps")}


def _fmt_brief(b):
    return "none met the target" if not b else f"{b['solver']} {b['setting']} {b['wall_s']:.3g} s"


def _fx(x, spec=".2f"):
    return "–" if x is None else f"{x:{spec}}x"


# ========================================================= 3. first call, fresh process
FIRST_CALL_SCRIPT = r"""
import sys, time, warnings
t0 = time.perf_counter()
import lobattodae as L
from lobattodae.examples import get_example
t_import = time.perf_counter() - t0
import jax
from lib.output import print_result
from lib.timing import count_compiles
name, s, N, T = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), float(sys.argv[4])
ex = get_example(name, t_end=T)
m = L.LobattoIIIAIIIB(stages=s)
warnings.simplefilter("ignore")
with count_compiles() as first:
    t0 = time.perf_counter()
    sol = L.solve(ex.problem, m, (0.0, T), ex.q0, ex.p0, n_steps=N, args=ex.args)
    t_first = time.perf_counter() - t0
with count_compiles() as second:
    t0 = time.perf_counter()
    sol = L.solve(ex.problem, m, (0.0, T), ex.q0, ex.p0, n_steps=N, args=ex.args)
    t_second = time.perf_counter() - t0
print_result({"import_s": t_import, "first_solve_s": t_first, "second_solve_s": t_second,
              "xla_compilations_first": first.summary()["xla_compilations"],
              "xla_compile_s_first": first.summary()["xla_compile_s"],
              "xla_compilations_second": second.summary()["xla_compilations"], "success": bool(sol.success),
              "jax_cache_dir": str(jax.config.jax_compilation_cache_dir)})
"""


def part_first_call(cfg: dict, repeats: int) -> dict:
    fc = cfg["first_call"]
    out: dict = {"env": {"LOBATTODAE_NO_CACHE": "1", "LOBATTODAE_CACHE_DIR": None, "JAX_COMPILATION_CACHE_DIR": None},
                 "cases": {}}
    for name, s, N, T in fc["cases"]:
        key = f"{name} s={s} N={N}"
        runs = []
        for _ in range(fc["processes"]):
            r = child_result(python_child(FIRST_CALL_SCRIPT, name, str(s), str(N), str(T)), child_env(), 900.0)
            if "error" in r:
                out["cases"][key] = {"error": r["error"]}
                out.setdefault("errors", []).append(f"{key}: {r['error'][-300:]}")
                log(f"  {key}: FAILED {r['error'][-600:]}")
                break
            runs.append(r)
        if not runs:
            continue
        best = min(runs, key=lambda r: r["import_s"] + r["first_solve_s"])
        best["import_plus_first_s"] = best["import_s"] + best["first_solve_s"]
        best["processes"] = len(runs)
        best["all_import_plus_first_s"] = [r["import_s"] + r["first_solve_s"] for r in runs]
        out["cases"][key] = best
        log(f"  fresh process, {key} (T={T:g}): import {best['import_s']:.2f} s, first solve {best['first_solve_s']:.2f} s "
            f"({best['xla_compilations_first']} XLA compilations, {best['xla_compile_s_first']:.2f} s in XLA), "
            f"second solve {best['second_solve_s']:.3f} s ({best['xla_compilations_second']} compilations); "
            f"best of {len(runs)} process(es); persistent cache dir: {best['jax_cache_dir']}")
    return out


# =============================================================== 4. recompilation
def _compiles(label: str, call) -> dict:
    with count_compiles() as cc:
        t0 = time.perf_counter()
        success = call()
        wall = time.perf_counter() - t0
    row = {"call": label, "wall_s": wall, "success": success, **cc.summary()}
    log(f"  {row['call']:55s} {wall * 1e3:9.1f} ms   XLA compilations {row['xla_compilations']:3d} "
        f"({row['xla_compile_s']:.2f} s), tracings {row['tracings']}")
    return row


def part_recompile(cfg: dict, repeats: int) -> dict:
    T = cfg["recompile"]["T"]
    method = L.LobattoIIIAIIIB(stages=3)
    base = get_example("knife-edge", t_end=T)
    other_args = get_example("knife-edge", m=2.0, J=3.0, g=0.5, t_end=T)
    other_init = get_example("knife-edge", omega=2.0, v0=0.5, t_end=T)
    plan = [
        ("n_steps=1000 (first call)", base, (0.0, T), 1000),
        ("n_steps=1000 again", base, (0.0, T), 1000),
        ("n_steps=1500", base, (0.0, T), 1500),
        ("n_steps=3000", base, (0.0, T), 3000),
        ("n_steps=777", base, (0.0, T), 777),
        (f"t_span=(0, {T / 2:g}), n_steps=1000", base, (0.0, T / 2), 1000),
        ("args m=2, J=3, g=0.5, n_steps=1000", other_args, (0.0, T), 1000),
        ("the same args again", other_args, (0.0, T), 1000),
        ("other q0, p0 (ω=2, v0=0.5), n_steps=1000", other_init, (0.0, T), 1000),
    ]
    rows = [_compiles(f"solve: {label}", lambda ex=ex, t_span=t_span, n=n: bool(
        run_solve(ex.problem, method, t_span, ex.q0, ex.p0, n, ex.args)[0].success)) for label, ex, t_span, n in plan]
    h = T / 1000
    for k in (1, 2):
        rows.append(_compiles(f"integrate eagerly (not under jit), call {k}", lambda: int(jax.block_until_ready(
            L.integrate(base.problem, method, 0.0, h, 1000, base.q0, base.p0, base.lam0, base.args))[3]) == 0))
    return {"example": "knife-edge", "s": 3, "T": T, "calls": rows}


# ======================================================================= 5. size
def part_size(cfg: dict, repeats: int) -> dict:
    sc = cfg["size"]
    h = sc["h"]
    method = L.LobattoIIIAIIIB(stages=3)
    rows = []
    for n in sc["n"]:
        if n % 3:
            raise ValueError(f"n = {n} is not a multiple of 3")
        N = sc["N"] if n <= 60 else sc.get("N_large", sc["N"])  # n = 240: 25 ms per step
        problem, q0, p0, args = particle_chain(n // 3)
        tm = best_of(lambda: run_solve(problem, method, (0.0, N * h), q0, p0, N, args), repeats, first=True)
        sol = tm.result[0]
        jac = sol.stats.get("n_jacobians")
        row = {"n": n, "m": n // 3, "N": N, "first_call_s": tm.first, "wall_s": tm.best, "all_s": tm.times,
               "us_per_step": 1e6 * tm.best / N, "us_per_step_in_loop": loop_us(sol, N),
               "jacobians_per_step": None if jac is None else float(jac) / N, "newton_per_step": newton_mean(sol),
               "success": bool(sol.success), "max_phi": float(np.max(sol.stats["constraint_residual"]))}
        rows.append(row)
        log(f"  chain n={n:3d} (m={n // 3:2d}): {row['us_per_step']:9.1f} µs/step"
            + ("" if row["us_per_step_in_loop"] is None else f" ({row['us_per_step_in_loop']:.1f} in the compiled loop)")
            + f", Jacobians/step {row['jacobians_per_step'] if jac is not None else math.nan:.3f}, "
            f"Newton/step {row['newton_per_step'] or math.nan:.2f}, first call {tm.first:.2f} s")
    out = {"s": 3, "h": h, "N": sc["N"], "rows": rows,
           "note": "n must be a multiple of 3 (x, y, z per particle): n = 21 stands for the issue's n = 20; "
                   "each row's own N is in the row"}
    if len(rows) >= 2:
        out["ratios_over_first"] = {f"n={r['n']} / n={rows[0]['n']}": r["us_per_step"] / rows[0]["us_per_step"]
                                    for r in rows[1:]}
        out["ratio_last_over_first"] = rows[-1]["us_per_step"] / rows[0]["us_per_step"]
        out["ratio_label"] = f"n={rows[-1]['n']} / n={rows[0]['n']}"
        log("  => time per step " + ", ".join(f"{k}: {v:.1f}x" for k, v in out["ratios_over_first"].items()))
    return out


# ================================================================== 6. threading
THREADING_SCRIPT = r"""
import json, sys, warnings
import lobattodae as L
from lobattodae.examples import get_example
from lib.output import print_result
from lib.problems import particle_chain
from lib.timing import best_of
cfg = json.loads(sys.argv[1])
warnings.simplefilter("ignore")
out = {}
s, N, T = cfg["knife"]
ex = get_example("knife-edge", t_end=T)
m = L.LobattoIIIAIIIB(stages=s)
tm = best_of(lambda: L.solve(ex.problem, m, (0.0, T), ex.q0, ex.p0, n_steps=N, args=ex.args), cfg["repeats"],
             first=True)
out["knife"] = {"us_per_step": 1e6 * tm.best / N, "all_s": tm.times}
if cfg.get("chain_n"):
    problem, q0, p0, args = particle_chain(cfg["chain_n"] // 3)
    m3, Nc = L.LobattoIIIAIIIB(stages=3), cfg["chain_N"]
    tm = best_of(lambda: L.solve(problem, m3, (0.0, 0.05 * Nc), q0, p0, n_steps=Nc, args=args), cfg["repeats"],
                 first=True)
    out["chain"] = {"us_per_step": 1e6 * tm.best / Nc, "all_s": tm.times}
print_result(out)
"""

XLA_SINGLE_THREAD_CANDIDATES = ["--xla_cpu_multi_thread_eigen=false", "--intra_op_parallelism_threads=1"]


def accepted_xla_flags() -> tuple[list[str], dict]:
    """Each candidate flag tried alone in a throw-away process (an unknown XLA flag aborts)."""
    ok, verdict = [], {}
    probe = "import jax, jax.numpy as jnp; print(float(jax.jit(lambda x: x @ x)(jnp.ones((8, 8))).sum()))"
    for flag in XLA_SINGLE_THREAD_CANDIDATES:
        r = subprocess.run(python_child(probe), capture_output=True, text=True, timeout=120,
                           env=child_env(XLA_FLAGS=flag))
        tail = (r.stderr.strip().splitlines() or [""])[-1][:200]
        verdict[flag] = "accepted" if r.returncode == 0 else f"rejected ({tail})"
        if r.returncode == 0:
            ok.append(flag)
    return ok, verdict


def part_threading(cfg: dict, repeats: int) -> dict:
    tc = cfg["threading"]
    flags, verdict = accepted_xla_flags()
    for f, v in verdict.items():
        log(f"  XLA flag {f}: {v}")
    wcfg = {"knife": list(tc["knife"]), "chain_n": tc["chain_n"], "chain_N": tc["chain_N"], "repeats": max(3, repeats)}
    variants = [("default (no XLA_FLAGS)", None, [])]
    if flags:
        variants.append((f"XLA_FLAGS='{' '.join(flags)}'", " ".join(flags), []))
    if shutil.which("taskset") and (os.cpu_count() or 1) > 1:
        variants.append(("taskset -c 0 (one CPU), no XLA_FLAGS", None, ["taskset", "-c", "0"]))
    out = {"flags_tried": verdict, "config": wcfg, "variants": {}}
    for label, xla, prefix in variants:
        r = child_result(prefix + python_child(THREADING_SCRIPT, json.dumps(wcfg)), child_env(XLA_FLAGS=xla), 900.0)
        out["variants"][label] = r
        if "error" in r:
            out.setdefault("errors", []).append(f"{label}: {r['error'][-300:]}")
            log(f"  {label}: FAILED {r['error'][-600:]}")
            continue
        log(f"  {label}: knife edge s={tc['knife'][0]} {r['knife']['us_per_step']:.2f} µs/step"
            + (f", chain n={tc['chain_n']} s=3 {r['chain']['us_per_step']:.1f} µs/step" if "chain" in r else ""))
    d = out["variants"].get("default (no XLA_FLAGS)", {})
    for label, r in out["variants"].items():
        if "error" in r or "error" in d or r is d:
            continue
        r["knife_ratio_to_default"] = r["knife"]["us_per_step"] / d["knife"]["us_per_step"]
        if "chain" in r and "chain" in d:
            r["chain_ratio_to_default"] = r["chain"]["us_per_step"] / d["chain"]["us_per_step"]
    return out


# ==================================================================== summary
def summary_markdown(res: dict) -> str:
    parts = []
    p = res.get("c_limit")
    if p and "error" not in p:
        parts.append(f"**1. C speed limit** (knife edge, s = {p['s']}, N = {p['N']}, T = {p['T']:g})\n\n" + md_table(
            ["", "µs/step", "ours/C", "err (q,p) at T", "err q at T"],
            [["C (knife_edge_c, gcc -O2 -march=native)", p["c"]["us_per_step"], 1.0, p["c"]["err_qp"], None],
             ["lobattodae solve (compiled)", p["solve"]["us_per_step"], p["ratio_solve_over_c"], p["solve"]["err_qp"],
              p["solve"]["err_q"]],
             *([["lobattodae solve, lam_start='previous' (the C code's scheme)", p["solve_previous"]["us_per_step"],
                 p["ratio_solve_previous_over_c"], p["solve_previous"]["err_qp"], p["solve_previous"]["err_q"]]]
               if "solve_previous" in p else []),
             ["lobattodae jax.jit(integrate)", p["integrate_jit"]["us_per_step"], p["ratio_integrate_over_c"],
              p["integrate_jit"]["err_qp"], p["integrate_jit"]["err_q"]]]))
    p = res.get("work_precision")
    if p and "error" not in p:
        rows = []
        for name, r in p["problems"].items():
            sm = r.get("summary", {})
            for key, lab in (("ours_best", "lobattodae (cheapest)"), ("ours_s5", "lobattodae s=5"),
                             ("diffrax", "diffrax Dopri8"), ("dop853", "scipy DOP853")):
                b = sm.get(key) or {}
                rows.append([name, lab, f"{b['solver']} {b['setting']}" if b else None, b.get("wall_s"),
                             b.get("err_q"), b.get("max_phi")])
            rows.append([name, "**ratios**", f"ours/diffrax {_fx(sm.get('ours_over_diffrax'))}, "
                         f"DOP853/ours {_fx(sm.get('dop853_over_ours'))} (s=5: {_fx(sm.get('ours_s5_over_diffrax'))}, "
                         f"{_fx(sm.get('dop853_over_ours_s5'))})", None, None, None])
        parts.append(f"**2. Work–precision**, T = {p['T']:g}, max-norm error of q(T) ≤ {p['target_err_q']:g}\n\n"
                     + md_table(["problem", "solver", "setting", "wall s", "err q(T)", "max ‖φ‖"], rows))
    p = res.get("first_call")
    if p and "error" not in p:
        rows = [[k, v.get("import_s"), v.get("first_solve_s"), v.get("xla_compilations_first"),
                 v.get("xla_compile_s_first"), v.get("second_solve_s")] if "error" not in v else [k, "FAILED"] + [None] * 4
                for k, v in p["cases"].items()]
        parts.append("**3. First call** (fresh process, no persistent cache)\n\n" + md_table(
            ["case", "import s", "first solve s", "XLA compilations", "XLA compile s", "second solve s"], rows))
    p = res.get("recompile")
    if p and "error" not in p:
        rows = [[r["call"], f"{1e3 * r['wall_s']:.1f}", r["xla_compilations"], f"{r['xla_compile_s']:.2f}"]
                for r in p["calls"]]
        parts.append(f"**4. Recompilation** (knife edge, s = {p['s']}, one process)\n\n" + md_table(
            ["call", "wall ms", "XLA compilations", "XLA compile s"], rows))
    p = res.get("size")
    if p and "error" not in p:
        first = p["rows"][0]
        rows = [[r["n"], r["m"], r.get("N", p["N"]), r["us_per_step"], r["us_per_step_in_loop"],
                 r["us_per_step"] / first["us_per_step"], r["jacobians_per_step"], r["newton_per_step"]]
                for r in p["rows"]]
        parts.append(f"**5. Size** (particle chain, s = 3, h = {p['h']})\n\n" + md_table(
            ["n", "m", "steps", "µs/step (solve)", "µs/step (loop)", f"/ n={first['n']}", "Jacobians/step",
             "Newton/step"], rows))
    p = res.get("threading")
    if p and "error" not in p:
        rows = [[lab, "FAILED", None, None, None] if "error" in r else
                [lab, r["knife"]["us_per_step"], r.get("knife_ratio_to_default"),
                 (r.get("chain") or {}).get("us_per_step"), r.get("chain_ratio_to_default")]
                for lab, r in p["variants"].items()]
        parts.append("**6. XLA CPU threading** (subprocesses)\n\n" + md_table(
            ["variant", f"knife edge s={p['config']['knife'][0]} µs/step", "vs default",
             f"chain n={p['config']['chain_n']} µs/step" if p["config"]["chain_n"] else "chain (not run)",
             "vs default"], rows))
    for name in PARTS:
        if isinstance(res.get(name), dict) and "error" in res[name]:
            parts.append(f"**{name}: FAILED** — {res[name]['error'].splitlines()[0]}")
        for e in (res.get(name) or {}).get("errors", []):
            parts.append(f"**{name}: a measurement FAILED** — {e.splitlines()[0]}")
    return "\n\n".join(parts)


# ======================================================================= main
RUNNERS = {"c_limit": part_c_limit, "work_precision": part_work_precision, "first_call": part_first_call,
           "recompile": part_recompile, "size": part_size, "threading": part_threading}
TITLES = {"c_limit": "1. C speed limit (knife edge)", "work_precision": "2. work-precision, error <= 1e-8",
          "first_call": "3. first call in a fresh process", "recompile": "4. recompilation",
          "size": "5. time per step vs size (particle chain)", "threading": "6. XLA CPU threading"}


def main(argv=None) -> int:
    ap = cli.parser(__doc__, "quick", "pin_cpu", "watchdog", watchdog={"default": 3600.0},
                    quick={"help": "small N, fewer repeats and searches (smoke test, ~2 min)"})
    ap.add_argument("--only", default=",".join(PARTS), help=f"comma-separated parts: {','.join(PARTS)}")
    a = ap.parse_args(argv)
    parts = [p.strip() for p in a.only.split(",") if p.strip()]
    unknown = [p for p in parts if p not in PARTS]
    if unknown:
        ap.error(f"unknown part(s) {unknown}; choose from {PARTS}")
    cli.start(a)
    cfg = config(a.quick)
    repeats = cfg["repeats"]
    start = time.perf_counter()
    jnp.zeros(1).block_until_ready()  # JAX's backend starts before anything is timed
    meta = run_meta(cwd=os.getcwd(), PYTHONPATH=os.environ.get("PYTHONPATH", ""), quick=a.quick, parts=parts,
                    pin_cpu=a.pin_cpu)
    machine = meta["machine"]
    log(f"# lobattodae engine benchmark (issue #9){' --quick' if a.quick else ''}")
    log(f"command: {meta['command']}   (cwd {os.getcwd()})")
    log(f"machine: {machine['platform']}, {machine['cpu']}, {machine['cpu_count']} CPUs ({machine['cpus_usable']} "
        f"usable); python {machine['python']}, jax {machine['versions']['jax']}, diffrax "
        f"{machine['versions']['diffrax']}, scipy {machine['versions']['scipy']}; XLA_FLAGS={machine['XLA_FLAGS']!r}")
    log(f"lobattodae {meta['lobattodae_revision']} from {meta['lobattodae_path']}")
    log(f"load average at start: {meta['loadavg_start']}  (2-core shared machine: compare ratios, not times)")
    res: dict = {"meta": meta}
    failed = []
    for name in parts:
        log(f"\n== {TITLES[name]} ==")
        t0, load0 = time.perf_counter(), loadavg()
        try:
            res[name] = RUNNERS[name](cfg, repeats)
        except Exception as exc:
            tb = traceback.format_exc()
            res[name] = {"error": f"{type(exc).__name__}: {exc}\n{tb}"}
            failed.append(name)
            log(f"  PART {name} FAILED: {type(exc).__name__}: {exc}")
            log("\n".join("    " + line for line in tb.strip().splitlines()[-5:]))
        if res[name].get("errors") and name not in failed:  # some measurements of the part failed
            failed.append(name)
        res[name]["part_meta"] = {"seconds": time.perf_counter() - t0, "loadavg_start": load0, "loadavg_end": loadavg()}
    meta["loadavg_end"] = loadavg()
    meta["wall_seconds"] = time.perf_counter() - start
    meta["failed_parts"] = failed

    path = results_path(f"engine{'_quick' if a.quick else ''}.json")
    write_json(with_parts(path, res, parts, PARTS), path)

    log("\n## Summary\n")
    log(f"{meta['date']}, {machine['cpu']} ({machine['cpu_count']} CPUs), lobattodae {meta['lobattodae_revision']}, "
        f"load average {meta['loadavg_start']} -> {meta['loadavg_end']}, {meta['wall_seconds']:.0f} s"
        + (", QUICK (smoke test: small N, fewer repeats, T = 100 in part 2)" if a.quick else ""))
    log("")
    log(summary_markdown(res))
    if failed:
        log(f"FAILED parts: {', '.join(failed)}")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
