"""Eager validation of a problem, its ``args`` and its initial values (run once, outside jit).

Every failure becomes a :class:`~lobattodae.LobattoDAEInputError` subclass whose message names
the argument (``q0``, ``args.m``, ``constraint_matrix``, ...) and the fix; never a raw JAX or
NumPy traceback. The user's functions are first *traced* to check what they return
(:mod:`lobattodae._problem_trace`); then the initial values are checked against the
constraints φ and ψ and the hidden constraint (λ0), and the mass matrix and ``D_pφ D_λg``
against singularity.
"""

from __future__ import annotations

import math
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from . import _compile
from ._errors import (
    InconsistentInitialValuesError,
    LobattoDAEInputError,
    ProblemDefinitionError,
    ShapeError,
    SingularConstraintError,
)
from ._problem import _hidden_constraint_and_jacobian, projection_step
from ._projection import project_positions
from ._problem_trace import check_args, function_error, length_hint, output_signature, short

__all__ = ["validate_initial_values", "check_float64", "check_args", "check_tolerance_attainable"]

#: Default tolerance for ``‖φ(t0, q0, p0)‖∞`` and for the hidden-constraint residual of a
#: given λ0, relative to the size of the data.
CONSISTENCY_TOL = 1e-10
#: Calls of the position projection (each three Newton steps) that project_initial may take.
_POSITION_PROJECTIONS = 5
#: ``D_pφ D_λg`` counts as singular when its reciprocal condition number is below this.
SINGULAR_RCOND = 1e-12
_LAMBDA_NEWTON_ITERATIONS = 20
#: The smallest Newton tolerance float64 can deliver: increments stall at round-off, a few
#: machine epsilons relative to the unknowns.
MIN_NEWTON_TOL = 4 * float(np.finfo(np.float64).eps)
def check_float64() -> None:
    if not jax.config.jax_enable_x64:
        raise RuntimeError(
            "lobattodae computes in float64, but JAX's float64 support has been switched off "
            "(jax_enable_x64=False) after lobattodae was imported. Re-enable it with "
            "jax.config.update('jax_enable_x64', True)."
        )


def check_method(method, *, native: bool = False) -> None:
    """``method`` must be a :class:`~lobattodae.LobattoIIIAIIIB`; where ``native`` allows it
    (:func:`~lobattodae.solve`), also a model's
    :class:`~lobattodae.mechanics.NativeIntegrator`, which the pure entry points refuse with the
    way out.

    Raises
    ------
    TypeError
        Neither.
    LobattoDAEInputError
        A NativeIntegrator where it cannot run.
    """
    from ._stepper import LobattoIIIAIIIB

    if isinstance(method, LobattoIIIAIIIB):
        return
    if callable(getattr(method, "doubling", None)):  # a NativeIntegrator (lobattodae.mechanics)
        if native:
            return
        raise LobattoDAEInputError(
            f"{method!r} runs in lobattodae.solve (error control) and in its own integrate and solve (constant "
            "steps), forward on the CPU: no jax.grad, jit, vmap or ensemble through it; here use its JAX method, "
            "native.method, instead.")
    raise TypeError(
        f"method must be a LobattoIIIAIIIB instance, e.g. LobattoIIIAIIIB(stages=3)"
        + (" (or a model's NativeIntegrator, model.native(stages))" if native else "") + f"; got {method!r}."
    )


def check_tolerance_attainable(method) -> None:
    """Refuse a Newton tolerance ``method.tol`` below what float64 can deliver.

    Newton's increments stall at round-off, a few machine epsilons relative to the unknowns,
    so a tolerance below :data:`MIN_NEWTON_TOL` (4 × machine epsilon ≈ 8.9e-16) would end in
    iteration-limit failures rather than a more accurate solution.

    Raises
    ------
    LobattoDAEInputError
    """
    tol = getattr(method, "tol", None)
    if isinstance(tol, bool) or not isinstance(tol, (int, float, np.integer, np.floating)):
        raise LobattoDAEInputError(f"the method's Newton tolerance tol must be a number; got {tol!r}.")
    if not float(tol) >= MIN_NEWTON_TOL:
        raise LobattoDAEInputError(
            f"tol={float(tol):.3g} ({type(method).__name__}) is below what float64 arithmetic can deliver: "
            f"Newton's increments stall at round-off, about {MIN_NEWTON_TOL / 4:.1e}·(1 + |x|), so steps would "
            f"fail at the iteration limit instead of getting more accurate. Use tol ≥ {MIN_NEWTON_TOL:.1e} "
            "(4 × machine epsilon); the default 1e-14 already solves the stage equations to round-off."
        )


def as_vector(x: Any, name: str) -> np.ndarray:
    """Convert an initial value to a finite float64 1-D array, or raise a clear error."""
    if x is None:
        raise ShapeError(f"{name} is None; pass a real numeric 1-D array of shape (n,).")
    if isinstance(x, (str, bytes)):
        raise ShapeError(f"{name} must be a real numeric 1-D array of shape (n,); got the string {short(x)}.")
    try:
        arr = np.asarray(x)
    except Exception:  # ragged nested lists, objects NumPy cannot convert
        raise ShapeError(
            f"{name} must be a real numeric 1-D array of shape (n,); {short(x)} cannot be converted "
            "to one (nested lists must be rectangular, entries numbers)."
        ) from None
    if arr.dtype == object or not (
        np.issubdtype(arr.dtype, np.floating) or np.issubdtype(arr.dtype, np.integer)
    ):
        what = " (it holds None or other non-numeric entries)" if arr.dtype == object else ""
        raise ShapeError(f"{name} must be a real numeric array; got dtype {arr.dtype}{what}: {short(x)}.")
    if arr.ndim != 1:
        raise ShapeError(
            f"{name} must be a 1-D array of shape (n,); got shape {arr.shape}. "
            "For many initial values at once use jax.vmap over lobattodae.integrate."
        )
    with np.errstate(over="ignore"):
        arr = arr.astype(np.float64)
    if not np.all(np.isfinite(arr)):
        raise ShapeError(f"{name} contains non-finite values (NaN or inf): {arr}.")
    return arr


def _as_time(t0: Any) -> float:
    if isinstance(t0, (str, bytes, bool, np.bool_)) or t0 is None:
        raise ShapeError(f"t0 must be a finite real number; got {short(t0)}.")
    try:
        arr = np.asarray(t0)
    except Exception:
        arr = np.asarray(None)
    if arr.shape != () or not (np.issubdtype(arr.dtype, np.floating) or np.issubdtype(arr.dtype, np.integer)):
        raise ShapeError(f"t0 must be a finite real number; got {short(t0)}.")
    t = float(arr)
    if not math.isfinite(t):
        raise ShapeError(f"t0 must be a finite real number; got {t}.")
    return t


@_compile.jit(static_argnums=0)
def _position_residual(problem, t, q, args):
    return problem.position_constraint(t, q, args)


def _check_position_constraint(problem, t0, q0, args, tol, scale) -> None:
    """q0 must satisfy the holonomic constraints ψ(t0, q0) = 0: the steps keep ψ at its
    initial value's manifold by projection, they do not move an inconsistent q0 onto it."""
    if getattr(problem, "position_constraint", None) is None:
        return
    try:
        psi0 = np.asarray(_position_residual(problem, t0, q0, args))
    except Exception as exc:  # re-raised with context: the user's function failed
        raise function_error("position_constraint(t, q, args)", exc) from exc
    norm = float(np.max(np.abs(psi0)))
    if not norm <= tol * scale:
        raise InconsistentInitialValuesError(
            f"the initial position violates the holonomic constraint: ‖ψ(t0, q0)‖∞ = {norm:.3e} > "
            f"{tol:.1e}·(1 + ‖q0‖∞ + ‖p0‖∞) (ψ = {psi0}). Fix q0 so that position_constraint(t0, q0, args) = 0, "
            "or pass project_initial=True to project q0 onto it."
        )


@_compile.jit(static_argnums=0)
def _projected_position(problem, t, q, p, args):
    q1 = project_positions(problem, t, q, p, args)
    return q1, problem.position_constraint(t, q1, args)


def _project_positions_initial(problem, t0, q0, p0, args, tol):
    """q0 moved onto ψ(t0, q) = 0 as the steps' projection moves their end points
    (:func:`~lobattodae._projection.project_positions`: along D_p f ψ_qᵀ, for a mechanical
    system the kinetic metric), repeated until the residual is at round-off, so that the result
    does not depend on how close q0 already was."""
    if getattr(problem, "position_constraint", None) is None:
        return q0
    eps = float(np.finfo(np.float64).eps)
    q = q0
    for _ in range(_POSITION_PROJECTIONS):
        try:
            q1, psi = (np.asarray(x) for x in _projected_position(problem, t0, q, p0, args))
        except Exception as exc:  # re-raised with context: the user's function failed
            raise function_error("position_constraint(t, q, args)", exc) from exc
        if not np.all(np.isfinite(q1)):
            break
        q = q1
        if float(np.max(np.abs(psi), initial=0.0)) <= 16 * eps * (1.0 + float(np.max(np.abs(q)))):
            return q
    psi = np.asarray(_position_residual(problem, t0, q, args))
    norm = float(np.max(np.abs(psi), initial=0.0))
    if not (np.all(np.isfinite(q)) and norm <= tol):
        raise InconsistentInitialValuesError(
            f"projecting q0 onto the holonomic constraint failed (remaining ‖ψ‖∞ = {norm:.3e}); check that "
            "position_constraint(t0, q, args) = 0 has a solution near q0 and that q0 is close to it."
        )
    return q


@_compile.jit(static_argnums=0)
def _initial_quantities(problem, t, q, p, lam, args):
    """φ, the hidden-constraint residual, D_pφ·D_λg and one Newton update of λ (one compile)."""
    r, jac = _hidden_constraint_and_jacobian(problem, t, q, p, lam, args)
    return problem.phi(t, q, p, args), r, jac


@_compile.jit(static_argnums=0)
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

    The checks :func:`~lobattodae.solve` makes before any work, on their own.

    Parameters
    ----------
    problem : PartitionedDAE, NonholonomicSystem or MechanicalSystem
    t0 : float
    q0, p0 : array_like, shape (n,)
    lam0 : array_like, shape (m,), optional
        Checked against the hidden constraint when given, computed from it otherwise.
    args : pytree, optional
    project : bool
        Replace ``p0`` by the nearest (least-squares) ``p`` with ``φ(t0, q0, p) = 0`` instead
        of raising; when the problem has a ``position_constraint``, first move ``q0`` onto
        ``ψ(t0, q) = 0`` as the steps' projection moves their end points (along
        ``D_p f ψ_qᵀ``: for a mechanical system the kinetic metric). Both to round-off.
    tol : float
        The consistency tolerance on ``‖φ‖∞`` and the hidden constraint.

    Returns
    -------
    (ndarray, ndarray, ndarray)
        ``(q0, p0, lam0)`` as float64 arrays.

    Raises
    ------
    ShapeError, InconsistentInitialValuesError, SingularConstraintError
    """
    q0, p0, lam0, _, _ = validate_and_residual(problem, t0, q0, p0, lam0, args, project=project, tol=tol)
    return q0, p0, lam0


class Initial(NamedTuple):
    """Validated initial values, ``‖φ(t0, q0, p0)‖∞`` and ``λ(t0, q0, p0)`` from the hidden
    constraint (one Newton update of λ0)."""

    q0: np.ndarray
    p0: np.ndarray
    lam0: np.ndarray
    phi_norm: float
    lam_hidden: np.ndarray


def validate_and_residual(problem, t0, q0, p0, lam0=None, args=None, *, project=False, tol=CONSISTENCY_TOL):
    """:func:`validate_initial_values`, also returning ‖φ(t0, q0, p0)‖∞ of the values returned
    and λ(t0, q0, p0) from the hidden constraint (an :class:`Initial`)."""
    for attr in ("f", "g", "phi"):
        if not callable(getattr(problem, attr, None)):
            raise ProblemDefinitionError(
                f"problem must provide f, g and phi (a PartitionedDAE, NonholonomicSystem or "
                f"MechanicalSystem); {type(problem).__name__} has no callable '{attr}'."
            )
    check_args(args)
    t0 = _as_time(t0)
    q0 = as_vector(q0, "q0")
    p0 = as_vector(p0, "p0")
    if lam0 is not None:
        lam0 = as_vector(lam0, "lam0")
    n = q0.shape[0]
    if p0.shape != q0.shape:
        raise ShapeError(
            f"q0 and p0 must have the same shape (n,); got {q0.shape} and {p0.shape}."
            + length_hint(problem, q0.shape[0], p0.shape[0], args)
        )
    if n == 0:
        raise ShapeError("q0 and p0 are empty; pass arrays of shape (n,) with n ≥ 1, one entry per coordinate.")
    # NumPy on the host (the compiled checks take it as it is; a jnp.asarray costs ~30 µs each)
    t0j = np.asarray(t0, np.float64)
    m = output_signature(problem, n, args)  # first: shapes (also of M and μ), by tracing
    _check_mass_matrix(problem, t0j, q0, args)  # then M's values: f, g and φ all solve with M
    if lam0 is not None and lam0.shape != (m,):
        raise ShapeError(
            f"lam0 must have shape (m,) = ({m},) to match phi; got {lam0.shape}. The problem has m = {m} "
            "constraint(s); omit lam0 to have it computed."
        )
    lam = np.zeros(m) if lam0 is None else lam0

    scale = 1.0 + float(np.max(np.abs(p0))) + float(np.max(np.abs(q0)))
    if project:
        q0 = _project_positions_initial(problem, t0j, q0, p0, args, tol * scale)
    _check_position_constraint(problem, t0j, q0, args, tol, scale)
    phi0, r, jac = (np.asarray(x) for x in _initial_quantities(problem, t0j, q0, p0, lam, args))
    _check_finite_at_start(phi0, r, jac, lam0 is not None)
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
        phi0, r, jac = (np.asarray(x) for x in _initial_quantities(problem, t0j, q0, p0, lam, args))
        _check_finite_at_start(phi0, r, jac, lam0 is not None)
    _check_nonsingular(jac)

    current = True  # r and jac are those at lam
    if lam0 is None:
        for _ in range(_LAMBDA_NEWTON_ITERATIONS):
            dlam = np.linalg.solve(jac, r)
            lam = np.asarray(lam) - dlam
            if not np.all(np.isfinite(lam)):
                raise InconsistentInitialValuesError(
                    "could not compute a consistent λ0 from the hidden constraint (non-finite result)."
                )
            if float(np.max(np.abs(dlam))) <= 1e-15 * (1.0 + float(np.max(np.abs(lam)))):
                current = False  # converged: one more update would move λ by round-off
                break
            _, r, jac = (np.asarray(x) for x in _initial_quantities(problem, t0j, q0, p0, lam, args))
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
    lam0 = np.asarray(lam0, np.float64)
    # λ(t0, q0, p0) as a step's start computes it (one Newton update of λ0; the stepper's initial
    # state takes it from here instead of evaluating the hidden constraint's Jacobian once more)
    lam_hidden = lam0 - np.linalg.solve(jac, r) if current else lam0
    return Initial(q0, np.asarray(p0, np.float64), lam0, float(np.max(np.abs(phi0))), lam_hidden)


@_compile.jit(static_argnums=0)
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
        raise function_error("mass_matrix(t, q, args)", exc) from exc
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


def _check_finite_at_start(phi0, r, jac, lam_given: bool) -> None:
    """φ, the hidden constraint and D_pφ·D_λg at the initial point must be finite: with finite
    q0, p0 and args (checked before) a NaN or inf here comes from the problem's functions."""
    cause = (
        "the problem's functions return NaN or inf there. Check the values in args (e.g. a zero "
        "mass or inertia, a division by a parameter) and q0, p0"
        + (", lam0" if lam_given else "")
        + "."
    )
    if not np.all(np.isfinite(phi0)):
        raise ShapeError(f"phi(t0, q0, p0, args) is not finite at the initial point ({phi0}): {cause}")
    if not (np.all(np.isfinite(r)) and np.all(np.isfinite(jac))):
        raise ShapeError(
            "the hidden constraint d/dt φ (from f, g and φ) or its λ-Jacobian D_pφ·D_λg is not finite at "
            f"the initial point: {cause}"
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
        p, dp = projection_step(problem, t0, q, p, args)
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
