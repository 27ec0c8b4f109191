"""Embedded data that vfjax makes itself, deterministically (no download, no shared files)."""

import numpy as np

from .integrator import simulate
from .presets import preset
from .recording import Recording


def demo_recording(name: str = "N3", noise_px: float = 2.0, seed: int = 0, fps: float = 4000.0,
                   n_frames: int = 201) -> Recording:  # fmt: skip
    """A GAW of the paper's subject ``name`` simulated by vfjax, as a camera would see it.

    Sampled from 27.7 ms after the onset (an arbitrary point of the cycle), with Gaussian
    noise of ``noise_px`` pixels (seeded), rounded to whole pixels and clipped at zero.
    """
    sim = simulate(preset(name), fps, n_frames, t_start=0.0277)
    rng = np.random.default_rng(seed)
    area = np.asarray(sim.area) + rng.normal(0.0, noise_px, n_frames)
    area = np.clip(np.round(area), 0.0, None)
    meta = {"sex": "male" if name in ("N1", "N2") else "female", "source": "vfjax demo",
            "subject": name, "noise_px": noise_px, "seed": seed}  # fmt: skip
    return Recording(area=area, fps=fps, unit="px", metadata=meta, name=f"demo_{name}")
