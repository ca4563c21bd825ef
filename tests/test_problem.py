"""Problem definitions (lobattodae._problem): what a problem object refuses to be built from,
and how problems compare (by identity: one compiled loop per problem object)."""

import jax.numpy as jnp
import pytest

import lobattodae as L
from lobattodae._errors import ProblemDefinitionError

from helpers import particle_with


@pytest.mark.parametrize(
    "build, expected",
    [
        (lambda: L.NonholonomicSystem(), "NonholonomicSystem needs hamiltonian, a function H(t, q, p, args)"),
        (lambda: L.NonholonomicSystem(lambda t, q, p, a: 0.0), "needs constraint_matrix, a function mu(t, q, args)"),
        (lambda: L.NonholonomicSystem(lambda t, q, p, a: 0.0, 2), "constraint_matrix must be a function mu(t, q, args) -> (m, n); got int 2"),
        (lambda: L.NonholonomicSystem(hamiltonian=3.0, constraint_matrix=lambda t, q, a: q), "hamiltonian must be a function"),
        (lambda: L.MechanicalSystem(lambda t, q, a: jnp.eye(3)), "MechanicalSystem needs potential, a function V(t, q, args)"),
        (lambda: L.MechanicalSystem(lambda t, q, a: jnp.eye(3), lambda t, q, a: 0.0), "needs constraint_matrix"),
        (lambda: L.MechanicalSystem(jnp.eye(3), lambda t, q, a: 0.0, lambda t, q, a: q), "mass_matrix must be a function M(t, q, args)"),
        (lambda: L.PartitionedDAE(lambda *a: 0, lambda *a: 0, "phi"), "phi must be a function phi(t, q, p, args)"),
        (lambda: L.NonholonomicSystem(lambda *a: 0, lambda *a: 0, lambda *a: 0), "name must be a string"),
    ],
)
def test_problem_construction_refused(build, expected):
    with pytest.raises(ProblemDefinitionError) as info:
        build()
    assert expected in str(info.value)
    assert isinstance(info.value, L.LobattoDAEInputError) and isinstance(info.value, TypeError)


def test_problems_stay_hashable_by_identity():
    a, b = particle_with(), particle_with()
    assert hash(a) == object.__hash__(a) and len({a, b}) == 2
    assert a != b and a == a and {a: 1}[a] == 1
    with pytest.raises(AttributeError):
        a.name = "other"  # frozen


def _counting_particle():
    """The nonholonomic particle as a PartitionedDAE whose f, g and φ count their traces."""
    traces = {"f": 0, "g": 0, "phi": 0}

    def f(t, q, p, a):
        traces["f"] += 1
        return p

    def g(t, q, p, lam, a):
        traces["g"] += 1
        return jnp.array([-q[1], 0.0, 1.0]) * lam[0]

    def phi(t, q, p, a):
        traces["phi"] += 1
        return jnp.array([-q[1] * p[0] + p[2]])

    return L.PartitionedDAE(f, g, phi), (f, g, phi), traces


def test_functions_are_traced_once_per_signature():
    """A compiled run evaluates f, g and φ in a dozen places (Newton's two loops, its matrix, the
    consistent λ, the doubling's vector fields, ...): each function is traced once per input
    signature (scalar point, vmapped stages), not once per place."""
    problem, given, traces = _counting_particle()
    assert [problem.f.__wrapped__, problem.g.__wrapped__, problem.phi.__wrapped__] == list(given)
    sol = L.solve(problem, L.LobattoIIIAIIIB(stages=3), (0.0, 1.0), jnp.zeros(3), jnp.array([1.0, 1.0, 0.0]),
                  rtol=1e-6, atol=1e-6)
    assert sol.success
    # the checks before the run trace each function plainly once (their messages need it), and
    # the run's programs reuse one trace per signature: twice each. Traced at every call site,
    # f and g were traced 12 times and φ 10.
    assert max(traces.values()) <= 3, traces


def test_rebuilt_problem_is_not_wrapped_twice():
    import dataclasses

    problem, (f, _, _), _ = _counting_particle()
    again = dataclasses.replace(problem, name="again")
    assert again.f is problem.f and again.f.__wrapped__ is f


def _f(t, q, p, a):
    return p


def _g(t, q, p, lam, a):
    return jnp.array([-q[1], 0.0, 1.0]) * lam[0]


def _phi(t, q, p, a):
    return jnp.array([-q[1] * p[0] + p[2]])


@pytest.mark.parametrize("problem", [L.PartitionedDAE(_f, _g, _phi), L.examples.get_example("knife-edge").problem],
                         ids=["PartitionedDAE", "NonholonomicSystem"])
def test_problems_pickle_and_copy(problem):
    """A problem pickles and copies with the functions as given (jitted callables do not pickle)
    and is rebuilt with them traced once again: the copy solves as the original does."""
    import copy
    import pickle

    import numpy as np

    q0, p0 = (jnp.zeros(3), jnp.array([1.0, 1.0, 0.0])) if isinstance(problem, L.PartitionedDAE) else (
        jnp.asarray(L.examples.get_example("knife-edge").q0), jnp.asarray(L.examples.get_example("knife-edge").p0))
    args = None if isinstance(problem, L.PartitionedDAE) else L.examples.get_example("knife-edge").args
    runs = []
    for p in (problem, pickle.loads(pickle.dumps(problem)), copy.deepcopy(problem), copy.copy(problem)):
        assert p.f.__wrapped__ is not None and p.name == problem.name
        runs.append(L.solve(p, L.LobattoIIIAIIIB(stages=3), (0.0, 0.5), q0, p0, args=args, n_steps=5).q[-1])
    for q in runs[1:]:
        np.testing.assert_array_equal(q, runs[0])


def test_fingerprint_sees_the_functions_as_given():
    """Checkpoints identify a problem by its functions as given (a resume compares them), so the
    jitted wrappers are transparent: a checkpoint written before the functions were wrapped
    still resumes."""
    import dataclasses

    from lobattodae._io import fingerprint_callable

    problem = L.PartitionedDAE(_f, _g, _phi)
    assert fingerprint_callable(problem.f) == fingerprint_callable(_f)
    unwrapped = object.__new__(L.PartitionedDAE)  # the same fields, never wrapped
    for field in dataclasses.fields(problem):
        value = getattr(problem, field.name)
        object.__setattr__(unwrapped, field.name, getattr(value, "__wrapped__", value))
    assert unwrapped.f is _f
    assert fingerprint_callable(problem) == fingerprint_callable(unwrapped)
