"""A measured (or simulated) glottal area waveform with its frame rate and unit."""

import csv
import dataclasses
import io
import json
import math
import pathlib
import warnings

import numpy as np

from ._validate import check_schema

AREA_UNITS = ("px", "mm2", "cm2")


@dataclasses.dataclass(frozen=True)
class Recording:
    """A GAW: one area per frame, at a known frame rate.

    Attributes:
        area: glottal area per frame, in ``unit``.
        fps: frame rate (Hz).
        unit: "px", "mm2" or "cm2".
        metadata: subject and source information (sex, vocal_fold_length_cm, ...).
        name: a short label (e.g. the file stem).
        edges: optional glottal edge traces, shape (frames, 2, rows): the left and right
            edge column of each image row (0 where the glottis does not reach the row), as
            in contour segmentations; kept for asymmetry analysis.
        masks: optional per-frame glottis masks, shape (frames, height, width): binary, or
            each pixel's share of glottis in [0, 1] (a segmented video's coverage, whose sum
            is the area).
        folds: optional per-fold areas, shape (frames, 2): the glottal area left and right
            of the glottal midline in the image, in ``unit``, adding up to ``area`` (within
            1 % of its peak, or 1 in ``unit``). A fit of a model with two folds
            (`vfjax.LeftRightAsymmetry`) fits them; `vfjax.asymmetry.fold_areas` reads them
            first.
    """

    area: np.ndarray
    fps: float
    unit: str = "px"
    metadata: dict = dataclasses.field(default_factory=dict)
    name: str = "recording"
    edges: np.ndarray | None = None
    masks: np.ndarray | None = None
    folds: np.ndarray | None = None

    def __post_init__(self):
        area = np.asarray(self.area, dtype=float)
        if area.ndim != 1 or area.size < 2:
            raise ValueError(f"area must be a 1-D series of at least 2 frames, got {area.shape}")
        if not np.all(np.isfinite(area)):
            bad = np.flatnonzero(~np.isfinite(area))
            raise ValueError(f"area has NaN or infinite values at frames {bad[:10].tolist()}")
        if np.any(area < 0):
            bad = np.flatnonzero(area < 0)
            raise ValueError(f"area is negative at frames {bad[:10].tolist()}: an area is >= 0")
        fps = check_frame_rate(self.fps, f"{self.name}: fps")
        if self.unit not in AREA_UNITS:
            raise ValueError(f"unit must be one of {AREA_UNITS}, got {self.unit!r}")
        for extra in ("edges", "masks", "folds"):
            value = getattr(self, extra)
            if value is not None and len(value) != area.size:
                raise ValueError(f"{extra} has {len(value)} frames, area has {area.size}")
        if self.folds is not None:
            folds = np.asarray(self.folds, dtype=float)
            if folds.shape != (area.size, 2) or not np.all(np.isfinite(folds)):
                raise ValueError(
                    f"folds must hold finite left and right areas, shape ({area.size}, 2), "
                    f"got shape {folds.shape}"
                )
            if np.any(folds < 0):
                raise ValueError("folds: a fold's area is negative; an area is >= 0")
            off = np.abs(folds.sum(axis=1) - area).max()
            if off > max(0.01 * area.max(), 1.0):
                raise ValueError(
                    f"folds do not add up to the area: off by up to {off:.3g} {self.unit}"
                )
            folds.setflags(write=False)
            object.__setattr__(self, "folds", folds)
        area.setflags(write=False)
        object.__setattr__(self, "area", area)
        object.__setattr__(self, "fps", fps)

    @property
    def n_frames(self) -> int:
        return int(self.area.size)

    @property
    def time(self) -> np.ndarray:
        """Frame times (s) from 0."""
        return np.arange(self.n_frames) / self.fps

    @property
    def duration(self) -> float:
        """Time from the first to the last frame (s)."""
        return (self.n_frames - 1) / self.fps

    def crop(self, start: float = 0.0, stop: float | None = None) -> "Recording":
        """The frames from time ``start`` to ``stop`` (s, from the first frame; stop excluded)."""
        i0 = int(round(start * self.fps))
        i1 = self.n_frames if stop is None else int(round(stop * self.fps))
        if not 0 <= i0 < i1 <= self.n_frames or i1 - i0 < 2:
            raise ValueError(
                f"crop [{start}, {stop}) s is outside the recording's "
                f"{self.duration:.6g} s or shorter than 2 frames"
            )
        sl = slice(i0, i1)
        return dataclasses.replace(
            self,
            area=self.area[sl],
            edges=None if self.edges is None else self.edges[sl],
            masks=None if self.masks is None else self.masks[sl],
            folds=None if self.folds is None else self.folds[sl],
        )

    def resample(self, fps: float) -> "Recording":
        """The GAW at another frame rate (Hz), by linear interpolation over the same span.
        Per-frame edges, masks and per-fold areas do not survive resampling and are
        dropped."""
        fps = check_frame_rate(fps, f"{self.name}: resampling fps")
        t = np.arange(int(np.floor(self.duration * fps + 1e-9)) + 1) / fps
        area = np.interp(t, self.time, self.area)
        meta = {**self.metadata, "resampled_from_fps": self.fps}
        return Recording(area=area, fps=float(fps), unit=self.unit, metadata=meta, name=self.name)

    @classmethod
    def from_simulation(cls, sim, fps: float, name: str = "simulated", **metadata):
        """A recording of a `Simulation`'s GAW (pixels), negative areas clipped to 0."""
        area = np.clip(np.asarray(sim.area), 0.0, None)
        return cls(area=area, fps=fps, unit="px", metadata=metadata, name=name)


#: Frame rates (Hz) a laryngeal high-speed recording can have. Vocal folds vibrate at about
#: 50-1 000 Hz: below 1 000 frames per second a glottal cycle spans too few frames to be
#: described or fitted (a container's playback rate, 25-60 fps, is no camera rate); the
#: fastest laryngeal cameras record up to about 100 000 frames per second.
FRAME_RATE_RANGE_HZ = (1000.0, 100_000.0)


def check_frame_rate(fps, where: str = "recording", hint: str = "") -> float:
    """``fps`` as a float, or ValueError (naming ``where``, ending with ``hint``) unless it
    is a number within `FRAME_RATE_RANGE_HZ`."""
    low, high = FRAME_RATE_RANGE_HZ
    if isinstance(fps, bool) or not isinstance(fps, (int, float, np.integer, np.floating)):
        raise ValueError(f"{where}: the frame rate must be a number in Hz, got {fps!r}")
    fps = float(fps)
    if not (math.isfinite(fps) and low <= fps <= high):
        raise ValueError(
            f"{where}: a frame rate of {fps:g} Hz is not that of a laryngeal high-speed "
            f"recording; expected {low:g} to {high:g} Hz (the vocal folds vibrate at "
            "50-1000 Hz, so a slower camera cannot resolve a glottal cycle; 25-60 fps is a "
            f"playback rate){hint}"
        )
    return fps


def load_recording(path, sidecar=None, fps: float | None = None) -> Recording:
    """Load a GAW table (CSV or TSV) and its JSON sidecar.

    The table needs an area column (``area_px``, ``area_mm2``, ``area_cm2`` or ``area``, the
    unit then from the sidecar); the folds' areas, left and right of the glottal midline in
    the image, may follow as ``area_left_<unit>`` and ``area_right_<unit>`` (both, adding up
    to the area: `Recording.folds`). The sidecar (default: the table's path with ``.json``) gives
    ``fps`` and ``area_unit``; see ``data_schema/recording.schema.json``. A table without a
    sidecar is read with ``fps`` (Hz) given here and the unit its area column names.

    A ``frame`` column (integers) orders the rows: rows out of order are sorted (with a
    warning), a repeated frame is an error, and so is a gap (frame 50 followed by frame 80:
    use `load_segments` to cut such a recording into its gap-free segments). A ``time_s``
    column (s) must agree with the sidecar's frame rate to a tenth of a frame; without a
    ``frame`` column it orders the rows and locates gaps instead.

    Raises:
        FileNotFoundError: the table is missing, or its sidecar where no ``fps`` is given.
        ValueError: anything else the files get wrong (an ``fps`` other than the sidecar's,
            a table without sidecar whose area column names no unit); the message names the
            file.
    """
    path = pathlib.Path(path)
    meta, unit, spans = _read_table(path, sidecar, fps)
    if len(spans) > 1:
        (_, f1, _, _), (g0, _, _, _) = spans[0], spans[1]
        raise ValueError(
            f"{path}: frames missing: frame {f1} is followed by frame {g0} "
            f"({g0 - f1 - 1} frames missing, {len(spans) - 1} gap(s) in all). A GAW must be "
            "sampled without gaps; vfjax.recording.load_segments cuts it into segments"
        )
    return _recording(path, spans[0][2], meta, unit, folds=spans[0][3])


def load_segments(
    path, sidecar=None, min_frames: int = 2, fps: float | None = None
) -> list[Recording]:
    """Load a GAW table like `load_recording` (``sidecar`` and ``fps`` as there), cut at its
    gaps: one `Recording` per run of consecutive frames of at least ``min_frames`` frames,
    named ``<stem>_frames_<a>-<b>`` (its first and last frame numbers; its metadata gives
    ``first_frame``)."""
    path = pathlib.Path(path)
    meta, unit, spans = _read_table(path, sidecar, fps)
    out = []
    for first, last, area, folds in spans:
        if area.size >= max(min_frames, 2):
            name = f"{path.stem}_frames_{first}-{last}"
            meta_i = {**meta, "first_frame": first}
            out.append(_recording(path, area, meta_i, unit, name, folds))
    if not out:
        raise ValueError(f"{path}: no segment of at least {min_frames} consecutive frames")
    return out


#: A GAW table's area column, by preference: its unit in its name, or ("area") in the sidecar.
AREA_COLUMNS = ("area_px", "area_mm2", "area_cm2", "area")
#: Text inputs larger than this (bytes) are refused unread: a GAW table of a million frames
#: takes about 30 MB.
MAX_TEXT_BYTES = 256 * 2**20


def _read_text(path: pathlib.Path, what: str, limit: int = MAX_TEXT_BYTES) -> str:
    if path.is_file() and path.stat().st_size > limit:
        raise ValueError(
            f"{path}: {path.stat().st_size} bytes, more than a {what} can be ({limit} bytes)"
        )
    try:
        data = path.read_bytes()
    except IsADirectoryError:
        raise ValueError(f"{path}: is a folder, not a {what}") from None
    if b"\0" in data:
        raise ValueError(f"{path}: a binary file, not a {what} (text)")
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError as err:
        raise ValueError(
            f"{path}: not a {what} in UTF-8 text ({err.reason} at byte {err.start})"
        ) from None


def read_sidecar(path) -> dict:
    """A recording's JSON sidecar as a dict, validated against its schema; errors name the
    file."""
    path = pathlib.Path(path)
    if not path.exists():
        raise FileNotFoundError(f"no sidecar {path}: it must give fps and area_unit")
    text = _read_text(path, "JSON sidecar", limit=2**20)
    try:
        meta = json.loads(text)
    except json.JSONDecodeError as err:
        raise ValueError(f"{path}: invalid JSON: {err}") from None
    if not isinstance(meta, dict):
        raise ValueError(
            f"{path}: a sidecar must be a JSON object {{...}}, got {type(meta).__name__}"
        )
    validate_sidecar(meta, path)
    meta["fps"] = check_frame_rate(meta["fps"], f"{path}: fps")
    return meta


def table_delimiter(path) -> str:
    """The field separator of a GAW table: a tab for ``.tsv`` and ``.tab``, else a comma."""
    return "\t" if pathlib.Path(path).suffix.lower() in (".tsv", ".tab") else ","


def _read_table(path, sidecar, fps=None):
    """The sidecar (or ``{"fps": fps}`` for a table without one), the area unit and the
    table's runs of consecutive frames, as [(first frame, last frame, areas)]."""
    if not path.exists():
        raise FileNotFoundError(f"no recording at {path}")
    if fps is not None:
        fps = check_frame_rate(fps, f"{path}: fps")
    sidecar = pathlib.Path(sidecar) if sidecar else path.with_suffix(".json")
    if fps is not None and not sidecar.exists():
        meta = {"fps": fps}
    else:
        meta = read_sidecar(sidecar)
        if fps is not None and not math.isclose(fps, meta["fps"]):
            raise ValueError(
                f"{path}: fps {fps:g} Hz disagrees with the sidecar's ({meta['fps']:g} Hz)"
            )
    fps = meta["fps"]
    text = _read_text(path, "GAW table (CSV or TSV)")
    try:
        rows = list(csv.reader(io.StringIO(text, newline=""), delimiter=table_delimiter(path)))
    except csv.Error as err:
        raise ValueError(f"{path}: not a readable table: {err}") from None
    rows = [r for r in rows if any(cell.strip() for cell in r)]
    if len(rows) < 2:
        raise ValueError(f"{path}: no data rows under a header line")
    header = [h.strip() for h in rows[0]]
    if len(set(header)) != len(header):
        raise ValueError(f"{path}: repeated column names in the header {header}")
    unit = meta.get("area_unit")
    for name in AREA_COLUMNS:
        if name in header:
            column = name
            if name != "area":
                col_unit = name.split("_", 1)[1]
                if unit is not None and unit != col_unit:
                    warnings.warn(
                        f"{path}: column {name} but sidecar area_unit {unit!r}; using {col_unit!r}",
                        stacklevel=3,
                    )
                unit = col_unit
            break
    else:
        raise ValueError(f"{path}: no area column (area_px, area_mm2, area_cm2 or area)")
    if unit is None:
        raise ValueError(
            f"{path}: the column 'area' names no unit and there is no sidecar to give it: "
            "name the column area_px, area_mm2 or area_cm2, or write the sidecar"
        )
    body = rows[1:]
    for i, r in enumerate(body):
        if len(r) != len(header):
            raise ValueError(f"{path}: line {i + 2} has {len(r)} fields, the header {len(header)}")
    area = _column(path, header, body, column)
    # the folds' areas, left and right of the glottal midline, in the area column's unit
    sides = [column.replace("area", f"area_{side}", 1) for side in ("left", "right")]
    present = [c for c in sides if c in header]
    if len(present) == 1:
        raise ValueError(f"{path}: column {present[0]} without its other fold's ({sides})")
    folds = np.stack([_column(path, header, body, c) for c in sides], 1) if present else None
    frames = _column(path, header, body, "frame") if "frame" in header else None
    times = _column(path, header, body, "time_s") if "time_s" in header else None
    if times is not None and not np.all(np.isfinite(times)):
        raise ValueError(f"{path}: time_s has NaN or infinite values")
    if frames is not None:
        whole = np.isfinite(frames) & (frames == np.round(frames)) & (np.abs(frames) < 2**53)
        if not np.all(whole):
            raise ValueError(f"{path}: the frame column must hold whole numbers")
        frames = frames.astype(np.int64)
    elif times is not None:
        spacing = np.median(np.diff(np.sort(times))) * fps if times.size > 1 else 1.0
        if not 0.9 <= spacing <= 1.1:
            raise ValueError(
                f"{path}: time_s disagrees with the sidecar's fps of {fps:g} Hz ({sidecar}): "
                f"the times are {spacing / fps:.6g} s apart ({1 / spacing * fps:.6g} Hz)"
            )
        steps = (times - times.min()) * fps
        frames = np.round(steps).astype(np.int64)
        off = np.abs(steps - frames).max()
        if off > 0.1:
            raise ValueError(
                f"{path}: time_s disagrees with the sidecar's fps {fps:g} Hz ({sidecar}): "
                f"the times lie up to {off:.2f} frames off that rate's frame times"
            )
    else:
        frames = np.arange(len(area))
    order = np.argsort(frames, kind="stable")
    if np.any(np.diff(frames) < 0):
        warnings.warn(
            f"{path}: rows out of frame order; sorted by "
            f"{'frame' if 'frame' in header else 'time_s'}",
            stacklevel=3,
        )
    frames, area = frames[order], area[order]
    folds = None if folds is None else folds[order]
    repeated = frames[1:][np.diff(frames) == 0]
    if repeated.size:
        raise ValueError(f"{path}: frame {int(repeated[0])} appears more than once")
    if times is not None:
        times = times[order]
        offsets = times - (frames - frames[0]) / fps
        off = np.abs(offsets - np.median(offsets)).max() * fps
        if off > 0.1 and len(frames) > 1:
            implied = (
                (frames[-1] - frames[0]) / (times[-1] - times[0]) if times[-1] > times[0] else 0
            )
            raise ValueError(
                f"{path}: time_s disagrees with the sidecar's fps of {fps:g} Hz ({sidecar}): "
                f"the times imply {implied:.6g} Hz (off by up to {off:.2f} frames)"
            )
    bounds = np.flatnonzero(np.diff(frames) > 1) + 1
    pieces = [None] * (len(bounds) + 1) if folds is None else np.split(folds, bounds)
    spans = [
        (int(f[0]), int(f[-1]), a, d)
        for f, a, d in zip(np.split(frames, bounds), np.split(area, bounds), pieces)
    ]
    return meta, unit, spans


def _recording(path, area, meta, unit, name=None, folds=None) -> Recording:
    try:
        return Recording(
            area=area,
            fps=meta["fps"],
            unit=unit,
            metadata=meta,
            name=name or path.stem,
            folds=folds,
        )
    except ValueError as err:
        raise ValueError(f"{path}: {err}") from None


def _column(path, header, body, name) -> np.ndarray:
    j = header.index(name)
    values = np.empty(len(body))
    for i, r in enumerate(body):
        cell = r[j].strip()
        try:
            values[i] = float(cell)
        except ValueError:
            raise ValueError(
                f"{path}: non-numeric value {cell[:20]!r} in column {name}, line {i + 2}"
            ) from None
    return values


def load_contours(path, fps: float, **metadata) -> Recording:
    """Load a glottal contour file (``*_segdata.txt`` of the AutoGlottisSegmentation study).

    Format: a comment line, then two lines per frame: the glottis' left and right edge as a
    column index for each image row (0 where the glottis does not reach the row). The area
    of a frame is the sum over rows of ``right - left`` where both are non-zero (pixels).
    The frame rate is not in the file: give it (Hz).
    """
    path = pathlib.Path(path)
    if not path.exists():
        raise FileNotFoundError(f"no contour file at {path}")
    fps = check_frame_rate(fps, f"{path}: fps")
    text = _read_text(path, "contour file")
    lines = [ln for ln in text.splitlines() if ln.strip() and not ln.startswith("#")]
    if not lines:
        raise ValueError(
            f"{path}: no edge lines: a contour file has two lines (left and right edges) per frame"
        )
    if len(lines) % 2:
        raise ValueError(f"{path}: {len(lines)} edge lines; expected two (left, right) per frame")
    try:
        rows = [np.array(ln.split(), dtype=float) for ln in lines]
    except ValueError as err:
        raise ValueError(f"{path}: non-numeric edge value: {err}") from None
    widths = {r.size for r in rows}
    if len(widths) != 1:
        raise ValueError(f"{path}: edge lines of different lengths {sorted(widths)}")
    if rows[0].size == 0 or not all(np.all(np.isfinite(r) & (r >= 0)) for r in rows):
        raise ValueError(f"{path}: edge values must be column indices >= 0")
    edges = np.stack(rows).reshape(-1, 2, rows[0].size)
    left, right = edges[:, 0], edges[:, 1]
    both = (left > 0) & (right > 0)
    width = np.where(both, right - left, 0.0)
    if np.any(width < 0):
        frame = int(np.flatnonzero((width < 0).any(axis=1))[0])
        warnings.warn(
            f"{path}: right edge left of the left edge in frame {frame}; "
            "those rows count as closed",
            stacklevel=2,
        )
        width = np.maximum(width, 0.0)
    meta = {"source": str(path.name), "fps_given": fps, **metadata}
    name = path.name.removesuffix("_segdata.txt").removesuffix(".txt")
    try:
        return Recording(
            area=width.sum(axis=1), fps=fps, unit="px", metadata=meta, name=name, edges=edges
        )
    except ValueError as err:
        raise ValueError(f"{path}: {err}") from None


def validate_sidecar(meta: dict, where="sidecar") -> None:
    """Check a recording sidecar against ``data_schema/recording.schema.json``; the error
    names the field and what is wrong with it."""
    check_schema(meta, "recording.schema.json", where, "invalid recording sidecar")
