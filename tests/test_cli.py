"""The command-line interface end to end: every command, its files, and bad arguments.

``main`` is called in-process (so compilations are shared between tests); one test runs
``python -m lobattodae`` in a subprocess to check the module entry point.
"""

import json
import os
import subprocess
import sys

import numpy as np
import pytest

import lobattodae as L
from lobattodae._cli import DEMO_EXAMPLE, build_parser, main
from lobattodae.examples import EXAMPLES, get_example, list_examples

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
RUN_STAGES = 3
RUN_STEPS = 50
#: ``run`` always compiles chunks of this length; the direct solves below use the same so
#: that they reuse the compilation.
RUN_CHUNK = 4096


def _is_png(path):
    data = path.read_bytes()
    return len(data) > 1000 and data[:8] == PNG_SIGNATURE


def _main(argv, capsys):
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


# ------------------------------------------------------------------------- examples
def test_examples_lists_every_registry_name(capsys):
    code, out, err = _main(["examples"], capsys)
    assert code == 0
    lines = out.strip().splitlines()
    assert len(lines) == len(EXAMPLES)
    listed = [line.split()[0] for line in lines]
    assert listed == list(EXAMPLES)
    for (name, desc), line in zip(list_examples(), lines):
        assert desc in line, (name, line)


def test_python_dash_m_entry_point():
    proc = subprocess.run(
        [sys.executable, "-m", "lobattodae", "examples"], capture_output=True, text=True, timeout=120
    )
    assert proc.returncode == 0, proc.stderr
    for name in EXAMPLES:
        assert name in proc.stdout


def test_python_dash_m_bad_argument_exit_code():
    proc = subprocess.run(
        [sys.executable, "-m", "lobattodae", "tableau", "1"], capture_output=True, text=True, timeout=120
    )
    assert proc.returncode == 2
    assert "stages must be >= 2" in proc.stderr


def _cli_subprocess(argv, env_update):
    env = {k: v for k, v in os.environ.items() if k != "LOBATTODAE_NO_CACHE"}
    env.update(env_update)
    return subprocess.run(
        [sys.executable, "-m", "lobattodae", *argv], capture_output=True, text=True, timeout=300, env=env
    )


def test_cli_persistent_compilation_cache(tmp_path):
    """`run` stores its compiled step loop in $LOBATTODAE_CACHE_DIR, a second process reuses
    it (no new entries, same numbers), and LOBATTODAE_NO_CACHE=1 keeps it off."""
    cache = tmp_path / "cache"
    argv = ["run", "--example", "knife-edge", "--stages", "2", "--n-steps", "20", "--no-progress"]
    first = _cli_subprocess([*argv, "--save", str(tmp_path / "a.npz")], {"LOBATTODAE_CACHE_DIR": str(cache)})
    assert first.returncode == 0, first.stderr
    entries = sorted(p.name for p in cache.iterdir())
    assert entries, "the compiled step loop was not written to the cache"
    second = _cli_subprocess([*argv, "--save", str(tmp_path / "b.npz")], {"LOBATTODAE_CACHE_DIR": str(cache)})
    assert second.returncode == 0, second.stderr
    assert sorted(p.name for p in cache.iterdir()) == entries  # everything came from the cache
    with np.load(tmp_path / "a.npz") as a, np.load(tmp_path / "b.npz") as b:
        np.testing.assert_array_equal(a["q"], b["q"])
    off = tmp_path / "off"
    third = _cli_subprocess(argv, {"LOBATTODAE_CACHE_DIR": str(off), "LOBATTODAE_NO_CACHE": "1"})
    assert third.returncode == 0, third.stderr
    assert not off.exists()


def test_cache_dir_environment_variable_enables_cache_on_import(tmp_path):
    """A library user sets LOBATTODAE_CACHE_DIR: `import lobattodae` switches the cache on."""
    cache = tmp_path / "libcache"
    code = (
        "import lobattodae as L; from lobattodae.examples import get_example; "
        "ex = get_example('knife-edge'); "
        "L.solve(ex.problem, L.LobattoIIIAIIIB(stages=2), (0.0, 0.2), ex.q0, ex.p0, n_steps=4, args=ex.args)"
    )
    env = {k: v for k, v in os.environ.items() if k != "LOBATTODAE_NO_CACHE"}
    env["LOBATTODAE_CACHE_DIR"] = str(cache)
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300, env=env)
    assert proc.returncode == 0, proc.stderr
    assert cache.is_dir() and any(cache.iterdir())


def test_enable_compilation_cache_unwritable_directory(tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("")
    with pytest.raises(ValueError, match="cannot create the compilation cache directory"):
        L.enable_compilation_cache(blocker / "sub")


# -------------------------------------------------------------------------- tableau
def test_tableau_check_prints_coefficients_and_assumptions(capsys):
    code, out, err = _main(["tableau", "3", "--check"], capsys)
    assert code == 0
    pair = L.lobatto_pair(3)
    assert "s = 3" in out
    # the coefficients: c = (0, 1/2, 1), b = (1/6, 2/3, 1/6), a_23 = -1/24 (IIIA), â_12 = -1/6 (IIIB)
    assert "c = [0.  0.5 1. ]" in out
    for value in (1 / 6, 2 / 3, 5 / 24, -1 / 24):
        assert repr(float(np.float64(value)))[:12] in out, value
    assert np.isclose(pair.a[1, 2], -1 / 24)
    assert "A (IIIA)" in out and "A_hat (IIIB)" in out
    # the assumption table with the values of DESIGN.md for s = 3
    for text in ("B(4)", "C(3)", "D(1)", "C_hat(1)", "D_hat(3)", "CC_hat(3)", "DD_hat(3)"):
        assert text in out, text
    for hyp in ("H1 ", "H2 ", "H3 ", "H1'", "H2'"):
        assert hyp in out, hyp
    assert "R(infinity)                : +1" in out
    # predicted orders: q, p 4 and λ 2
    tail = out[out.index("Predicted global orders"):]
    assert [line.split()[-1] for line in tail.splitlines()[1:4]] == ["4", "4", "2"]


def test_tableau_without_check_has_no_assumption_table(capsys):
    code, out, _ = _main(["tableau", "4"], capsys)
    assert code == 0
    assert "s = 4" in out and "A_hat (IIIB)" in out
    assert "Simplifying assumptions" not in out and "Hypotheses" not in out


# ---------------------------------------------------------------------- convergence
@pytest.fixture(scope="module")
def convergence_files(tmp_path_factory):
    d = tmp_path_factory.mktemp("conv")
    png, js = d / "conv.png", d / "conv.json"
    import contextlib
    import io

    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        code = main(["convergence", "--example", "knife-edge", "--stages", "2", "3",
                     "--plot", str(png), "--json", str(js)])
    return code, out.getvalue(), png, js


def test_convergence_writes_png_and_json(convergence_files):
    code, out, png, js = convergence_files
    assert code == 0
    assert _is_png(png)
    data = json.loads(js.read_text())
    assert data["name"] == "knife-edge" and data["reference"] == "exact"
    assert data["stages"] == [2, 3]
    for s, q_order in ((2, 2), (3, 4)):
        run = data["runs"][str(s)]
        assert abs(run["observed_order"]["q"] - q_order) <= 0.3
        assert abs(run["observed_order"]["p"] - q_order) <= 0.3
        assert run["expected_order"] == {"q": 2 * s - 2, "p": 2 * s - 2, "lam": 2}
        assert run["max_constraint_residual"] <= 1e-12
        n = run["n_steps"]
        assert len(run["h"]) == len(n) == len(run["errors"]["q"])
        np.testing.assert_allclose(np.asarray(run["h"]) * np.asarray(n), 2.0, rtol=1e-12)
        # errors decrease with h
        assert run["errors"]["q"][-1] < run["errors"]["q"][0]
    assert f"wrote {js}" in out and f"wrote {png}" in out


def test_convergence_prints_table(convergence_files):
    code, out, _, _ = convergence_files
    assert "Convergence study: knife-edge" in out
    rows = [line for line in out.splitlines() if line.strip().startswith(("2 |", "3 |"))]
    assert len(rows) == 2
    # q observed and theory columns of the s = 3 row
    cols = rows[1].split("|")[1].split()
    assert abs(float(cols[0]) - 4) <= 0.3 and cols[1] == "4"


# ------------------------------------------------------------------------------ run
def _run_method(stages):
    """The method ``run`` uses: its ``--lam-start`` default, where the option exists."""
    ns = build_parser().parse_args(["run", "--example", "particle", "--stages", str(stages), "--n-steps", "1"])
    return L.LobattoIIIAIIIB(stages=stages, lam_start=getattr(ns, "lam_start", "previous"))


@pytest.fixture(scope="module")
def particle_direct():
    ex = get_example("particle")
    sol = L.solve(ex.problem, _run_method(RUN_STAGES), ex.t_span, ex.q0, ex.p0,
                  n_steps=RUN_STEPS, args=ex.args, chunk_size=RUN_CHUNK)
    assert sol.success
    return ex, sol


def _run_particle(tmp_path, capsys, *extra):
    return _main(["run", "--example", "particle", "--stages", RUN_STAGES, "--n-steps", RUN_STEPS,
                  "--no-progress", *extra], capsys)


def test_run_save_npz_matches_direct_solve(tmp_path, capsys, particle_direct):
    ex, sol = particle_direct
    f = tmp_path / "sol.npz"
    code, out, err = _run_particle(tmp_path, capsys, "--save", f)
    assert code == 0, err
    assert f"wrote {f}" in out
    assert "steps: 50 of 50" in out
    with np.load(f) as z:
        assert z["t"].shape == (RUN_STEPS + 1,)
        assert z["q"].shape == z["p"].shape == (RUN_STEPS + 1, 3)
        assert z["lam"].shape == (RUN_STEPS + 1, 1)
        assert z["constraint_residual"].shape == (RUN_STEPS + 1,)
        assert z["newton_iterations"].shape == (RUN_STEPS,)
        assert int(z["status"]) == 0
        assert float(z["h"]) == pytest.approx(2.0 / RUN_STEPS, rel=1e-15)
        for key in ("t", "q", "p", "lam"):
            np.testing.assert_allclose(z[key], getattr(sol, key), rtol=0, atol=1e-12, err_msg=key)
        assert np.max(z["constraint_residual"]) <= 1e-12
    # and the saved solution is the right one: 4th order accurate against the closed form
    qe, _, _ = ex.exact(sol.t)
    assert np.max(np.abs(sol.q - qe)) < 1e-5


def test_run_save_csv_matches_direct_solve(tmp_path, capsys, particle_direct):
    _, sol = particle_direct
    f = tmp_path / "sol.csv"
    code, out, err = _run_particle(tmp_path, capsys, "--save", f)
    assert code == 0, err
    lines = f.read_text().splitlines()
    assert lines[0] == "t,q0,q1,q2,p0,p1,p2,lam0"
    assert len(lines) == RUN_STEPS + 2
    data = np.loadtxt(f, delimiter=",", skiprows=1)
    assert data.shape == (RUN_STEPS + 1, 8)
    expected = np.column_stack([sol.t, sol.q, sol.p, sol.lam])
    np.testing.assert_allclose(data, expected, rtol=0, atol=1e-12)


def test_run_plot_writes_png(tmp_path, capsys):
    f = tmp_path / "diag.png"
    code, out, err = _run_particle(tmp_path, capsys, "--plot", f)
    assert code == 0, err
    assert _is_png(f)
    # the report: success message, constraint and every invariant of the example
    assert "successfully reached the end" in out
    for name in get_example("particle").invariants:
        assert f"max |{name}(t) - {name}(0)|" in out
    phi_line = next(line for line in out.splitlines() if line.startswith("max ‖φ"))
    assert float(phi_line.split("=")[-1]) <= 1e-12


def test_run_dt_and_t1(tmp_path, capsys):
    f = tmp_path / "sol.npz"
    # dt = 0.3 on [0, 1]: ceil(1/0.3) = 4 steps of 0.25
    code, out, err = _main(["run", "--example", "particle", "--stages", "2", "--dt", "0.3", "--t1", "1",
                            "--no-progress", "--save", f], capsys)
    assert code == 0, err
    with np.load(f) as z:
        np.testing.assert_allclose(z["t"], [0.0, 0.25, 0.5, 0.75, 1.0], rtol=0, atol=1e-15)
        assert float(z["h"]) == 0.25
    assert "steps: 4 of 4" in out


# ----------------------------------------------------------------------------- demo
def test_demo_prints_table_and_writes_plot(tmp_path, capsys):
    # knife-edge reuses the compilations of the convergence test above (the default
    # example, the sleigh, is covered by tests/test_orders.py).
    f = tmp_path / "demo.png"
    code, out, err = _main(["demo", "--example", "knife-edge", "--stages", "2", "3", "--plot", f], capsys)
    assert code == 0, err
    assert "Convergence study: knife-edge" in out
    assert "max constraint residual" in out
    rows = [line for line in out.splitlines() if line.strip().startswith(("2 |", "3 |"))]
    assert len(rows) == 2
    assert _is_png(f)


def test_demo_defaults():
    ns = build_parser().parse_args(["demo"])
    assert ns.example == DEMO_EXAMPLE and ns.stages == [2, 3, 4, 5] and ns.plot == "convergence.png"
    assert get_example(DEMO_EXAMPLE).exact is not None  # the demo needs a closed form


# ---------------------------------------------------------------------- bad arguments
@pytest.mark.parametrize(
    "argv, needles",
    [
        (["run", "--example", "no-such", "--n-steps", "5"], ["unknown example 'no-such'", "knife-edge"]),
        (["convergence", "--example", "bogus"], ["unknown example 'bogus'"]),
        (["tableau", "1"], ["stages must be >= 2", "got 1"]),
        (["tableau", "two"], ["expected a positive integer", "'two'"]),
        (["convergence", "--example", "knife-edge", "--stages", "1"], ["stages must be >= 2"]),
        (["run", "--example", "particle", "--stages", "1", "--n-steps", "5"], ["stages must be >= 2"]),
        (["run", "--example", "particle", "--dt", "-0.1"], ["--dt", "positive finite number", "-0.1"]),
        (["run", "--example", "particle", "--dt=-0.1"], ["--dt", "positive finite number"]),
        (["run", "--example", "particle", "--dt", "0"], ["--dt", "positive finite number"]),
        (["run", "--example", "particle", "--dt", "nan"], ["--dt", "positive finite number"]),
        (["run", "--example", "particle", "--n-steps", "0"], ["--n-steps", "positive integer"]),
        (["run", "--example", "particle", "--n-steps", "-3"], ["--n-steps", "positive integer"]),
        (["run", "--example", "particle", "--t1", "-1", "--n-steps", "5"], ["--t1", "positive"]),
        (["run", "--example", "particle", "--dt", "0.1", "--n-steps", "5"], ["not allowed with argument"]),
        (["run", "--example", "particle"], ["one of the arguments --dt --n-steps is required"]),
        (["run", "--n-steps", "5"], ["required", "--example"]),
        (["convergence"], ["required", "--example"]),
        (["tableau"], ["required", "s"]),
        ([], ["required", "command"]),
        (["frobnicate"], ["invalid choice", "frobnicate"]),
    ],
)
def test_bad_arguments_exit_2_with_message(argv, needles, capsys):
    code, out, err = _main(argv, capsys)
    assert code == 2, (argv, out, err)
    assert err.startswith("lobattodae"), err
    for needle in needles:
        assert needle in err, (needle, err)


@pytest.mark.parametrize(
    "argv, needles",
    [
        (["run", "--example", "particle", "--n-steps", "5", "--save", "{d}/sol.txt"], ["--save", ".npz or .csv", "sol.txt"]),
        (["run", "--example", "particle", "--n-steps", "5", "--save", "{d}/sol"], ["--save", ".npz or .csv"]),
        (["run", "--example", "particle", "--n-steps", "5", "--plot", "{d}/d.pdf"], ["--plot", ".png", "d.pdf"]),
        (["convergence", "--example", "knife-edge", "--json", "{d}/c.txt"], ["--json", ".json"]),
        (["convergence", "--example", "knife-edge", "--plot", "{d}/c.jpg"], ["--plot", ".png"]),
        (["demo", "--plot", "{d}/c.svg"], ["--plot", ".png"]),
    ],
)
def test_bad_file_suffix_rejected_before_any_work(argv, needles, tmp_path, capsys):
    argv = [a.format(d=tmp_path) for a in argv]
    code, out, err = _main(argv, capsys)
    assert code == 2, (out, err)
    for needle in needles:
        assert needle in err, (needle, err)
    # rejected up front: nothing was computed or written
    assert out == ""
    assert list(tmp_path.iterdir()) == []


def test_help_exits_zero(capsys):
    code, out, _ = _main(["run", "--help"], capsys)
    assert code == 0
    assert "--n-steps" in out and "--save" in out


# ----------------------------------------------------------------- solver failure in run
def test_run_newton_failure_nonzero_exit_with_message(tmp_path, capsys):
    f = tmp_path / "prefix.npz"
    code, out, err = _main(["run", "--example", "falling-disk-general", "--stages", "2", "--dt", "10",
                            "--no-progress", "--save", f], capsys)
    assert code == 1, (out, err)
    assert "Step 0 (t = 0" in out and "failed" in out
    # the computed prefix (here only the initial point) is still written
    with np.load(f) as z:
        assert int(z["status"]) != 0
        assert z["q"].shape[0] == 1 and np.all(np.isfinite(z["q"]))
