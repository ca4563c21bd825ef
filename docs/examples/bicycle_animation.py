"""An animation of the nonlinear Whipple bicycle righting itself at a self-stable speed.

Integrates the nonlinear benchmark bicycle (:func:`lobattodae.mechanics.bicycle.whipple_bicycle`,
s = 4, constant steps h = 0.01) from upright rolling at 4.6 m/s (inside the self-stable range
4.29 < v < 6.02 m/s) kicked by a roll rate of 0.5 rad/s, the run of ``docs/bicycle.md``
("Nonlinear runs") cut to its first 3.95 s: the bicycle leans right, steers into the lean
and turns right, and the weave (roll and steer oscillating with a period of 1.6 s,
eigenvalues −0.38 ± 3.87i 1/s) decays. Reports the constraint residuals and the energy error
of the run and writes ``docs/figures/bicycle.gif`` with :func:`lobattodae.animate`
(the bicycle's built-in drawing: wheels, frames and both contacts' trails in 3-D, the view
following the bicycle), one frame every fifth step, in real time at 20 frames per second.

    .venv/bin/python docs/examples/bicycle_animation.py [--speed 4.6] [--roll-rate 0.5] [--out FILE]
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

import lobattodae
from lobattodae.mechanics import bicycle as bike

FIGURE = Path(__file__).resolve().parents[1] / "figures" / "bicycle.gif"
#: Frames of the GIF and steps between them: 80 frames, h = 0.01, so 395 steps on [0, 3.95].
FRAMES, STEPS_PER_FRAME, H = 80, 5, 0.01


def main(argv=None) -> dict:
    """Integrate, check and animate (options as on the command line); print what was done and
    return it: ``"phi"``, ``"psi"``, ``"energy_error"`` (maxima over the step points),
    ``"energy0"`` (J), ``"roll_max"``, ``"steer_max"`` (rad), ``"travelled"`` (m), ``"out"``
    (the file) and ``"frames"``."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--speed", type=float, default=4.6, help="forward speed v [m/s] (default 4.6)")
    parser.add_argument("--roll-rate", type=float, default=0.5, help="initial roll rate [rad/s] (default 0.5)")
    parser.add_argument("--out", type=Path, default=FIGURE, help=f"the GIF (default {FIGURE})")
    opts = parser.parse_args(argv)

    t0 = time.perf_counter()
    model = bike.whipple_bicycle()
    args = model.args()
    vw, vc = bike.weave_capsize_speeds(model, args)
    print(f"model built and linearised in {time.perf_counter() - t0:.1f} s; self-stable for {vw:.3f} < v < {vc:.3f} m/s")

    q0, p0 = bike.upright_state(model, opts.speed, args, roll_rate=opts.roll_rate)
    n_steps = (FRAMES - 1) * STEPS_PER_FRAME
    t0 = time.perf_counter()
    sol = lobattodae.solve(model.problem, lobattodae.LobattoIIIAIIIB(stages=4), (0.0, n_steps * H), q0, p0,
                           n_steps=n_steps, args=args)
    wall = time.perf_counter() - t0
    if not sol.success:
        raise SystemExit(f"the run failed at t = {sol.t[-1]:.3f}: {sol.message}")
    phi = np.abs(model.constraint_residual(sol.t, sol.q, sol.p, args)).max()
    psi = np.abs(model.holonomic_residual(sol.t, sol.q, args)).max()
    H_ = model.energy(sol.t, sol.q, sol.p, args)
    print(f"v = {opts.speed} m/s, roll rate {opts.roll_rate} rad/s: {n_steps} steps of h = {H} (s = 4) in {wall:.1f} s "
          f"(compilation included); max ‖φ‖∞ = {phi:.2e}, max |ψ_F| = {psi:.2e}, "
          f"max |H − H0| = {np.abs(H_ - H_[0]).max():.2e} (H0 = {H_[0]:.2f} J); "
          f"max |roll| = {np.abs(sol.q[:, 3]).max():.3f}, max |steer| = {np.abs(sol.q[:, 5]).max():.3f} rad, "
          f"travelled {sol.q[-1, 0]:.2f} m")

    import matplotlib

    matplotlib.use("Agg")
    t0 = time.perf_counter()
    out = lobattodae.animate(sol, opts.out, frames=FRAMES, fps=20, figsize=(5.0, 4.5),
                             title=f"Whipple bicycle, v = {opts.speed:g} m/s")
    print(f"wrote {out} ({out.stat().st_size / 1e6:.2f} MB, {FRAMES} frames) in {time.perf_counter() - t0:.1f} s")
    return {"phi": float(phi), "psi": float(psi), "energy_error": float(np.abs(H_ - H_[0]).max()),
            "energy0": float(H_[0]), "roll_max": float(np.abs(sol.q[:, 3]).max()),
            "steer_max": float(np.abs(sol.q[:, 5]).max()),
            "travelled": float(sol.q[-1, 0]), "out": out, "frames": FRAMES}


if __name__ == "__main__":
    main()
