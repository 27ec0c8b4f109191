"""Do the first fits describe a sustained oscillation? On the shared synthetic and real
recordings (needs ../shared): the first fit at the default 20 ms warm-up
(`vfjax.fit_recording(..., settle=False)`) and `vfjax.settling` of it (the fitted model after
0.2 s); then the default first fit (`vfjax.fit_recording`, made again after 0.2 s where the
20 ms fit is not settled), its warm-up, and its settling after twice that warm-up (at least
0.2 s). Prints one row per recording.

Run: python benchmarks/settling.py
"""

import pathlib
import time

import vfjax
from vfjax.recording import load_contours

SHARED = pathlib.Path(__file__).resolve().parents[2] / "shared" / "data"
#: the real contour files' frame rates (the data's README)
REAL_FPS = {"MN003_adapt": 8000.0, "FD003_pre": 8000.0, "FN003": 8000.0, "FP005_naso": 4000.0}


def recordings():
    folder = SHARED / "synthetic"
    for name in ("syn_base", "syn_gap", "syn_tremor"):
        yield vfjax.load_recording(folder / f"{name}.csv")
    for name, fps in REAL_FPS.items():
        yield load_contours(SHARED / "real" / f"{name}_segdata.txt", fps=fps)


def _row(fit, check):
    mark = "settled" if check.settled else "not settled"
    return f"{fit.nmse:.3%} | {check.nmse:.3%} ({mark})"


def main():
    print(
        "| recording | noise floor | first fit (20 ms) | after 0.2 s | default first fit: "
        "warm-up | its NMSE | after twice the warm-up | P_s (20 ms / default) | wall (s) |"
    )
    print("|---|---|---|---|---|---|---|---|---|")
    for rec in recordings():
        t0 = time.perf_counter()
        short = vfjax.fit_recording(rec, settle=False, progress=False)
        short_check = vfjax.settling(short, rec)
        first = vfjax.fit_recording(rec, progress=False)
        wall = time.perf_counter() - t0
        check = vfjax.settling(first, rec)
        print(
            f"| {rec.name} | {short_check.noise_nmse:.3%} | {_row(short, short_check)} | "
            f"{first.sampling.warmup * 1e3:.0f} ms | {_row(first, check)} | "
            f"{short.params['P_s']:.0f} / {first.params['P_s']:.0f} | {wall:.0f} |",
            flush=True,
        )


if __name__ == "__main__":
    main()
