"""The runnable examples under docs/examples: they run, and their numbers are right."""

import math

import numpy as np
import pytest

import lobattodae as L

from helpers import load_example_script as _load  # test_gallery.py looks for _load("NAME")

#: The touchdown time must agree with the independent reference (scipy DOP853 on the reduced
#: ODE at rtol 1e-13) to this relative difference (measured 9.3e-10 at the script's rtol 1e-10, 2026-11-26).
TOUCHDOWN_REL_TOL = 1e-8


@pytest.fixture(scope="module")
def touchdown_script():
    return _load("falling_disk_touchdown")


@pytest.fixture(scope="module")
def reference(touchdown_script):
    return touchdown_script.reference_touchdown()


def test_falling_disk_touchdown_time_matches_the_reference(touchdown_script, reference):
    td = touchdown_script.touchdown()
    t_ref, y_ref, _ = reference
    assert td.solution.result == L.Result.EVENT and td.solution.success
    assert abs(td.t - t_ref) <= TOUCHDOWN_REL_TOL * abs(t_ref), (td.t, t_ref)
    assert td.solution.t[-1] == td.t  # the run ends on the event
    # the disk fell: from the initial tilt to the touchdown tilt arctan(1/AXLE)
    assert touchdown_script.DISK["theta0"] < 0.5 and td.q[2] > 1.4
    assert abs(td.q[2] - math.atan(1.0 / touchdown_script.AXLE)) < 1e-8
    np.testing.assert_allclose(td.q, y_ref[: td.q.size], atol=1e-7)
    # the final state is a step of the method: the constraint holds to round-off
    assert td.constraint_residual < 1e-13


def test_the_reference_is_independent_and_consistent(touchdown_script, reference):
    """The reduced ODE of the script reproduces the library's vector field with λ eliminated,
    and the reference run sits on the event surface."""
    import jax.numpy as jnp

    ex = touchdown_script.disk()
    rhs = touchdown_script.reduced_ode(ex.problem, ex.args)
    y0 = np.concatenate([ex.q0, ex.p0])
    lam0 = L.consistent_lambda(ex.problem, 0.0, jnp.asarray(ex.q0), jnp.asarray(ex.p0), jnp.asarray(ex.lam0), ex.args)
    expected = np.concatenate([ex.problem.f(0.0, ex.q0, ex.p0, ex.args), ex.problem.g(0.0, ex.q0, ex.p0, lam0, ex.args)])
    np.testing.assert_allclose(rhs(0.0, y0), expected, rtol=1e-12, atol=1e-12)
    t_ref, y_ref, phi_ref = reference
    n = ex.n
    assert abs(float(touchdown_script.axle_height(t_ref, y_ref[:n], y_ref[n:], ex.args))) < 1e-12
    assert phi_ref < 1e-10  # the explicit reference drifts off the constraint, but only a little


def test_falling_disk_touchdown_script_main(touchdown_script, capsys):
    assert touchdown_script.main(["--check", str(TOUCHDOWN_REL_TOL)]) == 0
    out = capsys.readouterr().out
    assert "touchdown" in out and "relative difference of the touchdown times" in out
