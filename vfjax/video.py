"""Laryngeal high-speed video: readers, and supplied masks.

Readers return a (frames, height, width) array. Formats: multi-page TIFF (tifffile), NumPy
``.npy``, Photron MRAW with its CIH/CIHX header (pyMRAW, 8, 12 and 16 bit; optional
dependency ``pip install pyMRAW``), and AVI/MP4 (imageio; a video plugin such as ``imageio[pyav]``
or ``imageio[ffmpeg]`` is needed). Colour video is converted to grey.
"""

import pathlib
import re

import numpy as np


def _to_grey(video: np.ndarray) -> np.ndarray:
    if video.ndim == 4 and video.shape[-1] in (3, 4):
        video = video[..., :3] @ np.array([0.299, 0.587, 0.114])
    if video.ndim != 3:
        raise ValueError(f"expected a (frames, height, width) video, got shape {video.shape}")
    if video.shape[0] < 2:
        raise ValueError(f"a video needs at least 2 frames, got {video.shape[0]}")
    return video


def read_video(path) -> tuple[np.ndarray, float | None]:
    """Read a video file; returns (frames, fps or None when the file does not say)."""
    path = pathlib.Path(path)
    if not path.exists():
        raise FileNotFoundError(f"no video at {path}")
    suffix = path.suffix.lower()
    known = (".tif", ".tiff", ".npy", ".cih", ".cihx", ".mraw", ".avi", ".mp4", ".mov", ".mkv")
    if suffix not in known:
        raise ValueError(
            f"unsupported video format {suffix!r}: use .tif/.tiff, .npy, .cih/.cihx "
            "(+ .mraw), .avi or .mp4"
        )
    fps = None
    try:
        if suffix in (".tif", ".tiff"):
            import tifffile

            video = tifffile.imread(path)
        elif suffix == ".npy":
            video = np.load(path, allow_pickle=False)
        elif suffix in (".cih", ".cihx", ".mraw"):
            video, fps = _read_mraw(path)
        elif suffix in (".avi", ".mp4", ".mov", ".mkv"):
            import imageio.v3 as iio

            video = np.asarray(iio.imread(path))
            try:
                fps = iio.immeta(path).get("fps")
            except Exception:  # noqa: BLE001 - metadata is optional
                fps = None
    except Exception as err:  # unreadable or corrupt file: say which
        raise ValueError(f"cannot read {path}: {type(err).__name__}: {err}") from err
    return _to_grey(np.asarray(video)), fps


def _read_mraw(path: pathlib.Path):
    try:
        import pyMRAW
    except ImportError as err:
        raise ValueError("reading Photron MRAW needs pyMRAW: pip install pyMRAW") from err
    header = path if path.suffix.lower() in (".cih", ".cihx") else None
    if header is None:
        for ext in (".cihx", ".cih"):
            if path.with_suffix(ext).exists():
                header = path.with_suffix(ext)
                break
    if header is None:
        raise ValueError(f"{path}: no .cih/.cihx header beside the .mraw file")
    video, info = pyMRAW.load_video(str(header))
    fps = info.get("Record Rate(fps)") if isinstance(info, dict) else None
    return np.asarray(video), float(fps) if fps else None


def read_masks(folder) -> np.ndarray:
    """Binary masks from a folder of PNG files named like the BAGLS benchmark: ``N_seg.png``
    (N the frame number), in frame order. Returns (frames, height, width) bool."""
    from skimage import io

    folder = pathlib.Path(folder)
    files = [
        (int(m.group(1)), p)
        for p in folder.glob("*_seg.png")
        if (m := re.fullmatch(r"(\d+)_seg\.png", p.name))
    ]
    if not files:
        raise ValueError(f"{folder}: no masks named like N_seg.png")
    files.sort()
    numbers = [n for n, _ in files]
    if numbers != list(range(numbers[0], numbers[0] + len(numbers))):
        missing = sorted(set(range(numbers[0], numbers[-1] + 1)) - set(numbers))
        raise ValueError(f"{folder}: masks missing for frames {missing[:10]}")
    masks = np.stack([np.asarray(io.imread(p)) for _, p in files])
    if masks.ndim == 4:
        masks = masks[..., 0]
    return masks > 0
