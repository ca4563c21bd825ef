"""The figures of the verification report, drawn from the runs of :mod:`.runs`.

Each function takes ``(record, series)`` pairs, as :mod:`.runs` returns them, and writes
one PNG file.
"""

from __future__ import annotations

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import matplotlib.ticker  # noqa: E402
import numpy as np  # noqa: E402

from lobattodae._plotting import plot_convergence  # noqa: E402

from .runs import LONG_N, LONG_STAGES  # noqa: E402

#: lam_start -> (colour, line style, width)
MODE_STYLE = {
    "auto": ("tab:green", "-", 2.2),
    "previous": ("tab:red", "--", 1.0),
    "consistent": ("tab:blue", ":", 1.4),
}
#: Values drawn on log axes are clipped below at this (exact zeros have no logarithm).
LOG_FLOOR = 1e-18


def mode_name(mode, default_mode) -> str:
    return f"{mode} (default)" if mode == default_mode else "previous (paper)" if mode == "previous" else mode


def mode_label(record, default_mode) -> str:
    """A legend entry: the mode, and the resets of an 'auto' run."""
    name = mode_name(record["lam_start"], default_mode)
    return f"{name}: {record['lam_resets']} resets" if record["lam_start"] == "auto" else name


def envelope(t, x, blocks=1000):
    """Max of |x| over consecutive blocks (for readable plots of 1e5 points)."""
    x = np.abs(np.asarray(x))
    b = max(1, x.size // blocks)
    m = (x.size // b) * b
    return np.asarray(t)[:m].reshape(-1, b).mean(axis=1), x[:m].reshape(-1, b).max(axis=1), b


def semilogy(ax, x, y, mode, **kwargs):
    colour, style, width = MODE_STYLE[mode]
    ax.semilogy(x, np.maximum(y, LOG_FLOOR), style, color=colour, lw=kwargs.pop("lw", width), **kwargs)


def mark_resets(ax, x):
    """Vertical lines at the re-synchronisations of an 'auto' run."""
    for i, xi in enumerate(x[:200]):
        ax.axvline(xi, color=MODE_STYLE["auto"][0], lw=0.7, ls="-.", alpha=0.8,
                   label="auto: reset" if i == 0 else None)


def finish(fig, axes, path, dpi, legend_size=8, **legend):
    for ax in np.ravel(axes):
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=legend_size, **legend)
    fig.savefig(path, dpi=dpi)
    plt.close(fig)


def convergence(study, path):
    axes = plot_convergence(study)
    for ax in axes:  # the minor-tick labels of log axes overlap at this figure size
        ax.xaxis.set_minor_formatter(matplotlib.ticker.NullFormatter())
    axes[0].figure.savefig(path, dpi=100)
    plt.close(axes[0].figure)


def long_runs(runs, path):
    """Energy error, constraint residual and multiplier drift of the long runs."""
    names = list(dict.fromkeys(r["name"] for r, _ in runs))
    fig, axes = plt.subplots(3, len(names), figsize=(6.2 * len(names), 9.6), squeeze=False,
                             constrained_layout=True)
    colours = dict(zip(LONG_N, ("tab:blue", "tab:orange")))
    for j, name in enumerate(names):
        for r, x in ((r, x) for r, x in runs if r["name"] == name):
            label = f"h = 2 sin(π/{r['N']}) = {r['h']:.4f}"
            for ax, y, lw in zip(axes[:, j], (x.dH, x.phi, x.drift), (1.0, 0.8, 0.8)):
                tm, ym, b = envelope(x.t, y)
                ax.semilogy(tm, np.maximum(ym, LOG_FLOOR), color=colours[r["N"]], lw=lw, label=label)
        axes[0, j].set_title(f"{name}, s = {LONG_STAGES}: |H − H0| (max per {b} steps)")
        axes[1, j].set_title(f"{name}: ‖φ(q_k, p_k)‖∞ (max per {b} steps)")
        axes[2, j].set_title(f"{name}: ‖λ_k − λ(q_k, p_k)‖∞ (max per {b} steps)")
        for ax, label in zip(axes[:, j], ("|H(t) − H(0)|", "‖φ‖∞", "multiplier drift")):
            ax.set_ylabel(label)
        axes[-1, j].set_xlabel("t")
    finish(fig, axes, path, dpi=110)


def variants(runs, default_mode, path):
    """The long runs in every lam_start mode: the energy error."""
    names = list(dict.fromkeys(r["name"] for r, _ in runs))
    fig, axes = plt.subplots(1, len(names), figsize=(6.2 * len(names), 3.8), squeeze=False,
                             constrained_layout=True)
    for ax, name in zip(axes[0], names):
        for r, x in ((r, x) for r, x in runs if r["name"] == name):
            tm, em, b = envelope(x.t, x.dH)
            coarse = r["N"] == LONG_N[0]
            semilogy(ax, tm, em, r["lam_start"], lw=MODE_STYLE[r["lam_start"]][2] * (1.0 if coarse else 0.6),
                     alpha=1.0 if coarse else 0.55,
                     label=f"h = {r['h']:.4f}, {mode_name(r['lam_start'], default_mode)}")
        ax.set_title(f"{name}, s = {LONG_STAGES}: |H − H0| (max per {b} steps)")
        ax.set_xlabel("t")
        ax.set_ylabel("|H(t) − H(0)|")
    finish(fig, axes, path, dpi=110, legend_size=6.5, ncol=2)


def lam_modes(sleigh, contact, default_mode, path):
    """One column per sleigh configuration (drift, q error against t) and one for the contact
    oscillator (energy error, drift against the step index)."""
    configs = list(dict.fromkeys((r["s"], r["h"], r["T"]) for r, _ in sleigh))
    ncol = len(configs) + bool(contact)
    fig, axes = plt.subplots(2, ncol, figsize=(5.6 * ncol, 7.0), squeeze=False, constrained_layout=True)
    for (ax_d, ax_q), (s, h, T) in zip(axes.T, configs):
        for r, x in ((r, x) for r, x in sleigh if (r["s"], r["h"], r["T"]) == (s, h, T)):
            label = mode_label(r, default_mode)
            semilogy(ax_d, x.t[1:], x.drift[1:], r["lam_start"], label=label)  # no drift recorded at t_0
            semilogy(ax_q, x.t, x.q_error, r["lam_start"], label=label)
            if r["lam_start"] == "auto":
                mark_resets(ax_d, x.t[x.resync])
                mark_resets(ax_q, x.t[x.resync])
        ax_d.set_title(f"sleigh, s = {s}, h = {h:g}: ‖λ_n − λ(q_n, p_n)‖∞")
        ax_q.set_title(f"sleigh, s = {s}, h = {h:g}: ‖q_n − q(t_n)‖∞ (closed form)")
        ax_d.set_ylabel("multiplier drift")
        ax_q.set_ylabel("q error")
        ax_q.set_xlabel("t")
    if contact:
        ax_e, ax_d = axes[:, -1]
        for r, x in contact:
            k = np.arange(len(x.t))
            label = mode_label(r, default_mode)
            km, em, b = envelope(k, x.dH)
            semilogy(ax_e, km, em, r["lam_start"], label=label)
            km, dm, _ = envelope(k[1:], x.drift[1:])
            semilogy(ax_d, km, dm, r["lam_start"], label=label)
            if r["lam_start"] == "auto":
                mark_resets(ax_e, x.resync)
                mark_resets(ax_d, x.resync)
        ax_e.set_title(f"contact, s = {LONG_STAGES}, h = {contact[0][0]['h']:.4f}: |H − H0| (max per {b} steps)")
        ax_d.set_title(f"contact: ‖λ_n − λ(q_n, p_n)‖∞ (max per {b} steps)")
        ax_e.set_ylabel("|H(t_n) − H(0)|")
        ax_d.set_ylabel("multiplier drift")
        ax_d.set_xlabel("step index n")
    finish(fig, axes, path, dpi=100, legend_size=7)
