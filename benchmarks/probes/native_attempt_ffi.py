"""A probe for issue #26 (not part of the library): an error-controlled attempt (the whole step,
the two half steps and the estimate's three vector fields) as one XLA FFI call into the native
step's generated C (``native_attempt_ffi.c`` appended to ``lobattodae.mechanics._native.program_source``),
inside lobattodae's JAX loop; the controller, the share of the estimate (``StepDoubling._share``),
recording and output stay JAX. It replaces ``StepDoubling``'s ``init``, ``step`` and
``after_rejection`` in its own process (the Newton matrices and predictor histories ride in the loop
state as one opaque float64 buffer, taken from the attempt whether it was kept or not; the
compensation is selected like the JAX path's state), so run each mode in a process of its own::

    PYTHONPATH=src .venv/bin/python benchmarks/probes/native_attempt_ffi.py sleigh 1000 5 1e-8 jax
    PYTHONPATH=src .venv/bin/python benchmarks/probes/native_attempt_ffi.py sleigh 1000 5 1e-8 ffi

(``disk`` for the falling disk in general motion). Prints the steps, the time of ``solve``
(best of 9 after a compiling call) and, on the sleigh, the error of q(T); ``benchmarks/RESULTS.md``,
2026-11-29 12:45, has the numbers. Needs gcc and jaxlib's FFI header (``jax.ffi.include_dir()``).
"""
import ctypes, pathlib, subprocess, sys, tempfile, time
from typing import NamedTuple
import numpy as np
import jax, jax.numpy as jnp
import lobattodae as L
from lobattodae import examples, mechanics
from lobattodae.mechanics import _native
from lobattodae import _doubling
from lobattodae._dense import joined, one_piece
from lobattodae._stepper import StepInfo, LamMonitor, as_step_arrays
L.set_cpu_threads(1)

class NState(NamedTuple):
    buf: jax.Array
    comp: jax.Array
    monitor: LamMonitor

def build(model, s):
    src = _native.program_source(model, s) + (pathlib.Path(__file__).with_name("native_attempt_ffi.c")).read_text()
    d = pathlib.Path(tempfile.mkdtemp(prefix="native-attempt-"))
    (d / "a.c").write_text(src); so = d / "a.so"
    r = subprocess.run(["gcc", "-O2", "-fPIC", "-shared", "-I", jax.ffi.include_dir(), "-o", str(so), str(d / "a.c"), "-lm"], capture_output=True, text=True)
    if r.returncode: sys.exit(r.stderr[-3000:])
    lib = ctypes.CDLL(str(so))
    lib.set_tableau.argtypes = [ctypes.POINTER(ctypes.c_double)]; lib.attempt_state_doubles.restype = ctypes.c_long
    tab = _native._tableau(s); lib.set_tableau(tab.ctypes.data_as(ctypes.POINTER(ctypes.c_double)))
    name = f"lobattodae_native_attempt_{id(lib)}"
    jax.ffi.register_ffi_target(name, jax.ffi.pycapsule(lib.lobattodae_native_attempt), platform="cpu")
    return name, int(lib.attempt_state_doubles()), lib, tab

def install(model, s):
    name, size, lib, tab = build(model, s)
    n, m = model.n, model.m
    f64, i32 = jnp.float64, jnp.int32
    def init(self, problem, t0, q0, p0, lam0, args=None, h=None, lam_hidden=None):
        z = jnp.asarray(0.0, f64)
        return NState(jnp.zeros((size,), f64), jnp.zeros((2 * n,), f64),
                      LamMonitor(z, z, jnp.asarray(0, i32), jnp.asarray(10, i32), jnp.asarray(0, i32)))
    def after_rejection(self, kept, new, old):
        return new._replace(comp=jnp.where(kept, new.comp, old.comp))
    def step(self, problem, t0, q0, p0, lam0, h, args=None, state=None):
        t0, q0, p0, lam0, h = as_step_arrays(t0, q0, p0, lam0, h)
        if state is None:
            state = init(self, problem, t0, q0, p0, lam0, args, h)
        k = jnp.stack([jnp.asarray(args[nm], f64) for nm in model.parameters])
        S = self.stages
        sd = jax.ShapeDtypeStruct
        outs = [sd((n,), f64), sd((n,), f64), sd((m,), f64), sd((n,), f64), sd((n,), f64), sd((3, 2 * n), f64),
                sd((4,), i32), sd((), f64), sd((), f64), sd((2, S, n), f64), sd((2, S, n), f64), sd((2, S, m), f64),
                sd((n,), f64), sd((n,), f64), sd((size,), f64), sd((2 * n,), f64)]
        call = jax.ffi.ffi_call(name, outs, vmap_method="sequential")
        sg = jax.lax.stop_gradient
        q1, p1, lam1, qw, pw, fields, ints, resn, drift, V, W, Lm, qh, ph, buf, comp = call(
            sg(t0), sg(h), sg(q0), sg(p0), sg(k), state.buf, jnp.asarray(int(self.method._use_extrapolation), i32),
            jnp.asarray(self.method.max_iterations, i32), state.comp)
        y1 = jnp.concatenate([q1, p1])
        diff = y1 - jnp.concatenate([qw, pw])
        noise = _doubling.NOISE * self.method.tol * (1.0 + jnp.abs(y1))
        share, resolved = self._share(h, diff, fields[1] - fields[0], y1, fields[1] - fields[2])
        error = share * jnp.sign(diff) * jnp.maximum(jnp.abs(diff) - noise, 0.0)
        dense = joined(one_piece(t0, 0.5 * h, q0, p0, V[0], W[0], Lm[0]), one_piece(t0 + 0.5 * h, 0.5 * h, qh, ph, V[1], W[1], Lm[1]))
        info = StepInfo(ints[0], ints[1], resn, ints[2], drift, jnp.asarray(False), error, dense,
                        jnp.where(ints[3] == 1, 0.5, 0.25).astype(f64), share, resolved)
        return q1, p1, lam1, info, NState(buf, comp, state.monitor)
    _doubling.StepDoubling.init = init
    _doubling.StepDoubling.after_rejection = after_rejection
    _doubling.StepDoubling.step = step

if __name__ == "__main__":
    which, T, s, tol = sys.argv[1], float(sys.argv[2]), int(sys.argv[3]), float(sys.argv[4])
    ex = {"sleigh": examples.chaplygin_sleigh, "disk": lambda: examples.falling_rolling_disk(steady=False)}[which]()
    model = {"sleigh": mechanics.systems.chaplygin_sleigh, "disk": mechanics.systems.falling_disk}[which]()
    args = model.args(**ex.args._asdict())
    m = L.LobattoIIIAIIIB(stages=s)
    call = lambda: L.solve(model.problem, m, (0.0, T), ex.q0, ex.p0, args=args, lam0=ex.lam0, rtol=tol, atol=tol, save_every="final")
    def best():
        call()
        return min((lambda t0: (call(), time.perf_counter() - t0)[1])(time.perf_counter()) for _ in range(9))
    mode = sys.argv[5]
    if mode == "ffi":
        install(model, s)
    t0 = time.perf_counter(); sol = call(); first = time.perf_counter() - t0
    tb = best()
    print(mode, sol.result.name, {k: sol.stats[k] for k in ("n_steps", "n_rejected", "n_newton", "n_jacobians")},
          f"run {tb*1e3:.3f} ms (first call {first:.2f} s)")
    if which == "sleigh":
        qref = ex.exact(np.array([T]))[0][0]
        print("error %.2e" % np.max(np.abs(np.asarray(sol.q[-1]) - qref)))
    print("q(T) =", np.asarray(sol.q[-1]).tolist())
