"""JAX code generation from SymPy expressions, with common-subexpression elimination.

A generated function reads scalars out of its vector arguments (``q_0 = q[0]``) and its
parameters out of the ``args`` dict (``k_0 = args['m']``), evaluates the expressions of
all its outputs once, sharing common subexpressions (:func:`sympy.cse`), and stacks the
results into float64 arrays. A function may solve a linear system on the way: the
velocities ``v = M(t, q)⁻¹ (p − a(t, q))`` are computed numerically, never symbolically,
block by block along the structural sparsity of ``M`` (a division for 1×1 blocks, the closed
form for 2×2 blocks, :func:`lobattodae._linalg.spd_solve` for larger ones). The
subexpressions that do not depend on ``v`` are evaluated before the solve, the others after.

Every function of a model is written into one module source, which is kept (``source``) and
registered with :mod:`linecache`, so tracebacks show the generated lines.

**No string is pasted into the source unquoted.** The model's name and the docstrings enter as
``repr()`` literals, parameter names as ``args[<repr>]`` keys; every other name in the source is
one the generator chose (``q_0``, ``k_3``, ``s_12``). SymPy prints some constructs with names of
their own (the bound variable of an unevaluated ``Sum``), so before the source is compiled its
syntax tree is checked against the little it may contain (:func:`_check_source`): function
definitions of plain arguments, assignments to plain names, arithmetic, calls of ``jax.*`` and
of the helpers, subscripts of the arguments, number literals, and string literals only as
docstrings and ``args`` keys. Anything else (an import, a lambda, a comprehension, an unknown
name, an attribute starting with ``_``) is refused with :class:`~lobattodae.LobattoDAEInputError`
and nothing is executed.
"""

from __future__ import annotations

import ast
import functools
import itertools
import linecache
from dataclasses import dataclass, field
from typing import NamedTuple

import jax
import jax.numpy as jnp
import sympy as sp
from sympy.printing.numpy import JaxPrinter
from sympy.printing.precedence import PRECEDENCE

from .._errors import LobattoDAEInputError
from .._linalg import spd_solve

__all__ = ["FunctionSpec", "SolveSpec", "common_subexpressions", "generate_module", "plain_symbols"]

_counter = itertools.count()


class _Printer(JaxPrinter):
    """The JAX printer with exact float literals and cheap integer powers.

    ``x**-1`` becomes ``1/x`` (SymPy's printer writes ``x**(-1.0)``, a general ``pow``),
    ``x**(1/2)`` ``jax.numpy.sqrt(x)``; floats are written with ``repr`` (round trip exact).
    """

    def _print_Float(self, expr):
        return repr(float(expr))

    def _print_Rational(self, expr):
        return repr(int(expr.p) / int(expr.q))

    def _print_Integer(self, expr):
        return str(int(expr))

    def _print_Pow(self, expr, rational=False):
        base, exp = expr.as_base_exp()
        b = self.parenthesize(base, PRECEDENCE["Pow"])
        if exp.is_Integer:
            k = int(exp)
            if k == 1:
                return b
            if k > 0:
                return f"{b}**{k}"
            if k == -1:
                return f"1/{b}"
            return f"1/{b}**{-k}"
        if exp == sp.S.Half:
            return f"jax.numpy.sqrt({self._print(base)})"
        if exp == -sp.S.Half:
            return f"1/jax.numpy.sqrt({self._print(base)})"
        if exp.is_Rational:
            return f"{b}**{float(exp)!r}"
        return f"{b}**{self.parenthesize(exp, PRECEDENCE['Pow'])}"


_PRINTER = _Printer({"fully_qualified_modules": True, "inline": True, "allow_unknown_functions": False})


def _code(expr) -> str:
    return _PRINTER.doprint(expr)


@dataclass(frozen=True)
class SolveSpec:
    """``v = M⁻¹ rhs`` inside a generated function.

    ``matrix`` is the (n, n) SymPy matrix ``M`` and ``rhs`` the n right-hand sides, in the
    symbols available before the solve; ``unknowns`` are the n symbols ``v`` the outputs use.
    """

    matrix: sp.Matrix
    rhs: tuple
    unknowns: tuple


@dataclass(frozen=True)
class FunctionSpec:
    """One generated function ``name(t, <vector args>..., args)``.

    Parameters
    ----------
    name : str
        Python name of the function.
    vectors : tuple of (str, tuple of Symbol)
        The vector arguments after ``t``, in order, with the symbols of their entries.
    outputs : tuple of (str, object)
        ``("vector", exprs)``, ``("matrix", Matrix)`` or ``("scalar", expr)``; one output is
        returned as is, several as a tuple.
    solve : SolveSpec, optional
    doc : str
    """

    name: str
    vectors: tuple
    outputs: tuple
    solve: SolveSpec | None = None
    doc: str = ""


@dataclass
class GeneratedModule:
    """The functions of one generated module and its source."""

    functions: dict
    source: str
    filename: str
    cse_counts: dict = field(default_factory=dict)


def _stack(entries):
    """Stack scalars (traced values or Python numbers) into a float64 vector."""
    if not entries:
        return jnp.zeros((0,), dtype=jnp.float64)
    return jnp.stack([jnp.asarray(e, dtype=jnp.float64) for e in entries])


def _matrix(entries, rows, cols):
    if rows * cols == 0:
        return jnp.zeros((rows, cols), dtype=jnp.float64)
    return jnp.reshape(_stack(entries), (rows, cols))


def _scalar(x):
    return jnp.asarray(x, dtype=jnp.float64)


def _flatten_outputs(outputs):
    flat = []
    layout = []
    for kind, value in outputs:
        if kind == "vector":
            entries = list(value)
            layout.append((kind, len(entries)))
        elif kind == "matrix":
            mat = sp.Matrix(value)
            entries = list(mat)  # row-major
            layout.append((kind, mat.shape))
        elif kind == "scalar":
            entries = [value]
            layout.append((kind, 1))
        else:  # pragma: no cover - internal misuse
            raise ValueError(f"unknown output kind {kind!r}")
        flat.extend(sp.sympify(e) for e in entries)
    return flat, layout


def _entry(expr) -> str:
    if expr.is_number:
        return repr(float(expr))
    return _code(expr)


def _blocks(mat: sp.Matrix) -> list[list[int]]:
    """The diagonal blocks of a symmetric matrix: the connected components of its structural
    nonzeros (entries that are not identically 0), each sorted, ordered by first index."""
    n = mat.shape[0]
    parent = list(range(n))

    def root(i):
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    for i in range(n):
        for j in range(i + 1, n):
            if mat[i, j] != 0 or mat[j, i] != 0:
                parent[root(i)] = root(j)
    groups: dict[int, list[int]] = {}
    for i in range(n):
        groups.setdefault(root(i), []).append(i)
    return sorted(groups.values(), key=lambda b: b[0])


def _solve_lines(solve: SolveSpec, blocks, pre_red, after) -> list[str]:
    """``v = M⁻¹ rhs`` block by block: a division for 1×1 blocks, the closed form for 2×2
    blocks, :func:`spd_solve` (unrolled elimination) for larger ones. Blocks whose unknowns
    are not used are skipped."""
    n = len(solve.unknowns)
    rhs = pre_red[len(pre_red) - n:]
    names = [u.name for u in solve.unknowns]
    lines = []
    pos = 0
    for k, block in enumerate(blocks):
        size = len(block)
        count = size if size == 1 else 3 if size == 2 else size * size
        entries = [f"({_entry(e)})" for e in pre_red[pos : pos + count]]
        pos += count
        if not any(solve.unknowns[i] in after for i in block):
            continue
        r = [f"({_entry(rhs[i])})" for i in block]
        if size == 1:
            lines.append(f"    {names[block[0]]} = {r[0]}/{entries[0]}")
        elif size == 2:
            a, b, c = entries
            i, j = block
            lines.append(f"    det_{k} = {a}*{c} - {b}*{b}")
            lines.append(f"    {names[i]} = ({c}*{r[0]} - {b}*{r[1]})/det_{k}")
            lines.append(f"    {names[j]} = ({a}*{r[1]} - {b}*{r[0]})/det_{k}")
        else:
            lines.append(f"    mblock_{k} = _matrix([{', '.join(entries)}], {size}, {size})")
            lines.append(f"    vblock_{k} = spd_solve(mblock_{k}, _stack([{', '.join(r)}]))")
            for pos_in, i in enumerate(block):
                lines.append(f"    {names[i]} = vblock_{k}[{pos_in}]")
    return lines


class PlainSymbols(NamedTuple):
    """The symbols generated code is written in, and the map to them from a model's internal ones."""

    t: sp.Symbol
    q: tuple
    v: tuple
    p: tuple
    lam: tuple
    params: tuple  # k_0, k_1, ...: the parameters in the model's order
    rename: dict  # internal time, coordinates, velocities and parameters -> the symbols above


def plain_symbols(ctx, m: int, parameters, param_symbols) -> PlainSymbols:
    """``t``, ``q_i``, ``v_i``, ``p_i``, ``lam_j``, ``k_j`` for a model of ``ctx.n`` coordinates, m
    multipliers and the parameters ``parameters`` (names; ``param_symbols``: name -> Symbol)."""
    n = ctx.n
    t = sp.Symbol("t")
    q = tuple(sp.Symbol(f"q_{i}") for i in range(n))
    v = tuple(sp.Symbol(f"v_{i}") for i in range(n))
    p = tuple(sp.Symbol(f"p_{i}") for i in range(n))
    lam = tuple(sp.Symbol(f"lam_{j}") for j in range(m))
    ks = tuple(sp.Symbol(f"k_{j}") for j in range(len(parameters)))
    rename = {ctx.t: t, **dict(zip(ctx.q, q)), **dict(zip(ctx.v, v)),
              **{param_symbols[name]: k for name, k in zip(parameters, ks)}}
    return PlainSymbols(t, q, v, p, lam, ks, rename)


class SharedSubexpressions(NamedTuple):
    """What :func:`common_subexpressions` returns."""

    replacements: list  # (symbol, expression) pairs of sympy.cse
    pre: list  # the reduced expressions evaluated before the solve
    outputs: list  # the reduced outputs
    early: list  # lines of the replacements that do not need the solve's unknowns
    late: list  # lines of those that do
    late_symbols: set  # the unknowns and every replacement that depends on them


def common_subexpressions(pre, flat, unknowns, line) -> SharedSubexpressions:
    """:func:`sympy.cse` over ``pre`` (what a solve needs) and ``flat`` (the outputs), with the
    replacements written as ``line(symbol, expression)`` and sorted into those evaluated before
    the solve for ``unknowns`` and those that need its result (shared with the native step's C,
    :mod:`lobattodae.mechanics._native`)."""
    pre = list(pre)
    replacements, reduced = sp.cse(pre + list(flat), symbols=sp.numbered_symbols("s_"), order="none")
    reduced = list(reduced)
    late = set(unknowns)
    early_lines, late_lines = [], []
    for sym, expr in replacements:
        if expr.free_symbols & late:
            late.add(sym)
            late_lines.append(line(sym, expr))
        else:
            early_lines.append(line(sym, expr))
    return SharedSubexpressions(replacements, reduced[: len(pre)], reduced[len(pre):], early_lines, late_lines, late)


def _function_source(spec: FunctionSpec, t: sp.Symbol, params) -> tuple[str, int]:
    """Source text of one function; ``params`` is a sequence of ``(key, Symbol)``."""
    flat, layout = _flatten_outputs(spec.outputs)
    solve = spec.solve
    blocks, pre = [], []
    if solve is not None:
        mat = sp.Matrix(solve.matrix)
        blocks = _blocks(mat)
        for block in blocks:
            if len(block) == 1:
                pre.append(mat[block[0], block[0]])
            elif len(block) == 2:
                i, j = block
                pre += [mat[i, i], mat[i, j], mat[j, j]]
            else:
                pre += [mat[i, j] for i in block for j in block]
        pre += list(solve.rhs)
    unknowns = set(solve.unknowns) if solve is not None else set()
    shared = common_subexpressions(pre, flat, unknowns, lambda sym, expr: f"    {sym.name} = {_code(expr)}")
    replacements, pre_red, out_red = shared.replacements, shared.pre, shared.outputs
    early_lines, late_lines, late = shared.early, shared.late, shared.late_symbols
    reduced = pre_red + out_red

    used = set()
    for _, expr in replacements:
        used |= expr.free_symbols
    for expr in reduced:
        used |= expr.free_symbols

    argnames = ["t"] + [name for name, _ in spec.vectors] + ["args"]
    lines = [f"def {spec.name}({', '.join(argnames)}):"]
    if spec.doc:
        lines.append(f"    {spec.doc!r}")
    for name, symbols in spec.vectors:
        for i, s in enumerate(symbols):
            if s in used:
                lines.append(f"    {s.name} = {name}[{i}]")
    for key, s in params:
        if s in used:
            lines.append(f"    {s.name} = args[{key!r}]")
    if t in used and t.name != "t":  # pragma: no cover - the time symbol is named t
        lines.append(f"    {t.name} = t")
    lines += early_lines
    after = set()
    for line_expr in [e for s_, e in replacements if s_ in late] + out_red:
        after |= line_expr.free_symbols
    if solve is not None and not (after & unknowns):
        solve = None  # the outputs do not use the velocities: no solve
    if solve is not None:
        lines += _solve_lines(solve, blocks, pre_red, after)
    lines += late_lines
    results = []
    pos = 0
    for kind, shape in layout:
        if kind == "vector":
            entries = out_red[pos : pos + shape]
            pos += shape
            results.append(f"_stack([{', '.join(_entry(e) for e in entries)}])")
        elif kind == "matrix":
            r, c = shape
            entries = out_red[pos : pos + r * c]
            pos += r * c
            results.append(f"_matrix([{', '.join(_entry(e) for e in entries)}], {r}, {c})")
        else:
            results.append(f"_scalar({_entry(out_red[pos])})")
            pos += 1
    lines.append(f"    return {results[0] if len(results) == 1 else '(' + ', '.join(results) + ')'}")
    return "\n".join(lines) + "\n", len(replacements)


#: The names a generated module may use besides its own functions' arguments and local variables.
_GLOBALS = frozenset({"jax", "functools", "_stack", "_matrix", "_scalar", "spd_solve"})
#: Expression nodes the generated code may contain (operators and contexts are checked by kind).
_EXPRESSIONS = (ast.BinOp, ast.UnaryOp, ast.BoolOp, ast.Compare, ast.IfExp, ast.Call, ast.keyword, ast.Attribute,
                ast.Subscript, ast.Name, ast.Constant, ast.Tuple, ast.List)
_OPERATORS = (ast.operator, ast.unaryop, ast.cmpop, ast.boolop, ast.expr_context)


class _UnsafeSource(Exception):
    """The generated source holds something the generator never writes itself."""


def _docstring(stmt) -> bool:
    return isinstance(stmt, ast.Expr) and isinstance(stmt.value, ast.Constant) and isinstance(stmt.value.value, str)


def _attribute_root(node) -> ast.AST:
    while isinstance(node, ast.Attribute):
        node = node.value
    return node


def _check_expression(expr, names: frozenset) -> None:
    """``expr`` uses only known names, ``jax.<public>`` attributes, numbers and ``args['key']``."""
    allowed_strings = set()
    for node in ast.walk(expr):
        if isinstance(node, ast.Subscript) and isinstance(node.value, ast.Name) and node.value.id == "args":
            if isinstance(node.slice, ast.Constant) and isinstance(node.slice.value, str):
                allowed_strings.add(id(node.slice))
    for node in ast.walk(expr):
        if isinstance(node, _OPERATORS):
            continue
        if not isinstance(node, _EXPRESSIONS):
            raise _UnsafeSource(f"a {type(node).__name__} node")
        if isinstance(node, ast.Name):
            if node.id not in names:
                raise _UnsafeSource(f"the unknown name {node.id!r}")
        elif isinstance(node, ast.Attribute):
            root = _attribute_root(node)
            if node.attr.startswith("_") or not (isinstance(root, ast.Name) and root.id == "jax"):
                raise _UnsafeSource(f"the attribute {ast.unparse(node)!r}")
        elif isinstance(node, ast.Constant):
            value = node.value
            if isinstance(value, str):
                if id(node) not in allowed_strings:
                    raise _UnsafeSource(f"the string literal {value!r} outside a docstring or args[...]")
            elif isinstance(value, complex) or not isinstance(value, (bool, int, float)):
                raise _UnsafeSource(f"the constant {value!r}")
        elif isinstance(node, ast.Call):  # of a helper or of jax.<...> (checked as an attribute above)
            func = node.func
            if not ((isinstance(func, ast.Name) and func.id in _GLOBALS) or isinstance(func, ast.Attribute)):
                raise _UnsafeSource(f"a call of {ast.unparse(func)!r}")
        elif isinstance(node, ast.keyword):
            if node.arg is None or node.arg.startswith("_"):
                raise _UnsafeSource("a ** argument" if node.arg is None else f"the keyword {node.arg!r}")


def _check_source(source: str, names) -> None:
    """Refuse (``_UnsafeSource``) a generated module that is not made of what the generator writes
    (the definitions of the functions ``names``, in order): see the module docstring."""
    try:
        tree = ast.parse(source)
    except (SyntaxError, ValueError) as exc:
        raise _UnsafeSource(f"it does not parse ({type(exc).__name__}: {exc})") from None
    body = list(tree.body)
    if body and _docstring(body[0]):
        body = body[1:]
    expected = list(names)
    if [getattr(stmt, "name", None) for stmt in body] != expected or not all(
            type(stmt) is ast.FunctionDef for stmt in body):
        raise _UnsafeSource("statements other than the definitions of " + ", ".join(expected))
    for fn in body:
        a = fn.args
        if fn.decorator_list or fn.returns or getattr(fn, "type_params", None) or a.vararg or a.kwarg \
                or a.posonlyargs or a.kwonlyargs or a.defaults or a.kw_defaults:
            raise _UnsafeSource(f"the signature of {fn.name}")
        params = [arg.arg for arg in a.args]
        if any(arg.annotation is not None for arg in a.args):
            raise _UnsafeSource(f"annotations in {fn.name}")
        stmts = list(fn.body)
        if stmts and _docstring(stmts[0]):
            stmts = stmts[1:]
        local = set(params)
        for stmt in stmts:
            if isinstance(stmt, ast.Assign):
                if len(stmt.targets) != 1 or not isinstance(stmt.targets[0], ast.Name):
                    raise _UnsafeSource(f"an assignment to {ast.unparse(stmt.targets[0])!r} in {fn.name}")
                local.add(stmt.targets[0].id)
            elif not isinstance(stmt, ast.Return) or stmt.value is None:
                raise _UnsafeSource(f"a {type(stmt).__name__} statement in {fn.name}")
        bad = sorted(n for n in local if n.startswith("__") or n in _GLOBALS)
        if bad:
            raise _UnsafeSource(f"the local name {bad[0]!r} in {fn.name}")
        names = frozenset(local) | _GLOBALS
        for stmt in stmts:
            _check_expression(stmt.value, names)


def generate_module(label: str, specs, t: sp.Symbol, params) -> GeneratedModule:
    """Write the functions ``specs`` into one module, check it (:func:`_check_source`) and execute it.

    Parameters
    ----------
    label : str
        Shown in the module's docstring (as a quoted literal) and file name (tracebacks).
    specs : sequence of FunctionSpec
    t : Symbol
        The time symbol (named ``t``).
    params : sequence of (str, Symbol)
        Keys of the ``args`` dict and the symbols they bind.

    Raises
    ------
    LobattoDAEInputError
        The source holds something the generator does not write itself (see the module
        docstring); nothing of it has run.
    """
    label = str(label)
    header = repr(f"Generated by lobattodae.mechanics for {label}: do not edit.") + "\n"
    bodies = []
    counts = {}
    for spec in specs:
        src, count = _function_source(spec, t, params)
        bodies.append(src)
        counts[spec.name] = count
    module = load_module(label, header + "\n\n".join(bodies), [spec.name for spec in specs])
    module.cse_counts = counts
    return module


def load_module(label: str, source: str, names, *, check: bool = True) -> GeneratedModule:
    """Check the generated ``source`` (:func:`_check_source`: the definitions of ``names`` and
    nothing the generator does not write) and execute it: the module of :func:`generate_module`.
    ``check=False`` for a source that passed the check when it was written and was kept since
    (``lobattodae.mechanics._model_cache``, whose entries are trusted as the native libraries are).

    Raises
    ------
    LobattoDAEInputError
        The source failed the check; nothing of it has run.
    """
    label = str(label)
    try:
        if check:
            _check_source(source, names)
    except _UnsafeSource as exc:
        raise LobattoDAEInputError(
            f"{label!r}: the generated code failed lobattodae's safety check ({exc}) and was not run. The "
            "expressions hold something the code generator does not write itself: an unevaluated Sum, Product "
            "or other construct with variables of its own (apply .doit() first, or write it out), or a name "
            "that is not a plain identifier."
        ) from None
    filename = f"<lobattodae.mechanics generated #{next(_counter)}: {label!r}>"
    namespace = {
        "__name__": "lobattodae.mechanics._generated",
        "jax": jax,
        "functools": functools,
        "_stack": _stack,
        "_matrix": _matrix,
        "_scalar": _scalar,
        "spd_solve": spd_solve,
    }
    code = compile(source, filename, "exec")
    linecache.cache[filename] = (len(source), None, source.splitlines(True), filename)
    exec(code, namespace)  # noqa: S102 - our own generated source, checked by _check_source
    functions = {name: namespace[name] for name in names}
    return GeneratedModule(functions=functions, source=source, filename=filename)
