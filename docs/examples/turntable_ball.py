r"""A ball rolling on a rotating turntable: its centre moves on circles, at 2/7 of the table's rate.

A homogeneous ball (mass m, radius r, moment of inertia ``I = (2/5) m r²``) rolls without
slipping on a horizontal turntable that turns at the constant rate Ω about its centre. A
classical result (e.g. Neimark & Fufaev, *Dynamics of Nonholonomic Systems*; Weltner,
Am. J. Phys. 47 (1979) 984): whatever its initial velocity, the ball's centre moves on a
circle, at the angular rate ``ω_c = Ω I/(I + m r²) = 2Ω/7``, so it is back where it started
after ``T = 2π/ω_c = 7π/Ω``, three and a half turns of the table. It does not fly off the
table. If the table's centre also translates at a constant velocity V, the circle moves
along with it.

The model is :func:`lobattodae.mechanics.systems.turntable_ball`, built by
:func:`lobattodae.mechanics.from_lagrangian` from ``L = ½ m (ẋ² + ẏ²) + ½ I |ω|²`` with the
rolling constraints, which are affine and explicitly time dependent:

    ẋ − r ω_y − Vx + Ω (y − Vy t) = 0,      ẏ + r ω_x − Vy − Ω (x − Vx t) = 0.

Its coordinates are ``q = (x, y, α, β, γ)``: the centre and Tait–Bryan angles of the
orientation (singular at ``β = ±π/2``). The closed form
:func:`lobattodae.mechanics.systems.turntable_ball_centre` comes from the Newton–Euler
equations (``w = ẋ − V`` turns at the rate ω_c). Neither depends on m or r; the script takes
``m = r = 1`` and ``Ω = 1`` (lengths in units of r, times in units of 1/Ω) and keeps the
circles within a few tenths of r of the table's centre, so that the ball turns through
moderate angles and β stays far from π/2.

What is computed: five balls over one period T (constant steps, s = :data:`STAGES`), four
on a table turning in place and one on a table that also translates; for each, the largest
distance of the computed centre from the closed form over every step point, the distance from
its start (relative to the table's centre) after one period, ``max |φ|`` and ``max |β|``.

Run from the repository root::

    .venv/bin/python docs/examples/turntable_ball.py [--no-figure]

writes ``docs/figures/gallery/turntable-ball.png`` (not with ``--no-figure``, the tests'
run).
"""

from __future__ import annotations

import argparse
import math
import pathlib
import sys
import time
from typing import NamedTuple

import numpy as np

import lobattodae as L
from lobattodae.mechanics import systems

#: The table's rate (rad per unit time); m = r = 1.
OMEGA = 1.0
#: The centre's angular rate and its period: ω_c = 2Ω/7, T = 7π/Ω.
RATE = 2.0 * OMEGA / 7.0
PERIOD = 2.0 * math.pi / RATE
#: Stages and steps over one period.
STAGES, N_STEPS = 3, 500


class Ball(NamedTuple):
    """A ball's start: centre ``(x0, y0)``, velocity ``(vx0, vy0)`` of its centre, and the
    table's translation ``(Vx, Vy)``."""

    label: str
    x0: float
    y0: float
    vx0: float
    vy0: float
    Vx: float = 0.0
    Vy: float = 0.0


def _on_circle(label, centre, radius, angle, V=(0.0, 0.0)) -> Ball:
    """The start on the circle of ``radius`` about ``centre`` (relative to the table's centre
    at t = 0) at polar ``angle``, moving counter-clockwise at the rate ω_c."""
    e = np.array([math.cos(angle), math.sin(angle)])
    x0 = np.asarray(centre) + radius * e
    w0 = RATE * radius * np.array([-e[1], e[0]])
    return Ball(label, float(x0[0]), float(x0[1]), float(w0[0] + V[0]), float(w0[1] + V[1]), *V)


#: The balls: circles about the table's centre and off it; one placed at rest on the table
#: (moving with it, ``ẋ = Ω ẑ × x``), which circles a point on the far side of the centre;
#: and one on a table that also translates.
BALLS = (
    _on_circle("circle about the table's centre", (0.0, 0.0), 0.25, 0.0),
    _on_circle("circle off the centre", (0.1, 0.1), 0.15, math.pi),
    _on_circle("small circle off the centre", (-0.12, 0.05), 0.06, -math.pi / 2),
    Ball("placed at rest on the table", 0.03, -0.02, OMEGA * 0.02, OMEGA * 0.03),
    _on_circle("table translating at V", (0.08, 0.0), 0.2, math.pi / 2, V=(0.03, 0.01)),
)


class BallRun(NamedTuple):
    """One ball's run against the closed form."""

    ball: Ball
    t: np.ndarray
    xy: np.ndarray  # (N, 2) the computed centre
    exact: np.ndarray  # (N, 2) the closed form
    max_error: float  # max |computed − closed form| over every step point
    return_distance: float  # |x(T) − V T − x0|: back at the start, relative to the table's centre
    radius: float  # of the closed form's circle, |w0| / ω_c
    max_phi: float  # max |φ| over every step point
    max_beta: float  # max |β| (the chart is singular at π/2)


def initial_state(model, args, ball: Ball):
    """``(q0, p0)``: the centre at ``(x0, y0)``, orientation α = β = γ = 0, centre velocity
    ``(vx0, vy0)``, no spin about the vertical (γ̇ = ω_z = 0); α̇, β̇ from rolling."""
    q0 = np.array([ball.x0, ball.y0, 0.0, 0.0, 0.0])
    qdot0 = model.complete_velocities(0.0, q0, {"x": ball.vx0, "y": ball.vy0, "gamma": 0.0}, args)
    return q0, model.momenta(0.0, q0, qdot0, args)


def run_ball(model, method, ball: Ball, n_steps: int = N_STEPS) -> BallRun:
    """One period of ``ball`` with ``n_steps`` constant steps, against the closed form."""
    args = model.args(Omega=OMEGA, Vx=ball.Vx, Vy=ball.Vy)
    q0, p0 = initial_state(model, args, ball)
    sol = L.solve(model.problem, method, (0.0, PERIOD), q0, p0, n_steps=n_steps, args=args)
    x, y, _, _ = systems.turntable_ball_centre(sol.t, ball.x0, ball.y0, ball.vx0, ball.vy0, OMEGA, ball.Vx, ball.Vy)
    exact = np.column_stack([x, y])
    xy = np.asarray(sol.q[:, :2])
    back = xy[-1] - np.array([ball.Vx, ball.Vy]) * sol.t[-1] - np.array([ball.x0, ball.y0])
    radius = math.hypot(ball.vx0 - ball.Vx, ball.vy0 - ball.Vy) / RATE
    phi = np.abs(model.constraint_residual(sol.t, sol.q, sol.p, args)).max()
    return BallRun(ball, np.asarray(sol.t), xy, exact, float(np.max(np.abs(xy - exact))), float(np.hypot(*back)),
                   radius, float(phi), float(np.max(np.abs(sol.q[:, 3]))))


def main(figure: bool = True) -> list[BallRun]:
    """Integrate every ball of :data:`BALLS` over one period, print the checks and (with
    ``figure``) draw the figure."""
    start = time.perf_counter()
    model = systems.turntable_ball()
    built = time.perf_counter() - start
    method = L.LobattoIIIAIIIB(stages=STAGES)
    start = time.perf_counter()
    runs = [run_ball(model, method, ball) for ball in BALLS]
    print(f"ball on a turntable, Ω = {OMEGA}, one period T = 7π/Ω = {PERIOD:.6f}: s = {STAGES}, {N_STEPS} steps "
          f"(model built in {built:.1f} s, {len(runs)} runs in {time.perf_counter() - start:.1f} s, "
          f"compilation included)")
    for r in runs:
        print(f"  {r.ball.label}: circle radius {r.radius:.4f}; max |centre − closed form| = {r.max_error:.1e}, "
              f"after one period {r.return_distance:.1e} from its start; max |φ| = {r.max_phi:.1e}, "
              f"max |β| = {r.max_beta:.3f}")
    if figure:
        plot(runs)
        print(f"  figure: {FIGURE}")
    return runs


FIGURE = pathlib.Path(__file__).resolve().parents[1] / "figures" / "gallery" / "turntable-ball.png"


def plot(runs: list[BallRun], path: pathlib.Path = FIGURE) -> None:
    """(a) The centres' paths on the table turning in place; (b) the ball on the translating
    table; (c) the paths of (a) as seen on the turning table; (d) the distance from the
    closed form against time."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(2, 2, figsize=(10.5, 9.5), constrained_layout=True)
    (ax1, ax2), (ax3, ax4) = axes
    for k, r in enumerate(runs):
        colour = f"C{k}"
        moving = bool(r.ball.Vx or r.ball.Vy)
        ax = ax2 if moving else ax1
        ax.plot(r.xy[:, 0], r.xy[:, 1], "-", color=colour, lw=1.2, label=r.ball.label)
        ax.plot(r.exact[::25, 0], r.exact[::25, 1], "o", color=colour, ms=3.5, mfc="none")
        ax.plot(r.ball.x0, r.ball.y0, "^", color=colour, ms=8)
        ax.plot(r.xy[-1, 0], r.xy[-1, 1], "x", color="k", ms=6)
        if moving:
            table = np.outer(r.t, [r.ball.Vx, r.ball.Vy])
            ax2.plot(table[:, 0], table[:, 1], "k:", lw=1, label="the table's centre")
            # the closed form's circle is centred at x0 + ẑ × w0 / ω_c (w0 = ẋ0 − V), moving with V
            w0 = np.array([r.ball.vx0 - r.ball.Vx, r.ball.vy0 - r.ball.Vy])
            centre = np.array([r.ball.x0, r.ball.y0]) + np.array([-w0[1], w0[0]]) / RATE
            ax2.plot(*(centre + table).T, "--", color=colour, lw=0.8, label="the centre of the ball's circle")
        else:
            # on the table: rotate by −Ω t about the table's centre
            c, s = np.cos(-OMEGA * r.t), np.sin(-OMEGA * r.t)
            ax3.plot(c * r.xy[:, 0] - s * r.xy[:, 1], s * r.xy[:, 0] + c * r.xy[:, 1], "-", color=colour, lw=0.9)
            ax3.plot(r.ball.x0, r.ball.y0, "^", color=colour, ms=8)
        ax4.semilogy(r.t, np.maximum(np.hypot(*(r.xy - r.exact).T), 1e-17), "-", color=colour, lw=0.9,
                     label=r.ball.label)
    for ax in (ax1, ax2, ax3):
        ax.plot([0], [0], "k+", ms=12)
        ax.set_aspect("equal")
        ax.set_xlabel("x / r")
        ax.set_ylabel("y / r")
    ax1.set_xlim(-0.45, 0.45)
    ax1.set_ylim(-0.3, 0.45)
    ax1.legend(fontsize=8, loc="upper left", ncol=2)
    ax2.legend(fontsize=8, loc="upper left")
    ax2.set_ylim(-0.25, 0.65)
    ax1.set_title("(a) table turning in place: laboratory frame", fontsize=10)
    ax2.set_title("(b) table turning and translating at V = (0.03, 0.01) rΩ", fontsize=10)
    ax3.set_title("(c) the paths of (a) seen on the turning table", fontsize=10)
    ax4.set_title("(d) distance from the closed form", fontsize=10)
    ax4.set_xlabel("Ω t")
    ax4.set_ylabel("|centre − closed form| / r")
    ax4.set_ylim(1e-17, 1e-8)
    ax4.legend(fontsize=8, loc="upper left")
    fig.suptitle(f"A ball rolling on a turntable (lobattodae.mechanics.systems.turntable_ball), one period "
                 f"T = 7π/Ω, s = {STAGES}, {N_STEPS} steps\n"
                 "▲ start, × end of the run, ○ closed form, + the table's centre at t = 0", fontsize=10)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=100)
    plt.close(fig)


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description="a ball rolling on a turntable against the closed form")
    ap.add_argument("--no-figure", action="store_true", help="the tests' run: no figure")
    main(figure=not ap.parse_args().no_figure)
    sys.exit(0)
