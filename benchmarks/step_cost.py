"""Step cost of lobattodae (issue #4): time per step vs s and vs system size, Newton
iterations per step, compile time and the first call in a fresh process.

Four parts:

1. ``stages``: the falling rolling disk (n = 5, m = 2; general nutating motion and steady
   rolling), s = 2..6, h = 0.05. The steady-state time per step is the slope
   ``(t(2N) - t(N)) / N`` of the best-of-3 wall times of two ``solve`` calls with the
   same compiled chunk (so fixed per-call costs -- input validation, λ0 check,
   assembling the Solution -- cancel); the per-call overhead ``t(N) - N·slope`` is
   reported too. For s = 3 also with ``lam_start="consistent"``, ``reuse_jacobian=False`` and
   ``extrapolate=False``, and the McLachlan-Perlmutter baseline's cost per step for comparison.
2. ``size``: a chain of N_p nonholonomic particles (``lib.problems.particle_chain``:
   q_i = (x_i, y_i, z_i), z_i' = y_i x_i', each in a harmonic well and coupled to its
   neighbours by springs), ``n = 3 N_p`` up to 99, ``m = N_p``, s = 3.
3. ``padding``: ``solve`` runs whole compiled chunks (4096 steps by default), so N just
   above a multiple of the chunk length costs as much as the next multiple (knife edge,
   s = 3, N = 4096, 4097, 5000, 8192, 8193, 12288).
4. ``first_call``: a fresh Python process without the persistent compilation cache imports
   lobattodae and times its first ``solve`` (compile + run; the "first call ≤ 2 s" target),
   the import, and a second call, for the knife edge, the sleigh and the falling disk with
   s = 3; then two processes sharing a new cache (the second loads what the first compiled).

Usage::

    .venv/bin/python benchmarks/step_cost.py            # full (~8 min)
    .venv/bin/python benchmarks/step_cost.py --quick    # reduced (< 1 min)
    .venv/bin/python benchmarks/step_cost.py --parts stages padding   # a subset, merged into the JSON
    .venv/bin/python benchmarks/step_cost.py --replot   # the figure and tables from the JSON

Outputs ``benchmarks/results/step_cost[_quick].json`` and ``step_cost[_quick].png``, and prints
the Markdown tables of ``RESULTS.md``.
"""

from __future__ import annotations

import tempfile
import time
import warnings

import jax.numpy as jnp
import numpy as np

import lobattodae as L
from lib import cli
from lib.mclachlan import McLachlanPerlmutter
from lib.output import child_env, child_result, fmt, loadavg, log, md_table, pyplot, python_child, read_json, \
    results_path, run_meta, save_figure, with_parts, write_json
from lib.problems import particle_chain
from lib.timing import best_of
from lobattodae.examples import get_example

H = 0.05


# ------------------------------------------------------------------------------ timing
def _solve(problem, method, q0, p0, lam0, args, n_steps, chunk):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return L.solve(problem, method, (0.0, n_steps * H), q0, p0, n_steps=n_steps, lam0=lam0, args=args,
                       chunk_size=chunk, throw=False)


def measure(problem, method, q0, p0, lam0, args, n1, chunk, repeats=3):
    """First call, best-of-``repeats`` for n1 and 2·n1 steps; slope = time per step."""
    t1 = best_of(lambda: _solve(problem, method, q0, p0, lam0, args, n1, chunk), repeats, first=True)
    t2 = best_of(lambda: _solve(problem, method, q0, p0, lam0, args, 2 * n1, chunk), repeats)
    sol2 = t2.result
    slope = (t2.best - t1.best) / n1
    its = sol2.stats["newton_iterations"]
    return {
        "first_call": t1.first,
        "compile_estimate": t1.first - t1.best,
        "t_N": t1.best, "t_2N": t2.best, "N": n1,
        "us_per_step": 1e6 * slope,
        "us_per_step_incl_overhead": 1e6 * t2.best / (2 * n1),
        "overhead_per_call_ms": 1e3 * (t1.best - n1 * slope),
        "integrate_time_2N": float(sol2.stats["compile_and_run_time"]),
        "us_per_step_in_loop": 1e6 * float(sol2.stats["compile_and_run_time"]) / (2 * n1),
        "newton_iterations_mean": float(np.mean(its)) if its.size else float("nan"),
        "newton_iterations_max": int(np.max(its)) if its.size else -1,
        "jacobians_per_step": sol2.stats["n_jacobians"] / (2 * n1),
        "success": bool(sol2.success),
        "max_phi": float(np.max(sol2.stats["constraint_residual"])),
    }


def _fmt(r):
    return (f"{r['us_per_step_in_loop']:8.1f} µs/step in the compiled loop, slope {r['us_per_step']:8.1f} "
            f"(incl. per-call overhead {r['us_per_step_incl_overhead']:7.1f}; "
            f"overhead {r['overhead_per_call_ms']:6.1f} ms/call)  newton {r['newton_iterations_mean']:.2f} "
            f"(max {r['newton_iterations_max']})  jac/step {r['jacobians_per_step']:.3f}  "
            f"first call {r['first_call']:.2f} s (compile ≈ {r['compile_estimate']:.2f} s)"
            + ("" if r["success"] else "  FAILED"))


def part_stages(quick: bool):
    out = {}
    stages = [3] if quick else [2, 3, 4, 5, 6]
    n1 = 512 if quick else 4096
    variants = {"s=3 consistent λ": {"lam_start": "consistent"}, "s=3 reuse_jacobian=False": {"reuse_jacobian": False},
                "s=3 extrapolate=False": {"extrapolate": False}}
    for name in ["falling-disk-general"] if quick else ["falling-disk-general", "falling-disk"]:
        ex = get_example(name, t_end=2 * n1 * H)
        methods = {f"s={s}": L.LobattoIIIAIIIB(stages=s) for s in stages}
        methods.update({} if quick else {key: L.LobattoIIIAIIIB(stages=3, **opt) for key, opt in variants.items()})
        out[name] = {}
        for key, method in methods.items():
            out[name][key] = r = measure(ex.problem, method, ex.q0, ex.p0, ex.lam0, ex.args, n1, n1)
            log(f"  {name:22s} {key}: {_fmt(r)}")
        # the second-order baseline, for scale
        mp = McLachlanPerlmutter(ex.problem, ex.args, ex.q0.size, ex.lam0.size)
        t1, t2 = (best_of(lambda n=n: mp.integrate((0.0, n * H), ex.q0, ex.p0, ex.lam0, n, n_record=64), 3, first=True)
                  for n in (n1, 2 * n1))
        us = 1e6 * (t2.best - t1.best) / n1
        out[name]["McLachlan-Perlmutter"] = {"us_per_step": us,
                                             "newton_iterations_mean": t2.result["newton_iterations_mean"]}
        log(f"  {name:22s} McLachlan-Perlmutter (2nd order): {us:.1f} µs/step, "
            f"newton {t2.result['newton_iterations_mean']:.2f}")
    return out


def part_padding(quick: bool):
    """solve() runs whole compiled chunks: the cost of N steps just above a multiple of
    the chunk length (4096 by default), against N at the multiple."""
    ex = get_example("knife-edge", t_end=1000.0)
    method = L.LobattoIIIAIIIB(stages=3)
    out = {}
    for N in [2048, 2049, 4096] if quick else [4096, 4097, 5000, 8192, 8193, 12288]:
        # the first call compiles where N needs another chunk length
        t = best_of(lambda: _solve(ex.problem, method, ex.q0, ex.p0, ex.lam0, ex.args, N, None), 3, first=True).best
        out[f"N={N}"] = {"N": N, "wall": t, "us_per_requested_step": 1e6 * t / N}
        log(f"  knife edge s=3, h = 0.05, N = {N:6d}: {t:.3f} s ({1e6 * t / N:.1f} µs per requested step)")
    return out


def part_size(quick: bool):
    out = {}
    for k in [1, 4] if quick else [1, 2, 4, 8, 16, 33]:
        problem, q0, p0, args = particle_chain(k)
        n1 = 256 if (quick or k > 16) else 1024
        r = measure(problem, L.LobattoIIIAIIIB(stages=3), q0, p0, None, args, n1, n1,
                    repeats=2 if k > 16 else 3)
        r.update({"n": 3 * k, "m": k, "newton_unknowns": L.LobattoIIIAIIIB(stages=3).n_unknowns(3 * k, k)})
        out[f"n={3 * k}"] = r
        log(f"  chain N_p={k:3d} (n={3 * k:3d}, m={k:2d}, {r['newton_unknowns']:4d} unknowns): {_fmt(r)}")
    return out


FIRST_CALL_SCRIPT = r"""
import time, sys, warnings
t0 = time.perf_counter()
import lobattodae as L
from lobattodae.examples import get_example
t_import = time.perf_counter() - t0
from lib.output import print_result
name, s, N, T = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), float(sys.argv[4])
if len(sys.argv) > 5:
    L.enable_compilation_cache(sys.argv[5])
ex = get_example(name, t_end=T)
m = L.LobattoIIIAIIIB(stages=s)
warnings.simplefilter("ignore")
t0 = time.perf_counter()
sol = L.solve(ex.problem, m, ex.t_span, ex.q0, ex.p0, n_steps=N, lam0=ex.lam0, args=ex.args)
t_first = time.perf_counter() - t0
in_loop_first = sol.stats["compile_and_run_time"]
t0 = time.perf_counter()
sol = L.solve(ex.problem, m, ex.t_span, ex.q0, ex.p0, n_steps=N, lam0=ex.lam0, args=ex.args)
t_second = time.perf_counter() - t0
print_result({"import": t_import, "first_call": t_first, "second_call": t_second,
              "first_call_compiled_loop": in_loop_first})
"""


def part_first_call(quick: bool):
    """Fresh processes without the persistent cache (a first call compiles), then a pair that
    shares one (``lobattodae.enable_compilation_cache``): the first fills it, the second loads
    the compiled loops from it."""
    cases = [("knife-edge", 3, 1000, 100.0)]
    if not quick:
        cases += [("sleigh", 3, 1000, 100.0), ("falling-disk", 3, 1000, 50.0), ("knife-edge", 5, 1000, 100.0)]
    out = {}
    for name, s, N, T in cases:
        key, argv = f"{name} s={s} N={N}", (name, str(s), str(N), str(T))
        out[key] = r = child_result(python_child(FIRST_CALL_SCRIPT, *argv), child_env(), 600.0)
        if "error" in r:
            log(f"  {key}: FAILED\n{r['error']}")
            continue
        log(f"  fresh process, {key}: import {r['import']:.2f} s, first solve {r['first_call']:.2f} s, "
            f"(of which compile+run of the integration loop {r['first_call_compiled_loop']:.2f} s), "
            f"second solve {r['second_call']:.3f} s")
        with tempfile.TemporaryDirectory() as cache:
            runs = [child_result(python_child(FIRST_CALL_SCRIPT, *argv, cache), child_env(), 600.0) for _ in range(2)]
        failed = [x["error"] for x in runs if "error" in x]
        if failed:
            log(f"    with the persistent compilation cache: FAILED\n{failed[0]}")
            continue
        r["cached"] = {"filling_process": runs[0], "next_process": runs[1]}
        log(f"    with the persistent compilation cache: first solve {runs[0]['first_call']:.2f} s in the "
            f"process that fills it, {runs[1]['first_call']:.2f} s in the next process")
    return out


def plot(res, path):
    plt = pyplot()

    def in_loop(r):
        return r.get("us_per_step_in_loop", 1e6 * r["integrate_time_2N"] / (2 * r["N"]))

    fig, axes = plt.subplots(1, 3, figsize=(15, 4.5), constrained_layout=True)
    for name, d in res["stages"].items():
        ss = sorted(int(k[2:]) for k in d if k.startswith("s=") and k[2:].isdigit())
        line, = axes[0].plot(ss, [in_loop(d[f"s={s}"]) for s in ss], "o-", label=f"{name}: in compiled loop")
        axes[0].plot(ss, [d[f"s={s}"]["us_per_step"] for s in ss], "x:", color=line.get_color(),
                     label=f"{name}: slope (t(2N)-t(N))/N")
        if "McLachlan-Perlmutter" in d:
            axes[0].axhline(d["McLachlan-Perlmutter"]["us_per_step"], ls="--", lw=0.8, color=line.get_color(),
                            label=f"{name}: McLachlan-Perlmutter (2nd order)")
        axes[1].plot(ss, [d[f"s={s}"]["newton_iterations_mean"] for s in ss], "s-", color=line.get_color(),
                     label=f"{name}: Newton iterations")
        axes[1].plot(ss, [10 * d[f"s={s}"]["jacobians_per_step"] for s in ss], "^:", color=line.get_color(),
                     label=f"{name}: 10 × Jacobians")
    axes[0].axhline(20, color="red", lw=0.8, ls=":", label="target s=3: 20 µs")
    axes[0].set_xlabel("stages s")
    axes[0].set_ylabel("µs per step (h = 0.05)")
    axes[0].set_yscale("log")
    axes[0].legend(fontsize=7)
    axes[0].set_title("falling rolling disk (n=5, m=2)")
    axes[1].set_xlabel("stages s")
    axes[1].set_ylabel("per step")
    axes[1].legend(fontsize=7)
    axes[1].set_title("Newton iterations and Jacobian factorisations")
    sz = res["size"]
    ns = [v["n"] for v in sz.values()]
    axes[2].loglog(ns, [in_loop(v) for v in sz.values()], "o-", label="µs/step in compiled loop (s=3)")
    axes[2].loglog(ns, [v["compile_estimate"] * 1e3 for v in sz.values()], "x:", label="compile [ms]")
    nn = np.array(ns, float)
    axes[2].loglog(nn, in_loop(list(sz.values())[-1]) * (nn / nn[-1]) ** 3, "k--", lw=0.6, label="∝ n³")
    axes[2].set_xlabel("n (chain of n/3 nonholonomic particles, m = n/3)")
    axes[2].legend(fontsize=7)
    axes[2].set_title("cost vs system size")
    save_figure(fig, path)


def _load(meta: dict) -> str:
    return f"load average {fmt(meta['loadavg_start'][0], '.1f')} → {fmt(meta.get('loadavg_end', [None])[0], '.1f')}"


def tables(d: dict) -> str:
    """The saved results as the Markdown tables of RESULTS.md."""
    meta = d["meta"]
    out = [f"Run {meta['date']}, lobattodae {meta.get('lobattodae_revision', meta['lobattodae'])}, h = {meta['h']}; "
           f"{_load(meta)}; {fmt(meta.get('wall_seconds'), '.0f')} s."]
    out += [f"Part `{part}` re-measured {pm['date']}, lobattodae {pm.get('lobattodae_revision')}, {_load(pm)}."
            for part, pm in d.get("meta_parts", {}).items()]
    if "stages" in d:
        rows = []
        for name, runs in d["stages"].items():
            for k, r in runs.items():
                rows.append([name, k, fmt(r.get("us_per_step_in_loop"), ".1f"), fmt(r["us_per_step"], ".1f")]
                            + ([fmt(r["overhead_per_call_ms"], ".1f"),
                                f"{fmt(r['newton_iterations_mean'], '.2f')} ({r['newton_iterations_max']})",
                                fmt(r["jacobians_per_step"], ".3f"), fmt(r["first_call"], ".2f"),
                                fmt(r["compile_estimate"], ".2f")] if "first_call" in r else
                               ["", fmt(r.get("newton_iterations_mean"), ".2f"), "", "", ""]))
        out.append(md_table(["problem", "method", "µs/step in loop", "µs/step (slope)", "per-call overhead [ms]",
                             "Newton/step (max)", "Jacobians/step", "first call [s]", "compile ≈ [s]"], rows))
    if "size" in d:
        out.append(md_table(
            ["n", "m", "Newton unknowns", "µs/step in loop", "µs/step (slope)", "Newton/step", "Jacobians/step",
             "first call [s]", "compile ≈ [s]"],
            [[r["n"], r["m"], r["newton_unknowns"], fmt(r.get("us_per_step_in_loop"), ".1f"),
              fmt(r["us_per_step"], ".1f"), fmt(r["newton_iterations_mean"], ".2f"),
              fmt(r["jacobians_per_step"], ".3f"), fmt(r["first_call"], ".2f"), fmt(r["compile_estimate"], ".2f")] for r in d["size"].values()]))
    if "padding" in d:
        out.append(md_table(["knife edge, s = 3, h = 0.05: N", "wall [s]", "µs per requested step"],
                            [[r["N"], f"{r['wall']:.3f}", f"{r['us_per_requested_step']:.1f}"]
                             for r in d["padding"].values()]))
    if "first_call" in d:
        rows = []
        for k, r in d["first_call"].items():
            cached = r.get("cached")
            rows.append([k, "failed", "", "", "", ""] if "error" in r else
                        [k, f"{r['import']:.2f}", f"{r['first_call']:.2f}", f"{r['first_call_compiled_loop']:.2f}",
                         f"{r['second_call']:.3f}",
                         f"{cached['filling_process']['first_call']:.2f} / {cached['next_process']['first_call']:.2f}"
                         if cached else "–"])
        out.append(md_table(["fresh process", "import [s]", "first solve [s]", "of which compiled loop [s]",
                             "second solve [s]", "first solve, persistent cache: filling it / next process [s]"], rows))
    return "\n\n".join(out)


PARTS = ["stages", "padding", "size", "first_call"]
TITLES = {"stages": "time per step vs s (falling rolling disk, h = 0.05)",
          "padding": "chunk padding: cost of N just above a multiple of the chunk length",
          "size": "time per step vs n (particle chain, s = 3, h = 0.05)", "first_call": "first call in a fresh process"}
RUNNERS = {"stages": part_stages, "padding": part_padding, "size": part_size, "first_call": part_first_call}


def main(argv=None):
    ap = cli.parser(__doc__, "quick", "replot", "pin_cpu", "watchdog")
    ap.add_argument("--parts", nargs="*", default=PARTS, choices=PARTS)
    a = cli.start(ap.parse_args(argv))
    suffix = "_quick" if a.quick else ""
    path, png = results_path(f"step_cost{suffix}.json"), results_path(f"step_cost{suffix}.png")
    if a.replot:
        res = read_json(path)
        plot(res, png)
        log(tables(res))
        return
    start = time.perf_counter()
    jnp.zeros(1).block_until_ready()  # JAX's backend starts before anything is timed
    res = {"meta": run_meta(quick=a.quick, h=H, pin_cpu=a.pin_cpu)}
    for part in a.parts:
        log(f"== {TITLES[part]} ==")
        res[part] = RUNNERS[part](a.quick)
    res["meta"]["loadavg_end"] = loadavg()
    res["meta"]["wall_seconds"] = time.perf_counter() - start
    res = with_parts(path, res, a.parts, PARTS)
    write_json(res, path)
    if "stages" in res and "size" in res:
        plot(res, png)
    log("\n" + tables(res))
    log(f"({time.perf_counter() - start:.0f} s)")


if __name__ == "__main__":
    main()
