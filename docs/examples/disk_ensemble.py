r"""An ensemble sweep: how far a tilted rolling disk leans, over a grid of speeds and tilts.

A thin disk rolls straight at speed v on a horizontal plane, started upright but for a small
tilt θ0 (no tilt rate, no turning). Above the critical speed v_c of upright rolling it wobbles
about a steady circular motion and its tilt stays of the order of θ0; below it upright rolling
is unstable and the tilt grows to a large angle, however small θ0 (the linear stability of
upright rolling is derived in ``docs/examples/disk_stability.py``). This script integrates
the whole grid (two bodies × speeds × initial tilts) in one call of
:func:`lobattodae.ensemble`, which vmaps the constant-step entry point ``integrate`` over the
trajectories; the inertias are batched parameters (``batch_args``), the initial values are
one row per trajectory. It records every step (``save="all"``) and reads off the largest
tilt of each run.

The model and the linear prediction
-----------------------------------
``get_example("falling-disk-general")``: ``q = (x, y, θ, φ, ψ)`` (contact point, tilt from
the vertical, heading, spin angle); mass m, radius R, inertias A about a diameter and C about
the axis. The linearised equations about upright rolling at ``ω = v/R`` (derived in
``disk_stability.py``, whose orientation convention gives θ the opposite sign to the model's;
that changes nothing below, which is about ``|θ|``) are

    (A + mR²) θ'' = (C + mR²) ω φ' + m g R θ,       A φ'' = −C ω θ'.

The second integrates to ``A φ' + C ω θ = A c`` with ``c = C ω θ0 / A`` for the start
``θ = θ0``, ``θ' = φ' = 0``. Then ``(A + mR²) θ'' = −K θ + (C + mR²) ω c`` with
``K = (C + mR²) C ω²/A − m g R``: for ``K > 0`` (``v > v_c``,
``v_c² = m g R³ A / (C (C + mR²))``) θ oscillates about

    θ* = (C + mR²) ω c / K = θ0 / (1 − v_c²/v²),

``θ(t) = θ* + (θ0 − θ*) cos νt``, and its largest value is ``2θ* − θ0``:

    max|θ| / θ0 = (v² + v_c²) / (v² − v_c²)        (v > v_c, small θ0),

a function of ``v/v_c`` alone, the same for every disk and ring. It diverges at v_c; below
v_c the tilt grows exponentially until the nonlinear terms take over (in this conservative
model, which neither slips nor dissipates, they stop it at a large angle and the disk rises
again: a large nutation instead of upright rolling). The nonlinear terms change the largest
tilt by a relative ``O(θ0²)``. The uniform disk
(A = mR²/4, C = mR²/2) has ``v_c² = gR/3``, the thin ring (A = mR²/2, C = mR²)
``v_c² = gR/4``.

What is computed
----------------
For each body, speed ``v = x v_c`` (x on :data:`SPEED_RATIOS`) and tilt θ0 (:data:`TILTS`),
the run over ``[0, T_END]`` with constant steps h (:data:`STAGES` stages); the largest
``|θ|`` over the step points, refined by the vertex of the parabola through the largest
sample and its two neighbours (the samples alone would miss the peak by up to
``(νh)²/8`` of the oscillation's amplitude); and ``max|θ| / θ0`` against the formula above.
A few trajectories are integrated again one by one with :func:`lobattodae.solve` and compared
with the ensemble's rows.

Run from the repository root::

    .venv/bin/python docs/examples/disk_ensemble.py [--short]

The full run writes ``docs/figures/gallery/disk-ensemble.png``; ``--short`` (the tests' run)
integrates a small grid and writes no figure.
"""

from __future__ import annotations

import argparse
import math
import pathlib
import sys
import time
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

import lobattodae as L
from lobattodae.examples import get_example

#: The disks: mass (kg), radius (m), gravity (m/s²).
MASS, RADIUS, GRAVITY = 1.0, 0.3, 9.81
#: The bodies of the sweep, inertias in units of m R² (about a diameter, about the axis).
BODIES = {"uniform disk": (0.25, 0.5), "thin ring": (0.5, 1.0)}
#: Speeds in units of each body's critical speed v_c (full run, short run).
SPEED_RATIOS = np.linspace(0.5, 2.5, 41)
SPEED_RATIOS_SHORT = np.array([0.7, 1.3, 2.0])
#: Initial tilts θ0 (rad; full run, short run).
TILTS = np.array([0.003, 0.03, 0.3])
TILTS_SHORT = np.array([0.003, 0.03])
#: Integration interval (s), step (s), stages. The peak of θ comes after half a period π/ν,
#: within T_END for v > 1.012 v_c (uniform disk; ν² = 4(3v² − gR)/(5R²)).
T_END, H, STAGES = 4.0, 0.01, 3
#: Speeds (units of v_c) from which the largest tilt is compared with the linear formula.
LINEAR_FROM = 1.2
#: Trajectories integrated again with ``solve``: (body, speed ratio, tilt).
SOLVE_CHECKS = (("uniform disk", 0.7, 0.003), ("thin ring", 1.3, 0.03), ("uniform disk", 2.0, 0.03))
FIGURE = pathlib.Path(__file__).resolve().parents[1] / "figures" / "gallery" / "disk-ensemble.png"


def critical_speed(inertia) -> float:
    """``v_c = √(m g R³ A / (C (C + mR²)))`` for inertias ``(A, C)`` in units of m R²."""
    a, c = inertia
    return math.sqrt(GRAVITY * RADIUS * a / (c * (c + 1.0)))


def linear_amplification(ratio):
    """``max|θ| / θ0 = (x² + 1) / (x² − 1)``, ``x = v/v_c > 1``: the small-tilt limit."""
    x2 = np.asarray(ratio, dtype=float) ** 2
    return (x2 + 1.0) / (x2 - 1.0)


class Grid(NamedTuple):
    """One row per trajectory of the sweep."""

    body: np.ndarray  # (B,) index into BODIES
    ratio: np.ndarray  # (B,) v / v_c
    speed: np.ndarray  # (B,) v (m/s)
    tilt: np.ndarray  # (B,) θ0 (rad)
    inertia1: np.ndarray  # (B,) A (kg m²)
    inertia3: np.ndarray  # (B,) C (kg m²)


def make_grid(ratios, tilts) -> Grid:
    """The product of :data:`BODIES`, ``ratios`` and ``tilts``, flattened."""
    names = list(BODIES)
    b, x, th = (g.ravel() for g in np.meshgrid(np.arange(len(names)), ratios, tilts, indexing="ij"))
    inertia = np.array([BODIES[n] for n in names])[b] * MASS * RADIUS**2
    speed = x * np.array([critical_speed(BODIES[n]) for n in names])[b]
    return Grid(b, x, speed, th, inertia[:, 0], inertia[:, 1])


def disk_example():
    """The ``falling-disk-general`` example with this script's mass, radius and gravity (its
    inertias are replaced per trajectory)."""
    return get_example("falling-disk-general", m=MASS, R=RADIUS, g=GRAVITY, theta0=0.0, Omega=0.0,
                       theta_rate0=0.0, spin_rate0=0.0)


def initial_state(problem, args, speed, tilt):
    """``(q0, p0, λ0)``: rolling straight along x at ``speed`` with tilt ``tilt``; the
    contact point's velocity follows the rolling constraint (φ = 0), λ0 the hidden one."""
    q0 = jnp.zeros(5).at[2].set(tilt)
    w = speed / args.R
    qdot0 = jnp.stack([args.R * w, 0.0 * w, 0.0 * w, 0.0 * w, w])
    p0 = problem.mass_matrix(0.0, q0, args) @ qdot0
    lam0 = L.consistent_lambda(problem, 0.0, q0, p0, jnp.zeros(2), args)
    return q0, p0, lam0


def batch_inputs(ex, grid: Grid):
    """Initial values (one row per trajectory), the batched ``args`` and ``batch_args``."""
    args = ex.args._replace(I1=grid.inertia1, I3=grid.inertia3)
    batch_args = type(ex.args)(m=False, R=False, g=False, I1=True, I3=True)

    def one(speed, tilt, i1, i3):
        return initial_state(ex.problem, ex.args._replace(I1=i1, I3=i3), speed, tilt)

    q0, p0, lam0 = jax.vmap(one)(grid.speed, grid.tilt, grid.inertia1, grid.inertia3)
    return np.asarray(q0), np.asarray(p0), np.asarray(lam0), args, batch_args


def peak(values: np.ndarray) -> np.ndarray:
    """The largest value of each row of ``values`` (B, N), refined by the vertex of the
    parabola through the largest sample and its neighbours (unrefined at the ends)."""
    k = np.nanargmax(values, axis=1)
    rows = np.arange(values.shape[0])
    best = values[rows, k]
    inner = (k > 0) & (k < values.shape[1] - 1)
    km, kp = np.clip(k - 1, 0, None), np.clip(k + 1, None, values.shape[1] - 1)
    y0, y1, y2 = values[rows, km], best, values[rows, kp]
    curv = y0 - 2.0 * y1 + y2
    with np.errstate(divide="ignore", invalid="ignore"):
        vertex = y1 - (y2 - y0) ** 2 / (8.0 * curv)
    return np.where(inner & (curv < 0), vertex, best)


class SolveCheck(NamedTuple):
    """One trajectory of the ensemble integrated again by ``lobattodae.solve``."""

    body: str
    ratio: float
    tilt: float
    max_difference: float  # max |q_ensemble − q_solve| over every step point


class SweepResult(NamedTuple):
    """What :func:`main` found."""

    grid: Grid
    status: np.ndarray  # (B,) Result code of each trajectory
    amplification: np.ndarray  # (B,) max|θ| / θ0 (refined peak)
    linear_error: np.ndarray  # (B,) |amplification − linear formula| / formula (NaN at v ≤ LINEAR_FROM v_c)
    max_phi: float  # max ‖φ‖∞ over every trajectory and step point
    solve_checks: list  # [SolveCheck]
    seconds: float  # wall time of the ensemble call (compilation included)
    t: np.ndarray  # (N,) the step points
    theta: np.ndarray  # (B, N) θ at every step point


def ensemble_run(ex, grid: Grid, method):
    """The sweep in one ``lobattodae.ensemble`` call; returns the result and its wall time."""
    q0, p0, lam0, args, batch_args = batch_inputs(ex, grid)
    n_steps = round(T_END / H)
    start = time.perf_counter()
    res = L.ensemble(ex.problem, method, q0, p0, lam0, args, batch_args=batch_args, h=H, n_steps=n_steps,
                     save="all")
    return res, time.perf_counter() - start


def constraint_residual(ex, grid: Grid, res) -> float:
    """max ‖φ‖∞ = max |G(q) f(q, p)| over the trajectories and their step points."""
    def phi(q, p, i1, i3):
        args = ex.args._replace(I1=i1, I3=i3)
        return ex.problem.constraint_matrix(0.0, q, args) @ ex.problem.f(0.0, q, p, args)

    per_row = jax.vmap(jax.vmap(phi, in_axes=(0, 0, None, None)))
    out = per_row(jnp.asarray(res.q), jnp.asarray(res.p), jnp.asarray(grid.inertia1), jnp.asarray(grid.inertia3))
    return float(jnp.nanmax(jnp.abs(out)))


def solve_check(ex, grid: Grid, res, method, body: str, ratio: float, tilt: float) -> SolveCheck:
    """Integrate the grid's trajectory (``body``, ``ratio``, ``tilt``) with ``lobattodae.solve``
    and compare its rows with the ensemble's."""
    b = list(BODIES).index(body)
    k = int(np.flatnonzero((grid.body == b) & np.isclose(grid.ratio, ratio) & np.isclose(grid.tilt, tilt))[0])
    args = ex.args._replace(I1=float(grid.inertia1[k]), I3=float(grid.inertia3[k]))
    q0, p0, _ = initial_state(ex.problem, args, float(grid.speed[k]), float(grid.tilt[k]))
    sol = L.solve(ex.problem, method, (0.0, T_END), q0, p0, n_steps=round(T_END / H), args=args)
    return SolveCheck(body, ratio, tilt, float(np.max(np.abs(sol.q - res.q[k]))))


def main(short: bool = False) -> SweepResult:
    """Run the sweep, check it, print it; the full run also draws the figure."""
    ex = disk_example()
    method = L.LobattoIIIAIIIB(stages=STAGES)
    grid = make_grid(SPEED_RATIOS_SHORT if short else SPEED_RATIOS, TILTS_SHORT if short else TILTS)
    res, seconds = ensemble_run(ex, grid, method)
    theta = np.abs(res.q[:, :, 2])
    amplification = peak(theta) / grid.tilt
    linear = np.where(grid.ratio >= LINEAR_FROM, linear_amplification(np.maximum(grid.ratio, LINEAR_FROM)), np.nan)
    linear_error = np.abs(amplification - linear) / linear
    checks = [solve_check(ex, grid, res, method, *c) for c in SOLVE_CHECKS
              if np.any(np.isclose(grid.ratio, c[1])) and np.any(np.isclose(grid.tilt, c[2]))]
    out = SweepResult(grid, res.status, amplification, linear_error, constraint_residual(ex, grid, res), checks,
                      seconds, np.arange(round(T_END / H) + 1) * H, res.q[:, :, 2])
    report(out)
    if not short:
        plot(out)
        print(f"figure: {FIGURE}")
    return out


def report(r: SweepResult) -> None:
    g = r.grid
    print(f"{g.ratio.size} trajectories ({len(BODIES)} bodies × {np.unique(g.ratio).size} speeds × "
          f"{np.unique(g.tilt).size} tilts), s = {STAGES}, h = {H}, {round(T_END / H)} steps each: "
          f"one ensemble call, {r.seconds:.1f} s (compilation included)")
    ok = r.status == L.Result.SUCCESSFUL
    print(f"  successful: {ok.sum()} of {ok.size}; max ‖φ‖∞ over every step point: {r.max_phi:.1e}")
    for b, name in enumerate(BODIES):
        print(f"  {name}: v_c = {critical_speed(BODIES[name]):.6f} m/s")
        for th in np.unique(g.tilt):
            sel = (g.body == b) & (g.tilt == th)
            above = sel & (g.ratio >= LINEAR_FROM)
            below = sel & (g.ratio < 1.0)
            line = f"    θ0 = {th:g}: "
            if above.any():
                line += (f"max|θ|/θ0 against (x² + 1)/(x² − 1) for v ≥ {LINEAR_FROM} v_c: relative difference "
                         f"≤ {np.max(r.linear_error[above]):.1e}")
            if below.any():
                line += f"; below v_c: max|θ| from {np.min(r.amplification[below] * th):.3f} rad"
            print(line)
    for c in r.solve_checks:
        print(f"  {c.body}, v = {c.ratio} v_c, θ0 = {c.tilt}: ensemble against solve, max |Δq| = "
              f"{c.max_difference:.1e}")


def plot(r: SweepResult, path: pathlib.Path = FIGURE) -> None:
    """Left: max|θ|/θ0 against v/v_c for each body and tilt, with the linear formula. Middle:
    its relative difference from the formula. Right: θ(t) of a few trajectories."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    g = r.grid
    tilts = np.unique(g.tilt)
    fig, (ax1, ax2, ax3) = plt.subplots(1, 3, figsize=(15, 4.6), constrained_layout=True)
    x = np.linspace(1.02, g.ratio.max(), 400)
    ax1.semilogy(x, linear_amplification(x), "k-", lw=1, label="(x² + 1)/(x² − 1), linear theory")
    for b, name in enumerate(BODIES):
        for j, th in enumerate(tilts):
            sel = (g.body == b) & (g.tilt == th)
            style = {"color": f"C{j}", "ms": 4 if b == 0 else 3, "mfc": "none" if b == 0 else f"C{j}"}
            ax1.semilogy(g.ratio[sel], r.amplification[sel], "os"[b], label=f"{name}, θ0 = {th:g}", **style)
            near = sel & (g.ratio > 1.0)
            diff = np.abs(r.amplification[near] / linear_amplification(g.ratio[near]) - 1.0)
            ax2.loglog(g.ratio[near] - 1.0, diff, "os"[b], **style)
    ax1.axvline(1.0, color="k", ls=":", lw=0.8)
    ax1.set_xlabel("speed x = v / v_c")
    ax1.set_ylabel(f"largest tilt over [0, {T_END:g} s]  /  θ0")
    ax1.set_ylim(1.0, 1e3)
    ax1.legend(fontsize=7.5, ncol=2, loc="upper right")
    ax1.set_title("every trajectory of the sweep (○ uniform disk, ■ thin ring)", fontsize=10)
    ax2.set_xlabel("x − 1")
    ax2.set_ylabel("relative difference from (x² + 1)/(x² − 1)")
    ax2.set_title("above v_c: the nonlinear terms, O(θ0²)", fontsize=10)

    b = list(BODIES).index("uniform disk")
    th = tilts[len(tilts) // 2]
    for j, ratio in enumerate((0.8, 0.95, 1.1, 1.5, 2.5)):
        k = np.flatnonzero((g.body == b) & (g.tilt == th) & np.isclose(g.ratio, ratio))
        if k.size:
            ax3.plot(r.t, r.theta[k[0]], color=f"C{j + 3}", lw=1, label=f"v = {ratio:g} v_c")
    ax3.set_xlabel("t (s)")
    ax3.set_ylabel("tilt θ (rad)")
    ax3.legend(fontsize=8, loc="upper left")
    ax3.set_title(f"uniform disk, θ0 = {th:g} rad", fontsize=10)
    fig.suptitle(f"Rolling disks started with a tilt: {g.ratio.size} trajectories in one lobattodae.ensemble call "
                 f"(R = {RADIUS} m, s = {STAGES}, h = {H} s)", fontsize=10)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=100)
    plt.close(fig)


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description="ensemble sweep of the tilted rolling disk")
    ap.add_argument("--short", action="store_true", help="the short run of the tests (no figure)")
    main(ap.parse_args().short)
    sys.exit(0)
