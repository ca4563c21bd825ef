"""Command-line interface ``lobattodae``: parses, calls the library, writes files, returns an exit code."""

from __future__ import annotations

import argparse
import os
import re
import signal
import sys
import threading
import time
import warnings
from contextlib import contextmanager
from pathlib import Path
from typing import Sequence

import numpy as np

from ._cache import cache_switched_off, enable_compilation_cache
from ._cli_model import MODEL_HELP, from_example, load_model
from ._cli_model import UsageError as _UsageError
from ._controllers import ATOL, RTOL
from ._cpu import one_thread_unless_set

__all__ = ["main"]

DEMO_EXAMPLE = "sleigh"

#: ``run --lam-start``: the start multiplier Λ_1 of each step (``LobattoIIIAIIIB(lam_start=...)``).
LAM_START_CHOICES = ("auto", "previous", "consistent")
LAM_START_HELP = (
    "start multiplier Λ_1 of each step:\n"
    "auto: paper's scheme, λ re-synced on drift (default)\n"
    "previous: paper's scheme; symmetric, λ errors can grow\n"
    "consistent: Λ_1 from hidden constraint; energy drifts"
)

#: Exit code after Ctrl-C or SIGTERM outside the integration loop (128 + SIGINT, as shells do).
EXIT_INTERRUPTED = 130
EXIT_BROKEN_PIPE = 141  # 128 + SIGPIPE


class _HelpFormatter(argparse.HelpFormatter):
    """argparse's formatter, but a help text's own line breaks are kept (each line wrapped)."""

    def _split_lines(self, text, width):
        lines = []
        for line in text.splitlines():
            lines.extend(super()._split_lines(line, width) or [""])
        return lines


class _ArgumentParser(argparse.ArgumentParser):
    """argparse that raises instead of exiting, so ``main`` can return the exit code."""

    def __init__(self, *args, **kwargs):
        kwargs.setdefault("formatter_class", _HelpFormatter)
        super().__init__(*args, **kwargs)

    def error(self, message):
        raise _UsageError(f"{self.prog}: error: {message}")




#: Steps between checkpoints of ``lobattodae run --checkpoint FILE`` without ``--checkpoint-every``.
CHECKPOINT_EVERY = 100_000

def _positive_int(text: str) -> int:
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {text!r}") from None
    if v <= 0:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {v}")
    return v


#: ``--stages`` above this compile for long: warned about (the tableau command does not compile).
#: Measured with ``lobattodae run`` (adaptive, LOBATTODAE_NO_CACHE=1) on 2 loaded CPU cores: knife
#: edge s = 3, 6, 8, 10, 16, 24: 4.9, 5.2, 7.1, 8.4, 8.5, 18.9 s; sleigh s = 24, 32, 48, 64: 23, 82,
#: 157, 219 s; s = 100: 574 s (issue #30).
MANY_STAGES = 16


def _stage_count(text: str) -> int:
    v = _positive_int(text)
    if v < 2:
        raise argparse.ArgumentTypeError(f"the number of stages must be >= 2 (Lobatto needs both end points), got {v}")
    return v


def _stages(text: str) -> int:
    """A number of stages for a command that compiles the step loop: a warning on stderr when
    compiling it will take long."""
    v = _stage_count(text)
    if v > MANY_STAGES:
        sys.stderr.write(
            f"lobattodae: warning: --stages {v}: compiling the step loop takes longer the more stages, and fast "
            f"beyond s = {MANY_STAGES} (measured on 2 CPU cores: under 10 s up to s = 16, about 20 s at s = 24, "
            "80 s at s = 32, 3-4 minutes at s = 48-64, nearly 10 minutes at s = 100); nothing is printed "
            "meanwhile.\n"
        )
    return v


def _positive_float(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a positive number, got {text!r}") from None
    if not (np.isfinite(v) and v > 0):
        raise argparse.ArgumentTypeError(f"expected a positive finite number, got {text}")
    return v


def _real(text: str) -> float:
    """A number on the command line, parsed only: whether it is a valid option value is decided by
    the library's own rules (:mod:`lobattodae._options`), with the library's message."""
    try:
        return float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None


def _integer(text: str) -> int:
    """An integer on the command line, parsed only (see :func:`_real`)."""
    try:
        return int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None


def _example_name(text: str) -> str:
    from .examples import EXAMPLES

    if text not in EXAMPLES:
        raise argparse.ArgumentTypeError(f"unknown example {text!r}; choose from: {', '.join(EXAMPLES)}")
    return text


def _suffix(path: str, allowed: Sequence[str], what: str) -> Path:
    p = Path(path)
    if p.suffix.lower() not in allowed:
        raise _UsageError(f"{what} must end in {' or '.join(allowed)}; got {path!r}")
    return p


def _output_file(path: str | None, allowed: Sequence[str], option: str) -> Path | None:
    """An output file of a command, checked before any work: its suffix, and that its
    directory exists and is writable (the library's own check, :func:`~lobattodae._options.check_writable`)."""
    if path is None:
        return None
    p = _suffix(path, allowed, option)
    from ._errors import LobattoDAEInputError
    from ._options import check_writable

    try:
        check_writable(str(p), f"{option} file")
    except LobattoDAEInputError as exc:
        raise _UsageError(str(exc)) from None
    return p


def build_parser() -> argparse.ArgumentParser:
    parser = _ArgumentParser(
        prog="lobattodae",
        description="Lobatto IIIA-IIIB integrators for partitioned index-2 DAEs and nonholonomic systems.",
        epilog="demo, convergence and run keep compiled step loops in a persistent cache "
        "($LOBATTODAE_CACHE_DIR, default ~/.cache/lobattodae), so a second invocation skips XLA "
        "compilation; set LOBATTODAE_NO_CACHE=1 to switch it off.",
    )
    sub = parser.add_subparsers(dest="command", required=True, parser_class=_ArgumentParser)

    p = sub.add_parser("demo", help="reproduce the paper's Corollary: orders of q, p, λ for s = 2..5")
    p.add_argument("--example", type=_example_name, default=DEMO_EXAMPLE)
    p.add_argument("--stages", type=_stages, nargs="+", default=[2, 3, 4, 5])
    p.add_argument("--plot", default="convergence.png", help="PNG file for the convergence plot")

    p = sub.add_parser("tableau", help="print the Lobatto IIIA-IIIB coefficients for s stages")
    p.add_argument("s", type=_stage_count)
    p.add_argument("--check", action="store_true", help="also check simplifying assumptions and hypotheses")

    p = sub.add_parser("convergence", help="convergence study on an example with a closed-form solution")
    p.add_argument("--example", type=_example_name, required=True)
    p.add_argument("--stages", type=_stages, nargs="+", default=[2, 3, 4, 5])
    p.add_argument("--n-steps", type=_positive_int, nargs="+", default=None, help="step counts (default: per s)")
    p.add_argument("--plot", default=None, help="PNG file for the convergence plot")
    p.add_argument("--json", default=None, help="JSON file for the errors and orders")

    p = sub.add_parser("run", help="integrate an example or your own model and report constraint and invariants")
    what = p.add_mutually_exclusive_group(required=True)
    what.add_argument("--example", type=_example_name, help="a built-in example (lobattodae examples lists them)")
    what.add_argument("--model", metavar="MODULE:FACTORY", help=MODEL_HELP)
    p.add_argument("--stages", type=_stages, default=3)
    step = p.add_mutually_exclusive_group(required=False)
    step.add_argument("--dt", type=_real, help="constant steps of at most this size")
    step.add_argument("--n-steps", type=_integer, help="this many constant steps")
    p.add_argument("--rtol", type=_real, default=None,
                   help=f"adaptive steps (the default without --dt/--n-steps): relative tolerance ({RTOL:g})")
    p.add_argument("--atol", type=_real, default=None, help=f"adaptive steps: absolute tolerance ({ATOL:g})")
    p.add_argument("--t-eval", type=float, nargs="+", default=None, help="output times (adaptive steps end on them; constant steps interpolate)")
    p.add_argument("--save-every", type=_integer, default=None, help="keep every k-th step point")
    p.add_argument("--t1", type=_positive_float, default=None,
                   help="final time (default: the example's, or the t_span of --model's factory)")
    p.add_argument("--plot", default=None,
                   help="PNG file: solution, constraints, invariants, step sizes, Newton iterations (lobattodae.plot)")
    p.add_argument("--animate", default=None, metavar="FILE",
                   help="trajectory animation, FILE.gif (or FILE.mp4 with ffmpeg) (lobattodae.animate)")
    p.add_argument("--frames", type=_positive_int, default=None,
                   help="frames of --animate (default 100; 20 per second)")
    p.add_argument("--save", default=None, help="write the solution to F.npz or F.csv")
    p.add_argument("--no-progress", action="store_true",
                   help="never show a progress bar (by default one appears when a run takes more than a second)")
    p.add_argument("--lam-start", choices=LAM_START_CHOICES, default="auto", help=LAM_START_HELP)
    p.add_argument("--checkpoint", default=None,
                   help="checkpoint file (.npz; its rows go to FILE.rows/, appended at each save): written "
                        "periodically and on Ctrl-C/SIGTERM")
    p.add_argument("--checkpoint-every", type=_positive_int, default=None,
                   help=f"steps between checkpoints (with --checkpoint; default {CHECKPOINT_EVERY:,})")
    p.add_argument("--resume", action="store_true", help="continue from --checkpoint if it exists")
    p.add_argument("--max-recoveries", type=int, default=0, help="retry failed steps as substeps up to this many times")

    sub.add_parser("examples", help="list the example problems")
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point; returns the exit code (0 success, 1 failure or a run stopped early,
    2 usage error, 130 interrupted before or after the integration, 141 output pipe closed).

    SIGTERM is handled as Ctrl-C: during an integration both stop it cleanly at the end of
    the current compiled chunk (checkpoint written, prefix reported, exit code 1); elsewhere
    (start-up, compilation, writing files) the program stops with one line and exit code 130.
    """
    with _sigterm_as_sigint():
        try:
            return _main(argv)
        except KeyboardInterrupt:
            print("lobattodae: interrupted", file=sys.stderr)
            return EXIT_INTERRUPTED
        except BrokenPipeError:
            # the reader of our output went away (``lobattodae run ... | head``): stop quietly,
            # with the shell's code for SIGPIPE, and keep Python's exit flush off the closed pipe
            os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
            return EXIT_BROKEN_PIPE


def _main(argv: Sequence[str] | None) -> int:
    parser = build_parser()
    try:
        ns = parser.parse_args(list(sys.argv[1:] if argv is None else argv))
    except _UsageError as exc:
        print(exc, file=sys.stderr)
        return 2
    except SystemExit as exc:  # --help
        return int(exc.code or 0)
    try:
        if ns.command in _COMPILING_COMMANDS:
            if not cache_switched_off():
                enable_compilation_cache()
            one_thread_unless_set()  # fastest for these small systems (lobattodae._cpu)
        return _COMMANDS[ns.command](ns)
    except _UsageError as exc:
        print(f"lobattodae: error: {exc}", file=sys.stderr)
        return 2
    except (ValueError, RuntimeError) as exc:
        print(f"lobattodae: {type(exc).__name__}: {exc}", file=sys.stderr)
        return 1


def _sigterm_handler(signum, frame):
    """SIGTERM does what Ctrl-C does at this moment: it calls the SIGINT handler installed now
    (inside ``solve``, the deferred one: a clean stop at the end of the chunk); with Python's
    default handler (or none) it raises KeyboardInterrupt."""
    handler = signal.getsignal(signal.SIGINT)
    if callable(handler) and handler is not signal.default_int_handler:
        handler(signum, frame)
    else:  # SIG_DFL, SIG_IGN (SIGTERM must still stop the program), None, default_int_handler
        raise KeyboardInterrupt


@contextmanager
def _sigterm_as_sigint():
    """Install :func:`_sigterm_handler` for the duration of ``main`` (main thread only)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.signal(signal.SIGTERM, _sigterm_handler)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


def _cmd_examples(ns) -> int:
    from .examples import list_examples

    for name, desc in list_examples():
        print(f"{name:24s} {desc}")
    return 0


def _cmd_tableau(ns) -> int:
    from ._tableau_report import check_tableau
    from ._tableau import lobatto_pair

    pair = lobatto_pair(ns.s)
    with np.printoptions(precision=17, linewidth=160, suppress=False):
        print(f"Lobatto IIIA-IIIB, s = {pair.s}")
        print("c =", pair.c)
        print("b =", pair.b)
        print("A (IIIA) =\n", pair.a, sep="")
        print("A_hat (IIIB) =\n", pair.a_hat, sep="")
    if ns.check:
        print()
        print(check_tableau(pair))
    return 0


def _study(example_name, stages, n_steps):
    from ._convergence import convergence_study
    from .examples import get_example

    ex = get_example(example_name)
    if ex.exact is None:
        print(f"note: {example_name} has no closed form; errors are measured against a reference solution")
    return convergence_study(ex, stages=stages, n_steps=n_steps)


def _save_plot(axes_fn, path: Path) -> None:
    _save_figure(axes_fn()[0].figure, path)


def _save_figure(fig, path: Path) -> None:
    fig.savefig(path, dpi=120)
    import matplotlib.pyplot as plt

    plt.close(fig)
    print(f"wrote {path}")


def _cmd_convergence(ns) -> int:
    from ._plotting import plot_convergence

    plot = _output_file(ns.plot, [".png"], "--plot")
    js = _output_file(ns.json, [".json"], "--json")
    start = time.perf_counter()
    study = _study(ns.example, ns.stages, ns.n_steps)
    print(study.table(more="give more --n-steps"))
    print(f"({time.perf_counter() - start:.1f} s including compilation)")
    if js:
        study.to_json(js)
        print(f"wrote {js}")
    if plot:
        _save_plot(lambda: plot_convergence(study), plot)
    return 0


def _cmd_demo(ns) -> int:
    from ._plotting import plot_convergence

    plot = _output_file(ns.plot, [".png"], "--plot")
    print("lobattodae demo: the Lobatto IIIA-IIIB pair on a nonlinear nonholonomic problem")
    print("Theory (paper, Corollary): q, p ~ h^(2s-2); λ ~ h^s (s even), h^(s-1) (s odd)\n")
    start = time.perf_counter()
    study = _study(ns.example, ns.stages, None)
    print(study.table(more="give more --n-steps"))
    worst = max(study.constraint_residual.values())
    print(f"\nmax constraint residual ‖φ(q_k, p_k)‖∞ over all runs: {worst:.1e}")
    print(f"({time.perf_counter() - start:.1f} s including compilation)")
    _save_plot(lambda: plot_convergence(study), plot)
    return 0


def _cmd_run(ns) -> int:
    from ._diagnostics import invariant_error
    from ._errors import LobattoDAEInputError
    from ._results import Result
    from ._solve import solve
    from ._stepper import LobattoIIIAIIIB
    from .examples import get_example

    # every option and output path is checked before the work
    plot = _output_file(ns.plot, [".png"], "--plot")
    movie = _output_file(ns.animate, [".gif", ".mp4"], "--animate")
    if movie is not None and movie.suffix.lower() == ".mp4":
        from matplotlib import animation

        if not animation.writers.is_available("ffmpeg"):
            raise _UsageError(f"--animate {movie}: writing MP4 needs ffmpeg on the PATH, and it was not found; "
                              "write a .gif instead (Pillow, installed with matplotlib)")
    if ns.frames is not None and movie is None:
        raise _UsageError("--frames needs --animate FILE (it sets the number of frames of that animation)")
    if ns.frames is not None and ns.frames < 2:
        raise _UsageError(f"--frames must be >= 2; got {ns.frames}")
    save = _output_file(ns.save, [".npz", ".csv"], "--save")
    checkpoint = _output_file(ns.checkpoint, [".npz"], "--checkpoint")
    if ns.resume and checkpoint is None:
        raise _UsageError("--resume needs --checkpoint FILE")
    if ns.checkpoint_every is not None and not ns.checkpoint:
        raise _UsageError("--checkpoint-every needs --checkpoint FILE (it sets how often that file is written)")
    if ns.max_recoveries < 0:
        raise _UsageError(f"--max-recoveries must be >= 0; got {ns.max_recoveries}")
    ex = from_example(get_example(ns.example)) if ns.example else load_model(ns.model)
    if ex.t_span is None and ns.t1 is None:
        raise _UsageError(f"--model {ns.model}: the factory gives no t_span; pass --t1 (the final time; t0 = 0) "
                          "or have the factory return a dict with t_span=(t0, t1)")
    t0 = ex.t_span[0] if ex.t_span is not None else 0.0
    t1 = ns.t1 if ns.t1 is not None else ex.t_span[1]
    if not t1 > t0:
        raise _UsageError(f"--t1 must be larger than the initial time {t0}; got {t1}")
    with warnings.catch_warnings(record=True) as caught:  # reported below, in the command line's words
        try:
            sol = solve(
                ex.problem, LobattoIIIAIIIB(stages=ns.stages, lam_start=ns.lam_start), (t0, t1), ex.q0, ex.p0,
                n_steps=ns.n_steps, dt=ns.dt, rtol=ns.rtol, atol=ns.atol, t_eval=ns.t_eval, save_every=ns.save_every,
                lam0=ex.lam0, args=ex.args, throw=False,
                progress=not ns.no_progress, max_recoveries=ns.max_recoveries,
                checkpoint=checkpoint, checkpoint_every=(ns.checkpoint_every or CHECKPOINT_EVERY) if checkpoint else None,
                resume=ns.resume,
            )
        except LobattoDAEInputError as exc:
            if type(exc) is not LobattoDAEInputError:  # the problem or the checkpoint, not an option
                raise
            raise _UsageError(str(exc)) from None  # the library's rules and message for the options
    message, lam_warning = _split_warning(sol.message)
    print(message)
    if sol.stats["h"] is not None:  # constant steps: how many of how many
        total = round(abs(t1 - t0) / abs(sol.stats["h"]))
        steps = f"{sol.stats['n_steps']} of {total}, h = {sol.stats['h']:.6g}"
    else:
        steps = f"{sol.stats['n_steps']} ({sol.stats['n_rejected']} rejected), {len(sol.t)} output rows"
    print(f"steps: {steps}, time {sol.stats['compile_and_run_time']:.2f} s (including compilation)")
    print(f"max ‖φ(q_k, p_k)‖∞ = {sol.stats['max_constraint_residual']:.2e}")
    if ns.t_eval:
        print(f"max ‖φ‖∞ at the --t-eval rows (dense output, between steps) = {np.max(sol.stats['constraint_residual']):.2e}")
    _print_lam_bookkeeping(sol, ns.lam_start, lam_warning)
    if sol.stats["recoveries"]:
        print(f"recovered steps (retried as substeps): {sol.stats['recoveries']}")
    if checkpoint:
        more = " (continue with the same command and --resume)" if sol.result == Result.INTERRUPTED else ""
        print(f"checkpoint: {checkpoint}{more}")
    print(f"Newton iterations per step: mean {np.mean(sol.stats['newton_iterations']) if len(sol.t) > 1 else 0:.2f}")
    for name, fn in ex.invariants.items():
        err = invariant_error(sol, fn)
        print(f"max |{name}(t) - {name}(0)| = {np.max(np.abs(err)):.2e}")
    for w in caught:  # other warnings of the run (the λ one is part of the message, printed above)
        if str(w.message) not in sol.message:
            print(f"lobattodae: warning: {w.message}", file=sys.stderr)
    if save:
        _save_solution(sol, save)
        print(f"wrote {save}")
    if plot:
        from ._plotting import plot as plot_run

        labels = ex.labels if ex.labels is not None and len(ex.labels) == sol.q.shape[1] else None
        fig, _ = plot_run(sol, name=ex.name, invariants=dict(ex.invariants), labels=labels,
                          rtol=_tolerance(sol, ns.rtol, RTOL), atol=_tolerance(sol, ns.atol, ATOL))
        _save_figure(fig, plot)
    if movie:
        from ._animation import FRAMES, animate

        if len(sol.t) < 2:
            print(f"lobattodae: warning: no step was taken; {movie} not written", file=sys.stderr)
        else:
            animate(sol, movie, draw=ex.draw, frames=ns.frames or FRAMES)
            print(f"wrote {movie}")
    return 0 if sol.success else 1


def _tolerance(sol, given, default):
    """The tolerance an adaptive run used (for the plot's title), None for constant steps."""
    return None if sol.stats["h"] is not None else (given if given is not None else default)


#: ``Solution.message`` appends a warning to the status message after this marker.
_WARNING_MARKER = " Warning: "


def _split_warning(message: str) -> tuple[str, str | None]:
    """``(status message, warning)`` of a ``Solution.message`` (warning None when there is none)."""
    head, sep, tail = message.partition(_WARNING_MARKER)
    return (head, tail) if sep else (message, None)


def _cli_spelling(text: str) -> str:
    """A library message in the command line's words: ``lam_start='auto'`` -> ``--lam-start auto``."""
    return re.sub(r"lam_start\s*=\s*['\"](\w+)['\"]", r"--lam-start \1", text)


def _print_lam_bookkeeping(sol, lam_start: str, warning: str | None) -> None:
    """λ after a run: re-synchronisations (auto), excursions (previous), the drift warning."""
    stats = sol.stats
    drift = np.max(stats["multiplier_drift"]) if len(stats["multiplier_drift"]) else 0.0
    if lam_start == "auto":
        print(f"λ re-synchronisations (--lam-start auto): {stats['lam_resets']} in {len(sol.t) - 1} steps; "
              f"max ‖λ_k − λ(q_k, p_k)‖∞ = {drift:.2e}")
    elif lam_start == "previous":
        print(f"λ excursions out of the drift band (--lam-start previous): {stats['lam_excursions']}; "
              f"max ‖λ_k − λ(q_k, p_k)‖∞ = {drift:.2e}")
    if warning is None:
        return
    if "λ" in warning or "lam_start" in warning or "multiplier" in warning:
        # the library recommends its Python option; say it with the command line's
        text = warning.split(" Use lam_start", 1)[0].strip()
        print(f"warning: {_cli_spelling(text)}")
        print("recommendation: run again with --lam-start auto (re-synchronises λ with the hidden constraint "
              "when it drifts), or --lam-start consistent, or a smaller step (--dt / --n-steps)")
    else:
        print(f"warning: {_cli_spelling(warning)}")


def _save_solution(sol, path: Path) -> None:
    if path.suffix.lower() == ".npz":
        np.savez(
            path, t=sol.t, q=sol.q, p=sol.p, lam=sol.lam, status=int(sol.result),
            message=sol.message, h=np.nan if sol.stats["h"] is None else sol.stats["h"],
            constraint_residual=sol.stats["constraint_residual"],
            newton_iterations=sol.stats["newton_iterations"],
        )
    else:
        n, m = sol.q.shape[1], sol.lam.shape[1]
        header = ["t"] + [f"q{i}" for i in range(n)] + [f"p{i}" for i in range(n)] + [f"lam{i}" for i in range(m)]
        data = np.column_stack([sol.t, sol.q, sol.p, sol.lam])
        np.savetxt(path, data, delimiter=",", header=",".join(header), comments="", fmt="%.17g")


#: Commands that compile step loops use the persistent compilation cache (see
#: :func:`lobattodae.enable_compilation_cache`) unless LOBATTODAE_NO_CACHE=1, and a one-thread
#: CPU pool (:func:`lobattodae.set_cpu_threads`) unless PJRT_NPROC or NPROC is set.
_COMPILING_COMMANDS = frozenset({"demo", "convergence", "run"})

_COMMANDS = {
    "demo": _cmd_demo,
    "tableau": _cmd_tableau,
    "convergence": _cmd_convergence,
    "run": _cmd_run,
    "examples": _cmd_examples,
}


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
