"""The Whipple bicycle benchmark (Meijaard, Papadopoulos, Ruina & Schwab 2007) with lobattodae.

Builds the nonlinear model (:func:`lobattodae.mechanics.bicycle.whipple_bicycle`), linearises
it about upright rolling with JAX derivatives, compares the benchmark matrices, the eigenvalues
at 5 m/s and the weave and capsize speeds with the published values (MPRS eq. 5.4 and Table 2),
plots the eigenvalues against the speed (``docs/figures/bicycle-eigenvalues.png``, as MPRS
Fig. 3) and integrates the nonlinear model (s = 4, constant steps) from a roll-rate perturbation
at a self-stable speed and at a speed below the weave speed, reporting the constraint residuals
at every step, the energy error and the weave mode's decay or growth rate.

    .venv/bin/python docs/examples/bicycle_benchmark.py [--no-figure] [--no-runs]
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

import lobattodae
from lobattodae.mechanics import bicycle as bike

# MPRS = Meijaard et al., Proc. R. Soc. A 463 (2007) 1955-1982, doi:10.1098/rspa.2007.1857.
# Eq. (5.4) / Table 2, 14 decimals, as quoted e.g. by SymPy's bicycle example
# (doc/src/modules/physics/mechanics/examples/bicycle_example.rst) and BicycleParameters.
PUBLISHED = {
    "M": [[80.81722, 2.31941332208709], [2.31941332208709, 0.29784188199686]],
    "C1": [[0.0, 33.86641391492494], [-0.85035641456978, 1.68540397397560]],
    "K0": [[-80.95, -2.59951685249872], [-2.59951685249872, -0.80329488458618]],
    "K2": [[0.0, 76.59734589573222], [0.0, 2.65431523794604]],
    "eig5": [-14.07838969279822, -0.77534188219585 - 4.46486771378823j,
             -0.77534188219585 + 4.46486771378823j, -0.32286642900409],
    "weave": 4.29238253634111,
    "capsize": 6.02426201538837,
}


def digits(ours, ref):
    """Significant digits of agreement, -log10 of the relative error (17 when equal)."""
    err = abs(ours - ref) / abs(ref)
    return 17.0 if err == 0 else -np.log10(err)


def modal_rate(model, sol, v, args):
    """Growth rate of the weave mode along a nonlinear run: the modal coordinate
    c(t) = l·x(t) (l the left eigenvector of the linear state matrix for the weave eigenvalue
    with Im > 0, x = (roll, steer, roll rate, steer rate)), and the slope of log|c| fitted
    over the run."""
    A = bike.state_matrix(model, v, args)
    ev, L = np.linalg.eig(A.T)  # left eigenvectors of A
    k = int(np.argmax(np.where(np.abs(ev.imag) > 1e-9, ev.imag, -np.inf)))
    qdot = np.asarray(model.velocities(sol.t, sol.q, sol.p, args))
    x = np.column_stack([sol.q[:, 3], sol.q[:, 5], qdot[:, 3], qdot[:, 5]])
    c = x @ L[:, k]
    slope = np.polyfit(sol.t, np.log(np.abs(c)), 1)[0]
    return slope, ev[k]


def nonlinear_run(model, v, args, T, h=0.01, stages=4, roll_rate=0.5):
    q0, p0 = bike.upright_state(model, v, args, roll_rate=roll_rate)
    n = int(round(T / h))
    t0 = time.perf_counter()
    sol = lobattodae.solve(model.problem, lobattodae.LobattoIIIAIIIB(stages=stages), (0.0, T), q0, p0,
                           n_steps=n, args=args)
    wall = time.perf_counter() - t0
    phi = np.abs(model.constraint_residual(sol.t, sol.q, sol.p, args)).max(axis=1)
    psi = np.abs(model.holonomic_residual(sol.t, sol.q, args)).max(axis=1)
    H = model.energy(sol.t, sol.q, sol.p, args)
    return sol, dict(v=v, T=T, h=h, steps=n, stages=stages, wall=wall, phi=phi.max(), psi=psi.max(),
                     dH=np.abs(H - H[0]).max(), H0=H[0], roll_max=np.abs(sol.q[:, 3]).max(),
                     steer_max=np.abs(sol.q[:, 5]).max(),
                     roll_end=np.abs(sol.q[-int(1.0 / h):, 3]).max(), steer_end=np.abs(sol.q[-int(1.0 / h):, 5]).max())


def main(argv=None) -> dict:
    """Run the comparison (and, unless switched off, the figure and the nonlinear runs);
    print it all and return the numbers: ``"matrices"`` (name -> ours), ``"eig5"`` (ours at
    5 m/s), ``"weave"``, ``"capsize"`` (m/s) and ``"runs"`` (one dict per nonlinear run, the
    keys of :func:`nonlinear_run` plus ``"rate"`` and ``"lam_w"``)."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--no-figure", action="store_true")
    parser.add_argument("--no-runs", action="store_true")
    opts = parser.parse_args(argv)
    t0 = time.perf_counter()
    model = bike.whipple_bicycle()
    args = model.args()
    print(f"model built in {time.perf_counter() - t0:.1f} s: {model.n} coordinates, {model.m} multipliers")

    t0 = time.perf_counter()
    mats = bike.linearize(model, args)
    results = {"matrices": {}, "runs": []}
    print(f"linearised in {time.perf_counter() - t0:.1f} s (first call: compilation included)")
    for name in ("M", "C1", "K0", "K2"):
        ours, ref = getattr(mats, name), np.array(PUBLISHED[name])
        results["matrices"][name] = np.asarray(ours)
        err = np.abs(ours - ref).max()
        print(f"{name}: max |ours - published| = {err:.2e}")
        print(np.array2string(ours, precision=14, floatmode="fixed"))
    ev = bike.eigenvalues(model, 5.0, args)
    results["eig5"] = np.asarray(ev)
    print("eigenvalues at v = 5 m/s (ours | published | digits)")
    ref = np.array(PUBLISHED["eig5"])
    for e in ev:
        r = ref[np.argmin(np.abs(ref - e))]
        print(f"  {e.real:+.15f} {e.imag:+.15f}i | {r.real:+.14f} {r.imag:+.14f}i | {digits(e, r):.1f}")
    t0 = time.perf_counter()
    vw, vc = bike.weave_capsize_speeds(model, args)
    results["weave"], results["capsize"] = vw, vc
    print(f"weave speed   {vw:.15f} (published {PUBLISHED['weave']}, {digits(vw, PUBLISHED['weave']):.1f} digits)")
    print(f"capsize speed {vc:.15f} (published {PUBLISHED['capsize']}, {digits(vc, PUBLISHED['capsize']):.1f} digits)"
          f" [{time.perf_counter() - t0:.2f} s]")

    if not opts.no_figure:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        speeds = np.linspace(0.0, 10.0, 501)
        eigs = np.array([bike.eigenvalues(model, v, args) for v in speeds])
        fig, ax = plt.subplots(figsize=(7, 5))
        for k in range(4):
            ax.plot(speeds, eigs[:, k].real, ".", ms=2, color="C0")
            im = np.abs(eigs[:, k].imag)
            ax.plot(speeds, np.where(im > 0, im, np.nan), ".", ms=2, color="C1")
        ax.plot([], [], ".", color="C0", label="Re λ")
        ax.plot([], [], ".", color="C1", label="|Im λ|")
        ax.axvspan(vw, vc, color="0.9", label=f"self-stable: {vw:.4f} < v < {vc:.4f} m/s")
        ax.axhline(0.0, color="k", lw=0.5)
        ax.set_xlim(0, 10)
        ax.set_ylim(-10, 10)
        ax.set_xlabel("forward speed v [m/s]")
        ax.set_ylabel("eigenvalues [1/s]")
        ax.set_title("Whipple benchmark bicycle (MPRS Fig. 3), from the nonlinear model")
        ax.legend(loc="lower left")
        out = Path(__file__).resolve().parents[1] / "figures" / "bicycle-eigenvalues.png"
        fig.savefig(out, dpi=120, bbox_inches="tight")
        print(f"figure: {out}")

    if not opts.no_runs:
        # One step count for all runs: the compiled loop is reused.
        # At 3 m/s the weave grows about 4.5-fold per second: a smaller kick and a shorter run
        # keep the bicycle from falling over (the knife-edge model breaks down when it does).
        for v, T, kick in ((5.0, 10.0, 0.5), (4.6, 10.0, 0.5), (3.0, 2.5, 0.005)):
            sol, r = nonlinear_run(model, v, args, T, h=T / 1000, roll_rate=kick)
            rate, lam_w = modal_rate(model, sol, v, args)
            results["runs"].append(dict(r, rate=rate, lam_w=lam_w, kick=kick))
            print(f"v = {v}, roll rate {kick} rad/s: s = {r['stages']}, h = {r['h']}, {r['steps']} steps on [0, {T}] in {r['wall']:.1f} s "
                  f"(first run of a shape: compilation included); max over the steps ‖φ‖∞ = {r['phi']:.2e}, "
                  f"|ψ| = {r['psi']:.2e}, |H - H0| = {r['dH']:.2e} (H0 = {r['H0']:.4f} J); max |roll| = "
                  f"{r['roll_max']:.4f}, max |steer| = {r['steer_max']:.4f}; over the last second |roll| <= "
                  f"{r['roll_end']:.2e}, |steer| <= {r['steer_end']:.2e}; weave modal rate {rate:+.4f} 1/s "
                  f"(linear: Re λ_w = {lam_w.real:+.4f})")
    return results


if __name__ == "__main__":
    main()
