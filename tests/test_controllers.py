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


def _pi_state(c: "L.PIController", h, order):
    """A PI controller's state at t = 0 on (0, 1) with atol = 1, rtol = 0: the error scale of a
    step of size h is h (per unit step), so a report with error ``E·h`` reads err = E."""
    from lobattodae._controllers import AdaptiveState

    f = jnp.float64
    return AdaptiveState(t=f(0.0), h=f(h), t0=f(0.0), t_end=f(1.0), err_prev=f(1.0),
                         h_rejected=f(0.0), err_rejected=f(jnp.inf), rtol=f(0.0), atol=f(1.0), max_step=f(jnp.inf),
                         order=f(order), span=f(1.0), n_rejected=jnp.asarray(0, jnp.int32), n_floored=jnp.asarray(0, jnp.int32),
                         h_last=f(0.0), err_last=f(0.0), checking=jnp.asarray(False), n_checked=jnp.asarray(0, jnp.int32), radius=f(6.0),
                         n_failed_solves=jnp.asarray(0, jnp.int32), n_unresolved=jnp.asarray(0, jnp.int32))


def _attempt(c, st, err_of_h):
    """One attempt of the proposed size against the error model ``err_of_h``."""
    _, h = c.proposal(st)
    z = jnp.zeros(2)
    e = jnp.full(2, err_of_h(float(h)) * float(h))
    return h, c.adapt(st, None, None, StepReport(jnp.asarray(True), jnp.asarray(0), st.t, h, z, z, e, z[:1], z[:1], z[:1]))


@pytest.mark.parametrize("power, factor", [(4.0, lambda err: 0.9 * err**-0.25), (1.0, lambda err: 0.9 / err),
                                           (-1.0, lambda err: 0.2)])
def test_a_second_rejection_shrinks_by_the_observed_power_of_h(power, factor):
    """Two rejected attempts from the same point differ only in h: the second shrinks by the
    power of h its error actually fell with (h^4 and h^1 where the rule assumes h^8; an error
    that grew on the shorter step, as a mode beyond the stability limit reads per unit step:
    fac_min), not by the asymptotic rule err^(-1/8). (Where the error does fall like h^8, the
    first shrink already passes.)"""
    c = L.PIController()
    k = 8.0
    err_of_h = lambda h: 30.0 * h**power  # noqa: E731
    st = _pi_state(c, 1.0, k)
    h1, (accept, st, _) = _attempt(c, st, err_of_h)
    assert not bool(accept)
    np.testing.assert_allclose(float(st.h), 0.9 * 30.0 ** (-1 / k), rtol=1e-12)  # the first: asymptotic
    h2, (accept, st, _) = _attempt(c, st, err_of_h)
    err2 = err_of_h(float(h2))
    assert not bool(accept) and err2 > 1
    np.testing.assert_allclose(float(st.h) / float(h2), min(max(factor(err2), c.fac_min), 0.9), rtol=1e-10)
    assert float(st.h) / float(h2) < 0.9 * err2 ** (-1 / k)


def test_a_step_beyond_the_stability_limit_is_left_in_few_attempts():
    """An error that does not fall until h is below 1e-3 (a fast mode outside the stability
    region): the asymptotic rule alone would shrink by 0.9·10^(-1/8) = 0.67 per attempt, 18
    rejections; the observed power takes fac_min after the second."""
    c = L.PIController()
    st = _pi_state(c, 1.0, 8.0)
    rejected = 0
    while True:
        h, (accept, st, _) = _attempt(c, st, lambda h: 10.0 if h > 1e-3 else 1e-3)
        if bool(accept):
            break
        rejected += 1
    assert rejected <= 6 and float(h) > 1e-4


def _measured(c, h_last, err_last):
    """A PI state after an accepted step of size ``h_last`` with error ``err_last``, the next
    attempt proposed with the same size (k = 8, s = 5: Richardson's divisor 255, radius 5.3)."""
    f = jnp.float64
    return _pi_state(c, h_last, 8.0)._replace(h_last=f(h_last), err_last=f(err_last), radius=f(5.3))


def test_a_step_whose_error_constant_jumps_is_checked_on_half_the_step():
    """The error constant err / h^k of an attempt 0.5 grew e^6.2 from the last step's 1e-3 at the
    same size (|hμ| = 6.2 > the radius 5.3) and the undivided difference (0.5 · 255) fails the
    test: rejected although err ≤ 1, retried with h/2. A retry whose error fell by 2^k confirms
    Richardson: accepted as it is, and the step may grow at once."""
    c = L.PIController()
    h, (accept, st, result) = _attempt(c, _measured(c, 0.1, 1e-3), lambda h: 0.5 * (h / 0.1) ** 8)
    assert not bool(accept) and bool(st.checking) and int(st.n_checked) == 1 and int(st.n_rejected) == 1
    assert float(st.h) == pytest.approx(0.05) and int(result) == 0
    h, (accept, st, _) = _attempt(c, st, lambda h: 0.5 * (h / 0.1) ** 8)
    assert bool(accept) and not bool(st.checking)
    np.testing.assert_allclose(float(st.err_last), 0.5 / 256, rtol=1e-12)  # not corrected
    assert float(st.h) > 0.05  # grows: the check held
    # the same error without the jump (the last step's constant 0.5 too): no check
    _, (accept, st, _) = _attempt(c, _measured(c, 0.1, 0.5), lambda h: 0.5 * (h / 0.1) ** 8)
    assert bool(accept) and int(st.n_checked) == 0
    # nor where the undivided difference passes (err · 255 ≤ 1), or when switched off
    _, (accept, st, _) = _attempt(c, _measured(c, 0.1, 1e-6), lambda h: 3e-3)
    assert bool(accept) and int(st.n_checked) == 0
    off = L.PIController(check_large_steps=False)
    _, (accept, st, _) = _attempt(off, _measured(off, 0.1, 1e-3), lambda h: 0.5)
    assert bool(accept) and int(st.n_checked) == 0
    # nor where step doubling's share was the linear theory's, not Richardson's, and the
    # difference itself passes (a settling sleigh's damped mode: share 0.36 of a difference 0.83)
    z = jnp.zeros(2)
    st = _measured(c, 0.1, 1e-3)
    e = jnp.full(2, 0.3 * 0.1)
    report = StepReport(jnp.asarray(True), jnp.asarray(0), st.t, jnp.float64(0.1), z, z, e, z[:1], z[:1], z[:1],
                        share=jnp.float64(0.36))
    accept, st, _ = c.adapt(st, None, None, report)
    assert bool(accept) and int(st.n_checked) == 0
    # with Richardson's share the same error is checked
    accept, st, _ = c.adapt(_measured(c, 0.1, 1e-3), None, None, report._replace(share=jnp.float64(1 / 255)))
    assert not bool(accept) and int(st.n_checked) == 1


def test_a_step_far_below_its_tolerance_grows_through_the_hysteresis():
    """At s = 6 (k = 10) the PI rule keeps h where err = 0.9^(10/0.3) = 0.03 and grows it only by
    (0.03/err)^0.03 below that: an error of 1.5e-4, steady, asks for 1.17 ×, inside the band
    [1, 1.2] that keeps h. The error itself asks for (0.03/1.5e-4)^(1/10) = 1.7 × h, outside it:
    h grows (it stayed at 0.828 for 110 steps on the test set's vertical disk). An error of 0.02,
    near the steady state, keeps h."""
    c = L.PIController()
    z = jnp.zeros(2)
    for err, kept in ((1.5e-4, False), (2e-2, True)):
        st = _pi_state(c, 0.1, 10.0)._replace(err_prev=jnp.float64(err))
        report = StepReport(jnp.asarray(True), jnp.asarray(0), st.t, jnp.float64(0.1), z, z, jnp.full(2, err * 0.1),
                            z[:1], z[:1], z[:1])
        accept, after, _ = c.adapt(st, None, None, report)
        grow = 0.9 * err ** (-0.7 / 10) * err ** (0.4 / 10)
        assert bool(accept) and 1.0 <= grow <= 1.2
        if kept:
            assert float(after.h) == 0.1
        else:
            assert float(after.h) == pytest.approx(0.1 * grow, rel=1e-12)


def test_what_set_the_steps_is_counted():
    """A failed stage solve is a rejection counted in ``n_failed_solves`` (retried at the size
    the stepper asks); an accepted step whose difference lay beyond Richardson's radius counts in
    ``n_unresolved``, a rejected one does not, nor one within the radius or without the flag
    (the embedded estimate)."""
    c = L.PIController()
    z = jnp.zeros(2)
    st = _pi_state(c, 0.1, 8.0)
    small = jnp.full(2, 1e-3 * 0.1)  # err = 1e-3: passes

    def report(ok=True, resolved=None, error=small):
        return StepReport(jnp.asarray(ok), jnp.asarray(0 if ok else 2), st.t, jnp.float64(0.1), z, z, error,
                          z[:1], z[:1], z[:1], retry=jnp.float64(0.25), share=jnp.float64(0.5),
                          resolved=None if resolved is None else jnp.asarray(resolved))

    accept, after, _ = c.adapt(st, None, None, report(ok=False))
    assert not bool(accept) and int(after.n_failed_solves) == 1 and int(after.n_rejected) == 1
    assert float(after.h) == pytest.approx(0.025) and int(after.n_unresolved) == 0
    accept, after, _ = c.adapt(st, None, None, report(resolved=False))
    assert bool(accept) and int(after.n_unresolved) == 1 and int(after.n_failed_solves) == 0
    for kw in ({"resolved": True}, {}):
        accept, after, _ = c.adapt(st, None, None, report(**kw))
        assert bool(accept) and int(after.n_unresolved) == 0
    accept, after, _ = c.adapt(st, None, None, report(resolved=False, error=jnp.full(2, 10 * 0.1)))
    assert not bool(accept) and int(after.n_unresolved) == 0 and int(after.n_failed_solves) == 0


def test_a_check_that_finds_the_error_falling_slowly_corrects_the_divisor():
    """The retry's error fell only by 2^2 between h and h/2 (the whole step's error 4 times the
    halves', not 2^8): its difference is divided by 2^2 − 1 instead of 2^8 − 1, so an estimate of
    0.1 is 0.1 · 255 / 3 = 8.5: rejected, and the step shrinks by the observed power."""
    c = L.PIController()
    err_of_h = lambda h: 0.4 * (h / 0.1) ** 2  # noqa: E731
    _, (accept, st, _) = _attempt(c, _measured(c, 0.1, 1e-3), err_of_h)
    assert not bool(accept) and bool(st.checking)
    h, (accept, st, _) = _attempt(c, st, err_of_h)
    assert not bool(accept) and not bool(st.checking) and int(st.n_checked) == 1
    np.testing.assert_allclose(float(st.err_rejected), 0.1 * 255 / 3, rtol=1e-10)
    assert float(st.h) < 0.5 * float(h)


def test_check_large_steps_is_a_bool():
    with pytest.raises(ValueError, match="check_large_steps must be True"):
        L.PIController(check_large_steps=1)


def _shortened(c, st, h, err):
    """An attempt that the loop shortened to ``h`` (to end on an output time), with error ``err``."""
    z = jnp.zeros(2)
    e = jnp.full(2, err * h)
    return c.adapt(st, None, None, StepReport(jnp.asarray(True), jnp.asarray(0), st.t, jnp.float64(h), z, z, e,
                                              z[:1], z[:1], z[:1]))


def test_after_a_step_shortened_onto_an_output_time_the_run_resumes_its_proposal():
    """A step cut short to land on a t_eval time: its small error must not set the next step
    (from the short size it would grow by at most fac_max, and its error would damp the PI
    memory), so the proposal it was cut from is resumed and the PI memory kept; a shortened step
    whose error still asks for less than the size it took gets what the error asks for."""
    c = L.PIController()
    st = _pi_state(c, 0.1, 8.0)._replace(err_prev=jnp.float64(0.5))
    accept, new, _ = _shortened(c, st, 0.001, 1e-6)
    assert bool(accept) and float(new.h) == pytest.approx(0.1) and float(new.err_prev) == 0.5
    accept, new, _ = _shortened(c, st, 0.05, 0.1)
    assert float(new.h) == pytest.approx(0.1)
    accept, new, _ = _shortened(c, st, 0.09, 1e-8)  # the error allows more than the proposal: taken
    assert float(new.h) > 0.2
    accept, new, _ = _shortened(c, st, 0.05, 0.99)  # near the tolerance: no resumption
    assert bool(accept) and float(new.h) < 0.05 and float(new.err_prev) == 0.5
    # a step of the proposed size is no shortened step: its error enters the PI memory
    accept, new, _ = _shortened(c, st, 0.1, 1e-6)
    assert float(new.h) > 0.1 and float(new.err_prev) == pytest.approx(1e-4)


def test_output_times_cost_at_most_a_shortened_step_each(knife):
    """Stepping onto 101 t_eval times costs the knife edge about what fitting its steps into the
    intervals between them costs: steps of size h need ⌈L/h⌉ of them for an interval L instead of
    L/h, up to one more. Measured (2026-11-29): 585 steps plain, 628 with the times (0.43 per
    time); 834 when the step after each time grew from the shortened one. Until 2026-11-29 the
    PI rule's hysteresis held steps whose error lay far below the tolerance, which could be
    stretched onto the times for free: 737 plain, 744 with the times."""
    m = L.LobattoIIIAIIIB(stages=4)
    run = lambda **kw: L.solve(knife.problem, m, (0.0, 100.0), knife.q0, knife.p0, args=knife.args,  # noqa: E731
                               rtol=1e-8, atol=1e-8, **kw)
    plain, rows = run(), run(t_eval=np.linspace(0.0, 100.0, 101))
    assert rows.stats["n_steps"] + rows.stats["n_rejected"] <= plain.stats["n_steps"] + 0.6 * 101
