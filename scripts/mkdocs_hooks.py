"""MkDocs hooks of the documentation site (``mkdocs.yml``: ``hooks``).

Three jobs, none of which changes a file in the repository:

* **Mirror** the benchmark pages and figures, which live under ``benchmarks/`` next to the
  scripts that write them, into the site at the same paths (``benchmarks/README.md`` becomes
  ``benchmarks/scripts.md``, since ``benchmarks/index.md`` is the site's own overview).
* **Rewrite relative links** so that one Markdown source reads right both on GitHub and on the
  site: a link is resolved against the page's place *in the repository*; a target the site
  has (a docs page, a mirrored file) gets its site-relative path, any other repository file
  (a script, a test) is not on the site and its link becomes the file's path as code.
* **API pages**: a line ``<!-- api: SECTION -->`` in ``docs/api/*.md`` becomes one
  ``::: lobattodae.NAME`` directive per exported name of that section (``API_SECTIONS``);
  ``<!-- api: other -->`` takes every name of ``lobattodae.__all__`` that no section lists, so
  a newly exported name is documented without editing the page.
"""

from __future__ import annotations

import ast
import posixpath
import re
from pathlib import Path

from mkdocs.structure.files import File, Files, InclusionLevel

ROOT = Path(__file__).resolve().parents[1]

#: Repository files shown on the site: (glob relative to the repository root, site path or
#: None for "the same path").
MIRRORS = (
    ("benchmarks/RESULTS.md", None),
    ("benchmarks/README.md", "benchmarks/scripts.md"),
    ("benchmarks/testset/README.md", None),
    ("benchmarks/results/*.md", None),
    ("benchmarks/results/*.png", None),
)

#: The sections of the ``lobattodae`` API page, in the order of the page. A name listed here
#: but not (yet) exported is skipped; an exported name listed nowhere goes to ``other``.
API_SECTIONS = {
    "solve": ["solve", "Solution", "STATS", "Result", "DenseOutput", "Event"],
    "controllers": ["PIController", "ReversibleStepSize"],
    "problems": [
        "PartitionedDAE", "NonholonomicSystem", "MechanicalSystem", "consistent_lambda",
        "hidden_constraint", "project_momenta", "validate_initial_values", "spd_solve",
    ],
    "methods": [
        "LobattoIIIAIIIB", "StepInfo", "StepperState", "LobattoPair", "lobatto_pair",
        "lobatto_iiia", "lobatto_iiib", "lobatto_nodes", "lobatto_weights", "check_tableau",
        "TableauReport",
    ],
    "pure": ["integrate", "IntegrateResult", "integrate_adaptive", "AdaptiveResult"],
    "ensembles": ["ensemble", "EnsembleResult", "EnsembleFiles", "load_ensemble"],
    "diagnostics": [
        "constraint_residual", "energy_error", "invariant_values", "invariant_error",
        "convergence_study", "ConvergenceStudy", "observed_order",
    ],
    "plots": ["plot", "animate", "plot_solution", "plot_diagnostics", "plot_convergence"],
    "performance": ["set_cpu_threads", "enable_compilation_cache", "compiler_options"],
    "errors": [
        "LobattoDAEInputError", "ShapeError", "ProblemDefinitionError", "ProblemFunctionError",
        "InconsistentInitialValuesError", "SingularConstraintError", "CheckpointError",
        "CheckpointWriteError", "EnsembleFileError", "SolverError", "NewtonFailure",
    ],
}

_API_MARK = re.compile(r"^<!-- api: (\w+) -->$", re.M)
_LINK = re.compile(r"(!?\[(?P<text>[^\]]*)\])\((?P<target>[^)\s]+)\)")
_FENCE = re.compile(r"^\s*(```|~~~)")


def exported_names(module_file: Path = ROOT / "src" / "lobattodae" / "__init__.py") -> list[str]:
    """``__all__`` of a module, read from its source (the site builds without importing JAX)."""
    for node in ast.parse(module_file.read_text(encoding="utf-8")).body:
        if isinstance(node, ast.Assign) and any(getattr(t, "id", None) == "__all__" for t in node.targets):
            return list(ast.literal_eval(node.value))
    raise ValueError(f"no __all__ in {module_file}")


def api_block(section: str, exported: list[str]) -> str:
    """The ``:::`` directives of one section of the API page."""
    if section == "other":
        listed = {n for names in API_SECTIONS.values() for n in names}
        names = sorted(n for n in exported if n not in listed)
    elif section in API_SECTIONS:
        names = [n for n in API_SECTIONS[section] if n in exported]
    else:
        raise ValueError(f"unknown API section {section!r} (known: {sorted(API_SECTIONS)}, other)")
    if not names:
        return "*(none)*"
    return "\n\n".join(f"::: lobattodae.{n}" for n in names)


# ---------------------------------------------------------------------------- mirrored files


def _mirrored() -> dict[str, str]:
    """Repository path -> site path of every mirrored file."""
    out = {}
    for pattern, site in MIRRORS:
        for path in sorted(ROOT.glob(pattern)):
            rel = path.relative_to(ROOT).as_posix()
            out[rel] = site or rel
    return out


def on_files(files: Files, config) -> Files:
    for repo_path, site_path in _mirrored().items():
        # a new benchmarks/results/*.md note is on the site without having to be in the nav
        inclusion = InclusionLevel.NOT_IN_NAV if repo_path.startswith("benchmarks/results/") else InclusionLevel.UNDEFINED
        files.append(File.generated(config, site_path, abs_src_path=str(ROOT / repo_path), inclusion=inclusion))
    return files


# ------------------------------------------------------------------------------------ links


def _repo_path_of_page(src_uri: str) -> str:
    """Where the page's Markdown lives in the repository."""
    for repo_path, site_path in _mirrored().items():
        if site_path == src_uri:
            return repo_path
    return f"docs/{src_uri}"


def _site_path(repo_path: str) -> str | None:
    """The file's path on the site (relative to docs/), or None if it is not on the site."""
    mirrored = _mirrored()
    if repo_path in mirrored:
        return mirrored[repo_path]
    if repo_path.startswith("docs/") and (ROOT / repo_path).exists():
        return repo_path[len("docs/"):]
    return None


def rewrite_links(markdown: str, page_uri: str) -> str:
    """Relative links resolved against the page's repository path (see the module docstring)."""
    page_repo = _repo_path_of_page(page_uri)
    page_dir = posixpath.dirname(page_uri)

    def fix(match: re.Match) -> str:
        target = match.group("target")
        if re.match(r"^[a-z][a-z0-9+.-]*:", target) or target.startswith(("#", "/")):
            return match.group(0)
        path, _, anchor = target.partition("#")
        repo = posixpath.normpath(posixpath.join(posixpath.dirname(page_repo), path))
        site = _site_path(repo)
        if site is None and (ROOT / repo).is_dir() and _site_path(repo + "/README.md"):
            site = posixpath.dirname(_site_path(repo + "/README.md")) + "/"
        if site is not None:
            new = posixpath.relpath(site, page_dir or ".") + ("/" if site.endswith("/") else "")
            return f"{match.group(1)}({new}{'#' + anchor if anchor else ''})"
        # a repository file that is not on the site: name it
        text = match.group("text")
        shown = repo.rstrip("/") + ("/" if (ROOT / repo).is_dir() else "")
        if shown.strip("/").split("/")[-1] in text or text.strip("`") == shown:
            return text
        return f"{text} (`{shown}`)"

    out, in_fence = [], False
    for line in markdown.splitlines(keepends=True):
        if _FENCE.match(line):
            in_fence = not in_fence
        out.append(line if in_fence else _LINK.sub(fix, line))
    return "".join(out)


def on_page_markdown(markdown: str, page, config, files) -> str:
    if _API_MARK.search(markdown):
        exported = exported_names()
        markdown = _API_MARK.sub(lambda m: api_block(m.group(1), exported), markdown)
    return rewrite_links(markdown, page.file.src_uri)
