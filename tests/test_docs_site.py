"""The documentation site builds with ``mkdocs build --strict`` (no broken link, no unknown
cross-reference, no docstring that fails to parse), every nav page and every public name of
the four public namespaces is on it, and the README's links point to files that exist.

MkDocs comes with the ``docs`` extra, which ``make test`` installs: without it these tests
fail (they are not skipped), saying what to install."""

import html
import importlib.util
import os
import pathlib
import re
import subprocess
import sys
import urllib.parse

import pytest

import lobattodae
import lobattodae.conditions
import lobattodae.examples
import lobattodae.mechanics

ROOT = pathlib.Path(__file__).resolve().parents[1]
CONFIG = ROOT / "mkdocs.yml"
#: The build takes about 10 s on the 2-core machine; this is the limit of a hung build.
BUILD_TIMEOUT = 300

#: Each public namespace and the API page that documents it.
NAMESPACES = {
    "lobattodae": (lobattodae, "api/lobattodae/index.html"),
    "lobattodae.mechanics": (lobattodae.mechanics, "api/mechanics/index.html"),
    "lobattodae.mechanics.bicycle": (lobattodae.mechanics.bicycle, "api/mechanics/index.html"),
    "lobattodae.mechanics.systems": (lobattodae.mechanics.systems, "api/mechanics/index.html"),
    "lobattodae.examples": (lobattodae.examples, "api/examples/index.html"),
    "lobattodae.conditions": (lobattodae.conditions, "api/conditions/index.html"),
}


def _require_mkdocs():
    missing = [m for m in ("mkdocs", "material", "mkdocstrings", "mkdocstrings_handlers.python")
               if importlib.util.find_spec(m.split(".")[0]) is None]
    if missing:
        pytest.fail(f"the documentation tools are not installed ({', '.join(missing)} missing): "
                    f"pip install -e '.[docs]' (make test installs lobattodae[test,docs])", pytrace=False)


@pytest.fixture(scope="module")
def site(tmp_path_factory) -> pathlib.Path:
    _require_mkdocs()
    out = tmp_path_factory.mktemp("site")
    env = dict(os.environ, NO_MKDOCS_2_WARNING="1")
    run = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "--config-file", str(CONFIG),
                          "--site-dir", str(out)], cwd=ROOT, env=env, capture_output=True, text=True,
                         timeout=BUILD_TIMEOUT)
    assert run.returncode == 0, "mkdocs build --strict failed:\n" + (run.stdout + run.stderr)[-6000:]
    return out


def _text(page: pathlib.Path) -> str:
    """The page's visible text, tags dropped and whitespace collapsed."""
    body = re.sub(r"<(script|style)\b.*?</\1>", " ", page.read_text(encoding="utf-8"), flags=re.S)
    return " ".join(html.unescape(re.sub(r"<[^>]+>", " ", body)).split())


def _nav_pages(nav) -> list[str]:
    out = []
    for item in nav:
        if isinstance(item, str):
            out.append(item)
        elif isinstance(item, dict):
            for value in item.values():
                out += _nav_pages(value) if isinstance(value, list) else [value]
    return out


def _built_page(site: pathlib.Path, src: str) -> pathlib.Path:
    stem = src[: -len(".md")]
    if stem == "index" or stem.endswith("/index"):
        return site / stem.rpartition("index")[0] / "index.html"
    if stem.endswith("/README"):
        return site / stem.rpartition("README")[0] / "index.html"
    return site / stem / "index.html"


def test_every_nav_page_is_built(site):
    from mkdocs.config import load_config

    nav = load_config(str(CONFIG))["nav"]
    pages = _nav_pages(nav)
    assert len(pages) >= 40 and "getting-started.md" in pages and "api/lobattodae.md" in pages
    missing = [p for p in pages if not _built_page(site, p).is_file()]
    assert not missing, missing


def test_every_public_name_has_an_api_entry(site):
    for namespace, (module, page) in NAMESPACES.items():
        ids = set(re.findall(r'id="([^"]+)"', (site / page).read_text(encoding="utf-8")))
        missing = [name for name in module.__all__ if f"{namespace}.{name}" not in ids]
        assert not missing, f"{namespace}: no entry on {page} for {missing}"


def test_solve_signature_and_sections_on_the_api_page(site):
    text = _text(site / "api/lobattodae/index.html")
    squeezed = re.sub(r"\s+", "", text)
    assert "solve(problem,method:LobattoIIIAIIIB,t_span,q0,p0,*,n_steps:int|None=None" in squeezed
    section = text[text.index("lobattodae.solve"):]
    section = section[: section.index("lobattodae.Solution")]
    for heading in ("Parameters:", "Returns:", "Raises:"):
        assert heading in section, heading
    # the docstrings' Sphinx roles became links or code, none is shown raw
    for page in ("lobattodae", "mechanics", "examples", "conditions"):
        raw = re.findall(r":(?:func|class|meth|attr|data|mod|exc|math):`", _text(site / f"api/{page}/index.html"))
        assert not raw, (page, raw[:5])


def test_math_is_marked_up_for_mathjax(site):
    scheme = (site / "theory/scheme/index.html").read_text(encoding="utf-8")
    assert scheme.count('class="arithmatex"') >= 10 and r"\hat a_{ij}" in scheme
    api = (site / "api/lobattodae/index.html").read_text(encoding="utf-8")
    assert 'class="arithmatex"' in api  # the .. math:: blocks of the problem classes


def test_internal_links_and_images_resolve(site):
    broken = []
    for page in site.rglob("*.html"):
        if page.name == "404.html":  # served from any depth, so its links are absolute
            continue
        for target in re.findall(r'(?:href|src)="([^"]+)"', page.read_text(encoding="utf-8")):
            if re.match(r"^[a-z][a-z0-9+.-]*:", target) or target.startswith(("#", "/")):
                continue
            path = urllib.parse.unquote(target.split("#")[0].split("?")[0])
            if not path:
                continue
            resolved = (page.parent / path).resolve()
            if resolved.is_dir():
                resolved = resolved / "index.html"
            if not resolved.exists():
                broken.append(f"{page.relative_to(site)} -> {target}")
    assert not broken, broken[:20]


def test_user_pages_name_no_private_module(site):
    """The guide, theory, examples and the benchmarks overview; not the API pages (signatures
    name where defaults come from) nor the benchmark logs mirrored from benchmarks/, which are
    the developers' notes."""
    skip = [site / "api", site / "benchmarks"]
    offenders = []
    for page in site.rglob("*.html"):
        if any(d in page.parents for d in skip) and page != site / "benchmarks" / "index.html":
            continue
        found = set(re.findall(r"lobattodae\._\w+", _text(page)))
        if found:
            offenders.append(f"{page.relative_to(site)}: {sorted(found)}")
    assert not offenders, offenders


def test_readme_links_point_to_files():
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    targets = [t for t in re.findall(r"\]\(([^)\s]+)\)", text) if not re.match(r"^[a-z]+:", t)]
    assert len(targets) >= 20
    missing = [t for t in targets if not (ROOT / t.split("#")[0]).exists()]
    assert not missing, missing
