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
