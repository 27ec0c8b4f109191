"""The compiled engine: wall times, compilations, batching.

a) `vfjax diagnose` of the shared syn_gap and syn_base, each from a fresh process, with a
   cold compilation cache (an empty folder) and then warm (the same folder again);
b) recordings of five lengths (101 to 2001 frames) and three frame rates diagnosed in one
   process (`vfjax.investigate`, one round): compilations per recording, counted from JAX's
   compile events, and the total time;
c) `fit_many` of 16 recordings against a loop of `fit` over them (fits per minute), one
   compiled fit's wall time, and the swarm's and the polish's share of each;
d) one calibrated diagnosis (`vfjax.diagnose` of the first fit, default settings) of the
   shared syn_gap and syn_base, timed apart from the first fit, in a fresh process with a
   cold compilation cache and then warm, with the CPU devices of --cores (default: every
   core, as the command line uses).

Run: python benchmarks/engine.py [--only a|b|c|d] [--quick]
"""

import argparse
import json
import os
import pathlib
import subprocess
import sys
import tempfile
import time

import jax
import numpy as np

import vfjax
from vfjax.cli import use_cpu_cores

SHARED = pathlib.Path(__file__).resolve().parents[2] / "shared"
COMPILE_EVENT = "/jax/core/compile/backend_compile_duration"


def fresh_env(cache: str, devices: int) -> dict:
    """The environment of a fresh process with the compilation cache in ``cache`` and
    ``devices`` CPU devices, as the command line reads them."""
    env = {**os.environ, "VFJAX_CACHE_DIR": cache, "VFJAX_CORES": str(devices)}
    env.pop("VFJAX_NO_CACHE", None)
    return env


def cli_diagnose(name: str, cache: str, devices: int) -> tuple[float, int, str]:
    """Wall time, exit code and verdict line of `vfjax diagnose` in a fresh process."""
    with tempfile.TemporaryDirectory() as out:
        env = fresh_env(cache, devices)
        t0 = time.perf_counter()
        proc = subprocess.run(
            [
                sys.executable,
                "-m",
                "vfjax",
                "diagnose",
                str(SHARED / "data" / "synthetic" / f"{name}.csv"),
                "--out",
                os.path.join(out, "d"),
            ],
            capture_output=True,
            text=True,
            env=env,
        )
        wall = time.perf_counter() - t0
    verdicts = [x for x in proc.stdout.splitlines() if x.startswith(f"{name}: ")]
    return wall, proc.returncode, verdicts[-1] if verdicts else proc.stderr[-300:]


def part_a(devices: int):
    print("a) vfjax diagnose from a fresh process (wall s; cold cache, then warm)")
    for name in ("syn_gap", "syn_base"):
        with tempfile.TemporaryDirectory() as cache:
            cold, rc1, verdict1 = cli_diagnose(name, cache, devices)
            warm, rc2, verdict2 = cli_diagnose(name, cache, devices)
        print(f"  {name}: cold {cold:.1f} s (exit {rc1}), warm {warm:.1f} s (exit {rc2})")
        print(f"    verdict: {verdict2}")
        if verdict1 != verdict2:
            print(f"    cold verdict differs: {verdict1}")


#: Part d's fresh process: the devices and compilation cache of `fresh_env`, as the command
#: line takes them, the first fit of the recording argv[1] as `vfjax diagnose` makes it, then
#: one diagnosis.
_ONE_DIAGNOSIS = """
import json, os, sys, time
from vfjax.cli import use_compilation_cache, use_cpu_cores
use_cpu_cores(int(os.environ["VFJAX_CORES"]))
use_compilation_cache()
import vfjax
t0 = time.perf_counter()
rec = vfjax.load_recording(sys.argv[1])
first = vfjax.fit_recording(rec, vfjax.initial_model(rec))
t1 = time.perf_counter()
d = vfjax.diagnose(first, rec)
t2 = time.perf_counter()
print(json.dumps({"fit": t1 - t0, "diagnosis": t2 - t1, "needed": d.needed,
                  "null": d.calibrated.replicates, "p": min(f.p_value for f in d.refits.values())}))
"""


def part_d(devices: int):
    print("d) one calibrated diagnosis of the first fit, fresh process (s; cold cache, then warm)")
    for name in ("syn_gap", "syn_base"):
        path = SHARED / "data" / "synthetic" / f"{name}.csv"
        with tempfile.TemporaryDirectory() as cache:
            for label in ("cold", "warm"):
                t0 = time.perf_counter()
                proc = subprocess.run(
                    [sys.executable, "-c", _ONE_DIAGNOSIS, str(path)],
                    capture_output=True,
                    text=True,
                    env=fresh_env(cache, devices),
                )
                wall = time.perf_counter() - t0
                if proc.returncode:
                    print(f"  {name} {label}: exit {proc.returncode}: {proc.stderr[-300:]}")
                    continue
                r = json.loads(proc.stdout.strip().splitlines()[-1])
                print(
                    f"  {name} {label}: diagnosis {r['diagnosis']:.1f} s (first fit "
                    f"{r['fit']:.1f} s, process {wall:.1f} s); needed {r['needed']} against "
                    f"{r['null']} null recordings, smallest p {r['p']:.3g}"
                )


def _counter():
    seen = []
    jax.monitoring.register_event_duration_secs_listener(
        lambda event, duration, **kw: seen.append(duration) if event == COMPILE_EVENT else None
    )
    return seen


def _recording(n_frames: int, fps: float, seed: int) -> vfjax.Recording:
    """A noisy N3 simulation with a hidden glottal gap, ``n_frames`` at ``fps``."""
    model = vfjax.preset("N3").with_effect(vfjax.GlottalGap(a_gap=0.004))
    sim = vfjax.simulate(model, fps, n_frames, t_start=0.03 + 0.0011 * seed)
    rng = np.random.default_rng(seed)
    area = np.clip(np.asarray(sim.area) + rng.normal(0, 2.0, n_frames), 0, None)
    return vfjax.Recording(area=area, fps=fps, name=f"n{n_frames}_f{int(fps)}")


def part_b(quick: bool):
    cases = [
        (101, 4000.0),
        (101, 8000.0),
        (201, 4000.0),
        (201, 2000.0),
        (501, 4000.0),
        (501, 8000.0),
        (1001, 4000.0),
        (1001, 2000.0),
        (2001, 4000.0),
        (2001, 8000.0),
    ]
    if quick:
        cases = cases[:4]
    print(f"b) {len(cases)} recordings diagnosed in one process (investigate, one round)")
    seen = _counter()
    t_all = time.perf_counter()
    for i, (n, fps) in enumerate(cases):
        rec = _recording(n, fps, i)
        before, t0 = len(seen), time.perf_counter()
        study = vfjax.investigate(rec, rounds=1)
        print(
            f"  {rec.name:12s} bucket {vfjax.length_bucket(n):5d}: {len(seen) - before:4d} "
            f"compilations ({sum(seen[before:]):6.1f} s), {time.perf_counter() - t0:6.1f} s; "
            f"needed {study.rounds[-1].diagnosis.needed}"
        )
    print(f"  total {time.perf_counter() - t_all:.1f} s, {len(seen)} compilations")


def part_c():
    print("c) fit_many of 16 recordings against a loop of fit")
    from vfjax.datasets import demo_recording

    recs = [demo_recording("N3", seed=s) for s in range(16)]
    recs = [vfjax.Recording(r.area, r.fps, name=f"demo{s}") for s, r in enumerate(recs)]
    start = vfjax.initial_model(recs[0], template="N4")
    vfjax.fit_many(start, recs, progress=False)  # compile
    t0 = time.perf_counter()
    many = vfjax.fit_many(start, recs, progress=False)
    t_many = time.perf_counter() - t0
    vfjax.fit(start, recs[0], progress=False)  # compile
    times = []
    loop = []
    for r in recs:
        t0 = time.perf_counter()
        loop.append(vfjax.fit(start, r, progress=False))
        times.append(time.perf_counter() - t0)
    t_loop = sum(times)
    print(
        f"  fit_many: {60 * len(recs) / t_many:.0f} fits/min ({t_many:.1f} s); loop of fit: "
        f"{60 * len(recs) / t_loop:.0f} fits/min ({t_loop:.1f} s); ratio {t_loop / t_many:.2f}"
    )
    print(f"  one compiled fit: median {np.median(times):.2f} s (min {min(times):.2f} s)")
    stages = [(r.timings["pso_s"], r.timings["lm_s"]) for r in loop]
    print(
        f"  swarm / polish: fit_many {many[0].timings['pso_s']:.2f} s / "
        f"{many[0].timings['lm_s']:.2f} s; one fit (median) "
        f"{np.median([a for a, _ in stages]):.2f} s / {np.median([b for _, b in stages]):.2f} s"
    )
    print(
        f"  median NMSE fit_many {np.median([r.nmse for r in many]):.4e}, "
        f"loop {np.median([r.nmse for r in loop]):.4e}"
    )


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--only", choices=("a", "b", "c", "d"))
    ap.add_argument("--quick", action="store_true", help="part b on four recordings")
    ap.add_argument("--cores", type=int, default=None, help="CPU devices (default: every core)")
    args = ap.parse_args()
    devices = use_cpu_cores(args.cores)  # as the command line does
    print(f"vfjax {vfjax.__version__}, jax {jax.__version__}, {devices} CPU devices")
    if args.only in (None, "a"):
        part_a(devices)
    if args.only in (None, "b"):
        part_b(args.quick)
    if args.only in (None, "c"):
        part_c()
    if args.only in (None, "d"):
        part_d(devices)


if __name__ == "__main__":
    main()
