"""Bad problems, args and initial values get a clear LobattoDAEInputError naming the argument
and the fix, before a run (lobattodae._validate, lobattodae._problem_trace; issue #13).

One test per defect fixed (each failed before the fix: a NaN in args reported as an
inconsistent λ0, a wrong-length q0 as "dot_general requires contracting dimensions", a string
args leaf with JAX's advice about static_argnums, ...), then hypothesis fuzz tests: every bad
q0, p0, lam0, t0, args or problem function raises a LobattoDAEInputError subclass with a
message, never a raw JAX/NumPy error, and nothing returns success with non-finite values.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import lobattodae as L
from lobattodae._validate import MIN_NEWTON_TOL, check_tolerance_attainable
from lobattodae.examples import get_example

from helpers import RAW, particle_with, solve_short

METHOD = L.LobattoIIIAIIIB(stages=2)


#: One particle reading args['k'], shared by the tests (a problem is compiled per object).
PARTICLE_K = particle_with(hamiltonian=lambda t, q, p, a: 0.5 * a["k"] * (p @ p))
Q3, P3 = np.zeros(3), np.array([1.0, 1.0, 0.0])


def _message(exc_info) -> str:
    msg = str(exc_info.value)
    assert msg, "empty message"
    for raw in RAW:
        assert raw not in msg, msg
    return msg


# -- initial values, user functions, consistency -------------------------------------------------
def test_shape_mismatch_q_p(particle):
    with pytest.raises(L.ShapeError, match="same shape"):
        solve_short(particle, p0=np.ones(4))


def test_q0_not_1d(particle):
    with pytest.raises(L.ShapeError, match=r"1-D array of shape \(n,\)"):
        solve_short(particle, q0=np.zeros((3, 1)))


def test_nonfinite_initial_values(particle):
    with pytest.raises(L.ShapeError, match="non-finite"):
        solve_short(particle, q0=np.array([0.0, np.nan, 0.0]))


def test_lam0_wrong_shape(particle):
    with pytest.raises(L.ShapeError, match=r"lam0 must have shape \(m,\) = \(1,\)"):
        solve_short(particle, lam0=np.ones(2))


def test_user_function_wrong_output_shape():
    prob = L.PartitionedDAE(
        f=lambda t, q, p, a: p[:2],
        g=lambda t, q, p, lam, a: -q,
        phi=lambda t, q, p, a: jnp.array([p[0]]),
    )
    with pytest.raises(L.ShapeError, match=r"f\(t, q, p, args\) must return an array of shape \(3,\)"):
        L.solve(prob, L.LobattoIIIAIIIB(stages=2), (0, 1), np.zeros(3), np.zeros(3), n_steps=2)


def test_user_function_raises():
    def bad_phi(t, q, p, a):
        raise KeyError("oops")

    prob = L.PartitionedDAE(lambda t, q, p, a: p, lambda t, q, p, lam, a: -q, bad_phi)
    with pytest.raises(L.ProblemFunctionError, match="calling phi.*KeyError.*problem's function") as info:
        L.solve(prob, L.LobattoIIIAIIIB(stages=2), (0, 1), np.zeros(3), np.zeros(3), n_steps=2)
    assert isinstance(info.value.__cause__, KeyError) and isinstance(info.value, L.LobattoDAEInputError)
    assert not isinstance(info.value, L.ShapeError)


def test_inconsistent_initial_values(particle):
    with pytest.raises(L.InconsistentInitialValuesError, match=r"violate the constraint.*project_initial=True"):
        solve_short(particle, p0=np.array([1.0, 1.0, 0.5]))


def test_inconsistent_initial_values_projected(particle):
    sol = solve_short(particle, p0=np.array([1.0, 1.0, 0.5]), project_initial=True)
    assert sol.success
    phi0 = particle.problem.phi(0.0, jnp.asarray(sol.q[0]), jnp.asarray(sol.p[0]), particle.args)
    assert float(jnp.max(jnp.abs(phi0))) < 1e-14
    assert np.max(sol.stats["constraint_residual"]) < 1e-13


def test_inconsistent_lambda0(particle):
    with pytest.raises(L.InconsistentInitialValuesError, match=r"lam0 violates the hidden constraint.*lam0 = \[1\.\]"):
        solve_short(particle, lam0=np.array([3.0]))


def test_consistent_lambda0_accepted(particle):
    sol = solve_short(particle, lam0=particle.lam0)
    np.testing.assert_array_equal(sol.lam[0], particle.lam0)


def test_singular_holonomic_constraint():
    # φ(q) = q_0 does not depend on p: D_pφ D_λg = 0, the problem is index 3.
    prob = L.PartitionedDAE(
        f=lambda t, q, p, a: p,
        g=lambda t, q, p, lam, a: -q + jnp.array([lam[0], 0.0]),
        phi=lambda t, q, p, a: jnp.array([q[0]]),
    )
    with pytest.raises(L.SingularConstraintError, match="holonomic constraint .* must be differentiated"):
        L.solve(prob, L.LobattoIIIAIIIB(stages=2), (0, 1), np.zeros(2), np.array([0.0, 1.0]), n_steps=2)


def test_repeated_constraint_is_singular():
    prob = L.NonholonomicSystem(
        lambda t, q, p, a: 0.5 * p @ p,
        lambda t, q, a: jnp.array([[-q[1], 0.0, 1.0], [-q[1], 0.0, 1.0]]),
    )
    with pytest.raises(L.SingularConstraintError, match="singular"):
        L.solve(prob, L.LobattoIIIAIIIB(stages=2), (0, 1), np.zeros(3), np.array([1.0, 1.0, 0.0]), n_steps=2)


# -- 1. non-finite args ----------------------------------------------------------------------
def test_nan_in_args_leaf_named_by_path(knife):
    bad = knife.args._replace(g=float("nan"))
    with pytest.raises(L.ShapeError) as info:
        L.solve(knife.problem, METHOD, knife.t_span, knife.q0, knife.p0, args=bad, n_steps=2)
    msg = _message(info)
    assert "args.g" in msg and "finite" in msg
    assert "lam0" not in msg and "nan]" not in msg  # no longer "lam0 = [nan]"


def test_inf_in_dict_args_array_named_by_path():
    args = {"k": np.array([1.0, np.inf])}
    with pytest.raises(L.ShapeError) as info:
        L.validate_initial_values(PARTICLE_K, 0.0, Q3, P3, args=args)
    msg = _message(info)
    assert "args['k']" in msg and "1 NaN or inf" in msg


def test_nan_in_nested_args_leaf():
    args = {"k": 1.0, "extra": (0.0, [1.0, -np.inf])}
    with pytest.raises(L.ShapeError, match=r"args\['extra'\]\[1\]\[1\] = -inf"):
        L.validate_initial_values(PARTICLE_K, 0.0, Q3, P3, args=args)


@pytest.mark.parametrize(
    "leaf, shown",
    [(jnp.asarray(np.nan), "= nan"), (np.float32(np.inf), "= inf"), (jnp.asarray(1j * np.inf), "inf"),
     (jnp.array([1.0, np.nan], jnp.bfloat16), "1 NaN or inf")],
)
def test_non_finite_args_leaf_of_any_inexact_kind_is_named(leaf, shown):
    """A JAX or NumPy scalar, a complex value and a bfloat16 array: each checked (the scalar
    fast path included) and named."""
    with pytest.raises(L.ShapeError) as info:
        L.validate_initial_values(PARTICLE_K, 0.0, Q3, P3, args={"k": 1.0, "x": leaf})
    assert "args['x']" in _message(info) and shown in _message(info)


def test_args_cache_key_is_jax_s_view_of_each_leaf():
    """The caches' key of an args leaf (decided once per dtype) is what ``jnp.result_type``
    says of the leaf itself, for every kind of leaf."""
    import jax

    from lobattodae._problem_trace import _aval

    leaves = [jnp.asarray(1.0), jnp.asarray(1.0) * 2, jnp.array(1.0, jnp.float32), np.float32(1.0), np.array([1, 2]),
              np.array([1, 2], np.int8), jnp.asarray(3), np.bool_(True), jnp.array([True]), 1.0, 2, True, 1j,
              np.complex64(1.0), jnp.array(1.0, jnp.bfloat16), np.array(1, np.uint32)]
    for leaf in leaves:
        expected = (np.shape(leaf), jnp.result_type(leaf), not isinstance(leaf, (np.ndarray, np.generic, jax.Array)))
        assert _aval(leaf) == expected, leaf


def test_args_making_functions_non_finite_is_named(knife):
    # finite args, but a zero mass: H divides by it. Before: "lam0 = [nan]" or a singular matrix.
    with pytest.raises(L.ShapeError, match=r"not finite at the initial point.*args.*zero mass"):
        L.validate_initial_values(knife.problem, 0.0, knife.q0, knife.p0, lam0=[1.0], args=knife.args._replace(m=0.0))


# -- 2. wrong-length q0 / p0 / lam0 ------------------------------------------------------------
@pytest.mark.parametrize("n", [2, 4])
def test_wrong_length_q0_p0_names_expected_length(knife, n):
    with pytest.raises(L.ShapeError) as info:
        L.solve(knife.problem, METHOD, knife.t_span, np.zeros(n), np.ones(n), args=knife.args, n_steps=2)
    msg = _message(info)
    assert f"q0 and p0 have length {n}" in msg
    assert "written for n = 3 coordinates" in msg and "pass q0 and p0 of length 3" in msg


def test_wrong_length_particle_was_dot_general():
    # the case of the report: "dot_general requires contracting dimensions to have the same shape"
    with pytest.raises(L.ShapeError) as info:
        L.validate_initial_values(particle_with(), 0.0, [0.0, 0.0], [1.0, 1.0])
    msg = _message(info)
    assert "q0 and p0 have length 2" in msg and "pass q0 and p0 of length 3" in msg


@pytest.mark.parametrize("which", ["q0", "p0"])
def test_q0_p0_of_different_lengths_says_which_is_wrong(knife, which):
    q0, p0 = (knife.q0[:2], knife.p0) if which == "q0" else (knife.q0, knife.p0[:2])
    with pytest.raises(L.ShapeError, match=rf"same shape.*work with n = 3: {which} has the wrong length"):
        L.validate_initial_values(knife.problem, 0.0, q0, p0, args=knife.args)


def test_wrong_length_general_dae_inferred_by_tracing():
    # no constraint matrix to read n from: g only works for n = 3, found by tracing other lengths
    dae = L.PartitionedDAE(
        f=lambda t, q, p, a: p,
        g=lambda t, q, p, lam, a: -q + jnp.array([0.0, lam[0], 0.0]),
        phi=lambda t, q, p, a: p[1:2],
    )
    with pytest.raises(L.ShapeError) as info:
        L.validate_initial_values(dae, 0.0, [0.0, 0.0], [1.0, 0.0])
    msg = _message(info)
    assert "q0 and p0 have length 2" in msg and "expect length 3" in msg and "g(t, q, p, lam, args)" in msg


def test_wrong_length_lam0(knife):
    with pytest.raises(L.ShapeError, match=r"lam0 must have shape \(m,\) = \(1,\).*omit lam0"):
        L.validate_initial_values(knife.problem, 0.0, knife.q0, knife.p0, lam0=[1.0, 2.0], args=knife.args)


def test_mass_matrix_of_other_size_names_lengths():
    mech = L.MechanicalSystem(
        mass_matrix=lambda t, q, a: jnp.eye(3),
        potential=lambda t, q, a: 0.0 * q[0],
        constraint_matrix=lambda t, q, a: jnp.array([[-q[1], 0.0, 1.0]]),
    )
    expected = r"q0 and p0 have length 2, but mass_matrix\(t, q, args\) returned shape \(3, 3\)"
    with pytest.raises(L.ShapeError, match=expected):
        L.validate_initial_values(mech, 0.0, [0.0, 0.0], [1.0, 1.0])


# -- 3. args leaves that are not numbers; fields missing from args ------------------------------
def test_string_args_leaf_named_without_static_argnums_advice(knife):
    bad = knife.args._replace(g="9.81")
    with pytest.raises(L.ShapeError) as info:
        L.solve(knife.problem, METHOD, knife.t_span, knife.q0, knife.p0, args=bad, n_steps=2)
    msg = _message(info)
    assert "args.g is the string '9.81'" in msg and "numbers or numeric arrays" in msg


@pytest.mark.parametrize(
    "args, where",
    [
        ({"k": 1.0, "mode": "fast"}, "args['mode'] is the string"),
        ({"k": 1.0, "obj": object()}, "args['obj'] is of type object"),
        ({"k": 1.0, "x": np.array(["a", "b"])}, "args['x'] is an array of dtype <U1"),
        ({"k": 1.0, "big": 10**30}, "args['big'] = 1000000000000000000000000000000 does not fit"),
    ],
)
def test_non_numeric_args_leaves(args, where):
    with pytest.raises(L.ShapeError) as info:
        L.validate_initial_values(PARTICLE_K, 0.0, Q3, P3, args=args)
    assert where in _message(info)


def test_missing_dict_key_named():
    with pytest.raises(L.ProblemFunctionError) as info:
        L.validate_initial_values(PARTICLE_K, 0.0, Q3, P3, args={"c": 1.0})
    msg = _message(info)
    assert "the key 'k' is missing from args" in msg and "['c']" in msg
    assert isinstance(info.value.__cause__, KeyError)


class _Wrong(NamedTuple):
    m: float
    J: float


@pytest.mark.parametrize(
    "args, expected",
    [
        (_Wrong(1.0, 1.0), "the field 'g' is missing from args (its fields: ['m', 'J'])"),
        (None, "args is None, but the problem's functions read args.m"),
        ({"m": 1.0, "J": 1.0, "g": 1.0}, "read args.m (an attribute), but args is a dict"),
        (2.0, "args is a single number or array, but the problem's functions read args.m"),
        ((1.0, 1.0, 1.0), "args is a tuple"),
    ],
)
def test_missing_attribute_field_named(knife, args, expected):
    with pytest.raises(L.ProblemFunctionError) as info:
        L.solve(knife.problem, METHOD, knife.t_span, knife.q0, knife.p0, args=args, n_steps=2)
    msg = _message(info)
    assert expected in msg, msg
    assert isinstance(info.value.__cause__, AttributeError)


def test_none_valued_args_field_named(knife):
    with pytest.raises(L.ProblemFunctionError, match=r"args\.m is None: args leaves must be numbers"):
        L.validate_initial_values(knife.problem, 0.0, knife.q0, knife.p0, args=knife.args._replace(m=None))


def test_bad_t0_for_validate(knife):
    for t0 in ("0", None, float("nan"), [0.0]):
        with pytest.raises(L.ShapeError, match="t0 must be a finite real number"):
            L.validate_initial_values(knife.problem, t0, knife.q0, knife.p0, args=knife.args)


# -- 4. constraint matrix of the wrong shape ----------------------------------------------------
def test_constraint_matrix_wrong_columns_named():
    prob = particle_with(mu=lambda t, q, a: jnp.array([[-q[1], 0.0, 1.0, 0.0]]))
    with pytest.raises(L.ShapeError) as info:
        L.solve(prob, METHOD, (0.0, 1.0), Q3, P3, n_steps=2)
    msg = _message(info)
    assert "constraint_matrix(t, q, args) returned shape (1, 4)" in msg
    assert "must return an array of shape (1, 3)" in msg
    assert "phi(" not in msg  # was reported as an error of phi


def test_constraint_matrix_one_dimensional_named():
    prob = particle_with(mu=lambda t, q, a: jnp.array([-q[1], 0.0, 1.0]))
    expected = r"constraint_matrix\(t, q, args\) must return a 2-D array of shape \(m, n\) = \(m, 3\).*returned shape \(3,\)"
    with pytest.raises(L.ShapeError, match=expected):
        L.validate_initial_values(prob, 0.0, Q3, P3)


# -- 5. a Newton tolerance below what float64 can deliver ---------------------------------------
def test_tolerance_below_round_off_refused():
    with pytest.raises(L.LobattoDAEInputError) as info:
        check_tolerance_attainable(L.LobattoIIIAIIIB(stages=3, tol=1e-17))
    msg = str(info.value)
    assert "tol=1e-17" in msg and "8.9e-16" in msg and "float64" in msg


def test_attainable_tolerances_accepted():
    assert math.isclose(MIN_NEWTON_TOL, 4 * np.finfo(np.float64).eps)
    for tol in (1e-14, 1e-10, MIN_NEWTON_TOL):
        check_tolerance_attainable(L.LobattoIIIAIIIB(stages=3, tol=tol))


# -- fuzz: every bad input gives a LobattoDAEInputError ----------------------------------------
_NONFINITE = st.sampled_from([float("nan"), float("inf"), -float("inf")])


@st.composite
def _nonfinite_vector(draw, n=3):
    v = draw(st.lists(st.floats(-10, 10), min_size=n, max_size=n))
    v[draw(st.integers(0, n - 1))] = draw(_NONFINITE)
    return v


def _bad_vector(n):
    """Values that are not a finite float vector of length n."""
    return st.one_of(
        _nonfinite_vector(n),
        st.integers(0, 6).filter(lambda k: k != n).map(lambda k: [0.5] * k),
        st.text(max_size=4),
        st.none(),
        st.just([[0.0] * n]),  # 2-D
        st.just([[0.0], [0.0, 1.0]] + [0.0] * (n - 2)),  # ragged
        st.just([None] + [0.0] * (n - 1)),
        st.just({"q": [0.0] * n}),
        st.just([1j] * n),
        st.just(np.array([True] * n)),
        st.just(object()),
    )


_BAD_LEAF = st.one_of(
    _NONFINITE,
    st.text(max_size=4),
    st.none(),
    st.just(object()),
    st.just(["a", "b"]),
    st.just([None]),
    st.just(1.0 + 2.0j),
    st.just(b"1.0"),
    st.just({"x": "y"}),
    st.just(np.array([1.0, np.nan])),
    st.just(np.array([1.0, 2.0])),
    st.just([[1.0], [2.0, 3.0]]),
)


_BAD_ARGS = st.one_of(
    st.none(),
    st.just(3.0),
    st.just([1.0, 1.0, 1.0]),
    st.just({"m": 1.0, "J": 1.0, "g": 1.0}),
    st.just({"m": 1.0}),
    st.just("m=1"),
    st.just((1.0,)),
)


@st.composite
def _bad_input(draw):
    """One argument of a consistent knife-edge start replaced by a bad value: (name, value)."""
    target = draw(st.sampled_from(["q0", "p0", "qp", "lam0", "t0", "leaf", "args"]))
    if target in ("q0", "p0"):
        return target, draw(_bad_vector(3))
    if target == "qp":
        k = draw(st.sampled_from([0, 1, 2, 4, 5]))
        return target, (np.zeros(k), np.ones(k))
    if target == "lam0":
        return target, draw(_bad_vector(1).filter(lambda v: v is not None))  # None: computed
    if target == "t0":
        return target, draw(st.one_of(_NONFINITE, st.text(max_size=3), st.none(), st.just([0.0]), st.just(1j)))
    if target == "leaf":
        return target, (draw(st.sampled_from(["m", "J", "g"])), draw(_BAD_LEAF))
    return target, draw(_BAD_ARGS)


def _call(entry, ex, target, value):
    kw = {"q0": ex.q0, "p0": ex.p0, "lam0": None, "t0": 0.0, "args": ex.args}
    if target == "qp":
        kw["q0"], kw["p0"] = value
    elif target == "leaf":
        kw["args"] = ex.args._replace(**{value[0]: value[1]})
    elif target == "args":
        kw["args"] = value
    else:
        kw[target] = value
    if entry == "validate":
        return L.validate_initial_values(ex.problem, kw["t0"], kw["q0"], kw["p0"], kw["lam0"], kw["args"])
    return L.solve(
        ex.problem, METHOD, (kw["t0"], 1.0), kw["q0"], kw["p0"], lam0=kw["lam0"], args=kw["args"], n_steps=2
    )


_KNIFE = get_example("knife-edge")


@pytest.mark.parametrize("entry", ["validate", "solve"])
@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(bad=_bad_input())
def test_fuzz_bad_inputs_raise_input_errors(entry, bad):
    target, value = bad
    try:
        out = _call(entry, _KNIFE, target, value)
    except L.LobattoDAEInputError as exc:
        msg = str(exc)
        assert len(msg) > 20, msg
        for raw in RAW:
            assert raw not in msg, (target, value, msg)
        return
    # nothing bad may pass as success with non-finite values
    arrays = out if entry == "validate" else (out.q, out.p, out.lam)
    assert all(np.all(np.isfinite(a)) for a in arrays), (target, value)
    if entry == "solve":
        assert out.success
    pytest.fail(f"{target}={value!r} was accepted")


def _bad_function(kind):
    """A problem function that is wrong in the way ``kind`` says (f, g or phi of the particle)."""
    return {
        "none": lambda *a: None,
        "string": lambda *a: "x",
        "tuple": lambda *a: (jnp.zeros(3), jnp.zeros(3)),
        "raises": lambda *a: (_ for _ in ()).throw(ValueError("user bug")),
        "int": lambda *a: jnp.zeros(3, dtype=jnp.int32),
        "float32": lambda *a: jnp.zeros(3, dtype=jnp.float32),
        "shape": lambda *a: jnp.zeros((3, 3)),
        "nan": lambda *a: jnp.full(3, jnp.nan),
        "branch": lambda t, q, *a: q if q[0] > 0 else -q,
    }[kind]


_GOOD = {
    "f": lambda t, q, p, a: p,
    "g": lambda t, q, p, lam, a: jnp.array([q[1] * lam[0], 0.0, -lam[0]]),
    "phi": lambda t, q, p, a: jnp.array([p[2] - q[1] * p[0]]),
}


_BAD_PROBLEMS = {
    (field, kind): L.PartitionedDAE(**{**_GOOD, field: _bad_function(kind)})
    for field in ("f", "g", "phi")
    for kind in ("none", "string", "tuple", "raises", "int", "float32", "shape", "nan", "branch")
}


@settings(max_examples=40, deadline=None)
@given(field=st.sampled_from(["f", "g", "phi"]), kind=st.sampled_from(sorted({k for _, k in _BAD_PROBLEMS})))
def test_fuzz_bad_problem_functions(field, kind):
    prob = _BAD_PROBLEMS[(field, kind)]  # built once: tracing results are cached per problem
    with pytest.raises(L.LobattoDAEInputError) as info:
        L.validate_initial_values(prob, 0.0, Q3, P3)
    msg = _message(info)
    assert f"{field}(" in msg or "hidden constraint" in msg, msg
    if kind == "raises":
        assert isinstance(info.value, L.ProblemFunctionError) and isinstance(info.value.__cause__, ValueError)


@pytest.mark.parametrize("name", ["falling-disk-general", "knife-edge", "sleigh"])
def test_validation_hands_on_the_start_multiplier_of_the_hidden_constraint(name):
    """solve's run program takes λ(t0, q0, p0) (one Newton update of λ0, which a step's start
    uses) from the validation that has just evaluated the hidden constraint and its Jacobian at
    λ0, instead of tracing that solve once more: the value is the stepper's own to round-off,
    for a computed λ0 and for a given one (off by less than the consistency tolerance)."""
    from lobattodae._validate import validate_and_residual

    ex = get_example(name)
    q0, p0 = np.asarray(ex.q0, np.float64), np.asarray(ex.p0, np.float64)

    def stepper_value(lam):
        return np.asarray(L.consistent_lambda(ex.problem, 0.0, jnp.asarray(q0), jnp.asarray(p0), jnp.asarray(lam),
                                              ex.args, iterations=1))

    computed = validate_and_residual(ex.problem, 0.0, q0, p0, None, ex.args)
    scale = 1.0 + np.max(np.abs(computed.lam0))
    np.testing.assert_allclose(computed.lam_hidden, stepper_value(computed.lam0), rtol=0, atol=1e-13 * scale)
    given_lam = computed.lam0 + 1e-11 * scale  # within the tolerance: accepted, and corrected by the update
    given = validate_and_residual(ex.problem, 0.0, q0, p0, given_lam, ex.args)
    np.testing.assert_array_equal(given.lam0, given_lam)
    np.testing.assert_allclose(given.lam_hidden, stepper_value(given_lam), rtol=0, atol=1e-13 * scale)
    assert np.max(np.abs(given.lam_hidden - computed.lam0)) < 1e-13 * scale
