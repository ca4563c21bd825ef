"""Shared helpers of ``benchmarks/engine.py`` (issue #9).

* machine description and load average, best-of-k timing, counting XLA compilations;
* searches for the cheapest setting that meets an error target (a step count for a
  constant-step method, a tolerance for an adaptive one);
* the **index-reduced ODEs** ``y' = F(y)``, ``y = (q, p)``, of the knife edge, the
  Chaplygin sleigh and the falling rolling disk, written as a user of scipy or diffrax
  would write them: the knife edge and the sleigh by hand, the falling disk generated with SymPy from the same Hamiltonian and
  constraint as ``lobattodae.examples`` (``_rolling_disk.py``); each comes as a plain
  Python/NumPy function for ``scipy.integrate.solve_ivp`` and as a JAX function for
  diffrax, and is validated against the library's own JAX vector field;
* a jit-compiled diffrax Dopri8 solve with a PID step-size controller whose tolerance and
  coefficients are arguments (one compilation for all settings).

Only the public API of lobattodae is used (``problem.f``, ``problem.g``, ``problem.phi``
of the example problems, for the validation).
"""

from __future__ import annotations

import contextlib
import datetime
import json
import logging
import math
import os
import platform
import re
import subprocess
import sys
import time
from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np


def log(msg: str = "") -> None:
    print(msg, flush=True)


# ------------------------------------------------------------------------------ machine
def loadavg() -> list[float]:
    try:
        return [round(x, 2) for x in os.getloadavg()]
    except OSError:  # pragma: no cover
        return []


def _version(mod: str) -> str | None:
    try:
        from importlib.metadata import version

        return version(mod)
    except Exception:
        return None


def cpu_model() -> str:
    try:
        with open("/proc/cpuinfo") as fh:
            for line in fh:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown"


def machine_info() -> dict:
    try:
        affinity = len(os.sched_getaffinity(0))
    except AttributeError:  # pragma: no cover
        affinity = None
    return {
        "platform": platform.platform(),
        "machine": platform.machine(),
        "cpu": cpu_model(),
        "cpu_count": os.cpu_count(),
        "cpus_usable": affinity,
        "python": sys.version.split()[0],
        "versions": {m: _version(m) for m in ("jax", "jaxlib", "numpy", "scipy", "diffrax", "equinox", "sympy")},
        "XLA_FLAGS": os.environ.get("XLA_FLAGS", ""),
    }


def gcc_version() -> str | None:
    try:
        out = subprocess.run(["gcc", "--version"], capture_output=True, text=True, timeout=30).stdout
        return out.splitlines()[0] if out else None
    except Exception:
        return None


# ------------------------------------------------------------------------------- timing
def best_of(fn: Callable[[], Any], repeats: int) -> tuple[float, list[float], Any]:
    """``(best wall seconds, all wall seconds, result of the best call)`` of ``repeats`` calls."""
    times, best, best_out = [], math.inf, None
    for _ in range(max(1, repeats)):
        t0 = time.perf_counter()
        out = fn()
        dt = time.perf_counter() - t0
        times.append(dt)
        if dt < best:
            best, best_out = dt, out
    return best, times, best_out


class _CompileLog(logging.Handler):
    _pat = re.compile(r"Finished XLA compilation of (.*) in ([0-9.eE+-]+) sec")

    def __init__(self):
        super().__init__(level=logging.DEBUG)
        self.compiles: list[tuple[str, float]] = []
        self.traces = 0

    def emit(self, record):
        msg = record.getMessage()
        m = self._pat.search(msg)
        if m:
            self.compiles.append((m.group(1), float(m.group(2))))
        elif msg.startswith("Finished tracing"):
            self.traces += 1


@contextlib.contextmanager
def count_compiles():
    """Counts XLA compilations (and tracings) inside the block, through ``jax_log_compiles``.

    Yields a handler with ``.compiles`` (list of ``(name, seconds)``) and ``.traces``.
    """
    import jax

    handler = _CompileLog()
    logger = logging.getLogger("jax")
    old_level, old_flag = logger.level, jax.config.jax_log_compiles
    logger.addHandler(handler)
    logger.setLevel(logging.DEBUG)
    jax.config.update("jax_log_compiles", True)
    try:
        yield handler
    finally:
        jax.config.update("jax_log_compiles", old_flag)
        logger.setLevel(old_level)
        logger.removeHandler(handler)


def compile_summary(handler: _CompileLog) -> dict:
    return {"xla_compilations": len(handler.compiles),
            "xla_compile_s": round(sum(s for _, s in handler.compiles), 4),
            "tracings": handler.traces,
            "largest": [f"{n} {s:.2f}s" for n, s in sorted(handler.compiles, key=lambda c: -c[1])[:3]]}


# ------------------------------------------------------------------------------- search
@dataclass
class Search:
    """Result of a search: the chosen setting, every probe ``setting -> (error, seconds)``."""

    best: Any = None
    probes: dict = field(default_factory=dict)
    message: str = ""

    def table(self):
        return [{"setting": k, "err": e, "seconds": s} for k, (e, s) in sorted(self.probes.items())]


def search_min_steps(err_of_n: Callable[[int], float], n0: int, order: float, target: float,
                     rel: float = 0.03, max_probes: int = 10, budget_s: float = math.inf) -> Search:
    """Smallest step count N with ``err_of_n(N) <= target`` (to ``rel`` relative), assuming
    the error falls with N. ``n0`` is the first probe; the next ones are predicted from
    the method's order (aiming at 0.85·target) until the target is bracketed, then the
    bracket is closed by bisection in log N.
    Two successive probes longer than ``budget_s`` seconds stop the search."""
    out = Search()

    def E(n):
        n = max(2, int(n))
        if n not in out.probes:
            t0 = time.perf_counter()
            e = float(err_of_n(n))
            out.probes[n] = (e if np.isfinite(e) else math.inf, time.perf_counter() - t0)
        return out.probes[n][0]

    def slow():  # the last two probes both over budget (a single slow one may be compilation)
        times = [s for _, s in out.probes.values()]
        return len(times) >= 2 and min(times[-2:]) > budget_s

    e0 = E(n0)
    lo, hi = (None, n0) if e0 <= target else (n0, None)
    # close the bracket: predict from the order (aiming at 0.85·target), at most 8x per probe
    while (lo is None or hi is None) and len(out.probes) < max_probes and not slow():
        ref = hi if lo is None else lo
        e_ref = out.probes[ref][0]
        if np.isfinite(e_ref) and e_ref > 0:
            pred = ref * (e_ref / (0.85 * target)) ** (1.0 / order)
        else:  # a failed run (Newton did not converge): try much smaller steps
            pred = 4.0 * ref
        pred = min(max(pred, ref / 8.0), ref * 8.0)
        if hi is None:
            n = max(int(math.ceil(pred)), int(ref * 1.05) + 1)
        else:
            n = min(int(pred), int(ref / 1.05))
            if n < 2:
                break
        if E(n) <= target:
            hi = n if hi is None else min(hi, n)
        else:
            lo = n if lo is None else max(lo, n)
    while lo is not None and hi is not None and hi > lo * (1 + rel) and hi - lo > 1 \
            and len(out.probes) < max_probes and not slow():
        n = int(round(math.sqrt(lo * hi)))
        if n in (lo, hi):
            break
        if E(n) <= target:
            hi = n
        else:
            lo = n
    out.best = hi
    if hi is None:
        out.message = f"no N tried reached the target (largest tried {max(out.probes)})"
    return out


def search_tolerance(err_of_tol: Callable[[float], float], tol0: float, target: float, tol_min: float,
                     tol_max: float = 1e-3, factor: float = 1.5, max_probes: int = 12,
                     budget_s: float = math.inf) -> Search:
    """Largest tolerance with ``err_of_tol(tol) <= target``, found by steps of 10 from
    ``tol0`` and bisection in log(tol) down to a ratio ``factor``. The error of an adaptive
    solver is not exactly monotone in its tolerance: this finds *a* largest passing
    tolerance of the bracket, as a user tuning it would."""
    out = Search()

    def E(tol):
        tol = float(f"{tol:.3g}")
        if tol not in out.probes:
            t0 = time.perf_counter()
            e = float(err_of_tol(tol))
            out.probes[tol] = (e if np.isfinite(e) else math.inf, time.perf_counter() - t0)
        return out.probes[tol][0], tol

    def slow():  # the last two probes both over budget (a single slow one may be compilation)
        times = [s for _, s in out.probes.values()]
        return len(times) >= 2 and min(times[-2:]) > budget_s

    e, t = E(tol0)
    ok, bad = (t, None) if e <= target else (None, t)
    while (ok is None or bad is None) and len(out.probes) < max_probes and not slow():
        if ok is None:  # tighten
            if bad <= tol_min:
                break
            e, t = E(max(bad / 10.0, tol_min))
            if e <= target:
                ok = t
            else:
                bad = t
        else:  # loosen
            if ok >= tol_max:
                break
            e, t = E(min(ok * 10.0, tol_max))
            if e <= target:
                ok = t
            else:
                bad = t
    while ok is not None and bad is not None and bad / ok > factor and len(out.probes) < max_probes \
            and not slow():
        e, t = E(math.sqrt(ok * bad))
        if t in (ok, bad):
            break
        if e <= target:
            ok = t
        else:
            bad = t
    out.best = ok
    if ok is None:
        best_err = min(e for e, _ in out.probes.values())
        out.message = f"no tolerance down to {min(out.probes):g} reached the target (best error {best_err:.2e})"
    return out


# --------------------------------------------------------------- index-reduced ODEs
@dataclass
class ReducedODE:
    """``y' = F(y)`` for ``y = (q, p)`` with λ eliminated through the hidden constraint.

    ``rhs(t, y)``: plain Python/NumPy, for scipy. ``rhs_jax(t, y, params)``: JAX, for
    diffrax. ``phi(q, p)``: NumPy, vectorised over a leading axis (constraint residual on a
    trajectory). ``params``: tuple of floats passed to ``rhs_jax``."""

    name: str
    n: int
    rhs: Callable
    rhs_jax: Callable
    phi: Callable
    params: tuple
    how: str
    build_seconds: float = 0.0


def knife_edge_ode(args) -> ReducedODE:
    """Knife edge, by hand: ``v = (p_x/m, p_y/m, p_θ/J)``, ``μ = (−sin θ, cos θ, 0)``,
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

    return ReducedODE("knife-edge", 3, rhs, rhs_jax, phi, (m, J, g), "written by hand (math.sin/cos on floats)")


_SYMPY_CACHE: dict = {}


def _falling_disk_sympy():
    """SymPy expressions of the falling disk's index-reduced ODE (PROBLEMS.md §5, the mass
    matrix of ``lobattodae/examples/_rolling_disk.py``):

    ``v = M⁻¹p``; ``H_q,k = −½ vᵀ(∂_k M)v + ∂_k V``; with ``μ = [[1,0,0,0,−R cos φ],
    [0,1,0,0,−R sin φ]]``, differentiating ``φ = μ M⁻¹ p`` along the flow gives
    ``(μM⁻¹μᵀ) λ = μM⁻¹(H_q + Ṁv) − μ̇v``; ``p' = −H_q + μᵀλ``."""
    if "fd" in _SYMPY_CACHE:
        return _SYMPY_CACHE["fd"]
    import sympy as sp

    q = sp.symbols("x y theta phi psi")
    p = sp.symbols("p0:5")
    m, R, g, I1, I3 = sp.symbols("m R g I1 I3", positive=True)
    th, ph = q[2], q[3]
    st, ct, sph, cph = sp.sin(th), sp.cos(th), sp.sin(ph), sp.cos(ph)
    M = sp.zeros(5, 5)
    M[0, 0] = M[1, 1] = m
    M[0, 2], M[0, 3] = -m * R * sph * ct, -m * R * st * cph
    M[1, 2], M[1, 3] = m * R * cph * ct, -m * R * sph * st
    M[2, 2] = I1 + m * R**2
    M[3, 3] = I1 * ct**2 + (I3 + m * R**2) * st**2
    M[3, 4] = -I3 * st
    M[4, 4] = I3
    for i in range(5):
        for j in range(i):
            M[i, j] = M[j, i]
    V = m * g * R * ct
    mu = sp.Matrix([[1, 0, 0, 0, -R * cph], [0, 1, 0, 0, -R * sph]])
    vs = sp.symbols("v0:5")
    v = sp.Matrix(vs)
    Hq = sp.Matrix([-(v.T * M.diff(qk) * v)[0] / 2 + V.diff(qk) for qk in q])
    Mdot_v = sum((M.diff(qk) * v * vs[k] for k, qk in enumerate(q)), sp.zeros(5, 1))
    mudot_v = sum((mu.diff(qk) * v * vs[k] for k, qk in enumerate(q)), sp.zeros(2, 1))
    W = M.LUsolve(mu.T)  # M⁻¹μᵀ
    lam = (mu * W).LUsolve(W.T * (Hq + Mdot_v) - mudot_v)
    pdot = -Hq + mu.T * lam
    sub = dict(zip(vs, M.LUsolve(sp.Matrix(p))))
    vel = list(v.subs(sub))
    exprs = vel + list(pdot.subs(sub))
    phi = list((mu * v).subs(sub))
    out = (q, p, (m, R, g, I1, I3), exprs, phi)
    _SYMPY_CACHE["fd"] = out
    return out


def falling_disk_ode(args) -> ReducedODE:
    """Falling rolling disk, generated with SymPy and ``lambdify(cse=True)``. For scipy the
    scalar functions come from ``math`` where it has them (on Python floats ``math.sin`` is
    several times faster than ``numpy.sin``; both variants are measured in ``how``), for
    diffrax from ``jax.numpy``."""
    import sympy as sp

    t0 = time.perf_counter()
    q, p, prm, exprs, phi_exprs = _falling_disk_sympy()
    params = tuple(float(getattr(args, k)) for k in ("m", "R", "g", "I1", "I3"))
    f_math = sp.lambdify([q, p, prm], exprs, ["math", "numpy"], cse=True)
    f_np = sp.lambdify([q, p, prm], exprs, "numpy", cse=True)
    f_jax = sp.lambdify([q, p, prm], exprs, "jax", cse=True)
    f_phi = sp.lambdify([q, p, prm], phi_exprs, "numpy", cse=True)
    build = time.perf_counter() - t0

    y_test = [0.1, -0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9, 1.0]
    cost = {}
    for label, f in (("math", f_math), ("numpy", f_np)):
        def call(f=f):
            return np.array(f(y_test[:5], y_test[5:], params))
        call()
        k = 300
        best = min(_time_k(call, k) for _ in range(3))
        cost[label] = 1e6 * best / k
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
    return ReducedODE("falling-disk", 5, rhs, rhs_jax, phi, params, how, build)


def sleigh_ode(args) -> ReducedODE:
    """Chaplygin sleigh, by hand: ``v = (p_x/m, p_y/m, p_θ/I)``, ``μ = (−sin θ, cos θ, −a)``,
    ``p' = μᵀλ`` (H does not depend on q), and differentiating ``φ = μ v`` along the flow,
    ``λ = ω (cos θ v_x + sin θ v_y) / (1/m + a²/I)`` with ``ω = p_θ/I`` (valid at any
    (q, p); on the constraint it is the closed form's ``I m v ω / (I + m a²)``)."""
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

    return ReducedODE("sleigh", 3, rhs, rhs_jax, phi, (m, I, a), "written by hand (math.sin/cos on floats)")


def _time_k(fn, k):
    t0 = time.perf_counter()
    for _ in range(k):
        fn()
    return time.perf_counter() - t0


def reduced_ode(name: str, args) -> ReducedODE:
    if name == "knife-edge":
        return knife_edge_ode(args)
    if name in ("falling-disk", "falling-disk-general"):  # same equations, other initial values
        return falling_disk_ode(args)
    if name == "sleigh":
        return sleigh_ode(args)
    raise ValueError(f"no index-reduced ODE written for {name!r}")


# ------------------------------------------------ index-2 DAE residuals for SUNDIALS IDA
@dataclass
class NumpyDAE:
    """The index-2 DAE ``F(t, y, y') = [q' − f, p' − g(λ), φ] = 0``, ``y = (q, p, λ)``, in
    plain Python/NumPy, as a user of IDA would write it (``baselines.IDANumpy`` calls it).

    ``res(t, y, yp) -> (2n+m,)``; ``jac_y(t, y) -> (2n+m, 2n+m)``, the exact ``∂F/∂y``
    (``∂F/∂y'`` is the constant ``diag(1, …, 1, 0, …, 0)``)."""

    name: str
    n: int
    m: int
    res: Callable
    jac_y: Callable
    how: str
    build_seconds: float = 0.0


def sleigh_dae(args) -> NumpyDAE:
    """Chaplygin sleigh, by hand: ``f = (p_x/m, p_y/m, p_θ/I)``, ``g = μᵀλ`` with
    ``μ = (−sin θ, cos θ, −a)``, ``φ = μ f``."""
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

    return NumpyDAE("sleigh", 3, 1, res, jac_y, "written by hand (math.sin/cos on floats)")


def falling_disk_dae(args) -> NumpyDAE:
    """Falling rolling disk (the mass matrix of ``_falling_disk_sympy``), generated with
    SymPy: ``f = v = M⁻¹p``, ``g = ½ vᵀ(∂_k M)v − ∂_k V + μᵀλ``, ``φ = μ v``, and the exact
    Jacobian ``∂F/∂y`` by symbolic differentiation, all through ``lambdify(cse=True)``
    with ``math`` functions (Python floats)."""
    import sympy as sp

    t0 = time.perf_counter()
    if "fd_dae" not in _SYMPY_CACHE:
        q = sp.symbols("x y theta phi psi")
        p = sp.symbols("p0:5")
        lam = sp.symbols("l0:2")
        qd = sp.symbols("qd0:5")
        pd = sp.symbols("pd0:5")
        m, R, g, I1, I3 = prm = sp.symbols("m R g I1 I3", positive=True)
        th, ph = q[2], q[3]
        st, ct, sph, cph = sp.sin(th), sp.cos(th), sp.sin(ph), sp.cos(ph)
        M = sp.zeros(5, 5)
        M[0, 0] = M[1, 1] = m
        M[0, 2], M[0, 3] = -m * R * sph * ct, -m * R * st * cph
        M[1, 2], M[1, 3] = m * R * cph * ct, -m * R * sph * st
        M[2, 2] = I1 + m * R**2
        M[3, 3] = I1 * ct**2 + (I3 + m * R**2) * st**2
        M[3, 4] = -I3 * st
        M[4, 4] = I3
        for i in range(5):
            for j in range(i):
                M[i, j] = M[j, i]
        V = m * g * R * ct
        mu = sp.Matrix([[1, 0, 0, 0, -R * cph], [0, 1, 0, 0, -R * sph]])
        v = M.LUsolve(sp.Matrix(p))
        # -H_q = ½ vᵀ(∂_k M)v − ∂_k V, written with v = M⁻¹p
        gq = sp.Matrix([(v.T * M.diff(qk) * v)[0] / 2 - V.diff(qk) for qk in q]) + mu.T * sp.Matrix(lam)
        F = sp.Matrix(list(sp.Matrix(qd) - v) + list(sp.Matrix(pd) - gq) + list(mu * v))
        y = sp.Matrix(list(q) + list(p) + list(lam))
        Jy = F.jacobian(y)
        _SYMPY_CACHE["fd_dae"] = (q, p, lam, qd, pd, prm, F, Jy)
    q, p, lam, qd, pd, prm, F, Jy = _SYMPY_CACHE["fd_dae"]
    params = tuple(float(getattr(args, k)) for k in ("m", "R", "g", "I1", "I3"))
    f_res = sp.lambdify([q, p, lam, qd, pd, prm], list(F), ["math", "numpy"], cse=True)
    f_jac = sp.lambdify([q, p, lam, prm], list(Jy), ["math", "numpy"], cse=True)
    build = time.perf_counter() - t0

    def res(t, y, yp):
        yl, ypl = y.tolist(), yp.tolist()
        return np.array(f_res(yl[:5], yl[5:10], yl[10:], ypl[:5], ypl[5:10], params))

    def jac_y(t, y):
        yl = y.tolist()
        return np.array(f_jac(yl[:5], yl[5:10], yl[10:], params), dtype=float).reshape(12, 12)

    return NumpyDAE("falling-disk", 5, 2, res, jac_y,
                    f"SymPy {sp.__version__} lambdify(cse=True) with math functions", build)


def numpy_dae(name: str, args) -> NumpyDAE:
    if name == "sleigh":
        return sleigh_dae(args)
    if name in ("falling-disk", "falling-disk-general"):
        return falling_disk_dae(args)
    raise ValueError(f"no NumPy DAE residual written for {name!r}")


def validate_dae(dae: NumpyDAE, ex, n_points: int = 6, seed: int = 0) -> dict:
    """Max relative difference of ``dae.res`` and ``dae.jac_y`` from the residual
    ``[y'_q − f, y'_p − g, φ]`` built from the library's ``problem.f, g, phi`` and its JAX
    Jacobian, at the initial value and random points (relative to the largest value)."""
    import jax
    import jax.numpy as jnp

    n, m, problem, args = dae.n, dae.m, ex.problem, ex.args

    def res_lib(y, yp):
        t = jnp.asarray(0.0)
        q, p, lam = y[:n], y[n:2 * n], y[2 * n:]
        return jnp.concatenate([yp[:n] - problem.f(t, q, p, args), yp[n:2 * n] - problem.g(t, q, p, lam, args),
                                problem.phi(t, q, p, args)])

    F, J = jax.jit(res_lib), jax.jit(jax.jacfwd(res_lib))
    rng = np.random.default_rng(seed)
    pts = [(np.r_[ex.q0, ex.p0, ex.lam0], np.zeros(2 * n + m))]
    for _ in range(n_points):
        y = rng.normal(size=2 * n + m)
        y[2] = rng.uniform(-1.2, 1.2)
        pts.append((y, rng.normal(size=2 * n + m)))
    d_r, d_j, s_r, s_j = [], [], [], []
    for y, yp in pts:
        r_ref, j_ref = np.asarray(F(jnp.asarray(y), jnp.asarray(yp))), np.asarray(J(jnp.asarray(y), jnp.asarray(yp)))
        d_r.append(np.max(np.abs(dae.res(0.0, y, yp) - r_ref)))
        d_j.append(np.max(np.abs(dae.jac_y(0.0, y) - j_ref)))
        s_r.append(np.max(np.abs(r_ref)))
        s_j.append(np.max(np.abs(j_ref)))
    err_r, err_j = max(d_r) / max(s_r), max(d_j) / max(s_j)
    return {"points": len(pts), "res_rel_err": float(err_r), "jac_rel_err": float(err_j),
            "ok": bool(max(err_r, err_j) <= 1e-12)}


def library_vector_field(problem, args, n: int, m: int):
    """The library's own vector field with λ from the hidden constraint, in JAX:
    ``F = (f, g(λ))`` with ``λ`` solving ``φ_q f + φ_p g(λ) = 0`` (g is affine in λ, so
    one linear solve is exact). Uses only ``problem.f, problem.g, problem.phi``."""
    import jax
    import jax.numpy as jnp

    def F(y):
        t = jnp.asarray(0.0)
        q, p = y[:n], y[n:]
        fq = problem.f(t, q, p, args)
        phi_q = jax.jacfwd(lambda qq: problem.phi(t, qq, p, args))(q)
        phi_p = jax.jacfwd(lambda pp: problem.phi(t, q, pp, args))(p)
        g0 = problem.g(t, q, p, jnp.zeros(m), args)
        g_l = jax.jacfwd(lambda lam: problem.g(t, q, p, lam, args))(jnp.zeros(m))
        lam = jnp.linalg.solve(phi_p @ g_l, -(phi_q @ fq + phi_p @ g0))
        return jnp.concatenate([fq, problem.g(t, q, p, lam, args)])

    def phi(y):
        return problem.phi(jnp.asarray(0.0), y[:n], y[n:], args)

    return jax.jit(F), jax.jit(phi)


def validate_ode(ode: ReducedODE, ex, n_points: int = 6, seed: int = 0) -> dict:
    """Max relative difference of ``rhs``, ``rhs_jax`` and ``phi`` from the library's JAX
    vector field and constraint at random points (angles in a range where M is well
    conditioned) and at the initial value; the differences are divided by the largest
    value of the reference over all points."""
    import jax.numpy as jnp

    n, m = ode.n, int(np.size(ex.lam0))
    F_lib, phi_lib = library_vector_field(ex.problem, ex.args, n, m)
    rng = np.random.default_rng(seed)
    pts = [np.r_[ex.q0, ex.p0]]
    for _ in range(n_points):
        y = rng.normal(size=2 * n)
        y[2] = rng.uniform(-1.2, 1.2)  # θ (tilt of the falling disk, heading of the knife edge)
        pts.append(y)
    d_np, d_jax, d_phi, s_F, s_phi = [], [], [], [], []
    for y in pts:
        ref = np.asarray(F_lib(jnp.asarray(y)))
        d_np.append(np.max(np.abs(ode.rhs(0.0, y) - ref)))
        d_jax.append(np.max(np.abs(np.asarray(ode.rhs_jax(0.0, jnp.asarray(y), ode.params)) - ref)))
        s_F.append(np.max(np.abs(ref)))
        ph_ref = np.asarray(phi_lib(jnp.asarray(y)))
        d_phi.append(np.max(np.abs(ode.phi(y[:n][None], y[n:][None])[0] - ph_ref)))
        s_phi.append(np.max(np.abs(ph_ref)))
    # relative to the largest value over all points (φ vanishes at the consistent initial value)
    err_np, err_jax = max(d_np) / max(s_F), max(d_jax) / max(s_F)
    err_phi = max(d_phi) / max(max(s_phi), 1e-300)
    return {"points": len(pts), "rhs_numpy_rel_err": float(err_np), "rhs_jax_rel_err": float(err_jax),
            "phi_rel_err": float(err_phi), "ok": bool(max(err_np, err_jax, err_phi) <= 1e-12)}


# ------------------------------------------------------------------------------ diffrax
class DiffraxDopri8:
    """diffrax Dopri8 on a :class:`ReducedODE`, jit-compiled once: ``t1``, the tolerance
    (``rtol = atol``) and the PID coefficients are traced arguments. ``final`` saves only
    y(t1) (what is timed); ``trajectory`` saves every step (for ‖φ‖)."""

    def __init__(self, ode: ReducedODE, max_steps: int = 10_000_000):
        import diffrax
        import jax

        self.ode = ode
        self._dfx = diffrax
        term = diffrax.ODETerm(lambda t, y, a: ode.rhs_jax(t, y, a))

        def run(t1, y0, tol, pcoeff, icoeff, saveat, n_max):
            return diffrax.diffeqsolve(
                term, diffrax.Dopri8(), 0.0, t1, None, y0, args=ode.params,
                stepsize_controller=diffrax.PIDController(rtol=tol, atol=tol, pcoeff=pcoeff, icoeff=icoeff),
                saveat=saveat, max_steps=n_max, adjoint=diffrax.ForwardMode(), throw=False)

        @jax.jit
        def final(t1, y0, tol, pcoeff, icoeff):
            sol = run(t1, y0, tol, pcoeff, icoeff, diffrax.SaveAt(t1=True), max_steps)
            return sol.ys[-1], sol.stats["num_accepted_steps"], sol.stats["num_steps"], \
                sol.result == diffrax.RESULTS.successful

        def trajectory(t1, y0, tol, pcoeff, icoeff, n_max):
            sol = run(t1, y0, tol, pcoeff, icoeff, diffrax.SaveAt(t0=True, steps=True), n_max)
            return sol.ts, sol.ys

        self._final = final
        self._traj = jax.jit(trajectory, static_argnames="n_max")

    def final(self, t1, y0, tol, pid):
        import jax
        import jax.numpy as jnp

        out = self._final(jnp.float64(t1), jnp.asarray(y0, jnp.float64), jnp.float64(tol),
                          jnp.float64(pid[0]), jnp.float64(pid[1]))
        yT, nacc, nsteps, ok = jax.block_until_ready(out)
        return np.asarray(yT), int(nacc), int(nsteps), bool(ok)

    def trajectory(self, t1, y0, tol, pid, n_steps_hint: int):
        import jax.numpy as jnp

        n_max = 1 << max(4, int(math.ceil(math.log2(max(n_steps_hint, 1) * 1.1 + 16))))
        ts, ys = self._traj(jnp.float64(t1), jnp.asarray(y0, jnp.float64), jnp.float64(tol),
                            jnp.float64(pid[0]), jnp.float64(pid[1]), n_max)
        ts, ys = np.asarray(ts), np.asarray(ys)
        ok = np.isfinite(ts)
        return ts[ok], ys[ok]


# ------------------------------------------------------------------------------- output
def md_table(headers: list[str], rows: list[list[Any]]) -> str:
    def fmt(x):
        if x is None:
            return "–"
        if isinstance(x, float):
            if not np.isfinite(x):
                return str(x)
            return f"{x:.3g}"
        return str(x)

    lines = ["| " + " | ".join(headers) + " |", "|" + "|".join("---" for _ in headers) + "|"]
    lines += ["| " + " | ".join(fmt(x) for x in r) + " |" for r in rows]
    return "\n".join(lines)


def jsonable(x):
    """Replace NaN/inf by strings and NumPy scalars/arrays by Python objects (for json.dump)."""
    if isinstance(x, dict):
        return {str(k): jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [jsonable(v) for v in x]
    if isinstance(x, np.ndarray):
        return jsonable(x.tolist())
    if isinstance(x, (np.floating, float)):
        x = float(x)
        return x if math.isfinite(x) else str(x)
    if isinstance(x, (np.integer,)):
        return int(x)
    if isinstance(x, (np.bool_,)):
        return bool(x)
    return x


def write_json(out: dict, path: str | None) -> None:
    """Write ``out`` (through :func:`jsonable`) to ``path`` if one is given, and say where."""
    if path is None:
        return
    os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
    with open(path, "w") as fh:
        json.dump(jsonable(out), fh, indent=1)
    log(f"\nwrote {path}")


# ------------------------------------------------------------------- fresh-process runs
def child_result(code: str, argv: list[str], env: dict) -> dict:
    """Run ``python -c code *argv`` in a fresh process with ``env`` and return the JSON it
    prints after ``RESULT `` (for settings that are fixed when JAX starts, such as the size of
    XLA's CPU thread pool, or constants read at trace time)."""
    proc = subprocess.run([sys.executable, "-c", code, *argv], env=env, capture_output=True, text=True, check=True)
    line = [ln for ln in proc.stdout.splitlines() if ln.startswith("RESULT ")][-1]
    return json.loads(line[len("RESULT "):])


def save_run(path: str, script: str, t0: float, **data) -> None:
    """Write a run's results with the date, machine, exact command, load and duration."""
    out = {"date": datetime.datetime.now().isoformat(timespec="seconds"), "machine": machine_info(),
           "command": f"PYTHONPATH=src .venv/bin/python benchmarks/{script} " + " ".join(sys.argv[1:]),
           "loadavg": loadavg(), "seconds": time.perf_counter() - t0, **data}
    write_json(out, path)
