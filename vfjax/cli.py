"""Command line: ``vfjax run`` (the main job on embedded data) and ``vfjax simulate``."""

import argparse
import pathlib
import sys
import time

import numpy as np

from . import __version__


def _simulate_preset(name, fps, n_frames, t_start):
    from .integrator import simulate
    from .presets import preset

    return simulate(preset(name), fps, n_frames, t_start=t_start)


def _describe(sim, fps):
    from .descriptors import fundamental_frequency

    mm2 = np.asarray(sim.glottal_area) * 100.0
    return {
        "min_area_mm2": float(mm2.min()),
        "max_area_mm2": float(mm2.max()),
        "f0_Hz": fundamental_frequency(np.asarray(sim.area), fps),
        "closed_frames": int(np.sum(np.asarray(sim.phase) == 3)),
    }


def cmd_run(args) -> int:
    """The paper's four subjects: GAWs (CSV + JSON sidecar), figures and a short report."""
    import matplotlib

    matplotlib.use("Agg")  # files only, no window
    import matplotlib.pyplot as plt

    from .io import write_simulation
    from .plotting import plot_gaw
    from .presets import PRESETS

    out = pathlib.Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    fig, axes = plt.subplots(4, 1, figsize=(9, 9), sharex=True)
    rows = []
    for ax, name in zip(axes, PRESETS):
        t0 = time.perf_counter()
        sim = _simulate_preset(name, args.fps, args.frames, args.t_start)
        seconds = time.perf_counter() - t0
        if bool(sim.diverged) or not bool(sim.complete):
            print(f"{name}: simulation did not complete (diverged={bool(sim.diverged)})")
            return 1
        meta = {"subject": name, "model": "paper (MODEL_SPEC.md)", **PRESETS[name]}
        write_simulation(sim, out / f"{name}_gaw.csv", metadata=meta)
        plot_gaw(sim, ax=ax, title=f"{name}")
        d = _describe(sim, args.fps)
        rows.append((name, d, seconds))
        print(f"{name}: f0 {d['f0_Hz']:.1f} Hz, area {d['min_area_mm2']:.3f} .. "
              f"{d['max_area_mm2']:.2f} mm², {seconds:.2f} s")  # fmt: skip
    fig.tight_layout()
    fig.savefig(out / "paper_subjects.png", dpi=120)
    plt.close(fig)
    lines = [
        "# vfjax: the paper's four subjects",
        "",
        f"Simulated with vfjax {__version__}: {args.frames} frames at {args.fps:g} fps, "
        f"sampling from t = {args.t_start:g} s (the folds start at rest at contact at t = 0).",
        "",
        "| subject | f0 (Hz) | min area (mm²) | max area (mm²) | closed frames |",
        "|---|---|---|---|---|",
    ]
    for name, d, _ in rows:
        lines.append(f"| {name} | {d['f0_Hz']:.1f} | {d['min_area_mm2']:.3f} | "
                     f"{d['max_area_mm2']:.2f} | {d['closed_frames']} |")  # fmt: skip
    lines += ["", "![GAWs with phases shaded](paper_subjects.png)", ""]
    (out / "report.md").write_text("\n".join(lines))
    print(f"wrote {out / 'report.md'}, {out / 'paper_subjects.png'} and 4 GAW tables")
    return 0


def cmd_simulate(args) -> int:
    """One preset's GAW as CSV + sidecar."""
    from .io import write_simulation
    from .presets import PRESETS

    sim = _simulate_preset(args.preset, args.fps, args.frames, args.t_start)
    path = write_simulation(sim, args.output, metadata={"subject": args.preset,
                                                        **PRESETS[args.preset]})  # fmt: skip
    print(f"wrote {path} ({args.frames} frames, diverged={bool(sim.diverged)})")
    return 0 if bool(sim.complete) else 1


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="vfjax", description="Differentiable vocal-fold model.")
    p.add_argument("--version", action="version", version=f"vfjax {__version__}")
    sub = p.add_subparsers(dest="command", required=True)

    run = sub.add_parser("run", help="the main job on embedded data (the paper's subjects)")
    run.add_argument("--out", default="vfjax_output", help="output folder (default: %(default)s)")
    run.add_argument("--fps", type=float, default=4000.0, help="frame rate, Hz")
    run.add_argument("--frames", type=int, default=201, help="number of frames")
    run.add_argument("--t-start", type=float, default=0.2, help="sampling start, s (after onset)")
    run.set_defaults(func=cmd_run)

    sim = sub.add_parser("simulate", help="simulate one preset and write its GAW")
    sim.add_argument("preset", choices=["N1", "N2", "N3", "N4"])
    sim.add_argument("-o", "--output", default="gaw.csv", help="CSV path (a .json sidecar too)")
    sim.add_argument("--fps", type=float, default=4000.0)
    sim.add_argument("--frames", type=int, default=201)
    sim.add_argument("--t-start", type=float, default=0.0)
    sim.set_defaults(func=cmd_simulate)
    return p


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return args.func(args)
    except (ValueError, TypeError, FileNotFoundError) as err:
        print(f"vfjax: error: {err}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    raise SystemExit(main())
