"""Functions and constants shared by several test files (fixtures are in ``conftest.py``).

Test files import them by name (``from helpers import FALL``): ``tests/`` is on ``sys.path``
for every test file, ``tests/verification/`` included (``pythonpath`` in ``pyproject.toml``).
Nothing here imports ``lobattodae.mechanics`` (SymPy) at import time.
"""

import importlib.util
import math
import os
import pathlib
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from scipy.integrate import solve_ivp

import lobattodae as L

ROOT = pathlib.Path(__file__).resolve().parents[1]


# -- processes, pytrees, messages -----------------------------------------------------------------
def subprocess_env(**extra):
    """This process's environment for a child Python, without the variables that size XLA's
    CPU pool (``PJRT_NPROC``, ``NPROC``; ``set_cpu_threads`` may have set one here), plus
    ``extra``."""
    base = {k: v for k, v in os.environ.items() if k not in ("PJRT_NPROC", "NPROC")}
    return {**base, **extra}


def assert_bitwise_equal(a, b):
    """Two pytrees with the same structure, and leaves equal in dtype, shape and every bit."""
    la, ta = jax.tree_util.tree_flatten(a)
    lb, tb = jax.tree_util.tree_flatten(b)
    assert ta == tb
    for x, y in zip(la, lb):
        x, y = np.asarray(x), np.asarray(y)
        assert x.dtype == y.dtype and x.shape == y.shape, (x.dtype, y.dtype, x.shape, y.shape)
        assert x.tobytes() == y.tobytes()


#: Phrases of raw JAX/NumPy errors that must never be the message a user gets.
RAW = ("static_argnums", "dot_general", "inhomogeneous", "Error interpreting argument", "Traceback",
       "ConcretizationTypeError", "could not be broadcast")


def max_abs(a):
    """max |a| over every entry, as a float."""
    return float(np.max(np.abs(np.asarray(a))))


# -- small problems -------------------------------------------------------------------------------
#: x'' = -1 with x(0) = 0, x'(0) = 1 (FALL_Q0, FALL_P0), beside a second coordinate held at rest by
#: φ = p[1] (q[1], p[1] stay exactly 0): an ODE that solve_ivp solves too, in the DAE's clothes.
FALL = L.PartitionedDAE(
    f=lambda t, q, p, a: p,
    g=lambda t, q, p, lam, a: jnp.stack([-1.0 + 0.0 * q[0], lam[0]]),
    phi=lambda t, q, p, a: p[1:2],
    name="falling particle",
)
FALL_Q0, FALL_P0 = np.zeros(2), np.array([1.0, 0.0])


def solve_example(ex, method, **kw):
    """``solve`` of an example (an :class:`~lobattodae.examples.Example`) from its initial values,
    with its args, over its t_span unless ``kw`` gives one."""
    kw.setdefault("t_span", ex.t_span)
    t_span = kw.pop("t_span")
    return L.solve(ex.problem, method, t_span, ex.q0, ex.p0, args=ex.args, **kw)


def solve_short(ex, **kw):
    """``solve`` of an example: 10 constant steps of s = 2 over its t_span from its initial
    values, unless ``kw`` gives ``n_steps``, ``method``, ``q0``, ``p0`` or ``t_span``."""
    kw.setdefault("n_steps", 10)
    method = kw.pop("method", L.LobattoIIIAIIIB(stages=2))
    q0 = kw.pop("q0", ex.q0)
    p0 = kw.pop("p0", ex.p0)
    t_span = kw.pop("t_span", ex.t_span)
    return L.solve(ex.problem, method, t_span, q0, p0, args=ex.args, **kw)


def particle_with(mu=None, hamiltonian=None):
    """The nonholonomic particle, H = |p|²/2, μ = (−y, 0, 1), with ``mu`` or ``hamiltonian``
    replaced where given (a new problem object on every call)."""
    return L.NonholonomicSystem(
        hamiltonian or (lambda t, q, p, a: 0.5 * p @ p),
        mu or (lambda t, q, a: jnp.array([[-q[1], 0.0, 1.0]])),
    )


def stiff_particle():
    """The nonholonomic particle with the potential ``args · x⁴`` (``args`` a number): with
    ``args = 100`` and 20 constant steps on (0, 6) (q0 = 0, p0 = (1, 1, 0)), Newton fails at
    step 2."""
    return L.NonholonomicSystem(
        lambda t, q, p, a: 0.5 * p @ p + a * q[0] ** 4,
        lambda t, q, a: jnp.array([[-q[1], 0.0, 1.0]]),
    )


# -- order studies ----------------------------------------------------------------------------------
#: ψ, φ and |Q·Q − 1| at the step points of the mechanics models: round-off.
EXACT = 1e-13
#: errors below this are on the round-off plateau and left out of the order fits
PLATEAU = 1e-11


def fitted_order(ns, errors):
    """The order fitted to the errors above PLATEAU against the step counts ``ns``."""
    ns, errors = np.asarray(ns, float), np.asarray(errors)
    keep = errors > PLATEAU
    assert keep.sum() >= 2, errors
    return -np.polyfit(np.log(ns[keep]), np.log(errors[keep]), 1)[0]


# -- a loop-state-like tree for the checkpoint format and the fingerprints ---------------------------
class Jac(NamedTuple):
    inverse: Any
    valid: Any


class Stepper(NamedTuple):
    jacobian: Jac
    slopes: Any


class Y(NamedTuple):
    q: Any
    p: Any


class State(NamedTuple):
    y: Y
    stepper: Stepper
    step: Any


def make_state(n=3, seed=0):
    rng = np.random.default_rng(seed)
    return State(
        y=Y(jnp.asarray(rng.standard_normal(n)), jnp.asarray(rng.standard_normal(n))),
        stepper=Stepper(Jac(jnp.asarray(rng.standard_normal((n, n))), jnp.asarray(True)),
                        jnp.asarray(rng.standard_normal((2, n)))),
        step=jnp.asarray(17, jnp.int32),
    )


# -- the command line -----------------------------------------------------------------------------
RUN_STAGES = 3
RUN_STEPS = 50
# ``run`` compiles chunks of solve's default length (lobattodae._chunks.CHUNK); the direct solves
# of the tests use the same so that they reuse the compilation.


def run_cli(argv, capsys):
    """``main(argv)`` in this process: its exit code, stdout and stderr."""
    from lobattodae._cli import main

    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def cli_method(stages):
    """The method ``run`` uses: its ``--lam-start`` default."""
    from lobattodae._cli import build_parser

    ns = build_parser().parse_args(["run", "--example", "particle", "--stages", str(stages), "--n-steps", "1"])
    return L.LobattoIIIAIIIB(stages=stages, lam_start=ns.lam_start)


#: The module of model factories behind ``lobattodae run --model`` (fixture ``model_module``).
MODEL_SOURCE = '''
from lobattodae.examples import get_example

EX = get_example("particle")
NOT_CALLABLE = 3


def as_dict():
    return {"problem": EX.problem, "q0": EX.q0, "p0": EX.p0, "args": EX.args, "t_span": EX.t_span,
            "name": "my particle", "draw": lambda t, q, args: {"dot": [q[0], q[2]]}}


def as_tuple():
    return EX.problem, list(EX.q0), list(EX.p0), EX.args


def as_example():
    return EX


def returns_int():
    return 42


def returns_pair():
    return EX.problem, EX.q0


def dict_without_q0():
    return {"problem": EX.problem, "p0": EX.p0, "t_span": (0.0, 1.0)}


def dict_with_typo():
    return {"problem": EX.problem, "q0": EX.q0, "p0": EX.p0, "tspan": (0.0, 1.0)}


def not_a_problem():
    return "sleigh", EX.q0, EX.p0


def q0_matrix():
    return EX.problem, [[0.0, 0.0, 0.0]], EX.p0


def raises():
    raise ValueError("boom: bad parameter")
'''


# -- the scripts under docs/examples ---------------------------------------------------------------
EXAMPLES_DIR = ROOT / "docs" / "examples"


def load_example_script(name: str):
    """The script ``docs/examples/NAME.py``, imported as a module (its ``main`` not run)."""
    spec = importlib.util.spec_from_file_location(name, EXAMPLES_DIR / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


# -- the reversible contact oscillator --------------------------------------------------------------
#: The first step of the reversible runs: mean step about 0.17 on the contact oscillator.
FIRST_STEP = 0.2


def example_energy_error(ex, sol):
    """|H(q, p) − H(q0, p0)| along the rows of ``sol`` (the example's invariant ``energy``)."""
    energy = jax.vmap(lambda q, p: ex.invariants["energy"](0.0, q, p, ex.args))
    h0 = float(energy(ex.q0[None], ex.p0[None])[0])
    return np.abs(np.asarray(energy(jnp.asarray(sol.q), jnp.asarray(sol.p))) - h0)


def energy_growth(ex, sol):
    """The max energy error over the last tenth of the run divided by that over the first
    tenth, and the max over the whole run."""
    d_h = example_energy_error(ex, sol)
    t_end = sol.t[-1]
    return d_h[sol.t >= 0.9 * t_end].max() / d_h[sol.t <= 0.1 * t_end].max(), d_h.max()


# -- the Cartesian pendulum (holonomic; needs SymPy when built) ------------------------------------
class Pendulum:
    """The Cartesian pendulum, θ0 = 0.6, ℓ = 1.3, and the angle ODE θ'' = −(g/ℓ) sin θ."""

    g, ell, mass, th0 = 9.81, 1.3, 0.7, 0.6
    #: tolerance of the reference (scipy's DOP853)
    ref_tol = 1e-13

    def __init__(self):
        from lobattodae.mechanics import systems

        self.model = systems.cartesian_pendulum()
        self.args = self.model.args(m=self.mass, g=self.g, l=self.ell)
        self.q0 = self.ell * np.array([math.sin(self.th0), -math.cos(self.th0)])
        qd0 = self.model.complete_velocities(0.0, self.q0, np.array([0.5, 0.5]), self.args)
        self.om0 = (self.q0[0] * qd0[1] - self.q0[1] * qd0[0]) / self.ell**2
        self.model.check(0.0, self.q0, self.args)
        self.p0 = self.model.momenta(0.0, self.q0, qd0, self.args)

    def reference(self, t_end):
        k = self.g / self.ell
        ref = solve_ivp(lambda t, y: [y[1], -k * math.sin(y[0])], (0.0, t_end), [self.th0, self.om0],
                        method="DOP853", rtol=self.ref_tol, atol=self.ref_tol, dense_output=True)

        def states(t):
            th, om = ref.sol(t)
            q = self.ell * np.stack([np.sin(th), -np.cos(th)], -1)
            v = self.ell * om[:, None] * np.stack([np.cos(th), np.sin(th)], -1)
            return q, self.mass * v

        return states


# -- rigid bodies oriented by unit quaternions (lobattodae.mechanics; needs SymPy) -------------------
#: tolerance of the rigid-body references (scipy's DOP853)
RIGID_REF_TOL = 1e-12
SUSLOV_Q0 = np.array([0.9, 0.2, -0.3, 0.25])
SUSLOV_W0 = np.array([1.0, -0.6, 0.0])
SPHERE_Q0 = np.array([0.8, 0.3, -0.4, 0.2])
SPHERE_W0 = np.array([0.7, -1.1, 1.5])


def body_omega(model, sol, args, first=0):
    """Body angular velocity, quaternions and rotation matrices along a solution."""
    from lobattodae.mechanics import body_angular_velocity, rotation_matrix

    v = model.velocities(sol.t, sol.q, sol.p, args)
    Q = sol.q[:, first:first + 4]
    return body_angular_velocity(Q, v[:, first:first + 4]), Q, rotation_matrix(Q)


def quaternion_exactness(model, sol, args, first=0):
    """max |Q·Q − 1| and max ‖φ‖ over the rows of a solution."""
    Q = sol.q[:, first:first + 4]
    return max_abs(np.sum(Q * Q, 1) - 1.0), max_abs(model.constraint_residual(sol.t, sol.q, sol.p, args))


def tilted(roll_deg, pitch_deg):
    """The unit quaternion of a roll, then a pitch (degrees)."""
    from lobattodae.mechanics import quaternion_from_axis_angle, quaternion_multiply

    return quaternion_multiply(quaternion_from_axis_angle([1, 0, 0], np.radians(roll_deg)),
                               quaternion_from_axis_angle([0, 1, 0], np.radians(pitch_deg)))


def suslov_reference(I, a, Q0, w0, t_end, t_eval):
    """Suslov's problem, ``I ω̇ = (Iω) × ω + λ a`` with ``λ`` from ``aᵀω̇ = 0`` and
    ``Q̇ = ½ E(Q)ᵀ ω``, by scipy's DOP853: ω and Q at ``t_eval``."""
    from lobattodae.mechanics import quaternion_rates

    Iinv_a = np.linalg.solve(I, a)

    def rhs(t, y):
        w, Q = y[:3], y[3:]
        b = np.linalg.solve(I, np.cross(I @ w, w))
        lam = -(a @ b) / (a @ Iinv_a)
        return np.concatenate([b + lam * Iinv_a, quaternion_rates(Q, w)])

    ref = solve_ivp(rhs, (0.0, t_end), np.concatenate([w0, Q0]), method="DOP853", rtol=RIGID_REF_TOL,
                    atol=RIGID_REF_TOL, t_eval=t_eval)
    return ref.y[:3].T, ref.y[3:].T
