"""References for problems without a closed form.

``falling_disk(ex, T, h)``: q(T) of the falling rolling disk from its reduced ODE
(:func:`lib.falling_disk.reduced_ode`'s expressions, evaluated with NumPy in 80-bit extended
precision, ``np.longdouble``, eps = 1.1e-19) integrated with the 5-stage Gauss-Legendre
method (order 10, coefficients from mpmath at 40 digits), constant steps, fixed-point stage
iteration to round-off and compensated summation. :func:`cached` keeps such references in a
JSON file, with the difference to a run at twice the step as their error bound.
"""

from __future__ import annotations

import datetime
import time
from typing import Callable

import numpy as np

from . import falling_disk as fd
from .output import log, read_json, write_json


def gauss_legendre(s: int, dps: int = 40) -> tuple[np.ndarray, np.ndarray]:
    """Gauss-Legendre coefficients (A, b) in ``np.longdouble``, computed with mpmath."""
    import mpmath as mp

    mp.mp.dps = dps
    x0 = np.polynomial.legendre.leggauss(s)[0]
    c = [(1 + mp.findroot(lambda z: mp.legendre(s, z), mp.mpf(float(x)))) / 2 for x in x0]

    def ell(j):
        return lambda t: mp.fprod([(t - c[k]) / (c[j] - c[k]) for k in range(s) if k != j])

    ld = lambda v: np.longdouble(mp.nstr(v, 30))  # noqa: E731  (strtold: full extended precision)
    A = np.array([[ld(mp.quad(ell(j), [0, c[i]])) for j in range(s)] for i in range(s)])
    b = np.array([ld(mp.quad(ell(j), [0, 1])) for j in range(s)])
    return A, b


def falling_disk(ex, T: float, h: float) -> tuple[np.ndarray, dict]:
    """q(T) of the falling disk from ``ex.q0, ex.p0`` (float64 high and low parts stacked),
    and what the integration took."""
    import sympy as sp

    q, p, prm, exprs, _ = fd.reduced_ode()
    f = sp.lambdify([q, p, prm], exprs, "numpy", cse=True)
    params = fd.values(ex.args, np.longdouble)

    def F(Y):
        out = f([Y[:, i] for i in range(5)], [Y[:, 5 + i] for i in range(5)], params)
        return np.stack([np.broadcast_to(np.asarray(o, dtype=np.longdouble), (Y.shape[0],)) for o in out], axis=1)

    A, b = gauss_legendre(5)
    y = np.r_[ex.q0, ex.p0].astype(np.longdouble)
    comp = np.zeros_like(y)
    N = int(round(T / h))
    hh = np.longdouble(T) / N
    eps = np.finfo(np.longdouble).eps
    K = np.tile(F(y[None])[0], (5, 1))
    its, t0 = 0, time.perf_counter()
    for _ in range(N):
        prev = np.inf
        for _ in range(60):
            Kn = F(y[None] + hh * (A @ K))
            d = float(np.max(np.abs(Kn - K)))
            K = Kn
            its += 1
            if d <= 4 * eps * float(np.max(np.abs(K))) or d >= prev:
                break
            prev = d
        inc = hh * (b @ K) - comp  # compensated (Kahan) summation of the increments
        y_new = y + inc
        comp = (y_new - y) - inc
        y = y_new
    hi = y[:5].astype(np.float64)
    lo = (y[:5] - hi.astype(np.longdouble)).astype(np.float64)
    return np.stack([hi, lo]), {"h": float(hh), "steps": N, "stage_iterations_per_step": its / N,
                                "seconds": time.perf_counter() - t0}


def cached(path: str, key: str, compute: Callable[[float], tuple[np.ndarray, dict]], h: tuple[float, float]) -> dict:
    """The reference ``key`` of the file at ``path``: ``compute(h)`` at the fine step ``h[1]``,
    its error bounded by the difference to the coarse step ``h[0]`` (``ref_diff``); computed and
    stored on first use. Returns ``q_ref`` (float64), ``how`` and ``ref_diff``."""
    cache = read_json(path, {})
    if key not in cache:
        log(f"  computing the extended-precision reference ({key}; cached afterwards)")
        coarse, info_c = compute(h[0])
        fine, info_f = compute(h[1])
        diff = (fine[0].astype(np.longdouble) + fine[1]) - (coarse[0].astype(np.longdouble) + coarse[1])
        cache[key] = {"q_ref_hi": fine[0].tolist(), "q_ref_lo": fine[1].tolist(),
                      "ref_diff": float(np.max(np.abs(diff))), "fine": info_f, "coarse": info_c,
                      "how": "Gauss-Legendre s = 5 (order 10) in np.longdouble on the index-reduced ODE, "
                             f"h = {info_f['h']:g}; ref_diff = max|q(h={info_c['h']:g}) - q(h={info_f['h']:g})|",
                      "date": datetime.datetime.now().isoformat(timespec="seconds")}
        write_json(cache, path)
    e = cache[key]
    log(f"  reference: {e['how']}; ref_diff {e['ref_diff']:.1e}")
    return {"q_ref": np.asarray(e["q_ref_hi"]) + np.asarray(e["q_ref_lo"]), "how": e["how"], "ref_diff": e["ref_diff"]}
