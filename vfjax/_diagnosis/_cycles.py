"""Cycle-to-cycle variability as a candidate: does a recording vary from cycle to cycle more
than its noise makes it, and by how much?

The other candidates are deterministic terms, tested against null recordings that carry the
recording's own variability (`vfjax.diagnosis.Calibrated`). Variability is tested against
its own null: the fitted model with white noise only. Its statistic is the misfit that
changes from cycle to cycle (`cycle_deviation`: the residual cut at the fitted GAW's cycles,
less the misfit every cycle shares), its size the spread of per-cycle timing offsets and
amplitude factors (`TimingJitter`, `AmplitudeJitter`) fitted to the recording.
"""

import dataclasses
import math

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from scipy import stats

from .._fit._polish import levenberg_marquardt
from ..descriptors import cycle_starts

#: Levenberg-Marquardt steps of the per-cycle fit (the fitted parameters and the cycles'
#: offsets and factors together: the fit's parameters, made with none, move along narrow
#: valleys as the cycles take their share; 30 steps leave the N1 case of the tests with
#: its amplitude spread a third too large, 60 within a fifth).
_STEPS = 60


def cycle_deviation(area, fitted, fps: float) -> float:
    """The part of a GAW's misfit that changes from cycle to cycle, as a share of its
    squared area: the residual (``area`` - ``fitted``) cut at the fitted GAW's cycles,
    each resampled to one common length, minus their mean (the misfit that every cycle
    shares, which an effect may explain); the sum of squares left, over sum(area²). NaN
    with fewer than three cycles."""
    a, g = np.asarray(area, float), np.asarray(fitted, float)
    starts = cycle_starts(g, fps) * fps
    if starts.size < 4:
        return math.nan
    length = max(int(round(float(np.median(np.diff(starts))))), 2)
    frames = np.arange(a.size)
    r = a - g
    rows = np.stack(
        [
            np.interp(s0 + (s1 - s0) * np.arange(length) / length, frames, r)
            for s0, s1 in zip(starts[:-1], starts[1:])
        ]
    )
    per_point = float(np.mean(np.diff(starts))) / length  # frames per resampled point
    dev = rows - rows.mean(axis=0)
    return float(np.sum(dev**2) * per_point / np.sum(a**2))


@dataclasses.dataclass(frozen=True)
class CycleVariability:
    """The calibrated test of cycle-to-cycle variability, and its size.

    The test: the recording's `cycle_deviation` about its fitted GAW against that of
    ``replicates`` recordings simulated from the fitted model with white noise only (at the
    recording's level, clipped and rounded like it), each about the model's GAW. The size:
    one timing offset (s) and one amplitude factor per glottal cycle (`TimingJitter`,
    `AmplitudeJitter`, slots of one fitted period), fitted to the recording with the model
    held at its fit; the spread of the offsets and factors of the cycles inside the
    recording, less what their standard errors (from the noise level) add to it (a
    method-of-moments estimate), with chi-square intervals on the cycles' count.

    Attributes:
        p_value: (1 + white-noise recordings whose cycle deviation is at least the
            recording's) / (1 + replicates).
        deviation: the recording's `cycle_deviation` (share of its squared area).
        null_deviation: the median over the white-noise recordings.
        replicates: white-noise recordings simulated.
        cycles: the slots (cycles) whose whole support lies inside the recording, those the
            spreads are taken over.
        timing_sd: spread of the per-cycle timing offsets (s).
        timing_interval: its interval (s), at ``level``.
        amplitude_sd: spread of the per-cycle amplitude factors (a fraction).
        amplitude_interval: its interval, at ``level``.
        offsets: the fitted timing offset of each cycle inside the recording (s).
        factors: the fitted amplitude factor of each cycle inside the recording.
        nmse: the NMSE with the per-cycle offsets and factors.
        fit_nmse: the NMSE of the fitted GAW (the model without them).
        level: the intervals' confidence level.
    """

    p_value: float
    deviation: float
    null_deviation: float
    replicates: int
    cycles: int
    timing_sd: float
    timing_interval: tuple[float, float]
    amplitude_sd: float
    amplitude_interval: tuple[float, float]
    offsets: tuple[float, ...]
    factors: tuple[float, ...]
    nmse: float
    fit_nmse: float
    level: float

    @property
    def fall(self) -> float:
        """Share of the fit's squared error that the per-cycle offsets and factors remove."""
        return 1.0 - self.nmse / self.fit_nmse if self.fit_nmse > 0 else 0.0

    def needed(self, alpha: float) -> bool:
        """Whether the recording varies beyond its noise at level ``alpha`` (and the spread's
        interval excludes zero for the timing or the amplitude)."""
        return self.p_value <= alpha and (
            self.timing_interval[0] > 0 or self.amplitude_interval[0] > 0
        )

    def words(self) -> str:
        """The finding in a phrase (without the p-value)."""
        t_low, t_high = self.timing_interval
        a_low, a_high = self.amplitude_interval
        return (
            f"timing offsets of {1e3 * self.timing_sd:.3g} ms [{1e3 * t_low:.3g}, "
            f"{1e3 * t_high:.3g}] and amplitude factors of {self.amplitude_sd:.2%} "
            f"[{a_low:.2%}, {a_high:.2%}] from cycle to cycle over {self.cycles} cycles "
            f"remove {self.fall:.0%} of the squared error"
        )


@eqx.filter_jit
def _per_cycle_fit(problem, y0, basis, period, steps: int):
    """The fit of ``problem`` (its model with a `TimingJitter` and an `AmplitudeJitter` last,
    one slot each per cycle) continued from its point ``y0`` with each cycle's timing offset
    (in periods) and amplitude factor (less 1) appended to the point, along the rows of
    ``basis``: (point, its sum of squares (px²))."""
    k = y0.shape[0]
    n = (basis.shape[1] - k) // 2

    def residual(y):
        z = y[: len(problem.names) + 1]
        model = problem.model_at(z, y[k - 1] if problem.fit_s else None)
        model = eqx.tree_at(
            lambda m: (m.terms[-2].offsets, m.terms[-1].factors),
            model,
            (y[k : k + n] * period, 1.0 + y[k + n :]),
        )
        sim = problem.simulate(model, problem.shift(z))
        g = jnp.maximum(jnp.where(sim.complete, sim.area, 0.0), 0.0)
        return problem.counted * (g - problem.measured)

    return levenberg_marquardt(residual, jnp.concatenate([y0, jnp.zeros(2 * n)]), basis, steps)


def _spread(values, trend: bool) -> float:
    """The variance of per-cycle estimates ``values`` about their mean, or about a straight
    line if ``trend`` (a timing trend is a change of period, which the fitted parameters
    hold), on the cycles less the line's parameters; and those degrees of freedom."""
    n = len(values)
    x = np.arange(n, dtype=float)
    design = np.stack([np.ones(n), x], axis=1) if trend else np.ones((n, 1))
    residual = values - design @ np.linalg.lstsq(design, values, rcond=None)[0]
    dof = n - design.shape[1]
    return float(np.sum(residual**2) / dof), dof


def _size(observed: float, noise: float, dof: int, level: float):
    """A spread (standard deviation) less the estimation noise, from the ``observed``
    variance and the ``noise`` variance that white noise alone gives (method of moments),
    and its interval at ``level`` (chi-square on ``dof``)."""
    tail = (1.0 - level) / 2.0
    low = observed * dof / stats.chi2.ppf(1.0 - tail, dof) - noise
    high = observed * dof / stats.chi2.ppf(tail, dof) - noise
    return (
        math.sqrt(max(observed - noise, 0.0)),
        (math.sqrt(max(low, 0.0)), math.sqrt(max(high, 0.0))),
    )


def _per_cycle_spreads(problem, y0, basis, period, inside, k, n):
    """The per-cycle fit of ``problem`` (`_per_cycle_fit`): the variances of its timing
    offsets (s, about a line) and amplitude factors (about their mean) over the cycles
    ``inside`` the recording, with their degrees of freedom, the offsets and factors, and
    the fit's sum of squares (px²)."""
    y, sse = _per_cycle_fit(problem, y0, basis, period, _STEPS)
    y = np.asarray(y)[k:]
    offsets, factors = y[:n][inside] * period, 1.0 + y[n:][inside]
    return _spread(offsets, True), _spread(factors, False), offsets, factors, float(sse)


def variability_test(
    source, problem, y0, replicates: int, level: float, noise_replicates: int = 4
) -> CycleVariability | None:
    """The calibrated test of cycle-to-cycle variability of ``source``'s recording (a
    `vfjax.diagnosis` null source: the fitted model with a `TimingJitter` and an
    `AmplitudeJitter` last, its sampling, shift and noise level); ``problem``: the fit's
    problem with that model, ``y0`` the fit's point there. The per-cycle fit is repeated on
    ``noise_replicates`` white-noise recordings, whose spreads are what noise alone adds.
    None where the recording holds fewer than four whole cycles."""
    rec = source.recording
    frames = rec.n_frames
    fitted = source.clean[:frames]
    observed = cycle_deviation(rec.area, fitted, rec.fps)
    # the null: the model's GAW with white noise only, each about the model's GAW
    nulls = source.draw(replicates, 0.0, 0.0)
    null = np.array([cycle_deviation(a[:frames], fitted, rec.fps) for a in nulls])
    if not np.isfinite(observed):
        return None
    exceed = int(np.sum(~np.isfinite(null) | (null >= observed)))
    p_value = (1 + exceed) / (1 + replicates)
    # the cycles: slots of one period; those whose support meets the frames are fitted,
    # those whose whole support (a period either side of the middle) lies inside the
    # recording are counted (a slot at an edge is seen in part, and trades with the
    # fitted parameters)
    grid = source.simulator.problem.grid
    t0 = float(grid.t_start) + float(source.shift)
    t1 = t0 + (frames - 1) / rec.fps
    period = source.period
    n = source.n_slots
    middles = (np.arange(n) + 0.5) * period
    inside = (middles >= t0 + period) & (middles <= t1 - period)
    if int(inside.sum()) < 4:
        return None
    fitted_slots = (middles > t0 - period) & (middles < t1 + period)
    k = int(y0.shape[0])
    free = np.r_[np.asarray(problem.free), np.ones(k - len(problem.names))] > 0
    rows = np.flatnonzero(np.r_[free, fitted_slots, fitted_slots])
    basis = np.zeros((rows.size, k + 2 * n))
    basis[np.arange(rows.size), rows] = 1.0
    y0, basis = jnp.asarray(y0), jnp.asarray(basis)
    (t_var, dof_t), (a_var, dof_a), offsets, factors, sse = _per_cycle_spreads(
        problem, y0, basis, period, inside, k, n
    )
    # what white noise alone adds to the spreads: the same fit on recordings of the model
    noise_t, noise_a = [], []
    for area in nulls[:noise_replicates]:
        null_problem = dataclasses.replace(problem, measured=jnp.asarray(area))
        (t_null, _), (a_null, _), *_ = _per_cycle_spreads(
            null_problem, y0, basis, period, inside, k, n
        )
        noise_t.append(t_null)
        noise_a.append(a_null)
    timing_sd, timing_interval = _size(t_var, float(np.mean(noise_t)), dof_t, level)
    amplitude_sd, amplitude_interval = _size(a_var, float(np.mean(noise_a)), dof_a, level)
    scale = float(np.sum(np.square(rec.area)))
    return CycleVariability(
        p_value=float(p_value),
        deviation=float(observed),
        null_deviation=float(np.nanmedian(null)),
        replicates=int(replicates),
        cycles=int(inside.sum()),
        timing_sd=timing_sd,
        timing_interval=timing_interval,
        amplitude_sd=amplitude_sd,
        amplitude_interval=amplitude_interval,
        offsets=tuple(float(x) for x in offsets),
        factors=tuple(float(x) for x in factors),
        nmse=float(sse) / scale,
        fit_nmse=float(np.sum(np.square(rec.area - fitted))) / scale,
        level=float(level),
    )
