"""Glottal area from high-speed video by thresholding (scikit-image).

Method, for a (frames, height, width) grey video:
1. Flicker: each frame is scaled so that its median brightness matches the video's.
2. Drift: each frame is registered to the temporal median frame (of up to 32 evenly spaced
   frames) by phase correlation
   (whole-pixel shifts, one batched FFT for the whole video) and shifted back.
3. Region of interest: the glottis is what moves. The temporal standard deviation of each
   pixel is thresholded (Otsu); the moving components (all of at least a tenth of the largest),
   padded, make the ROI.
4. Darkness: a pixel's *tissue* brightness is a high percentile of its values over time
   (the glottis is closed, or elsewhere, most of the time); a frame's darkness is tissue
   brightness minus the pixel's value. Static dark structures (shadows) have no darkness.
5. Threshold: Otsu's threshold of the darkness pooled over the clearly open frames (an
   adaptive, contrast-independent level half way between tissue and open glottis).
6. Clean-up: holes are filled, components smaller than ``min_size`` pixels are dropped, and
   only components that touch the moving region's core are kept (the dark component that
   moves like a glottis). No opening: it would erode the thin slit of a nearly closed
   glottis. Frames whose darkness never reaches the threshold are closed: area 0.
7. Temporal consistency: a component that no neighbouring frame's glottis comes within two
   pixels of (a one-frame blob from flicker or a glint) is dropped.
8. Posterior gap: a part of the glottis that never closes has no darkness against its own
   brightness over time. Pixels whose brightness over time is nearer the open glottis's grey
   than the surrounding tissue's, adjoining the glottis beyond one of its ends and no wider
   than it, are added to every frame's mask (a static shadow beside the glottis is not).

Returns per-frame masks and areas (pixels).
"""

import dataclasses
import warnings

import numpy as np
from scipy import ndimage


@dataclasses.dataclass(frozen=True)
class Segmentation:
    """Per-frame glottis masks (full frame size) and areas (pixels), with the ROI used.

    Attributes:
        masks: (frames, height, width) bool.
        area: (frames,) glottal area in pixels.
        roi: (row0, row1, col0, col1) of the region of interest.
        threshold: the darkness threshold (grey levels).
        shifts: (frames, 2) drift correction applied to each frame (rows, columns).
    """

    masks: np.ndarray
    area: np.ndarray
    roi: tuple
    threshold: float
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
    cross /= np.maximum(np.abs(cross), 1e-12)
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


def segment_video(
    video,
    *,
    register: bool = True,
    tissue_percentile: float = 90.0,
    min_size: int = 3,
    roi_pad: int = 8,
    temporal: bool = True,
    posterior_gap: bool = True,
    progress: bool = False,
) -> Segmentation:
    """Glottis masks and areas from a (frames, height, width) grey video.

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
        progress: show a progress bar over the frames.
    """
    from skimage import filters, measure, morphology

    v = np.asarray(video, dtype=np.float32)
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
    v *= (np.median(med) / np.maximum(med, 1e-6))[:, None, None]
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

    masks = np.zeros(v.shape, dtype=bool)
    frames = range(len(v))
    if progress:
        from tqdm.auto import tqdm

        frames = tqdm(frames, desc="segmenting", unit="frame")
    for i in frames:
        m = dark[i] > threshold
        if not m.any():
            continue
        m = ndimage.binary_fill_holes(m)
        lab, n = ndimage.label(m)
        if n == 0:
            continue
        sizes = np.bincount(lab.ravel())
        touches = np.bincount(lab.ravel(), weights=core.ravel())
        keep = (sizes >= min_size) & (touches > 0)
        keep[0] = False
        m = keep[lab]
        masks[i, r0:r1, c0:c1] = m
    if temporal:
        masks[:, r0:r1, c0:c1] = _temporally_consistent(masks[:, r0:r1, c0:c1])
    if posterior_gap and masks.any():
        # a window wider than the ROI: a gap that never closes does not move, so the ROI
        # (what moves) can end where the gap begins
        g0, g1 = max(r0 - 2 * roi_pad, 0), min(r1 + 2 * roi_pad, v.shape[1])
        h0, h1 = max(c0 - 2 * roi_pad, 0), min(c1 + 2 * roi_pad, v.shape[2])
        window = np.percentile(v[:, g0:g1, h0:h1], tissue_percentile, axis=0)
        open_grey = float(np.median(v[masks]))
        gap = _persistent_gap(window, open_grey, masks[:, g0:g1, h0:h1].any(axis=0))
        masks[:, g0:g1, h0:h1] |= gap[None]
    area = masks.sum(axis=(1, 2)).astype(float)
    if area.max() == 0:
        warnings.warn("no glottis found in any frame: the area is zero throughout", stacklevel=2)
    return Segmentation(
        masks=masks, area=area, roi=(r0, r1, c0, c1), threshold=threshold, shifts=shifts
    )


#: A segmented glottis covering more of the frame than this at its widest is no glottis: it
#: covers a few percent of a laryngeal video's frame (0.6-1.9 % in the shared clips), while
#: thresholding a video of noise marks 60-90 % of it.
MAX_GLOTTIS_FRACTION = 0.25
#: The least periodicity (`vfjax.descriptors.periodicity`) of a glottal area waveform: the
#: shared clips and contour recordings give 0.97 to 1.0, noise 0.3 to 0.45.
MIN_PERIODICITY = 0.7


def video_to_recording(path, fps: float | None = None, **kwargs):
    """Read a video and segment it: a `Recording` of the glottal area (pixels) with its
    masks. ``fps`` (Hz) is required when the file does not store it, and overrides the
    file's rate (a container may store a playback rate, such as 30 fps)."""
    from .video import read_video

    video, file_fps = read_video(path)
    return frames_to_recording(video, fps, source=path, file_fps=file_fps, **kwargs)


def frames_to_recording(
    video, fps: float | None, source="video", *, file_fps=None, check: bool = True, **kwargs
):
    """Segment frames already in memory: a `Recording` of the glottal area (pixels) with its
    masks; ``source`` (a path or a label) names it.

    Arguments:
        video: (frames, height, width) grey frames.
        fps: the camera's frame rate (Hz); default ``file_fps``.
        source: the file or a label, for the recording's name and the messages.
        file_fps: the rate the file states, if any.
        check: refuse a result that is no glottal area waveform: a dark region covering
            more than `MAX_GLOTTIS_FRACTION` of the frame, or an area whose periodicity is
            below `MIN_PERIODICITY` (a video of noise, or with no vibrating glottis).
        kwargs: passed to `segment_video`.
    """
    import pathlib

    from .descriptors import periodicity
    from .recording import Recording, check_frame_rate

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
        area=seg.area, fps=float(fps), unit="px", metadata=meta, name=source.stem, masks=seg.masks
    )
