r"""Rigid-body orientation by unit quaternions, for Lagrangians written in SymPy.

Euler or Tait–Bryan angles are singular somewhere (``turntable_ball``'s chart at
``β = ±π/2``). A unit quaternion ``Q = (q0, q1, q2, q3)`` (scalar first, Hamilton's
convention) has no singularity; it costs one extra coordinate and the holonomic constraint
``Q·Q − 1 = 0``, which lobattodae keeps to round-off by projecting every step's end point
(:mod:`lobattodae._projection`).

Kinematics (all matrices homogeneous in ``Q``; on ``|Q| = 1`` they are the usual ones)
------------------------------------------------------------------------------------

.. math::

    R(Q) = (q_0^2 - |v|^2)\,1 + 2 v v^T + 2 q_0 [v]_\times, \qquad v = (q_1, q_2, q_3),

maps body to space (``x_space = R x_body``), and with

.. math::

    E(Q) = \begin{pmatrix} -q_1 & q_0 & q_3 & -q_2\\ -q_2 & -q_3 & q_0 & q_1\\
    -q_3 & q_2 & -q_1 & q_0 \end{pmatrix},\qquad
    G(Q) = \begin{pmatrix} -q_1 & q_0 & -q_3 & q_2\\ -q_2 & q_3 & q_0 & -q_1\\
    -q_3 & -q_2 & q_1 & q_0 \end{pmatrix}

the angular velocity is ``ω_body = 2 E(Q) Q̇`` and ``ω_space = 2 G(Q) Q̇ = R ω_body``
(``[ω_body]_× = Rᵀ Ṙ``, ``[ω_space]_× = Ṙ Rᵀ`` on ``|Q| = 1``). ``E Q = G Q = 0`` and
``E Eᵀ = G Gᵀ = |Q|² 1``: the 4×4 matrix ``U = [E; Qᵀ]`` is orthogonal for a unit ``Q``.

The regularised kinetic energy
------------------------------
``T_rot = ½ ω_bodyᵀ I ω_body = 2 Q̇ᵀ Eᵀ I E Q̇`` is degenerate: ``M = 4 Eᵀ I E`` has the null
vector ``Q`` (``E Q = 0``), so a model built from it is (rightly) refused when it is first
used (:meth:`~lobattodae.mechanics.LagrangianModel.check`, ``momenta``, ``solve``). This
module uses instead

.. math::

    T = ½\,ω^T I ω + ½\,J\,ω_0^2, \qquad ω_0 = 2\,Q·\dot Q = \tfrac{d}{dt}|Q|^2,

i.e. ``½ J₀ (Q·Q̇)²`` added with ``J₀ = 4J``. Why it changes nothing:

* on the constraint manifold ``|Q|² = 1`` every admissible velocity has ``Q·Q̇ = 0``, so the
  added term vanishes on the tangent bundle of the manifold. The constrained motion (with
  or without further nonholonomic constraints) depends on ``L`` only through its restriction
  there (Hamilton's / Lagrange–d'Alembert's principle with variations tangent to the
  manifold), so it is unchanged;
* explicitly, the term adds ``d/dt(J₀ (Q·Q̇) Q) − J₀ (Q·Q̇) Q̇ = J₀ (d/dt (Q·Q̇)) Q`` to the
  left side of the Lagrange equations: zero along motions with ``Q·Q̇ ≡ 0`` (which the
  velocity form ``2 Q·Q̇ = 0`` of the constraint enforces), and in any case parallel to the
  constraint gradient ``ψ_Q = 2Q``, so it would only shift the norm constraint's multiplier;
* the energy ``½ q̇ᵀM q̇ + V`` equals the physical one wherever ``Q·Q̇ = 0`` (at every step
  point of a lobattodae solution, where φ holds to round-off).

Conditioning: ``M = 4 (Eᵀ I E + J Q Qᵀ) = 4 Uᵀ diag(I, J) U`` with ``U`` orthogonal for a
unit ``Q``, so the eigenvalues of ``M`` are ``4 I_1, 4 I_2, 4 I_3`` (principal moments) and
``4 J``. The default ``J = tr(I)/3`` (the mean principal moment) lies between them: the
condition number of ``M`` is that of ``I``, whatever the orientation (any ``J`` in
``[I_min, I_max]`` would do; a tiny or huge ``J`` would spoil it, and ``J ≤ 0`` makes ``M``
singular or indefinite).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import sympy as sp
from sympy.physics.mechanics import dynamicsymbols

from .._errors import LobattoDAEInputError

__all__ = [
    "QuaternionBody",
    "quaternion_body",
    "quaternion_matrices",
    "rotation_matrix",
    "quaternion_rates",
    "body_angular_velocity",
    "quaternion_from_axis_angle",
    "quaternion_multiply",
]


def quaternion_matrices(Q):
    r"""``(R, E, G)`` for a quaternion ``Q = (q0, q1, q2, q3)`` (SymPy or NumPy entries).

    ``R`` (3×3) maps body to space; ``ω_body = 2 E Q̇``, ``ω_space = 2 G Q̇`` (see the module
    docstring). All three are homogeneous in ``Q`` (``R`` quadratic, ``E``, ``G`` linear); for
    ``|Q| = 1`` ``R`` is a rotation.

    Parameters
    ----------
    Q : sequence of 4 entries
        ``(q0, q1, q2, q3)``, scalar part first: SymPy expressions (e.g. the coordinates of
        :func:`quaternion_body`) or numbers (a single quaternion).

    Returns
    -------
    R : sympy.Matrix or numpy.ndarray, shape (3, 3)
        The rotation body → space (for a unit ``Q``).
    E, G : sympy.Matrix or numpy.ndarray, shape (3, 4)
        ``ω_body = 2 E Q̇`` and ``ω_space = 2 G Q̇``.

        All three are ``sympy.Matrix`` when an entry of ``Q`` is a SymPy expression, NumPy
        arrays otherwise.
    """
    q0, q1, q2, q3 = Q
    R = [
        [q0 * q0 + q1 * q1 - q2 * q2 - q3 * q3, 2 * (q1 * q2 - q0 * q3), 2 * (q1 * q3 + q0 * q2)],
        [2 * (q1 * q2 + q0 * q3), q0 * q0 - q1 * q1 + q2 * q2 - q3 * q3, 2 * (q2 * q3 - q0 * q1)],
        [2 * (q1 * q3 - q0 * q2), 2 * (q2 * q3 + q0 * q1), q0 * q0 - q1 * q1 - q2 * q2 + q3 * q3],
    ]
    E = [[-q1, q0, q3, -q2], [-q2, -q3, q0, q1], [-q3, q2, -q1, q0]]
    G = [[-q1, q0, -q3, q2], [-q2, q3, q0, -q1], [-q3, -q2, q1, q0]]
    if any(isinstance(x, sp.Basic) for x in (q0, q1, q2, q3)):
        return sp.Matrix(R), sp.Matrix(E), sp.Matrix(G)
    return np.array(R, dtype=float), np.array(E, dtype=float), np.array(G, dtype=float)


class QuaternionBody(NamedTuple):
    r"""What a Lagrangian of a rigid body needs, in SymPy (from :func:`quaternion_body`).

    Attributes
    ----------
    coordinates : list
        The four ``dynamicsymbols`` ``[Q0, Q1, Q2, Q3]`` (scalar first): put them in the
        model's coordinates.
    rates : sympy.Matrix
        ``Q̇`` (4×1).
    quaternion : sympy.Matrix
        ``Q`` (4×1).
    rotation : sympy.Matrix
        ``R(Q)`` (3×3), body → space.
    omega_body, omega_space : sympy.Matrix
        ``ω = 2 E(Q) Q̇`` in the body frame and ``2 G(Q) Q̇`` in space (3×1).
    vertical : sympy.Matrix
        ``γ = Rᵀ e_z``: the space frame's upward unit vector in body coordinates (3×1); the
        third row of ``R``.
    inertia : sympy.Matrix
        The inertia tensor ``I`` (3×3, body frame) used in ``kinetic_energy``.
    regularization : sympy.Expr
        ``J`` (default ``tr(I)/3``).
    kinetic_energy : sympy.Expr
        ``½ ωᵀ I ω + ½ J (2 Q·Q̇)²``: the rotational energy made positive definite along ``Q``
        (the added term and its contributions to the equations vanish on ``Q·Q̇ = 0``; see the
        module docstring).
    rotational_energy : sympy.Expr
        ``½ ωᵀ I ω`` alone (singular in ``Q̇``: not for ``from_lagrangian``).
    norm_constraint : sympy.Expr
        ``Q·Q − 1``: pass it in ``holonomic=[...]``.
    """

    coordinates: list
    rates: sp.Matrix
    quaternion: sp.Matrix
    rotation: sp.Matrix
    omega_body: sp.Matrix
    omega_space: sp.Matrix
    vertical: sp.Matrix
    inertia: sp.Matrix
    regularization: sp.Expr
    kinetic_energy: sp.Expr
    rotational_energy: sp.Expr
    norm_constraint: sp.Expr

    def to_space(self, vector_body) -> sp.Matrix:
        """``R(Q) x``: a body-frame vector in space coordinates.

        Parameters
        ----------
        vector_body : sequence of 3 entries or sympy.Matrix
            The vector's components in the body frame (SymPy expressions or numbers).

        Returns
        -------
        sympy.Matrix
            Its components in the space frame (3×1).
        """
        return self.rotation * sp.Matrix(vector_body)

    def to_body(self, vector_space) -> sp.Matrix:
        """``R(Q)ᵀ x``: a space-frame vector in body coordinates (the inverse of
        :meth:`to_space` for a unit ``Q``).

        Parameters
        ----------
        vector_space : sequence of 3 entries or sympy.Matrix
            The vector's components in the space frame.

        Returns
        -------
        sympy.Matrix
            Its components in the body frame (3×1).
        """
        return self.rotation.T * sp.Matrix(vector_space)

    def torque_forces(self, torque, frame: str = "space") -> list:
        r"""The generalized forces on ``Q̇`` of a torque ``τ``.

        ``F_Q = (∂ω/∂Q̇)ᵀ τ = 2 Gᵀ τ`` (``frame="space"``) or ``2 Eᵀ τ`` (``"body"``), so
        that the power is ``F_Q·Q̇ = ω·τ``.

        Parameters
        ----------
        torque : sequence of 3 entries or sympy.Matrix
            ``τ``, SymPy expressions that may depend on ``t``, ``Q`` and ``Q̇`` (a feedback or
            damping torque) and on parameter symbols.
        frame : {"space", "body"}, optional
            The frame of ``torque``'s components (default ``"space"``).

        Returns
        -------
        dict
            ``{Q_i: F_i}``, the coordinates of the body to their generalized forces: pass it
            (merged with any other forces) as ``forces=`` to :func:`from_lagrangian`.

        Raises
        ------
        LobattoDAEInputError
            If ``frame`` is neither ``"space"`` nor ``"body"``.
        """
        tau = sp.Matrix(torque)
        if frame == "space":
            omega = self.omega_space
        elif frame == "body":
            omega = self.omega_body
        else:
            raise LobattoDAEInputError(f"torque_forces: frame must be 'space' or 'body'; got {frame!r}.")
        jac = omega.jacobian(self.rates)  # 3×4 = 2 G or 2 E
        F = jac.T * tau
        return {c: F[i] for i, c in enumerate(self.coordinates)}


def _inertia_matrix(inertia, name):
    if inertia is None:
        return sp.diag(*sp.symbols(f"{name}_I1 {name}_I2 {name}_I3", positive=True))
    if isinstance(inertia, sp.MatrixBase):
        I = sp.Matrix(inertia)
    else:
        entries = list(inertia)
        if len(entries) == 3 and not any(isinstance(e, (list, tuple)) for e in entries):
            I = sp.diag(*[sp.sympify(e) for e in entries])
        else:
            I = sp.Matrix(entries)
    if I.shape != (3, 3):
        raise LobattoDAEInputError(
            f"quaternion_body({name!r}): inertia must be 3 principal moments or a 3×3 matrix; got shape {I.shape}."
        )
    if (I - I.T).applyfunc(sp.simplify) != sp.zeros(3, 3):
        raise LobattoDAEInputError(
            f"quaternion_body({name!r}): the inertia tensor must be symmetric; got {sp.sstr(I)}. Use the same "
            "product of inertia above and below the diagonal."
        )
    return I


def quaternion_body(name: str = "Q", inertia=None, t=None, *, regularization=None) -> QuaternionBody:
    r"""A rigid body's orientation as a unit quaternion, for :func:`from_lagrangian`.

    Parameters
    ----------
    name : str
        Prefix of the coordinates: ``name0 … name3`` (``Q0`` is the scalar part).
    inertia : 3 moments, 3×3 matrix or None
        Inertia tensor in the body frame (about the point whose rotation energy you want: the
        centre of mass, or a fixed point). ``None``: symbols ``{name}_I1, {name}_I2,
        {name}_I3`` (principal axes).
    t : sympy.Symbol, optional
        The time symbol (default ``dynamicsymbols._t``); use the same one in
        :func:`from_lagrangian`.
    regularization : sympy.Expr, optional
        ``J`` in ``½ J (2 Q·Q̇)²`` (default ``tr(I)/3``: the mass matrix then has the
        eigenvalues ``4 I_k`` and ``4 J``, so its condition number is that of ``I``).

    Returns
    -------
    QuaternionBody
        The coordinates, the kinematics (``R``, ``ω``, ``γ``), the regularised kinetic energy
        and the norm constraint, as SymPy objects.

    Raises
    ------
    LobattoDAEInputError
        If ``inertia`` is neither 3 moments nor a 3×3 matrix, is not symmetric, or
        ``regularization`` is a number that is not positive.

    Notes
    -----
    ``ω_body = 2 E(Q) Q̇``, ``ω_space = 2 G(Q) Q̇``, ``R(Q)`` body → space (formulas in the
    module docstring). The rotational kinetic energy ``½ ωᵀIω = 2 Q̇ᵀEᵀIE Q̇`` is singular
    along ``Q``; ``kinetic_energy`` adds ``½ J (2 Q·Q̇)²``, which vanishes, with its
    contributions ``4J (d/dt(Q·Q̇)) Q`` to the Lagrange equations, on motions with
    ``Q·Q̇ ≡ 0``: those that the holonomic constraint ``norm_constraint = Q·Q − 1 = 0`` (which
    lobattodae keeps to round-off) allows. The constrained dynamics is therefore unchanged,
    and ``M = 4 Uᵀ diag(I, J) U`` (``U = [E; Qᵀ]``, orthogonal) is positive definite.

    Examples
    --------
    A free body spinning about a fixed point (the Euler top):

    >>> import sympy as sp
    >>> from sympy.physics.mechanics import dynamicsymbols
    >>> from lobattodae.mechanics import from_lagrangian
    >>> from lobattodae.mechanics import quaternion_body
    >>> body = quaternion_body("Q", inertia=sp.symbols("A B C"))
    >>> top = from_lagrangian(body.kinetic_energy, body.coordinates, dynamicsymbols._t,
    ...                       holonomic=[body.norm_constraint], name="Euler top")
    >>> top.n, top.m
    (4, 1)
    """
    if t is None:
        t = dynamicsymbols._t
    coords = list(dynamicsymbols(f"{name}0:4"))
    Q = sp.Matrix(coords)
    Qd = Q.diff(t)
    R, E, G = quaternion_matrices(coords)
    I = _inertia_matrix(inertia, name)
    J = sp.trace(I) / 3 if regularization is None else sp.sympify(regularization)
    if J.is_number and not J > 0:
        raise LobattoDAEInputError(
            f"quaternion_body({name!r}): regularization must be positive (J > 0 makes the mass matrix positive "
            f"definite; J between the smallest and largest principal moment keeps it well conditioned); got {J}. "
            "Leave it out for tr(I)/3."
        )
    w_b = 2 * E * Qd
    w_s = 2 * G * Qd
    w0 = 2 * (Q.T * Qd)[0, 0]
    rot = sp.Rational(1, 2) * (w_b.T * I * w_b)[0, 0]
    T = rot + sp.Rational(1, 2) * J * w0**2
    return QuaternionBody(
        coordinates=coords,
        rates=Qd,
        quaternion=Q,
        rotation=R,
        omega_body=w_b,
        omega_space=w_s,
        vertical=R[2, :].T,
        inertia=I,
        regularization=J,
        kinetic_energy=T,
        rotational_energy=rot,
        norm_constraint=(Q.T * Q)[0, 0] - 1,
    )


# ----------------------------------------------------------------------------- numerics
def rotation_matrix(Q) -> np.ndarray:
    """``R(Q)`` (body → space) of one quaternion or of a stack of them.

    Parameters
    ----------
    Q : array_like, shape (4,) or (N, 4)
        Quaternions, scalar part first (unit quaternions for a rotation; ``R`` is quadratic
        in ``Q``).

    Returns
    -------
    numpy.ndarray, shape (3, 3) or (N, 3, 3)
        ``x_space = R x_body``.
    """
    Q = np.asarray(Q, dtype=float)
    q0, q1, q2, q3 = np.moveaxis(Q, -1, 0)
    R = np.stack([
        np.stack([q0 * q0 + q1 * q1 - q2 * q2 - q3 * q3, 2 * (q1 * q2 - q0 * q3), 2 * (q1 * q3 + q0 * q2)], -1),
        np.stack([2 * (q1 * q2 + q0 * q3), q0 * q0 - q1 * q1 + q2 * q2 - q3 * q3, 2 * (q2 * q3 - q0 * q1)], -1),
        np.stack([2 * (q1 * q3 - q0 * q2), 2 * (q2 * q3 + q0 * q1), q0 * q0 - q1 * q1 - q2 * q2 + q3 * q3], -1),
    ], -2)
    return R


def _E(Q):
    q0, q1, q2, q3 = np.moveaxis(np.asarray(Q, dtype=float), -1, 0)
    return np.stack([
        np.stack([-q1, q0, q3, -q2], -1),
        np.stack([-q2, -q3, q0, q1], -1),
        np.stack([-q3, q2, -q1, q0], -1),
    ], -2)


def quaternion_rates(Q, omega_body) -> np.ndarray:
    """``Q̇ = ½ E(Q)ᵀ ω_body`` (= ``½ Q ⊗ (0, ω)``): the quaternion rates of a body angular
    velocity.

    Parameters
    ----------
    Q : array_like, shape (4,) or (N, 4)
        Unit quaternions, scalar part first.
    omega_body : array_like, shape (3,) or (N, 3)
        The angular velocity in the body frame.

    Returns
    -------
    numpy.ndarray, shape (4,) or (N, 4)
        ``Q̇``, with ``Q·Q̇ = 0`` (the velocity form of ``|Q| = 1``).
    """
    return 0.5 * np.einsum("...ki,...k->...i", _E(Q), np.asarray(omega_body, dtype=float))


def body_angular_velocity(Q, Qdot) -> np.ndarray:
    """``ω_body = 2 E(Q) Q̇``: the body angular velocity of quaternion rates (the inverse of
    :func:`quaternion_rates` on ``Q·Q̇ = 0``).

    Parameters
    ----------
    Q : array_like, shape (4,) or (N, 4)
        Quaternions, scalar part first.
    Qdot : array_like, shape (4,) or (N, 4)
        Their rates (e.g. the last four of ``model.velocities(t, q, p, args)``).

    Returns
    -------
    numpy.ndarray, shape (3,) or (N, 3)
        ``ω`` in the body frame; ``R(Q) ω`` is the space frame's.
    """
    return 2.0 * np.einsum("...ki,...i->...k", _E(Q), np.asarray(Qdot, dtype=float))


def quaternion_multiply(a, b) -> np.ndarray:
    """The Hamilton product ``a ⊗ b`` (scalar first); ``R(a ⊗ b) = R(a) R(b)``.

    Parameters
    ----------
    a, b : array_like, shape (4,) or (N, 4)
        Quaternions, scalar part first (stacks are multiplied row by row).

    Returns
    -------
    numpy.ndarray, shape (4,) or (N, 4)
        ``a ⊗ b``: the rotation ``b`` followed by ``a`` (for unit quaternions).
    """
    a0, a1, a2, a3 = np.moveaxis(np.asarray(a, dtype=float), -1, 0)
    b0, b1, b2, b3 = np.moveaxis(np.asarray(b, dtype=float), -1, 0)
    return np.stack([
        a0 * b0 - a1 * b1 - a2 * b2 - a3 * b3,
        a0 * b1 + a1 * b0 + a2 * b3 - a3 * b2,
        a0 * b2 - a1 * b3 + a2 * b0 + a3 * b1,
        a0 * b3 + a1 * b2 - a2 * b1 + a3 * b0,
    ], -1)


def quaternion_from_axis_angle(axis, angle) -> np.ndarray:
    """The unit quaternion of the rotation by ``angle`` about ``axis``.

    Parameters
    ----------
    axis : array_like, shape (3,)
        The rotation axis (normalised here; must not be zero).
    angle : float
        The angle (rad), positive counter-clockwise about ``axis``.

    Returns
    -------
    numpy.ndarray, shape (4,)
        ``(cos(angle/2), sin(angle/2) axis/|axis|)``.
    """
    axis = np.asarray(axis, dtype=float)
    axis = axis / np.linalg.norm(axis)
    return np.concatenate([[np.cos(angle / 2)], np.sin(angle / 2) * axis])
