"""Step-size controllers (lobattodae._controllers): the constant controller lands on t1, the PI
controller checks its fields. (Error control as users see it: ``test_adaptive.py``; the
reversible control: ``test_reversible.py``.)"""

import jax.numpy as jnp
import numpy as np
import pytest

import lobattodae as L
from lobattodae._controllers import ConstantStepSize, ControlOptions, StepReport


def _report(ok):
    z = jnp.zeros(2)
    return StepReport(jnp.asarray(ok), jnp.asarray(0 if ok else 1), 0.0, 0.0, z, z, z, z[:1], z[:1], z[:1])


def test_constant_controller_lands_exactly_on_t1():
    c = ConstantStepSize()
    st = c.init(None, None, jnp.asarray(0.1), jnp.asarray(0.7), None, None, None, None, ControlOptions(n=3))
    times = []
    while not bool(c.done(st)):
        t, h = c.proposal(st)
        times.append(float(t))
        _, st, _ = c.adapt(st, None, None, _report(True))
    assert float(c.time(st)) == 0.7
    np.testing.assert_allclose(times, [0.1, 0.3, 0.5], rtol=1e-15)
    accept, st2, result = c.adapt(st, None, None, _report(False))
    assert int(st2.k) == int(st.k) and not bool(accept) and int(result) == 1  # a failed step ends the run


@pytest.mark.parametrize("field, value", [("safety", 0.0), ("safety", 1.5), ("fac_min", 1.0), ("fac_max", 0.9),
                                          ("beta1", 0.0), ("beta2", -0.1), ("hysteresis", 0.5), ("c_tol", 0.0),
                                          ("c_tol", float("nan")), ("fac_max", "5"), ("estimate", "richardson")])
def test_pi_controller_validates_its_fields(field, value):
    with pytest.raises(ValueError, match=f"PIController: {field} must be"):
        L.PIController(**{field: value, **({"estimate": "embedded"} if field == "c_tol" else {})})


def test_c_tol_belongs_to_the_embedded_estimate():
    """The default estimate uses the tolerances as given: a tolerance constant is refused."""
    with pytest.raises(ValueError, match="c_tol maps the tolerances of the embedded estimate"):
        L.PIController(c_tol=2.0)
