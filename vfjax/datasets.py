"""Embedded data that vfjax makes itself, deterministically (no download, no shared files)."""

import numpy as np

from .integrator import simulate
from .presets import preset
from .recording import Recording


def demo_recording(
    name: str = "N3",
    noise_px: float = 2.0,
    seed: int = 0,
    fps: float = 4000.0,
    n_frames: int = 201,
    effect=None,
    name_suffix: str = "",
) -> Recording:
    """A GAW of the paper's subject ``name`` simulated by vfjax, as a camera would see it.

    Sampled from 27.7 ms after the onset (an arbitrary point of the cycle), with Gaussian
    noise of ``noise_px`` pixels (seeded), rounded to whole pixels and clipped at zero.
    ``effect``: a term hidden in the model (e.g. ``GlottalGap(a_gap=0.008)``).
    """
    model = preset(name) if effect is None else preset(name).with_effect(effect)
    sim = simulate(model, fps, n_frames, t_start=0.0277)
    rng = np.random.default_rng(seed)
    area = np.asarray(sim.area) + rng.normal(0.0, noise_px, n_frames)
    area = np.clip(np.round(area), 0.0, None)
    meta = {"sex": "male" if name in ("N1", "N2") else "female", "source": "vfjax demo",
            "subject": name, "noise_px": noise_px, "seed": seed,
            "hidden_effect": None if effect is None else type(effect).__name__}  # fmt: skip
    return Recording(area=area, fps=fps, unit="px", metadata=meta, name=f"demo_{name}{name_suffix}")
