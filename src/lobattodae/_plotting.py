"""Plots of convergence studies and solution diagnostics (matplotlib, imported lazily).

Every function draws into given or new Axes and returns them; none calls ``show``.
"""

from __future__ import annotations

from typing import Any

import numpy as np

__all__ = ["plot_convergence", "plot_diagnostics", "plot_solution"]

_LABELS = {"q": "q", "p": "p", "lam": "λ"}


def _plt():
    import matplotlib

    if matplotlib.get_backend().lower() not in ("agg",) and not _interactive():
        matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _interactive() -> bool:
    import sys

    return hasattr(sys, "ps1") or "ipykernel" in sys.modules


def plot_convergence(study, axes=None, components=("q", "p", "lam")):
    """Log-log global error against h, one panel per component, with reference slopes.

    Parameters
    ----------
    study : ConvergenceStudy
    axes : sequence of matplotlib Axes, optional
        One per component; created (in one figure) when omitted.

    Returns
    -------
    list of Axes
    """
    plt = _plt()
    if axes is None:
        fig, axes = plt.subplots(1, len(components), figsize=(4.2 * len(components), 3.8), constrained_layout=True)
        fig.suptitle(f"{study.name}: global error vs step size")
    axes = list(np.atleast_1d(axes))
    cmap = plt.get_cmap("viridis")
    for ax, comp in zip(axes, components):
        for idx, s in enumerate(study.stages):
            color = cmap(idx / max(1, len(study.stages) - 1) * 0.9)
            h = np.asarray(study.h[s])
            e = np.asarray(study.errors[s][comp])
            ok = e > 0
            obs = study.observed[s][comp]
            lab = f"s={s}: {'exact' if not np.isfinite(obs) else f'{obs:.2f}'} (theory {study.expected[s][comp]})"
            ax.loglog(h[ok], e[ok], "o-", color=color, label=lab, ms=4)
            order = study.expected[s][comp]
            if ok.any():
                h0, e0 = h[ok][0], e[ok][0]
                ax.loglog(h[ok], e0 * (h[ok] / h0) ** order, ":", color=color, lw=1)
        ax.axhline(study.floors[comp], color="0.6", lw=0.8, ls="--")
        ax.set_xlabel("step size h")
        ax.set_ylabel(f"max error in {_LABELS[comp]}")
        ax.set_title(f"{_LABELS[comp]} (dotted: theoretical slope)")
        ax.legend(fontsize=7)
        ax.grid(True, which="both", alpha=0.3)
    return axes


def plot_solution(sol, axes=None):
    """q, p and λ against t."""
    plt = _plt()
    if axes is None:
        fig, axes = plt.subplots(3, 1, figsize=(7, 7), sharex=True, constrained_layout=True)
    for ax, name in zip(axes, ("q", "p", "lam")):
        x = getattr(sol, name)
        for i in range(x.shape[1]):
            ax.plot(sol.t, x[:, i], label=f"{_LABELS[name]}[{i}]")
        ax.set_ylabel(_LABELS[name])
        ax.legend(fontsize=7, ncol=min(5, x.shape[1]))
        ax.grid(True, alpha=0.3)
    axes[-1].set_xlabel("t")
    return list(axes)


def plot_diagnostics(sol, invariants: dict[str, Any] | None = None, axes=None):
    """Constraint residual, invariant errors and Newton iterations along a solution.

    Parameters
    ----------
    sol : Solution
    invariants : dict name -> callable(t, q, p, args), optional
        Their relative drift |I(t) - I(t0)| / max(1, |I(t0)|) is plotted (e.g. the energy).
    """
    from ._diagnostics import invariant_error

    plt = _plt()
    invariants = dict(invariants or {})
    if axes is None:
        fig, axes = plt.subplots(3, 1, figsize=(7, 7.5), sharex=True, constrained_layout=True)
    ax_c, ax_i, ax_n = axes
    ax_c.semilogy(sol.t, np.maximum(sol.stats["constraint_residual"], 1e-18), lw=0.8)
    ax_c.set_ylabel("‖φ(q_k, p_k)‖∞")
    for name, fn in invariants.items():
        err = invariant_error(sol, fn)
        ax_i.semilogy(sol.t, np.maximum(np.abs(err), 1e-18), lw=0.8, label=name)
    if invariants:
        ax_i.legend(fontsize=8)
    ax_i.set_ylabel("|I(t) − I(t0)|")
    ax_n.plot(sol.t[1:], sol.stats["newton_iterations"], lw=0.6)
    ax_n.set_ylabel("Newton iterations")
    ax_n.set_xlabel("t")
    for ax in axes:
        ax.grid(True, alpha=0.3)
    return list(axes)
