r"""What the competitors integrate, written as a user of each would write it.

* **Reduced index-1 ODEs** ``y' = F(t, y)`` (:class:`ReducedODE`): λ eliminated through the
  hidden constraint ``φ_t + φ_q f + φ_p g(λ) = 0`` (g is affine in λ, so the elimination is
  exact). Each comes as a plain Python/NumPy right-hand side for scipy (``math`` on floats: on
  Python floats ``math.sin`` is several times faster than ``numpy.sin``) and as ``jax.numpy``
  for diffrax: the knife edge, the Chaplygin sleigh and the servo-driven sleigh by hand, the
  falling disk generated with SymPy (:mod:`lib.falling_disk`), Andrews' squeezer in
  ``y = (q, w)`` at the acceleration level; any other problem in JAX only, from its own
  functions (:func:`hidden_constraint`).
* **Index-2 residuals** ``F(t, y, y') = [q' − f, p' − g(λ), φ]``, ``y = (q, p, λ)``, and their
  exact Jacobians ``∂F/∂y`` for IDA (:class:`DAEResidual`): by hand (sleigh), SymPy-generated
  (falling disk), or the problem's own JAX functions compiled ahead of time
  (:func:`jax_dae`).

Each is validated against the problem's own functions before it is timed
(:func:`validate_ode`, :func:`validate_dae`).
"""

from __future__ import annotations

import math
import time
import warnings
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from . import falling_disk as fd
from .timing import best_of

#: Largest relative difference from the problem's own functions a right-hand side may have.
VALID = 1e-12


def _split(n: int) -> Callable:
    def to_qp(Y):
        Y = np.atleast_2d(Y)
        return Y[:, :n], Y[:, n:]

    return to_qp


@dataclass
class ReducedODE:
    """``y' = F(t, y)`` with the map to and from the problem's ``(q, p)``.

    ``rhs(t, y)``: plain Python/NumPy for scipy (None: no hand-written one, scipy is skipped);
    ``rhs_jax(t, y, params)``: ``jax.numpy`` for diffrax; ``phi(Q, P)``: NumPy, vectorised over
    rows (the constraint on a trajectory; None where not written); ``to_qp(Y) -> (Q, P)`` for
    rows ``Y``; ``from_qp(q, p) -> y``."""

    name: str
    n: int
    rhs: Callable | None
    rhs_jax: Callable
    how: str
    params: tuple = ()
    phi: Callable | None = None
    to_qp: Callable | None = None
    from_qp: Callable = lambda q, p: np.r_[q, p]
    build_seconds: float = 0.0
    validation: dict = field(default_factory=dict)

    def __post_init__(self):
        if self.to_qp is None:
            self.to_qp = _split(self.n)


# ---------------------------------------------------------------------------------- by hand
def knife_edge(args) -> ReducedODE:
    """``v = (p_x/m, p_y/m, p_θ/J)``, ``μ = (−sin θ, cos θ, 0)``,
    ``λ = m (g cos θ + ω (cos θ v_x + sin θ v_y))`` (valid at any (q, p)),
    ``p' = (−sin θ λ, −m g + cos θ λ, 0)``."""
    m, J, g = float(args.m), float(args.J), float(args.g)
    sin, cos = math.sin, math.cos

    def rhs(t, y):
        _, _, th, px, py, pth = y.tolist()
        s, c = sin(th), cos(th)
        vx, vy, w = px / m, py / m, pth / J
        lam = m * (g * c + w * (c * vx + s * vy))
        return np.array([vx, vy, w, -s * lam, -m * g + c * lam, 0.0])

    def rhs_jax(t, y, params):
        import jax.numpy as jnp

        m_, J_, g_ = params
        th, px, py, pth = y[2], y[3], y[4], y[5]
        s, c = jnp.sin(th), jnp.cos(th)
        vx, vy, w = px / m_, py / m_, pth / J_
        lam = m_ * (g_ * c + w * (c * vx + s * vy))
        return jnp.stack([vx, vy, w, -s * lam, -m_ * g_ + c * lam, jnp.zeros_like(th)])

    def phi(q, p):
        q, p = np.atleast_2d(q), np.atleast_2d(p)
        return (-np.sin(q[:, 2]) * p[:, 0] + np.cos(q[:, 2]) * p[:, 1]) / m

    return ReducedODE("knife-edge", 3, rhs, rhs_jax, "written by hand (math.sin/cos on floats)", (m, J, g), phi)


def sleigh(args) -> ReducedODE:
    """``v = (p_x/m, p_y/m, p_θ/I)``, ``μ = (−sin θ, cos θ, −a)``, ``p' = μᵀλ`` (H does not
    depend on q), and differentiating ``φ = μ v`` along the flow,
    ``λ = ω (cos θ v_x + sin θ v_y) / (1/m + a²/I)`` with ``ω = p_θ/I`` (valid at any (q, p); on
    the constraint it is the closed form's ``I m v ω / (I + m a²)``)."""
    m, I, a = float(args.m), float(args.I), float(args.a)  # noqa: E741
    sin, cos = math.sin, math.cos
    den = 1.0 / m + a * a / I

    def rhs(t, y):
        _, _, th, px, py, pth = y.tolist()
        s, c = sin(th), cos(th)
        vx, vy, w = px / m, py / m, pth / I
        lam = w * (c * vx + s * vy) / den
        return np.array([vx, vy, w, -s * lam, c * lam, -a * lam])

    def rhs_jax(t, y, params):
        import jax.numpy as jnp

        m_, I_, a_ = params
        th, px, py, pth = y[2], y[3], y[4], y[5]
        s, c = jnp.sin(th), jnp.cos(th)
        vx, vy, w = px / m_, py / m_, pth / I_
        lam = w * (c * vx + s * vy) / (1.0 / m_ + a_ * a_ / I_)
        return jnp.stack([vx, vy, w, -s * lam, c * lam, -a_ * lam])

    def phi(q, p):
        q, p = np.atleast_2d(q), np.atleast_2d(p)
        return (-np.sin(q[:, 2]) * p[:, 0] + np.cos(q[:, 2]) * p[:, 1]) / m - a * p[:, 2] / I

    return ReducedODE("sleigh", 3, rhs, rhs_jax, "written by hand (math.sin/cos on floats)", (m, I, a), phi)


def servo_sleigh(params: dict) -> ReducedODE:
    """The servo-driven sleigh (``testset.servo_sleigh``): ``q' = (p_x/m, p_y/m, p_θ/I)``,
    ``p' = (F cos θ, F sin θ, τ) + μᵀλ``, ``μ = (−sin θ, cos θ, −a)``; differentiating
    ``φ = μ q'`` along the flow gives ``λ = (ω (cos θ x' + sin θ y') + a τ / I) / (1/m + a²/I)``.
    (Not the body-velocity ODE the reference was computed with.)"""
    m, I, a, cv, cw = (float(params[k]) for k in ("m", "I", "a", "c_v", "c_w"))  # noqa: E741
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

    def rhs_jax(t, y, _):
        import jax.numpy as jnp

        th, px, py, pth = y[2], y[3], y[4], y[5]
        s, c = jnp.sin(th), jnp.cos(th)
        xd, yd, w = px / m, py / m, pth / I
        v = c * xd + s * yd
        F = -cv * (v - (1.0 + 0.5 * jnp.sin(t)))
        tau = -cw * (w - 0.8 * jnp.cos(0.5 * t))
        lam = (w * v + a * tau / I) / den
        return jnp.stack([xd, yd, w, F * c - s * lam, F * s + c * lam, tau - a * lam])

    return ReducedODE("servo-sleigh", 3, rhs, rhs_jax,
                      "(q, p), λ from the hidden constraint, by hand (NumPy: math on floats)")


# --------------------------------------------------------------------------- falling disk
def falling_disk(args) -> ReducedODE:
    """Generated with SymPy's ``lambdify(cse=True)``. For scipy the scalar functions come from
    ``math`` where it has them, or from NumPy if that is faster (both measured, in ``how``);
    for diffrax from ``jax.numpy``."""
    import sympy as sp

    t0 = time.perf_counter()
    q, p, prm, exprs, phi_exprs = fd.reduced_ode()
    params = fd.values(args)
    f_math = sp.lambdify([q, p, prm], exprs, ["math", "numpy"], cse=True)
    f_np = sp.lambdify([q, p, prm], exprs, "numpy", cse=True)
    f_jax = sp.lambdify([q, p, prm], exprs, "jax", cse=True)
    f_phi = sp.lambdify([q, p, prm], phi_exprs, "numpy", cse=True)
    build = time.perf_counter() - t0

    y_test, calls = [0.1, -0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9, 1.0], 300
    cost = {}
    for label, f in (("math", f_math), ("numpy", f_np)):
        def batch(f=f):
            for _ in range(calls):
                np.array(f(y_test[:5], y_test[5:], params))

        cost[label] = 1e6 * best_of(batch, 3, first=True).best / calls
    f_fast = f_math if cost["math"] <= cost["numpy"] else f_np

    def rhs(t, y):
        yl = y.tolist()
        return np.array(f_fast(yl[:5], yl[5:], params))

    def rhs_jax(t, y, prm_):
        import jax.numpy as jnp

        return jnp.stack(f_jax([y[i] for i in range(5)], [y[5 + i] for i in range(5)], prm_))

    def phi(qq, pp):
        qq, pp = np.atleast_2d(qq), np.atleast_2d(pp)
        r = f_phi(list(qq.T), list(pp.T), params)
        return np.stack([np.broadcast_to(np.asarray(x, float), (qq.shape[0],)) for x in r], axis=1)

    how = (f"SymPy {sp.__version__} lambdify(cse=True): {cost['math']:.1f} µs/call with math, "
           f"{cost['numpy']:.1f} µs/call with numpy -> using {'math' if f_fast is f_math else 'numpy'}")
    return ReducedODE("falling-disk", 5, rhs, rhs_jax, how, params, phi, build_seconds=build)


# ------------------------------------------------------------------------- Andrews' squeezer
def _andrews_numpy_rhs(P: dict) -> Callable:
    """``y = (q, w)``: plain Python/NumPy, by hand from the test set's ``andrews.f`` (M, f, G and
    the acceleration-level term g_qq(w, w)); ``rhs.lam(y)`` gives the multipliers."""
    sin, cos, sqrt = math.sin, math.cos, math.sqrt
    m1, m2, m3, m4, m5, m6, m7 = (P[f"m{k}"] for k in range(1, 8))
    i1, i2, i3, i4, i5, i6, i7 = (P[f"i{k}"] for k in range(1, 8))
    rr, d, da, ra, e, ea = P["rr"], P["d"], P["da"], P["ra"], P["e"], P["ea"]
    ss, sa, sb, sc, sd = P["ss"], P["sa"], P["sb"], P["sc"], P["sd"]
    ta, tb, u, ua, ub = P["ta"], P["tb"], P["u"], P["ua"], P["ub"]
    zf, zt, fa, mom, c0, l0 = P["zf"], P["zt"], P["fa"], P["mom"], P["c0"], P["l0"]
    xb, yb, xc, yc = P["xb"], P["yb"], P["xc"], P["yc"]
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


def _andrews_jax_accel(A) -> Callable:
    """``(w', λ)`` in ``jax.numpy`` from the test set module's functions; g_qq by ``jax.jvp``."""
    import jax
    import jax.numpy as jnp

    def accel(q, w):
        M, G = A.mass_matrix(q), A.constraint_jacobian(q)
        _, dG = jax.jvp(A.constraint_jacobian, (q,), (w,))  # D_q G(q)[w]
        K = jnp.block([[M, G.T], [G, jnp.zeros((G.shape[0], G.shape[0]))]])
        return jnp.linalg.solve(K, jnp.concatenate([A.forces(q, w), -dG @ w]))

    return accel


def andrews(entry) -> ReducedODE:
    """Andrews' squeezer in ``y = (q, w)``, ``q' = w`` and

        [M(q)  G(q)ᵀ] [w']   [ f(q, w)         ]
        [G(q)  0    ] [λ ] = [ −g_qq(q)(w, w)  ]

    (the acceleration-level constraint ``G w' + g_qq(w, w) = 0``), ``g_qq(q)(w, w) = (D_q G(q)[w]) w``;
    NumPy by hand from the test set's ``andrews.f``, JAX from ``testset.andrews`` with ``jax.jvp``.
    Validated before timing: NumPy against JAX at random points, ``w'(0)`` and ``λ(0)`` against
    the test set's values, and a DOP853 run at rtol = atol = 1e-13 that must keep ``g(q) ≈ 0``
    and meet the published reference. The compared p is ``M(q) w``."""
    import jax
    import jax.numpy as jnp
    from scipy.integrate import solve_ivp
    from testset import andrews as A
    from testset import error

    t0 = time.perf_counter()
    n, setup = 7, entry.build()
    rhs, accel = _andrews_numpy_rhs(dict(A.PARAMS)), _andrews_jax_accel(A)

    def rhs_jax(t, y, _):
        return jnp.concatenate([y[n:], accel(y[:n], y[n:])[:n]])

    def to_qp(Y):
        Y = np.atleast_2d(Y)
        Q, W = Y[:, :n], Y[:, n:]
        return Q, np.stack([A.mass_matrix(q) @ w for q, w in zip(Q, W)])

    def from_qp(q, p):
        return np.r_[q, np.linalg.solve(A.mass_matrix(q), p)]

    y0 = from_qp(setup.q0, setup.p0)
    # 1. NumPy against JAX at random points (near the initial configuration and far from it)
    F_jax = jax.jit(rhs_jax)
    lam_jax = jax.jit(lambda y: accel(y[:n], y[n:])[n:])
    rng = np.random.default_rng(0)
    pts = [y0] + [np.r_[np.asarray(A.Q0) + rng.normal(scale=sc, size=n), rng.normal(scale=100.0 * sc, size=n)]
                  for sc in (0.05, 0.3, 1.0, 2.0) for _ in range(3)]
    d_rhs, d_lam = [], []
    for y in pts:
        ref = np.asarray(F_jax(0.0, jnp.asarray(y), ()))
        d_rhs.append(np.max(np.abs(rhs(0.0, y) - ref)) / np.max(np.abs(ref)))
        lref = np.asarray(lam_jax(jnp.asarray(y)))
        d_lam.append(np.max(np.abs(rhs.lam(y) - lref)) / np.max(np.abs(lref)))
    # 2. w'(0), λ(0) against the test set's values (y(15..21), y(22..27) at t = 0)
    err_wdot0 = float(np.max(np.abs(rhs(0.0, y0)[n:] - np.asarray(A.W_DOT0)) / (1 + np.abs(A.W_DOT0))))
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
    val["ok"] = bool(max(d_rhs) <= VALID and max(d_lam) <= 1e-10 and err_wdot0 <= 1e-10 and err_lam0 <= 1e-10
                     and err_ref <= 10 * entry.ref_accuracy and g_max <= 1e-10)
    val["seconds"] = time.perf_counter() - t0
    how = ("y = (q, w); [M Gᵀ; G 0][w'; λ] = [f; −g_qq(w,w)]: NumPy by hand (math on floats, "
           "np.linalg.solve 13×13), JAX from testset.andrews with jax.jvp for g_qq")
    return ReducedODE("andrews", n, rhs, rhs_jax, how, to_qp=to_qp, from_qp=from_qp, validation=val)


def caraxis(entry) -> ReducedODE:
    """The car axis in ``y = (q, u)`` (``p = u``), ``q' = u``, ``k u' = F(t, q) + G(t, q)ᵀλ`` with λ from
    the acceleration-level constraint ``G u' = −c``, ``c = ψ_tt + 2 ψ_tq u + ψ_qq(u, u)``: with
    ``u' = (F + Gᵀλ)/k`` that is the 2×2 system ``(G Gᵀ) λ = −k c − G F``, solved in closed form.
    NumPy by hand (``math`` on floats) from the test set's ``caraxis.f``; JAX from the problem's
    own functions (:func:`hidden_constraint`)."""
    from testset import caraxis as C

    setup = entry.build()
    P = dict(C.PARAMS)
    sin, cos, sqrt = math.sin, math.cos, math.sqrt
    k, big_l, l0, r, w, kg = C.mass(P), P["L"], P["L0"], P["r"], P["w"], C.mass(P) * P["g"]
    out = np.zeros(8)

    def rhs(t, y):
        xl, yl, xr, yr, uxl, uyl, uxr, uyr = y.tolist()
        swt, cwt = sin(w * t), cos(w * t)
        yb, ybd, ybdd = r * swt, r * w * cwt, -r * w * w * swt
        xb = sqrt(big_l * big_l - yb * yb)
        xbd = -yb * ybd / xb
        xbdd = -(ybd * ybd + yb * ybdd + xbd * xbd) / xb
        ll = sqrt(xl * xl + yl * yl)
        lr = sqrt((xr - xb) ** 2 + (yr - yb) ** 2)
        f1, f2 = (l0 - ll) * xl / ll, (l0 - ll) * yl / ll - kg
        f3, f4 = (l0 - lr) * (xr - xb) / lr, (l0 - lr) * (yr - yb) / lr - kg
        dx, dy, dux, duy = xl - xr, yl - yr, uxl - uxr, uyl - uyr
        # G = [[xb, yb, 0, 0], [2dx, 2dy, −2dx, −2dy]]
        c1 = xbdd * xl + ybdd * yl + 2.0 * (xbd * uxl + ybd * uyl)
        c2 = 2.0 * (dux * dux + duy * duy)
        gf1 = xb * f1 + yb * f2
        gf2 = 2.0 * (dx * (f1 - f3) + dy * (f2 - f4))
        a11, a12, a22 = xb * xb + yb * yb, 2.0 * (xb * dx + yb * dy), 8.0 * (dx * dx + dy * dy)
        b1, b2 = -k * c1 - gf1, -k * c2 - gf2
        det = a11 * a22 - a12 * a12
        lam1, lam2 = (a22 * b1 - a12 * b2) / det, (a11 * b2 - a12 * b1) / det
        out[:4] = uxl, uyl, uxr, uyr
        out[4] = (f1 + xb * lam1 + 2.0 * dx * lam2) / k
        out[5] = (f2 + yb * lam1 + 2.0 * dy * lam2) / k
        out[6] = (f3 - 2.0 * dx * lam2) / k
        out[7] = (f4 - 2.0 * dy * lam2) / k
        return out.copy()

    n, m = _sizes(setup.problem, setup.args, setup.q0, setup.p0, setup.t_span[0])
    jax_ode = hidden_constraint(setup.problem, setup.args, n, m)
    how = ("y = (q, u): λ from (G Gᵀ)λ = −k c − G F (2×2, closed form), NumPy by hand (math on floats); "
           "JAX from the problem's f, g, φ by jax.jacfwd")
    return ReducedODE("caraxis", n, rhs, jax_ode.rhs_jax, how)


# ------------------------------------------------------------------------------- any problem
def hidden_constraint(problem, args, n: int, m: int) -> ReducedODE:
    """``(q, p)`` with λ from ``φ_t + φ_q f + φ_p g(λ) = 0`` (``jax.jacfwd`` of the problem's own
    f, g, φ; exact for g affine in λ); JAX only. Also the reference of :func:`validate_ode`."""
    import jax
    import jax.numpy as jnp

    def rhs_jax(t, y, _):
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

    return ReducedODE(getattr(problem, "name", "problem"), n, None, rhs_jax,
                      "(q, p), λ from the hidden constraint by jax.jacfwd of the problem's f, g, φ (JAX only)")


def reduced_ode(name: str, args) -> ReducedODE:
    """The hand-written ODE of a problem of ``lobattodae.examples`` (``args`` its parameters)."""
    if name == "knife-edge":
        return knife_edge(args)
    if name == "sleigh":
        return sleigh(args)
    if name in ("falling-disk", "falling-disk-general"):  # the same equations, other initial values
        return falling_disk(args)
    raise ValueError(f"no index-reduced ODE written for {name!r}")


def testset_ode(entry) -> ReducedODE:
    """The ODE of a problem of the external test set: written for it where a user of scipy would
    have written one, else :func:`hidden_constraint` (JAX only); validated."""
    setup = entry.build()
    if entry.name == "andrews":
        return andrews(entry)
    n, m = _sizes(setup.problem, setup.args, setup.q0, setup.p0, setup.t_span[0])
    if entry.name == "caraxis":
        ode = caraxis(entry)
    elif entry.name == "fekete":
        from testset import fekete as problem_module

        jax_ode = hidden_constraint(setup.problem, setup.args, n, m)
        ode = ReducedODE("fekete", n, problem_module.index1_rhs, jax_ode.rhs_jax,
                         "y = (x, v), λ from the hidden constraint d/dt(x_i·v_i) = 0 in closed form: NumPy "
                         "(vectorised over the 190 pairs) from the test set's fekete.f; JAX from the problem's f, g, φ")
    elif entry.name == "crank":
        from testset import crank as problem_module

        jax_ode = hidden_constraint(setup.problem, setup.args, n, m)
        ode = ReducedODE("crank", n, problem_module.index1_rhs, jax_ode.rhs_jax,
                         "y = (q, v), v' and λ from [M, Gᵀ; G, 0] with the differentiated velocity constraint: "
                         "NumPy from the test set's crank.f (the reference's own ODE); JAX from the problem's f, g, φ")
    elif entry.name in ("knife-edge", "sleigh"):
        ode = reduced_ode(entry.name, setup.args)
    elif entry.name in ("servo-sleigh", "servo-sleigh-rest"):
        from testset import servo_sleigh as problem_module

        ode = servo_sleigh(problem_module.PARAMS)
    else:
        return hidden_constraint(setup.problem, setup.args, n, m)
    ode.validation = validate_ode(ode, setup.problem, setup.args, setup.q0, setup.p0, setup.t_span)
    return ode


def _sizes(problem, args, q0, p0, t0) -> tuple[int, int]:
    import jax.numpy as jnp

    return int(np.size(q0)), int(np.size(problem.phi(jnp.asarray(float(t0)), jnp.asarray(q0), jnp.asarray(p0), args)))


def validate_ode(ode: ReducedODE, problem, args, q0, p0, t_span=(0.0, 0.0), n_points: int = 7, seed: int = 0) -> dict:
    """Largest differences of ``rhs``, ``rhs_jax`` and ``phi`` from the problem's own vector
    field (:func:`hidden_constraint`) and constraint, relative to the largest reference value
    over all points: the initial value, and random points (``y[2]`` -- the tilt or heading --
    in a range where the mass matrices are well conditioned) at random times of ``t_span``."""
    import jax
    import jax.numpy as jnp

    n, m = _sizes(problem, args, q0, p0, t_span[0])
    F = jax.jit(hidden_constraint(problem, args, n, m).rhs_jax)
    phi = jax.jit(lambda t, y: problem.phi(t, y[:n], y[n:], args))
    rng = np.random.default_rng(seed)
    pts = [(float(t_span[0]), ode.from_qp(q0, p0))]
    for _ in range(n_points - 1):
        y = rng.normal(size=2 * n)
        y[2] = rng.uniform(-1.2, 1.2)
        pts.append((float(rng.uniform(*t_span)), y))
    diffs: dict = {"rhs_numpy": [], "rhs_jax": [], "phi": []}
    scale_F = scale_phi = 0.0
    for t, y in pts:
        tj, yj = jnp.float64(t), jnp.asarray(y)
        ref = np.asarray(F(tj, yj, ()))
        scale_F = max(scale_F, np.max(np.abs(ref)))
        if ode.rhs is not None:
            diffs["rhs_numpy"].append(np.max(np.abs(ode.rhs(t, y) - ref)))
        diffs["rhs_jax"].append(np.max(np.abs(np.asarray(ode.rhs_jax(tj, yj, ode.params)) - ref)))
        if ode.phi is not None:
            ph = np.asarray(phi(tj, yj))
            scale_phi = max(scale_phi, np.max(np.abs(ph)))
            diffs["phi"].append(np.max(np.abs(ode.phi(y[:n][None], y[n:][None])[0] - ph)))
    # relative to the largest value over all points (φ vanishes at the consistent initial value)
    out = {"points": len(pts)}
    for key, d in diffs.items():
        if d:
            out[f"{key}_rel_err"] = float(max(d) / max(scale_phi if key == "phi" else scale_F, 1e-300))
    out["ok"] = bool(max(v for k, v in out.items() if k.endswith("_rel_err")) <= VALID)
    return out


# ---------------------------------------------------------------------- index-2 residuals
@dataclass
class DAEResidual:
    """``F(t, y, y') = [q' − f, p' − g(λ), φ] = 0``, ``y = (q, p, λ)``, called from NumPy.

    ``res(t, y, yp) -> (2n+m,)``; ``jac_y(t, y) -> (2n+m, 2n+m)``, the exact ``∂F/∂y``
    (``∂F/∂y'`` is the constant ``diag(1, …, 1, 0, …, 0)``)."""

    name: str
    n: int
    m: int
    res: Callable
    jac_y: Callable
    how: str
    build_seconds: float = 0.0


def sleigh_dae(args) -> DAEResidual:
    """By hand: ``f = (p_x/m, p_y/m, p_θ/I)``, ``g = μᵀλ`` with ``μ = (−sin θ, cos θ, −a)``,
    ``φ = μ f``."""
    m, I, a = float(args.m), float(args.I), float(args.a)  # noqa: E741
    sin, cos = math.sin, math.cos

    def res(t, y, yp):
        _, _, th, px, py, pth, lam = y.tolist()
        s, c = sin(th), cos(th)
        vx, vy, w = px / m, py / m, pth / I
        return np.array([yp[0] - vx, yp[1] - vy, yp[2] - w,
                         yp[3] + s * lam, yp[4] - c * lam, yp[5] + a * lam,
                         -s * vx + c * vy - a * w])

    def jac_y(t, y):
        _, _, th, px, py, pth, lam = y.tolist()
        s, c = sin(th), cos(th)
        J = np.zeros((7, 7))
        J[0, 3] = J[1, 4] = -1.0 / m
        J[2, 5] = -1.0 / I
        J[3, 2], J[3, 6] = c * lam, s
        J[4, 2], J[4, 6] = s * lam, -c
        J[5, 6] = a
        J[6, 2] = (-c * px - s * py) / m
        J[6, 3], J[6, 4], J[6, 5] = -s / m, c / m, -a / I
        return J

    return DAEResidual("sleigh", 3, 1, res, jac_y, "written by hand (math.sin/cos on floats)")


def falling_disk_dae(args) -> DAEResidual:
    """SymPy-generated (:func:`lib.falling_disk.dae`), the exact Jacobian by symbolic
    differentiation, all through ``lambdify(cse=True)`` with ``math`` functions (Python floats)."""
    import sympy as sp

    t0 = time.perf_counter()
    q, p, lam, qd, pd, prm, F, Jy = fd.dae()
    params = fd.values(args)
    f_res = sp.lambdify([q, p, lam, qd, pd, prm], list(F), ["math", "numpy"], cse=True)
    f_jac = sp.lambdify([q, p, lam, prm], list(Jy), ["math", "numpy"], cse=True)
    build = time.perf_counter() - t0

    def res(t, y, yp):
        yl, ypl = y.tolist(), yp.tolist()
        return np.array(f_res(yl[:5], yl[5:10], yl[10:], ypl[:5], ypl[5:10], params))

    def jac_y(t, y):
        yl = y.tolist()
        return np.array(f_jac(yl[:5], yl[5:10], yl[10:], params), dtype=float).reshape(12, 12)

    how = f"SymPy {sp.__version__} lambdify(cse=True) with math functions"
    return DAEResidual("falling-disk", 5, 2, res, jac_y, how, build)


def numpy_dae(name: str, args) -> DAEResidual:
    if name == "sleigh":
        return sleigh_dae(args)
    if name in ("falling-disk", "falling-disk-general"):
        return falling_disk_dae(args)
    raise ValueError(f"no NumPy DAE residual written for {name!r}")


def _residual(problem, args, n: int):
    import jax.numpy as jnp

    def res(t, y, yp):
        q, p, lam = y[:n], y[n:2 * n], y[2 * n:]
        return jnp.concatenate([yp[:n] - problem.f(t, q, p, args), yp[n:2 * n] - problem.g(t, q, p, lam, args),
                                problem.phi(t, q, p, args)])

    return res


def jax_dae(problem, args, n: int, m: int) -> DAEResidual:
    """The residual from the problem's own JAX functions and its ``jax.jacfwd``, compiled ahead
    of time and called from NumPy (one dispatch per call, no retracing)."""
    import jax
    import jax.numpy as jnp

    t0 = time.perf_counter()
    res = _residual(problem, args, n)
    ts, ys = jax.ShapeDtypeStruct((), jnp.float64), jax.ShapeDtypeStruct((2 * n + m,), jnp.float64)
    res_c = jax.jit(res).lower(ts, ys, ys).compile()
    jac_c = jax.jit(jax.jacfwd(lambda t, y: res(t, y, jnp.zeros_like(y)), argnums=1)).lower(ts, ys).compile()
    return DAEResidual(getattr(problem, "name", "problem"), n, m,
                       lambda t, y, yp: np.asarray(res_c(np.float64(t), y, yp)),
                       lambda t, y: np.asarray(jac_c(np.float64(t), y)),
                       "the problem's f, g, φ in JAX, AOT-compiled, called from NumPy", time.perf_counter() - t0)


def validate_dae(dae: DAEResidual, problem, args, q0, p0, lam0, n_points: int = 6, seed: int = 0) -> dict:
    """Largest relative differences of ``dae.res`` and ``dae.jac_y`` from the residual built
    from the problem's own f, g, φ and its JAX Jacobian, at the initial value and random points
    (relative to the largest value)."""
    import jax
    import jax.numpy as jnp

    n, m = dae.n, dae.m
    res = _residual(problem, args, n)
    F, J = jax.jit(res), jax.jit(jax.jacfwd(res, argnums=1))
    rng = np.random.default_rng(seed)
    pts = [(np.r_[q0, p0, lam0], np.zeros(2 * n + m))]
    for _ in range(n_points):
        y = rng.normal(size=2 * n + m)
        y[2] = rng.uniform(-1.2, 1.2)
        pts.append((y, rng.normal(size=2 * n + m)))
    d_r, d_j, s_r, s_j = [], [], [], []
    for y, yp in pts:
        t, yj, ypj = jnp.float64(0.0), jnp.asarray(y), jnp.asarray(yp)
        r_ref, j_ref = np.asarray(F(t, yj, ypj)), np.asarray(J(t, yj, ypj))
        d_r.append(np.max(np.abs(dae.res(0.0, y, yp) - r_ref)))
        d_j.append(np.max(np.abs(dae.jac_y(0.0, y) - j_ref)))
        s_r.append(np.max(np.abs(r_ref)))
        s_j.append(np.max(np.abs(j_ref)))
    err_r, err_j = max(d_r) / max(s_r), max(d_j) / max(s_j)
    return {"points": len(pts), "res_rel_err": float(err_r), "jac_rel_err": float(err_j),
            "ok": bool(max(err_r, err_j) <= VALID)}
