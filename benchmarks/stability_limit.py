"""The step-size limit of the Lobatto IIIA-IIIB step on a dissipative mode, and what it does
to adaptive runs (issue #10: the Chaplygin sleigh's error plateau at T = 1000).

Part 1 -- the amplification factor. On straight motion with speed v along x, the sleigh's
turning rate ω decays like ``exp(-k t)``, ``k = m a v / (I + m a²)`` (the constraint turns the
velocity into straight motion). One step of size h from ``ω₀ = 1e-6`` multiplies ω by
``R(h) = ω₁/ω₀``; the exact factor is ``exp(-k h)``. The scheme's R is unbounded (it grows
like h² here): |R(h)| > 1 beyond a step ``h*`` found by bisection, so steps above h* amplify
a mode that the exact flow damps.

Part 2 -- adaptive runs over [0, 1000]: once the sleigh moves straight, accuracy allows huge
steps, the controller grows h up to h* and then cycles around it; the turning mode is then
kept at the tolerance level instead of decaying, and the error at T no longer falls
monotonically with the tolerance. Capping the steps below h* (``max_step = 0.7 h*``)
restores it. Error: max |q(T) − q_exact(T)| (closed form).

    PYTHONPATH=src .venv/bin/python benchmarks/stability_limit.py [--quick]

Prints Markdown tables and writes ``benchmarks/results/stability_limit.json``.
"""

from __future__ import annotations

import math

import numpy as np

import lobattodae as L
from lib import cli
from lib.output import results_path, run_meta, write_json
from lobattodae.examples import get_example

EX = get_example("sleigh")
V, OMEGA0 = math.sqrt(2.0), 1e-6


def decay_rate() -> float:
    a = EX.args
    return a.m * a.a * V / (a.I + a.m * a.a**2)


def amplification(stages: int, h: float) -> float:
    """ω₁/ω₀ over one step from straight motion at speed V with a small turning rate ω₀."""
    a = EX.args
    q0 = np.zeros(3)
    p0 = np.array([a.m * V, a.m * a.a * OMEGA0, a.I * OMEGA0])
    lam0 = L.consistent_lambda(EX.problem, 0.0, q0, p0, np.zeros(1), a)
    _, p1, _, info, _ = L.LobattoIIIAIIIB(stages=stages).step(EX.problem, 0.0, q0, p0, lam0, h, a)
    assert int(info.result) == 0, f"step failed (s = {stages}, h = {h})"
    return float(p1[2] / p0[2])


def limit(stages: int, lo: float = 0.5, hi: float = 200.0) -> float:
    """The smallest h with |R(h)| = 1 (bisection on a bracket found by doubling)."""
    h = lo
    while abs(amplification(stages, h)) < 1.0:
        lo, h = h, 2 * h
        if h > hi:
            return math.inf
    hi = h
    for _ in range(30):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if abs(amplification(stages, mid)) < 1.0 else (lo, mid)
    return 0.5 * (lo + hi)


def adaptive_error(stages: int, tol: float, max_step: float | None, t_end: float) -> dict:
    q_exact = EX.exact(np.array([t_end]))[0][0]
    kw = {} if max_step is None else {"max_step": max_step}
    sol = L.solve(EX.problem, L.LobattoIIIAIIIB(stages=stages), (0.0, t_end), EX.q0, EX.p0, lam0=EX.lam0,
                  args=EX.args, rtol=tol, atol=tol, save_every="final", **kw)
    return {"err": float(np.max(np.abs(sol.q[-1] - q_exact))), "steps": int(sol.stats["n_steps"]),
            "rejected": int(sol.stats["n_rejected"]), "max_phi": float(sol.stats["max_constraint_residual"])}


def main() -> None:
    ns = cli.parser(__doc__, "quick", quick={"help": "s = 4 only, three tolerances"}).parse_args()
    k = decay_rate()
    meta = run_meta(decay_rate=k)
    stages = (4,) if ns.quick else (2, 3, 4, 5)
    hs = (1.0, 4.0, 8.0, 12.0, 16.0, 24.0, 50.0)
    print(f"Part 1: decay rate k = {k:.6f}; R(h) = ω₁/ω₀ against exp(-k h)\n")
    print("| s | " + " | ".join(f"h = {h:g}" for h in hs) + " | h* (|R| = 1) | k h* |")
    print("|---|" + "---|" * (len(hs) + 2))
    part1 = []
    for s in stages:
        rs = [amplification(s, h) for h in hs]
        h_star = limit(s)
        part1.append({"stages": s, "h": list(hs), "R": rs, "h_star": h_star})
        print(f"| {s} | " + " | ".join(f"{r:+.3g}" for r in rs) + f" | {h_star:.4g} | {k * h_star:.4g} |")
    print("| exact | " + " | ".join(f"{math.exp(-k * h):.3g}" for h in hs) + " | – | – |")

    tols = (1e-8, 1e-9, 1e-10) if ns.quick else (1e-8, 1e-9, 3.16e-10, 1e-10, 1e-11, 1e-12)
    t_end = 1000.0
    print(f"\nPart 2: adaptive solve on [0, {t_end:g}], rtol = atol = tol; error at T (steps)\n")
    print("| s | max_step | " + " | ".join(f"tol {t:.3g}" for t in tols) + " |")
    print("|---|---|" + "---|" * len(tols))
    part2 = []
    for row in part1:
        s = row["stages"]
        if s < 3:
            continue
        for cap in (None, 0.7 * row["h_star"]):
            runs = [adaptive_error(s, tol, cap, t_end) for tol in tols]
            part2.append({"stages": s, "max_step": cap, "tols": list(tols), "runs": runs})
            label = "none" if cap is None else f"{cap:.3g}"
            print(f"| {s} | {label} | " + " | ".join(f"{r['err']:.2e} ({r['steps']})" for r in runs) + " |")
    if not ns.quick:
        write_json({"meta": meta, "amplification": part1, "adaptive": part2}, results_path("stability_limit.json"))


if __name__ == "__main__":
    main()
