"""Embedded data that vfjax makes itself, deterministically (no download, no shared files)."""

import dataclasses

import numpy as np

from ._fit import default_warmup
from ._integrate import simulate, simulated_fold_areas
from ._validate import check_nonnegative
from .descriptors import fundamental_frequency
from .model import VocalFoldModel
from .presets import PRESSURE_KEY, preset
from .recording import Recording
from .terms import AbstractTerm
from .terms.variability import ClosureJitter

#: The seconds a per-cycle variability term (`ClosureJitter` and its kin) covers at least.
_FACTORS_COVER = 0.2


def demo_span(model: VocalFoldModel, fps: float, n_frames: int, warmup: float | None = None):
    """When `demo_recording` samples ``model``: (first frame, end of the last frame), s after
    the onset. ``fps``: frame rate (Hz); ``n_frames``: frames; ``warmup``: as there (None:
    7.7 ms after the model's `default_warmup`)."""
    start = default_warmup(model) + 0.0077 if warmup is None else float(warmup)
    check_nonnegative("warmup", start, "s")
    return start, start + n_frames / fps


def factors_duration(end: float, period: float) -> float:
    """The seconds that per-cycle factors (``random(..., duration=)`` of the variability
    terms) must cover for a recording ending ``end`` s after the onset, cycles of ``period``
    s: at least the terms' default (their first draws are the same for any duration)."""
    return max(_FACTORS_COVER, end + period)


def demo_recording(
    name: str = "N3",
    noise_px: float = 2.0,
    seed: int = 0,
    fps: float = 4000.0,
    n_frames: int = 201,
    effect: AbstractTerm | None = None,
    name_suffix: str = "",
    jitter: float = 0.0,
    model: VocalFoldModel | None = None,
    warmup: float | None = None,
) -> Recording:
    """A GAW of the paper's subject ``name`` simulated by vfjax, as a camera would see it.

    Sampled from 27.7 ms after the onset (an arbitrary point of the cycle; 7.7 ms after the
    model's `default_warmup` where that is longer, e.g. with a slow modulation), with Gaussian
    noise of ``noise_px`` pixels (seeded), rounded to whole pixels and clipped at zero. The
    metadata state the subject's sex and the subglottal pressure (as a lab that measured it
    would), so that a first fit (`vfjax.fit_recording`) holds P_s at the truth. The left and
    right folds' areas (`Recording.folds`) are measured with noise of their own (each half
    the total's variance), rounded, and add up to the GAW.

    Arguments:
        name: the preset (N1-N4).
        noise_px: standard deviation of the measurement noise (px).
        seed: seed of the noise and the jitter.
        fps: frame rate (Hz).
        n_frames: number of frames.
        effect: a term hidden in the model (e.g. ``GlottalGap(a_gap=0.008)``).
        name_suffix: appended to the recording's name.
        jitter: cycle-to-cycle variability: relative standard deviation of the closure
            duration per cycle (`ClosureJitter`), e.g. 0.003.
        model: the model to simulate instead of the preset (its subject's sex is taken
            from ``name``).
        warmup: simulated time before the first frame (s); None: 7.7 ms after the model's
            `default_warmup`. A later start records a model that settles slowly (a cubic
            stiffness: its amplitude still drifts 0.8 s after the onset) in sustained
            phonation rather than in its start-up.
    """
    model = preset(name) if model is None else model
    if effect is not None:
        model = model.with_effect(effect)
    t_start, end = demo_span(model, fps, n_frames, warmup)
    if jitter > 0 and model.closure_duration is not None:
        f0 = fundamental_frequency(np.asarray(simulate(model, fps, 400, t_start=0.02).area), fps)
        covered = factors_duration(end, 1.0 / f0)
        model = model.with_term(
            ClosureJitter.random(jitter, 1.0 / f0, duration=covered, seed=seed + 1)
        )
    sim = simulate(model, fps, n_frames, t_start=t_start)
    rng = np.random.default_rng(seed)
    area = np.asarray(sim.area) + rng.normal(0.0, noise_px, n_frames)
    area = np.clip(np.round(area), 0.0, None)
    # the left fold's share, measured with its own noise (half the total's variance); the
    # right fold's is the rest
    left, _ = simulated_fold_areas(model, sim)
    noisy = np.asarray(left) + np.random.default_rng([seed, 1]).normal(
        0.0, noise_px / 2**0.5, n_frames
    )
    left = np.clip(np.round(noisy), 0.0, area)
    meta = {
        "sex": "male" if name in ("N1", "N2") else "female",
        PRESSURE_KEY: float(model.params()["P_s"]),
        "source": "vfjax demo",
        "subject": name,
        "noise_px": noise_px,
        "seed": seed,
        "hidden_effect": None if effect is None else type(effect).__name__,
        "closure_jitter_rel": jitter,
    }
    return Recording(
        area=area,
        fps=fps,
        unit="px",
        metadata=meta,
        name=f"demo_{name}{name_suffix}",
        folds=np.stack([left, area - left], axis=1),
    )


@dataclasses.dataclass(frozen=True)
class DemoVideo:
    """A rendered laryngeal high-speed clip with its true glottal areas.

    Attributes:
        frames: the video, (frames, height, width) grey or (frames, height, width, 3) colour,
            float32 grey levels (0-255 before noise).
        fps: frame rate (Hz).
        area: the true glottal area of every frame (pixels, fractional: the share of each
            pixel that the glottis covers, summed).
        left_area, right_area: the true areas left and right of the glottal midline (pixels);
            they add up to ``area``.
        midline_column: the column of the glottal midline (pixels from the image's left edge,
            the edge of column 0 at 0).
    """

    frames: np.ndarray
    fps: float
    area: np.ndarray
    left_area: np.ndarray
    right_area: np.ndarray
    midline_column: float


def demo_video(
    area_px: np.ndarray | None = None,
    *,
    fps: float = 4000.0,
    shape: tuple[int, int] = (160, 128),
    glottal_length_px: float = 80.0,
    contrast: float = 1.0,
    blur_px: float = 1.0,
    noise: float = 3.0,
    colour: bool = False,
    asymmetry: float = 1.0,
    seed: int = 0,
) -> DemoVideo:
    """A synthetic laryngeal high-speed clip whose true glottal area is known to a fraction of
    a pixel: for testing a segmentation under noise, blur, low contrast and colour.

    The glottis is a slit along the image's columns between two folds: at a height y along
    its length L it is open from ``c - w_l(y)`` to ``c + w_r(y)`` with
    ``w(y) ~ sin(pi y / L)^0.7`` (widest in the middle, closed at both ends). Each frame's
    opening is scaled to the frame's area. Pixels are rendered from an 8 x 8 subsample of the
    geometry (so the true area counts partly covered pixels by their share), on textured,
    vignetted tissue with brighter folds beside the glottis and a dark glottis, then blurred
    (Gaussian), and noise is added.

    Arguments:
        area_px: the true glottal area of each frame (pixels); default the subject N3's GAW
            (vfjax's simulation, 160 frames at ``fps``) scaled to a 600 px peak.
        fps: frame rate (Hz).
        shape: (height, width) of a frame (pixels).
        glottal_length_px: the glottis's length along the rows (pixels).
        contrast: factor on the difference between tissue and glottis grey levels (1: about
            150 grey levels, the shared clip's; 0.2 is a dim, low-contrast camera).
        blur_px: standard deviation of the optics' Gaussian blur (pixels).
        noise: standard deviation of the sensor noise (grey levels).
        colour: render red-dominated colour frames (frames, height, width, 3), as an
            endoscope's camera does.
        asymmetry: ratio of the right fold's excursion to the left's (1: symmetric).
        seed: seed of the texture and the noise.
    """
    from scipy import ndimage

    if area_px is None:
        sim = simulate(preset("N3"), fps, 160, t_start=0.0277)
        area_px = np.clip(np.asarray(sim.area), 0.0, None) * 600.0 / float(np.max(sim.area))
    area_px = np.asarray(area_px, dtype=float)
    if area_px.ndim != 1 or np.any(area_px < 0) or not np.all(np.isfinite(area_px)):
        raise ValueError("area_px must be a 1-D series of finite areas >= 0 (pixels)")
    if not (contrast > 0 and blur_px >= 0 and noise >= 0 and asymmetry > 0):
        raise ValueError("contrast and asymmetry must be > 0, blur_px and noise >= 0")
    height, width = shape
    if not (16 <= height and 16 <= width and 2 <= glottal_length_px <= height - 4):
        raise ValueError(
            f"a frame of {height} x {width} pixels cannot hold a glottis {glottal_length_px} px "
            "long: frames of at least 16 x 16, a glottis from 2 px to 4 px short of the height"
        )
    rng = np.random.default_rng(seed)
    sub = 8
    ys = (np.arange(height * sub) + 0.5) / sub
    xs = (np.arange(width * sub) + 0.5) / sub
    top = 0.5 * (height - glottal_length_px)
    centre = 0.5 * width + 0.3
    along = np.clip((ys - top) / glottal_length_px, 0.0, 1.0)
    profile = np.sin(np.pi * along) ** 0.7  # half-width shape per subsample row
    unit_area = 2.0 * profile.sum() / sub  # area (px) of half-widths of 1 px per fold
    left_share = 1.0 / (1.0 + asymmetry)

    # tissue: smooth texture, vignetting, brighter folds along the glottis
    yy, xx = np.mgrid[:height, :width].astype(float)
    texture = ndimage.gaussian_filter(rng.standard_normal((height, width)), 3.0)
    texture *= 12.0 / texture.std()
    vignette = 1.0 - 0.35 * (((yy - height / 2) / height) ** 2 + ((xx - width / 2) / width) ** 2)
    folds = 25.0 * np.exp(-0.5 * ((xx - centre) / 12.0) ** 2) * (np.abs(yy - height / 2) < 50)
    tissue = (120.0 + texture + folds) * vignette
    dark = 25.0
    frames, areas, lefts = [], [], []
    for a in area_px:
        scale = a / unit_area
        w_l = 2.0 * left_share * scale * profile[:, None]
        w_r = 2.0 * (1.0 - left_share) * scale * profile[:, None]
        inside = (xs[None, :] > centre - w_l) & (xs[None, :] < centre + w_r)
        cover = inside.reshape(height, sub, width, sub).mean(axis=(1, 3))
        left = (inside & (xs[None, :] < centre)).reshape(height, sub, width, sub).mean(axis=(1, 3))
        areas.append(cover.sum())
        lefts.append(left.sum())
        grey = dark + (tissue - dark) * (1.0 - cover)
        frames.append(grey)
    video = np.stack(frames)
    # contrast: the tissue's distance from the glottis's level scaled about that level
    video = dark + contrast * (video - dark)
    if colour:
        tint = np.array([1.0, 0.55, 0.45])
        video = video[..., None] * tint
    if blur_px > 0:
        sigma = (0, blur_px, blur_px) + ((0,) if colour else ())
        video = ndimage.gaussian_filter(video, sigma)
    video = video + rng.normal(0.0, noise, video.shape)
    area, left = np.asarray(areas), np.asarray(lefts)
    return DemoVideo(
        frames=video.astype(np.float32),
        fps=float(fps),
        area=area,
        left_area=left,
        right_area=area - left,
        midline_column=float(centre),
    )
