"""Embedded data that vfjax makes itself, deterministically (no download, no shared files)."""

import numpy as np

from ._fit import default_warmup
from .descriptors import fundamental_frequency
from .integrator import simulate
from .presets import PRESSURE_KEY, preset
from .recording import Recording
from .terms.variability import ClosureJitter


def demo_recording(
    name: str = "N3",
    noise_px: float = 2.0,
    seed: int = 0,
    fps: float = 4000.0,
    n_frames: int = 201,
    effect=None,
    name_suffix: str = "",
    jitter: float = 0.0,
    model=None,
) -> Recording:
    """A GAW of the paper's subject ``name`` simulated by vfjax, as a camera would see it.

    Sampled from 27.7 ms after the onset (an arbitrary point of the cycle; 7.7 ms after the
    model's `default_warmup` where that is longer, e.g. with a slow modulation), with Gaussian
    noise of ``noise_px`` pixels (seeded), rounded to whole pixels and clipped at zero. The
    metadata state the subject's sex and the subglottal pressure (as a lab that measured it
    would), so that a first fit (`vfjax.fit_recording`) holds P_s at the truth.

    Arguments:
        name: the preset (N1-N4).
        noise_px: standard deviation of the measurement noise (px).
        seed: seed of the noise and the jitter.
        fps, n_frames: frame rate (Hz) and number of frames.
        effect: a term hidden in the model (e.g. ``GlottalGap(a_gap=0.008)``).
        name_suffix: appended to the recording's name.
        jitter: cycle-to-cycle variability: relative standard deviation of the closure
            duration per cycle (`ClosureJitter`), e.g. 0.003.
        model: the model to simulate instead of the preset (its subject's sex is taken
            from ``name``).
    """
    model = preset(name) if model is None else model
    if effect is not None:
        model = model.with_effect(effect)
    if jitter > 0 and model.closure_duration is not None:
        f0 = fundamental_frequency(np.asarray(simulate(model, fps, 400, t_start=0.02).area), fps)
        model = model.with_term(ClosureJitter.random(jitter, 1.0 / f0, seed=seed + 1))
    sim = simulate(model, fps, n_frames, t_start=default_warmup(model) + 0.0077)
    rng = np.random.default_rng(seed)
    area = np.asarray(sim.area) + rng.normal(0.0, noise_px, n_frames)
    area = np.clip(np.round(area), 0.0, None)
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
    return Recording(area=area, fps=fps, unit="px", metadata=meta, name=f"demo_{name}{name_suffix}")
