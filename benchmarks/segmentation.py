"""Segmentation accuracy per clip and speed (frames/s), against true glottal areas.

Clips: the shared clip_a, and harder variants made from it here (the truth is unchanged):
drift (a random walk of up to 4 px) with 10 % flicker; a static dark band beside the glottis;
low contrast (the image range squeezed to a third, noise added); a mucus bridge (a bright
horizontal strand across the glottis, 2 px); 12-bit data (scaled to 0..4095); a posterior
gap (a small ellipse beyond the glottis's end, at the open glottis's grey level in every
frame: its area is added to the truth, and no frame is truly closed).
And clips rendered by `vfjax.datasets.demo_video`, whose true area counts each pixel's covered
share (an 8 x 8 subsample of the glottis's outline): noise, blur, low contrast, colour, left-right
asymmetry and all of them at once.
Per clip: median relative area error on frames whose true area is >= 10 % of the peak, the
share of truly closed frames measured as closed (<= 1 % of the peak), and for the rendered
clips the median absolute error (px) on small openings (true area 10 px to 15 % of the peak).

Run: python benchmarks/segmentation.py
"""

import pathlib
import time

import numpy as np
from scipy import ndimage

from vfjax.datasets import demo_video
from vfjax.segmentation import segment_video
from vfjax.video import _to_grey, read_video

HSV = pathlib.Path(__file__).resolve().parents[2] / "shared" / "data" / "hsv"


def scores(area, truth):
    big = truth >= 0.1 * truth.max()
    closed = truth == 0
    closed_ok = np.mean(area[closed] <= 0.01 * truth.max()) if closed.any() else np.nan
    return np.median(np.abs(area[big] - truth[big]) / truth[big]), closed_ok


def variants(video, roi, rng):
    v = video.astype(np.float32)
    r0, r1, c0, c1 = roi
    walk = np.cumsum(rng.integers(-1, 2, (len(v), 2)), axis=0).clip(-4, 4)
    drift = np.stack([ndimage.shift(f, s, order=0, mode="nearest") for f, s in zip(v, walk)])
    yield "drift+flicker", drift * (1 + 0.1 * rng.standard_normal(len(v)))[:, None, None], 0
    shadow = v.copy()
    shadow[:, r0 + 20 : r0 + 60, c1 : c1 + 6] *= 0.2
    yield "dark shadow", shadow, 0
    low = v / 3 + 60 + rng.normal(0, 2, v.shape)
    yield "low contrast", low, 0
    bridge = v.copy()
    mid = (r0 + r1) // 2
    bridge[:, mid : mid + 2, c0:c1] = np.maximum(bridge[:, mid : mid + 2, c0:c1], 150)
    yield "mucus bridge", bridge, 0
    yield "12-bit", np.round(v * 4095 / 255).astype(np.uint16), 0
    union = segment_video(video).masks.any(axis=0)
    rows, cols = np.nonzero(union)
    end, mid = rows.max(), int(np.median(cols[rows >= rows.max() - 3]))
    yy, xx = np.mgrid[: v.shape[1], : v.shape[2]]
    gap = (((yy - end - 4) / 4.0) ** 2 + ((xx - mid) / 2.5) ** 2 <= 1) & ~union
    posterior = v.copy()
    posterior[:, gap] = np.median(v[:, union][v[:, union] < 60])
    yield "posterior gap", posterior, int(gap.sum())


def main():
    video, _ = read_video(HSV / "clip_a.tif")
    truth = np.loadtxt(HSV / "clip_a_truth.csv", delimiter=",", skiprows=1)[:, 1]
    seg = segment_video(video)
    rng = np.random.default_rng(1)
    print(f"{'clip':16s} {'median rel err':>14s} {'closed ok':>10s}")
    clips = [("clip_a", video, 0)] + list(variants(video, seg.roi, rng))
    for name, clip, extra in clips:
        m, c = scores(segment_video(clip).area, truth + extra)
        c = f"{c:10.3f}" if extra == 0 else f"{'n/a':>10s}"
        print(f"{name:16s} {m:14.4f} {c}")
    from skimage.filters import threshold_otsu

    r0, r1, c0, c1 = seg.roi
    otsu = np.array([(f < threshold_otsu(f)).sum() for f in video[:, r0:r1, c0:c1]], float)
    print(f"{'plain Otsu':16s} {scores(otsu, truth)[0]:14.4f} {scores(otsu, truth)[1]:10.3f}")
    print(f"\n{'rendered clip':32s} {'median rel err':>14s} {'closed ok':>10s} {'small px':>9s}")
    for name, settings in RENDERED:
        errors = [rendered(settings, seed) for seed in range(3)]
        m, c, small = (np.median([e[k] for e in errors]) for k in range(3))
        worst = max(e[0] for e in errors)
        print(f"{name:32s} {m:14.4f} {c:10.3f} {small:9.1f}   (worst of 3 seeds {worst:.4f})")
    for reg in (True, False):
        best = min(_timed(video, reg) for _ in range(3))
        print(
            f"speed ({video.shape[1]}x{video.shape[2]}, register={reg}): "
            f"{len(video) / best:.0f} frames/s"
        )


RENDERED = [
    ("rendered: default (blur 1, noise 3)", {}),
    ("noise 8 grey levels", {"noise": 8.0}),
    ("blur 2 px", {"blur_px": 2.0}),
    ("low contrast (x0.2, blur 1.5)", {"contrast": 0.2, "blur_px": 1.5}),
    ("colour (red-dominated)", {"colour": True}),
    ("asymmetric folds (right 0.5 x left)", {"asymmetry": 0.5}),
    (
        "all: x0.25, blur 2, noise 4, colour",
        {"contrast": 0.25, "blur_px": 2.0, "noise": 4.0, "colour": True},
    ),
]


def rendered(settings, seed):
    clip = demo_video(seed=seed, **settings)
    area = segment_video(_to_grey(clip.frames)).area
    m, c = scores(area, clip.area)
    small = (clip.area >= 10) & (clip.area < 0.15 * clip.area.max())
    return m, c, float(np.median(np.abs(area[small] - clip.area[small])))


def _timed(video, register):
    t0 = time.perf_counter()
    segment_video(video, register=register)
    return time.perf_counter() - t0


if __name__ == "__main__":
    main()
