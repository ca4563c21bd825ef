"""Trajectory animations of a :class:`~lobattodae.Solution` (matplotlib, imported lazily).

A *drawing* maps one state to the shapes of one frame::

    draw(t, q, args) -> {name: array of shape (k, 2) or (k, 3)}

each shape a polyline of k points in the plane or in space (one point: a marker). The
example problems have their own drawings (:func:`known_system`: the rolling disks' rims in
3-D, the sleigh's body and blade, the knife edge's blade, the Whipple bicycle of
:func:`lobattodae.mechanics.bicycle.whipple_bicycle` in 3-D); any other problem is drawn as the
point ``(q[0], q[1])`` unless a ``draw`` is given.
"""

from __future__ import annotations

import sys
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["KnownSystem", "animate", "frame_states", "known_system"]

#: Default number of frames of :func:`animate` (5 s at the default 20 frames per second).
FRAMES = 100
#: Default frame rate.
FPS = 20
#: The trail is drawn through this many states per frame (at most; fewer when there are fewer rows).
TRAIL_DENSITY = 10
#: Suffixes :func:`animate` writes: GIF with Pillow (a matplotlib dependency), MP4 with ffmpeg.
SUFFIXES = (".gif", ".mp4")

_DEFAULT = object()  # "not given" for trail (None means: no trail)


@dataclass(frozen=True)
class KnownSystem:
    """How the diagnostics and the animation show one of the example problems.

    Attributes
    ----------
    name : str
        The problem, in words.
    labels : tuple of str
        Names of the coordinates q[i].
    path : tuple of int
        Indices ``(i, j)`` of the planar path drawn by :func:`lobattodae.plot` (the contact
        point or the position in the plane).
    draw : callable
        ``draw(t, q, args) -> {name: (k, 2|3) array}`` (the module docstring).
    styles : dict
        matplotlib keyword arguments per shape name.
    trail : str, tuple of str, or None
        The shape(s) whose first point leaves a trail in the animation.
    follow : bool
        The animation's view follows the drawing (a window the size of one frame's drawing)
        instead of showing the whole run: for systems that travel far compared with their size.
    axes : tuple of str, optional
        Axis labels of a 3-D drawing (default ``x, y, z``).
    view : tuple of float, optional
        ``(elevation, azimuth)`` of a 3-D drawing's camera in degrees (default matplotlib's).
    """

    name: str
    labels: tuple[str, ...]
    path: tuple[int, int]
    draw: Callable[..., Mapping[str, Any]]
    styles: Mapping[str, Mapping[str, Any]] = field(default_factory=dict)
    trail: str | tuple[str, ...] | None = None
    follow: bool = False
    axes: tuple[str, str, str] | None = None
    view: tuple[float, float] | None = None


# ------------------------------------------------------------------------------ drawings
_CIRCLE = np.linspace(0.0, 2.0 * np.pi, 65)


def _disk_shapes(x, y, tilt, heading, spin, radius):
    """Rim, spoke and contact point of a thin disk of ``radius`` touching the plane z = 0 at
    (x, y): rolling direction (cos heading, sin heading, 0), tilted by ``tilt`` from the vertical
    (the falling disk's convention: centre = contact + R (sin θ n̂ + cos θ ẑ),
    n̂ = (−sin φ, cos φ, 0)), rotated by ``spin`` about its axis."""
    forward = np.array([np.cos(heading), np.sin(heading), 0.0])
    normal = np.array([-np.sin(heading), np.cos(heading), 0.0])
    up = np.sin(tilt) * normal + np.array([0.0, 0.0, np.cos(tilt)])
    contact = np.array([x, y, 0.0])
    centre = contact + radius * up
    rim = centre + radius * (np.cos(_CIRCLE)[:, None] * forward + np.sin(_CIRCLE)[:, None] * up)
    # a material spoke: at the contact point when spin = 0, turning backwards as the disk rolls on
    angle = -0.5 * np.pi - spin
    spoke = np.stack([centre, centre + radius * (np.cos(angle) * forward + np.sin(angle) * up)])
    return {"rim": rim, "spoke": spoke, "contact": contact[None, :]}


def _falling_disk(t, q, args):
    x, y, theta, phi, psi = (float(v) for v in q[:5])
    return _disk_shapes(x, y, theta, phi, psi, float(args.R))


def _vertical_disk(t, q, args):
    x, y, phi, theta = (float(v) for v in q[:4])
    return _disk_shapes(x, y, 0.0, phi, theta, float(args.R))


def _sleigh(t, q, args):
    """Body outline (an ellipse about the centre of mass), the blade at distance a behind it."""
    x, y, th = (float(v) for v in q[:3])
    a = float(args.a)
    e = np.array([np.cos(th), np.sin(th)])
    n = np.array([-np.sin(th), np.cos(th)])
    centre = np.array([x, y])
    body = centre + 1.6 * a * np.cos(_CIRCLE)[:, None] * e + 0.8 * a * np.sin(_CIRCLE)[:, None] * n
    nose = np.stack([centre, centre + 1.6 * a * e])
    contact = centre - a * e
    blade = np.stack([contact - 0.4 * a * e, contact + 0.4 * a * e])
    return {"body": body, "heading": nose, "blade": blade, "contact": contact[None, :]}


#: Half length of the knife edge's blade as drawn (the model has no length).
KNIFE_HALF_LENGTH = 0.1


def _knife_edge(t, q, args):
    x, y, th = (float(v) for v in q[:3])
    e = np.array([np.cos(th), np.sin(th)])
    centre = np.array([x, y])
    return {"blade": np.stack([centre - KNIFE_HALF_LENGTH * e, centre + KNIFE_HALF_LENGTH * e]),
            "contact": centre[None, :]}


def _point3(t, q, args):
    return {"particle": np.asarray(q[:3], dtype=float)[None, :]}


#: Proportions of the bicycle as drawn, in units of the front wheel radius rF (the model has
#: no such dimensions): the head tube's bottom this far above the front axle along the
#: steering axis, the head tube's length, the handlebar's half width.
BICYCLE_HEAD_BOTTOM = 1.15
BICYCLE_HEAD_LENGTH = 0.5
BICYCLE_HANDLEBAR = 0.7
#: The camera of the bicycle's animation, ``(elevation, azimuth)`` in degrees: behind the
#: bicycle and to its right, looking forward and down.
BICYCLE_VIEW = (20.0, -150.0)


def _wheel(centre, contact, axle, spoke, radius):
    """Rim (a circle of ``radius`` about ``centre`` in the plane normal to ``axle``, starting
    at ``contact``) and a spoke from the centre along ``spoke``."""
    e1 = (contact - centre) / radius
    e2 = np.cross(axle, e1)
    rim = centre + radius * (np.cos(_CIRCLE)[:, None] * e1 + np.sin(_CIRCLE)[:, None] * e2)
    return rim, np.stack([centre, centre + radius * spoke])


def _whipple_bicycle(t, q, args):
    """The Whipple bicycle (:func:`lobattodae.mechanics.bicycle.whipple_bicycle`) in 3-D, from
    the model's own kinematics (``mechanics._bicycle._geometry``): both wheel rims and a
    material spoke of each, the rear frame (rear axle, mass centre of the rear frame with the
    rider, top and bottom of the head tube), the front frame (front axle, fork to the head tube
    on the steering axis, handlebar along the front axle's direction) and both contact points.
    MPRS axes have ``z`` down: the points are drawn as ``(x, −y, −z)`` (a half turn about
    ``x``), so the bicycle stands upright, height up, and the picture is not mirrored."""
    from .mechanics import _bicycle

    g = _bicycle._geometry(q, args)
    rR, rF = float(args["rR"]), float(args["rF"])
    rear_rim, rear_spoke = _wheel(g["rear centre"], g["rear contact"], g["rear axle"], g["rear spoke"], rR)
    front_rim, front_spoke = _wheel(g["front centre"], g["front contact"], g["front axle"], g["front spoke"], rF)
    d, ground = g["steering axis"], g["steering axis ground"]  # d points down along the axis
    up = (ground - g["front centre"]) @ d + BICYCLE_HEAD_BOTTOM * rF  # front axle's foot on the axis, then up
    bottom = ground - up * d
    top = bottom - BICYCLE_HEAD_LENGTH * rF * d
    bar = BICYCLE_HANDLEBAR * rF * g["front axle"]
    shapes = {
        "rear wheel": rear_rim,
        "front wheel": front_rim,
        "rear spoke": rear_spoke,
        "front spoke": front_spoke,
        "rear frame": np.stack([g["rear centre"], g["rear frame mass centre"], top, bottom, g["rear centre"]]),
        "front frame": np.stack([g["front centre"], bottom, top, top + bar, top - bar]),
        "rear contact": g["rear contact"][None, :],
        "front contact": g["front contact"][None, :],
    }
    flip = np.array([1.0, -1.0, -1.0])
    return {name: points * flip for name, points in shapes.items()}


_BICYCLE_STYLES = {
    "rear wheel": {"color": "C0", "lw": 1.8},
    "front wheel": {"color": "C0", "lw": 1.8},
    "rear spoke": {"color": "C3", "lw": 1.2},
    "front spoke": {"color": "C3", "lw": 1.2},
    "rear frame": {"color": "0.25", "lw": 2.2},
    "front frame": {"color": "C1", "lw": 2.2},
    "rear contact": {"color": "k", "marker": "o", "ms": 3, "ls": "none"},
    "front contact": {"color": "k", "marker": "o", "ms": 3, "ls": "none"},
}

_DISK_STYLES = {
    "rim": {"color": "C0", "lw": 2.0},
    "spoke": {"color": "C3", "lw": 1.5},
    "contact": {"color": "k", "marker": "o", "ms": 4, "ls": "none"},
}
_PLANAR_STYLES = {
    "body": {"color": "C0", "lw": 1.5},
    "heading": {"color": "C0", "lw": 1.0, "ls": "--"},
    "blade": {"color": "C3", "lw": 3.0},
    "contact": {"color": "k", "marker": "o", "ms": 3, "ls": "none"},
}


def known_system(problem) -> KnownSystem | None:
    """The :class:`KnownSystem` of one of the example problems (by identity), else None.

    The examples' problems are module constants. The Whipple bicycle's problem is built on
    demand (:func:`lobattodae.mechanics.bicycle.whipple_bicycle`, SymPy): it is recognised by
    identity too, against the problems that function has built, and only when its module is
    loaded (a bicycle problem cannot exist otherwise), so this never imports SymPy.
    """
    bicycle = sys.modules.get("lobattodae.mechanics._bicycle")
    if bicycle is not None and problem is not None and bicycle._is_whipple_problem(problem):
        return KnownSystem(
            "Whipple bicycle", bicycle.COORDINATES, (0, 1), _whipple_bicycle, _BICYCLE_STYLES,
            ("rear contact", "front contact"), follow=True, axes=("x", "−y", "−z"), view=BICYCLE_VIEW)
    from .examples import _knife_edge as knife
    from .examples import _particle as particle
    from .examples import _rolling_disk as disks
    from .examples import _sleigh as sleigh

    table = {
        id(disks.FALLING_PROBLEM): KnownSystem(
            "falling rolling disk", ("x", "y", "θ", "φ", "ψ"), (0, 1), _falling_disk, _DISK_STYLES, "contact"),
        id(disks.VERTICAL_PROBLEM): KnownSystem(
            "vertical rolling disk", ("x", "y", "φ", "θ"), (0, 1), _vertical_disk, _DISK_STYLES, "contact"),
        id(sleigh.PROBLEM): KnownSystem(
            "Chaplygin sleigh", ("x", "y", "θ"), (0, 1), _sleigh, _PLANAR_STYLES, "contact"),
        id(knife.PROBLEM): KnownSystem(
            "knife edge", ("x", "y", "θ"), (0, 1), _knife_edge, _PLANAR_STYLES, "contact"),
        id(particle.PROBLEM): KnownSystem(
            "nonholonomic particle", ("x", "y", "z"), (0, 1), _point3,
            {"particle": {"color": "C3", "marker": "o", "ms": 5, "ls": "none"}}, "particle"),
    }
    return table.get(id(problem))


def _generic_draw(t, q, args):
    """Any problem: the point (q[0], q[1]) (or (t, q[0]) for one coordinate)."""
    q = np.asarray(q, dtype=float)
    xy = (q[0], q[1]) if q.shape[0] >= 2 else (float(t), q[0])
    return {"point": np.array([xy])}


# ------------------------------------------------------------------------------ frames
def _dense_q(sol, times):
    """q at ``times`` from the dense output (either layout of ``sol.sol``), or None."""
    dense = getattr(sol, "sol", None)
    if dense is None:
        return None
    try:
        values = dense(times)
    except (ValueError, TypeError):
        return None
    if isinstance(values, tuple):
        return np.asarray(values[0], dtype=float)
    n = sol.q.shape[1]
    return np.asarray(values, dtype=float)[:n].T


def frame_states(sol, frames: int = FRAMES) -> tuple[np.ndarray, np.ndarray]:
    """``(times, q)`` of the frames: ``frames`` equally spaced times on the dense output when
    the solution has one (``dense_output=True``), else the rows nearest to such times (at most
    one frame per row, so a run with few rows gives fewer frames)."""
    if isinstance(frames, bool) or not isinstance(frames, (int, np.integer)) or frames < 2:
        raise ValueError(f"frames must be an integer >= 2; got {frames!r}")
    t = np.asarray(sol.t, dtype=float)
    if t.size == 0:
        raise ValueError("the solution has no rows to animate")
    times = np.linspace(t[0], t[-1], int(frames))
    if t.size > 1:
        q = _dense_q(sol, times)
        if q is not None and q.shape[0] == times.size and np.all(np.isfinite(q)):
            return times, q
    forward = t[-1] >= t[0]
    key, target = (t, times) if forward else (-t, -times)
    idx = np.clip(np.searchsorted(key, target), 0, t.size - 1)
    prev = np.clip(idx - 1, 0, t.size - 1)
    idx = np.where(np.abs(key[prev] - target) <= np.abs(key[idx] - target), prev, idx)
    idx = np.unique(idx)
    return t[idx], np.asarray(sol.q, dtype=float)[idx]


def _shapes(draw, t, q, args, first=None) -> dict[str, np.ndarray]:
    out = draw(t, q, args)
    if not isinstance(out, Mapping):
        out = {"shape": out}
    if not out:
        raise ValueError("the drawing returned no shapes; return {name: (k, 2) or (k, 3) array}")
    shapes = {}
    for name, value in out.items():
        a = np.asarray(value, dtype=float)
        if a.ndim == 1:
            a = a[None, :]
        if a.ndim != 2 or a.shape[1] not in (2, 3) or a.shape[0] < 1:
            raise ValueError(
                f"the drawing's shape {name!r} must be an array of shape (k, 2) or (k, 3) (k points in the "
                f"plane or in space); got shape {np.shape(value)}"
            )
        shapes[str(name)] = a
    dims = {a.shape[1] for a in shapes.values()}
    if len(dims) != 1:
        raise ValueError("the drawing mixes planar (k, 2) and spatial (k, 3) shapes; use one kind per drawing")
    if first is not None and (shapes.keys() != first.keys() or any(
            shapes[k].shape[1] != first[k].shape[1] for k in shapes)):
        raise ValueError(f"the drawing must return the same shape names for every state; got {sorted(first)} "
                         f"at t = {t!r} and then {sorted(shapes)}")
    return shapes


def _limits(points: np.ndarray, dim: int) -> list[tuple[float, float]]:
    lo, hi = points.min(axis=0), points.max(axis=0)
    span = max(float(np.max(hi - lo)), 1e-12)
    pad = 0.06 * span
    return [(float(lo[i]) - pad, float(hi[i]) + pad) for i in range(dim)]


# ------------------------------------------------------------------------------ animate
#: Zoom of a 3-D view that follows the drawing (matplotlib's default box leaves wide margins;
#: the window is the size of the drawing, so nothing is cut off).
FOLLOW_ZOOM = 1.15
#: Colours of the trails, in the order of the trail shapes.
TRAIL_COLORS = ("C2", "C4", "C5", "C6")


def _trail_names(trail, default, names) -> list[str]:
    """The trail shapes as a list: ``trail`` a name, a sequence of names or None; not given,
    the drawing's ``default`` (a name or names) when it has those shapes, else its first shape."""
    if trail is _DEFAULT:
        wanted = [default] if isinstance(default, str) else list(default or ())
        return wanted if wanted and all(t in names for t in wanted) else [names[0]]
    if trail is None:
        return []
    chosen = [trail] if isinstance(trail, str) else list(trail)
    if not chosen or any(not isinstance(t, str) or t not in names for t in chosen):
        raise ValueError(f"trail must be one of the drawing's shapes {names}, a list of them, or None; got {trail!r}")
    return chosen


def _windows(shapes, padding=0.06):
    """A view that follows the drawing: per frame the centre of the drawing's bounding box in
    the first two coordinates, and one half width for all frames (the largest extent of one
    frame's drawing in those coordinates, padded). Returns ``(centres (k, 2), half width)``."""
    centres, extent = [], 0.0
    for frame in shapes:
        pts = np.concatenate(list(frame.values()))[:, :2]
        lo, hi = pts.min(axis=0), pts.max(axis=0)
        centres.append(0.5 * (lo + hi))
        extent = max(extent, float(np.max(hi - lo)))
    return np.array(centres), 0.5 * max(extent, 1e-12) * (1.0 + 2.0 * padding)


def animate(
    sol,
    path: str | Path | None = None,
    *,
    draw: Callable[..., Any] | None = None,
    frames: int = FRAMES,
    fps: int = FPS,
    styles: Mapping[str, Mapping[str, Any]] | None = None,
    trail: Any = _DEFAULT,
    follow: bool | None = None,
    title: str | None = None,
    figsize: tuple[float, float] = (4.5, 4.5),
    dpi: int = 80,
):
    """An animation of the trajectory, saved as GIF or MP4 or returned for display.

    Parameters
    ----------
    sol : Solution
    path : str or Path, optional
        ``*.gif`` (matplotlib's ``PillowWriter``; Pillow comes with matplotlib) or ``*.mp4``
        (``FFMpegWriter``; needs ``ffmpeg`` on the PATH). Without it the animation is returned.
    draw : callable, optional
        ``draw(t, q, args) -> {name: (k, 2) or (k, 3) array}``: the shapes of one frame (a
        polyline of k points each; one point is drawn as a marker; one array alone is taken as
        one shape). Default: the example's own drawing (:func:`known_system`: the rolling
        disks' rims in 3-D, the sleigh's body and blade, the knife edge's blade, the particle
        in space, the Whipple bicycle in 3-D), else the point ``(q[0], q[1])``.
    frames : int
        Number of frames (default 100): equally spaced in time on the dense output when
        ``sol`` has one (``dense_output=True``), else the rows nearest to those times (no more
        frames than rows).
    fps : int
        Frames per second of the file (default 20).
    styles : dict, optional
        ``{shape name: matplotlib line keyword arguments}``, over the drawing's defaults.
    trail : str, list of str, or None, optional
        The shape(s) whose first point leaves a trail (its whole path is drawn faintly);
        default the example's choice (its contact point(s)), or the first shape; None for no
        trail.
    follow : bool, optional
        True: the view follows the drawing (a window the size of one frame's drawing, centred
        on it in the first two coordinates, the trails clipped to it); False: the whole run in
        one view. Default: the example's choice (the bicycle follows), else False.
    title : str, optional
        Shown above the time (default: the problem's name).
    figsize, dpi
        Size of the frames (default 4.5 × 4.5 in at 80 dpi: 360 × 360 pixels).

    Returns
    -------
    matplotlib.animation.FuncAnimation, or the Path written when ``path`` is given (the
    figure is closed then).

    Raises
    ------
    ValueError
        For an unknown suffix, MP4 without ffmpeg, or a drawing that returns something else
        than shapes (the message says which shape and why).
    """
    from matplotlib import animation

    from ._mpl import pyplot as _plt

    if path is not None:
        path = Path(path)
        suffix = path.suffix.lower()
        if suffix not in SUFFIXES:
            raise ValueError(f"animate writes .gif (Pillow) or .mp4 (ffmpeg); got {str(path)!r}")
        if suffix == ".mp4" and not animation.writers.is_available("ffmpeg"):
            raise ValueError(
                f"writing {str(path)!r} needs ffmpeg on the PATH (matplotlib's FFMpegWriter), and it was not "
                "found; save a .gif instead (Pillow, installed with matplotlib)"
            )
    if isinstance(fps, bool) or not isinstance(fps, (int, np.integer)) or fps < 1:
        raise ValueError(f"fps must be a positive integer; got {fps!r}")
    if follow is not None and not isinstance(follow, (bool, np.bool_)):
        raise ValueError(f"follow must be True, False or None; got {follow!r}")
    plt = _plt()
    system = known_system(getattr(sol, "problem", None))
    style_table: dict[str, dict[str, Any]] = {}
    own = False  # drawing with the example's own drawing
    if draw is None:
        if system is not None:
            draw, default_trail, own = system.draw, system.trail, True
            style_table = {k: dict(v) for k, v in system.styles.items()}
        else:
            draw, default_trail = _generic_draw, "point"
    else:
        default_trail = None
        own = system is not None and draw is system.draw
    if follow is None:
        follow = bool(own and system.follow)
    for name, kw in dict(styles or {}).items():
        style_table[name] = {**style_table.get(name, {}), **dict(kw)}

    times, qs = frame_states(sol, frames)
    args = getattr(sol, "args", None)
    first = _shapes(draw, float(times[0]), qs[0], args)
    shapes = [first] + [_shapes(draw, float(tk), qk, args, first) for tk, qk in zip(times[1:], qs[1:])]
    names = list(first)
    trails = _trail_names(trail, default_trail, names)
    dim = first[names[0]].shape[1]
    points = np.concatenate([a for frame in shapes for a in frame.values()])
    limits = _limits(points, dim)
    if follow:
        centres, half = _windows(shapes)
        limits[:2] = [(float(centres[0, i]) - half, float(centres[0, i]) + half) for i in range(2)]
        if dim == 3:  # the height padded in proportion to the window, not to the whole run
            pad, low = 0.12 * half, float(points[:, 2].min())
            limits[2] = (low - pad if low < 0.0 else low, float(points[:, 2].max()) + pad)

    fig = plt.figure(figsize=figsize, dpi=dpi)
    if dim == 3:
        ax = fig.add_subplot(projection="3d")
        ax.set_xlim(*limits[0])
        ax.set_ylim(*limits[1])
        ax.set_zlim(min(limits[2][0], 0.0), limits[2][1])
        spans = [hi - lo for lo, hi in (limits[0], limits[1], (min(limits[2][0], 0.0), limits[2][1]))]
        ax.set_box_aspect(spans, zoom=FOLLOW_ZOOM if follow else 1.0)
        if follow:  # grid lines that move in every frame triple the size of a GIF
            ax.grid(False)
        if own and system.view is not None:
            ax.view_init(*system.view)
        axes = system.axes if (own and system.axes is not None) else ("x", "y", "z")
        ax.set_xlabel(axes[0])
        ax.set_ylabel(axes[1])
        ax.set_zlabel(axes[2])
        ax.tick_params(labelsize=7)
    else:
        ax = fig.add_subplot()
        ax.set_xlim(*limits[0])
        ax.set_ylim(*limits[1])
        ax.set_aspect("equal")
        ax.grid(True, alpha=0.3)
        labels = system.labels if own else ("", "")
        ax.set_xlabel(labels[0])
        ax.set_ylabel(labels[1])
    traces = []  # (faint whole path, growing trail, track)
    if trails:
        fine_t, fine_q = frame_states(sol, int(frames) * TRAIL_DENSITY)
        fine = [_shapes(draw, float(tk), qk, args, first) for tk, qk in zip(fine_t, fine_q)]
        sign = 1.0 if times[-1] >= times[0] else -1.0
        span = abs(float(times[-1] - times[0])) or 1.0
        cut = np.searchsorted(sign * fine_t, sign * times + 1e-9 * span, side="right")
        for k, name in enumerate(trails):
            track = np.array([frame[name][0] for frame in fine])
            faint = ax.plot(*track.T, color="0.8", lw=1.0, gid="path")[0]
            grow = ax.plot(*track[:1].T, color=TRAIL_COLORS[k % len(TRAIL_COLORS)], lw=1.2, gid="trail",
                           label=name)[0]
            traces.append((faint, grow, track))
    artists = {}
    for name in names:
        kw = dict(style_table.get(name, {}))
        if first[name].shape[0] == 1:
            kw.setdefault("marker", "o")
            kw.setdefault("ls", "none")
        artists[name] = ax.plot(*first[name].T, gid=name, **kw)[0]
    heading = title if title is not None else (system.name if own
                                               else getattr(getattr(sol, "problem", None), "name", ""))
    text = fig.suptitle("", fontsize=10)
    fig.subplots_adjust(left=0.14, right=0.96, bottom=0.1, top=0.9)

    def put(line, xyz):
        if dim == 3:
            line.set_data_3d(xyz[:, 0], xyz[:, 1], xyz[:, 2])
        else:
            line.set_data(xyz[:, 0], xyz[:, 1])

    def update(i):
        for name, line in artists.items():
            put(line, shapes[i][name])
        window = None
        if follow:
            lo, hi = centres[i] - half, centres[i] + half
            ax.set_xlim(lo[0], hi[0])
            ax.set_ylim(lo[1], hi[1])
            window = (lo, hi)
        for faint, grow, track in traces:
            upto = track[: max(int(cut[i]), 1)]
            if window is not None and dim == 3:  # 3-D axes do not clip lines to their limits
                outside = np.any((track[:, :2] < window[0]) | (track[:, :2] > window[1]), axis=1)
                shown = np.where(outside[:, None], np.nan, track)
                put(faint, shown)
                upto = shown[: len(upto)]
            put(grow, upto)
        text.set_text(f"{heading}   t = {times[i]:.3g}".strip())
        return [*artists.values(), text] + [line for trace in traces for line in trace[:2]]

    update(0)
    anim = animation.FuncAnimation(fig, update, frames=len(times), interval=1000.0 / fps, blit=False)
    if path is None:
        return anim
    writer = animation.PillowWriter(fps=fps) if path.suffix.lower() == ".gif" else animation.FFMpegWriter(fps=fps)
    try:
        anim.save(str(path), writer=writer, dpi=dpi)
    finally:
        plt.close(fig)
    return path
