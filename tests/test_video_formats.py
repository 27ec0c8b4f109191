"""Photron MRAW/CIH in 8, 12 (packed) and 16 bit, read back exactly; 12-bit clip_a segmented."""

import pathlib
import warnings

import numpy as np
import pytest

from vfjax.segmentation import segment_video
from vfjax.video import read_video

pyMRAW = pytest.importorskip("pyMRAW", reason="pyMRAW is in the test extras")


def _write_12bit(video: np.ndarray, cih_template: pathlib.Path, path: pathlib.Path):
    """Photron's packed 12-bit layout: two pixels in three bytes, most significant first."""
    flat = video.astype(np.uint16).ravel()
    a, b = flat[0::2], flat[1::2]
    packed = np.stack([a >> 4, ((a & 0xF) << 4) | (b >> 8), b & 0xFF], axis=1).astype(np.uint8)
    packed.ravel().tofile(path.with_suffix(".mraw"))
    header = cih_template.read_text().replace("Color Bit : 16", "Color Bit : 12")
    path.with_suffix(".cih").write_text(header)
    return path.with_suffix(".cih")


@pytest.mark.parametrize("bits", [8, 12, 16])
def test_mraw_round_trip(tmp_path, bits):
    rng = np.random.default_rng(bits)
    top = 255 if bits == 8 else 4095
    video = rng.integers(0, top + 1, (6, 16, 24)).astype(np.uint8 if bits == 8 else np.uint16)
    _, cih16 = pyMRAW.save_mraw(
        video.astype(np.uint16),
        str(tmp_path / "v16.cih"),
        bit_depth=16,
        info_dict={"Record Rate(fps)": 4000},
    )
    if bits == 8:
        _, cih = pyMRAW.save_mraw(
            video, str(tmp_path / "v8.cih"), bit_depth=8, info_dict={"Record Rate(fps)": 4000}
        )
    elif bits == 12:
        cih = _write_12bit(video, pathlib.Path(cih16), tmp_path / "v12.cih")
    else:
        cih = cih16
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # read as it was written, without a warning
        got, fps = read_video(cih)
    assert fps == 4000.0
    np.testing.assert_array_equal(got, video)


def test_clip_a_as_12bit_mraw(shared_dir, tmp_path):
    folder = shared_dir / "data" / "hsv"
    video, _ = read_video(folder / "clip_a.tif")
    truth = np.loadtxt(folder / "clip_a_truth.csv", delimiter=",", skiprows=1)[:, 1]
    twelve = np.round(video.astype(float) * 4095 / 255).astype(np.uint16)
    _, cih16 = pyMRAW.save_mraw(
        twelve[:2], str(tmp_path / "t.cih"), bit_depth=16, info_dict={"Record Rate(fps)": 4000}
    )
    cih = _write_12bit(twelve, pathlib.Path(cih16), tmp_path / "clip12.cih")
    text = cih.read_text().replace("Total Frame : 2", f"Total Frame : {len(twelve)}")
    cih.write_text(text)
    got, fps = read_video(cih)
    np.testing.assert_array_equal(got, twelve)
    area = segment_video(got).area
    big = truth >= 0.1 * truth.max()
    assert np.median(np.abs(area[big] - truth[big]) / truth[big]) <= 0.03


def test_avi_round_trip(tmp_path):
    pytest.importorskip("av", reason="PyAV is in the test extras")
    import imageio.v3 as iio

    video = np.random.default_rng(0).integers(0, 256, (8, 32, 48)).astype(np.uint8)
    path = tmp_path / "v.avi"
    iio.imwrite(
        path, np.repeat(video[..., None], 3, axis=-1), plugin="pyav", codec="ffv1", fps=1000
    )  # this AVI muxer refuses frame rates above 1000
    got, fps = read_video(path)
    assert got.shape == video.shape and fps == 1000.0
    assert np.max(np.abs(got - video)) <= 1.0 + 1e-9  # lossless codec; colour-to-grey rounding
