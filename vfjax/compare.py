"""Compare a fitted model with the measurement: where it fails, in numbers and in words."""

import dataclasses

import numpy as np

from ._fit import FitResult
from .descriptors import Descriptors, describe, noise_level
from .phases import CLOSED, PHASE_NAMES
from .recording import Recording

#: Descriptors shown in the comparison table: (attribute, label, unit, relative tolerance
#: beyond which the model "misses"; None: an absolute tolerance given in the next field).
TABLE = (
    ("f0", "f0", "Hz", 0.02),
    ("open_quotient", "open quotient", "", 0.05),
    ("speed_quotient", "speed quotient", "", 0.15),
    ("closing_quotient", "closing quotient", "", 0.15),
    ("closed_phase_level", "closed-phase level", "unit", None),
    ("amplitude", "amplitude", "unit", 0.05),
    ("jitter", "jitter", "", None),
    ("shimmer", "shimmer", "", None),
)


@dataclasses.dataclass(frozen=True)
class Comparison:
    """Measured against fitted GAW, on the recording's frames.

    Attributes:
        time: frame times (s).
        measured, simulated: GAWs (the recording's unit; simulated clipped at zero).
        residual: measured - simulated.
        phase: the model's phase at each frame.
        nmse: normalised squared error.
        error_share: share of the squared error in each phase (by name).
        time_share: share of the frames in each phase.
        measured_descriptors, simulated_descriptors: `Descriptors` of both.
        unit: area unit.
    """

    time: np.ndarray
    measured: np.ndarray
    simulated: np.ndarray
    residual: np.ndarray
    phase: np.ndarray
    nmse: float
    error_share: dict
    time_share: dict
    measured_descriptors: Descriptors
    simulated_descriptors: Descriptors
    unit: str

    def table(self) -> list[tuple[str, float, float, str]]:
        """(descriptor, measured, simulated, unit) rows."""
        rows = []
        for attr, label, unit, _ in TABLE:
            unit = self.unit if unit == "unit" else unit
            rows.append(
                (
                    label,
                    getattr(self.measured_descriptors, attr),
                    getattr(self.simulated_descriptors, attr),
                    unit,
                )
            )
        return rows

    def failures(self) -> list[str]:
        """Where the model misses, in words, largest first."""
        return _failures(self)


def compare(result: FitResult, recording: Recording) -> Comparison:
    """Compare ``result``'s fitted model with ``recording``."""
    sim = result.simulate(recording)
    simulated = np.clip(np.asarray(sim.area), 0.0, None)
    measured = np.asarray(recording.area, dtype=float)
    phase = np.asarray(sim.phase)
    residual = measured - simulated
    total = float(np.sum(residual**2))
    error_share = {
        name: float(np.sum(residual[phase == code] ** 2) / total) if total else 0.0
        for code, name in enumerate(PHASE_NAMES)
    }
    time_share = {name: float(np.mean(phase == code)) for code, name in enumerate(PHASE_NAMES)}
    return Comparison(
        time=recording.time,
        measured=measured,
        simulated=simulated,
        residual=residual,
        phase=phase,
        nmse=float(total / np.sum(measured**2)),
        error_share=error_share,
        time_share=time_share,
        measured_descriptors=describe(measured, recording.fps),
        simulated_descriptors=describe(simulated, recording.fps),
        unit=recording.unit,
    )


def _fmt(x, unit=""):
    return f"{x:.3g}{(' ' + unit) if unit else ''}"


#: How `Comparison.failures` begins when it finds none.
NO_CLEAR_FAILURE = "no clear failure"


def _failures(c: Comparison) -> list[str]:
    found = []  # (weight, sentence)
    sigma = noise_level(c.measured, c.simulated)
    peak = max(float(np.max(c.measured)), 1e-12)
    # phases that carry more of the error than of the time, well above the noise (and above
    # a thousandth of the peak: on noise-free data the noise estimate is ~0)
    visible = max(3.0 * sigma, 1e-3 * peak)
    for code, (name, share) in enumerate(c.error_share.items()):
        in_phase = c.phase == code
        rms = float(np.sqrt(np.mean(c.residual[in_phase] ** 2))) if in_phase.any() else 0.0
        if share > 0.25 and share > 1.5 * c.time_share[name] and rms > visible:
            found.append(
                (
                    share,
                    f"{name} phase: {100 * share:.0f} % of the squared error in "
                    f"{100 * c.time_share[name]:.0f} % of the frames",
                )
            )
    m, s = c.measured_descriptors, c.simulated_descriptors
    closed = c.phase == CLOSED
    if closed.any():
        floor = float(np.median(c.measured[closed]))
        model_floor = float(np.median(c.simulated[closed]))
        if floor - model_floor > 0.02 * peak:
            model_words = (
                "the model closes fully"
                if model_floor <= 0.005 * peak
                else f"the model's is {_fmt(model_floor, c.unit)}"
            )
            found.append(
                (
                    (floor - model_floor) / peak,
                    f"closed phase: the measured area never falls below "
                    f"{_fmt(float(np.min(c.measured[closed])), c.unit)} (median "
                    f"{_fmt(floor, c.unit)}), {model_words}",
                )
            )
    for attr, label, unit, tol in TABLE:
        a, b = getattr(m, attr), getattr(s, attr)
        if not (np.isfinite(a) and np.isfinite(b)):
            continue
        unit = c.unit if unit == "unit" else unit
        if attr == "closed_phase_level":
            miss = abs(a - b) > 0.02 * peak
        elif attr in ("jitter", "shimmer"):
            miss = a > 0.01 and a > 3 * b
        else:
            miss = abs(a - b) > tol * max(abs(a), 1e-12)
        if miss:
            rel = abs(a - b) / max(abs(a), 1e-12)
            found.append(
                (min(rel, 1.0), f"{label}: measured {_fmt(a, unit)}, model {_fmt(b, unit)}")
            )
    if not found:
        return [
            f"{NO_CLEAR_FAILURE}: NMSE {100 * c.nmse:.2f} %, no phase's error stands out "
            f"above the noise ({_fmt(sigma, c.unit)}), descriptors within tolerance"
        ]
    found.sort(key=lambda w: -w[0])
    return [text for _, text in found]


def plot_comparison(c: Comparison, title: str = ""):
    """Overlay, residual with the model's phases shaded, and the error share per phase."""
    import matplotlib.pyplot as plt

    from .plotting import shade_phases

    fig, axes = plt.subplots(3, 1, figsize=(9, 7), gridspec_kw={"height_ratios": [2, 1.3, 1]})
    t = c.time * 1e3
    shade_phases(axes[0], c.time, c.phase)
    axes[0].plot(t, c.measured, color="#2a9d8f", lw=1.4, label="measured")
    axes[0].plot(t, c.simulated, color="#c1121f", lw=1.2, label="model")
    axes[0].set_ylabel(f"area ({c.unit})")
    axes[0].legend(fontsize=7, ncol=6, loc="upper right", frameon=False)
    axes[0].set_title(title or f"NMSE {100 * c.nmse:.2f} %")
    shade_phases(axes[1], c.time, c.phase)
    axes[1].plot(t, c.residual, color="#343a40", lw=1.0)
    axes[1].axhline(0, color="#1d3557", lw=0.6)
    axes[1].set_ylabel(f"residual ({c.unit})")
    axes[1].set_xlabel("time (ms)")
    for ax in axes[:2]:
        ax.margins(x=0)
    names = list(c.error_share)
    x = np.arange(len(names))
    axes[2].bar(
        x - 0.2,
        [c.error_share[n] for n in names],
        0.4,
        label="share of squared error",
        color="#e63946",
    )
    axes[2].bar(
        x + 0.2, [c.time_share[n] for n in names], 0.4, label="share of frames", color="#adb5bd"
    )
    axes[2].set_xticks(x, names)
    axes[2].legend(fontsize=7, frameon=False)
    fig.tight_layout()
    return fig
