"""Sharded ensembles (issue #11): ``lobattodae.ensemble`` on 1, 2 and 4 devices.

For each device count D the script starts a fresh Python process with
``XLA_FLAGS=--xla_force_host_platform_device_count=D`` (on a GPU machine: the first D GPUs,
when there are that many) and times ``lobattodae.ensemble`` on B trajectories of N
constant steps (knife edge by default, s = 3, final states kept): one first call (compile +
run), then the best of ``--repeats`` calls. The D = 1 process also times plain
``jax.vmap(lobattodae.integrate)`` on the same batch (the library's ensemble costs nothing
extra) and checks that ``ensemble`` reproduces it bit for bit; the processes with D ≥ 2
report the largest difference to it (round-off: a partitioned XLA program, see
``lobattodae.ensemble``). Throughput is trajectory-steps per second; ratios are taken within
one run. Prints a Markdown table and writes ``benchmarks/results/ensemble_sharded[_quick].json``.

On CPU, forced host devices are threads of one process: D devices can use at most
``min(D, cores)`` cores, so on the 2-core development machine four devices cannot beat two.
Every CPU process gets ``NPROC = 2 × max(--devices)``, the size of XLA's CPU thread pool: with
as many devices as pool threads jaxlib's batched LU can deadlock, and ``ensemble`` would then
shard over fewer devices (see ``lobattodae._ensemble._guard_cpu_pool``).

    PYTHONPATH=src .venv/bin/python benchmarks/ensemble_sharded.py [--quick] [--devices 1 2 4]
"""

from __future__ import annotations

import os
import sys
import time

from lib import cli
from lib.output import RESULTS, child_env, child_result, loadavg, print_result, run_meta, write_json
from lib.timing import best_of


def child(ns) -> None:
    """One device count: runs in its own process (XLA_FLAGS set by the parent before JAX starts)."""
    import jax
    import numpy as np

    import lobattodae as L
    from lib.problems import consistent_batch
    from lobattodae.examples import get_example

    platform = jax.default_backend()
    devices = jax.local_devices()[: ns.child]
    if len(devices) < ns.child:
        print_result({"devices": ns.child, "skipped": f"only {len(devices)} {platform} device(s)"})
        return
    ex = get_example(ns.example)
    method = L.LobattoIIIAIIIB(stages=ns.stages)
    q0, p0, lam0 = (np.asarray(x) for x in consistent_batch(ex, ns.batch))

    def run():
        return L.ensemble(ex.problem, method, q0, p0, lam0, ex.args, h=ns.h, n_steps=ns.steps, devices=devices)

    t = time.perf_counter()
    first = run()
    compile_and_run = time.perf_counter() - t
    tm = best_of(run, ns.repeats)
    result = tm.result
    row = {
        "devices": ns.child, "device_kind": devices[0].device_kind, "platform": platform,
        "compile_and_first_run_s": compile_and_run, "times_s": tm.times, "best_s": tm.best,
        "cpu_s_of_best": tm.cpu, "cores_used": tm.cpu / tm.best, "traj_steps_per_s": ns.batch * ns.steps / tm.best,
        "successful": int(np.count_nonzero(result.status == 0)),
        "reproducible": bool(np.array_equal(first.q, result.q)),
    }
    plain = jax.jit(jax.vmap(lambda q, p, lam: L.integrate(ex.problem, method, 0.0, ns.h, ns.steps, q, p, lam,
                                                           ex.args).q[-1]))
    if ns.child == 1:
        tv = best_of(lambda: np.asarray(plain(q0, p0, lam0)), ns.repeats, first=True)
        ref, row["vmap_best_s"] = tv.result, tv.best
    else:
        with jax.default_device(devices[0]):
            ref = np.asarray(plain(q0, p0, lam0))
    row["max_abs_diff_to_vmap"] = float(np.max(np.abs(result.q - ref)))
    print_result(row)


def main() -> None:
    ap = cli.parser(__doc__, "quick", quick={"help": "B = 64, N = 100, 3 repeats"})
    ap.add_argument("--devices", type=int, nargs="+", default=[1, 2, 4])
    ap.add_argument("--example", default="knife-edge")
    ap.add_argument("--stages", type=int, default=3)
    ap.add_argument("--batch", type=int, default=None, help="trajectories (default 1024, quick 64)")
    ap.add_argument("--steps", type=int, default=None, help="steps per trajectory (default 500, quick 100)")
    ap.add_argument("--h", type=float, default=0.01)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--gpu", action="store_true", help="use the GPUs (default: forced CPU devices)")
    ap.add_argument("--out", default=RESULTS, help="the directory of the JSON")
    ap.add_argument("--child", type=int, default=None, help="(internal) this many devices, in this process")
    ns = ap.parse_args()
    ns.batch = ns.batch or (64 if ns.quick else 1024)
    ns.steps = ns.steps or (100 if ns.quick else 500)
    if ns.child is not None:
        child(ns)
        return

    meta = run_meta(example=ns.example, stages=ns.stages, batch=ns.batch, steps=ns.steps, h=ns.h, repeats=ns.repeats,
                    NPROC=None if ns.gpu else 2 * max(ns.devices))
    rows = []
    for d in ns.devices:
        if ns.gpu:
            env = child_env(no_cache=False, JAX_PLATFORMS=None)
        else:  # PJRT_NPROC would take precedence over NPROC
            xla = (os.environ.get("XLA_FLAGS", "") + f" --xla_force_host_platform_device_count={d}").strip()
            env = child_env(no_cache=False, XLA_FLAGS=xla, JAX_PLATFORMS="cpu", NPROC=str(2 * max(ns.devices)),
                            PJRT_NPROC=None)
        r = child_result([sys.executable, os.path.abspath(__file__), "--child", str(d), "--example", ns.example,
                          "--stages", str(ns.stages), "--batch", str(ns.batch), "--steps", str(ns.steps), "--h",
                          str(ns.h), "--repeats", str(ns.repeats)], env)
        if "error" in r:
            sys.exit(f"the process for {d} device(s) failed:\n{r['error']}")
        rows.append(r)
        print(f"{d} device(s): {r}", flush=True)
    meta["loadavg_end"] = loadavg()
    done = [r for r in rows if "skipped" not in r]
    base = next((r for r in done if r["devices"] == 1), None) or (done[0] if done else None)
    print(f"\n{ns.example}, s = {ns.stages}, B = {ns.batch} trajectories x N = {ns.steps} steps (h = {ns.h}), "
          f"final states kept; best of {ns.repeats} after a compiling call; load average "
          f"{meta['loadavg_start']} -> {meta['loadavg_end']}\n")
    print("| devices | device | compile + 1st run | best run | CPU time / wall (cores used) | trajectory-steps/s "
          "| vs 1 device | max abs diff to vmap |")
    print("|---|---|---|---|---|---|---|---|")
    for r in rows:
        if "skipped" in r:
            print(f"| {r['devices']} | – | – | – | – | – | – | {r['skipped']} |")
            continue
        speedup = base["best_s"] / r["best_s"]
        print(f"| {r['devices']} | {r['device_kind']} | {r['compile_and_first_run_s']:.1f} s | {r['best_s']:.3f} s | "
              f"{r['cores_used']:.2f} | {r['traj_steps_per_s']:.3e} | {speedup:.2f}x | "
              f"{r['max_abs_diff_to_vmap']:.1e} |")
    if base is not None and "vmap_best_s" in base:
        print(f"\nplain jax.vmap(integrate) on 1 device: {base['vmap_best_s']:.3f} s "
              f"({ns.batch * ns.steps / base['vmap_best_s']:.3e} trajectory-steps/s; ensemble/vmap time "
              f"{base['best_s'] / base['vmap_best_s']:.2f})")
    write_json({"meta": meta, "rows": rows},
               os.path.join(ns.out, f"ensemble_sharded{'_gpu' if ns.gpu else ''}{'_quick' if ns.quick else ''}.json"))


if __name__ == "__main__":
    main()
