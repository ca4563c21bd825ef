"""Cost of a gradient through the solver: ``jax.grad`` of a scalar of the final state over the
forward solve alone, and the memory the backward pass keeps.

For each (example, s): N constant steps of ``lobattodae.integrate`` from consistent initial
values computed from parameters (``project_momenta``, ``consistent_lambda``); the loss is
``Σ q_N²``, differentiated with respect to p0 (reverse mode). Times are the best of
``--repeats`` after compilation, measured in the same process one after the other, and the
ratio grad/forward is what to read. Memory is XLA's temporary buffer size of the compiled
gradient (``memory_analysis().temp_size_in_bytes``). Two settings: √N checkpointed segments
(what ``checkpoints="auto"`` takes beyond its memory bound) and ``checkpoints=None`` (every step
kept for the backward pass), each forward timed with its own setting. Writes ``benchmarks/results/gradients.json``.

    PYTHONPATH=src python benchmarks/gradients.py [--quick]
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp

import lobattodae as L
from lib import cli
from lib.output import results_path, run_meta, write_json
from lib.timing import best_of
from lobattodae._integrate import kept_bytes, resolve_checkpoints
from lobattodae.examples import get_example

CASES = (("falling-disk-general", 3, 0.01), ("falling-disk-general", 4, 0.02), ("sleigh", 3, 0.01), ("sleigh", 5, 0.05))


def measure(name: str, stages: int, h: float, n_steps: int, repeats: int) -> dict:
    ex = get_example(name)
    method = L.LobattoIIIAIIIB(stages=stages)
    q0 = jnp.asarray(ex.q0)

    def loss(p, checkpoints):
        p0 = L.project_momenta(ex.problem, 0.0, q0, p, ex.args)
        lam0 = L.consistent_lambda(ex.problem, 0.0, q0, p0, jnp.asarray(ex.lam0), ex.args)
        r = L.integrate(ex.problem, method, 0.0, h, n_steps, q0, p0, lam0, ex.args, checkpoints=checkpoints)
        return jnp.sum(r.q[-1] ** 2)

    p = jnp.asarray(ex.p0)
    segments = int(round(math.sqrt(n_steps)))  # what checkpoints="auto" takes beyond its memory bound
    auto = resolve_checkpoints("auto", n_steps, kept_bytes(method, q0.shape[-1], len(ex.lam0)))
    forward = jax.jit(lambda x: loss(x, segments))
    forward_all = jax.jit(lambda x: loss(x, None))
    grad = jax.jit(jax.grad(lambda x: loss(x, segments)))
    grad_all = jax.jit(jax.grad(lambda x: loss(x, None)))
    t_fwd, t_fwd_all, t_grad, t_all = (best_of(lambda fn=fn: fn(p), repeats, first=True).best
                                       for fn in (forward, forward_all, grad, grad_all))
    mem = grad.lower(p).compile().memory_analysis().temp_size_in_bytes
    mem_all = grad_all.lower(p).compile().memory_analysis().temp_size_in_bytes
    row = dict(example=name, stages=stages, h=h, n_steps=n_steps, segments=segments, auto_segments=auto,
               forward_s=t_fwd, forward_every_step_kept_s=t_fwd_all, grad_s=t_grad, grad_every_step_kept_s=t_all,
               ratio=t_grad / t_fwd, ratio_every_step_kept=t_all / t_fwd_all,
               temp_bytes=mem, temp_bytes_every_step_kept=mem_all)
    print(f"{name:22s} s={stages} N={n_steps:6d}  checkpoints={segments} (auto: {auto}): forward {t_fwd * 1e3:7.1f} ms, "
          f"grad {t_grad * 1e3:7.1f} ms ({t_grad / t_fwd:4.2f}x, {mem / 1e6:6.2f} MB)  |  every step kept: forward "
          f"{t_fwd_all * 1e3:7.1f} ms, grad {t_all * 1e3:7.1f} ms ({t_all / t_fwd_all:4.2f}x, {mem_all / n_steps:6.0f} B/step)",
          flush=True)
    return row


def main() -> None:
    ap = cli.parser(__doc__, "quick", "pin_cpu", quick={"help": "short runs (smoke test)"})
    ap.add_argument("--repeats", type=int, default=3)
    ns = cli.start(ap.parse_args())
    n_steps = 200 if ns.quick else 2000
    meta = run_meta(pin_cpu=ns.pin_cpu)
    rows = [measure(name, s, h, n_steps, ns.repeats) for name, s, h in (CASES[:1] if ns.quick else CASES)]
    if not ns.quick:
        write_json(dict(meta, device=str(jax.devices()[0]), rows=rows), results_path("gradients.json"))


if __name__ == "__main__":
    main()
