"""Calibration by simulation: each candidate's refit statistic on the recording against the
same statistic on null recordings of the fit (a parametric bootstrap of the test),
sequential over batches of null recordings; the needed effects' intervals by a parametric
bootstrap of the estimate.

The null recordings are `_nulls`'s, the statistic `_statistic`'s; `calibrate` draws them in
batches until every verdict is decided, tests the search refits that would explain the
recording against null recordings searched alike, and sizes the needed effects
(`bootstrap_interval`).
"""

import contextlib
import dataclasses
import math
import sys

import jax.numpy as jnp
import numpy as np
from scipy import stats

from .._fit import FitResult
from .._fit._problem import prepare
from ..descriptors import describe, fundamental_frequency
from ..recording import Recording
from ._cycles import CycleVariability, variability_test
from ._nulls import NO_SPREADS, Variability, _NullSource, variability_kind, variability_size
from ._options import DEFAULT_CALIBRATION, DEFAULT_PLAN, Calibration
from ._refits import refit_replicates, simulated_like
from ._statistic import (
    _fit_point,
    _Jobs,
    _point_of,
    f_p_values,
    family_p_values,
    refit_groups,
    run_statistics,
)


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
        values: each candidate's fitted parameters on the recording (refitted again, for
            those with an interval).
        f_p_values: each refit's uncalibrated F-test p-value (the standardisation).
        p_values: family-wise p-values (`family_p_values`): (1 + null recordings whose
            largest standardised statistic over all candidates is at least this
            candidate's) / (1 + null recordings).
        marginal_p_values: (1 + null recordings whose F-test p-value for this candidate is
            at most the recording's) / (1 + null recordings).
        replicates: null recordings simulated (fewer than the most when every verdict was
            decided early).
        null_max_t: the largest standardised statistic over the candidates on each null
            recording.
        centred: each candidate's standardised statistic on the recording (its -log F-test
            p-value less its median over the recording and the null recordings, over its
            spread there, `family_p_values`): what its family-wise p-value
            compares with ``null_max_t``, and what orders candidates whose p-values tie (at
            the smallest, 1 / (1 + replicates), when several fall beyond every null
            recording).
        search_p_values: each candidate's search refit (``estimates``, swarm and polish)
            put to the same family-wise test: (1 + null recordings whose largest standardised
            statistic reaches the search refit's) / (1 + null recordings); NaN without a
            search refit or where it is not tested (``tested_searches``). That alone is no
            evidence (the search chose its basin on the recording, a favour the null
            recordings' refits from fixed starts do not have); where it reaches alpha while
            the candidate's own p-value does not, the null recordings are searched alike
            (``searched_nulls`` > 0, `Calibration.search_nulls`): then (1 + searched null
            recordings whose better refit falls as far) / (1 + searched null recordings),
            times the candidates so searched. Where that reaches alpha the search's fall is
            the candidate's evidence (``p_values`` and ``nmse`` are the search's).
        searched_nulls: per candidate, the null recordings its search was weighed on:
            searched, or counted against it without a search where their statistic refit
            already fell as far (0: none; fewer than ``replicates`` where one that fell as
            far ruled it out early).
        variability: the variability and noise of the null recordings.
        intervals: per candidate, ``{parameter: (low, high)}`` for those significant at
            alpha, else None.
        interval_level: the intervals' confidence level (``Calibration.interval``).
        bootstrap_values: per candidate with an interval, ``{parameter: (value, ...)}``:
            its parameters and the fitted ones refitted on each of the interval's bootstrap
            recordings, the distribution its interval is made from (`bootstrap_interval`);
            else None.
        cycles: the test of cycle-to-cycle variability against the fitted model with white
            noise only, and its size (`vfjax.diagnosis.CycleVariability`), where no
            candidate is significant; None otherwise or with fewer than four whole cycles.
        null_controls: the control refit's NMSE on each null recording (NaN where it
            failed), in the order drawn: what ``control_nmse`` is on recordings of the
            fitted model with the recording's noise and cycle-to-cycle variability
            (`fit_p_value`).
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
    null_controls: tuple = ()
    bootstrap_values: tuple = ()

    @property
    def fit_p_value(self) -> float:
        """The calibrated goodness of fit of the model without any effect: (1 + null
        recordings whose control refit ends at least as high as the recording's, or failed)
        / (1 + null recordings). The null recordings carry the recording's noise and the
        misfit that changes from cycle to cycle, so a small p-value says that the recording
        holds a misfit they lack, one that repeats from cycle to cycle: something the model
        misses. NaN without null recordings."""
        nulls = np.asarray(self.null_controls, float)
        if nulls.size == 0:
            return math.nan
        return _fit_p_value(self.control_nmse, nulls)

    def ranking(self) -> list[str]:
        """The candidates' names, best first: by family-wise p-value, ties (several
        candidates beyond every null recording) by the larger standardised statistic, the
        quantity that p-value ranks, then by the lower refit NMSE."""
        order = sorted(
            range(len(self.candidates)),
            key=lambda k: (self.p_values[k], -self.centred[k], self.nmse[k]),
        )
        return [self.candidates[k] for k in order]


def _searched_nulls(search, k, q_obs, nulls, sizes, limit, most=None):
    """Candidate ``k``'s search refit on the recording (its F-test p-value ``q_obs``)
    against the same search on the null recordings ``nulls`` (areas, rows in the order they
    were drawn, and their statistic's control and candidate NMSE), ``search.per_batch(k)``
    at a time: the null recordings whose better refit, the search's or the statistic's,
    falls as far, and how many were weighed (the p-value is (1 + the first) / (1 + the
    second)). A null recording whose statistic refit already falls as far, or whose
    statistic failed, counts against without a search. Sequential: stops once ``limit``
    exceedances rule the candidate out, or after ``most`` null recordings (None: all).
    ``sizes``: frames, fitted parameters and the candidate's, of the F test."""
    areas, controls, refits = nulls
    end = len(areas) if most is None else min(len(areas), most)
    controls, refits = controls[:end], refits[:end]
    # each one's statistic refit; a failed null counts against
    q = np.where(np.isfinite(controls), f_p_values(controls, refits, *sizes), 0.0)
    to_search = np.flatnonzero(q > q_obs)  # the others count as they are
    exceed, n, per = 0, 0, search.per_batch(k)
    while n < end and 1 + exceed <= limit:
        last = n
        if q[n] > q_obs:  # the next one needs a search: it and the batch after it
            rows = to_search[to_search >= n][:per]
            best = np.fmin(search(k, areas[rows]), refits[rows])
            q[rows] = f_p_values(controls[rows], best, *sizes)
            last = rows[-1]
        for qi in q[n : last + 1]:
            n += 1
            exceed += bool(qi <= q_obs)
            if 1 + exceed > limit:
                break
    return exceed, n


def _fit_p_value(observed: float, nulls: np.ndarray) -> float:
    """(1 + null controls at least ``observed``, a failed one, NaN, counting) / (1 + nulls)."""
    reach = ~(np.asarray(nulls, float) < observed)
    return float((1 + np.sum(reach)) / (1 + len(reach)))


def _dofs(cands) -> np.ndarray:
    return np.array([len(c.tested + c.extra) for c in cands], float)


def _values(jobs: _Jobs, y, cand, fitted: tuple = ()) -> dict:
    """The candidate's parameter values at the wide problem's point ``y`` (and those of
    the ``fitted`` parameters)."""
    model, _ = jobs.problem.unpack(jnp.asarray(y))
    params = model.params()
    return {n: float(params[n]) for n in (*fitted, *cand.tested, *cand.extra)}


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
    progress: bool | None = None,
) -> Calibrated:
    """Calibrate each candidate's refit statistic on null recordings of ``result``.

    The null recordings are ``result``'s fitted model in its own sampling, with the
    recording's variability and noise: what the recording would be without any effect. On
    the recording and on each null recording the same statistic is computed
    (`refit_groups`): a candidate that needs a longer warm-up than the fit's (``min_warmup``:
    a slow modulation's history must be in the state at the first frame) is refitted, and
    its control too, after that warm-up; the others in the fit's own sampling.

    Sequential: null recordings come in batches of ``calibration.batch`` (the first one
    with the recording itself); once every candidate's family-wise p-value, its search
    refit's (``search_p_values``) and the fit's own goodness (`Calibrated.fit_p_value`:
    whether the recording's control ends above every null recording's) exceed ``alpha``
    whatever the remaining ones show, no more are simulated.

    For each candidate whose p-value is at most ``alpha``, its values (its refit on the
    recording continued from where the statistic's or the search's ended) and their
    interval (a parametric bootstrap: ``calibration.interval_replicates`` recordings
    simulated from the model with the effect at those values, with the same variability and
    noise, each refitted alike, by the statistic's steps or, with
    ``calibration.interval_search``, by a search, `refit_replicates`; `bootstrap_interval`:
    bias-corrected, Student's t quantile times their spread either way). Last, where no
    candidate is significant, the test of cycle-to-cycle variability (`variability_test`),
    against null recordings with white noise only.

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
    recordings searched alike (`Calibrated.search_p_values`). ``progress``: show a progress
    bar of the null recordings on stderr (default: on a terminal), its total the most there
    can be (``calibration.replicates``), the smallest family-wise p-value so far beside it; a
    calibration that decides early closes it short of that total."""
    cands = list(cands)
    groups = refit_groups(result, recording, cands, estimates, calibration, anchor)
    period = 1.0 / fundamental_frequency(result.fitted_gaw(recording), recording.fps)
    own, _, _ = prepare(
        result.model, recording, tuple(result.params), result.sampling, period, None
    )
    latest_start = max(
        float(g.problem.grid.t_start) + float(g.problem.grid.max_time_shift) for g in groups
    )
    source = _NullSource(
        own,
        result.model,
        result.time_shift,
        recording,
        period,
        calibration.seed,
        latest_start,
        fitted=tuple(result.params),
    )
    noise = source.noise_sd
    size = calibration.batch
    observed = np.asarray(own.measured)[None]
    n_fitted = len(result.params) + 1
    dofs = _dofs(cands)
    n_cands = len(cands)
    spreads = _spreads(source, calibration)

    # the bar is closed however the calibration ends (an interrupt, a failed simulation)
    with _progress_bar(progress, calibration.replicates, recording.name) as bar:

        def statistics(rows, nulls):  # ``nulls``: how many of the rows are null recordings
            out = run_statistics(groups, rows, calibration, n_cands)
            if bar is not None:
                bar.update(min(nulls, bar.total - bar.n))
            return out

        rows = [observed, source.draw(size - 1, spreads)]
        cc, cb, yb = statistics(np.concatenate(rows), size - 1)
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
                cc[:1],
                np.where(has_search, searched, 1.0)[None],
                recording.n_frames,
                n_fitted,
                dofs,
            )[0],
            1.0,
        )
        # the exceedances that rule a candidate out
        level_count = alpha * (calibration.replicates + 1)
        nulls_q, controls = [], []
        drawn, c, b = rows[1], cc[1:], cb[1:]  # the first batch's null recordings
        kept = []  # each null recording's areas, controls and refits, for a search
        while len(nulls_q) < calibration.replicates:
            if len(c) == 0:
                drawn = source.draw(size, spreads)
                c, b, _ = statistics(drawn, size)
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
            # the fit's own goodness (`Calibrated.fit_p_value`): open while the recording's
            # control ends above every null recording's
            open_ = np.minimum(open_, _fit_p_value(cc[0, main], np.asarray(controls)))
            if bar is not None:
                bar.set_postfix(p=f"{float(np.min(family)):.2g}")
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
    replicated = [None] * n_cands
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
        null_controls=tuple(float(x) for x in controls),
    )
    if refine is not None:
        estimates = refine(tested)
    plan = DEFAULT_PLAN if search is None else search.plan

    def refitted(k, jobs, y, point, drawn):
        """Candidate ``k``'s values refitted from ``y`` (``point``, by name) on the recording
        and on each ``drawn`` recording, and the recording's refit NMSE (None: not
        measured apart from ``y``'s): by a search (`refit_replicates`) with
        ``calibration.interval_search``, else by the statistic's steps."""
        cand = cands[k]
        if not calibration.interval_search:
            stepped = _stepped_values(jobs, k, cand, y, drawn, observed, calibration, n_cands)
            return stepped, None
        replicates = [simulated_like(recording, a, "replicate") for a in drawn]
        warmup = float(jobs.problem.grid.t_start)
        fits = refit_replicates(
            result,
            [recording, *replicates],
            cand,
            point,
            plan,
            family=cands,
            anchor=anchor,
            warmup=warmup,
        )
        return [{n: float(f.model.params()[n]) for n in point} for f in fits], fits[0].nmse

    for k, cand in enumerate(cands):
        if family[k] <= alpha:
            jobs, y, y_nmse = group_of[k], yb[k][0], float(cb[0, k])
            found = None if estimates is None else estimates[k]
            # a fit after another warm-up maps to a point that can fit far worse here (the
            # state at the first frame carries a modulation's history): only a fit in the
            # group's own sampling, where its point is exact, starts the refinement
            same = found is not None and found.sampling.warmup == float(jobs.problem.grid.t_start)
            if (same or k in flagged) and found.nmse < cb[0, k]:  # (the search, where the
                # null recordings were searched alike: its basin is the evidence)
                y, y_nmse = _point_of(jobs.problem, found), float(found.nmse)
            values[k], intervals[k], replicated[k] = _interval(
                jobs, source, (y, y_nmse), k, cand, tuple(result.params), calibration, refitted
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
        tested,
        values=tuple(values),
        intervals=tuple(intervals),
        bootstrap_values=tuple(replicated),
        cycles=cycles,
    )


def _spreads(source: _NullSource, calibration: Calibration):
    """The cycle-to-cycle variability of recordings drawn from ``source``: the spreads
    whose draws show the recording's about the source's GAW (`variability_kind`, sized by
    `variability_size`), or none where ``calibration.variability`` is off."""
    if not calibration.variability:
        return NO_SPREADS
    clean = source.clean[: source.recording.n_frames]
    return variability_size(source, clean, variability_kind(source, clean))


def _progress_bar(show: bool | None, total: int, name: str):
    """A progress bar of ``total`` null recordings of the recording ``name`` on stderr
    where ``show`` (where it is None: on a terminal), as a context that closes it; else a
    context of None."""
    if not (sys.stderr.isatty() if show is None else show):
        return contextlib.nullcontext()
    from tqdm.auto import tqdm

    return tqdm(total=total, desc=f"calibrate {name}", unit="null", leave=False)


def bootstrap_interval(
    estimate: float, replicates: np.ndarray, level: float, *, positive: bool = False
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

    A size that is positive, with its off-value at zero (a gap, a delay), is bounded below
    and errs by factors: its estimate lands in a basin some factor above or below the truth
    now and then (a medium gap on the paper's N1: a third of the searched replicates at 1.3
    to 2 times the rest). On the value's own scale such a tail, reflected about the estimate
    by the bias correction, reaches across zero although no replicate comes near it; on the
    scale of its logarithm it is the factor it is. With ``positive`` the interval is made
    there (from the logarithms of the estimate and of the replicates) and mapped back, so it
    holds only positive sizes, unless a replicate refits to zero or below (the effect
    switched off, where the logarithm does not exist): then it is made on the value's scale.

    Arguments:
        estimate: the value fitted to the recording (in the parameter's units).
        replicates: the value refitted on each bootstrap recording (same units; any
            sequence of numbers); a non-finite one makes the interval NaN (not measured).
        level: the confidence level, in (0, 1).
        positive: the size is positive with its off-value at zero: the interval is made on
            the scale of its logarithm where the estimate and every replicate are positive.

    Returns:
        ``(low, high)``; NaN for fewer than two replicates. Replicates that all equal one
        value give zero width (an interval that measured nothing).
    """
    values = np.asarray(replicates, dtype=float)
    if values.size < 2:
        return (math.nan, math.nan)
    if positive and estimate > 0 and np.all(values > 0):
        low, high = bootstrap_interval(math.log(estimate), np.log(values), level)
        return (math.exp(low), math.exp(high))
    centre = 2.0 * estimate - float(np.mean(values))
    spread = float(np.std(values, ddof=1)) * math.sqrt(1.0 + 1.0 / values.size)
    half = float(stats.t.ppf(0.5 + level / 2, values.size - 1)) * spread
    return (centre - half, centre + half)


def _positive_sizes(cand) -> tuple[str, ...]:
    """The candidate's tested parameters that are positive sizes with their off-value at
    zero (a one-sided effect's: a gap, a delay), whose interval is made on the scale of
    their logarithm (`bootstrap_interval`)."""
    off = type(cand.term).off_values
    return tuple(n for n in cand.tested if cand.one_sided and off.get(n) == 0.0)


def _refitted_names(jobs, k: int) -> tuple[str, ...]:
    """The parameters that candidate ``k``'s refits in ``jobs`` adjust (those any of its
    jobs frees), S where the problem fits it."""
    problem = jobs.problem
    frees = np.asarray(jobs.frees[1:])[np.asarray(jobs.owner) == k].any(axis=0)
    names = [n for n, f in zip(problem.names, frees) if f]
    return tuple(names + (["S"] if problem.fit_s else []))


def _interval(jobs, source, start, k, cand, names, calibration, refit) -> tuple:
    """Candidate ``k``'s parameters on the recording and their interval, from the point
    ``y`` of the recording's refit (in its group ``jobs``) and its NMSE, ``start = (y,
    nmse)``: ``({parameter: value}, {parameter: (low, high)}, {parameter: replicates})``
    (see `calibrate`).

    The bootstrap recordings are simulated from ``y`` in the group's sampling, with the white
    noise and the cycle-to-cycle variability that the recording shows about that truth's
    GAW: not those of the null recordings, which the fitted model's misfit sizes, the
    missing effect's included (a large misfit is taken up there as variability at the
    largest spreads, and replicates of the effect's model drawn with it are refitted far
    from their truth). They and the recording itself are refitted from ``y`` by
    ``refit(k, jobs, y, point, drawn)`` (``calibrate``'s: ``point`` holds ``y``'s values of
    the candidate's parameters and of ``names``, the fitted ones), and the recording's
    refit is the estimate (``y`` where its refit ends above it), the others its replicates
    (`bootstrap_interval`)."""
    y, y_nmse = start
    model, shift = jobs.problem.unpack(jnp.asarray(y))
    truth = _NullSource(
        jobs.problem,
        model,
        shift,
        source.recording,
        source.period,
        int(source.rng.integers(2**32)),
        fitted=_refitted_names(jobs, k),
    )
    drawn = truth.draw(calibration.interval_replicates, _spreads(truth, calibration))
    params = model.params()
    at_y = {name: float(params[name]) for name in cand.tested + cand.extra}
    point = {name: float(params[name]) for name in (*names, *at_y)}
    values, ends = refit(k, jobs, y, point, drawn)
    estimate, values = {n: values[0][n] for n in at_y}, values[1:]
    if ends is not None and not ends <= y_nmse:  # the recording's search ended above y
        estimate = at_y
    replicated = {name: tuple(x[name] for x in values) for name in values[0]}
    positive = _positive_sizes(cand)
    intervals = {
        name: bootstrap_interval(
            v, replicated[name], calibration.interval, positive=name in positive
        )
        for name, v in estimate.items()
    }
    return estimate, intervals, replicated


def _stepped_values(jobs, k, cand, y, drawn, observed, calibration, n_cands) -> list[dict]:
    """Candidate ``k``'s values refitted from ``y`` (in its group ``jobs``) on the recording
    (``observed``) and on each of the ``drawn`` recordings, by the statistic's refits
    (``calibration.steps`` Levenberg-Marquardt steps, `run_statistics`, in batches of
    ``calibration.batch``)."""
    size, n = calibration.batch, len(drawn)
    own = (np.asarray(jobs.owner) == k)[:, None]
    from_y = dataclasses.replace(
        jobs,
        starts=jnp.where(own, jnp.asarray(y)[None], jobs.starts),
        rank=jnp.where(own[:, 0], -1, jobs.rank),
    )
    rows = np.concatenate([observed, drawn])
    rows = np.concatenate([rows, np.repeat(observed, -len(rows) % size, axis=0)])
    fitted, values = _refitted_names(jobs, k), []
    for i in range(0, len(rows), size):
        _, _, yb = run_statistics([from_y], rows[i : i + size], calibration, n_cands)
        values += [_values(jobs, row, cand, fitted) for row in yb[k]]
    return values[: n + 1]
