#!/usr/bin/env python
"""Regenerate ``docs/verification.md`` (and its figures) from the repository.

    python scripts/make_verification.py            # full report -> docs/ (several minutes)
    python scripts/make_verification.py --quick    # smoke run -> a temporary directory
    python scripts/make_verification.py --out DIR  # write verification.md + figures/ to DIR

What it does (issue #3, item 5):

* a convergence study (``lobattodae._convergence.convergence_study``) with s = 2..6 stages
  for every example that has a closed-form solution, with the observed orders beside the
  theoretical ones (DESIGN.md section 3), the convergence plot and all errors;
* checks of the known special cases (knife edge s = 2: lambda; vertical rolling disk: p)
  computed from dedicated runs, so that the explanations in the report rest on numbers
  from this run;
* long runs (1e5 steps) on the reversible and the non-reversible contact oscillator with
  the energy error and the constraint residual (library default ``lam_start="auto"``), and
  the same runs with ``lam_start="previous"`` and ``"consistent"``;
* the measure of success of the lambda-mode decision (DESIGN.md, "The λ mode") on both
  classes: 1e6 steps of the reversible contact oscillator and the Chaplygin sleigh against
  its closed form, for the three modes ``"auto"``, ``"previous"``, ``"consistent"``.

The convergence studies and the special cases use ``lam_start="previous"`` (the paper's
scheme) explicitly, because the proven orders refer to it; every study is repeated with the
default ``"auto"`` and the two are compared.

Every number written to the report is computed by this script; the prose around the
numbers is fixed, but the statements that depend on the data are checked and reworded
(or flagged) when the data disagree.
"""

from __future__ import annotations

import argparse
import dataclasses
import datetime
import hashlib
import json
import math
import os
import platform
import subprocess
import sys
import tempfile
import time
import warnings
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "src"))  # always the library of this checkout

import matplotlib  # noqa: E402

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import matplotlib.ticker  # noqa: E402
import numpy as np  # noqa: E402

import lobattodae  # noqa: E402
from lobattodae import LobattoIIIAIIIB  # noqa: E402
from lobattodae._convergence import (  # noqa: E402
    COMPONENTS,
    PLATEAU_REL,
    convergence_study,
    default_step_counts,
    observed_order,
)
from lobattodae._diagnostics import invariant_error, invariant_values  # noqa: E402
from lobattodae._plotting import plot_convergence  # noqa: E402
from lobattodae.examples import get_example, list_examples  # noqa: E402

# ----------------------------------------------------------------------------- settings
#: Fits of q and p use errors above QP_PLATEAU * (1 + max|x|). The library default
#: (PLATEAU_REL["lam"]) is kept for lambda, whose round-off level is higher (lambda is
#: recovered from h * Lambda, so its round-off grows like eps / h). For q and p the
#: observed round-off level is ~1e-15 (measured below and printed in the report), and
#: the library's q/p default would leave the s = 5, 6 fits only their coarsest, pre-asymptotic step counts.
QP_PLATEAU = 1e-14
#: Points per fit: the library's default (the n_fit finest step sizes above the floor).
N_FIT = 4
#: |observed - expected| above this is flagged as a deviation.
ORDER_TOL = 0.3
#: The paper's scheme (Λ_1 = λ_n). The proven orders (DESIGN.md §3) refer to it, so the
#: convergence studies and the special cases use it explicitly; the library's default is
#: "auto" (the paper's scheme, re-synchronised with the hidden constraint when the λ drift
#: leaves its band), which run_study compares with it.
PAPER = {"lam_start": "previous"}
#: The lam_start modes compared in section 4 (the library default first).
LAM_MODES = ("auto", "previous", "consistent")
#: Examples whose error constants depend on the parity of the step count (see their
#: Example.notes): only even step counts are used for them.
EVEN_ONLY = {"vertical-disk"}

FULL = {
    "stages": (2, 3, 4, 5, 6),
    # None: the library's default_step_counts. s = 5, 6: denser and coarser than the
    # default, because their q, p errors reach round-off within a few step counts.
    "counts": {
        2: None,
        3: None,
        4: None,
        5: (3, 4, 5, 6, 7, 8, 10, 12, 14, 16, 20, 24, 32, 48, 64),
        6: (2, 3, 4, 5, 6, 7, 8, 10, 12, 16, 24, 32, 48, 64),
    },
    "long_steps": 100_000,
    # the measure of success of the lambda-mode decision (DESIGN.md, "The λ mode")
    "lam_contact_steps": 1_000_000,
    "sleigh_runs": ((5, 0.1, 130.0), (3, 0.01, 400.0)),  # (s, h, T)
    "knife_counts": (16, 17, 64, 65),
    "disk_pairs": {2: (32, 64), 3: (16, 32), 4: (8, 16), 5: (4, 8), 6: (4, 6)},
}
QUICK = {
    "examples": ("knife-edge", "vertical-disk"),
    "stages": (2, 3),
    "counts": {2: (16, 32, 64, 128), 3: (8, 16, 32, 64)},
    "long_steps": 2_000,
    "lam_contact_steps": 20_000,
    "sleigh_runs": ((5, 0.1, 130.0),),
    "knife_counts": (16, 17),
    "disk_pairs": {2: (32, 64), 3: (16, 32)},
}
LONG_STAGES = 3
#: Step sizes of the long runs: h = 2 sin(pi / N) (McLachlan & Perlmutter), N = 15 and 40.
LONG_N = (15, 40)
#: The contact run of the lambda-mode comparison: h = 2 sin(pi / LAM_N), s = LONG_STAGES.
LAM_N = 15

LABEL = {"q": "q", "p": "p", "lam": "λ"}


def log(msg: str) -> None:
    print(msg, file=sys.stderr, flush=True)


# ----------------------------------------------------------------------------- helpers
def fmt_order(x) -> str:
    return "—" if x is None or not np.isfinite(x) else f"{x:.2f}"


def fmt_e(x) -> str:
    return "—" if x is None or not np.isfinite(x) else f"{x:.2e}"


def fit_indices(h, err, floor, n_fit=N_FIT):
    """The indices observed_order() uses (mirrors the library; checked against it)."""
    h = np.asarray(h, float)
    err = np.asarray(err, float)
    keep = np.flatnonzero(np.isfinite(err) & (err > floor) & (err > 0))
    if keep.size < 2:
        return np.array([], int)
    return keep[np.argsort(h[keep])][:n_fit]


def local_slopes(h, err):
    """Slope between consecutive step sizes (NaN where an error is 0)."""
    h = np.asarray(h, float)
    e = np.asarray(err, float)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.diff(np.log(e)) / np.diff(np.log(h))


def machine_info() -> dict:
    cpu = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo") as fh:
            for line in fh:
                if line.startswith("model name"):
                    cpu = line.split(":", 1)[1].strip()
                    break
    except OSError:
        pass
    import jax

    info = {
        "cpu": cpu,
        "logical cores": os.cpu_count(),
        "os": platform.platform(),
        "python": platform.python_version(),
        "jax": jax.__version__,
        "jax backend": jax.default_backend(),
        "numpy": np.__version__,
        "matplotlib": matplotlib.__version__,
        "lobattodae": lobattodae.__version__,
    }
    try:
        rev = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT,
                             capture_output=True, text=True, check=True).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"],
                               cwd=ROOT, capture_output=True, text=True, check=True).stdout.strip()
        info["git"] = rev + (" (with uncommitted changes)" if dirty else "")
    except (OSError, subprocess.CalledProcessError):
        info["git"] = "unknown"
    return info


class Recorder:
    """Collects the RuntimeWarnings of the library (e.g. its multiplier-drift warning)."""

    def __enter__(self):
        self._cm = warnings.catch_warnings(record=True)
        self.caught = self._cm.__enter__()
        warnings.simplefilter("always", RuntimeWarning)
        return self

    def __exit__(self, *exc):
        self._cm.__exit__(*exc)
        self.messages = [str(w.message) for w in self.caught if issubclass(w.category, RuntimeWarning)]
        return False


def solve_example(ex, s, n_steps, t_span=None, chunk_size=None, throw=True, **method_options):
    return lobattodae.solve(ex.problem, LobattoIIIAIIIB(stages=s, **method_options), t_span or ex.t_span,
                            ex.q0, ex.p0, n_steps=int(n_steps), lam0=ex.lam0, args=ex.args,
                            chunk_size=chunk_size, throw=throw)


# --------------------------------------------------------------------- convergence study
def step_counts(ex, s, cfg):
    length = ex.t_end - ex.t0
    base = cfg["counts"].get(s)
    default = default_step_counts(s, length)
    if base is None:
        counts = list(default)
    else:
        scale = max(1.0, length / 2.0)  # as default_step_counts does
        counts = sorted({int(round(n * scale)) for n in base})
    if ex.name in EVEN_ONLY:
        counts = [n for n in counts if n % 2 == 0]
    # Counts coarser than the library's defaults may be beyond Newton's reach: try them.
    dropped = []
    while counts and counts[0] < min(default):
        try:
            solve_example(ex, s, counts[0], chunk_size=1 << (max(counts) - 1).bit_length(), **PAPER)
            break
        except lobattodae.SolverError as exc:
            dropped.append((counts.pop(0), str(exc).split(";")[0]))
    return tuple(counts), dropped


def run_study(ex, cfg):
    stages = cfg["stages"]
    counts, dropped = {}, {}
    for s in stages:
        counts[s], dropped[s] = step_counts(ex, s, cfg)
    t0 = time.perf_counter()
    with Recorder() as rec:  # the paper's scheme: the proven orders refer to it
        study = convergence_study(ex, stages=stages, n_steps=counts, method_options=PAPER)
    elapsed = time.perf_counter() - t0
    if rec.messages:
        dropped.setdefault("warnings", []).extend(rec.messages)
    # The same runs with the library's default lam_start="auto". It takes the paper's steps
    # until the drift monitor sees an excursion (which a 'previous' run reports with a
    # RuntimeWarning) and then re-synchronises λ; compare the errors run by run.
    t0 = time.perf_counter()
    auto = convergence_study(ex, stages=stages, n_steps=counts, method_options={"lam_start": "auto"})
    n_runs = identical = 0
    rel = 0.0
    for s in stages:
        for i in range(len(study.n_steps[s])):
            e_p = np.array([study.errors[s][c][i] for c in COMPONENTS])
            e_a = np.array([auto.errors[s][c][i] for c in COMPONENTS])
            n_runs += 1
            identical += bool(np.array_equal(e_p, e_a, equal_nan=True))
            with np.errstate(divide="ignore", invalid="ignore"):
                d = np.abs(e_a - e_p) / np.maximum(np.abs(e_p), 1e-300)
            rel = max(rel, float(np.nanmax(d)) if np.any(np.isfinite(d)) else 0.0)
    auto_cmp = {"runs": n_runs, "identical": identical, "max_rel_diff": rel,
                # solve's only RuntimeWarning: a drift excursion in lam_start='previous'
                "excursion_runs": len(rec.messages),
                "wall": time.perf_counter() - t0}
    # Refit q and p above the lower floor (lambda keeps the library floor).
    floors = dict(study.floors)
    for c in ("q", "p"):
        floors[c] = study.floors[c] * (QP_PLATEAU / PLATEAU_REL[c])
    observed = {}
    for s in stages:
        observed[s] = {}
        for c in COMPONENTS:
            o = observed_order(study.h[s], study.errors[s][c], floors[c], n_fit=N_FIT)
            idx = fit_indices(study.h[s], study.errors[s][c], floors[c])
            if idx.size >= 2:  # guard: our reading of the library's fit window is right
                slope = np.polyfit(np.log(study.h[s][idx]), np.log(study.errors[s][c][idx]), 1)[0]
                assert abs(slope - o) < 1e-9, (ex.name, s, c, slope, o)
            observed[s][c] = o
    study = dataclasses.replace(study, floors=floors, observed=observed)
    order_diff = 0.0  # largest |order(auto) - order(previous)| with the same floors
    for s in stages:
        for c in COMPONENTS:
            o = observed_order(auto.h[s], auto.errors[s][c], floors[c], n_fit=N_FIT)
            if np.isfinite(o) != np.isfinite(observed[s][c]):
                order_diff = float("inf")
            elif np.isfinite(o):
                order_diff = max(order_diff, abs(o - observed[s][c]))
    auto_cmp["max_order_diff"] = order_diff
    return study, dropped, elapsed, auto_cmp


def classify(ex, study, s, c):
    """('ok' | 'documented' | 'deviation', text for the theory cell)."""
    theory = study.expected[s][c]
    obs = study.observed[s][c]
    table = ex.expected_order_overrides.get(c, {})
    documented = s in table
    doc = table.get(s)
    cell = str(theory)
    if documented:
        cell += f" (documented: {'exact' if doc is None else doc})"
    if documented:
        if doc is None and not np.isfinite(obs):
            return "documented", cell
        if doc is not None and np.isfinite(obs) and abs(obs - doc) <= ORDER_TOL:
            return "documented", cell
    if np.isfinite(obs) and abs(obs - theory) <= ORDER_TOL and not documented:
        return "ok", cell
    return "deviation", cell


def roundoff_levels(study, stages):
    """Largest q, p error among the runs of the highest s with h <= T/32: the truncation
    error there is many orders below eps, so this is the round-off level of the study."""
    s = max(stages)
    if s < 6:
        return None
    T = study.h[s][0] * study.n_steps[s][0]
    sel = study.h[s] <= T / 32 + 1e-15
    if not np.any(sel):
        return None
    return {c: float(np.max(study.errors[s][c][sel])) for c in ("q", "p")}


# ----------------------------------------------------------------------- special cases
def knife_edge_lambda(cfg):
    """s = 2 on the knife edge: lambda at even and odd step indices."""
    ex = get_example("knife-edge")
    a = ex.args
    theta0 = float(ex.q0[2])
    omega = float(ex.p0[2]) / a.J
    v0 = (math.cos(theta0) * ex.p0[0] + math.sin(theta0) * ex.p0[1]) / a.m
    counts = cfg["knife_counts"]
    chunk = 1 << (max(counts) - 1).bit_length()
    rows = []
    for n in counts:
        sol = solve_example(ex, 2, n, chunk_size=chunk, **PAPER)
        _, _, le = ex.exact(sol.t)
        e = np.max(np.abs(sol.lam - le.reshape(sol.lam.shape)), axis=1)
        h = sol.stats["h"]
        # Prediction of the two-step recursion (see the report): the error at every odd
        # step equals that of lambda_1.
        pred = a.m * a.g * math.cos(theta0) * (1 - math.cos(omega * h)) + a.m * v0 * (
            2 * math.sin(omega * h) / h - omega * (1 + math.cos(omega * h)))
        odd = e[1::2]
        rows.append({
            "n": n, "h": h, "even_max": float(np.max(e[0::2])), "odd_max": float(np.max(odd)),
            "odd_min": float(np.min(odd)), "pred": abs(pred), "final": float(e[-1]),
            "q": float(np.max(np.abs(sol.q - ex.exact(sol.t)[0]))),
        })
    return rows


def vertical_disk_components(cfg):
    """Per-component errors of the vertical disk for two step counts per s."""
    ex = get_example("vertical-disk")
    names = ["x", "y", "φ", "θ", "p_x", "p_y", "p_φ", "p_θ"]
    out = {}
    for s, (n1, n2) in cfg["disk_pairs"].items():
        if s not in cfg["stages"]:
            continue
        errs = []
        for n in (n1, n2):
            sol = solve_example(ex, s, n, chunk_size=1 << (n2 - 1).bit_length(), **PAPER)
            qe, pe, _ = ex.exact(sol.t)
            errs.append(np.concatenate([np.max(np.abs(sol.q - qe), axis=0),
                                        np.max(np.abs(sol.p - pe), axis=0)]))
        e1, e2 = errs
        with np.errstate(divide="ignore", invalid="ignore"):
            order = np.log(e1 / e2) / math.log(n2 / n1)
        order = np.where(e2 > 2e-14, order, np.nan)  # round-off here is ~1e-15
        out[s] = {"n": (n1, n2), "names": names, "e1": e1, "e2": e2, "order": order}
    return out


# ----------------------------------------------------------------------------- long runs
def envelope(t, x, blocks=1000):
    """Max of |x| over consecutive blocks (for readable plots of 1e5 points)."""
    x = np.abs(np.asarray(x))
    n = x.size
    b = max(1, n // blocks)
    m = (n // b) * b
    xm = x[:m].reshape(-1, b).max(axis=1)
    tm = np.asarray(t)[:m].reshape(-1, b).mean(axis=1)
    return tm, xm, b


def digest(*arrays) -> str:
    """A fingerprint of a run's numbers (to tell bitwise-identical runs apart)."""
    hsh = hashlib.sha256()
    for a in arrays:
        hsh.update(np.ascontiguousarray(np.asarray(a, np.float64)).tobytes())
    return hsh.hexdigest()[:16]


def lam_stats(sol) -> dict:
    """The λ-mode statistics of a run: the number of re-synchronisations ('auto'), the
    excursions of the drift monitor, and the times t_k of the steps that started from
    λ(t_k, q_k, p_k) (``lam_resync[k]`` refers to the step from t_k to t_{k+1})."""
    resync = np.flatnonzero(np.asarray(sol.stats.get("lam_resync", []), bool))
    return {"lam_resets": int(sol.stats.get("lam_resets", 0)),
            "lam_excursions": int(sol.stats.get("lam_excursions", 0)),
            "resync_t": [float(sol.t[k]) for k in resync[:100]], "_resync": resync}


def long_run(name, n_steps, N, **method_options):
    ex = get_example(name)
    mode = LobattoIIIAIIIB(stages=LONG_STAGES, **method_options).lam_start
    h = 2 * math.sin(math.pi / N)
    T = n_steps * h
    t0 = time.perf_counter()
    with Recorder() as rec:
        # throw=False: a run that fails part-way is reported with its computed prefix
        sol = solve_example(ex, LONG_STAGES, n_steps, t_span=(0.0, T), throw=False,
                            **method_options)
    wall = time.perf_counter() - t0
    done = len(sol.t) - 1  # steps actually taken
    lam_drift = sol.stats.get("multiplier_drift")  # ‖λ_k − λ(q_k, p_k)‖∞, if the library has it
    dH = invariant_error(sol, ex.invariants["energy"])
    dHy = invariant_error(sol, ex.invariants["H_y"])
    H0 = float(invariant_values(sol, ex.invariants["energy"])[0])
    Hy0 = float(invariant_values(sol, ex.invariants["H_y"])[0])
    phi = np.asarray(sol.stats["constraint_residual"])
    k = max(1, done // 10)
    kf = min(done, max(1, n_steps // 10))  # first tenth of the planned run
    slope, icpt = np.polyfit(sol.t, dH, 1)
    slope_first = np.polyfit(sol.t[: kf + 1], dH[: kf + 1], 1)[0]
    slope_last = np.polyfit(sol.t[-k - 1:], dH[-k - 1:], 1)[0]
    dec = np.linspace(0, done, 11).astype(int)
    return {
        "name": name, "N": N, "h": h, "T": T, "n_steps": n_steps, "H0": H0, "wall": wall,
        "Hy0": Hy0, "epsilon": float(getattr(ex.args, "epsilon", float("nan"))),
        "success": bool(sol.success), "message": sol.message, "steps_done": done,
        "options": dict(method_options), "lam_start": mode,
        "digest": digest(sol.q, sol.p, sol.lam), **lam_stats(sol),
        "t_end": float(sol.t[-1]),
        "compile_and_run": float(sol.stats.get("compile_and_run_time", float("nan"))),
        "first10": float(np.max(np.abs(dH[: kf + 1]))), "last10": float(np.max(np.abs(dH[-k - 1:]))),
        "max_dH": float(np.max(np.abs(dH))), "slope": float(slope), "slope_first": float(slope_first),
        "slope_last": float(slope_last), "final_dH": float(dH[-1]),
        "max_phi": float(np.max(phi)), "max_dHy": float(np.max(np.abs(dHy))),
        "newton_mean": float(np.mean(sol.stats["newton_iterations"])),
        "newton_max": int(np.max(sol.stats["newton_iterations"])),
        "deciles": [(float(sol.t[i]), float(dH[i])) for i in dec],
        "decile_gain": [float(dH[b] - dH[a]) for a, b in zip(dec[:-1], dec[1:])],
        "warnings": rec.messages,
        "lam_drift_first10": None if lam_drift is None else float(np.max(lam_drift[: kf + 1])),
        "lam_drift_last10": None if lam_drift is None else float(np.max(lam_drift[-k - 1:])),
        "lam_max_first10": float(np.max(np.abs(sol.lam[: kf + 1]))),
        "lam_max_last10": float(np.max(np.abs(sol.lam[-k - 1:]))),
        "_t": sol.t, "_dH": dH, "_phi": phi, "_lam_drift": lam_drift,
    }


MODE_STYLE = {  # lam_start -> (colour, line style, width)
    "auto": ("tab:green", "-", 2.2),
    "previous": ("tab:red", "--", 1.0),
    "consistent": ("tab:blue", ":", 1.4),
}


def mode_label(mode) -> str:
    return {"auto": "auto (default)", "previous": "previous (paper)"}.get(mode, mode)


def sleigh_run(s, h, T, lam_start):
    """The Chaplygin sleigh with s stages and n = T/h steps, against its closed form."""
    ex = get_example("sleigh")
    n = int(round(T / h))
    t0 = time.perf_counter()
    with Recorder() as rec:
        sol = solve_example(ex, s, n, t_span=(0.0, n * h), throw=False, lam_start=lam_start)
    wall = time.perf_counter() - t0
    qe, pe, le = ex.exact(sol.t)
    eq = np.max(np.abs(sol.q - qe), axis=1)
    drift = np.asarray(sol.stats["multiplier_drift"])
    ls = lam_stats(sol)
    return {
        "name": "sleigh", "s": s, "h": h, "T": n * h, "n_steps": n, "lam_start": lam_start,
        "success": bool(sol.success), "message": sol.message, "steps_done": len(sol.t) - 1,
        "t_end": float(sol.t[-1]), "q_err_T": float(eq[-1]), "q_scale_T": float(np.max(np.abs(qe[-1]))),
        "p_err_T": float(np.max(np.abs(sol.p[-1] - pe[-1]))),
        "lam_err_T": float(np.max(np.abs(sol.lam[-1] - np.reshape(le[-1], sol.lam[-1].shape)))),
        "max_q_err": float(np.max(eq)), "max_drift": float(np.max(drift)), "drift_T": float(drift[-1]),
        "newton_mean": float(np.mean(sol.stats["newton_iterations"])),
        "wall": wall, "warnings": rec.messages, "digest": digest(sol.q, sol.p, sol.lam),
        # the drift at the end of each re-synchronised step, and just before it
        "drift_after_reset": [float(drift[k + 1]) for k in ls["_resync"][:100]],
        "drift_before_reset": [float(drift[k]) for k in ls["_resync"][:100]],
        **ls, "_t": sol.t, "_drift": drift, "_qerr": eq,
    }


def lam_mode_runs(cfg):
    """The measure of success of the λ-mode decision (DESIGN.md, "The λ mode"): the three
    modes on the reversible contact oscillator (energy) and on the Chaplygin sleigh (q error)."""
    contact = []
    for mode in LAM_MODES:
        log(f"lambda mode: contact, h = 2 sin(pi/{LAM_N}), {cfg['lam_contact_steps']} steps, "
            f"lam_start={mode!r} ...")
        r = long_run("contact", cfg["lam_contact_steps"], LAM_N, lam_start=mode)
        log(f"  {r['wall']:.1f} s; max|dH| first/last 10%: {r['first10']:.2e} / {r['last10']:.2e}; "
            f"resets {r['lam_resets']}, excursions {r['lam_excursions']}")
        contact.append(r)
    sleigh = []
    for s, h, T in cfg["sleigh_runs"]:
        for mode in LAM_MODES:
            log(f"lambda mode: sleigh, s = {s}, h = {h}, T = {T}, lam_start={mode!r} ...")
            r = sleigh_run(s, h, T, mode)
            log(f"  {r['wall']:.1f} s; q error at T {r['q_err_T']:.2e}; resets {r['lam_resets']} "
                f"at t = {[round(x, 2) for x in r['resync_t'][:8]]}")
            sleigh.append(r)
    return {"contact": contact, "sleigh": sleigh}


def _mark_resets(ax, r, x_of):
    """Vertical lines at the re-synchronisations of an 'auto' run."""
    for i, k in enumerate(r["_resync"][:200]):
        ax.axvline(x_of(k), color=MODE_STYLE["auto"][0], lw=0.7, ls="-.", alpha=0.8,
                   label="auto: reset" if i == 0 else None)


def plot_lam_modes(lam, path):
    configs = list(dict.fromkeys((r["s"], r["h"], r["T"]) for r in lam["sleigh"]))
    ncol = len(configs) + (1 if lam["contact"] else 0)
    fig, axes = plt.subplots(2, ncol, figsize=(5.6 * ncol, 7.0), squeeze=False,
                             constrained_layout=True)
    for j, (s, h, T) in enumerate(configs):
        ax_d, ax_q = axes[0, j], axes[1, j]
        for r in (r for r in lam["sleigh"] if (r["s"], r["h"], r["T"]) == (s, h, T)):
            col, ls, lw = MODE_STYLE[r["lam_start"]]
            lab = f"{mode_label(r['lam_start'])}: {r['lam_resets']} resets" if r["lam_start"] == "auto" \
                else mode_label(r["lam_start"])
            t = r["_t"][1:]  # the drift at t_0 is not recorded (0)
            ax_d.semilogy(t, np.maximum(r["_drift"][1:], 1e-18), ls, color=col, lw=lw, label=lab)
            ax_q.semilogy(r["_t"], np.maximum(r["_qerr"], 1e-18), ls, color=col, lw=lw, label=lab)
            if r["lam_start"] == "auto":
                for ax in (ax_d, ax_q):
                    _mark_resets(ax, r, lambda k, r=r: r["_t"][k])
        ax_d.set_title(f"sleigh, s = {s}, h = {h:g}: ‖λ_n − λ(q_n, p_n)‖∞")
        ax_q.set_title(f"sleigh, s = {s}, h = {h:g}: ‖q_n − q(t_n)‖∞ (closed form)")
        ax_d.set_ylabel("multiplier drift")
        ax_q.set_ylabel("q error")
        ax_q.set_xlabel("t")
    if lam["contact"]:
        ax_e, ax_d = axes[0, -1], axes[1, -1]
        for r in lam["contact"]:
            col, ls, lw = MODE_STYLE[r["lam_start"]]
            k = np.arange(len(r["_t"]))
            lab = f"{mode_label(r['lam_start'])}: {r['lam_resets']} resets" if r["lam_start"] == "auto" \
                else mode_label(r["lam_start"])
            km, em, b = envelope(k, r["_dH"])
            ax_e.semilogy(km, np.maximum(em, 1e-18), ls, color=col, lw=lw, label=lab)
            km, dm, _ = envelope(k[1:], r["_lam_drift"][1:])
            ax_d.semilogy(km, np.maximum(dm, 1e-18), ls, color=col, lw=lw, label=lab)
            if r["lam_start"] == "auto":
                for ax in (ax_e, ax_d):
                    _mark_resets(ax, r, lambda k: k)
        r0 = lam["contact"][0]
        ax_e.set_title(f"contact, s = {LONG_STAGES}, h = {r0['h']:.4f}: |H − H0| (max per {b} steps)")
        ax_d.set_title(f"contact: ‖λ_n − λ(q_n, p_n)‖∞ (max per {b} steps)")
        ax_e.set_ylabel("|H(t_n) − H(0)|")
        ax_d.set_ylabel("multiplier drift")
        ax_d.set_xlabel("step index n")
    for ax in axes.ravel():
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=7)
    fig.savefig(path, dpi=100)
    plt.close(fig)


def plot_variants(runs, variant_runs, path):
    """The long runs of section 4 (default 'auto') beside the same runs in the other modes."""
    names = list(dict.fromkeys(r["name"] for r in runs))
    fig, axes = plt.subplots(1, len(names), figsize=(6.2 * len(names), 3.8), squeeze=False,
                             constrained_layout=True)
    for j, name in enumerate(names):
        ax = axes[0, j]
        for r in runs + variant_runs:
            if r["name"] != name:
                continue
            col, ls, lw = MODE_STYLE[r["lam_start"]]
            tm, em, b = envelope(r["_t"], r["_dH"])
            ax.semilogy(tm, np.maximum(em, 1e-18), ls, lw=lw if r["N"] == LONG_N[0] else lw * 0.6,
                        color=col, alpha=1.0 if r["N"] == LONG_N[0] else 0.55,
                        label=f"h = {r['h']:.4f}, {mode_label(r['lam_start'])}")
        ax.set_title(f"{name}, s = {LONG_STAGES}: |H − H0| (max per {b} steps)")
        ax.set_xlabel("t")
        ax.set_ylabel("|H(t) − H(0)|")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=6.5, ncol=2)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _resets_cell(r) -> str:
    if r["lam_start"] != "auto":
        ex = r["lam_excursions"]
        return f"— ({ex} excursion{'s' if ex != 1 else ''})" if r["lam_start"] == "previous" else "—"
    ts = r["resync_t"]
    if not ts:
        return "0"
    shown = ", ".join(f"{t:.4g}" for t in ts[:6]) + (" …" if len(ts) > 6 else "")
    return f"{r['lam_resets']} (t = {shown})"


def lam_mode_text(lam, runs, variant_runs):
    """Section 4, second part: the three lam_start modes and the decision's measure of success."""
    L = ["### The λ mode (`lam_start`): measure of success on both classes", ""]
    L.append(
        "λ is carried from step to step through Λ_1 = λ_n (the paper's scheme), with "
        "|R(∞)| = 1: a λ error is never damped. On reversible problems it stays bounded; on "
        "non-reversible ones it can grow like exp(Ct) and then spoil q and p. "
        "`LobattoIIIAIIIB(lam_start=...)` has three modes: **`'auto'` (the default)** takes "
        "the paper's step and re-synchronises λ with the hidden constraint (one step starts "
        "from λ(t_n, q_n, p_n)) only when the drift ‖λ_n − λ(q_n, p_n)‖∞ exceeds 10× its "
        "level in the previous epoch of a sequence of doubling epochs (a *reset*, counted in "
        "`sol.stats['lam_resets']`, marked per step in `sol.stats['lam_resync']`); "
        "`'previous'` is the pure paper's scheme (an excursion of the drift is only counted, "
        "`sol.stats['lam_excursions']`, and reported by a RuntimeWarning); `'consistent'` "
        "re-solves Λ_1 from the hidden constraint at every step (not symmetric). The "
        "decision (DESIGN.md, 'The λ mode') is measured on both classes at once: bounded "
        "energy on the reversible contact oscillator over 10⁶ steps, and the q error at "
        "round-off level on the sleigh at t = 130 (s = 5, h = 0.1).")
    L.append("")
    C = {r["lam_start"]: r for r in lam["contact"]}
    if C:
        r0 = next(iter(C.values()))
        L.append(f"**Reversible class**: contact oscillator, s = {LONG_STAGES}, h = 2 sin(π/{LAM_N}) "
                 f"= {r0['h']:.4f}, {r0['n_steps']:,} steps (T = {r0['T']:.0f}).")
        L.append("")
        L.append("| lam_start | max\\|ΔH\\| first 10 % | max\\|ΔH\\| last 10 % | drift rate | "
                 "max ‖λ−λ(q,p)‖∞ first / last 10 % | resets (auto) | identical to 'previous' | wall time |")
        L.append("|---|---|---|---|---|---|---|---|")
        ref = C.get("previous")
        for mode in LAM_MODES:
            r = C.get(mode)
            if r is None:
                continue
            stop = "" if r["success"] else f" (stopped at step {r['steps_done']:,})"
            same = "—" if mode == "previous" or ref is None else (
                "yes (bitwise)" if r["digest"] == ref["digest"] else "no")
            L.append(f"| {mode_label(mode)}{stop} | {r['first10']:.2e} | {r['last10']:.2e} | "
                     f"{r['slope']:+.2e} | {fmt_e(r['lam_drift_first10'])} / {fmt_e(r['lam_drift_last10'])} | "
                     f"{_resets_cell(r)} | {same} | {r['wall']:.1f} s |")
        L.append("")
    S = lam["sleigh"]
    if S:
        L.append("**Non-reversible class**: Chaplygin sleigh (`sleigh`, initial data of the "
                 "example), error against the closed form at the final time T.")
        L.append("")
        L.append("| s | h | T | lam_start | ‖q − q(T)‖∞ | relative to ‖q(T)‖∞ | ‖p − p(T)‖∞ | "
                 "\\|λ − λ(T)\\| | max ‖λ−λ(q,p)‖∞ | resets (auto) | wall time |")
        L.append("|---|---|---|---|---|---|---|---|---|---|---|")
        for r in S:
            stop = "" if r["success"] else f" (**stopped at t = {r['t_end']:.4g}**)"
            L.append(f"| {r['s']} | {r['h']:g} | {r['T']:.0f} | {mode_label(r['lam_start'])}{stop} | "
                     f"{r['q_err_T']:.2e} | {r['q_err_T'] / r['q_scale_T']:.1e} | {r['p_err_T']:.2e} | "
                     f"{r['lam_err_T']:.2e} | {r['max_drift']:.2e} | {_resets_cell(r)} | {r['wall']:.1f} s |")
        L.append("")
    L.append("![the three λ modes](figures/lam-modes.png)")
    L.append("")
    L.append("Figure: one column per sleigh run (top: drift of the multiplier from the hidden "
             "constraint; bottom: q error against the closed form; against t) and, on the "
             "right, the contact oscillator (top: energy error; bottom: drift; against the step "
             "index, max per block of steps). Dash-dotted vertical lines: the resets of 'auto'.")
    L.append("")
    # --- the checks of the decision's measure of success
    if C:
        a, p, c = C.get("auto"), C.get("previous"), C.get("consistent")
        if a and p:
            bounded = a["last10"] <= 1.5 * a["first10"]
            same = a["digest"] == p["digest"]
            L.append(
                "**Reversible class.** "
                + check(a["lam_resets"] == 0 and same and bounded,
                        f"'auto' makes no reset in {a['n_steps']:,} steps and its run is bitwise "
                        "identical to the paper's scheme: the drift stays in its band (max "
                        f"{np.max(a['_lam_drift']):.2e} over the run, {a['lam_drift_first10']:.2e} / "
                        f"{a['lam_drift_last10']:.2e} in the first / last tenth), and the energy error is "
                        f"bounded ({a['first10']:.2e} → {a['last10']:.2e}, first → last tenth). ",
                        f"'auto' makes {a['lam_resets']} reset(s) (first at t = "
                        f"{a['resync_t'][0] if a['resync_t'] else float('nan'):.4g}), is "
                        f"{'' if same else 'not '}identical to 'previous', and its max |ΔH| goes "
                        f"{a['first10']:.2e} → {a['last10']:.2e} (first → last tenth; 'previous': "
                        f"{p['first10']:.2e} → {p['last10']:.2e}). ")
                + (f"'consistent' drifts: {c['first10']:.2e} → {c['last10']:.2e}, "
                   f"ΔH(T) = {c['final_dH']:+.2f}"
                   + (f", i.e. H(T) = {c['H0'] + c['final_dH']:.2f}, the energy H_y = "
                      f"{c['Hy0']:.2f} of the decoupled y oscillator alone: the rest of the "
                      "energy is gone" if abs(c["H0"] + c["final_dH"] - c["Hy0"]) < 0.02 else "")
                   + "." if c else ""))
            L.append("")
    if S:
        configs = list(dict.fromkeys((r["s"], r["h"], r["T"]) for r in S))
        parts = []
        for s, h, T in configs:
            R = {r["lam_start"]: r for r in S if (r["s"], r["h"], r["T"]) == (s, h, T)}
            a, p, c = R.get("auto"), R.get("previous"), R.get("consistent")
            if not (a and p and c):
                continue
            close = a["q_err_T"] <= max(10 * c["q_err_T"], 1e-12 * a["q_scale_T"])
            gain = p["q_err_T"] / max(a["q_err_T"], 1e-300)
            roundoff = a["q_err_T"] <= 1e-13 * a["q_scale_T"]
            parts.append(check(
                close and gain >= 100 and a["lam_resets"] > 0,
                f"s = {s}, h = {h:g}, T = {T:.0f}: 'auto' resets {a['lam_resets']} times "
                f"(t = {', '.join(f'{t:.4g}' for t in a['resync_t'][:6])}) and reaches "
                f"‖q − q(T)‖∞ = {a['q_err_T']:.2e}, against {c['q_err_T']:.2e} with 'consistent' "
                f"and {p['q_err_T']:.2e} with 'previous' ({gain:.1e}× larger)"
                + (f"; relative to ‖q(T)‖∞ = {a['q_scale_T']:.0f} that is "
                   f"{a['q_err_T'] / a['q_scale_T']:.1e}, round-off level" if roundoff else
                   f"; relative to ‖q(T)‖∞ = {a['q_scale_T']:.0f} that is "
                   f"{a['q_err_T'] / a['q_scale_T']:.1e}, the truncation error of the method at this h "
                   "(of the size of that of 'consistent'), not round-off") + ".",
                f"s = {s}, h = {h:g}, T = {T:.0f}: 'auto' ({a['lam_resets']} resets) reaches "
                f"‖q − q(T)‖∞ = {a['q_err_T']:.2e}, 'consistent' {c['q_err_T']:.2e}, 'previous' "
                f"{p['q_err_T']:.2e}; expected: 'auto' within 10× of 'consistent' and ≥ 100× "
                "better than 'previous', with at least one reset."))
        L.append("**Non-reversible class.** " + " ".join(parts))
        L.append("")
        for s, h, T in configs:
            R = {r["lam_start"]: r for r in S if (r["s"], r["h"], r["T"]) == (s, h, T)}
            a, p, c = R.get("auto"), R.get("previous"), R.get("consistent")
            if not (a and p and c):
                continue
            L.append(
                f"- *Drift, s = {s}, h = {h:g}:* with 'previous' ‖λ_n − λ(q_n, p_n)‖∞ grows to "
                f"{p['max_drift']:.1e} ({p['lam_excursions']} steps outside the band, λ error at T "
                f"{p['lam_err_T']:.1e}) and the q error follows it (figure). With 'consistent' it "
                f"stays ≤ {c['max_drift']:.1e}. With 'auto' it is "
                + (", ".join(f"{b:.1e} → {x:.1e}" for b, x in
                             zip(a["drift_before_reset"][:6], a["drift_after_reset"][:6]))
                   + " before → after the resets" if a["lam_resets"] else "never reset")
                + f", its maximum is {a['max_drift']:.1e}, its value at T {a['drift_T']:.1e}"
                + (f"; last reset at t = {a['resync_t'][-1]:.4g} of T = {T:.0f}" if a["resync_t"] else "")
                + (". Between resets it grows again (figure); the monitor's epochs restart at 10 steps and double after each "
                   "reset, so the next reset comes once the drift grows more than 10× from one "
                   "epoch to the next: intervals from the start to the first reset and between "
                   "resets " + ", ".join(f"{d:.3g}" for d in np.diff([0.0] + a["resync_t"][:8]))
                   + "." if a["lam_resets"] else "."))
        L.append("")
    # --- the other two modes on the 1e5-step runs above
    if variant_runs:
        L.append("### The other modes on the long runs above")
        L.append("")
        L.append("The runs of the table above (default 'auto') repeated with "
                 "`lam_start='previous'` and `'consistent'`:")
        L.append("")
        L.append("| example | h | lam_start | max\\|ΔH\\| first 10 % | max\\|ΔH\\| last 10 % | "
                 "drift rate | ‖λ−λ(q,p)‖∞ first / last 10 % | resets (auto) | identical to 'previous' | wall time |")
        L.append("|---|---|---|---|---|---|---|---|---|---|")
        by = {(r["name"], r["N"], r["lam_start"]): r for r in runs + variant_runs}
        for name in dict.fromkeys(r["name"] for r in runs):
            for N in LONG_N:
                for mode in LAM_MODES:
                    r = by.get((name, N, mode))
                    if r is None:
                        continue
                    ref = by.get((name, N, "previous"))
                    same = "—" if mode == "previous" or ref is None else (
                        "yes (bitwise)" if r["digest"] == ref["digest"] else "no")
                    stop = "" if r["success"] else f" (stopped at step {r['steps_done']:,})"
                    L.append(f"| {name}{stop} | {r['h']:.4f} | {mode_label(mode)} | {r['first10']:.2e} | "
                             f"{r['last10']:.2e} | {r['slope']:+.2e} | {fmt_e(r['lam_drift_first10'])} / "
                             f"{fmt_e(r['lam_drift_last10'])} | {_resets_cell(r)} | {same} | {r['wall']:.1f} s |")
        L.append("")
        L.append("![lam_start comparison](figures/long-runs-lam-start.png)")
        L.append("")
        for N in LONG_N:  # the non-reversible oscillator: what the three modes do with λ
            a, p, c = (by.get(("contact-nonreversible", N, m)) for m in LAM_MODES)
            if not (a and p and c):
                continue
            gain = a["lam_drift_last10"] / a["lam_drift_first10"]
            grows = gain > 3
            if not (grows or a["lam_resets"] or not p["success"]):
                continue
            lam_grows = a["lam_max_last10"] > 1.5 * a["lam_max_first10"]
            L.append(
                f"**Non-reversible oscillator, h = {a['h']:.4f}.** "
                + (f"'previous' stopped at step {p['steps_done']:,} of {p['n_steps']:,} "
                   f"(t = {p['t_end']:.0f}): *{p['message'].split(' Warning:')[0]}* "
                   if not p["success"] else
                   f"'previous' reaches a drift of {p['lam_drift_last10']:.1e} in the last tenth. ")
                + "'auto' " + ("finishes the run" if a["success"] else
                                f"stops at step {a['steps_done']:,}")
                + f" with {a['lam_resets']} reset(s)"
                + (f" (t = {', '.join(f'{t:.0f}' for t in a['resync_t'][:6])})" if a["resync_t"] else "")
                + (f", and its drift ‖λ_n − λ(q_n, p_n)‖∞ still grows from {a['lam_drift_first10']:.1e} "
                   f"(first tenth) to {a['lam_drift_last10']:.1e} (last tenth, {gain:.0f}×), with "
                   f"max |ΔH| {a['first10']:.1e} → {a['last10']:.1e} and max |λ| "
                   f"{a['lam_max_first10']:.1f} → {a['lam_max_last10']:.1f}"
                   + (": the energy of this non-reversible problem drifts far at this coarse "
                      "step and λ grows with the motion" if lam_grows else "")
                   + ". A drift that grows by less than 10× from one (doubling) epoch of the "
                   "monitor to the next is not an excursion, so slow growth is left alone"
                   + (" — **here 'auto' does not keep λ close to the hidden constraint**"
                      if a["lam_drift_last10"] > 1.0 else "")
                   if grows else f"; its drift stays at {a['lam_drift_last10']:.1e} in the last tenth")
                + f". 'consistent' keeps the drift at {c['lam_drift_last10']:.1e} and max |ΔH| at "
                f"{c['last10']:.1e} in the last tenth.")
            L.append("")
        rev = [r for r in variant_runs if r["name"] == "contact" and r["lam_start"] == "consistent"]
        grows = [r for r in rev if r["last10"] > 3 * r["first10"]]
        if grows:
            L.append(
                "**On the reversible oscillator 'consistent' does not keep the energy error "
                "bounded**: "
                + "; ".join(f"h = {r['h']:.4f}: max |ΔH| {r['first10']:.2e} → {r['last10']:.2e}"
                            for r in grows)
                + " (first → last tenth), while the paper's scheme and 'auto' stay bounded. "
                "It keeps the multiplier close to the hidden constraint, but the step map is "
                "no longer symmetric (Λ_1 is fixed by the hidden constraint at the start of the "
                "step while Λ_s is left free at its end; a step forward and one back miss the "
                "start, see `tests/test_longrun.py`), and with the symmetry goes the "
                "reversibility argument for bounded energy. For long-time energy behaviour on "
                "reversible problems use the default 'auto' (identical to the paper's scheme "
                "while the drift stays in its band) or 'previous'.")
        elif rev:
            L.append("On the reversible oscillator 'consistent' also keeps the energy error bounded "
                     "in these runs (max |ΔH| first → last tenth: "
                     + "; ".join(f"{r['first10']:.2e} → {r['last10']:.2e}" for r in rev) + ").")
        L.append("")
    return L


def plot_long_runs(runs, path):
    names = list(dict.fromkeys(r["name"] for r in runs))
    has_drift = all(r["_lam_drift"] is not None for r in runs)
    rows = 3 if has_drift else 2
    fig, axes = plt.subplots(rows, len(names), figsize=(6.2 * len(names), 3.2 * rows),
                             squeeze=False, constrained_layout=True)
    colors = {LONG_N[0]: "tab:blue", LONG_N[1]: "tab:orange"}
    for j, name in enumerate(names):
        ax_e, ax_c = axes[0, j], axes[1, j]
        for r in (r for r in runs if r["name"] == name):
            tm, em, b = envelope(r["_t"], r["_dH"])
            lab = f"h = 2 sin(π/{r['N']}) = {r['h']:.4f}"
            ax_e.semilogy(tm, em, color=colors.get(r["N"]), lw=1, label=lab)
            tm, pm, _ = envelope(r["_t"], r["_phi"])
            ax_c.semilogy(tm, np.maximum(pm, 1e-18), color=colors.get(r["N"]), lw=0.8, label=lab)
            if has_drift:
                tm, dm, _ = envelope(r["_t"], r["_lam_drift"])
                axes[2, j].semilogy(tm, np.maximum(dm, 1e-18), color=colors.get(r["N"]), lw=0.8,
                                    label=lab)
        ax_e.set_title(f"{name}, s = {LONG_STAGES}: |H − H0| (max per {b} steps)")
        ax_c.set_title(f"{name}: ‖φ(q_k, p_k)‖∞ (max per {b} steps)")
        ax_e.set_ylabel("|H(t) − H(0)|")
        ax_c.set_ylabel("‖φ‖∞")
        axes[-1, j].set_xlabel("t")
        if has_drift:
            axes[2, j].set_title(f"{name}: ‖λ_k − λ(q_k, p_k)‖∞ (max per {b} steps)")
            axes[2, j].set_ylabel("multiplier drift")
        for ax in axes[:, j]:
            ax.grid(True, which="both", alpha=0.3)
            ax.legend(fontsize=8)
    fig.savefig(path, dpi=110)
    plt.close(fig)


# ------------------------------------------------------------------------------ report
def study_table(ex, study, dropped):
    lines = [
        "| s | q observed | q theory | p observed | p theory | λ observed | λ theory | max ‖φ‖∞ | step counts n |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    flags = []
    for s in study.stages:
        cells = [str(s)]
        for c in COMPONENTS:
            kind, theory = classify(ex, study, s, c)
            obs = fmt_order(study.observed[s][c])
            if kind == "deviation":
                obs += " ⚠"
                flags.append((s, c))
            elif kind == "documented":
                obs += " †"
            cells += [obs, theory]
        n = study.n_steps[s]
        cells.append(f"{study.constraint_residual[s]:.1e}")
        cells.append(f"{n[0]}–{n[-1]} ({len(n)})")
        lines.append("| " + " | ".join(cells) + " |")
    notes = []
    for s in study.stages:
        for n, why in dropped.get(s, []):
            notes.append(f"s = {s}: n = {n} left out ({why}).")
    msgs = dropped.get("warnings", [])
    if msgs:
        notes.append(f"`solve` issued {len(msgs)} RuntimeWarning(s) during the study; the first: "
                     f"*{msgs[0]}*")
    return "\n".join(lines), flags, notes


def details_block(study):
    out = ["<details><summary>All errors (max over the grid of the max-norm error) and local "
           "slopes; bold = points used in the fit</summary>", ""]
    for s in study.stages:
        h = study.h[s]
        n = study.n_steps[s]
        out.append(f"**s = {s}**")
        out.append("")
        out.append("| n | h | err q | slope | err p | slope | err λ | slope |")
        out.append("|---|---|---|---|---|---|---|---|")
        cols = {}
        for c in COMPONENTS:
            e = study.errors[s][c]
            used = set(fit_indices(h, e, study.floors[c]).tolist())
            sl = local_slopes(h, e)
            cols[c] = [(f"**{fmt_e(e[i])}**" if i in used else fmt_e(e[i]),
                        "" if i == 0 else fmt_order(sl[i - 1])) for i in range(len(h))]
        for i in range(len(h)):
            row = [str(n[i]), f"{h[i]:.4g}"]
            for c in COMPONENTS:
                row += list(cols[c][i])
            out.append("| " + " | ".join(row) + " |")
        out.append("")
    out.append(f"Floors (errors at or below are not fitted): q {study.floors['q']:.1e}, "
               f"p {study.floors['p']:.1e}, λ {study.floors['lam']:.1e}. The local slope in a "
               "row is between that row and the previous one.")
    out.append("")
    out.append("</details>")
    return "\n".join(out)


def bracket_note(study, s, c) -> str:
    """Generic reading of a deviation: do the local slopes inside the fit window bracket
    the theoretical order (then the fitted value is within the scatter of the data)?"""
    h, e = study.h[s], study.errors[s][c]
    idx = np.sort(fit_indices(h, e, study.floors[c]))  # ascending h
    theory = study.expected[s][c]
    if idx.size < 3:
        return "Too few points above the floor to say more; not explained here."
    sl = np.diff(np.log(e[idx])) / np.diff(np.log(h[idx]))  # coarse -> fine
    lo, hi = float(np.min(sl)), float(np.max(sl))
    above = np.flatnonzero(e > study.floors[c])
    coarse = [i for i in above if i not in set(idx.tolist())]
    all_sl = local_slopes(h, e)
    before = [f"{all_sl[i - 1]:.2f}" for i in sorted(coarse, key=lambda i: -h[i])[-3:] if i > 0]
    if hi < 1.0:
        return (f"The errors in the fit window do not decrease with h (local slopes {lo:.2f} … "
                f"{hi:.2f}): they lie on an error plateau at about {np.min(e[idx]):.1e}, above "
                f"the floor ({study.floors[c]:.1e}), so the fit measures the plateau, not the "
                "order; the coarser points before it have local slopes "
                f"{', '.join(before) if before else '—'}. A plateau at this level means the "
                "component is resolved only to about that accuracy in this build (round-off or "
                "the Newton stopping test), not a lower order of the method.")
    if sl[-1] == lo and sl[-1] < theory - 1.0:
        return (f"The local slopes fall towards the finest steps ({', '.join(f'{x:.2f}' for x in sl)}, "
                f"coarse → fine): the errors flatten onto a plateau of about {np.min(e[idx]):.1e}, "
                f"above the floor ({study.floors[c]:.1e}); the points before it follow the theory. "
                "This is an accuracy limit of the computation in this build (round-off or the "
                "Newton stopping test), not a lower order of the method.")
    if lo <= theory <= hi:
        return (f"The local slopes inside the fit window ({lo:.2f} … {hi:.2f}) bracket the "
                f"theoretical {theory}; the window spans only h = {h[idx].max():.3g} … "
                f"{h[idx].min():.3g} before the error reaches the floor, so the deviation is "
                "within the scatter of the data, not evidence of a different order.")
    return (f"The local slopes inside the fit window ({lo:.2f} … {hi:.2f}) do not bracket the "
            f"theoretical {theory}. Not explained here.")


def summary(cfg, studies, specials, runs):
    counts = {"ok": 0, "documented": [], "deviation": []}
    for name, (study, _, _) in studies.items():
        ex = get_example(name)
        for s in study.stages:
            for c in COMPONENTS:
                kind, _ = classify(ex, study, s, c)
                if kind == "ok":
                    counts["ok"] += 1
                else:
                    counts[kind].append((name, s, c, study.observed[s][c], study.expected[s][c]))
    total = counts["ok"] + len(counts["documented"]) + len(counts["deviation"])
    L = ["## Summary", ""]
    for name, msg in specials.get("failed", {}).items():
        L.append(f"- **Convergence study of {name} failed** (no table below): {msg}")
    L.append(f"- Convergence (paper's scheme, `lam_start='previous'`): {len(studies)} closed-form "
             f"examples × s = {list(cfg['stages'])} × "
             f"(q, p, λ) = {total} observed orders; {counts['ok']} within {ORDER_TOL} of the "
             "generic theory (q, p: 2s−2; λ: s for even s, s−1 for odd s).")
    ac = specials.get("auto_checks", {})
    if ac:
        n_runs = sum(a["runs"] for a in ac.values())
        n_same = sum(a["identical"] for a in ac.values())
        dmax = max(a["max_order_diff"] for a in ac.values())
        L.append(f"- The same {n_runs} convergence runs with the default `lam_start='auto'`: "
                 f"{n_same} give identical errors"
                 + ("; all observed orders are the same." if dmax == 0 else
                    f"; the observed orders differ by at most {dmax:.2f}."))
    if counts["documented"]:
        L.append("- Documented special cases, matched: " + "; ".join(
            f"{n} s = {s} {LABEL[c]}: {fmt_order(o)}" for n, s, c, o, _ in counts["documented"]) + ".")
    for n, s, c, o, t in counts["deviation"]:
        study = studies[n][0]
        why = specials["explain"].get((n, s, c), bracket_note(study, s, c))
        L.append(f"- Deviation: {n} s = {s} {LABEL[c]}: {fmt_order(o)} vs {t}. {why}")
    cmax = max(max(st.constraint_residual.values()) for st, _, _ in studies.values()) if studies else float("nan")
    L.append(f"- Constraint residual at the step points, max over all {sum(len(np.concatenate(list(st.n_steps.values()))) for st, _, _ in studies.values())} "
             f"convergence runs: {cmax:.1e}.")
    for r in runs:
        if not r["success"]:
            L.append(f"- Long run, {r['name']}, h = {r['h']:.4f}: **stopped at step "
                     f"{r['steps_done']:,} of {r['n_steps']:,}** (t = {r['t_end']:.0f}): "
                     f"{r['message'].split(';')[0]}.")
            continue
        L.append(f"- Long run ('{r['lam_start']}'), {r['name']}, h = {r['h']:.4f}, {r['n_steps']:,} "
                 f"steps: max |ΔH| "
                 f"{r['first10']:.2e} (first 10 %) → {r['last10']:.2e} (last 10 %), linear-fit "
                 f"drift {r['slope']:+.1e} per unit time, max ‖φ‖∞ {r['max_phi']:.1e}, "
                 f"{r['lam_resets']} λ resets, {r['wall']:.1f} s.")
    for r in specials.get("variant_runs", []):
        if not r["success"]:
            L.append(f"- Long run with lam_start='{r['lam_start']}', {r['name']}, h = {r['h']:.4f}: "
                     f"**stopped at step {r['steps_done']:,} of {r['n_steps']:,}** (t = {r['t_end']:.0f}): "
                     f"{r['message'].split(' Warning:')[0]}")
            continue
        if r["lam_start"] != "consistent":
            continue
        L.append(f"- Long run with lam_start='consistent', {r['name']}, h = {r['h']:.4f}: max |ΔH| "
                 f"{r['first10']:.2e} (first 10 %) → {r['last10']:.2e} (last 10 %)"
                 + ("" if r["success"] else f", **stopped at step {r['steps_done']:,}**") + ".")
    lam = specials.get("lam", {})
    C = {r["lam_start"]: r for r in lam.get("contact", [])}
    if C:
        r0 = next(iter(C.values()))
        L.append(f"- **λ mode, reversible class** (contact, s = {LONG_STAGES}, h = {r0['h']:.4f}, "
                 f"{r0['n_steps']:,} steps), max |ΔH| first → last tenth: "
                 + "; ".join(f"'{m}' {C[m]['first10']:.2e} → {C[m]['last10']:.2e}"
                             + (f" ({C[m]['lam_resets']} resets"
                                + (", bitwise identical to 'previous')" if "previous" in C
                                   and C[m]["digest"] == C["previous"]["digest"] else ")")
                                if m == "auto" else "")
                             for m in LAM_MODES if m in C) + ".")
    S = lam.get("sleigh", [])
    for cfg_key in dict.fromkeys((r["s"], r["h"], r["T"]) for r in S):
        R = {r["lam_start"]: r for r in S if (r["s"], r["h"], r["T"]) == cfg_key}
        s_, h_, T_ = cfg_key
        L.append(f"- **λ mode, non-reversible class** (sleigh, s = {s_}, h = {h_:g}), "
                 f"‖q − q(T)‖∞ at T = {T_:.0f}: "
                 + "; ".join(f"'{m}' {R[m]['q_err_T']:.2e}"
                             + (f" ({R[m]['lam_resets']} resets)" if m == "auto" else "")
                             for m in LAM_MODES if m in R) + ".")
    L.append("")
    return L


def check(flag: bool, text_true: str, text_false: str) -> str:
    return text_true if flag else "**Not confirmed by this run:** " + text_false


def write_report(out_dir: Path, cfg, quick, studies, specials, long_runs, timings, info):
    L = []
    now = datetime.datetime.now(datetime.timezone.utc)
    L.append("# Verification report")
    L.append("")
    L.append("Generated by `python scripts/make_verification.py` from the repository root "
             "(do not edit by hand; rerun the script). "
             + ("**This is a `--quick` smoke run (fewer stages and steps); not the report.**"
                if quick else ""))
    L.append("")
    L.append(f"- Date: {now:%Y-%m-%d %H:%M} UTC")
    L.append(f"- Machine: {info['cpu']}, {info['logical cores']} logical cores, {info['os']}; "
             f"JAX backend: {info['jax backend']}")
    L.append(f"- Software: Python {info['python']}, JAX {info['jax']}, NumPy {info['numpy']}, "
             f"matplotlib {info['matplotlib']}, lobattodae {info['lobattodae']} (git {info['git']})")
    L.append(f"- Total run time of the script: {timings['total']:.0f} s "
             f"(convergence studies {timings['studies']:.0f} s, of which "
             f"{sum(a['wall'] for a in specials.get('auto_checks', {}).values()):.0f} s for their "
             f"repetition with lam_start='auto'; special-case runs "
             f"{timings['specials']:.0f} s, long runs {timings['long']:.0f} s, λ-mode comparison "
             f"{timings.get('lam_modes', 0.0):.0f} s)")
    L.append("")
    L += summary(cfg, studies, specials, long_runs)
    L.append("Contents: [1 Convergence orders](#1-convergence-orders) · "
             "[2 Special cases](#2-special-cases-superconvergence-and-exactness) · "
             "[3 Deviations](#3-deviations-from-theory) · "
             "[4 Long runs](#4-long-runs-energy-and-constraint) · "
             "[5 Mechanics systems](#5-systems-built-with-lobattodaemechanics)")
    L.append("")

    # ---------------------------------------------------------------- section 1
    L.append("## 1. Convergence orders")
    L.append("")
    L.append(
        "For every example of `lobattodae.examples` with a closed-form solution, "
        "`convergence_study(example, stages=..., n_steps=...)` integrates over the example's "
        "`t_span` with s-stage Lobatto IIIA-IIIB and constant steps h = T/n. The error of a "
        "component is the maximum over all grid points of the max-norm error against the "
        "exact solution. The observed order is the least-squares slope of log(error) against "
        f"log(h) over the {N_FIT} smallest step sizes whose error is above a round-off floor "
        "(the library's `observed_order`). Theory (DESIGN.md §3): q, p of order 2s−2; λ of "
        "order s for even s and s−1 for odd s.")
    L.append("")
    ac = specials.get("auto_checks", {})
    para = ("**λ mode.** The studies (and the special-case runs of §2) use "
            "`LobattoIIIAIIIB(stages=s, lam_start='previous')` explicitly, the paper's scheme "
            "Λ_1 = λ_n: the proven orders refer to it. The library's default `'auto'` is the "
            "same scheme re-synchronised with the hidden constraint when the drift "
            "‖λ_n − λ(q_n, p_n)‖ leaves its band (§4), so it takes the paper's steps until "
            "the first such excursion.")
    if ac:
        n_runs = sum(a["runs"] for a in ac.values())
        n_same = sum(a["identical"] for a in ac.values())
        n_exc = sum(a["excursion_runs"] for a in ac.values())
        dmax = max(a["max_order_diff"] for a in ac.values())
        rel = max(a["max_rel_diff"] for a in ac.values())
        para += (f" Every study was repeated with `'auto'` ({sum(a['wall'] for a in ac.values()):.0f} s): "
                 f"{n_same} of the {n_runs} runs give bitwise identical errors"
                 + ("" if n_same == n_runs else
                    f" (largest relative difference of an error: {rel:.1e}; per example: "
                    + ", ".join(f"{n} {a['identical']}/{a['runs']}" for n, a in ac.items()) + ")")
                 + f"; the 'previous' runs reported {n_exc} drift excursion(s)"
                 + (", so 'auto' never re-synchronised on these short intervals, and the observed "
                    "orders with 'auto' are the same as in the tables."
                    if n_same == n_runs and dmax == 0 else
                    f"; the observed orders with 'auto' differ from those in the tables by at most "
                    f"{dmax:.2f}."))
    L.append(para)
    L.append("")
    L.append(
        f"Floors: for λ the library default {PLATEAU_REL['lam']:g}·(1 + max|λ|); for q and p "
        f"{QP_PLATEAU:g}·(1 + max|x|), lower than the library default, because with "
        f"{PLATEAU_REL['q']:g} the fits for s ≥ 5 would be left with only their coarsest "
        "(pre-asymptotic) step sizes or none at all. λ keeps the higher floor: it is recovered "
        "from h·Λ, and its round-off level grows as h shrinks.")
    L.append("")
    rl = [(name, roundoff_levels(st, cfg["stages"])) for name, (st, _, _) in studies.items()]
    rl = [(n, r) for n, r in rl if r is not None]
    if rl:
        worst = {c: max(r[c] for _, r in rl) for c in ("q", "p")}
        # per example and component: floor / measured round-off level
        ratios = sorted((studies[n][0].floors[c] / r[c], n, c) for n, r in rl for c in ("q", "p"))
        rmin, rn, rc = ratios[0]
        L.append(
            f"Measured round-off level (largest q, p error of the s = {max(cfg['stages'])} runs "
            f"with h ≤ T/32, where the truncation error is far below eps): up to "
            f"{worst['q']:.1e} in q and {worst['p']:.1e} in p. Per example, the q/p floor is at "
            f"least {rmin:.1f}× the example's own round-off level (smallest: {rn}, {LABEL[rc]})"
            + ("." if rmin >= 3 else
               " — **less than 3×: the finest fitted q/p points of that example may carry "
               "round-off of up to a third of their size.**"))
    L.append("")
    L.append(
        "Step counts: the library's `default_step_counts` for s ≤ 4"
        + (f"; for s = 5 and 6 denser and coarser lists ({cfg['counts'].get(5)} and "
           f"{cfg['counts'].get(6)}), because with the default counts the q and p errors of "
           "s = 6 fall below the floor after the first one or two counts (several entries "
           "would read '—', i.e. no order measurable)" if 6 in cfg["stages"] else "")
        + ". Counts coarser than the library default are tried first and left out where "
        "Newton fails. The vertical disk uses even counts only (its error constants depend "
        "on the parity of n, see its `notes`). Marks: † = a special case documented in the "
        "example's `expected_order_overrides` and matched; ⚠ = observed differs from the "
        f"expectation by more than {ORDER_TOL} (discussed in §2–3); — = no order measurable "
        "(fewer than two errors above the floor). Dotted lines in the plots: slope of the "
        "generic theory; dashed grey: the floor.")
    L.append("")
    all_flags = []
    for name, (study, dropped, elapsed) in studies.items():
        ex = get_example(name)
        L.append(f"### {name}")
        L.append("")
        L.append(f"{ex.description}. Example notes: *{ex.notes}*")
        L.append("")
        table, flags, notes = study_table(ex, study, dropped)
        all_flags += [(name, s, c) for s, c in flags]
        L.append(table)
        L.append("")
        for n in notes:
            L.append(f"- {n}")
        if notes:
            L.append("")
        L.append(f"![convergence plot for {name}](figures/convergence-{name}.png)")
        L.append("")
        L.append(details_block(study))
        L.append(f"\nStudy run time: {elapsed:.1f} s.")
        L.append("")

    # ---------------------------------------------------------------- section 2
    L.append("## 2. Special cases: superconvergence and exactness")
    L.append("")
    L += specials["text"]

    # ---------------------------------------------------------------- section 3
    L.append("## 3. Deviations from theory")
    L.append("")
    if not all_flags:
        L.append(f"None: every observed order is within {ORDER_TOL} of the generic theory or "
                 "of a documented special case.")
        L.append("")
    else:
        L.append(f"Observed orders more than {ORDER_TOL} away from the generic theory and not "
                 "matching a documented special case (⚠ in the tables):")
        L.append("")
        for name, s, c in all_flags:
            study = studies[name][0]
            h = study.h[s]
            e = study.errors[s][c]
            idx = fit_indices(h, e, study.floors[c])
            sl = local_slopes(h, e)
            above = np.flatnonzero(e > study.floors[c])
            tail = [f"{sl[i - 1]:.2f} (n {study.n_steps[s][i - 1]}→{study.n_steps[s][i]})"
                    for i in above if i > 0 and (i - 1) in above]
            L.append(
                f"- **{name}, s = {s}, {LABEL[c]}**: observed {fmt_order(study.observed[s][c])}, "
                f"theory {study.expected[s][c]}; fit over n = {sorted(study.n_steps[s][idx].tolist())}. "
                f"Local slopes above the floor: {', '.join(tail) if tail else 'none'}. "
                + specials["explain"].get((name, s, c), bracket_note(study, s, c)))
        L.append("")

    # ---------------------------------------------------------------- section 4
    L.append("## 4. Long runs: energy and constraint")
    L.append("")
    L += long_text(long_runs)
    L += lam_mode_text(specials.get("lam", {"contact": [], "sleigh": []}), long_runs,
                       specials.get("variant_runs", []))
    L += MECHANICS_SECTION

    (out_dir / "verification.md").write_text("\n".join(L) + "\n")


#: Section 5 is a map, not a computation: the systems built with ``lobattodae.mechanics`` are
#: verified by their tests, and their measured tables live with their guides.
MECHANICS_SECTION = [
    "",
    "## 5. Systems built with `lobattodae.mechanics`",
    "",
    "Each system of `lobattodae.mechanics.systems` is checked against an independent reference by "
    "its tests (default run; longer studies under `-m slow`); the measured numbers, dated, are in "
    "the guides:",
    "",
    "| systems | reference | tests | measured |",
    "|---|---|---|---|",
    "| sleigh, knife edge, falling disk (derived from the disk's geometry) | the hand-written "
    "problems of `lobattodae.examples`: f, g, φ, energy at random states; a solve | "
    "`tests/test_mechanics.py` | [mechanics.md](mechanics.md) |",
    "| turntable ball (affine, time-dependent constraints) | closed form (the centre circles at 2Ω/7) | "
    "`tests/test_mechanics.py` | [mechanics.md](mechanics.md) |",
    "| differential-drive robot (time-dependent torques, damping) | reduced ODE derived by hand, "
    "scipy DOP853 | `tests/test_mechanics.py` | [mechanics.md](mechanics.md) |",
    "| Cartesian pendulum and double pendulum (holonomic, kept exactly) | angle ODEs, scipy DOP853; "
    "orders 2s − 2 for s = 2..5 | `tests/test_holonomic.py` | [mechanics.md](mechanics.md) |",
    "| models from `KanesMethod`, `System`, `LagrangesMethod` | the same systems from "
    "`from_lagrangian`; SymPy's own Kane equations | `tests/test_kane.py`, `tests/test_mechanics.py` | "
    "[mechanics.md](mechanics.md) |",
    "| Suslov problem, Chaplygin sphere, rattleback (unit quaternions) | reduced equations derived "
    "independently, scipy DOP853; first integrals; spin reversal | `tests/test_rigid.py` | "
    "[rigid-bodies.md](rigid-bodies.md) |",
    "| Whipple bicycle | the published benchmark (Meijaard et al. 2007): M, C1, K0, K2, eigenvalues, "
    "weave and capsize speeds | `tests/test_bicycle.py` | [bicycle.md](bicycle.md) |",
]


def drift_shape(r) -> str:
    g = np.asarray(r["decile_gain"])
    lo, hi = float(np.min(g)), float(np.max(g))
    linear = lo > 0 and hi / lo <= 2
    return (("The drift is close to linear" if linear else "The drift is not linear")
            + f": the energy gained per tenth of the run ranges from {lo:+.2e} to {hi:+.2e} "
            f"(tenth with the largest gain: {int(np.argmax(g)) + 1} of 10); fitted rates "
            f"{r['slope_first']:+.2e} per unit time over the first tenth, {r['slope_last']:+.2e} "
            f"over the last, {r['slope']:+.2e} over the whole run.")


def long_text(runs):
    L = []
    if not runs:
        return ["(not run)"]
    n = runs[0]["n_steps"]
    L.append(
        f"McLachlan–Perlmutter contact oscillator (`contact`, reversible) and its variant with "
        f"S = cos z (`contact-nonreversible`), s = {LONG_STAGES}, {n:,} steps of "
        f"h = 2 sin(π/N) for N = {LONG_N[0]} and {LONG_N[1]}, initial data of the examples "
        f"(H = {runs[0]['H0']:.4g}, H_y = {runs[0]['Hy0']:.4g}, ε = {runs[0]['epsilon']:.4g}), "
        f"with the library's default `lam_start='{runs[0]['lam_start']}'` (the other two modes "
        "follow below). The exact flow conserves H (dH/dt = φᵀλ = 0). "
        "ΔH = H(q_k, p_k) − H(q_0, p_0) from `invariant_error`; ‖φ‖ from "
        "`sol.stats['constraint_residual']`. 'First/last 10 %': max |ΔH| over the first/last "
        "tenth of the steps; 'drift rate': slope of a least-squares line through ΔH(t) over the "
        "whole run (and over the first and last tenth).")
    L.append("")
    L.append("| example | h | T | H0 | max\\|ΔH\\| first 10 % | max\\|ΔH\\| last 10 % | ΔH(T) | "
             "drift rate (whole run) | rate, first 10 % | rate, last 10 % | max ‖φ‖∞ | "
             "max\\|ΔH_y\\| | ‖λ−λ(q,p)‖ first / last 10 % | λ resets | Newton its (mean/max) | wall time |")
    L.append("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for r in runs:
        T_cell = (f"{r['T']:.0f}" if r["success"] else
                  f"**stopped at t = {r['t_end']:.0f}** (step {r['steps_done']:,} of {r['n_steps']:,})")
        L.append(
            f"| {r['name']} | 2 sin(π/{r['N']}) = {r['h']:.4f} | {T_cell} | {r['H0']:.4f} | "
            f"{r['first10']:.2e} | {r['last10']:.2e} | {r['final_dH']:+.2e} | {r['slope']:+.2e} | "
            f"{r['slope_first']:+.2e} | {r['slope_last']:+.2e} | {r['max_phi']:.1e} | "
            f"{r['max_dHy']:.1e} | {fmt_e(r['lam_drift_first10'])} / {fmt_e(r['lam_drift_last10'])} | "
            f"{r['lam_resets'] if r['lam_start'] == 'auto' else '—'} | "
            f"{r['newton_mean']:.2f} / {r['newton_max']} | {r['wall']:.1f} s |")
    L.append("")
    L.append("Wall time includes JIT compilation. ‖λ−λ(q,p)‖: distance of the multiplier from "
             "the hidden constraint at the step points (`sol.stats['multiplier_drift']`). "
             "λ resets: re-synchronisations of λ by 'auto' (`sol.stats['lam_resets']`). "
             "Statistics of a run that stopped are over its computed steps.")
    for r in runs:
        if not r["success"]:
            L.append(f"- **{r['name']}, h = {r['h']:.4f} did not finish:** *{r['message']}*")
    for r in runs:
        if r["warnings"]:
            L.append(f"- `solve` warned on {r['name']}, h = {r['h']:.4f}: *{r['warnings'][0]}*")
    L.append("")
    L.append("![long runs](figures/long-runs-contact.png)")
    L.append("")
    by = {(r["name"], r["N"]): r for r in runs}
    rev = [by.get(("contact", N)) for N in LONG_N]
    nrev = [by.get(("contact-nonreversible", N)) for N in LONG_N]
    if rev[0]:
        r = rev[0]
        ratio = abs(r["slope"]) * r["T"] / r["max_dH"]
        bounded = r["last10"] <= 1.5 * r["first10"] and ratio < 0.05
        L.append(
            "**Reversible oscillator.** "
            + check(bounded,
                    f"The energy error is bounded: max |ΔH| is {r['first10']:.2e} over the first "
                    f"and {r['last10']:.2e} over the last tenth of the run; the fitted linear "
                    f"drift ({r['slope']:+.1e} per unit time) accumulates to "
                    f"{abs(r['slope']) * r['T']:.1e} over T = {r['T']:.0f}, "
                    f"{ratio:.1e} of the oscillation amplitude, i.e. no measurable drift.",
                    f"max |ΔH| grows from {r['first10']:.2e} (first tenth) to {r['last10']:.2e} "
                    f"(last tenth); drift rate {r['slope']:+.2e}.")
        )
        if rev[1]:
            q = rev[0]["max_dH"] / rev[1]["max_dH"]
            p = math.log(q) / math.log(rev[0]["h"] / rev[1]["h"])
            L.append(
                f"With the smaller step the bounded error is {rev[1]['max_dH']:.2e} "
                f"(ratio {q:.0f}, i.e. h^{p:.2f}; the method has order {2 * LONG_STAGES - 2}).")
        L.append("")
    if nrev[0]:
        r = nrev[0]
        drift = r["last10"] > 3 * r["first10"]
        stop = ("" if r["success"] else
                f"(This run stopped at step {r['steps_done']:,} of {r['n_steps']:,}, "
                f"t = {r['t_end']:.0f}: *{r['message']}* The numbers are over the computed "
                "steps.) ")
        L.append(
            "**Non-reversible oscillator.** " + stop
            + check(drift,
                    f"The energy drifts: max |ΔH| is {r['first10']:.2e} over the first and "
                    f"{r['last10']:.2e} over the last tenth; ΔH({'T' if r['success'] else 'last step'}) = {r['final_dH']:+.2e} "
                    f"({100 * r['final_dH'] / r['H0']:+.3g} % of H0 = {r['H0']:.2f}). "
                    + drift_shape(r) + " ",
                    f"max |ΔH| is {r['first10']:.2e} (first tenth) and {r['last10']:.2e} (last "
                    "tenth): no clear drift in this run. ")
        )
        if nrev[1]:
            q = nrev[0]["slope_first"] / nrev[1]["slope_first"]
            p = math.log(abs(q)) / math.log(nrev[0]["h"] / nrev[1]["h"]) if q > 0 else float("nan")
            L.append(
                f"With h = 2 sin(π/{LONG_N[1]}) the early drift rate is "
                f"{nrev[1]['slope_first']:+.2e} per unit time (ratio {q:.3g} to the larger step, "
                f"i.e. ∝ h^{p:.2f}; order of the method {2 * LONG_STAGES - 2}), and max |ΔH| over "
                f"the run is {nrev[1]['max_dH']:.2e}. A drift that shrinks like a power of h is a "
                "truncation-error effect of the method, not a conservation bug: the exact flow "
                "conserves H, but nonholonomic flows are not symplectic, so there is no "
                "symplectic backward-error argument for the energy; the bounded energy error on "
                "the first problem rests on the reversibility of the system and the method "
                "(McLachlan & Perlmutter 2006; Modin & Verdier 2020), which S = cos z destroys.")
        for r in nrev[1:]:
            if r is not None:
                L.append("")
                L.append(f"*h = {r['h']:.4f}:* " + drift_shape(r))
        L.append("")
        L.append(
            "In both problems the constraint holds to round-off at every step point "
            f"(max ‖φ‖∞ ≤ {max(x['max_phi'] for x in runs):.1e}), as it must (the last stage "
            "enforces φ(q₁, p₁) = 0 to Newton tolerance), and the decoupled oscillator energy "
            f"H_y stays within {max(x['max_dHy'] for x in runs):.1e}.")
        if all(x["lam_drift_first10"] is not None for x in runs):
            grow = [x for x in runs if x["lam_drift_last10"] > 3 * x["lam_drift_first10"]]
            L.append(
                "The multiplier's distance from the hidden constraint, ‖λ_k − λ(q_k, p_k)‖, is "
                "large at these coarse steps (λ has order only s − 1 = "
                f"{LONG_STAGES - 1} for s = {LONG_STAGES}, and with R(∞) = +1 the paper's "
                "scheme never damps its errors): "
                + "; ".join(f"{x['name']}, h = {x['h']:.3f}: {x['lam_drift_first10']:.1e} → "
                            f"{x['lam_drift_last10']:.1e}"
                            + (f" ({x['lam_resets']} resets)" if x["lam_start"] == "auto" else "")
                            for x in runs)
                + " (max over the first → last tenth). "
                + ("It does not grow in any of the runs."
                   if not grow else
                   "It grows (more than 3×) in: " + ", ".join(
                       f"{x['name']} (h = {x['h']:.3f})" for x in grow) + ".")
                + (" 'auto' re-synchronised λ in: " + ", ".join(
                    f"{x['name']} (h = {x['h']:.3f}, {x['lam_resets']}×)" for x in runs
                    if x["lam_resets"]) + "." if any(x["lam_resets"] for x in runs) else
                   " 'auto' made no reset in these runs.")
                + (" On the reversible problem it made none: there the drift stays in its band."
                   if any(x["lam_resets"] for x in runs)
                   and not any(x["lam_resets"] for x in runs if x["name"] == "contact") else ""))
        L.append("")
        L.append("<details><summary>ΔH at every tenth of the runs</summary>")
        L.append("")
        L.append("| example | h | " + " | ".join(f"{10 * i} %" for i in range(11)) + " |")
        L.append("|---|---|" + "---|" * 11)
        for r in runs:
            L.append(f"| {r['name']} | {r['h']:.4f} | "
                     + " | ".join(f"{d:+.2e}" for _, d in r["deciles"]) + " |")
        L.append("")
        L.append("</details>")
        L.append("")
    return L


# ------------------------------------------------------------------- special-case text
def special_cases(cfg, studies):
    text, explain = [], {}
    stages = cfg["stages"]

    # --- knife edge, s = 2, lambda
    if "knife-edge" in studies and 2 in stages:
        rows = knife_edge_lambda(cfg)
        even_exact = all(r["even_max"] < 1e-12 for r in rows)
        odd_const = all(abs(r["odd_max"] - r["pred"]) <= 1e-9 + 1e-6 * r["pred"]
                        and abs(r["odd_min"] - r["pred"]) <= 1e-9 + 1e-6 * r["pred"] for r in rows)
        st = studies["knife-edge"][0]
        text.append("### Knife edge, s = 2: λ exact at every other step")
        text.append("")
        text.append(
            "θ' = p_θ/J is constant (H does not depend on θ and μ has no θ-component), so θ "
            "and p_θ are reproduced exactly. For s = 2 the scheme is RATTLE-like: "
            "p_{k+½} = p_k + (h/2)(−∇V + μ_k λ_k), q_{k+1} = q_k + h p_{k+½}/m, "
            "p_{k+1} = p_{k+½} + (h/2)(−∇V + μ_{k+1} λ_{k+1}), φ(q_{k+1}, p_{k+1}) = 0. With "
            "μ_k = (−sin θ_k, cos θ_k, 0), p_k = m v_k (cos θ_k, sin θ_k, ·) (the constraint) "
            "and c = cos ωh, σ = sin ωh, projecting on μ_{k+1} and on the blade direction gives "
            "λ_{k+1} + c λ_k = 2mg cos θ_{k+1} + (2σ/h) m v_k and "
            "m v_{k+1} = c m v_k + (h/2) σ λ_k − h m g sin θ_{k+1}. Eliminating v: "
            "**λ_{k+2} = λ_k + 2mg (cos θ_{k+2} − cos θ_k)**, and the exact multiplier "
            "λ(t) = mωv₀ − mg cos θ₀ + 2mg cos θ(t) satisfies the same two-step relation. Since "
            "θ_k is exact and λ_0 is consistent, λ_k is exact at every even k; at odd k the error "
            "is that of λ_1, the same at every odd step: "
            "mg cos θ₀ (1 − cos ωh) + m v₀ (2 sin(ωh)/h − ω(1 + cos ωh)) = O(h²) "
            "(the R(∞) = −1 oscillation, undamped here).")
        text.append("")
        text.append("| n | h | max λ error, even k | λ error at odd k (min … max) | predicted odd-k error | λ error at t = T | max q error |")
        text.append("|---|---|---|---|---|---|---|")
        for r in rows:
            text.append(f"| {r['n']} | {r['h']:.4g} | {r['even_max']:.1e} | {r['odd_min']:.6e} … "
                        f"{r['odd_max']:.6e} | {r['pred']:.6e} | {r['final']:.1e} | {r['q']:.1e} |")
        text.append("")
        text.append(check(even_exact and odd_const,
                          "The run confirms it: even-k errors are at round-off, the odd-k error "
                          "is one constant equal to the prediction. ",
                          "even-k errors or odd-k errors do not match the derivation above. "))
        o2 = st.observed[2]["lam"]
        ex = get_example("knife-edge")
        documented = 2 in ex.expected_order_overrides.get("lam", {})
        text.append(
            f"Consequently the s = 2 λ entry of the knife-edge table reads {fmt_order(o2)}, "
            "not 'exact': the study measures the maximum over *all* grid points, which includes "
            "the odd ones (the error at t = T alone would measure no order for even n). "
            + ("The example's `expected_order_overrides` declares λ exact for s = 2, which holds "
               "at even steps only; this is why that entry is flagged. It is explained, not a "
               "defect of the method."
               if documented else
               "The example documents this and (rightly) declares no override for it."))
        text.append("")
        explain[("knife-edge", 2, "lam")] = (
            "Explained in §2 (λ is exact at even steps, O(h²) and constant at odd ones; the "
            "study's max over all steps sees the odd ones).")

    # --- vertical disk
    if "vertical-disk" in studies:
        comp = vertical_disk_components(cfg)
        st = studies["vertical-disk"][0]
        text.append("### Vertical rolling disk: p superconverges for even s")
        text.append("")
        text.append(
            "Here H has no potential and does not depend on φ, and μᵀλ has no φ-component, so "
            "p_φ' = 0 and φ' = p_φ/J: every Runge–Kutta method reproduces constants and linear "
            "functions, so φ and p_φ are exact at all stages (table below: errors at round-off). "
            "At every step point the constraint holds to round-off, so p_x = (mR/I) cos φ_k p_θ "
            "and p_y = (mR/I) sin φ_k p_θ with φ_k exact: **the whole p error is the error of the "
            "single scalar p_θ**, a conserved quantity of the exact motion "
            "(p_θ + R(cos φ p_x + sin φ p_y) = (1 + mR²/I) p_θ is a first integral). The "
            "positions x, y (and θ, except for s = 2) show the generic q order 2s−2 in the "
            "table below.")
        text.append("")
        text.append("Per-component max errors for two step counts and the order between them "
                    "(— : at round-off):")
        text.append("")
        names = next(iter(comp.values()))["names"] if comp else []
        text.append("| s | n | " + " | ".join(names) + " |")
        text.append("|---|---|" + "---|" * len(names))
        for s, d in comp.items():
            text.append(f"| {s} | {d['n'][0]} | " + " | ".join(fmt_e(x) for x in d["e1"]) + " |")
            text.append(f"| {s} | {d['n'][1]} | " + " | ".join(fmt_e(x) for x in d["e2"]) + " |")
            text.append(f"| {s} | order | " + " | ".join(fmt_order(x) for x in d["order"]) + " |")
        text.append("")
        pth = {s: d["order"][7] for s, d in comp.items()}
        even = [s for s in pth if s % 2 == 0]
        odd = [s for s in pth if s % 2 == 1]
        even_2s = all(abs(pth[s] - 2 * s) <= 0.5 for s in even)
        odd_reg = all(abs(pth[s] - (2 * s - 2)) <= 0.5 for s in odd)
        phi_exact = all(d["e1"][2] < 1e-12 and d["e1"][6] < 1e-12 for d in comp.values())
        text.append(check(
            even_2s and odd_reg and phi_exact,
            "In this run p_θ (hence p) has order 2s for even s ("
            + ", ".join(f"s = {s}: {pth[s]:.2f}" for s in even) + ") and the regular 2s−2 "
            "for odd s (" + ", ".join(f"s = {s}: {pth[s]:.2f}" for s in odd) + "); φ, p_φ are "
            "exact. ",
            "p_θ orders " + ", ".join(f"s = {s}: {pth[s]:.2f}" for s in pth) + " do not all "
            "follow '2s for even s, 2s−2 for odd s' within 0.5"
            + ("" if phi_exact else ", and φ / p_φ are not exact") + ". "))
        text.append(
            "What this argument does not give is *why* the conserved p_θ gains two orders only "
            "for even s (where R(∞) = −1 and the λ errors alternate in sign from step to step; "
            "a cancellation of the per-step p_θ changes over consecutive steps would explain "
            "it). We have not derived it; it is an observation"
            + (f" (even s measured here: {even})." if even else "."))
        if 6 in st.stages:
            o = st.observed[6]["p"]
            kind, _ = classify(get_example("vertical-disk"), st, 6, "p")
            listed = sorted(get_example("vertical-disk").expected_order_overrides.get("p", {}))
            text.append(
                f" For s = 6 the study's fitted p order is {fmt_order(o)} (generic theory 10, "
                f"pattern 2s = 12); the example's `expected_order_overrides` lists p for s = "
                f"{listed}" + (", so this entry is flagged ⚠." if kind == "deviation" else "."))
            explain[("vertical-disk", 6, "p")] = (
                "Same even-s superconvergence as s = 2, 4 (pattern 2s = 12, see §2); not listed "
                "in the example's expected_order_overrides.")
        text.append("")

    # --- particle p for s >= 5 (and anything else flagged is handled in §3)
    if "particle" in studies and 5 in stages:
        st = studies["particle"][0]
        h, e = st.h[5], st.errors[5]["p"]
        sl = local_slopes(h, e)
        n = st.n_steps[5]
        above = e > st.floors["p"]
        default_floor = st.floors["p"] * PLATEAU_REL["p"] / QP_PLATEAU
        o_default = observed_order(h, e, default_floor)
        idx_def = fit_indices(h, e, default_floor)
        rows = [f"{n[i - 1]}→{n[i]}: {sl[i - 1]:.2f}" for i in range(1, len(n)) if above[i]]
        pairs = [sl[i - 1] for i in range(1, len(n)) if above[i] and above[i - 1]]
        fine = pairs[-4:]
        rising = len(fine) >= 3 and all(b >= a - 0.05 for a, b in zip(fine, fine[1:]))
        reg = rising and abs(fine[-1] - 8) < 0.5
        coarse_max = max(pairs) if pairs else float("nan")
        text.append("### Nonholonomic particle, s = 5: p")
        text.append("")
        text.append(
            f"With the library's default floor ({PLATEAU_REL['p']:g}) the p fit for s = 5 uses "
            f"n = {sorted(n[idx_def].tolist())} and gives {fmt_order(o_default)}; with the q/p floor "
            f"of this report it gives {fmt_order(st.observed[5]['p'])} over "
            f"n = {sorted(n[fit_indices(h, e, st.floors['p'])].tolist())}. The local slopes of the "
            f"p error between consecutive step counts are: {'; '.join(rows)}.")
        text.append("")
        text.append(check(
            reg,
            f"They scatter widely at the coarsest steps (up to {coarse_max:.2f}; the location of "
            "the maximum error moves between components and times) and then rise steadily "
            f"towards the theoretical 8 ({', '.join(f'{x:.2f}' for x in fine)} over the finest "
            "pairs above the floor), until the error reaches round-off. So the slopes above 8 "
            "are pre-asymptotic, **not superconvergence**, and the data are consistent with "
            "order 8 with a large next-order term (an error a·h⁸ − b·h⁹ has local slopes that "
            "approach 8 from below like this). The fitted value falls short of 8 because the "
            "error reaches round-off before the slope has settled; the data cannot show order "
            "8 directly.",
            "the local slopes at the finest steps above the floor "
            f"({', '.join(f'{x:.2f}' for x in fine)}) neither settle near 8 nor rise steadily "
            "towards it; unexplained."))
        text.append("")
        explain[("particle", 5, "p")] = (
            "Pre-asymptotic behaviour of the p error at coarse steps; see §2 (the local slopes "
            "at the finest steps approach 8).")
    return {"text": text, "explain": explain}


# --------------------------------------------------------------------------------- main
def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true",
                    help="smoke run: s = 2, 3, few step counts, short long runs; writes to a "
                         "temporary directory unless --out is given")
    ap.add_argument("--out", type=Path, default=None,
                    help="output directory for verification.md and figures/ (default: docs/, "
                         "or a temporary directory with --quick)")
    ap.add_argument("--examples", nargs="*", default=None,
                    help="restrict the convergence studies to these examples (debugging)")
    opts = ap.parse_args(argv)
    cfg = QUICK if opts.quick else FULL
    out = opts.out or (Path(tempfile.mkdtemp(prefix="lobattodae-verification-")) if opts.quick
                       else ROOT / "docs")
    (out / "figures").mkdir(parents=True, exist_ok=True)
    t_start = time.perf_counter()
    info = machine_info()

    names = [n for n, _ in list_examples() if get_example(n).has_exact]
    if opts.examples:
        unknown = set(opts.examples) - set(names)
        if unknown:
            ap.error(f"not closed-form examples: {sorted(unknown)}; choose from {names}")
        names = [n for n in names if n in opts.examples]
    elif "examples" in cfg:
        names = [n for n in names if n in cfg["examples"]]

    studies, failed_studies, auto_checks = {}, {}, {}
    t0 = time.perf_counter()
    for name in names:
        log(f"convergence study: {name} (s = {cfg['stages']}) ...")
        ex = get_example(name)
        try:
            study, dropped, elapsed, auto_checks[name] = run_study(ex, cfg)
        except lobattodae.SolverError as exc:  # reported, not fatal
            failed_studies[name] = str(exc)
            log(f"  FAILED: {exc}")
            continue
        studies[name] = (study, dropped, elapsed)
        log(study.table())
        a = auto_checks[name]
        log(f"  {elapsed:.1f} s; with lam_start='auto': {a['identical']}/{a['runs']} runs identical, "
            f"orders differ by <= {a['max_order_diff']:.2f} ({a['wall']:.1f} s)")
        axes = plot_convergence(study)
        for ax in axes:  # the minor-tick labels of log axes overlap at this figure size
            ax.xaxis.set_minor_formatter(matplotlib.ticker.NullFormatter())
        axes[0].figure.savefig(out / "figures" / f"convergence-{name}.png", dpi=100)
        plt.close(axes[0].figure)
    t_studies = time.perf_counter() - t0

    t0 = time.perf_counter()
    log("special cases ...")
    specials = special_cases(cfg, studies)
    t_specials = time.perf_counter() - t0

    t0 = time.perf_counter()
    runs = []
    for name in ("contact", "contact-nonreversible"):
        for N in LONG_N:
            log(f"long run: {name}, h = 2 sin(pi/{N}), {cfg['long_steps']} steps ...")
            r = long_run(name, cfg["long_steps"], N)
            log(f"  {r['wall']:.1f} s; max|dH| first/last 10%: {r['first10']:.2e} / {r['last10']:.2e}; "
                f"drift {r['slope']:+.2e}; max phi {r['max_phi']:.1e}")
            runs.append(r)
    plot_long_runs(runs, out / "figures" / "long-runs-contact.png")
    # The same runs with the other two lam_start modes (the runs above use the default).
    variant_runs = []
    for mode in (m for m in LAM_MODES if m != runs[0]["lam_start"]):
        for name in ("contact", "contact-nonreversible"):
            for N in LONG_N:
                log(f"long run: {name}, h = 2 sin(pi/{N}), lam_start={mode!r} ...")
                r = long_run(name, cfg["long_steps"], N, lam_start=mode)
                log(f"  {r['wall']:.1f} s; max|dH| first/last 10%: {r['first10']:.2e} / {r['last10']:.2e}")
                variant_runs.append(r)
    plot_variants(runs, variant_runs, out / "figures" / "long-runs-lam-start.png")
    specials["variant_runs"] = variant_runs
    t_long = time.perf_counter() - t0

    # The measure of success of the lambda-mode decision, on both classes.
    t0 = time.perf_counter()
    lam = lam_mode_runs(cfg)
    plot_lam_modes(lam, out / "figures" / "lam-modes.png")
    specials["lam"] = lam
    specials["auto_checks"] = auto_checks
    t_lam = time.perf_counter() - t0

    timings = {"studies": t_studies, "specials": t_specials, "long": t_long, "lam_modes": t_lam,
               "total": time.perf_counter() - t_start}
    specials["failed"] = failed_studies
    write_report(out, cfg, opts.quick, studies, specials, runs, timings, info)
    data = {
        "generated": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
        "machine": info, "quick": opts.quick, "qp_plateau": QP_PLATEAU,
        # to_dict() holds the refitted orders and the floors of this report
        "studies": {n: st.to_dict() for n, (st, _, _) in studies.items()},
        "long_runs": [{k: v for k, v in r.items() if not k.startswith("_")}
                      for r in runs + specials.get("variant_runs", [])],
        # the measure of success of the lambda-mode decision (DESIGN.md, "The λ mode")
        "lam_modes": {k: [{f: v for f, v in r.items() if not f.startswith("_")} for r in rs]
                      for k, rs in lam.items()},
        # the convergence runs repeated with lam_start="auto", compared with "previous"
        "auto_checks": auto_checks,
        "timings_s": timings,
    }
    (out / "verification-data.json").write_text(json.dumps(data, indent=1) + "\n")
    log(f"wrote {out / 'verification.md'} ({timings['total']:.0f} s)")
    print(out / "verification.md")
    return 0


if __name__ == "__main__":
    sys.exit(main())
