"""The statements of the verification report that depend on its data, decided from the data.

Each function reads the JSON data of :mod:`.runs` (nothing else) and returns booleans,
categories and the derived numbers they rest on; the template words them. The thresholds
of these decisions are the named constants below, which the template quotes.
"""

from __future__ import annotations

import itertools
import math

import numpy as np

COMPONENTS = ("q", "p", "lam")
#: An observed order more than this from its expectation is a deviation.
ORDER_TOL = 0.3
#: A quantity of a long run stays bounded when its maximum over the last tenth is at most
#: BOUNDED times that over the first tenth; for the energy error of the reversible oscillator,
#: the fitted linear drift must also accumulate over the run to less than NO_DRIFT of max |ΔH|.
BOUNDED = 1.5
NO_DRIFT = 0.05
#: A quantity grows (drifts) when its last tenth exceeds GROWS times its first tenth.
GROWS = 3.0
#: A drift is close to linear when the energy gained per tenth varies by at most this factor.
LINEAR = 2.0
#: The q/p floor should be at least FLOOR_MARGIN times the measured round-off level.
FLOOR_MARGIN = 3.0
#: The round-off level is read from the runs with ROUNDOFF_STAGES stages and h <= T/ROUNDOFF_STEPS,
#: where the truncation error is many orders below eps.
ROUNDOFF_STAGES = 6
ROUNDOFF_STEPS = 32
#: Errors of O(1) quantities below this are at round-off (exact components, exact steps).
EXACT = 1e-12
#: The odd-step λ error of the knife edge matches its prediction within ATOL + RTOL·|prediction|.
PREDICTION_ATOL, PREDICTION_RTOL = 1e-9, 1e-6
#: The vertical disk's p_θ orders follow "2s for even s, 2s − 2 for odd s" within this.
PATTERN_TOL = 0.5
#: How many of the finest local slopes above the floor a reading of an order looks at.
FINEST = 4
#: Local slopes that rise towards the theory may dip by this much from one pair to the next,
#: and settle when the last is within SETTLED of the theory.
RISE_SLACK, SETTLED = 0.05, 0.5
#: 'auto' succeeds on the sleigh when its q error at T is within AUTO_NEAR times that of
#: 'consistent' (or below AUTO_FLOOR relative to ‖q(T)‖), at least AUTO_GAIN times below
#: that of 'previous', after at least one reset; below ROUNDOFF_REL relative it is round-off.
AUTO_NEAR, AUTO_FLOOR, AUTO_GAIN, ROUNDOFF_REL = 10.0, 1e-12, 100.0, 1e-13
#: H(T) of the reversible oscillator within this of H_y: only the y oscillator's energy is left.
ENERGY_MATCH = 0.02
#: A multiplier drift above this is not "close to the hidden constraint".
FAR_DRIFT = 1.0


def number(x) -> float:
    """A JSON number (None for NaN or ±inf) as a float."""
    return float("nan") if x is None else float(x)


def local_slopes(h, err) -> np.ndarray:
    """Slope of log(err) against log(h) between consecutive entries (NaN where an error is 0)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.diff(np.log(np.asarray(err, float))) / np.diff(np.log(np.asarray(h, float)))


# ------------------------------------------------------------------- convergence orders
def order_verdict(observed: float, generic: int, documented: bool, doc) -> str:
    """'ok': within ORDER_TOL of the generic theory; 'documented': a special case of the
    example's expected_order_overrides, matched (``doc`` None: exact, no order measurable);
    'deviation': neither."""
    if documented:
        matched = not math.isfinite(observed) if doc is None else (
            math.isfinite(observed) and abs(observed - doc) <= ORDER_TOL)
        return "documented" if matched else "deviation"
    return "ok" if math.isfinite(observed) and abs(observed - generic) <= ORDER_TOL else "deviation"


def entries(data):
    """Every (example, s, component) of the studies with its observed order and verdict."""
    for name, record in data["studies"].items():
        for s in record["study"]["stages"]:
            run = record["study"]["runs"][str(s)]
            for c in COMPONENTS:
                table = record["overrides"].get(c, {})
                observed = number(run["observed_order"][c])
                generic = data["library"]["orders"][str(s)][c]
                documented = str(s) in table
                doc = table.get(str(s))
                yield {"name": name, "s": s, "c": c, "observed": observed, "generic": generic,
                       "documented": documented, "doc": doc,
                       "expected": doc if documented else generic,  # None: exact
                       "verdict": order_verdict(observed, generic, documented, doc)}


def study_rows(data, name):
    """The rows of an example's table: per s, the entries and the runs' extent."""
    record = data["studies"][name]
    by_s = {}
    for e in entries(data):
        if e["name"] == name:
            by_s.setdefault(e["s"], []).append(e)
    rows = []
    for s, cells in by_s.items():
        run = record["study"]["runs"][str(s)]
        rows.append({"s": s, "cells": cells, "residual": run["max_constraint_residual"],
                     "n_first": run["n_steps"][0], "n_last": run["n_steps"][-1], "runs": len(run["n_steps"])})
    return rows


def error_rows(data, name):
    """Every error of an example's study with its local slope and whether it is above the floor."""
    study = data["studies"][name]["study"]
    out = []
    for s in study["stages"]:
        run = study["runs"][str(s)]
        cols = {}
        for c in COMPONENTS:
            e = np.asarray(run["errors"][c], float)
            slopes = [None, *local_slopes(run["h"], e)]  # None: no previous row
            cols[c] = [{"error": e[i], "above": bool(e[i] > study["floors"][c]), "slope": slopes[i]}
                       for i in range(e.size)]
        out.append({"s": s, "rows": [{"n": n, "h": h, "cells": [cols[c][i] for c in COMPONENTS]}
                                     for i, (n, h) in enumerate(zip(run["n_steps"], run["h"]))]})
    return out


def finest_above(data, name, s, c, floor) -> int:
    """The largest step count of one entry whose error is above ``floor``."""
    run = data["studies"][name]["study"]["runs"][str(s)]
    return int(np.max(np.asarray(run["n_steps"])[np.asarray(run["errors"][c], float) > floor]))


def slope_pairs(data, name, s, c):
    """The local slopes between consecutive step counts whose errors are both above the
    floor, coarse to fine, with the step sizes and the finer error of each pair."""
    study = data["studies"][name]["study"]
    run = study["runs"][str(s)]
    e = np.asarray(run["errors"][c], float)
    above = e > study["floors"][c]
    slopes = local_slopes(run["h"], e)
    return [{"n0": run["n_steps"][i], "n1": run["n_steps"][i + 1], "h0": run["h"][i], "h1": run["h"][i + 1],
             "error": e[i + 1], "slope": slopes[i]} for i in range(len(slopes)) if above[i] and above[i + 1]]


def generic_reading(data, name, s, c, expected):
    """What the last FINEST local slopes above the floor say about a deviation: 'too-few'
    of them, a 'plateau' (the errors do not decrease), 'flattening' (slopes falling towards
    the finest steps), 'bracketed' (the slopes bracket the theory: the fitted order is within
    their scatter) or 'unexplained'."""
    pairs = slope_pairs(data, name, s, c)[-FINEST:]
    if len(pairs) < 2:
        return {"kind": "too-few"}
    slopes = [p["slope"] for p in pairs]
    lo, hi = min(slopes), max(slopes)
    reading = {"slopes": slopes, "lo": lo, "hi": hi, "level": min(p["error"] for p in pairs),
               "floor": data["studies"][name]["study"]["floors"][c],
               "h_max": pairs[0]["h0"], "h_min": pairs[-1]["h1"], "expected": expected}
    if hi < 1.0:
        return {**reading, "kind": "plateau"}
    if slopes[-1] == lo and lo < expected - 1.0:
        return {**reading, "kind": "flattening"}
    if lo <= expected <= hi:
        return {**reading, "kind": "bracketed"}
    return {**reading, "kind": "unexplained"}


def deviation_reading(data, entry, special):
    """The reading of a deviation: the special case of §2 that explains it, where there is
    one and its own check holds, else :func:`generic_reading`."""
    key = (entry["name"], entry["s"], entry["c"])
    knife, disk, particle = special["knife_edge"], special["vertical_disk"], special["particle"]
    if key == ("knife-edge", 2, "lam") and knife and knife["confirmed"]:
        return {"kind": "knife-edge"}
    if key[0] == "vertical-disk" and key[2] == "p" and key[1] % 2 == 0 and disk and disk["pattern"]:
        return {"kind": "even-s"}
    if key == ("particle", 5, "p") and particle and particle["confirmed"]:
        return {"kind": "pre-asymptotic"}
    return generic_reading(data, *key, entry["generic"] if entry["expected"] is None else entry["expected"])


def deviations(data, special):
    return [{**e, "pairs": slope_pairs(data, e["name"], e["s"], e["c"]),
             "reading": deviation_reading(data, e, special)}
            for e in entries(data) if e["verdict"] == "deviation"]


def step_counts(data):
    """Which numbers of stages use the library's default step counts, and the explicit lists."""
    counts = data["settings"]["counts"]
    return {"default": [s for s in data["settings"]["stages"] if counts[str(s)] is None],
            "explicit": {s: counts[str(s)] for s in data["settings"]["stages"] if counts[str(s)] is not None}}


def order_counts(data):
    verdicts = [e["verdict"] for e in entries(data)]
    return {"total": len(verdicts), "ok": verdicts.count("ok"),
            "documented": [e for e in entries(data) if e["verdict"] == "documented"]}


def order_difference(a: float, b: float) -> float:
    """|a − b| for two observed orders; 0 when neither is measurable, inf when one is not."""
    if math.isfinite(a) and math.isfinite(b):
        return abs(a - b)
    return 0.0 if math.isfinite(a) == math.isfinite(b) else math.inf


def auto_agreement(data):
    """The convergence runs repeated with 'auto' against those with 'previous'."""
    autos = {name: r["auto"] for name, r in data["studies"].items()}
    if not autos:
        return None
    diffs = [order_difference(number(r["study"]["runs"][str(s)]["observed_order"][c]),
                              number(r["auto"]["observed"][str(s)][c]))
             for r in data["studies"].values() for s in r["study"]["stages"] for c in COMPONENTS]
    runs = sum(a["runs"] for a in autos.values())
    identical = sum(a["identical"] for a in autos.values())
    return {"runs": runs, "identical": identical, "all_identical": identical == runs,
            "per_example": [{"name": n, "identical": a["identical"], "runs": a["runs"]} for n, a in autos.items()],
            "max_rel_diff": max(a["max_rel_diff"] for a in autos.values()),
            "excursion_runs": sum(len(r["warnings"]) for r in data["studies"].values()),
            "max_order_diff": max(diffs), "orders_same": max(diffs) == 0.0,
            "wall": sum(a["wall"] for a in autos.values())}


def roundoff(data):
    """The round-off level of q and p: the largest error of the runs with ROUNDOFF_STAGES
    stages and h <= T/ROUNDOFF_STEPS; and the smallest ratio of an example's floor to it."""
    levels = {}
    for name, record in data["studies"].items():
        run = record["study"]["runs"].get(str(ROUNDOFF_STAGES))
        if run is None:
            continue
        h = np.asarray(run["h"], float)
        fine = h <= h[0] * run["n_steps"][0] / ROUNDOFF_STEPS * (1 + 1e-12)
        if np.any(fine):
            levels[name] = {c: float(np.max(np.asarray(run["errors"][c], float)[fine])) for c in ("q", "p")}
    if not levels:
        return None
    ratio, name, c = min((data["studies"][n]["study"]["floors"][c] / lv[c], n, c)
                         for n, lv in levels.items() for c in ("q", "p"))
    return {"q": max(lv["q"] for lv in levels.values()), "p": max(lv["p"] for lv in levels.values()),
            "ratio": ratio, "name": name, "c": c, "enough": ratio >= FLOOR_MARGIN}


def convergence_runs(data):
    """The number of convergence runs and their largest constraint residual."""
    runs = [r for record in data["studies"].values() for r in record["study"]["runs"].values()]
    return {"count": sum(len(r["n_steps"]) for r in runs),
            "max_residual": max((r["max_constraint_residual"] for r in runs), default=math.nan)}


# ----------------------------------------------------------------------- special cases
def knife_edge(data):
    """λ of the knife edge with s = 2: exact at even steps, the predicted constant at odd ones."""
    rows = data["knife_edge"]
    if rows is None:
        return None
    even_exact = all(r["even_max"] < EXACT for r in rows)
    odd_match = all(abs(r[k] - r["predicted"]) <= PREDICTION_ATOL + PREDICTION_RTOL * r["predicted"]
                    for r in rows for k in ("odd_min", "odd_max"))
    observed = number(data["studies"]["knife-edge"]["study"]["runs"]["2"]["observed_order"]["lam"])
    return {"rows": rows, "even_exact": even_exact, "odd_match": odd_match, "confirmed": even_exact and odd_match,
            "observed": observed, "documented": "2" in data["studies"]["knife-edge"]["overrides"].get("lam", {})}


def vertical_disk(data):
    """The vertical disk's p_θ orders: 2s for even s, 2s − 2 for odd s; φ and p_φ exact."""
    disk = data["vertical_disk"]
    if disk is None:
        return None
    names = disk["names"]
    at = {x: names.index(x) for x in ("φ", "p_φ", "p_θ")}
    p_theta = {r["s"]: number(r["order"][at["p_θ"]]) for r in disk["rows"]}
    even = [s for s in p_theta if s % 2 == 0]
    odd = [s for s in p_theta if s % 2 == 1]
    even_2s = all(abs(p_theta[s] - 2 * s) <= PATTERN_TOL for s in even)
    odd_regular = all(abs(p_theta[s] - data["library"]["orders"][str(s)]["p"]) <= PATTERN_TOL for s in odd)
    exact = all(r["e1"][at["φ"]] < EXACT and r["e1"][at["p_φ"]] < EXACT for r in disk["rows"])
    flagged = [e for e in entries(data) if e["name"] == "vertical-disk" and e["c"] == "p"
               and e["s"] % 2 == 0 and e["verdict"] == "deviation"]
    return {"names": names, "rows": disk["rows"], "p_theta": p_theta, "even": even, "odd": odd,
            "even_2s": even_2s, "odd_regular": odd_regular, "exact": exact,
            "pattern": even_2s and odd_regular and exact, "flagged": flagged,
            "listed": sorted(int(s) for s in data["studies"]["vertical-disk"]["overrides"].get("p", {}))}


def particle(data):
    """The particle's p with s = 5: the local slopes above the floor rise towards the theory
    at the finest steps (pre-asymptotic behaviour), or not."""
    refit = data["particle_default_floor"]
    if refit is None:
        return None
    expected = data["library"]["orders"]["5"]["p"]
    pairs = slope_pairs(data, "particle", 5, "p")
    finest = [p["slope"] for p in pairs[-FINEST:]]
    rising = len(finest) >= 3 and all(b >= a - RISE_SLACK for a, b in itertools.pairwise(finest))
    settles = bool(finest) and abs(finest[-1] - expected) < SETTLED
    study = data["studies"]["particle"]["study"]
    observed = number(study["runs"]["5"]["observed_order"]["p"])
    return {"expected": expected, "pairs": pairs, "finest": finest, "rising": rising,
            "confirmed": rising and settles, "falls_short": observed < expected,
            "coarse_max": max((p["slope"] for p in pairs), default=math.nan), "observed": observed,
            "last_n": finest_above(data, "particle", 5, "p", study["floors"]["p"]),
            "default": {"rel": data["library"]["plateau_rel"]["p"], "observed": number(refit["observed"]),
                        "last_n": finest_above(data, "particle", 5, "p", refit["floor"])}}


# ----------------------------------------------------------------------------- long runs
def energy_shape(r):
    """How the energy of a drifting run grows: the gain per tenth, linear or not."""
    gains = np.diff(np.asarray(r["tenths"], float))
    lo, hi = float(np.min(gains)), float(np.max(gains))
    return {"linear": lo > 0 and hi / lo <= LINEAR, "lo": lo, "hi": hi, "largest": int(np.argmax(gains)) + 1,
            "parts": gains.size}


def coarse_and_fine(data, name):
    """The long runs of ``name`` with the larger and the smaller step (None where missing)."""
    by = {(r["name"], r["N"]): r for r in data["long_runs"]}
    return tuple(by.get((name, N)) for N in data["settings"]["long_n"])


def reversible_energy(data):
    """The reversible oscillator: bounded energy error, and its order in h."""
    r, fine = coarse_and_fine(data, "contact")
    if r is None:
        return None
    accumulated = abs(r["slope"]) * r["T"]
    out = {"run": r, "accumulated": accumulated, "relative": accumulated / r["max_dH"],
           "bounded": r["last10"] <= BOUNDED * r["first10"] and accumulated / r["max_dH"] < NO_DRIFT,
           "finer": None}
    if fine is not None:
        ratio = r["max_dH"] / fine["max_dH"]
        out["finer"] = {"run": fine, "ratio": ratio, "order": math.log(ratio) / math.log(r["h"] / fine["h"])}
    return out


def nonreversible_energy(data):
    """The non-reversible oscillator: the energy drifts, and the drift rate's order in h."""
    r, fine = coarse_and_fine(data, "contact-nonreversible")
    if r is None:
        return None
    out = {"run": r, "drifts": r["last10"] > GROWS * r["first10"], "shape": energy_shape(r),
           "percent": 100 * r["final_dH"] / r["H0"], "finer": None}
    if fine is not None:
        ratio = r["slope_first"] / fine["slope_first"]
        out["finer"] = {"run": fine, "ratio": ratio, "shape": energy_shape(fine),
                        "order": math.log(ratio) / math.log(r["h"] / fine["h"]) if ratio > 0 else math.nan}
    return out


def constraints(data):
    """The constraint residual and the decoupled oscillator's energy H_y over the long runs."""
    max_phi = max(r["max_phi"] for r in data["long_runs"])
    return {"max_phi": max_phi, "at_roundoff": max_phi < EXACT,
            "max_dHy": max(r["max_dHy"] for r in data["long_runs"])}


def multiplier_drift(data):
    """The multiplier's distance from the hidden constraint over the long runs, and where
    'auto' re-synchronised it."""
    runs = data["long_runs"]
    reset = [r for r in runs if r["lam_resets"]]
    return {"grows": [r for r in runs if r["lam_drift_last10"] > GROWS * r["lam_drift_first10"]],
            "reset": reset, "none_on_reversible": bool(reset) and not any(r["name"] == "contact" for r in reset)}


# ------------------------------------------------------------------------------ λ modes
def bitwise(r, previous) -> str | None:
    """'same' or 'different' from the 'previous' run of the same configuration; None for
    the 'previous' run itself or where there is none."""
    if r["lam_start"] == "previous" or previous is None:
        return None
    return "same" if r["digest"] == previous["digest"] else "different"


def contact_table(data):
    """The rows of the λ-mode contact table, in the library's order of the modes."""
    modes = {r["lam_start"]: r for r in data["lam_modes"]["contact"]}
    return [{"run": modes[m], "bitwise": bitwise(modes[m], modes.get("previous"))}
            for m in data["library"]["lam_start_modes"] if m in modes]


def variant_table(data):
    """The long runs in every mode: per example and step size, the modes in the library's order."""
    by = {(r["name"], r["N"], r["lam_start"]): r for r in data["long_runs"] + data["variant_runs"]}
    return [{"run": by[(name, N, m)], "bitwise": bitwise(by[(name, N, m)], by.get((name, N, "previous")))}
            for name in dict.fromkeys(r["name"] for r in data["long_runs"])
            for N in data["settings"]["long_n"] for m in data["library"]["lam_start_modes"] if (name, N, m) in by]


def reversible_class(data):
    """'auto' on the reversible oscillator: no reset, bitwise the paper's scheme, bounded
    energy; and where 'consistent' ends."""
    modes = {r["lam_start"]: r for r in data["lam_modes"]["contact"]}
    a, p, c = (modes.get(m) for m in ("auto", "previous", "consistent"))
    if not (a and p):
        return None
    same = a["digest"] == p["digest"]
    bounded = a["last10"] <= BOUNDED * a["first10"]
    out = {"auto": a, "previous": p, "consistent": c, "same": same, "bounded": bounded,
           "confirmed": a["lam_resets"] == 0 and same and bounded, "consistent_end": None}
    if c is not None:
        H_T = c["H0"] + c["final_dH"]
        out["consistent_end"] = {"H_T": H_T, "only_y": abs(H_T - c["Hy0"]) < ENERGY_MATCH}
    return out


def sleigh_configs(data):
    """Per sleigh configuration: does 'auto' reach the error of 'consistent', far below that
    of 'previous', with resets; and how the drift behaves around the resets."""
    out = []
    runs = data["lam_modes"]["sleigh"]
    for s, h, T in dict.fromkeys((r["s"], r["h"], r["T"]) for r in runs):
        modes = {r["lam_start"]: r for r in runs if (r["s"], r["h"], r["T"]) == (s, h, T)}
        a, p, c = (modes.get(m) for m in ("auto", "previous", "consistent"))
        if not (a and p and c):
            continue
        relative = a["q_err_T"] / a["q_scale_T"]
        near = a["q_err_T"] <= max(AUTO_NEAR * c["q_err_T"], AUTO_FLOOR * a["q_scale_T"])
        gain = p["q_err_T"] / max(a["q_err_T"], np.finfo(float).tiny)
        out.append({"s": s, "h": h, "T": T, "auto": a, "previous": p, "consistent": c,
                    "relative": relative, "gain": gain, "roundoff": relative <= ROUNDOFF_REL,
                    "confirmed": near and gain >= AUTO_GAIN and a["lam_resets"] > 0,
                    "resets": list(zip(a["drift_before_reset"], a["drift_after_reset"])),
                    "intervals": np.diff([0.0, *a["resync_t"]]).tolist()})
    return out


def nonreversible_modes(data):
    """The three modes on the non-reversible oscillator, per step size where 'auto' resets,
    its drift grows or 'previous' stops."""
    by = {(r["name"], r["N"], r["lam_start"]): r for r in data["long_runs"] + data["variant_runs"]}
    out = []
    for N in data["settings"]["long_n"]:
        a, p, c = (by.get(("contact-nonreversible", N, m)) for m in ("auto", "previous", "consistent"))
        if not (a and p and c):
            continue
        gain = a["lam_drift_last10"] / a["lam_drift_first10"]
        grows = gain > GROWS
        if grows or a["lam_resets"] or not p["success"]:
            out.append({"auto": a, "previous": p, "consistent": c, "gain": gain, "grows": grows,
                        "lam_grows": a["lam_max_last10"] > BOUNDED * a["lam_max_first10"],
                        "far": a["lam_drift_last10"] > FAR_DRIFT})
    return out


def consistent_on_reversible(data):
    """'consistent' on the reversible oscillator: the runs whose energy error grows."""
    runs = [r for r in data["variant_runs"] if r["name"] == "contact" and r["lam_start"] == "consistent"]
    return {"runs": runs, "grows": [r for r in runs if r["last10"] > GROWS * r["first10"]]}


def findings(data) -> dict:
    """Every data-dependent statement of the report, decided from ``data``."""
    special = {"knife_edge": knife_edge(data), "vertical_disk": vertical_disk(data), "particle": particle(data)}
    return {
        **special,
        "studies": {n: {"rows": study_rows(data, n), "errors": error_rows(data, n)} for n in data["studies"]},
        "orders": order_counts(data),
        "step_counts": step_counts(data),
        "deviations": deviations(data, special),
        "auto": auto_agreement(data),
        "roundoff": roundoff(data),
        "convergence_runs": convergence_runs(data),
        "reversible": reversible_energy(data),
        "nonreversible": nonreversible_energy(data),
        "constraints": constraints(data),
        "multiplier_drift": multiplier_drift(data),
        "reversible_class": reversible_class(data),
        "sleigh": sleigh_configs(data),
        "nonreversible_modes": nonreversible_modes(data),
        "consistent_on_reversible": consistent_on_reversible(data),
        "contact_table": contact_table(data),
        "variant_table": variant_table(data),
    }
