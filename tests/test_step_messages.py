"""Messages that name the actual cause (issue #30, "misleading"): step bounds below the
resolution of t, ``atol=0`` with a component at 0, a ``ReversibleStepSize`` density that is
not one positive number, and ``--stages`` large enough to compile for minutes.

Before, the first three ended the run later as "step size too small ... the problem may be
singular" (or "non-finite values ... the step is too large" for the density, or a broadcasting
``ValueError`` for a vector density), and the last compiled without a word.
"""

import jax.numpy as jnp
import numpy as np
import pytest

import lobattodae as L
from helpers import FALL, FALL_Q0, FALL_P0
from lobattodae import _cli
from lobattodae._reversible import phase_space_speed

METHOD = L.LobattoIIIAIIIB(stages=3)
Q0, P0 = FALL_Q0, FALL_P0


# -- step bounds below the resolution of t ----------------------------------------------------------
@pytest.mark.parametrize("t_span, kw", [
    ((0.0, 4.0), dict(first_step=1e-15)),
    ((1e8, 1e8 + 10.0), dict(max_step=5e-7, max_steps=20_000_000)),  # 1e-14·|t| = 1e-6
])
def test_step_bounds_below_the_resolution_of_t_are_refused_up_front(t_span, kw):
    (name, value), = ((k, v) for k, v in kw.items() if k != "max_steps")
    with pytest.raises(L.LobattoDAEInputError,
                       match=rf"{name}={value:g} is below the smallest step a run can take here.*{name} >= "):
        L.solve(FALL, METHOD, t_span, Q0, P0, **kw)


# -- atol = 0 --------------------------------------------------------------------------------------
def test_atol_zero_with_a_component_at_rest_runs():
    # q[1] = p[1] = 0 throughout: their error scale atol + rtol·|y| is 0 and so is their error.
    # Before, the embedded estimate divided 0 by 0 and rejected every step (STEP_SIZE_TOO_SMALL).
    sol = L.solve(FALL, METHOD, (0.0, 4.0), Q0, P0, rtol=1e-6, atol=0.0,
                  controller=L.PIController(estimate="embedded"), throw=False)
    assert sol.success, sol.message
    np.testing.assert_allclose(sol.q[-1], [4.0 - 8.0, 0.0], atol=1e-9)


# -- the density of ReversibleStepSize -------------------------------------------------------------
def _vector_density(t, q, p, lam, f, g, args):
    return jnp.abs(f) + 1.0


def _scaled_density(t, q, p, lam, f, g, args):  # negative for d < 0, NaN for e < 0: not a density
    return args["d"] * (1.0 + q[0] ** 2) + jnp.sqrt(args["e"])


def test_a_vector_density_is_refused_at_set_up():
    with pytest.raises(L.ShapeError, match=r"density '_vector_density' must return one positive number.*"
                                           r"shape \(2,\)"):
        L.solve(FALL, METHOD, (0.0, 4.0), Q0, P0, controller=L.ReversibleStepSize(_vector_density))


@pytest.mark.parametrize("args", [{"d": -1.0, "e": 0.0}, {"d": 1.0, "e": -1.0}], ids=["negative", "nan"])
def test_a_density_that_is_not_positive_says_so(args):
    sol = L.solve(FALL, METHOD, (0.0, 4.0), Q0, P0, args=args, first_step=0.1,
                  controller=L.ReversibleStepSize(_scaled_density), throw=False)
    assert not sol.success and sol.result == L.Result.DENSITY_NOT_POSITIVE
    assert "density of ReversibleStepSize was not positive and finite" in sol.message
    assert "Non-finite values" not in sol.message and np.all(np.isfinite(sol.q))


def test_the_default_density_is_still_accepted():
    assert L.ReversibleStepSize(phase_space_speed).density is phase_space_speed


# -- many stages -------------------------------------------------------------------------------------
def test_many_stages_warn_that_compilation_takes_long(capsys):
    assert _cli._stages(str(_cli.MANY_STAGES)) == _cli.MANY_STAGES
    assert capsys.readouterr().err == ""
    assert _cli._stages("24") == 24
    err = capsys.readouterr().err
    assert "--stages 24" in err and "compil" in err and "minutes" in err


def test_the_tableau_of_many_stages_does_not_warn(capsys):
    assert _cli.main(["tableau", "12"]) == 0
    assert "compil" not in capsys.readouterr().err
