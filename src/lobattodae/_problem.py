"""Problem definitions: partitioned index-2 DAEs and nonholonomic Hamiltonian systems.

All user functions are pure JAX functions of ``(t, q, p[, lam], args)`` returning arrays.
Problems are immutable and hashed by identity, so they can be passed as static arguments
to ``jax.jit``: compiled code is cached per problem object.
"""

from __future__ import annotations

import contextlib
import contextvars
import dataclasses
import functools
from dataclasses import dataclass
from typing import Any, Callable

import jax
import jax.numpy as jnp

from ._errors import ProblemDefinitionError
from ._linalg import small_solve, spd_solve, value_and_jacobian

__all__ = [
    "PartitionedDAE",
    "NonholonomicSystem",
    "MechanicalSystem",
    "hidden_constraint",
    "consistent_lambda",
    "vector_field",
]


def _check_functions(problem, fields: tuple[tuple[str, str], ...]) -> None:
    """Refuse a problem whose functions are missing or not callable, naming the field.

    ``fields`` pairs each field with the call signature it must have (for the message). Run by
    ``__post_init__``, so a bad problem fails where it is built, not at the first solve.
    """
    cls = type(problem).__name__
    call = ", ".join(f"{name}=..." for name, _ in fields)
    optional = getattr(problem, "_optional_functions", ())  # None allowed: no such constraints
    for (name, signature), required in [(f, True) for f in fields] + [(f, False) for f in optional]:
        fn = getattr(problem, name)
        if fn is None:
            if not required:
                continue
            raise ProblemDefinitionError(
                f"{cls} needs {name}, a function {signature}; it is missing. "
                f"Construct it as {cls}({call})."
            )
        if not callable(fn):
            text = repr(fn)
            text = text if len(text) <= 60 else text[:57] + "..."
            alternative = "" if required else " or None (no such constraints)"
            raise ProblemDefinitionError(
                f"{cls}: {name} must be a function {signature}{alternative}; got {type(fn).__name__} {text}. "
                "Pass the function itself (not its value at some point)."
            )
    if not isinstance(problem.name, str):
        raise ProblemDefinitionError(
            f"{cls}: name must be a string; got {type(problem.name).__name__} {problem.name!r} "
            f"(the functions are {call.replace('=...', '')}; pass them by keyword)."
        )


#: Set while the problem's functions are checked one by one (:func:`plain_calls`).
_PLAIN_CALLS = contextvars.ContextVar("lobattodae_plain_calls", default=False)


@contextlib.contextmanager
def plain_calls():
    """Within this context the problem's functions run as given, not through ``jax.jit``: the
    checks of :mod:`~lobattodae._problem_trace` read what a failing function was called with
    (the very ``args`` objects), which a jitted call rebuilds from its leaves."""
    token = _PLAIN_CALLS.set(True)
    try:
        yield
    finally:
        _PLAIN_CALLS.reset(token)


class _TracedOnce:
    """A problem function called through ``jax.jit`` (see :func:`_traced_once`)."""

    def __init__(self, fn):
        self.plain, self.jitted = fn, jax.jit(fn)
        functools.update_wrapper(self, fn)

    @property
    def __fingerprint_as__(self):
        """Checkpoints identify the problem by the function as given (``lobattodae._io``):
        those written before the functions were wrapped still resume."""
        return self.plain

    def __call__(self, *args, **kwargs):
        return (self.plain if _PLAIN_CALLS.get() else self.jitted)(*args, **kwargs)


class _PicklableProblem:
    """Pickling and copying for the problem classes: the state is the dataclass fields with the
    functions as given (jitted callables do not pickle), and :func:`_traced_once` wraps them
    again when the copy is built (``__post_init__``)."""

    def __getstate__(self):
        fields = {f.name for f in dataclasses.fields(self)}
        return {k: v.plain if isinstance(v, _TracedOnce) else v for k, v in self.__dict__.items() if k in fields}

    def __setstate__(self, state):
        for k, v in state.items():
            object.__setattr__(self, k, v)
        self.__post_init__()


def _traced_once(problem, names: tuple[str, ...]) -> None:
    """Replace the functions ``names`` of ``problem`` (fields or methods) by jitted calls of them.

    A step program evaluates the problem's functions in a dozen places (the stage residual in
    both of Newton's loops, Newton's matrix, the stage completion, the consistent λ, the step
    doubling's vector fields, the projection). Called plainly, every place traces the function
    again, with its derivatives; a jitted function is traced once per input signature, and every
    place reuses that trace and its lowering. XLA inlines the calls, so the compiled program
    and its speed are the same (``benchmarks/RESULTS.md``, 2026-11-28 18:25: Andrews' squeezer
    traces in 0.50 instead of 1.05 s and lowers in 0.34 instead of 0.50 s).
    """
    for name in names:
        fn = getattr(problem, name, None)
        if fn is not None and not isinstance(fn, _TracedOnce):
            object.__setattr__(problem, name, _TracedOnce(fn))


@dataclass(frozen=True, eq=False)
class PartitionedDAE(_PicklableProblem):
    r"""A partitioned index-2 differential-algebraic equation

    .. math::

        q' = f(t, q, p), \qquad p' = g(t, q, p, λ), \qquad 0 = φ(t, q, p),

    with :math:`q, p ∈ R^n`, :math:`λ ∈ R^m` and :math:`D_p φ \, D_λ g` (m×m) invertible.

    Holonomic position constraints :math:`ψ(t, q) = 0` (k of them) whose velocity form
    :math:`ψ_q f + ψ_t = 0` is among the rows of φ can be given as ``position_constraint``:
    the integrator then projects every step's end point onto :math:`ψ = 0` and back onto
    :math:`φ = 0` (``docs/mechanics.md``, holonomic constraints), so that both hold to round-off at every
    step point, with the method's orders unchanged.

    Parameters
    ----------
    f : callable
        ``f(t, q, p, args) -> (n,)``.
    g : callable
        ``g(t, q, p, lam, args) -> (n,)``.
    phi : callable
        ``phi(t, q, p, args) -> (m,)``.
    name : str, optional
        Used in messages and plots.
    position_constraint : callable, optional
        ``psi(t, q, args) -> (k,)``, holonomic constraints ``ψ(t, q) = 0`` kept exactly by a
        projection after each step (None, the default: no projection, no cost). φ must
        contain their velocity form ``ψ_q f + ψ_t`` and g the forces ``ψ_qᵀ λ`` (as every
        :func:`lobattodae.mechanics.from_lagrangian` model with ``holonomic=[...]`` does);
        the initial q0 must satisfy ψ.
    """

    f: Callable[..., Any] | None = None
    g: Callable[..., Any] | None = None
    phi: Callable[..., Any] | None = None
    name: str = "PartitionedDAE"
    position_constraint: Callable[..., Any] | None = None

    #: Optional functions (None allowed), checked by ``_check_functions`` when given.
    _optional_functions = (("position_constraint", "psi(t, q, args) -> (k,)"),)

    def __post_init__(self):
        _check_functions(
            self,
            (
                ("f", "f(t, q, p, args) -> (n,)"),
                ("g", "g(t, q, p, lam, args) -> (n,)"),
                ("phi", "phi(t, q, p, args) -> (m,)"),
            ),
        )
        # f_and_g where a subclass has one (the models of lobattodae.mechanics)
        _traced_once(self, ("f", "g", "phi", "f_and_g", "position_constraint"))


class _HamiltonianMixin(_PicklableProblem):
    r"""f, g, φ of a nonholonomic Hamiltonian system with linear constraints μ(q) q' = 0:

    .. math::

        f = ∂H/∂p, \qquad g = -∂H/∂q + μ(q)^T λ, \qquad φ = μ(q) \, ∂H/∂p.
    """

    #: The functions the integrator evaluates (traced once per signature: :func:`_traced_once`).
    _EVALUATED = ("f", "g", "phi", "f_and_g")

    def hamiltonian(self, t, q, p, args):  # pragma: no cover - overridden
        raise NotImplementedError

    def constraint_matrix(self, t, q, args):  # pragma: no cover - overridden
        raise NotImplementedError

    def energy(self, t, q, p, args=None):
        """The Hamiltonian H(t, q, p) (the energy for mechanical systems)."""
        return self.hamiltonian(t, q, p, args)

    def f(self, t, q, p, args):
        return jax.grad(self.hamiltonian, argnums=2)(t, q, p, args)

    def f_and_g(self, t, q, p, lam, args):
        """``(f, g)`` from one gradient of H (cheaper than ``f`` and ``g`` separately)."""
        dh_dq, dh_dp = jax.grad(self.hamiltonian, argnums=(1, 2))(t, q, p, args)
        return dh_dp, -dh_dq + self.constraint_matrix(t, q, args).T @ lam

    def g(self, t, q, p, lam, args):
        dh_dq = jax.grad(self.hamiltonian, argnums=1)(t, q, p, args)
        mu = self.constraint_matrix(t, q, args)
        return -dh_dq + mu.T @ lam

    def phi(self, t, q, p, args):
        return self.constraint_matrix(t, q, args) @ self.f(t, q, p, args)


@dataclass(frozen=True, eq=False)
class NonholonomicSystem(_HamiltonianMixin):
    r"""A nonholonomic Hamiltonian system with constraints linear in the velocities.

    .. math::

        q' = ∂H/∂p, \qquad p' = -∂H/∂q + μ(q)^T λ, \qquad 0 = φ = μ(q)\, ∂H/∂p,

    built from the Hamiltonian and the constraint matrix by automatic differentiation.

    Parameters
    ----------
    hamiltonian : callable
        ``H(t, q, p, args) -> scalar``.
    constraint_matrix : callable
        ``mu(t, q, args) -> (m, n)``; the constraints are ``mu(t, q) q' = 0``.
    name : str, optional
    """

    # None marks a missing argument (refused by __post_init__ with a clear message); without a
    # default the mixin's placeholder methods would be taken as defaults by the dataclass.
    hamiltonian: Callable[..., Any] | None = None
    constraint_matrix: Callable[..., Any] | None = None
    name: str = "NonholonomicSystem"

    def __post_init__(self):
        _check_functions(
            self,
            (
                ("hamiltonian", "H(t, q, p, args) -> scalar"),
                ("constraint_matrix", "mu(t, q, args) -> (m, n)"),
            ),
        )
        _traced_once(self, _HamiltonianMixin._EVALUATED)


@dataclass(frozen=True, eq=False)
class MechanicalSystem(_HamiltonianMixin):
    r"""A mechanical system ``H = ½ pᵀ M(q)⁻¹ p + V(q)`` with constraints ``μ(q) q' = 0``.

    ``q' = M(q)⁻¹ p`` is computed by a linear solve without pivoting
    (:func:`~lobattodae.spd_solve`: written out column by column for n ≤ 8, faster per step on
    CPU than a LAPACK call: see the [benchmarks page](../benchmarks/index.md)), and
    ``D_p φ · D_λ g = μ M⁻¹ μᵀ``. ``M(q0)`` is checked to be symmetric positive definite
    when a solve starts.

    Parameters
    ----------
    mass_matrix : callable
        ``M(t, q, args) -> (n, n)``, symmetric positive definite.
    potential : callable
        ``V(t, q, args) -> scalar``.
    constraint_matrix : callable
        ``mu(t, q, args) -> (m, n)``.
    name : str, optional
    """

    mass_matrix: Callable[..., Any] | None = None
    potential: Callable[..., Any] | None = None
    constraint_matrix: Callable[..., Any] | None = None
    name: str = "MechanicalSystem"

    def __post_init__(self):
        _check_functions(
            self,
            (
                ("mass_matrix", "M(t, q, args) -> (n, n)"),
                ("potential", "V(t, q, args) -> scalar"),
                ("constraint_matrix", "mu(t, q, args) -> (m, n)"),
            ),
        )
        _traced_once(self, _HamiltonianMixin._EVALUATED)

    def hamiltonian(self, t, q, p, args):
        """The energy ``H = ½ pᵀ M(q)⁻¹ p + V(q)``.

        Parameters
        ----------
        t : float
            Time.
        q, p : array, shape (n,)
            Position and momentum.
        args : pytree
            Passed to ``mass_matrix``, ``potential`` and ``constraint_matrix``.

        Returns
        -------
        jax.Array
            H, a scalar.
        """
        v = spd_solve(self.mass_matrix(t, q, args), p)
        return 0.5 * jnp.dot(p, v) + self.potential(t, q, args)

    def f(self, t, q, p, args):
        """``f = ∂H/∂p = M(q)⁻¹ p``, the velocity q'.

        Parameters
        ----------
        t : float
            Time.
        q, p : array, shape (n,)
            Position and momentum.
        args : pytree
            Passed to ``mass_matrix``, ``potential`` and ``constraint_matrix``.

        Returns
        -------
        jax.Array, shape (n,)
            ``M(q)⁻¹ p``.
        """
        return spd_solve(self.mass_matrix(t, q, args), p)

    def g(self, t, q, p, lam, args):
        """``g = -∂H/∂q + μ(q)ᵀ λ``, the momentum's rate p'.

        Parameters
        ----------
        t : float
            Time.
        q, p : array, shape (n,)
            Position and momentum.
        lam : array, shape (m,)
            The multiplier λ.
        args : pytree
            Passed to ``mass_matrix``, ``potential`` and ``constraint_matrix``.

        Returns
        -------
        jax.Array, shape (n,)
            ``½ vᵀ (∂M/∂q) v − ∇V + μᵀ λ`` with ``v = M⁻¹ p``.
        """
        return self.f_and_g(t, q, p, lam, args)[1]

    def f_and_g(self, t, q, p, lam, args):
        """``(f, g)`` together, with one linear solve for ``v = M(q)⁻¹ p`` (the derivative of
        the kinetic energy in q is taken with v held fixed, not through the solve).

        Parameters
        ----------
        t : float
            Time.
        q, p : array, shape (n,)
            Position and momentum.
        lam : array, shape (m,)
            The multiplier λ.
        args : pytree
            Passed to ``mass_matrix``, ``potential`` and ``constraint_matrix``.

        Returns
        -------
        f, g : jax.Array, shape (n,)
            As :meth:`f` and :meth:`g`.
        """
        # -∂H/∂q = ½ vᵀ (∂M/∂q) v - ∇V with v = M⁻¹p held fixed: no derivative of the solve.
        v = self.f(t, q, p, args)
        kinetic = jax.grad(lambda qq: 0.5 * jnp.dot(v, self.mass_matrix(t, qq, args) @ v))(q)
        dv = jax.grad(lambda qq: self.potential(t, qq, args))(q)
        return v, kinetic - dv + self.constraint_matrix(t, q, args).T @ lam


def vector_field(problem, t, q, p, lam, args=None):
    """``(f(t, q, p), g(t, q, p, λ))``, through ``problem.f_and_g`` when it has one."""
    both = getattr(problem, "f_and_g", None)
    if both is not None:
        return both(t, q, p, lam, args)
    return problem.f(t, q, p, args), problem.g(t, q, p, lam, args)


def hidden_constraint(problem, t, q, p, lam, args=None):
    r"""The hidden constraint ``d/dt φ = φ_t + φ_q f + φ_p g(λ)`` at ``(t, q, p, λ)``.

    Consistent initial values satisfy ``φ = 0`` and this ``= 0``.

    Parameters
    ----------
    problem : PartitionedDAE, NonholonomicSystem or MechanicalSystem
    t : float
    q, p : jax.Array, shape (n,)
    lam : jax.Array, shape (m,)
    args : pytree, optional

    Returns
    -------
    jax.Array, shape (m,)
        The residual ``d/dt φ``.
    """
    t = jnp.asarray(t, dtype=q.dtype)
    dq, dp = vector_field(problem, t, q, p, lam, args)
    _, dphi = jax.jvp(
        lambda tt, qq, pp: problem.phi(tt, qq, pp, args),
        (t, q, p),
        (jnp.ones_like(t), dq, dp),
    )
    return dphi


def _hidden_constraint_and_jacobian(problem, t, q, p, lam, args):
    """The hidden-constraint residual and its λ-Jacobian ``D_pφ·D_λg`` in one forward pass."""
    return value_and_jacobian(lambda ll: hidden_constraint(problem, t, q, p, ll, args), lam)


def consistent_lambda(problem, t, q, p, lam_guess, args=None, iterations=3):
    r"""Solve the hidden constraint for λ by Newton's method (pure, jit/vmap-able).

    ``g`` is affine in λ for every nonholonomic system, so one iteration is exact there;
    ``iterations`` Newton steps are taken for general problems.

    Parameters
    ----------
    problem : PartitionedDAE, NonholonomicSystem or MechanicalSystem
    t : float
    q, p : jax.Array, shape (n,)
        A consistent state, ``φ(t, q, p) = 0``.
    lam_guess : jax.Array, shape (m,)
        Newton's starting value (any value, e.g. zeros, for nonholonomic systems).
    args : pytree, optional
    iterations : int
        Newton steps (static).

    Returns
    -------
    jax.Array, shape (m,)
        λ with ``hidden_constraint(problem, t, q, p, λ, args) = 0``.
    """

    def update(lam):
        r, jac = _hidden_constraint_and_jacobian(problem, t, q, p, lam, args)
        return lam - small_solve(jac, r)

    if iterations == 1:  # the common case inside the step loop: no loop construct
        return update(lam_guess)
    return jax.lax.fori_loop(0, iterations, lambda _, lam: update(lam), lam_guess)


def projection_step(problem, t, q, p, args=None):
    r"""One Gauss-Newton step of the projection onto ``{p : φ(t, q, p) = 0}``,

        p ← p − D_pφᵀ (D_pφ D_pφᵀ)⁻¹ φ(t, q, p),

    returning the new p and the correction (exact in one step for φ linear in p)."""
    r = problem.phi(t, q, p, args)
    jp = jax.jacfwd(lambda pp: problem.phi(t, q, pp, args))(p)
    dp = jp.T @ small_solve(jp @ jp.T, r)
    return p - dp, dp


def project_momenta(problem, t, q, p, args=None, iterations=2):
    r"""The least-squares projection of p onto the constraint ``φ(t, q, p) = 0`` (pure,
    jit/vmap/grad-able): ``iterations`` steps of :func:`projection_step`.

    One step is exact for every nonholonomic system (φ linear in p); the default second one
    removes its round-off. With :func:`consistent_lambda` it completes initial values computed
    from parameters, ``p0 = project_momenta(...)``, ``λ0 = consistent_lambda(...)``, so that a
    loss can be differentiated from physical parameters to the final state.

    Parameters
    ----------
    problem : PartitionedDAE, NonholonomicSystem or MechanicalSystem
    t : float
    q, p : array_like, shape (n,)
    args : pytree, optional
    iterations : int
        Gauss–Newton steps (static).

    Returns
    -------
    jax.Array, shape (n,)
        The momenta closest to ``p`` with ``φ(t, q, ·) = 0``.
    """
    t = jnp.asarray(t, jnp.result_type(p))
    return jax.lax.fori_loop(0, iterations, lambda _, pp: projection_step(problem, t, q, pp, args)[0], jnp.asarray(p))
