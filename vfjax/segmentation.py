"""Glottal area from high-speed video, to a fraction of a pixel (scikit-image, SciPy).

Method, for a (frames, height, width) grey video:
1. Flicker: each frame is scaled by its median ratio to the still scene (the temporal median
   of up to 32 evenly spaced frames), which the opening glottis hardly moves.
2. Drift: each frame is registered to the still scene by a partly whitened phase correlation
   (whole-pixel shifts, one batched FFT for the whole video) and shifted back. Full whitening
   lets the sensor noise of a dim, featureless clip's empty high frequencies pick the shift.
3. Region of interest: the glottis is what moves. The temporal standard deviation of each
   pixel is thresholded (Otsu); the moving components (all of at least a tenth of the largest),
   padded, make the ROI.
4. First pass, whole pixels: a pixel's *tissue* brightness is a high percentile of its values
   over time; a frame's darkness is tissue brightness minus the pixel's value (static dark
   structures, shadows, have none); Otsu's threshold of the darkness pooled over the clearly
   open frames; holes filled, components smaller than ``min_size`` pixels dropped, only
   components touching the moving region's core kept (no opening: it would erode the thin
   slit of a nearly closed glottis).
5. Each pixel's share of glottis: where its grey level lies between the tissue's local level
   (its median over the frames in which no glottis comes near it) and the glottis's level
   (`_glottis_level`: fitted with the optics' blur to blurred-opening profiles across the
   rows of the widest frames; the glottis's median beyond the blur's reach where it is that
   wide). The boundary is where the grey level crosses half way (share 1/2).
6. Detection: the shares smoothed over a pixel above ``detect_level``, cleaned as in 4, and
   temporal consistency: a component that no neighbouring frame's glottis comes within two
   pixels of (a one-frame blob from flicker or a glint) is dropped.
7. Area: the shares summed over each frame's glottis and its rim (blur moves darkness into
   the rim without changing its sum). A narrow glottis, or none detected but whose shares
   over the glottis's corridor stand out of the noise (a slit narrower than the blur), is
   summed over the whole corridor. The tissue's levels are then taken again away from
   every frame's glottis and rim.
8. Posterior gap: a part of the glottis that never closes has no darkness against its own
   brightness over time. Pixels whose brightness over time is nearer the open glottis's grey
   than the surrounding tissue's, adjoining the glottis beyond one of its ends and no wider
   than it, are added to every frame's mask and counted whole (a static shadow beside the
   glottis is not).

Returns per-frame masks (inside the half-level boundary), coverage (each pixel's share) and
areas (pixels, the coverage's sums).
"""

import dataclasses
import warnings
from os import PathLike
from typing import Any

import numpy as np
from scipy import ndimage

from .recording import Recording, check_frame_rate


@dataclasses.dataclass(frozen=True)
class Segmentation:
    """Per-frame glottis masks and coverage (full frame size) and areas (pixels), with the
    ROI used.

    Attributes:
        masks: (frames, height, width) bool: the pixels more than half covered by glottis
            (inside the boundary where the grey level crosses half way between the tissue's
            and the glottis's local levels).
        coverage: (frames, height, width) float32: each pixel's share of glottis (0 outside
            the glottis and its rim; noise leaves shares slightly below 0 or above 1).
        area: (frames,) glottal area in pixels, the sum of ``coverage`` (sub-pixel).
        roi: (row0, row1, col0, col1) of the region of interest.
        threshold: the darkness threshold of the first, whole-pixel pass (grey levels).
        levels: the tissue's grey level at each pixel of the ROI (rows, columns) and the
            glottis's grey level, between which the coverage is measured.
        shifts: (frames, 2) drift correction applied to each frame (rows, columns).
    """

    masks: np.ndarray
    coverage: np.ndarray
    area: np.ndarray
    roi: tuple
    threshold: float
    levels: tuple
    shifts: np.ndarray


def _register(video, reference, max_shift=8):
    """Whole-pixel drift of every frame against ``reference`` by phase correlation (one
    batched FFT), and the frames shifted back (edges repeated)."""
    from scipy import fft

    # the central half of the frame is enough to measure a drift of a few pixels
    h0, w0 = video.shape[1:]
    crop = (slice(h0 // 4, h0 // 4 + h0 // 2), slice(w0 // 4, w0 // 4 + w0 // 2))
    a = video[:, crop[0], crop[1]]
    b = reference[crop]
    f = fft.rfft2(a - a.mean(axis=(1, 2), keepdims=True), workers=-1)
    g = fft.rfft2(b - b.mean(), workers=-1)
    cross = f.conj() * g
    # partly whitened: full whitening (phase correlation proper) lets the sensor noise of a
    # dim, smooth clip's empty high frequencies decide the peak
    cross /= np.sqrt(np.maximum(np.abs(cross), 1e-12))
    corr = fft.irfft2(cross, s=a.shape[1:], workers=-1)
    h, w = a.shape[1:]
    flat = corr.reshape(len(video), -1).argmax(axis=1)
    dy, dx = np.unravel_index(flat, (h, w))
    dy = np.where(dy > h // 2, dy - h, dy)
    dx = np.where(dx > w // 2, dx - w, dx)
    shifts = np.clip(np.stack([dy, dx], axis=1), -max_shift, max_shift)
    out = video.copy()
    for i, (sy, sx) in enumerate(shifts):
        if sy or sx:
            out[i] = ndimage.shift(video[i], (sy, sx), order=0, mode="nearest")
    return out, shifts.astype(float)


def _temporally_consistent(masks, reach=2):
    """Drop the components of a frame that no neighbouring frame's glottis comes within
    ``reach`` pixels of: a glottis opens from, and closes into, where it was a frame before or
    after; a one-frame blob (flicker, a glint between mucus strands) does not."""
    out = masks.copy()
    grow = ndimage.generate_binary_structure(2, 2)
    for i in np.flatnonzero(masks.any(axis=(1, 2))):
        near = masks[max(i - 1, 0)] | masks[min(i + 1, len(masks) - 1)]
        if not near.any():
            out[i] = False
            continue
        near = ndimage.binary_dilation(near, grow, iterations=reach)
        lab, n = ndimage.label(masks[i])
        hit = np.bincount(lab.ravel(), weights=near.ravel(), minlength=n + 1) > 0
        hit[0] = False
        out[i] = hit[lab]
    return out


def _persistent_gap(tissue, open_grey, union, reach=2):
    """Pixels dark in every frame that continue the glottis along its long axis (a posterior
    gap: the glottis never closes there). Each pixel's darkness is measured against its own
    brightness over time, so a permanently open part of the glottis has none. Found instead:
    the persistently dark pixels (brightness over time, ``tissue``, nearer the open glottis's
    grey level ``open_grey`` than the surrounding tissue's) that adjoin the glottis beyond one
    of its ends, no wider than it. A static shadow beside the glottis lies off its axis."""
    if union.sum() < 5 or union.all():
        return np.zeros_like(union)
    level = np.median(tissue[~union])
    static = (tissue < 0.5 * (level + open_grey)) & ~union
    if not static.any():
        return np.zeros_like(union)
    pts = np.argwhere(union).astype(float)
    centre = pts.mean(axis=0)
    _, vecs = np.linalg.eigh(np.cov((pts - centre).T))
    along, side = (pts - centre) @ vecs[:, 1], np.abs((pts - centre) @ vecs[:, 0])
    low, high, half_width = along.min(), along.max(), np.percentile(side, 95)
    # the corridor that continues the glottis beyond its two ends, no wider than it
    grid = np.indices(union.shape).reshape(2, -1).T - centre
    a = (grid @ vecs[:, 1]).reshape(union.shape)
    w = np.abs(grid @ vecs[:, 0]).reshape(union.shape)
    corridor = ((a > high - reach) | (a < low + reach)) & (w <= half_width + reach)
    lab, _ = ndimage.label(static & corridor)
    touching = np.unique(lab[ndimage.binary_dilation(union, iterations=reach) & (lab > 0)])
    return np.isin(lab, touching) & (lab > 0)


def _components(candidates, core, min_size, frames=None):
    """Per frame: the candidate pixels with holes filled, in components of at least
    ``min_size`` pixels that touch the moving region's ``core``."""
    out = np.zeros(candidates.shape, dtype=bool)
    for i in range(len(candidates)) if frames is None else frames:
        m = candidates[i]
        if not m.any():
            continue
        lab, n = ndimage.label(ndimage.binary_fill_holes(m))
        sizes = np.bincount(lab.ravel())
        touches = np.bincount(lab.ravel(), weights=core.ravel())
        keep = (sizes >= min_size) & (touches > 0)
        keep[0] = False
        out[i] = keep[lab]
    return out


def _grow_frames(masks, pixels):
    """Each frame's mask (frames, rows, columns) grown by ``pixels`` within its own frame
    (scipy grows until nothing changes when told 0 iterations: 0 leaves the masks as they
    are)."""
    if pixels < 1:
        return masks
    in_frame = np.zeros((3, 3, 3), dtype=bool)
    in_frame[1] = ndimage.generate_binary_structure(2, 1)
    return ndimage.binary_dilation(masks, in_frame, iterations=pixels)


def _tissue_levels(sub, masks, rim_px):
    """Each pixel's tissue grey level: its median over the frames in which no glottis comes
    within ``rim_px`` pixels of it (unbiased by noise, unlike a high percentile; a pixel
    that the glottis's rim covers in nearly every frame falls back on its 90th percentile)."""
    clear = ~_grow_frames(masks, rim_px)
    if not clear.any():
        return np.percentile(sub, 90.0, axis=0)
    # the median over the clear frames: sorted with the others last (NaN sorts last)
    count = clear.sum(axis=0)
    ordered = np.sort(np.where(clear, sub, np.nan), axis=0)
    low = np.take_along_axis(ordered, np.maximum(count - 1, 0)[None] // 2, axis=0)[0]
    high = np.take_along_axis(ordered, (count // 2)[None], axis=0)[0]
    tissue = 0.5 * (low + high)
    rare = count < 3
    if rare.any():
        tissue[rare] = np.percentile(sub[:, rare], 90.0, axis=0)
    return tissue


def _glottis_level(sub, tissue, masks, n_frames=5):
    """The glottis's grey level G and the optics' blur sigma (pixels), fitted to the rows of
    the widest frames.

    Blur mixes a narrow glottis with the tissue beside it, so its darkest pixels need not
    reach G. Across each row a blurred opening from a to b darkens pixel x (centre x + 1/2)
    by ``(T(x) - G) (Phi((x + 1/2 - a) / s) - Phi((x + 1/2 - b) / s))``, with T the tissue's
    level and s the blur (with the pixel's width); G and s are common to the rows, a and b
    (sub-pixel edges) their own. Fitted by least squares over the middle half of the
    glottis's rows in the ``n_frames`` widest frames. Returns None where too few rows open.
    """
    from scipy import optimize, sparse, special

    widest = np.argsort(masks.sum(axis=(1, 2)))[::-1][:n_frames]
    rows, cols, darks = [], [], []
    for i in widest:
        hit = np.flatnonzero(masks[i].any(axis=1))
        if hit.size < 4:
            continue
        lo, hi = np.percentile(hit, [25, 75])
        for r in hit[(hit >= lo) & (hit <= hi)]:
            c = np.flatnonzero(masks[i, r])
            if c.size < 2:
                continue
            c0, c1 = max(c[0] - 6, 0), min(c[-1] + 7, sub.shape[2])
            x = np.arange(c0, c1)
            rows.append((float(c[0]), float(c[-1] + 1)))
            cols.append(x + 0.5)
            darks.append((tissue[r, c0:c1], sub[i, r, c0:c1]))
    if len(rows) < 4:
        return None
    n = len(rows)
    sizes = np.array([x.size for x in cols])
    xs = np.concatenate(cols)
    which = np.repeat(np.arange(n), sizes)
    t_level = np.concatenate([d[0] for d in darks])
    grey = np.concatenate([d[1] for d in darks])
    deepest = float(np.percentile(grey, 1))

    rows_of = np.arange(xs.size)

    def parts(p):
        g, s, a, b = p[0], np.exp(p[1]), p[2 : 2 + n][which], p[2 + n :][which]
        za, zb = (xs - a) / s, (xs - b) / s
        return g, s, za, zb, special.ndtr(za) - special.ndtr(zb)

    def residual(p):
        g, _, _, _, share = parts(p)
        return t_level - (t_level - g) * share - grey

    def jacobian(p):
        g, s, za, zb, share = parts(p)
        pa, pb = np.exp(-0.5 * za**2), np.exp(-0.5 * zb**2)
        pa, pb = pa / np.sqrt(2 * np.pi), pb / np.sqrt(2 * np.pi)
        depth = t_level - g
        values = np.concatenate(
            [share, -depth * (zb * pb - za * pa), depth * pa / s, -depth * pb / s]
        )
        cols = np.concatenate(
            [np.zeros(xs.size), np.ones(xs.size), 2 + which, 2 + n + which]
        ).astype(int)
        return sparse.csr_matrix((values, (np.tile(rows_of, 4), cols)), shape=(xs.size, 2 + 2 * n))

    p0 = np.concatenate([[deepest, 0.0], [r[0] for r in rows], [r[1] for r in rows]])
    try:
        fit = optimize.least_squares(residual, p0, jac=jacobian, method="trf", tr_solver="lsmr")
    except (ValueError, np.linalg.LinAlgError):
        return None
    g, s = float(fit.x[0]), float(np.exp(fit.x[1]))
    if not (np.isfinite(g) and np.isfinite(s)) or g >= np.median(t_level):
        return None
    return g, s


#: A frame with no pixel above the detection level is open when the shares summed over the
#: glottis's corridor exceed this many standard deviations of that sum on closed frames.
FAINT_OPENING_SIGMAS = 5.0
#: A frame whose detected glottis is smaller than this share of the widest frame's is summed
#: over the whole corridor: a slit about as narrow as the blur shows its middle only, and
#: its thin ends lie beyond the rim of what was detected.
NARROW_SHARE = 0.2


def _regions(share, found, union, rim_px, dropped):
    """Where each frame's shares are summed: the detected glottis and its rim, and the
    glottis's corridor (every frame's glottis, and its rim) in the frames whose glottis is
    narrow or undetected but whose shares over the corridor stand out of the noise (a slit
    narrower than the blur, which no single pixel shows). The noise of the corridor's sum is
    its robust spread over the frames with nothing detected (closed, mostly). Frames whose
    blobs the temporal check ``dropped`` (a glint in a closed frame) are closed."""
    region = _grow_frames(found, rim_px)
    corridor = _grow_frames(union[None], rim_px)[0]
    if not corridor.any():
        return region
    sizes = found.sum(axis=(1, 2))
    narrow = (sizes > 0) & (sizes < NARROW_SHARE * sizes.max())
    empty = sizes == 0
    if empty.sum() >= 8:
        sums = share[:, corridor].sum(axis=1)
        centre = np.median(sums[empty])
        spread = 1.4826 * np.median(np.abs(sums[empty] - centre))
        faint = sums - centre > FAINT_OPENING_SIGMAS * max(spread, 1e-6)
        narrow |= empty & faint & ~dropped
    region[narrow] |= corridor
    return region


def _coverage(sub, masks, rim_px, glottis_masks=None, fitted=None):
    """Each pixel's share of glottis in every frame, from the local grey levels.

    A pixel's share is where its grey level lies between the tissue's level there
    (`_tissue_levels`) and the glottis's (`_glottis_level`): 0 at the tissue's, 1 at the
    glottis's, 1/2 on the boundary. Blur spreads the glottis's darkness into its rim without
    changing its sum, so the shares summed over the glottis and its rim give its area to a
    fraction of a pixel, however narrow the opening.

    Arguments:
        sub: the frames of the region of interest (frames, rows, columns).
        masks: where the glottis is (or may be) in each frame: the tissue's levels are
            taken away from it.
        rim_px: the least rim (pixels) kept clear of ``masks`` for the tissue's levels.
        glottis_masks: the glottis proper, whose widest frames give the glottis's level;
            default ``masks``.
        fitted: the glottis's level and the blur (grey levels, pixels) from an earlier
            pass (`_glottis_level`), if any.

    Returns:
        (frames, rows, columns) shares (not clipped: noise averages out in the sum), the
        tissue's levels (rows, columns), the glottis's level (grey levels) and the rim
        (pixels) that holds the blurred boundary, and the fitted glottis's level and blur
        (None where they could not be fitted).
    """
    tissue = _tissue_levels(sub, masks, rim_px)
    glottal = masks if glottis_masks is None else glottis_masks
    if fitted is None:
        fitted = _glottis_level(sub, tissue, glottal)
    if fitted is None:
        inside = sub[glottal]
        glottis = float(np.median(inside)) if inside.size else float(np.min(sub))
    else:
        glottis, blur = fitted
        rim_px = int(np.clip(np.ceil(2.5 * blur + 0.5), rim_px, 12))
        # a glottis wide enough to show its own level beyond the blur's reach: its median
        # there (a real glottis is not evenly dark, which the fitted level averages over)
        widest = np.argsort(glottal.sum(axis=(1, 2)))[::-1][:5]
        half = glottal[widest] & (sub[widest] < 0.5 * (tissue + glottis)[None])
        depth = np.stack([ndimage.distance_transform_edt(m) for m in half])
        deep = depth > 2.0 * blur + 0.5
        if deep.sum() >= 30:
            glottis = float(np.median(sub[widest][deep]))
    contrast = np.maximum(tissue - glottis, 1e-3 * max(float(np.ptp(sub)), 1e-6))
    return (tissue[None] - sub) / contrast[None], tissue, glottis, rim_px, fitted


def segment_video(
    video: np.ndarray,
    *,
    register: bool = True,
    tissue_percentile: float = 90.0,
    min_size: int = 3,
    roi_pad: int = 8,
    temporal: bool = True,
    posterior_gap: bool = True,
    rim_px: int = 4,
    detect_level: float = 0.25,
    progress: bool = False,
) -> Segmentation:
    """Glottis masks, coverage and areas (sub-pixel) from a (frames, height, width) grey video.

    Arguments:
        video: the frames (any real dtype; 8, 12 or 16 bit).
        register: correct camera drift by phase correlation.
        tissue_percentile: percentile over time taken as each pixel's tissue brightness.
        min_size: components smaller than this (pixels) are dropped.
        roi_pad: pixels added around the moving region.
        temporal: enforce temporal consistency: drop components that no neighbouring frame's
            glottis comes within 2 pixels of (one-frame blobs).
        posterior_gap: add the persistently dark pixels that continue the glottis beyond one
            of its ends, in every frame (a glottis that never closes there).
        rim_px: the least width (pixels) of the rim around the glottis over which the
            blurred boundary's shares are summed; widened to 2.5 standard deviations of the
            fitted blur (an edge's spread), up to 12.
        detect_level: a frame's glottis is where its share of glottis, smoothed over a pixel,
            exceeds this (a narrow slit, blurred, never reaches half).
        progress: show a progress bar over the frames.
    """
    from skimage import filters, measure, morphology

    if not (isinstance(rim_px, int | np.integer) and rim_px >= 1):
        raise ValueError(f"rim_px must be a whole number of pixels >= 1, got {rim_px!r}")
    if not 0.0 < detect_level < 1.0:
        raise ValueError(f"detect_level must be a share of glottis in (0, 1), got {detect_level}")
    v = np.array(video, dtype=np.float32)  # a copy: the caller's frames stay as they are
    if v.ndim != 3 or v.shape[0] < 2:
        raise ValueError(f"expected a (frames, height, width) video, got shape {v.shape}")
    if not np.all(np.isfinite(v)):
        raise ValueError("the video has NaN or infinite pixels")
    if np.ptp(v) == 0:
        raise ValueError("the video is constant (all frames one grey level): nothing to segment")
    # medians on a 2 x 2 subsample and over <= 32 evenly spaced frames: as good an estimate
    # of the brightness level and of the still scene, at a fraction of the cost
    med = np.median(v[:, ::2, ::2], axis=(1, 2))
    if np.median(med) <= 0:
        raise ValueError("the video is (almost) all dark: no tissue to find a glottis against")
    # flicker: each frame's median ratio to the still scene, on the lit pixels (a frame's
    # own median would move by a percent as the glottis opens, darkening the whole frame)
    reference = np.median(v[:: max(1, len(v) // 32), ::4, ::4], axis=0)
    lit = reference > 0.1 * np.median(med)
    if lit.sum() >= 100:
        gain = np.median(v[:, ::4, ::4][:, lit] / reference[lit][None], axis=1)
    else:
        gain = med / np.median(med)
    v /= np.maximum(gain, 1e-6)[:, None, None]
    shifts = np.zeros((len(v), 2))
    if register:
        still = v[:: max(1, len(v) // 32)]
        v, shifts = _register(v, np.median(still, axis=0))

    std = v.std(axis=0)
    if np.ptp(std) == 0:
        raise ValueError("nothing moves in the video: no glottis to segment")
    moving = morphology.opening(std > filters.threshold_otsu(std), morphology.disk(1))
    labels = measure.label(moving)
    if labels.max() == 0:
        raise ValueError("no moving region found: is there a vibrating glottis in view?")
    # the moving region: every component of at least a tenth of the largest (a mucus bridge or
    # a specular highlight can split the glottis's region in parts)
    sizes = np.bincount(labels.ravel())
    sizes[0] = 0
    core = (sizes >= 0.1 * sizes.max())[labels]
    rows, cols = np.nonzero(core)
    r0, r1 = max(rows.min() - roi_pad, 0), min(rows.max() + roi_pad + 1, v.shape[1])
    c0, c1 = max(cols.min() - roi_pad, 0), min(cols.max() + roi_pad + 1, v.shape[2])
    sub = v[:, r0:r1, c0:c1]
    core = core[r0:r1, c0:c1]

    tissue = np.percentile(sub, tissue_percentile, axis=0)
    dark = tissue[None] - sub
    peak = np.percentile(dark, 99.9, axis=(1, 2))
    open_frames = peak >= 0.5 * peak.max()
    threshold = float(filters.threshold_otsu(dark[open_frames]))

    frames = range(len(v))
    if progress:
        from tqdm.auto import tqdm

        frames = tqdm(frames, desc="segmenting", unit="frame")
    first = _components(dark > threshold, core, min_size, frames)
    if temporal:
        first = _temporally_consistent(first)
    # the sub-pixel pass: each pixel's share of glottis from the local grey levels
    share, level_tissue, level_glottis, rim_px, fitted = _coverage(sub, first, rim_px)
    found = _components(ndimage.gaussian_filter(share, (0, 1, 1)) > detect_level, core, min_size)
    # a frame whose only blob the temporal check drops (a glint) is closed, not faint
    dropped = found.any(axis=(1, 2))
    if temporal:
        found = _temporally_consistent(found)
    if not found.any():
        found = first
    dropped &= ~found.any(axis=(1, 2))
    region = _regions(share, found, first.any(axis=0) | found.any(axis=0), rim_px, dropped)
    # the levels again, with the tissue's taken away from every frame's glottis and rim
    share, level_tissue, level_glottis, _, _ = _coverage(sub, region, 0, found, fitted)
    cover = np.where(region, np.clip(share, -1.0, 2.0), 0.0).astype(np.float32)
    masks = np.zeros(v.shape, dtype=bool)
    masks[:, r0:r1, c0:c1] = found & (share > 0.5)
    coverage = np.zeros(v.shape, dtype=np.float32)
    coverage[:, r0:r1, c0:c1] = cover
    if posterior_gap and masks.any():
        # a window wider than the ROI: a gap that never closes does not move, so the ROI
        # (what moves) can end where the gap begins
        g0, g1 = max(r0 - 2 * roi_pad, 0), min(r1 + 2 * roi_pad, v.shape[1])
        h0, h1 = max(c0 - 2 * roi_pad, 0), min(c1 + 2 * roi_pad, v.shape[2])
        window = np.percentile(v[:, g0:g1, h0:h1], tissue_percentile, axis=0)
        gap = _persistent_gap(window, level_glottis, masks[:, g0:g1, h0:h1].any(axis=0))
        masks[:, g0:g1, h0:h1] |= gap[None]
        coverage[:, g0:g1, h0:h1] = np.where(gap[None], 1.0, coverage[:, g0:g1, h0:h1])
    # noise can leave a faint frame's sum below zero: no area is negative
    area = np.maximum(coverage.sum(axis=(1, 2), dtype=float), 0.0)
    if area.max() == 0:
        warnings.warn("no glottis found in any frame: the area is zero throughout", stacklevel=2)
    return Segmentation(
        masks=masks,
        coverage=coverage,
        area=area,
        roi=(r0, r1, c0, c1),
        threshold=threshold,
        levels=(level_tissue, level_glottis),
        shifts=shifts,
    )


#: A segmented glottis covering more of the frame than this at its widest is no glottis: it
#: covers a few percent of a laryngeal video's frame (0.6-1.9 % in the shared clips), while
#: thresholding a video of noise marks 60-90 % of it.
MAX_GLOTTIS_FRACTION = 0.25


def video_to_recording(
    path: str | PathLike, fps: float | None = None, *, folds: bool = False, **kwargs: Any
) -> Recording:
    """Read a video and segment it: a `Recording` of the glottal area (pixels) with its
    coverage as masks.

    Arguments:
        path: the video file (`vfjax.video.VIDEO_SUFFIXES`).
        fps: the camera's frame rate (Hz); required when the file does not store it, and
            overrides the file's rate (a container may store a playback rate, such as 30
            fps).
        folds: split the area into the left and right folds' by the glottal midline, where
            the glottis spans rows to split (`vfjax.asymmetry.with_fold_areas`), and drop the
            masks (a frame's worth of floats per frame): the recording that a fit takes, as
            `vfjax fit`, `vfjax diagnose` and a cohort read a video.
        kwargs: passed to `frames_to_recording` (and on to `segment_video`).
    """
    from .video import read_video

    video, file_fps = read_video(path)
    rec = frames_to_recording(video, fps, source=path, file_fps=file_fps, **kwargs)
    del video
    if not folds:
        return rec
    from .asymmetry import glottal_midline, with_fold_areas

    try:
        midline = glottal_midline(masks=rec.masks)
    except ValueError:  # a glottis that never spans two rows: no midline
        return dataclasses.replace(rec, masks=None)
    return dataclasses.replace(with_fold_areas(rec, midline), masks=None)


def frames_to_recording(
    video, fps: float | None, source="video", *, file_fps=None, check: bool = True, **kwargs
):
    """Segment frames already in memory: a `Recording` of the glottal area (pixels) with its
    coverage (each pixel's share of glottis) as masks; ``source`` (a path or a label) names
    it.

    Arguments:
        video: (frames, height, width) grey frames.
        fps: the camera's frame rate (Hz); default ``file_fps``.
        source: the file or a label, for the recording's name and the messages.
        file_fps: the rate the file states, if any.
        check: refuse a result that is no glottal area waveform: a dark region covering
            more than `MAX_GLOTTIS_FRACTION` of the frame, or an area whose periodicity is
            below `vfjax.descriptors.MIN_PERIODICITY` (a video of noise, or with no vibrating
            glottis).
        kwargs: passed to `segment_video`.
    """
    import pathlib

    from .descriptors import MIN_PERIODICITY, periodicity

    if fps is None and file_fps is None:
        raise ValueError(f"{source}: the frame rate is not in the file; give fps (--fps)")
    if fps is None:
        fps = check_frame_rate(
            file_fps,
            f"{source} (the rate the file states)",
            "; if the camera's rate differs, give it with --fps",
        )
    else:
        fps = check_frame_rate(fps, f"{source}: the given frame rate")
    seg = segment_video(video, **kwargs)
    if check:
        frame = seg.masks.shape[1] * seg.masks.shape[2]
        widest = float(seg.area.max()) / frame
        if widest > MAX_GLOTTIS_FRACTION:
            raise ValueError(
                f"{source}: no glottis found: the dark moving region covers up to {widest:.0%} "
                f"of the frame, where a glottis covers a few percent (is this a laryngeal "
                "high-speed video?)"
            )
        if seg.area.max() > 0:
            score, _ = periodicity(seg.area, fps)
            if score < MIN_PERIODICITY:
                raise ValueError(
                    f"{source}: no vibrating glottis found: the segmented area is not "
                    f"periodic (autocorrelation {score:.2f} at best over glottal periods of "
                    f"1-20 ms, where a vibrating glottis gives 0.95 or more)"
                )
    source = pathlib.Path(source)
    meta = {"source": source.name, "roi": list(map(int, seg.roi)), "threshold": seg.threshold}
    return Recording(
        area=seg.area,
        fps=float(fps),
        unit="px",
        metadata=meta,
        name=source.stem,
        masks=seg.coverage,
    )
