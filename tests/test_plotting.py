"""``lobattodae.plot`` (the diagnostics figure) and ``lobattodae.animate`` (trajectory animations).

Small runs (tens to hundreds of steps) of a few examples, compiled once per module; the
figures are inspected through their artists (titles, labels, gids, data), the animations
through the files they write (Pillow counts a GIF's frames).
"""

import dataclasses
import gc
import subprocess
import sys

import jax.numpy as jnp
import matplotlib
import matplotlib.animation
import numpy as np
import pytest

import lobattodae as L
from lobattodae import _animation
from lobattodae._animation import _disk_shapes, frame_states
from lobattodae.examples import get_example

matplotlib.use("Agg")
import matplotlib.pyplot as plt

Image = pytest.importorskip("PIL.Image")

# animations returned for inspection are never rendered: matplotlib warns when they are collected
pytestmark = pytest.mark.filterwarnings("ignore:Animation was deleted without rendering")


@pytest.fixture(autouse=True)
def _close_figures():
    yield
    plt.close("all")


@pytest.fixture(scope="module")
def knife_run():
    """The knife edge, constant steps: 20 of h = 0.1 (s = 2)."""
    ex = get_example("knife-edge")
    sol = L.solve(ex.problem, L.LobattoIIIAIIIB(stages=2), ex.t_span, ex.q0, ex.p0, args=ex.args, n_steps=20)
    assert sol.success
    return ex, sol


@pytest.fixture(scope="module")
def sleigh_run():
    """The Chaplygin sleigh, adaptive steps with dense output (s = 3, rtol 1e-6)."""
    ex = get_example("sleigh")
    sol = L.solve(ex.problem, L.LobattoIIIAIIIB(stages=3), ex.t_span, ex.q0, ex.p0, args=ex.args,
                  rtol=1e-6, atol=1e-8, dense_output=True)
    assert sol.success and sol.stats["h"] is None and sol.stats["n_steps"] == len(sol.t) - 1
    return ex, sol


def _line(ax, gid):
    found = [a for a in ax.get_lines() if a.get_gid() == gid]
    assert len(found) == 1, (gid, [a.get_gid() for a in ax.get_lines()])
    return found[0]


def _legend_texts(ax):
    legend = ax.get_legend()
    return [t.get_text() for t in legend.get_texts()] if legend else []


# ------------------------------------------------------------------------------ plot
def test_import_lobattodae_does_not_import_matplotlib():
    code = "import sys, lobattodae; print('matplotlib' in sys.modules, 'PIL' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, check=True)
    assert out.stdout.split() == ["False", "False"]


def test_plot_constant_steps_title_panels_and_labels(knife_run):
    ex, sol = knife_run
    fig, axes = L.plot(sol, name=ex.name, invariants=dict(ex.invariants))
    title = fig._suptitle.get_text()
    for needle in ("knife-edge (knife edge)", "Lobatto IIIA–IIIB", "s = 2", "h = 0.1", "(20 steps)", "t ∈ [0, 2]"):
        assert needle in title, (needle, title)
    assert "rtol" not in title
    assert set(axes) == {"solution", "constraint", "invariants", "newton", "path", "summary", "histogram"}
    # constant steps: no step-size panel, h is in the title
    assert "step" not in axes
    # the solution: one line per coordinate, named as the example names them
    ax = axes["solution"]
    assert [line.get_label() for line in ax.get_lines()] == ["x", "y", "θ"]
    np.testing.assert_array_equal(_line(ax, "q2").get_ydata(), sol.q[:, 2])
    # the path in the plane: y against x
    ax = axes["path"]
    assert ax.get_xlabel() == "x" and ax.get_ylabel() == "y"
    np.testing.assert_array_equal(_line(ax, "path").get_xdata(), sol.q[:, 0])
    # every invariant of the example, by name
    texts = _legend_texts(axes["invariants"])
    assert any(t.startswith("|energy(t) − energy(t0)|") for t in texts)
    assert any(t.startswith("|p_theta(t) − p_theta(t0)|") for t in texts)
    assert axes["constraint"].get_yscale() == "log" and axes["invariants"].get_yscale() == "log"
    # Newton iterations: per step (few steps) and the histogram counts every step
    newton = _line(axes["newton"], "newton")
    assert newton.get_drawstyle() == "steps-post"
    np.testing.assert_array_equal(newton.get_xdata(), sol.t)
    heights = [p.get_height() for p in axes["histogram"].patches]
    assert sum(heights) == len(sol.stats["newton_iterations"]) == 20
    summary = [t.get_text() for t in axes["summary"].texts][0]
    assert "20 constant steps, h = 0.1" in summary and "max ‖φ‖∞ over all steps" in summary


def test_plot_adaptive_title_tolerances_and_step_sizes_as_steps(sleigh_run):
    ex, sol = sleigh_run
    fig, axes = L.plot(sol, name="sleigh", rtol=1e-6, atol=1e-8)
    title = fig._suptitle.get_text()
    assert "rtol = 1.0e-06, atol = 1.0e-08" in title and "s = 3" in title
    assert f"({sol.stats['n_steps']} steps, {sol.stats['n_rejected']} rejected)" in title
    # the step size: constant over each step interval [t_k, t_k+1), not a line between points
    step = _line(axes["step"], "step size")
    assert step.get_drawstyle() == "steps-post"
    h = np.abs(np.diff(sol.t))
    np.testing.assert_array_equal(step.get_xdata(), sol.t)
    np.testing.assert_array_equal(step.get_ydata(), np.append(h, h[-1]))
    assert axes["step"].get_yscale() == "log"
    # default invariant: the Hamiltonian
    assert any(t.startswith("|energy H(t) − energy H(t0)|") for t in _legend_texts(axes["invariants"]))
    # without the tolerances the title says what it knows
    fig, _ = L.plot(sol)
    assert "adaptive steps" in fig._suptitle.get_text() and "rtol" not in fig._suptitle.get_text()


def test_plot_adaptive_without_every_step_in_the_rows_has_no_step_panel(sleigh_run):
    _, sol = sleigh_run
    rows = np.arange(0, len(sol.t), 3)  # as save_every=3 keeps them
    stats = {**sol.stats, "constraint_residual": sol.stats["constraint_residual"][rows],
             "newton_iterations": sol.stats["newton_iterations"][rows[1:] - 1]}
    sparse = dataclasses.replace(sol, t=sol.t[rows], q=sol.q[rows], p=sol.p[rows], lam=sol.lam[rows], stats=stats)
    fig, axes = L.plot(sparse)
    assert "step" not in axes
    assert "rows are not every step" in axes["summary"].texts[0].get_text()


def test_exact_zeros_are_counted_and_marked_not_clipped(knife_run):
    _, sol = knife_run
    res = np.full(len(sol.t), 2.0e-16)
    zero_rows = [0, 3, 4, 11]
    res[zero_rows] = 0.0
    res[7] = 3.0e-17
    fake = dataclasses.replace(sol, stats={**sol.stats, "constraint_residual": res})
    fig, axes = L.plot(fake, invariants={})
    ax = axes["constraint"]
    phi = _line(ax, "phi")
    y = np.asarray(phi.get_ydata())
    # the log line holds exactly the positive values, none raised to a floor
    assert len(y) == len(sol.t) - len(zero_rows)
    assert y.min() == 3.0e-17 and np.all(y > 0)
    np.testing.assert_array_equal(np.sort(y), np.sort(res[res > 0]))
    # the zeros: counted in the legend and drawn as ticks at their times in the "= 0" band
    assert any(f"= 0 exactly at {len(zero_rows)} of {len(sol.t)} rows" in t for t in _legend_texts(ax))
    ticks = _line(ax, "phi=0")
    np.testing.assert_array_equal(ticks.get_xdata(), sol.t[zero_rows])
    assert any(p.get_gid() == "zero band" for p in ax.patches)
    assert any(t.get_text() == "= 0" for t in ax.texts)
    # the band is below the data: the smallest value sits above the band's top
    lo, hi = np.log10(ax.get_ylim())
    assert (np.log10(y.min()) - lo) / (hi - lo) > _plotting_band()
    # every row exactly zero: no data on the log scale, still a sensible figure
    fake0 = dataclasses.replace(sol, stats={**sol.stats, "constraint_residual": np.zeros(len(sol.t))})
    fig, axes = L.plot(fake0, invariants={})
    assert len(_line(axes["constraint"], "phi").get_ydata()) == 0
    assert len(_line(axes["constraint"], "phi=0").get_xdata()) == len(sol.t)
    assert np.all(np.isfinite(axes["constraint"].get_ylim()))


def _plotting_band():
    from lobattodae._plotting import _BAND

    return _BAND


def test_newton_iterations_moving_summary_for_many_steps(knife_run):
    ex, _ = knife_run
    sol = L.solve(ex.problem, L.LobattoIIIAIIIB(stages=2), ex.t_span, ex.q0, ex.p0, args=ex.args, n_steps=1000)
    fig, axes = L.plot(sol)
    ax = axes["newton"]
    mean = _line(ax, "newton")
    assert mean.get_drawstyle() == "steps-post"
    assert "mean per 5 steps" in mean.get_label()  # 1000 steps in 200 bins
    assert len(mean.get_xdata()) == 201
    assert [c.get_gid() for c in ax.collections] == ["newton range"]
    heights = [p.get_height() for p in axes["histogram"].patches]
    assert sum(heights) == 1000


def _with_holonomic(sol):
    """``sol`` as if its problem had a holonomic constraint ψ(q) = q_0 − q_1 (plot is a view on
    a Solution: no new solve, no compilation of a new loop)."""
    p = sol.problem
    problem = L.PartitionedDAE(f=p.f, g=p.g, phi=p.phi, name="with ψ",
                               position_constraint=lambda t, q, args: jnp.array([q[0] - q[1]]))
    return dataclasses.replace(sol, problem=problem)


def test_plot_holonomic_residual_and_no_hamiltonian(knife_run):
    _, sol = knife_run
    fig, axes = L.plot(_with_holonomic(sol))
    texts = _legend_texts(axes["constraint"])
    assert any(t.startswith("‖φ(q_k, p_k)‖∞") for t in texts)
    assert any(t.startswith("|ψ(q_k)|∞ (holonomic)") for t in texts)
    psi = _line(axes["constraint"], "psi")
    values = np.abs(sol.q[:, 0] - sol.q[:, 1])
    np.testing.assert_allclose(psi.get_ydata(), values[values > 0], rtol=1e-15)
    assert len(_line(axes["constraint"], "psi=0").get_xdata()) == np.sum(values == 0) >= 1  # ψ(q_0) = 0
    assert f"max |ψ|∞ at the rows: {np.max(np.abs(sol.q[:, 0] - sol.q[:, 1])):.2e}" in axes["summary"].texts[0].get_text()
    # a PartitionedDAE has no Hamiltonian: no invariants panel unless given, no path unless asked
    assert "invariants" not in axes and "path" not in axes
    assert "with ψ" in fig._suptitle.get_text()
    # projections: a pair of indices, a callable, refused strings
    _, axes = L.plot(sol, projection=(1, 0))
    assert axes["path"].get_xlabel() == "y" and axes["path"].get_ylabel() == "x"
    _, axes = L.plot(sol, projection=lambda t, q, p: (t, q[:, 0] + q[:, 1]), invariants={})
    np.testing.assert_array_equal(_line(axes["path"], "path").get_ydata(), sol.q[:, 0] + sol.q[:, 1])
    assert "invariants" not in axes
    with pytest.raises(ValueError, match="projection"):
        L.plot(sol, projection="xy")
    with pytest.raises(ValueError, match="labels"):
        L.plot(sol, labels=["x"])


# ------------------------------------------------------------------------------ animate
def _gif_frames(path):
    with Image.open(path) as im:
        return im.n_frames, im.size


def test_animate_gif_subsamples_rows(knife_run, tmp_path):
    _, sol = knife_run  # 21 rows, no dense output
    out = L.animate(sol, tmp_path / "knife.gif", frames=10, fps=10)
    assert out == tmp_path / "knife.gif"
    assert _gif_frames(out) == (10, (360, 360))
    # never more frames than rows
    assert _gif_frames(L.animate(sol, tmp_path / "all.gif", frames=50, dpi=40, figsize=(3, 3)))[0] == 21
    times, q = frame_states(sol, 50)
    np.testing.assert_array_equal(times, sol.t)
    np.testing.assert_array_equal(q, sol.q)
    assert not plt.get_fignums()  # saved figures are closed


def test_frames_from_the_dense_output_are_equally_spaced(sleigh_run):
    _, sol = sleigh_run
    times, q = frame_states(sol, 12)
    np.testing.assert_allclose(times, np.linspace(sol.t[0], sol.t[-1], 12), rtol=0, atol=1e-15)
    np.testing.assert_allclose(q, sol.sol(times)[0], rtol=0, atol=0)
    with pytest.raises(ValueError, match="frames"):
        frame_states(sol, 1)


def test_animate_custom_drawing_and_its_errors(sleigh_run, tmp_path):
    _, sol = sleigh_run

    def draw(t, q, args):
        return {"dot": [q[0], q[1]], "stick": [[q[0], q[1]], [q[0] + np.cos(q[2]), q[1] + np.sin(q[2])]]}

    anim = L.animate(sol, draw=draw, frames=8, trail="dot")
    fig = anim._fig
    ax = fig.axes[0]
    gids = {line.get_gid() for line in ax.get_lines()}
    assert {"dot", "stick", "trail", "path"} <= gids
    anim._draw_frame(7)  # the last frame: the stick at the final state
    stick = _line(ax, "stick")
    _, q = frame_states(sol, 8)
    np.testing.assert_allclose(stick.get_xdata(), [q[-1, 0], q[-1, 0] + np.cos(q[-1, 2])])
    assert "t = " in fig._suptitle.get_text()
    del anim
    gc.collect()  # while the warning filter is on
    assert _gif_frames(L.animate(sol, tmp_path / "c.gif", draw=draw, frames=6, trail=None))[0] == 6

    with pytest.raises(ValueError, match=r"shape 'bad' must be an array of shape \(k, 2\) or \(k, 3\)"):
        L.animate(sol, draw=lambda t, q, a: {"bad": np.zeros((2, 4))}, frames=3)
    with pytest.raises(ValueError, match="mixes planar"):
        L.animate(sol, draw=lambda t, q, a: {"a": np.zeros((1, 2)), "b": np.zeros((1, 3))}, frames=3)
    with pytest.raises(ValueError, match="trail must be one of"):
        L.animate(sol, draw=draw, frames=3, trail="nothing")
    with pytest.raises(ValueError, match=r"\.gif \(Pillow\) or \.mp4"):
        L.animate(sol, tmp_path / "x.avi", frames=3)
    assert not (tmp_path / "x.avi").exists()


@pytest.mark.skipif(matplotlib.animation.writers.is_available("ffmpeg"), reason="ffmpeg is installed")
def test_animate_mp4_without_ffmpeg_says_so(knife_run, tmp_path):
    _, sol = knife_run
    with pytest.raises(ValueError, match="needs ffmpeg"):
        L.animate(sol, tmp_path / "x.mp4", frames=3)


def test_rolling_disk_is_drawn_in_3d(knife_run, tmp_path):
    ex = get_example("vertical-disk")
    t = np.linspace(*ex.t_span, 11)
    q, p, lam = ex.exact(t)  # the closed form as a Solution: no solve needed to draw it
    sol = dataclasses.replace(knife_run[1], t=t, q=q, p=p, lam=lam, problem=ex.problem, args=ex.args, sol=None)
    anim = L.animate(sol, frames=5)
    ax = anim._fig.axes[0]
    assert ax.name == "3d"
    assert {"rim", "spoke", "contact", "trail"} <= {line.get_gid() for line in ax.get_lines()}
    assert "vertical rolling disk" in anim._fig._suptitle.get_text()
    rim = _line(ax, "rim")
    z = rim.get_data_3d()[2]
    assert min(z) == pytest.approx(0.0, abs=1e-12) and max(z) == pytest.approx(2 * ex.args.R)
    del anim
    gc.collect()
    assert _gif_frames(L.animate(sol, tmp_path / "disk.gif", frames=5, dpi=40, figsize=(3, 3)))[0] == 5


@pytest.mark.parametrize("tilt", [0.0, 0.4, -0.7])
def test_disk_drawing_geometry(tilt):
    """The rim touches the plane at the contact point, its centre is at height R cos θ (the
    falling disk's potential m g R cos θ), it is a circle of radius R in the plane of the
    rolling direction, and the spoke turns backwards as ψ grows (rolling forwards)."""
    R, heading = 0.7, 0.9
    shapes = _disk_shapes(1.0, -2.0, tilt, heading, 0.0, R)
    rim, spoke, contact = shapes["rim"], shapes["spoke"], shapes["contact"][0]
    np.testing.assert_allclose(contact, [1.0, -2.0, 0.0])
    centre = spoke[0]
    assert centre[2] == pytest.approx(R * np.cos(tilt))
    np.testing.assert_allclose(np.linalg.norm(rim - centre, axis=1), R, rtol=1e-14)
    assert rim[:, 2].min() == pytest.approx(0.0, abs=1e-12)
    np.testing.assert_allclose(spoke[1], contact, atol=1e-14)  # spin 0: spoke at the contact point
    axis = np.cross(rim[0] - centre, rim[16] - centre)
    np.testing.assert_allclose(np.abs(axis @ np.array([np.cos(heading), np.sin(heading), 0.0])), 0.0, atol=1e-14)
    # the centre's offset: the falling disk's sign convention (mass matrix entry M_02 = −m R sin φ cos θ)
    np.testing.assert_allclose(centre[:2] - contact[:2], R * np.sin(tilt) * np.array([-np.sin(heading), np.cos(heading)]),
                               atol=1e-14)
    turned = _disk_shapes(1.0, -2.0, tilt, heading, 0.3, R)["spoke"][1]
    forward = np.array([np.cos(heading), np.sin(heading), 0.0])
    assert (turned - contact) @ forward < 0  # the contact-side spoke moves backwards


def test_known_systems_cover_the_planar_and_rolling_examples():
    for name, shape_names in [("falling-disk", {"rim", "spoke", "contact"}), ("vertical-disk", {"rim", "spoke", "contact"}),
                              ("sleigh", {"body", "heading", "blade", "contact"}), ("knife-edge", {"blade", "contact"}),
                              ("particle", {"particle"})]:
        ex = get_example(name)
        system = _animation.known_system(ex.problem)
        assert system is not None, name
        assert len(system.labels) == ex.n
        assert set(system.draw(0.0, ex.q0, ex.args)) == shape_names
        assert system.trail in shape_names
    sleigh = get_example("sleigh").problem
    same_functions = L.NonholonomicSystem(sleigh.hamiltonian, sleigh.constraint_matrix, name=sleigh.name)
    assert _animation.known_system(same_functions) is None  # by identity of the problem, not by name


# ------------------------------------------------------------------------------ the bicycle
@pytest.fixture(scope="module")
def bicycle():
    """The Whipple bicycle (SymPy model, built once per process: about 5 s), its benchmark
    args, and two consistent configurations from the model's own ``upright_state`` (pitch by
    Newton's method on ψ_F): upright, and rolled and steered, moved along and turned."""
    pytest.importorskip("sympy")
    from lobattodae.mechanics import bicycle as bike

    model = bike.whipple_bicycle()
    args = model.args()
    upright, _ = bike.upright_state(model, 4.6, args)
    leaning, _ = bike.upright_state(model, 4.6, args, roll=0.3, steer=0.5)
    # x, y, yaw and the wheel angles do not enter ψ_F: any values keep the state consistent
    leaning[[0, 1, 2, 6, 7]] = [2.0, -1.0, 0.7, -3.0, 1.2]
    return model, args, {"upright": upright, "rolled and steered": leaning}


def _bicycle_psi(model, q, args):
    return float(model.holonomic_residual(0.0, q, args)[0])


@pytest.mark.parametrize("state", ["upright", "rolled and steered"])
def test_bicycle_drawing_touches_the_ground_with_round_wheels(bicycle, state):
    """The drawing (x, −y, −z of the model's MPRS axes) puts both contact points on the ground,
    draws the rims as circles of radius rR and rF about the wheel centres through the contact
    points and never below the ground, and the rear contact is (x, y) of the coordinates."""
    model, args, states = bicycle
    q = states[state]
    assert abs(_bicycle_psi(model, q, args)) <= 1e-15  # the model's check: a consistent state
    shapes = _animation._whipple_bicycle(0.0, q, args)
    rear, front = shapes["rear contact"][0], shapes["front contact"][0]
    assert abs(rear[2]) <= 1e-12 and abs(front[2]) <= 1e-12
    np.testing.assert_allclose(rear[:2], [q[0], -q[1]], rtol=0, atol=1e-14)
    for wheel, radius, contact in (("rear", float(args["rR"]), rear), ("front", float(args["rF"]), front)):
        rim, spoke = shapes[f"{wheel} wheel"], shapes[f"{wheel} spoke"]
        centre = spoke[0]
        np.testing.assert_allclose(np.linalg.norm(rim - centre, axis=1), radius, rtol=1e-14)
        np.testing.assert_allclose(np.linalg.norm(spoke[1] - centre), radius, rtol=1e-14)
        normal = np.cross(rim[5] - centre, rim[21] - centre)
        normal /= np.linalg.norm(normal)
        np.testing.assert_allclose((rim - centre) @ normal, 0.0, atol=1e-14)  # a plane circle...
        assert abs((spoke[1] - centre) @ normal) <= 1e-14  # ...with the spoke in its plane
        np.testing.assert_allclose(rim[0], contact, atol=1e-15)
        assert rim[:, 2].min() >= -1e-12  # the contact is the rim's lowest point
        if wheel == "rear":  # the rear axle is tilted from the horizontal by the roll angle
            assert abs(normal[2]) == pytest.approx(np.sin(abs(q[3])), abs=1e-14)


def test_bicycle_drawing_front_contact_is_the_models(bicycle):
    """The drawing's front contact is the model's: its height is −ψ_F (the model's holonomic
    constraint, ``C_F·z + rF √(1 − (a·z)²)``) in any configuration, consistent or not."""
    model, args, _ = bicycle
    rng = np.random.default_rng(7)
    for _ in range(5):
        q = rng.uniform(-0.6, 0.6, size=8)
        height = _animation._whipple_bicycle(0.0, q, args)["front contact"][0, 2]
        psi = _bicycle_psi(model, q, args)
        assert abs(psi) > 1e-3  # off the constraint manifold
        assert height == pytest.approx(-psi, rel=1e-12, abs=1e-15)


def test_bicycle_drawing_directions(bicycle):
    """Positive roll leans right and positive steer turns the front wheel right (MPRS: y to the
    right, drawn as −y), height up; the reference geometry: wheelbase w, wheel centres at rR, rF."""
    _, args, states = bicycle
    up = _animation._whipple_bicycle(0.0, states["upright"], args)
    np.testing.assert_allclose(up["front contact"][0], [float(args["w"]), 0.0, 0.0], atol=1e-14)
    np.testing.assert_allclose(up["rear spoke"][0], [0.0, 0.0, float(args["rR"])], atol=1e-14)
    np.testing.assert_allclose(up["front spoke"][0], [float(args["w"]), 0.0, float(args["rF"])], atol=1e-14)
    assert up["rear frame"][:, 2].max() > 2 * float(args["rF"])  # upright, above the wheels
    np.testing.assert_allclose(up["rear spoke"][1], up["rear contact"][0], atol=1e-14)  # θ_R = 0: spoke down
    q = states["upright"].copy()
    q[6] = -0.3  # rolled forwards (θ̇_R = −v/rR): the spoke's lower end has moved backwards
    assert _animation._whipple_bicycle(0.0, q, args)["rear spoke"][1, 0] < -0.05
    q = states["rolled and steered"].copy()
    q[[0, 1, 2]] = 0.0  # heading along x
    lean = _animation._whipple_bicycle(0.0, q, args)
    assert lean["rear frame"][1, 1] < -0.1  # the rear frame's mass centre (rider) is right of the rear contact
    rim = lean["front wheel"]
    centre = lean["front spoke"][0]
    normal = np.cross(rim[5] - centre, rim[21] - centre)
    forward = np.cross(normal, [0.0, 0.0, 1.0])
    forward *= np.sign(forward[0])
    assert forward[1] < -0.3 * forward[0]  # heading right: −y in the drawing


def test_bicycle_is_a_known_system_and_is_followed(bicycle, knife_run, tmp_path):
    from lobattodae.mechanics import _bicycle

    model, args, states = bicycle
    system = _animation.known_system(model.problem)
    assert system is not None and system.name == "Whipple bicycle" and system.follow
    assert system.labels == _bicycle.COORDINATES and system.path == (0, 1)
    assert set(system.trail) == {"rear contact", "front contact"}
    # identity, not structure: another problem of the same class is not the bicycle
    assert _animation.known_system(dataclasses.replace(model.problem)) is None
    assert _animation.known_system(None) is None

    t = np.linspace(0.0, 1.0, 9)
    q = np.tile(states["rolled and steered"], (t.size, 1))
    q[:, 0] += 4.6 * t  # rolling along x (the holonomic constraint does not see x or the wheel angles)
    q[:, 6] -= 4.6 / float(args["rR"]) * t
    sol = dataclasses.replace(knife_run[1], t=t, q=q, p=np.zeros_like(q), lam=np.zeros((t.size, model.m)),
                              problem=model.problem, args=args, sol=None)
    anim = L.animate(sol, frames=5)
    ax = anim._fig.axes[0]
    assert ax.name == "3d" and ax.get_zlabel() == "−z" and ax.get_ylabel() == "−y"
    gids = [line.get_gid() for line in ax.get_lines()]
    assert gids.count("trail") == 2 and gids.count("path") == 2
    assert {"rear wheel", "front wheel", "rear spoke", "front spoke", "rear frame", "front frame"} <= set(gids)
    assert "Whipple bicycle" in anim._fig._suptitle.get_text()
    x0 = ax.get_xlim()
    anim._draw_frame(4)
    x4 = ax.get_xlim()
    # the view follows: the window keeps its width and moves with the bicycle (4.6 m)
    assert x4[1] - x4[0] == pytest.approx(x0[1] - x0[0]) and x4[0] - x0[0] == pytest.approx(4.6, abs=0.05)
    assert x4[1] - x4[0] < 3.0
    del anim
    gc.collect()
    assert _gif_frames(L.animate(sol, tmp_path / "bike.gif", frames=4, dpi=40, figsize=(3, 3)))[0] == 4
    # follow=False shows the whole run
    anim = L.animate(sol, frames=3, follow=False)
    assert anim._fig.axes[0].get_xlim()[1] - anim._fig.axes[0].get_xlim()[0] > 4.6
    del anim
    gc.collect()


def test_animate_several_trails_and_follow_for_any_drawing(sleigh_run):
    _, sol = sleigh_run

    def draw(t, q, args):
        return {"a": [q[0], q[1]], "b": [q[0] + 1.0, q[1]], "stick": [[q[0], q[1]], [q[0] + 1.0, q[1]]]}

    anim = L.animate(sol, draw=draw, frames=6, trail=["a", "b"], follow=True)
    ax = anim._fig.axes[0]
    trails = [line for line in ax.get_lines() if line.get_gid() == "trail"]
    assert [line.get_label() for line in trails] == ["a", "b"]
    assert trails[0].get_color() != trails[1].get_color()
    anim._draw_frame(5)
    _, q = frame_states(sol, 6)
    lo, hi = ax.get_xlim()
    assert lo < q[-1, 0] < hi and hi - lo < 1.5  # centred on the last state, one frame's size
    del anim
    gc.collect()
    with pytest.raises(ValueError, match="trail must be one of"):
        L.animate(sol, draw=draw, frames=3, trail=["a", "nothing"])
    with pytest.raises(ValueError, match="follow must be"):
        L.animate(sol, draw=draw, frames=3, follow="yes")
