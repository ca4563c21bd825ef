"""Memory and checkpoint I/O of a long run (issue #13): does a 10⁸-step run keeping every
1000th point fit in 1 GiB, and are checkpoints O(steps)?

``lobattodae.solve`` on the knife edge (``get_example("knife-edge")``), s-stage Lobatto
IIIA-IIIB (default s = 2), constant steps h = 0.01, ``save_every=1000``, for ``--steps``
steps (default 10⁷; ``--quick``: 10⁶), once per configuration of ``--every`` (steps between
periodic checkpoints; 0: no checkpoint file). Each configuration runs in a fresh Python
process, which reports

* its peak resident memory (``resource.getrusage(RUSAGE_SELF).ru_maxrss``), after compiling
  the loop on a short run (``warm``) and after the long run (``peak``);
* the wall time of the long run, and the part of it spent in checkpoint saves;
* the bytes its checkpoints wrote (every file write of ``lobattodae._io.atomic.write_npz`` is
  counted, main files and row segments apart; ``/proc/self/io`` ``wchar`` as a cross-check),
  the files left on disk, and what the single-file format of version 3 would have written
  (each save rewriting every row so far: Σ over saves of main file + rows so far);
* that ``resume=True`` on the finished checkpoint gives the same rows, bit for bit.

From the measured run it projects the 10⁸-step figures: time, bytes and segment files scale
with the steps (every save writes the rows since the previous one and one main file), the
memory held by the kept rows grows by three times their size (``10⁸/1000`` rows: the
recorded blocks, their concatenation and the Solution's arrays), and version 3's bytes
grow with the square of the saves. Writes ``benchmarks/results/longrun_memory.json``
(``--quick``: ``longrun_memory_quick.json``) and prints a Markdown table. Run from the
repository root::

    PYTHONPATH=src .venv/bin/python benchmarks/longrun_memory.py [--quick] [--steps N]
        [--every 100000 10000 0] [--stages 2] [--dir DIRECTORY]

10⁸ steps (``--steps 100000000``) take about ten times the 10⁷ run (about an hour on the
2-core development machine with s = 2).
"""

from __future__ import annotations

import json
import os
import resource
import shutil
import sys
import tempfile
import time

from lib import cli
from lib.output import child_env, child_result, loadavg, log, md_table, print_result, results_path, run_meta, \
    write_json

JSON_PATH = results_path("longrun_memory.json")
QUICK_JSON_PATH = results_path("longrun_memory_quick.json")

#: The step size (t1 = steps × H) and the output selection of every run.
H = 0.01
SAVE_EVERY = 1000
#: The 10⁸ steps of the issue's target, and its memory bound.
TARGET_STEPS = 10**8
GIB = 2**30


def _maxrss_bytes() -> int:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024  # KiB on Linux


def _wchar() -> int | None:
    try:
        with open("/proc/self/io") as fh:
            for line in fh:
                if line.startswith("wchar:"):
                    return int(line.split()[1])
    except OSError:
        pass
    return None


def child(steps: int, every: int, stages: int, directory: str) -> dict:
    """One configuration, in this (fresh) process; returns what it measured."""
    import numpy as np

    import lobattodae as L
    from lobattodae._io import atomic, checkpoint
    from lobattodae.examples import get_example

    writes = {"main_bytes": 0, "main_files": 0, "segment_bytes": 0, "segment_files": 0, "row_data_bytes": 0,
              "segment_rows": 0, "committed_rows": [], "checkpoint_s": 0.0}
    real, real_save = atomic.write_npz, checkpoint.save

    def counting(target, payload):
        real(target, payload)
        size = os.path.getsize(target)
        if "segment" in payload:
            writes["segment_bytes"] += size
            writes["segment_files"] += 1
            writes["row_data_bytes"] += sum(v.nbytes for k, v in payload.items() if k.startswith("rows/"))
            writes["segment_rows"] += len(payload["rows/t"])
        else:
            writes["main_bytes"] += size
            writes["main_files"] += 1
            writes["committed_rows"].append((json.loads(str(payload["counters"]))["rows"], size))

    def timed_save(*args, **kwargs):
        start = time.perf_counter()
        try:
            return real_save(*args, **kwargs)
        finally:
            writes["checkpoint_s"] += time.perf_counter() - start

    atomic.write_npz = counting
    checkpoint.save = timed_save
    ex = get_example("knife-edge")
    method = L.LobattoIIIAIIIB(stages=stages)
    path = os.path.join(directory, f"run-{every}.npz") if every else None

    def run(n, **kw):
        return L.solve(ex.problem, method, (0.0, n * H), ex.q0, ex.p0, n_steps=n, args=ex.args,
                       save_every=SAVE_EVERY, **kw)

    run(4096)  # compiles the loop (its shapes do not depend on the number of steps)
    warm = _maxrss_bytes()
    wchar0 = _wchar()
    start = time.perf_counter()
    sol = run(steps, checkpoint=path, checkpoint_every=every or None)
    wall = time.perf_counter() - start
    peak = _maxrss_bytes()
    wchar = None if wchar0 is None else _wchar() - wchar0
    out = {"steps": steps, "every": every, "stages": stages, "rows": len(sol.t), "success": bool(sol.success),
           "max_constraint_residual": float(sol.stats["max_constraint_residual"]), "wall_s": wall,
           "rss_warm_bytes": warm, "rss_peak_bytes": peak, "row_bytes_in_memory": int(
               sum(x.nbytes for x in (sol.t, sol.q, sol.p, sol.lam))
               + sum(v.nbytes for v in sol.stats.values() if isinstance(v, np.ndarray))),
           "wchar_bytes": wchar}
    if path:
        committed = writes.pop("committed_rows")
        per_row = writes["row_data_bytes"] / max(writes["segment_rows"], 1)
        rows_dir = checkpoint.rows_directory(path)
        files = os.listdir(rows_dir)
        out.update(writes)
        out.update({
            "saves": len(committed),
            "written_bytes": writes["main_bytes"] + writes["segment_bytes"],
            "row_bytes_per_row": per_row,
            "v3_bytes": int(sum(size + rows * per_row for rows, size in committed)),
            "main_file_bytes": os.path.getsize(path),
            "rows_dir_bytes": sum(os.path.getsize(os.path.join(rows_dir, f)) for f in files),
            "rows_dir_files": len(files),
        })
        start = time.perf_counter()
        again = run(steps, checkpoint=path, checkpoint_every=every, resume=True)
        out["resume_s"] = time.perf_counter() - start
        out["resume_bit_for_bit"] = all(np.array_equal(getattr(sol, k), getattr(again, k))
                                        for k in ("t", "q", "p", "lam"))
    return out


def project(r: dict, target: int = TARGET_STEPS) -> dict:
    """The figures of ``target`` steps from a measured run (see the module docstring)."""
    f = target / r["steps"]
    rows_memory = 3 * r["row_bytes_in_memory"] * (f - 1)  # the blocks, their concatenation, the Solution
    out = {"steps": target, "wall_s": r["wall_s"] * f, "rss_peak_bytes": r["rss_peak_bytes"] + rows_memory}
    if r["every"]:
        saves = r["saves"] * f
        main = r["main_bytes"] / r["saves"]
        per_save_rows = r["segment_rows"] / r["saves"]
        out.update({
            "saves": saves,
            "checkpoint_s": r["checkpoint_s"] * f,
            "written_bytes": r["written_bytes"] * f,
            "rows_dir_bytes": r["rows_dir_bytes"] * f,
            "rows_dir_files": r["rows_dir_files"] * f,
            # Σ_{k=1}^{S} (main + k × rows per save × bytes per row)
            "v3_bytes": saves * main + r["row_bytes_per_row"] * per_save_rows * saves * (saves + 1) / 2,
        })
    return out


def _mib(x) -> str:
    return "–" if x is None else f"{x / 2**20:,.1f} MiB"


def _size(x) -> str:
    if x is None:
        return "–"
    for unit, scale in (("TiB", 2**40), ("GiB", 2**30), ("MiB", 2**20)):
        if x >= scale:
            return f"{x / scale:,.1f} {unit}"
    return f"{x / 2**10:,.1f} KiB"


def table(results: dict) -> str:
    headers = ["checkpoint_every", "steps", "wall (saves)", "peak RSS (after compile)", "written by checkpoints",
               "segments", "on disk", "version 3 would write", "resume"]
    rows = []
    for r in results["runs"]:
        for label, x in (("measured", r), ("projected", r["projected"])):
            if label == "projected" and x["steps"] == r["steps"]:
                continue
            ck = r["every"] or "none"
            rss = _mib(x["rss_peak_bytes"]) + (f" ({_mib(r['rss_warm_bytes'])})" if label == "measured" else "")
            rows.append([
                f"{ck} ({label})", f"{x['steps']:.0e}",
                f"{x['wall_s']:,.0f} s" + (f" ({x['checkpoint_s']:,.1f} s)" if r["every"] else ""), rss,
                _size(x.get("written_bytes")),
                f"{x['rows_dir_files']:,.0f}" if r["every"] else "–",
                _size(x.get("rows_dir_bytes", 0) + (r.get("main_file_bytes", 0) if r["every"] else 0))
                if r["every"] else "–",
                _size(x.get("v3_bytes")),
                ("bit for bit" if r["resume_bit_for_bit"] else "DIFFERS") + f", {r['resume_s']:.1f} s"
                if label == "measured" and r["every"] else "–",
            ])
    return md_table(headers, rows)


def main() -> None:
    ap = cli.parser(__doc__, "quick", quick={"help": "10⁶ steps"})
    ap.add_argument("--steps", type=int, default=None, help="steps per run (default 10⁷; --quick: 10⁶)")
    ap.add_argument("--every", type=int, nargs="+", default=[100_000, 10_000, 0],
                    help="steps between checkpoints, one run each (0: no checkpoint; default: 100000 10000 0)")
    ap.add_argument("--stages", type=int, default=2)
    ap.add_argument("--dir", default=None, help="where the checkpoints go (default: a temporary directory)")
    ap.add_argument("--child", action="store_true", help="(internal) one configuration, in this process")
    a = ap.parse_args()
    steps = a.steps or (10**6 if a.quick else 10**7)
    if a.child:
        print_result(child(steps, a.every[0], a.stages, a.dir))
        return
    results = {"meta": run_meta(), "steps": steps, "h": H, "save_every": SAVE_EVERY, "stages": a.stages, "runs": []}
    directory = a.dir or tempfile.mkdtemp(prefix="longrun-")
    os.makedirs(directory, exist_ok=True)
    try:
        for every in a.every:
            log(f"{steps:.0e} steps, s = {a.stages}, checkpoint_every = {every or 'none'} ...")
            r = child_result([sys.executable, os.path.abspath(__file__), "--child", "--steps", str(steps), "--every",
                              str(every), "--stages", str(a.stages), "--dir", directory],
                             child_env(no_cache=False, JAX_PLATFORMS="cpu"), timeout=24 * 3600.0)
            if "error" in r:
                raise SystemExit(f"the run with checkpoint_every={every} failed: {r['error']}")
            r["projected"] = project(r)
            results["runs"].append(r)
            log(f"  {r['wall_s']:.0f} s, peak RSS {_mib(r['rss_peak_bytes'])} (after compiling "
                f"{_mib(r['rss_warm_bytes'])}), checkpoints wrote {_size(r.get('written_bytes'))}")
    finally:
        if a.dir is None:
            shutil.rmtree(directory, ignore_errors=True)
    results["meta"]["loadavg_end"] = loadavg()
    log("\n" + table(results))
    fits = [r["projected"]["rss_peak_bytes"] < GIB and r["projected"].get("written_bytes", 0) < GIB
            for r in results["runs"]]
    log(f"\n10⁸ steps keeping every {SAVE_EVERY}th point within 1 GiB (memory and bytes written): "
        + ", ".join(f"checkpoint_every={r['every'] or 'none'}: {'yes' if ok else 'NO'}"
                  for r, ok in zip(results["runs"], fits)))
    write_json(results, QUICK_JSON_PATH if a.quick else JSON_PATH)


if __name__ == "__main__":
    main()
