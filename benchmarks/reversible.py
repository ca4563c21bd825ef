"""Time-reversible variable steps (issue #10): Hairer & Söderlind's control on the contact oscillator.

McLachlan & Perlmutter's contact oscillator (``lobattodae.examples``, "contact": reversible
under p ↦ -p; "contact-nonreversible": S = cos z breaks it), s-stage Lobatto IIIA-IIIB,
about N steps (default 10⁵) with

* ``ReversibleStepSize()`` (the symmetric control, default density ‖(f, g)‖, first step 0.2),
* ``PIController`` at the rtol (= atol) that gives the same number of steps (calibrated on
  t ≤ 500; its error-controlled runs start every step from the consistent λ),
* ``PIController`` with ``lam_start="previous"`` (the paper's symmetric step, unsymmetric
  steps: isolates the controller),
* constant steps, as many as the reversible run took (the reference: symmetric, bounded),

all with ``save_every`` so that memory stays small. For each run: max |ΔH| per decade of
time, the least-squares slope of ΔH(t) and the exponent of the envelope's growth (0:
bounded; 1: linear drift). A second part compares step densities at equal cost on t ≤ 500
(global q error against an s = 5 reference). Run from the repository root::

    PYTHONPATH=src .venv/bin/python benchmarks/reversible.py [--quick] [--steps N] [--stages 2 3 4]
        [--million]        # also 10⁶ steps of s = 3 on the reversible problem
        [--replot]         # redraw the figure from the saved JSON

Prints tables; writes ``benchmarks/results/reversible.json`` and
``docs/figures/reversible-control.png`` (``--quick``: ``benchmarks/results/reversible_quick.*``).
"""

from __future__ import annotations

import math
import os
import time

import jax
import jax.numpy as jnp
import numpy as np

import lobattodae as L
from lib import cli
from lib.output import ROOT, loadavg, log, pyplot, read_json, results_path, run_meta, save_figure, write_json
from lobattodae._problem import consistent_lambda, vector_field
from lobattodae.examples import get_example

JSON_PATH = results_path("reversible.json")
FIGURE_PATH = os.path.join(ROOT, "docs", "figures", "reversible-control.png")
#: --quick writes here instead (the full results stay).
QUICK_JSON_PATH = results_path("reversible_quick.json")
QUICK_FIGURE_PATH = results_path("reversible_quick.png")

#: The reversible control's first step (ε = FIRST_STEP·σ(y0)): mean step about 0.17.
FIRST_STEP = 0.2
#: The calibration interval (every step kept): PI's rtol is chosen there to match step counts.
T_CALIBRATE = 500.0
#: Rows kept per long run (save_every = steps / KEPT_ROWS).
KEPT_ROWS = 100_000
#: Log-spaced time bins of the figure's envelopes.
ENVELOPE_BINS = 80
#: The growth exponent fits the decades of time from here on (before, the quasi-periodic
#: envelope of a bounded error is still filling in: ×2 between t = 10 and 100 on the oscillator).
EXPONENT_FROM = 100.0
#: The step sizes of the first TRACE_T time units are kept for the figure.
TRACE_T = 60.0
#: The stage count of the density comparison and of the 10⁶-step run.
S_MAIN = 3

CONTROLS = ("reversible", "pi", "pi-previous", "constant")
LABELS = {
    "reversible": "ReversibleStepSize (symmetric control)",
    "pi": "PIController (default, consistent λ start)",
    "pi-previous": "PIController, lam_start='previous'",
    "constant": "constant steps (same count)",
}
COLORS = {"reversible": "C0", "pi": "C3", "pi-previous": "C1", "constant": "0.4"}


# -- step densities -----------------------------------------------------------------------------
def _local_frequency(problem):
    """``σ = ‖y''‖ / ‖y'‖``, y = (q, p) on the constraint manifold: a local angular frequency
    (steps ∝ 1/σ: a fixed number of steps per radian of the fastest local rotation). Even
    under p ↦ -p (y'' does not change sign, nor does ‖y'‖)."""

    def density(t, q, p, lam, f, g, args):
        def field(qq, pp):
            lam_c = consistent_lambda(problem, t, qq, pp, lam, args, iterations=1)
            return jnp.concatenate(vector_field(problem, t, qq, pp, lam_c, args))

        acc = jax.jvp(field, (q, p), (f, g))[1]
        return jnp.sqrt(jnp.sum(acc * acc) / (jnp.sum(f * f) + jnp.sum(g * g)))

    return density


# -- runs ---------------------------------------------------------------------------------------
def _energy(ex):
    fn = jax.jit(jax.vmap(lambda q, p: ex.invariants["energy"](0.0, q, p, ex.args)))
    h0 = float(fn(jnp.asarray(ex.q0)[None], jnp.asarray(ex.p0)[None])[0])
    return lambda sol: np.asarray(fn(jnp.asarray(sol.q), jnp.asarray(sol.p))) - h0


def _method(control, s):
    return L.LobattoIIIAIIIB(stages=s, lam_start="previous" if control == "pi-previous" else "auto")


def _solve(ex, control, s, t_end, *, rtol=None, n_steps=None, save_every=None, density=None):
    kw = {}
    if control == "reversible":
        kw = dict(controller=L.ReversibleStepSize() if density is None else L.ReversibleStepSize(density),
                  first_step=FIRST_STEP)
    elif control in ("pi", "pi-previous"):
        kw = dict(rtol=rtol, atol=rtol)
    else:
        kw = dict(n_steps=n_steps)
    return L.solve(ex.problem, _method(control, s), (0.0, t_end), ex.q0, ex.p0, args=ex.args, save_every=save_every,
                   throw=False, **kw)


def calibrate(ex, s):
    """The reversible run's step count on t ≤ T_CALIBRATE, and the PI rtol that matches it
    (secant steps in log-log, n ∝ rtol^(-1/(2s-2)))."""
    rev = _solve(ex, "reversible", s, T_CALIBRATE)
    target = rev.stats["n_steps"]
    h = np.diff(rev.t)[:-1]
    rtol, probes = 1e-4, []
    for _ in range(6):
        n = _solve(ex, "pi", s, T_CALIBRATE, rtol=rtol, save_every="final").stats["n_steps"]
        probes.append((rtol, n))
        if abs(n / target - 1) < 0.01:
            break
        rtol *= (n / target) ** (2 * s - 2)
    rtol, n = min(probes, key=lambda p: abs(p[1] / target - 1))
    pi = _solve(ex, "pi", s, T_CALIBRATE, rtol=rtol)
    h_pi = np.diff(pi.t)[:-1]
    pip = _solve(ex, "pi-previous", s, T_CALIBRATE, rtol=rtol)
    h_pip = np.diff(pip.t)[:-1]
    return {"steps_reversible": target, "rtol": rtol, "steps_pi": n, "probes": probes,
            "h_reversible": [float(h.min()), float(np.mean(h)), float(h.max())],
            "h_pi": [float(h_pi.min()), float(np.mean(h_pi)), float(h_pi.max())],
            "steps_pi_previous": pip.stats["n_steps"],
            "h_pi_previous": [float(h_pip.min()), float(np.mean(h_pip)), float(h_pip.max())],
            # PI keeps h for factors in [1, 1.2]: the fraction of steps that change it
            "h_changes": {"reversible": float(np.mean(h[1:] != h[:-1])), "pi": float(np.mean(h_pi[1:] != h_pi[:-1])),
                          "pi-previous": float(np.mean(h_pip[1:] != h_pip[:-1]))},
            "steps_trace": _trace(rev.t, h, pi.t, h_pi)}


def _trace(t_rev, h_rev, t_pi, h_pi):
    """The step sizes of the first TRACE_T time units (h[k] is the step from t[k])."""
    early_rev, early_pi = t_rev[:-2] < TRACE_T, t_pi[:-2] < TRACE_T
    return {"t_rev": t_rev[:-2][early_rev].tolist(), "h_rev": h_rev[early_rev].tolist(),
            "t_pi": t_pi[:-2][early_pi].tolist(), "h_pi": h_pi[early_pi].tolist()}


def decades(t_end):
    edges = [0.0] + [10.0**k for k in range(1, int(math.ceil(math.log10(t_end))))] + [t_end]
    return list(zip(edges[:-1], edges[1:]))


def summarize(t, d_h):
    """Max |ΔH| per decade of time, the least-squares slope of ΔH(t), the growth exponent
    of the envelope (log-log fit of max |ΔH| per decade against the decade's end, decades
    from t = EXPONENT_FROM on) and log-spaced envelopes for the figure."""
    per_decade = []
    for a, b in decades(t[-1]):
        sel = (t >= a) & (t <= b)
        per_decade.append({"t": [a, b], "max_abs_dH": float(np.max(np.abs(d_h[sel]))) if sel.any() else None})
    usable = [d for d in per_decade if d["t"][0] >= EXPONENT_FROM and d["max_abs_dH"]]
    if len(usable) < 2:  # short (quick) runs
        usable = [d for d in per_decade if d["t"][0] >= 10.0 and d["max_abs_dH"]]
    exponent = None
    if len(usable) >= 2:
        exponent = float(np.polyfit(np.log10([d["t"][1] for d in usable]), np.log10([d["max_abs_dH"] for d in usable]),
                                    1)[0])
    edges = np.geomspace(1.0, t[-1], ENVELOPE_BINS + 1)
    index = np.clip(np.searchsorted(edges, t, side="right") - 1, 0, ENVELOPE_BINS - 1)
    envelope = np.zeros(ENVELOPE_BINS)
    np.maximum.at(envelope, index[t >= 1.0], np.abs(d_h[t >= 1.0]))
    tenth = t[-1] / 10
    return {
        "per_decade": per_decade,
        "first_tenth": float(np.max(np.abs(d_h[t <= tenth]))),
        "last_tenth": float(np.max(np.abs(d_h[t >= t[-1] - tenth]))),
        "max_abs_dH": float(np.max(np.abs(d_h))),
        "drift_slope": float(np.polyfit(t, d_h, 1)[0]),
        "growth_exponent": exponent,
        "envelope": {"t": np.sqrt(edges[:-1] * edges[1:]).tolist(), "max_abs_dH": envelope.tolist()},
    }


def long_runs(ex, s, n_target, cal, controls=CONTROLS):
    """The runs of one (problem, s) over about ``n_target`` steps."""
    h_mean = T_CALIBRATE / cal["steps_reversible"]
    t_end = float(round(n_target * h_mean, -1))
    every = max(1, n_target // KEPT_ROWS)
    energy = _energy(ex)
    out, n_rev = {}, None
    for control in controls:
        t0 = time.perf_counter()
        sol = _solve(ex, control, s, t_end, rtol=cal["rtol"], n_steps=n_rev, save_every=every)
        wall = time.perf_counter() - t0
        row = {"control": control, "stages": s, "t_end": t_end, "save_every": every, "success": sol.success,
               "message": sol.message, "steps": sol.stats["n_steps"], "rejected": sol.stats["n_rejected"],
               "lam_resets": sol.stats["lam_resets"], "max_phi": sol.stats["max_constraint_residual"],
               "wall_s": wall, "rtol": cal["rtol"] if control.startswith("pi") else None,
               "first_step": FIRST_STEP if control == "reversible" else None}
        if control == "reversible":  # the constant run takes as many steps (the planned number if it failed)
            n_rev = sol.stats["n_steps"] if sol.success else n_target
        row.update(summarize(sol.t, energy(sol)))
        out[control] = row
        log(f"  {ex.name:22s} s={s} {control:12s} {row['steps']:8d} steps  t_end {t_end:9.0f}  "
            f"max|ΔH| first/last tenth {row['first_tenth']:.2e} / {row['last_tenth']:.2e}  "
            f"exponent {_fmt(row['growth_exponent'], '.2f')}  {wall:6.1f} s  {'' if sol.success else sol.message}")
    return out


def density_study(ex, rtol, s=S_MAIN, t_end=T_CALIBRATE):
    """Equal cost on t ≤ t_end: constant steps, the reversible control with the default and
    with the local-frequency density, PI; global q error at t_end (s = 5 reference) and max
    |ΔH|."""
    energy = _energy(ex)
    ref = L.solve(ex.problem, L.LobattoIIIAIIIB(stages=5), (0.0, t_end), ex.q0, ex.p0, args=ex.args,
                  n_steps=int(40 * t_end), save_every="final")
    freq = _local_frequency(ex.problem)
    rows = []

    def add(name, sol):
        h = np.diff(sol.t)[:-1]
        rows.append({"run": name, "steps": sol.stats["n_steps"], "h_min": float(h.min()), "h_max": float(h.max()),
                     "q_error": float(np.max(np.abs(sol.q[-1] - ref.q[-1]))),
                     "max_abs_dH": float(np.max(np.abs(energy(sol))))})

    rev = _solve(ex, "reversible", s, t_end)
    n = rev.stats["n_steps"]
    add("reversible, σ = ‖(f, g)‖ (default)", rev)
    # the frequency density, its first step scaled so that it takes about n steps
    probe = L.solve(ex.problem, _method("reversible", s), (0.0, t_end), ex.q0, ex.p0, args=ex.args,
                    controller=L.ReversibleStepSize(freq), first_step=FIRST_STEP)
    first = FIRST_STEP * probe.stats["n_steps"] / n
    add("reversible, σ = ‖y''‖/‖y'‖", L.solve(ex.problem, _method("reversible", s), (0.0, t_end), ex.q0, ex.p0,
                                                args=ex.args, controller=L.ReversibleStepSize(freq), first_step=first))
    add("constant", L.solve(ex.problem, _method("constant", s), (0.0, t_end), ex.q0, ex.p0, args=ex.args, n_steps=n))
    add(f"PI (rtol {rtol:.2g})", _solve(ex, "pi", s, t_end, rtol=rtol))
    return rows


# -- report -------------------------------------------------------------------------------------
def _fmt(x, spec=".2e"):
    return "—" if x is None else format(x, spec)


def print_tables(results):
    for key, block in results["runs"].items():
        log(f"\n### {key}: max |ΔH| per decade of time\n")
        runs = block["runs"]
        first = next(iter(runs.values()))
        head = [f"[{a:g}, {b:g}]" for a, b in (d["t"] for d in first["per_decade"])]
        log("| control | steps | " + " | ".join(head) + " | slope of ΔH(t) | growth exponent | wall |")
        log("|---|---|" + "---|" * len(head) + "---|---|---|")
        for control, r in runs.items():
            cells = " | ".join(_fmt(d["max_abs_dH"]) for d in r["per_decade"])
            log(f"| {LABELS[control]} | {r['steps']:,} | {cells} | {r['drift_slope']:+.2e} | "
                f"{_fmt(r['growth_exponent'], '.2f')} | {r['wall_s']:.0f} s |")
    if results.get("density"):
        log(f"\n### step densities at equal cost, s = {S_MAIN}, t ≤ {T_CALIBRATE:g} (contact)\n")
        log("| run | steps | h min | h max | q error at t_end | max |ΔH| |")
        log("|---|---|---|---|---|---|")
        for r in results["density"]:
            log(f"| {r['run']} | {r['steps']:,} | {r['h_min']:.3f} | {r['h_max']:.3f} | {r['q_error']:.2e} | "
                f"{r['max_abs_dH']:.2e} |")


def plot(results, path):
    plt = pyplot()

    keys = list(results["runs"])
    problems = sorted({results["runs"][k]["problem"] for k in keys}, key=lambda p: p != "contact")
    stages = sorted({results["runs"][k]["stages"] for k in keys if results["runs"][k]["steps_target"]
                     == results["steps_target"]})
    fig, axes = plt.subplots(len(problems), len(stages) + 1, figsize=(4.2 * (len(stages) + 1), 3.6 * len(problems)),
                             squeeze=False)
    for i, problem in enumerate(problems):
        for j, s in enumerate(stages):
            ax = axes[i, j]
            key = f"{problem}, s={s}, N={results['steps_target']}"
            if key not in results["runs"]:
                ax.set_visible(False)
                continue
            for control, r in results["runs"][key]["runs"].items():
                env = np.asarray(r["envelope"]["max_abs_dH"])
                t = np.asarray(r["envelope"]["t"])
                ok = env > 0
                ax.loglog(t[ok], env[ok], color=COLORS[control], label=f"{LABELS[control]} ({r['steps']:,} steps)")
            ax.set_title(f"{problem}, s = {s}", fontsize=10)
            ax.set_xlabel("t")
            ax.grid(True, which="both", alpha=0.3)
            if j == 0:
                ax.set_ylabel("max |H − H(0)| (log bins)")
            if i == 0 and j == 0:
                ax.legend(fontsize=7, loc="lower right")
        ax = axes[i, -1]
        trace = results["runs"][f"{problem}, s={S_MAIN}, N={results['steps_target']}"]["calibration"]["steps_trace"]
        ax.plot(trace["t_rev"], trace["h_rev"], color=COLORS["reversible"], lw=0.9, label="ReversibleStepSize")
        ax.plot(trace["t_pi"], trace["h_pi"], color=COLORS["pi"], lw=0.9, label="PIController (same cost)")
        ax.set_xlim(0, TRACE_T)
        ax.set_xlabel("t")
        ax.set_ylabel("step size h")
        ax.set_title(f"{problem}, s = {S_MAIN}: steps", fontsize=10)
        ax.legend(fontsize=7)
        ax.grid(True, alpha=0.3)
        million = results["runs"].get(f"{problem}, s={S_MAIN}, N=1000000")
        if million is not None and results["steps_target"] != 1_000_000 and S_MAIN in stages:
            ax = axes[i, stages.index(S_MAIN)]
            for control, r in million["runs"].items():
                env, t = np.asarray(r["envelope"]["max_abs_dH"]), np.asarray(r["envelope"]["t"])
                ok = env > 0
                ax.loglog(t[ok], env[ok], color=COLORS[control], ls=":", lw=0.9)
            ax.set_title(f"{problem}, s = {S_MAIN} (dotted: {million['runs']['reversible']['steps']:,} steps)",
                         fontsize=10)
    fig.suptitle("Energy error with variable steps: Hairer–Söderlind reversible control vs PI control", fontsize=11)
    fig.tight_layout()
    save_figure(fig, path)


# -- main -------------------------------------------------------------------------------------
def main() -> None:
    ap = cli.parser(__doc__, "quick", "replot", quick={"help": "10⁴ steps, s = 3 only, no density study"})
    ap.add_argument("--steps", type=int, default=100_000)
    ap.add_argument("--stages", type=int, nargs="+", default=[2, 3, 4])
    ap.add_argument("--million", action="store_true", help=f"also 10⁶ steps, s = {S_MAIN}, reversible problem")
    a = ap.parse_args()
    if a.replot:
        results = read_json(JSON_PATH)
        print_tables(results)
        plot(results, FIGURE_PATH)
        return
    steps = 10_000 if a.quick else a.steps
    stages = [S_MAIN] if a.quick else a.stages
    results = {"meta": run_meta(),
               "quick": a.quick, "steps_target": steps, "first_step": FIRST_STEP, "t_calibrate": T_CALIBRATE,
               "runs": {}}
    started = time.perf_counter()
    plan = [(name, s, steps) for name in ("contact", "contact-nonreversible") for s in stages]
    if a.million:
        plan.append(("contact", S_MAIN, 1_000_000))
    for name, s, n in plan:
        ex = get_example(name)
        cal = calibrate(ex, s)
        log(f"{name}, s = {s}: calibration on t ≤ {T_CALIBRATE:g}: reversible {cal['steps_reversible']} steps "
            f"(h {cal['h_reversible'][0]:.3f}..{cal['h_reversible'][2]:.3f}), PI rtol {cal['rtol']:.3g} "
            f"{cal['steps_pi']} steps (h {cal['h_pi'][0]:.3f}..{cal['h_pi'][2]:.3f}), with lam_start='previous' "
            f"{cal['steps_pi_previous']} steps (h {cal['h_pi_previous'][0]:.3f}..{cal['h_pi_previous'][2]:.3f}); "
            f"steps that change h: {cal['h_changes']}")
        results["runs"][f"{name}, s={s}, N={n}"] = {"problem": name, "stages": s, "steps_target": n,
                                                    "calibration": cal, "runs": long_runs(ex, s, n, cal)}
        _save(results)
    main_key = f"contact, s={S_MAIN}, N={steps}"
    if not a.quick and main_key in results["runs"]:
        results["density"] = density_study(get_example("contact"), results["runs"][main_key]["calibration"]["rtol"])
    results["meta"]["loadavg_end"] = loadavg()
    results["meta"]["wall_s"] = time.perf_counter() - started
    _save(results)
    print_tables(results)
    plot(results, QUICK_FIGURE_PATH if a.quick else FIGURE_PATH)


def _save(results):
    write_json(results, QUICK_JSON_PATH if results["quick"] else JSON_PATH, quiet=True)


if __name__ == "__main__":
    main()
