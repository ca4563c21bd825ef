"""Step cost of lobattodae (issue #4): time per step vs s and vs system size, Newton
iterations per step, compile time and the first call in a fresh process.

Four parts:

1. ``stages``: the falling rolling disk (n = 5, m = 2; general nutating motion and steady
   rolling), s = 2..6, h = 0.05. The steady-state time per step is the slope
   ``(t(2N) - t(N)) / N`` of the best-of-3 wall times of two ``solve`` calls with the
   same compiled chunk (so fixed per-call costs -- input validation, λ0 check,
   assembling the Solution -- cancel); the per-call overhead ``t(N) - N·slope`` is
   reported too. For s = 3 also with ``lam_start="consistent"`` (if available), and the
   McLachlan-Perlmutter baseline's cost per step for comparison.
2. ``size``: a chain of N_p nonholonomic particles (q_i = (x_i, y_i, z_i),
   z_i' = y_i x_i'), each in a harmonic well and coupled to its neighbours by springs,
   ``n = 3 N_p`` up to 99, ``m = N_p``, s = 3, defined here with
   ``lobattodae.NonholonomicSystem``.
3. ``padding``: ``solve`` runs whole compiled chunks (4096 steps by default), so N just
   above a multiple of the chunk length costs as much as the next multiple (knife edge,
   s = 3, N = 4096, 4097, 5000, 8192, 8193, 12288).
4. ``first_call``: a fresh Python process imports lobattodae and times its first
   ``solve`` (compile + run; the "first call ≤ 2 s" target), the import, and a second
   call, for the knife edge, the sleigh and the falling disk with s = 3.

Usage::

    .venv/bin/python benchmarks/step_cost.py            # full (~8 min)
    .venv/bin/python benchmarks/step_cost.py --quick    # reduced (< 1 min)

Outputs ``benchmarks/results/step_cost[_quick].json`` and ``step_cost[_quick].png``.
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
import warnings

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from baselines import RESULTS_DIR, McLachlanPerlmutter, source_revision  # noqa: E402

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import lobattodae as L  # noqa: E402, N812
from lobattodae.examples import get_example  # noqa: E402

H = 0.05


def _log(msg):
    print(msg, flush=True)


# ------------------------------------------------------------------------ particle chain
def particle_chain(n_particles: int, omega: float = 1.0, kappa: float = 0.5):
    """N_p nonholonomic particles z_i' = y_i x_i' in harmonic wells, neighbours coupled by
    springs in (x, y). Returns ``(problem, q0, p0, args)`` with consistent ``(q0, p0)``."""

    def hamiltonian(t, q, p, args):
        r = q.reshape(-1, 3)
        x, y = r[:, 0], r[:, 1]
        kin = 0.5 * jnp.dot(p, p)
        pot = 0.5 * omega**2 * (jnp.dot(x, x) + jnp.dot(y, y))
        pot += 0.5 * kappa * (jnp.sum(jnp.diff(x) ** 2) + jnp.sum(jnp.diff(y) ** 2))
        return kin + pot

    def constraint_matrix(t, q, args):
        r = q.reshape(-1, 3)
        k = r.shape[0]
        rows = jnp.arange(k)
        mu = jnp.zeros((k, 3 * k), q.dtype)
        return mu.at[rows, 3 * rows].set(-r[:, 1]).at[rows, 3 * rows + 2].set(1.0)

    problem = L.NonholonomicSystem(hamiltonian, constraint_matrix, name=f"particle chain N_p={n_particles}")
    i = np.arange(n_particles)
    x, y, z = 0.3 * np.sin(1.3 * i + 0.2), 0.4 * np.cos(0.7 * i), np.zeros(n_particles)
    px, py = 0.5 + 0.2 * np.cos(i), 0.3 * np.sin(2.1 * i + 0.5)
    pz = y * px  # φ = -y p_x + p_z = 0 (M = I)
    q0 = np.stack([x, y, z], 1).ravel()
    p0 = np.stack([px, py, pz], 1).ravel()
    return problem, q0, p0, None


# ------------------------------------------------------------------------------ timing
def _solve(problem, method, q0, p0, lam0, args, n_steps, chunk):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return L.solve(problem, method, (0.0, n_steps * H), q0, p0, n_steps=n_steps, lam0=lam0, args=args,
                       chunk_size=chunk, throw=False)


def _best(fn, repeats):
    """Best wall time of ``repeats`` calls and the result of that call."""
    best, best_out = np.inf, None
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = fn()
        dt = time.perf_counter() - t0
        if dt < best:
            best, best_out = dt, out
    return best, best_out


def measure(problem, method, q0, p0, lam0, args, n1, chunk, repeats=3):
    """First call, best-of-``repeats`` for n1 and 2·n1 steps; slope = time per step."""
    t0 = time.perf_counter()
    _solve(problem, method, q0, p0, lam0, args, n1, chunk)
    first = time.perf_counter() - t0
    t1, sol1 = _best(lambda: _solve(problem, method, q0, p0, lam0, args, n1, chunk), repeats)
    t2, sol2 = _best(lambda: _solve(problem, method, q0, p0, lam0, args, 2 * n1, chunk), repeats)
    slope = (t2 - t1) / n1
    its = sol2.stats["newton_iterations"]
    return {
        "first_call": first,
        "compile_estimate": first - t1,
        "t_N": t1, "t_2N": t2, "N": n1,
        "us_per_step": 1e6 * slope,
        "us_per_step_incl_overhead": 1e6 * t2 / (2 * n1),
        "overhead_per_call_ms": 1e3 * (t1 - n1 * slope),
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
    variants = {"falling-disk-general": {}, "falling-disk": {}}
    if quick:
        variants = {"falling-disk-general": {}}
    for name in variants:
        ex = get_example(name, t_end=2 * n1 * H)
        out[name] = {}
        for s in stages:
            r = measure(ex.problem, L.LobattoIIIAIIIB(stages=s), ex.q0, ex.p0, ex.lam0, ex.args, n1, n1)
            out[name][f"s={s}"] = r
            _log(f"  {name:22s} s={s}: {_fmt(r)}")
        if not quick:
            try:
                meth = L.LobattoIIIAIIIB(stages=3, lam_start="consistent")
                r = measure(ex.problem, meth, ex.q0, ex.p0, ex.lam0, ex.args, n1, n1)
                out[name]["s=3 consistent λ"] = r
                _log(f"  {name:22s} s=3 consistent λ: {_fmt(r)}")
            except TypeError:
                pass
            for opt in ({"reuse_jacobian": False}, {"extrapolate": False}):
                meth = L.LobattoIIIAIIIB(stages=3, **opt)
                r = measure(ex.problem, meth, ex.q0, ex.p0, ex.lam0, ex.args, n1, n1)
                key = "s=3 " + ", ".join(f"{k}={v}" for k, v in opt.items())
                out[name][key] = r
                _log(f"  {name:22s} {key}: {_fmt(r)}")
        # the second-order baseline, for scale
        mp = McLachlanPerlmutter(ex.problem, ex.args, ex.q0.size, ex.lam0.size)
        call = lambda N: mp.integrate((0.0, N * H), ex.q0, ex.p0, ex.lam0, N, n_record=64)  # noqa: E731
        call(n1)
        t1, _ = _best(lambda: call(n1), 3)
        t2, r2 = _best(lambda: call(2 * n1), 3)
        out[name]["McLachlan-Perlmutter"] = {"us_per_step": 1e6 * (t2 - t1) / n1,
                                             "newton_iterations_mean": r2["newton_iterations_mean"]}
        _log(f"  {name:22s} McLachlan-Perlmutter (2nd order): {1e6 * (t2 - t1) / n1:.1f} µs/step, "
             f"newton {r2['newton_iterations_mean']:.2f}")
    return out


def part_padding(quick: bool):
    """solve() runs whole compiled chunks: the cost of N steps just above a multiple of
    the chunk length (4096 by default), against N at the multiple."""
    ex = get_example("knife-edge", t_end=1000.0)
    method = L.LobattoIIIAIIIB(stages=3)
    Ns = [2048, 2049, 4096] if quick else [4096, 4097, 5000, 8192, 8193, 12288]
    out = {}
    _solve(ex.problem, method, ex.q0, ex.p0, ex.lam0, ex.args, Ns[0], None)
    for N in Ns:
        _solve(ex.problem, method, ex.q0, ex.p0, ex.lam0, ex.args, N, None)  # compile if needed
        t, sol = _best(lambda: _solve(ex.problem, method, ex.q0, ex.p0, ex.lam0, ex.args, N, None), 3)
        out[f"N={N}"] = {"N": N, "wall": t, "us_per_requested_step": 1e6 * t / N}
        _log(f"  knife edge s=3, h = 0.05, N = {N:6d}: {t:.3f} s ({1e6 * t / N:.1f} µs per requested step)")
    return out


def part_size(quick: bool):
    sizes = [1, 4] if quick else [1, 2, 4, 8, 16, 33]
    out = {}
    for k in sizes:
        problem, q0, p0, args = particle_chain(k)
        n1 = 256 if (quick or k > 16) else 1024
        r = measure(problem, L.LobattoIIIAIIIB(stages=3), q0, p0, None, args, n1, n1,
                    repeats=2 if k > 16 else 3)
        r.update({"n": 3 * k, "m": k, "newton_unknowns": L.LobattoIIIAIIIB(stages=3).n_unknowns(3 * k, k)})
        out[f"n={3 * k}"] = r
        _log(f"  chain N_p={k:3d} (n={3 * k:3d}, m={k:2d}, {r['newton_unknowns']:4d} unknowns): {_fmt(r)}")
    return out


FIRST_CALL_SCRIPT = r"""
import time, json, sys, warnings
t0 = time.perf_counter()
import lobattodae as L
from lobattodae.examples import get_example
t_import = time.perf_counter() - t0
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
print(json.dumps({"import": t_import, "first_call": t_first, "second_call": t_second,
                  "first_call_compiled_loop": in_loop_first}))
"""


def part_first_call(quick: bool):
    cases = [("knife-edge", 3, 1000, 100.0)]
    if not quick:
        cases += [("sleigh", 3, 1000, 100.0), ("falling-disk", 3, 1000, 50.0), ("knife-edge", 5, 1000, 100.0)]
    out = {}
    env = dict(os.environ)
    src = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "src")
    env["PYTHONPATH"] = os.path.abspath(src) + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
    for name, s, N, T in cases:
        res = subprocess.run([sys.executable, "-c", FIRST_CALL_SCRIPT, name, str(s), str(N), str(T)],
                             capture_output=True, text=True, env=env, timeout=600)
        key = f"{name} s={s} N={N}"
        if res.returncode != 0:
            out[key] = {"error": res.stderr[-2000:]}
            _log(f"  {key}: FAILED\n{res.stderr[-2000:]}")
            continue
        r = json.loads(res.stdout.strip().splitlines()[-1])
        out[key] = r
        _log(f"  fresh process, {key}: import {r['import']:.2f} s, first solve {r['first_call']:.2f} s, "
             f"(of which compile+run of the integration loop {r['first_call_compiled_loop']:.2f} s), "
             f"second solve {r['second_call']:.3f} s")
        # with lobattodae.enable_compilation_cache: a first process fills the cache, a second
        # (fresh) process loads the compiled loops from it
        with tempfile.TemporaryDirectory() as cache:
            runs = []
            for _ in range(2):
                res = subprocess.run([sys.executable, "-c", FIRST_CALL_SCRIPT, name, str(s), str(N), str(T), cache],
                                     capture_output=True, text=True, env=env, timeout=600)
                if res.returncode != 0:
                    break
                runs.append(json.loads(res.stdout.strip().splitlines()[-1]))
        if len(runs) == 2:
            r["cached"] = {"filling_process": runs[0], "next_process": runs[1]}
            _log(f"    with the persistent compilation cache: first solve {runs[0]['first_call']:.2f} s in the "
                 f"process that fills it, {runs[1]['first_call']:.2f} s in the next process")
        else:
            _log(f"    with the persistent compilation cache: FAILED\n{res.stderr[-2000:]}")
    return out


def plot(res, path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

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
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv=None):
    ap = argparse.ArgumentParser(description="lobattodae step cost (issue #4)")
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--parts", nargs="*", default=["stages", "padding", "size", "first_call"])
    ap.add_argument("--watchdog", type=float, default=1800.0,
                    help="abort with a traceback after this many seconds (0: off)")
    ap.add_argument("--replot", action="store_true", help="only redraw the PNG from the saved JSON")
    a = ap.parse_args(argv)
    if a.replot:
        sfx = "_quick" if a.quick else ""
        with open(os.path.join(RESULTS_DIR, f"step_cost{sfx}.json")) as fh:
            plot(json.load(fh), os.path.join(RESULTS_DIR, f"step_cost{sfx}.png"))
        return
    start = time.perf_counter()
    if a.watchdog > 0:  # a hung XLA call prints every thread's traceback and exits
        import faulthandler

        faulthandler.dump_traceback_later(a.watchdog, exit=True)
    jnp.zeros(1).block_until_ready()
    res = {"meta": {"date": datetime.datetime.now().isoformat(timespec="seconds"),
                    "machine": f"{platform.machine()}, {os.cpu_count()} cores",
                    "jax": jax.__version__, "lobattodae": L.__version__, "quick": a.quick, "h": H,
                    "lobattodae_revision": source_revision(), "lobattodae_path": os.path.dirname(L.__file__),
                    "loadavg_start": os.getloadavg()}}
    if "stages" in a.parts:
        _log("== time per step vs s (falling rolling disk, h = 0.05) ==")
        res["stages"] = part_stages(a.quick)
    if "padding" in a.parts:
        _log("== chunk padding: cost of N just above a multiple of the chunk length ==")
        res["padding"] = part_padding(a.quick)
    if "size" in a.parts:
        _log("== time per step vs n (particle chain, s = 3, h = 0.05) ==")
        res["size"] = part_size(a.quick)
    if "first_call" in a.parts:
        _log("== first call in a fresh process ==")
        res["first_call"] = part_first_call(a.quick)
    res["meta"]["loadavg_end"] = os.getloadavg()
    res["meta"]["wall_seconds"] = time.perf_counter() - start
    os.makedirs(RESULTS_DIR, exist_ok=True)
    suffix = "_quick" if a.quick else ""
    path = os.path.join(RESULTS_DIR, f"step_cost{suffix}.json")
    all_parts = {"stages", "padding", "size", "first_call"}
    if set(a.parts) != all_parts and os.path.exists(path):  # a subset: update the saved file
        with open(path) as fh:
            old = json.load(fh)
        old.setdefault("meta_parts", {})
        for part in a.parts:
            old["meta_parts"][part] = res["meta"]
        old.update({k: v for k, v in res.items() if k != "meta"})
        res = old
    with open(path, "w") as fh:
        json.dump(res, fh, indent=1)
    if "stages" in res and "size" in res:
        plot(res, os.path.join(RESULTS_DIR, f"step_cost{suffix}.png"))
    _log(f"saved {path} ({time.perf_counter() - start:.0f} s)")


if __name__ == "__main__":
    main()
