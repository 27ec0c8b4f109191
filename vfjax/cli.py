"""Command line: ``vfjax run`` (the main job on embedded data), ``fit``, ``diagnose``,
``cohort``, ``extract`` and ``simulate``."""

import argparse
import dataclasses
import os
import pathlib
import signal
import sys
import threading
import time
import warnings

import numpy as np

from ._fit._options import Swarm
from ._runtime import (  # noqa: F401  (the command line's settings, importable from here)
    CACHE_MAX_BYTES,
    CACHE_MIN_COMPILE_S,
    cache_folder,
    use_compilation_cache,
    use_cpu_cores,
)
from ._version import __version__


def _simulate_preset(name, fps, n_frames, t_start):
    from ._integrate import simulate
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

    from .io import check_output_folder, staged_output
    from .recording import check_frame_rate

    check_frame_rate(args.fps, "--fps")
    check_output_folder(args.out, args.force)
    with staged_output(args.out, args.force) as out:
        code = _run(args, out, plt)
    if code == 0:
        print(f"wrote {pathlib.Path(args.out) / 'report.md'} with its figures and tables")
    return code


def _run(args, out, plt) -> int:
    from ._html import write_markdown_report
    from .io import save_figure, write_recording, write_simulation
    from .plotting import plot_gaw
    from .presets import PRESETS

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
        print(
            f"{name}: f0 {d['f0_Hz']:.1f} Hz, area {d['min_area_mm2']:.3f} .. "
            f"{d['max_area_mm2']:.2f} mm², {seconds:.2f} s"
        )
    fig.tight_layout()
    save_figure(fig, out / "paper_subjects.png", dpi=120)
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
        lines.append(
            f"| {name} | {d['f0_Hz']:.1f} | {d['min_area_mm2']:.3f} | "
            f"{d['max_area_mm2']:.2f} | {d['closed_frames']} |"
        )
    lines += ["", "![GAWs with phases shaded](paper_subjects.png)", ""]

    # Fit: the embedded demo recording (made by vfjax: N3, 2 px noise, arbitrary start).
    from .datasets import demo_recording
    from .presets import initial_model, preset

    rec = demo_recording()
    write_recording(rec, out / f"{rec.name}.csv")
    start = initial_model(rec, template="N4")
    result = _fit_and_report(rec, start, out, None, 60, 0)
    truth = preset("N3").params()
    lines += [
        "## Fit of the embedded demo recording",
        "",
        f"`{rec.name}.csv`: the N3 model simulated by vfjax with 2 px noise. Fitted S, K, C_f",
        "and t_c, starting from subject N4 (the other female set) with t_c measured on the GAW,",
        "by particle swarm + Levenberg-Marquardt:",
        "",
        "| parameter | fitted | true | unit |",
        "|---|---|---|---|",
    ]
    for n, v in result.params.items():
        lines.append(f"| {n} | {v:.6g} | {float(truth[n]):.6g} | {result.units[n]} |")
    lines += [
        "",
        f"NMSE {result.nmse:.3e} (status: {result.status}); "
        f"optimistix: {result.optimistix_result}; "
        f"{result.n_simulations} simulations; {result.timings['total_s']:.1f} s "
        f"(PSO {result.timings['pso_s']:.1f} s, LM {result.timings['lm_s']:.1f} s, "
        "compilation included).",
        "",
        f"![fit]({rec.name}_fit.png)",
        "",
    ]
    print(
        f"fit {rec.name}: NMSE {result.nmse:.3e}, "
        + ", ".join(f"{n} {v:.5g}" for n, v in result.params.items())
    )
    lines += _diagnosis_section(out)
    write_markdown_report(out / "report.md", "\n".join(lines))
    return 0


def _fit_and_report(
    recording, model, out, params, iterations, key_seed, restarts=None, warmup=None
):
    import jax
    import matplotlib.pyplot as plt

    from ._fit import FIRST_FIT_RESTARTS, fit_recording
    from .io import save_figure
    from .plotting import plot_convergence, plot_overlay

    result = fit_recording(
        recording,
        model,
        params,
        restarts=FIRST_FIT_RESTARTS if restarts is None else restarts,
        swarm=Swarm(iterations=iterations),
        key=jax.random.key(key_seed),
        warmup=warmup,
    )
    result.to_json(out / f"{recording.name}_fit.json")
    fig, (a, b) = plt.subplots(1, 2, figsize=(12, 3.4), gridspec_kw={"width_ratios": [2.2, 1]})
    plot_overlay(recording, result, ax=a)
    plot_convergence(result, ax=b)
    fig.tight_layout()
    save_figure(fig, out / f"{recording.name}_fit.png", dpi=120)
    plt.close(fig)
    return result


def _diagnosis_section(out):
    """Fit, diagnose and extend on the embedded hidden-gap recording; writes its report to
    ``out/diagnosis/report.md`` and returns the main report's Markdown lines."""
    from ._diagnosis import investigate
    from .datasets import demo_recording
    from .io import write_recording
    from .report import write_report
    from .terms.effects import GlottalGap

    rec = demo_recording("N3", effect=GlottalGap(a_gap=0.008), name_suffix="_gap")
    write_recording(rec, out / f"{rec.name}.csv")
    study = investigate(rec, progress=True)
    path = write_report(
        study, rec, out / "diagnosis", title=f"vfjax diagnosis of the embedded recording {rec.name}"
    )
    added = study.added
    print(
        f"diagnosis: added {added or 'nothing'}; NMSE {study.first.nmse:.3e} -> "
        f"{study.final.nmse:.3e}; report diagnosis/{path.name} in the output folder"
    )
    values = {n: v for n, v in study.final.params.items() if n not in study.first.params}
    return [
        "## Fit, diagnose, extend: the embedded gap recording",
        "",
        f"`{rec.name}.csv` is made by vfjax: subject N3 with a hidden posterior gap of "
        "0.008 cm² (`GlottalGap`), 2 px noise. vfjax fits the paper's model, compares it with "
        "the measurement, tests every catalogue effect (score test + refit), adds the "
        "one that is needed and refits.",
        "",
        f"- paper's model: NMSE {study.first.nmse:.3%}",
        f"- effects added: {', '.join(added) if added else 'none'}",
        f"- final NMSE: {study.final.nmse:.3%}"
        + (" (" + ", ".join(f"{n} = {v:.4g}" for n, v in values.items()) + ")" if values else ""),
        f"- conclusion: {study.rounds[-1].diagnosis.verdict}",
        "",
        "Full report with figures: [diagnosis/report.md](diagnosis/report.md).",
        "",
        "![rounds](diagnosis/" + f"{rec.name}_rounds.png)",
        "",
    ]


def _load_input(args):
    """The recording named on the command line: a GAW table with its sidecar (or with --fps,
    where it has none), a contour file (``.txt``, with --fps), or a high-speed video,
    segmented into its glottal area (split into the folds' where it can be) as
    `vfjax extract` and a cohort segment it."""
    from .recording import check_frame_rate, load_contours, load_recording
    from .video import VIDEO_SUFFIXES

    path = pathlib.Path(args.recording)
    if args.fps is not None:
        check_frame_rate(args.fps, "--fps")
    if path.suffix.lower() == ".txt":
        if args.fps is None:
            raise ValueError(f"{path.name}: a contour file carries no frame rate; give --fps")
        return load_contours(path, args.fps)
    if path.suffix.lower() in VIDEO_SUFFIXES:
        from .segmentation import video_to_recording

        return video_to_recording(path, args.fps, folds=True, progress=True)
    return load_recording(path, fps=args.fps)


def _report_failure(result, what: str) -> int:
    """Exit code 0 for a trusted fit; else 1, with the reason on stderr."""
    if not result.failed:
        return 0
    print(f"vfjax: {what} {result.status_message()}", file=sys.stderr)
    return 1


#: Effects that `vfjax diagnose --also` offers beside the catalogue's default candidates (by
#: name: the command line builds no class from its input).
EXTRA_CANDIDATES = ("PowerLawTissue", "SourceTractInertance")


def diagnosis_candidates(also) -> list | None:
    """The candidate effects of ``vfjax diagnose``: the catalogue's defaults (None) or, with
    ``--also`` names (of `EXTRA_CANDIDATES`), the catalogue's classes and those."""
    if not also:
        return None
    import vfjax

    from ._diagnosis import DEFAULT_CANDIDATES

    unknown = sorted(set(also) - set(EXTRA_CANDIDATES))
    if unknown:
        raise ValueError(f"--also: unknown effect {unknown[0]!r}")
    return list(DEFAULT_CANDIDATES) + [getattr(vfjax, name) for name in dict.fromkeys(also)]


def _warn_of_recording(rec) -> None:
    """Warnings on stderr of what a model of sustained phonation cannot describe in the
    recording (`vfjax.descriptors.recording_cautions`)."""
    from .descriptors import recording_cautions

    for words in recording_cautions(rec.area, rec.fps, rec.name):
        print(f"vfjax: warning: {words}", file=sys.stderr)


def cmd_diagnose(args) -> int:
    """Fit, diagnose, extend (up to --rounds effects) and write the report."""
    import matplotlib

    matplotlib.use("Agg")
    from ._diagnosis import Criteria, investigate
    from .io import check_output_folder, staged_output
    from .presets import initial_model
    from .report import write_report

    check_output_folder(args.out, args.force)
    rec = _load_input(args)
    _warn_of_recording(rec)
    model = initial_model(rec, template=args.start)
    with staged_output(args.out, args.force) as out:
        study = investigate(
            rec,
            model,
            None if args.params is None else tuple(args.params),
            rounds=args.rounds,
            restarts=args.restarts,
            warmup=args.warmup,
            criteria=Criteria(alpha=args.alpha),
            calibration=_calibration(args),
            swarm=Swarm(iterations=args.iterations),
            candidates=diagnosis_candidates(args.also),
            progress=True,
        )
        write_report(study, rec, out)
        study.final.to_json(out / f"{rec.name}_final_fit.json")
    print(f"{rec.name}: {study.rounds[-1].diagnosis.verdict}")
    print(f"wrote {pathlib.Path(args.out) / 'report.md'} and its figures")
    return _report_failure(study.final, f"{rec.name}: the final fit")


def cmd_cohort(args) -> int:
    """Fit and diagnose every recording of a folder or manifest; resumable."""
    import matplotlib

    matplotlib.use("Agg")
    from ._cohort import CohortOptions, cohort
    from ._diagnosis import Criteria

    options = CohortOptions(
        diagnose=not args.fits_only,
        rounds=args.rounds,
        restarts=args.restarts,
        swarm=Swarm(size=args.particles, iterations=args.iterations),
        criteria=Criteria(alpha=args.alpha),
        calibration=_calibration(args),
        candidates=diagnosis_candidates(args.also),
        batch=args.batch,
        seed=args.seed,
    )
    frame = cohort(
        args.input,
        args.out,
        options,
        fps=args.fps,
        workers=args.workers,
        scheduler=args.scheduler,
        retry_failed=args.retry_failed,
        progress=True,
    )
    failed = frame[frame["status"] != "done"]
    out = pathlib.Path(args.out)
    print(f"{len(frame)} recordings: {len(frame) - len(failed)} done, {len(failed)} failed")
    for _, row in failed.iterrows():
        print(f"  {row['recording']}: {row['reason']}", file=sys.stderr)
    print(f"wrote {out / 'cohort.csv'}, {out / 'cohort.parquet'} and {out / 'report.md'}")
    return 0


def cmd_fit(args) -> int:
    """Fit the paper's model to a recording (table + JSON sidecar, or a contour file)."""
    import matplotlib

    matplotlib.use("Agg")
    from ._fit import settling
    from .io import check_output_folder, staged_output
    from .presets import initial_model

    check_output_folder(args.out, args.force)
    rec = _load_input(args)
    _warn_of_recording(rec)
    model = initial_model(rec, template=args.start)
    with staged_output(args.out, args.force) as out:
        params = None if args.params is None else tuple(args.params)
        result = _fit_and_report(
            rec, model, out, params, args.iterations, args.seed, args.restarts, args.warmup
        )
    units = result.units
    print(
        f"{rec.name}: NMSE {result.nmse:.3e} ({result.status}); "
        + ", ".join(f"{n} = {v:.6g} {units[n]}" for n, v in result.params.items())
    )
    out = pathlib.Path(args.out)
    print(f"wrote {out / (rec.name + '_fit.json')} and {out / (rec.name + '_fit.png')}")
    check = settling(result, rec)
    if not check.settled:
        print(f"vfjax: warning: {rec.name}: {check.words()}", file=sys.stderr)
    return _report_failure(result, f"{rec.name}: the fit")


def _finite_or_none(x: float):
    return float(x) if np.isfinite(x) else None


def cmd_extract(args) -> int:
    """Glottal area from a high-speed video: CSV (the area and each fold's, split by the
    glottal midline) + sidecar (with the midline and the asymmetry indices) + preview."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from .asymmetry import asymmetry_indices, glottal_midline, with_fold_areas
    from .io import check_output_file, save_figure, write_recording
    from .recording import check_frame_rate
    from .segmentation import frames_to_recording
    from .video import read_video

    if args.fps is not None:
        check_frame_rate(args.fps, "--fps")
    table = check_output_file(args.output, args.force)
    preview = table.with_suffix(".png")
    for extra in (table.with_suffix(".json"), preview):
        check_output_file(extra, args.force)
    video, file_fps = read_video(args.video)
    rec = frames_to_recording(video, args.fps, source=args.video, file_fps=file_fps, progress=True)
    # per-fold areas split by the glottal midline, where the glottis spans rows to split
    try:
        midline = glottal_midline(masks=rec.masks)
    except ValueError as err:
        print(f"vfjax: no left/right split: {err}", file=sys.stderr)
        midline = None
    else:
        rec = with_fold_areas(rec, midline)  # written as area_left_px and area_right_px
        indices = asymmetry_indices(rec.folds[:, 0], rec.folds[:, 1], rec.fps)
        rec = dataclasses.replace(
            rec,
            metadata={
                **rec.metadata,
                "midline": {"top": list(midline.top), "bottom": list(midline.bottom)},
                "asymmetry": {
                    "asi": _finite_or_none(indices.asi),
                    "pai": _finite_or_none(indices.pai),
                    "cycles": indices.n_cycles,
                },
            },
        )
    # masks go in the figure, not the table
    out = write_recording(dataclasses.replace(rec, masks=None), table)
    i = int(np.argmax(rec.area))
    fig, (a, b) = plt.subplots(1, 2, figsize=(11, 3.6), gridspec_kw={"width_ratios": [1, 2.2]})
    a.imshow(video[i], cmap="gray")
    a.contour(rec.masks[i], levels=[0.5], colors="#e63946", linewidths=0.8)
    if midline is not None:
        span = np.array([midline.top[0] - 10.0, midline.bottom[0] + 10.0])
        a.plot(midline.image_column(span), span, color="#ffd166", linewidth=0.8)
    a.set_title(f"frame {i} (largest area)")
    a.axis("off")
    b.plot(rec.time * 1e3, rec.area, color="#2a9d8f", label="total")
    if rec.folds is not None:
        for side, values in zip(("left", "right"), rec.folds.T):
            b.plot(rec.time * 1e3, values, linewidth=0.8, label=f"{side} (image)")
        b.legend()
    b.set_xlabel("time (ms)")
    b.set_ylabel("glottal area (px)")
    b.set_title(rec.name)
    fig.tight_layout()
    save_figure(fig, preview, dpi=120)
    plt.close(fig)
    print(
        f"wrote {out}, its .json sidecar and {preview} ({rec.n_frames} frames, "
        f"peak area {rec.area.max():.0f} px)"
    )
    return 0


def cmd_simulate(args) -> int:
    """One preset's GAW as CSV + sidecar."""
    from .io import check_output_file, write_simulation
    from .presets import PRESETS
    from .recording import check_frame_rate

    path = check_output_file(args.output, args.force)
    check_output_file(path.with_suffix(".json"), args.force)
    check_frame_rate(args.fps, "--fps")
    sim = _simulate_preset(args.preset, args.fps, args.frames, args.t_start)
    path = write_simulation(sim, path, metadata={"subject": args.preset, **PRESETS[args.preset]})
    print(f"wrote {path} ({args.frames} frames)")
    return 0


def _search_nulls(text: str) -> int | None:
    """``--search-nulls``: a count of null recordings (>= 0) or ``all`` (None)."""
    if text.strip().lower() == "all":
        return None
    try:
        count = int(text)
    except ValueError:
        count = -1
    if count < 0:
        raise argparse.ArgumentTypeError(f"expected a count >= 0 or 'all', got {text!r}")
    return count


def _calibration(args):
    """The `vfjax.Calibration` of a diagnosis's command-line options."""
    from ._diagnosis import Calibration

    return Calibration(
        replicates=args.replicates,
        seed=args.seed,
        search_nulls=args.search_nulls,
        interval_search=args.interval_search,
    )


def _diagnosis_arguments(parser) -> None:
    """The options of a diagnosis (``diagnose``, ``cohort``): the first fit's restarts and
    swarm, the rounds, the level, the null recordings and the effects offered beside the
    catalogue's."""
    from ._diagnosis import Calibration

    parser.add_argument(
        "--restarts",
        type=int,
        default=4,
        help="independent searches of the first fit (default: %(default)s)",
    )
    parser.add_argument("--rounds", type=int, default=2, help="most effects to add (default: 2)")
    parser.add_argument(
        "--alpha",
        type=float,
        default=0.01,
        help="family-wise significance level over the candidates (default: %(default)s)",
    )
    parser.add_argument(
        "--replicates",
        type=int,
        default=111,
        help="most null recordings simulated to calibrate the verdicts; the smallest "
        "p-value is 1 / (1 + replicates) (default: %(default)s)",
    )
    parser.add_argument(
        "--search-nulls",
        type=_search_nulls,
        default=Calibration().search_nulls,
        metavar="N|all",
        help="where an effect's search passes while its refit from fixed starts does not, "
        "search at most this many null recordings alike ('all': every one, which decides "
        "it either way at a search per null recording; default: %(default)s, which may "
        "leave it unconfirmed)",
    )
    parser.add_argument(
        "--interval-search",
        action=argparse.BooleanOptionalAction,
        default=Calibration().interval_search,
        help="refit the bootstrap replicates of a needed effect's interval by a search, as "
        "its estimate is made (the default), or, with --no-interval-search, by a few steps "
        "from their truth (faster, but too narrow for an effect that trades with the "
        "fitted parameters)",
    )
    parser.add_argument(
        "--seed", type=int, default=0, help="seed of the null recordings (a cohort's fits too)"
    )
    parser.add_argument(
        "--iterations",
        type=int,
        default=Swarm().iterations,
        help="PSO iterations per fit (default: %(default)s)",
    )
    parser.add_argument(
        "--also",
        action="append",
        choices=sorted(EXTRA_CANDIDATES),
        default=[],
        metavar="EFFECT",
        help="offer this effect too, beside the catalogue's (repeatable; one of: "
        f"{', '.join(sorted(EXTRA_CANDIDATES))})",
    )


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="vfjax",
        description="Differentiable vocal-fold model.",
        epilog="Compiled programs are kept in JAX's persistent compilation cache (default "
        "~/.cache/vfjax/jax; VFJAX_CACHE_DIR names another folder), so a second run of the "
        "same kind skips compilation; --no-cache (or VFJAX_NO_CACHE=1) turns it off.",
    )
    p.add_argument("--version", action="version", version=f"vfjax {__version__}")
    p.add_argument(
        "--cores",
        type=int,
        default=None,
        help="CPU cores the fits use (default: all; VFJAX_CORES)",
    )
    p.add_argument(
        "--no-cache",
        action="store_true",
        help="do not read or write the persistent compilation cache",
    )
    sub = p.add_subparsers(dest="command", required=True)

    run = sub.add_parser("run", help="the main job on embedded data: simulate, fit, report")
    run.add_argument("--out", default="vfjax_output", help="output folder (default: %(default)s)")
    run.add_argument("--fps", type=float, default=4000.0, help="frame rate, Hz")
    run.add_argument("--frames", type=int, default=201, help="number of frames")
    run.add_argument("--t-start", type=float, default=0.2, help="sampling start, s (after onset)")
    run.add_argument("--force", action="store_true", help="overwrite the files of an earlier run")
    run.set_defaults(func=cmd_run)

    f = sub.add_parser("fit", help="fit the paper's model to a recording (GAW table or video)")
    f.add_argument(
        "recording",
        help="GAW table (its sidecar is the same path with .json), a "
        "*_segdata.txt contour file (with --fps), or a high-speed video (segmented first)",
    )
    f.add_argument("--fps", type=float, help="frame rate, Hz (contour files; a video's camera)")
    f.add_argument("--out", default="vfjax_output", help="output folder (default: %(default)s)")
    f.add_argument(
        "--params",
        nargs="+",
        help="parameters to fit (default: S, K, C_f, t_c, and P_s unless the sidecar states "
        "subglottal_pressure_dyne_per_cm2; the paper fitted S, K, C_f)",
    )
    f.add_argument(
        "--restarts",
        type=int,
        default=4,
        help="independent searches, the best kept (default: %(default)s)",
    )
    f.add_argument(
        "--start",
        choices=["N1", "N2", "N3", "N4"],
        help="preset to start from (default: N1 for male or unknown, N3 for female)",
    )
    f.add_argument(
        "--iterations",
        type=int,
        default=Swarm().iterations,
        help="PSO iterations (default: %(default)s)",
    )
    f.add_argument(
        "--warmup",
        type=float,
        help="simulated time (s) before the first frame (default: 0.02, longer where a term "
        "needs it); lengthen it when the fit is reported not settled",
    )
    f.add_argument("--seed", type=int, default=0, help="PRNG seed")
    f.add_argument("--force", action="store_true", help="overwrite the files of an earlier run")
    f.set_defaults(func=cmd_fit)

    dg = sub.add_parser("diagnose", help="fit, find the missing effect, extend, write a report")
    dg.add_argument(
        "recording",
        help="GAW table + .json sidecar, a *_segdata.txt contour file (with --fps), or a "
        "high-speed video (segmented first)",
    )
    dg.add_argument("--out", default="vfjax_diagnosis", help="report folder (default: %(default)s)")
    dg.add_argument("--fps", type=float, help="frame rate, Hz (contour files; a video's camera)")
    dg.add_argument(
        "--params",
        nargs="+",
        help="parameters of the first fit (default: S, K, C_f, t_c, and P_s unless the "
        "sidecar states subglottal_pressure_dyne_per_cm2)",
    )
    dg.add_argument("--start", choices=["N1", "N2", "N3", "N4"], help="preset to start from")
    dg.add_argument(
        "--warmup",
        type=float,
        help="simulated time (s) before the first frame (default: 0.02, longer where a term "
        "needs it); lengthen it when the fit is reported not settled",
    )
    _diagnosis_arguments(dg)
    dg.add_argument("--force", action="store_true", help="overwrite the files of an earlier run")
    dg.set_defaults(func=cmd_diagnose)

    co = sub.add_parser(
        "cohort",
        help="fit and diagnose every recording of a folder or manifest (resumable)",
        description="Fit and diagnose every recording of a folder or manifest. Each "
        "recording's results are written as soon as they are complete; a rerun with the "
        "same --out skips what is done and redoes what changed.",
    )
    co.add_argument(
        "input",
        help="a folder (GAW tables with .json sidecars, contour .txt files, videos) or a "
        "manifest CSV (path, optional fps, grouping columns)",
    )
    co.add_argument("--out", default="vfjax_cohort", help="output folder (default: %(default)s)")
    co.add_argument("--fps", type=float, help="frame rate, Hz, for files that state none")
    co.add_argument("--fits-only", action="store_true", help="first fits only, no diagnosis")
    co.add_argument(
        "--workers",
        type=int,
        help="run on a local Dask cluster of this many worker processes",
    )
    co.add_argument(
        "--scheduler", help="address of a running Dask scheduler (e.g. tcp://host:8786)"
    )
    co.add_argument(
        "--batch",
        type=int,
        default=16,
        help="most recordings in one batched fit (default: %(default)s)",
    )
    _diagnosis_arguments(co)
    co.add_argument(
        "--particles",
        type=int,
        default=Swarm().size,
        help="PSO particles per fit (default: %(default)s)",
    )
    co.add_argument(
        "--retry-failed",
        action="store_true",
        help="redo recordings that failed in an earlier run although their files did not change",
    )
    co.set_defaults(func=cmd_cohort)

    ex = sub.add_parser("extract", help="glottal area waveform from a high-speed video")
    ex.add_argument("video", help=".tif/.tiff, .npy, .cih/.cihx (+.mraw), .avi or .mp4")
    ex.add_argument("-o", "--output", default="recording.csv", help="CSV path (+ .json, .png)")
    ex.add_argument(
        "--fps",
        type=float,
        help="the camera's frame rate, Hz (when the file does not say, or says a playback rate)",
    )
    ex.add_argument("--force", action="store_true", help="overwrite the files of an earlier run")
    ex.set_defaults(func=cmd_extract)

    sim = sub.add_parser("simulate", help="simulate one preset and write its GAW")
    sim.add_argument("preset", choices=["N1", "N2", "N3", "N4"], help="the paper's subject")
    sim.add_argument("-o", "--output", default="gaw.csv", help="CSV path (a .json sidecar too)")
    sim.add_argument("--fps", type=float, default=4000.0, help="frame rate, Hz (default: 4000)")
    sim.add_argument("--frames", type=int, default=201, help="number of frames (default: 201)")
    sim.add_argument(
        "--t-start", type=float, default=0.0, help="sampling start, s after onset (default: 0)"
    )
    sim.add_argument("--force", action="store_true", help="overwrite the files of an earlier run")
    sim.set_defaults(func=cmd_simulate)
    return p


#: Seconds a Ctrl-C may take to unwind the stack (the staged outputs' clean-up) before the
#: process removes them itself and exits.
INTERRUPT_GRACE_S = 3.0


def _exit_interrupted(outputs) -> None:
    """Exit with code 130 and one line on stderr, without a traceback and without the
    interpreter's teardown under JAX's threads (which can crash); removes this process's
    staged outputs beside each of ``outputs`` (paths) first."""
    from .io import remove_partials

    for path in outputs:
        remove_partials(pathlib.Path(path).absolute().parent)
    print("vfjax: interrupted; the output folder is left as it was", file=sys.stderr)
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(130)


class _InterruptHandler:
    """A SIGINT handler: the first Ctrl-C raises KeyboardInterrupt (the outputs' context
    managers clean up as the stack unwinds) and arms a timer that ends the process after
    `INTERRUPT_GRACE_S` if it is still running (a KeyboardInterrupt raised inside a
    finaliser or a library's callback is lost); a second Ctrl-C ends it at once.
    ``pressed`` says whether Ctrl-C was pressed during the run."""

    def __init__(self, outputs):
        self.outputs = outputs
        self.pressed = False

    def __call__(self, signum, frame):
        if self.pressed:
            _exit_interrupted(self.outputs)
        self.pressed = True
        timer = threading.Timer(INTERRUPT_GRACE_S, _exit_interrupted, args=(self.outputs,))
        timer.daemon = True
        timer.start()
        raise KeyboardInterrupt


def _unraisable_hook(outputs, fallback):
    """A `sys.unraisablehook`: a KeyboardInterrupt raised inside a finaliser or a library's
    garbage-collection callback cannot unwind the stack, so it ends the process at once
    (`_exit_interrupted`) instead of being printed with a traceback and lost; anything
    else goes to ``fallback`` (the hook in place before)."""

    def hook(unraisable):
        if unraisable.exc_type is not None and issubclass(unraisable.exc_type, KeyboardInterrupt):
            _exit_interrupted(outputs)
        fallback(unraisable)

    return hook


def main(argv=None) -> int:
    """Run the command line; returns the exit code: 0 done, 1 the fit or simulation failed
    (the reason on stderr), 2 bad input or arguments, 130 interrupted (Ctrl-C)."""
    args = build_parser().parse_args(argv)
    from ._integrate import SimulationError
    from .descriptors import RecordingWarning

    if not (args.no_cache or os.environ.get("VFJAX_NO_CACHE")):
        use_compilation_cache()
    else:  # also a cache that JAX's own settings (JAX_COMPILATION_CACHE_DIR) turn on
        import jax

        jax.config.update("jax_enable_compilation_cache", False)
    try:
        cores = args.cores if args.cores is not None else os.environ.get("VFJAX_CORES")
        use_cpu_cores(None if cores is None else int(cores))
    except ValueError as err:
        print(f"vfjax: error: --cores / VFJAX_CORES: {err}", file=sys.stderr)
        return 2
    outputs = [p for p in (getattr(args, n, None) for n in ("out", "output")) if p]
    previous = None
    previous_hook = sys.unraisablehook
    handler = _InterruptHandler(outputs)
    if threading.current_thread() is threading.main_thread():
        previous = signal.signal(signal.SIGINT, handler)
        sys.unraisablehook = _unraisable_hook(outputs, previous_hook)
    try:
        with warnings.catch_warnings():  # the commands say these in their own words
            warnings.simplefilter("ignore", RecordingWarning)
            return args.func(args)
    except KeyboardInterrupt:
        _exit_interrupted([])
    except (SimulationError, ValueError, TypeError, OSError, ImportError) as err:
        if handler.pressed:
            # a library that catches the KeyboardInterrupt inside its own code raises an
            # error of its own instead (matplotlib's "Invalid bounding box" when Ctrl-C
            # lands in a drawing): the run was interrupted, not given bad input
            _exit_interrupted([])
        if isinstance(err, SimulationError):
            print(f"vfjax: simulation failed: {err}", file=sys.stderr)
            return 1
        print(f"vfjax: error: {err}", file=sys.stderr)
        return 2
    finally:
        if previous is not None:
            signal.signal(signal.SIGINT, previous)
            sys.unraisablehook = previous_hook


if __name__ == "__main__":
    raise SystemExit(main())
