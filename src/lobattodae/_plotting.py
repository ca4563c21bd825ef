"""Plots of convergence studies and solution diagnostics (matplotlib, imported lazily).

:func:`plot` is the diagnostics figure of a run (``lobattodae run --plot``); the other
functions draw into given or new Axes and return them. None calls ``show``.
"""

from __future__ import annotations

from typing import Any, Sequence

import numpy as np

from ._animation import known_system
from ._mpl import pyplot as _plt

__all__ = ["plot", "plot_convergence", "plot_solution"]

#: :func:`plot` shows Newton iterations per step up to this many steps, above it a moving
#: summary (min–max band and mean) over :data:`NEWTON_BINS` bins of consecutive steps.
NEWTON_STEPS = 500
NEWTON_BINS = 200

_LABELS = {"q": "q", "p": "p", "lam": "λ"}


def plot_convergence(study, axes=None, components=("q", "p", "lam")):
    """Log-log global error against h, one panel per component, with reference slopes.

    Parameters
    ----------
    study : ConvergenceStudy
        What :func:`~lobattodae.convergence_study` returned.
    axes : sequence of matplotlib Axes, optional
        One per component; created (in one figure) when omitted.
    components : sequence of {"q", "p", "lam"}, optional
        The components to draw, one panel each (default all three).

    Returns
    -------
    list of Axes
        The panels, in the order of ``components``.

    Raises
    ------
    ImportError
        matplotlib is not installed.
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
    """q, p and λ against t, one panel each, a line per component.

    Parameters
    ----------
    sol : Solution
        The run to draw (its ``t``, ``q``, ``p``, ``lam``).
    axes : sequence of three matplotlib Axes, optional
        The panels for q, p and λ; created (in one figure, sharing the t axis) when omitted.

    Returns
    -------
    list of Axes
        The three panels.

    Raises
    ------
    ImportError
        matplotlib is not installed.
    """
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


def _result(sol):
    """The run's :class:`Result` (``sol.result``; ``sol.status`` before the scipy views)."""
    return getattr(sol, "result", sol.status)


def _problem_name(sol, name: str | None) -> str:
    problem = getattr(sol, "problem", None)
    own = getattr(problem, "name", None) or (type(problem).__name__ if problem is not None else "solution")
    if name and name != own:
        return f"{name} ({own})"
    return own


def _title(sol, name, rtol, atol) -> str:
    stats = sol.stats
    method = getattr(sol, "method", None)
    stages = getattr(method, "stages", None)
    head = f"{_problem_name(sol, name)} — Lobatto IIIA–IIIB" + (f", s = {stages}" if stages is not None else "")
    if stats.get("h") is not None:
        steps = f"h = {abs(stats['h']):.4g} ({stats['n_steps']} steps)"
    else:
        rtol = stats.get("rtol", rtol)
        atol = stats.get("atol", atol)
        if rtol is not None:
            steps = f"rtol = {rtol:.1e}, atol = {atol:.1e}" if atol is not None else f"rtol = {rtol:.1e}"
        else:
            steps = "adaptive steps"
        if stats.get("n_clamped") is not None:  # ReversibleStepSize
            steps = "reversible step size"
        steps += f" ({stats['n_steps']} steps, {stats.get('n_rejected', 0)} rejected)"
    t = np.asarray(sol.t)
    span = f"t ∈ [{t[0]:.4g}, {t[-1]:.4g}]" if t.size else ""
    return f"{head}, {steps}, {span}"


def _every_step_is_a_row(sol) -> bool:
    """The rows are the initial point and every step point (so diff(t) are the steps)."""
    return len(sol.t) >= 2 and int(sol.stats.get("n_steps", -1)) == len(sol.t) - 1


def _log_with_zeros(ax, t, values, *, label, color, slot, n_slots, gid):
    """``values`` (>= 0) on the log axis; exact zeros drawn as ticks in a band marked "= 0" at
    the bottom of the panel and counted in the label (a log axis has no place for 0)."""
    import matplotlib.transforms as mtransforms

    values = np.abs(np.asarray(values, dtype=float))
    t = np.asarray(t, dtype=float)
    finite = np.isfinite(values)
    zero = finite & (values == 0.0)
    pos = finite & (values > 0.0)
    nz, n = int(zero.sum()), int(values.size)
    text = label
    if nz:
        text += f"  (= 0 exactly at {nz} of {n} rows: ticks in the '= 0' band)"
    line = ax.plot(t[pos], values[pos], color=color, lw=0.6, marker=".", ms=2.5 if pos.sum() < 2000 else 1.0,
                   label=text, gid=gid)[0]
    if nz:
        trans = mtransforms.blended_transform_factory(ax.transData, ax.transAxes)
        y = _BAND * (slot + 0.5) / n_slots
        ax.plot(t[zero], np.full(nz, y), "|", color=color, ms=5, mew=0.8, transform=trans, gid=f"{gid}=0")
    return line, values[pos], nz


#: Height (axes fraction) of the "= 0" band at the bottom of the log panels.
_BAND = 0.08
#: Room above the data of the log panels (in units of the data's decades), for the legend.
_HEADROOM = 0.4


def _finish_log_panel(ax, positive: list[np.ndarray], any_zero: bool):
    """y limits that leave the '= 0' band free of data, and the band itself."""
    import matplotlib.patches as mpatches
    import matplotlib.transforms as mtransforms

    ax.set_yscale("log")
    pos = np.concatenate([p for p in positive if p.size]) if any(p.size for p in positive) else np.array([])
    if pos.size:
        lo, hi = float(pos.min()), float(pos.max())
    else:
        lo, hi = 1e-16, 1e-16  # every value is 0: an empty log scale near round-off
    decades = max(np.log10(hi / lo), 1.0)
    if any_zero:
        # data occupies the top (1 - band - margin) of the axes
        bottom = lo / 10 ** (decades * (_BAND + 0.04) / (1 - _BAND - 0.04))
        ax.set_ylim(bottom, hi * 10 ** (_HEADROOM * decades))
        trans = mtransforms.blended_transform_factory(ax.transAxes, ax.transAxes)
        ax.add_patch(mpatches.Rectangle((0, 0), 1, _BAND, transform=trans, color="0.93", zorder=0, gid="zero band"))
        ax.text(1.005, _BAND / 2, "= 0", transform=ax.transAxes, va="center", ha="left", fontsize=7, color="0.3")
    else:
        ax.set_ylim(lo / 10 ** (0.08 * decades), hi * 10 ** (_HEADROOM * decades))


def _moving_summary(ax, t, iterations, bins: int):
    """Newton iterations of many steps: min–max band and mean per bin of consecutive steps."""
    n = iterations.size
    size = int(np.ceil(n / bins))
    edges = np.arange(0, n, size)
    groups = [iterations[i:i + size] for i in edges]
    mean = np.array([g.mean() for g in groups])
    lo = np.array([g.min() for g in groups])
    hi = np.array([g.max() for g in groups])
    x = np.append(t[edges], t[-1])
    ax.fill_between(x, np.append(lo, lo[-1]), np.append(hi, hi[-1]), step="post", color="C0", alpha=0.25,
                    lw=0, label="min–max", gid="newton range")
    ax.plot(x, np.append(mean, mean[-1]), drawstyle="steps-post", color="C0", lw=1.0,
            label=f"mean per {size} steps", gid="newton")


def plot(
    sol,
    *,
    projection: Any = "auto",
    coordinates: Sequence[int] | None = None,
    labels: Sequence[str] | None = None,
    invariants: dict[str, Any] | None = None,
    name: str | None = None,
    rtol: float | None = None,
    atol: float | None = None,
    newton_steps: int = NEWTON_STEPS,
    figsize: tuple[float, float] | None = None,
):
    """The diagnostics of a run in one figure: what was solved, the solution, its constraints,
    invariants, step sizes and Newton iterations.

    Panels (left, sharing the t axis): the coordinates ``q[i](t)``; ‖φ(q_k, p_k)‖∞ and, with
    holonomic constraints, |ψ(q_k)|∞ per row; the invariants' errors |I(t) − I(t0)| (the energy
    by default); the step size (adaptive runs whose rows are every step, drawn as a constant
    over each step); Newton iterations per step (all Newton solves of the step; a min–max band
    and mean per bin when there are more than ``newton_steps`` steps). Right: the path in a plane (``projection``), a summary of
    the run and the histogram of Newton iterations. The title names the problem, the method, s
    and h or the tolerances.

    Exact zeros are not clipped to a floor: a log axis has no 0, so they are drawn as ticks in
    a band marked "= 0" at the bottom of the panel and counted in the legend.

    Parameters
    ----------
    sol : Solution
    projection : "auto", (i, j), callable or None
        The path panel: ``(i, j)`` draws q[j] against q[i]; a callable
        ``projection(t, q, p) -> (x, y)`` (arrays over the rows) draws any planar view;
        ``"auto"`` (default) the example's plane (the contact point of the rolling disks, the
        sleigh's and the knife edge's position) and none for other problems; None: no path.
    coordinates : sequence of int, optional
        The q[i] drawn against t (default: all).
    labels : sequence of str, optional
        Names of the coordinates (default: the example's, else ``q[i]``).
    invariants : dict name -> callable(t, q, p, args), optional
        Drawn as |I(t) − I(t0)|. Default: the energy ``H`` when the problem has a Hamiltonian;
        ``{}`` for none.
    name : str, optional
        The problem's name in the title (e.g. the example's name).
    rtol, atol : float, optional
        The tolerances of an adaptive run, for the title (a ``Solution`` does not record them).
    newton_steps : int
        Above this many steps the Newton panel shows a moving summary: the min–max band and the
        mean over 200 bins of consecutive steps (default 500).
    figsize : (float, float), optional

    Returns
    -------
    (Figure, dict of Axes)
        The axes by panel name: ``"solution"``, ``"constraint"``, ``"invariants"`` (when
        there are invariants), ``"step"`` (adaptive runs with every step in the rows),
        ``"newton"``, ``"path"`` (with a projection), ``"summary"``, ``"histogram"``.

    Raises
    ------
    ValueError
        ``labels`` does not name every coordinate, or ``projection`` is a string other than
        ``"auto"``.
    ImportError
        matplotlib is not installed.
    """
    from ._diagnostics import _over_trajectory, invariant_error

    plt = _plt()
    stats = sol.stats
    t = np.asarray(sol.t, dtype=float)
    q = np.asarray(sol.q, dtype=float)
    n = q.shape[1] if q.ndim == 2 else 0
    problem = getattr(sol, "problem", None)
    system = known_system(problem)
    labels = list(labels) if labels is not None else (
        list(system.labels) if system is not None and len(system.labels) == n else [f"q[{i}]" for i in range(n)])
    if len(labels) != n:
        raise ValueError(f"labels must name the {n} coordinates; got {len(labels)}")
    if invariants is None:
        ham = getattr(problem, "hamiltonian", None)
        invariants = {"energy H": ham} if callable(ham) else {}
    invariants = dict(invariants)
    if isinstance(projection, str):
        if projection != "auto":
            raise ValueError(f"projection must be 'auto', a pair of indices, a callable or None; got {projection!r}")
        projection = system.path if system is not None else None
    psi = getattr(problem, "position_constraint", None)
    iterations = np.asarray(stats.get("newton_iterations", []), dtype=float)
    show_steps = stats.get("h") is None and _every_step_is_a_row(sol)

    left = ["solution", "constraint"] + (["invariants"] if invariants else []) + (["step"] if show_steps else [])
    left.append("newton")
    right = []
    if projection is not None:
        right += ["path"] * max(1, len(left) - 3)
    right.append("summary")
    right += ["histogram"] * (len(left) - len(right))
    if figsize is None:
        figsize = (12.5, 1.1 + 2.0 * len(left))
    fig, axes = plt.subplot_mosaic([[a, b] for a, b in zip(left, right)], figsize=figsize,
                                   width_ratios=[2.2, 1], constrained_layout=True)
    for key in left[1:]:
        axes[key].sharex(axes["solution"])
    fig.suptitle(_title(sol, name, rtol, atol), fontsize=11)

    # the solution
    ax = axes["solution"]
    shown = range(n) if coordinates is None else [int(i) for i in coordinates]
    for i in shown:
        ax.plot(t, q[:, i], lw=1.0, label=labels[i], gid=f"q{i}")
    ax.set_ylabel("coordinates")
    ax.set_title("solution q(t)", fontsize=9, loc="left")
    if n:
        ax.legend(fontsize=7, ncol=min(6, len(list(shown)) or 1), loc="best")

    # constraints
    ax = axes["constraint"]
    series = [("‖φ(q_k, p_k)‖∞", stats["constraint_residual"], "phi")]
    if callable(psi):
        values = _over_trajectory(lambda tk, qk, pk: _max_abs(psi(tk, qk, sol.args)), sol)
        series.append(("|ψ(q_k)|∞ (holonomic)", values, "psi"))
    positives, any_zero, maxima = [], False, {}
    for slot, (label, values, gid) in enumerate(series):
        _, pos, nz = _log_with_zeros(ax, t[: len(values)], values, label=label, color=f"C{slot}", slot=slot,
                                     n_slots=len(series), gid=gid)
        positives.append(pos)
        any_zero |= bool(nz)
        maxima[gid] = float(np.max(np.abs(values))) if len(values) else 0.0
    _finish_log_panel(ax, positives, any_zero)
    ax.set_ylabel("constraint residual")
    ax.set_title("constraints at the rows", fontsize=9, loc="left")
    ax.legend(fontsize=7, loc="upper left")

    # invariants
    errors = {}
    if invariants:
        ax = axes["invariants"]
        positives, any_zero = [], False
        for slot, (key, fn) in enumerate(invariants.items()):
            err = np.abs(invariant_error(sol, fn))
            errors[key] = float(np.max(err)) if err.size else 0.0
            _, pos, nz = _log_with_zeros(ax, t, err, label=f"|{key}(t) − {key}(t0)|", color=f"C{slot + 2}",
                                         slot=slot, n_slots=len(invariants), gid=f"invariant:{key}")
            positives.append(pos)
            any_zero |= bool(nz)
        _finish_log_panel(ax, positives, any_zero)
        ax.set_ylabel("invariant error")
        ax.set_title("invariants (|I(t) − I(t0)|)", fontsize=9, loc="left")
        ax.legend(fontsize=7, loc="upper left")

    # step sizes: one constant per step interval [t_k, t_k+1)
    if show_steps:
        ax = axes["step"]
        h = np.abs(np.diff(t))
        ax.plot(t, np.append(h, h[-1]), drawstyle="steps-post", color="C1", lw=1.0, gid="step size",
                label=f"{h.size} steps, {stats.get('n_rejected', 0)} rejected")
        ax.set_yscale("log")
        ax.set_ylabel("step size |h|")
        ax.set_title("step size (constant over each step)", fontsize=9, loc="left")
        ax.legend(fontsize=7, loc="upper left")

    # Newton iterations
    ax = axes["newton"]
    if iterations.size and iterations.size == t.size - 1:  # one per step (row) after the first
        tn = t
        if iterations.size <= newton_steps:
            ax.plot(tn, np.append(iterations, iterations[-1]), drawstyle="steps-post", color="C0", lw=1.0,
                    gid="newton", label="per step")
        else:
            _moving_summary(ax, tn, iterations, NEWTON_BINS)
        ax.legend(fontsize=7, loc="upper left")
    ax.set_ylabel("Newton iterations")
    ax.set_title("Newton iterations of each step", fontsize=9, loc="left")
    ax.yaxis.get_major_locator().set_params(integer=True)
    ax.set_xlabel("t")
    for key in left:
        axes[key].grid(True, alpha=0.3)
        if key != left[-1]:
            axes[key].tick_params(labelbottom=False)

    # path in a plane
    if projection is not None:
        ax = axes["path"]
        if callable(projection):
            x, y = (np.asarray(v, dtype=float) for v in projection(t, q, np.asarray(sol.p)))
            xlabel, ylabel = "x", "y"
        else:
            i, j = (int(k) for k in projection)
            x, y = q[:, i], q[:, j]
            xlabel, ylabel = labels[i], labels[j]
        ax.plot(x, y, color="C0", lw=1.0, gid="path")
        ax.plot(x[:1], y[:1], "o", color="C2", ms=5, label=f"t = {t[0]:.3g}")
        ax.plot(x[-1:], y[-1:], "s", color="C3", ms=5, label=f"t = {t[-1]:.3g}")
        ax.set_aspect("equal", adjustable="datalim")
        ax.set_xlabel(xlabel)
        ax.set_ylabel(ylabel)
        what = "contact point" if system is not None and "disk" in system.name else "path"
        ax.set_title(f"{what}: {ylabel} against {xlabel}", fontsize=9, loc="left")
        ax.legend(fontsize=7)
        ax.grid(True, alpha=0.3)

    # summary
    ax = axes["summary"]
    ax.axis("off")
    result = _result(sol)
    lines = [f"{'success' if sol.success else 'FAILED'}: {getattr(result, 'name', result)}"]
    if stats.get("h") is not None:
        lines.append(f"{stats['n_steps']} constant steps, h = {abs(stats['h']):.4g}")
    else:
        lines.append(f"{stats['n_steps']} steps, {stats.get('n_rejected', 0)} rejected")
        if not show_steps:
            lines.append("(rows are not every step: no step-size panel)")
    lines.append(f"{t.size} rows")
    lines.append(f"max ‖φ‖∞ over all steps: {stats['max_constraint_residual']:.2e}")
    if "psi" in maxima:
        lines.append(f"max |ψ|∞ at the rows: {maxima['psi']:.2e}")
    for key, value in errors.items():
        lines.append(f"max |Δ {key}|: {value:.2e}")
    if iterations.size:
        lines.append(f"Newton: mean {iterations.mean():.2f}, max {int(iterations.max())} per step; "
                     f"{stats.get('n_jacobians', '?')} Jacobians")
    if stats.get("lam_resets"):
        lines.append(f"λ re-synchronisations: {stats['lam_resets']}")
    if stats.get("compile_and_run_time") is not None:
        lines.append(f"time {stats['compile_and_run_time']:.2f} s (with compilation)")
    ax.text(0.0, 1.0, "\n".join(lines), transform=ax.transAxes, va="top", ha="left", fontsize=8.5,
            family="DejaVu Sans", gid="summary")

    # histogram of Newton iterations
    ax = axes["histogram"]
    if iterations.size:
        values, counts = np.unique(iterations.astype(int), return_counts=True)
        bars = ax.bar(values, counts, width=0.7, color="C0", gid="histogram")
        for bar, c in zip(bars, counts):
            share = 100 * c / iterations.size
            ax.annotate(f"{share:.0f}%" if share >= 0.5 else "<1%", (bar.get_x() + bar.get_width() / 2, c),
                        ha="center", va="bottom", fontsize=7)
        ax.set_xticks(values)
        ax.set_ylim(0, counts.max() * 1.18)
    ax.set_xlabel("Newton iterations")
    ax.set_ylabel("steps")
    ax.set_title("Newton iterations per step", fontsize=9, loc="left")
    return fig, axes


def _max_abs(x):
    """max |x| of a scalar or vector (jax)."""
    import jax.numpy as jnp

    return jnp.max(jnp.abs(jnp.atleast_1d(x)))
