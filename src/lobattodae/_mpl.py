"""matplotlib, imported on first use (the library does not import it otherwise) with a
non-interactive backend unless the session is interactive (a REPL or Jupyter)."""

from __future__ import annotations

import sys

__all__ = ["pyplot"]


def pyplot():
    """``matplotlib.pyplot``, with the Agg backend outside interactive sessions."""
    import matplotlib

    if matplotlib.get_backend().lower() not in ("agg",) and not _interactive():
        matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _interactive() -> bool:
    return hasattr(sys, "ps1") or "ipykernel" in sys.modules
