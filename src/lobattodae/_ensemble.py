"""Ensembles: one problem, a batch of initial values and parameters, sharded across devices.

:func:`ensemble` integrates B trajectories of one problem with :func:`~lobattodae.integrate`
(constant steps) or :func:`~lobattodae.integrate_adaptive` (error-controlled steps), vmapped
over the trajectories and sharded over devices:

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
  :func:`load_ensemble` reads them back. A file is written like a checkpoint
  (:func:`lobattodae._checkpoint._write_atomic`: a unique temporary file, fsynced, renamed
  over the block's name) and carries a SHA-256 digest of each of its arrays (``digests``),
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
import glob
import hashlib
import json
import math
import os
import re
import stat
import warnings
import zipfile
import zlib
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec

from . import _checkpoint
from ._cpu import cpu_pool_size
from ._errors import LobattoDAEInputError, ProblemFunctionError, ShapeError
from ._loop import integrate, integrate_adaptive
from ._solve import _Options
from ._validate import CONSISTENCY_TOL, SINGULAR_RCOND, _initial_quantities, validate_and_residual

__all__ = [
    "AXIS",
    "DEFAULT_BLOCK_PER_DEVICE",
    "MAX_BLOCK_OUTPUT_BYTES",
    "EnsembleFileError",
    "EnsembleFiles",
    "EnsembleResult",
    "ensemble",
    "file_name",
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
#: Error-control defaults, as in :func:`~lobattodae.integrate_adaptive`.
DEFAULT_RTOL = 1e-8
DEFAULT_ATOL = 1e-10
DEFAULT_MAX_STEPS = 4096
#: The file format written with ``out_dir`` (a ``.npz`` per block, see :func:`load_ensemble`).
FILE_FORMAT = "lobattodae-ensemble"
#: 2: every file has a ``digests`` entry (SHA-256 of each array); version 1 files had none.
FILE_VERSION = 2
_FILE_GLOB = "ensemble-p*-b*.npz"
_FILE_RE = re.compile(r"^ensemble-p(\d+)-b(\d+)\.npz$")
#: The result fields of every run, and those only error-controlled runs have.
_COMMON_FIELDS = ("q", "p", "lam", "status")
_ADAPTIVE_FIELDS = ("t", "n_rows", "n_steps", "n_rejected")


class EnsembleFileError(LobattoDAEInputError):
    """An ensemble file cannot be used: unreadable, damaged (an array does not match the digest
    written with it), not a regular file, or of another format or version.

    Attributes
    ----------
    path : str
        The file.
    """

    def __init__(self, message: str, path: str | None = None):
        super().__init__(message)
        self.path = path


class EnsembleResult(NamedTuple):
    """What :func:`ensemble` returns without ``out_dir`` (and :func:`load_ensemble`): NumPy arrays,
    trajectory-major (axis 0 is the trajectory, then time for ``save="all"``).

    Fields that a run does not have are ``None``: ``t``, ``n_rows``, ``n_steps`` and
    ``n_rejected`` belong to error-controlled runs (constant steps are on the grid
    ``t0 + k·h``); :func:`load_ensemble` with ``fields=`` leaves out the others.
    """

    index: np.ndarray  # (B,) int64: the trajectory's position in the global batch
    q: np.ndarray | None  # (B, n) final, or (B, rows, n)
    p: np.ndarray | None  # (B, n) or (B, rows, n)
    lam: np.ndarray | None  # (B, m) or (B, rows, m)
    status: np.ndarray | None  # (B,) int32 Result code (0: success)
    t: np.ndarray | None = None  # adaptive: (B,) final time or (B, rows) step points / t_eval
    n_rows: np.ndarray | None = None  # adaptive: (B,) int32 valid rows of q, p, lam, t (NaN after them)
    n_steps: np.ndarray | None = None  # adaptive: (B,) int32 accepted steps
    n_rejected: np.ndarray | None = None  # adaptive: (B,) int32 rejected step attempts


class EnsembleFiles(NamedTuple):
    """What :func:`ensemble` returns with ``out_dir``: this process's files, not the results."""

    paths: tuple[str, ...]  # this process's block files, in the order of the trajectories
    start: int  # this process's slice of the global batch: trajectories start .. stop - 1
    stop: int
    n_failed: int  # trajectories of the slice whose status is not SUCCESSFUL
    n_skipped: int  # blocks found complete on disk (if_exists="resume") and not recomputed
    process_index: int
    process_count: int


def file_name(process: int, block: int) -> str:
    """The name of one block's file: ``ensemble-p<process, 5 digits>-b<block, 6 digits>.npz``."""
    return f"ensemble-p{process:05d}-b{block:06d}.npz"


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


def _merge(flags, batched, shared):
    b, s = iter(batched), iter(shared)
    return [next(b) if f else next(s) for f in flags]


def _one(plan: _Plan, numbers, shared, q0, p0, lam0, batched):
    """One trajectory (the function that is vmapped): the entry point, then what ``save`` keeps."""
    args = jax.tree_util.tree_unflatten(plan.treedef, _merge(plan.flags, batched, shared))
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


@functools.partial(jax.jit, static_argnums=0)
def _run_block(plan: _Plan, numbers, shared, q0, p0, lam0, batched):
    """One block, sharded over ``plan.mesh``: each device vmaps :func:`_one` over its part."""
    split, whole = PartitionSpec(AXIS), PartitionSpec()
    sharded = jax.shard_map(
        lambda numbers, shared, *xs: jax.vmap(functools.partial(_one, plan, numbers, shared))(*xs),
        mesh=plan.mesh, in_specs=(whole, whole, split, split, split, split), out_specs=split,
        # the integrators' loops carry device-invariant initial values that become per-device
        # ones (the check would want a pcast inside them); nothing here communicates
        check_vma=False,
    )
    return sharded(numbers, shared, q0, p0, lam0, batched)


# -- input checks --------------------------------------------------------------------------------------
def _count(name: str, value, *, allow_none: bool = False) -> None:
    if value is None and allow_none:
        return
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
        raise LobattoDAEInputError(f"{name} must be a positive integer; got {value!r}.")


def _number(name: str, value, *, finite: bool = True) -> float:
    if isinstance(value, (bool, str, bytes)) or np.ndim(value) != 0:
        raise LobattoDAEInputError(f"{name} must be a real number; got {value!r}.")
    try:
        x = float(value)
    except (TypeError, ValueError):
        raise LobattoDAEInputError(f"{name} must be a real number; got {value!r}.") from None
    if math.isnan(x) or (finite and not math.isfinite(x)):
        raise LobattoDAEInputError(f"{name} must be a finite number; got {value!r}.")
    return x


def _batch_array(name: str, x, what: str):
    """``x`` as an array-like with a shape (NumPy arrays, memory maps and jax Arrays stay as they are)."""
    if not (hasattr(x, "shape") and hasattr(x, "dtype")):
        try:
            x = np.asarray(x, dtype=np.float64)
        except (TypeError, ValueError) as exc:
            raise ShapeError(f"{name} must be an array of {what}; got {type(x).__name__} ({exc}).") from None
    kind = np.dtype(x.dtype).kind
    if kind not in "fiu":
        raise ShapeError(f"{name} must hold real numbers; got dtype {x.dtype}.")
    return x


def _initial_values(q0, p0, lam0):
    q0 = _batch_array("q0", q0, "initial positions, shape (B, n)")
    p0 = _batch_array("p0", p0, "initial momenta, shape (B, n)")
    lam0 = _batch_array("lam0", lam0, "initial multipliers, shape (B, m)")
    for name, x, dims in (("q0", q0, "(B, n)"), ("p0", p0, "(B, n)"), ("lam0", lam0, "(B, m)")):
        if len(x.shape) != 2:
            hint = (f" For one trajectory use {name}[None]; to repeat one value B times use "
                    f"np.broadcast_to({name}, (B, {name}.size)).") if len(x.shape) == 1 else ""
            raise ShapeError(
                f"{name} must be a batch of shape {dims}, one row per trajectory; got shape {tuple(x.shape)}.{hint}"
            )
    batch = q0.shape[0]
    if batch < 1:
        raise ShapeError("q0 holds no trajectories (shape (0, n)); an ensemble needs at least one.")
    if tuple(p0.shape) != tuple(q0.shape):
        raise ShapeError(
            f"p0 must have the shape of q0, {tuple(q0.shape)} (one momentum per coordinate and trajectory); "
            f"got {tuple(p0.shape)}."
        )
    if lam0.shape[0] != batch:
        raise ShapeError(
            f"lam0 must have one row per trajectory, like q0 ({batch} rows); got shape {tuple(lam0.shape)}."
        )
    return q0, p0, lam0, batch


def _arg_flags(args, batch_args) -> tuple[list, Any, tuple[bool, ...], list]:
    """(leaves, treedef, batched flag per leaf, key paths) of ``args``."""
    path_leaves, treedef = jax.tree_util.tree_flatten_with_path(args)
    paths = ["args" + jax.tree_util.keystr(p) for p, _ in path_leaves]
    leaves = [leaf for _, leaf in path_leaves]
    if isinstance(batch_args, (bool, np.bool_)):
        return leaves, treedef, (bool(batch_args),) * len(leaves), paths
    if batch_args is None:
        raise LobattoDAEInputError(
            "batch_args must be True, False or a pytree of bools shaped like args (a prefix of it); got None."
        )
    try:
        expanded = jax.tree_util.tree_map(
            lambda flag, sub: jax.tree_util.tree_map(lambda _: flag, sub), batch_args, args
        )
    except (ValueError, TypeError) as exc:
        raise LobattoDAEInputError(
            "batch_args must be True, False or a pytree of bools with the structure of args (or a prefix of "
            f"it), e.g. {type(args).__name__}(...) with True for the batched fields; it does not match args: {exc}"
        ) from None
    flags = jax.tree_util.tree_leaves(expanded)
    if len(flags) != len(leaves):
        raise LobattoDAEInputError(
            f"batch_args must give one flag per leaf of args ({len(leaves)} leaves); got {len(flags)} flags."
        )
    for path, flag in zip(paths, flags):
        if not isinstance(flag, (bool, np.bool_)):
            raise LobattoDAEInputError(f"batch_args must hold bools; got {flag!r} for {path}.")
    return leaves, treedef, tuple(bool(f) for f in flags), paths


def _check_batched_args(leaves, flags, paths, batch: int) -> list:
    out = []
    for leaf, flag, path in zip(leaves, flags, paths):
        if not flag:
            out.append(leaf)
            continue
        leaf = _batch_array(path, leaf, f"values, one per trajectory (leading axis of length {batch})")
        if len(leaf.shape) == 0 or leaf.shape[0] != batch:
            raise ShapeError(
                f"{path} is batched (batch_args) and must have one entry per trajectory along axis 0 "
                f"({batch}, like q0); got shape {tuple(leaf.shape)}. Give it a leading axis of length {batch}, "
                f"or mark it unbatched in batch_args."
            )
        out.append(leaf)
    return out


def _local_devices(devices) -> list:
    local = jax.local_devices()
    if devices is None:
        return list(local)
    devices = list(devices)
    if not devices:
        raise LobattoDAEInputError("devices must name at least one device; pass None for all of jax.local_devices().")
    if len(set(devices)) != len(devices):
        raise LobattoDAEInputError(f"devices must not repeat a device; got {devices}.")
    foreign = [d for d in devices if d not in local]
    if foreign:
        raise LobattoDAEInputError(
            f"devices must be devices of this process (jax.local_devices() = {local}); got {foreign}. Under "
            "jax.distributed every process runs its own slice of the batch on its own devices: call ensemble in "
            "every process, each with devices=None or its own local devices."
        )
    return devices


# -- initial values, checked as solve checks them -----------------------------------------------------------
#: Rows of a block whose pre-check fails that are checked one by one (the first failure raises).
_MAX_ROWS_CHECKED = 8


def _args_hints(leaves, flags, paths, batch: int) -> str:
    """What may be wrong with the batching of ``args``, for a problem function's error."""
    hints = []
    for leaf, flag, path in zip(leaves, flags, paths):
        shape = tuple(np.shape(leaf))
        if flag and len(shape) >= 2:
            hints.append(f"{path} is batched: trajectory k gets {path}[k], of shape {shape[1:]}")
        elif not flag and len(shape) >= 1 and shape[0] == batch:
            hints.append(f"{path} has shape {shape}, one entry per trajectory (B = {batch}), but is not marked in "
                         "batch_args, so every trajectory gets all of it: mark it batched (batch_args) if it holds "
                         "one value per trajectory")
    return (" Note: " + "; ".join(hints) + ".") if hints else ""


def _row_args(treedef, leaves, flags, k: int):
    """``args`` of trajectory ``k``: row k of the batched leaves (float64, as the blocks read them)."""
    return jax.tree_util.tree_unflatten(
        treedef, [np.asarray(leaf[k], dtype=np.float64) if f else leaf for leaf, f in zip(leaves, flags)]
    )


def _validate_row(problem, t0, q0, p0, lam0, treedef, leaves, flags, paths, batch: int, k: int):
    """:func:`validate_and_residual` of trajectory ``k`` (``lam0`` None: computed, to learn m);
    its errors name the trajectory."""
    try:
        return validate_and_residual(problem, t0, np.asarray(q0[k], np.float64), np.asarray(p0[k], np.float64),
                                     None if lam0 is None else np.asarray(lam0[k], np.float64),
                                     _row_args(treedef, leaves, flags, k))
    except LobattoDAEInputError as exc:
        message = str(exc)
        if "project_initial" in message:
            message += (" (ensemble has no project_initial: project the rows first, e.g. with "
                        "lobattodae.validate_initial_values(..., project=True) per trajectory)")
        message = message.replace("(omit lam0 to have it computed)", "(lobattodae.consistent_lambda computes it)")
        if isinstance(exc, (ProblemFunctionError, ShapeError)):
            message += _args_hints(leaves, flags, paths, batch)
        exc.args = (f"trajectory {k} (row {k} of q0, p0, lam0): {message}",) + exc.args[1:]
        raise


@functools.partial(jax.jit, static_argnums=(0, 1, 2))
def _passes(problem, treedef, flags, t0, shared, q0, p0, lam0, batched):
    """Per trajectory of a block: whether it passes the consistency checks of
    :func:`validate_and_residual` (φ, the hidden constraint with the given λ0, ψ, a nonsingular
    D_pφ·D_λg; the same tolerances), vectorised. A row that fails is checked again by
    :func:`validate_and_residual` itself, which raises solve's error."""
    position = getattr(problem, "position_constraint", None)
    tol = CONSISTENCY_TOL

    def one(q, p, lam, rows):
        args = jax.tree_util.tree_unflatten(treedef, _merge(flags, rows, shared))
        phi, r, jac = _initial_quantities(problem, t0, q, p, lam, args)
        biggest = lambda x: jnp.max(jnp.abs(x), initial=0.0)  # noqa: E731
        scale = 1.0 + biggest(p) + biggest(q)
        jscale = 1.0 + biggest(jac) * (1.0 + biggest(lam))
        ok = (biggest(phi) <= tol * scale) & (biggest(r) <= tol * jscale * scale)
        if position is not None:
            ok &= biggest(position(t0, q, args)) <= tol * scale
        if jac.shape[0]:
            sv = jnp.linalg.svd(jac, compute_uv=False)
            ok &= sv[-1] > SINGULAR_RCOND * sv[0]
        return ok

    return jax.vmap(one)(q0, p0, lam0, batched)


def _check_initial_values(problem, blocks: _Blocks, bounds, treedef, leaves, flags, paths, batch: int) -> None:
    """Refuse, before any work, what :func:`~lobattodae.solve` refuses: the problem functions and
    ``args`` on this process's first trajectory (errors of the functions, ``args=None``, m for the
    width of ``lam0``), then the consistency of every trajectory, block by block."""
    if not bounds:
        return
    t0 = blocks.numbers[0]
    q0, p0, lam0 = blocks.initial
    first = bounds[0][0]
    _, _, lam_first, _ = _validate_row(problem, t0, q0, p0, None, treedef, leaves, flags, paths, batch, first)
    m = lam_first.shape[0]
    if lam0.shape[1] != m:
        raise ShapeError(
            f"lam0 must have shape (B, m) = ({batch}, {m}): the problem has m = {m} constraint(s); got shape "
            f"{tuple(lam0.shape)}. Compute consistent rows with lobattodae.consistent_lambda."
        )
    for a, b in bounds:
        host = blocks.inputs(a, b)
        ok = np.asarray(_passes(problem, treedef, flags, t0, blocks.shared, host[0], host[1], host[2], host[3:]))
        for k in (np.flatnonzero(~ok[: b - a]) + a)[:_MAX_ROWS_CHECKED]:
            _validate_row(problem, t0, q0, p0, lam0, treedef, leaves, flags, paths, batch, int(k))


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


def _block_digest(run_digest: str, a: int, b: int, block_inputs) -> str:
    h = hashlib.sha256(f"{run_digest}:{a}:{b}:".encode())
    for x in block_inputs:
        x = np.ascontiguousarray(x)
        h.update(f"{x.dtype.str}:{x.shape}:".encode())
        h.update(x.tobytes())
    return h.hexdigest()


def _array_digest(name: str, x: np.ndarray) -> str:
    """SHA-256 of one array of a block file: its name, dtype, shape and C-order bytes."""
    x = np.ascontiguousarray(x)
    h = hashlib.sha256(f"{FILE_FORMAT}:{name}:{x.dtype.str}:{x.shape}:".encode())
    h.update(x.tobytes())
    return h.hexdigest()


def _write_npz(path: str, arrays: dict) -> None:
    """Write ``arrays`` and their digests (the entry ``digests``) to ``path`` with the checkpoint's
    atomic writer: a unique temporary file in the same directory, fsynced, then renamed."""
    arrays = {name: np.asarray(x) for name, x in arrays.items()}
    digests = {name: _array_digest(name, x) for name, x in arrays.items()}
    _checkpoint._write_atomic(path, {**arrays, "digests": np.asarray(json.dumps(digests, sort_keys=True))})


def _file_error(path: str, what: str, fix: str = "delete it and run that block again (if_exists='resume' "
                                                 "recomputes missing blocks)") -> EnsembleFileError:
    return EnsembleFileError(f"ensemble file '{path}' {what}; {fix}.", path)


def _kind(mode: int) -> str:
    for test, name in ((stat.S_ISDIR, "a directory"), (stat.S_ISFIFO, "a FIFO (named pipe)"),
                       (stat.S_ISSOCK, "a socket"), (stat.S_ISCHR, "a character device"),
                       (stat.S_ISBLK, "a block device")):
        if test(mode):
            return name
    return "not a plain file"


def _open_regular(path: str):
    """``path`` opened for reading if it is a regular file (a FIFO would block ``open`` until a
    writer comes); anything else raises :class:`EnsembleFileError`."""
    not_regular = "is not a regular file ({}); remove it or use another out_dir"
    try:
        info = os.stat(path)
    except OSError as exc:
        raise _file_error(path, f"cannot be read ({type(exc).__name__}: {exc})") from exc
    if not stat.S_ISREG(info.st_mode):
        raise EnsembleFileError(f"ensemble file '{path}' {not_regular.format(_kind(info.st_mode))}.", path)
    # O_NONBLOCK: should it have become a FIFO since, open() returns at once (and fstat refuses it)
    flags = os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_CLOEXEC", 0) | getattr(os, "O_BINARY", 0)
    try:
        fd = os.open(path, flags)
    except OSError as exc:
        raise _file_error(path, f"cannot be read ({type(exc).__name__}: {exc})") from exc
    mode = os.fstat(fd).st_mode
    if not stat.S_ISREG(mode):
        os.close(fd)
        raise EnsembleFileError(f"ensemble file '{path}' {not_regular.format(_kind(mode))}.", path)
    return os.fdopen(fd, "rb")


#: Everything NumPy's and zipfile's readers may raise on a damaged file.
_READ_ERRORS = (OSError, ValueError, EOFError, KeyError, IndexError, TypeError, OverflowError, zipfile.BadZipFile,
                zipfile.LargeZipFile, NotImplementedError, RuntimeError, zlib.error)


def _read_block(path: str, names: Sequence[str] | None = None) -> tuple[dict, dict]:
    """``(meta, arrays)`` of one block file, each array read checked against its digest:
    ``names`` (default: all of them) besides ``meta``. Raises :class:`EnsembleFileError`."""
    with _open_regular(path) as fh:
        try:
            with np.load(fh, allow_pickle=False) as z:
                files = set(z.files)
                if "meta" not in files:
                    raise _file_error(path, "is not a lobattodae ensemble file (no 'meta' entry)",
                                      "remove it from the directory")
                raw_meta = z["meta"]
                meta = json.loads(str(raw_meta))
                if not isinstance(meta, dict) or meta.get("format") != FILE_FORMAT:
                    raise _file_error(path, "is not a lobattodae ensemble file (format "
                                      f"{meta.get('format') if isinstance(meta, dict) else None!r})",
                                      "remove it from the directory")
                if meta.get("version") != FILE_VERSION:
                    raise _file_error(path, f"was written in ensemble file version {meta.get('version')!r}; this "
                                      f"lobattodae reads version {FILE_VERSION}", "run the ensemble again")
                if "digests" not in files:
                    raise _file_error(path, "is damaged: it has no 'digests' entry")
                digests = json.loads(str(z["digests"]))
                if not isinstance(digests, dict) or set(digests) != files - {"digests"}:
                    raise _file_error(path, "is damaged: its 'digests' entry does not list its arrays")
                arrays = {"meta": raw_meta}
                for name in (sorted(digests) if names is None else names):
                    if name not in arrays:
                        if name not in files:
                            raise _file_error(path, f"is damaged: it has no entry {name!r}")
                        arrays[name] = z[name]
                for name, x in arrays.items():
                    if _array_digest(name, x) != digests[name]:
                        raise _file_error(path, f"is damaged: its entry {name!r} does not match the digest "
                                          "written with it")
        except EnsembleFileError:
            raise
        except _READ_ERRORS as exc:  # json.JSONDecodeError is a ValueError
            raise _file_error(path, f"is damaged or cannot be read as an ensemble file ({type(exc).__name__}: "
                              f"{exc})") from exc
    del arrays["meta"]
    return meta, arrays


def _read_meta(path: str) -> dict:
    return _read_block(path, ())[0]


def _own_files(out_dir: str, process: int) -> list[str]:
    return sorted(glob.glob(os.path.join(glob.escape(out_dir), f"ensemble-p{process:05d}-b*.npz")))


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
        regular files).

    Notes
    -----
    **Reproducibility.** On one device the results are bit for bit those of ``jax.vmap`` of
    the entry point. On two or more devices XLA compiles a partitioned (SPMD) program, whose
    optimisation passes fuse and rewrite some floating-point expressions differently, so
    results agree with ``jax.vmap`` to round-off (measured on the knife edge: ≤ 2e-16 in q and
    p, ≤ 1.2e-14 in λ; tested to 1e-12). Observed, not guaranteed: every device count ≥ 2 with
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
    if save not in SAVE_MODES:
        raise LobattoDAEInputError(f"save must be one of {SAVE_MODES}; got {save!r}.")
    if if_exists not in IF_EXISTS:
        raise LobattoDAEInputError(f"if_exists must be one of {IF_EXISTS}; got {if_exists!r}.")
    mode = _mode(method, t0, h, n_steps, t_span, rtol, atol, first_step, max_step, max_steps, t_eval, controller,
                 t_eval_rows)
    q0, p0, lam0, batch = _initial_values(q0, p0, lam0)
    leaves, treedef, flags, paths = _arg_flags(args, batch_args)
    leaves = _check_batched_args(leaves, flags, paths, batch)
    explicit = devices is not None
    devices = _guard_cpu_pool(_local_devices(devices), explicit=explicit)
    _count("block_size", block_size, allow_none=True)

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
                 save, mesh, treedef, flags)
    blocks = _Blocks(plan, mode.numbers, [x for x, f in zip(leaves, flags) if not f], (q0, p0, lam0),
                     [x for x, f in zip(leaves, flags) if f], -(-block // n_dev) * n_dev)
    bounds = [(a, min(a + block, stop)) for a in range(start, stop, block)]
    _check_initial_values(problem, blocks, bounds, treedef, leaves, flags, paths, batch)
    if out_dir is None:
        parts = [part for _, part in blocks.run(((a, b), blocks.inputs(a, b), b - a) for a, b in bounds)]
        return _assemble(parts, np.arange(start, stop, dtype=np.int64), mode.n_steps is not None, n, m,
                         mode.rows, save)
    run_meta = {
        "format": FILE_FORMAT, "version": FILE_VERSION, "save": save, "batch": batch, "n": n, "m": m,
        "method": repr(method), "problem": _problem_token(problem), "args": _args_token(blocks.shared, paths, flags),
        **mode.settings,
    }
    n_failed, n_skipped, paths = _write_blocks(blocks, bounds, os.fspath(out_dir), if_exists, run_meta, process,
                                               n_processes)
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
        _count("n_steps", n_steps)
        t0 = 0.0 if t0 is None else _number("t0", t0)
        h = _number("h", h)
        if h == 0.0:
            raise LobattoDAEInputError("h must be nonzero (negative h integrates backwards).")
        return _Mode(n_steps, None, None, False, None, (np.float64(t0), np.float64(h)),
                     {"mode": "constant", "t0": t0, "h": h, "n_steps": n_steps}, n_steps + 1)
    if h is not None or n_steps is not None or t0 is not None:
        raise LobattoDAEInputError(
            "give either t_span (error-controlled steps) or h and n_steps (constant steps), not both; t0 is t_span[0]."
        )
    if isinstance(t_span, (str, bytes)) or np.shape(t_span) != (2,):
        raise LobattoDAEInputError(f"t_span must be a pair (t0, t1); got {t_span!r}.")
    ta, tb = (_number("t_span", x) for x in t_span)
    if ta == tb:
        raise LobattoDAEInputError(f"t_span must be an interval of positive length; got ({ta!r}, {tb!r}).")
    rtol = DEFAULT_RTOL if rtol is None else _number("rtol", rtol)
    atol = DEFAULT_ATOL if atol is None else _number("atol", atol)
    first_step = 0.0 if first_step is None else _number("first_step", first_step)
    max_step = math.inf if max_step is None else _number("max_step", max_step, finite=False)
    if not rtol > 0 or not atol >= 0 or not first_step >= 0 or not max_step > 0:
        raise LobattoDAEInputError(
            "rtol and max_step must be positive, atol and first_step non-negative (first_step=0: automatic); "
            f"got rtol={rtol!r}, atol={atol!r}, first_step={first_step!r}, max_step={max_step!r}."
        )
    max_steps = DEFAULT_MAX_STEPS if max_steps is None else max_steps
    _count("max_steps", max_steps)
    if t_eval is not None:
        t_eval = np.asarray(t_eval, dtype=np.float64)
        if t_eval.ndim != 1 or t_eval.size == 0 or not np.all(np.isfinite(t_eval)):
            raise LobattoDAEInputError(f"t_eval must be a non-empty 1-D array of finite times; got {t_eval!r}.")
    # then solve's own rules, with its messages: the rtol floor, t_eval within t_span and sorted in
    # the direction of integration, the controller's type, first_step within the span
    opt = _Options.check(
        method=method, t_span=(ta, tb), n_steps=None, dt=None, rtol=rtol, atol=atol,
        first_step=first_step or None, max_step=max_step, controller=controller, t_eval=t_eval,
        dense_output=False, events=None, save_every=None, chunk_size=None, max_recoveries=0, checkpoint=None,
        checkpoint_every=None, resume=False, t_eval_rows=t_eval_rows,
    )
    controller = opt.controller
    numbers = tuple(np.float64(x) for x in (ta, tb, rtol, atol, first_step, max_step)) + (t_eval,)
    settings = {"mode": "adaptive", "t_span": [ta, tb], "rtol": rtol, "atol": atol, "first_step": first_step,
                "max_step": repr(max_step), "max_steps": max_steps, "controller": repr(controller),
                "t_eval": None if t_eval is None else hashlib.sha256(t_eval.tobytes()).hexdigest(),
                "t_eval_rows": t_eval_rows}
    rows = max_steps + 1 if t_eval is None else t_eval.size
    return _Mode(None, max_steps, controller, t_eval is not None, t_eval_rows, numbers, settings, rows)


def _guard_cpu_pool(devices: list, *, explicit: bool) -> list:
    """Keep CPU meshes out of a deadlock of jaxlib's batched LAPACK kernels.

    On CPU each device's part of a sharded program runs on a thread of XLA's CPU thread pool,
    and jaxlib's batched LU (Newton's linear solves) splits a large batch into tasks on the
    same pool and waits for them. With as many devices as pool threads every thread can end
    up waiting: the run hangs (seen with 2 forced devices on 2 cores and 64 trajectories per
    device; jax 0.10.2). With fewer devices than threads a free thread runs the tasks. Default
    devices are therefore cut to ``pool - 1`` (with a warning); devices given explicitly are
    kept, with a warning.
    """
    if len(devices) < 2 or any(getattr(d, "platform", None) != "cpu" for d in devices):
        return devices
    pool = cpu_pool_size()
    if len(devices) < pool:
        return devices
    why = (f"{len(devices)} CPU devices with {pool} threads in XLA's CPU thread pool can deadlock: jaxlib's "
           "batched LU queues tasks on that pool and waits for them, and when every pool thread runs a device's "
           "part all of them can wait at once")
    fix = (f"set PJRT_NPROC={2 * len(devices)} (or NPROC) in the environment before JAX starts (the pool's size; "
           "XLA reads it once)")
    if explicit:
        warnings.warn(f"{why}. Large blocks may hang; {fix}, or pass at most {max(1, pool - 1)} device(s).",
                      RuntimeWarning, stacklevel=3)
        return devices
    keep = max(1, pool - 1)
    warnings.warn(f"ensemble shards over {keep} of the {len(devices)} local CPU devices: {why}. To use all of "
                  f"them, {fix}.", RuntimeWarning, stacklevel=3)
    return devices[:keep]


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
                  n_processes: int) -> tuple[int, int, list[str]]:
    """Stream the blocks to ``out_dir`` (one ``.npz`` each), skipping complete ones on resume.

    Returns (failed trajectories, blocks skipped, the paths of all blocks)."""
    os.makedirs(out_dir, exist_ok=True)
    existing = _own_files(out_dir, process)
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
            raise EnsembleFileError(f"ensemble file '{path}' is not a regular file ({_kind(mode)}); remove it or "
                                    "use another out_dir.", path)
    for path in existing:  # "overwrite": all of them; "resume": those of an earlier run with more blocks
        if if_exists == "overwrite" or path not in paths:
            os.unlink(path)
    run_digest = hashlib.sha256(json.dumps(run_meta, sort_keys=True).encode()).hexdigest()
    count = {"failed": 0, "skipped": 0}

    def todo():
        """The blocks to compute, read one at a time; complete ones are skipped on resume."""
        for k, (a, b) in enumerate(bounds):
            host = blocks.inputs(a, b)
            digest = _block_digest(run_digest, a, b, [x[: b - a] for x in host])
            failed = _resumable(paths[k], digest) if if_exists == "resume" and os.path.lexists(paths[k]) else None
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
        _write_npz(paths[k], arrays)
        count["failed"] += int(np.count_nonzero(result["status"] != 0))
    return count["failed"], count["skipped"], paths


def _problem_token(problem) -> str:
    from ._checkpoint import fingerprint_callable

    return fingerprint_callable(problem)


def _args_token(shared, paths, flags) -> dict:
    from ._checkpoint import fingerprint_arrays

    try:
        digest = fingerprint_arrays(shared)
    except TypeError:  # a non-numeric leaf: the run is identified without it
        digest = None
    return {"shared": digest, "batched": [p for p, f in zip(paths, flags) if f]}


def _resumable(path: str, digest: str) -> int | None:
    """The number of failed trajectories in the block file ``path`` if it is complete, intact
    (every array matches its digest) and of this run (``digest``); else None: computed again.
    A file that cannot be used is named in a warning; one that is not a regular file is refused."""
    try:
        meta, arrays = _read_block(path)
    except EnsembleFileError as exc:
        if os.path.exists(path) and not os.path.isfile(path):  # not a regular file: never replaced
            raise
        warnings.warn(f"{exc.args[0][:-1]} (if_exists='resume': the block is computed again and the file "
                      "replaced).", RuntimeWarning, stacklevel=2)
        return None
    if meta.get("block_digest") != digest or "status" not in arrays:  # another run's block
        return None
    return int(np.count_nonzero(arrays["status"] != 0))


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
        ``n_rejected`` (the others are ``None``); default: all that the run saved.

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
        paths = sorted(glob.glob(os.path.join(glob.escape(directory), _FILE_GLOB)))
        paths = [p for p in paths if _FILE_RE.match(os.path.basename(p))]
        if not paths:
            raise LobattoDAEInputError(f"'{directory}' holds no ensemble files ({_FILE_GLOB}).")
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
        metas.append(_read_meta(path))
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
        parts.append(_read_block(path, ("index",) + wanted)[1])
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
