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
"""

from __future__ import annotations

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
#: The private module behind each public namespace (for an object's home namespace).
_HOMES = {
    "lobattodae.mechanics._bicycle": "lobattodae.mechanics.bicycle",
    "lobattodae.mechanics._systems": "lobattodae.mechanics.systems",
    "lobattodae.mechanics": "lobattodae.mechanics",
    "lobattodae.examples": "lobattodae.examples",
    "lobattodae._conditions": "lobattodae.conditions",
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
