"""A cohort's inputs: the recordings of a folder or a manifest, how each is read, and the
key that says whether its results are still current."""

import csv
import dataclasses
import hashlib
import io
import pathlib
import re
from os import PathLike

from ..recording import (
    AREA_COLUMNS,
    MAX_TEXT_BYTES,
    Recording,
    check_frame_rate,
    table_delimiter,
)
from ..video import VIDEO_SUFFIXES

#: Suffixes of GAW tables (read with their JSON sidecar).
TABLE_SUFFIXES = (".csv", ".tsv")
#: Suffix of contour files (left and right glottal edges per image row); their frame rate
#: comes from the manifest or the cohort's ``fps``.
CONTOUR_SUFFIXES = (".txt",)
#: Manifest columns that are not grouping columns.
MANIFEST_COLUMNS = ("path", "fps")


@dataclasses.dataclass(frozen=True)
class CohortEntry:
    """One recording of a cohort.

    Attributes:
        id: its name in the cohort's outputs (the path relative to the cohort's folder or
            manifest, made safe for a file name); unique within the cohort.
        path: the input file (a GAW table, a contour file or a video).
        fps: the frame rate (Hz) where the file does not state it (contour files, some
            videos), or None.
        groups: the manifest's grouping columns for it (subject, sex, condition, ...), as
            text.
    """

    id: str
    path: pathlib.Path
    fps: float | None = None
    groups: dict = dataclasses.field(default_factory=dict)

    @property
    def kind(self) -> str:
        """ "table", "contours" or "video", from the file's suffix."""
        suffix = self.path.suffix.lower()
        if suffix in TABLE_SUFFIXES:
            return "table"
        if suffix in CONTOUR_SUFFIXES:
            return "contours"
        return "video"

    def companions(self) -> list[pathlib.Path]:
        """The files read with it: a table's sidecar, an MRAW header's raw frames."""
        suffix = self.path.suffix.lower()
        if suffix in TABLE_SUFFIXES:
            return [self.path.with_suffix(".json")]
        if suffix in (".cih", ".cihx"):
            return [self.path.with_suffix(".mraw")]
        return []


def _safe_id(relative: pathlib.PurePath) -> str:
    text = "__".join(relative.parts)
    return re.sub(r"[^A-Za-z0-9._-]+", "_", text).strip("._") or "recording"


#: Bytes of a text file read to tell whether it is a recording.
_SNIFF_BYTES = 1 << 16


def _first_line(path: pathlib.Path) -> str:
    """The first line of ``path`` that is neither empty nor a ``#`` comment ("" if none in
    its first `_SNIFF_BYTES`)."""
    with open(path, "rb") as f:
        head = f.read(_SNIFF_BYTES).decode("utf-8-sig", errors="replace")
    for line in head.splitlines():
        if line.strip() and not line.lstrip().startswith("#"):
            return line
    return ""


def _is_input(path: pathlib.Path) -> bool:
    """Whether a file found in a cohort's folder is a recording: a video (by its suffix), a
    table whose header names an area column, or a contour file whose first line is numbers
    (a README.txt or a manifest beside the recordings is not one)."""
    suffix = path.suffix.lower()
    if suffix in VIDEO_SUFFIXES:
        return True
    if suffix in TABLE_SUFFIXES:  # the header read as the loader reads it (quotes and all)
        try:
            cells = next(csv.reader([_first_line(path)], delimiter=table_delimiter(path)), [])
        except csv.Error:
            return False
        header = [c.strip() for c in cells]
        return any(c in header for c in AREA_COLUMNS)
    if suffix in CONTOUR_SUFFIXES:
        tokens = _first_line(path).split()
        return bool(tokens) and all(_is_number(t) for t in tokens)
    return False


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def find_entries(
    folder: str | PathLike, fps: float | None = None, exclude: str | PathLike | None = None
) -> list[CohortEntry]:
    """Every recording under ``folder`` (recursively, hidden files and folders skipped):
    GAW tables (``.csv``/``.tsv`` whose header names an area column, with a ``.json``
    sidecar or read at ``fps``), contour files (``.txt`` of numbers) and videos, in sorted
    order. Other files (notes, a manifest, a README.txt) are left out.

    Arguments:
        folder: the cohort's folder.
        fps: frame rate (Hz) for files that do not state one (contour files, tables without
            a sidecar).
        exclude: a folder to leave out (the cohort's output folder, when it lies inside).
    """
    folder = pathlib.Path(folder)
    if not folder.is_dir():
        raise FileNotFoundError(f"cohort folder {folder} does not exist")
    if fps is not None:
        fps = check_frame_rate(fps, "fps")
    exclude = pathlib.Path(exclude).resolve() if exclude is not None else None
    entries = []
    for path in sorted(folder.rglob("*")):
        relative = path.relative_to(folder)
        if any(part.startswith(".") for part in relative.parts) or not path.is_file():
            continue
        if exclude is not None and path.resolve().is_relative_to(exclude):
            continue
        if _is_input(path):
            entries.append(CohortEntry(_safe_id(relative.with_suffix("")), path, fps))
    _check_unique(entries, folder)
    if not entries:
        raise ValueError(
            f"no recordings in {folder}: expected GAW tables (.csv/.tsv with an area "
            f"column), contour files (.txt) or videos ({', '.join(VIDEO_SUFFIXES)})"
        )
    return entries


def read_manifest(path: str | PathLike, fps: float | None = None) -> list[CohortEntry]:
    """The recordings a manifest lists: a CSV with a ``path`` column (relative to the
    manifest's folder, or absolute), an optional ``fps`` column (Hz, for files that do not
    state their frame rate; empty where they do) and any grouping columns (subject, sex,
    condition, ...), kept as text.

    Arguments:
        path: the manifest (CSV).
        fps: frame rate (Hz) for files that state none and whose row leaves ``fps`` empty.

    Raises:
        ValueError: no ``path`` column, a listed file twice, a frame rate that is not a
            positive number, or no rows; the message names the row.
    """
    path = pathlib.Path(path)
    size = path.stat().st_size
    if size > MAX_TEXT_BYTES:
        raise ValueError(f"{path}: {size} bytes, more than a manifest may hold")
    text = path.read_text(encoding="utf-8-sig")
    reader = csv.DictReader(io.StringIO(text))
    if reader.fieldnames is None or "path" not in reader.fieldnames:
        raise ValueError(f"{path}: a manifest needs a 'path' column, got {reader.fieldnames}")
    groups = [c for c in reader.fieldnames if c not in MANIFEST_COLUMNS and c]
    entries = []
    for line, row in enumerate(reader, start=2):
        where = f"{path}, line {line}"
        name = (row.get("path") or "").strip()
        if not name:
            raise ValueError(f"{where}: empty path")
        file = pathlib.Path(name)
        file = file if file.is_absolute() else path.parent / file
        rate = (row.get("fps") or "").strip()
        if rate:
            try:
                rate = float(rate)
            except ValueError:
                raise ValueError(f"{where}: fps {rate!r} is not a number") from None
            rate = check_frame_rate(rate, f"{where}: fps")
        else:
            rate = fps
        relative = pathlib.PurePath(name).with_suffix("")
        if relative.is_absolute():
            relative = pathlib.PurePath(*relative.parts[1:])
        entries.append(
            CohortEntry(
                _safe_id(relative),
                file,
                rate,
                {g: (row.get(g) or "").strip() for g in groups},
            )
        )
    if not entries:
        raise ValueError(f"{path}: the manifest lists no recordings")
    _check_unique(entries, path)
    return entries


def _check_unique(entries, where) -> None:
    seen = {}
    for e in entries:
        if e.id in seen and seen[e.id].path.resolve() == e.path.resolve():
            raise ValueError(f"{where}: lists {e.path} twice")
        if e.id in seen:
            raise ValueError(
                f"{where}: {seen[e.id].path} and {e.path} have the same name in the cohort "
                f"({e.id!r}); list each recording once, under distinct names"
            )
        seen[e.id] = e


def content_key(entry: CohortEntry, settings: str) -> str:
    """A digest of what the recording's results depend on: the bytes of its file and its
    companions (`CohortEntry.companions`), its frame rate and ``settings`` (the cohort's
    options and vfjax's version). A missing file digests as missing (its failure is kept
    like a result, and redone when the file appears)."""
    h = hashlib.sha256()
    h.update(settings.encode())
    h.update(repr(entry.fps).encode())
    for path in [entry.path, *entry.companions()]:
        h.update(path.name.encode())
        try:
            with open(path, "rb") as f:
                for block in iter(lambda: f.read(1 << 20), b""):
                    h.update(block)
        except FileNotFoundError:
            h.update(b"<missing>")
    return h.hexdigest()


def load_entry(entry: CohortEntry) -> Recording:
    """Read the recording: a table with its sidecar (or at ``entry.fps`` where it has none;
    an ``entry.fps`` other than the sidecar's is an error), a contour file at ``entry.fps``, or a
    video segmented into its glottal area (with per-fold areas split by the glottal
    midline, where the glottis spans rows to split). Named by ``entry.id``."""
    from ..recording import load_contours, load_recording

    kind = entry.kind
    if kind == "table":
        rec = load_recording(entry.path, fps=entry.fps)
    elif kind == "contours":
        if entry.fps is None:
            raise ValueError(
                f"{entry.path.name}: a contour file carries no frame rate; give it in the "
                "manifest's fps column (or the cohort's fps)"
            )
        rec = load_contours(entry.path, entry.fps)
    else:
        rec = _load_video(entry)
    return dataclasses.replace(rec, name=entry.id)


def _load_video(entry: CohortEntry) -> Recording:
    from ..segmentation import video_to_recording

    return video_to_recording(entry.path, entry.fps, folds=True)
