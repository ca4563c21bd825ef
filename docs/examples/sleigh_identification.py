r"""Identify the Chaplygin sleigh's inertia and knife-edge offset from a noisy trajectory.

The sleigh (``get_example("sleigh")``, ``q = (x, y, θ)``: centre of mass and heading;
``SleighParams(m, I, a)``: mass, moment of inertia about the centre of mass, distance of the
knife edge behind it) is simulated with the true parameters, its configuration is observed
at sample times with Gaussian noise (positions σ = 1 cm, heading σ = 0.01 rad, as from two
tracked markers), and the parameters are recovered by nonlinear least squares: Optimistix's
Levenberg–Marquardt on the residuals ``(q_model(t_k) − q_obs(t_k)) / σ``, where q_model comes
from ``lobattodae.integrate`` with constant steps and the residuals' Jacobian from JAX's
forward-mode autodiff through the solver (exact derivatives of the discrete map).

Which parameters are identifiable
---------------------------------
The unknowns are a, I and the unobserved initial state: pose ``(x0, y0, θ0)`` and velocities
``(v0, ω0)`` (forward speed along the heading and turning rate). The mass is not
identifiable from a trajectory: ``H = (p_x² + p_y²)/(2m) + p_θ²/(2I)`` and the constraint
``−sin θ x' + cos θ y' − a θ' = 0`` give equations of motion that are unchanged by
``(m, I) → (c m, c I)`` at the same initial velocities (the momenta and the multiplier scale
by c), so the observations determine a and I/m only. The script fixes m (it would be
weighed) and fits the seven others; it also checks the degeneracy numerically: the columns
of the Jacobian for m and I satisfy ``m ∂r/∂m + I ∂r/∂I = 0`` to round-off.

Data and model
--------------
The observations are generated from the closed-form solution of the example (not with the
integrator), so the fit also absorbs the integrator's discretisation error; it is printed
(max over the samples) and is far below the noise. Initial values for the fit: a and I from
rough guesses (0.5 m, 1 kg m², against 0.8 and 0.5), the pose from the first observation and
the velocities from the first two. The initial momenta are computed from the velocities,
``p0 = (m (v0 cos θ0 − a ω0 sin θ0), m (v0 sin θ0 + a ω0 cos θ0), I ω0)`` (consistent by
construction), and ``λ0 = consistent_lambda(...)``, so every parameter value gives consistent
initial values and the derivatives flow through them.

Standard errors: the Gauss–Newton covariance ``(JᵀJ)⁻¹`` of the σ-scaled residuals at the
solution. The full run checks them by refitting many independent noise draws (the spread of
the estimates against the standard errors).

Run from the repository root::

    .venv/bin/python docs/examples/sleigh_identification.py [--short]
"""

from __future__ import annotations

import argparse
import functools
import math
import sys
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx

import lobattodae as L
from lobattodae.examples import SleighParams, get_example

#: The true sleigh: mass (known, kg), inertia (kg m²), knife-edge offset (m).
MASS, TRUE_I, TRUE_A = 1.0, 0.5, 0.8
#: The true initial state: pose (m, m, rad) and velocities (m/s, rad/s).
TRUE_STATE = {"x0": 0.0, "y0": 0.0, "theta0": 0.3, "v0": 0.5, "omega0": 2.0}
#: Observation window (s) and noise of the observed x, y (m) and θ (rad).
T_END = 8.0
SIGMA = np.array([0.01, 0.01, 0.01])
#: The noise draw of the main fit (numpy Generator seed).
SEED = 20261124
#: Stages; steps over [0, T_END] and the stride of the samples (every k-th step point):
#: full run 80 steps (h = 0.1 s), 41 samples; short run 20 steps (h = 0.4 s), 11 samples.
STAGES = 4
N_STEPS, EVERY = 80, 2
N_STEPS_SHORT, EVERY_SHORT = 20, 2
#: Starting guesses for a and I (the initial state is estimated from the data).
GUESS_A, GUESS_I = 0.5, 1.0
#: Levenberg–Marquardt tolerances on the parameters and the loss, and its step limit.
LM_RTOL = LM_ATOL = 1e-8
LM_MAX_STEPS = 256
#: Full run: independent noise draws refitted to check the standard errors.
N_DRAWS = 40
#: Names of the fitted parameters, in the order of the parameter vector.
NAMES = ("a", "I", "x0", "y0", "theta0", "v0", "omega0")


def sleigh():
    """The example with the true parameters and initial state (its closed form makes the data)."""
    return get_example("sleigh", m=MASS, I=TRUE_I, a=TRUE_A, **TRUE_STATE, t_end=T_END)


def truth() -> np.ndarray:
    """The true parameter vector, in the order of :data:`NAMES`."""
    return np.array([TRUE_A, TRUE_I] + [TRUE_STATE[k] for k in ("x0", "y0", "theta0", "v0", "omega0")])


def sample_times(n_steps: int, every: int) -> np.ndarray:
    """Every ``every``-th step point of ``n_steps`` constant steps over ``[0, T_END]``."""
    return np.arange(n_steps + 1)[::every] * (T_END / n_steps)


def observe(t: np.ndarray, seed: int) -> np.ndarray:
    """Noisy configurations ``(x, y, θ)`` at the times ``t``, from the closed form."""
    q = sleigh().exact(t)[0]
    return q + SIGMA * np.random.default_rng(seed).standard_normal(q.shape)


def simulate(params, mass, problem, method, n_steps: int, every: int):
    """The model's configurations at the sample times, ``params = (a, I, x0, y0, θ0, v0, ω0)``."""
    a, inertia, x0, y0, th0, v0, w0 = params
    args = SleighParams(m=mass, I=inertia, a=a)
    q0 = jnp.stack([x0, y0, th0])
    c, s = jnp.cos(th0), jnp.sin(th0)
    p0 = jnp.stack([mass * (v0 * c - a * w0 * s), mass * (v0 * s + a * w0 * c), inertia * w0])
    lam0 = L.consistent_lambda(problem, 0.0, q0, p0, jnp.zeros(1), args)
    sol = L.integrate(problem, method, 0.0, T_END / n_steps, n_steps, q0, p0, lam0, args)
    return jnp.where(sol.status == L.Result.SUCCESSFUL, sol.q[::every], jnp.nan)


def residuals(params, data, mass, problem, method, n_steps, every):
    """σ-scaled residuals, flattened."""
    return ((simulate(params, mass, problem, method, n_steps, every) - data) / SIGMA).ravel()


@functools.partial(jax.jit, static_argnames=("problem", "method", "n_steps", "every"))
def linearise(params, data, problem, method, n_steps, every):
    """``(r, J, ∂r/∂m)``: the residuals of :func:`residuals`, their Jacobian in the seven
    parameters and the column of the mass, by forward mode through the solver (one compiled
    function for all three)."""

    def fn(x):
        r = residuals(x[:-1], data, x[-1], problem, method, n_steps, every)
        return r, r

    jac, r = jax.jacfwd(fn, has_aux=True)(jnp.concatenate([params, jnp.array([MASS])]))
    return r, jac[:, :-1], jac[:, -1]


def initial_guess(data: np.ndarray, t: np.ndarray) -> np.ndarray:
    """a, I from :data:`GUESS_A`, :data:`GUESS_I`; the pose from the first observation; the
    speed and turning rate from the first two (finite differences)."""
    d = data[1] - data[0]
    dt = t[1] - t[0]
    th = data[0, 2]
    return np.array([GUESS_A, GUESS_I, data[0, 0], data[0, 1], th,
                     (d[0] * math.cos(th) + d[1] * math.sin(th)) / dt, d[2] / dt])


class Fit(NamedTuple):
    """One least-squares fit and its Gauss–Newton standard errors."""

    value: np.ndarray  # (7,) in the order of NAMES
    stderr: np.ndarray  # (7,)
    chi2_dof: float  # Σ r² / (number of residuals − 7); ≈ 1 for a good fit
    lm_steps: int
    success: bool
    mass_degeneracy: float  # |m ∂r/∂m + I ∂r/∂I| / |m ∂r/∂m|

    @property
    def error(self) -> np.ndarray:
        return self.value - truth()


@functools.cache
def _objective(problem, method, n_steps: int, every: int):
    """``fn(params, data)`` for Optimistix, one function object per configuration (Optimistix
    compiles once per function object: a new closure per fit would compile every fit)."""

    def fn(params, data):
        return residuals(params, data, MASS, problem, method, n_steps, every)

    return fn


def fit(data, guess, problem, method, n_steps, every) -> Fit:
    """Levenberg–Marquardt from ``guess``, then the standard errors at the solution."""
    solver = optx.LevenbergMarquardt(rtol=LM_RTOL, atol=LM_ATOL)
    fn = _objective(problem, method, n_steps, every)
    sol = optx.least_squares(fn, solver, jnp.asarray(guess), args=jnp.asarray(data), max_steps=LM_MAX_STEPS,
                             throw=False)
    value = np.asarray(sol.value)
    r, jac, jac_mass = (np.asarray(x) for x in linearise(sol.value, jnp.asarray(data), problem, method, n_steps, every))
    cov = np.linalg.inv(jac.T @ jac)
    degeneracy = np.linalg.norm(MASS * jac_mass + value[1] * jac[:, 1]) / np.linalg.norm(MASS * jac_mass)
    return Fit(value, np.sqrt(np.diag(cov)), float(r @ r) / (r.size - len(NAMES)), int(sol.stats["num_steps"]),
               bool(sol.result == optx.RESULTS.successful), float(degeneracy))


class IdentificationResult(NamedTuple):
    """What :func:`main` found."""

    fit: Fit
    model_error: float  # max |q_model − q_exact| at the samples, true parameters (discretisation)
    n_samples: int
    draws: np.ndarray | None  # (N_DRAWS, 7) refits of independent noise draws (full run)
    draws_chi2_dof: np.ndarray | None  # (N_DRAWS,)
    draws_converged: int


def main(short: bool = False) -> IdentificationResult:
    """Simulate, add noise, fit; print the recovered values, errors and standard errors."""
    n_steps, every = (N_STEPS_SHORT, EVERY_SHORT) if short else (N_STEPS, EVERY)
    ex = sleigh()
    method = L.LobattoIIIAIIIB(stages=STAGES)
    t = sample_times(n_steps, every)
    data = observe(t, SEED)
    # the model's error at the true parameters: its residuals against the noise-free data
    exact = jnp.asarray(ex.exact(t)[0])
    exact_residuals = np.asarray(linearise(jnp.asarray(truth()), exact, ex.problem, method, n_steps, every)[0])
    model_error = float(np.max(np.abs(exact_residuals.reshape(-1, 3) * SIGMA)))
    result = fit(data, initial_guess(data, t), ex.problem, method, n_steps, every)
    print(f"Chaplygin sleigh, m = {MASS} kg (known); {t.size} samples of (x, y, θ) on [0, {T_END}] s, "
          f"σ = {SIGMA[0]} m / {SIGMA[2]} rad; model: s = {STAGES}, {n_steps} steps (h = {T_END / n_steps} s), "
          f"its error at the true parameters {model_error:.1e}")
    print(f"  Levenberg–Marquardt: {result.lm_steps} steps, converged: {result.success}, "
          f"χ²/dof = {result.chi2_dof:.3f}")
    for name, value, true, err, se in zip(NAMES, result.value, truth(), result.error, result.stderr):
        print(f"  {name:>6} = {value:.6f} ± {se:.6f}   (truth {true:.6f}, error {err:+.2e} = {err / se:+.2f} SE)")
    print(f"  the mass is not identifiable: |m ∂r/∂m + I ∂r/∂I| / |m ∂r/∂m| = {result.mass_degeneracy:.1e}")
    draws, chi2, converged = None, None, 0
    if not short:
        draws, chi2, converged = _refit_draws(ex.problem, method, n_steps, every, t)
        ratio = draws.std(axis=0, ddof=1) / result.stderr
        within = np.mean(np.abs(draws - truth()) <= 2 * result.stderr, axis=0)
        print(f"  {N_DRAWS} independent noise draws ({converged} converged), mean χ²/dof {chi2.mean():.3f}:")
        print("    spread of the estimates / standard error: "
              + ", ".join(f"{n} {r:.2f}" for n, r in zip(NAMES, ratio)))
        print("    fraction within 2 standard errors of the truth: "
              + ", ".join(f"{n} {w:.2f}" for n, w in zip(NAMES, within)))
    return IdentificationResult(result, model_error, t.size, draws, chi2, converged)


def _refit_draws(problem, method, n_steps, every, t):
    """Fits of :data:`N_DRAWS` further noise draws: their estimates, χ²/dof and how many
    converged."""
    fits = [fit(data, initial_guess(data, t), problem, method, n_steps, every)
            for data in (observe(t, SEED + 1 + k) for k in range(N_DRAWS))]
    return np.array([f.value for f in fits]), np.array([f.chi2_dof for f in fits]), sum(f.success for f in fits)


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description="identify the sleigh's a and I from a noisy trajectory")
    ap.add_argument("--short", action="store_true", help="the short run of the tests")
    main(ap.parse_args().short)
    sys.exit(0)
