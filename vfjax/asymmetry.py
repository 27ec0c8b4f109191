"""Left and right folds: the glottal midline, per-fold glottal areas and asymmetry indices.

The glottis is taken as lying along the image's rows (its posterior and anterior ends at the
top and bottom of the glottal region), as in the contour files of ``shared/data/real`` and in
laryngeal high-speed video. The **glottal midline** is the straight line through the glottis's
two ends over the whole recording: at each end, the column where the folds meet, from the
glottis's centre columns over the frames and rows within `END_BAND` of the glottal length from
that end, extrapolated to zero width (folds that open unequally lean each row's centre toward
the wider one, in proportion to the opening). Each frame's area
is split by the midline into the image-left fold's part (left of the line) and the
image-right fold's (the rest); the two add up to the frame's area exactly.

The indices are those of OpenHSV (Kist et al. 2021), computed per glottal cycle of the total
area (cycles as in `vfjax.descriptors`, from one opening to the next) and averaged:

| index | per cycle | symmetric folds |
|---|---|---|
| amplitude symmetry index, ASI | min(max A_l, max A_r) / max(max A_l, max A_r) | 1 |
| phase asymmetry index, PAI | abs(frame of max A_l - frame of max A_r) / frames in the cycle | 0 |

The same functions serve measured and simulated per-fold areas.
"""

import dataclasses

import numpy as np

from .descriptors import detect_cycles
from .recording import Recording

#: Share of the glottal length, at each end, whose centre columns locate that end.
END_BAND = 0.1


@dataclasses.dataclass(frozen=True)
class Midline:
    """The glottal midline: the column ``column(row)`` of the line through the glottis's ends.

    Attributes:
        top: (row, column) of the glottis's end at the top of the image (pixels).
        bottom: (row, column) of its end at the bottom of the image (pixels).
    """

    top: tuple[float, float]
    bottom: tuple[float, float]

    def column(self, row) -> np.ndarray:
        """The midline's column (pixels, fractional) at image row(s) ``row``."""
        (r0, c0), (r1, c1) = self.top, self.bottom
        slope = (c1 - c0) / (r1 - r0) if r1 != r0 else 0.0
        return c0 + (np.asarray(row, dtype=float) - r0) * slope

    def image_column(self, row) -> np.ndarray:
        """The midline's column at image row(s) ``row`` in image coordinates (pixel j's
        centre at j, as matplotlib's ``imshow`` draws it): the edges' 1-based columns put
        pixel j over [j + 1, j + 2)."""
        return self.column(row) - 1.5


def _rows_and_centres(edges: np.ndarray) -> tuple[np.ndarray, ...]:
    """(frame, row, centre column, width) of every row the glottis reaches in ``edges``."""
    left, right = edges[:, 0], edges[:, 1]
    reached = (left > 0) & (right > 0) & (right > left)
    frames, rows = np.nonzero(reached)
    centres = 0.5 * (left[frames, rows] + right[frames, rows])
    return frames, rows, centres, right[frames, rows] - left[frames, rows]


def _end_column(rows: np.ndarray, centres: np.ndarray, widths: np.ndarray) -> float:
    """The column where the folds meet at one end of the glottis, at the median of ``rows``:
    the centres of the narrower half of the rows near that end, fitted linearly in row (a
    slanted glottis) and width, at zero width. Folds that open unequally shift each row's
    centre toward the wider one in proportion to the opening, so the median centre would
    lean toward it; the fit at zero width does not. Without the width where the widths
    hardly vary; the median centre with too few rows; kept within the centres seen."""
    at = np.median(rows)
    # the narrower half of the rows: the extrapolation stays short, and a glottis whose end
    # stays open (a chink) does not lend it wide rows
    narrow = widths <= np.median(widths)
    r, c, w = rows[narrow], centres[narrow], widths[narrow]
    if c.size < 5 or np.ptp(r) == 0:
        return float(np.median(centres))
    columns = [np.ones_like(w), r - at] + ([w] if np.std(w) >= 0.25 else [])
    coef, *_ = np.linalg.lstsq(np.stack(columns, axis=1), c, rcond=None)
    return float(np.clip(coef[0], centres.min(), centres.max()))


def _edges_from_masks(masks: np.ndarray) -> np.ndarray:
    """Per-row edges (left column, right column + 1, in 1-based columns: pixel j covers
    [j + 1, j + 2)) of masks; 0 where a row has no glottis (the contour files' convention).

    Binary masks give each row's outer edges. A coverage (each pixel's share of glottis)
    gives sub-pixel edges: a row's width is its summed share and its centre the
    share-weighted centre of its pixels, so that the glottal midline is not rounded to half
    a pixel; a row whose share sums to less than half a pixel has no glottis.
    """
    masks = np.asarray(masks)
    n, h, w = masks.shape
    edges = np.zeros((n, 2, h))
    if np.issubdtype(masks.dtype, np.floating):
        share = np.clip(masks, 0.0, 1.0)
        width = share.sum(axis=2)
        centre = (share * (np.arange(w) + 1.5)).sum(axis=2) / np.maximum(width, 1e-12)
        some = width >= 0.5
        edges[:, 0] = np.where(some, centre - 0.5 * width, 0.0)
        edges[:, 1] = np.where(some, centre + 0.5 * width, 0.0)
        return edges
    masks = masks.astype(bool)
    any_px = masks.any(axis=2)
    first = np.argmax(masks, axis=2).astype(float)
    last = (w - np.argmax(masks[:, :, ::-1], axis=2)).astype(float)
    # a glottis touching column 0 keeps a non-zero edge: columns count from 1 here
    edges[:, 0] = np.where(any_px, first + 1.0, 0.0)
    edges[:, 1] = np.where(any_px, last + 1.0, 0.0)
    return edges


def glottal_midline(
    edges: tuple[np.ndarray, np.ndarray] | None = None, masks: np.ndarray | None = None
) -> Midline:
    """The glottal midline of a recording, from its edges or its masks.

    Arguments:
        edges: (frames, 2, rows) left and right edge columns per image row (pixels; 0 where
            the glottis does not reach the row), as `vfjax.Recording.edges`.
        masks: (frames, height, width) glottis masks, binary or each pixel's share of
            glottis, as `vfjax.Recording.masks` (used when ``edges`` is None).

    Raises:
        ValueError: without edges or masks, or when the glottis never spans two rows.
    """
    if edges is None:
        if masks is None:
            raise ValueError("a glottal midline needs edges or masks")
        edges = _edges_from_masks(masks)
    edges = np.asarray(edges, dtype=float)
    if edges.ndim != 3 or edges.shape[1] != 2:
        raise ValueError(f"edges must have shape (frames, 2, rows), got {edges.shape}")
    _, rows, centres, widths = _rows_and_centres(edges)
    if rows.size == 0 or rows.min() == rows.max():
        raise ValueError(
            "the glottis never spans two image rows: no midline (and no left/right split)"
        )
    r0, r1 = float(rows.min()), float(rows.max())
    band = max(END_BAND * (r1 - r0), 1.0)
    top, bottom = rows <= r0 + band, rows >= r1 - band
    return Midline(
        top=(float(np.median(rows[top])), _end_column(rows[top], centres[top], widths[top])),
        bottom=(
            float(np.median(rows[bottom])),
            _end_column(rows[bottom], centres[bottom], widths[bottom]),
        ),
    )


def fold_areas(
    recording: Recording, midline: Midline | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """The image-left and image-right folds' glottal areas per frame (pixels), split by the
    glottal midline; they add up to the recording's area.

    Arguments:
        recording: a `vfjax.Recording` with ``folds`` (per-fold areas, returned as they
            are), ``edges`` (contour files) or ``masks`` (video).
        midline: the midline to split by; default `glottal_midline` of the recording.

    Raises:
        ValueError: for a recording with neither edges nor masks (a bare GAW has no folds).
    """
    edges, masks = recording.edges, recording.masks
    if recording.folds is not None and midline is None:
        return recording.folds[:, 0].copy(), recording.folds[:, 1].copy()
    if edges is None and masks is None:
        raise ValueError(
            f"{recording.name}: per-fold areas need the glottis's edges (a contour file) or "
            "masks (a segmented video); this recording holds its total area only"
        )
    if midline is None:
        midline = glottal_midline(edges=edges, masks=masks)
    if edges is not None:
        edges = np.asarray(edges, dtype=float)
        left, right = edges[:, 0], edges[:, 1]
        width = np.where((left > 0) & (right > 0), np.maximum(right - left, 0.0), 0.0)
        mid = midline.column(np.arange(edges.shape[2]))
        left_part = np.clip(mid - left, 0.0, width)
        left_area = left_part.sum(axis=1)
        return left_area, width.sum(axis=1) - left_area
    # a binary mask counts whole pixels; a segmented video's coverage, each pixel's share
    masks = np.asarray(masks, dtype=float)
    # pixel j of a row covers columns [j + 1, j + 2) in the edges' 1-based columns
    mid = midline.column(np.arange(masks.shape[1]))[:, None]
    share = np.clip(mid - (np.arange(masks.shape[2])[None, :] + 1.0), 0.0, 1.0)
    left_area = (masks * share[None]).sum(axis=(1, 2))
    return left_area, masks.sum(axis=(1, 2)) - left_area


def with_fold_areas(recording, midline: Midline | None = None):
    """A copy of ``recording`` whose ``folds`` hold its per-fold areas (`fold_areas`, split
    by ``midline`` or the recording's own glottal midline), so that a model with two folds
    (`vfjax.LeftRightAsymmetry`) is fitted to them."""
    left, right = fold_areas(recording, midline)
    return dataclasses.replace(recording, folds=np.stack([left, right], axis=1))


@dataclasses.dataclass(frozen=True)
class AsymmetryIndices:
    """Left-right asymmetry of a recording (OpenHSV's definitions; see the module).

    Attributes:
        asi: amplitude symmetry index (1 symmetric, 0 one fold still), mean over cycles.
        pai: phase asymmetry index (0 in phase; share of the cycle between the folds'
            maxima), mean over cycles.
        n_cycles: complete cycles averaged over.
    """

    asi: float
    pai: float
    n_cycles: int


def asymmetry_indices(left, right, fps: float, level: float = 0.05) -> AsymmetryIndices:
    """ASI and PAI of per-fold areas ``left`` and ``right`` (same unit, one value per frame at
    ``fps`` Hz), per cycle of their sum (`vfjax.descriptors.detect_cycles` at ``level``);
    NaN without a complete cycle."""
    left, right = np.asarray(left, dtype=float), np.asarray(right, dtype=float)
    if left.shape != right.shape or left.ndim != 1:
        raise ValueError(
            f"left and right must be 1-D areas of equal length, got {left.shape}, {right.shape}"
        )
    cycles = detect_cycles(left + right, fps, level)
    asi, pai = [], []
    for c in cycles:
        i0, i1 = int(np.floor(c.opening * fps)), int(np.ceil(c.end * fps))
        seg_l, seg_r = left[i0 : i1 + 1], right[i0 : i1 + 1]
        hi = max(seg_l.max(), seg_r.max())
        asi.append(min(seg_l.max(), seg_r.max()) / hi if hi > 0 else np.nan)
        pai.append(abs(int(np.argmax(seg_l)) - int(np.argmax(seg_r))) / seg_l.size)
    if not cycles:
        return AsymmetryIndices(float("nan"), float("nan"), 0)
    return AsymmetryIndices(float(np.nanmean(asi)), float(np.mean(pai)), len(cycles))
