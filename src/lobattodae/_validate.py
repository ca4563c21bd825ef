"""Eager validation of a problem and its initial values (run once, outside jit)."""

from __future__ import annotations

import functools
import math
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from ._errors import (
    InconsistentInitialValuesError,
    ProblemFunctionError,
    ShapeError,
    SingularConstraintError,
)
from ._problem import _hidden_constraint_and_jacobian

__all__ = ["validate_initial_values", "check_float64"]

#: Default tolerance for ``‖φ(t0, q0, p0)‖∞`` and for the hidden-constraint residual of a
#: given λ0, relative to the size of the data.
CONSISTENCY_TOL = 1e-10
#: ``D_pφ D_λg`` counts as singular when its reciprocal condition number is below this.
SINGULAR_RCOND = 1e-12
_LAMBDA_NEWTON_ITERATIONS = 20


def check_float64() -> None:
    if not jax.config.jax_enable_x64:
        raise RuntimeError(
            "lobattodae computes in float64, but JAX's float64 support has been switched off "
            "(jax_enable_x64=False) after lobattodae was imported. Re-enable it with "
            "jax.config.update('jax_enable_x64', True)."
        )


def as_vector(x: Any, name: str) -> np.ndarray:
    """Convert an initial value to a finite float64 1-D array, or raise a clear error."""
    arr = np.asarray(x)
    if arr.dtype == object or not (
        np.issubdtype(arr.dtype, np.floating) or np.issubdtype(arr.dtype, np.integer)
    ):
        raise ShapeError(f"{name} must be a real numeric array; got dtype {arr.dtype}.")
    if arr.ndim != 1:
        raise ShapeError(
            f"{name} must be a 1-D array of shape (n,); got shape {arr.shape}. "
            "For many initial values at once use jax.vmap over lobattodae.integrate."
        )
    arr = arr.astype(np.float64)
    if not np.all(np.isfinite(arr)):
        raise ShapeError(f"{name} contains non-finite values (NaN or inf): {arr}.")
    return arr


def _shape_of(fn, name: str, expected: tuple[int, ...] | None, *a):
    """Shape and dtype of a user function's output, found by tracing (nothing is compiled)."""
    try:
        out = jax.eval_shape(fn, *a)
    except Exception as exc:  # re-raised with context: the user's function failed
        raise _function_error(name, exc) from exc
    if not hasattr(out, "shape"):
        raise ShapeError(f"{name} must return a single array; it returned {type(out).__name__}.")
    if expected is not None and out.shape != expected:
        raise ShapeError(f"{name} must return an array of shape {expected}; it returned shape {out.shape}.")
    if not jnp.issubdtype(out.dtype, jnp.floating):
        raise ShapeError(f"{name} must return floating-point values; it returned dtype {out.dtype}.")
    if out.dtype != jnp.float64:
        raise ShapeError(
            f"{name} returned {out.dtype}, not float64: lobattodae computes in float64; "
            "do not cast to float32 inside the problem functions."
        )
    return out


def _function_error(name: str, exc: Exception) -> ProblemFunctionError:
    return ProblemFunctionError(
        f"calling {name} at the initial point (t0, q0, p0, args) raised {type(exc).__name__}: {exc} "
        "(the error comes from the problem's function; the original traceback is chained above)."
    )


def _check_output_shapes(problem, n: int, t, q, p, args) -> int:
    """Trace f, g and φ once (nothing is compiled) and check what they return; return m."""
    phi_s = _shape_of(problem.phi, "phi(t, q, p, args)", None, t, q, p, args)
    if len(phi_s.shape) != 1 or phi_s.shape[0] < 1:
        raise ShapeError(f"phi(t, q, p, args) must return a 1-D array of shape (m,), m ≥ 1; got shape {phi_s.shape}.")
    m = phi_s.shape[0]
    if m > n:
        raise ShapeError(f"there are more constraints (m={m}) than degrees of freedom (n={n}).")
    _shape_of(problem.f, "f(t, q, p, args)", (n,), t, q, p, args)
    lam = jax.ShapeDtypeStruct((m,), jnp.float64)
    _shape_of(problem.g, "g(t, q, p, lam, args)", (n,), t, q, p, lam, args)
    return m


@functools.lru_cache(maxsize=256)
def _cached_output_shapes(problem, n: int, args_treedef, args_avals) -> int:
    args = jax.tree_util.tree_unflatten(
        args_treedef, [jax.ShapeDtypeStruct(shape, dtype, weak_type=weak) for shape, dtype, weak in args_avals]
    )
    vec = jax.ShapeDtypeStruct((n,), jnp.float64)
    return _check_output_shapes(problem, n, jax.ShapeDtypeStruct((), jnp.float64), vec, vec, args)


def _output_signature(problem, n: int, args) -> int:
    """``m``, after checking the shapes and dtypes f, g and φ return for these input shapes.

    Tracing the user's functions costs ~10 ms, so the result is cached per (problem, n,
    abstract args); a second ``solve`` of the same problem does not trace them again.
    Problems or args that cannot be cached (unhashable, non-array leaves) are traced each time.
    """
    leaves, treedef = jax.tree_util.tree_flatten(args)
    try:
        avals = tuple(
            (np.shape(x), jnp.result_type(x), not isinstance(x, (np.ndarray, jax.Array, np.generic)))
            for x in leaves
        )
        hash((problem, treedef, avals))
    except TypeError:
        vec = jnp.zeros(n)
        return _check_output_shapes(problem, n, jnp.asarray(0.0), vec, vec, args)
    return _cached_output_shapes(problem, n, treedef, avals)


@functools.partial(jax.jit, static_argnums=0)
def _initial_quantities(problem, t, q, p, lam, args):
    """φ, the hidden-constraint residual, D_pφ·D_λg and one Newton update of λ (one compile)."""
    r, jac = _hidden_constraint_and_jacobian(problem, t, q, p, lam, args)
    return problem.phi(t, q, p, args), r, jac


@functools.partial(jax.jit, static_argnums=0)
def _phi_and_jacobian(problem, t, q, p, args):
    return problem.phi(t, q, p, args), jax.jacfwd(lambda pp: problem.phi(t, q, pp, args))(p)


def validate_initial_values(
    problem,
    t0: float,
    q0,
    p0,
    lam0=None,
    args: Any = None,
    *,
    project: bool = False,
    tol: float = CONSISTENCY_TOL,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Check shapes and consistency of ``(q0, p0, λ0)``; compute λ0 if it is not given.

    Returns float64 arrays ``(q0, p0, lam0)``. ``project=True`` replaces ``p0`` by the
    nearest (least-squares) ``p`` with ``φ(t0, q0, p) = 0`` instead of raising.

    Raises
    ------
    ShapeError, InconsistentInitialValuesError, SingularConstraintError
    """
    q0, p0, lam0, _ = validate_and_residual(problem, t0, q0, p0, lam0, args, project=project, tol=tol)
    return q0, p0, lam0


def validate_and_residual(problem, t0, q0, p0, lam0=None, args=None, *, project=False, tol=CONSISTENCY_TOL):
    """:func:`validate_initial_values`, also returning ‖φ(t0, q0, p0)‖∞ of the values returned."""
    for attr in ("f", "g", "phi"):
        if not callable(getattr(problem, attr, None)):
            raise TypeError(
                f"problem must provide f, g and phi (a PartitionedDAE, NonholonomicSystem or "
                f"MechanicalSystem); {type(problem).__name__} has no callable '{attr}'."
            )
    q0 = as_vector(q0, "q0")
    p0 = as_vector(p0, "p0")
    n = q0.shape[0]
    if p0.shape != q0.shape:
        raise ShapeError(f"q0 and p0 must have the same shape (n,); got {q0.shape} and {p0.shape}.")
    t0j = jnp.asarray(t0, jnp.float64)
    qj, pj = jnp.asarray(q0), jnp.asarray(p0)
    _check_mass_matrix(problem, t0j, qj, args)  # first: f, g and φ all solve with M
    m = _output_signature(problem, n, args)
    if lam0 is not None:
        lam0 = as_vector(lam0, "lam0")
        if lam0.shape != (m,):
            raise ShapeError(f"lam0 must have shape (m,) = ({m},) to match phi; got {lam0.shape}.")
    lam = jnp.zeros(m) if lam0 is None else jnp.asarray(lam0)

    scale = 1.0 + float(np.max(np.abs(p0))) + float(np.max(np.abs(q0)))
    phi0, r, jac = (np.asarray(x) for x in _initial_quantities(problem, t0j, qj, pj, lam, args))
    phi_norm = float(np.max(np.abs(phi0)))
    if not project and not phi_norm <= tol * scale:
        raise InconsistentInitialValuesError(
            f"the initial values violate the constraint: ‖φ(t0, q0, p0)‖∞ = {phi_norm:.3e} "
            f"> {tol:.1e}·(1 + ‖q0‖∞ + ‖p0‖∞). Fix q0/p0 so that φ = 0, or pass "
            "project_initial=True to project p0 onto the constraint."
        )
    if project:
        # Always project when asked, also when p0 is already within the tolerance: the user
        # then gets φ(t0, q0, p0) = 0 to round-off, not merely ≤ tol.
        p0 = _project_momenta(problem, t0j, q0, p0, args, tol * scale)
        pj = jnp.asarray(p0)
        phi0, r, jac = (np.asarray(x) for x in _initial_quantities(problem, t0j, qj, pj, lam, args))
    _check_nonsingular(jac)

    if lam0 is None:
        for _ in range(_LAMBDA_NEWTON_ITERATIONS):
            dlam = np.linalg.solve(jac, r)
            lam = np.asarray(lam) - dlam
            if not np.all(np.isfinite(lam)):
                raise InconsistentInitialValuesError(
                    "could not compute a consistent λ0 from the hidden constraint (non-finite result)."
                )
            if float(np.max(np.abs(dlam))) <= 1e-15 * (1.0 + float(np.max(np.abs(lam)))):
                break
            _, r, jac = (np.asarray(x) for x in _initial_quantities(problem, t0j, qj, pj, jnp.asarray(lam), args))
        lam0 = np.asarray(lam)
    else:
        rn = float(np.max(np.abs(r)))
        jscale = 1.0 + float(np.max(np.abs(jac))) * (1.0 + float(np.max(np.abs(lam0))))
        if not rn <= tol * jscale * scale:
            dl = np.linalg.solve(jac, r)
            raise InconsistentInitialValuesError(
                f"the given lam0 violates the hidden constraint d/dt φ = 0: residual {rn:.3e}. "
                f"The consistent value is lam0 = {np.asarray(lam0) - dl} "
                "(omit lam0 to have it computed)."
            )
    return q0, np.asarray(p0, np.float64), np.asarray(lam0, np.float64), float(np.max(np.abs(phi0)))


@functools.partial(jax.jit, static_argnums=0)
def _mass_matrix_at(problem, t, q, args):
    return problem.mass_matrix(t, q, args)


def _check_mass_matrix(problem, t0, q0, args) -> None:
    """A MechanicalSystem's M(t0, q0) must be symmetric positive definite (it is solved
    without pivoting, which relies on that; a bad M would only show later, as a failed step)."""
    mass = getattr(problem, "mass_matrix", None)
    if mass is None:
        return
    n = q0.shape[0]
    try:
        mm = _mass_matrix_at(problem, t0, q0, args)
    except Exception as exc:  # re-raised with context: the user's function failed
        raise _function_error("mass_matrix(t, q, args)", exc) from exc
    if mm.shape != (n, n):
        raise ShapeError(f"mass_matrix(t, q, args) must return an array of shape {(n, n)}; it returned shape {mm.shape}.")
    mm = np.asarray(mm, np.float64)
    if not np.all(np.isfinite(mm)):
        raise ShapeError(f"mass_matrix(t0, q0, args) contains non-finite values:\n{mm}")
    asym = float(np.max(np.abs(mm - mm.T)))
    if asym > 1e-12 * (1.0 + float(np.max(np.abs(mm)))):
        raise ShapeError(
            f"mass_matrix(t0, q0, args) must be symmetric; max |M - Mᵀ| = {asym:.3e}. "
            "Return the symmetric kinetic-energy matrix (H = ½ pᵀ M⁻¹ p + V)."
        )
    eig = np.linalg.eigvalsh(mm)
    if not eig[0] > 1e-14 * max(1.0, float(eig[-1])):
        raise ShapeError(
            f"mass_matrix(t0, q0, args) must be positive definite; its smallest eigenvalue is "
            f"{eig[0]:.3e}. A zero or negative mass (or a configuration where M degenerates) "
            "cannot be integrated; check the masses and inertias, or use PartitionedDAE."
        )


def _check_nonsingular(jac: np.ndarray) -> None:
    m = jac.shape[0]
    if not np.all(np.isfinite(jac)):
        raise SingularConstraintError(
            f"D_pφ·D_λg is not finite at the initial point:\n{jac}\nCheck the problem functions."
        )
    sv = np.linalg.svd(jac, compute_uv=False)
    rcond = sv[-1] / sv[0] if sv[0] > 0 else 0.0
    if not rcond > SINGULAR_RCOND or math.isclose(sv[0], 0.0):
        raise SingularConstraintError(
            f"D_pφ·D_λg ({m}×{m}) is singular at the initial point (reciprocal condition number "
            f"{rcond:.1e}): the problem is not an index-2 DAE there. A holonomic constraint "
            "ψ(q) = 0 must be differentiated once, φ = D_qψ(q)·f(q, p), and independent "
            "constraints must not be repeated."
        )


def _project_momenta(problem, t0, q0, p0, args, tol):
    """Least-squares projection of p0 onto {p : φ(t0, q0, p) = 0} (Gauss-Newton).

    Iterates until the correction is at round-off level (one step is exact for φ linear in
    p, the second confirms it), so the result does not depend on how close p0 already was.
    """
    p = jnp.asarray(p0)
    q = jnp.asarray(q0)
    eps = float(np.finfo(np.float64).eps)
    for _ in range(20):
        r, jp = _phi_and_jacobian(problem, t0, q, p, args)
        dp = jp.T @ jnp.linalg.solve(jp @ jp.T, r)
        p = p - dp
        if float(jnp.max(jnp.abs(dp))) <= 4 * eps * (1.0 + float(jnp.max(jnp.abs(p)))):
            break
    r, _ = _phi_and_jacobian(problem, t0, q, p, args)
    r = float(jnp.max(jnp.abs(r)))
    if not r <= tol:
        raise InconsistentInitialValuesError(
            f"projecting p0 onto the constraint failed (remaining ‖φ‖∞ = {r:.3e}); "
            "check that φ can be satisfied at q0."
        )
    return np.asarray(p)
