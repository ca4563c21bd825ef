"""The command-line interface end to end: every command, its files, and bad arguments.

``main`` is called in-process (so compilations are shared between tests); a few tests run
``python -m lobattodae`` in a subprocess: the module entry point and the persistent compilation
cache. Checkpoints, SIGTERM to a running integration and ``--resume``: ``test_resume.py``.
"""

import json
import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

import lobattodae as L
from lobattodae import _cli
from lobattodae._cli import DEMO_EXAMPLE, build_parser, main
from lobattodae._chunks import CHUNK as RUN_CHUNK
from lobattodae.examples import EXAMPLES, get_example, list_examples

from helpers import RUN_STAGES, RUN_STEPS, cli_method, run_cli

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def _is_png(path):
    data = path.read_bytes()
    return len(data) > 1000 and data[:8] == PNG_SIGNATURE


# ------------------------------------------------------------------------- examples
def test_examples_lists_every_registry_name(capsys):
    code, out, err = run_cli(["examples"], capsys)
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


def test_output_into_a_closed_pipe_stops_quietly():
    """`lobattodae ... | head -1`: the reader is gone; exit 141 (SIGPIPE) without a traceback."""
    read_end, write_end = os.pipe()
    os.close(read_end)  # every write fails with EPIPE
    try:
        proc = subprocess.run([sys.executable, "-m", "lobattodae", "tableau", "5", "--check"], stdout=write_end,
                              stderr=subprocess.PIPE, text=True, timeout=120)
    finally:
        os.close(write_end)
    assert proc.returncode == _cli.EXIT_BROKEN_PIPE == 141
    assert "Traceback" not in proc.stderr and "BrokenPipeError" not in proc.stderr, proc.stderr


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


def test_a_cache_entry_without_access_time_does_not_break_eviction(tmp_path):
    """An entry left without its access-time file (by a process with an unbounded cache in the
    same directory) made JAX's bounded cache fail at every write ("Error writing persistent
    compilation cache entry"): the library gives such entries one, and bounds every cache it
    switches on (the command line's too)."""
    cache = tmp_path / "xdg" / "lobattodae"
    cache.mkdir(parents=True)
    (cache / "jit_left_behind-0123-cache").write_bytes(b"x" * 64)
    code = (
        "import jax, lobattodae as L; from lobattodae.examples import get_example; "
        "ex = get_example('knife-edge'); "
        "L.solve(ex.problem, L.LobattoIIIAIIIB(stages=2), (0.0, 0.2), ex.q0, ex.p0, n_steps=4, args=ex.args); "
        "print(jax.config.jax_compilation_cache_max_size)"
    )
    env = {k: v for k, v in os.environ.items() if k not in ("LOBATTODAE_NO_CACHE", "LOBATTODAE_CACHE_DIR")}
    env.update(XDG_CACHE_HOME=str(tmp_path / "xdg"), JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS="0")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300, env=env)
    assert proc.returncode == 0, proc.stderr
    assert "Error writing persistent compilation cache" not in proc.stderr
    assert (cache / "jit_left_behind-0123-atime").is_file()
    assert len(list(cache.glob("*-cache"))) > 1  # the solve's programs were stored
    assert proc.stdout.strip() == str(1 << 30)


def test_enable_compilation_cache_unwritable_directory(tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("")
    with pytest.raises(ValueError, match="cannot create the compilation cache directory"):
        L.enable_compilation_cache(blocker / "sub")


# -------------------------------------------------------------------------- tableau
def test_tableau_check_prints_coefficients_and_assumptions(capsys):
    code, out, err = run_cli(["tableau", "3", "--check"], capsys)
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
    code, out, _ = run_cli(["tableau", "4"], capsys)
    assert code == 0
    assert "s = 4" in out and "A_hat (IIIB)" in out
    assert "Simplifying assumptions" not in out and "Hypotheses" not in out


def test_many_stages_warn_that_compilation_takes_long(capsys):
    assert _cli._stages(str(_cli.MANY_STAGES)) == _cli.MANY_STAGES
    assert capsys.readouterr().err == ""
    assert _cli._stages("24") == 24
    err = capsys.readouterr().err
    assert "--stages 24" in err and "compil" in err and "minutes" in err


def test_the_tableau_of_many_stages_does_not_warn(capsys):
    assert _cli.main(["tableau", "12"]) == 0
    assert "compil" not in capsys.readouterr().err


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


def test_convergence_single_step_count_prints_na_not_exact(convergence_files, capsys):
    """One step count: no order can be fitted (NaN); the table says n/a, never "exact".
    (s = 2 with 256 steps reuses the compilation of the study above.)"""
    code, out, err = run_cli(["convergence", "--example", "knife-edge", "--stages", "2", "--n-steps", "256"], capsys)
    assert code == 0, err
    row = next(line for line in out.splitlines() if line.strip().startswith("2 |"))
    assert "exact" not in row, row
    assert row.count("n/a") == 3, row
    assert "n/a: no order can be fitted" in out and "--n-steps" in out


# ------------------------------------------------------------------------------ run
def _run_particle(tmp_path, capsys, *extra):
    return run_cli(["run", "--example", "particle", "--stages", RUN_STAGES, "--n-steps", RUN_STEPS,
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
    # λ bookkeeping of the default --lam-start auto: no re-synchronisation on this problem
    assert f"λ re-synchronisations (--lam-start auto): 0 in {RUN_STEPS} steps" in out
    assert "warning" not in out.lower() and "lam_start" not in out + err


def test_run_dt_and_t1(tmp_path, capsys):
    f = tmp_path / "sol.npz"
    # dt = 0.3 on [0, 1]: ceil(1/0.3) = 4 steps of 0.25
    code, out, err = run_cli(["run", "--example", "particle", "--stages", "2", "--dt", "0.3", "--t1", "1",
                              "--no-progress", "--save", f], capsys)
    assert code == 0, err
    with np.load(f) as z:
        np.testing.assert_allclose(z["t"], [0.0, 0.25, 0.5, 0.75, 1.0], rtol=0, atol=1e-15)
        assert float(z["h"]) == 0.25
    assert "steps: 4 of 4, h = 0.25" in out


def test_run_adaptive_with_t_eval(tmp_path, capsys):
    f = tmp_path / "sol.npz"
    code, out, err = run_cli(["run", "--example", "particle", "--stages", "3", "--rtol", "1e-8", "--atol", "1e-10",
                              "--t1", "1", "--t-eval", "0.25", "0.5", "1.0", "--no-progress", "--save", f], capsys)
    assert code == 0, err
    with np.load(f) as z:
        np.testing.assert_array_equal(z["t"], [0.25, 0.5, 1.0])
    assert "rejected), 3 output rows" in out


class _SolveCalled(Exception):
    """Raised by a stand-in for ``solve``: the CLI got as far as starting the integration."""


def _forbid_integration(monkeypatch):
    """Any integration (``run``, ``convergence``, ``demo``) fails the test."""
    import lobattodae._convergence
    import lobattodae._solve

    def no_solve(*args, **kwargs):
        raise AssertionError("the integration ran although the options should have been refused")

    monkeypatch.setattr(lobattodae._solve, "solve", no_solve)
    monkeypatch.setattr(lobattodae._convergence, "solve", no_solve)


def _capture_solve(monkeypatch):
    """Replace ``solve`` by a stand-in that raises :class:`_SolveCalled` with its arguments."""
    import lobattodae._solve

    def fake(problem, method, t_span, q0, p0, **kwargs):
        raise _SolveCalled(method, kwargs)

    monkeypatch.setattr(lobattodae._solve, "solve", fake)


def test_lam_start_choices_and_default(monkeypatch, capsys):
    parse = build_parser().parse_args
    assert parse(["run", "--example", "particle", "--n-steps", "5"]).lam_start == "auto"
    assert L.LobattoIIIAIIIB().lam_start == "auto"  # the CLI's default is the library's
    _capture_solve(monkeypatch)
    argv = ["run", "--example", "particle", "--n-steps", "5"]
    for mode in ("auto", "previous", "consistent"):
        with pytest.raises(_SolveCalled) as called:
            main([*argv, "--lam-start", mode])
        method, _ = called.value.args
        assert method.lam_start == mode
    with pytest.raises(_SolveCalled) as called:
        main(argv)
    assert called.value.args[0].lam_start == "auto"
    code, out, err = run_cli([*argv, "--lam-start", "zero"], capsys)
    assert code == 2 and "invalid choice: 'zero'" in err and "auto" in err


def test_lam_start_help_one_line_per_mode(capsys, monkeypatch):
    monkeypatch.setenv("COLUMNS", "100")
    code, out, _ = run_cli(["run", "--help"], capsys)
    assert code == 0
    lines = [line.strip() for line in out.splitlines()]
    for mode in ("auto", "previous", "consistent"):
        line = next(line for line in lines if line.startswith(f"{mode}:"))
        assert len(line) > len(mode) + 10, line
    assert "(default)" in next(line for line in lines if line.startswith("auto:"))


def test_run_uses_the_library_progress_bar(monkeypatch):
    """One progress bar in the project: run passes progress=True (solve's bar) unless
    --no-progress."""
    assert not hasattr(_cli, "_DelayedProgress")
    _capture_solve(monkeypatch)
    argv = ["run", "--example", "particle", "--n-steps", "5"]
    with pytest.raises(_SolveCalled) as called:
        main(argv)
    assert called.value.args[1]["progress"] is True
    with pytest.raises(_SolveCalled) as called:
        main([*argv, "--no-progress"])
    assert called.value.args[1]["progress"] is False


@pytest.mark.parametrize(
    "argv, option",
    [
        (["run", "--example", "particle", "--n-steps", "5", "--save", "{d}/sol.npz"], "--save"),
        (["run", "--example", "particle", "--n-steps", "5", "--save", "{d}/sol.csv"], "--save"),
        (["run", "--example", "particle", "--n-steps", "5", "--plot", "{d}/diag.png"], "--plot"),
        (["run", "--example", "particle", "--n-steps", "5", "--checkpoint", "{d}/run.npz"], "--checkpoint"),
        (["run", "--example", "particle", "--n-steps", "5", "--checkpoint", "{d}/run.npz", "--resume"],
         "--checkpoint"),
        (["convergence", "--example", "knife-edge", "--json", "{d}/c.json"], "--json"),
        (["convergence", "--example", "knife-edge", "--plot", "{d}/c.png"], "--plot"),
        (["demo", "--stages", "2", "--plot", "{d}/c.png"], "--plot"),
    ],
)
def test_output_file_in_a_missing_directory_refused_before_any_work(argv, option, tmp_path, monkeypatch, capsys):
    _forbid_integration(monkeypatch)
    missing = tmp_path / "no" / "such"
    argv = [a.format(d=missing) for a in argv]
    path = argv[argv.index(option) + 1]
    start = time.perf_counter()
    code, out, err = run_cli(argv, capsys)
    assert time.perf_counter() - start < 5
    assert code == 2, (out, err)
    assert err.startswith("lobattodae: error:"), err
    for needle in (option, path, str(missing), "does not exist", "create it first"):
        assert needle in err, (needle, err)
    assert len(err.strip().splitlines()) == 1, err  # one line, no traceback
    assert out == ""
    assert list(tmp_path.iterdir()) == []


def test_output_path_that_is_a_directory_refused(tmp_path, monkeypatch, capsys):
    _forbid_integration(monkeypatch)
    (tmp_path / "sol.npz").mkdir()
    code, out, err = run_cli(["run", "--example", "particle", "--n-steps", "5", "--save", tmp_path / "sol.npz"], capsys)
    assert code == 2 and "--save" in err and "is a directory" in err


def test_output_file_in_a_read_only_directory_refused(tmp_path, monkeypatch, capsys):
    """A directory without write permission (simulated: root may write anywhere)."""
    _forbid_integration(monkeypatch)
    ro = tmp_path / "ro"
    ro.mkdir()
    real_access = os.access
    monkeypatch.setattr(os, "access", lambda p, mode, **kw: False if str(p) == str(ro) else real_access(p, mode, **kw))
    code, out, err = run_cli(["convergence", "--example", "knife-edge", "--json", ro / "c.json"], capsys)
    assert code == 2, (out, err)
    assert "--json" in err and str(ro / "c.json") in err and "not writable" in err


def test_run_lam_drift_warning_recommends_the_option(capsys):
    """The paper's scheme on the Chaplygin sleigh (s = 5, h = 0.1, t = 130): λ leaves its band;
    run prints the library's warning in the command line's words and recommends
    --lam-start auto (not the Python API)."""
    code, out, err = run_cli(["run", "--example", "sleigh", "--stages", "5", "--n-steps", "1300", "--t1", "130",
                              "--lam-start", "previous", "--no-progress"], capsys)
    assert code == 0, err
    lines = out.splitlines()
    assert lines[0] == "The solver successfully reached the end of the integration interval."
    excursions = next(line for line in lines if line.startswith("λ excursions out of the drift band"))
    assert int(excursions.split(":")[1].split(";")[0]) > 0
    warning = next(line for line in lines if line.startswith("warning: the multiplier λ_k left its normal band"))
    assert "--lam-start previous" in warning
    recommendation = next(line for line in lines if line.startswith("recommendation:"))
    assert "--lam-start auto" in recommendation
    assert "lam_start" not in out + err  # the Python spelling is not shown
    assert "RuntimeWarning" not in err  # shown once, in the report


def test_split_warning_and_cli_spelling():
    msg = "The solver successfully reached the end. Warning: λ drifted. Use lam_start='auto' or 'consistent'."
    head, warning = _cli._split_warning(msg)
    assert head == "The solver successfully reached the end."
    assert warning.startswith("λ drifted.")
    assert _cli._split_warning("done.") == ("done.", None)
    assert _cli._cli_spelling("With lam_start='previous' and lam_start = \"auto\"") == (
        "With --lam-start previous and --lam-start auto"
    )


# ------------------------------------------------------------------ interrupts and SIGTERM
@pytest.fixture
def restore_signals():
    saved = {sig: signal.getsignal(sig) for sig in (signal.SIGINT, signal.SIGTERM)}
    yield
    for sig, handler in saved.items():
        signal.signal(sig, handler)


def test_sigterm_handler_calls_the_installed_sigint_handler(restore_signals):
    calls = []
    signal.signal(signal.SIGINT, lambda signum, frame: calls.append((signum, frame)))
    _cli._sigterm_handler(signal.SIGTERM, None)
    assert calls == [(signal.SIGTERM, None)]
    for default in (signal.default_int_handler, signal.SIG_DFL, signal.SIG_IGN):
        signal.signal(signal.SIGINT, default)
        with pytest.raises(KeyboardInterrupt):
            _cli._sigterm_handler(signal.SIGTERM, None)


def _run_argv(*extra):
    return ["run", "--example", "particle", "--n-steps", "5", "--no-progress", *extra]


def test_sigterm_during_start_up_one_line_exit_130(monkeypatch, restore_signals, capsys):
    """SIGTERM before the integration (here: while the example is loaded) stops the program
    with one line and exit code 130; main restores the SIGTERM handler it found."""
    import lobattodae.examples

    before = signal.getsignal(signal.SIGTERM)

    def slow_start(name):
        os.kill(os.getpid(), signal.SIGTERM)
        time.sleep(5)  # the handler runs (and raises) right away
        raise AssertionError("SIGTERM did not stop the start-up")

    monkeypatch.setattr(lobattodae.examples, "get_example", slow_start)
    _forbid_integration(monkeypatch)
    start = time.perf_counter()
    code, out, err = run_cli(_run_argv(), capsys)
    assert time.perf_counter() - start < 4
    assert code == 130
    assert err == "lobattodae: interrupted\n" and out == ""
    assert signal.getsignal(signal.SIGTERM) is before


def test_ctrl_c_during_start_up_one_line_exit_130(monkeypatch, capsys):
    import lobattodae.examples

    def interrupted(name):
        raise KeyboardInterrupt

    monkeypatch.setattr(lobattodae.examples, "get_example", interrupted)
    code, out, err = run_cli(_run_argv(), capsys)
    assert code == 130
    assert err.strip() == "lobattodae: interrupted" and "Traceback" not in err


# ----------------------------------------------------------------------------- demo
def test_demo_prints_table_and_writes_plot(tmp_path, capsys):
    # knife-edge reuses the compilations of the convergence test above (the default
    # example, the sleigh, is covered by tests/verification/test_orders.py).
    f = tmp_path / "demo.png"
    code, out, err = run_cli(["demo", "--example", "knife-edge", "--stages", "2", "3", "--plot", f], capsys)
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
        # the library's rules and messages for the options of a run (tests/test_options.py)
        (["run", "--example", "particle", "--dt", "-0.1"], ["dt must be a positive finite step size; got dt=-0.1"]),
        (["run", "--example", "particle", "--dt=-0.1"], ["dt must be a positive finite step size"]),
        (["run", "--example", "particle", "--dt", "0"], ["dt must be a positive finite step size"]),
        (["run", "--example", "particle", "--dt", "nan"], ["dt must be a positive finite step size"]),
        (["run", "--example", "particle", "--dt", "x"], ["--dt", "expected a number", "'x'"]),
        (["run", "--example", "particle", "--n-steps", "0"], ["n_steps must be a positive integer; got n_steps=0"]),
        (["run", "--example", "particle", "--n-steps", "-3"], ["n_steps must be a positive integer"]),
        (["run", "--example", "particle", "--t1", "-1", "--n-steps", "5"], ["--t1", "positive"]),
        (["run", "--example", "particle", "--dt", "0.1", "--n-steps", "5"], ["not allowed with argument"]),
        (["run", "--example", "particle", "--rtol", "0"], ["rtol must be a positive finite number"]),
        (["run", "--n-steps", "5"], ["required", "--example"]),
        (["run", "--example", "particle", "--n-steps", "5", "--lam-start", "zero"],
         ["--lam-start", "invalid choice", "'zero'", "auto", "previous", "consistent"]),
        (["convergence"], ["required", "--example"]),
        (["tableau"], ["required", "s"]),
        ([], ["required", "command"]),
        (["frobnicate"], ["invalid choice", "frobnicate"]),
    ],
)
def test_bad_arguments_exit_2_with_message(argv, needles, capsys):
    code, out, err = run_cli(argv, capsys)
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
    code, out, err = run_cli(argv, capsys)
    assert code == 2, (out, err)
    for needle in needles:
        assert needle in err, (needle, err)
    # rejected up front: nothing was computed or written
    assert out == ""
    assert list(tmp_path.iterdir()) == []


def test_help_exits_zero(capsys):
    code, out, _ = run_cli(["run", "--help"], capsys)
    assert code == 0
    assert "--n-steps" in out and "--save" in out


# ----------------------------------------------------------------- solver failure in run
def test_run_newton_failure_nonzero_exit_with_message(tmp_path, capsys):
    f = tmp_path / "prefix.npz"
    code, out, err = run_cli(["run", "--example", "falling-disk-general", "--stages", "2", "--dt", "10",
                              "--no-progress", "--save", f], capsys)
    assert code == 1, (out, err)
    assert "Step 0 (t = 0" in out and "failed" in out
    # the computed prefix (here only the initial point) is still written
    with np.load(f) as z:
        assert int(z["status"]) != 0
        assert z["q"].shape[0] == 1 and np.all(np.isfinite(z["q"]))


# ------------------------------------------------------------------------- run --model
def test_run_model_dict_factory_plot_and_animation(model_module, particle_direct, tmp_path, capsys):
    _, sol = particle_direct
    f, png, gif = tmp_path / "sol.npz", tmp_path / "diag.png", tmp_path / "traj.gif"
    code, out, err = run_cli(["run", "--model", f"{model_module}:as_dict", "--stages", RUN_STAGES, "--n-steps",
                              RUN_STEPS, "--no-progress", "--save", f, "--plot", png, "--animate", gif, "--frames", 6],
                             capsys)
    assert code == 0, err
    assert "steps: 50 of 50" in out and "max |energy(t) - energy(0)|" in out  # the problem's H by default
    with np.load(f) as z:  # the same run as the example's
        for key in ("t", "q", "p", "lam"):
            np.testing.assert_allclose(z[key], getattr(sol, key), rtol=0, atol=1e-12, err_msg=key)
    assert _is_png(png) and f"wrote {png}" in out
    from PIL import Image

    with Image.open(gif) as im:  # the factory's own drawing, 6 frames
        assert im.n_frames == 6
    assert f"wrote {gif}" in out


def test_run_model_tuple_needs_t1_file_path_and_example(model_module, particle_direct, tmp_path, capsys):
    _, sol = particle_direct
    f = tmp_path / "sol.npz"
    base = ["run", "--stages", RUN_STAGES, "--n-steps", RUN_STEPS, "--no-progress", "--save", f]
    code, out, err = run_cli(base + ["--model", f"{model_module}:as_tuple", "--t1", "2"], capsys)
    assert code == 0, err
    with np.load(f) as z:
        np.testing.assert_allclose(z["q"], sol.q, rtol=0, atol=1e-12)
    # a tuple has no t_span: --t1 is needed, and the message says so (before any work)
    code, out, err = run_cli(["run", "--model", f"{model_module}:as_tuple", "--n-steps", "5"], capsys)
    assert code == 2 and "gives no t_span; pass --t1" in err and out == ""
    # FILE.py:FACTORY, returning an Example
    code, out, err = run_cli(base + ["--model", f"./{model_module}.py:as_example"], capsys)
    assert code == 0, err
    with np.load(f) as z:
        np.testing.assert_allclose(z["q"], sol.q, rtol=0, atol=1e-12)


@pytest.mark.parametrize(
    "spec, needles",
    [
        ("nocolon", ["--model must be MODULE:FACTORY", "got 'nocolon'"]),
        ("{m}:", ["--model must be MODULE:FACTORY"]),
        ("{m}:not-a-name", ["--model must be MODULE:FACTORY"]),
        ("no_such_module_xyz:f", ["cannot import 'no_such_module_xyz'", "ModuleNotFoundError",
                                  "No module named 'no_such_module_xyz'", "from the directory that contains it"]),
        ("{m}_broken:f", ["cannot import '{m}_broken'", "No module named 'missing_dependency_xyz'"]),
        ("{m}_syntax:f", ["cannot import '{m}_syntax'", "SyntaxError"]),
        ("missing_file.py:f", ["no such file 'missing_file.py'"]),
        ("{m}:nope", ["has no attribute 'nope'", "its functions:", "as_dict"]),
        ("{m}:NOT_CALLABLE", ["'NOT_CALLABLE' is a int, not a function"]),
        ("{m}:raises", ["the factory raises() raised ValueError: boom: bad parameter"]),
        ("{m}:returns_int", ["the factory returned int 42", "return (problem, q0, p0)"]),
        ("{m}:returns_pair", ["the factory returned a tuple of 2"]),
        ("{m}:dict_without_q0", ["a dict without 'q0'"]),
        ("{m}:dict_with_typo", ["unknown keys ['tspan']"]),
        ("{m}:not_a_problem", ["str 'sleigh' where the problem goes"]),
        ("{m}:q0_matrix", ["q0 = list [[0.0, 0.0, 0.0]]", "1-D array"]),
    ],
)
def test_run_model_errors_one_line_exit_2(spec, needles, model_module, monkeypatch, capsys):
    _forbid_integration(monkeypatch)
    spec = spec.format(m=model_module)
    code, out, err = run_cli(["run", "--model", spec, "--n-steps", "5", "--t1", "1"], capsys)
    assert code == 2, (out, err)
    assert out == ""
    assert err.startswith("lobattodae: error: --model"), err
    assert err.count("\n") == 1, err  # one line
    for needle in needles:
        assert needle.format(m=model_module) in err, (needle, err)


def test_run_example_and_model_are_exclusive(capsys):
    code, out, err = run_cli(["run", "--example", "particle", "--model", "m:f", "--n-steps", "5"], capsys)
    assert code == 2 and "not allowed with argument" in err


@pytest.mark.parametrize(
    "extra, needles",
    [
        (["--animate", "{d}/a.avi"], ["--animate", ".gif or .mp4"]),
        (["--frames", "10"], ["--frames needs --animate"]),
        (["--animate", "{d}/a.gif", "--frames", "1"], ["--frames must be >= 2"]),
    ]
    + ([] if __import__("matplotlib.animation").animation.writers.is_available("ffmpeg")
       else [(["--animate", "{d}/a.mp4"], ["needs ffmpeg", ".gif"])]),
)
def test_run_animation_options_checked_before_any_work(extra, needles, tmp_path, monkeypatch, capsys):
    _forbid_integration(monkeypatch)
    argv = ["run", "--example", "particle", "--n-steps", "5"] + [a.format(d=tmp_path) for a in extra]
    code, out, err = run_cli(argv, capsys)
    assert code == 2, (out, err)
    for needle in needles:
        assert needle in err, (needle, err)
    assert list(tmp_path.iterdir()) == []


def test_run_model_from_a_mechanics_model(tmp_path, monkeypatch, capsys):
    pytest.importorskip("sympy")
    from lobattodae import mechanics

    (tmp_path / "mech_models_cli.py").write_text(
        "from lobattodae import mechanics\n"
        "def sleigh():\n"
        "    return {'model': mechanics.systems.chaplygin_sleigh(), 'q0': [0.0, 0.0, 0.0], 'qdot0': [0.0, 1.0, 1.0],\n"
        "            'args': {'m': 1.0, 'I': 1.0, 'a': 1.0}, 't_span': (0.0, 1.0)}\n"
        "def bare():\n"
        "    return mechanics.systems.chaplygin_sleigh()\n"
    )
    monkeypatch.chdir(tmp_path)
    monkeypatch.delitem(sys.modules, "mech_models_cli", raising=False)
    try:
        f = tmp_path / "sol.npz"
        code, out, err = run_cli(["run", "--model", "mech_models_cli:sleigh", "--stages", "3", "--n-steps", "10",
                                  "--no-progress", "--save", f], capsys)
        assert code == 0, err
        model = mechanics.systems.chaplygin_sleigh()
        args = model.args(m=1.0, I=1.0, a=1.0)
        p0 = model.momenta(0.0, [0.0, 0.0, 0.0], [0.0, 1.0, 1.0], args)  # qdot0 -> p0 as the CLI does
        sol = L.solve(model.problem, cli_method(3), (0.0, 1.0), [0.0, 0.0, 0.0], p0, args=args, n_steps=10,
                      chunk_size=RUN_CHUNK)
        with np.load(f) as z:
            np.testing.assert_allclose(z["q"], sol.q, rtol=0, atol=1e-12)
        code, out, err = run_cli(["run", "--model", "mech_models_cli:bare", "--n-steps", "10"], capsys)
        assert code == 2 and "a mechanics model (Chaplygin sleigh (Lagrangian)) without initial values" in err
    finally:
        sys.modules.pop("mech_models_cli", None)


def _import_in_a_fresh_process(tmp_path, env_changes, code="import jax, lobattodae; print(jax.config.jax_compilation_cache_dir)"):
    env = {k: v for k, v in os.environ.items() if k not in ("LOBATTODAE_NO_CACHE", "LOBATTODAE_CACHE_DIR",
                                                             "JAX_COMPILATION_CACHE_DIR")}
    env.update(env_changes)
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, env=env)
    assert proc.returncode == 0, proc.stderr
    return proc.stdout.strip()


def test_the_compilation_cache_is_on_by_default_in_the_user_cache_directory(tmp_path):
    """Decided in #26: `import lobattodae` switches JAX's persistent cache on in the user cache
    directory (compilations of a second or more, 1 GiB at most); LOBATTODAE_NO_CACHE=1 keeps it
    off, a cache directory the process configured itself is left alone, and an unwritable
    location leaves the cache off without an error."""
    xdg = tmp_path / "xdg"
    settings = "import jax, lobattodae; c = jax.config; print(c.jax_compilation_cache_dir, " \
               "c.jax_persistent_cache_min_compile_time_secs, c.jax_compilation_cache_max_size)"
    out = _import_in_a_fresh_process(tmp_path, {"XDG_CACHE_HOME": str(xdg)}, settings)
    assert out == f"{xdg / 'lobattodae'} 1.0 {1 << 30}" and (xdg / "lobattodae").is_dir()
    assert _import_in_a_fresh_process(tmp_path, {"XDG_CACHE_HOME": str(xdg), "LOBATTODAE_NO_CACHE": "1"}) == "None"
    own = tmp_path / "own"
    assert _import_in_a_fresh_process(tmp_path, {"JAX_COMPILATION_CACHE_DIR": str(own)}) == str(own)
    blocker = tmp_path / "file"
    blocker.write_text("")
    assert _import_in_a_fresh_process(tmp_path, {"XDG_CACHE_HOME": str(blocker)}) == "None"
