"""Injection-recovery of cycle-to-cycle variability: is it found, and is its size right?

Recordings made by vfjax (401 frames at 4 kHz, 1 px noise, rounded and clipped at 0): the
paper's model for a male (N1) and a female (N3) subject with per-cycle timing offsets
(`TimingJitter`, 0.1 ms standard deviation), amplitude factors (`AmplitudeJitter`, 5 %), both,
or neither, seeds 0-2. Each is fitted as the command line does (`vfjax.fit_recording`, a model
without variability), then tested and sized as `vfjax.diagnose` does
(`vfjax.diagnosis.CycleVariability`, 99 white-noise recordings). Per recording: the p-value,
the spreads found with their 95 % intervals, and the spreads drawn over the cycles the
diagnosis counts (those whose whole support lies inside the recording), which are what it
can recover.

Run: python benchmarks/variability_recovery.py [--presets N1 N3] [--seeds 0 1 2]
"""

import argparse
import time

import numpy as np

import vfjax
from vfjax._diagnosis._cycles import variability_test
from vfjax._diagnosis._nulls import _NullSource
from vfjax._diagnosis._statistic import _fit_point
from vfjax._fit._problem import prepare

FPS, FRAMES, NOISE_PX = 4000.0, 401, 1.0
FIRST = 0.0277  # demo_recording's first frame (s)
CASES = {"timing": (1e-4, 0.0), "amplitude": (0.0, 0.05), "both": (1e-4, 0.05), "none": (0, 0)}


def _drawn(values, period, trend: bool) -> float:
    """The deviation of the drawn per-slot values over the counted cycles, about a line
    (``trend``, the offsets: a trend is a change of period) or their mean."""
    middles = (np.arange(len(values)) + 0.5) * period
    last = FIRST + (FRAMES - 1) / FPS
    v = np.asarray(values)[(middles >= FIRST + period) & (middles <= last - period)]
    x = np.arange(v.size)
    centre = np.polyval(np.polyfit(x, v, 1), x) if trend else v.mean()
    return float(np.sqrt(np.sum((v - centre) ** 2) / (v.size - (2 if trend else 1))))


def run(preset: str, case: str, seed: int) -> dict:
    sd_t, sd_a = CASES[case]
    model = vfjax.preset(preset)
    clean = np.asarray(vfjax.simulate(model, FPS, 400, t_start=0.02).area)
    period = 1.0 / vfjax.descriptors.fundamental_frequency(clean, FPS)
    drawn = {}
    if sd_t > 0:
        term = vfjax.TimingJitter.random(sd_t, period, duration=0.3, seed=10 * seed + 7)
        model = model.with_term(term)
        drawn["timing"] = _drawn(term.offsets, period, True)
    if sd_a > 0:
        term = vfjax.AmplitudeJitter.random(sd_a, period, duration=0.3, seed=10 * seed + 8)
        model = model.with_term(term)
        drawn["amplitude"] = _drawn(term.factors, period, False)
    rec = vfjax.datasets.demo_recording(preset, NOISE_PX, seed, FPS, FRAMES, model=model)
    fit = vfjax.fit_recording(rec, progress=False)
    t0 = time.perf_counter()
    measured = 1.0 / vfjax.descriptors.fundamental_frequency(fit.fitted_gaw(rec), FPS)
    own = prepare(fit.model, rec, tuple(fit.params), fit.sampling, measured, None)[0]
    source = _NullSource(own, fit.model, fit.time_shift, rec, measured, seed=0)
    jittered = prepare(source.model, rec, tuple(fit.params), fit.sampling, measured, None)[0]
    found = variability_test(source, jittered, _fit_point(jittered, fit), 99, 0.95)
    return {
        "preset": preset,
        "case": case,
        "seed": seed,
        "found": found,
        "drawn": drawn,
        "fit_nmse": fit.nmse,
        "seconds": time.perf_counter() - t0,
    }


def _row(r) -> str:
    f = r["found"]
    t, a = r["drawn"].get("timing"), r["drawn"].get("amplitude")
    lo_t, hi_t = f.timing_interval
    lo_a, hi_a = f.amplitude_interval
    return (
        f"| {r['preset']} | {r['case']} | {r['seed']} | {f.p_value:.2g} | {f.cycles} | "
        f"{'-' if t is None else f'{1e3 * t:.3f}'} | "
        f"{1e3 * f.timing_sd:.3f} [{1e3 * lo_t:.3f}, {1e3 * hi_t:.3f}] | "
        f"{'-' if a is None else f'{a:.1%}'} | "
        f"{f.amplitude_sd:.1%} [{lo_a:.1%}, {hi_a:.1%}] | {f.fall:.0%} | {r['seconds']:.1f} |"
    )


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--presets", nargs="+", default=["N1", "N3"])
    parser.add_argument("--seeds", nargs="+", type=int, default=[0, 1, 2])
    parser.add_argument("--cases", nargs="+", default=list(CASES))
    args = parser.parse_args()
    print(
        "| subject | hidden | seed | p | cycles | timing drawn (ms) | found [95 %] | "
        "amplitude drawn | found [95 %] | fall | s |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for preset in args.presets:
        for case in args.cases:
            for seed in args.seeds:
                print(_row(run(preset, case, seed)), flush=True)


if __name__ == "__main__":
    main()
