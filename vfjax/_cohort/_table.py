"""The cohort table: one row per recording, as a pandas DataFrame, CSV and Parquet."""

import pathlib

from ..io import atomic_path, write_text

#: Columns in this order first (those present); then the parameters, the effects' p-values
#: and intervals, the conclusion and the time.
LEADING_COLUMNS = (
    "recording",
    "path",
    "kind",
    "status",
    "reason",
    "fps [Hz]",
    "frames",
    "unit",
    "f0 [Hz]",
    "cycles",
    "open quotient",
    "speed quotient",
    "closing quotient",
    "jitter",
    "shimmer",
    "ASI",
    "PAI",
    "first NMSE",
    "final NMSE",
    "noise NMSE",
    "fit status",
    "settled NMSE",
    "settled",
    "outcome",
    "effects needed",
    "effects unconfirmed",
)
TRAILING_COLUMNS = ("conclusion", "seconds")
#: Counts (missing where a recording could not be read).
INTEGER_COLUMNS = ("frames", "cycles")


def pandas():
    """pandas, or an ImportError that says how to install it."""
    try:
        import pandas
    except ImportError as err:  # pragma: no cover - the cohort extra is installed in tests
        raise ImportError(
            "vfjax's cohorts need pandas and pyarrow: pip install 'vfjax[cohort]'"
        ) from err
    return pandas


def table(rows: list[dict], groups: list[str]):
    """The cohort table of ``rows`` (one dict per recording) as a DataFrame: the recording,
    its grouping columns, then `LEADING_COLUMNS`, the parameters and effect columns in the
    order met, and `TRAILING_COLUMNS`. Missing values are NaN (numbers) or empty (text)."""
    pd = pandas()
    frame = pd.DataFrame(rows)
    present = list(frame.columns)
    head = ["recording", *groups]
    head += [c for c in LEADING_COLUMNS if c in present and c not in head]
    tail = [c for c in TRAILING_COLUMNS if c in present]
    middle = [c for c in present if c not in head and c not in tail]
    frame = frame.reindex(columns=head + middle + tail)
    text = (
        "reason",
        "phonation breaks",
        "cautions",
        "settled",
        "outcome",
        "effects needed",
        "effects unconfirmed",
        "conclusion",
    )
    for column in (*text, *groups):
        if column in frame:
            frame[column] = frame[column].fillna("").astype(str)
    for column in INTEGER_COLUMNS:
        if column in frame:
            frame[column] = frame[column].astype("Int64")
    return frame


def write_table(frame, folder) -> tuple[pathlib.Path, pathlib.Path]:
    """Write the table as ``cohort.csv`` and ``cohort.parquet`` in ``folder``, each
    atomically; returns their paths."""
    folder = pathlib.Path(folder)
    csv = write_text(folder / "cohort.csv", frame.to_csv(index=False))
    parquet = folder / "cohort.parquet"
    with atomic_path(parquet) as tmp:
        frame.to_parquet(tmp, index=False)
    return csv, parquet
