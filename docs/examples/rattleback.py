r"""The rattleback: spun one way it rocks and reverses its spin; spun the other way it keeps it longer.

A rattleback (celt) is a rigid body with a smooth convex bottom whose principal axes of
inertia are turned, about the vertical, against the principal axes of curvature of the
bottom. Spun about the vertical in its "wrong" sense, it soon starts to pitch, the spin
dies, and it spins up the other way; spun in its preferred sense it keeps turning much
longer. The mechanism is the rolling contact, a nonholonomic constraint: the contact point
moves over the bottom as the body rocks, and the contact force converts rocking into spin
and spin into rocking (Walker 1896; Garcia & Hubbard, Proc. R. Soc. A 418 (1988) 165–197).

The model is :func:`lobattodae.mechanics.systems.rattleback`: an ellipsoid-bottomed body
(semi-axes a, b, c, centre of mass h below the ellipsoid's centre, central inertia
``[[A, D, 0], [D, B, 0], [0, 0, C]]``; ``D ≠ 0`` turns the axes of inertia) that rolls without
slipping on a horizontal plane, built by :func:`lobattodae.mechanics.from_lagrangian` with the
orientation as a unit quaternion (``q = (x, y, Q0..Q3)``, the norm kept as a holonomic
constraint). Its parameters default to the rattleback of Kane & Levinson (1982)
(:data:`lobattodae.mechanics.systems.RATTLEBACK_KANE_LEVINSON`). There is no slip and no
friction, so the energy is conserved: the integrator's energy error measures its accuracy.

What is computed: two runs from the same slightly tilted start (:data:`ROLL_DEG` of roll and
:data:`PITCH_DEG` of pitch, at rest but for the spin), spun at ``±SPIN`` rad/s about the
vertical, over ``[0, T_END]`` with constant steps h (Lobatto IIIA–IIIB, :data:`STAGES`
stages). For each: the spin ``ω·e_z`` (the angular velocity's vertical component) at every
step point, the first time its sign changes (linear interpolation between step points), the
tilt of the body (the angle of its z axis from the vertical), the energy error, the largest
``‖φ‖∞`` of the rolling constraints and ``|Q·Q − 1|``.

Run from the repository root::

    .venv/bin/python docs/examples/rattleback.py [--short]

The full run (2 × 20 s, 4·10⁴ steps) writes ``docs/figures/gallery/rattleback.png``;
``--short`` (the tests' run) integrates 4 s of each and writes no figure.
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
from lobattodae.mechanics import (
    body_angular_velocity,
    quaternion_from_axis_angle,
    quaternion_multiply,
    rotation_matrix,
    systems,
)

#: Initial roll and pitch (degrees) and the spin about the vertical (rad/s), in both senses.
ROLL_DEG, PITCH_DEG, SPIN = 0.5, 0.5, 5.0
#: Interval (s), full and short run; step (s); stages. The body rocks at about 100 rad/s, so
#: h = 1e-3 resolves it with about 60 steps per rocking period.
T_END, T_END_SHORT, H, STAGES = 20.0, 4.0, 1e-3, 3
FIGURE = pathlib.Path(__file__).resolve().parents[1] / "figures" / "gallery" / "rattleback.png"


class SpinRun(NamedTuple):
    """One run of the rattleback."""

    spin0: float  # the initial spin about the vertical (rad/s)
    t: np.ndarray  # (N,) step points
    spin: np.ndarray  # (N,) ω·e_z (rad/s)
    tilt: np.ndarray  # (N,) angle of the body's z axis from the vertical (rad)
    energy_error: np.ndarray  # (N,) H(t) − H(0) (J)
    energy0: float  # H(0) (J)
    first_reversal: float  # first sign change of the spin (s); inf if none
    max_phi: float  # max ‖φ‖∞ over every step point
    max_norm_error: float  # max |Q·Q − 1| over every step point
    seconds: float  # wall time of the solve (compilation included in the first run)


def tilted_start():
    """The initial orientation: roll ``ROLL_DEG`` about x, then pitch ``PITCH_DEG`` about y."""
    return quaternion_multiply(quaternion_from_axis_angle([1.0, 0.0, 0.0], math.radians(ROLL_DEG)),
                               quaternion_from_axis_angle([0.0, 1.0, 0.0], math.radians(PITCH_DEG)))


def first_sign_change(t: np.ndarray, x: np.ndarray) -> float:
    """The first zero of ``x(t)`` where it leaves the sign of ``x[0]``, by linear interpolation
    between the samples around it; ``inf`` if ``x`` keeps its sign."""
    flipped = np.flatnonzero(np.sign(x) != np.sign(x[0]))
    if flipped.size == 0:
        return math.inf
    k = int(flipped[0])
    return float(t[k - 1] - x[k - 1] * (t[k] - t[k - 1]) / (x[k] - x[k - 1]))


def spin_run(model, args, method, spin0: float, t_end: float) -> SpinRun:
    """Integrate the rattleback from :func:`tilted_start`, spun at ``spin0`` about the
    vertical, over ``[0, t_end]`` with steps :data:`H`."""
    Q0 = tilted_start()
    w0_body = rotation_matrix(Q0).T @ np.array([0.0, 0.0, spin0])
    q0, p0 = systems.rattleback_state(model, args, Q0, w0_body)
    start = time.perf_counter()
    sol = L.solve(model.problem, method, (0.0, t_end), q0, p0, n_steps=round(t_end / H), args=args)
    seconds = time.perf_counter() - start
    Q = np.asarray(sol.q[:, 2:6])
    qdot = model.velocities(sol.t, sol.q, sol.p, args)
    R = rotation_matrix(Q)
    w_space = np.einsum("nij,nj->ni", R, body_angular_velocity(Q, qdot[:, 2:6]))
    energy = model.energy(sol.t, sol.q, sol.p, args)
    phi = np.abs(model.constraint_residual(sol.t, sol.q, sol.p, args)).max()
    t = np.asarray(sol.t)
    return SpinRun(spin0, t, w_space[:, 2], np.arccos(np.clip(R[:, 2, 2], -1.0, 1.0)), energy - energy[0],
                   float(energy[0]), first_sign_change(t, w_space[:, 2]), float(phi),
                   float(np.max(np.abs(np.sum(Q * Q, axis=1) - 1.0))), seconds)


def main(short: bool = False) -> list[SpinRun]:
    """Both spin senses; print what was found; the full run also draws the figure."""
    start = time.perf_counter()
    model = systems.rattleback()
    args = model.args()
    built = time.perf_counter() - start
    method = L.LobattoIIIAIIIB(stages=STAGES)
    t_end = T_END_SHORT if short else T_END
    runs = [spin_run(model, args, method, spin0, t_end) for spin0 in (-SPIN, SPIN)]
    print(f"rattleback (Kane & Levinson 1982), {ROLL_DEG}° roll, {PITCH_DEG}° pitch; s = {STAGES}, h = {H}, "
          f"{round(t_end / H)} steps on [0, {t_end:g}] per run; model built in {built:.1f} s")
    for r in runs:
        print(f"  spin {r.spin0:+g} rad/s: first reversal at t = {r.first_reversal:.3f} s; spin range "
              f"[{r.spin.min():+.3f}, {r.spin.max():+.3f}] rad/s, largest tilt {math.degrees(r.tilt.max()):.1f}°; "
              f"max |H − H0| = {np.max(np.abs(r.energy_error)):.1e} J (H0 = {r.energy0:.4f} J), "
              f"max ‖φ‖∞ = {r.max_phi:.1e}, max |Q·Q − 1| = {r.max_norm_error:.1e} [{r.seconds:.1f} s]")
    if not short:
        plot(runs)
        print(f"  figure: {FIGURE}")
    return runs


def envelope(t: np.ndarray, x: np.ndarray, width: int):
    """``(t_mid, lower, upper)``: the midpoints, minima and maxima of ``x`` over consecutive
    windows of ``width`` samples (the rocking is too fast to draw sample by sample)."""
    n = (x.size // width) * width
    windows = x[:n].reshape(-1, width)
    return t[:n].reshape(-1, width).mean(axis=1), windows.min(axis=1), windows.max(axis=1)


def plot(runs: list[SpinRun], path: pathlib.Path = FIGURE) -> None:
    """The spin, the rocking (the largest tilt per 0.1 s) and the energy error of both runs
    against time."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    width = round(0.1 / H)
    fig, (ax1, ax2, ax3) = plt.subplots(3, 1, figsize=(9, 9), sharex=True, constrained_layout=True)
    for k, r in enumerate(runs):
        colour = f"C{k}"
        label = f"spun at {r.spin0:+g} rad/s"
        ax1.plot(r.t, r.spin, color=colour, lw=1.0, label=label)
        if math.isfinite(r.first_reversal):
            ax1.axvline(r.first_reversal, color=colour, ls=":", lw=0.9)
            ax1.annotate(f"first reversal: {r.first_reversal:.2f} s", (r.first_reversal, 0.0),
                         xytext=(6, 40 if r.spin0 < 0 else -45), textcoords="offset points", fontsize=8,
                         color=colour, bbox={"fc": "white", "ec": "none", "alpha": 0.8})
        tm, _, hi = envelope(r.t, np.degrees(r.tilt), width)
        ax2.plot(tm, hi, color=colour, lw=1.0, label=label)
        tm, _, err = envelope(r.t, np.abs(r.energy_error) / r.energy0, width)
        ax3.semilogy(tm, np.maximum(err, 1e-17), color=colour, lw=1.0, label=label)
    ax1.axhline(0.0, color="k", lw=0.5)
    ax1.set_ylabel("spin ω·e_z (rad/s)")
    ax1.legend(fontsize=8, loc="upper right")
    ax1.set_title("spin about the vertical", fontsize=10)
    ax2.set_ylabel("largest tilt per 0.1 s (degrees)")
    ax2.set_ylim(bottom=0.0)
    ax2.set_title("rocking: the angle of the body's z axis from the vertical, largest per 0.1 s "
                  "(it rocks at about 100 rad/s)", fontsize=10)
    ax2.legend(fontsize=8, loc="upper left")
    ax3.set_ylabel("|H − H0| / H0")
    ax3.set_xlabel("t (s)")
    ax3.set_title("energy error, largest per 0.1 s (no slip, no friction: the energy is conserved)",
                  fontsize=10)
    ax3.legend(fontsize=8, loc="lower right")
    fig.suptitle(f"Kane & Levinson's rattleback (lobattodae.mechanics.systems.rattleback), "
                 f"s = {STAGES}, h = {H} s", fontsize=10)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=100)
    plt.close(fig)


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description="the rattleback's spin reversal")
    ap.add_argument("--short", action="store_true", help="the tests' run: 4 s of each sense, no figure")
    main(ap.parse_args().short)
    sys.exit(0)
