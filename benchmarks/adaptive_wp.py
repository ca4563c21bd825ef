"""Work-precision diagrams of adaptive steps (issue #10): error of q(T) against wall time.

Problems, T = 1000 (``--quick``: T = 100):

* ``sleigh`` -- the Chaplygin sleigh (``get_example("sleigh")``); reference: its closed
  form (x, y from the example's Gauss-Legendre quadrature, accurate to round-off).
* ``falling-disk-general`` -- the falling rolling disk in general nutating motion; no closed
  form. Reference: the index-reduced ODE (``_common.falling_disk_ode``'s SymPy expressions,
  evaluated with NumPy in 80-bit extended precision, ``np.longdouble``, eps = 1.1e-19)
  integrated with the 5-stage Gauss-Legendre method (order 10, coefficients from mpmath at
  40 digits), constant steps h = 0.05, fixed-point stage iteration to round-off and
  compensated summation; the same integration with h = 0.1 bounds its error (``ref_diff``).
  Computed once and cached in ``results/adaptive_wp_reference.json``. Float64 solvers
  cannot get much closer than ~1e-9 on this problem at T = 1000: round-off is amplified
  ~1e7 (two float64 runs that differ only in rounding differ by ~1e-9 at T = 1000, by
  ~7e-12 at T = 100), so every curve has a floor there.

Solvers (every point: best of up to 3 calls after a warm-up call of the same solver; a
call longer than ``REPEAT_LIMIT_S`` = 5 s is not repeated; a solver stops tightening once
one call takes longer than ``--budget`` seconds (default 20) or its next call is predicted
to take > 3x that, once its error stops falling below 1e-6 (best error not improved 2x over
three settings: the round-off floor; a plateau above 1e-6 is saturation at loose tolerances,
not a floor) or drops below 2e-13):

* **lobattodae adaptive**, s = 3, 4, 5, 6 (``LobattoIIIAIIIB(stages=s)``): ``solve`` with
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
* **scipy DOP853** (``solve_ivp``, rtol = atol = tol, 1e-3 ... 2.3e-14 = scipy's floor) on
  the index-reduced ODE with a plain Python/NumPy right-hand side (by hand for the sleigh,
  SymPy-generated for the disk), validated against the library's JAX vector field;
  every step is kept (the default), and max ‖φ‖ is evaluated on them.
* **diffrax Dopri8** on the same ODE in ``jax.numpy``, ``PIDController(rtol = atol = tol)``,
  jit-compiled once (``_common.DiffraxDopri8``), for each of ``engine.PID_SETS`` (diffrax's
  documented coefficient sets), tol = 1e-3 ... 1e-15; the set with the smallest time at
  error 1e-8 is plotted (the others are in the JSON). ‖φ‖ over every step is recomputed
  (untimed) for its point closest to 1e-8.
* **SUNDIALS IDA** (scikit-sundae) on the index-2 DAE, ``y = (q, p, λ)``, λ excluded from
  the error test (``baselines.IDABaseline``), with the residual and exact Jacobian in plain
  Python/NumPy (``baselines.IDANumpy``, ``_common.numpy_dae``; validated against the
  library's residual), tol = 1e-3 ... 1e-12.

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

import argparse
import datetime
import json
import math
import os
import sys
import time
import warnings

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
try:
    import lobattodae as L  # noqa: N812
except ImportError:  # pragma: no cover
    sys.path.insert(0, os.path.join(HERE, "..", "src"))
    import lobattodae as L  # noqa: N812
from lobattodae.examples import get_example  # noqa: E402

import _common as C  # noqa: E402
from baselines import IDANumpy, ida_available, time_best  # noqa: E402
from engine import PID_SETS  # noqa: E402

RESULTS_DIR = os.path.join(HERE, "results")
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
log = C.log


def half_decades(hi: float, lo: float) -> list[float]:
    k0, k1 = round(-2 * math.log10(hi)), round(-2 * math.log10(lo))
    return [float(f"{10 ** (-k / 2):.3g}") for k in range(k0, k1 + 1)]


def config(quick: bool) -> dict:
    if quick:
        return {"T": 100.0, "repeats": 1, "stages": [3, 5], "const_stages": [5],
                "lob_tols": [1e-2, 1e-4, 1e-6, 1e-8, 1e-10], "const_N": [64, 256, 1024],
                "dop_tols": [1e-3, 1e-5, 1e-7, 1e-9, 1e-11], "dfx_tols": [1e-3, 1e-5, 1e-7, 1e-9, 1e-11],
                "pids": PID_SETS[:1], "ida_tols": [1e-3, 1e-5, 1e-7], "ref_h": (0.1, 0.05),
                "rev_stages": [5], "rev_h0": [0.4, 0.2, 0.1]}
    return {"T": 1000.0, "repeats": 3, "stages": [3, 4, 5, 6], "const_stages": [4, 5, 6],
            "lob_tols": half_decades(1e-2, 1e-13), "const_N": [int(round(250 * 2 ** (k / 2))) for k in range(0, 15)],
            "dop_tols": half_decades(1e-3, 1e-13) + [2.3e-14], "dfx_tols": half_decades(1e-3, 1e-15),
            "pids": PID_SETS, "ida_tols": half_decades(1e-3, 1e-12), "ref_h": (0.1, 0.05),
            "rev_stages": [5], "rev_h0": [round(0.5 * 2 ** (-k / 2), 4) for k in range(0, 9)]}


# ------------------------------------------------------------------------- reference
def _gauss_legendre(s: int, dps: int = 40):
    """Gauss-Legendre coefficients (A, b) in np.longdouble, computed with mpmath."""
    import mpmath as mp

    mp.mp.dps = dps
    x0 = np.polynomial.legendre.leggauss(s)[0]
    c = [(1 + mp.findroot(lambda z: mp.legendre(s, z), mp.mpf(float(x)))) / 2 for x in x0]

    def ell(j):
        return lambda t: mp.fprod([(t - c[k]) / (c[j] - c[k]) for k in range(s) if k != j])

    ld = lambda v: np.longdouble(mp.nstr(v, 30))  # noqa: E731  (strtold: full extended precision)
    A = np.array([[ld(mp.quad(ell(j), [0, c[i]])) for j in range(s)] for i in range(s)])
    b = np.array([ld(mp.quad(ell(j), [0, 1])) for j in range(s)])
    return A, b


def _disk_extended(ex, T: float, h: float) -> tuple[np.ndarray, dict]:
    """q(T) of the falling disk from Gauss-Legendre s = 5 in np.longdouble (see the module
    docstring); returns (q as float64 hi + lo parts stacked, info)."""
    import sympy as sp

    q, p, prm, exprs, _ = C._falling_disk_sympy()
    f = sp.lambdify([q, p, prm], exprs, "numpy", cse=True)
    params = tuple(np.longdouble(float(getattr(ex.args, k))) for k in ("m", "R", "g", "I1", "I3"))

    def F(Y):
        out = f([Y[:, i] for i in range(5)], [Y[:, 5 + i] for i in range(5)], params)
        return np.stack([np.broadcast_to(np.asarray(o, dtype=np.longdouble), (Y.shape[0],)) for o in out], axis=1)

    A, b = _gauss_legendre(5)
    y = np.r_[ex.q0, ex.p0].astype(np.longdouble)
    comp = np.zeros_like(y)
    N = int(round(T / h))
    hh = np.longdouble(T) / N
    eps = np.finfo(np.longdouble).eps
    K = np.tile(F(y[None])[0], (5, 1))
    its, t0 = 0, time.perf_counter()
    for _ in range(N):
        prev = np.inf
        for _ in range(60):
            Kn = F(y[None] + hh * (A @ K))
            d = float(np.max(np.abs(Kn - K)))
            K = Kn
            its += 1
            if d <= 4 * eps * float(np.max(np.abs(K))) or d >= prev:
                break
            prev = d
        inc = hh * (b @ K) - comp  # compensated (Kahan) summation of the increments
        y_new = y + inc
        comp = (y_new - y) - inc
        y = y_new
    hi = y[:5].astype(np.float64)
    lo = (y[:5] - hi.astype(np.longdouble)).astype(np.float64)
    return np.stack([hi, lo]), {"h": float(hh), "steps": N, "stage_iterations_per_step": its / N,
                                "seconds": time.perf_counter() - t0}


def reference(name: str, ex, T: float, cfg: dict) -> dict:
    if name == "sleigh":
        return {"q_ref": ex.exact(np.array([T]))[0][0], "how": "closed form (x, y by the example's quadrature)"}
    path = os.path.join(RESULTS_DIR, "adaptive_wp_reference.json")
    cache = {}
    if os.path.exists(path):
        with open(path) as fh:
            cache = json.load(fh)
    key = f"{name} T={T:g} h={cfg['ref_h'][1]:g}"
    if key not in cache:
        log(f"  computing the extended-precision reference ({key}; cached afterwards)")
        coarse, info_c = _disk_extended(ex, T, cfg["ref_h"][0])
        fine, info_f = _disk_extended(ex, T, cfg["ref_h"][1])
        diff = (fine[0].astype(np.longdouble) + fine[1]) - (coarse[0].astype(np.longdouble) + coarse[1])
        cache[key] = {"q_ref_hi": fine[0].tolist(), "q_ref_lo": fine[1].tolist(),
                      "ref_diff": float(np.max(np.abs(diff))), "fine": info_f, "coarse": info_c,
                      "how": "Gauss-Legendre s = 5 (order 10) in np.longdouble on the index-reduced ODE, "
                             f"h = {info_f['h']:g}; ref_diff = max|q(h={info_c['h']:g}) - q(h={info_f['h']:g})|",
                      "date": datetime.datetime.now().isoformat(timespec="seconds")}
        C.write_json(cache, path)
    e = cache[key]
    log(f"  reference: {e['how']}; ref_diff {e['ref_diff']:.1e}")
    return {"q_ref": np.asarray(e["q_ref_hi"]) + np.asarray(e["q_ref_lo"]), "how": e["how"],
            "ref_diff": e["ref_diff"]}


# -------------------------------------------------------------------------- sweeping
class Sweep:
    """Runs one solver over a list of settings with the timing and stopping rules of the
    module docstring. ``run(setting) -> dict`` with at least ``err`` (inf on failure)."""

    def __init__(self, label: str, budget: float, repeats: int):
        self.label, self.budget, self.repeats = label, budget, repeats
        self.points: list[dict] = []
        self.stopped = ""

    def go(self, settings, run, warm=None, key="tol"):
        if warm is not None:
            t0 = time.perf_counter()
            try:
                warm()
            except Exception as exc:  # a failed warm-up is recorded, the sweep continues
                log(f"    {self.label}: warm-up failed: {type(exc).__name__}: {exc}")
            self.warmup_s = time.perf_counter() - t0
        best_err, since_improved, last_t, prev_t = math.inf, 0, None, None
        for st in settings:
            if last_t is not None and prev_t is not None and last_t > 0.5:
                pred = last_t * max(1.0, last_t / prev_t)
                if pred > 3 * self.budget:
                    self.stopped = f"next call predicted to take {pred:.0f} s (> 3x the {self.budget:g} s budget)"
                    break
            try:
                wall, k, rec = time_best(lambda: run(st), self.repeats, REPEAT_LIMIT_S)
                rec.update(cpu_s=time_best.last_cpu)
            except Exception as exc:
                wall, k, rec = math.nan, 1, {"err": math.inf, "message": f"{type(exc).__name__}: {str(exc)[:200]}"}
            rec.update({key: st, "wall_s": wall, "repeats": k})
            self.points.append(rec)
            e = rec["err"]
            log(f"    {self.label} {key}={st:g}: err {e:.2e}  {wall:.4g} s ({k}x)"
                + (f"  {rec['steps']} steps" if "steps" in rec else "")
                + (f" ({rec['rejected']} rejected)" if "rejected" in rec else "")
                + (f"  {rec['newton_per_step']} Newton it/step" if "newton_per_step" in rec else "")
                + (f"  max|φ| {rec['max_phi']:.1e}" if "max_phi" in rec else "")
                + (f"  [{rec['message']}]" if rec.get("message") else ""))
            prev_t, last_t = last_t, wall
            if np.isfinite(wall) and wall > self.budget:
                self.stopped = f"a call took {wall:.0f} s (> {self.budget:g} s budget)"
                break
            if e < best_err / 2:
                best_err, since_improved = e, 0
            elif np.isfinite(best_err):
                since_improved += 1
            if since_improved >= 3 and best_err <= FLOOR_ABOVE:
                self.stopped = f"error floor (best {best_err:.1e} not improved 2x over three settings)"
                break
            if e <= LOW_ERR:
                self.stopped = f"error {e:.1e} below the range"
                break
        if self.stopped:
            log(f"    {self.label}: stopped: {self.stopped}")
        return {"label": self.label, "points": self.points, "stopped": self.stopped,
                "warmup_s": getattr(self, "warmup_s", None)}


def _finite(p) -> bool:
    """Point with a finite, positive error and a finite time (the JSON stores inf as "inf")."""
    return math.isfinite(float(p["err"])) and math.isfinite(float(p["wall_s"])) and float(p["err"]) > 0


def pareto(points):
    pts = sorted((p for p in points if _finite(p)), key=lambda p: p["wall_s"])
    front, best = [], math.inf
    for p in pts:
        if p["err"] < best:
            front.append(p)
            best = p["err"]
    return front  # time increasing, error decreasing


def time_at(points, target=TARGET):
    """Interpolated wall time at error ``target`` on the Pareto front (log-log), or None."""
    front = pareto(points)
    for a, b in zip(front, front[1:]):
        if a["err"] >= target >= b["err"]:
            if a["err"] == b["err"]:
                return a["wall_s"]
            w = (math.log(target) - math.log(a["err"])) / (math.log(b["err"]) - math.log(a["err"]))
            return math.exp(math.log(a["wall_s"]) + w * (math.log(b["wall_s"]) - math.log(a["wall_s"])))
    if front and front[0]["err"] <= target:  # already the cheapest point is accurate enough
        return front[0]["wall_s"]
    return None


# ------------------------------------------------------------------------- the solvers
def lob_adaptive(ex, T, q_ref, s, cfg, budget):
    method = L.LobattoIIIAIIIB(stages=s)

    def solve(tol):
        return L.solve(ex.problem, method, (0.0, T), ex.q0, ex.p0, args=ex.args, lam0=ex.lam0, rtol=tol, atol=tol,
                       save_every="final", throw=False)

    def run(tol):
        sol = solve(tol)
        st = sol.stats
        n, nrej = int(st["n_steps"]), int(st["n_rejected"])
        err = float(np.max(np.abs(np.asarray(sol.q[-1]) - q_ref))) if sol.success else math.inf
        return {"err": err, "ok": bool(sol.success), "message": "" if sol.success else str(sol.message)[:200],
                "steps": n, "rejected": nrej, "max_phi": float(st["max_constraint_residual"]),
                "newton_per_step": round(float(st["n_newton"]) / max(1, n + nrej), 2),
                "jacobians_per_step": round(float(st["n_jacobians"]) / max(1, n + nrej), 3),
                "loop_s": float(st["compile_and_run_time"]) if st.get("compile_and_run_time") is not None else None}

    return Sweep(f"lobattodae adaptive s={s}", budget, cfg["repeats"]).go(
        cfg["lob_tols"], run, warm=lambda: solve(1e-6))


def lob_constant(ex, T, q_ref, s, cfg, budget):
    method = L.LobattoIIIAIIIB(stages=s)

    def solve(N):
        return L.solve(ex.problem, method, (0.0, T), ex.q0, ex.p0, n_steps=int(N), args=ex.args, lam0=ex.lam0,
                       save_every="final", throw=False)

    def run(N):
        sol = solve(N)
        st = sol.stats
        err = float(np.max(np.abs(np.asarray(sol.q[-1]) - q_ref))) if sol.success else math.inf
        return {"err": err, "ok": bool(sol.success), "message": "" if sol.success else str(sol.message)[:200],
                "steps": int(N), "max_phi": float(st["max_constraint_residual"]),
                "newton_per_step": round(float(st["n_newton"]) / N, 2),
                "jacobians_per_step": round(float(st["n_jacobians"]) / N, 3)}

    return Sweep(f"lobattodae constant s={s}", budget, cfg["repeats"]).go(
        cfg["const_N"], run, warm=lambda: solve(cfg["const_N"][0]), key="N")


def lob_reversible(ex, T, q_ref, s, cfg, budget):
    """Reversible step-size control (``ReversibleStepSize``, default density ‖(f, g)‖) with the
    symmetric scheme; ``first_step`` sets ε = h₀ σ(y₀), so it is the swept setting."""
    method = L.LobattoIIIAIIIB(stages=s)
    controller = L.ReversibleStepSize()

    def solve(h0):
        return L.solve(ex.problem, method, (0.0, T), ex.q0, ex.p0, args=ex.args, lam0=ex.lam0, first_step=h0,
                       controller=controller, save_every="final", throw=False)

    def run(h0):
        sol = solve(h0)
        st = sol.stats
        n = int(st["n_steps"])
        err = float(np.max(np.abs(np.asarray(sol.q[-1]) - q_ref))) if sol.success else math.inf
        return {"err": err, "ok": bool(sol.success), "message": "" if sol.success else str(sol.message)[:200],
                "steps": n, "max_phi": float(st["max_constraint_residual"]),
                "newton_per_step": round(float(st["n_newton"]) / max(1, n), 2)}

    return Sweep(f"lobattodae reversible s={s}", budget, cfg["repeats"]).go(
        cfg["rev_h0"], run, warm=lambda: solve(cfg["rev_h0"][0]), key="first_step")


def dop853(ode, T, y0, q_ref, cfg, budget):
    from scipy.integrate import solve_ivp

    n = ode.n

    def run(tol):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # scipy warns when rtol is below 100 eps
            r = solve_ivp(ode.rhs, (0.0, T), y0, method="DOP853", rtol=tol, atol=tol)
        err = float(np.max(np.abs(r.y[:n, -1] - q_ref))) if r.success else math.inf
        return {"err": err, "ok": bool(r.success), "message": "" if r.success else str(r.message)[:200],
                "steps": len(r.t) - 1, "nfev": int(r.nfev),
                "max_phi": float(np.max(np.abs(ode.phi(r.y[:n].T, r.y[n:].T))))}

    return Sweep("scipy DOP853", budget, cfg["repeats"]).go(cfg["dop_tols"], run, warm=lambda: run(1e-6))


def dopri8(ode, T, y0, q_ref, cfg, budget):
    n = ode.n
    dfx = C.DiffraxDopri8(ode)
    t0 = time.perf_counter()
    dfx.final(T, y0, 1e-6, PID_SETS[0])
    compile_s = time.perf_counter() - t0
    sweeps = []
    for pid in cfg["pids"]:
        def run(tol, pid=pid):
            yT, nacc, nsteps, ok = dfx.final(T, y0, tol, pid)
            err = float(np.max(np.abs(yT[:n] - q_ref))) if ok else math.inf
            return {"err": err, "ok": ok, "steps": nacc, "rejected": nsteps - nacc}

        sw = Sweep(f"diffrax Dopri8 PID(p={pid[0]:g}, i={pid[1]:g})", budget, cfg["repeats"]).go(cfg["dfx_tols"], run)
        sw["pid"] = pid
        sw["time_at_1e-8"] = time_at(sw["points"])
        sweeps.append(sw)
    timed = [s for s in sweeps if s["time_at_1e-8"] is not None]
    best = min(timed, key=lambda s: s["time_at_1e-8"]) if timed else sweeps[0]
    # ‖φ‖ at every step of the point closest to 1e-8 (untimed; compiles a saving variant)
    pts = [p for p in best["points"] if _finite(p)]
    if pts:
        p = min(pts, key=lambda p: abs(math.log(p["err"] / TARGET)))
        ts, ys = dfx.trajectory(T, y0, p["tol"], best["pid"], p["steps"] + p["rejected"])
        p["max_phi"] = float(np.max(np.abs(ode.phi(ys[:, :n], ys[:, n:]))))
        best["phi_at"] = p["tol"]
        log(f"    {best['label']}: tol {p['tol']:g}: max|φ| over {len(ts)} step points {p['max_phi']:.1e}")
    return {"compile_s": compile_s, "sweeps": sweeps, "best_pid": best["pid"], "best": best}


def ida(dae, phi, T, ex, q_ref, cfg, budget):
    n = dae.n
    solver = IDANumpy(dae)

    def run(tol):
        r = solver.solve((0.0, T), ex.q0, ex.p0, ex.lam0, tol, tol)
        ok = r.success and abs(float(r.t[-1]) - T) <= 1e-9 * T
        err = float(np.max(np.abs(r.y[-1, :n] - q_ref))) if ok else math.inf
        return {"err": err, "ok": bool(ok), "message": "" if ok else r.message[:200], "steps": r.n_steps,
                "nfev": r.nfev, "njev": r.njev, "max_phi": float(np.max(np.abs(phi(r.y[:, :n], r.y[:, n:2 * n]))))}

    return Sweep("SUNDIALS IDA", budget, cfg["repeats"]).go(cfg["ida_tols"], run, warm=lambda: run(1e-4))


# ------------------------------------------------------------------------------ driver
def run_problem(name: str, cfg: dict, budget: float) -> dict:
    T = cfg["T"]
    t_start = time.perf_counter()
    entry = {"T": T, "loadavg_start": C.loadavg()}
    ex = get_example(name, t_end=T)
    ref = reference(name, ex, T, cfg)
    q_ref = ref["q_ref"]
    entry["reference"] = {k: (v.tolist() if isinstance(v, np.ndarray) else v) for k, v in ref.items()}
    y0 = np.r_[ex.q0, ex.p0]
    ode = C.reduced_ode(name, ex.args)
    val = C.validate_ode(ode, ex)
    dae = C.numpy_dae(name, ex.args)
    val_dae = C.validate_dae(dae, ex)
    entry["reduced_ode"] = {"how": ode.how, "validation": val}
    entry["ida_dae"] = {"how": dae.how, "validation": val_dae}
    log(f"  reduced ODE ({ode.how}): validation {'OK' if val['ok'] else 'FAILED'} "
        f"(rhs {val['rhs_numpy_rel_err']:.1e}/{val['rhs_jax_rel_err']:.1e}, φ {val['phi_rel_err']:.1e}); "
        f"IDA residual ({dae.how}): {'OK' if val_dae['ok'] else 'FAILED'} "
        f"(res {val_dae['res_rel_err']:.1e}, jac {val_dae['jac_rel_err']:.1e})")
    runs: dict = {}
    for s in cfg["stages"]:
        runs[f"adaptive s={s}"] = lob_adaptive(ex, T, q_ref, s, cfg, budget)
    for s in cfg["const_stages"]:
        runs[f"constant s={s}"] = lob_constant(ex, T, q_ref, s, cfg, budget)
    if name in REVERSIBLE:
        for s in cfg["rev_stages"]:
            runs[f"reversible s={s}"] = lob_reversible(ex, T, q_ref, s, cfg, budget)
    if val["ok"]:
        runs["DOP853"] = dop853(ode, T, y0, q_ref, cfg, budget)
        runs["Dopri8"] = dopri8(ode, T, y0, q_ref, cfg, budget)
    ok_ida, why = ida_available()
    entry["ida"] = why
    if ok_ida and val_dae["ok"]:
        runs["IDA"] = ida(dae, ode.phi, T, ex, q_ref, cfg, budget)
    entry["runs"] = runs
    entry["summary"] = summarize(runs)
    entry["loadavg_end"] = C.loadavg()
    entry["seconds"] = time.perf_counter() - t_start
    return entry


def curve(runs, key):
    r = runs.get(key)
    if r is None:
        return None
    return r["best"] if key == "Dopri8" else r


def summarize(runs) -> dict:
    t = {}
    for key in runs:
        c = curve(runs, key)
        t[key] = time_at(c["points"])
    ad = {k: v for k, v in t.items() if k.startswith("adaptive") and v is not None}
    co = {k: v for k, v in t.items() if k.startswith("constant") and v is not None}
    every = {k: v for k, v in t.items() if k.startswith(("adaptive", "constant", "reversible")) and v is not None}
    best_any = min(every, key=every.get) if every else None
    best_ad = min(ad, key=ad.get) if ad else None
    best_co = min(co, key=co.get) if co else None
    ours = t.get(best_ad) if best_ad else None

    def ratio(a, b):
        return a / b if a is not None and b is not None else None

    return {"time_at_1e-8": t, "ours": best_ad, "ours_constant": best_co,
            "ours_over_dopri8": ratio(ours, t.get("Dopri8")), "ours_over_dop853": ratio(ours, t.get("DOP853")),
            "ours_over_ida": ratio(ours, t.get("IDA")),
            "constant_over_dopri8": ratio(t.get(best_co) if best_co else None, t.get("Dopri8")),
            "adaptive_over_constant": ratio(ours, t.get(best_co) if best_co else None),
            "ours_any": best_any, "any_over_dopri8": ratio(t.get(best_any) if best_any else None, t.get("Dopri8")),
            "any_over_dop853": ratio(t.get(best_any) if best_any else None, t.get("DOP853"))}


STYLE = {"adaptive s=3": ("#9ecae1", "o", "-"), "adaptive s=4": ("#4292c6", "s", "-"),
         "adaptive s=5": ("#08306b", "D", "-"), "adaptive s=6": ("#6a51a3", "p", "-"),
         "reversible s=5": ("#2ca02c", "*", "-."), "DOP853": ("#ff7f0e", "^", "-"),
         "Dopri8": ("#d62728", "v", "-"), "IDA": ("#9467bd", "P", "-")}


def plot(name: str, entry: dict, path: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    runs, sm = entry["runs"], entry["summary"]
    fig, (ax, ax2) = plt.subplots(1, 2, figsize=(13, 5.2), gridspec_kw={"width_ratios": [3, 2]})
    keys = [k for k in runs if k.startswith("adaptive")] + ([sm["ours_constant"]] if sm.get("ours_constant") else []) \
        + [k for k in runs if k.startswith("reversible")] + [k for k in ("DOP853", "Dopri8", "IDA") if k in runs]
    for key in keys:
        c = curve(runs, key)
        pts = [p for p in c["points"] if _finite(p)]
        if not pts:
            continue
        color, marker, ls = STYLE.get(key, ("black", "x", "--"))
        label = {"DOP853": "scipy DOP853 (NumPy rhs)", "IDA": "SUNDIALS IDA (index 2, NumPy residual)"}.get(key, key)
        if key == "Dopri8":
            label = f"diffrax Dopri8, PID(p={c['pid'][0]:g}, i={c['pid'][1]:g})"
        elif key.startswith("adaptive"):
            label = f"lobattodae {key}"
        elif key.startswith("constant"):
            label = f"lobattodae {key} (n_steps)"
        elif key.startswith("reversible"):
            label = f"lobattodae {key} (ReversibleStepSize)"
        ts = [p["wall_s"] for p in pts]
        ax.loglog(ts, [max(p["err"], 1e-16) for p in pts], ls, color=color, marker=marker, ms=5, label=label)
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
    fig.savefig(path, dpi=110)
    plt.close(fig)
    log(f"  wrote {path}")


def fmt_ratio(x):
    return "–" if x is None else f"{x:.2f}"


def ratio_table(out: dict) -> str:
    rows = []
    for name, e in out["problems"].items():
        sm = e["summary"]
        t = sm["time_at_1e-8"]
        ms = lambda k: "–" if k is None or t.get(k) is None else f"{1e3 * t[k]:.1f} ms"  # noqa: E731
        rows.append([name, f"{sm['ours']} ({ms(sm['ours'])})" if sm["ours"] else "not reached",
                     f"{sm['ours_constant']} ({ms(sm['ours_constant'])})" if sm["ours_constant"] else "–",
                     ms("Dopri8"), ms("DOP853"), ms("IDA"), fmt_ratio(sm["ours_over_dopri8"]),
                     fmt_ratio(sm["ours_over_dop853"]), fmt_ratio(sm["ours_over_ida"]),
                     fmt_ratio(sm["adaptive_over_constant"]),
                     f"{sm.get('ours_any')} ({ms(sm.get('ours_any'))})" if sm.get("ours_any") else "–",
                     fmt_ratio(sm.get("any_over_dopri8")), fmt_ratio(sm.get("any_over_dop853"))])
    return C.md_table(["problem", "ours adaptive (best s)", "ours constant", "Dopri8", "DOP853", "IDA",
                       "adaptive/Dopri8", "adaptive/DOP853", "adaptive/IDA", "adaptive/constant",
                       "best of ours", "best/Dopri8", "best/DOP853"], rows)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true", help="T = 100, fewer settings, 1 call each")
    ap.add_argument("--problems", nargs="+", choices=PROBLEMS, default=list(PROBLEMS))
    ap.add_argument("--budget", type=float, default=20.0, help="stop a solver's sweep after a call this long [s]")
    ap.add_argument("--replot", action="store_true", help="redraw the PNGs from the saved JSON")
    ap.add_argument("--watchdog", type=float, default=1800.0, help="abort with tracebacks after this many s (0: off)")
    ap.add_argument("--cpu-threads", type=int, default=None,
                    help="size of XLA's CPU thread pool (lobattodae.set_cpu_threads; default: XLA's)")
    a = ap.parse_args(argv)
    if a.cpu_threads is not None:
        L.set_cpu_threads(a.cpu_threads)  # before the first JAX computation; applies to every solver
    suffix = "_quick" if a.quick else ""
    path = os.path.join(RESULTS_DIR, f"adaptive_wp{suffix}.json")
    out = {"meta": {}, "problems": {}}
    if os.path.exists(path):
        with open(path) as fh:
            out = json.load(fh)
    if a.replot:
        for name, e in out["problems"].items():
            plot(name, e, os.path.join(RESULTS_DIR, f"{PNG_NAME[name]}{suffix}.png"))
        print(ratio_table(out))
        return 0
    if a.watchdog > 0:
        import faulthandler

        faulthandler.dump_traceback_later(a.watchdog, exit=True)
    cfg = config(a.quick)
    start = time.perf_counter()
    meta = {"date": datetime.datetime.now().isoformat(timespec="seconds"), "machine": C.machine_info(),
            "command": "PYTHONPATH=src .venv/bin/python benchmarks/adaptive_wp.py " + " ".join(sys.argv[1:]),
            "lobattodae": getattr(L, "__version__", None), "lobattodae_path": os.path.dirname(L.__file__),
            "ida": ida_available()[1], "loadavg_start": C.loadavg(), "budget_s": a.budget,
            "repeat_limit_s": REPEAT_LIMIT_S, "config": cfg,
            "cpu_threads": {k: os.environ.get(k) for k in ("PJRT_NPROC", "NPROC")}}
    log(f"adaptive_wp: {meta['command']}  (load average {meta['loadavg_start']})")
    import jax.numpy as jnp

    jnp.zeros(1).block_until_ready()
    for name in a.problems:
        log(f"\n=== {name}, T = {cfg['T']:g} ===")
        e = run_problem(name, cfg, a.budget)
        e["meta"] = meta
        out["problems"][name] = e
        out["meta"] = meta
        C.write_json(out, path)  # after each problem
        plot(name, out["problems"][name], os.path.join(RESULTS_DIR, f"{PNG_NAME[name]}{suffix}.png"))
        log(f"  ({e['seconds']:.0f} s for {name})")
    meta["loadavg_end"] = C.loadavg()
    meta["wall_seconds"] = time.perf_counter() - start
    C.write_json(out, path)
    log("\nWall time at max|q(T) − q_ref| = 1e-8 (interpolated on each solver's Pareto front, log-log):\n")
    log(ratio_table(json.loads(json.dumps(C.jsonable(out)))))
    log(f"\n({meta['wall_seconds']:.0f} s in all)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
