"""Null recordings: what the fitted model, with no candidate effect, would have produced in
the fit's own sampling, with the recording's cycle-to-cycle variability and noise.

A null recording is the fitted model's GAW with cycle-to-cycle variability drawn afresh
(timing offsets, a random walk of the timing and amplitude factors, `TimingJitter` and
`AmplitudeJitter`, matched to the recording's per-cycle misfits: `Variability`) and white
noise at the recording's level, clipped at zero and rounded like the recording
(`_NullSource`). The variability's kind and size are found by simulation
(`variability_kind`, `variability_size`).
"""

import dataclasses
import math
from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from scipy import optimize

from .._programs import program
from .._sampling import length_bucket
from ..compare import noise_level
from ..recording import Recording
from ..terms.variability import AmplitudeJitter, TimingJitter
from ._cycles import cycle_deviation, variability_measures


@dataclasses.dataclass(frozen=True)
class Variability:
    """The cycle-to-cycle variability of a recording, and the model's that matches it.

    Null recordings carry `TimingJitter` offsets, a random walk of them (periods that vary
    from cycle to cycle, so that the timing wanders, as a closure hold of varying length
    makes it) and `AmplitudeJitter` factors, one per cycle. Their proportions are those
    that show the recording's per-cycle timing and amplitude misfits (`variability_kind`),
    measured alike on the recording and on simulated ones, noise included. A mechanism the
    model lacks varies too: their size is set so that null recordings show the recording's
    misfit that changes from cycle to cycle (`cycle_deviation`, theirs after what a refit of
    the fitted parameters takes up, as the recording's is measured about its fit; the misfit
    every cycle shares is left to the candidates; `variability_size`).

    Attributes:
        jitter, shimmer: the recording's local jitter and shimmer (fractions; reported,
            not simulated: at a few frames a cycle they mostly show the noise).
        timing_sd: standard deviation of the timing offsets about the model's clock (s).
        amplitude_sd: standard deviation of the amplitude factors.
        simulated_control_nmse: the control refit's mean NMSE on the null recordings (on
            the recording: `Calibrated.control_nmse`).
        noise_sd: standard deviation of the white measurement noise (the GAW's unit).
        period: the fitted model's cycle length (s), the slot of the jitter factors.
        period_sd: standard deviation of each cycle's period, the step of the timing's
            random walk (s).
    """

    jitter: float
    shimmer: float
    timing_sd: float
    amplitude_sd: float
    simulated_control_nmse: float
    noise_sd: float
    period: float
    period_sd: float = 0.0


class _Simulator(eqx.Module):
    """Simulates recordings of one fit's sampling (padded to its length bucket)."""

    problem: object  # the fit's `Problem` (its grid and sizes)

    def gaw(self, model, shift):
        """The area as the model gives it: negative where the folds overlap (a camera adds
        its noise to what it sees, then clips)."""
        sim = self.problem.simulate(model, shift)
        return jnp.where(sim.complete, sim.area, jnp.nan)


@program
def _jittered_gaws(simulator, model, shift, offsets, factors):
    """The GAWs of ``model`` (whose last two terms are a `TimingJitter` and an
    `AmplitudeJitter`) with each row of offsets and factors; NaN rows for failed
    simulations."""

    def one(o, f):
        m = eqx.tree_at(lambda m: (m.terms[-2].offsets, m.terms[-1].factors), model, (o, f))
        return simulator.gaw(m, shift)

    return jax.vmap(one)(offsets, factors)


#: Recordings simulated per call of the null recordings' program.
_DRAW_BATCH = 16


class Spreads(NamedTuple):
    """The cycle-to-cycle variability of null recordings (`_NullSource.jitter`)."""

    timing: float = 0.0  # deviation of the timing offsets about the model's clock (s)
    amplitude: float = 0.0  # deviation of the amplitude factors
    period: float = 0.0  # deviation of each cycle's period, a random walk of the timing (s)


#: A parameter's step in the central differences of `_NullSource._fit_directions`, relative
#: to its value.
_RELATIVE_STEP = 1e-4

#: No variability: white noise only.
NO_SPREADS = Spreads()


class Normals(NamedTuple):
    """Standard normal draws of null recordings, one row each, which `_NullSource.draw_from`
    scales into their timing offsets, the steps of their timing's walk, their amplitude
    factors (one per slot) and their white noise (one per frame). One set of draws at
    several spreads (common random numbers) changes a measure only as the spreads change
    it, not by the draws' own scatter: what `variability_kind` and `variability_size`
    solve for."""

    offsets: np.ndarray  # (recordings, slots)
    factors: np.ndarray  # (recordings, slots)
    steps: np.ndarray  # (recordings, slots)
    noise: np.ndarray  # (recordings, frames bucket)


class _NullSource:
    """Draws recordings from a model: its GAW at the problem's sampling and time shift, with
    cycle-to-cycle variability and white noise at the level of the recording's misfit to
    that GAW, clipped at zero and rounded like the recording (integer areas stay
    integers). ``fitted``: the names of the parameters the fit adjusted (S for the scale),
    whose first-order effect on the GAW (with the time shift's) `refitted` removes from a
    null recording's misfit before its variability is measured."""

    def __init__(
        self, problem, model, shift, recording: Recording, period, seed, start=0.0, fitted=()
    ):
        self.simulator = _Simulator(problem)
        self.shift = jnp.asarray(shift)
        self.recording = recording
        self.period = float(period)
        # the jitter's slots reach the last frame of any sampling it is simulated in
        # (``start``: the latest first frame, warm-up and shift, of those)
        horizon = max(float(problem.grid.t_start) + float(problem.grid.max_time_shift), start)
        horizon += recording.n_frames / recording.fps
        self.n_slots = length_bucket(math.ceil(horizon / period) + 2)
        # the slot of the first frame, where a random walk of the timing starts (its value
        # there is a time shift, which the refits take up)
        first = float(problem.grid.t_start) + float(shift)
        self.first_slot = min(max(int(first / period), 0), self.n_slots - 1)
        self.model = model.with_term(TimingJitter(np.zeros(self.n_slots), period)).with_term(
            AmplitudeJitter(np.ones(self.n_slots), period)
        )
        self.integral = bool(np.all(recording.area == np.round(recording.area)))
        zero = jnp.zeros((_DRAW_BATCH, self.n_slots))
        one = jnp.ones((_DRAW_BATCH, self.n_slots))
        clean = np.asarray(_jittered_gaws(self.simulator, self.model, self.shift, zero, one))
        self.clean = np.maximum(clean[0], 0.0)
        # the white noise: what the recording's misfit to the model shows
        self.noise_sd = noise_level(recording.area, self.clean[: recording.n_frames])
        self.rng = np.random.default_rng(seed)
        self.absorbed = self._fit_directions(tuple(fitted))

    def _fit_directions(self, fitted: tuple) -> np.ndarray | None:
        """An orthonormal basis (frames, directions) of what a refit of ``fitted`` (names
        of the model's parameters; S for the scale) and the time shift moves the clean GAW
        along over the recording's frames, to first order: each parameter's central
        difference, the GAW itself for S, its slope for the shift. None without ``fitted``."""
        if not fitted:
            return None
        frames = self.recording.n_frames
        clean = self.clean[:frames]
        columns = [np.gradient(clean) * self.recording.fps]
        if "S" in fitted:
            columns.append(clean)
        values = self.model.params()
        # the program's batch of rows (one compiled program), all alike
        none = jnp.zeros((_DRAW_BATCH, self.n_slots)), jnp.ones((_DRAW_BATCH, self.n_slots))
        for name in fitted:
            if name == "S" or name not in values:
                continue
            value = float(values[name])
            step = _RELATIVE_STEP * (abs(value) or 1.0)
            up = self.model.set(**{name: value + step})
            try:  # a central difference, or a forward one at a bound (a delay at 0)
                down, width = self.model.set(**{name: value - step}), 2 * step
            except ValueError:
                down, width = self.model, step
            moved = [
                np.asarray(_jittered_gaws(self.simulator, m, self.shift, *none))[0, :frames]
                for m in (up, down)
            ]
            columns.append((moved[0] - moved[1]) / width)
        columns = np.stack(columns, axis=1)
        if not np.all(np.isfinite(columns)):
            return None
        q, r = np.linalg.qr(columns)
        kept = np.abs(np.diag(r)) > 1e-9 * np.max(np.abs(np.diag(r)))
        return q[:, kept]

    def refitted(self, areas: np.ndarray) -> np.ndarray:
        """``areas`` (rows, the recording's frames) with their misfit to the clean GAW less
        its part along `_fit_directions`: what a refit of the fitted parameters would leave,
        to first order (a refit takes up a share of the variability, the larger the fewer
        the cycles: the recording's own misfit is measured about its fit)."""
        if self.absorbed is None:
            return areas
        clean = self.clean[: areas.shape[1]]
        misfit = areas - clean
        return clean + misfit - (misfit @ self.absorbed) @ self.absorbed.T

    def normals(self, n: int) -> Normals:
        """Standard normal draws of ``n`` null recordings (`Normals`)."""
        slots = (n, self.n_slots)
        return Normals(
            self.rng.standard_normal(slots),
            self.rng.standard_normal(slots),
            self.rng.standard_normal(slots),
            self.rng.standard_normal((n, self.clean.shape[0])),
        )

    def draw(self, n: int, spreads=NO_SPREADS) -> np.ndarray:
        """``n`` recordings' areas (n, frames bucket), zero beyond the recording, with the
        cycle-to-cycle variability ``spreads`` (`Spreads`)."""
        return self.draw_from(self.normals(n), spreads)

    def draw_from(self, normals: Normals, spreads=NO_SPREADS) -> np.ndarray:
        """`draw` of the recordings whose standard normal draws are ``normals``."""
        offsets, factors = self.scaled(normals, *spreads)
        return self.draw_with(offsets, factors, noise=normals.noise)

    def jitter(self, n: int, timing_sd: float, amplitude_sd: float, period_sd: float = 0.0):
        """``n`` rows of timing offsets (s) and amplitude factors, one per slot (`scaled`)."""
        return self.scaled(self.normals(n), timing_sd, amplitude_sd, period_sd)

    def scaled(
        self, normals: Normals, timing_sd: float, amplitude_sd: float, period_sd: float = 0.0
    ):
        """Rows of timing offsets (s) and amplitude factors, one per slot, from ``normals``:
        offsets of deviation ``timing_sd`` about the model's clock plus a random walk of
        steps of deviation ``period_sd`` (each cycle's period off by its step) from the
        slot of the recording's first frame on, and factors of deviation
        ``amplitude_sd``."""
        offsets = timing_sd * normals.offsets
        factors = np.clip(1.0 + amplitude_sd * normals.factors, 0.05, None)
        if period_sd > 0:
            steps = period_sd * normals.steps
            steps[:, : self.first_slot + 1] = 0.0
            offsets = offsets + np.cumsum(steps, axis=1)
        return offsets, factors

    def draw_with(self, offsets, factors, noise_sd=None, noise=None) -> np.ndarray:
        """`draw` with the given rows of timing offsets (s) and amplitude factors, and white
        noise of deviation ``noise_sd`` where given (else the source's) times ``noise``
        (standard normals, one row per recording, the frames bucket long; drawn where
        None)."""
        n = offsets.shape[0]
        # simulated _DRAW_BATCH at a time: one compiled program for every count
        pad = -n % _DRAW_BATCH
        offsets = np.concatenate([offsets, np.zeros((pad, self.n_slots))])
        factors = np.concatenate([factors, np.ones((pad, self.n_slots))])
        clean = np.concatenate(
            [
                np.asarray(
                    _jittered_gaws(
                        self.simulator,
                        self.model,
                        self.shift,
                        jnp.asarray(offsets[i : i + _DRAW_BATCH]),
                        jnp.asarray(factors[i : i + _DRAW_BATCH]),
                    )
                )
                for i in range(0, n + pad, _DRAW_BATCH)
            ]
        )[:n]
        frames = self.recording.n_frames
        noise_sd = self.noise_sd if noise_sd is None else noise_sd
        if noise is None:
            noise = self.rng.standard_normal(clean.shape)
        noisy = np.maximum(clean + noise_sd * noise, 0.0)
        if self.integral:
            noisy = np.round(noisy)
        noisy[:, frames:] = 0.0
        return noisy


def _mean_measure(source, areas: np.ndarray, measure, width: int) -> np.ndarray:
    """The mean of ``measure(area, clean, fps)`` (``width`` numbers) over simulated
    recordings (rows) about the source's clean GAW, those whose simulation and measure are
    finite; NaN where none is."""
    rec = source.recording
    clean = source.clean[: rec.n_frames]
    areas = areas[np.all(np.isfinite(areas), axis=1), : rec.n_frames]
    found = [measure(a, clean, rec.fps) for a in source.refitted(areas)]
    found = [f for f in found if np.all(np.isfinite(f))]
    return np.mean(found, axis=0) if found else np.full(width, math.nan)


def _measures(source, areas: np.ndarray) -> np.ndarray:
    """Mean `variability_measures` of simulated recordings (rows) about the source's clean
    GAW."""
    return _mean_measure(source, areas, variability_measures, 4)


#: Spreads tried first, one at a time, to learn how each shows in the measures.
_TRIAL = Spreads(timing=5e-5, amplitude=0.02, period=3e-5)
#: The largest spreads the null recordings are given.
_CEILING = Spreads(timing=2e-3, amplitude=0.3, period=1e-3)
#: Simulated recordings whose mean measures size the null recordings' variability.
_SIZING_DRAWS = 64
#: Scalings of `variability_size`, and the share of the recording's excess over the noise's
#: cycle deviation within which it stops.
_SIZING_STEPS = 6
_SIZING_TOLERANCE = 0.02


def variability_kind(source: "_NullSource", fitted, n: int = _SIZING_DRAWS) -> Spreads:
    """The kind of the recording's cycle-to-cycle variability: the spreads (`Spreads`) whose
    null recordings show its `variability_measures` about ``fitted`` (its fitted GAW): the
    per-cycle timing offsets' spread about a line and their differences', and the
    amplitude factors' spread. Each measure's excess over what noise alone shows is taken
    as linear in the three variances, whose slopes come from the same ``n`` simulated
    recordings (`Normals`) with each spread alone at its trial value (`_TRIAL`); the
    variances are the non-negative least-squares solution, each measure weighed by its
    noise-only value. A period that varies from cycle to cycle (a closure hold of varying
    length, a varying stiffness) makes the timing wander, which offsets that scatter about
    the model's clock do not; local jitter and shimmer, measured at a few frames a cycle,
    mostly show the noise. Zero spreads where noise alone shows as much."""
    rec = source.recording
    want = variability_measures(rec.area, fitted, rec.fps)
    normals = source.normals(n)
    base = _measures(source, source.draw_from(normals))
    if not (np.all(np.isfinite(want)) and np.all(np.isfinite(base)) and np.all(base > 0)):
        return _TRIAL
    columns = []
    for name, trial in zip(Spreads._fields, _TRIAL):
        alone = NO_SPREADS._replace(**{name: trial})
        columns.append((_measures(source, source.draw_from(normals, alone)) - base) / trial**2)
    slopes = np.stack(columns, axis=1)
    if not np.all(np.isfinite(slopes)):
        return _TRIAL
    variances, _ = optimize.nnls(slopes / base[:, None], (want - base) / base)
    return Spreads(*np.minimum(np.sqrt(variances), _CEILING))


def _deviation(source, areas) -> float:
    """Mean `cycle_deviation` of simulated recordings (rows) about the source's clean GAW."""
    return float(_mean_measure(source, areas, lambda *a: (cycle_deviation(*a),), 1)[0])


def variability_size(
    source: "_NullSource", fitted, kind: Spreads, n: int = _SIZING_DRAWS
) -> Spreads:
    """The spreads ``kind`` scaled together so that null recordings show the recording's
    cycle-to-cycle misfit (`cycle_deviation` about ``fitted``, its fitted GAW; for the null
    recordings about the clean GAW after what a refit takes up, `_NullSource.refitted`),
    their mean over ``n`` simulated recordings (one set of draws, `Normals`, at every
    scale): the excess over what noise alone leaves taken as proportional to the variance,
    solved until it is within `_SIZING_TOLERANCE` of the recording's (at most
    `_SIZING_STEPS` times). A mechanism the model lacks that varies from cycle to cycle
    shows there too. Where ``kind`` is zero, the trial spreads' proportions (`_TRIAL`).
    Where the misfit lies within what noise alone leaves, ``kind`` itself (zero spreads
    where it is `variability_kind`'s fallback, `_TRIAL`): the deviation, a mean over the
    frames, can hide a wander of the timing over the cycles that `variability_measures`
    see, and null recordings without it would let a candidate that fits the wander pass for
    an effect."""
    rec = source.recording
    want = cycle_deviation(rec.area, fitted, rec.fps)
    normals = source.normals(n)
    base = _deviation(source, source.draw_from(normals))
    sd = np.asarray(kind if any(kind) else _TRIAL, float)
    if not (np.isfinite(want) and np.isfinite(base)):
        return NO_SPREADS
    if want <= base:
        return NO_SPREADS if kind == _TRIAL else Spreads(*(float(x) for x in kind))
    for _ in range(_SIZING_STEPS):
        got = _deviation(source, source.draw_from(normals, Spreads(*sd)))
        if not np.isfinite(got) or got <= base:
            break
        if abs(got - want) <= _SIZING_TOLERANCE * (want - base):
            break
        sd = np.minimum(sd * math.sqrt((want - base) / (got - base)), _CEILING)
    return Spreads(*(float(x) for x in sd))
