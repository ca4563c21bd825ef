"""The user-facing documentation pages' Python examples run as written (issue #28).

For each page of :data:`PAGES`, the page's ```` ```python ```` fenced blocks are joined in
order into one script, the way a reader copies a page from top to bottom, and run in a fresh
interpreter (``sys.executable``; a process that has imported nothing, so a missing import in
the docs fails here) with ``LOBATTODAE_NO_CACHE=1`` and the working directory a fresh
``tmp_path``, so that the files an example writes (``run.npz``, ``run.gif``) land there. A
block that uses a name must define it on the same page (or import it): pages do not share
names.

A block that cannot run by design is marked in the Markdown on the line before its fence::

    <!-- docs-test: skip (the reason) -->
    ```python

and is left out of its page's script. Keep such skips rare, and give the reason.

The examples are kept small (short intervals, few steps, s = 2..4) so that the whole file runs
in about a minute on a loaded 2-core machine; what they compute is checked by the test suite
proper, here only that they run.
"""

import pathlib
import re
import subprocess
import sys
import textwrap
import time

import pytest

from helpers import subprocess_env

ROOT = pathlib.Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"

#: Every user-facing page this file covers (getting-started.md, index.md, guide/*.md,
#: theory/*.md), relative to docs/: ``None`` runs the page's Python blocks; a string is the
#: reason the page is left out. A page left out for having no Python code is checked to have
#: none (:func:`test_pages_without_code_have_none`), so code added to it must be added here.
NO_CODE = "no Python code"
PAGES: dict[str, str | None] = {
    "index.md": None,
    "getting-started.md": None,
    "guide/index.md": NO_CODE,            # the guide's table of contents
    "guide/problems.md": None,
    "guide/methods.md": None,
    "guide/steps.md": None,
    "guide/dense-output.md": None,
    "guide/events.md": None,
    "guide/output.md": None,
    "guide/lambda.md": NO_CODE,
    "guide/transformations.md": None,
    "guide/checkpoints.md": None,
    "guide/cli.md": None,                 # the model file of `--model`; the shell commands are not run
    "guide/errors.md": NO_CODE,
    "theory/index.md": NO_CODE,           # the theory section's table of contents
    "theory/scheme.md": NO_CODE,          # equations only
    "theory/lambda-modes.md": NO_CODE,    # a study: its numbers come from scripts/ and tests/
    "theory/stability-limit.md": NO_CODE,
}

#: The sections of the site this file covers; every page in them must be in PAGES.
COVERED = ("index.md", "getting-started.md", "guide/*.md", "theory/*.md")

#: A fenced Python block, with the line before it (where a skip marker goes). Fences may be
#: indented (inside a list item): the indentation of the opening fence is removed.
_FENCE = re.compile(r"^(?P<before>[^\n]*)\n(?P<indent>[ \t]*)```python[ \t]*\n(?P<body>.*?)^(?P=indent)```[ \t]*$",
                    flags=re.S | re.M)
_SKIP = re.compile(r"<!--\s*docs-test:\s*skip\s*\((?P<reason>[^)]+)\)\s*-->")

#: The limit of one page's run (a hung example), not its expected time (a few seconds each).
PAGE_TIMEOUT = 300


def python_blocks(text: str) -> list[tuple[str, str | None]]:
    """The page's ```python blocks in order, each as ``(code, skip_reason)``; ``skip_reason``
    is None for a block that runs."""
    blocks = []
    for m in _FENCE.finditer("\n" + text):
        skip = _SKIP.search(m["before"])
        if "docs-test" in m["before"] and skip is None:
            raise ValueError(f"malformed docs-test marker (want <!-- docs-test: skip (reason) -->): {m['before']!r}")
        body = textwrap.dedent("".join(line[len(m["indent"]):] if line.startswith(m["indent"]) else line
                                       for line in m["body"].splitlines(keepends=True)))
        blocks.append((body, skip["reason"].strip() if skip else None))
    return blocks


def page_script(page: str) -> str:
    text = (DOCS / page).read_text(encoding="utf-8")
    parts = []
    for i, (code, skip) in enumerate(python_blocks(text)):
        if skip is None:
            parts.append(f"# --- {page}, block {i + 1}\n{code}")
    return "\n".join(parts)


def test_every_covered_page_is_listed():
    found = {p.relative_to(DOCS).as_posix() for pattern in COVERED for p in DOCS.glob(pattern)}
    assert found == set(PAGES), (f"pages not in PAGES: {sorted(found - set(PAGES))}; "
                                 f"PAGES that do not exist: {sorted(set(PAGES) - found)}")


@pytest.mark.parametrize("page", [p for p, why in PAGES.items() if why == NO_CODE])
def test_pages_without_code_have_none(page):
    text = (DOCS / page).read_text(encoding="utf-8")
    assert not re.search(r"^[ \t]*```(python|py|pycon)\b", text, flags=re.M), (
        f"{page} now has Python code: list it in PAGES as None so that its blocks run")


def test_skip_markers_are_rare_and_give_a_reason():
    """A docs-test marker anywhere in the covered pages sits right before a ```python fence."""
    for page in PAGES:
        text = (DOCS / page).read_text(encoding="utf-8")
        markers = text.count("docs-test")
        skipped = sum(skip is not None for _, skip in python_blocks(text))
        assert markers == skipped, f"{page}: a docs-test marker that is not on the line before a ```python fence"


def test_block_extraction():
    text = ("intro\n```python\na = 1\n```\n\n<!-- docs-test: skip (needs your own file) -->\n"
            "```python\nopen('mine.csv')\n```\n* item:\n\n    ```python\n    if a:\n        b = 2\n    ```\n")
    assert python_blocks(text) == [("a = 1\n", None), ("open('mine.csv')\n", "needs your own file"),
                                   ("if a:\n    b = 2\n", None)]
    with pytest.raises(ValueError, match="malformed"):
        python_blocks("<!-- docs-test: skip -->\n```python\nx\n```\n")


@pytest.mark.parametrize("page", [p for p, why in PAGES.items() if why is None])
def test_page_code_runs(page, tmp_path):
    script = page_script(page)
    assert script.strip(), f"{page} is listed as having code but has no runnable ```python block"
    path = tmp_path / (page.replace("/", "_").removesuffix(".md") + "_docs.py")
    path.write_text(script, encoding="utf-8")
    env = subprocess_env(LOBATTODAE_NO_CACHE="1", MPLBACKEND="Agg")
    start = time.perf_counter()
    run = subprocess.run([sys.executable, str(path)], cwd=tmp_path, env=env, capture_output=True, text=True,
                         timeout=PAGE_TIMEOUT)
    elapsed = time.perf_counter() - start
    if run.returncode != 0:
        pytest.fail(f"docs/{page}: its Python blocks, run as one script ({path}), exited with status "
                    f"{run.returncode} after {elapsed:.1f} s:\n{run.stderr[-4000:]}", pytrace=False)
