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
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any, Callable, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import sympy as sp
from sympy.core.function import AppliedUndef

from .._errors import LobattoDAEInputError, ShapeError
from .._problem import PartitionedDAE
from ._codegen import FunctionSpec, SolveSpec, generate_module

__all__ = [
    "LagrangianDAE",
    "LagrangianModel",
    "SymbolicParts",
    "from_lagrangian",
    "from_lagranges_method",
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


def _err(msg: str) -> LobattoDAEInputError:
    return LobattoDAEInputError(msg)


def _short(expr, limit: int = 120) -> str:
    text = sp.sstr(expr)
    return text if len(text) <= limit else text[: limit - 3] + "..."


# ----------------------------------------------------------------------------- parsing
class _Context:
    """The coordinates, their canonical symbols and the substitutions between them."""

    def __init__(self, coordinates, t):
        if not isinstance(t, sp.Symbol):
            raise _err(
                f"t must be a SymPy Symbol (the time the coordinates depend on); got {t!r}. "
                "Use t = sympy.Symbol('t') (the argument of dynamicsymbols)."
            )
        if isinstance(coordinates, (sp.Basic, str)) or not isinstance(coordinates, Sequence):
            raise _err(
                "coordinates must be a list of functions of time, e.g. "
                "dynamicsymbols('x y theta'); got " + repr(coordinates)
            )
        coords = list(coordinates)
        if not coords:
            raise _err("coordinates is empty: give at least one generalized coordinate q(t).")
        for c in coords:
            if not (isinstance(c, AppliedUndef) and c.args == (t,)):
                hint = ""
                if isinstance(c, AppliedUndef) and len(c.args) == 1 and isinstance(c.args[0], sp.Symbol):
                    arg = c.args[0]
                    if arg.name == t.name:
                        hint = (f" (its argument {arg} has the same name but other assumptions "
                                f"{arg.assumptions0} than the t you passed {t.assumptions0})")
                    else:
                        hint = f" (it depends on {arg}, not on the time symbol {t} you passed)"
                raise _err(
                    f"coordinate {c!r} is not a function of the time symbol {t}{hint}: pass "
                    "coordinates made with sympy.physics.mechanics.dynamicsymbols (or "
                    "sympy.Function('x')(t)) and the same t."
                )
        if len(set(coords)) != len(coords):
            dup = sorted({str(c) for c in coords if coords.count(c) > 1})
            raise _err(f"coordinates contain duplicates: {dup}.")
        names = [c.func.__name__ for c in coords]
        if len(set(names)) != len(names):
            raise _err(f"two coordinates share a name: {names}; give each its own name.")
        self.t = t
        self.coords = tuple(coords)
        self.names = tuple(names)
        self.n = len(coords)
        self.q = tuple(sp.Dummy(f"q{i}") for i in range(self.n))
        self.v = tuple(sp.Dummy(f"v{i}") for i in range(self.n))
        self.dots = tuple(c.diff(t) for c in coords)
        self.to_internal = {}
        for c, d, q, v in zip(self.coords, self.dots, self.q, self.v):
            self.to_internal[d] = v
            self.to_internal[c] = q
        self.to_user = {}
        for c, d, q, v in zip(self.coords, self.dots, self.q, self.v):
            self.to_user[q] = c
            self.to_user[v] = d
        self.v_zero = {v: sp.S.Zero for v in self.v}
        self.to_pretty = {}
        for name, q, v in zip(self.names, self.q, self.v):
            self.to_pretty[q] = sp.Symbol(name)
            self.to_pretty[v] = sp.Symbol(name + "'")

    def pretty(self, expr, limit: int = 120) -> str:
        """An internal expression for messages: ``x`` for x(t), ``x'`` for its velocity."""
        return _short(sp.sympify(expr).xreplace(self.to_pretty), limit)

    def user(self, expr):
        return sp.sympify(expr).xreplace(self.to_user)

    def internal(self, expr, what: str):
        """``expr`` with ``x(t) → q_i``, ``ẋ(t) → v_i``; rejects anything else that moves."""
        if isinstance(expr, sp.Equality):
            expr = expr.lhs - expr.rhs
        try:
            e = sp.sympify(expr)
        except (sp.SympifyError, TypeError) as exc:
            raise _err(f"{what} is not a SymPy expression: {expr!r} ({exc}).") from None
        if isinstance(e, (sp.MatrixBase, sp.MatrixExpr)) or not isinstance(e, sp.Expr):
            raise _err(f"{what} must be a scalar SymPy expression; got {type(e).__name__}: {_short(e)}.")
        # Unevaluated derivatives of expressions, e.g. Derivative(x(t)**2, t), are evaluated.
        e = e.replace(lambda d: isinstance(d, sp.Derivative) and d not in self.dots, lambda d: d.doit())
        # Check before substituting: x(t) -> q inside a second derivative would make it 0.
        for d in sorted(e.atoms(sp.Derivative), key=sp.default_sort_key):
            if d in self.dots:
                continue
            if d.expr in self.coords:
                raise _err(
                    f"{what} contains the acceleration {_short(d)}: only coordinates and their "
                    "first derivatives may appear (a Lagrangian L(t, q, q̇), constraints in t, q, q̇)."
                )
            raise _err(
                f"{what} contains the derivative {_short(d)} of something that is not a "
                f"coordinate; the coordinates are {list(self.coords)}."
            )
        undefined = sorted(set(e.atoms(AppliedUndef)) - set(self.coords), key=sp.default_sort_key)
        if undefined:
            shown = ", ".join(str(u) for u in undefined)
            raise _err(
                f"{what} contains the undefined function(s) {shown}, which are not among the "
                f"coordinates {list(self.coords)}. Add them to the coordinates, or write a "
                "prescribed input as an explicit expression of t (e.g. A*sin(w*t)) with its "
                "constants as symbols passed through args."
            )
        out = e.xreplace(self.to_internal)
        if out.has(sp.I) or out.has(sp.zoo) or out.has(sp.nan) or out.has(sp.oo):
            raise _err(f"{what} contains a complex or infinite constant: {_short(e)}.")
        return out

    def label(self, key) -> int:
        """The index of a coordinate given as ``x(t)``, ``ẋ(t)``, its name or its index."""
        if isinstance(key, (int, np.integer)) and not isinstance(key, bool):
            if 0 <= int(key) < self.n:
                return int(key)
            raise _err(f"coordinate index {key} is out of range 0..{self.n - 1}.")
        if isinstance(key, str):
            if key in self.names:
                return self.names.index(key)
        elif isinstance(key, sp.Basic):
            if key in self.coords:
                return self.coords.index(key)
            if key in self.dots:
                return self.dots.index(key)
            if isinstance(key, sp.Symbol) and key.name in self.names:
                return self.names.index(key.name)
        raise _err(
            f"{key!r} is not one of the coordinates {list(self.names)} (give a coordinate as "
            "x(t), its name 'x' or its index)."
        )


def _free_of(expr, symbols) -> bool:
    return not (expr.free_symbols & set(symbols))


def _without(expr, symbols):
    """``expr`` if it does not depend on ``symbols`` (after simplification), else None."""
    if _free_of(expr, symbols):
        return expr
    simpler = sp.simplify(expr)
    return simpler if _free_of(simpler, symbols) else None


def _labelled(constraints, kind: str):
    """``[(label, expr)]`` from a list or a dict of constraints."""
    if constraints is None:
        return []
    if isinstance(constraints, Mapping):
        return [(f"{kind} {key!s}", expr) for key, expr in constraints.items()]
    if not isinstance(constraints, (list, tuple, sp.MatrixBase)):
        raise _err(
            f"{kind} constraints must be a list (or a dict name -> expression); got {constraints!r}. "
            "Wrap a single constraint in a list."
        )
    return [(f"{kind}[{i}]", expr) for i, expr in enumerate(list(constraints))]


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
        ctx, n, m = self._ctx, self.n, self.m
        t = sp.Symbol("t")
        q = tuple(sp.Symbol(f"q_{i}") for i in range(n))
        v = tuple(sp.Symbol(f"v_{i}") for i in range(n))
        p = tuple(sp.Symbol(f"p_{i}") for i in range(n))
        lam = tuple(sp.Symbol(f"lam_{j}") for j in range(m))
        ks = tuple(sp.Symbol(f"k_{j}") for j in range(len(self.parameters)))
        rename = {ctx.t: t}
        rename.update(zip(ctx.q, q))
        rename.update(zip(ctx.v, v))
        rename.update({self._param_symbols[name]: k for name, k in zip(self.parameters, ks)})

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
        params = list(zip(self.parameters, ks))
        module = generate_module(self.name, specs, t, params)
        self.source = module.source
        fns = module.functions
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
        self._jit = {key: jax.jit(fn) for key, fn in fns.items()}
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
                fn = self._vmapped[key] = jax.jit(jax.vmap(self._fns[key], in_axes=axes))
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


# ----------------------------------------------------------------------------- builders
def from_lagrangian(
    lagrangian,
    coordinates,
    t,
    *,
    nonholonomic=None,
    holonomic=None,
    forces=None,
    name: str | None = None,
    defaults: Mapping | None = None,
    simplify: bool = False,
) -> LagrangianModel:
    r"""Build a :class:`LagrangianModel` (and its :class:`~lobattodae.PartitionedDAE`) from a
    Lagrangian.

    Parameters
    ----------
    lagrangian : sympy.Expr
        ``L(t, q, q̇)``, quadratic in the velocities: ``½ q̇ᵀM(t, q)q̇ + a(t, q)ᵀq̇ − V(t, q)``
        with ``M`` symmetric positive definite.
    coordinates : list
        The generalized coordinates, functions of ``t``
        (:func:`sympy.physics.mechanics.dynamicsymbols`).
    t : sympy.Symbol
        The time symbol the coordinates depend on.
    nonholonomic : list or dict, optional
        Expressions ``c(t, q, q̇)`` (or ``Eq``), kept as ``c = 0``; each must be affine in the
        velocities: ``c = μ(t, q) q̇ + ν(t, q)``.
    holonomic : list or dict, optional
        Position constraints ``ψ(t, q) = 0``. They are differentiated once and kept at the
        velocity level, ``ψ_q q̇ + ψ_t = 0``, as rows of φ (index 2), and ψ itself is passed
        to the problem as ``position_constraint``: every step's end point is projected onto
        ``ψ = 0`` (in the kinetic metric, ``q ← q + M⁻¹ψ_qᵀκ``) and back onto ``φ = 0``, so
        both hold to round-off at every step point with the orders of q and p unchanged (the
        projected step is not symmetric; see ``docs/mechanics.md``). q0 must satisfy ψ
        (:meth:`LagrangianModel.check`); :meth:`LagrangianModel.holonomic_residual` evaluates ψ.
    forces : list or dict, optional
        Generalized (non-conservative) forces ``F_i(t, q, q̇)``, one per coordinate (a dict
        ``{coordinate: force}`` may leave out zeros); inputs as explicit functions of ``t``.
    name : str, optional
        For messages (default ``"LagrangianModel"``).
    defaults : dict, optional
        Default parameter values for :meth:`LagrangianModel.args`.
    simplify : bool
        Apply :func:`sympy.simplify` to ``M``, ``a``, ``V``, ``μ``, ``ν`` (slower to build,
        sometimes shorter code).

    Returns
    -------
    LagrangianModel
        The model; ``model.problem`` is the problem to pass to :func:`~lobattodae.solve`.

    Raises
    ------
    LobattoDAEInputError
        For a Lagrangian that is not quadratic in the velocities, a coordinate without
        kinetic energy, a constant mass matrix that is not positive definite, constraints
        that are not affine in the velocities, holonomic constraints with velocities,
        accelerations, undefined functions other than the coordinates, clashing symbol
        names, and malformed arguments; the message names the culprit.

    Notes
    -----
    The multipliers are ordered as ``model.constraint_labels``: nonholonomic constraints
    first, then holonomic ones; ``p' = ∂L/∂q + F + μᵀλ``.
    """
    ctx = _Context(coordinates, t)
    name = "LagrangianModel" if name is None else str(name)
    L = ctx.internal(lagrangian, "the Lagrangian")
    q, v = ctx.q, ctx.v
    n = ctx.n

    # --- kinetic energy: L = ½ vᵀMv + aᵀv − V
    M = sp.zeros(n, n)
    for i in range(n):
        dLi = sp.diff(L, v[i])
        for j in range(i, n):
            entry = sp.diff(dLi, v[j])
            fixed = _without(entry, v)
            if fixed is None:
                raise _err(
                    f"{name}: the Lagrangian is not quadratic in the velocities: ∂²L/∂{ctx.names[i]}'∂"
                    f"{ctx.names[j]}' = {ctx.pretty((entry))} depends on the velocities. lobattodae."
                    "mechanics needs L = ½ q̇ᵀM(t,q)q̇ + a(t,q)ᵀq̇ − V(t,q)."
                )
            M[i, j] = M[j, i] = fixed
    for i in range(n):
        if M[i, i] == 0:
            raise _err(
                f"{name}: the coordinate {ctx.names[i]} has no kinetic energy (∂²L/∂{ctx.names[i]}'² = 0), "
                "so the mass matrix is singular. Give it kinetic energy, or eliminate it (a "
                "coordinate without inertia is not a dynamical coordinate)."
            )
    a = sp.Matrix([sp.diff(L, v[i]).xreplace(ctx.v_zero) for i in range(n)])
    V = -L.xreplace(ctx.v_zero)
    if simplify:
        M = M.applyfunc(sp.simplify)
        a = a.applyfunc(sp.simplify)
        V = sp.simplify(V)

    # --- constraints: μ v + ν = 0
    rows, offsets, labels, psis = [], [], [], []
    for label, expr in _labelled(nonholonomic, "nonholonomic"):
        c = ctx.internal(expr, f"the constraint {label}")
        row = []
        for i in range(n):
            coeff = _without(sp.diff(c, v[i]), v)
            if coeff is None:
                raise _err(
                    f"{name}: the constraint {label}: {ctx.pretty((c))} = 0 is not affine in the "
                    f"velocities (its coefficient of {ctx.names[i]}' depends on velocities). Constraints "
                    "must read μ(t, q) q̇ + ν(t, q) = 0."
                )
            row.append(coeff)
        if all(r == 0 for r in row):
            raise _err(
                f"{name}: the constraint {label}: {ctx.pretty((c))} = 0 contains no velocities. A "
                "position constraint ψ(t, q) = 0 belongs in holonomic=[...]."
            )
        rows.append(row)
        offsets.append(c.xreplace(ctx.v_zero))
        labels.append(f"{label} ({ctx.pretty(c, 60)} = 0)")
    hol = _labelled(holonomic, "holonomic")
    for label, expr in hol:
        psi = ctx.internal(expr, f"the constraint {label}")
        if not _free_of(psi, v):
            raise _err(
                f"{name}: the holonomic constraint {label}: {ctx.pretty((psi))} = 0 contains "
                "velocities; pass a velocity constraint in nonholonomic=[...]."
            )
        row = [sp.diff(psi, qi) for qi in q]
        if all(r == 0 for r in row):
            raise _err(
                f"{name}: the holonomic constraint {label}: {ctx.pretty((psi))} = 0 does not "
                "depend on the coordinates."
            )
        rows.append(row)
        offsets.append(sp.diff(psi, ctx.t))
        labels.append(f"{label} ({ctx.pretty(psi, 60)} = 0)")
        psis.append(psi)
    m = len(rows)
    if m == 0:
        raise _err(
            f"{name}: no constraints. lobattodae integrates constrained systems (index-2 DAEs "
            "with at least one multiplier): give nonholonomic=[...] or holonomic=[...]; an "
            "unconstrained Lagrangian system is an ODE (use a symplectic ODE integrator)."
        )
    mu = sp.Matrix(m, n, lambda j, i: rows[j][i]) if m else sp.zeros(0, n)
    nu = sp.Matrix(offsets) if m else sp.zeros(0, 1)
    if simplify and m:
        mu = mu.applyfunc(sp.simplify)
        nu = nu.applyfunc(sp.simplify)

    # --- forces
    F = sp.zeros(n, 1)
    if forces is not None:
        if isinstance(forces, Mapping):
            for key, expr in forces.items():
                i = ctx.label(key)
                F[i] = F[i] + ctx.internal(expr, f"the force on {ctx.names[i]}")
        else:
            if isinstance(forces, (sp.Basic, str)) or not isinstance(forces, (Sequence, sp.MatrixBase)):
                raise _err(f"{name}: forces must be a list with one generalized force per coordinate, or a dict; got {forces!r}.")
            flist = list(forces)
            if len(flist) != n:
                raise _err(
                    f"{name}: forces has {len(flist)} entries but there are {n} coordinates "
                    f"{list(ctx.names)}: give one generalized force per coordinate (0 where none), "
                    "or a dict {coordinate: force}."
                )
            for i, expr in enumerate(flist):
                F[i] = ctx.internal(expr, f"the force on {ctx.names[i]}")

    # --- parameters
    everything = [L, *M, *a, V, *mu, *nu, *F, *psis]
    symbols = set()
    for e in everything:
        symbols |= sp.sympify(e).free_symbols
    symbols -= set(q) | set(v) | {ctx.t}
    params: dict[str, sp.Symbol] = {}
    for s in sorted(symbols, key=lambda s: (s.name, sp.default_sort_key(s))):
        if s.name == ctx.t.name:
            raise _err(
                f"{name}: the symbol {s.name!r} {s.assumptions0 or ''} differs from the time symbol t "
                f"{ctx.t.assumptions0 or ''} the coordinates depend on (same name, other assumptions). "
                "Use one time symbol."
            )
        if s.name in ctx.names:
            raise _err(
                f"{name}: the symbol {s.name!r} has the name of the coordinate {s.name}(t): write "
                f"{s.name}(t) (the coordinate) or rename the parameter."
            )
        if s.name in params:
            raise _err(
                f"{name}: two different symbols are named {s.name!r} (different assumptions: "
                f"{params[s.name].assumptions0} vs {s.assumptions0}); use one symbol per parameter."
            )
        params[s.name] = s
    defaults = dict(defaults or {})
    bad = [k for k in defaults if (k.name if isinstance(k, sp.Symbol) else k) not in params]
    if bad:
        raise _err(f"{name}: defaults for unknown parameter(s) {bad}; the parameters are {list(params)}.")
    defaults = {(k.name if isinstance(k, sp.Symbol) else k): val for k, val in defaults.items()}

    # A constant mass matrix can be checked now.
    if not any(e.free_symbols for e in M):
        w = np.linalg.eigvalsh(np.array(M.tolist(), dtype=np.float64))
        if not w[0] > RANK_TOL * max(float(np.max(np.abs(w))), 1e-300):
            raise _err(
                f"{name}: the kinetic energy is not positive definite: the constant mass matrix "
                f"M = ∂²L/∂q̇² = {M.tolist()} has the eigenvalue {w[0]:.6g}. Check the signs of the "
                "kinetic terms (L = T − V)."
            )

    return LagrangianModel(
        name=name,
        ctx=ctx,
        params=params,
        defaults=defaults,
        parts_internal=(M, a, V, mu, nu, F, sp.Matrix(psis) if psis else sp.zeros(0, 1), L),
        labels=labels,
        n_holonomic=len(psis),
        lagrangian_user=ctx.user(L),
    )


def load_forces(kind: str, frame, loads, qdots, to_rates=None) -> list:
    r"""``F_i = Σ (∂v_P/∂q̇_i)·F + (∂ω_B/∂q̇_i)·τ`` over ``loads`` (``(Point, force)`` or
    ``(ReferenceFrame, torque)`` pairs), velocities in the inertial ``frame``; ``to_rates``
    substitutes speeds by their expressions in the coordinate rates (Kane-style models)."""
    from sympy.physics.mechanics import Point, ReferenceFrame

    forces = [sp.S.Zero] * len(qdots)
    for load in loads or []:
        obj, vec = load[0], load[1]
        if isinstance(obj, Point):
            vel = obj.vel(frame)
        elif isinstance(obj, ReferenceFrame):
            vel = obj.ang_vel_in(frame)
        else:
            raise _err(f"the {kind}'s load ({obj!r}, ...): the first item must be a Point or a ReferenceFrame.")
        v = vel.to_matrix(frame).xreplace(to_rates or {})
        f = vec.to_matrix(frame)
        for i, qd in enumerate(qdots):
            forces[i] += (v.diff(qd).T * f)[0, 0]
    return forces


def from_lagranges_method(method, *, name: str | None = None, defaults: Mapping | None = None,
                          simplify: bool = False) -> LagrangianModel:
    r"""Build a :class:`LagrangianModel` from a :class:`sympy.physics.mechanics.LagrangesMethod`.

    Uses its Lagrangian, coordinates, holonomic constraints (``hol_coneqs``, kept at the
    velocity and position levels as in :func:`from_lagrangian`), nonholonomic constraints
    (``nonhol_coneqs``) and its ``forcelist`` (generalized forces
    ``F_i = Σ ∂v/∂q̇_i · force`` in the inertial ``frame``, which must then be given).

    Note the sign: SymPy writes ``d/dt ∂L/∂q̇ − ∂L/∂q − F = −(∂c/∂q̇)ᵀλ_sympy``;
    lobattodae's ``λ`` is ``−λ_sympy``.

    Parameters
    ----------
    method : sympy.physics.mechanics.LagrangesMethod
        The system (its equations need not have been formed).
    name : str, optional
        For messages (default ``"LagrangianModel"``).
    defaults : dict, optional
        Default parameter values for :meth:`LagrangianModel.args`.
    simplify : bool, optional
        As in :func:`from_lagrangian`.

    Returns
    -------
    LagrangianModel
        The model; ``model.problem`` is the problem to pass to :func:`~lobattodae.solve`.

    Raises
    ------
    LobattoDAEInputError
        For anything that is not a ``LagrangesMethod`` (a ``KanesMethod`` is pointed to
        :func:`~lobattodae.mechanics.from_kanes_method`), a ``forcelist`` without an inertial
        frame, and everything :func:`from_lagrangian` refuses.
    """
    from sympy.physics.mechanics import KanesMethod, LagrangesMethod
    from sympy.physics.vector import dynamicsymbols

    if isinstance(method, KanesMethod):
        raise _err(
            "from_lagranges_method got a KanesMethod: convert it with mechanics.from_kanes_method(kane) "
            "(or a System with mechanics.from_system(system))."
        )
    if not isinstance(method, LagrangesMethod):
        raise _err(
            f"from_lagranges_method needs a sympy.physics.mechanics.LagrangesMethod; got "
            f"{type(method).__name__}. For a Lagrangian expression use from_lagrangian(L, coordinates, t)."
        )
    t = dynamicsymbols._t
    L = method._L[0]
    coords = list(method.q)
    hol = list(method._hol_coneqs)
    nonhol = list(method.coneqs)[len(hol):]
    qdots = [c.diff(t) for c in coords]
    forces = None
    flist = list(method.forcelist or [])
    if flist:
        frame = method.inertial
        if frame is None:
            raise _err(
                "the LagrangesMethod has a forcelist but no inertial frame: create it with "
                "LagrangesMethod(..., forcelist=..., frame=N)."
            )
        forces = load_forces("LagrangesMethod", frame, flist, qdots)
    return from_lagrangian(
        L, coords, t, nonholonomic=nonhol or None, holonomic=hol or None, forces=forces,
        name=name, defaults=defaults, simplify=simplify,
    )
