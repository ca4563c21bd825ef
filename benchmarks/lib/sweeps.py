"""Settings swept under a time budget, Pareto fronts, and searches for the cheapest setting
that meets an error target.

A sweep's points share one vocabulary: the setting (``tol`` unless named otherwise), ``error``
(inf on failure), ``time`` (best wall time), ``cpu_time`` (its process CPU time), ``repeats``,
``first_call_time`` (when a first call is timed apart) and what the script's ``post`` adds
(``ok``, ``steps``, ``message``, ...).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np

from .output import loadavg, log
from .timing import best_of

#: Optional fields of a point, in the order the sweep's log line shows them.
_LOGGED = (("steps", " {} steps"), ("rejected", " ({} rejected)"), ("newton_per_step", " {} Newton it/step"),
           ("max_phi", " max|φ| {:.1e}"), ("nfev", " {} fev"), ("message", " [{}]"))


def half_decades(hi: float, lo: float) -> list[float]:
    """``hi`` down to ``lo`` in steps of √10 (both ends powers of √10)."""
    k0, k1 = round(-2 * math.log10(hi)), round(-2 * math.log10(lo))
    return [float(f"{10 ** (-k / 2):.3g}") for k in range(k0, k1 + 1)]


def decades(hi: float, lo: float) -> list[float]:
    return [10.0 ** -k for k in range(round(-math.log10(hi)), round(-math.log10(lo)) + 1)]


class Sweep:
    """One solver over a list of settings, loosest first.

    Every setting is timed with :func:`~lib.timing.best_of` (``repeats`` calls, a call longer
    than ``repeat_limit`` not repeated); ``post`` turns the best call's output into the point
    (untimed). The sweep stops once a call takes longer than ``budget`` seconds or the next is
    predicted (from the growth of the last two) to take more than 3× that, once the best error
    has not halved over three settings while below ``floor`` (a round-off floor; above it a
    plateau is saturation at loose settings), or once an error is at most ``low``.
    """

    def __init__(self, label: str, *, budget: float, repeats: int, repeat_limit: float, floor: float,
                 low: float = 0.0, setting: str = "tol"):
        self.label, self.budget, self.repeats, self.repeat_limit = label, budget, repeats, repeat_limit
        self.floor, self.low, self.setting = floor, low, setting

    def run(self, settings, call: Callable[[Any], Any], post: Callable[[Any], dict], *,
            warm: Callable[[], Any] | None = None, first_call: bool = False) -> dict:
        """``call(setting)`` is what is timed. ``warm``: one call before the sweep (compilation;
        its time is ``warmup_s``); ``first_call``: one call before each setting's timed calls,
        its time kept as ``first_call_time``."""
        out = {"label": self.label, "points": [], "stopped": "", "warmup_s": None, "loadavg_start": loadavg()}
        start = time.perf_counter()
        if warm is not None:
            try:
                warm()
            except Exception as exc:  # recorded; the sweep goes on
                log(f"    {self.label}: warm-up failed: {type(exc).__name__}: {exc}")
            out["warmup_s"] = time.perf_counter() - start
        best_err, since, times = math.inf, 0, []
        for st in settings:
            if len(times) >= 2 and times[-1] > 0.5:
                predicted = times[-1] * max(1.0, times[-1] / times[-2])
                if predicted > 3 * self.budget:
                    out["stopped"] = (f"next call predicted to take {predicted:.0f} s "
                                      f"(> 3x the {self.budget:g} s budget)")
                    break
            p = self._point(st, call, post, first_call)
            out["points"].append(p)
            self._log(p)
            times.append(p["time"])
            err = p["error"]
            if math.isfinite(p["time"]) and p["time"] > self.budget:
                out["stopped"] = f"a call took {p['time']:.0f} s (> {self.budget:g} s budget)"
                break
            if err < best_err / 2:
                best_err, since = err, 0
            elif math.isfinite(best_err):
                since += 1
            if since >= 3 and best_err <= self.floor:
                out["stopped"] = f"error floor (best {best_err:.1e} not halved over three settings)"
                break
            if err <= self.low:
                out["stopped"] = f"error {err:.1e} below the range"
                break
        if out["stopped"]:
            log(f"    {self.label}: stopped: {out['stopped']}")
        out.update(seconds=time.perf_counter() - start, loadavg_end=loadavg())
        return out

    def _point(self, st, call, post, first_call) -> dict:
        p: dict = {self.setting: st}
        try:
            timing = best_of(lambda: call(st), self.repeats, limit=self.repeat_limit, first=first_call)
            if first_call:
                p["first_call_time"] = timing.first
            p.update(time=timing.best, cpu_time=timing.cpu, repeats=len(timing.times))
            p.update(post(timing.result))
        except Exception as exc:  # recorded, never hidden
            p.update(time=math.nan, error=math.inf, ok=False, message=f"{type(exc).__name__}: {str(exc)[:300]}")
        p.setdefault("ok", True)
        if not np.isfinite(p.get("error", math.inf)):
            p["error"] = math.inf
        return p

    def _log(self, p: dict) -> None:
        extra = "".join(f.format(p[k]) for k, f in _LOGGED if p.get(k) not in (None, ""))
        first = f", first {p['first_call_time']:.3g} s" if p.get("first_call_time") is not None else ""
        log(f"    {self.label:26s} {self.setting}={p[self.setting]:<8g} err {p['error']:.2e}  {p['time']:.4g} s "
            f"({p.get('repeats', 0)}x, cpu {p.get('cpu_time', math.nan):.3g} s{first}){extra}")


def solution_point(sol, error: Callable[[Any], float]) -> dict:
    """A lobattodae ``Solution`` as a sweep point: ``error(sol)`` where it succeeded, and its
    cost counters per attempted step."""
    st = sol.stats
    n, rejected = int(st["n_steps"]), int(st["n_rejected"])
    attempts = max(1, n + rejected)
    loop = st.get("compile_and_run_time")
    p = {"ok": bool(sol.success), "steps": n, "rejected": rejected,
         "newton_per_step": round(float(st["n_newton"]) / attempts, 2),
         "jacobians_per_step": round(float(st["n_jacobians"]) / attempts, 3),
         "max_phi": float(st["max_constraint_residual"]), "loop_s": None if loop is None else float(loop)}
    if sol.success:
        p["error"] = float(error(sol))
    else:
        p.update(error=math.inf, message=str(sol.message)[:300])
    return p


# ---------------------------------------------------------------------------- Pareto fronts
def pareto(points: list[dict], error: str = "error", time: str = "time") -> list[tuple[float, float]]:
    """The ``(error, time)`` pairs of ``points`` not beaten in both, time increasing, error
    decreasing; failed and non-finite points left out (values read back from JSON may be the
    strings "inf" and "nan")."""
    pairs = ((float(p[error]), float(p.get(time, math.nan))) for p in points)
    finite = sorted(((e, t) for e, t in pairs if math.isfinite(e) and math.isfinite(t) and e > 0), key=lambda p: p[1])
    front, best = [], math.inf
    for e, t in finite:
        if e < best:
            front.append((e, t))
            best = e
    return front


def time_at(points: list[dict], target: float, error: str = "error", time: str = "time") -> float | None:
    """The time at error ``target`` on the Pareto front of ``points``, log time interpolated
    linearly in log error between the two points that bracket it; None where the front does
    not reach it."""
    front = pareto(points, error, time)
    for (ea, ta), (eb, tb) in zip(front, front[1:]):
        if ea >= target >= eb:
            if ea == eb:
                return ta
            w = (math.log(target) - math.log(ea)) / (math.log(eb) - math.log(ea))
            return math.exp(math.log(ta) + w * (math.log(tb) - math.log(ta)))
    if front and front[0][0] <= target:  # the cheapest point is accurate enough already
        return front[0][1]
    return None


# --------------------------------------------------------------------------------- searches
@dataclass
class Search:
    """A search's result: the chosen setting and every probe ``setting -> (error, seconds)``."""

    best: Any = None
    probes: dict = field(default_factory=dict)
    message: str = ""

    def probe(self, setting, err_of: Callable[[Any], float]) -> float:
        if setting not in self.probes:
            t0 = time.perf_counter()
            e = float(err_of(setting))
            self.probes[setting] = (e if np.isfinite(e) else math.inf, time.perf_counter() - t0)
        return self.probes[setting][0]

    def slow(self, budget_s: float) -> bool:
        """The last two probes both over budget (a single slow one may be compilation)."""
        times = [s for _, s in self.probes.values()]
        return len(times) >= 2 and min(times[-2:]) > budget_s

    def table(self) -> list[dict]:
        return [{"setting": k, "err": e, "seconds": s} for k, (e, s) in sorted(self.probes.items())]


def search_min_steps(err_of_n: Callable[[int], float], n0: int, order: float, target: float,
                     rel: float = 0.03, max_probes: int = 10, budget_s: float = math.inf) -> Search:
    """Smallest step count N with ``err_of_n(N) <= target`` (to ``rel`` relative), assuming the
    error falls with N. ``n0`` is the first probe; the next ones are predicted from the method's
    order (aiming at 0.85·target, at most 8× per probe) until the target is bracketed, then the
    bracket is closed by bisection in log N. Two successive probes longer than ``budget_s``
    seconds stop the search."""
    out = Search()

    def E(n):
        return out.probe(max(2, int(n)), err_of_n)

    lo, hi = (None, n0) if E(n0) <= target else (n0, None)
    while (lo is None or hi is None) and len(out.probes) < max_probes and not out.slow(budget_s):
        ref = hi if lo is None else lo
        e_ref = out.probes[ref][0]
        if np.isfinite(e_ref) and e_ref > 0:
            pred = ref * (e_ref / (0.85 * target)) ** (1.0 / order)
        else:  # a failed run (Newton did not converge): try much smaller steps
            pred = 4.0 * ref
        pred = min(max(pred, ref / 8.0), ref * 8.0)
        if hi is None:
            n = max(int(math.ceil(pred)), int(ref * 1.05) + 1)
        else:
            n = min(int(pred), int(ref / 1.05))
            if n < 2:
                break
        if E(n) <= target:
            hi = n if hi is None else min(hi, n)
        else:
            lo = n if lo is None else max(lo, n)
    while lo is not None and hi is not None and hi > lo * (1 + rel) and hi - lo > 1 \
            and len(out.probes) < max_probes and not out.slow(budget_s):
        n = int(round(math.sqrt(lo * hi)))
        if n in (lo, hi):
            break
        if E(n) <= target:
            hi = n
        else:
            lo = n
    out.best = hi
    if hi is None:
        out.message = f"no N tried reached the target (largest tried {max(out.probes)})"
    return out


def search_tolerance(err_of_tol: Callable[[float], float], tol0: float, target: float, tol_min: float,
                     tol_max: float = 1e-3, factor: float = 1.5, max_probes: int = 12,
                     budget_s: float = math.inf) -> Search:
    """Largest tolerance with ``err_of_tol(tol) <= target``, found by steps of 10 from ``tol0``
    and bisection in log(tol) down to a ratio ``factor``. The error of an adaptive solver is not
    exactly monotone in its tolerance: this finds *a* largest passing tolerance of the bracket,
    as a user tuning it would."""
    out = Search()

    def E(tol):
        tol = float(f"{tol:.3g}")
        return out.probe(tol, err_of_tol), tol

    e, t = E(tol0)
    ok, bad = (t, None) if e <= target else (None, t)
    while (ok is None or bad is None) and len(out.probes) < max_probes and not out.slow(budget_s):
        if ok is None and bad <= tol_min or bad is None and ok >= tol_max:
            break
        e, t = E(max(bad / 10.0, tol_min) if ok is None else min(ok * 10.0, tol_max))
        if e <= target:
            ok = t
        else:
            bad = t
    while ok is not None and bad is not None and bad / ok > factor and len(out.probes) < max_probes \
            and not out.slow(budget_s):
        e, t = E(math.sqrt(ok * bad))
        if t in (ok, bad):
            break
        if e <= target:
            ok = t
        else:
            bad = t
    out.best = ok
    if ok is None:
        best_err = min(e for e, _ in out.probes.values())
        out.message = f"no tolerance down to {min(out.probes):g} reached the target (best error {best_err:.2e})"
    return out
