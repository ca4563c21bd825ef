"""Reading a model's SymPy input: coordinates, parameters, the Lagrangian, constraints and
loads are sorted into a :class:`_Context` (what is a coordinate, a rate, a parameter, a time),
with a message that names what does not fit (:func:`_err`)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np
import sympy as sp
from sympy.core.function import AppliedUndef

from .._errors import LobattoDAEInputError

__all__ = ["_Context", "_err", "_free_of", "_labelled", "_short", "_without"]


def _err(msg: str) -> LobattoDAEInputError:
    return LobattoDAEInputError(msg)


def _short(expr, limit: int = 120) -> str:
    text = sp.sstr(expr)
    return text if len(text) <= limit else text[: limit - 3] + "..."


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
