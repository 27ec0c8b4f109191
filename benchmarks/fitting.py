"""Fitting benchmarks, all on the same recordings in one run.

a) the hybrid (PSO 60 iterations + Levenberg-Marquardt) against PSO alone for 1000 iterations,
   as in the paper: the cost each reaches, its wall time, and when the hybrid first came
   within 1 % of the PSO-1000 cost ("reach", from the hybrid's timed trace);
b) pyswarms' GlobalBestPSO with a NumPy objective (the model simulated by the numba loop at the
   paper's step, the time shift and S profiled out as in vfjax), same swarm and iterations as
   the hybrid's swarm stage;
c) wall time of one fit after compilation, and the compile time;
d) `fit_many` on 8 recordings against a loop of `fit`: fits per minute.

Recordings: the shared syn_base (needs ../shared), vfjax's demo recording (N3, 2 px noise) and
an N2 simulation with 2 px noise at an arbitrary start.

Run: python benchmarks/fitting.py [--pso-iterations 1000]
"""

import argparse
import pathlib
import sys
import time

import jax
import numpy as np

import vfjax
from vfjax import Swarm, fit, fit_many, initial_model
from vfjax.datasets import demo_recording

sys.path.insert(0, str(pathlib.Path(__file__).parent))
SHARED = pathlib.Path(__file__).resolve().parents[2] / "shared"
PARAMS = ("S", "K", "C_f")


def recordings():
    out = []
    base = SHARED / "data" / "synthetic" / "syn_base.csv"
    if base.exists():
        out.append(vfjax.load_recording(base))
    out.append(demo_recording("N3"))
    n2 = demo_recording("N2", seed=5)
    out.append(vfjax.Recording(n2.area, n2.fps, metadata=n2.metadata, name="sim_N2"))
    return out


def numpy_objective(recording, model, warmup, max_shift):
    """The cost of a swarm (n, 3) of log-factors of S, K, C_f, as a Python user would write
    it: numba simulation per particle at the paper's step, shift grid and S projection in
    NumPy."""
    from numba_reference import simulate_gaw

    p = {k: float(v) for k, v in model.params().items()}
    fps, n = recording.fps, recording.n_frames
    w, m = int(round(warmup * fps)), int(np.ceil(max_shift * fps))
    a = recording.area
    energy = np.sum(a * a)

    def cost(z):
        out = np.empty(len(z))
        for i, (_, lk, lc) in enumerate(z):
            g = simulate_gaw(
                p["K"] * np.exp(lk),
                p["C_f"] * np.exp(lc),
                1.0,
                p["t_c"],
                p["P_s"],
                p["M"],
                p["l"],
                fps,
                w + m + n,
                128,
            )
            g = np.clip(g, 0, None)
            windows = np.lib.stride_tricks.sliding_window_view(g[w:], n)[: m + 1]
            s = windows @ a / np.maximum(np.sum(windows * windows, axis=1), 1e-300)
            out[i] = np.min(np.sum((a - s[:, None] * windows) ** 2, axis=1)) / energy
        return out

    return cost


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--pso-iterations", type=int, default=1000)
    args = ap.parse_args()
    recs = recordings()
    print(f"recordings: {[r.name for r in recs]}; fitted: {PARAMS}")

    # c) compile once, then time
    model0 = initial_model(recs[0])
    t0 = time.perf_counter()
    first = fit(model0, recs[0], params=PARAMS, progress=False)
    t_first = time.perf_counter() - t0
    print(f"\nc) first fit, compilation included: {t_first:.1f} s")
    del first

    print(
        f"\na) hybrid (48 particles x 60 iterations + LM) vs PSO alone, "
        f"{args.pso_iterations} iterations"
    )
    # "PSO NMSE": the swarm's own best cost (with the shift on its half-frame grid);
    # "re-sim.": the NMSE at that point with the shift as fitted (`FitResult.nmse`)
    head = f"{'recording':12s} {'PSO NMSE':>11s} {'re-sim.':>11s} {'PSO s':>8s} "
    print(head + f"{'hybrid NMSE':>12s} {'hybrid s':>9s} {'reach s':>8s} {'ratio':>6s}  reached?")
    hybrid_times = []
    for rec in recs:
        model = initial_model(rec)
        fit(model, rec, params=PARAMS, progress=False)  # compile for this recording's shapes
        t0 = time.perf_counter()
        h = fit(model, rec, params=PARAMS, progress=False)
        th = time.perf_counter() - t0
        hybrid_times.append(th)
        long = Swarm(iterations=args.pso_iterations, chunk=50)
        fit(model, rec, params=PARAMS, swarm=Swarm(iterations=50, chunk=50), polish=None)
        t0 = time.perf_counter()
        p = fit(model, rec, params=PARAMS, swarm=long, polish=None, progress=False)
        tp = time.perf_counter() - t0
        # when the hybrid's best first came within 1 % of the PSO-1000 cost
        trace = np.r_[h.pso_trace, h.lm_trace]
        swarm_best = p.pso_trace[-1]
        hit = np.flatnonzero(trace <= 1.01 * swarm_best)
        reach = h.trace_times[hit[0]] if hit.size else float("nan")
        print(
            f"{rec.name:12s} {swarm_best:11.4e} {p.nmse:11.4e} {tp:8.1f} {h.nmse:12.4e} "
            f"{th:9.1f} {reach:8.2f} {reach / tp:6.3f}  {bool(hit.size)}"
        )

    print(f"\nc) one fit after compilation: {min(hybrid_times):.1f} to {max(hybrid_times):.1f} s")

    print(
        "\nb) pyswarms GlobalBestPSO (NumPy objective with the numba model at k = 128),"
        " 48 particles x 60 iterations, same search box (S, shift profiled out)"
    )
    import pyswarms as ps

    for rec in recs:
        model = initial_model(rec)
        h = fit(model, rec, params=PARAMS, progress=False)
        cost = numpy_objective(rec, model, h.sampling.warmup, h.sampling.max_time_shift)
        lo = np.log([0.1, 0.25, 0.05])
        hi = np.log([10.0, 4.0, 20.0])
        opt = ps.single.GlobalBestPSO(
            n_particles=48,
            dimensions=3,
            bounds=(lo, hi),
            options={"c1": 1.49618, "c2": 1.49618, "w": 0.7298},
            init_pos=None,
        )
        cost(np.zeros((1, 3)))  # numba compile
        np.random.seed(0)  # noqa: NPY002  (pyswarms draws from the global NumPy RNG)
        t0 = time.perf_counter()
        best, _ = opt.optimize(cost, iters=60, verbose=False)
        tps = time.perf_counter() - t0
        print(
            f"{rec.name:12s} pyswarms NMSE {best:.4e} in {tps:.1f} s; vfjax hybrid NMSE "
            f"{h.nmse:.4e} in {h.timings['total_s']:.1f} s"
        )

    print("\nd) many recordings: fit_many against a loop of fit (8 recordings of the demo kind)")
    many = [demo_recording("N3", seed=s) for s in range(8)]
    many = [
        vfjax.Recording(r.area, r.fps, metadata=r.metadata, name=f"demo{s}")
        for s, r in enumerate(many)
    ]
    start = initial_model(many[0], template="N4")
    fit_many(start, many[:8], params=PARAMS)  # compile
    t0 = time.perf_counter()
    res = fit_many(start, many, params=PARAMS)
    t_many = time.perf_counter() - t0
    fit(start, many[0], params=PARAMS, progress=False)  # compile
    t0 = time.perf_counter()
    loop = [fit(start, r, params=PARAMS, progress=False) for r in many]
    t_loop = time.perf_counter() - t0
    print(
        f"fit_many: {60 * len(many) / t_many:.1f} fits/min ({t_many:.1f} s); "
        f"loop of fit: {60 * len(many) / t_loop:.1f} fits/min ({t_loop:.1f} s)"
    )
    print(
        f"median NMSE fit_many {np.median([r.nmse for r in res]):.3e}, "
        f"loop {np.median([r.nmse for r in loop]):.3e}"
    )
    print(f"jax {jax.__version__}")


if __name__ == "__main__":
    main()
