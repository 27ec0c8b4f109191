"""Calibration by simulation: the null recordings of a fit and the refit statistics that a
diagnosis compares with theirs (a parametric bootstrap of the test).

A null recording is what the fitted model, with no candidate effect, would have produced in
the fit's own sampling: its GAW with the recording's cycle-to-cycle variability drawn afresh
(timing offsets, a random walk of the timing and amplitude factors, `TimingJitter` and
`AmplitudeJitter`, matched to the recording's per-cycle misfits: `Variability`) and white
noise at the recording's level, clipped at zero and rounded like the recording. On every
recording, the observed one and the null ones, the same refit statistic is computed by the
same compiled programs (`_statistics`, one per group of candidates that share a warm-up,
`refit_groups`): the control refit of the fitted parameters, then each candidate's refit
from the control's optimum and from the same fixed starts (`refit_jobs`;
`Calibration.steps` Levenberg-Marquardt steps each). A candidate's refit never ends worse
than its control: the control's optimum, with the effect off, is one of its points.
"""

import dataclasses
import math
from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from scipy import optimize, stats
from scipy.stats import qmc

from .._fit import FitResult, search_range
from .._fit._engine import placed, side_by_side
from .._fit._polish import levenberg_marquardt
from .._fit._problem import prepare, start_point
from .._programs import program
from .._sampling import length_bucket
from ..compare import noise_level
from ..descriptors import describe, fundamental_frequency
from ..recording import Recording
from ..terms.variability import AmplitudeJitter, TimingJitter
from ._candidates import Candidate, extended
from ._cycles import (
    CycleVariability,
    cycle_deviation,
    variability_measures,
    variability_test,
)


class Calibration(eqx.Module):
    """How a diagnosis calibrates its verdicts by simulation (a parametric bootstrap).

    Attributes:
        replicates: most null recordings simulated (B). A candidate's p-value is
            (1 + the null recordings whose statistic is as extreme) / (B + 1); the smallest
            is 1 / (B + 1).
        batch: null recordings per compiled batch. Between batches the diagnosis stops as
            soon as every candidate's verdict is decided (a candidate whose p-value can no
            longer fall to alpha needs no more), so a recording with nothing to find costs
            one or two batches.
        interval: level of the confidence interval of a needed effect's size.
        interval_replicates: recordings simulated from the model with the effect, refitted
            for its interval (a parametric bootstrap of the estimate); with the recording
            itself they fill batches of ``batch`` (15: one batch).
        steps: Levenberg-Marquardt steps of each candidate's refits in the statistic (a few
            suffice: they start at the fit's optimum, the null recordings' truth); the
            control's refit takes twice as many.
        variability: simulate the recording's cycle-to-cycle variability in the null
            recordings (else white noise only).
        seed: seed of the null recordings' noise and variability.
        pool: for a candidate with many basins (the pressure modulation), how many starts
            of its pool about the recording's starting model are refitted on each recording
            (the ones of lowest profiled cost, `refit_jobs`); 0: no pool. Four find a
            modulation that the first fit imitates with a stretched closure hold, at half
            as much again of the statistic's refits (benchmarks/README.md).
        search_nulls: where a candidate's search refit (swarms and polish from the score
            tests' starts) passes the test while its refit from fixed starts does not, the
            same search runs on the null recordings, one after another until one falls as
            far (the search fits what the null recordings' variability makes) or all have
            (`vfjax.diagnosis.Calibrated.search_p_values`): on at most this many (None: all
            of them, ``replicates``, which decides it either way; 0: none). A search that
            these leave undecided is named unconfirmed (`vfjax.Diagnosis.unconfirmed`). A
            search that fits the recording's cycle-to-cycle variability is ruled out by the
            first null recording whose search falls as far (the fourth, on a no-effect N1
            of the injection-recovery benchmark); one that every null recording's falls
            short of costs this many searches (on a 401-frame N1, the modulation's takes
            about 10 s a null recording on 2 cores: about 3 minutes for 19, 18 for 111).
        control_starts: besides its refit from the fit's point, the control of the
            statistic is refitted on each recording from the best of this many more starts
            (by their cost with the time shift and S found afresh, `Problem.start`): the
            fit's point with the control's fitted parameters moved within
            ``control_spread``, and the fit's point itself (0: no more starts). A null
            recording is simulated from the fit's point, but its cycle-to-cycle variability
            can move the paper model's best into another basin, one the control's steps from
            its truth do not reach and a candidate's refit (one more degree of freedom) does:
            that null's candidates then fall far, and the recording's own fall, measured
            from a control at its optimum, is outranked. On a GlottalGap recording of the
            injection-recovery benchmark (N1, a_gap 0.003 cm², 3 px, seed 0) three of 31
            null recordings' controls ended at NMSE 0.0022, 0.0039 and 0.0032 where a full
            fit reaches 0.00090, 0.00032 and 0.00072 and the cubic stiffness's refit 0.00092,
            0.00037 and 0.00072: the gap was missed (p = 0.0625). From the best of 16 more
            starts within 2 % the controls reach 0.00091, 0.00032 and 0.00073.
        control_spread: half-width of the control's extra starts about the fit's point in
            the search's coordinates: the logarithm of a multiplicative parameter (0.02:
            within 2 %), an additive parameter in units of its search scale.
    """

    replicates: int = eqx.field(default=111, converter=int)
    batch: int = eqx.field(default=16, converter=int)
    interval: float = eqx.field(default=0.95, converter=float)
    interval_replicates: int = eqx.field(default=15, converter=int)
    steps: int = eqx.field(default=10, converter=int)
    variability: bool = True
    seed: int = eqx.field(default=0, converter=int)
    pool: int = eqx.field(default=0, converter=int)
    search_nulls: int | None = eqx.field(default=19, converter=lambda n: n if n is None else int(n))
    control_starts: int = eqx.field(default=16, converter=int)
    control_spread: float = eqx.field(default=0.02, converter=float)

    def __check_init__(self):
        if self.control_starts < 0 or not self.control_spread >= 0:
            raise ValueError(
                "Calibration: control_starts and control_spread must be >= 0, got "
                f"{self.control_starts}, {self.control_spread}"
            )
        if self.pool < 0:
            raise ValueError(f"Calibration: pool must be >= 0, got {self.pool}")
        if self.search_nulls is not None and self.search_nulls < 0:
            raise ValueError(
                f"Calibration: search_nulls must be >= 0 or None, got {self.search_nulls}"
            )
        if self.replicates < 1 or self.batch < 1 or self.interval_replicates < 2:
            raise ValueError(
                "Calibration: replicates and batch must be >= 1 and interval_replicates >= 2, "
                f"got {self.replicates}, {self.batch}, {self.interval_replicates}"
            )
        if not 0 < self.interval < 1:
            raise ValueError(f"Calibration: interval must lie in (0, 1), got {self.interval}")


DEFAULT_CALIBRATION = Calibration()


def check_reachable(alpha: float, calibration: Calibration) -> None:
    """Refuse a calibration whose smallest p-value, 1 / (1 + replicates), is above the level
    ``alpha``: with it no effect could ever be found needed."""
    smallest = 1.0 / (1 + calibration.replicates)
    if smallest > alpha:
        need = math.ceil(1.0 / alpha - 1.0 - 1e-9)
        raise ValueError(
            f"Calibration(replicates={calibration.replicates}) cannot reach alpha = {alpha:g}: "
            f"its smallest p-value is 1/{calibration.replicates + 1}; give at least {need} "
            "replicates, or a larger alpha"
        )


# --------------------------------------------------------------------------- null recordings
@dataclasses.dataclass(frozen=True)
class Variability:
    """The cycle-to-cycle variability of a recording, and the model's that matches it.

    Null recordings carry `TimingJitter` offsets, a random walk of them (periods that vary
    from cycle to cycle, so that the timing wanders, as a closure hold of varying length
    makes it) and `AmplitudeJitter` factors, one per cycle. Their proportions are those
    that show the recording's per-cycle timing and amplitude misfits (`variability_kind`),
    measured alike on the recording and on simulated ones, noise included. A mechanism the
    model lacks varies too: their size is set so that null recordings show the recording's
    misfit that changes from cycle to cycle (`cycle_deviation`; the misfit every cycle
    shares is left to the candidates; `variability_size`).

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


#: No variability: white noise only.
NO_SPREADS = Spreads()


class _NullSource:
    """Draws recordings from a model: its GAW at the problem's sampling and time shift, with
    cycle-to-cycle variability and white noise at the level of the recording's misfit to
    that GAW, clipped at zero and rounded like the recording (integer areas stay
    integers)."""

    def __init__(self, problem, model, shift, recording: Recording, period, seed, start=0.0):
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

    def draw(self, n: int, spreads=NO_SPREADS, model=None, shift=None, problem=None) -> np.ndarray:
        """``n`` recordings' areas (n, frames bucket), zero beyond the recording, with the
        cycle-to-cycle variability ``spreads`` (`Spreads`); of ``model`` (with the source's
        jitter terms last) at ``shift`` (s) in the sampling of ``problem`` (a `Problem` of
        the same recording) if given."""
        return self.draw_with(*self.jitter(n, *spreads), model, shift, problem)

    def jitter(self, n: int, timing_sd: float, amplitude_sd: float, period_sd: float = 0.0):
        """``n`` rows of timing offsets (s) and amplitude factors, one per slot: offsets of
        deviation ``timing_sd`` about the model's clock plus a random walk of steps of
        deviation ``period_sd`` (each cycle's period off by its step) from the slot of the
        recording's first frame on, and factors of deviation ``amplitude_sd``."""
        shape = (n, self.n_slots)
        offsets = timing_sd * self.rng.standard_normal(shape)
        factors = np.clip(1.0 + amplitude_sd * self.rng.standard_normal(shape), 0.05, None)
        if period_sd > 0:
            steps = period_sd * self.rng.standard_normal(shape)
            steps[:, : self.first_slot + 1] = 0.0
            offsets = offsets + np.cumsum(steps, axis=1)
        return offsets, factors

    def draw_with(
        self, offsets, factors, model=None, shift=None, problem=None, noise_sd=None
    ) -> np.ndarray:
        """`draw` with the given rows of timing offsets (s) and amplitude factors (and white
        noise of deviation ``noise_sd`` where given, else the source's)."""
        simulator = self.simulator if problem is None else _Simulator(problem)
        n = offsets.shape[0]
        base = self.model if model is None else model
        shift = self.shift if shift is None else jnp.asarray(shift)
        # simulated _DRAW_BATCH at a time: one compiled program for every count
        pad = -n % _DRAW_BATCH
        offsets = np.concatenate([offsets, np.zeros((pad, self.n_slots))])
        factors = np.concatenate([factors, np.ones((pad, self.n_slots))])
        clean = np.concatenate(
            [
                np.asarray(
                    _jittered_gaws(
                        simulator,
                        base,
                        shift,
                        jnp.asarray(offsets[i : i + _DRAW_BATCH]),
                        jnp.asarray(factors[i : i + _DRAW_BATCH]),
                    )
                )
                for i in range(0, n + pad, _DRAW_BATCH)
            ]
        )[:n]
        frames = self.recording.n_frames
        noise_sd = self.noise_sd if noise_sd is None else noise_sd
        noisy = clean + noise_sd * self.rng.standard_normal(clean.shape)
        noisy = np.maximum(noisy, 0.0)
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
    found = [measure(a[: rec.n_frames], clean, rec.fps) for a in areas if np.all(np.isfinite(a))]
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


def variability_kind(source: "_NullSource", fitted, n: int = 16) -> Spreads:
    """The kind of the recording's cycle-to-cycle variability: the spreads (`Spreads`) whose
    null recordings show its `variability_measures` about ``fitted`` (its fitted GAW): the
    per-cycle timing offsets' spread about a line and their differences', and the
    amplitude factors' spread. Each measure's excess over what noise alone shows (``n``
    simulated recordings) is taken as linear in the three variances, whose slopes come
    from ``n`` recordings with each spread alone at its trial value (`_TRIAL`); the
    variances are the non-negative least-squares solution, each measure weighed by its
    noise-only value. A period that varies from cycle to cycle (a closure hold of varying
    length, a varying stiffness) makes the timing wander, which offsets that scatter about
    the model's clock do not; local jitter and shimmer, measured at a few frames a cycle,
    mostly show the noise. Zero spreads where noise alone shows as much."""
    rec = source.recording
    want = variability_measures(rec.area, fitted, rec.fps)
    base = _measures(source, source.draw(n))
    if not (np.all(np.isfinite(want)) and np.all(np.isfinite(base)) and np.all(base > 0)):
        return _TRIAL
    columns = []
    for name, trial in zip(Spreads._fields, _TRIAL):
        alone = NO_SPREADS._replace(**{name: trial})
        columns.append((_measures(source, source.draw(n, alone)) - base) / trial**2)
    slopes = np.stack(columns, axis=1)
    if not np.all(np.isfinite(slopes)):
        return _TRIAL
    variances, _ = optimize.nnls(slopes / base[:, None], (want - base) / base)
    return Spreads(*np.minimum(np.sqrt(variances), _CEILING))


def _deviation(source, areas) -> float:
    """Mean `cycle_deviation` of simulated recordings (rows) about the source's clean GAW."""
    return float(_mean_measure(source, areas, lambda *a: (cycle_deviation(*a),), 1)[0])


def variability_size(source: "_NullSource", fitted, kind: Spreads, n: int = 8) -> Spreads:
    """The spreads ``kind`` scaled together so that null recordings show the recording's
    cycle-to-cycle misfit (`cycle_deviation` about ``fitted``, its fitted GAW; about the
    clean GAW for the null recordings), the excess over what noise alone leaves taken as
    proportional to the variance, solved twice: a mechanism the model lacks that varies
    from cycle to cycle shows there too. Where ``kind`` is zero, the trial spreads'
    proportions (`_TRIAL`)."""
    rec = source.recording
    want = cycle_deviation(rec.area, fitted, rec.fps)
    base = _deviation(source, source.draw(n))
    sd = np.asarray(kind if any(kind) else _TRIAL, float)
    if not (np.isfinite(want) and np.isfinite(base)) or want <= base:
        return NO_SPREADS
    for _ in range(2):
        got = _deviation(source, source.draw(n, Spreads(*sd)))
        if not np.isfinite(got) or got <= base:
            break
        sd = sd * math.sqrt((want - base) / (got - base))
        sd = np.minimum(sd, _CEILING)
    return Spreads(*(float(x) for x in sd))


# ---------------------------------------------------------------------------- the statistic
@dataclasses.dataclass(frozen=True)
class _Jobs:
    """The refits of one statistic: the control, then each candidate from its starts."""

    problem: object  # the group's wide model's `Problem` (the observed recording's data)
    y0: jax.Array  # (n_y,) where every refit starts: the control's point on the recording
    starts: jax.Array  # (jobs, n_y) candidate starts; NaN where the control's optimum is taken
    frees: jax.Array  # (1 + jobs, n_params) fitted parameters of the control and each job
    bases: jax.Array  # (1 + jobs, columns, n_y) each refit's search directions
    owner: tuple  # candidate index of each job (in the diagnosis's list of candidates)
    # starts chosen on each recording: a pool of points whose time shift and S are found
    # afresh there (`Problem.start`), ranked per candidate by the cost so profiled
    pool: jax.Array  # (entries, n_y) NaN where the control's optimum is taken
    pool_free: jax.Array  # (entries, n_params) fitted parameters of each entry
    pool_owner: jax.Array  # (entries,) candidate index of each entry (-1: padding)
    rank: jax.Array  # (jobs,) which of its candidate's entries a job starts from (-1: none)
    # the control's extra starts (`Calibration.control_starts`): offsets of its search
    # coordinates from y0, the first row zero
    restarts: jax.Array  # (1 + control_starts, names) or (0, names)


@program
def _refit_control(problem, y0, free, basis, steps: int):
    """The control's refit on the problem's own recording: (point, NMSE)."""
    return levenberg_marquardt(dataclasses.replace(problem, free=free).residual, y0, basis, steps)


def settled(jobs: _Jobs, steps: int) -> _Jobs:
    """``jobs`` starting from the control refitted on the recording in the group's own
    sampling (``2 * steps`` steps from the fit's point), for a group whose warm-up is longer
    than the fit's. There the fit's point is not the control's optimum (a longer warm-up
    changes the state at the first frame: syn_gap's fit with its gap, simulated after 0.1 s
    rather than its 20 ms, has 2.4 times its error until refitted), and refits from it
    within a few steps would differ by where they stop."""
    y, _ = _refit_control(jobs.problem, jobs.y0, jobs.frees[0], jobs.bases[0], 2 * int(steps))
    return dataclasses.replace(jobs, y0=y)


@program
def _statistics(problem, y0, starts, frees, bases, pool, restarts, data, steps: int):
    """For each recording (rows of ``data``): the control's NMSE and point, and each job's
    NMSE (never above the control's) and point. The control takes ``2 * steps`` steps (one
    refit beside the many jobs: a control left short of its optimum would hand every
    candidate a fall of its own) from ``y0`` and, where ``restarts`` has rows, from the best
    of ``y0`` moved by each row with its time shift and S found afresh
    (`Calibration.control_starts`), and the jobs without a start of their own continue
    from its optimum. (`run_statistics` gives each device its share of the recordings.)

    The control is then refitted again (``steps`` steps) from each candidate's best refit
    with its effect switched off (its other coordinates kept), and takes the best of those
    where it is better: a refit whose fitted parameters found a basin that the control's
    steps from the fit's point did not reach shows the control that basin. On a null
    recording whose control stopped short, every candidate would otherwise fall far (on one
    of the injection-recovery benchmark's N3 gap recordings at 3 px, seed 1, a null
    recording's control at NMSE 0.197 % beside the gap's refit at 0.062 %: refitted from
    that refit, the control reaches 0.066 %), and the family-wise test would count that
    fall against every candidate on the recording.

    ``pool`` is ``(entries, entries' free parameters, entries' candidates, jobs' ranks,
    jobs' candidates, candidates)``: on each recording, every entry's time shift and S are
    found afresh and its cost profiled (one simulation each), and a job with a rank
    ``r >= 0`` starts from its candidate's entry of ``r``-th lowest cost: a choice made alike
    on every recording, null or observed. ``candidates``: the candidates the jobs belong to
    (padded with -1)."""
    entries, entry_free, entry_owner, ranks, job_owner, members = pool
    n_names = len(problem.names)
    # the coordinates the control moves (its fitted parameters, the time shift and S): a
    # refit's point with the others at the fit's (the candidates' off-values) is the
    # control's
    kept = jnp.sum(bases[0], axis=0) > 0

    def one(measured):
        p = dataclasses.replace(problem, measured=measured)
        pc = dataclasses.replace(p, free=frees[0])
        begin = y0[None]
        if restarts.shape[0]:
            moved, moved_cost = jax.vmap(pc.start)(y0[:n_names] + restarts)
            moved_cost = jnp.where(jnp.isfinite(moved_cost), moved_cost, jnp.inf)
            begin = jnp.stack([y0, moved[jnp.argmin(moved_cost)]])
        ycs, ccs = jax.vmap(lambda y: levenberg_marquardt(pc.residual, y, bases[0], 2 * steps))(
            begin
        )
        yc, cc = ycs[jnp.argmin(ccs)], jnp.min(ccs)
        if entries.shape[0]:

            def profiled(entry, free):
                z = jnp.where(jnp.isnan(entry), yc, entry)[:n_names]
                y, cost = dataclasses.replace(p, free=free).start(z)
                return y, jnp.where(jnp.isfinite(cost), cost, jnp.inf)

            chosen, profiled_cost = jax.vmap(profiled)(entries, entry_free)

        def job(start, free, basis, rank, owner):
            pj = dataclasses.replace(p, free=free)
            y = jnp.where(jnp.isnan(start), yc, start)
            if entries.shape[0]:
                mine = jnp.where(entry_owner == owner, profiled_cost, jnp.inf)
                pick = jnp.argsort(mine)[jnp.maximum(rank, 0)]
                y = jnp.where(rank >= 0, chosen[pick], y)
            return levenberg_marquardt(pj.residual, y, basis, steps)

        yj, cj = jax.vmap(job)(starts, frees[1:], bases[1:], ranks, job_owner)

        def control_from(cand):
            mine = jnp.where(job_owner == cand, cj, jnp.inf)
            best = jnp.argmin(mine)
            y, cost = levenberg_marquardt(
                pc.residual, jnp.where(kept, yj[best], y0), bases[0], steps
            )
            return y, jnp.where(jnp.isfinite(mine[best]), cost, jnp.inf)

        def padding(cand):
            return jnp.zeros_like(yc), jnp.asarray(jnp.inf, cc.dtype)

        # one candidate after another: ``members`` is the same on every recording, so a
        # padding slot (-1) skips its refit instead of running it masked beside the others
        ys, costs = jax.lax.map(
            lambda cand: jax.lax.cond(cand >= 0, control_from, padding, cand), members
        )
        best = jnp.argmin(costs)
        better = costs[best] < cc
        yc, cc = jnp.where(better, ys[best], yc), jnp.where(better, costs[best], cc)
        below = cj <= cc
        return cc, yc, jnp.where(below, cj, cc), jnp.where(below[:, None], yj, yc)

    return jax.vmap(one)(data)


def _shares(n_recordings: int) -> list:
    """The devices among which ``n_recordings`` recordings are split in equal shares of
    consecutive rows: the default backend's devices where the count divides among them,
    else the first one."""
    devices = jax.devices()
    return devices if n_recordings % len(devices) == 0 else devices[:1]


def _start_values(cand: Candidate, model, whole_circle: bool = False) -> list[dict]:
    """The candidate's fixed starts: its tested parameters a step off their off-values (a
    third of their search scale; two-sided single parameters at the off-value), over a
    lattice of four grid settings and its directions (a modulation: two phases a quarter
    cycle apart; from one phase alone its refit on syn_base falls 0 % where from two it
    falls 12 %). With ``whole_circle``, the directions' phases are three spread over the
    whole cycle (a one-sided size, such as a modulation's depth, does not reach the
    opposite phase through zero)."""

    def scale(name):
        return (search_range(model, name) or (0.0, 1.0, 0.1))[2]

    step = cand.one_sided or len(cand.grid) > 1 or len(cand.directions) > 1
    tested = {t: cand.point[t] + (scale(t) / 3 if step else 0.0) for t in cand.tested}
    if len(cand.grid) == 1 and len(cand.directions) == 1:
        return [{**cand.grid[0], **cand.directions[0], **tested}]
    grid = [cand.grid[int(i)] for i in np.linspace(0, len(cand.grid) - 1, min(4, len(cand.grid)))]
    directions = cand.directions
    if whole_circle and len(directions) > 1:
        third = 2.0 * math.pi / 3.0
        directions = [{**directions[0], **t} for t in cand.turned((0.0, third, -third))]
    return [{**g, **d, **tested} for g in grid for d in directions]


def _coordinates(problem, values: dict, fill: float = math.nan) -> np.ndarray:
    """The search coordinates of parameter ``values`` in ``problem`` (``fill`` for those
    not given; 0 is the problem's reference point)."""
    z = np.full(len(problem.names), fill)
    linear, reference, scale = (
        np.asarray(a) for a in (problem.linear, problem.reference, problem.scale)
    )
    for i, n in enumerate(problem.names):
        if n in values:
            if linear[i]:
                z[i] = (values[n] - reference[i]) / scale[i]
            else:
                z[i] = math.log(values[n] / reference[i])
    return z


def _single_basin(cand: Candidate) -> bool:
    """Whether the candidate's error has one basin near the control (no grid of settings
    and no directions to try, unlike a modulation's frequency and phase)."""
    return len(cand.grid) == 1 and len(cand.directions) == 1


def _fit_point(problem, result: FitResult) -> np.ndarray:
    """The point of ``problem`` (the fit's sampling, its model extended by effects held
    off) where its model is ``result``'s fitted model at its time shift."""
    y = np.r_[_coordinates(problem, result.params, 0.0), result.time_shift / float(problem.period)]
    if problem.fit_s:
        y = np.r_[y, math.log(result.params["S"] / float(problem.s_reference))]
    return y


def _point_of(problem, fit: FitResult) -> np.ndarray:
    """The point of ``problem`` where its model is ``fit``'s (its effects held off but those
    ``fit`` has): exact where ``fit`` has the problem's warm-up (`_fit_point`); else the
    fitted parameters with the time shift found afresh on the grid of shifts (a longer
    warm-up moves the phase of the cycle at the first frame) and S projected."""
    if fit.sampling.warmup == float(problem.grid.t_start):
        return _fit_point(problem, fit)
    z = _coordinates(problem, fit.params, 0.0)
    return np.asarray(start_point(problem, jnp.asarray(z))[0])


def refit_groups(
    result: FitResult,
    recording: Recording,
    cands,
    estimates,
    calibration: Calibration = DEFAULT_CALIBRATION,
    anchor=None,
) -> list:
    """The statistic's refits of ``result`` on ``recording``, in groups of one warm-up each
    (`refit_jobs`): the candidates that need no longer warm-up than the fit's are refitted
    in the fit's own sampling, from the fit's point; those that do (a slow modulation's
    ``min_warmup``), in theirs, from the control refitted there (`settled`, twice
    ``calibration.steps`` steps). Each candidate's statistic compares its refit with the
    control of its own group. ``calibration``: the refits' steps, pool and control starts.

    Every group refits the same model (extended by every candidate, held off but its own)
    with as many jobs (padded with copies of the control, owner -1), so that one compiled
    program serves them all: the warm-up is data."""
    warmups = [max(result.sampling.warmup, float(type(c.term).min_warmup)) for c in cands]
    levels = sorted(set(warmups))
    groups = [
        refit_jobs(
            result,
            recording,
            cands,
            estimates,
            [k for k in range(len(cands)) if warmups[k] == w],
            w,
            anchor,
            calibration,
        )
        for w in levels
    ]
    n_jobs = max(len(g.owner) for g in groups)
    width = max(g.bases.shape[1] for g in groups)
    n_entries = max(g.pool.shape[0] for g in groups)
    out = []
    for g, w in zip(groups, levels):
        pad = n_jobs - len(g.owner)
        more = n_entries - g.pool.shape[0]
        bases = jnp.pad(g.bases, ((0, 0), (0, width - g.bases.shape[1]), (0, 0)))
        g = dataclasses.replace(
            g,
            starts=jnp.concatenate([g.starts, jnp.full((pad, g.starts.shape[1]), jnp.nan)]),
            frees=jnp.concatenate([g.frees, jnp.repeat(g.frees[:1], pad, axis=0)]),
            bases=jnp.concatenate([bases, jnp.repeat(bases[:1], pad, axis=0)]),
            owner=g.owner + (-1,) * pad,
            pool=jnp.concatenate([g.pool, jnp.full((more, g.pool.shape[1]), jnp.nan)]),
            pool_free=jnp.concatenate([g.pool_free, jnp.repeat(g.frees[:1], more, axis=0)]),
            pool_owner=jnp.concatenate([g.pool_owner, jnp.full(more, -1)]),
            rank=jnp.concatenate([g.rank, jnp.full(pad, -1)]),
        )
        out.append(g if w == result.sampling.warmup else settled(g, calibration.steps))
    return out


def refit_jobs(
    result: FitResult,
    recording: Recording,
    cands,
    estimates,
    members,
    warmup: float,
    anchor: dict | None = None,
    calibration: Calibration = DEFAULT_CALIBRATION,
) -> _Jobs:
    """The statistic's refits of ``result`` on ``recording`` for the candidates ``members``
    (indices into ``cands``) at ``warmup`` (s): the model extended by every candidate (held
    at their off-values), the control, and each member's starts, the same for every
    recording the statistic is computed on:

    - the fixed lattice of `_start_values` from the control's optimum;
    - for a candidate with a single basin, its fit on the recording (``estimates[k]``, a
      `FitResult` of the model with it, such as the search's refit) where that fit is
      better than ``result``, else the control's optimum with the effect off;
    - for a candidate with many basins (a grid of settings or several directions: the
      modulation's frequency and phase), given an ``anchor`` (`anchor_values`: the fitted
      parameters in the recording's starting model), a pool of starts: the lattice with
      the fitted parameters at the anchor and phases over the whole cycle. On each
      recording every entry's time shift and S are found afresh (`Problem.start`: the
      control's shift does not align the cycles of a model that far from it) and the
      ``calibration.pool`` entries of lowest cost so profiled are refitted.

    The control's extra starts: ``calibration.control_starts`` offsets of its fitted
    parameters' coordinates, a scrambled Halton design over the cube of half-width
    ``calibration.control_spread`` (the same for every recording), after a zero offset.

    A fit without the effect can bend the fitted parameters far from where the effect needs
    them (a closure hold stretched to imitate a pressure modulation's skipped closures: on
    vfjax's N1 with a modulation of 10 % at 8 Hz, seed 1 of the injection-recovery
    benchmark at 1 px, 8.7 ms where the starting model's is 5.6 ms), and ten steps from
    the control's optimum stay in its basin: there the lattice's best refit removes 8 % of
    the error, the pool's 58 % and the search's 94 % (the refits of all twelve entries
    reach the same 58 % as the best four, the best two 29 %). The lattice's few steps also
    stop short of an effect that moves the other parameters along the valleys where they
    trade off (on N1 with a cubic stiffness of 1 500 the lattice's refit keeps eta at 0
    where the search's removes half of the error), so the statistic would miss what the
    search sees. The search's point is chosen on the recording, and a null recording
    refitted from it can fall less than the recording does; where the error has a single
    basin near the control, a null recording without the effect finds the same optimum from
    the lattice, and the favour is small (the injection-recovery benchmark's false-alarm
    rate measures it). A candidate with many basins never starts from its search's point:
    there the search's choice of the best basin on the recording is a look-elsewhere
    favour (on an N3 recording without any effect, seed 1 at 1 px, that start gave the
    modulation p = 1/112)."""
    wide = extended(result.model, cands)
    if wide is None:
        raise ValueError("the candidates' parameter names clash: calibrate them one by one")
    fitted = tuple(result.params)
    union = fitted + tuple(
        dict.fromkeys(n for c in cands for n in c.tested + c.extra if n not in fitted)
    )
    sampling = dataclasses.replace(result.sampling, warmup=warmup)
    period = 1.0 / fundamental_frequency(recording.area, recording.fps)
    problem, _, _ = prepare(wide, recording, union, sampling, period, None)
    names = problem.names

    def coords(values):
        free = _coordinates(problem, values)
        return np.r_[free, np.full(problem.point_size - len(free), np.nan)]

    y0 = _point_of(problem, result)
    frees = [[1.0 if n in fitted else 0.0 for n in names]]
    restarts = _control_restarts(np.asarray(frees[0]) > 0, calibration)
    picked = calibration.pool
    starts, owner, ranks = [], [], []
    pool, pool_free, pool_owner = [], [], []
    for k in members:
        c = cands[k]
        own = set(fitted) | set(c.tested + c.extra)
        free = [1.0 if n in own else 0.0 for n in names]
        begin = [coords(s) for s in _start_values(c, wide)]
        rank = [-1] * len(begin)
        if picked and anchor and not _single_basin(c):
            fixed = {n: v for n, v in anchor.items() if n in fitted}
            around = [coords({**s, **fixed}) for s in _start_values(c, wide, whole_circle=True)]
            pool += around
            pool_free += [free] * len(around)
            pool_owner += [k] * len(around)
            begin += [np.full(y0.size, np.nan)] * picked
            rank += list(range(picked))
        if _single_basin(c):
            found = None if estimates is None else estimates[k]
            if found is not None and found.nmse < result.nmse:
                begin.append(_point_of(problem, found))
            else:
                begin.append(np.full(y0.size, np.nan))
            rank.append(-1)
        ranks += rank
        for b in begin:
            starts.append(b)
            frees.append(free)
            owner.append(k)
    # each refit's search directions: its free parameters, the time shift and S
    n_y = y0.size
    movable = [np.r_[f, np.ones(n_y - len(names))] for f in frees]
    width = int(max(m.sum() for m in movable))
    bases = np.zeros((len(frees), width, n_y))
    for i, m in enumerate(movable):
        idx = np.flatnonzero(m)
        bases[i, np.arange(idx.size), idx] = 1.0
    return _Jobs(
        problem,
        jnp.asarray(y0),
        jnp.asarray(np.array(starts)),
        jnp.asarray(np.array(frees)),
        jnp.asarray(bases),
        tuple(owner),
        jnp.asarray(np.array(pool).reshape(len(pool), y0.size)),
        jnp.asarray(np.array(pool_free).reshape(len(pool), len(names))),
        jnp.asarray(np.array(pool_owner, dtype=np.int32)),
        jnp.asarray(np.array(ranks, dtype=np.int32)),
        jnp.asarray(restarts),
    )


def _control_restarts(free: np.ndarray, calibration: Calibration) -> np.ndarray:
    """The control's extra starts as offsets of the search coordinates (`refit_jobs`): a
    zero row, then ``calibration.control_starts`` points of a scrambled Halton design in
    the cube of half-width ``calibration.control_spread`` over the coordinates where
    ``free``; none without control starts."""
    count = calibration.control_starts
    if count == 0 or not free.any():
        return np.zeros((0, free.size))
    unit = qmc.Halton(int(free.sum()), scramble=True, seed=calibration.seed).random(count)
    offsets = np.zeros((1 + count, free.size))
    offsets[1:, free] = (2.0 * unit - 1.0) * calibration.control_spread
    return offsets


def _members(owner, n_cands: int) -> np.ndarray:
    """The candidates among the jobs' owners, padded with -1 to ``n_cands`` (one shape, and
    so one compiled program, for every group)."""
    found = sorted({o for o in owner if o >= 0})
    return np.array(found + [-1] * (n_cands - len(found)))


def run_statistics(groups, data: np.ndarray, steps: int, n_cands: int):
    """The statistic of every group's refits on the recordings ``data`` (rows): each
    candidate's control NMSE (recordings, candidates): its group's, or the first group's
    (the fit's sampling) where that is lower; each candidate's best refit NMSE (recordings,
    candidates) and the points of those refits (per candidate, an array (recordings, n_y)
    in its group's coordinates)."""
    controls = np.full((len(data), n_cands), np.nan)
    best_cost = np.full((len(data), n_cands), np.inf)
    best_y = [None] * n_cands
    devices = _shares(len(data))
    parts = np.split(np.asarray(data), len(devices))
    for jobs in groups:
        args = (
            jobs.problem,
            jobs.y0,
            jobs.starts,
            jobs.frees,
            jobs.bases,
            (
                jobs.pool,
                jobs.pool_free,
                jobs.pool_owner,
                jobs.rank,
                jnp.asarray(jobs.owner, dtype=jnp.int32),
                jnp.asarray(_members(jobs.owner, n_cands), dtype=jnp.int32),
            ),
            jobs.restarts,
        )
        # each device refits its share of the recordings with the one-device program, in
        # a thread of its own: a recording's statistic has the same bits on any number of
        # devices
        out = side_by_side(
            [
                lambda d=d, rows=rows, a=args: _statistics(*placed((*a, rows), d), int(steps))
                for d, rows in zip(devices, parts)
            ]
        )
        cc, _, cj, yj = (np.concatenate([np.asarray(o[i]) for o in out]) for i in range(4))
        owner = np.asarray(jobs.owner)
        for k in np.unique(owner[owner >= 0]):
            rows = np.flatnonzero(owner == k)
            finite = np.where(np.isfinite(cj[:, rows]), cj[:, rows], np.inf)
            pick = rows[np.argmin(finite, axis=1)]
            controls[:, k] = cc
            best_cost[:, k] = cj[np.arange(len(data)), pick]
            best_y[k] = yj[np.arange(len(data)), pick]
    # a candidate refitted after a longer warm-up answers to the best model without any
    # effect, in whichever sampling: the control after its warm-up can fit the recording far
    # worse than the fit's own (a state at the first frame that a longer warm-up moves into
    # another regime, near a grazing closure), and a fall from there is no evidence
    first = groups[0].owner[0]  # a candidate of the first group
    return np.minimum(controls, controls[:, first : first + 1]), best_cost, best_y


def f_p_values(control, refit, n_frames: int, n_fitted: int, dofs) -> np.ndarray:
    """The F test's p-value of each refit's error fall (a monotone standardisation across
    candidates of different degrees of freedom; the calibration, not the F distribution,
    gives the verdict's p-values)."""
    refit = np.asarray(refit, float)
    control = np.asarray(control, float)
    if control.ndim < refit.ndim:  # one control for every candidate
        control = control[..., None]
    dofs = np.asarray(dofs, float)
    resid = np.maximum(n_frames - n_fitted - dofs, 1.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        f = np.maximum(control - refit, 0.0) / dofs / (refit / resid)
    f = np.where(np.isfinite(f), f, np.where(refit < control, np.inf, 0.0))
    return stats.f.sf(f, dofs, resid)


def _statistic(q) -> np.ndarray:
    """The test statistic of F-test p-values ``q``: -log q."""
    return -np.log(np.maximum(np.asarray(q, float), 1e-300))


def family_p_values(q_obs, nulls_q):
    """Calibrated p-values of the candidates' F-test p-values on the recording, ``q_obs``
    (candidates,), against those on null recordings, ``nulls_q`` (nulls, candidates): the
    family-wise ones, the marginal ones, each null recording's largest centred statistic and
    the recording's centred statistics.

    A step of max-T (Westfall and Young) on centred statistics: each candidate's statistic,
    -log of its F-test p-value (a scale common to candidates of different dimension), less
    its median over the null recordings, so that a candidate whose refit falls far on every
    recording does not mask the others, while the rare large falls that any candidate can
    show on a null recording count at their size. A candidate's family-wise p-value is (1 +
    null recordings whose largest centred statistic reaches its own) / (1 + null
    recordings)."""
    obs, nulls = _statistic(q_obs), _statistic(nulls_q)
    n = len(nulls)
    centre = np.median(nulls, axis=0)
    largest = (nulls - centre).max(axis=1)
    family = (1 + (largest[:, None] >= (obs - centre)[None, :]).sum(axis=0)) / (n + 1)
    marginal = (1 + (nulls >= obs[None, :]).sum(axis=0)) / (n + 1)
    return family, marginal, largest, obs - centre


# ------------------------------------------------------------------------------ calibration
@dataclasses.dataclass(frozen=True)
class Calibrated:
    """The calibrated refit statistics of a diagnosis.

    Attributes:
        candidates: the candidates' names, in order.
        control_nmse: the control refit's NMSE on the recording, in the fit's sampling
            (after the shortest warm-up a candidate needs, where that is longer).
        controls: the control refit's NMSE that each candidate's is compared with: the
            best model without any effect, ``control_nmse`` or, for a candidate refitted
            after a longer warm-up, the control refitted there where that is lower.
        nmse: each candidate's refit NMSE on the recording (never above the control's in
            its own sampling; above ``controls`` where a refit after a longer warm-up ends
            above the fit's own control).
        values: each candidate's fitted parameters on the recording (refined, for those
            with an interval).
        f_p_values: each refit's uncalibrated F-test p-value (the standardisation).
        p_values: family-wise p-values (`family_p_values`): (1 + null recordings whose
            largest centred statistic over all candidates is at least this candidate's) /
            (1 + null recordings).
        marginal_p_values: (1 + null recordings whose F-test p-value for this candidate is
            at most the recording's) / (1 + null recordings).
        replicates: null recordings simulated (fewer than the most when every verdict was
            decided early).
        null_max_t: the largest centred statistic over the candidates on each null
            recording.
        centred: each candidate's centred statistic on the recording (its -log F-test
            p-value less the median over the null recordings): what its family-wise p-value
            compares with ``null_max_t``, and what orders candidates whose p-values tie (at
            the smallest, 1 / (1 + replicates), when several fall beyond every null
            recording).
        search_p_values: each candidate's search refit (``estimates``, swarm and polish)
            put to the same family-wise test: (1 + null recordings whose largest centred
            statistic reaches the search refit's) / (1 + null recordings); NaN without a
            search refit or where it is not tested (``tested_searches``). That alone is no
            evidence (the search chose its basin on the recording, a favour the null
            recordings' refits from fixed starts do not have); where it reaches alpha while
            the candidate's own p-value does not, the null recordings are searched alike
            (``searched_nulls`` > 0, `Calibration.search_nulls`): then (1 + searched null
            recordings whose better refit falls as far) / (1 + searched null recordings),
            times the candidates so searched. Where that reaches alpha the search's fall is
            the candidate's evidence (``p_values`` and ``nmse`` are the search's).
        searched_nulls: per candidate, the null recordings its search ran on (0: none;
            fewer than ``replicates`` where one that fell as far ruled it out early).
        variability: the variability and noise of the null recordings.
        intervals: per candidate, ``{parameter: (low, high)}`` for those significant at
            alpha, else None.
        interval_level: the intervals' confidence level (``Calibration.interval``).
        cycles: the test of cycle-to-cycle variability against the fitted model with white
            noise only, and its size (`vfjax.diagnosis.CycleVariability`), where no
            candidate is significant; None otherwise or with fewer than four whole cycles.
    """

    candidates: tuple
    control_nmse: float
    controls: tuple
    nmse: tuple
    values: tuple
    f_p_values: tuple
    p_values: tuple
    marginal_p_values: tuple
    replicates: int
    null_max_t: tuple
    centred: tuple
    variability: Variability
    intervals: tuple
    interval_level: float
    cycles: CycleVariability | None = None
    search_p_values: tuple = ()
    searched_nulls: tuple = ()

    def ranking(self) -> list[str]:
        """The candidates' names, best first: by family-wise p-value, ties (several
        candidates beyond every null recording) by the larger centred statistic, the quantity
        that p-value ranks, then by the lower refit NMSE."""
        order = sorted(
            range(len(self.candidates)),
            key=lambda k: (self.p_values[k], -self.centred[k], self.nmse[k]),
        )
        return [self.candidates[k] for k in order]


def _searched_nulls(search, k, q_obs, nulls, sizes, limit, most=None):
    """Candidate ``k``'s search refit on the recording (its F-test p-value ``q_obs``)
    against the same search on the null recordings ``nulls`` (areas, rows in the order they
    were drawn, and their statistic's control and candidate NMSE), one batch of
    ``search.per_batch(k)`` at a time: the null recordings whose better refit, the search's
    or the statistic's, falls as far, and how many were searched (the p-value is (1 + the
    first) / (1 + the second)). Sequential: stops once ``limit`` exceedances rule the
    candidate out, or after ``most`` null recordings (None: all). ``sizes``: frames, fitted
    parameters and the candidate's, of the F test."""
    areas, controls, refits = nulls
    exceed, n, per = 0, 0, search.per_batch(k)
    end = len(areas) if most is None else min(len(areas), most)
    while n < end and 1 + exceed <= limit:
        batch = slice(n, min(n + per, end))
        best = np.fmin(search(k, areas[batch]), refits[batch])
        q = f_p_values(controls[batch], best, *sizes)
        q = np.where(np.isfinite(controls[batch]), q, 0.0)  # a failed null counts against
        for qi in q:
            n += 1
            exceed += bool(qi <= q_obs)
            if 1 + exceed > limit:
                break
    return exceed, n


def _dofs(cands) -> np.ndarray:
    return np.array([len(c.tested + c.extra) for c in cands], float)


def _values(jobs: _Jobs, y, cand) -> dict:
    """The candidate's parameter values at the wide problem's point ``y``."""
    model, _ = jobs.problem.unpack(jnp.asarray(y))
    params = model.params()
    return {n: float(params[n]) for n in cand.tested + cand.extra}


def calibrate(
    result: FitResult,
    recording: Recording,
    cands,
    alpha: float,
    calibration: Calibration = DEFAULT_CALIBRATION,
    estimates=None,
    anchor: dict | None = None,
    refine=None,
    tested_searches=None,
    search=None,
) -> Calibrated:
    """Calibrate each candidate's refit statistic on null recordings of ``result``.

    The null recordings are ``result``'s fitted model in its own sampling, with the
    recording's variability and noise: what the recording would be without any effect. On
    the recording and on each null recording the same statistic is computed
    (`refit_groups`): a candidate that needs a longer warm-up than the fit's (``min_warmup``:
    a slow modulation's history must be in the state at the first frame) is refitted, and
    its control too, after that warm-up; the others in the fit's own sampling.

    Sequential: null recordings come in batches of ``calibration.batch`` (the first one
    with the recording itself); once every candidate's family-wise p-value, and its search
    refit's (``search_p_values``), exceeds ``alpha`` whatever the remaining ones show, no
    more are simulated.

    For each candidate whose p-value is at most ``alpha``, its values refined (its refit on
    the recording continued from where the statistic's ended) and their interval (a
    parametric bootstrap: ``calibration.interval_replicates`` recordings simulated from the
    model with the effect at its fitted values, with the same variability and noise, each
    refitted from those values; `bootstrap_interval`: bias-corrected, Student's t quantile
    times their spread either way). Last, where no candidate is significant, the test of
    cycle-to-cycle variability (`variability_test`), against null recordings with white
    noise only.

    ``estimates``: per candidate, a fit of the model with it (`FitResult` or None, such as
    a search's refit on the recording): a start of the statistic's refits for a candidate
    with a single basin (`refit_jobs`), where its error is below the statistic's refit's
    the start of the refinement, and the search refit whose fall ``search_p_values``
    tests. ``anchor``: values of the fitted
    parameters (`anchor_values`) about which a candidate with many basins has a pool of
    starts (`refit_jobs`). ``refine``: called with the test's result (before its
    intervals), returns the estimates that start the refinement in place of
    ``estimates`` (such as a larger search for the effect the test ranks first).
    ``tested_searches``: per candidate, whether its search refit is tested (default: every
    one there is); the diagnosis tests those that would explain the recording, whose
    verdict the test can change (`vfjax.Diagnosis.unconfirmed`). ``search``: a candidate's
    search run on null recordings (`NullSearch`: called with the candidate's index and the
    null recordings' areas, returns each one's search refit NMSE; ``per_batch(k)`` null
    recordings at a time); given, and with ``calibration.search_nulls``, a candidate whose
    tested search refit passes where its own refit does not is calibrated against null
    recordings searched alike (`Calibrated.search_p_values`)."""
    cands = list(cands)
    steps = calibration.steps
    groups = refit_groups(result, recording, cands, estimates, calibration, anchor)
    period = 1.0 / fundamental_frequency(result.fitted_gaw(recording), recording.fps)
    own, _, _ = prepare(
        result.model, recording, tuple(result.params), result.sampling, period, None
    )
    latest_start = max(
        float(g.problem.grid.t_start) + float(g.problem.grid.max_time_shift) for g in groups
    )
    source = _NullSource(
        own, result.model, result.time_shift, recording, period, calibration.seed, latest_start
    )
    fitted, noise = source.clean[: recording.n_frames], source.noise_sd
    size = calibration.batch
    observed = np.asarray(own.measured)[None]
    n_fitted = len(result.params) + 1
    dofs = _dofs(cands)
    n_cands = len(cands)
    if calibration.variability:
        spreads = variability_size(source, fitted, variability_kind(source, fitted))
    else:
        spreads = NO_SPREADS

    def statistics(rows):
        return run_statistics(groups, rows, steps, n_cands)

    rows = [observed, source.draw(size - 1, spreads)]
    cc, cb, yb = statistics(np.concatenate(rows))
    main = groups[0].owner[0]  # a candidate of the shortest warm-up's group
    q_obs = f_p_values(cc[:1], cb[:1], recording.n_frames, n_fitted, dofs)[0]
    searched = np.array(
        [math.nan if e is None else float(e.nmse) for e in (estimates or [None] * n_cands)]
    )
    has_search = np.isfinite(searched)
    if tested_searches is not None:
        has_search &= np.asarray(tested_searches, bool)
    q_search = np.where(
        has_search,
        f_p_values(
            cc[:1], np.where(has_search, searched, 1.0)[None], recording.n_frames, n_fitted, dofs
        )[0],
        1.0,
    )
    level_count = alpha * (calibration.replicates + 1)  # exceedances that rule a candidate out
    nulls_q, controls = [], []
    drawn, c, b = rows[1], cc[1:], cb[1:]  # the first batch's null recordings
    kept = []  # each null recording's areas, controls and refits, for a search
    while len(nulls_q) < calibration.replicates:
        if len(c) == 0:
            drawn = source.draw(size, spreads)
            c, b, _ = statistics(drawn)
        q = f_p_values(c, b, recording.n_frames, n_fitted, dofs)
        q = np.where(np.isfinite(c), q, 0.0)  # a failed null counts against
        take = min(size, calibration.replicates - len(nulls_q))
        nulls_q += list(q[:take])
        controls += list(c[:take, main])
        kept.append((drawn[:take], c[:take], b[:take]))
        c = b = []
        family = family_p_values(q_obs, np.asarray(nulls_q))[0]
        searches = family_p_values(q_search, np.asarray(nulls_q))[0]
        open_ = np.minimum(family, np.where(has_search, searches, np.inf))
        if np.all(open_ * (len(nulls_q) + 1) > level_count):
            break
    nulls_q = np.asarray(nulls_q)
    n = len(nulls_q)
    family, marginal, nulls_max, centred = family_p_values(q_obs, nulls_q)
    search_p = np.where(has_search, family_p_values(q_search, nulls_q)[0], math.nan)
    nmse, searched_nulls = cb[0].copy(), np.zeros(n_cands, int)
    # a search refit that passes against the null recordings' refits from fixed starts, where
    # the candidate's own refit does not: the null recordings are searched alike
    # (Bonferroni over those flagged: the others cannot be named by their search)
    flagged = np.flatnonzero(has_search & (search_p <= alpha) & (family > alpha))
    limit = alpha * (n + 1) / max(flagged.size, 1)  # exceedances that rule a search out
    most = calibration.search_nulls
    if search is not None and most != 0 and flagged.size and limit >= 1:
        areas, null_c, null_b = (np.concatenate(x) for x in zip(*kept))
        for k in flagged:
            best = min(searched[k], cb[0, k])
            stat = f_p_values(cc[0, k], best, recording.n_frames, n_fitted, dofs[k])
            exceed, searched_nulls[k] = _searched_nulls(
                search,
                k,
                float(stat),
                (areas, null_c[:, k], null_b[:, k]),
                (recording.n_frames, n_fitted, dofs[k]),
                limit,
                most,
            )
            if 1 + exceed > limit or searched_nulls[k] == n:  # decided, else unconfirmed
                search_p[k] = min(1.0, (1 + exceed) / (1 + searched_nulls[k]) * flagged.size)
            if search_p[k] <= alpha and searched_nulls[k] == n:  # the search's evidence
                family[k], nmse[k] = search_p[k], best
    group_of = {k: g for g in groups for k in g.owner}
    values = [_values(group_of[k], yb[k][0], c) for k, c in enumerate(cands)]
    intervals = [None] * n_cands
    local = describe(recording.area, recording.fps)
    variability = Variability(
        float(local.jitter),
        float(local.shimmer),
        spreads.timing,
        spreads.amplitude,
        float(np.nanmean(controls)),
        noise,
        period,
        spreads.period,
    )
    tested = Calibrated(
        candidates=tuple(c.name for c in cands),
        control_nmse=float(cc[0, main]),
        controls=tuple(float(x) for x in cc[0]),
        nmse=tuple(float(x) for x in nmse),
        values=tuple(values),
        f_p_values=tuple(float(x) for x in q_obs),
        p_values=tuple(float(x) for x in family),
        marginal_p_values=tuple(float(x) for x in marginal),
        replicates=n,
        null_max_t=tuple(float(x) for x in nulls_max),
        centred=tuple(float(x) for x in centred),
        variability=variability,
        intervals=tuple(intervals),
        interval_level=calibration.interval,
        search_p_values=tuple(float(x) for x in search_p),
        searched_nulls=tuple(int(x) for x in searched_nulls),
    )
    if refine is not None:
        estimates = refine(tested)
    for k, cand in enumerate(cands):
        if family[k] <= alpha:
            jobs, y = group_of[k], yb[k][0]
            found = None if estimates is None else estimates[k]
            # a fit after another warm-up maps to a point that can fit far worse here (the
            # state at the first frame carries a modulation's history): only a fit in the
            # group's own sampling, where its point is exact, starts the refinement
            same = found is not None and found.sampling.warmup == float(jobs.problem.grid.t_start)
            if (same or k in flagged) and found.nmse < cb[0, k]:  # (the search, where the
                # null recordings were searched alike: its basin is the evidence)
                y = _point_of(jobs.problem, found)
            values[k], intervals[k] = _interval(
                jobs, source, observed, y, k, cand, spreads, calibration, n_cands
            )
    # cycle-to-cycle variability, where no candidate is significant (a missing effect's
    # misfit trades with the per-cycle factors: the extended fit's diagnosis tests it); its
    # null recordings drawn last, so the candidates' are the seed's first draws
    cycles = None
    if not np.any(family <= alpha):
        jittered, _, _ = prepare(
            source.model, recording, tuple(result.params), result.sampling, period, None
        )
        cycles = variability_test(
            source,
            jittered,
            _fit_point(jittered, result),
            calibration.replicates,
            calibration.interval,
            alpha,
        )
    return dataclasses.replace(
        tested, values=tuple(values), intervals=tuple(intervals), cycles=cycles
    )


def bootstrap_interval(
    estimate: float, replicates: np.ndarray, level: float
) -> tuple[float, float]:
    """A parametric bootstrap's confidence interval of a fitted value, bias-corrected.

    The replicates are the value refitted on recordings simulated from the model at the
    estimate, so their mean less the estimate measures the fit's bias (noise clipped at a
    closed glottis, for one, pulls a fit the same way on the recording and on every
    replicate). The interval is centred on the estimate less that bias and reaches Student's
    t quantile (n - 1 degrees of freedom, the spread being measured on n replicates) times
    the replicates' spread either way, widened by sqrt(1 + 1/n) for the uncertainty of the
    bias. For an estimate that is normal about the truth plus a bias, its coverage is the
    level exactly.

    Arguments:
        estimate: the value fitted to the recording (in the parameter's units).
        replicates: the value refitted on each bootstrap recording (same units; any
            sequence of numbers); a non-finite one makes the interval NaN (not measured).
        level: the confidence level, in (0, 1).

    Returns:
        ``(low, high)``; NaN for fewer than two replicates. Replicates that all equal one
        value give zero width (an interval that measured nothing).
    """
    values = np.asarray(replicates, dtype=float)
    if values.size < 2:
        return (math.nan, math.nan)
    centre = 2.0 * estimate - float(np.mean(values))
    spread = float(np.std(values, ddof=1)) * math.sqrt(1.0 + 1.0 / values.size)
    half = float(stats.t.ppf(0.5 + level / 2, values.size - 1)) * spread
    return (centre - half, centre + half)


def _interval(jobs, source, observed, y, k, cand, spreads, calibration, n_cands) -> tuple:
    """Candidate ``k``'s parameters refined from the point ``y`` of the recording's refit
    (in its group ``jobs``), and their interval: ``({parameter: value}, {parameter: (low,
    high)})`` (see `calibrate`).

    Every refit starts at ``y``, the bootstrap recordings' truth (a start elsewhere, such as
    the statistic's lattice, can leave a replicate far from its optimum within the fixed
    steps and inflate the spread); the recording itself rides in the first batch, and its
    refit from ``y`` is the refined estimate (`bootstrap_interval`). The bootstrap
    recordings are simulated in the group's sampling."""
    model, shift = jobs.problem.unpack(jnp.asarray(y))
    model = model.with_term(source.model.terms[-2]).with_term(source.model.terms[-1])
    size, n = calibration.batch, calibration.interval_replicates
    own = (np.asarray(jobs.owner) == k)[:, None]
    from_y = dataclasses.replace(
        jobs,
        starts=jnp.where(own, jnp.asarray(y)[None], jobs.starts),
        rank=jnp.where(own[:, 0], -1, jobs.rank),
    )
    drawn = source.draw(n, spreads, model=model, shift=shift, problem=jobs.problem)
    rows = np.concatenate([observed, drawn])
    rows = np.concatenate([rows, np.repeat(observed, -len(rows) % size, axis=0)])
    values = []
    for i in range(0, len(rows), size):
        _, _, yb = run_statistics([from_y], rows[i : i + size], calibration.steps, n_cands)
        values += [_values(jobs, row, cand) for row in yb[k]]
    estimate, values = values[0], values[1 : n + 1]
    return estimate, {
        name: bootstrap_interval(v, [x[name] for x in values], calibration.interval)
        for name, v in estimate.items()
    }
