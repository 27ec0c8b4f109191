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
from .._programs import program
from ..descriptors import cycle_starts

#: Levenberg-Marquardt steps of the per-cycle fit (the fitted parameters and the cycles'
#: offsets and factors together: the fit's parameters, made with none, move along narrow
#: valleys as the cycles take their share; on an N1 recording with both spreads the NMSE
#: reaches 5.8e-5 after 30 steps, 2.94e-5 after 60 and 2.87e-5 after 120).
_STEPS = 60


def cycle_deviation(area, fitted, fps: float) -> float:
    """The part of a GAW's misfit that changes from cycle to cycle, as a share of its
    squared area: the residual (``area`` - ``fitted``) cut at the fitted GAW's cycles,
    each resampled to one common length, minus their mean at each point of the cycle (the
    misfit that every cycle shares, which an effect may explain); the sum of squares left,
    over sum(area²). The frames before the first cycle's start and after the last one are
    partial cycles at the mean period, each point taken where it lies inside the recording:
    every frame counts, as in the NMSE (over six cycles, a misfit in the last one alone is a
    sixth of the frames). NaN with fewer than three cycles."""
    a, g = np.asarray(area, float), np.asarray(fitted, float)
    starts = cycle_starts(g, fps) * fps
    if starts.size < 4:
        return math.nan
    length = max(int(round(float(np.median(np.diff(starts))))), 2)
    frames = np.arange(a.size)
    r = a - g
    phase = np.arange(length) / length
    period = float(np.mean(np.diff(starts)))
    whole = [
        np.interp(s0 + (s1 - s0) * phase, frames, r) for s0, s1 in zip(starts[:-1], starts[1:])
    ]
    partial = []
    for t in (starts[0] - period * (1.0 - phase), starts[-1] + period * phase):
        inside = (t >= 0) & (t <= a.size - 1)
        partial.append(np.where(inside, np.interp(t, frames, r), np.nan))
    rows = np.stack(whole + partial)
    dev = rows - np.mean(whole, axis=0)
    per_point = period / length  # frames per resampled point
    return float(np.nansum(dev**2) * per_point / np.sum(a**2))


def cycle_projections(area, fitted, fps: float) -> tuple[np.ndarray, np.ndarray]:
    """Each cycle's misfit read as a timing offset and as an amplitude factor: the residual
    (``area`` - ``fitted``) over each cycle of the fitted GAW projected on the fitted GAW's
    slope (a cycle whose area at t is the fitted one at t + delta, a `TimingJitter` offset,
    shows delta g'(t)) and on the GAW itself (a cycle scaled by 1 + a shows a g(t)). Over a
    whole cycle the two directions are orthogonal (the integral of g g' over a period is
    zero). Returns (offsets in s, factors less 1), one per cycle; empty with fewer than
    three cycles."""
    a, g = np.asarray(area, float), np.asarray(fitted, float)
    starts = np.ceil(cycle_starts(g, fps) * fps).astype(int)
    if starts.size < 4:
        return np.zeros(0), np.zeros(0)
    r, slope = a - g, np.gradient(g) * fps
    offsets, factors = [], []
    for s0, s1 in zip(starts[:-1], starts[1:]):
        cycle = slice(s0, s1)
        ss, gg = np.sum(slope[cycle] ** 2), np.sum(g[cycle] ** 2)
        offsets.append(np.sum(r[cycle] * slope[cycle]) / ss if ss > 0 else 0.0)
        factors.append(np.sum(r[cycle] * g[cycle]) / gg if gg > 0 else 0.0)
    return np.asarray(offsets), np.asarray(factors)


def variability_measures(area, fitted, fps: float) -> np.ndarray:
    """Four measures of a GAW's cycle-to-cycle variability about its fitted GAW, from its
    `cycle_projections`: the variance of the timing offsets about a line, of their first
    and of their second differences (offsets that scatter about the model's clock show
    twice and six times their variance there; periods that scatter, a random walk of the
    offsets, once and twice theirs and a growing spread about the line), and of the
    amplitude factors. NaN with fewer than four cycles."""
    offsets, factors = cycle_projections(area, fitted, fps)
    if offsets.size < 4:
        return np.full(4, math.nan)
    return np.array(
        [
            _spread(offsets, True)[0],
            float(np.var(np.diff(offsets))),
            float(np.var(np.diff(offsets, 2))),
            float(np.var(factors)),
        ]
    )


@dataclasses.dataclass(frozen=True)
class CycleVariability:
    """The calibrated test of cycle-to-cycle variability, and its size.

    The test: the recording's `cycle_deviation` about its fitted GAW against that of
    ``replicates`` recordings simulated from the fitted model with white noise only (at the
    level the per-cycle fit leaves, clipped and rounded like the recording), each about the
    model's GAW. The size: one timing offset (s) and one amplitude factor per glottal cycle
    (`TimingJitter`, `AmplitudeJitter`, slots of one fitted period), fitted to the recording
    together with the fitted parameters; the spread of the offsets (about a line) and of the
    factors over the cycles whose whole support lies inside the recording, less what the
    same fit adds to the spreads of simulated recordings (a method-of-moments estimate),
    with chi-square intervals on the cycles' count. Where the p-value exceeds the level
    tested, both spreads are 0 and their intervals start at 0.

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


@program
def _per_cycle_fit(problem, gaw, y0, basis, period, steps: int):
    """The fit of ``problem`` (its model with a `TimingJitter` and an `AmplitudeJitter` last,
    one slot each per cycle) to ``gaw`` (padded like the problem's), continued from its
    point ``y0`` with each cycle's timing offset (in periods) and amplitude factor (less 1)
    appended to the point, along the rows of ``basis`` (zero rows are held): (point, its
    sum of squares (px²), its residual, fitted minus measured). One program for every
    recording of a length bucket and slot count (vmapped over recordings, it runs slower on
    CPU than one after the other)."""
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
        return problem.counted * (g - gaw)

    start = jnp.concatenate([y0, jnp.zeros(2 * n)])
    y, sse = levenberg_marquardt(residual, start, basis, steps)
    return y, sse, residual(y)


def _spread(values, trend: bool) -> tuple[float, int]:
    """The variance of per-cycle estimates ``values`` about their mean, or about a straight
    line if ``trend`` (a timing trend is a change of period, which the fitted parameters
    hold), on the cycles less the line's parameters; and those degrees of freedom."""
    n = len(values)
    x = np.arange(n, dtype=float)
    design = np.stack([np.ones(n), x], axis=1) if trend else np.ones((n, 1))
    residual = values - design @ np.linalg.lstsq(design, values, rcond=None)[0]
    dof = n - design.shape[1]
    return float(np.sum(residual**2) / dof), dof


def _size(observed: float, added, dof: int, level: float):
    """A spread (standard deviation) less what the fit adds to it, from the ``observed``
    variance and the variances ``added`` on simulated recordings (method of moments), and
    its interval at ``level``: chi-square on ``dof`` for the observed variance, Student's t
    for the mean of the added ones (each end takes the other's far end)."""
    added = np.asarray(added, float)
    mean = float(np.mean(added))
    tail = (1.0 - level) / 2.0
    spread = stats.t.ppf(1.0 - tail, added.size - 1) * np.std(added, ddof=1) / math.sqrt(added.size)
    low = observed * dof / stats.chi2.ppf(1.0 - tail, dof) - (mean + spread)
    high = observed * dof / stats.chi2.ppf(tail, dof) - (mean - spread)
    return (
        math.sqrt(max(observed - mean, 0.0)),
        (math.sqrt(max(low, 0.0)), math.sqrt(max(high, 0.0))),
    )


def _per_cycle_spreads(problem, measured, y0, basis, period, inside, k, n):
    """The per-cycle fits of ``problem`` to the rows of ``measured`` (`_per_cycle_fit`):
    per row, the variances of its timing offsets (s, about a line) and amplitude factors
    (about their mean) over the cycles ``inside`` the recording, with their degrees of
    freedom, the offsets and factors, the fit's sum of squares (px²) and its residual."""
    out = []
    for gaw in measured:
        y, sse, r = (
            np.asarray(a)
            for a in _per_cycle_fit(
                problem, jnp.asarray(gaw), y0, basis, jnp.asarray(period), _STEPS
            )
        )
        offsets, factors = y[k:][:n][inside] * period, 1.0 + y[k + n :][inside]
        out.append(
            (
                _spread(offsets, True),
                _spread(factors, False),
                offsets,
                factors,
                float(sse),
                r,
            )
        )
    return out


def _noise_sd(measured, residual, n_fitted: int, integral: bool) -> float:
    """The white noise of a recording, from the residual of a fit that leaves nothing else
    (the per-cycle fit): its variance over the frames where the measured or the fitted GAW
    is open (a clipped closed phase shows no noise), on those frames less the ``n_fitted``
    parameters; less the rounding's 1/12 where the recording is ``integral`` (its null
    recordings are rounded again)."""
    fitted = measured + residual
    open_ = (measured > 0) | (fitted > 0)
    variance = float(np.sum(residual[open_] ** 2)) / max(int(open_.sum()) - n_fitted, 1)
    if integral:
        variance -= 1.0 / 12.0
    return math.sqrt(max(variance, 0.0))


def _fit_additions(source, problem, nulls, fit, observed_var, noise) -> np.ndarray:
    """What the per-cycle fit adds to the spreads (variances), by simulation: the fit
    (``fit``: `_per_cycle_spreads`'s arguments after the recordings) on the white-noise
    recordings ``nulls`` (the noise's share), then, where a spread is found, on as many
    recordings with the spreads so found (noise ``noise``), each compared with the spreads
    drawn over its counted cycles (each spread's leak into the other too: a timing spread
    shows in part as an amplitude spread, and back). (replicates, 2): timing, amplitude."""
    inside = fit[3]
    found = [(t, a) for (t, _), (a, _), *_ in _per_cycle_spreads(problem, nulls, *fit)]
    added = np.asarray(found)
    sizes = np.sqrt(np.maximum(observed_var - added.mean(axis=0), 0.0))
    if not np.any(sizes > 0):
        return added
    shifts, gains = source.jitter(len(nulls), *sizes)
    areas = source.draw_with(shifts, gains, noise_sd=noise)
    drawn = [
        (_spread(o[inside], True)[0], _spread(g[inside], False)[0]) for o, g in zip(shifts, gains)
    ]
    found = [(t, a) for (t, _), (a, _), *_ in _per_cycle_spreads(problem, areas, *fit)]
    return np.asarray(found) - np.asarray(drawn)


def variability_test(
    source,
    problem,
    y0,
    replicates: int,
    level: float,
    alpha: float = 0.01,
    noise_replicates: int = 4,
) -> CycleVariability | None:
    """The calibrated test of cycle-to-cycle variability of ``source``'s recording (a
    `vfjax.diagnosis` null source: the fitted model with a `TimingJitter` and an
    `AmplitudeJitter` last, its sampling, shift and noise level); ``problem``: the fit's
    problem with that model, ``y0`` the fit's point there. The per-cycle fit is repeated on
    ``noise_replicates`` white-noise recordings, whose spreads are what noise adds, then,
    where a spread is found, on as many with the spreads so found: what the fit adds to
    the spreads it is given, subtracted from the recording's. Where the p-value exceeds
    ``alpha`` no spread is found (0, with the observed spreads' upper limits): the
    simulations are skipped. None where the recording holds fewer than four whole cycles."""
    rec = source.recording
    frames = rec.n_frames
    fitted = source.clean[:frames]
    observed = cycle_deviation(rec.area, fitted, rec.fps)
    if not np.isfinite(observed):
        return None
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
    fitted_rows = np.r_[free, fitted_slots, fitted_slots]
    # one row per fitted coordinate, padded with zero rows to a multiple of 16: recordings
    # of a length bucket share their programs (each row costs a jvp per step)
    index = np.flatnonzero(fitted_rows)
    basis = np.zeros((16 * math.ceil(index.size / 16), fitted_rows.size))
    basis[np.arange(index.size), index] = 1.0
    y0, basis = jnp.asarray(y0), jnp.asarray(basis)
    ((t_var, dof_t), (a_var, dof_a), offsets, factors, sse, residual) = _per_cycle_spreads(
        problem, np.asarray(problem.measured)[None], y0, basis, period, inside, k, n
    )[0]
    # the null: the model's GAW with white noise only, each about the model's GAW after
    # what a refit takes up (`_NullSource.refitted`: the recording's deviation is about its
    # fit); the noise is what the per-cycle fit leaves (a noise estimate from the first
    # fit's misfit would hold the variability, and one from the high frequencies of rounded
    # areas is biased, enough to flag a recording of the model itself)
    noise = _noise_sd(
        np.asarray(problem.measured)[:frames],
        residual[:frames],
        int(fitted_rows.sum()),
        source.integral,
    )
    still = (np.zeros((replicates, n)), np.ones((replicates, n)))
    nulls = source.draw_with(*still, noise_sd=noise)
    null = np.array(
        [cycle_deviation(a, fitted, rec.fps) for a in source.refitted(nulls[:, :frames])]
    )
    exceed = int(np.sum(~np.isfinite(null) | (null >= observed)))
    p_value = (1 + exceed) / (1 + replicates)
    if p_value <= alpha:
        added = _fit_additions(
            source,
            problem,
            nulls[:noise_replicates],
            (y0, basis, period, inside, k, n),
            np.array([t_var, a_var]),
            noise,
        )
        timing_sd, timing_interval = _size(t_var, added[:, 0], dof_t, level)
        amplitude_sd, amplitude_interval = _size(a_var, added[:, 1], dof_a, level)
    else:  # nothing beyond the noise: no spread, and the observed spreads' upper limits
        nothing = np.zeros(2)
        timing_sd = amplitude_sd = 0.0
        timing_interval = (0.0, _size(t_var, nothing, dof_t, level)[1][1])
        amplitude_interval = (0.0, _size(a_var, nothing, dof_a, level)[1][1])
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
