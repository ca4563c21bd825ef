"""Accuracy of event rows and ``t_eval`` rows on the Chaplygin sleigh (issue #25, item 4).

1. ``events``: a non-terminal heading event (q₃ = 0.5) at rtol = atol = 1e-10 on (0, 2), s = 3
   and 4: the event time against the closed form (brentq on the exact heading), ‖φ‖ at the
   event's state, and the step count. Under error control the steps land on the zero.
2. ``rows``: 201 ``t_eval`` rows on (0, 10) at rtol = atol = 1e-12, s = 3 and 5, for each
   ``t_eval_rows`` mode ("step", "interpolate", "project"): max error of q and p against the
   closed form, max ‖φ‖ over the rows, max error of λ, steps.

Run from the repository root::

    PYTHONPATH=src .venv/bin/python benchmarks/rows_and_events.py      # ~1 min

To compare with an earlier commit (e.g. the dense-output event times before the steps landed
on zeros), run the same command with ``PYTHONPATH`` pointing at that commit's ``src`` (a
``git worktree``).
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
from scipy.optimize import brentq

import lobattodae as L

TARGET = 0.5


def heading(t, q, p, args):
    return q[2] - TARGET


def events(ex) -> None:
    t_exact = brentq(lambda t: ex.exact(t)[0][2] - TARGET, 0.01, 2.0, xtol=1e-15)
    print("s  |t - t*|   ‖φ‖ at the event  steps")
    for s in (3, 4):
        sol = L.solve(ex.problem, L.LobattoIIIAIIIB(stages=s), (0.0, 2.0), ex.q0, ex.p0, args=ex.args, rtol=1e-10,
                      atol=1e-10, events=heading)
        t, q, p = sol.t_events[0][0], sol.q_events[0][0], sol.p_events[0][0]
        phi = float(jnp.max(jnp.abs(ex.problem.phi(t, q, p, ex.args))))
        print(f"{s}  {abs(t - t_exact):.1e}   {phi:.1e}           {sol.stats['n_steps']}")


def rows(ex) -> None:
    te = np.linspace(0.0, 10.0, 201)
    q_ex, p_ex, lam_ex = ex.exact(te)
    print("s  t_eval_rows  steps  error    ‖φ‖      λ")
    for s in (3, 5):
        for mode in ("step", "interpolate", "project"):
            sol = L.solve(ex.problem, L.LobattoIIIAIIIB(stages=s), (0.0, 10.0), ex.q0, ex.p0, args=ex.args, rtol=1e-12,
                          atol=1e-12, t_eval=te, t_eval_rows=mode)
            err = max(np.abs(sol.q - q_ex).max(), np.abs(sol.p - p_ex).max())
            print(f"{s}  {mode:<11}  {sol.stats['n_steps']:>5}  {err:.1e}  "
                  f"{np.max(sol.stats['constraint_residual']):.1e}  {np.abs(sol.lam - lam_ex).max():.1e}")


def main() -> None:
    L.set_cpu_threads(1)
    ex = L.examples.get_example("sleigh")
    events(ex)
    rows(ex)


if __name__ == "__main__":
    main()
