#!/usr/bin/env python
"""Regenerate ``docs/verification.md``, its data and its figures from the repository.

    python scripts/make_verification.py            # full report -> docs/ (several minutes)
    python scripts/make_verification.py --quick    # smoke run -> a temporary directory
    python scripts/make_verification.py --out DIR  # verification.md, its data, figures/ -> DIR
    python scripts/make_verification.py --render-only docs/verification-data.json  # no runs

The runs (``verification_report.runs``: convergence studies of every closed-form example,
the special cases, long runs of the contact oscillators, the three λ modes on both classes)
write every number the report shows, with the constants of the library its prose needs, to
``verification-data.json``, and draw the figures. The page is rendered from that file alone
(``verification_report.render`` and its template), so ``--render-only`` re-renders it without
running anything.
"""

from __future__ import annotations

import argparse
import contextlib
import datetime
import json
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT / "src"), str(ROOT / "scripts")]  # this checkout's library and report

import lobattodae  # noqa: E402
from lobattodae._convergence import PLATEAU_REL  # noqa: E402
from lobattodae._stepper import LAM_START_MODES  # noqa: E402
from lobattodae.examples import get_example, list_examples  # noqa: E402
from verification_report import figures, runs  # noqa: E402
from verification_report.render import render  # noqa: E402

DATA = "verification-data.json"
PAGE = "verification.md"


def log(msg: str) -> None:
    print(msg, file=sys.stderr, flush=True)


@contextlib.contextmanager
def timed(times: dict, name: str):
    """Records the wall time of the block in ``times[name]``."""
    t0 = time.perf_counter()
    yield
    times[name] = time.perf_counter() - t0


def convergence_studies(names, cfg, figures_dir):
    """The studies that ran, and the error messages of those that failed."""
    studies, failed = {}, {}
    for name in names:
        log(f"convergence study: {name} (s = {cfg['stages']}) ...")
        try:
            record, study = runs.convergence(get_example(name), cfg)
        except lobattodae.SolverError as exc:  # reported, not fatal
            failed[name] = str(exc)
            log(f"  FAILED: {exc}")
            continue
        studies[name] = record
        log(study.table())
        log(f"  {record['wall']:.1f} s; with lam_start='auto': {record['auto']['identical']}/"
            f"{record['auto']['runs']} runs identical ({record['auto']['wall']:.1f} s)")
        figures.convergence(study, figures_dir / f"convergence-{name}.png")
    return studies, failed


def special_cases(cfg, studies):
    """The runs behind §2 (None where the study they explain did not run)."""
    log("special cases ...")
    particle = "particle" in studies and 5 in cfg["stages"]
    return {
        "knife_edge": runs.knife_edge_lambda(cfg) if "knife-edge" in studies and 2 in cfg["stages"] else None,
        "vertical_disk": runs.vertical_disk_components(cfg) if "vertical-disk" in studies else None,
        # the particle's s = 5 p order with the library's default floor, beside the report's
        "particle_default_floor": (runs.order_with_floor(studies["particle"], 5, "p", PLATEAU_REL["p"])
                                   if particle else None),
    }


def long_run(name, n_steps, N, **options):
    log(f"long run: {name}, h = 2 sin(pi/{N}), {n_steps} steps, {options or 'default options'} ...")
    record, series = runs.long_run(name, n_steps, N, **options)
    log(f"  {record['wall']:.1f} s; max|dH| first/last 10%: {record['first10']:.2e} / {record['last10']:.2e}; "
        f"resets {record['lam_resets']}, excursions {record['lam_excursions']}")
    return record, series


def long_runs(cfg, default_mode, figures_dir):
    """The long runs with the library's default lam_start, and with the other modes."""
    default = [long_run(name, cfg["long_steps"], N) for name in runs.LONG_EXAMPLES for N in runs.LONG_N]
    figures.long_runs(default, figures_dir / "long-runs-contact.png")
    variants = [long_run(name, cfg["long_steps"], N, lam_start=mode)
                for mode in LAM_START_MODES if mode != default_mode
                for name in runs.LONG_EXAMPLES for N in runs.LONG_N]
    figures.variants(default + variants, default_mode, figures_dir / "long-runs-lam-start.png")
    return [r for r, _ in default], [r for r, _ in variants]


def lam_modes(cfg, default_mode, figures_dir):
    """The measure of success of the λ-mode decision (DESIGN.md, "The λ mode"): the three
    modes on the reversible contact oscillator (energy) and on the sleigh (q error)."""
    contact = [long_run("contact", cfg["lam_contact_steps"], runs.LAM_N, lam_start=mode)
               for mode in LAM_START_MODES]
    sleigh = []
    for s, h, T in cfg["sleigh_runs"]:
        for mode in LAM_START_MODES:
            log(f"lambda mode: sleigh, s = {s}, h = {h}, T = {T}, lam_start={mode!r} ...")
            sleigh.append(runs.sleigh_run(s, h, T, mode))
            log(f"  {sleigh[-1][0]['wall']:.1f} s; q error at T {sleigh[-1][0]['q_err_T']:.2e}; "
                f"resets {sleigh[-1][0]['lam_resets']}")
    figures.lam_modes(sleigh, contact, default_mode, figures_dir / "lam-modes.png")
    return {"contact": [r for r, _ in contact], "sleigh": [r for r, _ in sleigh]}


def compute(cfg, quick, names, figures_dir) -> dict:
    """Run everything, draw the figures, and return the report's data (JSON-ready)."""
    times = {}
    library = runs.library_constants(cfg)
    with timed(times, "total"):
        with timed(times, "studies"):
            studies, failed = convergence_studies(names, cfg, figures_dir)
        with timed(times, "specials"):
            special = special_cases(cfg, studies)
        with timed(times, "long"):
            default_runs, variant_runs = long_runs(cfg, library["default_lam_start"], figures_dir)
        with timed(times, "lam_modes"):
            modes = lam_modes(cfg, library["default_lam_start"], figures_dir)
    return runs.plain({
        "generated": datetime.datetime.now(datetime.UTC).strftime("%Y-%m-%d %H:%M"),
        "quick": quick,
        "machine": runs.machine(ROOT),
        "timings": times,
        "library": library,
        "settings": runs.settings(cfg),
        "studies": studies,
        "failed_studies": failed,
        **special,
        "long_runs": default_runs,
        "variant_runs": variant_runs,
        "lam_modes": modes,
    })


def write_page(out: Path, data: dict) -> Path:
    page = out / PAGE
    page.write_text(render(data))
    return page


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true",
                    help="smoke run: s = 2, 3, few step counts, short long runs; writes to a "
                         "temporary directory unless --out is given")
    ap.add_argument("--out", type=Path, default=None,
                    help=f"output directory for {PAGE}, {DATA} and figures/ (default: docs/, or a "
                         f"temporary directory with --quick; with --render-only: the data file's directory)")
    ap.add_argument("--examples", nargs="*", default=None,
                    help="restrict the convergence studies to these examples (debugging)")
    ap.add_argument("--render-only", type=Path, default=None, metavar="JSON",
                    help=f"render {PAGE} from this data file alone (no runs; the figures are not redrawn)")
    opts = ap.parse_args(argv)
    if opts.render_only is not None:
        if opts.quick or opts.examples is not None:
            ap.error("--render-only renders the data file as it is: it takes no --quick or --examples")
        page = write_page(opts.out or opts.render_only.parent, json.loads(opts.render_only.read_text()))
        print(page)
        return 0
    cfg = runs.QUICK if opts.quick else runs.FULL
    out = opts.out or (Path(tempfile.mkdtemp(prefix="lobattodae-verification-")) if opts.quick else ROOT / "docs")
    (out / "figures").mkdir(parents=True, exist_ok=True)
    names = [n for n, _ in list_examples() if get_example(n).has_exact]
    if opts.examples:
        unknown = set(opts.examples) - set(names)
        if unknown:
            ap.error(f"not closed-form examples: {sorted(unknown)}; choose from {names}")
        names = [n for n in names if n in opts.examples]
    elif "examples" in cfg:
        names = [n for n in names if n in cfg["examples"]]
    data = compute(cfg, opts.quick, names, out / "figures")
    (out / DATA).write_text(json.dumps(data, indent=1, ensure_ascii=False, allow_nan=False) + "\n")
    page = write_page(out, data)
    log(f"wrote {page} ({data['timings']['total']:.0f} s)")
    print(page)
    return 0


if __name__ == "__main__":
    sys.exit(main())
