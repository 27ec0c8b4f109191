"""Laryngeal high-speed video: readers, and supplied masks.

Readers return a (frames, height, width) array. Formats: multi-page TIFF (tifffile), NumPy
``.npy``, Photron MRAW with its CIH/CIHX header (pyMRAW, 8, 12 and 16 bit; optional
dependency ``pip install pyMRAW``), and AVI/MP4 (imageio; a video plugin such as ``imageio[pyav]``
or ``imageio[ffmpeg]`` is needed). Colour video is converted to grey.
"""

import pathlib
import re
import warnings

import numpy as np


def _to_grey(video: np.ndarray) -> np.ndarray:
    if video.ndim == 4 and video.shape[-1] in (3, 4):
        video = video[..., :3] @ np.array([0.299, 0.587, 0.114])
    if video.ndim != 3:
        raise ValueError(f"expected a (frames, height, width) video, got shape {video.shape}")
    if video.shape[0] < 2:
        raise ValueError(f"a video needs at least 2 frames, got {video.shape[0]}")
    return video


#: The most pixels (frames x height x width) a video may hold: 2^28, e.g. 4 000 frames of
#: 256 x 256. Segmentation works in float32 with a few copies, so this keeps it within a few
#: GB; a longer clip is refused before it is decoded (cut it into parts).
MAX_VIDEO_PIXELS = 2**28


def _check_size(path, shape) -> None:
    if shape is None:
        return
    shape = tuple(int(n) for n in shape)
    n = int(np.prod(shape[:3])) if len(shape) >= 3 else 0
    if n > MAX_VIDEO_PIXELS:
        raise ValueError(
            f"{path}: {shape[0]} frames of {shape[1]} x {shape[2]} pixels, more than the "
            f"{MAX_VIDEO_PIXELS} pixels vfjax segments at once: cut the video into parts"
        )


def _declared_shape(path, suffix):
    """The video's shape from its header, without decoding it (None if unknown)."""
    if suffix == ".npy":
        return np.load(path, mmap_mode="r", allow_pickle=False).shape
    if suffix in (".tif", ".tiff"):
        import tifffile

        with tifffile.TiffFile(path) as tif:
            return tif.series[0].shape
    if suffix in (".avi", ".mp4", ".mov", ".mkv"):
        import imageio.v3 as iio

        return iio.improps(path).shape
    return None


#: Suffixes of the high-speed videos `read_video` reads (a .mraw through its .cih/.cihx).
VIDEO_SUFFIXES = (".avi", ".mp4", ".mov", ".mkv", ".tif", ".tiff", ".npy", ".cih", ".cihx")


def read_video(path) -> tuple[np.ndarray, float | None]:
    """Read a video file; returns (frames, fps or None when the file does not say).

    A video of more than `MAX_VIDEO_PIXELS` pixels is refused, from its header where the
    format has one, before it is decoded."""
    path = pathlib.Path(path)
    if not path.exists():
        raise FileNotFoundError(f"no video at {path}")
    suffix = path.suffix.lower()
    if suffix not in (*VIDEO_SUFFIXES, ".mraw"):
        raise ValueError(
            f"unsupported video format {suffix!r}: use .tif/.tiff, .npy, .cih/.cihx "
            "(+ .mraw), .avi or .mp4"
        )
    fps = None
    try:
        _check_size(path, _declared_shape(path, suffix))
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
    except ValueError as err:
        if str(err).startswith(str(path)):
            raise
        raise ValueError(f"cannot read {path}: {type(err).__name__}: {err}") from err
    except Exception as err:  # unreadable or corrupt file: say which
        raise ValueError(f"cannot read {path}: {type(err).__name__}: {err}") from err
    video = np.asarray(video)
    _check_size(path, video.shape)
    return _to_grey(video), fps


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
    with warnings.catch_warnings():  # (pyMRAW warns of every depth but 12 bits, read alike)
        warnings.filterwarnings("ignore", "Not 12bit image!", UserWarning)
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
