"""Do the first fits describe a sustained oscillation? On the shared synthetic and real
recordings (needs ../shared): the default first fit (`vfjax.fit_recording`, its 20 ms
warm-up) and `vfjax.settling` of it (the fitted model after 0.2 s); then the first fit made
with a 0.2 s warm-up and its settling after 0.4 s. Prints one row per recording.

Run: python benchmarks/settling.py
"""

import pathlib
import time

import vfjax
from vfjax.recording import load_contours

SHARED = pathlib.Path(__file__).resolve().parents[2] / "shared" / "data"
#: the real contour files' frame rates (the data's README)
REAL_FPS = {"MN003_adapt": 8000.0, "FD003_pre": 8000.0, "FN003": 8000.0, "FP005_naso": 4000.0}
LONG = 0.2  # s


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
        f"| recording | noise floor | first fit (20 ms) | after {LONG:g} s | first fit "
        f"({LONG:g} s) | after {2 * LONG:g} s | P_s (20 ms / {LONG:g} s) | wall (s) |"
    )
    print("|---|---|---|---|---|---|---|---|")
    for rec in recordings():
        t0 = time.perf_counter()
        short = vfjax.fit_recording(rec, progress=False)
        short_check = vfjax.settling(short, rec, warmup_s=LONG)
        long = vfjax.fit_recording(rec, warmup=LONG, progress=False)
        long_check = vfjax.settling(long, rec, warmup_s=2 * LONG)
        print(
            f"| {rec.name} | {short_check.noise_nmse:.3%} | {_row(short, short_check)} | "
            f"{_row(long, long_check)} | {short.params['P_s']:.0f} / {long.params['P_s']:.0f} "
            f"| {time.perf_counter() - t0:.0f} |",
            flush=True,
        )


if __name__ == "__main__":
    main()
