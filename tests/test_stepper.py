"""The Lobatto IIIA-IIIB method object (lobattodae._stepper): its options, one step of the
public API (symmetric, jit- and vmap-able, the numbers of solve's loop), and the Λ₁ policies
(``lam_start``) over long runs."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import lobattodae as L
from lobattodae.examples import get_example


# -- options ------------------------------------------------------------------------------------------
@pytest.mark.parametrize("s", [1, 0, -3])
def test_too_few_stages(s):
    with pytest.raises(ValueError, match="s must be an integer >= 2"):
        L.LobattoIIIAIIIB(stages=s)


def test_non_integer_stages():
    with pytest.raises(TypeError):
        L.LobattoIIIAIIIB(stages=2.5)


def test_bad_lam_start():
    with pytest.raises(ValueError, match="lam_start must be 'auto'.*'previous'.*'consistent'"):
        L.LobattoIIIAIIIB(stages=3, lam_start="zero")


# -- one step ------------------------------------------------------------------------------------------
def test_step_forward_then_backward_returns_to_start(knife):
    m = L.LobattoIIIAIIIB(stages=4)
    q0, p0, lam0 = map(jnp.asarray, (knife.q0, knife.p0, knife.lam0))
    h = 0.1
    step = jax.jit(lambda t, q, p, lam, dt: m.step(knife.problem, t, q, p, lam, dt, knife.args))  # one compile
    q1, p1, lam1, info, _ = step(0.0, q0, p0, lam0, h)
    assert int(info.result) == 0
    qb, pb, lamb, info_b, _ = step(h, q1, p1, lam1, -h)
    assert int(info_b.result) == 0
    # q, p: the Lobatto IIIA-IIIB pair is symmetric, so it returns to the start to round-off.
    np.testing.assert_allclose(qb, q0, atol=1e-13)
    np.testing.assert_allclose(pb, p0, atol=1e-13)
    assert float(jnp.max(jnp.abs(qb - q1))) > 1e-3  # the step really moved


@pytest.mark.parametrize("lam_start", ["previous", "consistent"])
def test_solve_equals_a_loop_of_public_steps(lam_start):
    """solve's compiled loop hands λ(q_k, p_k) from its drift diagnostic to the next step for
    lam_start="consistent" instead of solving for it again; the numbers must be those of
    the public one-step API called in a Python loop (the rolling disk: λ is 2-dimensional
    and the hidden constraint is nonlinear in q, so a wrong Λ_1 would show)."""
    ex = get_example("falling-disk-general")
    m = L.LobattoIIIAIIIB(stages=3, lam_start=lam_start)
    n, h = 12, 0.05
    sol = L.solve(ex.problem, m, (0.0, n * h), ex.q0, ex.p0, n_steps=n, args=ex.args)
    step = jax.jit(lambda t, q, p, lam, st: m.step(ex.problem, t, q, p, lam, h, ex.args, st))
    q, p, lam = map(jnp.asarray, (sol.q[0], sol.p[0], sol.lam[0]))
    state = m.init(ex.problem, sol.t[0], q, p, lam, ex.args)
    for k in range(n):
        q, p, lam, info, state = step(sol.t[0] + k * h, q, p, lam, state)
        assert int(info.result) == 0
        np.testing.assert_allclose(q, sol.q[k + 1], rtol=0, atol=1e-14)
        np.testing.assert_allclose(p, sol.p[k + 1], rtol=0, atol=1e-14)
        np.testing.assert_allclose(lam, sol.lam[k + 1], rtol=0, atol=1e-12)
        if lam_start == "consistent":
            lam_c = L.consistent_lambda(ex.problem, sol.t[k + 1], q, p, lam, ex.args)
            assert sol.stats["multiplier_drift"][k + 1] == pytest.approx(float(jnp.max(jnp.abs(lam - lam_c))), abs=1e-12)


def test_step_is_jittable_and_vmappable(knife):
    m = L.LobattoIIIAIIIB(stages=3)
    q0, p0, lam0 = map(jnp.asarray, (knife.q0, knife.p0, knife.lam0))
    step = jax.jit(lambda q, p, l: m.step(knife.problem, 0.0, q, p, l, 0.05, knife.args)[:3])
    single = step(q0, p0, lam0)
    qs = jnp.stack([q0, q0 + jnp.array([1.0, 0.0, 0.0])])  # x shift keeps consistency
    batched = jax.vmap(step)(qs, jnp.stack([p0, p0]), jnp.stack([lam0, lam0]))
    for a, b in zip(single, batched):
        np.testing.assert_allclose(b[0], a, rtol=0, atol=1e-15)
    np.testing.assert_allclose(batched[0][1], single[0] + jnp.array([1.0, 0, 0]), atol=1e-13)


# -- the multiplier at the start of a step (lam_start) ---------------------------------------------------
def test_lam_policies_on_the_sleigh():
    """The Chaplygin sleigh (s = 5, h = 0.1, t = 130): the paper's scheme carries a λ error that
    grows like exp(0.18 t) and spoils q (the run warns and says so in its message); the default
    re-synchronises λ when its drift leaves the band and stays at round-off, as does
    lam_start='consistent'."""
    import warnings

    ex = get_example("sleigh")
    qe = ex.exact(np.array([130.0]))[0][0]
    kw = dict(n_steps=1300, args=ex.args)
    with pytest.warns(RuntimeWarning, match="lam_start='auto'"):
        paper = L.solve(ex.problem, L.LobattoIIIAIIIB(stages=5, lam_start="previous"), (0.0, 130.0), ex.q0, ex.p0,
                        throw=False, **kw)
    assert np.max(paper.stats["multiplier_drift"]) > 1.0 and paper.stats["lam_excursions"] > 0
    assert "Warning: the multiplier" in paper.message and paper.stats["lam_resets"] == 0
    assert np.max(np.abs(paper.q[-1] - qe)) > 1e-2
    for mode in ("auto", "consistent"):
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            sol = L.solve(ex.problem, L.LobattoIIIAIIIB(stages=5, lam_start=mode), (0.0, 130.0), ex.q0, ex.p0, **kw)
        assert np.max(np.abs(sol.q[-1] - qe)) < 1e-9, mode
        assert np.max(sol.stats["multiplier_drift"]) < 1e-4, mode
    assert 1 <= sol.stats["lam_resets"] or mode == "consistent"
    auto = L.solve(ex.problem, L.LobattoIIIAIIIB(stages=5), (0.0, 130.0), ex.q0, ex.p0, **kw)
    assert 1 <= auto.stats["lam_resets"] <= 10 and auto.stats["lam_resets"] == int(np.sum(auto.stats["lam_resync"]))


def test_auto_never_resets_on_a_reversible_problem():
    """On the reversible contact oscillator the λ error of the paper's scheme stays in its band:
    'auto' never re-synchronises, so it is the symmetric scheme, bit for bit."""
    ex = get_example("contact")
    h = 2 * np.sin(np.pi / 15)
    kw = dict(n_steps=20_000, args=ex.args)
    auto = L.solve(ex.problem, L.LobattoIIIAIIIB(stages=3), (0.0, 20_000 * h), ex.q0, ex.p0, **kw)
    paper = L.solve(ex.problem, L.LobattoIIIAIIIB(stages=3, lam_start="previous"), (0.0, 20_000 * h), ex.q0, ex.p0, **kw)
    assert auto.stats["lam_resets"] == 0 and paper.stats["lam_excursions"] == 0
    np.testing.assert_array_equal(auto.q, paper.q)


def test_a_rejected_attempt_hands_on_its_jacobian_and_nothing_else():
    """after_rejection: a rejected attempt's state is reverted, except its Jacobian factorisation
    (and the step size it was evaluated with); a kept attempt's state is taken whole. Also for
    step doubling's two factorisations."""
    from lobattodae._doubling import StepDoubling

    ex = get_example("knife-edge")
    q0, p0 = jnp.asarray(ex.q0), jnp.asarray(ex.p0)
    lam0 = jnp.zeros(1)
    for method in (L.LobattoIIIAIIIB(stages=3), StepDoubling(L.LobattoIIIAIIIB(stages=3, lam_start="consistent"))):
        old = method.init(ex.problem, 0.0, q0, p0, lam0, ex.args, 0.1)
        *_, new = method.step(ex.problem, 0.0, q0, p0, lam0, 0.1, ex.args, old)
        rejected = method.after_rejection(jnp.asarray(False), new, old)
        kept = method.after_rejection(jnp.asarray(True), new, old)
        same = lambda a, b: all(np.array_equal(x, y) for x, y in zip(jax.tree_util.tree_leaves(a), jax.tree_util.tree_leaves(b)))  # noqa: E731
        assert same(kept, new)
        if isinstance(method, StepDoubling):  # both factorisations, stacked (whole step, half steps)
            jac_new, jac_old, jac_rej = (x.jacobians for x in (new, old, rejected))
            h_new, h_rej = new.h_jacobians, rejected.h_jacobians
            assert same(rejected.whole_history, old.whole_history)
            assert new.half.jacobian is None and new.half.h_jacobian is None
        else:
            jac_new, jac_old, jac_rej = (x.jacobian for x in (new, old, rejected))
            h_new, h_rej = new.h_jacobian, rejected.h_jacobian
        half_new, half_old, half_rej = (getattr(x, "half", x) for x in (new, old, rejected))
        assert same(jac_rej, jac_new) and not same(jac_old, jac_new)
        assert same(h_rej, h_new)
        assert same(half_rej.history, half_old.history) and not same(half_new.history, half_old.history)
