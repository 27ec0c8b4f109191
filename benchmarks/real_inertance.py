"""Does an inertive vocal tract explain the real glottises? On the shared real contour
recordings (needs ../shared): the first fit (`vfjax.fit_recording`), then one calibrated
diagnosis (`vfjax.diagnose`, its defaults) offered the catalogue's candidates and
`vfjax.SourceTractInertance`. Prints per recording the first fit's NMSE, the ranking, the
effects needed, each candidate's refit (NMSE, sizes, calibrated p-value), the verdict and the
wall time.

Run: python benchmarks/real_inertance.py [NAME ...]   (default: every real recording)
"""

import argparse
import pathlib
import time

import vfjax
from vfjax.diagnosis import default_candidates
from vfjax.recording import load_contours

SHARED = pathlib.Path(__file__).resolve().parents[2] / "shared" / "data"
#: the real contour files' frame rates (the data's README)
REAL_FPS = {"MN003_adapt": 8000.0, "FD003_pre": 8000.0, "FN003": 8000.0, "FP005_naso": 4000.0}


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("names", nargs="*", default=list(REAL_FPS), choices=list(REAL_FPS))
    args = ap.parse_args()
    for name in args.names:
        rec = load_contours(SHARED / "real" / f"{name}_segdata.txt", REAL_FPS[name])
        t0 = time.perf_counter()
        first = vfjax.fit_recording(rec, progress=False)
        candidates = default_candidates(first.model) + [vfjax.SourceTractInertance]
        d = vfjax.diagnose(first, rec, candidates)
        print(
            f"{name}: first fit NMSE {first.nmse:.3%}; ranking {d.ranking}; needed {d.needed}; "
            f"{time.perf_counter() - t0:.0f} s",
            flush=True,
        )
        for effect, refit in d.refits.items():
            sizes = ", ".join(f"{k} {v:.4g}" for k, v in refit.values.items())
            print(
                f"  {effect:22s} NMSE {refit.result.nmse:.3%}  {sizes}  p {refit.p_value:.3g}",
                flush=True,
            )
        print(f"  {d.verdict}", flush=True)


if __name__ == "__main__":
    main()
