"""What the test set's independent checks share: the index-1 accelerations of a constrained
mechanical system, and scipy's end state of an ODE (NumPy only, no lobattodae code)."""

from __future__ import annotations

import numpy as np


def kkt_acceleration(mass, jacobian, force, curvature):
    """The accelerations a of ``M a = F ± Gᵀλ``, ``G a = −curvature`` (the second derivative of
    the position constraints): the first block of the solution of

        [M  Gᵀ] [a]   [F         ]
        [G  0 ] [λ] = [−curvature].

    The sign convention of λ does not change a."""
    n, m = mass.shape[0], jacobian.shape[0]
    K = np.zeros((n + m, n + m))
    K[:n, :n], K[:n, n:], K[n:, :n] = mass, jacobian.T, jacobian
    return np.linalg.solve(K, np.concatenate([force, -curvature]))[:n]


def end_state(rhs, y0, t_end, method, tol):
    """``y(t_end)`` of ``y' = rhs(t, y)``, ``y(0) = y0`` by ``scipy.integrate.solve_ivp`` with
    ``rtol = atol = tol``; raises if scipy reports a failure."""
    from scipy.integrate import solve_ivp

    sol = solve_ivp(rhs, (0.0, t_end), np.asarray(y0, dtype=float), method=method, rtol=tol, atol=tol)
    if not sol.success:
        raise RuntimeError(sol.message)
    return sol.y[:, -1]
