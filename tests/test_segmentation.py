"""Glottal area from video, against the shared clip's true area; readers and bad input."""

import numpy as np
import pytest
from scipy import ndimage

from vfjax.segmentation import segment_video, video_to_recording
from vfjax.video import read_masks, read_video


@pytest.fixture(scope="module")
def clip(shared_dir):
    folder = shared_dir / "data" / "hsv"
    video, fps = read_video(folder / "clip_a.tif")
    truth = np.loadtxt(folder / "clip_a_truth.csv", delimiter=",", skiprows=1)[:, 1]
    return video, truth


def _scores(area, truth):
    big = truth >= 0.1 * truth.max()
    closed = truth == 0
    median_rel = np.median(np.abs(area[big] - truth[big]) / truth[big])
    closed_ok = np.mean(area[closed] <= 0.01 * truth.max()) if closed.any() else np.nan
    return median_rel, closed_ok


def test_clip_a_accuracy(clip):
    video, truth = clip
    assert video.shape == (160, 256, 224)
    seg = segment_video(video)
    median_rel, closed_ok = _scores(seg.area, truth)
    assert median_rel <= 0.03, median_rel
    assert closed_ok >= 0.95, closed_ok
    assert seg.masks.shape == video.shape
    np.testing.assert_array_equal(seg.masks.sum(axis=(1, 2)), seg.area)


def test_plain_otsu_is_worse(clip):
    """The baseline the issue quotes: a per-frame Otsu threshold, far less accurate."""
    from skimage.filters import threshold_otsu

    video, truth = clip
    r0, r1, c0, c1 = segment_video(video).roi
    area = np.array([(f < threshold_otsu(f)).sum() for f in video[:, r0:r1, c0:c1]], float)
    assert _scores(area, truth)[0] > 0.05


def test_drift_and_flicker(clip):
    video, truth = clip
    rng = np.random.default_rng(1)
    walk = np.cumsum(rng.integers(-1, 2, (len(video), 2)), axis=0).clip(-4, 4)
    moved = np.stack(
        [
            ndimage.shift(f.astype(np.float32), s, order=0, mode="nearest")
            for f, s in zip(video, walk)
        ]
    )
    moved *= (1 + 0.1 * rng.standard_normal(len(video)))[:, None, None]
    median_rel, closed_ok = _scores(segment_video(moved).area, truth)
    assert median_rel <= 0.03 and closed_ok >= 0.9


def test_static_dark_shadow_is_ignored(clip):
    video, truth = clip
    shadowed = video.astype(np.float32).copy()
    r0, r1, c0, c1 = segment_video(video).roi
    shadowed[:, r0 + 20 : r0 + 60, c1 : c1 + 6] *= 0.2  # a dark band beside the glottis
    assert _scores(segment_video(shadowed).area, truth)[0] <= 0.03


def test_one_frame_blob_is_dropped_by_temporal_consistency(clip):
    """A dark glint in one closed frame, inside the glottis's region: without the temporal
    check it is measured as an opening; with it, the frame stays closed."""
    video, truth = clip
    seg = segment_video(video)
    closed = np.flatnonzero(truth == 0)
    # a closed frame whose neighbours are closed too, and a spot inside the glottis's region
    i = next(int(k) for k in closed if truth[k - 1] == 0 and truth[k + 1] == 0)
    rows, cols = np.nonzero(seg.masks.any(axis=0))
    r, c = int(np.median(rows)), int(np.median(cols))
    glint = video.astype(np.float32).copy()
    glint[i, r - 2 : r + 3, c - 2 : c + 3] = 0.0
    assert segment_video(glint, temporal=False).area[i] >= 20
    consistent = segment_video(glint)
    assert consistent.area[i] == 0
    np.testing.assert_allclose(_scores(consistent.area, truth), _scores(seg.area, truth), rtol=0.01)


def test_posterior_gap_is_kept_open(clip):
    """A part of the glottis that never closes (an ellipse beyond its end at the open
    glottis's grey level in every frame) has no darkness against its own brightness over
    time; it is found as a persistent gap and counted in every frame."""
    video, truth = clip
    clean = segment_video(video).masks
    assert not clean[truth == 0].any()  # clip_a itself: no gap
    union = clean.any(axis=0)
    rows, cols = np.nonzero(union)
    end, mid = rows.max(), int(np.median(cols[rows >= rows.max() - 3]))
    yy, xx = np.mgrid[: video.shape[1], : video.shape[2]]
    gap = (((yy - end - 4) / 4.0) ** 2 + ((xx - mid) / 2.5) ** 2 <= 1) & ~union
    gapped = video.astype(np.float32).copy()
    gapped[:, gap] = np.median(video[:, union][video[:, union] < 60])
    seg = segment_video(gapped)
    np.testing.assert_array_equal(seg.area[truth == 0], gap.sum())
    assert _scores(seg.area, truth + gap.sum())[0] <= 0.03
    assert segment_video(gapped, posterior_gap=False).area[truth == 0].max() == 0


def test_recording_from_video_and_npy(clip, tmp_path):
    video, truth = clip
    path = tmp_path / "clip.npy"
    np.save(path, video)
    with pytest.raises(ValueError, match="frame rate"):
        video_to_recording(path)
    rec = video_to_recording(path, fps=4000.0)
    assert rec.n_frames == 160 and rec.masks.shape == video.shape


def test_bad_videos(tmp_path):
    with pytest.raises(ValueError, match="constant"):
        segment_video(np.full((10, 32, 32), 7.0))
    with pytest.raises(ValueError, match="dark"):
        segment_video(np.zeros((10, 32, 32)) + np.eye(32)[None] * 1e-3)
    with pytest.raises(ValueError, match="shape"):
        segment_video(np.ones((32, 32)))
    bad = tmp_path / "v.xyz"
    bad.write_text("x")
    with pytest.raises(ValueError, match="unsupported"):
        read_video(bad)
    broken = tmp_path / "v.tif"
    broken.write_bytes(b"not a tiff")
    with pytest.raises(ValueError, match="cannot read"):
        read_video(broken)
    with pytest.raises(FileNotFoundError):
        read_video(tmp_path / "missing.tif")


def test_mask_folder(tmp_path):
    from skimage import io

    for n in range(3):
        m = np.zeros((8, 8), np.uint8)
        m[2:4, 2 : 3 + n] = 255
        io.imsave(tmp_path / f"{n}_seg.png", m, check_contrast=False)
    masks = read_masks(tmp_path)
    assert masks.shape == (3, 8, 8) and list(masks.sum(axis=(1, 2))) == [2, 4, 6]
    (tmp_path / "1_seg.png").unlink()
    with pytest.raises(ValueError, match="missing"):
        read_masks(tmp_path)


def test_mucus_bridge_does_not_drop_half_the_glottis(clip):
    video, truth = clip
    r0, r1, c0, c1 = segment_video(video).roi
    bridged = video.astype(np.float32).copy()
    mid = (r0 + r1) // 2
    bridged[:, mid : mid + 2, c0:c1] = np.maximum(bridged[:, mid : mid + 2, c0:c1], 150)
    # only the two occluded rows are lost (~4 % of the area), not a whole half
    assert _scores(segment_video(bridged).area, truth)[0] <= 0.06
