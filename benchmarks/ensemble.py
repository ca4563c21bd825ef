"""Ensemble throughput: ``jax.vmap`` over ``lobattodae.integrate`` on CPU and (if present) GPU.

Runs B trajectories of N steps of the falling rolling disk (general motion, n=5, m=2) and of
the knife edge (n=3, m=1) from perturbed consistent initial data, and reports compile time,
run time (best of 3, after compilation) and throughput in trajectory-steps per second.
Prints a table and writes ``benchmarks/results/ensemble_<platform>.json``.

    PYTHONPATH=src python benchmarks/ensemble.py [--quick] [--batches 1 64 1024] [--grad]

``--grad`` also times ``jax.vmap(jax.grad(loss))`` (one gradient of ``Σ q_N²`` with respect
to p0 per trajectory) against the forward ensemble.
"""

from __future__ import annotations

import os

import jax
import jax.numpy as jnp
import numpy as np

import lobattodae as L
from lib import cli
from lib.output import RESULTS, log, run_meta, write_json
from lib.problems import consistent_batch
from lib.timing import best_of
from lobattodae.examples import get_example


#: (example, h) of the tables; s = 3 throughout.
CASES = (("knife-edge", 0.01), ("falling-disk-general", 0.01))


def run(example: str, stages: int, batch: int, n_steps: int, h: float) -> dict:
    ex = get_example(example)
    method = L.LobattoIIIAIIIB(stages=stages)
    q0, p0, lam0 = consistent_batch(ex, batch)

    @jax.jit
    def ensemble(q0, p0, lam0):
        q, p, lam, status = jax.vmap(
            lambda a, b, c: L.integrate(ex.problem, method, 0.0, h, n_steps, a, b, c, ex.args)
        )(q0, p0, lam0)
        return q[:, -1], status

    tm = best_of(lambda: ensemble(q0, p0, lam0), 3, first=True)
    return {
        "example": example, "stages": stages, "batch": batch, "n_steps": n_steps, "h": h,
        "compile_and_first_run_s": tm.first, "run_s": tm.best,
        "traj_steps_per_s": batch * n_steps / tm.best, "us_per_traj_step": tm.best / (batch * n_steps) * 1e6,
        "successful": int(np.sum(np.asarray(tm.result[1]) == 0)),
    }


def run_grad(example: str, stages: int, batch: int, n_steps: int, h: float) -> dict:
    """``jax.vmap(jax.grad(loss))``: one gradient per trajectory of ``Σ q_N²`` with respect to
    its p0 (reverse mode through ``integrate``, default checkpoints), against the forward
    ensemble in the same process."""
    ex = get_example(example)
    method = L.LobattoIIIAIIIB(stages=stages)
    q0, p0, lam0 = consistent_batch(ex, batch)

    def loss(q, p, lam):
        r = L.integrate(ex.problem, method, 0.0, h, n_steps, q, p, lam, ex.args)
        return jnp.sum(r.q[-1] ** 2)

    forward = jax.jit(jax.vmap(loss))
    grad = jax.jit(jax.vmap(jax.grad(loss, argnums=1)))
    out = {}
    for name, fn in (("forward", forward), ("grad", grad)):
        tm = best_of(lambda fn=fn: fn(q0, p0, lam0), 3, first=True)
        out[name] = {"compile_and_first_run_s": tm.first, "run_s": tm.best,
                     "finite": bool(np.all(np.isfinite(tm.result)))}
    return {"example": example, "stages": stages, "batch": batch, "n_steps": n_steps, "h": h, **out,
            "grad_over_forward": out["grad"]["run_s"] / out["forward"]["run_s"],
            "grads_per_s": batch / out["grad"]["run_s"]}


def sweep(measure, batches: list[int], n_steps: int, header: str, row) -> list[dict]:
    """``measure(example, s, batch, n_steps, h)`` over CASES and ``batches`` (s = 3), a line
    each as it comes (``row(result)``), under ``header``."""
    log(header)
    out = []
    for example, h in CASES:
        for b in batches:
            out.append(measure(example, 3, b, n_steps, h))
            log(f"{example:22s} {3:>2} {b:>6} {n_steps:>6} " + row(out[-1]))
    return out


def main() -> None:
    ap = cli.parser(__doc__, "quick", "pin_cpu")
    ap.add_argument("--batches", type=int, nargs="+", default=None)
    ap.add_argument("--out", default=RESULTS, help="the directory of the JSON")
    ap.add_argument("--grad", action="store_true", help="also time a batch of gradients (jax.vmap(jax.grad))")
    ns = cli.start(ap.parse_args())
    backend = jax.default_backend()
    batches = ns.batches or ([1, 64] if ns.quick else [1, 64, 1024, 8192])
    n_steps = 200 if ns.quick else 1000
    log(f"backend: {backend}  devices: {jax.devices()}")
    head = f"{'example':22s} {'s':>2} {'batch':>6} {'steps':>6} "
    rows = sweep(run, batches, n_steps,
                 head + f"{'compile+1st':>11} {'run':>9} {'traj-steps/s':>13} {'us/traj-step':>12} ok",
                 lambda r: f"{r['compile_and_first_run_s']:10.2f}s {r['run_s']:8.3f}s {r['traj_steps_per_s']:13.3e} "
                           f"{r['us_per_traj_step']:12.3f} {r['successful']}/{r['batch']}")
    grads = []
    if ns.grad:
        grads = sweep(run_grad, batches, n_steps,
                      "\n" + head + f"{'forward':>9} {'grad':>9} {'grad/fwd':>8} {'gradients/s':>12}",
                      lambda r: f"{r['forward']['run_s']:8.3f}s {r['grad']['run_s']:8.3f}s "
                                f"{r['grad_over_forward']:8.2f} {r['grads_per_s']:12.3e}"
                                + ("" if r["grad"]["finite"] else "  NON-FINITE"))
    meta = run_meta(backend=backend, devices=[str(d) for d in jax.devices()], pin_cpu=ns.pin_cpu)
    write_json({"meta": meta, "rows": rows, "gradients": grads},
               os.path.join(ns.out, f"ensemble_{backend}{'_quick' if ns.quick else ''}.json"))


if __name__ == "__main__":
    main()
