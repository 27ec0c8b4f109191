"""The glottal midline, per-fold areas and asymmetry indices against constructed truths and
the real contour files."""

import dataclasses

import numpy as np
import pytest

import vfjax
from vfjax.asymmetry import Midline, asymmetry_indices, fold_areas, glottal_midline
from vfjax.recording import load_contours

FPS = 4000.0
ROWS = np.arange(120)
GLOTTIS = (ROWS >= 20) & (ROWS <= 100)
PROFILE = np.where(GLOTTIS, np.sin(np.pi * (ROWS - 20) / 80.0), 0.0)
LINE = Midline(top=(20.0, 60.0), bottom=(100.0, 72.0))  # slanted: 12 columns over 80 rows


def _edges(width_left, width_right, line=LINE):
    """Contour edges of folds that open ``width_left`` and ``width_right`` (pixels, per frame)
    from the midline ``line``, with the glottis's length profile: 0 outside the glottis."""
    mid = line.column(ROWS)
    left = mid[None] - np.outer(width_left, PROFILE)
    right = mid[None] + np.outer(width_right, PROFILE)
    open_ = GLOTTIS[None] & (np.outer(width_left + width_right, PROFILE) > 0)
    return np.stack([np.where(open_, left, 0.0), np.where(open_, right, 0.0)], axis=1)


def test_the_midline_runs_through_the_glottis_ends():
    frames = np.arange(200)
    width = 8.0 * np.maximum(np.sin(2 * np.pi * frames / 40.0), 0.0) + 0.5
    found = glottal_midline(_edges(width, width))
    for row in (20.0, 60.0, 100.0):
        assert float(found.column(row)) == pytest.approx(float(LINE.column(row)), abs=1e-9)


def test_indices_of_folds_with_known_amplitudes_and_lag():
    """Left fold opens 10 px, right 6 px and 4 frames later, with 40-frame cycles: ASI is 0.6
    and PAI is the lag over the cycle's frames."""
    frames = np.arange(240)
    w_l = 10.0 * np.maximum(np.sin(2 * np.pi * frames / 40.0), 0.0)
    w_r = 6.0 * np.maximum(np.sin(2 * np.pi * (frames - 4) / 40.0), 0.0)
    edges = _edges(w_l, w_r)
    width = np.where(edges[:, 0] > 0, edges[:, 1] - edges[:, 0], 0.0)
    rec = vfjax.Recording(area=width.sum(axis=1), fps=FPS, edges=edges)
    left, right = fold_areas(rec, LINE)
    np.testing.assert_allclose(left, w_l * PROFILE.sum(), atol=1e-9)
    np.testing.assert_allclose(right, w_r * PROFILE.sum(), atol=1e-9)
    ai = asymmetry_indices(left, right, FPS)
    assert ai.n_cycles >= 4
    assert ai.asi == pytest.approx(0.6, abs=1e-9)
    assert 4 / 42 <= ai.pai <= 4 / 40


def test_masks_split_by_pixel_share():
    """A mask row of pixels 40-59 split by a midline at 1-based column 51.5: 10.5 pixels on
    each side; the same split from the masks' own midline (a vertical glottis)."""
    masks = np.zeros((3, 30, 100), dtype=bool)
    masks[:, 5:25, 40:60] = True
    rec = vfjax.Recording(area=masks.sum(axis=(1, 2)).astype(float), fps=FPS, masks=masks)
    left, right = fold_areas(rec, Midline(top=(5.0, 51.5), bottom=(24.0, 51.5)))
    np.testing.assert_allclose(left, 20 * 10.5)
    np.testing.assert_allclose(right, 20 * 9.5)
    left, right = fold_areas(rec)  # midline at the centre, 1-based column 51
    np.testing.assert_allclose(left, 20 * 10.0)
    np.testing.assert_allclose(right, 20 * 10.0)


def test_real_contours_split_exactly_and_mirror(shared_dir):
    rec = load_contours(shared_dir / "data/real/FN003_segdata.txt", 8000.0)
    left, right = fold_areas(rec)
    np.testing.assert_allclose(left + right, rec.area, atol=1e-9)
    assert left.max() > 0 and right.max() > 0
    # mirrored left to right (column c -> 300 - c), the folds swap
    edges = np.where(rec.edges > 0, 300.0 - rec.edges[:, ::-1], 0.0)
    mirrored = dataclasses.replace(rec, edges=edges)
    m_left, m_right = fold_areas(mirrored)
    np.testing.assert_allclose(m_left, right, atol=1e-9)
    np.testing.assert_allclose(m_right, left, atol=1e-9)
    ai = asymmetry_indices(left, right, rec.fps)
    assert ai.n_cycles >= 1 and 0.0 < ai.asi < 1.0 and 0.0 <= ai.pai < 0.5


def test_symmetric_simulated_folds_and_bad_input():
    sim = vfjax.simulate(vfjax.preset("N3"), FPS, 201)
    half = np.clip(np.asarray(sim.area), 0.0, None) / 2
    ai = asymmetry_indices(half, half, FPS)
    assert ai.n_cycles >= 4 and ai.asi == 1.0 and ai.pai == 0.0
    with pytest.raises(ValueError, match="total area only"):
        fold_areas(vfjax.Recording(area=half, fps=FPS))
    with pytest.raises(ValueError, match="equal length"):
        asymmetry_indices(half, half[:-1], FPS)
    flat = np.zeros((4, 2, 10))
    flat[:, 0, 3], flat[:, 1, 3] = 10.0, 20.0  # one row only
    with pytest.raises(ValueError, match="two image rows"):
        glottal_midline(flat)
