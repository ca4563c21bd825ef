r"""Dense output: the continuous extension of one Lobatto IIIA-IIIB step.

Lobatto IIIA is the collocation method of the nodes ``c``: the polynomial of degree s

    u(t_0 + θh) = q_0 + h Σ_j (∫_0^θ l_j) V_j                                  (q)

(``l_j`` the Lagrange basis of the nodes) interpolates ``q_0``, passes through every stage
``Q_i = u(t_0 + c_i h)`` (``a_ij = ∫_0^{c_i} l_j``) and ends at ``q_1 = u(t_0 + h)``
(``a_sj = b_j``). The same construction with the slopes ``W_j = g(t_j, Q_j, P_j, Λ_j)``

    v(t_0 + θh) = p_0 + h Σ_j (∫_0^θ l_j) W_j                                  (p)

passes through the IIIA momenta ``p̃_i`` of row (3) of the stage system, where
``φ(t_i, Q_i, p̃_i) = 0`` is imposed, and ends at ``p_1``; so the constraint holds exactly at
every node and the dense output leaves it only between nodes, by the interpolation error.
The multiplier is interpolated at the nodes,

    λ(t_0 + θh) = Σ_j l_j(θ) Λ_j                                              (λ)

(degree s - 1; ``Λ_1`` is the step's start multiplier). Between step points q and p converge
with order s (the slopes V_j use the IIIB stage momenta; p: s + 1 with a constant mass matrix
when the stage multipliers are accurate to O(h^s), i.e. with the consistent start, which error
control uses, or even s), λ with order s with the consistent start and otherwise at most its
global order (s - 1 for odd s); measured in ``docs/variable-steps.md``. At the step points the
values are the step's own (``θ = 1`` gives ``q_1, p_1, λ_1`` exactly in the solver, which stores
them rather than re-evaluating the polynomials).
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from . import _compile
from ._errors import LobattoDAEInputError
from ._projection import project_row
from ._tableau import LobattoPair, lagrange_basis

__all__ = [
    "LAYOUTS", "DenseOutput", "DenseStep", "dense_size", "evaluate", "empty_dense_step", "integrated_basis", "joined",
    "one_piece", "pack_dense", "span", "stacked", "unpack_dense",
]


class DenseStep(NamedTuple):
    """What dense output needs from one step (a pytree; the stage slopes and multipliers).

    A step is made of P pieces, each one step of the method with its own polynomials: P = 1
    for a plain step, P = 2 for an error-controlled step (two half steps, see
    :class:`~lobattodae._doubling.StepDoubling`). Every field has the piece axis first.
    """

    t0: jax.Array  # (P,)
    h: jax.Array  # (P,)
    q0: jax.Array  # (P, n)
    p0: jax.Array  # (P, n)
    V: jax.Array  # (P, s, n)
    W: jax.Array  # (P, s, n)
    Lam: jax.Array  # (P, s, m)


def one_piece(t0, h, q0, p0, V, W, Lam) -> DenseStep:
    """The dense output of one step of the method (P = 1)."""
    return DenseStep(*(jnp.asarray(x)[None] for x in (t0, h, q0, p0, V, W, Lam)))


def joined(*steps: DenseStep) -> DenseStep:
    """Consecutive steps as the pieces of one."""
    return DenseStep(*(jnp.concatenate(fields) for fields in zip(*steps)))


def span(step: DenseStep):
    """``(t_start, h_total)`` of a step made of pieces."""
    return step.t0[..., 0], jnp.sum(step.h, axis=-1)


def dense_size(pieces: int, s: int, n: int, m: int) -> int:
    """The length of a packed :class:`DenseStep` (``_loop.pack_dense``)."""
    return pieces * (2 + 2 * n + s * (2 * n + m))


def pack_dense(step: DenseStep):
    """One flat vector (a row of the dense-output buffer)."""
    return jnp.concatenate([jnp.atleast_1d(x).ravel() for x in step])


def unpack_dense(rows, pieces: int, s: int, n: int, m: int) -> DenseStep:
    """``(k, D)`` packed rows -> a :class:`DenseStep` of stacked arrays (NumPy or JAX)."""
    shapes = [(pieces,), (pieces,), (pieces, n), (pieces, n), (pieces, s, n), (pieces, s, n), (pieces, s, m)]
    out, i = [], 0
    for shape in shapes:
        size = int(np.prod(shape))
        out.append(rows[:, i : i + size].reshape((rows.shape[0],) + shape))
        i += size
    return DenseStep(*out)


def empty_dense_step(t0, q0, p0, lam0, s: int, pieces: int = 1) -> DenseStep:
    """A zero-length "step" at ``(t0, q0, p0, λ0)``: evaluates to those values at ``t0``."""
    n, m = q0.shape[-1], lam0.shape[-1]
    zeros = jnp.zeros((pieces, s, n), q0.dtype)
    return DenseStep(
        jnp.full((pieces,), t0, q0.dtype), jnp.zeros((pieces,), q0.dtype), jnp.broadcast_to(q0, (pieces, n)),
        jnp.broadcast_to(p0, (pieces, n)), zeros, zeros, jnp.broadcast_to(lam0, (pieces, s, m)),
    )


def integrated_basis(c: np.ndarray, theta):
    """``(∫_0^θ l_j)_j`` for the nodes c at (traced) θ, by s-point Gauss-Legendre on ``[0, θ]``
    (exact: the integrand has degree s - 1) with the product-form basis."""
    x, w = np.polynomial.legendre.leggauss(c.shape[0])
    tau = 0.5 * theta * (1.0 + jnp.asarray(x, theta.dtype))
    return 0.5 * theta * (jnp.asarray(w, theta.dtype) @ lagrange_basis(c, tau))


def evaluate(pair: LobattoPair, step: DenseStep, t):
    """``(q(t), p(t), λ(t))`` from the polynomials (q), (p), (λ) of ``step`` at a scalar t.

    A zero-length step (no step taken yet) evaluates to its start values. A step of several
    pieces evaluates the piece that contains t.
    """
    t = jnp.asarray(t, step.q0.dtype)
    later = (jnp.sign(step.h[1:]) * (t - step.t0[1:]) > 0).astype(jnp.int32)  # pieces that start before t
    j = jnp.sum(later)
    step = jax.tree_util.tree_map(lambda x: x[j], step)
    safe_h = jnp.where(step.h == 0, 1.0, step.h)
    theta = jnp.where(step.h == 0, 0.0, (t - step.t0) / safe_h)
    k = integrated_basis(pair.c, theta)
    q = step.q0 + step.h * (k @ step.V)
    p = step.p0 + step.h * (k @ step.W)
    lam = lagrange_basis(pair.c, theta[None])[0] @ step.Lam
    return q, p, lam


def _evaluate_many(pair: LobattoPair, steps: DenseStep, t):
    return jax.vmap(lambda st, tt: evaluate(pair, st, tt))(steps, t)


_evaluate_many_compiled = _compile.jit(_evaluate_many, static_argnums=0)


#: The layouts of :meth:`DenseOutput.__call__`: ours (a tuple of time-major arrays) and scipy's.
LAYOUTS = ("tuple", "scipy")


def stacked(q, p, lam) -> np.ndarray:
    """``[q, p, λ]`` side by side along the last axis: (k, 2n + m) rows, or (2n + m,) for one time."""
    return np.concatenate([np.asarray(q), np.asarray(p), np.asarray(lam)], axis=-1)


class DenseOutput:
    """``sol(t) -> (q, p, lam)`` between the step points of a :func:`~lobattodae.solve` run
    (``dense_output=True``), from the stored steps' polynomials (q), (p), (λ).

    ``t`` is a scalar (1-D results) or a 1-D array (time-major results); it must lie in the
    integrated interval. ``sol(t, layout="scipy")`` returns scipy's layout instead.

    Accuracy: between step points q, p and λ converge with order s (the step points
    themselves with 2s − 2), and ‖φ‖ is of the interpolation error there, not at round-off.
    At tight tolerances the values between steps are therefore orders of magnitude less
    accurate than the steps (measured on the [benchmarks page](../benchmarks/index.md)).
    Where values at given times must be as accurate as the run, ask for them as ``t_eval``
    rows (under error control the steps end on them). Where they must satisfy the
    constraints, ``sol(t, project=True)`` moves them onto ψ = 0, φ = 0 and the consistent λ
    (the order stays s).

    Built by :func:`~lobattodae.solve`, not by hand: it is ``sol.sol`` of a
    :class:`~lobattodae.Solution`.

    Attributes
    ----------
    pair : LobattoPair
        The coefficients of the method that made the steps.
    n_steps : int
        The number of stored steps.
    t0, t1 : float
        The ends of the integrated interval (``t1 < t0`` for a run backwards).
    problem : PartitionedDAE, NonholonomicSystem or MechanicalSystem or None
        The problem, which ``project=True`` needs.
    args : pytree
        Its ``args``.
    """

    def __init__(self, pair: LobattoPair, packed: np.ndarray, pieces: int, n: int, m: int, t0: float,
                 problem=None, args=None):
        self.pair = pair
        self.steps = unpack_dense(np.asarray(packed), pieces, pair.s, n, m)
        self.n_steps = len(self.steps.t0)
        self.t0 = float(t0)
        self.t1 = float(self.steps.t0[-1, 0] + np.sum(self.steps.h[-1])) if self.n_steps else self.t0
        self._starts = np.asarray(self.steps.t0[:, 0])
        self.problem, self.args = problem, args

    def __call__(self, t, layout: str = "tuple", project: bool = False):
        """The dense output at ``t``.

        Parameters
        ----------
        t : float or (k,) array
            Times in the integrated interval.
        layout : {"tuple", "scipy"}
            ``"tuple"``: ``(q, p, lam)``, shapes (n,), (n,), (m,) for a scalar ``t`` and
            (k, n), (k, n), (k, m) for k times. ``"scipy"``: scipy's ``OdeSolution`` layout,
            ``[q; p; λ]`` stacked, shape (2n + m,) or (2n + m, k).
        project : bool
            Move the values onto the constraints (ψ = 0 where the problem has position
            constraints, φ = 0, λ consistent) instead of returning the interpolant itself.

        Returns
        -------
        tuple of ndarray, or ndarray
            ``(q, p, lam)`` or, with ``layout="scipy"``, one stacked array (shapes above).

        Raises
        ------
        LobattoDAEInputError
            An unknown ``layout``, a ``project`` that is not a bool, ``project=True`` without
            the problem, ``t`` not a scalar or 1-D array, a time outside the integrated
            interval, or no stored step.
        """
        if layout not in LAYOUTS:
            raise LobattoDAEInputError(f"layout must be one of {LAYOUTS}; got {layout!r}.")
        if not isinstance(project, (bool, np.bool_)):
            raise LobattoDAEInputError(f"project must be True or False; got {project!r}.")
        t_arr = self._times(t)
        q, p, lam = _evaluate_many_compiled(self.pair, self._steps_at(t_arr), jnp.asarray(t_arr))
        if project:
            if self.problem is None:
                raise LobattoDAEInputError("project=True needs the problem: use the DenseOutput of a Solution.")
            q, p, lam = _project_many_compiled(self.problem, jnp.asarray(t_arr), q, p, lam, self.args)
        q, p, lam = (np.asarray(x) for x in (q, p, lam))
        if np.ndim(t) == 0:
            q, p, lam = q[0], p[0], lam[0]
        if layout == "scipy":
            return stacked(q, p, lam).T
        return q, p, lam

    def _times(self, t) -> np.ndarray:
        t_arr = np.atleast_1d(np.asarray(t, dtype=np.float64))
        if t_arr.ndim != 1:
            raise LobattoDAEInputError(f"t must be a scalar or a 1-D array; got shape {t_arr.shape}.")
        if not self.n_steps:
            raise LobattoDAEInputError("no step was taken; there is no dense output to evaluate.")
        lo, hi = min(self.t0, self.t1), max(self.t0, self.t1)
        if np.any(~np.isfinite(t_arr)) or np.any(t_arr < lo) or np.any(t_arr > hi):
            raise LobattoDAEInputError(f"t must lie in the integrated interval [{lo:g}, {hi:g}].")
        return t_arr

    def _steps_at(self, t_arr: np.ndarray) -> DenseStep:
        """The stored step that covers each time."""
        forward = self.t1 >= self.t0
        keys = self._starts if forward else -self._starts
        idx = np.clip(np.searchsorted(keys, t_arr if forward else -t_arr, side="right") - 1, 0, self.n_steps - 1)
        return DenseStep(*(jnp.asarray(np.asarray(x)[idx]) for x in self.steps))


_project_many_compiled = _compile.jit(jax.vmap(project_row, in_axes=(None, 0, 0, 0, 0, None)), static_argnums=0)
