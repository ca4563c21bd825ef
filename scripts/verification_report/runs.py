"""The computations of the verification report: every number it shows, as plain data.

Each study returns a JSON-ready record; the long runs also return the time series that the
figures draw (:class:`LongSeries`, :class:`SleighSeries`), which are not written to the JSON. Nothing here words a
statement: :mod:`.findings` decides them from the records, the template words them.

The convergence studies and the special-case runs use ``lam_start="previous"`` (the paper's
scheme, Λ_1 = λ_n) explicitly, because the proven orders refer to it; every study is repeated
with ``"auto"`` and the two are compared.
"""

from __future__ import annotations

import hashlib
import math
import os
import platform
import subprocess
import time
import warnings
from pathlib import Path
from typing import NamedTuple

import jax
import matplotlib
import numpy as np

import lobattodae
from lobattodae import LobattoIIIAIIIB, lobatto_pair
from lobattodae._convergence import COMPONENTS, N_FIT, PLATEAU_REL, convergence_study, default_step_counts, observed_order
from lobattodae._diagnostics import invariant_error, invariant_values
from lobattodae._stepper import DRIFT_BAND, DRIFT_EPOCH, LAM_START_MODES
from lobattodae.conditions import r_infinity
from lobattodae.examples import get_example

# ----------------------------------------------------------------------------- settings
#: Fits of q and p use errors above QP_PLATEAU * (1 + max|x|), below the library's default
#: (PLATEAU_REL): the observed round-off level of q and p is ~1e-15, and the library's
#: default would leave the s = 5, 6 fits only their coarsest, pre-asymptotic step counts.
#: λ keeps the library's floor (it is recovered from h·Λ, so its round-off grows like eps/h).
QP_PLATEAU = 1e-14
PLATEAU = {"q": QP_PLATEAU, "p": QP_PLATEAU, "lam": PLATEAU_REL["lam"]}
#: The paper's scheme (Λ_1 = λ_n), to which the proven orders refer.
PAPER = {"lam_start": "previous"}
#: Examples whose error constants depend on the parity of the step count (see their
#: Example.notes): only even step counts are used for them.
EVEN_ONLY = ("vertical-disk",)
#: The long runs: the reversible contact oscillator and its non-reversible variant.
LONG_EXAMPLES = ("contact", "contact-nonreversible")
#: Stages of the long runs and of the λ-mode contact run.
LONG_STAGES = 3
#: Step sizes of the long runs: h = 2 sin(pi / N) (McLachlan & Perlmutter), N = 15 and 40.
LONG_N = (15, 40)
#: The contact run of the λ-mode comparison: h = 2 sin(pi / LAM_N).
LAM_N = 15
#: The coordinates of the vertical disk, in the order of its q.
DISK_COORDINATES = ("x", "y", "φ", "θ")
#: Disk errors at or below this are round-off (~1e-15 here): no order is taken from them.
DISK_ROUNDOFF = 2e-14

FULL = {
    "stages": (2, 3, 4, 5, 6),
    # None: the library's default_step_counts. s = 5, 6: denser and coarser than the
    # default, because their q, p errors reach round-off within a few step counts. Explicit
    # counts are used as given (the defaults are scaled to the example's t_span, these not).
    "counts": {
        2: None,
        3: None,
        4: None,
        5: (3, 4, 5, 6, 7, 8, 10, 12, 14, 16, 20, 24, 32, 48, 64),
        6: (2, 3, 4, 5, 6, 7, 8, 10, 12, 16, 24, 32, 48, 64),
    },
    "long_steps": 100_000,
    # the measure of success of the λ-mode decision (DESIGN.md, "The λ mode")
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


def settings(cfg: dict) -> dict:
    """The settings of this report, as the JSON records them."""
    return {**{k: v for k, v in cfg.items() if k != "examples"}, "qp_plateau": QP_PLATEAU,
            "even_only": EVEN_ONLY, "long_stages": LONG_STAGES, "long_n": LONG_N, "lam_n": LAM_N}


def library_constants(cfg: dict) -> dict:
    """The constants of the library that the report's prose names, read from the library."""
    stages = sorted({*cfg["stages"], LONG_STAGES})
    return {
        "plateau_rel": PLATEAU_REL,
        "n_fit": N_FIT,
        "drift_band": DRIFT_BAND,
        "drift_epoch": DRIFT_EPOCH,
        "lam_start_modes": LAM_START_MODES,
        "default_lam_start": LobattoIIIAIIIB(stages=LONG_STAGES).lam_start,
        "orders": {s: LobattoIIIAIIIB(stages=s).order() for s in stages},
        "r_infinity": {s: r_infinity(lobatto_pair(s).a, lobatto_pair(s).b) for s in stages},
    }


def machine(root: Path) -> dict:
    """The machine and the software versions of this run (``root``: the git checkout)."""
    cpu = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo") as fh:
            cpu = next((line.split(":", 1)[1].strip() for line in fh if line.startswith("model name")), cpu)
    except OSError:
        pass
    return {
        "cpu": cpu,
        "logical_cores": os.cpu_count(),
        "os": platform.platform(),
        "python": platform.python_version(),
        "jax": jax.__version__,
        "jax_backend": jax.default_backend(),
        "numpy": np.__version__,
        "matplotlib": matplotlib.__version__,
        "lobattodae": lobattodae.__version__,
        "git": git_revision(root),
    }


def git_revision(root: Path) -> str:
    try:
        rev = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=root,
                             capture_output=True, text=True, check=True).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"],
                               cwd=root, capture_output=True, text=True, check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"
    return rev + (" (with uncommitted changes)" if dirty else "")


def plain(x):
    """``x`` as JSON data: arrays and tuples as lists, keys as strings, NaN and ±inf as None."""
    if isinstance(x, dict):
        return {str(k): plain(v) for k, v in x.items()}
    if isinstance(x, (list, tuple, np.ndarray)):
        return [plain(v) for v in x]
    if isinstance(x, (bool, np.bool_)):
        return bool(x)
    if isinstance(x, (int, np.integer)):
        return int(x)
    if isinstance(x, (float, np.floating)):
        return float(x) if math.isfinite(x) else None
    return x


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


def chunk_for(counts) -> int:
    """One chunk size for all these step counts, the one ``convergence_study`` takes for them:
    the runs outside the study reuse its compiled loop."""
    return 1 << (int(max(counts)) - 1).bit_length()


def digest(*arrays) -> str:
    """A fingerprint of a run's numbers (to tell bitwise-identical runs apart)."""
    hsh = hashlib.sha256()
    for a in arrays:
        hsh.update(np.ascontiguousarray(np.asarray(a, np.float64)).tobytes())
    return hsh.hexdigest()[:16]


# --------------------------------------------------------------------- convergence study
def step_counts(ex, s, cfg):
    """The step counts for s stages, and those left out because Newton fails there."""
    default = default_step_counts(s, ex.t_end - ex.t0)
    counts = sorted(cfg["counts"][s] or default)
    if ex.name in EVEN_ONLY:
        counts = [n for n in counts if n % 2 == 0]
    # Counts coarser than the library's defaults may be beyond Newton's reach: try them.
    dropped = []
    while counts and counts[0] < min(default):
        try:
            solve_example(ex, s, counts[0], chunk_size=chunk_for(counts), **PAPER)
            break
        except lobattodae.SolverError as exc:
            dropped.append({"s": s, "n": counts.pop(0), "why": str(exc).split(";")[0]})
    return tuple(counts), dropped


def convergence(ex, cfg):
    """The convergence study of ``ex`` with the paper's scheme, repeated with 'auto'.

    Returns the JSON record and the study itself (for its figure)."""
    stages = cfg["stages"]
    counts, dropped = {}, []
    for s in stages:
        counts[s], left_out = step_counts(ex, s, cfg)
        dropped += left_out
    t0 = time.perf_counter()
    with Recorder() as rec:
        paper = convergence_study(ex, stages=stages, n_steps=counts, method_options=PAPER, plateau=PLATEAU)
    wall = time.perf_counter() - t0
    # 'auto' takes the paper's steps until the drift monitor sees an excursion (which a
    # 'previous' run reports with a RuntimeWarning) and then re-synchronises λ.
    t0 = time.perf_counter()
    auto = convergence_study(ex, stages=stages, n_steps=counts, method_options={"lam_start": "auto"},
                             plateau=PLATEAU)
    pairs = [(np.column_stack([paper.errors[s][c] for c in COMPONENTS]),
              np.column_stack([auto.errors[s][c] for c in COMPONENTS])) for s in stages]
    with np.errstate(invalid="ignore"):
        rel = max(np.nanmax(np.abs(a - p) / np.maximum(np.abs(p), np.finfo(float).tiny), initial=0.0)
                  for p, a in pairs)
    record = {
        "description": ex.description,
        "notes": ex.notes,
        "overrides": {c: dict(table) for c, table in ex.expected_order_overrides.items()},
        "study": paper.to_dict(),
        "dropped": dropped,
        "warnings": rec.messages,  # solve's only RuntimeWarning: a drift excursion
        "wall": wall,
        "auto": {
            "runs": sum(len(p) for p, _ in pairs),
            "identical": sum(np.array_equal(row_p, row_a, equal_nan=True)
                             for p, a in pairs for row_p, row_a in zip(p, a)),
            "max_rel_diff": rel,
            "observed": {s: dict(auto.observed[s]) for s in stages},
            "wall": time.perf_counter() - t0,
        },
    }
    return record, paper


def order_with_floor(record, s, c, rel):
    """The observed order of one entry of a study with the floor ``rel * (1 + max|x|)``
    instead of the report's (the library's own fit, on the study's errors)."""
    run = record["study"]["runs"][str(s)]
    floor = record["study"]["floors"][c] * rel / PLATEAU[c]
    errors = np.asarray(run["errors"][c], float)
    return {"floor": floor, "observed": observed_order(run["h"], errors, floor)}


# ----------------------------------------------------------------------- special cases
def knife_edge_lambda(cfg):
    """s = 2 on the knife edge: λ at even and odd step indices, and the odd-step error that
    the two-step recursion of the report predicts."""
    ex = get_example("knife-edge")
    a = ex.args
    theta0 = float(ex.q0[2])
    omega = float(ex.p0[2]) / a.J
    v0 = (math.cos(theta0) * ex.p0[0] + math.sin(theta0) * ex.p0[1]) / a.m
    rows = []
    for n in cfg["knife_counts"]:
        sol = solve_example(ex, 2, n, chunk_size=chunk_for(cfg["knife_counts"]), **PAPER)
        qe, _, le = ex.exact(sol.t)
        e = np.max(np.abs(sol.lam - le.reshape(sol.lam.shape)), axis=1)
        h = sol.stats["h"]
        pred = a.m * a.g * math.cos(theta0) * (1 - math.cos(omega * h)) + a.m * v0 * (
            2 * math.sin(omega * h) / h - omega * (1 + math.cos(omega * h)))
        rows.append({"n": n, "h": h, "even_max": np.max(e[0::2]), "odd_max": np.max(e[1::2]),
                     "odd_min": np.min(e[1::2]), "predicted": abs(pred), "final": e[-1],
                     "q": np.max(np.abs(sol.q - qe))})
    return rows


def vertical_disk_components(cfg):
    """Per-component errors of the vertical disk for two step counts per s."""
    ex = get_example("vertical-disk")
    rows = []
    for s, (n1, n2) in cfg["disk_pairs"].items():
        if s not in cfg["stages"]:
            continue
        errs = []
        for n in (n1, n2):
            sol = solve_example(ex, s, n, chunk_size=chunk_for((n2,)), **PAPER)
            qe, pe, _ = ex.exact(sol.t)
            errs.append(np.concatenate([np.max(np.abs(sol.q - qe), axis=0), np.max(np.abs(sol.p - pe), axis=0)]))
        e1, e2 = errs
        with np.errstate(divide="ignore", invalid="ignore"):
            order = np.where(e2 > DISK_ROUNDOFF, np.log(e1 / e2) / math.log(n2 / n1), np.nan)
        rows.append({"s": s, "n": (n1, n2), "e1": e1, "e2": e2, "order": order})
    return {"names": [*DISK_COORDINATES, *(f"p_{x}" for x in DISK_COORDINATES)], "rows": rows}


# ----------------------------------------------------------------------------- long runs
class LongSeries(NamedTuple):
    """The time series of a long run that the figures draw (not written to the JSON)."""

    t: np.ndarray
    dH: np.ndarray  # H(t_k) − H(t_0)
    phi: np.ndarray  # ‖φ(t_k, q_k, p_k)‖∞
    drift: np.ndarray  # ‖λ_k − λ(t_k, q_k, p_k)‖∞
    resync: np.ndarray  # indices k of the steps from t_k that started from λ(t_k, q_k, p_k)


class SleighSeries(NamedTuple):
    """The time series of a sleigh run that the figures draw (not written to the JSON)."""

    t: np.ndarray
    q_error: np.ndarray  # ‖q_k − q(t_k)‖∞ against the closed form
    drift: np.ndarray
    resync: np.ndarray


def lam_stats(sol, resync) -> dict:
    """The λ-mode statistics of a run: re-synchronisations ('auto'), excursions of the drift
    monitor, and the times t_k of the first steps that started from λ(t_k, q_k, p_k)."""
    return {"lam_resets": int(sol.stats["lam_resets"]), "lam_excursions": int(sol.stats["lam_excursions"]),
            "resync_t": sol.t[resync[:100]]}


def resyncs(sol) -> np.ndarray:
    """The indices k of the steps from t_k that started from λ(t_k, q_k, p_k) ('auto')."""
    return np.flatnonzero(np.asarray(sol.stats["lam_resync"], bool))


def long_run(name, n_steps, N, **method_options):
    """``name`` over ``n_steps`` steps of h = 2 sin(π/N) with LONG_STAGES stages."""
    ex = get_example(name)
    mode = LobattoIIIAIIIB(stages=LONG_STAGES, **method_options).lam_start
    h = 2 * math.sin(math.pi / N)
    t0 = time.perf_counter()
    with Recorder() as rec:
        # throw=False: a run that fails part-way is reported with its computed prefix
        sol = solve_example(ex, LONG_STAGES, n_steps, t_span=(0.0, n_steps * h), throw=False, **method_options)
    wall = time.perf_counter() - t0
    done = len(sol.t) - 1  # steps actually taken
    dH = invariant_error(sol, ex.invariants["energy"])
    dHy = invariant_error(sol, ex.invariants["H_y"])
    phi = np.asarray(sol.stats["constraint_residual"])
    drift = np.asarray(sol.stats["multiplier_drift"])
    resync = resyncs(sol)
    k = max(1, done // 10)
    kf = min(done, max(1, n_steps // 10))  # first tenth of the planned run
    first, last = slice(None, kf + 1), slice(-k - 1, None)
    tenths = np.linspace(0, done, 11).astype(int)
    record = {
        "name": name, "N": N, "h": h, "T": n_steps * h, "n_steps": n_steps, "lam_start": mode,
        "H0": invariant_values(sol, ex.invariants["energy"])[0],
        "Hy0": invariant_values(sol, ex.invariants["H_y"])[0],
        "epsilon": getattr(ex.args, "epsilon", float("nan")),
        "success": bool(sol.success), "message": sol.message, "steps_done": done, "t_end": sol.t[-1],
        "wall": wall, "digest": digest(sol.q, sol.p, sol.lam), **lam_stats(sol, resync),
        "first10": np.max(np.abs(dH[first])), "last10": np.max(np.abs(dH[last])),
        "max_dH": np.max(np.abs(dH)), "final_dH": dH[-1],
        "slope": np.polyfit(sol.t, dH, 1)[0],
        "slope_first": np.polyfit(sol.t[first], dH[first], 1)[0],
        "slope_last": np.polyfit(sol.t[last], dH[last], 1)[0],
        "max_phi": np.max(phi), "max_dHy": np.max(np.abs(dHy)),
        "newton_mean": np.mean(sol.stats["newton_iterations"]),
        "newton_max": np.max(sol.stats["newton_iterations"]),
        "tenths": dH[tenths],
        "max_lam_drift": np.max(drift),
        "lam_drift_first10": np.max(drift[first]), "lam_drift_last10": np.max(drift[last]),
        "lam_max_first10": np.max(np.abs(sol.lam[first])), "lam_max_last10": np.max(np.abs(sol.lam[last])),
        "warnings": rec.messages,
    }
    return record, LongSeries(sol.t, dH, phi, drift, resync)


def sleigh_run(s, h, T, lam_start):
    """The Chaplygin sleigh with s stages and n = T/h steps, against its closed form."""
    ex = get_example("sleigh")
    n = round(T / h)
    t0 = time.perf_counter()
    with Recorder() as rec:
        sol = solve_example(ex, s, n, t_span=(0.0, n * h), throw=False, lam_start=lam_start)
    wall = time.perf_counter() - t0
    qe, pe, le = ex.exact(sol.t)
    q_error = np.max(np.abs(sol.q - qe), axis=1)
    drift = np.asarray(sol.stats["multiplier_drift"])
    resync = resyncs(sol)
    record = {
        "name": "sleigh", "s": s, "h": h, "T": n * h, "n_steps": n, "lam_start": lam_start,
        "success": bool(sol.success), "message": sol.message, "steps_done": len(sol.t) - 1,
        "t_end": sol.t[-1], "q_err_T": q_error[-1], "q_scale_T": np.max(np.abs(qe[-1])),
        "p_err_T": np.max(np.abs(sol.p[-1] - pe[-1])),
        "lam_err_T": np.max(np.abs(sol.lam[-1] - np.reshape(le[-1], sol.lam[-1].shape))),
        "max_q_err": np.max(q_error), "max_drift": np.max(drift), "drift_T": drift[-1],
        "newton_mean": np.mean(sol.stats["newton_iterations"]),
        "wall": wall, "warnings": rec.messages, "digest": digest(sol.q, sol.p, sol.lam),
        # the drift at the end of each re-synchronised step, and just before it
        "drift_after_reset": drift[resync[:100] + 1], "drift_before_reset": drift[resync[:100]],
        **lam_stats(sol, resync),
    }
    return record, SleighSeries(sol.t, q_error, drift, resync)
