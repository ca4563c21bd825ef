"""What the scripts print and save: log lines, the record of a run (machine, command, load,
revision), JSON, Markdown tables, figures, and the results of child processes."""

from __future__ import annotations

import datetime
import json
import math
import os
import platform
import shlex
import subprocess
import sys
import time
from importlib.metadata import PackageNotFoundError, version
from typing import Any

import numpy as np

BENCHMARKS = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
ROOT = os.path.dirname(BENCHMARKS)
RESULTS = os.path.join(BENCHMARKS, "results")
#: Marks a child process's result line on its stdout (the rest is free for warnings).
RESULT_MARK = "RESULT "


def log(msg: str = "") -> None:
    print(msg, flush=True)


def results_path(name: str) -> str:
    return os.path.join(RESULTS, name)


# ------------------------------------------------------------------------------ the run record
def loadavg() -> list[float]:
    return [round(x, 2) for x in os.getloadavg()]


def _version(package: str) -> str | None:
    try:
        return version(package)
    except PackageNotFoundError:
        return None


def cpu_model() -> str:
    with open("/proc/cpuinfo") as fh:
        for line in fh:
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    return platform.processor() or "unknown"


def machine_info() -> dict:
    return {
        "platform": platform.platform(),
        "machine": platform.machine(),
        "cpu": cpu_model(),
        "cpu_count": os.cpu_count(),
        "cpus_usable": len(os.sched_getaffinity(0)),
        "python": sys.version.split()[0],
        "versions": {m: _version(m) for m in ("jax", "jaxlib", "numpy", "scipy", "diffrax", "equinox", "sympy",
                                              "scikit-sundae")},
        "XLA_FLAGS": os.environ.get("XLA_FLAGS", ""),
    }


def source_revision() -> str:
    """``git rev-parse --short HEAD`` of this checkout, ``-dirty`` when ``src/`` has uncommitted
    changes: which code produced the numbers ("unknown" where git or the repository is missing,
    as on a machine the tree was copied to)."""
    def git(*args):
        return subprocess.run(["git", *args], cwd=ROOT, capture_output=True, text=True, timeout=10).stdout.strip()

    try:
        rev = git("rev-parse", "--short", "HEAD")
    except OSError:
        return "unknown"
    return (rev or "unknown") + ("-dirty" if rev and git("status", "--porcelain", "src") else "")


def command() -> str:
    return " ".join(shlex.quote(x) for x in ["PYTHONPATH=src", ".venv/bin/python", os.path.relpath(sys.argv[0], ROOT)]
                    + sys.argv[1:])


def run_meta(**extra) -> dict:
    """The record every result file starts with: date, exact command, machine, the size of
    XLA's CPU pool where it is set, the lobattodae that ran (version, revision, path) and the
    load average at the start."""
    import lobattodae

    return {"date": datetime.datetime.now().isoformat(timespec="seconds"), "command": command(),
            "machine": machine_info(), "cpu_threads": {k: os.environ.get(k) for k in ("PJRT_NPROC", "NPROC")},
            "lobattodae": lobattodae.__version__, "lobattodae_revision": source_revision(),
            "lobattodae_path": os.path.dirname(lobattodae.__file__), "loadavg_start": loadavg(), **extra}


def finish(out: dict, path: str | None, start: float) -> None:
    """Closes the record ``out`` of a run that began at ``start`` (``time.perf_counter``): its
    wall time and the load average at the end; writes it to ``path`` unless that is None."""
    out["wall_s"] = time.perf_counter() - start
    out["loadavg_end"] = loadavg()
    if path is not None:
        write_json(out, path)
    log(f"({out['wall_s']:.0f} s)")


# ------------------------------------------------------------------------------------------ JSON
def jsonable(x):
    """NaN and inf as strings, NumPy scalars and arrays as Python objects (for ``json.dump``)."""
    if isinstance(x, dict):
        return {str(k): jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [jsonable(v) for v in x]
    if isinstance(x, np.ndarray):
        return jsonable(x.tolist())
    if isinstance(x, (np.floating, float)):
        x = float(x)
        return x if math.isfinite(x) else str(x)
    if isinstance(x, np.integer):
        return int(x)
    if isinstance(x, np.bool_):
        return bool(x)
    return x


def write_json(data: dict, path: str, *, quiet: bool = False) -> None:
    os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
    with open(path, "w") as fh:
        json.dump(jsonable(data), fh, indent=1)
    if not quiet:
        log(f"wrote {os.path.relpath(path, ROOT)}")


def read_json(path: str, default: Any = None) -> Any:
    """The saved results at ``path``, or ``default`` where there are none yet."""
    if not os.path.exists(path):
        return default
    with open(path) as fh:
        return json.load(fh)


def merged(path: str, key: str, updates: dict, meta: dict) -> dict:
    """The results file at ``path`` with the entries ``updates`` of ``key`` replaced (a run of a
    subset keeps the others; each entry records the run it came from in ``meta``)."""
    out = read_json(path, {"meta": {}, key: {}})
    for name, entry in updates.items():
        out[key][name] = {**entry, "meta": meta}
    out["meta"] = meta
    return out


def with_parts(path: str, res: dict, parts: list[str], all_parts: list[str]) -> dict:
    """What the results file of a script with parts should hold after a run of ``parts``: the
    run ``res`` when it ran them all; else the saved file with those parts replaced and the
    run's ``meta`` under ``meta_parts``."""
    if set(parts) == set(all_parts):
        return res
    saved = read_json(path, {})
    saved.setdefault("meta", res["meta"])
    for part in parts:
        saved.setdefault("meta_parts", {})[part] = res["meta"]
        saved[part] = res[part]
    return saved


# ------------------------------------------------------------------------------ tables, figures
def fmt(x: Any, spec: str = ".3g") -> str:
    """A table cell: ``–`` for None, ``spec`` for finite floats."""
    if x is None:
        return "–"
    if isinstance(x, float):
        return format(x, spec) if math.isfinite(x) else str(x)
    return str(x)


def md_table(headers: list[str], rows: list[list[Any]]) -> str:
    lines = ["| " + " | ".join(headers) + " |", "|" + "|".join("---" for _ in headers) + "|"]
    return "\n".join(lines + ["| " + " | ".join(fmt(x) for x in r) + " |" for r in rows])


def pyplot():
    """matplotlib's pyplot on the file-only Agg backend."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def save_figure(fig, path: str) -> None:
    os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
    fig.savefig(path, dpi=110)
    pyplot().close(fig)
    log(f"wrote {os.path.relpath(path, ROOT)}")


# ----------------------------------------------------------------------------- child processes
def child_env(*, no_cache: bool = True, **set_vars: str | None) -> dict:
    """The environment of a measuring child process: this process's lobattodae and ``lib`` first
    on ``PYTHONPATH``, no persistent compilation cache unless ``no_cache=False``, and the given
    variables set (None: removed)."""
    import lobattodae

    env = dict(os.environ)
    src = os.path.dirname(os.path.dirname(os.path.abspath(lobattodae.__file__)))
    env["PYTHONPATH"] = os.pathsep.join([src, BENCHMARKS] + ([env["PYTHONPATH"]] if env.get("PYTHONPATH") else []))
    if no_cache:
        env.pop("LOBATTODAE_CACHE_DIR", None)
        env.pop("JAX_COMPILATION_CACHE_DIR", None)
        env["LOBATTODAE_NO_CACHE"] = "1"
    for k, v in set_vars.items():
        if v is None:
            env.pop(k, None)
        else:
            env[k] = v
    return env


def print_result(result: dict) -> None:
    """What a child process ends with: its result, one marked JSON line."""
    print(RESULT_MARK + json.dumps(jsonable(result)), flush=True)


def child_result(cmd: list[str], env: dict, timeout: float = 3600.0) -> dict:
    """Runs ``cmd`` and returns the result it printed with :func:`print_result`; a failure comes
    back as ``{"error": ...}`` (recorded by the caller, never hidden)."""
    try:
        proc = subprocess.run(cmd, capture_output=True, text=True, env=env, timeout=timeout)
    except subprocess.TimeoutExpired:
        return {"error": f"timed out after {timeout:.0f} s"}
    lines = [ln for ln in proc.stdout.splitlines() if ln.startswith(RESULT_MARK)]
    if proc.returncode != 0 or not lines:
        return {"error": f"exit {proc.returncode}: " + (proc.stderr.strip()[-2000:] or proc.stdout.strip()[-2000:])}
    return json.loads(lines[-1][len(RESULT_MARK):])


def python_child(code: str, *argv: str) -> list[str]:
    """The command that runs ``code`` in a fresh interpreter with ``argv``."""
    return [sys.executable, "-c", code, *argv]


def rows_per_source(code: str, args: list, sources: list[str] | None, timeout: float = 3600.0) -> dict:
    """Runs ``code`` once per source tree (``--src`` directories; default ``src``), each in a fresh
    process with that tree's lobattodae, the repository and ``lib`` first on ``PYTHONPATH`` and
    ``args`` as JSON arguments; ``code`` prints ``{"rows": [...]}`` with :func:`print_result`.
    Returns ``{source: rows}``; a failing tree ends the script, naming it."""
    root = os.path.dirname(BENCHMARKS)
    runs = {}
    for src in sources or ["src"]:
        env = child_env(PYTHONPATH=os.pathsep.join([os.path.abspath(src), root, BENCHMARKS]))
        out = child_result(python_child(code, *(json.dumps(x) for x in args)), env, timeout=timeout)
        if "error" in out:
            sys.exit(f"{src}: {out['error']}")
        runs[src] = out["rows"]
    return runs
