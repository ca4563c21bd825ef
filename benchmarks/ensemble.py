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

import argparse
import json
import os
import platform
import time

import jax
import jax.numpy as jnp
import numpy as np

import lobattodae as L
from lobattodae.examples import get_example


#: (example, h) of the tables; s = 3 throughout.
CASES = (("knife-edge", 0.01), ("falling-disk-general", 0.01))


def _consistent_batch(ex, batch: int, seed: int = 0):
    """B consistent initial values: random momenta projected onto the constraint, λ0 solved."""
    rng = np.random.default_rng(seed)
    q0 = np.tile(ex.q0, (batch, 1))
    p0 = ex.p0 + 0.05 * rng.standard_normal((batch, ex.p0.size))

    def project(q, p):
        phi = lambda pp: ex.problem.phi(0.0, q, pp, ex.args)  # noqa: E731
        jp = jax.jacfwd(phi)(p)
        return p - jp.T @ jnp.linalg.solve(jp @ jp.T, phi(p))

    p0 = jax.vmap(project)(jnp.asarray(q0), jnp.asarray(p0))
    lam0 = jax.vmap(lambda q, p: L.consistent_lambda(ex.problem, 0.0, q, p, jnp.zeros(ex.m), ex.args))(
        jnp.asarray(q0), p0
    )
    return jnp.asarray(q0), p0, lam0


def run(example: str, stages: int, batch: int, n_steps: int, h: float) -> dict:
    ex = get_example(example)
    method = L.LobattoIIIAIIIB(stages=stages)
    q0, p0, lam0 = _consistent_batch(ex, batch)

    @jax.jit
    def ensemble(q0, p0, lam0):
        q, p, lam, status = jax.vmap(
            lambda a, b, c: L.integrate(ex.problem, method, 0.0, h, n_steps, a, b, c, ex.args)
        )(q0, p0, lam0)
        return q[:, -1], status

    t = time.perf_counter()
    qT, status = jax.block_until_ready(ensemble(q0, p0, lam0))
    first = time.perf_counter() - t
    best = min(_timed(ensemble, q0, p0, lam0) for _ in range(3))
    ok = int(np.sum(np.asarray(status) == 0))
    return {
        "example": example, "stages": stages, "batch": batch, "n_steps": n_steps, "h": h,
        "compile_and_first_run_s": first, "run_s": best,
        "traj_steps_per_s": batch * n_steps / best, "us_per_traj_step": best / (batch * n_steps) * 1e6,
        "successful": ok,
    }


def run_grad(example: str, stages: int, batch: int, n_steps: int, h: float) -> dict:
    """``jax.vmap(jax.grad(loss))``: one gradient per trajectory of ``Σ q_N²`` with respect to
    its p0 (reverse mode through ``integrate``, default checkpoints), against the forward
    ensemble in the same process."""
    ex = get_example(example)
    method = L.LobattoIIIAIIIB(stages=stages)
    q0, p0, lam0 = _consistent_batch(ex, batch)

    def loss(q, p, lam):
        r = L.integrate(ex.problem, method, 0.0, h, n_steps, q, p, lam, ex.args)
        return jnp.sum(r.q[-1] ** 2)

    forward = jax.jit(jax.vmap(loss))
    grad = jax.jit(jax.vmap(jax.grad(loss, argnums=1)))
    out = {}
    for name, fn in (("forward", forward), ("grad", grad)):
        t = time.perf_counter()
        value = jax.block_until_ready(fn(q0, p0, lam0))
        first = time.perf_counter() - t
        best = min(_timed(fn, q0, p0, lam0) for _ in range(3))
        out[name] = {"compile_and_first_run_s": first, "run_s": best, "finite": bool(np.all(np.isfinite(value)))}
    return {"example": example, "stages": stages, "batch": batch, "n_steps": n_steps, "h": h, **out,
            "grad_over_forward": out["grad"]["run_s"] / out["forward"]["run_s"],
            "grads_per_s": batch / out["grad"]["run_s"]}


def _timed(fn, *a) -> float:
    t = time.perf_counter()
    jax.block_until_ready(fn(*a))
    return time.perf_counter() - t


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--batches", type=int, nargs="+", default=None)
    ap.add_argument("--out", default=os.path.join(os.path.dirname(__file__), "results"))
    ap.add_argument("--grad", action="store_true", help="also time a batch of gradients (jax.vmap(jax.grad))")
    ns = ap.parse_args()
    backend = jax.default_backend()
    batches = ns.batches or ([1, 64] if ns.quick else [1, 64, 1024, 8192])
    n_steps = 200 if ns.quick else 1000
    rows = []
    print(f"backend: {backend}  devices: {jax.devices()}")
    print(f"{'example':22s} {'s':>2} {'batch':>6} {'steps':>6} {'compile+1st':>11} {'run':>9} {'traj-steps/s':>13} {'us/traj-step':>12} ok")
    for example, h in CASES:
        for b in batches:
            r = run(example, 3, b, n_steps, h)
            rows.append(r)
            print(f"{example:22s} {3:>2} {b:>6} {n_steps:>6} {r['compile_and_first_run_s']:10.2f}s {r['run_s']:8.3f}s "
                  f"{r['traj_steps_per_s']:13.3e} {r['us_per_traj_step']:12.3f} {r['successful']}/{b}")
    grads = []
    if ns.grad:
        print(f"\n{'example':22s} {'s':>2} {'batch':>6} {'steps':>6} {'forward':>9} {'grad':>9} {'grad/fwd':>8} {'gradients/s':>12}")
        for example, h in CASES:
            for b in batches:
                r = run_grad(example, 3, b, n_steps, h)
                grads.append(r)
                print(f"{example:22s} {3:>2} {b:>6} {n_steps:>6} {r['forward']['run_s']:8.3f}s {r['grad']['run_s']:8.3f}s "
                      f"{r['grad_over_forward']:8.2f} {r['grads_per_s']:12.3e}" + ("" if r["grad"]["finite"] else "  NON-FINITE"))
    os.makedirs(ns.out, exist_ok=True)
    path = os.path.join(ns.out, f"ensemble_{backend}{'_quick' if ns.quick else ''}.json")
    meta = {"date": time.strftime("%Y-%m-%d"), "backend": backend, "devices": [str(d) for d in jax.devices()],
            "machine": platform.platform(), "cpu_count": os.cpu_count(), "jax": jax.__version__}
    with open(path, "w") as fh:
        json.dump({"meta": meta, "rows": rows, "gradients": grads}, fh, indent=2)
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
