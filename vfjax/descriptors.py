"""GAW descriptors, computed the same way for measured and simulated waveforms.

Cycle detection: a cycle starts where the area rises through the middle of its range (the
level half way between its minimum and maximum), located to a fraction of a frame by linear
interpolation between the two frames around the crossing.
"""

import numpy as np


def _as_waveform(area, fps):
    area = np.asarray(area, dtype=float)
    if area.ndim != 1:
        raise ValueError(f"area must be one-dimensional, got shape {area.shape}")
    if not np.all(np.isfinite(area)):
        raise ValueError("area has NaN or infinite values")
    if not (np.isfinite(fps) and fps > 0):
        raise ValueError(f"fps (frame rate) must be > 0 Hz, got {fps}")
    return area


def cycle_starts(area, fps: float, level: float = 0.5) -> np.ndarray:
    """Times (s) at which the GAW rises through ``min + level * (max - min)``.

    Arguments:
        area: glottal area waveform, one value per frame (any unit).
        fps: frame rate (Hz).
        level: the crossing level as a fraction of the waveform's range.
    """
    area = _as_waveform(area, fps)
    lo, hi = area.min(), area.max()
    if hi <= lo:
        return np.zeros(0)
    thr = lo + level * (hi - lo)
    i = np.nonzero((area[:-1] < thr) & (area[1:] >= thr))[0]
    frac = (thr - area[i]) / (area[i + 1] - area[i])
    return (i + frac) / fps


def fundamental_frequency(area, fps: float) -> float:
    """f0 (Hz): the inverse of the mean cycle length; NaN with fewer than two cycle starts."""
    starts = cycle_starts(area, fps)
    if len(starts) < 2:
        return float("nan")
    return float((len(starts) - 1) / (starts[-1] - starts[0]))
