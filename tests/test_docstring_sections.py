"""The NumPy sections of the public docstrings of ``lobattodae``, ``lobattodae.examples``,
``lobattodae.conditions`` and ``lobattodae.mechanics`` (issue #28): every function, public
method and class there documents its parameters, what it returns and what it raises. The
check lives in ``scripts/griffe_docstrings.py`` (the site's griffe extension), which makes
``mkdocs build --strict`` fail on a missing section; here it runs without building the site,
and on a small package whose gaps are known, to show that it finds them."""

import importlib.util
import pathlib
import textwrap

import pytest

griffe = pytest.importorskip("griffe", reason="griffe comes with the docs extra (mkdocstrings-python)")

ROOT = pathlib.Path(__file__).resolve().parents[1]


def _extension():
    spec = importlib.util.spec_from_file_location("griffe_docstrings", ROOT / "scripts" / "griffe_docstrings.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.fixture(scope="module")
def ext():
    return _extension()


def test_checked_namespaces_have_complete_sections(ext):
    assert set(ext.CHECKED) == {"lobattodae", "lobattodae.examples", "lobattodae.conditions", "lobattodae.mechanics",
                                "lobattodae.mechanics.bicycle", "lobattodae.mechanics.systems"}
    pkg = griffe.load("lobattodae", search_paths=[str(ROOT / "src")], docstring_parser="numpy",
                      extensions=griffe.load_extensions(ext.SphinxToMarkdown))
    assert ext.missing_sections(pkg) == []
    # ... and the check saw them all: the wildcard re-export of conditions included
    names = {n for ns in ext.CHECKED
             for n in ext._export_names(pkg if ns == "lobattodae" else pkg[ns[len("lobattodae."):]])}
    assert {"b_error", "satisfies_d_hat_d", "check_tableau", "TableauReport"} <= names
    assert {"from_lagrangian", "LagrangianModel", "quaternion_body", "rattleback_state", "linearize"} <= names
    assert {"solve", "integrate_adaptive", "Solution", "LobattoIIIAIIIB", "PIController", "NewtonFailure"} <= names
    assert {"Example", "get_example", "knife_edge", "steady_spin_rate", "FallingDiskParams"} <= names


FAKE = '''
"""A package with known gaps."""

from typing import NamedTuple

__all__ = ["bare", "complete", "Record", "Built", "Pair", "CONSTANT"]

CONSTANT = 1.0


def bare(x, y=2):
    """Nothing but a summary."""
    if x < 0:
        raise ValueError("negative")
    return x + y


def complete(x, *, flag=False):
    """Everything.

    Parameters
    ----------
    x : float
        A number.
    flag : bool, optional
        A flag.

    Returns
    -------
    float
        ``x`` or ``-x``.

    Raises
    ------
    ValueError
        If ``x`` is negative.
    """
    def helper(z):
        return z  # a nested function's return is not the function's own

    if x < 0:
        raise ValueError("negative")
    return -x if flag else helper(x)


class Record(NamedTuple):
    """A record.

    Attributes
    ----------
    a : float
        The first.
    """

    a: float
    b: float

    def scaled(self, factor):
        """The record times ``factor``."""
        return Record(self.a * factor, self.b * factor)

    def _private(self, z):
        return z


class Built:
    """Built by hand.

    Parameters
    ----------
    a : int
        The first.
    """

    def __init__(self, a, b):
        self.a, self.b = a, b


class Pair(NamedTuple):
    """Built from its fields, documented as Parameters: its property is no parameter.

    Parameters
    ----------
    a, b : float
        The two.
    """

    a: float
    b: float

    @property
    def total(self) -> float:
        return self.a + self.b
'''


def test_the_check_finds_missing_sections(ext, tmp_path):
    pkg_dir = tmp_path / "fakepkg"
    pkg_dir.mkdir()
    (pkg_dir / "__init__.py").write_text(textwrap.dedent(FAKE), encoding="utf-8")
    pkg = griffe.load("fakepkg", search_paths=[str(tmp_path)], docstring_parser="numpy")
    assert ext.missing_sections(pkg, ("fakepkg",)) == sorted([
        "fakepkg.bare: no Parameters section",
        "fakepkg.bare: no Returns section",
        "fakepkg.bare: no Raises section",
        "fakepkg.Record: field 'b' is not documented",
        "fakepkg.Record.scaled: no Parameters section",
        "fakepkg.Record.scaled: no Returns section",
        "fakepkg.Built: parameter 'b' is not documented",
    ])
