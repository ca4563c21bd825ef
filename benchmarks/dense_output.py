"""Orders of the dense output between step points (issue #10), and the constraint along it.

The dense output of a step (:mod:`lobattodae._dense`) is the IIIA collocation polynomial
``u`` of q (degree s, slopes ``V_j``), the polynomial ``v`` of p through the IIIA momenta
``p̃_i`` (degree s, slopes ``W_j``) and the interpolant of the stage multipliers ``Λ_j``
(degree s - 1). Two parts:

1. ``constant``: constant steps (``n_steps``, ``dense_output=True``) on two examples with
   closed forms, the Chaplygin sleigh (constant mass matrix) and steady rolling of the
   tilted disk (configuration-dependent mass matrix), s = 2..5, both start multipliers
   (``"consistent"``, what error-controlled runs use, and ``"auto"``, the default of constant
   steps, which on these short runs is the paper's scheme ``Λ_1 = λ_n``). Measured: the max
   error of q, p, λ over ``N_THETA`` points inside every step (``θ = (k + 1/2)/N_THETA``, none
   of them a Lobatto node), the same at the step points for comparison, and
   ``max ‖φ(t, q(t), p(t))‖∞`` over those points; fitted orders above the round-off plateau.
2. ``adaptive``: error-controlled runs (``dense_output=True``) of the sleigh on [0, 10]: the
   error between step points against the error at them, over rtol.

Run from the repository root::

    PYTHONPATH=src .venv/bin/python benchmarks/dense_output.py            # ~7 min on 2 loaded cores
    PYTHONPATH=src .venv/bin/python benchmarks/dense_output.py --quick    # sleigh only, ~3 min

Prints tables and writes ``benchmarks/results/dense_output.json`` (``--quick`` writes nothing
unless ``--json PATH`` is given).
"""

from __future__ import annotations

import functools
import time

import jax
import jax.numpy as jnp
import numpy as np

import lobattodae as L
from lib import cli
from lib.output import finish, log, results_path, run_meta
from lobattodae.examples import get_example

EXAMPLES = ("sleigh", "falling-disk")
STAGES = (2, 3, 4, 5)
LAM_STARTS = ("consistent", "auto")
#: Evaluation points per step: θ = (k + 1/2)/N_THETA, k = 0..N_THETA-1 (no Lobatto node for s ≤ 5).
N_THETA = 8
#: Step counts on the examples' t_span = (0, 2), per s: errors stay above the round-off plateau,
#: and the smallest h are in the asymptotic regime (s = 3 on the falling disk needs h ≤ 1/16:
#: there the step-point error, of order 4 with a large constant, masks the order-3 part at
#: coarser steps).
STEP_COUNTS = {
    2: (16, 24, 32, 48, 64, 96, 128),
    3: (12, 16, 24, 32, 48, 64, 96, 128),
    4: (4, 6, 8, 12, 16, 24, 32),
    5: (4, 6, 8, 10, 12, 16, 20, 24),
}
#: Errors below PLATEAU_REL[c]·(1 + max|c|) are round-off and not fitted (λ = Λ_s is solved
#: through Z = hΛ, so its round-off level is higher; as in lobattodae._convergence).
PLATEAU_REL = {"q": 1e-13, "p": 1e-13, "lam": 1e-11, "phi": 1e-14}
#: Fitted orders use the N_FIT smallest step sizes above the plateau.
N_FIT = 4
#: The adaptive part: the sleigh on [0, T_ADAPTIVE], these rtol = atol.
T_ADAPTIVE = 10.0
RTOLS_ADAPTIVE = (1e-6, 1e-8, 1e-10, 1e-12)


def interior_times(t: np.ndarray) -> np.ndarray:
    """N_THETA points inside every step ``[t_k, t_k+1]``, time-major."""
    theta = (np.arange(N_THETA) + 0.5) / N_THETA
    return (t[:-1, None] + theta[None, :] * np.diff(t)[:, None]).ravel()


@functools.partial(jax.jit, static_argnums=0)
def _phi_along(problem, t, q, p, args):
    return jax.vmap(lambda tt, qq, pp: problem.phi(tt, qq, pp, args))(t, q, p)


def dense_errors(ex, sol) -> dict:
    """Max errors of the dense output inside the steps and at the step points, and ‖φ‖ inside."""
    t = interior_times(sol.t)
    q, p, lam = sol.sol(t)
    qe, pe, le = ex.exact(t)
    qs, ps, ls = ex.exact(sol.t)
    phi = np.asarray(_phi_along(ex.problem, jnp.asarray(t), jnp.asarray(q), jnp.asarray(p), ex.args))
    return {
        "q": float(np.abs(q - qe).max()), "p": float(np.abs(p - pe).max()), "lam": float(np.abs(lam - le).max()),
        "phi": float(np.abs(phi).max()),
        "q_steps": float(np.abs(sol.q - qs).max()), "p_steps": float(np.abs(sol.p - ps).max()),
        "lam_steps": float(np.abs(sol.lam - ls).max()),
    }


def floors(ex) -> dict:
    q, p, lam = ex.exact(np.linspace(*ex.t_span, 201))
    scale = {"q": np.abs(q).max(), "p": np.abs(p).max(), "lam": np.abs(lam).max(), "phi": 0.0}
    return {c: PLATEAU_REL[c] * (1.0 + scale[c]) for c in PLATEAU_REL}


def constant_study(ex, s: int, lam_start: str, counts) -> dict:
    """Part 1 for one example, s and start multiplier."""
    method = L.LobattoIIIAIIIB(stages=s, lam_start=lam_start)
    rows, resets = [], 0
    for n in counts:
        sol = L.solve(ex.problem, method, ex.t_span, ex.q0, ex.p0, args=ex.args, n_steps=n, dense_output=True)
        rows.append(dense_errors(ex, sol))
        resets += int(sol.stats.get("lam_resets", 0))
    h = (ex.t_span[1] - ex.t_span[0]) / np.asarray(counts, float)
    fl = floors(ex)
    errors = {key: np.array([r[key] for r in rows]) for key in rows[0]}
    orders = {key: L.observed_order(h, err, floor=fl[key.split("_")[0]], n_fit=N_FIT) for key, err in errors.items()}
    return {"n_steps": counts, "h": h, "errors": errors, "orders": orders, "floors": fl, "lam_resets": resets}


def adaptive_study(ex, s: int, rtols) -> list[dict]:
    """Part 2: dense-output error between steps against the error at the steps, over rtol."""
    method = L.LobattoIIIAIIIB(stages=s)
    out = []
    for rtol in rtols:
        sol = L.solve(ex.problem, method, ex.t_span, ex.q0, ex.p0, args=ex.args, rtol=rtol, atol=rtol,
                      dense_output=True)
        e = dense_errors(ex, sol)
        out.append({"rtol": rtol, "n_steps": sol.stats["n_steps"], "qp_between": max(e["q"], e["p"]),
                    "qp_steps": max(e["q_steps"], e["p_steps"]), "lam_between": e["lam"],
                    "lam_steps": e["lam_steps"], "phi_between": e["phi"],
                    "max_phi_steps": sol.stats["max_constraint_residual"]})
    return out


def _o(x) -> str:
    return "—" if not np.isfinite(x) else f"{x:.2f}"


def print_constant(name: str, res: dict) -> None:
    log(f"\n== {name}: dense output inside the steps (constant steps), fitted orders "
        "(in brackets: at the step points)")
    log(f"{'s':>2} {'Λ1':>10} | {'q':>12} | {'p':>12} | {'λ':>12} | {'‖φ‖':>5} | max‖φ‖ at the smallest h")
    for (s, lam_start), r in res.items():
        o = r["orders"]
        cells = " | ".join(f"{_o(o[c]):>5} ({_o(o[c + '_steps']):>4})" for c in ("q", "p", "lam"))
        log(f"{s:>2} {lam_start:>10} | {cells} | {_o(o['phi']):>5} | {r['errors']['phi'][-1]:.1e}")


def main() -> None:
    ap = cli.parser(__doc__, "quick", quick={"help": "the sleigh only (~2 min)"})
    ap.add_argument("--parts", nargs="*", default=["constant", "adaptive"], choices=["constant", "adaptive"])
    ap.add_argument("--json", default=None,
                    help="where to write the results (default: results/dense_output.json; none with --quick)")
    a = ap.parse_args()
    examples = EXAMPLES[:1] if a.quick else EXAMPLES
    out = {**run_meta(), "settings": {"n_theta": N_THETA, "step_counts": STEP_COUNTS,
                                                      "plateau_rel": PLATEAU_REL, "n_fit": N_FIT,
                                                      "t_adaptive": T_ADAPTIVE, "rtols_adaptive": RTOLS_ADAPTIVE},
           "constant": {}, "adaptive": {}}
    start = time.perf_counter()
    if "constant" in a.parts:
        for name in examples:
            ex = get_example(name)
            res = {(s, ls): constant_study(ex, s, ls, STEP_COUNTS[s]) for s in STAGES for ls in LAM_STARTS}
            print_constant(name, res)
            out["constant"][name] = {f"s={s},{ls}": r for (s, ls), r in res.items()}
    if "adaptive" in a.parts:
        ex = get_example("sleigh", t_end=T_ADAPTIVE)
        log(f"\n== sleigh on [0, {T_ADAPTIVE:g}], adaptive: max error of (q, p) between the steps (dense output) "
            "and at them; λ likewise")
        for s in STAGES[1:]:
            rows = adaptive_study(ex, s, RTOLS_ADAPTIVE)
            out["adaptive"][f"s={s}"] = rows
            for r in rows:
                log(f"s={s} rtol {r['rtol']:.0e}: {r['n_steps']:5d} steps | (q, p) between {r['qp_between']:.1e}, "
                    f"at steps {r['qp_steps']:.1e} | λ between {r['lam_between']:.1e}, at steps {r['lam_steps']:.1e} "
                    f"| ‖φ‖ between {r['phi_between']:.1e}")
    finish(out, a.json or (None if a.quick else results_path("dense_output.json")), start)


if __name__ == "__main__":
    main()
