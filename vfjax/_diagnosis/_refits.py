"""Refits: the model refitted with each candidate effect (and without, the control), every
refit of a diagnosis through one compiled program."""

import dataclasses
import itertools
from collections.abc import Sequence

import numpy as np

from .._fit import FitResult, Polish, fit_many, search_range
from .._fit._problem import PLAUSIBLE, plausible_range
from ..presets import initial_model
from ..recording import Recording
from ._candidates import Candidate, extended
from ._options import DEFAULT_PLAN, RefitPlan
from ._score import EffectScore, score_tests


def refit_starts(
    cand: Candidate, model, recording, score: EffectScore, n: int, anchor: dict | None = None
) -> list[dict]:
    """Starting values of the effect's parameters for the refit: just off the off-value (the
    current fit), then the one-step estimates (at the next-best grid settings, or scaled)
    and, for a candidate with a grid, a lattice over the grid and the phases; all clipped
    into the parameters' ranges.

    ``anchor`` (values of fitted parameters, e.g. `anchor_values`') is a second base for the
    lattice: every other lattice point starts from it instead of the current fit. A fit made
    without the effect may have bent the fitted parameters far from where the effect needs
    them (a closure hold stretched to mimic a pressure modulation's missing closures), and
    from there the effect's basin is out of a small swarm's reach."""

    def _range(name):
        return search_range(model, name) or (-np.inf, np.inf, 0.1)

    ests = list(score.estimates)
    if len(cand.grid) > 1:
        # far from the linear regime the one-step estimates mislead: add a lattice over the
        # grid (four settings) and, for a sine/cosine pair, three phases, with the tested
        # parameters one range-scale step off
        lattice = [
            {**ests[0], **g, **{t: cand.point[t] + _range(t)[2] for t in cand.tested}, **turn}
            for g in (cand.grid[int(i)] for i in np.linspace(0, len(cand.grid) - 1, 4))
            for turn in cand.turned((0.0, 2.1, -2.1))
        ]
        if anchor:
            lattice = [{**p, **anchor} if i % 2 else p for i, p in enumerate(lattice)]
        ests += lattice
        n += len(ests) - 1
    proposals = [just_off(cand, model, ests[0]), ests[0]]
    guess = type(cand.term).guess(recording)
    if guess:  # values the data show directly (a closure duration) come second
        proposals.insert(1, {**ests[0], **guess})
    proposals += (
        ests[1:]
        if len(ests) > 1
        else [
            {
                **ests[0],
                **{t: cand.point[t] + f * (ests[0][t] - cand.point[t]) for t in cand.tested},
            }
            for f in (2.0, 0.5)
        ]
    )
    starts = []
    for s in proposals[:n]:
        s = dict(s)
        for name in cand.tested + cand.extra:
            low, high, scale = _range(name)
            value = s[name]
            if cand.one_sided and name in cand.tested:
                value = max(value, cand.point[name] + 1e-2 * scale)
            s[name] = float(np.clip(value, low, high))
        starts.append(s)
    return starts


def just_off(cand: Candidate, model, values: dict) -> dict:
    """``values`` with the candidate's tested parameters just off their off-values (3 % of
    their search scale, `vfjax.search_range` in ``model``): a start whose refit contains the
    fit without the effect."""
    scale = {t: (search_range(model, t) or (0.0, 0.0, 0.1))[2] for t in cand.tested}
    return {**values, **{t: cand.point[t] + 0.03 * scale[t] for t in cand.tested}}


def refit_with(
    result: FitResult,
    recording: Recording,
    candidate=None,
    starts: Sequence[dict] = ({},),
    plan: RefitPlan = DEFAULT_PLAN,
    *,
    anchor: dict | None = None,
) -> FitResult:
    """Refit ``result``'s parameters plus the candidate's, from each of ``starts`` (values of
    the candidate's parameters, and of fitted ones where given), as one batch; returns the
    best refit. Without a candidate: the same refit of the fitted model alone (the control).

    Each start is particle 0 of a swarm (``plan.swarm``) that searches the effect's
    parameters over their range (`vfjax.search_range`) and the fitted ones within a factor
    ``plan.box`` of their current values, of their ``anchor`` values if given (e.g. the
    fit's starting model: an effect that changes the dynamics, such as the flow separation,
    can move K and C_f far from a fit made without it) and of the starts' values; then the
    polish (``plan.polish``) of the ``plan.polished`` swarms that ended lowest. `refit_each`
    runs several candidates' refits as one batch.
    """
    return refit_each(result, recording, [(candidate, starts)], plan, anchor=anchor)[0]


def refit_each(
    result: FitResult,
    recording: Recording | Sequence[Recording],
    jobs: Sequence[tuple],
    plan: RefitPlan = DEFAULT_PLAN,
    *,
    family: Sequence[Candidate] | None = None,
    anchor: dict | None = None,
    warmup: float | None = None,
    iterations: int | None = None,
    polish: Polish | None = None,
) -> list[FitResult]:
    """`refit_with` for several candidates at once: ``jobs`` is a list of ``(candidate or
    None, starts)``; returns the best refit of each job.

    All jobs run as one `vfjax.fit_many` batch (padded to ``plan.batch`` fits; of each
    job's swarms the ``plan.polished`` that end lowest are polished), so that one
    compiled program serves them all: every start simulates the fitted model extended by all
    the ``family``'s candidates (default: the jobs'), those not its own held at their
    off-values (where they change nothing). Every refit of a diagnosis passes the same
    family, so that its quick, confirming and extending refits share one program. Each
    returned fit's model carries its own candidate only. If the candidates' parameter names
    clash, each job runs as its own batch.

    Arguments:
        result: the fit being diagnosed.
        recording: its recording, or one recording per job (of the same length and frame
            rate: null recordings simulated from ``result``, searched as it is).
        jobs: ``(candidate or None, starts)`` pairs; a start is a dict of parameter values.
        plan: the refits' settings (`RefitPlan`).
        family: the candidates whose terms the compiled program carries.
        anchor: values of fitted parameters, a second centre of their search box.
        warmup: simulated time before the first frame (s); default: the fit's.
        iterations: swarm iterations (default: ``plan.swarm``'s).
        polish: the polish (default: ``plan.polish``).
    """
    cands = [
        None if c is None else c if isinstance(c, Candidate) else Candidate.of(c) for c, _ in jobs
    ]
    recordings = [recording] * len(jobs) if isinstance(recording, Recording) else list(recording)
    if len(recordings) != len(jobs):
        raise ValueError(f"{len(recordings)} recordings for {len(jobs)} jobs: give one per job")
    family = [c for c in cands if c is not None] if family is None else list(family)
    for c in cands:
        if c is not None and not any(f.name == c.name for f in family):
            family.append(c)
    names = tuple(result.params)
    own = [names + (() if c is None else c.tested + c.extra) for c in cands]
    wide = extended(result.model, family)
    if wide is None:
        return [
            refit_each(
                result,
                rec,
                [job],
                plan,
                family=[c] if c is not None else [],
                anchor=anchor,
                warmup=warmup,
                iterations=iterations,
                polish=polish,
            )[0]
            for c, job, rec in zip(cands, jobs, recordings)
        ]
    added = [type(t) for t in wide.terms if not result.model.has(type(t))]
    union = names + tuple(
        dict.fromkeys(n for c in family for n in c.tested + c.extra if n not in names)
    )
    models, holds, owner = [], [], []
    for j, (_, starts) in enumerate(jobs):
        for s in starts:
            models.append(wide.set(**{k: v for k, v in s.items() if k in own[j]}))
            holds.append(tuple(n for n in union if n not in own[j]))
            owner.append(j)
    anchor = {n: v for n, v in (anchor or {}).items() if n in result.params and v > 0}
    bounds = {}  # a factor box around the current values, the anchor's and every start's
    for n, v in result.params.items():
        if v > 0 and search_range(wide, n) is None:
            given = [v, anchor.get(n, v)] + [s[n] for _, ss in jobs for s in ss if s.get(n, 0) > 0]
            low, high = min(given) / plan.box, max(given) * plan.box
            if n in PLAUSIBLE:  # within the plausible range, or the values already beyond it
                floor, ceiling = plausible_range(n, *given)
                low, high = max(low, floor), min(high, ceiling)
            bounds[n] = (low, high)
    swarm = plan.swarm
    if iterations is not None:
        swarm = dataclasses.replace(swarm, iterations=iterations)
    fits = fit_many(
        models,
        [recordings[j] for j in owner],
        params=union,
        swarm=swarm,
        polish=plan.polish if polish is None else polish,
        warmup=result.sampling.warmup if warmup is None else warmup,
        substeps=result.sampling.substeps,
        bounds=bounds,
        hold=holds,
        min_batch=plan.batch,
        contest=None if plan.polished is None else (owner, plan.polished),
    )
    best = []
    for j, c in enumerate(cands):
        fit = min((f for f, o in zip(fits, owner) if o == j), key=error)
        # the other candidates sit at their off-values: drop them from the model
        dormant = [k for k in added if c is None or k is not type(c.term)]
        model = fit.model.without(*dormant) if dormant else fit.model
        best.append(dataclasses.replace(fit, model=model))
    return best


def anchor_values(result: FitResult, recording: Recording) -> dict:
    """The fitted parameters' values in the recording's starting model (`initial_model`),
    a second centre for the refits' search; empty if there is none."""
    try:
        start = initial_model(recording).params()
    except (ValueError, KeyError):
        return {}
    return {n: float(start[n]) for n in result.params if n in start}


def confirm(result, recording, jobs, control, fitted, *, top, plan, anchor, family):
    """Refit the control, and candidate ``top`` (an index into ``fitted``, the effect to add;
    None: the control alone) again with a larger search (`RefitPlan.confirm_search`: more
    swarms and iterations, scaled by the candidate's dimension, and a longer polish,
    `RefitPlan.confirm_polish`), from their quick refits and
    from the jobs' anchored starts; keep each one's better fit. The control gets the same
    search as the candidate, so that the fall it is measured against is not the product of a
    bigger search alone.

    A candidate that needs a longer warm-up than the fit's (its term's ``min_warmup``: a slow
    modulation, whose history is in the state at the first frame) is first refitted again at
    that warm-up from all its quick starts, and so is the control; the larger refits then
    start from those. Returns (control, fitted) with candidate ``top``'s refit replaced."""
    control_starts = jobs[0][1]
    cand, cand_starts = (None, []) if top is None else jobs[1 + top]
    n_params = 1 if cand is None else len(cand.tested + cand.extra)
    swarms, iterations = plan.confirm_search(n_params)
    warmup = max(result.sampling.warmup, float(0 if cand is None else type(cand.term).min_warmup))
    common = {"family": family, "anchor": anchor, "warmup": warmup}
    quick = [control] + ([] if cand is None else [fitted[top]])
    if warmup > result.sampling.warmup:
        quick = refit_each(result, recording, [jobs[0], jobs[1 + top]], plan, **common)

    def from_anchor(starts):
        return [s for s in starts if anchor and all(s.get(k) == v for k, v in anchor.items())]

    def cycled(starts):  # one swarm per start, the starts repeated (other keys) up to swarms
        return list(itertools.islice(itertools.cycle(starts), swarms))

    deep = [(None, cycled([dict(quick[0].params)] + from_anchor(control_starts)))]
    if cand is not None:
        # the control's optimum with the effect just off its off-value: the candidate's
        # refit contains the control, and a search that starts only from the quick refits
        # (made from the first fit) can end far above a control that the larger search
        # moved to another basin (syn_tremor: a gap's refit at NMSE 16.9 % beside a
        # control at 1.96 %)
        effect = {n: v for n, v in cand_starts[0].items() if n in cand.tested + cand.extra}
        nested = {**dict(quick[0].params), **effect}
        own = [dict(quick[1].params), nested] + (from_anchor(cand_starts) or cand_starts[-1:])
        deep.append((cand, cycled(own)))
    c, *f = refit_each(
        result, recording, deep, plan, iterations=iterations, polish=plan.confirm_polish, **common
    )
    fitted = list(fitted)
    if cand is not None:
        fitted[top] = min(fitted[top], quick[1], f[0], key=error)
    return min(control, quick[0], c, key=error), fitted


def refit_replicates(
    result: FitResult,
    recordings: Sequence[Recording],
    cand: Candidate,
    point: dict,
    plan: RefitPlan = DEFAULT_PLAN,
    *,
    family: Sequence[Candidate],
    anchor: dict | None = None,
    warmup: float | None = None,
) -> list[FitResult]:
    """The candidate's refit of each of ``recordings`` by a search, as the recording's
    estimate is made: the bootstrap of an effect's size (`vfjax.diagnosis.Calibrated`'s
    intervals) refits its replicates so with `vfjax.Calibration`'s ``interval_search``.
    Where the effect's parameter trades with the fitted ones along a valley of several
    basins of nearly equal error (a mucosal delay and K), Levenberg-Marquardt steps from the
    replicates' truth stay in its basin, and the replicates' spread understates the
    estimate's.

    Each recording is refitted by `refit_each` (one batch) from two swarms (``plan.swarm``):
    one from ``point`` (values of ``result``'s fitted parameters and the candidate's: the
    replicates' truth), one from the same with the candidate just off its off-value
    (`just_off`); the better of the two is polished with ``plan.confirm_polish``, as the
    confirming refit that gives the recording's estimate is.

    Arguments:
        result: the fit being diagnosed (its fitted parameters are refitted).
        recordings: the recordings to refit (of one length and frame rate).
        cand: the candidate whose parameters are refitted with the fitted ones.
        point: the starting values, by parameter name.
        plan: the refits' settings (`RefitPlan`).
        family: the candidates whose terms the compiled program carries (the diagnosis's).
        anchor: values of fitted parameters (`anchor_values`), a second centre of the box.
        warmup: simulated time before the first frame (s); default: the fit's.
    """
    starts = [point, just_off(cand, result.model.with_term(cand.term), point)]
    return refit_each(
        result,
        list(recordings),
        [(cand, starts)] * len(recordings),
        dataclasses.replace(plan, polished=1),
        family=family,
        anchor=anchor,
        warmup=warmup,
        polish=plan.confirm_polish,
    )


def simulated_like(recording: Recording, area, kind: str) -> Recording:
    """A recording simulated in ``recording``'s place (a null recording or a bootstrap
    replicate, ``kind``): ``area`` cut to its frames, with its frame rate, unit and
    metadata (its traces, masks and per-fold areas left out)."""
    return dataclasses.replace(
        recording,
        area=np.asarray(area[: recording.n_frames]),
        name=f"{recording.name} ({kind})",
        edges=None,
        masks=None,
        folds=None,
    )


def error(fit: FitResult) -> float:
    """A fit's NMSE for ranking (a non-finite one ranks last)."""
    return fit.nmse if np.isfinite(fit.nmse) else np.inf


class NullSearch:
    """A candidate's search (`refit_each` from its `refit_starts`) run on null recordings
    as it ran on the recording: on each one, the score tests at the null recording's truth
    (the fit they are simulated from) give the starts, and the same swarms and polish
    refit it; several null recordings share one batch of ``plan.batch`` fits.

    Arguments:
        result: the fit the null recordings are simulated from.
        recording: the recording (its frame rate and name).
        cands: the diagnosis's candidates (`Candidate`), the family of its refits.
        plan: the refits' settings (`RefitPlan`).
        anchor: values of fitted parameters (`anchor_values`), a second centre.
        variance: the score tests' variance (`Criteria.variance`).
        n_starts: per candidate, the starts of its search on the recording (as many as on
            each null recording).
    """

    def __init__(self, result, recording, cands, plan, anchor, variance, n_starts):
        self.result, self.recording, self.cands = result, recording, list(cands)
        self.plan, self.anchor, self.variance = plan, anchor, variance
        self.n_starts = tuple(n_starts)

    def _jobs(self, k: int, null: Recording):
        cand = self.cands[k]
        score = score_tests(self.result, null, self.cands, variance=self.variance)[k]
        model = self.result.model.with_term(cand.term)
        begin = refit_starts(cand, model, null, score, self.plan.starts, self.anchor)
        anchored = [{**begin[0], **self.anchor}] if self.anchor else []
        return cand, begin + anchored

    def per_batch(self, k: int) -> int:
        """Null recordings searched per batch for candidate ``k``."""
        return max(1, self.plan.batch // self.n_starts[k])

    def __call__(self, k: int, areas: np.ndarray) -> np.ndarray:
        """Candidate ``k``'s search refit NMSE on each null recording (rows of ``areas``,
        padded beyond the recording's frames)."""
        rec = self.recording
        nulls = [simulated_like(rec, a, "null") for a in areas]
        jobs = [self._jobs(k, null) for null in nulls]
        fits = refit_each(
            self.result, nulls, jobs, self.plan, family=self.cands, anchor=self.anchor
        )
        return np.array([error(f) for f in fits])
