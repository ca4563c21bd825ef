r"""Modelling front end: constrained Lagrangian systems written in SymPy, integrated by lobattodae.

>>> import sympy as sp
>>> from sympy.physics.mechanics import dynamicsymbols
>>> import lobattodae
>>> from lobattodae import mechanics
>>> t = sp.Symbol("t")
>>> x, y, th = dynamicsymbols("x y theta")
>>> m, I, a = sp.symbols("m I a")
>>> L = m * (x.diff(t)**2 + y.diff(t)**2) / 2 + I * th.diff(t)**2 / 2
>>> sleigh = mechanics.from_lagrangian(
...     L, [x, y, th], t, nonholonomic=[-sp.sin(th)*x.diff(t) + sp.cos(th)*y.diff(t) - a*th.diff(t)])
>>> args = sleigh.args(m=1.0, I=1.0, a=1.0)
>>> q0 = [0.0, 0.0, 0.0]
>>> qd0 = sleigh.complete_velocities(0.0, q0, {th: 1.0}, args)    # ẋ, ẏ from the constraint
>>> p0 = sleigh.momenta(0.0, q0, qd0, args)
>>> sol = lobattodae.solve(sleigh.problem, lobattodae.LobattoIIIAIIIB(stages=3), (0.0, 1.0),
...                        q0, p0, n_steps=20, args=args)

The Lagrangian must be quadratic in the velocities (``½ q̇ᵀM q̇ + aᵀq̇ − V``, ``M``
positive definite), the constraints affine in them (``μ q̇ + ν = 0``, possibly
time-dependent). Holonomic constraints ``ψ(t, q) = 0`` are kept at the velocity level as
rows of φ (index 2) and at the position level by projecting every step's end point onto
``ψ = 0`` and ``φ = 0`` (``LagrangianDAE.position_constraint``): both hold to round-off at
every step point, the orders of q and p are unchanged, the projected step is not symmetric
(:meth:`LagrangianModel.holonomic_residual` evaluates ψ). See ``docs/mechanics.md``.

Public names: :func:`from_lagrangian`, :func:`from_lagranges_method`,
:func:`from_kanes_method`, :func:`from_system`, :class:`LagrangianModel`,
:class:`LagrangianDAE`, :class:`SymbolicParts`; rigid bodies oriented by unit quaternions
(:func:`quaternion_body` and its numeric helpers, ``docs/rigid-bodies.md``); the Whipple
bicycle benchmark (:mod:`lobattodae.mechanics.bicycle`: model, linearisation, eigenvalues,
weave and capsize speeds, ``docs/bicycle.md``); and the verified systems in
:mod:`lobattodae.mechanics.systems`.
"""

try:
    import sympy as _sympy  # noqa: F401
except ImportError as _exc:  # pragma: no cover - depends on the installation
    raise ImportError(
        "lobattodae.mechanics needs SymPy: pip install 'lobattodae[mechanics]' (or sympy>=1.12)."
    ) from _exc


from . import _bicycle as bicycle
from . import _systems as systems
from ._kane import from_kanes_method, from_system
from ._rigid import (
    QuaternionBody,
    body_angular_velocity,
    quaternion_body,
    quaternion_from_axis_angle,
    quaternion_matrices,
    quaternion_multiply,
    quaternion_rates,
    rotation_matrix,
)
from ._builders import from_lagrangian, from_lagranges_method
from ._model import LagrangianDAE, LagrangianModel, SymbolicParts
from ._native import NativeIntegrator, NativeResult

__all__ = [
    "LagrangianDAE",
    "LagrangianModel",
    "NativeIntegrator",
    "NativeResult",
    "QuaternionBody",
    "SymbolicParts",
    "bicycle",
    "body_angular_velocity",
    "from_kanes_method",
    "from_lagrangian",
    "from_lagranges_method",
    "from_system",
    "quaternion_body",
    "quaternion_from_axis_angle",
    "quaternion_matrices",
    "quaternion_multiply",
    "quaternion_rates",
    "rotation_matrix",
    "systems",
]
