"""Derivatives through the solver: forward and reverse mode agree, match central finite
differences of the same discrete map, and converge to the derivative of the exact solution."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import lobattodae as L
from lobattodae.examples import get_example

EXAMPLES = ("knife-edge", "sleigh", "falling-disk-general")
N_STEPS = 8
H = 0.05
FD_STEP = 1e-5
#: attempts of the differentiable adaptive runs (a scan of this length; the sleigh to t = 1 at
#: rtol 1e-8 with s = 4 needs 27)
MAX_STEPS_ADAPTIVE = 40


def _final_state(ex, method, n_steps=N_STEPS, checkpoints=None):
    """``θ = (q0[0] shift, p0 scale, first args leaf, h) -> (q_N, p_N, λ_N)``, with p0 projected
    onto the constraint and λ0 from the hidden constraint, so every θ gives consistent values."""
    field = ex.args._fields[0]

    def run(theta):
        args = ex.args._replace(**{field: theta[2]})
        q0 = jnp.asarray(ex.q0).at[0].add(theta[0])
        p0 = L.project_momenta(ex.problem, 0.0, q0, theta[1] * jnp.asarray(ex.p0), args)
        lam0 = L.consistent_lambda(ex.problem, 0.0, q0, p0, jnp.asarray(ex.lam0), args)
        r = L.integrate(ex.problem, method, 0.0, theta[3], n_steps, q0, p0, lam0, args, checkpoints=checkpoints)
        return jnp.concatenate([r.q[-1], r.p[-1], r.lam[-1]])

    theta = jnp.array([0.1, 1.1, getattr(ex.args, field), H])
    return run, theta


def _central_differences(fn, x, step=FD_STEP):
    cols = [(fn(x + step * e) - fn(x - step * e)) / (2 * step) for e in np.eye(x.size)]
    return np.stack(cols, axis=1)


#: a few cases in the default run (s = 4 is in the adaptive test, s = 3 with a projection in test_holonomic); the whole grid, three
#: examples × s = 2..5, under -m slow
DEFAULT_CASES = {("sleigh", 2), ("knife-edge", 5)}  # s = 3: tests/test_holonomic.py (pendulum)
GRID = [
    pytest.param(name, s, marks=() if (name, s) in DEFAULT_CASES else pytest.mark.slow)
    for name in EXAMPLES for s in (2, 3, 4, 5)
]


@pytest.mark.parametrize("name, stages", GRID)
def test_forward_reverse_and_finite_differences_agree(name, stages):
    ex = get_example(name)
    run, theta = _final_state(ex, L.LobattoIIIAIIIB(stages=stages))
    run = jax.jit(run)
    forward = np.asarray(jax.jacfwd(run)(theta))
    reverse = np.asarray(jax.jacrev(run)(theta))
    scale = np.max(np.abs(forward))
    assert np.all(np.isfinite(forward)) and scale > 0
    assert np.max(np.abs(forward - reverse)) <= 1e-10 * scale
    fd = _central_differences(run, theta)
    assert np.max(np.abs(forward - fd)) <= 1e-6 * scale


def test_segment_checkpoints_give_the_same_gradient():
    ex = get_example("sleigh")
    method = L.LobattoIIIAIIIB(stages=3)
    plain, theta = _final_state(ex, method, n_steps=12)
    segmented, _ = _final_state(ex, method, n_steps=12, checkpoints=5)  # 5 segments of 3 (3 idle attempts)
    g_plain = jax.grad(lambda x: jnp.sum(plain(x) ** 2))(theta)
    g_seg = jax.grad(lambda x: jnp.sum(segmented(x) ** 2))(theta)
    np.testing.assert_allclose(g_seg, g_plain, rtol=1e-13, atol=1e-14)


def test_parameter_derivative_converges_to_the_exact_one():
    """Knife edge from rest (θ0 = v0 = 0): x(T) = g (½ sin 2ωT − 2 sin ωT + ωT)/(2ω²) is linear
    in g, so ∂x(T)/∂g = x(T)/g (ω = 1 here); the derivative of the discrete solution converges
    to it with the order of q, 2s − 2."""
    ex = get_example("knife-edge")
    w, T = 1.0, 1.0
    exact = (0.5 * np.sin(2 * w * T) - 2.0 * np.sin(w * T) + w * T) / (2 * w**2)
    # the closed form of x(T) (PROBLEMS.md) differentiated by hand, checked against the example
    g = ex.args.g
    assert abs(ex.exact(T)[0][0] - g * exact) < 1e-14

    def x_end(g, n):
        args = ex.args._replace(g=g)
        lam0 = L.consistent_lambda(ex.problem, 0.0, jnp.asarray(ex.q0), jnp.asarray(ex.p0), jnp.asarray(ex.lam0), args)
        return L.integrate(ex.problem, L.LobattoIIIAIIIB(stages=2), 0.0, T / n, n, ex.q0, ex.p0, lam0, args).q[-1, 0]

    errors = [abs(float(jax.grad(x_end)(g, n)) - exact) for n in (10, 20)]
    order = np.log2(errors[0] / errors[1])
    assert errors[1] < 1e-3 and order > 1.8, (errors, order)


def _adaptive_sleigh_run():
    """``(θ = (p0 scale, t1), differentiable, t_eval) -> q, p at t1 (or q at t_eval)``: the sleigh
    with s = 4 under PIController, p0 scaled (λ0 consistent)."""
    ex = get_example("sleigh")
    method = L.LobattoIIIAIIIB(stages=4)

    def run(theta, differentiable=True, t_eval=None):
        p0 = theta[0] * jnp.asarray(ex.p0)
        lam0 = L.consistent_lambda(ex.problem, 0.0, jnp.asarray(ex.q0), p0, jnp.asarray(ex.lam0), ex.args)
        r = L.integrate_adaptive(ex.problem, method, (0.0, theta[1]), ex.q0, p0, lam0, ex.args, rtol=1e-8,
                                 atol=1e-10, max_steps=MAX_STEPS_ADAPTIVE, differentiable=differentiable,
                                 t_eval=t_eval)
        if t_eval is not None:
            return r.q.ravel()
        return jnp.concatenate([r.q[r.n_rows - 1], r.p[r.n_rows - 1]])

    return run, jnp.array([1.0, 1.0])


def test_adaptive_reverse_mode_matches_forward_mode_and_finite_differences():
    run, theta = _adaptive_sleigh_run()
    reverse = np.asarray(jax.jacrev(run)(theta))
    forward = np.asarray(jax.jacfwd(lambda x: run(x, differentiable=False))(theta))
    scale = np.max(np.abs(forward))
    assert np.max(np.abs(forward - reverse)) <= 1e-10 * scale
    # the step-size choices are not differentiated: finite differences of the adaptive map
    # differ from the derivative along the chosen steps by O(tolerance)
    fd = _central_differences(run, theta, 1e-6)
    assert np.max(np.abs(forward - fd)) <= 1e-6 * scale


@pytest.mark.slow
def test_adaptive_t_eval_rows_in_reverse_mode_match_forward_mode():
    """t_eval rows are read from the dense output after the loop (differentiable=True) or while
    it runs; both give the same derivatives. Times inside the interval: a row at t1 itself is
    the end state in the while loop (derivative f in t1) and the dense value at the fixed time
    t1 after the scan (derivative ~0)."""
    run, theta = _adaptive_sleigh_run()
    t_eval = jnp.linspace(0.2, 0.9, 4)
    rows_reverse = np.asarray(jax.jacrev(lambda x: run(x, True, t_eval))(theta))
    rows_forward = np.asarray(jax.jacfwd(lambda x: run(x, False, t_eval))(theta))
    np.testing.assert_allclose(rows_reverse, rows_forward, rtol=1e-10, atol=1e-12)


def test_reversible_step_size_control_is_differentiable():
    """ReversibleStepSize's steps are not differentiated either (through its density they gave
    NaN): reverse and forward mode agree, and both agree with central differences."""
    ex = get_example("sleigh")
    method = L.LobattoIIIAIIIB(stages=4)

    def run(theta, differentiable=True):
        p0 = theta[0] * jnp.asarray(ex.p0)
        lam0 = L.consistent_lambda(ex.problem, 0.0, jnp.asarray(ex.q0), p0, jnp.asarray(ex.lam0), ex.args)
        r = L.integrate_adaptive(ex.problem, method, (0.0, theta[1]), ex.q0, p0, lam0, ex.args, rtol=1e-8,
                                 atol=1e-10, first_step=0.05, max_steps=MAX_STEPS_ADAPTIVE,
                                 differentiable=differentiable, controller=L.ReversibleStepSize())
        return jnp.concatenate([r.q[r.n_rows - 1], r.p[r.n_rows - 1]]), r.status

    theta = jnp.array([1.0, 1.0])
    assert int(run(theta)[1]) == L.Result.SUCCESSFUL

    def final(x, differentiable=True):
        return run(x, differentiable)[0]

    reverse = np.asarray(jax.jacrev(final)(theta))
    forward = np.asarray(jax.jacfwd(lambda x: final(x, differentiable=False))(theta))
    scale = np.max(np.abs(forward))
    assert np.all(np.isfinite(reverse)) and np.max(np.abs(forward - reverse)) <= 1e-10 * scale
    fd = _central_differences(lambda x: final(x, differentiable=False), theta, 1e-6)
    assert np.max(np.abs(forward - fd)) <= 1e-6 * scale


def test_differentiable_adaptive_run_gives_the_same_solution():
    ex = get_example("sleigh")
    method = L.LobattoIIIAIIIB(stages=4)
    kwargs = dict(rtol=1e-7, atol=1e-9, max_steps=200)
    a = L.integrate_adaptive(ex.problem, method, (0.0, 5.0), ex.q0, ex.p0, ex.lam0, ex.args, **kwargs)
    b = L.integrate_adaptive(ex.problem, method, (0.0, 5.0), ex.q0, ex.p0, ex.lam0, ex.args, differentiable=True,
                             **kwargs)
    assert int(a.status) == int(b.status) == L.Result.SUCCESSFUL
    assert int(a.n_rows) == int(b.n_rows) and int(a.n_rejected) == int(b.n_rejected)
    k = int(a.n_rows)
    np.testing.assert_array_equal(np.asarray(a.q[:k]), np.asarray(b.q[:k]))
    assert np.all(np.isnan(np.asarray(b.q[k:])))
    # too few attempts: the same status in both loops
    short = dict(kwargs, max_steps=5)
    c = L.integrate_adaptive(ex.problem, method, (0.0, 5.0), ex.q0, ex.p0, ex.lam0, ex.args, differentiable=True, **short)
    assert int(c.status) == L.Result.MAX_STEPS


def test_gradient_of_a_batch_by_vmap():
    ex = get_example("knife-edge")
    run, theta = _final_state(ex, L.LobattoIIIAIIIB(stages=2))
    grad = jax.grad(lambda x: run(x)[0])
    thetas = jnp.stack([theta, theta.at[1].set(0.9)])
    batched = np.asarray(jax.vmap(grad)(thetas))
    np.testing.assert_allclose(batched[1], np.asarray(grad(thetas[1])), rtol=1e-12, atol=1e-14)


def test_solve_under_a_transformation_points_to_the_pure_entry_points():
    ex = get_example("knife-edge")
    method = L.LobattoIIIAIIIB(stages=2)

    def loss(p0):
        return L.solve(ex.problem, method, (0.0, 1.0), ex.q0, p0, args=ex.args, n_steps=4).q[-1, 0]

    with pytest.raises(L.LobattoDAEInputError, match=r"traced p0.*integrate_adaptive\(\.\.\., differentiable=True\)"):
        jax.grad(loss)(jnp.asarray(ex.p0))


def test_projection_and_consistent_lambda_are_differentiable():
    ex = get_example("sleigh")
    q0 = jnp.asarray(ex.q0)

    def complete(p):
        p0 = L.project_momenta(ex.problem, 0.0, q0, p, ex.args)
        return jnp.concatenate([p0, L.consistent_lambda(ex.problem, 0.0, q0, p0, jnp.zeros(1), ex.args)])

    p = jnp.asarray(ex.p0) + 0.3
    assert float(jnp.max(jnp.abs(ex.problem.phi(0.0, q0, complete(p)[:3], ex.args)))) < 1e-14
    np.testing.assert_allclose(jax.jacrev(complete)(p), _central_differences(complete, p, 1e-6), atol=1e-8)


def test_auto_checkpoints_resolve_and_agree():
    """``checkpoints="auto"`` (the default) keeps every step up to AUTO_CHECKPOINT_BYTES per
    trajectory and splits longer scans into √length segments; segments change neither the
    forward values nor, beyond round-off, the gradient."""
    from lobattodae._doubling import StepDoubling
    from lobattodae._integrate import AUTO_CHECKPOINT_BYTES, kept_bytes, resolve_checkpoints

    method = L.LobattoIIIAIIIB(stages=3)
    per = kept_bytes(method, 3, 1)
    assert per == 3 * 8 * 4 * 7 and kept_bytes(StepDoubling(method), 3, 1) == 3 * per  # three solves per attempt
    fits = AUTO_CHECKPOINT_BYTES // per
    assert resolve_checkpoints("auto", fits, per) is None
    assert resolve_checkpoints("auto", fits + 1, per) == round((fits + 1) ** 0.5)
    assert resolve_checkpoints("auto", 2000, 4 * per) == 45
    assert resolve_checkpoints(None, 2000, per) is None and resolve_checkpoints(7, 2000, per) == 7
    ex = get_example("knife-edge")
    n = 121  # 11 segments of 11 (0 idle attempts)
    def final(p0, checkpoints):
        return L.integrate(ex.problem, method, 0.0, 0.02, n, ex.q0, p0, ex.lam0, ex.args, checkpoints=checkpoints)

    p0 = jnp.asarray(ex.p0)
    for a, b in zip(final(p0, 11), final(p0, None)):
        assert jnp.array_equal(a, b)
    loss = lambda p, ck: jnp.sum(final(p, ck).q[-1] ** 2)  # noqa: E731
    g_auto, g_all = jax.grad(loss)(p0, 11), jax.grad(loss)(p0, None)
    np.testing.assert_allclose(g_auto, g_all, rtol=1e-12, atol=1e-14)
    assert float(jnp.max(jnp.abs(g_all))) > 1e-3  # a gradient that is not trivially zero
