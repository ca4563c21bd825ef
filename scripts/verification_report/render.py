"""Render ``verification.md`` from the report's JSON data alone: the template, its filters
and the findings decided from the data."""

from __future__ import annotations

import functools
import math
from pathlib import Path

import jinja2

from . import findings

TEMPLATE = Path(__file__).with_name("verification.md.j2")
SUPERSCRIPTS = str.maketrans("0123456789-", "⁰¹²³⁴⁵⁶⁷⁸⁹⁻")


def fmt(x, spec: str = "") -> str:
    """``format(x, spec)``; '—' for a number that is missing (None) or not finite."""
    if x is None or (isinstance(x, float) and not math.isfinite(x)):
        return "—"
    return format(x, spec)


def paragraph(text: str) -> str:
    """The lines of a template paragraph joined into one line (whitespace runs as one space);
    nothing for a paragraph whose conditions left it empty."""
    words = text.split()
    return " ".join(words) + "\n" if words else ""


def sup(n) -> str:
    """An integer as superscript digits (an exponent: h⁸)."""
    return str(n).translate(SUPERSCRIPTS)


@functools.cache
def environment() -> jinja2.Environment:
    """The Jinja environment of the template (compiled once per process)."""
    env = jinja2.Environment(loader=jinja2.FileSystemLoader(TEMPLATE.parent), undefined=jinja2.StrictUndefined,
                             trim_blocks=True, lstrip_blocks=True, keep_trailing_newline=True, autoescape=False)
    env.filters.update(fmt=fmt, paragraph=paragraph, sup=sup)
    return env


def render(data: dict) -> str:
    """The report as Markdown, from the JSON data written by ``make_verification.py``."""
    return environment().get_template(TEMPLATE.name).render(
        data=data, lib=data["library"], cfg=data["settings"], f=findings.findings(data), rules=findings)
