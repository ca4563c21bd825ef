"""The inputs of :func:`~lobattodae.ensemble`, checked before any work: the batch of initial
values and ``args`` (which leaves are batched, their shapes), the devices, and every
trajectory's initial values as :func:`~lobattodae.solve` checks them (the same tolerance and
messages, naming the trajectory).
"""

from __future__ import annotations

import warnings
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from . import _compile
from ._cpu import cpu_pool_size
from ._errors import LobattoDAEInputError, ProblemFunctionError, ShapeError
from ._validate import CONSISTENCY_TOL, SINGULAR_RCOND, _initial_quantities, validate_and_residual

__all__ = ["arg_flags", "check_batched_args", "check_initial_values", "guard_cpu_pool", "initial_values",
           "local_devices", "merge_args"]


def merge_args(flags, batched, shared):
    b, s = iter(batched), iter(shared)
    return [next(b) if f else next(s) for f in flags]


# -- input checks --------------------------------------------------------------------------------------
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


def initial_values(q0, p0, lam0):
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


def arg_flags(args, batch_args) -> tuple[list, Any, tuple[bool, ...], list]:
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


def check_batched_args(leaves, flags, paths, batch: int) -> list:
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


def local_devices(devices) -> list:
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


@_compile.jit(static_argnums=(0, 1, 2))
def _passes(problem, treedef, flags, t0, shared, q0, p0, lam0, batched):
    """Per trajectory of a block: whether it passes the consistency checks of
    :func:`validate_and_residual` (φ, the hidden constraint with the given λ0, ψ, a nonsingular
    D_pφ·D_λg; the same tolerances), vectorised. A row that fails is checked again by
    :func:`validate_and_residual` itself, which raises solve's error."""
    position = getattr(problem, "position_constraint", None)
    tol = CONSISTENCY_TOL

    def one(q, p, lam, rows):
        args = jax.tree_util.tree_unflatten(treedef, merge_args(flags, rows, shared))
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


def check_initial_values(problem, blocks, bounds, treedef, leaves, flags, paths, batch: int) -> None:
    """Refuse, before any work, what :func:`~lobattodae.solve` refuses: the problem functions and
    ``args`` on this process's first trajectory (errors of the functions, ``args=None``, m for the
    width of ``lam0``), then the consistency of every trajectory, block by block."""
    if not bounds:
        return
    t0 = blocks.numbers[0]
    q0, p0, lam0 = blocks.initial
    first = bounds[0][0]
    _, _, lam_first, _, _ = _validate_row(problem, t0, q0, p0, None, treedef, leaves, flags, paths, batch, first)
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


def guard_cpu_pool(devices: list, *, explicit: bool) -> list:
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
