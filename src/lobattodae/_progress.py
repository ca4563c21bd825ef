"""Ctrl-C and progress during :func:`~lobattodae.solve`: interrupts deferred to the end of a
compiled chunk, and a progress bar on stderr (or the user's callback) after each chunk.
"""

from __future__ import annotations

import signal
import sys
import threading
import time
from contextlib import contextmanager

__all__ = ["ProgressBar", "deferred_interrupts", "progress_reporter"]


@contextmanager
def deferred_interrupts():
    """Within the block, Ctrl-C (SIGINT) only sets a flag that the chunk loop checks, so an
    interrupt never lands between updating the step count and the state; a second Ctrl-C
    raises KeyboardInterrupt as usual. Outside the main thread, or where SIGINT is ignored,
    nothing is changed."""
    flag = {"set": False}
    if threading.current_thread() is not threading.main_thread():
        yield lambda: False
        return
    previous = signal.getsignal(signal.SIGINT)
    if previous is signal.SIG_IGN:  # e.g. a background job: Ctrl-C stays ignored
        yield lambda: False
        return

    def handler(signum, frame):
        if flag["set"]:
            raise KeyboardInterrupt
        flag["set"] = True

    signal.signal(signal.SIGINT, handler)
    try:
        yield lambda: flag["set"]
    finally:
        signal.signal(signal.SIGINT, previous)


def progress_reporter(progress, opt):
    if progress is False or progress is None:
        return None
    if callable(progress):
        return progress
    return ProgressBar(adaptive=opt.adaptive, t0=opt.t0)


class ProgressBar:
    """A progress bar on stderr that appears once a run has taken more than ``delay`` seconds:
    steps for constant steps, simulated time for adaptive ones."""

    def __init__(self, delay: float = 1.0, adaptive: bool = False, t0: float = 0.0):
        self.start = time.perf_counter()
        self.delay = delay
        self.shown = False
        self.adaptive = adaptive
        self.t0 = t0

    def __call__(self, done: float, total: float) -> None:
        el = time.perf_counter() - self.start
        if el < self.delay and not self.shown:
            return
        self.shown = True
        if self.adaptive:
            frac = (done - self.t0) / (total - self.t0)
            what = f"t = {done:.6g} of {total:.6g}"
        else:
            frac = done / total
            what = f"{int(done)}/{int(total)} steps"
        eta = el / frac * (1 - frac) if frac > 0 else float("nan")
        fill = int(30 * frac)
        sys.stderr.write(f"\r[{'#' * fill}{'.' * (30 - fill)}] {what}  {el:6.1f}s  eta {eta:6.1f}s")
        if frac >= 1:
            self.close()
        sys.stderr.flush()

    def close(self) -> None:
        """End the bar's line (also when the run stopped early)."""
        if self.shown:
            sys.stderr.write("\n")
            sys.stderr.flush()
            self.shown = False
