"""The local error estimate of the adaptive steps (issue #10): what it estimates, and what
the error control built on it delivers.

Three parts, on three examples with closed forms (knife edge, Chaplygin sleigh, steady
rolling of the tilted disk) and s = 2..5:

1. ``local``: one step of size h from an exact point ``(t0, q(t0), p(t0), λ(t0))`` with the
   error-controlled method (``lam_start="consistent"``, as :func:`~lobattodae.solve` runs it
   under a :class:`~lobattodae.PIController`). With ``y_1`` the step, ``est = h Σ e_j (V_j,
   W_j)`` its error estimate (``StepInfo.error``) and ``ŷ_1 = y_1 - est`` the embedded
   formula (weights ``b̂ = b - e``, interpolatory on the first s - 1 nodes), the true local
   errors are ``δ_step = y_1 - y(t0 + h)`` and ``δ_emb = ŷ_1 - y(t0 + h)``. Reported: the
   ratios ``‖est‖/‖δ_emb‖`` and ``‖est‖/‖δ_step‖`` over a range of h, and the fitted slopes
   of ``‖est‖``, ``‖δ_emb‖``, ``‖δ_step‖`` (expected s, s and 2s - 1). By construction
   ``est = δ_step - δ_emb``, so the estimate tracks the embedded formula's error as soon as
   the step's own error is negligible against it. A fourth column shows why the start
   multiplier must be consistent: the same step with the paper's ``Λ_1 = λ_n`` and
   ``λ_n = λ(t0) + LAM_OFFSET`` changes the estimate by ``O(h·LAM_OFFSET)`` and the step
   itself only by ``O(h^s·LAM_OFFSET)``.
2. ``proportionality``: the global error ``max(|q(T) - q_exact|, |p(T) - p_exact|)`` of
   adaptive ``solve`` (rtol = atol, T = T_END) over several decades of rtol, and the fitted
   log-log slope (1 is proportionality).
3. ``calibration``: ``global error / rtol`` for the same runs (the controller maps
   ``rtol' = c_tol·rtol^(s/(2s-2))`` with ``c_tol = 1``), its geometric mean per s over the
   examples, and the ``c_tol`` that would make that mean 1 (``c_tol = mean^(-s/(2s-2))``).

Run from the repository root::

    PYTHONPATH=src .venv/bin/python benchmarks/error_estimate.py            # ~6-8 min on 2 loaded cores
    PYTHONPATH=src .venv/bin/python benchmarks/error_estimate.py --quick    # sleigh only, ~2 min

Prints tables and writes ``benchmarks/results/error_estimate.json`` (``--quick`` writes
nothing unless ``--json PATH`` is given). Compilation dominates the run time (one adaptive
loop per example and s).
"""

from __future__ import annotations

import functools
import math
import time

import jax
import jax.numpy as jnp
import numpy as np

import lobattodae as L
from lib import cli
from lib.output import finish, log, results_path, run_meta
from lobattodae.examples import get_example

EXAMPLES = ("knife-edge", "sleigh", "falling-disk")
STAGES = (2, 3, 4, 5)
#: The exact start point of the one-step study (a generic point of each example's motion).
T_START = 0.5
#: Step sizes of the one-step study: H_MAX · 2^(-k/2), k = 0..N_H-1.
H_MAX, N_H, N_H_QUICK = 0.8, 15, 9
#: Errors below PLATEAU_REL·(1 + max|y|) are round-off and neither fitted nor used in ratios.
PLATEAU_REL = 1e-13
#: Fitted slopes use the N_FIT smallest step sizes above the plateau.
N_FIT = 4
#: The λ error carried into the step to show why the estimate needs Λ_1 = λ(t_n, q_n, p_n).
LAM_OFFSET = 1e-8
#: Differences of two steps (or estimates) below DIFF_FLOOR_REL·(1 + max|y|) are round-off.
DIFF_FLOOR_REL = 1e-15
#: End of the interval of the adaptive runs.
T_END = 10.0
#: rtol = atol of the adaptive runs, per s (decades; s = 2 stops at 1e-8: ~1e5 steps).
RTOLS = {
    2: tuple(10.0**-k for k in range(3, 9)),
    3: tuple(10.0**-k for k in range(4, 12)),
    4: tuple(10.0**-k for k in range(5, 13)),
    5: tuple(10.0**-k for k in range(5, 13)),
}


@functools.partial(jax.jit, static_argnums=(0, 1))
def _one_step(problem, method, t0, q0, p0, lam0, h, args):
    q1, p1, _, info, _ = method.step(problem, t0, q0, p0, lam0, h, args)
    return jnp.concatenate([q1, p1]), info.error, info.result


def slope(h, err, floor) -> float:
    """Least-squares log-log slope over the N_FIT smallest h with ``err > floor``."""
    return L.observed_order(h, err, floor=floor, n_fit=N_FIT)


def local_study(ex, s: int, hs: np.ndarray) -> dict:
    """Part 1 for one example and s: the estimate against the true local errors of one step."""
    q0, p0, lam0 = ex.exact(T_START)
    y_scale = 1.0 + max(np.abs(q0).max(), np.abs(p0).max())
    floor = PLATEAU_REL * y_scale
    consistent = L.LobattoIIIAIIIB(stages=s, lam_start="consistent")
    previous = L.LobattoIIIAIIIB(stages=s, lam_start="previous")
    est, emb, step, est_q, emb_q, est_p, emb_p, pollution, step_change, est_off, failed = ([] for _ in range(11))
    n = ex.n
    for h in hs:
        y1, e, res = (np.asarray(x) for x in _one_step(ex.problem, consistent, T_START, q0, p0, lam0, h, ex.args))
        y1_d, e_d, res_d = (np.asarray(x) for x in _one_step(
            ex.problem, previous, T_START, q0, p0, lam0 + LAM_OFFSET, h, ex.args))
        qe, pe, _ = ex.exact(T_START + h)
        ye = np.concatenate([qe, pe])
        d_step, d_emb = y1 - ye, (y1 - e) - ye
        failed.append(bool(int(res) != 0 or int(res_d) != 0))
        est.append(np.linalg.norm(e))
        emb.append(np.linalg.norm(d_emb))
        step.append(np.linalg.norm(d_step))
        est_q.append(np.linalg.norm(e[:n]))
        emb_q.append(np.linalg.norm(d_emb[:n]))
        est_p.append(np.linalg.norm(e[n:]))
        emb_p.append(np.linalg.norm(d_emb[n:]))
        pollution.append(np.linalg.norm(e_d - e))
        est_off.append(np.linalg.norm(e_d))
        step_change.append(np.linalg.norm(y1_d - y1))
    est, emb, step = np.array(est), np.array(emb), np.array(step)
    resolved = emb > floor
    ratio_emb = np.where(resolved, est / emb, np.nan)
    ratio_step = np.where(step > floor, est / step, np.nan)
    # the estimate with the carried λ error, against the true error of the embedded formula
    ratio_polluted = np.where(resolved, np.array(est_off) / emb, np.nan)
    return {
        "h": hs, "floor": floor, "failed": failed,
        "est": est, "err_embedded": emb, "err_step": step,
        "est_q": est_q, "err_embedded_q": emb_q, "est_p": est_p, "err_embedded_p": emb_p,
        "ratio_est_over_embedded": ratio_emb, "ratio_est_over_step": ratio_step,
        "ratio_q": np.where(np.array(emb_q) > floor, np.array(est_q) / np.array(emb_q), np.nan),
        "ratio_p": np.where(np.array(emb_p) > floor, np.array(est_p) / np.array(emb_p), np.nan),
        "slope_est": slope(hs, est, floor), "slope_embedded": slope(hs, emb, floor),
        "slope_step": slope(hs, step, floor),
        "lam_offset": LAM_OFFSET, "est_change_lam_offset": pollution, "step_change_lam_offset": step_change,
        "ratio_est_lam_offset_over_embedded": ratio_polluted,
        "slope_est_change": slope(hs, pollution, DIFF_FLOOR_REL * y_scale),
        "slope_step_change": slope(hs, step_change, DIFF_FLOOR_REL * y_scale),
    }


def proportionality(ex, s: int, rtols) -> dict:
    """Parts 2 and 3 for one example and s: adaptive runs over rtol (= atol)."""
    method = L.LobattoIIIAIIIB(stages=s)
    q_exact, p_exact, _ = ex.exact(ex.t_end)
    rows = []
    for rtol in rtols:
        t0 = time.perf_counter()
        sol = L.solve(ex.problem, method, ex.t_span, ex.q0, ex.p0, args=ex.args, rtol=rtol, atol=rtol,
                      save_every="final", controller=L.PIController(estimate="embedded", c_tol=1.0))  # the uncalibrated map
        wall = time.perf_counter() - t0
        err = max(np.abs(sol.q[-1] - q_exact).max(), np.abs(sol.p[-1] - p_exact).max())
        rows.append({"rtol": rtol, "error": float(err), "error_over_rtol": float(err / rtol),
                     "n_steps": sol.stats["n_steps"], "n_rejected": sol.stats["n_rejected"],
                     "max_constraint_residual": sol.stats["max_constraint_residual"], "wall_s": wall,
                     "success": bool(sol.success)})
    r = np.array([x["rtol"] for x in rows])
    e = np.array([x["error"] for x in rows])
    keep = e > PLATEAU_REL * (1.0 + np.abs(np.r_[q_exact, p_exact]).max())
    fit = float(np.polyfit(np.log10(r[keep]), np.log10(e[keep]), 1)[0]) if keep.sum() >= 2 else math.nan
    ratios = e[keep] / r[keep]
    return {"runs": rows, "slope": fit, "error_over_rtol_min": float(ratios.min()),
            "error_over_rtol_max": float(ratios.max()),
            "error_over_rtol_geomean": float(np.exp(np.mean(np.log(ratios))))}


def _fmt(x, spec=".3f"):
    return "—" if x is None or not np.isfinite(x) else format(x, spec)


def print_local(name: str, res: dict) -> None:
    log(f"\n== {name}: one step from the exact point t0 = {T_START}; "
        "ratios ‖est‖/‖δ_emb‖ (‖est‖/‖δ_step‖)")
    log(f"{'h':>8} | " + " | ".join(f"{'s=' + str(s):^22}" for s in res))
    hs = next(iter(res.values()))["h"]
    for i in range(0, len(hs), 2):
        cells = []
        for s, r in res.items():
            emb, step = r["ratio_est_over_embedded"][i], r["ratio_est_over_step"][i]
            cells.append(f"{_fmt(emb, '.4f'):>9} ({_fmt(step, '.2e'):>9})")
        log(f"{hs[i]:8.4f} | " + " | ".join(f"{c:^22}" for c in cells))
    log(f"{'slopes':>8} | est, δ_emb, δ_step (expected s, s, 2s-1); "
        f"with λ_n off by {LAM_OFFSET:g}: Δest, Δstep")
    for s, r in res.items():
        polluted = np.asarray(r["ratio_est_lam_offset_over_embedded"])
        last = int(np.flatnonzero(np.isfinite(polluted))[-1])  # the smallest h above the plateau
        log(f"{'s=' + str(s):>8} | {_fmt(r['slope_est'], '.2f')}, {_fmt(r['slope_embedded'], '.2f')}, "
            f"{_fmt(r['slope_step'], '.2f')} | Δest {_fmt(r['slope_est_change'], '.2f')}, "
            f"Δstep {_fmt(r['slope_step_change'], '.2f')}; ratio ‖est‖/‖δ_emb‖ with λ off, "
            f"h = {hs[last]:.4f}: {_fmt(polluted[last], '.3g')}")


def print_proportionality(name: str, res: dict) -> None:
    log(f"\n== {name}: adaptive solve on [0, {T_END:g}], rtol = atol; global error / rtol, (steps)")
    for s, r in res.items():
        cells = " ".join(f"{x['error_over_rtol']:.2g}({x['n_steps']})" for x in r["runs"])
        log(f"s={s}: slope {r['slope']:.2f}; err/rtol in [{r['error_over_rtol_min']:.2g}, "
            f"{r['error_over_rtol_max']:.2g}], geomean {r['error_over_rtol_geomean']:.2g} | {cells}")


def calibration(prop: dict) -> dict:
    """Geometric mean of error/rtol per s over the examples, and the c_tol that would make it 1."""
    out = {}
    for s in STAGES:
        means = [prop[name][s]["error_over_rtol_geomean"] for name in prop if s in prop[name]]
        if not means:
            continue
        g = float(np.exp(np.mean(np.log(means))))
        kappa = s / (2.0 * s - 2.0)
        out[s] = {"error_over_rtol_geomean": g, "kappa": kappa, "c_tol_for_unit_ratio": g ** (-kappa),
                  "per_example": {name: prop[name][s]["error_over_rtol_geomean"] for name in prop if s in prop[name]}}
    return out


def main() -> None:
    ap = cli.parser(__doc__, "quick", quick={"help": "the sleigh only, fewer step sizes and tolerances (~2 min)"})
    ap.add_argument("--examples", nargs="*", default=None, choices=EXAMPLES,
                    help="a subset of the examples (default: all three; the sleigh with --quick)")
    ap.add_argument("--parts", nargs="*", default=["local", "proportionality"], choices=["local", "proportionality"])
    ap.add_argument("--json", default=None,
                    help="where to write the results (default: results/error_estimate.json; none with --quick)")
    a = ap.parse_args()
    if a.examples is None:
        a.examples = ["sleigh"] if a.quick else list(EXAMPLES)
    hs = H_MAX * 2.0 ** (-np.arange(N_H_QUICK if a.quick else N_H) / 2.0)
    out = {**run_meta(), "settings": {
               "t_start": T_START, "h": hs, "plateau_rel": PLATEAU_REL, "n_fit": N_FIT, "lam_offset": LAM_OFFSET,
               "t_end": T_END, "rtols": RTOLS}, "local": {}, "proportionality": {}}
    start = time.perf_counter()
    if "local" in a.parts:
        for name in a.examples:
            ex = get_example(name)
            out["local"][name] = {s: local_study(ex, s, hs) for s in STAGES}
            print_local(name, out["local"][name])
    if "proportionality" in a.parts:
        for name in a.examples:
            ex = get_example(name, t_end=T_END)
            res = {}
            for s in STAGES:
                rtols = RTOLS[s][::2] if a.quick else RTOLS[s]
                res[s] = proportionality(ex, s, rtols)
            out["proportionality"][name] = res
            print_proportionality(name, res)
        out["calibration"] = calibration(out["proportionality"])
        log("\n== calibration: geometric mean of global error / rtol over the examples")
        for s, c in out["calibration"].items():
            log(f"s={s}: {c['error_over_rtol_geomean']:.3g} (c_tol that would make it 1: "
                f"{c['c_tol_for_unit_ratio']:.3g})")
    finish(out, a.json or (None if a.quick else results_path("error_estimate.json")), start)


if __name__ == "__main__":
    main()
