"""A measured (or simulated) glottal area waveform with its frame rate and unit."""

import csv
import dataclasses
import json
import math
import pathlib
import warnings

import numpy as np

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
        masks: optional per-frame binary glottis masks, shape (frames, height, width).
    """

    area: np.ndarray
    fps: float
    unit: str = "px"
    metadata: dict = dataclasses.field(default_factory=dict)
    name: str = "recording"
    edges: np.ndarray | None = None
    masks: np.ndarray | None = None

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
        if not (isinstance(self.fps, (int, float)) and math.isfinite(self.fps) and self.fps > 0):
            raise ValueError(f"fps (frame rate) must be a number > 0 Hz, got {self.fps!r}")
        if self.unit not in AREA_UNITS:
            raise ValueError(f"unit must be one of {AREA_UNITS}, got {self.unit!r}")
        for extra in ("edges", "masks"):
            value = getattr(self, extra)
            if value is not None and len(value) != area.size:
                raise ValueError(f"{extra} has {len(value)} frames, area has {area.size}")
        area.setflags(write=False)
        object.__setattr__(self, "area", area)
        object.__setattr__(self, "fps", float(self.fps))

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
            raise ValueError(f"crop [{start}, {stop}) s is outside the recording's "
                             f"{self.duration:.6g} s or shorter than 2 frames")  # fmt: skip
        sl = slice(i0, i1)
        return dataclasses.replace(
            self, area=self.area[sl],
            edges=None if self.edges is None else self.edges[sl],
            masks=None if self.masks is None else self.masks[sl],
        )  # fmt: skip

    def resample(self, fps: float) -> "Recording":
        """The GAW at another frame rate (Hz), by linear interpolation over the same span.
        Per-frame edges and masks do not survive resampling and are dropped."""
        if not (isinstance(fps, (int, float)) and math.isfinite(fps) and fps > 0):
            raise ValueError(f"fps (frame rate) must be a number > 0 Hz, got {fps!r}")
        t = np.arange(int(np.floor(self.duration * fps + 1e-9)) + 1) / fps
        area = np.interp(t, self.time, self.area)
        meta = {**self.metadata, "resampled_from_fps": self.fps}
        return Recording(area=area, fps=float(fps), unit=self.unit, metadata=meta, name=self.name)

    @classmethod
    def from_simulation(cls, sim, fps: float, name: str = "simulated", **metadata):
        """A recording of a `Simulation`'s GAW (pixels), negative areas clipped to 0."""
        area = np.clip(np.asarray(sim.area), 0.0, None)
        return cls(area=area, fps=fps, unit="px", metadata=metadata, name=name)


def load_recording(path, sidecar=None) -> Recording:
    """Load a GAW table (CSV or TSV) and its JSON sidecar.

    The table needs an area column (``area_px``, ``area_mm2``, ``area_cm2`` or ``area``, the
    unit then from the sidecar). The sidecar (default: the table's path with ``.json``) gives
    ``fps`` and ``area_unit``; see ``data_schema/recording.schema.json``.
    """
    path = pathlib.Path(path)
    if not path.exists():
        raise FileNotFoundError(f"no recording at {path}")
    sidecar = pathlib.Path(sidecar) if sidecar else path.with_suffix(".json")
    if not sidecar.exists():
        raise FileNotFoundError(f"no sidecar {sidecar}: it must give fps and area_unit")
    meta = json.loads(sidecar.read_text())
    validate_sidecar(meta, sidecar)
    delimiter = "\t" if path.suffix.lower() in (".tsv", ".tab") else ","
    with path.open(newline="") as f:
        rows = list(csv.DictReader(f, delimiter=delimiter))
    if not rows:
        raise ValueError(f"{path}: no rows")
    columns = rows[0].keys()
    unit = meta.get("area_unit")
    for name in ("area_px", "area_mm2", "area_cm2", "area"):
        if name in columns:
            column = name
            if name != "area":
                col_unit = name.split("_", 1)[1]
                if unit is not None and unit != col_unit:
                    warnings.warn(
                        f"{path}: column {name} but sidecar area_unit {unit!r}; using {col_unit!r}",
                        stacklevel=2,
                    )
                unit = col_unit
            break
    else:
        raise ValueError(f"{path}: no area column (area_px, area_mm2, area_cm2 or area)")
    if unit is None:
        raise ValueError(f"{sidecar}: missing 'area_unit' for the column 'area'")
    try:
        area = np.array([float(r[column]) for r in rows])
    except ValueError as err:
        raise ValueError(f"{path}: non-numeric value in column {column}: {err}") from None
    fps = meta["fps"]
    return Recording(area=area, fps=fps, unit=unit, metadata=meta, name=path.stem)


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
    if not (isinstance(fps, (int, float)) and math.isfinite(fps) and fps > 0):
        raise ValueError(f"fps (frame rate) must be a number > 0 Hz, got {fps!r}")
    lines = [ln for ln in path.read_text().splitlines() if ln.strip() and not ln.startswith("#")]
    if len(lines) % 2:
        raise ValueError(f"{path}: {len(lines)} edge lines; expected two (left, right) per frame")
    try:
        rows = [np.array(ln.split(), dtype=float) for ln in lines]
    except ValueError as err:
        raise ValueError(f"{path}: non-numeric edge value: {err}") from None
    widths = {r.size for r in rows}
    if len(widths) != 1:
        raise ValueError(f"{path}: edge lines of different lengths {sorted(widths)}")
    edges = np.stack(rows).reshape(-1, 2, rows[0].size)
    left, right = edges[:, 0], edges[:, 1]
    both = (left > 0) & (right > 0)
    width = np.where(both, right - left, 0.0)
    if np.any(width < 0):
        frame = int(np.flatnonzero((width < 0).any(axis=1))[0])
        warnings.warn(f"{path}: right edge left of the left edge in frame {frame}; "
                      "those rows count as closed", stacklevel=2)  # fmt: skip
        width = np.maximum(width, 0.0)
    meta = {"source": str(path.name), "fps_given": fps, **metadata}
    name = path.name.removesuffix("_segdata.txt").removesuffix(".txt")
    return Recording(area=width.sum(axis=1), fps=fps, unit="px", metadata=meta, name=name,
                     edges=edges)  # fmt: skip


def validate_sidecar(meta: dict, where="sidecar") -> None:
    """Check a recording sidecar against ``data_schema/recording.schema.json``; the error
    names the field and what is wrong with it."""
    import jsonschema

    schema_path = pathlib.Path(__file__).parent / "schemas" / "recording.schema.json"
    schema = json.loads(schema_path.read_text())
    errors = sorted(jsonschema.Draft202012Validator(schema).iter_errors(meta), key=str)
    if errors:
        lines = []
        for err in errors:
            field = ".".join(map(str, err.absolute_path)) or "(top level)"
            lines.append(f"{field}: {err.message}")
        raise ValueError(f"{where}: invalid recording sidecar: " + "; ".join(lines))
