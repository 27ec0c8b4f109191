"""Writing recordings: a CSV table of the GAW plus a JSON sidecar with its metadata."""

import json
import pathlib

import numpy as np

from .phases import PHASE_NAMES


def write_simulation(sim, path, *, metadata: dict | None = None) -> pathlib.Path:
    """Write a `Simulation` as ``path`` (CSV: frame, time_s, area_px, phase) and a sidecar.

    The sidecar, ``path`` with the suffix ``.json``, holds the frame rate (Hz), the area unit
    and ``metadata``. Returns the CSV path.
    """
    path = pathlib.Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    t = np.asarray(sim.time)
    area = np.asarray(sim.area)
    phase = np.asarray(sim.phase)
    with path.open("w") as f:
        f.write("frame,time_s,area_px,phase\n")
        for i, (ti, ai, pi) in enumerate(zip(t, area, phase)):
            f.write(f"{i},{ti:.8f},{ai:.6f},{PHASE_NAMES[int(pi)]}\n")
    fps = 1.0 / float(np.median(np.diff(t))) if len(t) > 1 else None
    sidecar = {"fps": round(fps, 6) if fps else None, "area_unit": "px", "source": "vfjax"}
    sidecar.update(metadata or {})
    path.with_suffix(".json").write_text(json.dumps(sidecar, indent=1) + "\n")
    return path


def write_recording(recording, path) -> pathlib.Path:
    """Write a `Recording` as ``path`` (CSV: frame, time_s, area_<unit>) and its sidecar."""
    path = pathlib.Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("w") as f:
        f.write(f"frame,time_s,area_{recording.unit}\n")
        for i, (t, a) in enumerate(zip(recording.time, recording.area)):
            f.write(f"{i},{t:.8f},{a:.6f}\n")
    sidecar = {"fps": recording.fps, "area_unit": recording.unit, **recording.metadata}
    path.with_suffix(".json").write_text(json.dumps(sidecar, indent=1) + "\n")
    return path
