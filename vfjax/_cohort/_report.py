"""The cohort report: one Markdown page with its figures, from the cohort table."""

import math
import pathlib

import numpy as np

from .._html import write_markdown_report
from ..io import save_figure

#: The model parameters whose distributions the report plots, when fitted.
PLOTTED = ("K", "C_f", "P_s", "t_c", "S")


def _column(frame, name: str) -> str | None:
    for c in frame.columns:
        if c == name or c.startswith(name + " ["):
            return c
    return None


def _groups_of(frame, group: str | None):
    if group is None:
        return [("all", frame)]
    return [(str(k) or "(none)", g) for k, g in frame.groupby(group, sort=True)]


def _parameter_figure(done, group, path, dpi):
    import matplotlib.pyplot as plt

    columns = [c for c in (_column(done, n) for n in PLOTTED) if c is not None]
    columns = [c for c in columns if done[c].notna().any()]
    if not columns:
        return None
    fig, axes = plt.subplots(1, len(columns), figsize=(2.6 * len(columns) + 0.6, 3.4))
    axes = np.atleast_1d(axes)
    parts = _groups_of(done, group)
    rng = np.random.default_rng(0)
    for ax, column in zip(axes, columns):
        for i, (_, part) in enumerate(parts):
            values = part[column].dropna().to_numpy(float)
            if values.size:
                ax.boxplot(values, positions=[i], widths=0.5, showfliers=False)
            ax.plot(i + rng.uniform(-0.15, 0.15, values.size), values, "o", ms=3, alpha=0.7)
        ax.set_xticks(range(len(parts)), [n for n, _ in parts], rotation=30, ha="right")
        positive = done[column].dropna()
        if positive.size and (positive > 0).all() and positive.max() > 5 * positive.min():
            ax.set_yscale("log")
        ax.set_title(column, fontsize=9)
    fig.tight_layout()
    save_figure(fig, path, dpi=dpi)
    plt.close(fig)
    return path


def _nmse_figure(done, group, path, dpi):
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(4.4, 4.0))
    lows = []
    for name, part in _groups_of(done, group):
        first, final = part["first NMSE"].to_numpy(float), part["final NMSE"].to_numpy(float)
        ax.loglog(first * 100, final * 100, "o", ms=4, label=name)
        lows += [np.nanmin(first), np.nanmin(final)]
    low = max(min(lows) * 100 / 2, 1e-6)
    high = max(done["first NMSE"].max(), done["final NMSE"].max()) * 100 * 2
    ax.plot([low, high], [low, high], color="grey", linewidth=0.8)
    ax.set_xlabel("first fit NMSE (%)")
    ax.set_ylabel("final NMSE (%)")
    if group is not None:
        ax.legend(fontsize=8)
    fig.tight_layout()
    save_figure(fig, path, dpi=dpi)
    plt.close(fig)
    return path


def _fmt(value) -> str:
    if isinstance(value, float):
        return "" if math.isnan(value) else f"{value:.4g}"
    return str(value)


def write_cohort_report(frame, folder, groups: list[str], seconds: float, dpi: int = 100):
    """Write ``folder/report.md`` and its figures (``folder/figures``) for the cohort table
    ``frame``, and ``folder/report.html`` (the same, figures embedded); returns the
    Markdown's path.

    Arguments:
        frame: the cohort table (`vfjax.cohort`'s DataFrame).
        folder: the cohort's output folder.
        groups: the grouping columns; the first one splits the figures.
        seconds: the run's wall time (s).
        dpi: the figures' resolution.
    """
    folder = pathlib.Path(folder)
    group = groups[0] if groups else None
    done = frame[frame["status"] == "done"]
    failed = frame[frame["status"] != "done"]
    diagnosed = "outcome" in frame.columns
    lines = [
        "# vfjax cohort",
        "",
        f"{len(frame)} recordings: {len(done)} done, {len(failed)} failed. This run: "
        f"{seconds:.0f} s. Table: [cohort.csv](cohort.csv) (and cohort.parquet); each "
        "recording's fits and report under `recordings/<name>/`.",
        "",
    ]
    if len(done):
        figure = _parameter_figure(done, group, folder / "figures" / "parameters.png", dpi)
        if figure is not None:
            by = f" by {group}" if group else ""
            lines += [f"## Fitted parameters{by}", "", "![parameters](figures/parameters.png)", ""]
        if diagnosed:
            _nmse_figure(done, group, folder / "figures" / "nmse.png", dpi)
            lines += [
                "## Error before and after the added effects",
                "",
                "![nmse](figures/nmse.png)",
                "",
            ]
        lines += _effect_lines(done, group) if diagnosed else []
        lines += _recording_lines(done, diagnosed)
    cautioned = frame[frame["cautions"] != ""] if "cautions" in frame.columns else frame[:0]
    if len(cautioned):  # what a model of sustained phonation cannot describe
        lines += ["## Cautions", "", "| recording | caution |", "|---|---|"]
        for _, row in cautioned.iterrows():
            caution = str(row["cautions"]).replace("|", "/")
            lines.append(f"| {row['recording']} | {caution} |")
        lines.append("")
    if len(failed):
        lines += ["## Failures", "", "| recording | reason |", "|---|---|"]
        for _, row in failed.iterrows():
            reason = str(row["reason"]).replace("|", "/")
            lines.append(f"| {row['recording']} | {reason} |")
        lines.append("")
    return write_markdown_report(folder / "report.md", "\n".join(lines))


def _effect_lines(done, group) -> list[str]:
    effects = sorted({e for v in done["effects needed"] for e in str(v).split("; ") if e})
    parts = _groups_of(done, group)
    lines = ["## Effects found", ""]
    if not effects:
        return lines + ["No recording needed an effect of the catalogue.", ""]
    lines += [
        "| effect | " + " | ".join(n for n, _ in parts) + " |",
        "|---|" + "---|" * len(parts),
    ]
    for effect in effects:
        cells = []
        for _, part in parts:
            found = sum(effect in str(v).split("; ") for v in part["effects needed"])
            cells.append(f"{found} / {len(part)}")
        lines.append(f"| {effect} | " + " | ".join(cells) + " |")
    return lines + [""]


def _recording_lines(done, diagnosed: bool) -> list[str]:
    if diagnosed:
        lines = [
            "## Recordings",
            "",
            "| recording | NMSE first -> final | outcome | effects (calibrated p) | report |",
            "|---|---|---|---|---|",
        ]
        for _, row in done.iterrows():
            effects = [e for e in str(row["effects needed"]).split("; ") if e]
            words = ", ".join(f"{e} ({_fmt(row.get(e + ' p', float('nan')))})" for e in effects)
            name = row["recording"]
            lines.append(
                f"| {name} | {row['first NMSE']:.3%} -> {row['final NMSE']:.3%} | "
                f"{row['outcome']} | {words or 'none'} | "
                f"[report](recordings/{name}/report.md) |"
            )
    else:
        lines = ["## Recordings", "", "| recording | NMSE | fit status |", "|---|---|---|"]
        for _, row in done.iterrows():
            lines.append(f"| {row['recording']} | {row['first NMSE']:.3%} | {row['fit status']} |")
    return lines + [""]
