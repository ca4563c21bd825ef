r"""Work-precision diagrams on the external test set (``benchmarks/testset``): the test set's
error measure against wall time and against the requested tolerance.

For every problem of ``testset.PROBLEMS`` (default: ``andrews``; ``--problems all`` runs
every problem) and every solver, tol = 1e-4 ... 1e-12 in decades (``--half-decades``: in
half decades); rtol = atol = tol everywhere. Every point: a first call (``first_call_time``:
compilation + run for the first tolerance of a jitted solver, the run alone afterwards), then
the best of 3 further calls (``time``; a call longer than ``--repeat-limit`` = 5 s is not
repeated). A solver stops tightening once a call takes longer than ``--budget`` = 20 s, or
its next call is predicted to take more than 3x that, or its error has not halved over
three settings once it is within 3x of the reference's own accuracy (the floor).

Error: ``testset.error`` -- max over the compared components (q, and p where the entry
compares p) and the reference times of ``|y − y_ref| / (1 + |y_ref|)``.

Solvers
-------
* **lobattodae** ``solve(problem, LobattoIIIAIIIB(stages=s), t_span, q0, p0, args=...,
  rtol=tol, atol=tol)`` for s = 3, 4, 5, 6, ``save_every="final"`` when the only reference
  time is the end of the interval, else ``t_eval=t_ref``; the whole ``solve`` call is timed.
  ``lobattodae.set_cpu_threads(1)`` is called first thing (XLA's CPU pool of one thread
  applies to every solver of the process).
* **diffrax Dopri8** and **diffrax Kvaerno5** (implicit; its default root finder, VeryChord
  with the controller's tolerances) on the index-1 ODE of the problem (below),
  ``PIDController(rtol=tol, atol=tol)`` (default coefficients), ``dt0=None``,
  ``SaveAt(ts=t_ref)``, ``max_steps`` = 10⁶, ``adjoint=ForwardMode()`` (no backward pass is
  needed: a plain while loop), ``throw=False``; the whole ``diffeqsolve`` is jitted once per
  problem and solver with the tolerance a traced argument.
* **scipy DOP853** and **scipy Radau** (``solve_ivp``, rtol = atol = tol; Radau with its
  default finite-difference Jacobian) on the same index-1 ODE with a plain Python/NumPy
  right-hand side; ``t_eval=t_ref`` only when there are reference times before the end.
* **SUNDIALS IDA** (scikit-sundae, ``baselines.IDABaseline``: the index-2 form
  ``y = (q, p, λ)``, residual ``[q' − f, p' − g(λ), φ]`` from the problem's own JAX functions,
  AOT-compiled and called from NumPy, λ excluded from the error test), when scikit-sundae is
  importable (``--no-ida`` skips it).

Index-1 ODE forms
-----------------
* ``andrews`` (written here): ``y = (q, w)``, ``q' = w`` and

      [M(q)  G(q)ᵀ] [w']   [ f(q, w)         ]
      [G(q)  0    ] [λ ] = [ −g_qq(q)(w, w)  ]

  (the acceleration-level constraint ``(d²/dt²) g(q) = G w' + g_qq(w, w) = 0``), with
  ``g_qq(q)(w, w) = (D_q G(q)[w]) w``. For diffrax in ``jax.numpy`` from ``testset.andrews``'
  ``mass_matrix``, ``forces``, ``constraint_jacobian`` and ``jax.jvp`` of the latter; for
  scipy by hand in plain Python/NumPy (``math`` on floats, the 13×13 system solved with
  ``np.linalg.solve``), the same formulas as the test set's ``andrews.f`` (its ``gqq`` written
  out). Validated before timing: NumPy vs JAX at random points (≤ 1e-12 relative), ``w'(0)``
  and ``λ(0)`` against the test set's values, and a DOP853 run at rtol = atol = 1e-13 that
  must keep ``g(q) ≈ 0`` and meet the published reference. The compared p is ``M(q) w``.
* ``knife-edge``, ``sleigh``: the hand-written index-reduced ODEs of ``_common`` (``y = (q, p)``,
  λ eliminated through the hidden constraint; NumPy for scipy, ``jax.numpy`` for diffrax).
* ``servo-sleigh``, ``servo-sleigh-rest``: (q, p) with λ eliminated, by hand here
  (:func:`servo_sleigh_ode`; not the body-velocity ODE the reference was computed with).
* any other problem: diffrax only, on the (q, p) ODE with λ eliminated through the hidden
  constraint ``φ_t + φ_q f + φ_p g(λ) = 0`` built with ``jax.jacfwd`` from the problem's own
  functions (g affine in λ); scipy is skipped (no hand-written NumPy right-hand side -- a
  JAX-compiled one called from NumPy would not be how a scipy user works).

The table: wall time at error 1e-8 on each solver's Pareto front (log time interpolated
linearly in log error between the two bracketing points; ``adaptive_wp.time_at``), for
lobattodae the best s, and the ratios ours(best s)/Dopri8, /DOP853, /Radau (< 1: ours is
faster). The same table from process CPU times is printed too (the machine is shared: wall
time ≫ CPU time means other processes held the cores).

Usage (repository root)::

    PYTHONPATH=src .venv/bin/python benchmarks/testset_wp.py [--problems andrews ...|all] [--half-decades]
    PYTHONPATH=src .venv/bin/python benchmarks/testset_wp.py --replot

Writes ``benchmarks/results/testset_wp.json`` (``--problems`` merges into it) and
``benchmarks/results/testset_wp_<name>.png``.
"""

from __future__ import annotations

import argparse
import datetime
import json
import math
import os
import sys
import time
import warnings
from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
try:
    import lobattodae as L  # noqa: N812
except ImportError:  # pragma: no cover
    sys.path.insert(0, os.path.join(HERE, "..", "src"))
    import lobattodae as L  # noqa: N812

import _common as C  # noqa: E402
from adaptive_wp import half_decades, time_at  # noqa: E402
from baselines import IDABaseline, ida_available, source_revision, time_best  # noqa: E402

RESULTS_DIR = os.path.join(HERE, "results")
TARGET = 1e-8
STAGES = (3, 4, 5, 6)
SOLVERS = ("lobattodae", "Dopri8", "Kvaerno5", "DOP853", "Radau", "IDA")
MAX_STEPS = 1_000_000
log = C.log


# =============================================================================== ODE forms
@dataclass
class IndexOneODE:
    """``y' = F(t, y)`` for a test problem, with the map back to the compared (q, p).

    ``rhs(t, y)``: plain Python/NumPy for scipy (None: scipy is skipped); ``rhs_jax(t, y)``:
    ``jax.numpy`` for diffrax; ``y0``; ``to_qp(Y) -> (Q, P)`` for rows ``Y`` (N, dim)."""

    y0: np.ndarray
    rhs: Callable | None
    rhs_jax: Callable
    to_qp: Callable
    how: str
    validation: dict = field(default_factory=dict)


# ------------------------------------------------------------------------------ Andrews
def andrews_numpy_rhs(P: dict | None = None) -> Callable:
    """Andrews' squeezer, ``y = (q, w)``: plain Python/NumPy, by hand from the test set's
    ``andrews.f`` (M, f, G and the acceleration-level term g_qq(w, w))."""
    from testset import andrews as A

    P = dict(A.PARAMS if P is None else P)
    sin, cos, sqrt = math.sin, math.cos, math.sqrt
    m1, m2, m3, m4, m5, m6, m7 = (P[f"m{k}"] for k in range(1, 8))
    i1, i2, i3, i4, i5, i6, i7 = (P[f"i{k}"] for k in range(1, 8))
    rr, d, da, ra, e, ea = P["rr"], P["d"], P["da"], P["ra"], P["e"], P["ea"]
    ss, sa, sb, sc, sd = P["ss"], P["sa"], P["sb"], P["sc"], P["sd"]
    ta, tb, u, ua, ub = P["ta"], P["tb"], P["u"], P["ua"], P["ub"]
    zf, zt, fa, mom, c0, l0 = P["zf"], P["zt"], P["fa"], P["mom"], P["c0"], P["l0"]
    xa, ya, xb, yb, xc, yc = P["xa"], P["ya"], P["xb"], P["yb"], P["xc"], P["yc"]
    ee, ff = e - ea, zf - fa
    # constant parts of M
    c11 = m1 * ra**2 + m2 * (rr**2 + da**2) + i1 + i2
    c11c = 2 * m2 * da * rr  # m11 = c11 − c11c cos θ
    c21, c21c = m2 * da**2 + i2, m2 * da * rr  # m21 = c21 − c21c cos θ
    m22, m33 = m2 * da**2 + i2, m3 * (sa**2 + sb**2) + i3
    m44 = m4 * ee**2 + i4
    c54, c54s = m4 * ee**2 + i4, m4 * zt * ee  # m54 = c54 + c54s sin Φ
    c55 = m4 * (zt**2 + ee**2) + m5 * (ta**2 + tb**2) + i4 + i5
    c55s = 2 * m4 * zt * ee
    m66 = m6 * ff**2 + i6
    c76, c76s = m6 * ff**2 + i6, m6 * u * ff  # m76 = c76 − c76s sin Ω
    c77 = m6 * (ff**2 + u**2) + m7 * (ua**2 + ub**2) + i6 + i7
    c77s = 2 * m6 * u * ff
    k0, k4, k6 = m2 * da * rr, m4 * zt * ee, m6 * u * ff
    K = np.zeros((13, 13))
    K[1, 1], K[2, 2], K[3, 3], K[5, 5] = m22, m33, m44, m66
    b = np.zeros(13)
    out = np.zeros(14)

    def rhs(t, y):
        be, th, ga, ph, de, om, ep, bep, thp, gap, php, dep, omp, epp = y.tolist()
        sibe, cobe, sith, coth = sin(be), cos(be), sin(th), cos(th)
        sibeth, cobeth = sin(be + th), cos(be + th)
        siga, coga = sin(ga), cos(ga)
        siph, coph = sin(ph), cos(ph)
        siphde, cophde = sin(ph + de), cos(ph + de)
        side, code = sin(de), cos(de)
        siom, coom = sin(om), cos(om)
        siomep, coomep = sin(om + ep), cos(om + ep)
        siep, coep = sin(ep), cos(ep)
        # M(q)
        K[0, 0] = c11 - c11c * coth
        K[0, 1] = K[1, 0] = c21 - c21c * coth
        K[3, 4] = K[4, 3] = c54 + c54s * siph
        K[4, 4] = c55 + c55s * siph
        K[5, 6] = K[6, 5] = c76 - c76s * siom
        K[6, 6] = c77 - c77s * siom
        # G(q) (rows 7..12) and Gᵀ
        a1, a2 = -rr * sibe + d * sibeth, d * sibeth
        b1, b2 = rr * cobe - d * cobeth, -d * cobeth
        G = ((a1, a2, -ss * coga, 0.0, 0.0, 0.0, 0.0),
             (b1, b2, -ss * siga, 0.0, 0.0, 0.0, 0.0),
             (a1, a2, 0.0, -e * cophde, -e * cophde + zt * side, 0.0, 0.0),
             (b1, b2, 0.0, -e * siphde, -e * siphde - zt * code, 0.0, 0.0),
             (a1, a2, 0.0, 0.0, 0.0, zf * siomep, zf * siomep - u * coep),
             (b1, b2, 0.0, 0.0, 0.0, -zf * coomep, -zf * coomep - u * siep))
        Ga = np.array(G)
        K[7:, :7] = Ga
        K[:7, 7:] = Ga.T
        # f(q, w)
        xd = sd * coga + sc * siga + xb
        yd = sd * siga - sc * coga + yb
        lang = sqrt((xd - xc) ** 2 + (yd - yc) ** 2)
        force = -c0 * (lang - l0) / lang
        fx, fy = force * (xd - xc), force * (yd - yc)
        b[0] = mom - k0 * thp * (thp + 2 * bep) * sith
        b[1] = k0 * bep * bep * sith
        b[2] = fx * (sc * coga - sd * siga) + fy * (sd * coga + sc * siga)
        b[3] = k4 * dep * dep * coph
        b[4] = -k4 * php * (php + 2 * dep) * coph
        b[5] = -k6 * epp * epp * coom
        b[6] = k6 * omp * (omp + 2 * epp) * coom
        # −g_qq(q)(w, w): second time derivative of g along q'' = 0, negated
        w1, w2, w3 = (bep + thp) ** 2, (php + dep) ** 2, (omp + epp) ** 2
        cc = -rr * cobe * bep * bep + d * cobeth * w1
        cs = -rr * sibe * bep * bep + d * sibeth * w1
        b[7] = -(cc + ss * siga * gap * gap)
        b[8] = -(cs - ss * coga * gap * gap)
        b[9] = -(cc + e * siphde * w2 + zt * code * dep * dep)
        b[10] = -(cs - e * cophde * w2 + zt * side * dep * dep)
        b[11] = -(cc + zf * coomep * w3 + u * siep * epp * epp)
        b[12] = -(cs + zf * siomep * w3 - u * coep * epp * epp)
        sol = np.linalg.solve(K, b)
        out[:7] = y[7:]
        out[7:] = sol[:7]
        return out.copy()

    def lam(y):
        rhs(0.0, y)
        return np.linalg.solve(K, b)[7:]

    rhs.lam = lam
    return rhs


def andrews_jax_rhs():
    """The same ODE in ``jax.numpy`` from the test set's JAX functions; g_qq by ``jax.jvp``."""
    import jax
    import jax.numpy as jnp
    from testset import andrews as A

    def accel(q, w):
        M, G = A.mass_matrix(q), A.constraint_jacobian(q)
        _, dG = jax.jvp(A.constraint_jacobian, (q,), (w,))  # D_q G(q)[w]
        K = jnp.block([[M, G.T], [G, jnp.zeros((G.shape[0], G.shape[0]))]])
        return jnp.linalg.solve(K, jnp.concatenate([A.forces(q, w), -dG @ w]))

    def rhs(t, y):
        q, w = y[:7], y[7:]
        return jnp.concatenate([w, accel(q, w)[:7]])

    rhs.accel = accel
    return rhs


def andrews_ode(entry, setup) -> IndexOneODE:
    import jax
    import jax.numpy as jnp
    from scipy.integrate import solve_ivp
    from testset import andrews as A
    from testset import error

    t0 = time.perf_counter()
    rhs, rhs_jax = andrews_numpy_rhs(), andrews_jax_rhs()
    n = 7

    def to_qp(Y):
        Y = np.atleast_2d(Y)
        Q, W = Y[:, :n], Y[:, n:]
        return Q, np.stack([A.mass_matrix(q) @ w for q, w in zip(Q, W)])

    y0 = np.r_[setup.q0, np.linalg.solve(A.mass_matrix(setup.q0), setup.p0)]
    # 1. NumPy vs JAX at random points (near the initial configuration and far from it)
    F_jax = jax.jit(rhs_jax)
    lam_jax = jax.jit(lambda y: rhs_jax.accel(y[:7], y[7:])[7:])
    rng = np.random.default_rng(0)
    pts = [y0] + [np.r_[np.asarray(A.Q0) + rng.normal(scale=sc, size=7), rng.normal(scale=100.0 * sc, size=7)]
                  for sc in (0.05, 0.3, 1.0, 2.0) for _ in range(3)]
    d_rhs, s_rhs, d_lam, s_lam = [], [], [], []
    for y in pts:
        ref = np.asarray(F_jax(0.0, jnp.asarray(y)))
        d_rhs.append(np.max(np.abs(rhs(0.0, y) - ref)) / np.max(np.abs(ref)))
        lref = np.asarray(lam_jax(jnp.asarray(y)))
        d_lam.append(np.max(np.abs(rhs.lam(y) - lref)) / np.max(np.abs(lref)))
    # 2. w'(0), λ(0) against the test set's values (y(15..21), y(22..27) at t = 0)
    wdot0 = rhs(0.0, y0)[7:]
    err_wdot0 = float(np.max(np.abs(wdot0 - np.asarray(A.W_DOT0)) / (1 + np.abs(A.W_DOT0))))
    err_lam0 = float(np.max(np.abs(rhs.lam(y0) - np.asarray(A.LAM0)) / (1 + np.abs(A.LAM0))))
    # 3. a long accurate run: g(q) stays ~0 and the published reference is met
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        r = solve_ivp(rhs, setup.t_span, y0, method="DOP853", rtol=1e-13, atol=1e-13)
    Q, Pm = to_qp(r.y.T[-1:])
    err_ref = error(entry, r.t[-1], Q[0], Pm[0])
    g_max = float(max(np.max(np.abs(A.constraints(q))) for q in r.y[:n].T))
    gdot_max = float(max(np.max(np.abs(A.constraint_jacobian(y[:n]) @ y[n:])) for y in r.y.T))
    val = {"rhs_numpy_vs_jax_rel": float(max(d_rhs)), "lambda_numpy_vs_jax_rel": float(max(d_lam)),
           "points": len(pts), "wdot0_vs_testset": err_wdot0, "lambda0_vs_testset": err_lam0,
           "dop853_1e-13": {"error_vs_reference": float(err_ref), "max_abs_g": g_max, "max_abs_G_w": gdot_max,
                            "steps": len(r.t) - 1, "ref_accuracy": entry.ref_accuracy}}
    val["ok"] = bool(max(d_rhs) <= 1e-12 and max(d_lam) <= 1e-10 and err_wdot0 <= 1e-10 and err_lam0 <= 1e-10
                     and err_ref <= 10 * entry.ref_accuracy and g_max <= 1e-10)
    val["seconds"] = time.perf_counter() - t0
    how = ("y = (q, w); [M Gᵀ; G 0][w'; λ] = [f; −g_qq(w,w)]: NumPy by hand (math on floats, "
           "np.linalg.solve 13×13), JAX from testset.andrews with jax.jvp for g_qq")
    return IndexOneODE(y0, rhs, rhs_jax, to_qp, how, val)


# --------------------------------------------------------------- (q, p) forms, λ eliminated
def _qp_split(n):
    def to_qp(Y):
        Y = np.atleast_2d(Y)
        return Y[:, :n], Y[:, n:]

    return to_qp


def common_ode(name):
    """The hand-written index-reduced ODEs of ``_common`` (y = (q, p))."""

    def make(entry, setup) -> IndexOneODE:
        ode = C.reduced_ode(name, setup.args)
        params = ode.params
        rhs_jax = lambda t, y: ode.rhs_jax(t, y, params)  # noqa: E731
        return IndexOneODE(np.r_[setup.q0, setup.p0], ode.rhs, rhs_jax, _qp_split(ode.n),
                           f"_common.{name.replace('-', '_')}_ode: {ode.how}")

    return make


def servo_sleigh_ode(entry, setup) -> IndexOneODE:
    """The servo-driven sleigh in (q, p), by hand: ``q' = (p_x/m, p_y/m, p_θ/I)``,
    ``p' = (F cos θ, F sin θ, τ) + μᵀλ``, ``μ = (−sin θ, cos θ, −a)``; differentiating
    ``φ = μ q'`` along the flow gives ``λ = (ω (cos θ x' + sin θ y') + a τ / I) / (1/m + a²/I)``.
    (Not the body-velocity ODE ``servo_sleigh.body_rhs`` the reference was computed with.)
    Validated against :func:`generic_jax_ode` (the problem's own functions) at random points."""
    import jax
    import jax.numpy as jnp
    from testset import servo_sleigh as S

    m, I, a, cv, cw = (float(S.PARAMS[k]) for k in ("m", "I", "a", "c_v", "c_w"))  # noqa: E741
    den = 1.0 / m + a * a / I
    sin, cos = math.sin, math.cos

    def rhs(t, y):
        _, _, th, px, py, pth = y.tolist()
        s, c = sin(th), cos(th)
        xd, yd, w = px / m, py / m, pth / I
        v = c * xd + s * yd
        F = -cv * (v - (1.0 + 0.5 * sin(t)))
        tau = -cw * (w - 0.8 * cos(0.5 * t))
        lam = (w * v + a * tau / I) / den
        return np.array([xd, yd, w, F * c - s * lam, F * s + c * lam, tau - a * lam])

    def rhs_jax(t, y):
        th, px, py, pth = y[2], y[3], y[4], y[5]
        s, c = jnp.sin(th), jnp.cos(th)
        xd, yd, w = px / m, py / m, pth / I
        v = c * xd + s * yd
        F = -cv * (v - (1.0 + 0.5 * jnp.sin(t)))
        tau = -cw * (w - 0.8 * jnp.cos(0.5 * t))
        lam = (w * v + a * tau / I) / den
        return jnp.stack([xd, yd, w, F * c - s * lam, F * s + c * lam, tau - a * lam])

    ref = jax.jit(generic_jax_ode(entry, setup).rhs_jax)
    rng = np.random.default_rng(0)
    d_np, d_jax = [], []
    for k in range(8):
        t, y = rng.uniform(0, 10), (np.r_[setup.q0, setup.p0] if k == 0 else rng.normal(size=6))
        r = np.asarray(ref(jnp.float64(t), jnp.asarray(y)))
        d_np.append(np.max(np.abs(rhs(t, y) - r)) / np.max(np.abs(r)))
        d_jax.append(np.max(np.abs(np.asarray(rhs_jax(t, jnp.asarray(y))) - r)) / np.max(np.abs(r)))
    val = {"rhs_numpy_vs_problem_rel": float(max(d_np)), "rhs_jax_vs_problem_rel": float(max(d_jax)), "points": 8}
    val["ok"] = bool(max(d_np + d_jax) <= 1e-12)
    return IndexOneODE(np.r_[setup.q0, setup.p0], rhs, rhs_jax, _qp_split(3),
                       "(q, p), λ from the hidden constraint, by hand (NumPy: math on floats)", val)


def generic_jax_ode(entry, setup) -> IndexOneODE:
    """(q, p) with λ from ``φ_t + φ_q f + φ_p g(λ) = 0`` (jax.jacfwd of the problem's own
    functions; exact for g affine in λ); JAX only."""
    import jax
    import jax.numpy as jnp

    problem, args = setup.problem, setup.args
    n = np.size(setup.q0)
    m = int(np.size(problem.phi(jnp.asarray(0.0), jnp.asarray(setup.q0), jnp.asarray(setup.p0), args)))

    def rhs_jax(t, y):
        q, p = y[:n], y[n:]
        fq = problem.f(t, q, p, args)
        phi_t = jax.jacfwd(lambda tt: problem.phi(tt, q, p, args))(t)
        phi_q = jax.jacfwd(lambda qq: problem.phi(t, qq, p, args))(q)
        phi_p = jax.jacfwd(lambda pp: problem.phi(t, q, pp, args))(p)
        z = jnp.zeros(m, y.dtype)
        g0 = problem.g(t, q, p, z, args)
        g_l = jax.jacfwd(lambda lam: problem.g(t, q, p, lam, args))(z)
        lam = jnp.linalg.solve(phi_p @ g_l, -(phi_t + phi_q @ fq + phi_p @ g0))
        return jnp.concatenate([fq, problem.g(t, q, p, lam, args)])

    return IndexOneODE(np.r_[setup.q0, setup.p0], None, rhs_jax, _qp_split(n),
                       "(q, p), λ from the hidden constraint by jax.jacfwd of the problem's f, g, φ (JAX only)")


#: problem name -> builder of its index-1 ODE form (others: ``generic_jax_ode``)
ODE_FORMS: dict[str, Callable] = {
    "andrews": andrews_ode,
    "knife-edge": common_ode("knife-edge"),
    "sleigh": common_ode("sleigh"),
    "servo-sleigh": servo_sleigh_ode,
    "servo-sleigh-rest": servo_sleigh_ode,
}


# ==================================================================================== sweep
def sweep(label: str, tols, call: Callable, post: Callable, opts, floor: float) -> dict:
    """Run ``call(tol)`` for each tol (first call, then best of ``opts.repeats``); ``post(out)``
    turns the best call's output into a dict with at least ``error``."""
    points, stopped = [], ""
    best_err, since, last_t, prev_t = math.inf, 0, None, None
    load0 = C.loadavg()
    t_start = time.perf_counter()
    for tol in tols:
        if last_t is not None and prev_t is not None and last_t > 0.5:
            pred = last_t * max(1.0, last_t / prev_t)
            if pred > 3 * opts.budget:
                stopped = f"next call predicted to take {pred:.0f} s (> 3x the {opts.budget:g} s budget)"
                break
        rec: dict[str, Any] = {"tol": tol}
        try:
            t0 = time.perf_counter()
            call(tol)
            rec["first_call_time"] = time.perf_counter() - t0
            wall, k, out = time_best(lambda: call(tol), opts.repeats, opts.repeat_limit)
            rec.update(time=wall, cpu_time=time_best.last_cpu, repeats=k)
            rec.update(post(out))
        except Exception as exc:  # recorded, never hidden
            rec.update(time=math.nan, error=math.inf, ok=False, message=f"{type(exc).__name__}: {str(exc)[:300]}")
        rec.setdefault("ok", True)
        if not np.isfinite(rec.get("error", math.inf)):
            rec["error"] = math.inf
        points.append(rec)
        log(f"    {label:22s} tol={tol:<8.3g} err {rec['error']:.2e}  {rec['time']:.4g} s "
            f"(cpu {rec.get('cpu_time', math.nan):.3g} s, {rec.get('repeats', 0)}x; first {rec.get('first_call_time', math.nan):.3g} s)"
            + (f"  {rec['steps']} steps" if rec.get("steps") is not None else "")
            + (f" ({rec['rejected']} rej)" if rec.get("rejected") is not None else "")
            + (f"  {rec['nfev']} fev" if rec.get("nfev") is not None else "")
            + (f"  [{rec['message']}]" if rec.get("message") else ""))
        prev_t, last_t = last_t, rec["time"]
        if np.isfinite(rec["time"]) and rec["time"] > opts.budget:
            stopped = f"a call took {rec['time']:.0f} s (> {opts.budget:g} s budget)"
            break
        e = rec["error"]
        if e < best_err / 2:
            best_err, since = e, 0
        elif np.isfinite(best_err):
            since += 1
        if since >= 3 and best_err <= 3 * floor:
            stopped = f"error floor (best {best_err:.1e} not halved over three settings; reference accuracy {floor:.0e})"
            break
    if stopped:
        log(f"    {label}: stopped: {stopped}")
    return {"label": label, "points": points, "stopped": stopped, "seconds": time.perf_counter() - t_start,
            "loadavg_start": load0, "loadavg_end": C.loadavg()}


def _output_plan(entry, setup):
    """(t_ref inside t_span, sorted; True if the end of the interval is the only one)."""
    t0, t1 = map(float, setup.t_span)
    ts = sorted(float(t) for t in entry.t_ref if min(t0, t1) < t <= max(t0, t1))
    return ts, len(ts) == 1 and math.isclose(ts[0], t1, rel_tol=1e-12, abs_tol=1e-12)


# ================================================================================== solvers
def run_lobattodae(entry, setup, s, tols, opts):
    from testset import error

    method = L.LobattoIIIAIIIB(stages=s)
    ts, final_only = _output_plan(entry, setup)
    kw = {"save_every": "final"} if final_only else {"t_eval": ts}

    def call(tol):
        return L.solve(setup.problem, method, setup.t_span, setup.q0, setup.p0, args=setup.args,
                       rtol=tol, atol=tol, throw=False, **kw)

    def post(sol):
        st = sol.stats
        n, nrej = int(st["n_steps"]), int(st["n_rejected"])
        rec = {"ok": bool(sol.success), "steps": n, "rejected": nrej,
               "newton_per_step": round(float(st["n_newton"]) / max(1, n + nrej), 2),
               "jacobians_per_step": round(float(st["n_jacobians"]) / max(1, n + nrej), 2),
               "max_phi": float(st["max_constraint_residual"]),
               "loop_s": float(st["compile_and_run_time"]) if st.get("compile_and_run_time") is not None else None}
        if sol.success:
            rec["error"] = error(entry, np.asarray(sol.t), np.asarray(sol.q), np.asarray(sol.p))
        else:
            rec.update(error=math.inf, message=str(sol.message)[:300])
        return rec

    return sweep(f"lobattodae s={s}", tols, call, post, opts, entry.ref_accuracy)


class DiffraxRunner:
    """One jitted ``diffeqsolve`` (tolerance traced) per problem and solver."""

    def __init__(self, rhs_jax, solver: str, t0: float, ts):
        import diffrax
        import jax
        import jax.numpy as jnp

        term = diffrax.ODETerm(lambda t, y, a: rhs_jax(t, y))
        slv = {"Dopri8": diffrax.Dopri8, "Kvaerno5": diffrax.Kvaerno5}[solver]()
        self._ts = jnp.asarray(ts, jnp.float64)
        self._t0 = float(t0)

        @jax.jit
        def run(t0_, ts_, y0, tol):
            sol = diffrax.diffeqsolve(term, slv, t0_, ts_[-1], None, y0,
                                      stepsize_controller=diffrax.PIDController(rtol=tol, atol=tol),
                                      saveat=diffrax.SaveAt(ts=ts_), max_steps=MAX_STEPS,
                                      adjoint=diffrax.ForwardMode(), throw=False)
            return sol.ys, sol.stats["num_accepted_steps"], sol.stats["num_steps"], \
                sol.result == diffrax.RESULTS.successful

        self._run = run

    def __call__(self, y0, tol):
        import jax
        import jax.numpy as jnp

        ys, nacc, nsteps, ok = jax.block_until_ready(
            self._run(jnp.float64(self._t0), self._ts, jnp.asarray(y0, jnp.float64), jnp.float64(tol)))
        return np.asarray(ys), int(nacc), int(nsteps), bool(ok)


def run_diffrax(entry, setup, ode: IndexOneODE, solver: str, tols, opts):
    from testset import error

    ts, _ = _output_plan(entry, setup)
    runner = DiffraxRunner(ode.rhs_jax, solver, setup.t_span[0], ts)

    def post(out):
        ys, nacc, nsteps, ok = out
        rec = {"ok": ok, "steps": nacc, "rejected": nsteps - nacc}
        if ok and np.all(np.isfinite(ys)):
            Q, Pm = ode.to_qp(ys)
            rec["error"] = error(entry, np.asarray(ts), Q, Pm)
        else:
            rec.update(error=math.inf, message="diffrax: not successful (max_steps or step size)")
        return rec

    return sweep(f"diffrax {solver}", tols, lambda tol: runner(ode.y0, tol), post, opts, entry.ref_accuracy)


def run_scipy(entry, setup, ode: IndexOneODE, method: str, tols, opts):
    from scipy.integrate import solve_ivp
    from testset import error

    ts, final_only = _output_plan(entry, setup)
    kw = {} if final_only else {"t_eval": ts}

    def call(tol):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # scipy warns when rtol is below 100 eps
            return solve_ivp(ode.rhs, setup.t_span, ode.y0, method=method, rtol=tol, atol=tol, **kw)

    def post(r):
        rec = {"ok": bool(r.success), "nfev": int(r.nfev), "njev": int(getattr(r, "njev", 0) or 0),
               "steps": (len(r.t) - 1) if final_only else None}
        if r.success:
            Y = r.y.T[-1:] if final_only else r.y.T
            Q, Pm = ode.to_qp(Y)
            rec["error"] = error(entry, r.t[-1:] if final_only else r.t, Q, Pm)
        else:
            rec.update(error=math.inf, message=str(r.message)[:300])
        return rec

    return sweep(f"scipy {method}", tols, call, post, opts, entry.ref_accuracy)


def run_ida(entry, setup, tols, opts):
    import jax.numpy as jnp
    from testset import error

    problem, args = setup.problem, setup.args
    n = int(np.size(setup.q0))
    t0 = jnp.asarray(float(setup.t_span[0]))
    m = int(np.size(problem.phi(t0, jnp.asarray(setup.q0), jnp.asarray(setup.p0), args)))
    lam0 = np.asarray(L.consistent_lambda(problem, t0, jnp.asarray(setup.q0), jnp.asarray(setup.p0),
                                          jnp.zeros(m), args, iterations=3))
    ida = IDABaseline(problem, args, n, m)
    ts, final_only = _output_plan(entry, setup)
    span = (float(setup.t_span[0]), float(setup.t_span[1])) if final_only else [float(setup.t_span[0])] + ts

    def call(tol):
        return ida.solve(span, setup.q0, setup.p0, lam0, tol, tol)

    def post(r):
        # with output times IDA returns only those rows: its step count is not known then
        rec = {"ok": bool(r.success), "steps": r.n_steps if final_only else None, "nfev": r.nfev, "njev": r.njev}
        t = np.atleast_1d(r.t)
        if r.success and np.isclose(t[-1], setup.t_span[1]):
            rec["error"] = error(entry, t, r.y[:, :n], r.y[:, n:2 * n])
        else:
            rec.update(error=math.inf, message=r.message[:300])
        return rec

    return sweep("SUNDIALS IDA", tols, call, post, opts, entry.ref_accuracy)


# =================================================================================== driver
def run_problem(entry, opts) -> dict:
    t_start = time.perf_counter()
    setup = entry.build()
    tols = half_decades(1e-4, 1e-12) if opts.half_decades else [10.0 ** -k for k in range(4, 13)]
    out = {"source": entry.source, "t_span": list(setup.t_span), "t_ref": list(entry.t_ref),
           "compare": entry.compare, "ref_accuracy": entry.ref_accuracy, "tols": tols,
           "loadavg_start": C.loadavg(), "sweeps": {}}
    builder = ODE_FORMS.get(entry.name, generic_jax_ode)
    ode = None
    if any(s in opts.solvers for s in ("Dopri8", "Kvaerno5", "DOP853", "Radau")):
        ode = builder(entry, setup)
        out["ode"] = {"how": ode.how, "validation": ode.validation}
        log(f"  index-1 ODE: {ode.how}")
        if ode.validation:
            log(f"  validation: {json.dumps(C.jsonable(ode.validation))}")
            if not ode.validation.get("ok", True):
                log("  VALIDATION FAILED: the ODE solvers are skipped")
                ode = None
    sw = out["sweeps"]

    def save_partial():
        if opts.partial_save is not None:
            opts.partial_save(entry.name, out)

    if "lobattodae" in opts.solvers:
        for s in opts.stages:
            sw[f"s={s}"] = run_lobattodae(entry, setup, s, tols, opts)
            save_partial()
    if ode is not None:
        for solver in ("Dopri8", "Kvaerno5"):
            if solver in opts.solvers:
                sw[solver] = run_diffrax(entry, setup, ode, solver, tols, opts)
                save_partial()
        for method in ("DOP853", "Radau"):
            if method in opts.solvers:
                if ode.rhs is None:
                    sw[method] = {"label": f"scipy {method}", "points": [], "stopped": "",
                                  "skipped": "no hand-written NumPy right-hand side for this problem"}
                    continue
                sw[method] = run_scipy(entry, setup, ode, method, tols, opts)
                save_partial()
    if "IDA" in opts.solvers:
        ok, why = ida_available()
        out["ida"] = why
        if ok:
            sw["IDA"] = run_ida(entry, setup, tols, opts)
    out["summary"] = summarize(out)
    out["loadavg_end"] = C.loadavg()
    out["seconds"] = time.perf_counter() - t_start
    return out


# ================================================================================== summary
def _front_input(points, key):
    return [{"err": p["error"], "wall_s": p[key]} for p in points
            if isinstance(p.get("error"), (int, float)) and isinstance(p.get(key), (int, float))
            and math.isfinite(p["error"]) and p["error"] > 0 and math.isfinite(p[key])]


def summarize(entry_out: dict, key: str = "time") -> dict:
    sw = entry_out["sweeps"]
    t = {k: time_at(_front_input(v["points"], key), TARGET) for k, v in sw.items()}
    ours = {k: v for k, v in t.items() if k.startswith("s=") and v is not None}
    best = min(ours, key=ours.get) if ours else None
    tb = ours.get(best) if best else None

    def ratio(other):
        return tb / t[other] if tb is not None and t.get(other) else None

    return {"key": key, "time_at_1e-8": t, "ours_best_s": best, "ours": tb,
            "ours_over": {k: ratio(k) for k in ("Dopri8", "Kvaerno5", "DOP853", "Radau", "IDA")}}


def _fmt_s(x: float) -> str:
    return f"{x:.3g} s" if x >= 1 else f"{1e3 * x:.3g} ms"


def table(out: dict, key: str = "time") -> str:
    rows = []
    for name, e in out["problems"].items():
        sm = summarize(e, key)
        t = sm["time_at_1e-8"]
        ms = lambda k: "–" if t.get(k) is None else _fmt_s(t[k])  # noqa: E731
        ours = [f"s={s}: {ms(f's={s}')}" for s in STAGES if f"s={s}" in t]
        r = sm["ours_over"]
        fr = lambda x: "–" if x is None else f"{x:.2g}"  # noqa: E731
        rows.append([name, "; ".join(ours), sm["ours_best_s"] or "not reached", ms("Dopri8"), ms("Kvaerno5"),
                     ms("DOP853"), ms("Radau"), ms("IDA"), fr(r["Dopri8"]), fr(r["DOP853"]), fr(r["Radau"]),
                     fr(r["Kvaerno5"]), fr(r["IDA"])])
    return C.md_table(["problem", "lobattodae", "best", "Dopri8", "Kvaerno5", "DOP853", "Radau", "IDA",
                       "ours/Dopri8", "ours/DOP853", "ours/Radau", "ours/Kvaerno5", "ours/IDA"], rows)


# ===================================================================================== plot
STYLE = {"s=3": ("#9ecae1", "o"), "s=4": ("#4292c6", "s"), "s=5": ("#08519c", "D"), "s=6": ("#3f007d", "p"),
         "Dopri8": ("#d62728", "v"), "Kvaerno5": ("#8c564b", "X"), "DOP853": ("#ff7f0e", "^"),
         "Radau": ("#2ca02c", "<"), "IDA": ("#9467bd", "P")}
LABEL = {"Dopri8": "diffrax Dopri8 (jit, JAX rhs)", "Kvaerno5": "diffrax Kvaerno5 (jit, JAX rhs)",
         "DOP853": "scipy DOP853 (NumPy rhs)", "Radau": "scipy Radau (NumPy rhs, FD Jacobian)",
         "IDA": "SUNDIALS IDA (index 2, JAX residual)"}


def plot(name: str, e: dict, path: str, meta: dict) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax, ax2) = plt.subplots(1, 2, figsize=(14, 6.4))
    floor = float(e["ref_accuracy"])
    for key, sw in e["sweeps"].items():
        pts = [p for p in sw["points"] if math.isfinite(float(p["error"])) and math.isfinite(float(p["time"]))]
        if not pts:
            continue
        color, marker = STYLE.get(key, ("black", "x"))
        label = f"lobattodae {key}" if key.startswith("s=") else LABEL.get(key, key)
        lw = 2.0 if key.startswith("s=") else 1.4
        err = [max(float(p["error"]), 1e-16) for p in pts]
        ax.loglog([p["time"] for p in pts], err, "-", color=color, marker=marker, ms=5, lw=lw, label=label)
        ax2.loglog([p["tol"] for p in pts], err, "-", color=color, marker=marker, ms=5, lw=lw)
    for a in (ax, ax2):
        a.axhspan(1e-17, floor, color="0.88", zorder=0)
        a.axhline(TARGET, color="gray", lw=1, ls=":")
        a.grid(True, which="major", alpha=0.3)
        a.set_ylabel("error  max |y − y_ref| / (1 + |y_ref|)")
    tl = np.array([1e-13, 1e-3])
    ax2.loglog(tl, tl, "k--", lw=1, label="error = rtol")
    ax2.loglog(tl, 30 * tl, "k:", lw=1, label="error = 30·rtol")
    errs = [float(p["error"]) for sw in e["sweeps"].values() for p in sw["points"]
            if math.isfinite(float(p["error"])) and float(p["error"]) > 0]
    lo = max(min(errs + [floor]) / 3, 1e-16) if errs else 1e-14
    hi = min(max(errs + [1e-3]) * 3, 10.0) if errs else 1.0
    for a in (ax, ax2):
        a.set_ylim(lo, hi)
    ax2.set_xlim(3e-13, 3e-4)
    ax2.invert_xaxis()
    for a in (ax, ax2):
        a.text(0.005, TARGET, " 1e-8", transform=a.get_yaxis_transform(), va="bottom", color="gray", fontsize=8)
        a.text(0.005, floor, " reference accuracy", transform=a.get_yaxis_transform(), va="top",
               color="0.4", fontsize=8)
    t_ref = e["t_ref"]
    ax.set_title(f"{name}: error at t = {', '.join(f'{t:g}' for t in t_ref)} vs wall time")
    ax.set_xlabel("wall time per solve [s] (best of 3 after a warm-up call; compilation excluded)")
    ax2.set_title("error vs requested tolerance (rtol = atol)")
    ax2.set_xlabel("rtol = atol")
    fig.legend(*ax.get_legend_handles_labels(), loc="lower center", ncol=5, fontsize=8.5, frameon=False,
               bbox_to_anchor=(0.5, 0.03))
    ax2.legend(fontsize=8, loc="upper right")
    la = e.get("loadavg_start") or ["?"]
    fig.text(0.01, 0.005, f"{meta.get('machine', {}).get('cpu', '')}, {meta.get('machine', {}).get('cpu_count', '?')} "
             f"CPUs, load average {la[0]} at start, {e.get('loadavg_end', ['?'])[0]} at end; XLA CPU pool 1 thread; "
             + (f"process pinned to CPU {meta['pin_cpu']}; " if meta.get("pin_cpu") is not None else "process not pinned; ")
             + "lobattodae: whole solve() call; shaded: below the reference's own accuracy",
             fontsize=7, color="gray")
    fig.tight_layout(rect=(0, 0.11, 1, 1))
    fig.savefig(path, dpi=110)
    plt.close(fig)
    log(f"  wrote {path}")


# ===================================================================================== main
def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--problems", nargs="+", default=["andrews"], help="names of testset.PROBLEMS, or 'all'")
    ap.add_argument("--solvers", nargs="+", default=list(SOLVERS), choices=SOLVERS)
    ap.add_argument("--stages", nargs="+", type=int, default=list(STAGES))
    ap.add_argument("--half-decades", action="store_true", help="tolerances in half decades (default: decades)")
    ap.add_argument("--no-ida", action="store_true", help="skip SUNDIALS IDA")
    ap.add_argument("--budget", type=float, default=20.0, help="stop a sweep after a call this long [s]")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--repeat-limit", type=float, default=5.0, help="a call longer than this is not repeated [s]")
    ap.add_argument("--pin-cpu", type=int, default=None, metavar="CPU",
                    help="run the whole process on this one CPU (os.sched_setaffinity, before JAX starts)")
    ap.add_argument("--tag", default="", help="suffix of the output names: testset_wp<tag>.json, testset_wp<tag>_<name>.png")
    ap.add_argument("--out", default=None, help="the JSON (default benchmarks/results/testset_wp<tag>.json)")
    ap.add_argument("--replot", action="store_true", help="redraw the PNGs and tables from the JSON")
    a = ap.parse_args(argv)
    if a.pin_cpu is not None:  # before JAX creates its threads: they inherit the affinity
        os.sched_setaffinity(0, {a.pin_cpu})
    L.set_cpu_threads(1)  # before the first JAX computation; applies to every solver
    if a.out is None:
        a.out = os.path.join(RESULTS_DIR, f"testset_wp{a.tag}.json")
    if a.no_ida:
        a.solvers = [s for s in a.solvers if s != "IDA"]
    out = {"meta": {}, "problems": {}}
    if os.path.exists(a.out):
        with open(a.out) as fh:
            out = json.load(fh)
    png = lambda name: os.path.join(os.path.dirname(os.path.abspath(a.out)), f"testset_wp{a.tag}_{name}.png")  # noqa: E731
    if a.replot:
        for name, e in out["problems"].items():
            plot(name, e, png(name), e.get("meta", out.get("meta", {})))
        print(table(out, "time"))
        print()
        print(table(out, "cpu_time"))
        return 0

    from testset import PROBLEMS

    names = list(PROBLEMS) if a.problems == ["all"] else a.problems
    for nm in names:
        if nm not in PROBLEMS:
            ap.error(f"unknown problem {nm!r}; known: {', '.join(PROBLEMS)}")
    start = time.perf_counter()
    meta = {"date": datetime.datetime.now().isoformat(timespec="seconds"), "machine": C.machine_info(),
            "command": "PYTHONPATH=src .venv/bin/python benchmarks/testset_wp.py " + " ".join(sys.argv[1:]),
            "lobattodae": getattr(L, "__version__", None), "source_revision": source_revision(),
            "ida": ida_available()[1],
            "loadavg_start": C.loadavg(), "budget_s": a.budget, "repeats": a.repeats,
            "repeat_limit_s": a.repeat_limit, "solvers": a.solvers, "stages": a.stages,
            "cpu_threads": {k: os.environ.get(k) for k in ("PJRT_NPROC", "NPROC")},
            "pin_cpu": a.pin_cpu, "cpu_affinity": sorted(os.sched_getaffinity(0))}
    log(f"testset_wp: {meta['command']}  (load average {meta['loadavg_start']})")

    def partial_save(name, e):
        out["problems"][name] = e
        out["meta"] = meta
        C.write_json(out, a.out)

    a.partial_save = partial_save
    for nm in names:
        log(f"\n=== {nm} ===")
        e = run_problem(PROBLEMS[nm], a)
        e["meta"] = meta  # the run that produced this problem's entry (a later --problems run keeps it)
        out["problems"][nm] = e
        meta["loadavg_end"] = C.loadavg()
        meta["wall_seconds"] = time.perf_counter() - start
        out["meta"] = meta
        C.write_json(out, a.out)
        plot(nm, e, png(nm), meta)
        log(f"  ({e['seconds']:.0f} s for {nm})")
    out = json.loads(json.dumps(C.jsonable(out)))
    log(f"\nWall time at error {TARGET:g} (Pareto front, log-log interpolation); ours = lobattodae, best s:\n")
    log(table(out, "time"))
    log("\nThe same from the process CPU time of the best call:\n")
    log(table(out, "cpu_time"))
    log(f"\n({meta['wall_seconds']:.0f} s in all; load average {meta['loadavg_start']} -> {meta['loadavg_end']})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
