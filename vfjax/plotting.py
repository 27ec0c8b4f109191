"""Figures: GAWs with the model's phases shaded."""

import matplotlib.pyplot as plt
import numpy as np

from .phases import PHASE_COLOURS, PHASE_NAMES


def shade_phases(ax, time_s, phase, alpha: float = 0.35):
    """Shade the background of ``ax`` by phase code, one span per run of equal phases.

    Arguments:
        ax: a matplotlib Axes whose x axis is time in ms.
        time_s: frame times (s).
        phase: phase code per frame (see `vfjax.phases`).
    """
    t = np.asarray(time_s) * 1e3
    ph = np.asarray(phase)
    if len(t) < 2:
        return
    half = 0.5 * np.median(np.diff(t))
    starts = np.r_[0, np.nonzero(np.diff(ph))[0] + 1]
    ends = np.r_[starts[1:], len(ph)]
    seen = set()
    for a, b in zip(starts, ends):
        code = int(ph[a])
        label = PHASE_NAMES[code] if code not in seen else None
        seen.add(code)
        ax.axvspan(
            t[a] - half, t[b - 1] + half, color=PHASE_COLOURS[code], alpha=alpha, lw=0, label=label
        )


def plot_gaw(sim, ax=None, title: str | None = None, label: str = "model", unit: str = "px"):
    """Plot a simulated GAW (a `Simulation`) with its phases shaded; returns the Axes."""
    if ax is None:
        _, ax = plt.subplots(figsize=(8, 3))
    shade_phases(ax, sim.time, sim.phase)
    ax.plot(np.asarray(sim.time) * 1e3, np.asarray(sim.area), color="#c1121f", lw=1.4, label=label)
    ax.axhline(0.0, color="#1d3557", lw=0.8)
    ax.set_xlabel("time (ms)")
    ax.set_ylabel(f"glottal area ({unit})")
    if title:
        ax.set_title(title)
    ax.legend(loc="upper right", fontsize=7, ncol=5, frameon=False)
    ax.margins(x=0)
    return ax


def plot_convergence(result, ax=None):
    """The fit's convergence trace (like the paper's Fig. r1): best NMSE per PSO iteration,
    then per Levenberg-Marquardt step, on log axes."""
    if ax is None:
        _, ax = plt.subplots(figsize=(6, 3.5))
    pso = np.asarray(result.pso_trace)
    lm = np.asarray(result.lm_trace)
    it = np.arange(len(pso)) + 1
    ax.loglog(it, pso, color="#457b9d", label="particle swarm")
    if len(lm) > 1:
        ax.loglog(
            len(pso) + np.arange(len(lm)),
            np.maximum(lm, 1e-16),
            color="#e63946",
            label="Levenberg-Marquardt",
        )
    ax.set_xlabel("iteration")
    ax.set_ylabel("best NMSE")
    ax.legend(frameon=False, fontsize=8)
    ax.grid(True, which="both", alpha=0.3)
    return ax


def plot_overlay(recording, result, ax=None, title: str | None = None):
    """Measured and fitted GAW, the model's phases shaded."""
    if ax is None:
        _, ax = plt.subplots(figsize=(8, 3))
    sim = result.simulate(recording)
    t = recording.time
    shade_phases(ax, t, sim.phase)
    ax.plot(t * 1e3, recording.area, color="#2a9d8f", lw=1.4, label="measured")
    ax.plot(
        t * 1e3,
        np.clip(np.asarray(sim.area), 0, None),
        color="#c1121f",
        lw=1.2,
        label=f"model (NMSE {result.nmse:.2%})",
    )
    ax.set_xlabel("time (ms)")
    ax.set_ylabel(f"glottal area ({recording.unit})")
    ax.set_title(title or recording.name)
    ax.legend(loc="upper right", fontsize=7, ncol=6, frameon=False)
    ax.margins(x=0)
    return ax
