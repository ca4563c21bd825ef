"""Griffe extension for the API pages (``mkdocs.yml``: mkdocstrings' ``extensions``).

The library's docstrings are NumPy style with a few reStructuredText habits that Markdown
does not know. Before the docstrings are parsed, this rewrites, in the text only:

* ``:func:`x```, ``:class:`~pkg.X```, ``:meth:``, ``:attr:``, ``:data:``, ``:mod:``,
  ``:exc:``, ``:obj:`` -> a cross-reference ``[`x`][lobattodae.x]`` when ``x`` names a public
  object (exported by ``lobattodae``, ``lobattodae.mechanics`` (and its ``bicycle`` and
  ``systems``), ``lobattodae.examples`` or ``lobattodae.conditions``, or a public member of
  one), otherwise plain code (private modules and constants are never linked);
* ``:math:`x``` -> ``$x$`` and ``.. math::`` blocks -> ``$$ ... $$`` (MathJax, arithmatex);
* doctest lines (``>>>``) -> a fenced ``pycon`` block, a paragraph ending in ``::`` -> ``:``;
* a module constant documented by ``#:`` comments above it (Sphinx's convention) gets them
  as its docstring.

It also checks the NumPy sections of the namespaces in :data:`CHECKED` (issue #28): every
public function, public method of a public class, and class there must document each of its
parameters in a ``Parameters`` section (a class: ``Parameters`` or ``Attributes``), have a
``Returns`` (or ``Yields``) section if its body returns a value, and a ``Raises`` section if
its body raises. A missing section is a warning on the ``mkdocs`` logger, so that
``mkdocs build --strict`` fails; :func:`missing_sections` returns the same list for the tests.
"""

from __future__ import annotations

import ast
import logging
import re
import textwrap

import griffe

#: Public namespaces, most specific first: a relative name in a docstring is looked up in the
#: namespace its object belongs to, then in the others.
NAMESPACES = (
    "lobattodae.mechanics.bicycle",
    "lobattodae.mechanics.systems",
    "lobattodae.mechanics",
    "lobattodae.examples",
    "lobattodae.conditions",
    "lobattodae",
)
#: The public namespaces whose functions, methods and classes must have complete NumPy
#: sections (:func:`missing_sections`).
CHECKED = (
    "lobattodae",
    "lobattodae.examples",
    "lobattodae.conditions",
    "lobattodae.mechanics",
    "lobattodae.mechanics.bicycle",
    "lobattodae.mechanics.systems",
)
#: The private module behind each public namespace (for an object's home namespace).
_HOMES = {
    "lobattodae.mechanics._bicycle": "lobattodae.mechanics.bicycle",
    "lobattodae.mechanics._systems": "lobattodae.mechanics.systems",
    "lobattodae.mechanics": "lobattodae.mechanics",
    "lobattodae.examples": "lobattodae.examples",
    "lobattodae._conditions": "lobattodae.conditions",
    "lobattodae._condition_checks": "lobattodae.conditions",
    "lobattodae._tableau_report": "lobattodae.conditions",
    "lobattodae.conditions": "lobattodae.conditions",
}

_ROLE = re.compile(r":(?:py:)?(func|class|meth|attr|data|mod|exc|obj|const|math):`([^`]+)`")
_MATH_DIRECTIVE = re.compile(r"^(\s*)\.\. math::\s*$")


class SphinxToMarkdown(griffe.Extension):
    """Rewrite the docstrings of the whole ``lobattodae`` package once it is loaded."""

    def on_package(self, *, pkg: griffe.Module, **kwargs) -> None:
        if pkg.name != "lobattodae":
            return
        self.pkg = pkg
        self.public = self._public_names(pkg)
        self._walk(pkg, set())
        for problem in missing_sections(pkg):
            _LOGGER.warning("docstring: %s", problem)

    # -- what can be linked ----------------------------------------------------------------
    def _public_names(self, pkg: griffe.Module) -> dict[str, set[str]]:
        out = {}
        for ns in NAMESPACES:
            try:
                module = pkg[ns[len("lobattodae."):]] if ns != "lobattodae" else pkg
            except (KeyError, griffe.AliasResolutionError):
                continue
            exports = module.exports if module.exports is not None else []
            out[ns] = {e if isinstance(e, str) else e.name for e in exports}
        return out

    def _exists(self, path: str) -> bool:
        ns = next((n for n in NAMESPACES if path.startswith(n + ".")), None)
        if ns is None:
            return False
        first, *rest = path[len(ns) + 1:].split(".")
        if first not in self.public.get(ns, ()) or any(p.startswith("_") for p in rest):
            return False
        try:
            obj = self.pkg[path[len("lobattodae."):]]
            return obj is not None
        except Exception:
            return False

    def resolve(self, target: str, home: str) -> str | None:
        target = target.lstrip(".")
        if target.startswith("lobattodae."):
            return target if self._exists(target) else None
        for ns in (home, *NAMESPACES):
            if self._exists(f"{ns}.{target}"):
                return f"{ns}.{target}"
        return None

    # -- the rewrite -----------------------------------------------------------------------
    def _walk(self, obj, seen: set) -> None:
        if obj.is_alias or id(obj) in seen:
            return
        seen.add(id(obj))
        if obj.docstring is None and obj.is_attribute:
            _comment_docstring(obj)
        if obj.docstring is not None:
            obj.docstring.value = self.convert(obj.docstring.value, self._home(obj.path))
        for member in obj.members.values():
            if not member.is_alias:
                self._walk(member, seen)

    @staticmethod
    def _home(path: str) -> str:
        for private, public in _HOMES.items():
            if path == private or path.startswith(private + "."):
                return public
        return "lobattodae"

    def convert(self, text: str, home: str) -> str:
        text = _math_blocks(text)
        text = _ROLE.sub(lambda m: self._role(m.group(1), m.group(2), home), text)
        return _doctest_blocks(text)

    def _role(self, kind: str, body: str, home: str) -> str:
        if kind == "math":
            return f"${body.strip()}$"
        shown, _, explicit = body.partition(" <")
        if explicit:
            target = explicit.rstrip(">")
        else:
            target = body.lstrip("~!")
            shown = target.split(".")[-1] if body.startswith("~") else target
        path = self.resolve(target, home)
        return f"[`{shown}`][{path}]" if path else f"`{shown}`"


def _comment_docstring(obj) -> None:
    """The ``#:`` comment lines right above an attribute's assignment, as its docstring."""
    parent = obj.parent
    if parent is None or not parent.is_module or obj.lineno is None:
        return
    try:
        lines = parent.lines
    except Exception:
        return
    found, i = [], obj.lineno - 2
    while 0 <= i < len(lines) and lines[i].lstrip().startswith("#:"):
        found.insert(0, lines[i].lstrip()[2:].strip())
        i -= 1
    if found:
        obj.docstring = griffe.Docstring("\n".join(found), parent=obj)


def _math_blocks(text: str) -> str:
    """``.. math::`` and its indented body -> a ``$$`` block at the directive's indentation."""
    lines, out, i = text.splitlines(), [], 0
    while i < len(lines):
        m = _MATH_DIRECTIVE.match(lines[i])
        if not m:
            out.append(lines[i])
            i += 1
            continue
        indent, body, i = m.group(1), [], i + 1
        while i < len(lines) and (not lines[i].strip() or _indent(lines[i]) > len(indent)):
            body.append(lines[i])
            i += 1
        while body and not body[-1].strip():
            body.pop()
        math = textwrap.dedent("\n".join(body)).strip("\n")
        out += [f"{indent}$$", *(indent + ln for ln in math.splitlines()), f"{indent}$$", ""]
    return "\n".join(out)


def _doctest_blocks(text: str) -> str:
    """Runs of ``>>>`` lines (with their continuation and output lines) -> fenced blocks; a
    reST literal-block marker ``::`` at the end of a paragraph line -> ``:``."""
    lines, out, i, fenced = text.splitlines(), [], 0, False
    while i < len(lines):
        line = lines[i]
        if line.lstrip().startswith(("```", "~~~")):
            fenced = not fenced
        if fenced or not line.lstrip().startswith(">>>"):
            out.append(re.sub(r"(\S)::$", r"\1:", line) if not fenced else line)
            i += 1
            continue
        indent = " " * _indent(line)
        block = []
        while i < len(lines) and lines[i].strip():
            block.append(lines[i][len(indent):] if lines[i].startswith(indent) else lines[i].strip())
            i += 1
        out += [f"{indent}```pycon", *(indent + b for b in block), f"{indent}```"]
    return "\n".join(out)


def _indent(line: str) -> int:
    return len(line) - len(line.lstrip())


# -- the sections check ----------------------------------------------------------------------
_LOGGER = logging.getLogger("mkdocs.plugins.griffe_docstrings")
#: Parameters that need no entry in ``Parameters``.
_IMPLICIT = {"self", "cls"}


def missing_sections(pkg: griffe.Module, namespaces=CHECKED) -> list[str]:
    """What the docstrings of the public objects of ``namespaces`` lack, one line per problem
    (``"lobattodae.conditions.b_error: no Returns section"``); empty when nothing is missing.

    Parameters
    ----------
    pkg : griffe.Module
        The loaded package (``lobattodae``).
    namespaces : iterable of str, optional
        Public namespaces, full dotted names inside ``pkg`` (default :data:`CHECKED`); each
        name in a namespace's ``__all__`` is checked, and for a class its own public methods.

    Returns
    -------
    list of str
        The problems, sorted.
    """
    problems, seen = set(), set()
    for ns in namespaces:
        module = pkg if ns == pkg.path else pkg[ns[len(pkg.path) + 1:]]
        for name in _export_names(module):
            obj = _target(module[name])
            if obj is None or obj.is_module or obj.is_attribute or id(obj) in seen:
                continue
            seen.add(id(obj))
            problems.update(_check_object(obj, f"{ns}.{name}"))
            if obj.is_class:
                for member_name, member in obj.members.items():
                    if member_name.startswith("_") or member.is_alias or not member.is_function:
                        continue
                    if "property" in member.labels:
                        continue
                    problems.update(_check_object(member, f"{ns}.{name}.{member_name}"))
    return sorted(problems)


def _export_names(module) -> list[str]:
    """The names of ``module.__all__``; where griffe cannot read it statically (``conditions``
    re-exports the ``__all__`` of its private module with a wildcard import), the module's
    public members, which the wildcard import brought in."""
    if module.exports is not None:
        return [e if isinstance(e, str) else e.name for e in module.exports]
    return [name for name in module.members if not name.startswith("_")]


def _target(obj):
    """``obj``, or the object an alias points to (None if it cannot be resolved)."""
    if not obj.is_alias:
        return obj
    try:
        return obj.final_target
    except (griffe.AliasResolutionError, griffe.CyclicAliasError):
        return None


def _sections(obj) -> dict[str, list]:
    """The parsed NumPy sections of ``obj``'s docstring: kind -> the section's items. Parsed
    without griffe's own warnings: the check runs before griffe's dataclass extension has made
    the constructors, so a dataclass's ``Parameters`` would be reported as unknown here (the
    API pages parse the docstrings again, with the warnings, once the constructors exist)."""
    if obj.docstring is None:
        return {}
    out: dict[str, list] = {}
    for section in obj.docstring.parse("numpy", warnings=False):
        kind = section.kind.value
        value = section.value if isinstance(section.value, list) else [section.value]
        out.setdefault(kind, []).extend(value)
    return out


def _body(obj) -> ast.AST | None:
    """The function's own syntax tree (None where the source is not available)."""
    try:
        tree = ast.parse(textwrap.dedent(obj.source))
    except (SyntaxError, OSError, TypeError, ValueError):
        return None
    return tree.body[0] if tree.body else None


def _own_nodes(node):
    """The nodes of a function's body, without those of the functions, lambdas and classes
    it defines."""
    stack = list(ast.iter_child_nodes(node))
    while stack:
        child = stack.pop()
        if isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda, ast.ClassDef)):
            continue
        yield child
        stack.extend(ast.iter_child_nodes(child))


def _documented(items) -> set[str]:
    """The names of the parameters (or attributes) of a section, ``"a, b"`` split."""
    names = set()
    for item in items:
        for name in str(getattr(item, "name", "")).split(","):
            names.add(name.strip().lstrip("*"))
    return names


def _check_object(obj, path: str) -> list[str]:
    if obj.docstring is None:
        return [f"{path}: no docstring"]
    sections = _sections(obj)
    problems = []
    if obj.is_class:
        # A class documents its constructor in Parameters (each parameter of its __init__) or,
        # when it is built by a factory or is a record (dataclass, NamedTuple), its fields in
        # Attributes (each field).
        params, fields = _class_parameters(obj)
        if "parameters" in sections:
            documented = _documented(sections["parameters"])
            problems += [f"{path}: parameter {p!r} is not documented" for p in params if p not in documented]
        elif "attributes" in sections:
            documented = _documented(sections["attributes"])
            problems += [f"{path}: field {f!r} is not documented" for f in fields if f not in documented]
        elif params or fields:
            problems.append(f"{path}: no Parameters (or Attributes) section")
        return problems
    params = [p.name for p in obj.parameters if p.name not in _IMPLICIT]
    if params:
        if "parameters" not in sections and "other parameters" not in sections:
            problems.append(f"{path}: no Parameters section")
        else:
            documented = _documented(sections.get("parameters", []) + sections.get("other parameters", []))
            problems += [f"{path}: parameter {p!r} is not documented" for p in params if p not in documented]
    body = _body(obj)
    if body is not None:
        nodes = list(_own_nodes(body))
        returns = any(isinstance(n, ast.Return) and n.value is not None for n in nodes)
        if returns and "returns" not in sections and "yields" not in sections:
            problems.append(f"{path}: no Returns section")
        if any(isinstance(n, ast.Raise) for n in nodes) and "raises" not in sections:
            problems.append(f"{path}: no Raises section")
    return problems


def _class_parameters(cls) -> tuple[list[str], list[str]]:
    """``(constructor parameters, fields)``: the fields are the class's public annotated
    attributes (those of a dataclass or a ``NamedTuple``, and its properties, which griffe
    loads as attributes labelled ``property``); the constructor's parameters are those of the
    class's own ``__init__``, or where it has none (a dataclass before griffe's dataclass
    extension has made its ``__init__``, a ``NamedTuple``) the fields that are not properties."""
    fields = [name for name, member in cls.members.items()
              if not member.is_alias and member.is_attribute and not name.startswith("_")
              and member.annotation is not None]
    init = cls.members.get("__init__")
    if init is not None and not init.is_alias and init.is_function:
        return [p.name for p in init.parameters if p.name not in _IMPLICIT], fields
    return [name for name in fields if "property" not in cls.members[name].labels], fields
