"""The command-line options the scripts share, and the process setup they ask for.

``parser(doc, ...)`` adds the options a script names; ``start(args)`` then applies them in the
order they need: the CPU affinity and XLA's thread pool before the first JAX computation (the
threads XLA starts inherit both), the watchdog last.
"""

from __future__ import annotations

import argparse
import faulthandler

import lobattodae

from .timing import pin_cpu

#: The options :func:`parser` can add: (flags, keyword arguments of ``add_argument``).
OPTIONS = {
    "quick": (("--quick",), dict(action="store_true", help="the reduced run (about a minute)")),
    "replot": (("--replot",), dict(action="store_true", help="redraw the figures and tables from the saved JSON")),
    "pin_cpu": (("--pin-cpu",), dict(type=int, default=None, metavar="CPU",
                                     help="run the whole process on this one CPU (before JAX starts its threads)")),
    "cpu_threads": (("--cpu-threads",), dict(type=int, default=None, metavar="N",
                                             help="size of XLA's CPU thread pool for every solver of the process "
                                                  "(lobattodae.set_cpu_threads; default: XLA's)")),
    "watchdog": (("--watchdog",), dict(type=float, default=1800.0, metavar="SECONDS",
                                       help="print every thread's traceback and exit after this long (0: off)")),
}


def parser(doc: str, *options: str, **changes: dict) -> argparse.ArgumentParser:
    """An argument parser whose description is the first line of ``doc``, with the shared
    ``options`` (names of :data:`OPTIONS`); ``changes`` replace keyword arguments of an
    option's ``add_argument`` (``watchdog={"default": 3600.0}``, ``quick={"help": ...}``)."""
    ap = argparse.ArgumentParser(description=doc.strip().splitlines()[0])
    for name in options:
        flags, kw = OPTIONS[name]
        ap.add_argument(*flags, **{**kw, **changes.get(name, {})})
    return ap


def start(args: argparse.Namespace) -> argparse.Namespace:
    """Applies the shared options ``args`` carries (those its parser was given)."""
    args.cpus = pin_cpu(getattr(args, "pin_cpu", None))
    if getattr(args, "cpu_threads", None) is not None:
        lobattodae.set_cpu_threads(args.cpu_threads)
    if getattr(args, "watchdog", 0) > 0:  # a hung XLA call prints every thread's traceback and exits
        faulthandler.dump_traceback_later(args.watchdog, exit=True)
    return args
