r"""A native step for models of :mod:`lobattodae.mechanics`: generated C, compiled at first use.

:meth:`LagrangianModel.native <lobattodae.mechanics.LagrangianModel.native>` writes the model's
functions and the library's scheme as one C program, compiles it with the system's C compiler
the first time it is asked for (kept in the user cache directory, see below) and runs it two
ways. Constant steps run whole in C, called through :mod:`ctypes` (:meth:`NativeIntegrator.integrate`,
:meth:`NativeIntegrator.solve` with ``n_steps``); error-controlled steps run in
:func:`lobattodae.solve`'s loop with each attempt of step doubling one XLA FFI call into the same
program (:mod:`._native_loop`; ``solve`` with ``rtol``). On a CPU a step of a small system
costs XLA:CPU's overhead per kernel (hundreds of tiny kernels per step, about 57 ns each; issue
#26), which native code does not pay: measured 2.0–6.7 × less time per step than
``lobattodae.integrate`` (sleigh, falling disk, s = 3…6; the Whipple bicycle 3.7 ×; 1.24 × the
hand-written C limit) with results equal to round-off, and a first result in under a second for
the falling disk, ten seconds for the bicycle (``benchmarks/native_step.py``,
``benchmarks/RESULTS.md``, 2026-11-29 11:15; with the LU by columns 2.5–6.0 ×, the bicycle
4.1 ×, 14:45); error-controlled runs 2.1–3.8 × less time than ``lobattodae.solve`` with the same
steps (2026-11-29, 14:45). The JAX path stays the one for
``jax.grad``, ``vmap``, ensembles and GPUs: this is a forward integrator on the CPU. A
constant-step run keeps no state outside its call and releases Python's global lock, so runs in
threads use several CPUs.

**The scheme** is the library's (:mod:`lobattodae._stage_equations`; the rows are written out
above the C that implements them): unknowns ``(Q_2..Q_s, P_1..P_s, Z_2..Z_s)``, ``Z = hΛ``; the
step end summed with compensation; the start multiplier by the policy ``lam_start`` of
:class:`~lobattodae.LobattoIIIAIIIB` (``"auto"``: the paper's scheme re-synchronised when λ's
drift leaves its band, with the same monitor and constants; ``"previous"``; ``"consistent"``);
Newton's start from the previous step's stage polynomials with their correction; simplified
Newton with the matrix assembled from per-stage blocks as the JAX path's
(:func:`~lobattodae._stage_equations.stage_jacobian_differences`): those in q by forward
differences, those in p and λ exact, from the model's structure (∂f/∂p = M⁻¹, ∂g/∂p =
(∂g0/∂v) M⁻¹, ∂g/∂λ = μᵀ, ∂φ/∂p = μ M⁻¹; where the JAX path differences them too), its LU
factors kept across iterations and steps, and the stopping and refresh rules of
:mod:`lobattodae._newton` (their constants are read from there). The iterates differ from the
JAX path's only in rounding, in where Newton stops below its tolerance and, rarely, in a refresh
that the slightly different matrix makes earlier or later.

**The model** is evaluated as ``lobattodae.mechanics`` derives it (``docs/mechanics.md``):
``v = M(t, q)⁻¹ (p − a)`` solved numerically (elimination without pivoting, M being symmetric
positive definite), ``g = ∂L/∂q |_(q̇ = v) + F + μᵀλ``, ``φ = μ v + ν``, each function's outputs
with their common subexpressions shared (:func:`sympy.cse`); the hidden constraint's multiplier
``λ(t, q, p)`` solves ``(μ M⁻¹ μᵀ) λ = −(μ M⁻¹ b + μ̇ v + ν̇)``, ``b = ∂L/∂q + F − Ṁ v − ȧ``
(dots along ``q' = v``, differentiated symbolically). With holonomic constraints ψ(t, q) = 0 each
step's end is projected onto ψ = 0 and φ = 0 as :mod:`lobattodae._projection` does (positions along
``M⁻¹ ψ_qᵀ`` by its Newton steps, then the momenta by one impulse), with ψ and ψ_q generated.

**Compiler and cache.** ``$CC`` when set, else the first of ``cc``, ``gcc``, ``clang`` on the
``PATH``, with ``-O2`` (no ``-march=native``: a shared cache directory may serve other
processors; with gcc on x86-64 Linux the LU factorisation has a second, AVX-512 copy that the
processor picks at load time, giving the same bits). The shared library is kept in ``<cache>/native`` (``<cache>`` as for the
compilation cache: ``$LOBATTODAE_CACHE_DIR``, else ``~/.cache/lobattodae``), named by a hash of
the model (its generated JAX source), s, this generator's code and the compiler command, so a new
process loads it without generating or compiling the C again; with ``LOBATTODAE_NO_CACHE=1`` each
process compiles into a directory of its own, removed at exit.
"""

from __future__ import annotations

import atexit
import ctypes
import hashlib
import math
import os
import re
import shutil
import subprocess
import tempfile
import time
import warnings
from pathlib import Path
from typing import NamedTuple

import jax
import jaxlib
import numpy as np
import sympy as sp
from sympy.printing.c import C99CodePrinter

from .. import _newton, _projection, _stepper
from .._cache import cache_switched_off, default_cache_dir
from .._errors import InconsistentInitialValuesError, LobattoDAEInputError, NewtonFailure, ShapeError
from .._options import check_count
from .._results import Result
from .._solution import Solution, drift_note
from .._tableau import lobatto_pair
from . import _codegen, _native_loop
from ._codegen import common_subexpressions, plain_symbols
from ._native_loop import ATTEMPT_C, NativeDoubling, NativeStep, tableau_array

__all__ = ["NativeIntegrator", "NativeResult", "c_compiler", "model_source"]

#: The compiler flags (see the module docstring).
CFLAGS = ("-O2", "-fPIC", "-shared")


class NativeResult(NamedTuple):
    """What :meth:`NativeIntegrator.integrate` returns (NumPy arrays; unpacks as ``q, p, lam, status, ...``).

    Attributes
    ----------
    q, p : ndarray, shape (rows, n)
        Time-major, one row per kept step point (``n_steps + 1`` rows by default); row 0 is the
        initial value. After a failed step the last point reached is the last finite row and the
        rows after it are NaN.
    lam : ndarray, shape (rows, m)
        Row 0 is the start multiplier ``lam0`` (the hidden constraint's when not given).
    status : Result
        ``Result.SUCCESSFUL``, else the failed step's code (``MAX_ITERATIONS``, ``DIVERGED``,
        ``NONFINITE``).
    n_newton, n_jacobians : int
        Newton iterations and Newton matrices (each one factorisation) of the run.
    lam_resets : int
        Steps that ``lam_start="auto"`` re-synchronised with the hidden constraint.
    t : ndarray, shape (rows,)
        The times of the rows, ``t0 + j h`` (NaN where the rows are).
    """

    q: np.ndarray
    p: np.ndarray
    lam: np.ndarray
    status: Result
    n_newton: int
    n_jacobians: int
    lam_resets: int
    t: np.ndarray


# ----------------------------------------------------------------------------- the model
class _Printer(C99CodePrinter):
    """C99 with exact float literals and small integer powers as products."""

    def _print_Float(self, expr):
        return repr(float(expr))

    def _print_Rational(self, expr):
        return f"({int(expr.p)}.0/{int(expr.q)}.0)"

    def _print_Integer(self, expr):
        return f"{int(expr)}.0"

    def _print_Pow(self, expr, rational=False):
        base, exp = expr.as_base_exp()
        b = self.parenthesize(base, 60)
        if exp.is_Integer and 1 <= abs(int(exp)) <= 4:
            prod = "*".join([b] * abs(int(exp)))
            return f"({prod})" if exp > 0 else f"(1.0/({prod}))"
        if exp == sp.S.Half:
            return f"sqrt({self._print(base)})"
        if exp == -sp.S.Half:
            return f"(1.0/sqrt({self._print(base)}))"
        return f"pow({self._print(base)}, {self._print(sp.Float(float(exp)) if exp.is_Rational else exp)})"


_PRINTER = _Printer()


def _c(expr) -> str:
    return _PRINTER.doprint(sp.sympify(expr))


def _function(name, signature, pre, outputs, symbols, optional=()) -> str:
    """A C function ``name(signature)``: read the scalars, evaluate ``pre`` (M row-major, then
    p − a) and solve for v (``pre`` None: no v), then the ``outputs`` (``(array, exprs)`` pairs),
    sharing subexpressions; the arrays named in ``optional`` are written only where the caller
    passes one (not NULL)."""
    n, t, q, p, lam, params, v = symbols
    pre = [] if pre is None else list(pre)
    shared = common_subexpressions(pre, [e for _, exprs in outputs for e in exprs], v if pre else (),
                                   lambda sym, expr: f"  const double {sym.name} = {_c(expr)};")
    pre_red, out_red, early, after = shared.pre, shared.outputs, shared.early, shared.late
    used = set().union(*(e.free_symbols for _, e in shared.replacements), *(e.free_symbols for e in pre_red + out_red))
    lines = [f"static void {name}({signature}) {{", "  (void)t;"]
    for array, entries in (("q", q), ("p", p), ("lam", lam), ("k", params)):  # the inputs it reads
        lines += [f"  const double {x.name} = {array}[{i}];" for i, x in enumerate(entries) if x in used]
    lines += early
    if pre:
        lines.append(f"  double mm[{n * n}] = {{{', '.join(_c(e) for e in pre_red[: n * n])}}};")
        lines.append(f"  double vv[{n}] = {{{', '.join(_c(e) for e in pre_red[n * n:])}}};")
        lines.append("  mass_solve_columns(mm, vv, 1);")
        lines += [f"  const double {x.name} = vv[{i}];" for i, x in enumerate(v) if x in used]
    lines += after
    pos = 0
    for array, exprs in outputs:
        indent = "  "
        if array in optional:
            lines.append(f"  if ({array}) {{")
            indent = "    "
        for i in range(len(exprs)):
            lines.append(f"{indent}{array}[{i}] = {_c(out_red[pos])};")
            pos += 1
        if array in optional:
            lines.append("  }")
    lines.append("}")
    return "\n".join(lines)


#: The most multiply-adds per column for which the mass matrix's solve is written out for its
#: structure (:func:`mass_solve_source`); a larger one calls the elimination with loops.
_MASS_SOLVE_UNROLL = 600


def mass_solve_source(structure) -> str:
    """C of ``mass_solve_columns(mm, b, m)``: M X = B for the model's mass matrix (``NQ x NQ``
    row-major, overwritten) and the ``m`` columns of B (row-major, overwritten by X), the
    elimination of ``spd_solve_columns`` written out for M's structure (``structure[i][j]``: the
    entry is not identically zero; fill-in tracked). Skipping the entries that are zero whatever
    the state changes nothing but the sign of a zero; a matrix with more than
    :data:`_MASS_SOLVE_UNROLL` multiply-adds per column keeps the loops."""
    n = len(structure)
    nz = [[bool(structure[i][j]) or i == j for j in range(n)] for i in range(n)]
    body, ops = [], 0
    for k in range(n):
        rows = [i for i in range(k + 1, n) if nz[i][k]]
        if rows:
            body.append(f"  const double inv{k} = 1.0 / mm[{k * n + k}];")
        for i in rows:
            cols = [j for j in range(k + 1, n) if nz[k][j]]
            ops += len(cols) + 1
            updates = " ".join(f"mm[{i * n + j}] -= f*mm[{k * n + j}];" for j in cols)
            body.append(f"  {{ const double f = mm[{i * n + k}]*inv{k}; if (f != 0.0) {{ {updates}"
                        f" for (int c = 0; c < m; c++) b[{i}*m + c] -= f*b[{k}*m + c]; }} }}")
            for j in cols:
                nz[i][j] = True
    for i in reversed(range(n)):
        terms = "".join(f" x -= mm[{i * n + j}]*b[{j}*m + c];" for j in range(i + 1, n) if nz[i][j])
        ops += sum(nz[i][i + 1:])
        body.append(f"  for (int c = 0; c < m; c++) {{ double x = b[{i}*m + c];{terms} b[{i}*m + c] = x / mm[{i * n + i}]; }}")
    head = "static inline void mass_solve_columns(double *mm, double *b, int m) {"
    if ops > _MASS_SOLVE_UNROLL:
        return f"{head} spd_solve_columns(NQ, mm, b, m); }}\n"
    return "\n".join([head, *body, "}", ""])


def model_source(model) -> str:
    """The C of a model's functions: ``model_fg(t, q, p, lam, k, v, w, gv)`` (``v = f``, ``w = g``,
    ``gv = ∂g0/∂v`` where not NULL),
    ``model_phi(t, q, p, k, out)``, ``model_lambda(t, q, p, k, lam)`` (the hidden constraint's
    multiplier) and, with holonomic constraints, ``project_end(t, q, p, k)``; ``k`` holds
    ``model.parameters`` in order."""
    n, m = model.n, model.m
    parts = model.symbolic
    t, q, v, p, lam, params, rename = plain_symbols(model._ctx, m, model.parameters, model._param_symbols)

    def r(e):  # the user's symbols -> the internal ones -> the plain ones of the C
        return sp.sympify(e).xreplace(model._ctx.to_internal).xreplace(rename)

    M, a, V, mu, nu, F, psi = (r(x) for x in (parts.mass_matrix, parts.gyroscopic, parts.potential,
                                               parts.constraint_matrix, parts.constraint_offset, parts.forces,
                                               parts.holonomic))
    zero = sp.S.Zero
    # the derivatives of M (symmetric: each entry once) and a, shared by ∂L/∂q and the time
    # derivatives along q' = v that the hidden constraint needs
    dM, da = {}, {}

    def m_(x, i, c):
        key = (x, min(i, c), max(i, c))
        if key not in dM:
            dM[key] = sp.diff(M[key[1], key[2]], x)
        return dM[key]

    def a_(x, i):
        if (x, i) not in da:
            da[x, i] = sp.diff(a[i], x)
        return da[x, i]

    def dot(e):  # the derivative along q' = v at fixed v
        return sp.diff(e, t) + sum((sp.diff(e, qi) * vi for qi, vi in zip(q, v)), zero)

    # g0 = ∂L/∂q + F,  L = ½ vᵀ M v + aᵀ v − V, written with u_lc = Σ_i v_i ∂M_ic/∂q_l, which
    # also gives ∂g0/∂v = u_lc + ∂a_c/∂q_l + ∂F_l/∂v_c (row-major) for no more than n² additions:
    # with M⁻¹ it is g's exact derivative in p (model_derivatives_pl)
    u = [[sum((v[i] * m_(ql, i, c) for i in range(n)), zero) for c in range(n)] for ql in q]
    g0 = [sum((v[c] * u[l][c] for c in range(n)), zero) / 2
          + sum((v[i] * a_(ql, i) for i in range(n)), zero) - sp.diff(V, ql) + F[l] for l, ql in enumerate(q)]
    g0_v = [u[l][c] + a_(ql, c) + sp.diff(F[l], v[c]) for l, ql in enumerate(q) for c in range(n)]
    g = [g0[i] + sum((mu[j, i] * lam[j] for j in range(m)), zero) for i in range(n)]
    phi = [sum((mu[j, i] * v[i] for i in range(n)), zero) + nu[j] for j in range(m)]
    # b = g0 − Ṁ v − ȧ,  d = μ̇ v + ν̇
    b = [g0[i] - sum(((m_(t, i, c) + sum((m_(ql, i, c) * vl for ql, vl in zip(q, v)), zero)) * v[c]
                      for c in range(n)), zero)
         - a_(t, i) - sum((a_(ql, i) * vl for ql, vl in zip(q, v)), zero) for i in range(n)]
    d = [sum((dot(mu[j, c]) * v[c] for c in range(n)), zero) + dot(nu[j]) for j in range(m)]
    pre = list(M) + [p[i] - a[i] for i in range(n)]
    symbols = (n, t, q, p, lam, params, v)
    functions = [
        _function("model_fg", "double t, const double *q, const double *p, const double *lam, const double *k, "
                  "double *v, double *w, double *gv", pre, [("v", list(v)), ("w", g), ("gv", g0_v)], symbols,
                  optional=("gv",)),
        _function("model_phi", "double t, const double *q, const double *p, const double *k, double *out",
                  pre, [("out", phi)], symbols),
        _function("model_lambda_parts", "double t, const double *q, const double *p, const double *k, "
                  "double *b, double *d, double *mu, double *mo", pre,
                  [("b", b), ("d", d), ("mu", list(mu)), ("mo", list(M))], symbols),
        _function("model_mass_mu", "double t, const double *q, const double *k, double *mo, double *mu", None,
                  [("mo", list(M)), ("mu", list(mu))], symbols),
    ]
    nh = len(psi)
    if nh:
        psi_q = sp.Matrix(psi).jacobian(sp.Matrix(q))
        functions += [
            _function("model_psi", "double t, const double *q, const double *k, double *out, double *jac", None,
                      [("out", list(psi)), ("jac", list(psi_q))], symbols),
        ]
    structure = [[M[i, j] != 0 for j in range(n)] for i in range(n)]
    return (f"#define NQ {n}\n#define NM {m}\n#define NH {nh}\n" + _SPD_SOLVE_C + mass_solve_source(structure)
            + "\n".join(functions) + "\n"
            + _LAMBDA_C + _DERIVATIVES_C + (_PROJECTION_C if nh else ""))


_SPD_SOLVE_C = r"""
/* M X = B for symmetric positive definite M (n x n row-major, overwritten) and the m columns of
   B (n x m row-major, overwritten by X): elimination without pivoting; each column takes the same
   operations in the same order as it would alone */
static void spd_solve_columns(int n, double *mm, double *b, int m) {
  for (int kk = 0; kk < n; kk++) {
    const double inv = 1.0 / mm[kk*n + kk];
    for (int i = kk + 1; i < n; i++) {
      const double fct = mm[i*n + kk] * inv;
      if (fct == 0.0) continue;
      for (int j = kk + 1; j < n; j++) mm[i*n + j] -= fct * mm[kk*n + j];
      for (int c = 0; c < m; c++) b[i*m + c] -= fct * b[kk*m + c];
    }
  }
  for (int i = n - 1; i >= 0; i--) for (int c = 0; c < m; c++) {
    double sum = b[i*m + c];
    for (int j = i + 1; j < n; j++) sum -= mm[i*n + j] * b[j*m + c];
    b[i*m + c] = sum / mm[i*n + i];
  }
}

/* M x = b (one column) */
static void spd_solve(int n, double *mm, double *b) { spd_solve_columns(n, mm, b, 1); }
"""

_LAMBDA_C = r"""
/* λ(t, q, p) from the hidden constraint: (μ M⁻¹ μᵀ) λ = −(μ M⁻¹ b + d) */
static void model_lambda(double t, const double *q, const double *p, const double *k, double *lam) {
  enum { W = NM + 1 };   /* the columns (b, μ_1ᵀ, ..., μ_mᵀ), solved at once: u = M⁻¹ b, w_l = M⁻¹ μ_lᵀ */
  double b[NQ], d[NM], mu[NM*NQ], mo[NQ*NQ], x[NQ*W], sm[NM*NM];
  model_lambda_parts(t, q, p, k, b, d, mu, mo);
  for (int c = 0; c < NQ; c++) { x[c*W] = b[c]; for (int l = 0; l < NM; l++) x[c*W + 1 + l] = mu[l*NQ + c]; }
  mass_solve_columns(mo, x, W);
  for (int j = 0; j < NM; j++) {
    double r = 0.0;
    for (int c = 0; c < NQ; c++) r += mu[j*NQ + c] * x[c*W];
    lam[j] = -(r + d[j]);
    for (int l = 0; l < NM; l++) { double a = 0.0; for (int c = 0; c < NQ; c++) a += mu[j*NQ + c] * x[c*W + 1 + l]; sm[j*NM + l] = a; }
  }
  spd_solve(NM, sm, lam);
}
"""


_DERIVATIVES_C = r"""
/* The exact derivatives of f, g and φ in p and λ at (t, q, p, λ), which need no differences: with
   v = f = M⁻¹(p − a), g = g0(t, q, v) + μᵀλ and φ = μ v + ν,
     ∂f/∂p = M⁻¹,   ∂g/∂p = (∂g0/∂v) M⁻¹,   ∂g/∂λ = μᵀ,   ∂φ/∂p = μ M⁻¹   (∂f/∂λ = 0),
   from gv = ∂g0/∂v there (model_fg's last output) */
static void model_derivatives_pl(double t, const double *q, const double *k, const double *gv,
                                 double fp[NQ][NQ], double gp[NQ][NQ], double gl[NQ][NM], double pp[NM][NQ]) {
  double mo[NQ*NQ], mu[NM*NQ];
  model_mass_mu(t, q, k, mo, mu);
  for (int r = 0; r < NQ; r++) for (int c = 0; c < NQ; c++) fp[r][c] = r == c;
  mass_solve_columns(mo, &fp[0][0], NQ);   /* M⁻¹ */
  for (int r = 0; r < NQ; r++) {
    for (int c = 0; c < NQ; c++) { double x = 0.0; for (int e = 0; e < NQ; e++) x += gv[r*NQ + e]*fp[e][c]; gp[r][c] = x; }
    for (int c = 0; c < NM; c++) gl[r][c] = mu[c*NQ + r];
  }
  for (int r = 0; r < NM; r++) for (int c = 0; c < NQ; c++) {
    double x = 0.0; for (int e = 0; e < NQ; e++) x += mu[r*NQ + e]*fp[e][c]; pp[r][c] = x; }
}

/* model_derivatives_pl for a caller outside the program (the tests): out = (fp, gp, gl, pp), row-major */
void derivatives_pl(double t, const double *q, const double *p, const double *lam, const double *k, double *out) {
  double v[NQ], w[NQ], gv[NQ*NQ];
  model_fg(t, q, p, lam, k, v, w, gv);
  model_derivatives_pl(t, q, k, gv, (double (*)[NQ])out, (double (*)[NQ])(out + NQ*NQ),
                       (double (*)[NM])(out + 2*NQ*NQ), (double (*)[NQ])(out + 2*NQ*NQ + NQ*NM));
}
"""


_PROJECTION_C = r"""
/* A x = b for a small general A (n x n row-major, overwritten): elimination with partial pivoting */
static void small_solve(int n, double *a, double *b) {
  for (int kk = 0; kk < n; kk++) {
    int pv = kk;
    for (int i = kk + 1; i < n; i++) if (fabs(a[i*n + kk]) > fabs(a[pv*n + kk])) pv = i;
    if (pv != kk) { for (int j = 0; j < n; j++) { const double x = a[kk*n + j]; a[kk*n + j] = a[pv*n + j]; a[pv*n + j] = x; }
                    const double x = b[kk]; b[kk] = b[pv]; b[pv] = x; }
    for (int i = kk + 1; i < n; i++) {
      const double fct = a[i*n + kk] / a[kk*n + kk];
      for (int j = kk + 1; j < n; j++) a[i*n + j] -= fct*a[kk*n + j];
      b[i] -= fct*b[kk];
    }
  }
  for (int i = n - 1; i >= 0; i--) { double sum = b[i]; for (int j = i + 1; j < n; j++) sum -= a[i*n + j]*b[j]; b[i] = sum / a[i*n + i]; }
}

/* The end of a step projected onto ψ(t, q) = 0 and φ(t, q, p) = 0 (lobattodae._projection):
   positions q_1 = q̃ + D κ, D = M(t, q̃)⁻¹ ψ_q(t, q̃)ᵀ, κ by POSITION_NEWTON_ITERATIONS Newton steps
   κ ← κ − (ψ_q(t, q̃ + Dκ) D)⁻¹ ψ(t, q̃ + Dκ); momenta p_1 = p̃ − μᵀ (μ M⁻¹ μᵀ)⁻¹ φ(t, q_1, p̃) at q_1 */
static void project_end(double t, double *q, double *p, const double *k) {
  /* D = M⁻¹ ψ_qᵀ and W = M⁻¹ μᵀ each in one solve of their columns (row c of D at dd[c*NH]) */
  double mo[NQ*NQ], mu[NM*NQ], dd[NQ*NH], psi[NH], jac[NH*NQ], kappa[NH], qq[NQ], jd[NH*NH];
  model_mass_mu(t, q, k, mo, mu);
  model_psi(t, q, k, psi, jac);
  for (int c = 0; c < NQ; c++) for (int j = 0; j < NH; j++) dd[c*NH + j] = jac[j*NQ + c];
  mass_solve_columns(mo, dd, NH);
  for (int j = 0; j < NH; j++) kappa[j] = 0.0;
  for (int it = 0; it < POSITION_NEWTON_ITERATIONS; it++) {
    for (int c = 0; c < NQ; c++) { double x = 0.0; for (int j = 0; j < NH; j++) x += dd[c*NH + j]*kappa[j]; qq[c] = q[c] + x; }
    model_psi(t, qq, k, psi, jac);
    for (int a = 0; a < NH; a++) for (int b = 0; b < NH; b++) {
      double x = 0.0; for (int c = 0; c < NQ; c++) x += jac[a*NQ + c]*dd[c*NH + b]; jd[a*NH + b] = x; }
    small_solve(NH, jd, psi);
    for (int j = 0; j < NH; j++) kappa[j] -= psi[j];
  }
  for (int c = 0; c < NQ; c++) { double x = 0.0; for (int j = 0; j < NH; j++) x += dd[c*NH + j]*kappa[j]; q[c] += x; }
  double phi[NM], w[NQ*NM], sm[NM*NM];
  model_mass_mu(t, q, k, mo, mu);
  model_phi(t, q, p, k, phi);
  for (int c = 0; c < NQ; c++) for (int j = 0; j < NM; j++) w[c*NM + j] = mu[j*NQ + c];
  mass_solve_columns(mo, w, NM);
  for (int a = 0; a < NM; a++) for (int b = 0; b < NM; b++) {
    double x = 0.0; for (int c = 0; c < NQ; c++) x += mu[a*NQ + c]*w[c*NM + b]; sm[a*NM + b] = x; }
  spd_solve(NM, sm, phi);
  for (int c = 0; c < NQ; c++) { double x = 0.0; for (int j = 0; j < NM; j++) x += mu[j*NQ + c]*phi[j]; p[c] -= x; }
}
"""


# ------------------------------------------------------------------------------- the step
def _constants() -> str:
    """The numerical policies of the JAX path, read from where they are decided."""
    values = {
        "THETA_REFRESH": _newton.THETA_REFRESH, "REFRESH_PREDICTED": _newton.REFRESH_PREDICTED,
        "REFRESH_ITERATIONS": _newton.REFRESH_ITERATIONS, "THETA_STAGNATION": _newton.THETA_STAGNATION,
        "STAGNATION_LEVEL": _newton.STAGNATION_LEVEL, "FLOOR_FACTOR": _newton.FLOOR_FACTOR,
        "ROUNDOFF_LEVEL": _newton.ROUNDOFF_LEVEL, "THETA_DIVERGED": _newton.THETA_DIVERGED,
        "KAPPA_STALE": _newton.KAPPA_STALE, "H_CHANGE_REFRESH": _stepper.H_CHANGE_REFRESH,
        "POSITION_NEWTON_ITERATIONS": _projection.POSITION_NEWTON_ITERATIONS, "DRIFT_EPOCH": _stepper.DRIFT_EPOCH, "DRIFT_BAND": _stepper.DRIFT_BAND, "DRIFT_FLOOR": _stepper.DRIFT_FLOOR,
        "R_MAX_ITERATIONS": int(Result.MAX_ITERATIONS), "R_DIVERGED": int(Result.DIVERGED),
        "R_NONFINITE": int(Result.NONFINITE),
    }
    return "".join(f"#define {k} {float(v)!r}\n" if isinstance(v, float) else f"#define {k} {v}\n"
                   for k, v in values.items())


#: The stage equations of the stepping program (after ``#define S``, the model and :func:`_constants`).
_STAGES_C = r"""
#include <stdlib.h>
#define NU ((2*S - 1)*NQ + (S - 1)*NM)
#define OQ 0
#define OP ((S - 1)*NQ)
#define OZ ((2*S - 1)*NQ)

typedef struct { double A[S][S], AH[S][S], B[S], C[S]; } Tab;   /* IIIA a_ij, IIIB â_ij, b, c */

/* The stages encoded in x = (Q_2..Q_s, P_1..P_s, Z_2..Z_s), Q_1 = q_0, Λ_1 = lam1, Λ_j = Z_j / h,
   and their slopes V_j = f(t_j, Q_j, P_j), W_j = g(t_j, Q_j, P_j, Λ_j), t_j = t_0 + c_j h (and,
   where GV is not NULL, ∂g0/∂v there). */
static void stages(const Tab *tb, double t0, double h, const double *q0, const double *lam1, const double *k,
                   const double *x, double Q[S][NQ], double P[S][NQ], double L[S][NM], double V[S][NQ], double W[S][NQ],
                   double GV[S][NQ*NQ]) {
  memcpy(Q[0], q0, sizeof(double)*NQ);
  for (int i = 1; i < S; i++) memcpy(Q[i], x + OQ + (i - 1)*NQ, sizeof(double)*NQ);
  for (int i = 0; i < S; i++) memcpy(P[i], x + OP + i*NQ, sizeof(double)*NQ);
  memcpy(L[0], lam1, sizeof(double)*NM);
  for (int i = 1; i < S; i++) for (int j = 0; j < NM; j++) L[i][j] = x[OZ + (i - 1)*NM + j] / h;
  for (int j = 0; j < S; j++) model_fg(t0 + tb->C[j]*h, Q[j], P[j], L[j], k, V[j], W[j], GV ? GV[j] : NULL);
}

/* p̃_i = p_0 + h Σ_j a_ij W_j (the IIIA momenta of row (3)) */
static void p_tilde(const Tab *tb, int i, double h, const double *p0, double W[S][NQ], double *pt) {
  for (int c = 0; c < NQ; c++) { double a = 0.0; for (int j = 0; j < S; j++) a += tb->A[i][j]*W[j][c]; pt[c] = p0[c] + h*a; }
}

/* The rows of the stage equations at x:
     (1) Q_i − q_0 − h Σ_j a_ij V_j,   i = 2..s
     (2) P_i − p_0 − h Σ_j â_ij W_j,   i = 1..s
     (3) φ(t_i, Q_i, p̃_i),            i = 2..s */
static void residual(const Tab *tb, double t0, double h, const double *q0, const double *p0, const double *lam1,
                     const double *k, const double *x, double *r) {
  double Q[S][NQ], P[S][NQ], L[S][NM], V[S][NQ], W[S][NQ];
  stages(tb, t0, h, q0, lam1, k, x, Q, P, L, V, W, NULL);
  int o = 0;
  for (int i = 1; i < S; i++) for (int c = 0; c < NQ; c++) {
    double a = 0.0; for (int j = 0; j < S; j++) a += tb->A[i][j]*V[j][c];
    r[o++] = Q[i][c] - q0[c] - h*a; }
  for (int i = 0; i < S; i++) for (int c = 0; c < NQ; c++) {
    double a = 0.0; for (int j = 0; j < S; j++) a += tb->AH[i][j]*W[j][c];
    r[o++] = P[i][c] - p0[c] - h*a; }
  for (int i = 1; i < S; i++) { double pt[NQ]; p_tilde(tb, i, h, p0, W, pt); model_phi(t0 + tb->C[i]*h, Q[i], pt, k, r + o); o += NM; }
}

"""

#: The LU factorisation of Newton's matrix and its solve (for ``NU`` unknowns, defined before).
_LU_C = r"""
/* LU with partial pivoting in place, and its solve. The matrix is stored by columns (newton_assemble
   writes it so) and factor works on columns (LAPACK's dgetf2 order), so that the pivot search and
   every update run over contiguous memory. Both are compiled at -O3 by gcc (vectorised; the rest
   of the program stays at -O2, which keeps a large model's compilation short): with the column order,
   18-24 % less time per error-controlled attempt on the falling disk (s = 5, 6), 20 % on the
   sleigh (benchmarks/RESULTS.md, 2026-11-29 14:50). With gcc on x86-64 Linux and 40 unknowns or
   more the factorisation is compiled a second time for AVX-512 (x86-64-v4) and the processor picks
   its copy when the library is loaded (the library stays portable; without fused multiply-adds, so
   both copies give the same bits): with the factorisation as it is now, 0.59-0.71 times the time
   at 67 and 87 unknowns, 1.04-1.14 times at 24 and 29 in quiet runs, blurred by the machine's load
   in between (dense random matrices, benchmarks/lu_copies.py; RESULTS.md, 2026-11-29 21:05). The solve, called once
   per Newton iteration, has the same two copies under the same condition (2-4 % less time per run
   on Andrews' squeezer, 67 and 87 unknowns; below 40 unknowns, where it stays one copy, copies of it
   made the sleigh 3.5 % slower). */
#if defined(__GNUC__) && !defined(__clang__)
#define VECTORISED __attribute__((optimize("O3")))
#if __GNUC__ >= 11 && defined(__x86_64__) && defined(__GLIBC__) && NU >= 40
#define FACTOR_CLONES __attribute__((optimize("O3", "fp-contract=off"), target_clones("arch=x86-64-v4", "default")))
#else
#define FACTOR_CLONES VECTORISED
#endif
#else
#define VECTORISED
#define FACTOR_CLONES
#endif
/* The first row i >= k of column c with the largest |c_i| (the pivot of partial pivoting): the
   largest value first, in eight independent maxima (a reduction in one chain waits on each
   comparison; the maximum is the same in any order), then its first occurrence: the row the scan
   that keeps the first maximum picks (a NaN is never chosen; with no finite maximum, k) */
static inline int pivot_row(const double *restrict c, int k) {
  double big[8] = {0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0};
  int i = k;
  for (; i + 8 <= NU; i += 8) for (int l = 0; l < 8; l++) { const double a = fabs(c[i + l]); big[l] = a > big[l] ? a : big[l]; }
  for (; i < NU; i++) { const double a = fabs(c[i]); big[0] = a > big[0] ? a : big[0]; }
  double top = big[0];
  for (int l = 1; l < 8; l++) top = big[l] > top ? big[l] : top;
  for (i = k; i < NU; i++) if (fabs(c[i]) == top) return i;
  return k;
}

/* rows k and pv exchanged in every column */
static inline void swap_rows(double *restrict lu, int k, int pv) {
  for (int j = 0; j < NU; j++) { double *c = lu + j*NU; const double t = c[k]; c[k] = c[pv]; c[pv] = t; }
}

/* Pivots two at a time: columns k and k + 1 are factorised first (k + 1 updated by k), then each
   later column takes both updates in one pass over it (half the passes of one pivot at a time).
   Every entry gets the same operations in the same order as with one pivot at a time (the row
   exchange of k + 1 commutes with pivot k's update, which works row by row), so the factors have
   the same bits. */
FACTOR_CLONES static void factor(double *restrict lu, int *restrict piv) {
  int k = 0;
  for (; k + 1 < NU; k += 2) {
    double *restrict c0 = lu + k*NU, *restrict c1 = c0 + NU;   /* columns k, k + 1 */
    int pv = pivot_row(c0, k);
    piv[k] = pv;
    if (pv != k) swap_rows(lu, k, pv);
    const double inv0 = 1.0 / c0[k];
    for (int i = k + 1; i < NU; i++) c0[i] *= inv0;
    const double g = c1[k];
    if (g != 0.0) for (int i = k + 1; i < NU; i++) c1[i] -= g*c0[i];
    pv = pivot_row(c1, k + 1);
    piv[k + 1] = pv;
    if (pv != k + 1) swap_rows(lu, k + 1, pv);
    const double inv1 = 1.0 / c1[k + 1];
    for (int i = k + 2; i < NU; i++) c1[i] *= inv1;
    for (int j = k + 2; j < NU; j++) {
      double *restrict cj = lu + j*NU;
      const double f0 = cj[k];
      if (f0 != 0.0) cj[k + 1] -= f0*c0[k + 1];
      const double f1 = cj[k + 1];
      if (f0 != 0.0 && f1 != 0.0) for (int i = k + 2; i < NU; i++) cj[i] = (cj[i] - f0*c0[i]) - f1*c1[i];
      else if (f0 != 0.0) for (int i = k + 2; i < NU; i++) cj[i] -= f0*c0[i];
      else if (f1 != 0.0) for (int i = k + 2; i < NU; i++) cj[i] -= f1*c1[i];
    }
  }
  if (k < NU) piv[k] = k;   /* an odd count: the last pivot is its own row */
}

FACTOR_CLONES static void lu_solve(const double *restrict lu, const int *restrict piv, double *restrict b) {
  for (int k = 0; k < NU; k++) { const double t = b[k]; b[k] = b[piv[k]]; b[piv[k]] = t; }
  for (int j = 0; j < NU; j++) {                     /* L y = P b, column by column */
    const double bj = b[j]; const double *restrict c = lu + j*NU;
    if (bj != 0.0) for (int i = j + 1; i < NU; i++) b[i] -= c[i]*bj;
  }
  for (int j = NU - 1; j >= 0; j--) {                /* U x = y */
    const double *restrict c = lu + j*NU; const double bj = b[j] / c[j];
    b[j] = bj;
    if (bj != 0.0) for (int i = 0; i < j; i++) b[i] -= c[i]*bj;
  }
}

"""

#: The rest of the stepping program: Newton's matrix, the step.
_STEP_C = r"""
/* the forward-difference increment that z + δ represents, δ = √ε max(1, |z|) */
static double fd_step(double z) { return (z + 1.4901161193847656e-08*fmax(1.0, fabs(z))) - z; }

/* Newton's matrix from per-stage blocks F_x = ∂f/∂x, G_x = ∂g/∂x (at stage k) and Φ_x = ∂φ/∂x
   (at (Q_i, p̃_i)): those in p and λ exact (model_derivatives_pl), those in q by forward
   differences; then factorised:
     (1) r_q,i:  δ_ik I − h a_ik F_q,        −h a_ik F_p,              0
     (2) r_p,i:  −h â_ik G_q,                δ_ik I − h â_ik G_p,      −â_ik G_λ
     (3) r_φ,i:  δ_ik Φ_q + h a_ik Φ_p G_q,  h a_ik Φ_p G_p,           a_ik Φ_p G_λ
   (columns Q_k, P_k, Z_k; lobattodae._stage_equations.assemble_jacobian) */
typedef struct { double fq[S][NQ][NQ], fp[S][NQ][NQ], gq[S][NQ][NQ], gp[S][NQ][NQ], gl[S][NQ][NM], pq[S][NM][NQ], pp[S][NM][NQ]; } Blocks;

static void newton_blocks(const Tab *tb, double t0, double h, const double *q0, const double *p0, const double *lam1,
                          const double *k, const double *x, Blocks *bl) {
  double Q[S][NQ], P[S][NQ], L[S][NM], V[S][NQ], W[S][NQ], GV[S][NQ*NQ];
  stages(tb, t0, h, q0, lam1, k, x, Q, P, L, V, W, GV);
  for (int j = 0; j < S; j++) {   /* Φ_p at stage j's (t, q) is that of the constraint rows i = j */
    const double tj = t0 + tb->C[j]*h;
    double z[NQ], v1[NQ], w1[NQ];
    model_derivatives_pl(tj, Q[j], k, GV[j], bl->fp[j], bl->gp[j], bl->gl[j], bl->pp[j]);
    memcpy(z, Q[j], sizeof z);
    for (int c = 0; c < NQ; c++) {
      const double zc = z[c], dz = fd_step(zc);
      z[c] = zc + dz; model_fg(tj, z, P[j], L[j], k, v1, w1, NULL); z[c] = zc;
      for (int r = 0; r < NQ; r++) { bl->fq[j][r][c] = (v1[r] - V[j][r]) / dz; bl->gq[j][r][c] = (w1[r] - W[j][r]) / dz; }
    }
  }
  for (int i = 1; i < S; i++) {
    double z[NQ], pt[NQ], f0[NM], f1[NM];
    memcpy(z, Q[i], sizeof z); p_tilde(tb, i, h, p0, W, pt);
    model_phi(t0 + tb->C[i]*h, z, pt, k, f0);
    for (int c = 0; c < NQ; c++) {
      const double zc = z[c], dz = fd_step(zc);
      z[c] = zc + dz; model_phi(t0 + tb->C[i]*h, z, pt, k, f1); z[c] = zc;
      for (int r = 0; r < NM; r++) bl->pq[i][r][c] = (f1[r] - f0[r]) / dz;
    }
  }
}

/* Newton's matrix of step size h from the blocks, written by columns (factor's order, entry
   (R, C) at lu[C*NU + R]) and factorised. The constraint rows' products Φ_p,i G_x,k are formed
   first, each a small matrix product with its columns innermost (so that they vectorise; the sums
   over e run in the same order as written in (3)) */
#define AT(R, C) lu[(C)*NU + (R)]
VECTORISED static void newton_assemble(const Tab *tb, double h, const Blocks *bl, double *lu, int *piv) {
  memset(lu, 0, sizeof(double)*NU*NU);
  for (int i = 1; i < S; i++) for (int r = 0; r < NQ; r++) {                                  /* (1) */
    const int row = OQ + (i - 1)*NQ + r;
    for (int kk = 0; kk < S; kk++) {
      const double ha = h*tb->A[i][kk];
      for (int c = 0; c < NQ; c++) {
        if (kk) AT(row, OQ + (kk - 1)*NQ + c) = -ha*bl->fq[kk][r][c];
        AT(row, OP + kk*NQ + c) = -ha*bl->fp[kk][r][c];
      }
    }
    AT(row, row) += 1.0;
  }
  for (int i = 0; i < S; i++) for (int r = 0; r < NQ; r++) {                                  /* (2) */
    const int row = OP + i*NQ + r;
    for (int kk = 0; kk < S; kk++) {
      const double ah = tb->AH[i][kk];
      for (int c = 0; c < NQ; c++) {
        if (kk) AT(row, OQ + (kk - 1)*NQ + c) = -h*ah*bl->gq[kk][r][c];
        AT(row, OP + kk*NQ + c) = -h*ah*bl->gp[kk][r][c];
      }
      if (kk) for (int c = 0; c < NM; c++) AT(row, OZ + (kk - 1)*NM + c) = -ah*bl->gl[kk][r][c];
    }
    AT(row, row) += 1.0;
  }
  for (int i = 1; i < S; i++) for (int kk = 0; kk < S; kk++) {                                /* (3) */
    double sq[NM][NQ], sp[NM][NQ], sl[NM][NM];
    for (int r = 0; r < NM; r++) {
      for (int c = 0; c < NQ; c++) { sq[r][c] = 0.0; sp[r][c] = 0.0; }
      for (int c = 0; c < NM; c++) sl[r][c] = 0.0;
      for (int e = 0; e < NQ; e++) {
        const double x = bl->pp[i][r][e];
        for (int c = 0; c < NQ; c++) { sq[r][c] += x*bl->gq[kk][e][c]; sp[r][c] += x*bl->gp[kk][e][c]; }
        for (int c = 0; c < NM; c++) sl[r][c] += x*bl->gl[kk][e][c];
      }
    }
    const double a = tb->A[i][kk];
    for (int r = 0; r < NM; r++) {
      const int row = OZ + (i - 1)*NM + r;
      for (int c = 0; c < NQ; c++) {
        if (kk) AT(row, OQ + (kk - 1)*NQ + c) = (i == kk ? bl->pq[i][r][c] : 0.0) + h*a*sq[r][c];
        AT(row, OP + kk*NQ + c) = h*a*sp[r][c];
      }
      if (kk) for (int c = 0; c < NM; c++) AT(row, OZ + (kk - 1)*NM + c) = a*sl[r][c];
    }
  }
  factor(lu, piv);
}
#undef AT

static void newton_matrix(const Tab *tb, double t0, double h, const double *q0, const double *p0, const double *lam1,
                          const double *k, const double *x, Blocks *bl, double *lu, int *piv) {
  newton_blocks(tb, t0, h, q0, p0, lam1, k, x, bl);
  newton_assemble(tb, h, bl, lu, piv);
}

/* The predictor's memory: the last step's stage slopes, what the plain extrapolation missed on
   them, and that step's size (an error-controlled run selects it back after a rejected attempt). */
typedef struct {
  double Vh[S][NQ], Wh[S][NQ], Lh[S][NM], dV[S][NQ], dW[S][NQ], dL[S][NM], h_prev;
  int have_slopes, have_corr;
} History;

/* What a run keeps from step to step: Newton's LU factors (and the h they were made with), the
   round-off level where the last solve with a fresh matrix stopped, the predictor's history. */
typedef struct {
  double lu[NU*NU]; int piv[NU]; int have_lu; double h_lu, floor_;
  History hs;
  Blocks blocks; double blocks_t, blocks_h; int have_blocks;   /* the step the blocks were made in */
} Solver;

/* l_j(tau), the Lagrange basis of the nodes c_first..c_s (l_j = 0 for the nodes before) */
static void basis(const Tab *tb, int first, double tau, double *l) {
  for (int j = 0; j < S; j++) {
    double v = j >= first;
    for (int m = first; m < S; m++) if (m != j) v *= (tau - tb->C[m]) / (tb->C[j] - tb->C[m]);
    l[j] = v;
  }
}

/* One step of size h from (t, q, p) with start multiplier lam1: (q1, p1, lam_out), comp updated
   (compensated summation), res_norm the max-norm of the last evaluated residual. Returns 0 or the
   Result code of a failed stage solve. stats: [Newton iterations, Newton matrices]. */
static int step(Solver *sv, const Tab *tb, int extrapolate, double tol, int maxit, double t, double h,
                const double *q, const double *p, const double *lam1, double *comp, const double *k,
                double *q1, double *p1, double *lam_out, double *res_norm, long *stats) {
  double x[NU], dx[NU], Vp[S][NQ], Wp[S][NQ], Lp[S][NM];
  if (fabs(h - sv->h_lu) > H_CHANGE_REFRESH*fabs(h)) sv->have_lu = 0;
  if (extrapolate && sv->hs.have_slopes) {
    /* Newton's start: the previous step's stage polynomials at the new stage times, plus what they
       missed one step before; Q = q_0 + h A V, P = p_0 + h Â W, Z = h Λ */
    const double on = sv->hs.have_corr ? 1.0 : 0.0;
    for (int i = 0; i < S; i++) {
      double l[S]; basis(tb, 0, 1.0 + tb->C[i]*h/sv->hs.h_prev, l);
      for (int c = 0; c < NQ; c++) {
        double a = 0.0, b = 0.0;
        for (int j = 0; j < S; j++) { a += l[j]*sv->hs.Vh[j][c]; b += l[j]*sv->hs.Wh[j][c]; }
        Vp[i][c] = a; Wp[i][c] = b;
      }
      for (int c = 0; c < NM; c++) { double a = 0.0; for (int j = 0; j < S; j++) a += l[j]*sv->hs.Lh[j][c]; Lp[i][c] = a; }
    }
    for (int i = 1; i < S; i++) for (int c = 0; c < NQ; c++) {
      double a = 0.0; for (int j = 0; j < S; j++) a += tb->A[i][j]*(Vp[j][c] + on*sv->hs.dV[j][c]);
      x[OQ + (i - 1)*NQ + c] = q[c] + h*a; }
    for (int i = 0; i < S; i++) for (int c = 0; c < NQ; c++) {
      double a = 0.0; for (int j = 0; j < S; j++) a += tb->AH[i][j]*(Wp[j][c] + on*sv->hs.dW[j][c]);
      x[OP + i*NQ + c] = p[c] + h*a; }
    for (int i = 1; i < S; i++) for (int c = 0; c < NM; c++) x[OZ + (i - 1)*NM + c] = h*(Lp[i][c] + on*sv->hs.dL[i][c]);
  } else {
    for (int i = 1; i < S; i++) memcpy(x + OQ + (i - 1)*NQ, q, sizeof(double)*NQ);
    for (int i = 0; i < S; i++) memcpy(x + OP + i*NQ, p, sizeof(double)*NQ);
    for (int i = 1; i < S; i++) for (int c = 0; c < NM; c++) x[OZ + (i - 1)*NM + c] = h*lam1[c];
  }
  /* simplified Newton, the rules of lobattodae._newton: converged at a scaled increment
     |Δx_i| / (tol (1 + |x_i|)) <= 1 or when the rate predicts it (KAPPA_STALE stricter with a kept
     matrix); a kept matrix is made afresh at the current iterate when, above round-off, it
     contracts slower than THETA_REFRESH or its rate predicts more than REFRESH_PREDICTED further
     iterations, or after REFRESH_ITERATIONS; stagnation at round-off is accepted; a fresh matrix
     whose increments grow by THETA_DIVERGED has diverged */
  int result = R_MAX_ITERATIONS, fresh = 0;
  double prev = 0.0, best = INFINITY, theta_prev = 1.0;
  for (int it = 0; it < maxit; it++) {
    if (!sv->have_lu) {
      newton_matrix(tb, t, h, q, p, lam1, k, x, &sv->blocks, sv->lu, sv->piv);
      sv->have_lu = 1; sv->h_lu = h; fresh = 1; stats[1]++;
      sv->have_blocks = 1; sv->blocks_t = t; sv->blocks_h = h;
    }
    residual(tb, t, h, q, p, lam1, k, x, dx);
    double rn = 0.0;
    for (int i = 0; i < NU; i++) rn = fmax(rn, fabs(dx[i]));
    *res_norm = rn;
    lu_solve(sv->lu, sv->piv, dx);
    double nrm = 0.0;
    for (int i = 0; i < NU; i++) { x[i] -= dx[i]; nrm = fmax(nrm, fabs(dx[i]) / (tol*(1.0 + fabs(x[i])))); }
    stats[0]++;
    if (!isfinite(nrm)) { result = R_NONFINITE; break; }
    const int first = it == 0, stale = !fresh;
    const double theta = first ? 0.0 : nrm / (prev > 0.0 ? prev : 1.0);
    const double bst = fmin(best, prev), progress = first ? 0.0 : nrm / (bst > 0.0 ? bst : 1.0);
    const double th_est = stale ? fmax(theta, theta_prev) : theta;
    const int rate_known = !first && (!stale || it >= 2);
    const double kappa = stale ? KAPPA_STALE : 1.0;
    const double level = fmin(fmax(FLOOR_FACTOR*sv->floor_, ROUNDOFF_LEVEL), STAGNATION_LEVEL);
    if (nrm <= 1.0 || (rate_known && th_est < 0.5 && th_est/(1.0 - th_est)*nrm <= kappa)
        || (!first && progress >= THETA_STAGNATION && nrm <= (stale ? level : STAGNATION_LEVEL))) {
      result = 0; if (fresh) sv->floor_ = nrm; break;
    }
    if (!first && !stale && theta >= THETA_DIVERGED) { result = R_DIVERGED; break; }
    const double remaining = log(fmax(nrm, 1.0)) / -log(fmin(fmax(theta, 1e-300), 0.999));
    if (stale && !first && ((nrm > level && (theta >= THETA_REFRESH || remaining > REFRESH_PREDICTED))
                            || it + 1 >= REFRESH_ITERATIONS)) sv->have_lu = 0;
    best = first ? nrm : fmin(bst, nrm);
    theta_prev = stale ? theta : 1.0;
    prev = nrm;
    fresh = 0;
  }
  if (result) { sv->have_lu = 0; return result; }
  /* (4) q_1 = q_0 + h Σ_j b_j V_j, p_1 = p_0 + h Σ_j b_j W_j, summed with compensation
     (TwoSum: comp carries what y_1 could not hold); λ_1 = Λ_s */
  double Q[S][NQ], P[S][NQ], L[S][NM], V[S][NQ], W[S][NQ];
  stages(tb, t, h, q, lam1, k, x, Q, P, L, V, W, NULL);
  for (int c = 0; c < 2*NQ; c++) {
    double a = 0.0;
    for (int j = 0; j < S; j++) a += tb->B[j]*(c < NQ ? V[j][c] : W[j][c - NQ]);
    const double y0 = c < NQ ? q[c] : p[c - NQ], d = h*a + comp[c];
    const double y1 = y0 + d, d_kept = y1 - y0, y0_kept = y1 - d_kept;
    comp[c] = (y0 - y0_kept) + (d - d_kept);
    if (c < NQ) q1[c] = y1; else p1[c - NQ] = y1;
  }
  memcpy(lam_out, L[S - 1], sizeof(double)*NM);
#if NH > 0
  project_end(t + h, q1, p1, k);   /* ψ = 0 and φ = 0 at the step point, by projection */
#endif
  if (extrapolate && sv->hs.have_slopes) {
    for (int i = 0; i < S; i++) {
      for (int c = 0; c < NQ; c++) { sv->hs.dV[i][c] = V[i][c] - Vp[i][c]; sv->hs.dW[i][c] = W[i][c] - Wp[i][c]; }
      for (int c = 0; c < NM; c++) sv->hs.dL[i][c] = L[i][c] - Lp[i][c];
    }
    sv->hs.have_corr = 1;
  }
  memcpy(sv->hs.Vh, V, sizeof V); memcpy(sv->hs.Wh, W, sizeof W); memcpy(sv->hs.Lh, L, sizeof L);
  sv->hs.h_prev = h; sv->hs.have_slopes = 1;
  return 0;
}

/* n_steps steps of size h from (t0, y = (q0, p0, lam0)) (lam0 = λ(t0, q0, p0) when have_lam0 is
   0). The step points 0, every, 2 every, ... and the last are written to the rows of ts, qs, ps,
   ls (row 0 holds the initial values; with a failed step, the last point reached is written as
   the row after the last one written), with the diagnostics of the step that made each row: its
   Newton iterations, last residual norm, ‖φ‖∞ at the point, the drift ‖λ − λ(t, q, p)‖∞ and
   whether it started from the hidden constraint's λ ("auto"). mode: 0 "auto", 1 "previous",
   2 "consistent". The λ drift monitor (LobattoIIIAIIIB._watch) runs in every mode; only "auto"
   re-synchronises. stats: [Newton iterations, Newton matrices, monitor excursions, steps taken,
   rows written, steps re-synchronised]; maxes: [max ‖φ‖∞ over every step point, max drift over every step point].
   Returns 0 or the failed step's Result code (-1: no memory). */
int run(int n_steps, int every, double t0, double h, int mode, int have_lam0, double *ts, double *qs, double *ps,
        double *ls, int *row_it, double *row_res, double *row_phi, double *row_drift, int *row_resync,
        const double *k, const double *tab, int extrapolate, double tol, int maxit, long *stats, double *maxes) {
  Tab tb; memcpy(&tb, tab, sizeof tb);
  Solver *sv = calloc(1, sizeof(Solver));
  if (!sv) return -1;
  double comp[2*NQ] = {0.0}, lam1[NM], hidden[NM], phi[NM], y[2][2*NQ + NM];   /* the point and the next */
  double level = 0.0, current = 0.0; long count = 0, length = DRIFT_EPOCH; int resync = 0;
  model_lambda(t0, qs, ps, k, hidden);
  if (!have_lam0) memcpy(ls, hidden, sizeof hidden);
  ts[0] = t0;
  model_phi(t0, qs, ps, k, phi);
  row_phi[0] = 0.0;
  for (int j = 0; j < NM; j++) row_phi[0] = fmax(row_phi[0], fabs(phi[j]));
  row_drift[0] = 0.0; row_it[0] = 0; row_res[0] = 0.0; row_resync[0] = 0;
  maxes[0] = row_phi[0]; maxes[1] = 0.0;
  memcpy(y[0], qs, sizeof(double)*NQ); memcpy(y[0] + NQ, ps, sizeof(double)*NQ); memcpy(y[0] + 2*NQ, ls, sizeof(double)*NM);
  long rows = 1, written = 0;   /* rows written; the step of the last one */
  int result = 0, cur = 0, it_last = 0, resync_last = 0;
  double res_last = 0.0, phi_last = row_phi[0], drift_last = 0.0;
  for (long n = 0; n < n_steps; n++) {
    const double t = t0 + n*h;
    double *y0 = y[cur], *y1 = y[1 - cur];
    const int started_hidden = mode == 2 || (mode == 0 && resync);
    if (started_hidden) memcpy(lam1, hidden, sizeof lam1); else memcpy(lam1, y0 + 2*NQ, sizeof lam1);
    const long it0 = stats[0];
    double rn = 0.0;
    result = step(sv, &tb, extrapolate, tol, maxit, t, h, y0, y0 + NQ, lam1, comp, k, y1, y1 + NQ, y1 + 2*NQ, &rn, stats);
    if (result) break;
    cur = 1 - cur;
    stats[3] = n + 1;
    const double t1 = t0 + (n + 1)*h;
    model_lambda(t1, y1, y1 + NQ, k, hidden);
    model_phi(t1, y1, y1 + NQ, k, phi);
    double drift = 0.0, size = 0.0, phin = 0.0;
    for (int j = 0; j < NM; j++) { drift = fmax(drift, fabs(y1[2*NQ + j] - hidden[j])); size = fmax(size, fabs(y1[2*NQ + j]));
                                   phin = fmax(phin, fabs(phi[j])); }
    maxes[0] = fmax(maxes[0], phin); maxes[1] = fmax(maxes[1], drift);
    if (started_hidden && mode == 0) { level = 0.0; current = 0.0; count = 0; length = DRIFT_EPOCH; }
    const int excursion = level > 0.0 && drift > fmax(DRIFT_BAND*level, DRIFT_FLOOR*(1.0 + size));
    current = fmax(current, drift);
    if (++count >= length) { level = current; current = 0.0; count = 0; length *= 2; }
    stats[2] += excursion;
    stats[5] += started_hidden && mode == 0;
    resync = excursion && mode == 0;
    it_last = (int)(stats[0] - it0); res_last = rn; phi_last = phin; drift_last = drift; resync_last = started_hidden && mode == 0;
    if ((n + 1) % every == 0 || n + 1 == n_steps) {
      ts[rows] = t1;
      memcpy(qs + rows*NQ, y1, sizeof(double)*NQ); memcpy(ps + rows*NQ, y1 + NQ, sizeof(double)*NQ);
      memcpy(ls + rows*NM, y1 + 2*NQ, sizeof(double)*NM);
      row_it[rows] = it_last; row_res[rows] = res_last; row_phi[rows] = phi_last; row_drift[rows] = drift_last;
      row_resync[rows] = resync_last;
      rows++; written = n + 1;
    }
  }
  if (result && stats[3] > written) {   /* the last point reached, after the last row written */
    const double *yl = y[cur];
    ts[rows] = t0 + stats[3]*h;
    memcpy(qs + rows*NQ, yl, sizeof(double)*NQ); memcpy(ps + rows*NQ, yl + NQ, sizeof(double)*NQ);
    memcpy(ls + rows*NM, yl + 2*NQ, sizeof(double)*NM);
    row_it[rows] = it_last; row_res[rows] = res_last; row_phi[rows] = phi_last; row_drift[rows] = drift_last;
    row_resync[rows] = resync_last;
    rows++;
  }
  stats[4] = rows;
  free(sv);
  return result;
}
"""


def _tableau(s: int) -> np.ndarray:
    return tableau_array(lobatto_pair(s))


def program_source(model, stages: int) -> str:
    """The whole C program of (model, s): the policies, the model's functions, the step, the run
    and the error-controlled attempt (:mod:`._native_loop`)."""
    return ("#include <math.h>\n#include <string.h>\n" + f"#define S {int(stages)}\n" + _constants()
            + model_source(model) + _STAGES_C + _LU_C + _STEP_C + ATTEMPT_C)


# ------------------------------------------------------------------------ compile and load
def c_compiler() -> str | None:
    """``$CC``, else the first of ``cc``, ``gcc``, ``clang`` on the PATH (None if none)."""
    if os.environ.get("CC"):
        return os.environ["CC"]
    for name in ("cc", "gcc", "clang"):
        path = shutil.which(name)
        if path:
            return path
    return None


_PROCESS_DIR: list[Path] = []


def _library_dir() -> Path:
    """``<cache>/native``; a directory of this process's own (removed at exit) where the cache is
    switched off (``LOBATTODAE_NO_CACHE=1``) or cannot be created."""
    if not cache_switched_off():
        directory = default_cache_dir() / "native"
        try:
            directory.mkdir(parents=True, exist_ok=True)
            return directory
        except OSError:
            pass
    if not _PROCESS_DIR:
        _PROCESS_DIR.append(Path(tempfile.mkdtemp(prefix="lobattodae-native-")))
        atexit.register(shutil.rmtree, _PROCESS_DIR[0], True)
    return _PROCESS_DIR[0]


#: What the generated C depends on besides the model and s: this generator's own code.
_GENERATOR = hashlib.sha256(b"".join(Path(f).read_bytes() for f in (__file__, _codegen.__file__,
                                                                     _native_loop.__file__))).hexdigest()


def _compiled(make_source, inputs: str, label: str) -> Path:
    """The shared library of the program ``make_source()`` makes from ``inputs``: from the cache
    (named by a hash of ``inputs``, the generator's code and the compiler command, so a new process
    finds it without generating the C again), or generated, compiled and stored (atomically)."""
    cc = c_compiler()
    if cc is None:
        raise LobattoDAEInputError(
            "the native step needs a C compiler: none of $CC, cc, gcc, clang was found. Install one (e.g. "
            "gcc) or set CC; lobattodae.integrate and lobattodae.solve need none."
        )
    flags = [*CFLAGS, "-I", jax.ffi.include_dir()]  # XLA's FFI header, of the installed jaxlib
    key = hashlib.sha256("\0".join([inputs, _GENERATOR, cc, *flags, jaxlib.__version__]).encode()).hexdigest()[:24]
    directory = _library_dir()
    target = directory / f"{re.sub(r'[^A-Za-z0-9_-]+', '_', label).strip('_')}-{key}.so"
    if target.exists():
        return target
    source = make_source()
    with tempfile.TemporaryDirectory(dir=directory) as work:
        src = Path(work) / "step.c"
        src.write_text(source)
        out = Path(work) / "step.so"
        done = subprocess.run([cc, *flags, "-o", str(out), str(src), "-lm"], capture_output=True, text=True)
        if done.returncode != 0:
            raise RuntimeError(
                f"the C compiler ({cc}) failed on the generated native step (an expression of the model that C "
                "cannot take?); lobattodae.solve and lobattodae.integrate take this model without it. The "
                f"compiler said:\n{done.stderr[-4000:]}")
        os.replace(out, target)
    return target


_DOUBLE_P = ctypes.POINTER(ctypes.c_double)
#: The FFI handlers registered with XLA in this process (by name), and their loaded libraries.
_TARGETS: dict[str, ctypes.CDLL] = {}
_INT_P = ctypes.POINTER(ctypes.c_int32)


class NativeIntegrator:
    """A model's Lobatto IIIA-IIIB method in compiled C (see the module docstring): constant steps
    (:meth:`integrate`, :meth:`solve` with ``n_steps``) and the attempts of error-controlled runs
    (:meth:`solve` with ``rtol``, or ``lobattodae.solve(model.problem, native, ...)``).

    Made by :meth:`LagrangianModel.native <lobattodae.mechanics.LagrangianModel.native>` from a
    :class:`~lobattodae.LobattoIIIAIIIB` (its stages, ``lam_start``, ``tol`` and
    ``max_iterations``); one per (model, method). Holds no state between calls: each
    :meth:`integrate` is a run of its own.

    Attributes
    ----------
    model : LagrangianModel
    method : LobattoIIIAIIIB
        The method whose steps it takes (``Solution.method`` of :meth:`solve`).
    stages : int
    lam_start, tol, max_iterations :
        As in :class:`~lobattodae.LobattoIIIAIIIB`.
    library : pathlib.Path
        The compiled shared library.
    """

    _MODES = {"auto": 0, "previous": 1, "consistent": 2}

    def __init__(self, model, method):
        self.model, self.method = model, method
        self.stages, self.lam_start = method.stages, method.lam_start
        self.tol, self.max_iterations = method.tol, method.max_iterations
        self.extrapolate = method._use_extrapolation
        # the model is all in its generated JAX source (M, a, V, μ, ν, F, ψ and the parameters' order)
        self.library = _compiled(lambda: program_source(model, self.stages), f"S={self.stages}\n{model.source}",
                                 f"{model.name}-s{self.stages}")
        lib = ctypes.CDLL(str(self.library))
        self._run = lib.run
        self._run.argtypes = [ctypes.c_int, ctypes.c_int, ctypes.c_double, ctypes.c_double, ctypes.c_int, ctypes.c_int,
                              _DOUBLE_P, _DOUBLE_P, _DOUBLE_P, _DOUBLE_P, _INT_P, _DOUBLE_P, _DOUBLE_P, _DOUBLE_P,
                              _INT_P, _DOUBLE_P, _DOUBLE_P, ctypes.c_int, ctypes.c_double, ctypes.c_int,
                              ctypes.POINTER(ctypes.c_long), _DOUBLE_P]
        self._run.restype = ctypes.c_int
        self._tab = _tableau(self.stages)
        self._lib = lib
        self._steppers: dict = {}  # (kind, method) -> the loop's stepper (one object: jit's static key stays cheap)

    def doubling(self, method, problem=None) -> NativeDoubling:
        """The stepper of :func:`lobattodae.solve`'s error-controlled runs: each attempt of step
        doubling one call into this program (``lobattodae.mechanics._native_loop``).

        Called by ``solve`` (users pass the integrator itself as ``solve``'s method).

        Parameters
        ----------
        method : LobattoIIIAIIIB
            This integrator's method as error control runs it (``lam_start="auto"`` made
            ``"consistent"``).
        problem : optional
            The problem ``solve`` was given: it must be this model's ``problem``.

        Returns
        -------
        NativeDoubling
            One per method (kept), so that the compiled loop's key stays the same object.

        Raises
        ------
        LobattoDAEInputError
            ``problem`` is not this model's.
        """
        return self._stepper(NativeDoubling, "lobattodae_attempt", ("attempt_newton_doubles",
                                                                    "attempt_history_doubles"), method, problem)

    def single(self, method, problem=None) -> NativeStep:
        """The stepper of :func:`lobattodae.solve`'s runs under its other controllers (constant
        steps, :class:`~lobattodae.ReversibleStepSize`, the embedded estimate): each step one call
        into this program (``lobattodae.mechanics._native_loop``).

        Called by ``solve`` (users pass the integrator itself as ``solve``'s method).

        Parameters
        ----------
        method : LobattoIIIAIIIB
            This integrator's method as the controller runs it.
        problem : optional
            The problem ``solve`` was given: it must be this model's ``problem``.

        Returns
        -------
        NativeStep
            One per method (kept).

        Raises
        ------
        LobattoDAEInputError
            ``problem`` is not this model's.
        """
        return self._stepper(NativeStep, "lobattodae_step", ("step_newton_doubles", "step_history_doubles"), method,
                             problem)

    def _stepper(self, kind, handler: str, size_functions, method, problem):
        """The loop's stepper ``kind`` for ``method`` over the FFI ``handler`` (registered once per
        process), kept per (kind, method) so that the compiled loop's key stays one object."""
        if problem is not None and problem is not self.model.problem:
            raise LobattoDAEInputError(
                f"this NativeIntegrator steps the equations of the model {self.model.name!r}: pass its problem, "
                f"lobattodae.solve(model.problem, model.native(...), ...), or use native.solve(...).")
        stepper = self._steppers.get((kind, method))
        if stepper is None:
            name = f"{handler}_{self.library.stem.rsplit('-', 1)[-1]}"
            if name not in _TARGETS:
                jax.ffi.register_ffi_target(name, jax.ffi.pycapsule(getattr(self._lib, handler)), platform="cpu")
                _TARGETS[name] = self._lib  # registered once per process; the library stays loaded
            sizes = []
            for function in size_functions:
                fn = getattr(self._lib, function)
                fn.restype = ctypes.c_long
                sizes.append(int(fn()))
            stepper = self._steppers[(kind, method)] = kind(method, target=name, parameters=tuple(self.model.parameters),
                                                             sizes=tuple(sizes))
        return stepper

    def __repr__(self) -> str:
        return (f"NativeIntegrator({self.model.name!r}, stages={self.stages}, lam_start={self.lam_start!r}, "
                f"library={str(self.library)!r})")

    def _vector(self, name, x, size):
        arr = np.array(x, dtype=np.float64)
        if arr.shape != (size,):
            raise ShapeError(f"{self.model.name}: {name} must have shape ({size},); got {arr.shape}.")
        if not np.all(np.isfinite(arr)):
            raise LobattoDAEInputError(f"{self.model.name}: {name} has non-finite entries: {arr}.")
        return arr

    def _call(self, t0: float, h: float, n_steps: int, every: int, q0, p0, lam0, args) -> _Run:
        """One run of the compiled program (arguments checked but the step count and stride)."""
        model = self.model
        n, m = model.n, model.m
        k = np.array([float(v) for v in (model._check_args(args)[name] for name in model.parameters)], np.float64)
        rows = -(-n_steps // every) + 1  # 0, every, 2 every, ..., n_steps (a failed run's last point fits)
        ts = np.full(rows, np.nan)
        qs, ps, ls = np.full((rows, n), np.nan), np.full((rows, n), np.nan), np.full((rows, m), np.nan)
        qs[0], ps[0] = self._vector("q0", q0, n), self._vector("p0", p0, n)
        if lam0 is not None:
            ls[0] = self._vector("lam0", lam0, m)
        its, resync = np.zeros(rows, np.int32), np.zeros(rows, np.int32)
        res, phi, drift = np.full(rows, np.nan), np.full(rows, np.nan), np.full(rows, np.nan)
        stats, maxes = (ctypes.c_long * 6)(), np.zeros(2)

        def ptr(a):
            return a.ctypes.data_as(_INT_P if a.dtype == np.int32 else _DOUBLE_P)

        start = time.perf_counter()
        code = self._run(n_steps, every, t0, h, self._MODES[self.lam_start], int(lam0 is not None), ptr(ts), ptr(qs),
                         ptr(ps), ptr(ls), ptr(its), ptr(res), ptr(phi), ptr(drift), ptr(resync), ptr(k),
                         ptr(self._tab), int(self.extrapolate), self.tol, self.max_iterations, stats, ptr(maxes))
        elapsed = time.perf_counter() - start
        if code < 0:
            raise MemoryError("the native step could not allocate its Newton matrix.")
        return _Run(ts, qs, ps, ls, Result(code), its, res, phi, drift, resync.astype(bool), tuple(int(x) for x in stats),
                    float(maxes[0]), float(maxes[1]), elapsed)

    def integrate(self, t0, h, n_steps: int, q0, p0, lam0=None, args=None, *, save_every=1) -> NativeResult:
        """``n_steps`` steps of size ``h`` from ``(t0, q0, p0)``, as :func:`lobattodae.integrate`.

        Parameters
        ----------
        t0, h : float
            Initial time and step size (``h < 0``: backwards).
        n_steps : int
        q0, p0 : array_like, shape (n,)
            Consistent initial values (``φ(t0, q0, p0) = 0``; not checked, as in
            :func:`lobattodae.integrate`; :meth:`solve` checks them).
        lam0 : array_like, shape (m,), optional
            The start multiplier; default the hidden constraint's ``λ(t0, q0, p0)``.
        args : dict
            ``model.args(...)``.
        save_every : int or "final"
            Keep every k-th step point (and the last), or only the initial and the final one,
            as in :func:`lobattodae.solve`. Default: every step point.

        Returns
        -------
        NativeResult
            ``(q, p, lam, status, n_newton, n_jacobians, lam_resets, t)``, one row per kept
            step point (row 0 the initial values); after a failed step the last point reached
            is the last finite row and the rest are NaN.

        Raises
        ------
        LobattoDAEInputError
            A count, a time, a step, ``save_every`` or an initial value that is not usable
            (named in the message).
        """
        n_steps = check_count("n_steps", n_steps)
        every = _stride(save_every, n_steps)
        t0, h = float(t0), float(h)
        if not (math.isfinite(t0) and math.isfinite(h) and h != 0.0):
            raise LobattoDAEInputError(f"t0 and h must be finite and h nonzero; got t0={t0!r}, h={h!r}.")
        r = self._call(t0, h, n_steps, every, q0, p0, lam0, args)
        return NativeResult(r.q, r.p, r.lam, r.result, r.stats[0], r.stats[1], r.stats[5], r.t)

    def solve(self, t_span, q0, p0, *, n_steps=None, dt=None, rtol=None, atol=None, save_every=None, lam0=None,
              args=None, throw: bool = True, **options) -> Solution:
        """Integrate over ``t_span`` natively, as :func:`lobattodae.solve` does: a
        :class:`~lobattodae.Solution` (its plots, saving, scipy's views and ``energy_error`` work
        on it).

        With ``n_steps`` or ``dt`` and no other option than ``save_every``, constant steps in one
        call into the compiled program (rows and ``stats`` made there). Otherwise
        ``lobattodae.solve(model.problem, self, ...)``: the library's loop, each step (or attempt of
        step doubling, under error control: the default, ``rtol``, ``atol``) one native call
        (``lobattodae.mechanics._native_loop``), with every option of :func:`lobattodae.solve`
        (``t_eval``, ``events``, ``dense_output``, ``controller``, ``max_step``, checkpoints, ...)
        and the steps of the JAX path.

        Parameters
        ----------
        t_span : (float, float)
        q0, p0 : array_like, shape (n,)
            Consistent initial values, ``φ(t0, q0, p0) = 0`` to ``1e-10·(1 + ‖q0‖∞ + ‖p0‖∞)``
            (and ψ(t0, q0) = 0 with holonomic constraints).
        n_steps, dt : int or float
            Constant steps: their number, or a maximal step size, as in :func:`lobattodae.solve`.
        rtol, atol : float, optional
            Error-controlled steps (the default, with :func:`lobattodae.solve`'s tolerances).
        save_every : int or "final", optional
            Keep every k-th step point (and the last), or the initial and the final one.
        lam0 : array_like, shape (m,), optional
            Default: the hidden constraint's multiplier at ``(t0, q0, p0)``.
        args : dict
            ``model.args(...)``.
        throw : bool
            Raise :class:`~lobattodae.NewtonFailure` when a step fails (default), or return the
            computed prefix with ``success`` False.
        **options
            The other keywords of :func:`lobattodae.solve`.

        Returns
        -------
        Solution
            ``stats`` with the keys of :data:`lobattodae.STATS` (constant steps:
            ``compile_and_run_time`` is the native run's wall time).

        Raises
        ------
        LobattoDAEInputError
            Bad input (named), or initial values off the constraints.
        NewtonFailure
            A step failed and ``throw`` is True.
        """
        from .._options import ConstantSteps, TimeSpan
        from .._validate import CONSISTENCY_TOL

        if (n_steps is None and dt is None) or rtol is not None or atol is not None or options:
            from .._solve import solve

            return solve(self.model.problem, self, t_span, q0, p0, n_steps=n_steps, dt=dt, rtol=rtol, atol=atol,
                         save_every=save_every, lam0=lam0, args=args, throw=throw, **options)
        span = TimeSpan.of(t_span)
        steps = ConstantSteps.over(span, n_steps, dt)
        every = _stride(save_every, steps.n)
        r = self._call(span.t0, steps.h, steps.n, every, q0, p0, lam0, args)
        scale = 1.0 + float(np.max(np.abs(r.q[0]))) + float(np.max(np.abs(r.p[0])))
        if not r.phi[0] <= CONSISTENCY_TOL * scale:
            raise InconsistentInitialValuesError(
                f"the initial values violate the constraints: ‖φ(t0, q0, p0)‖∞ = {r.phi[0]:.3e} > "
                f"{CONSISTENCY_TOL:.1e}·(1 + ‖q0‖∞ + ‖p0‖∞). Make p0 consistent (model.complete_velocities, then "
                "model.momenta).")
        if self.model.n_holonomic:
            psi = np.asarray(self.model.holonomic_residual(span.t0, r.q[0], args))
            if not float(np.max(np.abs(psi))) <= CONSISTENCY_TOL * scale:
                raise InconsistentInitialValuesError(
                    f"the initial position violates the holonomic constraint: ‖ψ(t0, q0)‖∞ = "
                    f"{float(np.max(np.abs(psi))):.3e}; fix q0 so that ψ(t0, q0) = 0.")
        rows = int(r.stats[4])
        failed = r.result != Result.SUCCESSFUL
        taken = r.stats[3]
        resync = r.resync[1:rows]
        stats = {
            "newton_iterations": r.iterations[1:rows], "residual_norm": r.residual_norm[1:rows],
            "constraint_residual": r.phi[:rows], "multiplier_drift": r.drift[:rows], "lam_resync": resync,
            "lam_resets": int(np.count_nonzero(resync)), "lam_excursions": r.stats[2],
            "max_constraint_residual": r.max_phi, "max_multiplier_drift": r.max_drift, "n_jacobians": r.stats[1],
            "n_newton": r.stats[0], "n_steps": taken, "n_rejected": 0, "h": steps.h, "n_clamped": None,
            "n_roundoff_limited": None, "n_checked": None, "n_failed_solves": None, "n_unresolved": None,
            "failed_step": taken if failed else None, "recoveries": 0, "compile_and_run_time": r.elapsed,
        }
        message = r.result.message
        if failed:
            t_fail = span.t0 + taken * steps.h
            message = f"Step {taken} (t = {t_fail:.6g}, h = {steps.h:.3g}) failed: {r.result.message}"
            if throw:
                raise NewtonFailure(message, step=taken, t=t_fail, reason=r.result.name.lower())
        if self.lam_start == "previous" and r.stats[2]:  # as lobattodae.solve warns
            note = drift_note(r.stats[2], r.max_drift, r.t[1:rows], r.drift[1:rows], span.t0)
            message = f"{message} Warning: {note}"
            warnings.warn(note, RuntimeWarning, stacklevel=2)
        return Solution(r.t[:rows], r.q[:rows], r.p[:rows], r.lam[:rows], not failed, r.result, message, stats,
                        self.model.problem, self.method, args)


class _Run(NamedTuple):
    """What one native run hands back (see :meth:`NativeIntegrator._call`)."""

    t: np.ndarray
    q: np.ndarray
    p: np.ndarray
    lam: np.ndarray
    result: Result
    iterations: np.ndarray
    residual_norm: np.ndarray
    phi: np.ndarray
    drift: np.ndarray
    resync: np.ndarray
    stats: tuple  # Newton iterations, matrices, excursions, steps taken, rows written, steps re-synchronised
    max_phi: float
    max_drift: float
    elapsed: float


def _stride(save_every, n_steps: int) -> int:
    """The stride of the kept step points: ``save_every`` (a positive integer, default 1), or the
    whole run for ``"final"``."""
    if save_every is None:
        return 1
    every = n_steps if isinstance(save_every, str) and save_every == "final" else save_every
    return check_count("save_every", every, "a positive integer or 'final'")
