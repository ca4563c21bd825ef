"""Ensembles: one problem, a batch of initial values and parameters, sharded across devices.

:func:`ensemble` integrates B trajectories of one problem with :func:`~lobattodae.integrate`
(constant steps) or :func:`~lobattodae.integrate_adaptive` (error-controlled steps), vmapped
over the trajectories (error control on CPU devices: one after the other, :func:`_in_turn`)
and sharded over devices:

* **Sharding.** The trajectories of a block are laid out along the one axis of a
  :class:`jax.sharding.Mesh` of the devices (``jax.local_devices()`` by default) with
  :class:`~jax.sharding.NamedSharding`, and :func:`jax.shard_map` runs the vmapped integrator
  on each device's part. Under ``vmap`` a ``while_loop`` runs until every trajectory of its
  batch is done; with ``shard_map`` that batch is the device's own part, so the devices never
  wait for each other and never communicate (with a plain ``jit`` over sharded inputs the loop
  condition would be an all-reduce at every step). Compiled once per (problem, method,
  settings, block shape, devices).
* **Blocks and padding.** The batch runs in blocks of ``block_size`` trajectories, each padded
  to a multiple of the device count by repeating its last trajectory (a consistent initial
  value, so the padding cannot fail or slow the loop) and trimmed afterwards. Every block has
  the same shape: one compilation for all of them.
* **Streaming.** With ``out_dir`` each block is written to its own ``.npz`` file while the
  next one runs, and only the file names are returned (:class:`EnsembleFiles`);
  :func:`load_ensemble` reads them back (the format: :mod:`lobattodae._io.ensemble_files`). A
  file is written like a checkpoint (:func:`lobattodae._io.atomic.write_npz`: a unique
  temporary file, fsynced, renamed over the block's name, the directory fsynced) and carries a
  SHA-256 digest of each of its arrays (``digests``),
  checked whenever it is read: a damaged block is refused by :func:`load_ensemble`
  (:class:`EnsembleFileError`, naming the file) and computed again by ``if_exists="resume"``
  (with a warning). Only regular files are opened (a FIFO or directory named like a block is
  refused, never waited on). Inputs are read one block at a time (``x[a:b]``), so
  NumPy memory maps (``np.load(..., mmap_mode="r")``) keep even the initial values out of memory.
* **Several processes.** Under ``jax.distributed.initialize`` every process takes its own
  contiguous slice of the global batch (by ``jax.process_index()``), runs it on its local
  devices and writes its own files; with ``out_dir`` the processes meet at a barrier at the end.

Results agree with ``jax.vmap`` of the entry points to round-off, bit for bit on one device
(see :func:`ensemble`, "Reproducibility").
"""

from __future__ import annotations

import functools
import hashlib
import json
import os
import stat
import warnings
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec

from . import _compile
from ._controllers import ROUNDOFF_FLOOR, roundoff_may_exceed
from ._errors import LobattoDAEInputError
from ._integrate import integrate, integrate_adaptive
from ._results import REACHED_END
from ._io import fingerprint_arrays, fingerprint_callable
from ._io.ensemble_files import (
    FILE_FORMAT,
    FILE_GLOB,
    FILE_VERSION,
    EnsembleFileError,
    block_digest,
    block_files,
    file_name,
    not_regular_error,
    own_files,
    read_block,
    read_meta,
    resumable,
    write_block,
)
from ._ensemble_inputs import (
    arg_flags,
    check_batched_args,
    check_initial_values,
    guard_cpu_pool,
    initial_values,
    local_devices,
    merge_args,
)
from ._options import STATIC_MAX_STEPS, AdaptiveSteps, ConstantSteps, Saving, TimeSpan, check_count
from ._validate import check_method, check_tolerance_attainable

__all__ = [
    "AXIS",
    "DEFAULT_BLOCK_PER_DEVICE",
    "MAX_BLOCK_OUTPUT_BYTES",
    "EnsembleFiles",
    "EnsembleResult",
    "ensemble",
    "load_ensemble",
]

#: Name of the mesh axis along which the trajectories are sharded.
AXIS = "trajectories"
#: ``save`` values: the final state of every trajectory, or every step point (every ``t_eval`` row).
SAVE_MODES = ("final", "all")
#: ``if_exists`` values: what to do with this process's ensemble files already in ``out_dir``.
IF_EXISTS = ("error", "overwrite", "resume")
#: Default block size (without ``block_size``): this many trajectories per device ...
DEFAULT_BLOCK_PER_DEVICE = 8192
#: ... and at most this many bytes of results per block (``save="all"`` keeps every row).
MAX_BLOCK_OUTPUT_BYTES = 256 * 2**20
#: The result fields of every run, and those only error-controlled runs have.
_COMMON_FIELDS = ("q", "p", "lam", "status")
_ADAPTIVE_FIELDS = ("t", "n_rows", "n_steps", "n_rejected", "n_roundoff_limited")


class EnsembleResult(NamedTuple):
    """What :func:`ensemble` returns without ``out_dir`` (and :func:`load_ensemble`): NumPy arrays,
    trajectory-major (axis 0 is the trajectory, then time for ``save="all"``).

    Fields that a run does not have are ``None``: ``t``, ``n_rows``, ``n_steps``,
    ``n_rejected`` and ``n_roundoff_limited`` belong to error-controlled runs (constant steps
    are on the grid ``t0 + k·h``); :func:`load_ensemble` with ``fields=`` leaves out the others.

    Attributes
    ----------
    index : ndarray, shape (B,), int64
        Each trajectory's position in the global batch.
    q, p : ndarray, shape (B, n) or (B, rows, n)
        Final values (``save="final"``) or every row (``save="all"``).
    lam : ndarray, shape (B, m) or (B, rows, m)
        The multipliers λ, likewise.
    status : ndarray, shape (B,), int32
        Each trajectory's :class:`~lobattodae.Result` code (0: success; 11, ``ROUNDOFF_LIMITED``: the
        end was reached, but rtol asked the steps for less than their round-off).
    t : ndarray, shape (B,) or (B, rows), optional
        Error-controlled runs: the final time, or the times of the rows (step points or
        ``t_eval``).
    n_rows : ndarray, shape (B,), int32, optional
        Error-controlled runs: the number of valid rows of ``q``, ``p``, ``lam``, ``t`` (NaN
        after them).
    n_steps : ndarray, shape (B,), int32, optional
        Error-controlled runs: accepted steps.
    n_rejected : ndarray, shape (B,), int32, optional
        Error-controlled runs: rejected step attempts.
    n_roundoff_limited : ndarray, shape (B,), int32, optional
        Error-controlled runs: accepted steps that passed only by the round-off floor
        (:class:`~lobattodae.AdaptiveResult`); :func:`ensemble` warns when, for some
        trajectories, they may add up to more than rtol.
    """

    index: np.ndarray  # (B,) int64: the trajectory's position in the global batch
    q: np.ndarray | None  # (B, n) final, or (B, rows, n)
    p: np.ndarray | None  # (B, n) or (B, rows, n)
    lam: np.ndarray | None  # (B, m) or (B, rows, m)
    status: np.ndarray | None  # (B,) int32 Result code (0: success, 11: success limited by round-off)
    t: np.ndarray | None = None  # adaptive: (B,) final time or (B, rows) step points / t_eval
    n_rows: np.ndarray | None = None  # adaptive: (B,) int32 valid rows of q, p, lam, t (NaN after them)
    n_steps: np.ndarray | None = None  # adaptive: (B,) int32 accepted steps
    n_rejected: np.ndarray | None = None  # adaptive: (B,) int32 rejected step attempts
    n_roundoff_limited: np.ndarray | None = None  # adaptive: (B,) int32 steps passed only by the round-off floor


class EnsembleFiles(NamedTuple):
    """What :func:`ensemble` returns with ``out_dir``: this process's files, not the results.

    Attributes
    ----------
    paths : tuple of str
        This process's block files, in the order of the trajectories (read them with
        :func:`load_ensemble`).
    start, stop : int
        This process's slice of the global batch: trajectories ``start`` to ``stop - 1``.
    n_failed : int
        Trajectories of the slice that did not reach their end (``Result.success`` false).
    n_skipped : int
        Blocks found complete on disk (``if_exists="resume"``) and not computed again.
    process_index, process_count : int
        This process's index and the number of processes (``jax.process_index()``,
        ``jax.process_count()``).
    """

    paths: tuple[str, ...]  # this process's block files, in the order of the trajectories
    start: int  # this process's slice of the global batch: trajectories start .. stop - 1
    stop: int
    n_failed: int  # trajectories of the slice that did not reach their end (Result.success false)
    n_skipped: int  # blocks found complete on disk (if_exists="resume") and not recomputed
    process_index: int
    process_count: int


# -- the compiled block --------------------------------------------------------------------------------
@dataclass(frozen=True)
class _Plan:
    """Everything static about a block: it keys the compilation cache."""

    problem: Any
    method: Any
    n_steps: int | None  # constant steps
    max_steps: int | None  # error control
    controller: Any
    has_t_eval: bool
    t_eval_rows: str | None
    save: str
    mesh: Mesh
    treedef: Any  # of args
    flags: tuple[bool, ...]  # per leaf of args: batched along axis 0
    in_turn: bool = False  # a device's trajectories one after the other (lax.map), not vmapped

    def lanes(self, numbers, shared):
        """The function of a device's part of the block: :func:`_one` vmapped over its
        trajectories or, with ``in_turn``, mapped over them one after the other."""
        one = functools.partial(_one, self, numbers, shared)
        if self.in_turn:
            return lambda *xs: jax.lax.map(lambda x: one(*x), xs)
        return jax.vmap(one)


def _one(plan: _Plan, numbers, shared, q0, p0, lam0, batched):
    """One trajectory (the function that is vmapped): the entry point, then what ``save`` keeps."""
    args = jax.tree_util.tree_unflatten(plan.treedef, merge_args(plan.flags, batched, shared))
    if plan.n_steps is not None:
        t0, h = numbers
        # not differentiated: the plain scan (checkpointed segments only serve reverse mode)
        r = integrate(plan.problem, plan.method, t0, h, plan.n_steps, q0, p0, lam0, args, checkpoints=None)
        if plan.save == "final":
            return r._replace(q=r.q[-1], p=r.p[-1], lam=r.lam[-1])
        return r
    t0, t1, rtol, atol, first_step, max_step, t_eval = numbers
    r = integrate_adaptive(
        plan.problem, plan.method, (t0, t1), q0, p0, lam0, args, rtol=rtol, atol=atol, first_step=first_step,
        max_step=max_step, max_steps=plan.max_steps, t_eval=t_eval if plan.has_t_eval else None,
        controller=plan.controller, t_eval_rows=plan.t_eval_rows,
    )
    if plan.save == "final":
        last = jnp.maximum(r.n_rows - 1, 0)
        pick = lambda x: jnp.where(r.n_rows > 0, x[last], jnp.nan)  # noqa: E731
        return r._replace(t=pick(r.t), q=pick(r.q), p=pick(r.p), lam=pick(r.lam))
    return r


@_compile.jit(static_argnums=0)
def _run_block(plan: _Plan, numbers, shared, q0, p0, lam0, batched):
    """One block, sharded over ``plan.mesh``: each device runs :func:`_one` over its part
    (:meth:`_Plan.lanes`)."""
    split, whole = PartitionSpec(AXIS), PartitionSpec()
    sharded = jax.shard_map(
        lambda numbers, shared, *xs: plan.lanes(numbers, shared)(*xs),
        mesh=plan.mesh, in_specs=(whole, whole, split, split, split, split), out_specs=split,
        # the integrators' loops carry device-invariant initial values that become per-device
        # ones (the check would want a pcast inside them); nothing here communicates
        check_vma=False,
    )
    return sharded(numbers, shared, q0, p0, lam0, batched)


def _in_turn(adaptive: bool, devices) -> bool:
    """Error-controlled trajectories on CPU devices run one after the other (``lax.map``), not
    vmapped: under ``vmap`` every ``while_loop`` (the steps, Newton's iterations) runs until the
    slowest trajectory is done, which a CPU pays in full, while a GPU needs the batch to fill
    itself. Measured (16 trajectories, s = 3, rtol 1e-8, one CPU; ms per trajectory, vmapped /
    in turn / a loop of ``solve`` calls): knife edge T = 10: 12.0 / 10.1 / 12.6; falling disk:
    50 / 32 / 41; a chain of 14 particles (238 unknowns) T = 5: 344 / 124 / 106. Constant steps
    stay vmapped: their steps run in lockstep (200 steps, against a loop of ``integrate``
    calls: knife edge 0.76 / 2.80 / 2.34; falling disk 5.2 / 8.5 / 10.5; chain of 5 5.1 / 5.8 /
    7.1), except for large systems, where every Newton iteration waits for the slowest trajectory
    (chain of 14: 54 / 29 / 33). ``benchmarks/ensemble_lanes.py``, RESULTS.md 2026-11-28."""
    return adaptive and all(d.platform == "cpu" for d in devices)


# -- blocks --------------------------------------------------------------------------------------------
def _take(x, a: int, b: int, pad: int) -> np.ndarray:
    """Rows a..b-1 of ``x`` as float64 NumPy (reads only those rows of a memory map), padded with
    copies of the last row."""
    rows = np.asarray(x[a:b], dtype=np.float64)
    if pad:
        rows = np.concatenate([rows, np.repeat(rows[-1:], pad, axis=0)])
    return rows


def _to_host(out, keep: int) -> dict:
    return {name: np.asarray(getattr(out, name))[:keep] for name in out._fields}


# -- the entry point -----------------------------------------------------------------------------------
def ensemble(problem, method, q0, p0, lam0, args=None, *, batch_args=False, t0=None, h=None, n_steps=None,
             t_span=None, rtol=None, atol=None, first_step=None, max_step=None, max_steps=None, t_eval=None,
             controller=None, t_eval_rows: str | None = None, save: str = "final", devices=None, block_size: int | None = None,
             out_dir: str | os.PathLike | None = None, if_exists: str = "error") -> EnsembleResult | EnsembleFiles:
    """Integrate a batch of trajectories of one problem, sharded across devices.

    Constant steps (``h``, ``n_steps``, optional ``t0``) run :func:`~lobattodae.integrate`;
    ``t_span`` (with ``rtol``, ``atol``, ...) runs :func:`~lobattodae.integrate_adaptive`. Each
    trajectory has its own initial values and, for the leaves of ``args`` marked in
    ``batch_args``, its own parameters. The initial values must be consistent (φ = 0 and λ0
    from :func:`~lobattodae.consistent_lambda`), and are checked as :func:`~lobattodae.solve`
    checks them (with the same tolerance, every trajectory, before anything is integrated);
    the options of error-controlled runs obey :func:`~lobattodae.solve`'s rules too (``rtol``,
    ``t_eval`` sorted in the direction of integration and within ``t_span``, ``controller``).
    A host-level driver like :func:`~lobattodae.solve`: not for use inside ``jit``.

    Parameters
    ----------
    problem, method
        As for :func:`~lobattodae.integrate`.
    q0, p0 : array_like, shape (B, n)
        One row per trajectory. NumPy arrays, memory maps or jax Arrays; only one block at a
        time is read and converted to float64.
    lam0 : array_like, shape (B, m)
        Consistent multipliers, one row per trajectory.
    args : pytree, optional
        The problem's parameters; shared by all trajectories except the leaves marked in
        ``batch_args``, which have a leading axis of length B.
    batch_args : bool or pytree of bool
        ``False`` (default): ``args`` is shared; ``True``: every leaf is batched; or a pytree
        with the structure of ``args`` (or a prefix of it), e.g.
        ``KnifeEdgeParams(m=False, J=False, g=True)``.
    t0, h, n_steps
        Constant steps: ``n_steps`` steps of size ``h`` from ``t0`` (default 0).
    t_span, rtol, atol, first_step, max_step, max_steps, t_eval, controller, t_eval_rows
        Error-controlled (or reversible) steps, as for :func:`~lobattodae.integrate_adaptive`
        (defaults 1e-8, 1e-10, automatic, no limit, 4096, step points,
        :class:`~lobattodae.PIController`, ``t_eval`` rows as step points under error
        control). Shared by all trajectories.
    save : {"final", "all"}
        Keep each trajectory's final state (default), or every row (every step point of the
        constant-step grid; ``max_steps + 1`` rows or the ``t_eval`` rows with error control).
    devices : sequence of jax.Device, optional
        Devices of this process to shard over. Default: all of ``jax.local_devices()``; for
        CPU devices at most one fewer than XLA's CPU thread pool has threads (see Notes).
    block_size : int, optional
        Trajectories per compiled call (and per file). Default: the whole batch, at most
        ``DEFAULT_BLOCK_PER_DEVICE`` per device and ``MAX_BLOCK_OUTPUT_BYTES`` of results.
        Every block is padded to a multiple of the device count; a multiple of it wastes nothing.
    out_dir : path, optional
        Write each block to ``out_dir/ensemble-p<process>-b<block>.npz`` (created if missing)
        and return :class:`EnsembleFiles` instead of the results; read them with
        :func:`load_ensemble`.
    if_exists : {"error", "overwrite", "resume"}
        When ``out_dir`` already holds this process's ensemble files: refuse (default), delete
        them first, or keep each block whose file was written by the same run (same settings,
        ``args`` and block inputs, checked by a digest) and is intact (every array matches the
        digest written with it) and compute only the others; a damaged or unreadable block
        file is computed again and replaced, with a :class:`RuntimeWarning` naming it.

    Returns
    -------
    EnsembleResult or EnsembleFiles
        Without ``out_dir``: NumPy arrays of this process's trajectories (all of them in a
        single process), ``index`` giving their place in the batch. With ``out_dir``: the paths
        of this process's files and a summary.

    Raises
    ------
    ShapeError
        Initial values or batched ``args`` leaves of the wrong shape or dtype (``lam0`` not of
        width m), or batch sizes that do not match.
    InconsistentInitialValuesError
        A trajectory whose initial values violate the constraints (φ, the hidden constraint,
        ψ), as :func:`~lobattodae.solve` would refuse it; the message names the trajectory.
    ProblemFunctionError
        A problem function fails on the first trajectory (e.g. ``args=None`` where the problem
        reads ``args``, or an ``args`` leaf of the wrong shape: batched leaves give each
        trajectory one row, unbatched ones are passed whole).
    LobattoDAEInputError
        Bad options: both or neither of ``n_steps`` and ``t_span``, options of the other mode,
        options :func:`~lobattodae.solve` refuses, ``block_size``, ``save``, ``devices``,
        ``if_exists``, existing files (:class:`EnsembleFileError` for files that are not
        regular files), a model's ``NativeIntegrator`` as ``method`` (pass its ``method``).

    Warns
    -----
    RuntimeWarning
        Error-controlled runs where, for some trajectories, the steps that passed only by the
        round-off floor (``n_roundoff_limited``) may add up to more than rtol, as
        :func:`~lobattodae.solve` warns for one run: the tolerance asks for less than the steps
        resolve over the interval (with ``out_dir``: of the blocks computed by this call).

    Notes
    -----
    **Reproducibility.** On one device the results are bit for bit those of ``jax.vmap`` of
    the entry point (error control on a CPU: of the jitted entry point called for each
    trajectory, which runs them one after the other, see ``docs/ensembles.md``). On two or
    more devices XLA compiles a partitioned (SPMD) program, whose
    optimisation passes fuse and rewrite some floating-point expressions differently, so
    results agree with ``jax.vmap`` to round-off (tested to 1e-12; measurements on the
    [benchmarks page](../benchmarks/index.md)). Observed, not guaranteed: every device count ≥ 2 with
    at least two trajectories per device gives the same bits (``docs/ensembles.md``). Plain
    :func:`~lobattodae.integrate` and its ``vmap`` differ at round-off in the same way.

    **CPU devices.** Each CPU device's part runs on a thread of XLA's CPU thread pool (one
    thread per CPU, or ``$PJRT_NPROC``, or ``$NPROC``), and jaxlib's batched LU queues its
    tasks on the same pool and waits: with as many devices as pool threads the run can hang
    (JAX 0.10.2, 2 forced devices on 2 cores, 64 trajectories per device). So by default at
    most ``pool - 1`` CPU devices are used (with a ``RuntimeWarning``); set ``PJRT_NPROC``
    above the device count before JAX starts to use them all. Explicit ``devices`` are used
    as given, with a warning.

    **Several processes.** Under ``jax.distributed.initialize`` call ``ensemble`` in every
    process with the same arguments (the global batch, e.g. the same memory-mapped file):
    process i integrates trajectories ``i·B // P`` to ``(i+1)·B // P - 1`` on its local
    devices. With ``out_dir`` (a directory every process can reach) the processes wait for
    each other at the end (:func:`jax.experimental.multihost_utils.sync_global_devices`, which
    needs JAX's CPU collectives on CPU), so that any process can then load all files.
    """
    check_method(method)
    if save not in SAVE_MODES:
        raise LobattoDAEInputError(f"save must be one of {SAVE_MODES}; got {save!r}.")
    if if_exists not in IF_EXISTS:
        raise LobattoDAEInputError(f"if_exists must be one of {IF_EXISTS}; got {if_exists!r}.")
    mode = _mode(method, t0, h, n_steps, t_span, rtol, atol, first_step, max_step, max_steps, t_eval, controller,
                 t_eval_rows)
    q0, p0, lam0, batch = initial_values(q0, p0, lam0)
    leaves, treedef, flags, paths = arg_flags(args, batch_args)
    leaves = check_batched_args(leaves, flags, paths, batch)
    explicit = devices is not None
    devices = guard_cpu_pool(local_devices(devices), explicit=explicit)
    if block_size is not None:
        check_count("block_size", block_size, "trajectories per compiled call")

    n, m = q0.shape[1], lam0.shape[1]
    process, n_processes = jax.process_index(), jax.process_count()
    start, stop = process * batch // n_processes, (process + 1) * batch // n_processes
    n_local, n_dev = stop - start, len(devices)
    rows = mode.rows if save == "all" else 1
    if block_size is None:
        per_trajectory = 8 * rows * (2 * n + m + 1) + 16
        block_size = max(1, min(n_local, DEFAULT_BLOCK_PER_DEVICE * n_dev, MAX_BLOCK_OUTPUT_BYTES // per_trajectory))
    block = max(1, min(block_size, n_local))
    mesh = Mesh(np.asarray(devices), (AXIS,))
    plan = _Plan(problem, method, mode.n_steps, mode.max_steps, mode.controller, mode.has_t_eval, mode.t_eval_rows,
                 save, mesh, treedef, flags, in_turn=_in_turn(mode.n_steps is None, devices))
    blocks = _Blocks(plan, mode.numbers, [x for x, f in zip(leaves, flags) if not f], (q0, p0, lam0),
                     [x for x, f in zip(leaves, flags) if f], -(-block // n_dev) * n_dev)
    bounds = [(a, min(a + block, stop)) for a in range(start, stop, block)]
    check_initial_values(problem, blocks, bounds, treedef, leaves, flags, paths, batch)
    if out_dir is None:
        parts = [part for _, part in blocks.run(((a, b), blocks.inputs(a, b), b - a) for a, b in bounds)]
        out = _assemble(parts, np.arange(start, stop, dtype=np.int64), mode.n_steps is not None, n, m, mode.rows,
                        save)
        if out.n_roundoff_limited is not None:
            _warn_roundoff(out.index[_over_roundoff(out.n_roundoff_limited, mode)], out.index.size, mode)
        return out
    run_meta = {
        "format": FILE_FORMAT, "version": FILE_VERSION, "save": save, "batch": batch, "n": n, "m": m,
        "method": repr(method), "problem": _problem_token(problem), "args": _args_token(blocks.shared, paths, flags),
        **mode.settings,
    }
    n_failed, n_skipped, paths, over = _write_blocks(blocks, bounds, os.fspath(out_dir), if_exists, run_meta, process,
                                                     n_processes, mode)
    _warn_roundoff(over, stop - start, mode)
    if n_processes > 1:  # every process's files are complete once this returns anywhere
        from jax.experimental import multihost_utils

        multihost_utils.sync_global_devices("lobattodae.ensemble")
    return EnsembleFiles(tuple(paths), start, stop, n_failed, n_skipped, process, n_processes)


class _Mode(NamedTuple):
    """Constant or error-controlled steps: what is static, what is traced, what identifies the run."""

    n_steps: int | None  # constant steps
    max_steps: int | None  # error control
    controller: Any
    has_t_eval: bool
    t_eval_rows: str | None
    numbers: tuple  # traced: (t0, h) or (t0, t1, rtol, atol, first_step, max_step, t_eval)
    settings: dict  # for the files' meta
    rows: int  # rows of save="all"


def _mode(method, t0, h, n_steps, t_span, rtol, atol, first_step, max_step, max_steps, t_eval,
          controller, t_eval_rows=None) -> _Mode:
    """The steps of the run, by :func:`~lobattodae.solve`'s rules (:mod:`lobattodae._options`)."""
    adaptive_options = dict(rtol=rtol, atol=atol, first_step=first_step, max_step=max_step, max_steps=max_steps,
                            t_eval=t_eval, controller=controller, t_eval_rows=t_eval_rows)
    if t_span is None:
        if h is None or n_steps is None:
            raise LobattoDAEInputError(
                "give either h and n_steps (constant steps, integrate) or t_span (error-controlled steps, "
                "integrate_adaptive)."
            )
        for name, value in adaptive_options.items():
            if value is not None:
                raise LobattoDAEInputError(f"{name} applies to error-controlled runs (t_span=...); with h and "
                                           "n_steps the steps are constant.")
        t0, steps = ConstantSteps.grid(t0, h, n_steps)
        return _Mode(steps.n, None, None, False, None, (np.float64(t0), np.float64(steps.h)),
                     {"mode": "constant", "t0": t0, "steps": steps.identity()}, steps.n + 1)
    if h is not None or n_steps is not None or t0 is not None:
        raise LobattoDAEInputError(
            "give either t_span (error-controlled steps) or h and n_steps (constant steps), not both; t0 is t_span[0]."
        )
    check_tolerance_attainable(method)
    span = TimeSpan.of(t_span)
    steps = AdaptiveSteps.over(span, rtol, atol, first_step, max_step, controller, max_steps,
                               default_max_steps=STATIC_MAX_STEPS)
    saving = Saving.of(span, steps.controller, t_eval, t_eval_rows)
    t_eval = saving.t_eval
    numbers = tuple(np.float64(x) for x in (span.t0, span.t1, steps.rtol, steps.atol, steps.first_step,
                                             steps.max_step)) + (t_eval,)
    settings = {"mode": "adaptive", "t_span": span.identity(), "steps": steps.identity(), "max_steps": steps.max_steps,
                "saving": saving.identity()}
    rows = steps.max_steps + 1 if t_eval is None else t_eval.size
    return _Mode(None, steps.max_steps, steps.controller, t_eval is not None, saving.rows, numbers, settings, rows)


@dataclass
class _Blocks:
    """Runs blocks of the batch through the compiled program, one block ahead of the host."""

    plan: _Plan
    numbers: tuple
    shared: list  # args leaves shared by all trajectories
    initial: tuple  # (q0, p0, lam0), the whole batch (possibly memory maps)
    batched: list  # batched args leaves, the whole batch
    padded: int  # trajectories per compiled call (a multiple of the device count)

    def inputs(self, a: int, b: int) -> list[np.ndarray]:
        """Rows a..b-1 of every batched input, padded to ``padded`` rows."""
        return [_take(x, a, b, self.padded - (b - a)) for x in (*self.initial, *self.batched)]

    def launch(self, host: list[np.ndarray]):
        """Place a block on the mesh and dispatch it (returns at once; the result is a future)."""
        split = NamedSharding(self.plan.mesh, PartitionSpec(AXIS))
        xs = [jax.device_put(x, split) for x in host]
        return _run_block(self.plan, self.numbers, self.shared, xs[0], xs[1], xs[2], xs[3:])

    def run(self, items):
        """For ``(key, host inputs, trajectories)`` items, yield ``(key, results on the host)``.

        Block k + 1 is read and dispatched before block k is copied to the host: the copy (and
        whatever the caller does with it, e.g. writing a file) overlaps the computation.
        """
        pending = None
        for key, host, keep in items:
            out = self.launch(host)
            if pending is not None:
                yield pending[0], _to_host(pending[1], pending[2])
            pending = (key, out, keep)
        if pending is not None:
            yield pending[0], _to_host(pending[1], pending[2])


def _write_blocks(blocks: _Blocks, bounds, out_dir: str, if_exists: str, run_meta: dict, process: int,
                  n_processes: int, mode: _Mode) -> tuple[int, int, list[str], np.ndarray]:
    """Stream the blocks to ``out_dir`` (one ``.npz`` each), skipping complete ones on resume.

    Returns (failed trajectories, blocks skipped, the paths of all blocks, the trajectories of
    the computed blocks whose round-off-limited steps may add up to more than rtol)."""
    os.makedirs(out_dir, exist_ok=True)
    existing = own_files(out_dir, process)
    if existing and if_exists == "error":
        raise LobattoDAEInputError(
            f"'{out_dir}' already holds {len(existing)} ensemble file(s) of process {process} (e.g. "
            f"'{os.path.basename(existing[0])}'); pass if_exists='overwrite' to replace them, "
            "if_exists='resume' to keep the blocks of the same run, or use another out_dir."
        )
    paths = [os.path.join(out_dir, file_name(process, k)) for k in range(len(bounds))]
    for path in existing:  # refused before any work: what cannot be read (resume) or removed
        try:
            mode, own = os.stat(path).st_mode, os.lstat(path).st_mode
        except FileNotFoundError:  # a dangling link: removed below, or replaced
            continue
        if (stat.S_ISDIR(own) or (if_exists == "resume" and path in paths)) and not stat.S_ISREG(mode):
            raise not_regular_error(path, mode)
    for path in existing:  # "overwrite": all of them; "resume": those of an earlier run with more blocks
        if if_exists == "overwrite" or path not in paths:
            os.unlink(path)
    run_digest = hashlib.sha256(json.dumps(run_meta, sort_keys=True).encode()).hexdigest()
    count = {"failed": 0, "skipped": 0}
    over = []

    def todo():
        """The blocks to compute, read one at a time; complete ones are skipped on resume."""
        for k, (a, b) in enumerate(bounds):
            host = blocks.inputs(a, b)
            digest = block_digest(run_digest, a, b, [x[: b - a] for x in host])
            failed = resumable(paths[k], digest) if if_exists == "resume" and os.path.lexists(paths[k]) else None
            if failed is not None:
                count["failed"] += failed
                count["skipped"] += 1
                continue
            yield (k, a, b, digest), host, b - a

    for (k, a, b, digest), result in blocks.run(todo()):
        meta = {**run_meta, "run": run_digest, "block_digest": digest, "process_index": process,
                "process_count": n_processes, "block": k, "start": a, "stop": b,
                "n_devices": blocks.plan.mesh.devices.size, "padded_block": blocks.padded}
        arrays = {"meta": np.asarray(json.dumps(meta)), "index": np.arange(a, b, dtype=np.int64)}
        arrays.update({name: value for name, value in result.items() if value is not None})
        write_block(paths[k], arrays)
        if "n_roundoff_limited" in arrays:
            over.append(a + _over_roundoff(arrays["n_roundoff_limited"], mode))
        count["failed"] += int(np.count_nonzero(~np.isin(result["status"], REACHED_END)))
    over = np.concatenate(over, dtype=np.int64) if over else np.zeros(0, np.int64)
    return count["failed"], count["skipped"], paths, over


def _problem_token(problem) -> str:
    return fingerprint_callable(problem)


def _args_token(shared, paths, flags) -> dict:
    try:
        digest = fingerprint_arrays(shared)
    except TypeError:  # a non-numeric leaf: the run is identified without it
        digest = None
    return {"shared": digest, "batched": [p for p, f in zip(paths, flags) if f]}


def _over_roundoff(n_roundoff_limited: np.ndarray, mode: _Mode) -> np.ndarray:
    """Where (positions) the steps that passed only by the round-off floor may add up to more than rtol."""
    return np.flatnonzero(roundoff_may_exceed(np.asarray(n_roundoff_limited), float(mode.numbers[2])))


def _warn_roundoff(over: np.ndarray, total: int, mode: _Mode) -> None:
    """Warn, as :func:`~lobattodae.solve` does for one run, when some trajectories (``over``: their
    indices in the batch) took steps that passed only by the round-off floor and may add up to
    more than rtol."""
    if over.size:
        rtol = float(mode.numbers[2])  # (t0, t1, rtol, ...): only error-controlled runs count such steps
        warnings.warn(
            f"{over.size} of {total} trajectories (first: {int(np.min(over))}) took steps that asked for "
            f"less than their round-off: rtol={rtol:.3g} shared over the interval asks each step for a local error "
            f"below {ROUNDOFF_FLOOR:g}·(1 + |y|), which they were allowed instead (n_roundoff_limited); their error "
            "may exceed rtol. Use more stages (a higher order takes fewer steps) or a looser rtol.",
            RuntimeWarning, stacklevel=3,
        )


def _assemble(parts: list[dict], index: np.ndarray, fixed: bool, n: int, m: int, rows: int,
              save: str) -> EnsembleResult:
    if parts:
        joined = {name: np.concatenate([part[name] for part in parts]) for name in parts[0]}
    else:  # this process's slice is empty (fewer trajectories than processes)
        shape = (0,) if save == "final" else (0, rows)
        joined = {"q": np.zeros(shape + (n,)), "p": np.zeros(shape + (n,)), "lam": np.zeros(shape + (m,)),
                  "status": np.zeros((0,), np.int32)}
        if not fixed:
            joined.update(t=np.zeros(shape), **{name: np.zeros((0,), np.int32) for name in _ADAPTIVE_FIELDS[1:]})
    return EnsembleResult(index=index, **{name: joined.get(name) for name in _COMMON_FIELDS + _ADAPTIVE_FIELDS})


# -- reading the files back ----------------------------------------------------------------------------
def load_ensemble(source, *, fields: Sequence[str] | None = None) -> EnsembleResult:
    """Read the files of :func:`ensemble` (``out_dir=``) into one :class:`EnsembleResult`.

    Parameters
    ----------
    source : path, EnsembleFiles or sequence of paths
        A directory: all its ensemble files, which must form one complete run (every
        trajectory of the batch exactly once, all written with the same settings). An
        :class:`EnsembleFiles` or a list of files: just those (e.g. one block at a time, for
        post-processing a batch that does not fit in memory).
    fields : sequence of str, optional
        Load only these of ``q``, ``p``, ``lam``, ``status``, ``t``, ``n_rows``, ``n_steps``,
        ``n_rejected``, ``n_roundoff_limited`` (the others are ``None``); default: all that the
        run saved.

    Returns
    -------
    EnsembleResult
        Ordered by trajectory (``index``).

    Raises
    ------
    EnsembleFileError
        A file that is missing, not a regular file, unreadable, damaged (an array that does not
        match the digest written with it, or a failed zip CRC), of another format or version.
    LobattoDAEInputError
        No ensemble files, files of different runs, missing or repeated trajectories.
    """
    known = _COMMON_FIELDS + _ADAPTIVE_FIELDS
    if fields is not None:
        fields = tuple(fields)
        unknown = [f for f in fields if f not in known]
        if unknown:
            raise LobattoDAEInputError(f"fields must be among {known}; got {unknown}.")
    complete = False
    if isinstance(source, EnsembleFiles):
        paths = list(source.paths)
    elif isinstance(source, (str, os.PathLike)) and os.path.isdir(source):
        directory = os.fspath(source)
        paths = block_files(directory)
        if not paths:
            raise LobattoDAEInputError(f"'{directory}' holds no ensemble files ({FILE_GLOB}).")
        complete = True
    elif isinstance(source, (str, os.PathLike)):
        paths = [os.fspath(source)]
    else:
        paths = [os.fspath(p) for p in source]
    if not paths:
        raise LobattoDAEInputError("load_ensemble needs at least one ensemble file.")
    metas = []
    for path in paths:
        if not os.path.lexists(path):
            raise EnsembleFileError(f"'{path}' does not exist.", path)
        metas.append(read_meta(path))
    runs = {meta["run"] for meta in metas}
    if len(runs) > 1:
        first = {r: next(p for p, meta in zip(paths, metas) if meta["run"] == r) for r in runs}
        raise LobattoDAEInputError(
            f"the files come from {len(runs)} different ensemble runs (e.g. {sorted(first.values())}); "
            "remove the stale ones or load each run's files separately."
        )
    meta = metas[0]
    adaptive = meta["mode"] == "adaptive"
    saved = _COMMON_FIELDS + (_ADAPTIVE_FIELDS if adaptive else ())
    wanted = saved if fields is None else tuple(f for f in fields if f in saved)
    parts = []
    for path in paths:
        parts.append(read_block(path, ("index",) + wanted)[1])
    index = np.concatenate([part["index"] for part in parts])
    order = np.argsort(index, kind="stable")
    index = index[order]
    repeated = np.flatnonzero(np.diff(index) == 0)
    if repeated.size:
        raise LobattoDAEInputError(f"trajectory {int(index[repeated[0]])} appears in more than one file.")
    if complete and (index.size != meta["batch"] or index[0] != 0 or index[-1] != meta["batch"] - 1):
        missing = np.setdiff1d(np.arange(meta["batch"]), index)
        raise LobattoDAEInputError(
            f"the ensemble in '{source}' is incomplete: {missing.size} of {meta['batch']} trajectories are "
            f"missing (first: {int(missing[0])}); a process has not finished, or its files are elsewhere."
        )
    out = {name: np.concatenate([part[name] for part in parts])[order] for name in wanted}
    return EnsembleResult(index=index, **{name: out.get(name) for name in known})
