"""Loading recordings: tables with sidecars, and the real contour files."""

import dataclasses
import json

import numpy as np
import pytest

import vfjax
from vfjax.descriptors import fundamental_frequency
from vfjax.recording import Recording, load_contours, load_recording

REAL = {  # file stem: (frames, fps, f0 noted in the data's README or None)
    "MN003_adapt": (157, 8000.0, None),
    "FD003_pre": (145, 8000.0, None),
    "FN003": (127, 8000.0, 186.0),
    "FP005_naso": (130, 4000.0, 235.0),
}


@pytest.mark.parametrize("stem", list(REAL))
def test_real_contours(shared_dir, stem):
    frames, fps, f0 = REAL[stem]
    path = shared_dir / "data" / "real" / f"{stem}_segdata.txt"
    rec = load_contours(path, fps)
    assert rec.n_frames == frames and rec.edges.shape == (frames, 2, 256)
    # the area, computed independently from the raw lines
    lines = [ln for ln in path.read_text().splitlines() if not ln.startswith("#")]
    left = np.array(lines[0].split(), float)
    right = np.array(lines[1].split(), float)
    ok = (left > 0) & (right > 0)
    assert rec.area[0] == np.sum((right - left)[ok])
    if f0 is not None:
        assert fundamental_frequency(rec.area, fps) == pytest.approx(f0, rel=0.03)


def test_table_and_sidecar(shared_dir, tmp_path):
    rec = load_recording(shared_dir / "data" / "synthetic" / "syn_gap.csv")
    assert rec.fps == 4000.0 and rec.unit == "px" and rec.n_frames == 201
    assert rec.metadata["sex"] == "female" and rec.name == "syn_gap"
    # a round trip through vfjax's writer
    from vfjax.io import write_recording

    path = write_recording(rec, tmp_path / "copy.csv")
    back = load_recording(path)
    np.testing.assert_allclose(back.area, rec.area)
    assert back.fps == rec.fps and back.folds is None
    # per-fold areas round trip, through gaps too (each segment keeps its folds)
    left = np.round(0.3 * rec.area, 3)
    sided = dataclasses.replace(rec, folds=np.stack([left, rec.area - left], axis=1))
    path = write_recording(sided, tmp_path / "sided.csv")
    assert path.read_text().splitlines()[0] == "frame,time_s,area_px,area_left_px,area_right_px"
    np.testing.assert_allclose(load_recording(path).folds, sided.folds, atol=1e-6)
    lines = path.read_text().splitlines()
    path.write_text("\n".join(lines[:51] + lines[61:]) + "\n")  # frames 50-59 missing
    first, second = vfjax.recording.load_segments(path)
    np.testing.assert_allclose(second.folds, sided.folds[60:], atol=1e-6)
    assert first.folds.shape == (50, 2)
    path.write_text("\n".join(ln.rsplit(",", 1)[0] for ln in lines) + "\n")
    with pytest.raises(ValueError, match="area_left_px without its other fold"):
        load_recording(path)
    path.write_text(lines[0] + "\n" + lines[1].rsplit(",", 1)[0] + ",5000\n" + lines[2] + "\n")
    with pytest.raises(ValueError, match="folds do not add up"):
        load_recording(path)


def test_bad_tables_are_refused(tmp_path):
    csv = tmp_path / "a.csv"
    csv.write_text("frame,area_px\n0,1\n1,2\n")
    with pytest.raises(FileNotFoundError, match="sidecar"):
        load_recording(csv)
    (tmp_path / "a.json").write_text(json.dumps({"area_unit": "px"}))
    with pytest.raises(ValueError, match="fps"):
        load_recording(csv)
    (tmp_path / "a.json").write_text(json.dumps({"fps": 4000, "area_unit": "px"}))
    csv.write_text("frame,area_px\n0,1\n1,x\n")
    with pytest.raises(ValueError, match="non-numeric"):
        load_recording(csv)
    csv.write_text("frame,volume\n0,1\n1,2\n")
    with pytest.raises(ValueError, match="no area column"):
        load_recording(csv)
    with pytest.raises(ValueError, match="frames"):
        Recording(area=np.ones(5), fps=4000.0, edges=np.zeros((4, 2, 3)))
    # a table without a sidecar: read at a given frame rate, in the unit its column names
    plain = tmp_path / "plain.csv"
    plain.write_text("area_mm2\n0.5\n1.5\n0.25\n")
    with pytest.raises(FileNotFoundError, match="sidecar"):
        load_recording(plain)
    rec = load_recording(plain, fps=3000.0)
    assert rec.fps == 3000.0 and rec.unit == "mm2"
    np.testing.assert_array_equal(rec.area, [0.5, 1.5, 0.25])
    plain.write_text("area\n0.5\n1.5\n")
    with pytest.raises(ValueError, match="names no unit"):
        load_recording(plain, fps=3000.0)
    with pytest.raises(ValueError, match="fps"):
        load_recording(plain, fps=0.0)
    csv.write_text("frame,area_px\n0,1\n1,2\n")  # beside its sidecar (4000 Hz)
    assert load_recording(csv, fps=4000.0).fps == 4000.0
    with pytest.raises(ValueError, match="fps 5000 Hz disagrees with the sidecar's"):
        load_recording(csv, fps=5000.0)
    bad = tmp_path / "b_segdata.txt"
    bad.write_text("# c\n1 2 3\n")
    with pytest.raises(ValueError, match="two"):
        load_contours(bad, 4000.0)
    with pytest.raises(ValueError, match="fps"):
        load_contours(bad, -1.0)


def test_crop_and_resample():
    area = np.sin(np.linspace(0, 6 * np.pi, 201)) ** 2 * 100
    rec = Recording(area=area, fps=4000.0, name="x")
    c = rec.crop(0.01, 0.02)
    assert c.n_frames == 40 and c.area[0] == area[40]
    r = rec.resample(8000.0)
    assert r.n_frames == 401 and r.fps == 8000.0
    np.testing.assert_allclose(r.area[::2], area)  # original frames kept exactly
    np.testing.assert_allclose(r.area[1::2], 0.5 * (area[:-1] + area[1:]))  # linear between
    with pytest.raises(ValueError, match="crop"):
        rec.crop(0.04, 0.1)


def test_sidecar_errors_name_the_field(tmp_path):
    csv = tmp_path / "a.csv"
    csv.write_text("frame,area_px\n0,1\n1,2\n")
    (tmp_path / "a.json").write_text(json.dumps({"fps": -4000, "area_unit": "inch"}))
    with pytest.raises(ValueError, match=r"fps: -4000 .*|area_unit: 'inch'"):
        load_recording(csv)
