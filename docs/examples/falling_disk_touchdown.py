"""A rolling disk that falls over: integrate until it touches the ground (a terminal event).

The tilted rolling disk of ``lobattodae.examples`` (``"falling-disk-general"``,
``q = (x, y, θ, φ, ψ)``: contact point, tilt from the vertical, heading, spin angle) is started
with too little spin to stay up: θ grows until the disk lies on the ground. The coordinates
are Euler angles, singular at θ = π/2 (the mass matrix is singular there: heading and spin
turn about the same vertical axis), so the model cannot be integrated up to the disk lying
flat. The disk here is a wheel on an axle that sticks out by ``AXLE·R`` on each side of its
centre: it touches the ground when the lower end of the axle does, at height

    e(q) = R cos θ − AXLE·R sin θ = 0,   i.e.   θ* = arctan(1 / AXLE)  (84.3° for AXLE = 0.1),

well before the singularity. ``e`` is the terminal event, with direction −1 (falling).

The event time is checked independently: scipy's DOP853 (rtol = atol = 1e-13) on the
reduced ODE ``y' = F(y)``, ``y = (q, p)``, with λ eliminated from the hidden constraint
``d/dt φ = φ_t + φ_q f + φ_p g(λ) = 0`` (g is affine in λ); the elimination is written out
below with ``jax.jacfwd`` from the problem's f, g and φ, not with the library's
``consistent_lambda``, and scipy locates the event on its own dense output. Like every
rolling model, this one keeps the contact bilateral: it does not check that the normal force
stays positive.

Run from the repository root::

    .venv/bin/python docs/examples/falling_disk_touchdown.py [--rtol 1e-10] [--stages 4] [--study]

It prints the touchdown time and state, the constraint residual there, and the difference to
the reference (exit status 1 if the relative difference exceeds ``--check``).
"""

from __future__ import annotations

import argparse
import math
import sys
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from scipy.integrate import solve_ivp

import lobattodae as L
from lobattodae.examples import get_example

#: Half-length of the axle beyond the disk's centre, in units of the radius R.
AXLE = 0.1
#: Initial motion: tilt θ0, heading rate Ω = φ'(0), θ'(0), spin ψ'(0) (the disk turns while
#: it falls; with more spin it would stay up gyroscopically).
DISK = {"theta0": 0.3, "Omega": 0.6, "theta_rate0": 0.0, "spin_rate0": -0.3}
#: Long enough for the fall (touchdown is near t = 2).
T_MAX = 20.0
#: lobattodae's tolerance (rtol = atol) and stages.
RTOL, STAGES = 1e-10, 4
#: The reference: DOP853 at this rtol = atol.
REFERENCE_RTOL = 1e-13
#: Default acceptance threshold of the relative difference of the two touchdown times.
CHECK = 1e-8
#: ``--study``: the touchdown time's error against the reference over these tolerances.
STUDY_RTOLS = (1e-6, 1e-8, 1e-10, 1e-12)


def axle_height(t, q, p, args):
    """Height of the lower end of the axle, ``R cos θ − AXLE·R sin θ`` (the event function)."""
    return args.R * (jnp.cos(q[2]) - AXLE * jnp.sin(q[2]))


#: The terminal event; an Event sets terminal and direction without attributes on the
#: function (equal Events reuse the compiled loop, docs/variable-steps.md §4).
TOUCHDOWN = L.Event(axle_height, terminal=1, direction=-1.0)


def touchdown_tilt() -> float:
    """θ* = arctan(1 / AXLE), where :func:`axle_height` vanishes."""
    return math.atan(1.0 / AXLE)


class Touchdown(NamedTuple):
    """The state where the disk touches the ground, and how the run got there."""

    t: float
    q: np.ndarray
    p: np.ndarray
    lam: np.ndarray
    constraint_residual: float  # ‖φ(t, q, p)‖∞ at touchdown
    n_steps: int
    n_rejected: int
    solution: Any  # the lobattodae Solution


def disk(**overrides):
    """The falling disk example with the initial motion :data:`DISK` (``overrides`` replace
    entries) on ``[0, T_MAX]``."""
    return get_example("falling-disk-general", **{**DISK, **overrides}, t_end=T_MAX)


def touchdown(rtol: float = RTOL, stages: int = STAGES, **overrides) -> Touchdown:
    """Integrate with error control until the axle touches the ground.

    Raises
    ------
    RuntimeError
        If the run ends without the event (the disk did not fall before ``T_MAX``).
    """
    ex = disk(**overrides)
    sol = L.solve(ex.problem, L.LobattoIIIAIIIB(stages=stages), ex.t_span, ex.q0, ex.p0, args=ex.args,
                  rtol=rtol, atol=rtol, events=[TOUCHDOWN])
    if sol.result != L.Result.EVENT:
        raise RuntimeError(f"no touchdown before t = {T_MAX:g}: {sol.message}")
    return Touchdown(float(sol.t_events[0][0]), sol.q[-1], sol.p[-1], sol.lam[-1],
                     float(sol.stats["constraint_residual"][-1]), int(sol.stats["n_steps"]),
                     int(sol.stats["n_rejected"]), sol)


def reduced_ode(problem, args):
    """``F(t, y)`` of the index-reduced ODE, ``y = (q, p)``, as a jitted NumPy-in, NumPy-out
    function: λ from ``φ_t + φ_q f + φ_p (g(λ=0) + G λ) = 0`` with ``G = ∂g/∂λ``."""

    def rhs(t, y):
        n = y.shape[0] // 2
        q, p = y[:n], y[n:]
        m = problem.phi(t, q, p, args).shape[0]
        f = problem.f(t, q, p, args)
        g0 = problem.g(t, q, p, jnp.zeros(m, y.dtype), args)
        big_g = jax.jacfwd(lambda lam: problem.g(t, q, p, lam, args))(jnp.zeros(m, y.dtype))
        phi_t, phi_q, phi_p = jax.jacfwd(problem.phi, argnums=(0, 1, 2))(t, q, p, args)
        lam = -jnp.linalg.solve(phi_p @ big_g, phi_t + phi_q @ f + phi_p @ g0)
        return jnp.concatenate([f, g0 + big_g @ lam])

    compiled = jax.jit(rhs)
    return lambda t, y: np.asarray(compiled(jnp.asarray(t, jnp.float64), jnp.asarray(y)))


def reference_touchdown(rtol: float = REFERENCE_RTOL, **overrides) -> tuple[float, np.ndarray, float]:
    """The touchdown time and state ``(t, y = (q, p))`` from DOP853 on the reduced ODE, and
    ``‖φ‖∞`` there (the explicit method lets the constraint drift)."""
    ex = disk(**overrides)
    n = ex.n

    def event(t, y):
        return float(axle_height(t, y[:n], y[n:], ex.args))

    event.terminal, event.direction = True, -1.0
    res = solve_ivp(reduced_ode(ex.problem, ex.args), ex.t_span, np.concatenate([ex.q0, ex.p0]), method="DOP853",
                    rtol=rtol, atol=rtol, events=event)
    if res.status != 1 or not len(res.t_events[0]):
        raise RuntimeError(f"the reference run found no touchdown before t = {T_MAX:g}: {res.message}")
    y = res.y_events[0][0]
    phi = float(np.max(np.abs(np.asarray(ex.problem.phi(res.t_events[0][0], y[:n], y[n:], ex.args)))))
    return float(res.t_events[0][0]), y, phi


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description="the falling disk until it touches the ground")
    ap.add_argument("--rtol", type=float, default=RTOL, help="rtol = atol of lobattodae (default %(default)g)")
    ap.add_argument("--stages", type=int, default=STAGES, help="stages s (default %(default)d)")
    ap.add_argument("--check", type=float, default=CHECK,
                    help="largest accepted relative difference to the reference (default %(default)g)")
    ap.add_argument("--study", action="store_true",
                    help=f"also print the touchdown time's error over rtol in {STUDY_RTOLS}")
    a = ap.parse_args(argv)
    td = touchdown(a.rtol, a.stages)
    x, y, theta, phi, psi = td.q
    print(f"touchdown (axle end on the ground, tilt θ* = {touchdown_tilt():.15f} rad)")
    print(f"  lobattodae s={a.stages}, rtol=atol={a.rtol:g}: t = {td.t:.15f} ({td.n_steps} steps, "
          f"{td.n_rejected} rejected)")
    print(f"  state: contact point ({x:.12f}, {y:.12f}), tilt {theta:.15f}, heading {phi:.12f}, spin angle {psi:.12f}")
    print(f"  p = {np.array2string(td.p, precision=12)}, λ = {np.array2string(td.lam, precision=12)}")
    print(f"  constraint residual ‖φ‖∞ = {td.constraint_residual:.1e}, event function "
          f"{float(axle_height(td.t, td.q, td.p, td.solution.args)):.1e}")
    t_ref, y_ref, phi_ref = reference_touchdown()
    rel = abs(td.t - t_ref) / abs(t_ref)
    print(f"  reference (scipy DOP853, reduced ODE, rtol=atol={REFERENCE_RTOL:g}): t = {t_ref:.15f}, "
          f"‖φ‖∞ there {phi_ref:.1e}")
    print(f"  relative difference of the touchdown times: {rel:.1e}; max |q - q_ref| = "
          f"{np.max(np.abs(td.q - y_ref[: td.q.size])):.1e}")
    if a.study:
        print(f"touchdown time against the reference, s={a.stages}:")
        for rtol in STUDY_RTOLS:
            r = touchdown(rtol, a.stages)
            print(f"  rtol=atol={rtol:.0e}: |t - t_ref|/t_ref = {abs(r.t - t_ref) / abs(t_ref):.1e}, "
                  f"max |q - q_ref| = {np.max(np.abs(r.q - y_ref[: r.q.size])):.1e}, {r.n_steps} steps, "
                  f"‖φ‖∞ {r.constraint_residual:.1e}")
    return 0 if rel <= a.check else 1


if __name__ == "__main__":
    sys.exit(main())
