r"""From a SymPy Lagrangian to a :class:`~lobattodae.PartitionedDAE`.

The Lagrangian must be quadratic in the velocities,

.. math::

    L(t, q, \dot q) = ½ \dot q^T M(t, q) \dot q + a(t, q)^T \dot q - V(t, q),

with ``M`` symmetric positive definite, and the constraints affine in the velocities,
``μ(t, q) q̇ + ν(t, q) = 0``. With the momenta ``p = ∂L/∂q̇ = M q̇ + a`` the
Lagrange–d'Alembert equations ``d/dt ∂L/∂q̇ − ∂L/∂q = F + μᵀλ`` become the partitioned
index-2 DAE

.. math::

    q' = f = M^{-1}(p - a), \qquad
    p' = g = ∂L/∂q\,|_{\dot q = f} + F(t, q, f) + μ^T λ, \qquad
    0 = φ = μ(t, q) f + ν(t, q).

``M``, ``a``, ``∂L/∂q``, ``F``, ``μ`` and ``ν`` are derived symbolically once per model;
the solve ``M⁻¹(p − a)`` is done numerically in the generated JAX code.
"""

from __future__ import annotations

import difflib
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, Callable, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import sympy as sp

from .. import _compile
from .._errors import ShapeError
from .._problem import PartitionedDAE
from ._codegen import FunctionSpec, SolveSpec, generate_module, load_module, plain_symbols
from ._parsing import _Context, _err

__all__ = [
    "LagrangianDAE",
    "LagrangianModel",
    "SymbolicParts",
]

#: Relative tolerance below which the smallest eigenvalue of M (or of μ M⁻¹ μᵀ) counts as
#: zero: M is then not positive definite, the constraints dependent.
RANK_TOL = 1e-10
#: ‖ψ(t0, q0)‖∞ above which :meth:`LagrangianModel.check` rejects an initial position
#: (relative to 1 + ‖q0‖∞).
HOLONOMIC_TOL = 1e-10


@dataclass(frozen=True, eq=False)
class LagrangianDAE(PartitionedDAE):
    """The :class:`~lobattodae.PartitionedDAE` of a :class:`LagrangianModel`.

    Built by :func:`from_lagrangian` (as ``model.problem``), not by hand; pass it to
    :func:`lobattodae.solve` with ``args=model.args(...)``. Hashed by identity, like every
    problem.

    Attributes
    ----------
    f, g, phi : callable
        ``f(t, q, p, args)``, ``g(t, q, p, lam, args)``, ``phi(t, q, p, args)``, as in
        :class:`~lobattodae.PartitionedDAE`.
    f_and_g : callable
        ``(f, g)`` with one linear solve (used by the integrator).
    hamiltonian : callable
        ``hamiltonian(t, q, p, args)``: the energy ``pᵀq̇ − L``.
    mass_matrix : callable
        ``mass_matrix(t, q, args)``: ``M`` (checked to be symmetric positive definite when a
        solve starts).
    position_constraint : callable or None
        ``position_constraint(t, q, args)``: ``ψ`` of the holonomic constraints (None
        without them); the integrator keeps ``ψ = 0`` to round-off by projecting every
        step's end point.
    name : str
        The model's name.
    """

    f_and_g: Callable[..., Any] | None = None
    hamiltonian: Callable[..., Any] | None = None
    mass_matrix: Callable[..., Any] | None = None


class SymbolicParts(NamedTuple):
    """The symbolic ingredients of a model, in the user's symbols (``x(t)``, ``ẋ``).

    ``lagrangian = ½ q̇ᵀ mass_matrix q̇ + gyroscopic·q̇ − potential``; the constraints are
    ``constraint_matrix q̇ + constraint_offset = 0`` (nonholonomic first, then the
    differentiated holonomic ones); ``holonomic`` are the position-level ``ψ(t, q)``.

    Attributes
    ----------
    lagrangian : sympy.Expr
        ``L(t, q, q̇)`` as given.
    mass_matrix : sympy.Matrix
        ``M(t, q) = ∂²L/∂q̇²`` (n×n).
    gyroscopic : sympy.Matrix
        ``a(t, q)``, the part of ``L`` linear in ``q̇`` (n×1).
    potential : sympy.Expr
        ``V(t, q)``.
    constraint_matrix : sympy.Matrix
        ``μ(t, q)`` (m×n).
    constraint_offset : sympy.Matrix
        ``ν(t, q)`` (m×1): nonzero for affine or time-dependent constraints.
    forces : sympy.Matrix
        The generalized forces ``F(t, q, q̇)`` (n×1).
    holonomic : sympy.Matrix
        ``ψ(t, q)`` (k×1; empty without holonomic constraints).
    """

    lagrangian: sp.Expr
    mass_matrix: sp.Matrix
    gyroscopic: sp.Matrix
    potential: sp.Expr
    constraint_matrix: sp.Matrix
    constraint_offset: sp.Matrix
    forces: sp.Matrix
    holonomic: sp.Matrix


# ----------------------------------------------------------------------------- the model
class LagrangianModel:
    r"""A constrained Lagrangian system and its generated :class:`LagrangianDAE`.

    Built by :func:`from_lagrangian` (or :func:`from_lagranges_method`); the problem, its
    generated code and the compiled helpers exist once per model, so repeated solves with new
    ``args`` values do not recompile.

    Attributes
    ----------
    problem : LagrangianDAE
        Pass to :func:`lobattodae.solve` / :func:`lobattodae.integrate` with ``args=model.args(...)``.
    name : str
    coordinates : tuple
        The coordinates ``q_i(t)``, in the order of the state vectors.
    parameters : tuple of str
        The names of the free symbols; :meth:`args` needs a value for each.
    constraint_labels : tuple of str
        One per multiplier ``λ_j``: the nonholonomic constraints, then the holonomic ones
        (rows ``ψ_q q̇ + ψ_t = 0`` of φ; ψ itself is kept by projection).
    n, m : int
        Number of coordinates and of constraints (multipliers).
    n_holonomic : int
    symbolic : SymbolicParts
        ``M``, ``a``, ``V``, ``μ``, ``ν``, ``F``, ``ψ`` in the user's symbols.
    source : str
        The generated JAX code.
    """

    def __init__(self, *, name, ctx: _Context, params, defaults, parts_internal, labels, n_holonomic, lagrangian_user):
        self.name = name
        self._ctx = ctx
        self.t = ctx.t
        self.coordinates = ctx.coords
        self.coordinate_names = ctx.names
        self.n = ctx.n
        self._param_symbols = dict(params)  # name -> Symbol
        self.parameters = tuple(params.keys())
        self.defaults = dict(defaults)
        self.constraint_labels = tuple(labels)
        self.m = len(labels)
        self.n_holonomic = n_holonomic
        M, a, V, mu, nu, F, psi, L = parts_internal
        self.symbolic = SymbolicParts(
            lagrangian=lagrangian_user,
            mass_matrix=ctx.user(M),
            gyroscopic=ctx.user(a),
            potential=ctx.user(V),
            constraint_matrix=ctx.user(mu),
            constraint_offset=ctx.user(nu),
            forces=ctx.user(F),
            holonomic=ctx.user(psi),
        )
        self._generate(M, a, V, mu, nu, F, psi, L)

    # ------------------------------------------------------------------ code generation
    def _generate(self, M, a, V, mu, nu, F, psi, L):
        n, m = self.n, self.m
        t, q, v, p, lam, ks, rename = plain_symbols(self._ctx, m, self.parameters, self._param_symbols)

        def r(e):
            return sp.sympify(e).xreplace(rename)

        M, a, mu, nu, F, psi = (r(x) for x in (M, a, mu, nu, F, psi))
        V, L = r(V), r(L)
        dLdq = [sp.diff(L, qi) for qi in q]
        g = [dLdq[i] + F[i] + sum((mu[j, i] * lam[j] for j in range(m)), sp.S.Zero) for i in range(n)]
        phi = [sum((mu[j, i] * v[i] for i in range(n)), sp.S.Zero) + nu[j] for j in range(m)]
        vv = sp.Matrix(v)
        energy = sp.Rational(1, 2) * (vv.T * M * vv)[0, 0] + V
        momenta = list(M * vv + a)
        forces_on = [sum((mu[j, i] * lam[j] for j in range(m)), sp.S.Zero) for i in range(n)]
        solve = SolveSpec(matrix=M, rhs=tuple(p[i] - a[i] for i in range(n)), unknowns=v)
        Q, P, LAM, QD = ("q", q), ("p", p), ("lam", lam), ("qdot", v)
        specs = [
            FunctionSpec("f", (Q, P), (("vector", v),), solve, "q' = M^-1 (p - a)"),
            FunctionSpec("g", (Q, P, LAM), (("vector", g),), solve, "p' = dL/dq + F + mu^T lam"),
            FunctionSpec("f_and_g", (Q, P, LAM), (("vector", v), ("vector", g)), solve, "(f, g)"),
            FunctionSpec("phi", (Q, P), (("vector", phi),), solve, "phi = mu f + nu"),
            FunctionSpec("hamiltonian", (Q, P), (("scalar", energy),), solve, "H = p^T qdot - L"),
            FunctionSpec("mass_matrix", (Q,), (("matrix", M),), None, "M(t, q)"),
            FunctionSpec("constraint_terms", (Q,), (("matrix", mu), ("vector", list(nu))), None, "(mu, nu)"),
            FunctionSpec("momenta", (Q, QD), (("vector", momenta),), None, "p = M qdot + a"),
            FunctionSpec("constraint_forces", (Q, LAM), (("vector", forces_on),), None, "mu^T lam"),
            FunctionSpec("holonomic", (Q,), (("vector", list(psi)),), None, "psi(t, q)"),
            FunctionSpec("forces", (Q, QD), (("vector", list(F)),), None, "F(t, q, qdot)"),
            FunctionSpec("lagrangian", (Q, QD), (("scalar", L),), None, "L(t, q, qdot)"),
        ]
        assert tuple(spec.name for spec in specs) == self._FUNCTIONS  # what a restored model defines
        params = list(zip(self.parameters, ks))
        module = generate_module(self.name, specs, t, params)
        self.source = module.source
        self._bind(module.functions)

    #: What a model is besides its functions: kept across processes (``_model_cache``).
    _STATE = ("name", "_ctx", "t", "coordinates", "coordinate_names", "n", "_param_symbols", "parameters",
              "defaults", "constraint_labels", "m", "n_holonomic", "symbolic", "source")
    #: The generated module's functions, in the order the generator writes them.
    _FUNCTIONS = ("f", "g", "f_and_g", "phi", "hamiltonian", "mass_matrix", "constraint_terms", "momenta",
                  "constraint_forces", "holonomic", "forces", "lagrangian")

    def _snapshot(self) -> dict:
        """The model's state without its functions (which its ``source`` defines)."""
        return {key: getattr(self, key) for key in self._STATE}

    @classmethod
    def _restore(cls, state: dict) -> "LagrangianModel":
        """The model of :meth:`_snapshot`, its functions from its source (which passed
        :func:`~lobattodae.mechanics._codegen.load_module`'s check when it was generated)."""
        model = cls.__new__(cls)
        for key in cls._STATE:
            setattr(model, key, state[key])
        model._bind(load_module(model.name, model.source, cls._FUNCTIONS, check=False).functions)
        return model

    def _bind(self, fns: dict) -> None:
        """The problem and the compiled helpers from the generated functions."""
        self._fns = fns
        self.problem = LagrangianDAE(
            f=fns["f"],
            g=fns["g"],
            phi=fns["phi"],
            name=self.name,
            f_and_g=fns["f_and_g"],
            hamiltonian=fns["hamiltonian"],
            mass_matrix=fns["mass_matrix"],
            position_constraint=fns["holonomic"] if self.n_holonomic else None,
        )
        self._jit = {key: _compile.jit(fn) for key, fn in fns.items()}
        self._vmapped = {}

    # ------------------------------------------------------------------ parameters
    def args(self, values: Mapping | None = None, /, **kwargs) -> dict:
        """The ``args`` pytree: a dict ``name -> float64 scalar`` with one entry per parameter.

        Values come from ``values``, then keywords, then the model's defaults.

        Parameters
        ----------
        values : mapping, optional
            Parameter values keyed by name (str) or by SymPy Symbol.
        **kwargs
            Parameter values by name.

        Returns
        -------
        dict
            ``{name: jax float64 scalar}``, one entry for each of :attr:`parameters`: the
            ``args`` of :func:`lobattodae.solve` and of this model's methods.

        Raises
        ------
        LobattoDAEInputError
            For a missing or unknown parameter (naming it, with the closest known name), a
            name given twice, or a value that is not a finite real scalar.
        """
        given: dict[str, Any] = {}
        if values is not None:
            if not isinstance(values, Mapping):
                raise _err(
                    f"{self.name}: args() takes a mapping name -> value and/or keywords; got "
                    f"{type(values).__name__}."
                )
            for key, val in values.items():
                name = key.name if isinstance(key, sp.Symbol) else key
                if not isinstance(name, str):
                    raise _err(f"{self.name}: parameter names must be strings or Symbols; got {key!r}.")
                given[name] = val
        for key, val in kwargs.items():
            if key in given:
                raise _err(f"{self.name}: parameter {key!r} given twice.")
            given[key] = val
        unknown = [k for k in given if k not in self._param_symbols]
        if unknown:
            hints = []
            for k in unknown:
                close = difflib.get_close_matches(k, self.parameters, n=1)
                hints.append(f"{k!r}" + (f" (did you mean {close[0]!r}?)" if close else ""))
            raise _err(
                f"{self.name}: unknown parameter(s) {', '.join(hints)}; the model's parameters "
                f"(free symbols) are {list(self.parameters)}."
            )
        merged = {**self.defaults, **given}
        missing = [k for k in self.parameters if k not in merged]
        if missing:
            raise _err(
                f"{self.name}: no value for the parameter(s) {missing} (free symbols of the "
                f"Lagrangian, constraints or forces); pass them, e.g. model.args("
                + ", ".join(f"{k}=..." for k in missing) + ")."
            )
        out = {}
        for k in self.parameters:
            val = merged[k]
            try:
                arr = np.asarray(val, dtype=np.float64)
            except (TypeError, ValueError):
                raise _err(f"{self.name}: parameter {k!r} must be a real number; got {val!r}.") from None
            if arr.shape != ():
                raise _err(
                    f"{self.name}: parameter {k!r} must be a scalar; got shape {arr.shape}. For a "
                    "batch of parameter values, jax.vmap over lobattodae.integrate."
                )
            if not np.isfinite(arr):
                raise _err(f"{self.name}: parameter {k!r} must be finite; got {val!r}.")
            out[k] = jnp.asarray(arr)
        return out

    def _check_args(self, args):
        if args is None and not self.parameters:
            return {}
        if not isinstance(args, Mapping):
            raise _err(
                f"{self.name}: args must be the dict returned by model.args(...); got "
                f"{type(args).__name__}."
            )
        keys = set(args)
        expected = set(self.parameters)
        if keys != expected:
            missing = sorted(expected - keys)
            unknown = sorted(map(str, keys - expected))
            raise _err(
                f"{self.name}: args has missing parameter(s) {missing} and unknown key(s) {unknown}; "
                "build it with model.args(...)."
            )
        return args

    # ------------------------------------------------------------------ evaluation
    def _eval(self, key, t, vectors, sizes, args):
        args = self._check_args(args)
        t = jnp.asarray(t, dtype=jnp.float64)
        vecs = []
        for (label, size), x in zip(sizes, vectors):
            arr = jnp.asarray(x, dtype=jnp.float64)
            if arr.ndim not in (1, 2) or arr.shape[-1] != size:
                raise ShapeError(
                    f"{self.name}: {label} must have shape ({size},) or (N, {size}); got {arr.shape}."
                )
            vecs.append(arr)
        batched = vecs[0].ndim == 2
        if any((x.ndim == 2) != batched for x in vecs) or (batched and len({x.shape[0] for x in vecs}) != 1):
            raise ShapeError(f"{self.name}: mixed single states and trajectories: {[x.shape for x in vecs]}.")
        if not batched:
            if t.ndim != 0:
                raise ShapeError(f"{self.name}: t must be a scalar for a single state; got shape {t.shape}.")
            out = self._jit[key](t, *vecs, args)
        else:
            count = vecs[0].shape[0]
            if t.ndim == 0:
                t = jnp.full((count,), t)
            if t.shape != (count,):
                raise ShapeError(f"{self.name}: t must have shape ({count},) for {count} states; got {t.shape}.")
            fn = self._vmapped.get(key)
            if fn is None:
                axes = (0,) * (1 + len(vecs)) + (None,)
                fn = self._vmapped[key] = _compile.jit(jax.vmap(self._fns[key], in_axes=axes))
            out = fn(t, *vecs, args)
        return jax.tree_util.tree_map(np.asarray, out)

    def mass_matrix(self, t, q, args) -> np.ndarray:
        """``M(t, q) = ∂²L/∂q̇²``.

        Parameters
        ----------
        t : float or array_like, shape (N,)
            Time (one per state along a trajectory; a scalar is broadcast).
        q : array_like, shape (n,) or (N, n)
            One position, or one per row along a trajectory (e.g. ``sol.q``).
        args : dict
            From :meth:`args`.

        Returns
        -------
        numpy.ndarray, shape (n, n) or (N, n, n)
        """
        return self._eval("mass_matrix", t, (q,), (("q", self.n),), args)

    def constraint_terms(self, t, q, args) -> tuple[np.ndarray, np.ndarray]:
        """``(μ(t, q), ν(t, q))``: the constraints read ``μ q̇ + ν = 0``.

        Parameters
        ----------
        t, q, args
            As in :meth:`mass_matrix`: one state or a trajectory.

        Returns
        -------
        mu : numpy.ndarray, shape (m, n) or (N, m, n)
        nu : numpy.ndarray, shape (m,) or (N, m)
        """
        return self._eval("constraint_terms", t, (q,), (("q", self.n),), args)

    def momenta(self, t, q, qdot, args, *, check: bool = True) -> np.ndarray:
        """The Legendre transform ``p = ∂L/∂q̇ = M(t, q) q̇ + a(t, q)``.

        Parameters
        ----------
        t, q, args
            As in :meth:`mass_matrix`: one state or a trajectory.
        qdot : array_like, shape (n,) or (N, n)
            The velocities; they should satisfy the constraints (see
            :meth:`complete_velocities`).
        check : bool, optional
            Check that ``M(t, q)`` of a single state is symmetric positive definite (default
            True).

        Returns
        -------
        numpy.ndarray, shape (n,) or (N, n)
            ``p``: with ``q`` the initial state of :func:`lobattodae.solve`.

        Raises
        ------
        LobattoDAEInputError
            With ``check``, if ``M(t, q)`` is not finite or not positive definite (naming the
            velocities involved).
        """
        if check and np.ndim(q) == 1:
            self._check_mass(self.mass_matrix(t, q, args), t, q)
        return self._eval("momenta", t, (q, qdot), (("q", self.n), ("qdot", self.n)), args)

    def velocities(self, t, q, p, args) -> np.ndarray:
        """``q̇ = M(t, q)⁻¹ (p − a(t, q))`` (the problem's ``f``).

        Parameters
        ----------
        t, q, args
            As in :meth:`mass_matrix`: one state or a trajectory.
        p : array_like, shape (n,) or (N, n)
            The momenta (e.g. ``sol.p``).

        Returns
        -------
        numpy.ndarray, shape (n,) or (N, n)
        """
        return self._eval("f", t, (q, p), (("q", self.n), ("p", self.n)), args)

    def native(self, stages: int = 3, *, lam_start: str = "auto", tol: float = 1e-14, max_iterations: int = 20):
        """This model's steps in compiled C: a :class:`~lobattodae.mechanics.NativeIntegrator`.

        The library's scheme and Newton rules, with the model's functions generated from its
        SymPy expressions; compiled with the system's C compiler on first use and kept in the user
        cache directory (a new process loads it). Constant steps run whole in C, 2.0–6.7 × less
        time per step than :func:`lobattodae.integrate` on a CPU, with results equal to round-off
        (``benchmarks/RESULTS.md``, 2026-11-29 11:15); error-controlled steps run in
        :func:`lobattodae.solve`'s loop, each attempt one native call, with every option of
        ``solve`` (events, ``t_eval``, dense output) and the same steps, 2.1–3.8 × less time
        (2026-11-29, 14:45). Forward only, on the CPU: the JAX path stays the one for ``jax.grad``,
        ``vmap``, ensembles and GPUs. Holonomic constraints are kept by the library's projection
        after each step. One integrator is kept per (stages, options).

        Parameters
        ----------
        stages, lam_start, tol, max_iterations
            As in :class:`~lobattodae.LobattoIIIAIIIB`.

        Returns
        -------
        NativeIntegrator
            ``solve(t_span, q0, p0, n_steps=..., args=...)`` (constant steps) or
            ``solve(t_span, q0, p0, rtol=..., args=...)`` (error control, with any option of
            :func:`lobattodae.solve`) returns a :class:`~lobattodae.Solution` as
            :func:`lobattodae.solve` does; ``integrate(t0, h, n_steps, q0, p0, lam0=None,
            args=None)`` is the bare run of constant steps.

        Raises
        ------
        LobattoDAEInputError
            An invalid option, or no C compiler (``$CC``, ``cc``, ``gcc``, ``clang``).

        Examples
        --------
        >>> native = sleigh.native(stages=4)                                   # doctest: +SKIP
        >>> sol = native.solve((0.0, 100.0), q0, p0, n_steps=2000, args=args)  # doctest: +SKIP
        >>> sol = native.solve((0.0, 100.0), q0, p0, rtol=1e-8, args=args)     # doctest: +SKIP
        >>> q, p, lam, status, *_ = native.integrate(0.0, 0.05, 2000, q0, p0, args=args)  # doctest: +SKIP
        """
        from .._stepper import LobattoIIIAIIIB
        from ._native import NativeIntegrator

        method = LobattoIIIAIIIB(stages=stages, tol=tol, max_iterations=max_iterations, lam_start=lam_start)
        key = (method.stages, method.lam_start, method.tol, method.max_iterations)
        cache = self.__dict__.setdefault("_native", {})
        if key not in cache:
            cache[key] = NativeIntegrator(self, method)
        return cache[key]

    def energy(self, t, q, p, args) -> np.ndarray:
        """The Hamiltonian ``H = pᵀq̇ − L = ½ q̇ᵀM q̇ + V`` (conserved by conservative
        systems with time-independent linear constraints).

        Parameters
        ----------
        t, q, args
            As in :meth:`mass_matrix`: one state or a trajectory.
        p : array_like, shape (n,) or (N, n)
            The momenta.

        Returns
        -------
        numpy.ndarray, shape () or (N,)
        """
        return self._eval("hamiltonian", t, (q, p), (("q", self.n), ("p", self.n)), args)

    def lagrangian(self, t, q, qdot, args) -> np.ndarray:
        """``L(t, q, q̇)``.

        Parameters
        ----------
        t, q, args
            As in :meth:`mass_matrix`: one state or a trajectory.
        qdot : array_like, shape (n,) or (N, n)
            The velocities.

        Returns
        -------
        numpy.ndarray, shape () or (N,)
        """
        return self._eval("lagrangian", t, (q, qdot), (("q", self.n), ("qdot", self.n)), args)

    def generalized_forces(self, t, q, qdot, args) -> np.ndarray:
        """``F(t, q, q̇)``: the generalized forces given to :func:`from_lagrangian`.

        Parameters
        ----------
        t, q, args
            As in :meth:`mass_matrix`: one state or a trajectory.
        qdot : array_like, shape (n,) or (N, n)
            The velocities.

        Returns
        -------
        numpy.ndarray, shape (n,) or (N, n)
            Zero where the model has no forces.
        """
        return self._eval("forces", t, (q, qdot), (("q", self.n), ("qdot", self.n)), args)

    def constraint_forces(self, t, q, p, lam, args) -> np.ndarray:
        """The generalized constraint forces ``μ(t, q)ᵀ λ``.

        Parameters
        ----------
        t, q, args
            As in :meth:`mass_matrix`: one state or a trajectory.
        p : array_like
            Accepted for symmetry with the problem's functions; not used.
        lam : array_like, shape (m,) or (N, m)
            The multipliers (e.g. ``sol.lam``).

        Returns
        -------
        numpy.ndarray, shape (n,) or (N, n)
        """
        del p
        return self._eval("constraint_forces", t, (q, lam), (("q", self.n), ("lam", self.m)), args)

    def constraint_residual(self, t, q, p, args) -> np.ndarray:
        """``φ(t, q, p) = μ q̇ + ν`` (zero to round-off along a lobattodae solution).

        Parameters
        ----------
        t, q, args
            As in :meth:`mass_matrix`: one state or a trajectory.
        p : array_like, shape (n,) or (N, n)
            The momenta.

        Returns
        -------
        numpy.ndarray, shape (m,) or (N, m)
            One entry per constraint, in the order of :attr:`constraint_labels`.
        """
        return self._eval("phi", t, (q, p), (("q", self.n), ("p", self.n)), args)

    def holonomic_residual(self, t, q, args) -> np.ndarray:
        """``ψ(t, q)`` of the holonomic constraints, shape (k,) or (N, k) along a trajectory.

        The integrator keeps ``ψ_q q̇ + ψ_t = 0`` (a row of φ) and, by projecting every step's
        end point, ψ itself to round-off at the step points; between them (dense output) ψ is
        the interpolation error.

        Parameters
        ----------
        t, q, args
            As in :meth:`mass_matrix`: one state or a trajectory.

        Returns
        -------
        numpy.ndarray, shape (k,) or (N, k)
            Empty (k = 0) for a model without holonomic constraints.
        """
        return self._eval("holonomic", t, (q,), (("q", self.n),), args)

    # ------------------------------------------------------------------ checks
    def _involved(self, vec, names):
        vec = np.abs(np.asarray(vec))
        top = float(vec.max()) if vec.size else 0.0
        return [names[i] for i in range(len(names)) if top > 0 and vec[i] >= 0.1 * top]

    def _check_mass(self, M, t, q):
        M = np.asarray(M, dtype=np.float64)
        where = f"at t = {float(np.asarray(t))!r}, q = {np.asarray(q, dtype=float).tolist()}"
        if not np.all(np.isfinite(M)):
            raise _err(f"{self.name}: the mass matrix M = ∂²L/∂q̇² is not finite {where}:\n{M}")
        w, vecs = np.linalg.eigh(0.5 * (M + M.T))
        scale = max(float(np.max(np.abs(w))), 1e-300)
        if not w[0] > RANK_TOL * scale:
            dots = [f"{name}'" for name in self.coordinate_names]
            involved = self._involved(vecs[:, 0], dots)
            raise _err(
                f"{self.name}: the kinetic energy is not positive definite {where}: the mass matrix "
                f"M = ∂²L/∂q̇² has the eigenvalue {w[0]:.6g} (largest {w[-1]:.6g}) along the velocities "
                f"{involved}. Check the signs of the kinetic terms (L = T − V), that every coordinate "
                "has kinetic energy, and that the parameters are physical (positive masses and inertias)."
            )
        return w

    def _check_constraints(self, M, mu, t, q, free=None, fixed_names=()):
        """Eigenvalues of ``μ_U M_UU⁻¹ μ_Uᵀ`` (U: the free velocities); error if singular."""
        n = self.n
        free = list(range(n)) if free is None else list(free)
        where = f"at t = {float(np.asarray(t))!r}, q = {np.asarray(q, dtype=float).tolist()}"
        mu = np.asarray(mu, dtype=np.float64)
        labels = self.constraint_labels
        if not free:
            raise _err(f"{self.name}: every velocity is fixed; no freedom is left to satisfy the constraints {list(labels)}.")
        muu = mu[:, free]
        muu_full = mu
        for j in range(self.m):
            if not np.any(muu_full[j] != 0.0):
                raise _err(
                    f"{self.name}: the constraint {labels[j]} has no velocity coefficients {where} "
                    "(its row of μ = ∂c/∂q̇ vanishes): it cannot be kept there. Remove it or choose "
                    "other coordinates."
                )
        Muu = np.asarray(M, dtype=np.float64)[np.ix_(free, free)]
        gram = muu @ np.linalg.solve(Muu, muu.T)
        w, vecs = np.linalg.eigh(0.5 * (gram + gram.T))
        scale = max(float(np.max(np.abs(w))), 1e-300)
        if not w[0] > RANK_TOL * scale:
            involved = self._involved(vecs[:, 0], labels)
            if fixed_names:
                raise _err(
                    f"{self.name}: with the velocities of {list(fixed_names)} fixed, the constraints "
                    f"{involved} cannot be satisfied {where} (they leave no free velocity to "
                    "adjust); fix fewer velocities."
                )
            rank = int(np.sum(w > RANK_TOL * scale))
            raise _err(
                f"{self.name}: the constraints {involved} are linearly dependent {where} "
                f"(μ M⁻¹ μᵀ has rank {rank} < {self.m}; smallest eigenvalue {w[0]:.3g}): the "
                "multipliers are not determined. Remove the redundant constraint(s), or choose "
                "coordinates in which they are independent."
            )
        return w

    def check(self, t, q, args) -> dict:
        """Check a state's position: ``args`` complete, ``M(t, q)`` symmetric positive definite,
        the constraints independent there (``μ M⁻¹ μᵀ`` nonsingular) and the holonomic
        constraints satisfied (``|ψ(t, q)| ≤ HOLONOMIC_TOL (1 + ‖q‖∞)``).

        Parameters
        ----------
        t : float
            Time.
        q : array_like, shape (n,)
            One position.
        args : dict
            From :meth:`args`.

        Returns
        -------
        dict
            ``"mass_eigenvalues"`` and ``"constraint_eigenvalues"`` (of ``μ M⁻¹ μᵀ``).

        Raises
        ------
        LobattoDAEInputError
            Naming the failed check, the coordinates or the constraints involved.
        """
        args = self._check_args(args)
        q = np.asarray(q, dtype=np.float64)
        if q.shape != (self.n,):
            raise ShapeError(f"{self.name}: q must have shape ({self.n},); got {q.shape}.")
        M = self.mass_matrix(t, q, args)
        wm = self._check_mass(M, t, q)
        wc = np.zeros(0)
        if self.m:
            mu, _ = self.constraint_terms(t, q, args)
            wc = self._check_constraints(M, mu, t, q)
        if self.n_holonomic:
            psi = self.holonomic_residual(t, q, args)
            bad = np.abs(psi) > HOLONOMIC_TOL * (1.0 + float(np.max(np.abs(q))))
            if np.any(bad):
                names = [self.constraint_labels[self.m - self.n_holonomic + i] for i in np.flatnonzero(bad)]
                raise _err(
                    f"{self.name}: the position q = {q.tolist()} violates the holonomic constraint(s) "
                    f"{names}: ψ = {psi[bad].tolist()}. Start from a position with ψ(t0, q0) = 0."
                )
        return {"mass_eigenvalues": wm, "constraint_eigenvalues": wc}

    def complete_velocities(self, t, q, qdot, args, *, fixed=()) -> np.ndarray:
        """Velocities that satisfy the constraints ``μ q̇ + ν = 0``, closest to a guess.

        Parameters
        ----------
        t : float
            The state's time.
        q : array_like, shape (n,)
            The state's position.
        qdot : array (n,) or mapping
            An array is a guess for all velocities; it is projected onto the constraint set in
            the kinetic-energy metric (the velocities ``fixed`` kept). A mapping
            ``{coordinate: velocity}`` (keys ``x(t)``, ``'x'`` or an index) fixes those
            velocities and solves for the others (the solution of least kinetic energy
            ``½ q̇ᵀM q̇`` among them, when they are not determined).
        args : dict
            From :meth:`args`.
        fixed : iterable, optional
            Coordinates whose velocity in the array ``qdot`` is kept.

        Returns
        -------
        numpy.ndarray, shape (n,)
            ``q̇`` with ``μ q̇ + ν = 0``; pass it to :meth:`momenta`.

        Raises
        ------
        LobattoDAEInputError
            If ``M`` is not positive definite, the constraints are dependent (naming them),
            or the fixed velocities leave the constraints unsolvable.
        """
        args = self._check_args(args)
        q = np.asarray(q, dtype=np.float64)
        if q.shape != (self.n,):
            raise ShapeError(f"{self.name}: q must have shape ({self.n},); got {q.shape}.")
        fixed_idx = {self._ctx.label(k) for k in fixed}
        if isinstance(qdot, Mapping):
            guess = np.zeros(self.n)
            for key, val in qdot.items():
                i = self._ctx.label(key)
                guess[i] = float(val)
                fixed_idx.add(i)
        else:
            guess = np.array(qdot, dtype=np.float64)
            if guess.shape != (self.n,):
                raise ShapeError(f"{self.name}: qdot must have shape ({self.n},) or be a mapping; got {guess.shape}.")
        M = self.mass_matrix(t, q, args)
        self._check_mass(M, t, q)
        if self.m == 0:
            return guess
        mu, nu = self.constraint_terms(t, q, args)
        free = [i for i in range(self.n) if i not in fixed_idx]
        fixed_names = [self.coordinate_names[i] for i in sorted(fixed_idx)]
        if fixed_idx:
            self._check_constraints(M, mu, t, q)  # dependent constraints: say so first
        self._check_constraints(M, mu, t, q, free=free, fixed_names=fixed_names)
        resid = mu @ guess + nu
        Muu = M[np.ix_(free, free)]
        muu = mu[:, free]
        y = np.linalg.solve(Muu, muu.T)  # M_UU⁻¹ μ_Uᵀ
        corr = y @ np.linalg.solve(muu @ y, resid)
        out = guess.copy()
        out[free] -= corr
        return out

    def __repr__(self) -> str:
        return (
            f"LagrangianModel(name={self.name!r}, coordinates={list(self.coordinate_names)}, "
            f"parameters={list(self.parameters)}, constraints={list(self.constraint_labels)})"
        )
