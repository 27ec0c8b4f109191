"""Does the default first fit find the model's best? On the shared synthetic and real
recordings (needs ../shared):

- "paper": the paper's protocol, one search of S, K, C_f and t_c from `initial_model` in the
  fit's default box (P_s at the preset's value);
- "default": `vfjax.fit_recording` (P_s searched, the first fit's box, its restarts, made
  again after 0.2 s where the fit at the default warm-up is not settled);
- "best of N": N independent restarts (another key, none culled) in a box wider than the default's
  (K and C_f ×/÷ 20 and 200, t_c from 0 to 6× its start, P_s 500-40 000 dyne/cm²), P_s free,
  after the default fit's warm-up.

Target: default / best-of-N <= 1.05 on every recording. Prints one row per recording.

Run: python benchmarks/restarts.py [--restarts 20]
"""

import argparse
import pathlib
import time

import jax

import vfjax
from vfjax.recording import load_contours

SHARED = pathlib.Path(__file__).resolve().parents[2] / "shared" / "data"
#: the real contour files' frame rates (the data's README)
REAL_FPS = {"MN003_adapt": 8000.0, "FD003_pre": 8000.0, "FN003": 8000.0, "FP005_naso": 4000.0}
WIDE = {"K": (0.05, 20.0), "C_f": (0.005, 200.0)}


def recordings():
    for name in ("syn_base", "syn_gap", "syn_tremor"):
        yield vfjax.load_recording(SHARED / "synthetic" / f"{name}.csv")
    for name, fps in REAL_FPS.items():
        yield load_contours(SHARED / "real" / f"{name}_segdata.txt", fps)


def reference_box(model):
    p = {n: float(v) for n, v in model.params().items()}
    box = {n: (a * p[n], b * p[n]) for n, (a, b) in WIDE.items()}
    box["t_c"] = (0.0, 6.0 * p["t_c"])
    box["P_s"] = (500.0, 40000.0)
    return box


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--restarts", type=int, default=20, help="restarts of the reference")
    args = parser.parse_args()
    print(
        "| recording | paper protocol | default (s) | its warm-up | restarts' spread | "
        f"best of {args.restarts} (s) | default / best | P_s default, best (dyne/cm²) |"
    )
    print("|---|---|---|---|---|---|---|---|")
    worst = 0.0
    for rec in recordings():
        model = vfjax.initial_model(rec)
        paper = vfjax.fit(model, rec, ("S", "K", "C_f", "t_c"), progress=False)
        vfjax.fit_recording(rec, model, progress=False)  # compile first: time a warm fit
        t = time.perf_counter()
        default = vfjax.fit_recording(rec, model, progress=False)
        t_default = time.perf_counter() - t
        names = ("S", "K", "C_f", "t_c", "P_s")
        t = time.perf_counter()
        runs = vfjax.fit(
            model,
            rec,
            names,
            bounds=reference_box(model),
            restarts=args.restarts,
            swarm=vfjax.Swarm(cull_at=0),  # every restart searched to its end
            key=jax.random.key(2026),
            warmup=default.sampling.warmup,
            progress=False,
        )
        t_best = time.perf_counter() - t
        ratio = default.nmse / runs.nmse
        worst = max(worst, ratio)
        spread = [v for v in default.restart_nmse if v is not None]
        print(
            f"| {rec.name} | {paper.nmse:.4%} | {default.nmse:.4%} ({t_default:.1f}) | "
            f"{default.sampling.warmup * 1e3:.0f} ms | "
            f"{min(spread):.4%}-{max(spread):.4%} | {runs.nmse:.4%} ({t_best:.0f}) | "
            f"{ratio:.3f} | {default.params['P_s']:.0f}, {runs.params['P_s']:.0f} |",
            flush=True,
        )
    print(f"worst default / best: {worst:.3f} (target <= 1.05)")


if __name__ == "__main__":
    main()
