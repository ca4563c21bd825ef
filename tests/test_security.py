"""Hostile input (issue #30): strings that reach generated code, symlinks where a checkpoint
writes, FIFOs where an ensemble reads. Nothing is executed, deleted or waited on."""

import ast
import os
import subprocess
import sys
import textwrap

import numpy as np
import pytest

import lobattodae as L
from lobattodae._io import checkpoint
from lobattodae.examples import get_example

from helpers import subprocess_env

sp = pytest.importorskip("sympy")
from sympy.physics.mechanics import dynamicsymbols  # noqa: E402

from lobattodae import mechanics  # noqa: E402
from lobattodae.mechanics import _codegen  # noqa: E402

T = dynamicsymbols._t
PWNED = "LOBATTO_PWNED"


@pytest.fixture
def clean_environ(monkeypatch):
    monkeypatch.delenv(PWNED, raising=False)
    yield
    assert PWNED not in os.environ, "generated code ran the injected statement"


def _sleigh(name, coordinates="x y theta", parameters="m I a"):
    x, y, th = dynamicsymbols(coordinates)
    m, inertia, a = sp.symbols(parameters)
    lag = sp.Rational(1, 2) * m * (x.diff(T) ** 2 + y.diff(T) ** 2) + sp.Rational(1, 2) * inertia * th.diff(T) ** 2
    c = -sp.sin(th) * x.diff(T) + sp.cos(th) * y.diff(T) - a * th.diff(T)
    return mechanics.from_lagrangian(lag, [x, y, th], T, nonholonomic=[c], name=name)


def _same_as_the_sleigh(model, args):
    ref = mechanics.systems.chaplygin_sleigh()
    ref_args = ref.args(m=1.3, I=0.7, a=0.4)
    rng = np.random.default_rng(0)
    q, p, lam = rng.normal(size=3), rng.normal(size=3), rng.normal(size=1)
    np.testing.assert_allclose(model.problem.f(0.3, q, p, args), ref.problem.f(0.3, q, p, ref_args), rtol=1e-14)
    np.testing.assert_allclose(model.problem.g(0.3, q, p, lam, args), ref.problem.g(0.3, q, p, lam, ref_args),
                               rtol=1e-14, atol=1e-15)


# -- 1. strings in generated code -----------------------------------------------------------------------
INJECTED = 'x"""\nimport os; os.environ["LOBATTO_PWNED"]="1"\n"""'


@pytest.mark.parametrize("name", [
    INJECTED,
    "x'''\nimport os; os.environ['LOBATTO_PWNED']='1'\n'''",
    'x"\nimport os; os.environ["LOBATTO_PWNED"]="1"\n#',
    "x\\",
    "x\x00y\u2028z",
])
def test_model_name_cannot_inject_code(name, clean_environ):
    model = _sleigh(name)
    assert model.name == name
    _same_as_the_sleigh(model, model.args(m=1.3, I=0.7, a=0.4))
    sol = L.solve(model.problem, L.LobattoIIIAIIIB(stages=2), (0.0, 0.2), [0.0, 0.0, 0.0], [0.5, 0.0, 0.0],
                  n_steps=4, args=model.args(m=1.3, I=0.7, a=0.4))
    assert sol.success


def test_coordinate_and_parameter_names_cannot_inject_code(clean_environ):
    bad = 'q"]; import os; os.environ["LOBATTO_PWNED"]="1" #'
    x, y, th = (sp.Function(n)(T) for n in ("x" + bad, "y'''", 'theta"""'))
    m, inertia, a = sp.Symbol("m" + bad), sp.Symbol("I'''\n"), sp.Symbol('a"""')
    lag = sp.Rational(1, 2) * m * (x.diff(T) ** 2 + y.diff(T) ** 2) + sp.Rational(1, 2) * inertia * th.diff(T) ** 2
    c = -sp.sin(th) * x.diff(T) + sp.cos(th) * y.diff(T) - a * th.diff(T)
    model = mechanics.from_lagrangian(lag, [x, y, th], T, nonholonomic=[c], name="names")
    args = model.args({"m" + bad: 1.3, "I'''\n": 0.7, 'a"""': 0.4})
    _same_as_the_sleigh(model, args)
    assert bad not in model.source.replace(repr("m" + bad), "")  # only as a quoted dict key


def test_bound_symbol_names_cannot_inject_code(clean_environ):
    """A bound variable (of a Sum) keeps its name through the pipeline and is printed as is: the
    generated source is checked before it is compiled, and refused."""
    x, y, th = dynamicsymbols("x y theta")
    k = sp.Symbol('k in range(0)) if __import__("os").environ.__setitem__("LOBATTO_PWNED", "1") else (0 for k')
    lag = (sp.Rational(1, 2) * (x.diff(T) ** 2 + y.diff(T) ** 2 + th.diff(T) ** 2)
           + sp.Sum(k * x, (k, 0, 2)))
    c = -sp.sin(th) * x.diff(T) + sp.cos(th) * y.diff(T)
    with pytest.raises(L.LobattoDAEInputError, match="generated code"):
        mechanics.from_lagrangian(lag, [x, y, th], T, nonholonomic=[c], name="sum")


@pytest.mark.parametrize("evil", [
    "__import__('os')",
    "os.system",
    "(lambda: 1)",
    "[x for x in ()]",
    "args.__class__",
    "'a string'",
    "jax.numpy.__dict__",
    "args()",
])
def test_generated_source_is_checked_before_it_runs(evil, clean_environ):
    q0 = sp.Symbol("q_0")
    spec = _codegen.FunctionSpec("f", (("q", (q0,)),), (("scalar", q0 * sp.Symbol(evil)),))
    with pytest.raises(L.LobattoDAEInputError, match="generated code"):
        _codegen.generate_module("evil", [spec], sp.Symbol("t"), [(evil, sp.Symbol(evil))])


def test_generated_module_label_is_quoted():
    q0 = sp.Symbol("q_0")
    spec = _codegen.FunctionSpec("f", (("q", (q0,)),), (("vector", [q0]),), doc='doc"""')
    module = _codegen.generate_module(INJECTED, [spec], sp.Symbol("t"), [])
    tree = ast.parse(module.source)
    assert [type(s) for s in tree.body] == [ast.Expr, ast.FunctionDef]  # the docstring and f, nothing else
    assert INJECTED in ast.get_docstring(tree, clean=False)
    assert ast.get_docstring(tree.body[1], clean=False) == 'doc"""'
    np.testing.assert_array_equal(module.functions["f"](0.0, np.array([2.0]), {}), [2.0])


# -- 2. a symlinked rows directory ----------------------------------------------------------------------
def _victim(tmp_path):
    victim = tmp_path / "victim"
    victim.mkdir()
    names = ["000000-0123456789abcdef.npz", "000001-fedcba9876543210.npz", ".precious.tmp", "keep.txt"]
    for name in names:
        (victim / name).write_text("precious")
    return victim, names


def test_fresh_checkpoint_refuses_a_symlinked_rows_directory(tmp_path):
    ex = get_example("knife-edge")
    victim, names = _victim(tmp_path)
    path = tmp_path / "run.npz"
    os.symlink(victim, tmp_path / "run.npz.rows")
    with pytest.raises(checkpoint.CheckpointError, match=r"run\.npz\.rows.*symbolic link") as info:
        L.solve(ex.problem, L.LobattoIIIAIIIB(stages=2), (0.0, 0.1), ex.q0, ex.p0, n_steps=4, args=ex.args,
                checkpoint=path)
    assert info.value.path == str(path) and f"'{path}.rows'" in str(info.value)
    assert sorted(os.listdir(victim)) == sorted(names)
    assert all((victim / n).read_text() == "precious" for n in names)


def test_checkpoint_save_and_load_never_go_through_a_symlinked_rows_directory(tmp_path):
    victim, names = _victim(tmp_path)
    path = tmp_path / "ck.npz"
    kw = dict(meta={"a": 1}, counters={"done": 1}, state={"x": np.zeros(2)}, rows={"t": np.arange(3.0)})
    first = checkpoint.save(path, **kw)  # a real rows directory ...
    os.rename(tmp_path / "ck.npz.rows", tmp_path / "real.rows")
    os.symlink(tmp_path / "real.rows", tmp_path / "ck.npz.rows")  # ... moved behind a link
    with pytest.raises(checkpoint.CheckpointError, match="symbolic link"):
        checkpoint.load(path, meta={"a": 1}, state_template={"x": np.zeros(2)}, row_names=["t"])
    with pytest.raises(checkpoint.CheckpointError, match="symbolic link"):
        checkpoint.save(path, **{**kw, "rows": {"t": np.arange(2.0)}}, previous=first)
    os.unlink(tmp_path / "ck.npz.rows")
    os.symlink(victim, tmp_path / "ck.npz.rows")
    with pytest.raises(checkpoint.CheckpointError, match="symbolic link"):
        checkpoint.save(path, **kw)
    assert sorted(os.listdir(victim)) == sorted(names)


# -- 3. a FIFO named like an ensemble block -------------------------------------------------------------
@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="needs os.mkfifo")
def test_ensemble_resume_refuses_a_fifo_instead_of_waiting(tmp_path):
    """Run in a child process with a time limit: before the fix it blocked forever in open()."""
    out = tmp_path / "out"
    out.mkdir()
    os.mkfifo(out / "ensemble-p00000-b000000.npz")
    script = textwrap.dedent(f"""
        import numpy as np, lobattodae as L
        from lobattodae.examples import get_example
        ex = get_example("knife-edge")
        lam = np.asarray(L.consistent_lambda(ex.problem, 0.0, ex.q0, ex.p0, np.zeros(1), ex.args))
        try:
            L.ensemble(ex.problem, L.LobattoIIIAIIIB(stages=2), ex.q0[None], ex.p0[None], lam[None], ex.args,
                       h=0.05, n_steps=2, out_dir={str(out)!r}, if_exists="resume")
        except L.LobattoDAEInputError as exc:
            print("REFUSED", exc)
        else:
            print("ACCEPTED")
    """)
    try:
        done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120,
                              env=subprocess_env())
    except subprocess.TimeoutExpired:
        pytest.fail("ensemble(..., if_exists='resume') hung on a FIFO named like a block file")
    assert done.returncode == 0, done.stderr[-3000:]
    assert "REFUSED" in done.stdout and "not a regular file" in done.stdout, done.stdout + done.stderr[-2000:]
    assert "ensemble-p00000-b000000.npz" in done.stdout
