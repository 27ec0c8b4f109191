"""Cohort throughput: 64 recordings made by vfjax, fitted (and diagnosed) as one cohort,
in one process and on a local Dask cluster of 2 worker processes.

The recordings: lengths 101-1 001 frames, frame rates 2-8 kHz (at least 30 ms each), the
paper's four subjects, 1-2 px noise and 0.3 % closure jitter; every other one with a hidden
effect (a glottal gap of 0.003 cm², a cubic stiffness of eta 1 500 1/cm², a mucosal delay of
0.2 ms or a pressure modulation of depth 0.1 at 8 Hz: `effects`). Prints, per run: wall time,
recordings per hour, the largest difference from the serial run's table, and the memory
(RSS) of the process or each worker, sampled every 2 s, over the first and the second half
of the run.

    python benchmarks/cohort.py --out bench_cohort                 # fits alone (part a)
    python benchmarks/cohort.py --out bench_cohort --diagnose      # fit + diagnosis (part b)
    python benchmarks/cohort.py --out bench_cohort --diagnose --check 8
        # and the verdicts of 8 recordings diagnosed alone (vfjax.investigate)
    python benchmarks/cohort.py --out bench_cohort --n 96 --length 201 --skip-serial
        # one length bucket: whether a worker's memory grows with the recordings
    python benchmarks/cohort.py --out bench_cohort --diagnose --skip-serial --warmup 0.5
        # recordings in sustained phonation (default: from the start-up, 27.7 ms in)

Each run writes its own cohort folder under --out and reuses nothing of an earlier run
(each starts from an empty folder; JAX's compilation cache stays on, as for the command
line: a first run on a machine compiles).
"""

import argparse
import dataclasses
import pathlib
import shutil
import sys
import threading
import time

import numpy as np

LENGTHS = (101, 201, 401, 601, 1001)
RATES = (2000.0, 4000.0, 6000.0, 8000.0)
SUBJECTS = ("N1", "N2", "N3", "N4")
MIN_DURATION_S = 0.03


def effects():
    import vfjax

    return (
        ("GlottalGap", vfjax.GlottalGap(a_gap=0.003)),
        ("CubicStiffness", vfjax.CubicStiffness(eta=1500.0)),
        ("MucosalDelay", vfjax.MucosalDelay(tau=2e-4)),
        ("PressureModulation", vfjax.PressureModulation(a_pm=0.1, f_m=8.0, phi=-2.0)),
    )


def make_recordings(
    folder: pathlib.Path, n: int, lengths=LENGTHS, warmup: float | None = None
) -> pathlib.Path:
    """The cohort's recordings and manifest (path, subject, sex, effect), of ``lengths``
    frames in turn, each from ``warmup`` s after the onset (None: `demo_recording`'s 27.7
    ms, in the start-up)."""
    import vfjax
    from vfjax.io import write_recording

    folder.mkdir(parents=True, exist_ok=True)
    lines = ["path,subject,sex,effect"]
    kinds = effects()
    for i in range(n):
        length = lengths[i % len(lengths)]
        rates = [r for r in RATES if length / r >= MIN_DURATION_S]
        fps = rates[(i // len(lengths)) % len(rates)]
        subject = SUBJECTS[(i // 2) % len(SUBJECTS)]
        name, effect = kinds[(i // 2) % len(kinds)] if i % 2 else ("none", None)
        rec = vfjax.datasets.demo_recording(
            subject,
            noise_px=1.0 + (i % 3) / 2,
            seed=i,
            fps=fps,
            n_frames=length,
            effect=effect,
            jitter=0.003,
            warmup=warmup,
        )
        path = folder / f"r{i:02d}.csv"
        write_recording(rec, path)
        lines.append(f"{path.name},{subject},{rec.metadata['sex']},{name}")
    manifest = folder / "manifest.csv"
    manifest.write_text("\n".join(lines) + "\n")
    return manifest


class MemoryLog:
    """RSS (MB) of this process, or of each Dask worker, every ``period`` seconds."""

    def __init__(self, client=None, period: float = 2.0):
        self.client, self.period, self.samples = client, period, []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def _rss(self) -> dict:
        import psutil

        if self.client is None:
            return {"main": psutil.Process().memory_info().rss / 2**20}

        def rss():
            import psutil

            return psutil.Process().memory_info().rss / 2**20

        return self.client.run(rss)

    def _run(self):
        while not self._stop.wait(self.period):
            try:
                self.samples.append((time.perf_counter(), self._rss()))
            except Exception:  # a worker starting or stopping
                pass

    def __enter__(self):
        self._thread.start()
        return self

    def __exit__(self, *exc):
        self._stop.set()
        self._thread.join()

    def summary(self) -> str:
        if len(self.samples) < 2:
            return "too short to sample"
        half = len(self.samples) // 2
        out = []
        for who in self.samples[-1][1]:
            first = [s[who] for _, s in self.samples[:half] if who in s]
            second = [s[who] for _, s in self.samples[half:] if who in s]
            if first and second:
                quarter = first[len(first) // 2]
                out.append(
                    f"{who.split(':')[-1]}: peak {max(first):.0f} MB (first half), "
                    f"{max(second):.0f} MB (second half); {quarter:.0f} MB a quarter in, "
                    f"{second[-1]:.0f} MB at the end"
                )
        return "; ".join(out)


def run(manifest, out, options, workers):
    """The cohort from an empty folder; returns (table, seconds, memory summary)."""
    import vfjax

    shutil.rmtree(out, ignore_errors=True)
    t0 = time.perf_counter()
    if workers is None:
        with MemoryLog() as log:
            frame = vfjax.cohort(manifest, out, options, progress=True)
        return frame, time.perf_counter() - t0, log.summary()
    # a cluster of our own, so that its workers' memory can be sampled
    from distributed import Client, LocalCluster

    cluster = LocalCluster(
        n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=None
    )
    try:
        with Client(cluster) as client, MemoryLog(client) as log:
            frame = vfjax.cohort(manifest, out, options, scheduler=client)
    finally:
        cluster.close()
    return frame, time.perf_counter() - t0, log.summary()


def difference(a, b) -> str:
    """The largest relative difference of the tables' NMSE and parameter columns, in words;
    a closure duration that no hold uses (a flat direction of the fit) is named apart."""
    worst, flat = {}, []
    for column in a.columns:
        if column in ("seconds", "fps [Hz]") or a[column].dtype.kind != "f":
            continue
        x, y = a[column].to_numpy(float), b[column].to_numpy(float)
        both = np.isfinite(x) & np.isfinite(y) & (x != 0)
        rel = np.abs(x[both] - y[both]) / np.abs(x[both])
        if column.startswith("t_c") and rel.size:
            flat = list(a["recording"][both][rel > 1e-6])
            rel = rel[rel <= 1e-6]
        worst[column] = float(rel.max()) if rel.size else 0.0
    name = max(worst, key=worst.get)
    return (
        f"largest relative difference {worst[name]:.1e} ({name}); t_c differs beyond 1e-6 in "
        f"{len(flat)} recordings ({', '.join(flat) or 'none'})"
    )


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--out", default="bench_cohort", help="working folder")
    p.add_argument("--n", type=int, default=64, help="recordings (default: 64)")
    p.add_argument("--diagnose", action="store_true", help="fit and diagnose (part b)")
    p.add_argument("--workers", type=int, default=2, help="Dask worker processes")
    p.add_argument("--skip-serial", action="store_true", help="the cluster run only")
    p.add_argument("--check", type=int, default=0, help="recordings diagnosed alone too")
    p.add_argument(
        "--length",
        type=int,
        default=None,
        help="every recording this many frames (one length bucket: no new program after the "
        "first batch, so a memory that grows would grow with the recordings)",
    )
    p.add_argument(
        "--warmup",
        type=float,
        default=None,
        help="simulated time (s) before each recording's first frame (default: 27.7 ms after "
        "the onset, in the start-up; 0.5: sustained phonation, as benchmarks/diagnosis_power.py)",
    )
    args = p.parse_args()

    from vfjax._runtime import use_compilation_cache, use_cpu_cores

    use_compilation_cache()
    use_cpu_cores(None)  # as the command line does
    import vfjax

    out = pathlib.Path(args.out)
    lengths = LENGTHS if args.length is None else (args.length,)
    manifest = make_recordings(out / "data", args.n, lengths, args.warmup)
    options = vfjax.CohortOptions(diagnose=args.diagnose)
    part = "fit + diagnosis" if args.diagnose else "fits alone"
    tag = "diagnosed" if args.diagnose else "fits"
    print(f"{args.n} recordings, {part}")
    tables = {}
    for label, workers in (("serial", None), (f"{args.workers} workers", args.workers)):
        if workers is None and args.skip_serial:
            continue
        folder = out / f"{tag}_{'serial' if workers is None else 'dask'}"
        frame, seconds, memory = run(manifest, folder, options, workers)
        tables[label] = frame
        done = int((frame["status"] == "done").sum())
        print(
            f"{label}: {seconds:.0f} s, {args.n / seconds * 3600:.0f} recordings/hour, "
            f"{done} done, {args.n - done} failed; memory: {memory}"
        )
        sys.stdout.flush()
    if len(tables) == 2:
        a, b = tables.values()
        same = (a["effects needed"] == b["effects needed"]).all() if args.diagnose else True
        print(f"serial / cluster: {difference(a, b)}; same verdicts: {same}")
    frame = list(tables.values())[-1]
    if args.diagnose:
        truth = frame["effect"].replace("none", "")
        hit = (frame["effects needed"].str.split("; ").str[0] == truth) & (truth != "")
        alarms = (frame["effects needed"] != "") & (truth == "")
        print(
            f"hidden effect found first: {int(hit.sum())} of {int((truth != '').sum())}; "
            f"false alarms: {int(alarms.sum())} of {int((truth == '').sum())}"
        )
    if args.check:
        agree = 0
        for i in range(args.check):
            entry = frame.iloc[i]
            rec = vfjax.load_recording(out / "data" / pathlib.Path(entry["path"]).name)
            rec = dataclasses.replace(rec, name=entry["recording"])
            study = vfjax.investigate(rec, calibration=options.calibration)
            same = "; ".join(study.added) == entry["effects needed"]
            agree += same
            print(f"  {entry['recording']}: alone {study.added}, cohort {entry['effects needed']}")
        print(f"verdicts equal to single-recording runs: {agree} of {args.check}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
