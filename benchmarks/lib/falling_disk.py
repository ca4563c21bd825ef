r"""The falling rolling disk in SymPy, written once for the competitors (independently of the
library's ``examples/_rolling_disk.py``; PROBLEMS.md §5).

``q = (x, y, θ, φ, ψ)`` (contact point, tilt, heading, spin), ``H = ½ pᵀM(q)⁻¹p + V(q)`` with
``V = m g R cos θ``, rolling constraints ``μ(q) q' = 0``,
``μ = [[1, 0, 0, 0, −R cos φ], [0, 1, 0, 0, −R sin φ]]``, ``v = M⁻¹p``:

* :func:`reduced_ode` -- λ eliminated: ``H_q,k = −½ vᵀ(∂_k M)v + ∂_k V``; differentiating
  ``φ = μ v`` along the flow gives ``(μM⁻¹μᵀ) λ = μM⁻¹(H_q + Ṁv) − μ̇v``; ``p' = −H_q + μᵀλ``;
* :func:`dae` -- the index-2 residual ``F = [q' − v, p' − (½ vᵀ(∂_k M)v − ∂_k V + μᵀλ), μ v]``
  of ``y = (q, p, λ)`` and its exact Jacobian ``∂F/∂y``.
"""

from __future__ import annotations

import functools

#: The disk's parameters, in the order of the symbols (``args`` of the example carries them).
PARAMS = ("m", "R", "g", "I1", "I3")


@functools.cache
def model():
    """``(q, p, params, M, V, μ)``: symbols and the mass matrix, potential and constraint matrix."""
    import sympy as sp

    q = sp.symbols("x y theta phi psi")
    p = sp.symbols("p0:5")
    params = sp.symbols(" ".join(PARAMS), positive=True)
    m, R, g, I1, I3 = params
    st, ct, sph, cph = sp.sin(q[2]), sp.cos(q[2]), sp.sin(q[3]), sp.cos(q[3])
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
    return q, p, params, M, V, mu


@functools.cache
def reduced_ode():
    """``(q, p, params, rhs, φ)``: the expressions of ``y' = (v, p')`` and of ``φ = μ v`` in
    ``(q, p)``."""
    import sympy as sp

    q, p, params, M, V, mu = model()
    vs = sp.symbols("v0:5")
    v = sp.Matrix(vs)
    Hq = sp.Matrix([-(v.T * M.diff(qk) * v)[0] / 2 + V.diff(qk) for qk in q])
    Mdot_v = sum((M.diff(qk) * v * vs[k] for k, qk in enumerate(q)), sp.zeros(5, 1))
    mudot_v = sum((mu.diff(qk) * v * vs[k] for k, qk in enumerate(q)), sp.zeros(2, 1))
    W = M.LUsolve(mu.T)  # M⁻¹μᵀ
    lam = (mu * W).LUsolve(W.T * (Hq + Mdot_v) - mudot_v)
    pdot = -Hq + mu.T * lam
    sub = dict(zip(vs, M.LUsolve(sp.Matrix(p))))
    return q, p, params, list(v.subs(sub)) + list(pdot.subs(sub)), list((mu * v).subs(sub))


@functools.cache
def dae():
    """``(q, p, λ, q', p', params, F, ∂F/∂y)`` of the index-2 residual."""
    import sympy as sp

    q, p, params, M, V, mu = model()
    lam, qd, pd = sp.symbols("l0:2"), sp.symbols("qd0:5"), sp.symbols("pd0:5")
    v = M.LUsolve(sp.Matrix(p))
    g = sp.Matrix([(v.T * M.diff(qk) * v)[0] / 2 - V.diff(qk) for qk in q]) + mu.T * sp.Matrix(lam)
    F = sp.Matrix(list(sp.Matrix(qd) - v) + list(sp.Matrix(pd) - g) + list(mu * v))
    return q, p, lam, qd, pd, params, F, F.jacobian(sp.Matrix(list(q) + list(p) + list(lam)))


def values(args, dtype=float) -> tuple:
    """The example's ``args`` as the symbols' values."""
    return tuple(dtype(float(getattr(args, k))) for k in PARAMS)
