"""A cohort's output folder: one folder per recording, each written whole or not at all.

    DIR/cohort.json                  what ran (the options, vfjax's version)
    DIR/recordings/<id>/result.json  the recording's table row and its content key
    DIR/recordings/<id>/...          its fits (JSON) and, diagnosed, its report and figures
    DIR/cohort.csv, cohort.parquet   the cohort table
    DIR/report.md, DIR/figures/      the cohort report

A recording's folder is filled in a hidden staging folder beside it and renamed into place
when complete; ``result.json`` is written last, so a folder with it is whole. A run killed
at any moment leaves at most hidden staging folders, which the next run removes.
"""

import json
import os
import pathlib
import shutil

RESULT_FILE = "result.json"
SETTINGS_FILE = "cohort.json"


class CohortFolder:
    """The output folder of a cohort run (see the module)."""

    def __init__(self, folder):
        self.root = pathlib.Path(folder)
        self.recordings = self.root / "recordings"

    def check(self) -> None:
        """Refuse a folder that holds something other than a cohort's outputs."""
        if self.root.exists() and not self.root.is_dir():
            raise ValueError(f"cohort output {self.root} exists and is not a folder")
        if self.root.is_dir() and any(self.root.iterdir()):
            if not (self.root / SETTINGS_FILE).is_file():
                raise ValueError(
                    f"output folder {self.root} is not empty and holds no cohort "
                    f"({SETTINGS_FILE} is missing): name an empty or new folder with --out"
                )

    def prepare(self, settings: dict) -> None:
        """Create the folder, record ``settings`` and remove staging folders that a killed
        run left."""
        self.recordings.mkdir(parents=True, exist_ok=True)
        from ..io import write_json

        write_json(self.root / SETTINGS_FILE, settings)
        for leftover in self.recordings.glob(".*"):
            shutil.rmtree(leftover, ignore_errors=True)

    def folder(self, entry_id: str) -> pathlib.Path:
        return self.recordings / entry_id

    def done(self, entry_id: str, key: str) -> dict | None:
        """The recording's stored row if its results are current (same content key), else
        None (missing, unreadable, or made from other inputs or settings)."""
        path = self.folder(entry_id) / RESULT_FILE
        try:
            stored = json.loads(path.read_text(encoding="utf-8"))
        except (OSError, ValueError):
            return None
        if not isinstance(stored, dict) or stored.get("key") != key:
            return None
        row = stored.get("row")
        return row if isinstance(row, dict) else None

    def commit(self, entry_id: str, key: str, row: dict, write=None) -> pathlib.Path:
        """Write the recording's folder whole: ``write(stage)`` fills a staging folder with
        the recording's files, then its row goes in ``result.json`` and the folder replaces
        any earlier one of the same recording. Returns the folder."""
        from ..io import new_entry, write_json

        self.recordings.mkdir(parents=True, exist_ok=True)
        stage = new_entry(self.recordings, f".{entry_id}.partial-{os.getpid()}-", folder=True)
        final = self.folder(entry_id)
        try:
            if write is not None:
                write(stage)
            write_json(stage / RESULT_FILE, {"key": key, "row": row})
            old = None
            if final.exists():
                old = new_entry(self.recordings, f".{entry_id}.old-{os.getpid()}-", folder=True)
                os.replace(final, old / "folder")
            os.replace(stage, final)
            if old is not None:
                shutil.rmtree(old, ignore_errors=True)
        finally:
            shutil.rmtree(stage, ignore_errors=True)
        return final
