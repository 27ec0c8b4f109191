"""The diagnosis report, from an `Investigation` (or one `Diagnosis`): Markdown with PNG
figures, and the same as one self-contained HTML page (figures embedded).

    study = vfjax.investigate(recording)
    vfjax.report.write_report(study, recording, "out/")  # out/report.md, report.html, figures
"""

import pathlib
from os import PathLike

import numpy as np

from ._diagnosis import Diagnosis, Investigation, Round
from ._html import write_markdown_report
from .asymmetry import asymmetry_indices, fold_areas
from .compare import plot_comparison
from .io import save_figure
from .recording import Recording


def _fmt(v, digits=4):
    if v is None:
        return "-"
    if isinstance(v, float) and (abs(v) >= 1e4 or (0 < abs(v) < 1e-3)):
        return f"{v:.{digits - 1}e}"
    return f"{v:.{digits}g}"


def _needed_cell(row: dict) -> str:
    """The "needed" cell of a candidate's row: yes, unconfirmed (its search refit passes
    where its calibrated refit does not, `vfjax.Diagnosis.unconfirmed`) or no."""
    if row["needed"]:
        return "**yes**"
    return "unconfirmed" if row.get("unconfirmed") else "no"


def _p(v):
    return "-" if v is None else ("< 1e-16" if v < 1e-16 else f"{v:.2g}")


def plot_candidates(d: Diagnosis, ax=None):
    """NMSE each candidate's refit reaches, against the error before and the noise floor."""
    import matplotlib.pyplot as plt

    if ax is None:
        _, ax = plt.subplots(figsize=(6, 3))
    rows = [r for r in d.table() if r["nmse_after"] is not None]
    names = [r["effect"] for r in rows]
    values = [max(r["nmse_after"], 1e-12) for r in rows]
    colours = [
        "#2a9d8f" if r["needed"] else ("#e9c46a" if r["significant"] else "#adb5bd") for r in rows
    ]
    ax.barh(names[::-1], values[::-1], color=colours[::-1])
    before = d.calibrated.control_nmse if d.calibrated is not None else d.nmse_before
    ax.axvline(before, color="#c1121f", lw=1.2, label="before")
    if d.noise_nmse > 0:
        ax.axvline(d.noise_nmse, color="#1d3557", ls="--", lw=1.0, label="noise floor")
    ax.set_xscale("log")
    ax.set_xlabel("NMSE after the refit with the effect")
    ax.legend(frameon=False, fontsize=7)
    ax.set_title("green: needed, yellow: significant but not identified", fontsize=8)
    return ax


def plot_rounds(study: Investigation, recording: Recording):
    """Measured vs the first and the final fit, the error per round, and the convergence of
    the last extension."""
    import matplotlib.pyplot as plt

    from .plotting import plot_convergence

    fig = plt.figure(figsize=(12, 6))
    grid = fig.add_gridspec(2, 3)
    ax = fig.add_subplot(grid[0, :])
    t = recording.time * 1e3
    ax.plot(t, recording.area, color="#2a9d8f", lw=1.4, label="measured")
    ax.plot(
        t,
        study.first.fitted_gaw(recording),
        color="#adb5bd",
        lw=1.1,
        label=f"paper model (NMSE {study.first.nmse:.2%})",
    )
    if study.final is not study.first:
        what = "+ " + " + ".join(study.added) if study.added else "paper model, refitted"
        ax.plot(
            t,
            study.final.fitted_gaw(recording),
            color="#c1121f",
            lw=1.1,
            label=f"{what} (NMSE {study.final.nmse:.2%})",
        )
    ax.set_xlabel("time (ms)")
    ax.set_ylabel(f"area ({recording.unit})")
    ax.legend(frameon=False, fontsize=7, ncol=3, loc="upper right")
    ax.margins(x=0)
    ax = fig.add_subplot(grid[1, 0])
    labels = ["paper"] + [f"+ {n}" for n in study.added]
    errors = [study.first.nmse] + [r.extended.nmse for r in study.rounds if r.extended]
    if study.final is study.rounds[-1].diagnosis.control:  # it fitted the model better
        labels.append("refitted")
        errors.append(study.final.nmse)
    ax.bar(range(len(errors)), errors, color=["#adb5bd"] + ["#2a9d8f"] * (len(errors) - 1))
    ax.set_xticks(range(len(errors)), labels, fontsize=7, rotation=15)
    ax.set_yscale("log")
    ax.set_ylabel("NMSE")
    floor = study.rounds[-1].diagnosis.noise_nmse
    if floor > 0:
        ax.axhline(floor, color="#1d3557", ls="--", lw=1.0, label="noise floor")
        ax.legend(frameon=False, fontsize=7)
    ax = fig.add_subplot(grid[1, 1:])
    last = [r.extended for r in study.rounds if r.extended]
    plot_convergence(last[-1] if last else study.first, ax=ax)
    ax.set_title("convergence of the " + ("last extension" if last else "fit"), fontsize=8)
    fig.tight_layout()
    return fig


def _round_lines(i: int, r: Round, recording: Recording, folder: pathlib.Path, dpi: int):
    import matplotlib.pyplot as plt

    d = r.diagnosis
    c = d.comparison
    stem = f"{recording.name}_round{i}"
    fig = plot_comparison(c, f"round {i}: {' + '.join(_terms(r.fit)) or 'model'}")
    save_figure(fig, folder / f"{stem}_compare.png", dpi=dpi)
    plt.close(fig)
    lines = [
        f"## Round {i}: {_model_words(r.fit)}",
        "",
        "Fitted: "
        + ", ".join(f"{n} = {_fmt(v)} {r.fit.units[n]}" for n, v in r.fit.params.items())
        + f"; NMSE {r.fit.nmse:.3%} (noise floor about {d.noise_nmse:.3%}).",
        "",
        "### Where the model fails",
        "",
        *[f"- {w}" for w in c.failures()],
        "",
        "| phase | share of squared error | share of frames |",
        "|---|---|---|",
        *[f"| {n} | {c.error_share[n]:.0%} | {c.time_share[n]:.0%} |" for n in c.error_share],
        "",
        "| descriptor | measured | model |",
        "|---|---|---|",
        *[f"| {lab} | {_fmt(a)} {u} | {_fmt(b)} {u} |" for lab, a, b, u in c.table()],
        "",
        f"![measured vs model, residual with the model's phases]({stem}_compare.png)",
        "",
        "### Which effect is missing",
        "",
        *_method_lines(d, r),
    ]
    for row in d.table():
        values = ", ".join(
            f"{k} = {_fmt(v)}"
            + (
                f" [{_fmt(row['interval'][k][0])}, {_fmt(row['interval'][k][1])}]"
                if row["interval"]
                else ""
            )
            for k, v in row["values"].items()
        )
        nmse = "-" if row["nmse_after"] is None else f"{row['nmse_after']:.3%}"
        fall = "-" if row["fall"] is None else f"{row['fall']:.0%}"
        lines.append(
            f"| {row['rank']} | {row['effect']} | {row['statistic']:.3g} | "
            f"{_p(row['p_value'])} | {nmse} | {fall} | {_p(row['refit_f_p_value'])} | "
            f"{_p(row['calibrated_p_value'])} | "
            f"{_needed_cell(row)} | {values} |"
        )
    if d.refits:
        fig, ax = plt.subplots(figsize=(7, 0.5 + 0.45 * len(d.refits)))
        plot_candidates(d, ax=ax)
        fig.tight_layout()
        save_figure(fig, folder / f"{stem}_candidates.png", dpi=dpi)
        plt.close(fig)
        lines += ["", f"![error each candidate reaches]({stem}_candidates.png)"]
    cycles = d.variability
    if cycles is not None:
        lines += [
            "",
            f"**Cycle-to-cycle variability.** Against {cycles.replicates} recordings of the "
            f"fitted model with white noise only, p = {_p(cycles.p_value)}: {cycles.words()} "
            f"({cycles.level:.0%} intervals).",
        ]
    lines += ["", f"**Verdict.** {d.verdict}", ""]
    if r.extended is not None:
        added = {n: v for n, v in r.extended.params.items() if n not in r.fit.params}
        lines += [
            f"### Adding {r.added}",
            "",
            "| model | NMSE | " + " | ".join(added) + " |",
            "|---|---|" + "---|" * len(added),
            f"| before | {r.fit.nmse:.3%} | " + " | ".join("off" for _ in added) + " |",
            f"| + {r.added} | {r.extended.nmse:.3%} | "
            + " | ".join(f"{_fmt(v)} {r.extended.units[n]}" for n, v in added.items())
            + " |",
            "",
        ]
    return lines


def _terms(result):
    from .terms.paper import BernoulliForce, ClosureHold, Elastic, FlowSeparation, TanhDamping

    paper = (Elastic, TanhDamping, BernoulliForce, FlowSeparation, ClosureHold)
    return [type(t).__name__ for t in result.model.terms if not isinstance(t, paper)]


def _model_words(result):
    extra = _terms(result)
    return "the paper's model" + (" + " + " + ".join(extra) if extra else "")


def _asymmetry_lines(recording: Recording) -> list[str]:
    """The recording's left-right asymmetry indices, where it has edges or masks."""
    if recording.edges is None and recording.masks is None:
        return []
    try:
        left, right = fold_areas(recording)
    except ValueError as err:
        return [f"No left-right split: {err}.", ""]
    ai = asymmetry_indices(left, right, recording.fps)
    if ai.n_cycles == 0:
        return ["Left-right asymmetry: no complete cycle to measure it on.", ""]
    return [
        f"Left-right asymmetry (areas split by the glottal midline, {ai.n_cycles} cycles): "
        f"amplitude symmetry index ASI {ai.asi:.3f}, phase asymmetry index PAI {ai.pai:.3f} "
        "(symmetric folds: 1 and 0; the fitted model's folds are symmetric).",
        "",
    ]


def write_report(
    study: Investigation | Diagnosis,
    recording: Recording,
    folder: str | PathLike,
    title: str | None = None,
    dpi: int = 110,
) -> pathlib.Path:
    """Write ``folder/report.md`` with its PNG figures, and ``folder/report.html``, the same
    report as one self-contained page (figures embedded; readable offline); returns the
    Markdown's path.

    Arguments:
        study: an `Investigation` (`vfjax.investigate`) or a single `Diagnosis`.
        recording: the recording it was made on.
        folder: output folder (created).
        title: the report's title.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    folder = pathlib.Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    if isinstance(study, Diagnosis):
        study = Investigation(recording.name, [Round(study.result, study, None, None)])
    lines = [f"# {title or 'vfjax diagnosis: ' + recording.name}", ""]
    n_peak = float(np.max(recording.area))
    lines += [
        f"Recording `{recording.name}`: {recording.n_frames} frames at {recording.fps:g} fps "
        f"({recording.n_frames / recording.fps * 1e3:.1f} ms), peak area {_fmt(n_peak)} "
        f"{recording.unit}.",
        "",
        *_asymmetry_lines(recording),
        "| round | model | NMSE | added next |",
        "|---|---|---|---|",
    ]
    for i, r in enumerate(study.rounds, 1):
        lines.append(f"| {i} | {_model_words(r.fit)} | {r.fit.nmse:.3%} | {r.added or '-'} |")
    if study.final is not study.rounds[-1].fit:
        lines.append(f"| final | {_model_words(study.final)} | {study.final.nmse:.3%} | |")
    outcome = study.outcome(recording)
    lines += [
        "",
        f"**Conclusion.** {study.rounds[-1].diagnosis.verdict}",
        "",
        f"**Outcome: {outcome.status}.** {outcome.words[0].upper() + outcome.words[1:]}.",
        "",
    ]
    failed = [(i, r.fit) for i, r in enumerate(study.rounds, 1) if r.fit.failed]
    if study.final.failed:
        failed.append(("final", study.final))
    for which, result in failed:
        lines += [f"**Fit {which} failed.** {result.status_message()}", ""]
    fig = plot_rounds(study, recording)
    save_figure(fig, folder / f"{recording.name}_rounds.png", dpi=dpi)
    plt.close(fig)
    lines += [f"![fits, error per round, convergence]({recording.name}_rounds.png)", ""]
    for i, r in enumerate(study.rounds, 1):
        lines += _round_lines(i, r, recording, folder, dpi)
    return write_markdown_report(folder / "report.md", "\n".join(lines) + "\n")


def _method_lines(d, r) -> list[str]:
    """How the round's verdict was reached, and the table's header."""
    cal = d.calibrated
    if cal is None:
        text = (
            f"Score tests at the off-values (autocorrelation-robust, asymptotic; no refits): "
            f"an effect is *needed* when its p-value is below {d.level:.1e} "
            f"({d.criteria.alpha:g} over {len(d.scores)} candidates)."
        )
    else:
        v = cal.variability
        text = (
            f"Each candidate is refitted from the control's optimum (the model without any "
            f"effect refitted: NMSE {cal.control_nmse:.3%}). Its error fall is calibrated on "
            f"{cal.replicates} null recordings simulated from the fitted model with the "
            f"recording's noise ({v.noise_sd:.3g} per frame) and cycle-to-cycle variability "
            f"(per cycle, standard deviations of {v.timing_sd * 1e3:.3g} ms in the timing "
            f"offsets, {v.period_sd * 1e3:.3g} ms in the periods and {v.amplitude_sd:.2%} in "
            f"the amplitude factors; its local jitter {v.jitter:.2%} and shimmer "
            f"{v.shimmer:.2%}), refitted alike. An effect is *needed* when its "
            f"family-wise calibrated p-value is at most {d.criteria.alpha:g} and the "
            f"{cal.interval_level:.0%} interval of its size excludes its off-value."
        )
    return [
        text,
        "",
        "| rank | effect | score statistic | score p | NMSE after refit | error fall | "
        "F-test p (uncalibrated) | calibrated p | needed | fitted values [interval] |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
