"""Render the benchmark JSON files as Markdown tables (for RESULTS.md).

Usage::

    .venv/bin/python benchmarks/report.py [--quick] > /tmp/tables.md

Reads ``benchmarks/results/work_precision[_quick].json`` and
``benchmarks/results/step_cost[_quick].json`` (whichever exist).
"""

from __future__ import annotations

import argparse
import json
import math
import os

RESULTS_DIR = os.path.join(os.path.dirname(os.path.abspath(__file__)), "results")


def _f(x, fmt):
    if x is None or (isinstance(x, float) and not math.isfinite(x)):
        return "–"
    return format(x, fmt)


def work_precision(path):
    with open(path) as fh:
        d = json.load(fh)
    meta = d["meta"]
    print(f"Run {meta['date']}, lobattodae {meta.get('lobattodae_revision', meta['lobattodae'])}, jax {meta['jax']}, "
          f"scipy {meta.get('scipy')}, diffrax {meta.get('diffrax')}, {meta['ida']}; load average "
          f"{meta['loadavg_start'][0]:.1f} → {meta.get('loadavg_end', [math.nan])[0]:.1f}; "
          f"{meta.get('wall_seconds', math.nan):.0f} s.\n")
    for name, e in d["problems"].items():
        print(f"#### {name}, T = {e['T']:g} (n = {e['n']}, m = {e['m']})\n")
        pm = e.get("meta")
        if pm and pm.get("date") != meta.get("date"):
            print(f"(measured in the run of {pm['date']}, lobattodae {pm.get('lobattodae_revision')}, load average "
                  f"{pm['loadavg_start'][0]:.1f} → {pm.get('loadavg_end', [math.nan])[0]:.1f})\n")
        print("| solver | setting | error q(T) | wall [s] | 1st call [s] | max ‖φ‖ | max \\|H−H0\\| | steps | Newton/step | note |")
        print("|---|---|---|---|---|---|---|---|---|---|")
        for r in e["records"]:
            ex = r.get("extra", {})
            note = r["message"][:70].replace("|", "/") if r["message"] else ""
            if ex.get("nfev"):
                note = (f"nfev {ex['nfev']}" + ("; " + note if note else ""))
            print(f"| {r['solver']} | {r['setting']} | {_f(r['err_q'], '.2e')} | {_f(r['wall'], '.4f')} | "
                  f"{_f(r['compile_and_run'], '.2f')} | {_f(r['max_phi'], '.1e')} | {_f(r['max_dH'], '.1e')} | "
                  f"{r['n_steps']} | {_f(ex.get('newton_iterations_mean'), '.2f')} | {note} |")
        t = e["targets"]
        print()
        for key in ("lobattodae", "dop853", "diffrax"):
            x = t.get(key)
            lab = {"lobattodae": "lobattodae (err ≤ 1e-8, max‖φ‖ ≤ 1e-13)", "dop853": "DOP853 (err ≤ 1e-8)",
                   "diffrax": "diffrax Dopri8 (err ≤ 1e-8)"}[key]
            print(f"- cheapest {lab}: " + ("none" if x is None else
                  f"{x['solver']} {x['setting']}, {x['wall']:.4f} s (err {x['err_q']:.1e}, max‖φ‖ {x['max_phi']:.1e})"))
        if "speedup_vs_dop853" in t:
            print(f"- speed-up vs DOP853: {t['speedup_vs_dop853']:.2f}×")
        if "speedup_vs_diffrax" in t:
            print(f"- speed-up vs diffrax: {t['speedup_vs_diffrax']:.2f}×")
        print()


def step_cost(path):
    with open(path) as fh:
        d = json.load(fh)
    meta = d["meta"]
    print(f"Run {meta['date']}, lobattodae {meta.get('lobattodae_revision', meta['lobattodae'])}, h = {meta['h']}; "
          f"load average {meta['loadavg_start'][0]:.1f} → {meta.get('loadavg_end', [math.nan])[0]:.1f}; "
          f"{meta.get('wall_seconds', math.nan):.0f} s.\n")
    for part, pm in d.get("meta_parts", {}).items():
        print(f"Part `{part}` re-measured {pm['date']}, lobattodae {pm.get('lobattodae_revision')}, load average "
              f"{pm['loadavg_start'][0]:.1f} → {pm.get('loadavg_end', [math.nan])[0]:.1f}.\n")
    if "stages" in d:
        print("| problem | method | µs/step in loop | µs/step (slope) | per-call overhead [ms] | Newton/step (max) | Jacobians/step | first call [s] | compile ≈ [s] |")
        print("|---|---|---|---|---|---|---|---|---|")
        for name, rows in d["stages"].items():
            for k, r in rows.items():
                if "first_call" not in r:
                    print(f"| {name} | {k} | | {_f(r['us_per_step'], '.1f')} | | {_f(r.get('newton_iterations_mean'), '.2f')} | | | |")
                    continue
                print(f"| {name} | {k} | {_f(r.get('us_per_step_in_loop'), '.1f')} | {_f(r['us_per_step'], '.1f')} | "
                      f"{_f(r['overhead_per_call_ms'], '.1f')} | {_f(r['newton_iterations_mean'], '.2f')} ({r['newton_iterations_max']}) | "
                      f"{_f(r['jacobians_per_step'], '.3f')} | {_f(r['first_call'], '.2f')} | {_f(r['compile_estimate'], '.2f')} |")
        print()
    if "size" in d:
        print("| n | m | Newton unknowns | µs/step in loop | µs/step (slope) | Newton/step | Jacobians/step | first call [s] | compile ≈ [s] |")
        print("|---|---|---|---|---|---|---|---|---|")
        for k, r in d["size"].items():
            print(f"| {r['n']} | {r['m']} | {r['newton_unknowns']} | {_f(r.get('us_per_step_in_loop'), '.1f')} | "
                  f"{_f(r['us_per_step'], '.1f')} | {_f(r['newton_iterations_mean'], '.2f')} | "
                  f"{_f(r['jacobians_per_step'], '.3f')} | {_f(r['first_call'], '.2f')} | {_f(r['compile_estimate'], '.2f')} |")
        print()
    if "padding" in d:
        print("| knife edge, s = 3, h = 0.05: N | wall [s] | µs per requested step |")
        print("|---|---|---|")
        for k, r in d["padding"].items():
            print(f"| {r['N']} | {r['wall']:.3f} | {r['us_per_requested_step']:.1f} |")
        print()
    if "first_call" in d:
        print("| fresh process | import [s] | first solve [s] | of which compiled loop [s] | second solve [s] "
              "| first solve, persistent cache: filling it / next process [s] |")
        print("|---|---|---|---|---|---|")
        for k, r in d["first_call"].items():
            if "error" in r:
                print(f"| {k} | failed | | | | |")
                continue
            cached = r.get("cached")
            cache_col = (f"{cached['filling_process']['first_call']:.2f} / {cached['next_process']['first_call']:.2f}"
                         if cached else "–")
            print(f"| {k} | {r['import']:.2f} | {r['first_call']:.2f} | {r['first_call_compiled_loop']:.2f} "
                  f"| {r['second_call']:.3f} | {cache_col} |")
        print()


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--quick", action="store_true")
    a = ap.parse_args()
    sfx = "_quick" if a.quick else ""
    p = os.path.join(RESULTS_DIR, f"work_precision{sfx}.json")
    if os.path.exists(p):
        work_precision(p)
    p = os.path.join(RESULTS_DIR, f"step_cost{sfx}.json")
    if os.path.exists(p):
        step_cost(p)


if __name__ == "__main__":
    main()
