r"""Linear stability of a disk rolling upright, from the Jacobian of its flow map.

A thin disk (mass m, radius R, inertia A about a diameter, C about its axis) rolls without
slipping, upright and straight, at speed v on a horizontal plane under gravity g. Classical
result (Routh, Appell): for a uniform disk (A = mR²/4, C = mR²/2) this steady motion is
stable iff **v² > gR/3**. This script finds the threshold from the library's model alone:
the Jacobian of the time-τ flow map of ``lobattodae.integrate``, taken by ``jax.jacfwd``
through the solver, gives the Floquet multipliers of the steady motion, and bisection on
them gives the critical speed.

The model
---------
``get_example("falling-disk-general")``: ``q = (x, y, θ, φ, ψ)`` (contact point, tilt from
the vertical, heading, spin angle), rolling ``x' = R cos φ ψ'``, ``y' = R sin φ ψ'``. Upright
straight rolling is ``θ = θ' = φ' = 0``, ``ψ' = ω = v/R``, ``x = v t``.

The linearised equations (derivation)
-------------------------------------
Take the frame (i, j, k) with i horizontal in the disk's plane (the direction of rolling),
j along the axis, k from the contact point to the centre G; it turns with
``Ω_f = θ' i + φ' Z`` (Z the vertical, ``Z = cos θ k + sin θ j``). The disk turns with
``ω = Ω_f + ψ' j``; its axial component is ``s = ψ' + φ' sin θ`` (the sign of the
``sin θ`` term depends on the orientation convention; the model writes ``ψ' − φ' sin θ``,
which only reverses θ and leaves the threshold alone). Rolling makes G move with
``v_G = ω × R k = R (s i − θ' j)``; the angular momentum about G is
``L = (A θ', C s, A φ' cos θ)``. Newton–Euler, with F the contact force:

    m dv_G/dt = F − m g Z,      dL/dt = (−R k) × F,

where ``d/dt X = X' + Ω_f × X`` for components in the turning frame. To first order in the
small quantities θ, θ', φ' and ``s − ω``: ``Ω_f ≈ (θ', 0, φ')``, ``Z ≈ (0, θ, 1)``,

    m dv_G/dt = m R (s', ω φ' − θ'', 0),    dL/dt = (A θ'' − C ω φ', C s', A φ'' + C ω θ'),
    (−R k) × F = (R F_j, −R F_i, 0),         F = m dv_G/dt + m g Z.

The three components give

    (A + mR²) θ'' = (C + mR²) ω φ' + m g R θ      (tilt)
    C s' = −mR² s'  ⇒  s' = 0                       (spin: the speed is constant)
    A φ'' = −C ω θ'                                 (heading)

The heading equation integrates to ``A φ' + C ω θ = A c`` (c a constant, a neighbouring
steady circular motion), and then

    (A + mR²) θ'' = −[(C + mR²) C ω² / A − m g R] θ + (C + mR²) ω c.

θ oscillates about a shifted equilibrium with ``ν² = [(C + mR²) C ω²/A − m g R]/(A + mR²)``
iff ``(C + mR²) C ω² > m g R A``, i.e. **v_c² = R² ω_c² = m g R³ A / (C (C + mR²))**. The
uniform disk gives ``(3mR²/2)(mR²/2) ω² > m g R · mR²/4``, i.e. ``v² > gR/3``,
``ν² = 4 (3v² − gR)/(5R²)``; a thin ring (A = mR²/2, C = mR²) gives ``v² > gR/4``, a second
check of the general formula.

Floquet multipliers from the flow map
-------------------------------------
The coordinates x, y, ψ are cyclic and φ enters only as the orientation of the plane (the
model is invariant under rotating the plane and φ together), so the motion reduces to
``r = (θ, θ', φ', ψ')``, in which steady rolling is an equilibrium. The flow map ``r(0) ↦ r(τ)`` is evaluated through
``lobattodae.integrate``: r(0) gives ``q0 = (0, 0, θ, 0, 0)`` and the velocities
``q̇0 = (R ψ', 0, θ', φ', ψ')``, consistent with the rolling constraint by construction,
``p0 = M(q0) q̇0``, ``λ0`` from ``consistent_lambda``; r(τ) is read from ``q(τ)`` and
``q̇ = f(q, p) = M⁻¹p``. Its Jacobian J at the steady motion (``jax.jacfwd``: four tangent
directions through the solver, exact derivatives of the discrete map) has the multipliers
``{1, 1, μ, 1/μ}``: 1 for ``ψ'`` (straight rolling at another speed is steady too) and 1 for
the constant c above; ``μ = exp(±iντ)`` (on the unit circle: stable; the system is
conservative, so stable means neutral) or ``exp(±ν'τ)`` (a real pair, one |μ| > 1:
unstable).

Bisection on the multipliers: near the threshold all four multipliers approach 1; at it the
linearised (θ, θ', φ') system is nilpotent (a Jordan block of size 3), where eigenvalues are
ill-conditioned: an error ε in J moves them by O(ε^(1/3)) (measured below: |μ| − 1 ≈ 2e-5 at
the threshold, from round-off). Their sum is not:
``μ + 1/μ − 2 = tr J − 4`` is ``2 (cos ντ − 1) < 0`` on the stable side and
``2 (cosh ν'τ − 1) > 0`` on the unstable side, an analytic function of v² that crosses zero
linearly (``≈ −τ² ν²``). Bisection on its sign finds the threshold to round-off.

The step size: measured, the threshold of the discrete map agrees with the exact one to
round-off for s = 3 with 2, 4, 8 steps over τ and for s = 4 with 1, 2, 3, 5, 20 steps, while
s = 2 shifts it by O(h²) (−7.6 %, −2.1 %, −0.53 % with 4, 8, 16 steps; and s = 3 with a single
step of 0.25 s has a second sign change at +5.9 %). A likely reason, not proved here: at
the threshold the linearised motion is polynomial in t (θ and φ' of degree 2), which the
methods with s ≥ 3 reproduce exactly. Away from the threshold the multipliers carry the
method's error (order 2s − 2; compared with ``exp(±iντ)`` below).

Run from the repository root::

    .venv/bin/python docs/examples/disk_stability.py [--short]

The full run also writes ``docs/figures/disk-stability.png``.
"""

from __future__ import annotations

import argparse
import functools
import math
import pathlib
import sys
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

import lobattodae as L
from lobattodae.examples import get_example

#: The disk: mass (kg), radius (m), gravity (m/s²).
MASS, RADIUS, GRAVITY = 1.0, 0.3, 9.81
#: Inertias in units of m R²: (about a diameter, about the axis). A uniform thin disk and a
#: thin ring (all the mass on the rim).
UNIFORM_DISK = (0.25, 0.5)
THIN_RING = (0.5, 1.0)
#: Time of the flow map (s). The bisection needs ντ < 2π on the bracket (at ντ = 2π the
#: multipliers are back at 1 and tr J = 4 again); the plot needs ντ < π, so that arg μ is not
#: folded: ν ≤ 9.3 rad/s over the plotted speeds.
TAU = 0.25
#: Stages of the method and steps over τ (full run, short run). With s ≥ 3 the threshold of
#: the discrete map does not depend on the step (measured, see the module docstring); the
#: multipliers away from it do.
STAGES = 4
N_STEPS, N_STEPS_SHORT = 20, 5
#: The bisection starts from speeds known to be unstable / stable, in units of √(gR) (v = 0:
#: the disk falls; v = √(gR): a fast disk), and stops at this relative width of the bracket.
BRACKET = (0.3, 1.0)
REL_WIDTH, REL_WIDTH_SHORT = 4e-16, 1e-12
#: Speeds of the plot, in units of √(gR).
PLOT_SPEEDS = np.linspace(0.05, 1.2, 93)
#: Speed (units of √(gR)) at which the multipliers are compared with the linear theory.
CHECK_SPEED = 0.75
FIGURE = pathlib.Path(__file__).resolve().parents[1] / "figures" / "disk-stability.png"


def rolling_disk(inertia=UNIFORM_DISK):
    """The ``falling-disk-general`` example for a disk with inertias ``inertia`` (units of
    m R²); its ``problem`` and ``args`` are what the flow map uses."""
    a, c = inertia
    mr2 = MASS * RADIUS**2
    return get_example("falling-disk-general", m=MASS, R=RADIUS, g=GRAVITY, I1=a * mr2, I3=c * mr2,
                       theta0=0.0, Omega=0.0, theta_rate0=0.0, spin_rate0=0.0)


def critical_speed(args) -> float:
    """``v_c = √(m g R³ A / (C (C + mR²)))`` (the module docstring's derivation)."""
    m, r, g, a, c = args.m, args.R, args.g, args.I1, args.I3
    return math.sqrt(m * g * r**3 * a / (c * (c + m * r**2)))


def linear_frequency_squared(args, v: float) -> float:
    """``ν² = [(C + mR²) C ω²/A − m g R] / (A + mR²)``, ``ω = v/R``: the tilt's angular
    frequency squared (negative: the growth rate squared, ``ν'² = −ν²``)."""
    m, r, g, a, c = args.m, args.R, args.g, args.I1, args.I3
    w = v / r
    return ((c + m * r**2) * c * w**2 / a - m * g * r) / (a + m * r**2)


def initial_state(problem, args, v, r0):
    """``(q0, p0, λ0)`` of the motion with reduced state ``(θ, θ', φ', ψ' − v/R) = r0``."""
    theta, theta_rate, heading_rate, spin_rate = r0[0], r0[1], r0[2], v / args.R + r0[3]
    q0 = jnp.zeros(5).at[2].set(theta)
    # the contact point's velocity from the rolling constraint (φ = 0): consistent as built
    qdot0 = jnp.stack([args.R * spin_rate, jnp.zeros_like(spin_rate), theta_rate, heading_rate, spin_rate])
    p0 = problem.mass_matrix(0.0, q0, args) @ qdot0
    lam0 = L.consistent_lambda(problem, 0.0, q0, p0, jnp.zeros(2), args)
    return q0, p0, lam0


def reduced_state(problem, args, q, p):
    """``(θ, θ', φ', ψ')`` of the state ``(q, p)``, with ``q̇ = f(q, p)``."""
    qdot = problem.f(0.0, q, p, args)
    return jnp.stack([q[2], qdot[2], qdot[3], qdot[4]])


def flow_map(r0, v, args, problem, method, n_steps):
    """The reduced state after ``TAU``, from the reduced state ``r0`` relative to upright
    rolling at speed ``v`` (``n_steps`` constant steps of ``lobattodae.integrate``)."""
    q0, p0, lam0 = initial_state(problem, args, v, r0)
    sol = L.integrate(problem, method, 0.0, TAU / n_steps, n_steps, q0, p0, lam0, args)
    rows = reduced_state(problem, args, sol.q[-1], sol.p[-1])
    return jnp.where(sol.status == L.Result.SUCCESSFUL, rows, jnp.nan)


@functools.partial(jax.jit, static_argnames=("problem", "method", "n_steps"))
def monodromy(v, args, problem, method, n_steps):
    """The 4×4 Jacobian of :func:`flow_map` at the steady motion (``jax.jacfwd`` through the
    solver), compiled once per problem, method and ``n_steps``: the speed and the
    parameters are traced."""
    return jax.jacfwd(flow_map)(jnp.zeros(4), v, args, problem, method, n_steps)


def stability_indicator(jac) -> float:
    """``tr J − 4 = μ + 1/μ − 2`` (the two trivial multipliers removed): negative when the
    nontrivial pair is on the unit circle, positive when it is real."""
    return float(np.trace(np.asarray(jac))) - 4.0


def bisect(fn, lo: float, hi: float, rel_width: float) -> tuple[float, int]:
    """The sign change of ``fn`` in ``[lo, hi]`` (``fn(lo) > 0 > fn(hi)``) by bisection,
    down to a bracket of relative width ``rel_width`` (or adjacent floats); returns the
    midpoint and the number of evaluations."""
    f_lo, f_hi = fn(lo), fn(hi)
    if not (f_lo > 0 > f_hi):
        raise ValueError(f"no sign change in [{lo}, {hi}]: fn = {f_lo}, {f_hi}")
    count = 2
    while hi - lo > rel_width * hi:
        mid = 0.5 * (lo + hi)
        if mid in (lo, hi):
            break
        count += 1
        if fn(mid) > 0:
            lo = mid
        else:
            hi = mid
    return 0.5 * (lo + hi), count


class Threshold(NamedTuple):
    """A critical speed found by bisection, and the closed form it is compared with."""

    name: str
    speed: float  # bisection on the multipliers
    exact: float  # √(m g R³ A / (C (C + mR²)))
    rel_error: float
    evaluations: int  # Jacobians computed by the bisection

    @property
    def digits(self) -> float:
        """Correct significant digits, −log10 of the relative error (16 when exact)."""
        return 16.0 if self.rel_error == 0 else -math.log10(self.rel_error)


def find_threshold(name, inertia, method, n_steps, rel_width) -> Threshold:
    """Bisect the sign change of :func:`stability_indicator` over :data:`BRACKET` for the disk
    with inertias ``inertia`` (units of m R²) and compare with :func:`critical_speed`."""
    ex = rolling_disk(inertia)
    scale = math.sqrt(GRAVITY * RADIUS)

    def indicator(v):
        return stability_indicator(monodromy(v, ex.args, ex.problem, method, n_steps))

    speed, count = bisect(indicator, BRACKET[0] * scale, BRACKET[1] * scale, rel_width)
    exact = critical_speed(ex.args)
    return Threshold(name, speed, exact, abs(speed - exact) / exact, count)


class MultiplierCheck(NamedTuple):
    """The multipliers at one speed against the linear theory."""

    speed: float
    multipliers: np.ndarray  # (4,) complex, sorted by argument
    rotation_error: float  # |arg μ − ντ| / (ντ) of the nontrivial pair
    unit_circle: float  # max ||μ| − 1| over all four
    trivial: float  # the two multipliers closest to 1, max |μ − 1|


def check_multipliers(method, n_steps, speed=CHECK_SPEED) -> MultiplierCheck:
    """The multipliers of the uniform disk at ``speed`` (units of √(gR), stable side)."""
    ex = rolling_disk()
    v = speed * math.sqrt(GRAVITY * RADIUS)
    mu = np.linalg.eigvals(np.asarray(monodromy(v, ex.args, ex.problem, method, n_steps)))
    mu = mu[np.argsort(np.angle(mu))]
    nu_tau = math.sqrt(linear_frequency_squared(ex.args, v)) * TAU
    ones = np.sort(np.abs(mu - 1.0))[:2]
    return MultiplierCheck(v, mu, abs(np.angle(mu[-1]) - nu_tau) / nu_tau, float(np.max(np.abs(np.abs(mu) - 1.0))),
                           float(np.max(ones)))


class StabilityResult(NamedTuple):
    """What :func:`main` found."""

    disk: Threshold
    ring: Threshold
    check: MultiplierCheck
    multipliers_at_threshold: np.ndarray  # eigenvalues of J at the bisected speed (ill-conditioned)
    n_steps: int
    coarse: Threshold | None  # the uniform disk again with N_STEPS_SHORT steps (full run)


def main(short: bool = False) -> StabilityResult:
    """Find the thresholds (uniform disk, thin ring), compare the multipliers with the linear
    theory, print it all; the full run also plots the multipliers against the speed."""
    method = L.LobattoIIIAIIIB(stages=STAGES)
    n_steps = N_STEPS_SHORT if short else N_STEPS
    rel_width = REL_WIDTH_SHORT if short else REL_WIDTH
    disk = find_threshold("uniform disk, v_c = √(gR/3)", UNIFORM_DISK, method, n_steps, rel_width)
    ring = find_threshold("thin ring, v_c = √(gR/4)", THIN_RING, method, n_steps, rel_width)
    ex = rolling_disk()
    at_threshold = np.linalg.eigvals(np.asarray(monodromy(disk.speed, ex.args, ex.problem, method, n_steps)))
    check = check_multipliers(method, n_steps)
    print(f"upright rolling, m = {MASS} kg, R = {RADIUS} m, g = {GRAVITY} m/s²; flow map over τ = {TAU} s, "
          f"s = {STAGES}, {n_steps} steps")
    for t in (disk, ring):
        print(f"  {t.name}: bisection {t.speed:.16f} m/s, closed form {t.exact:.16f} m/s, relative error "
              f"{t.rel_error:.1e} ({t.digits:.1f} digits, {t.evaluations} Jacobians)")
    print(f"  multipliers at the bisected threshold (a Jordan block: ill-conditioned), max ||μ| − 1| = "
          f"{np.max(np.abs(np.abs(at_threshold) - 1)):.1e}")
    print(f"  at v = {check.speed:.4f} m/s: multipliers {np.array2string(check.multipliers, precision=12)}; "
          f"rotation angle vs linear theory ντ: relative error {check.rotation_error:.1e}; "
          f"max ||μ| − 1| = {check.unit_circle:.1e}; trivial multipliers within {check.trivial:.1e} of 1")
    coarse = None
    if not short:
        coarse = find_threshold(disk.name, UNIFORM_DISK, method, N_STEPS_SHORT, rel_width)
        print(f"  the same bisection with {N_STEPS_SHORT} steps (h = {TAU / N_STEPS_SHORT} s): "
              f"{coarse.speed:.16f} m/s, relative error {coarse.rel_error:.1e}")
        plot(method, n_steps, disk.speed)
        print(f"  figure: {FIGURE}")
    return StabilityResult(disk, ring, check, at_threshold, n_steps, coarse)


def plot(method, n_steps, threshold: float, path: pathlib.Path = FIGURE) -> None:
    """|μ| and arg μ / τ of the four multipliers against the speed, with the linear theory."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ex = rolling_disk()
    scale = math.sqrt(GRAVITY * RADIUS)
    speeds = PLOT_SPEEDS * scale
    mus = np.array([np.linalg.eigvals(np.asarray(monodromy(v, ex.args, ex.problem, method, n_steps)))
                    for v in speeds])
    nu2 = np.array([linear_frequency_squared(ex.args, v) for v in speeds])
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(10, 4), constrained_layout=True)
    x = np.repeat(PLOT_SPEEDS[:, None], 4, axis=1)
    ax1.semilogy(x.ravel(), np.abs(mus).ravel(), ".", ms=4, label="|μ|, Jacobian of the flow map")
    ax1.semilogy(PLOT_SPEEDS, np.exp(np.sqrt(np.maximum(-nu2, 0)) * TAU), "-", lw=0.8,
                 label="exp(ν′τ), linear theory")
    ax1.set_ylabel("|μ|")
    ax2.plot(x.ravel(), np.abs(np.angle(mus)).ravel() / TAU, ".", ms=4, label="|arg μ| / τ")
    ax2.plot(PLOT_SPEEDS, np.sqrt(np.maximum(nu2, 0)), "-", lw=0.8, label="ν, linear theory")
    ax2.set_ylabel("rad/s")
    for ax in (ax1, ax2):
        ax.axvline(threshold / scale, color="k", ls=":", lw=0.8, label=f"threshold by bisection, {threshold:.6f} m/s")
        ax.set_xlabel("speed v / √(gR)")
        ax.legend(fontsize=8)
    fig.suptitle(f"Upright rolling disk: Floquet multipliers of the time-{TAU} s flow map "
                 f"(R = {RADIUS} m, s = {STAGES}, {n_steps} steps)", fontsize=10)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description="stability threshold of the upright rolling disk")
    ap.add_argument("--short", action="store_true", help="the short run of the tests (no figure)")
    main(ap.parse_args().short)
    sys.exit(0)
