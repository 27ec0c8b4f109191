"""`diagnose`: the score tests, the refits and the verdict of one fit; `extend` by hand."""

import dataclasses
from collections.abc import Sequence
from typing import Any

import numpy as np

from .._fit import FitResult, Swarm, default_warmup, first_fit_parameters, fit
from ..compare import compare, noise_level
from ..recording import Recording
from ..terms import AbstractTerm
from ._calibration import calibrate
from ._candidates import as_candidates
from ._options import (
    DEFAULT_CALIBRATION,
    DEFAULT_CRITERIA,
    DEFAULT_PLAN,
    Calibration,
    Criteria,
    RefitPlan,
    check_reachable,
)
from ._refits import NullSearch, anchor_values, confirm, error, refit_each, refit_starts
from ._score import score_tests
from ._verdict import Diagnosis, EffectRefit, error_before, explains, verdict_text


def diagnose(
    result: FitResult,
    recording: Recording,
    candidates: Sequence | None = None,
    *,
    criteria: Criteria = DEFAULT_CRITERIA,
    plan: RefitPlan | None = DEFAULT_PLAN,
    calibration: Calibration = DEFAULT_CALIBRATION,
    progress: bool | None = None,
) -> Diagnosis:
    """Find the effect the fitted model misses (see `vfjax.diagnosis`).

    Arguments:
        result: a fit (`vfjax.fit`) of ``recording``.
        recording: the measured GAW.
        candidates: term classes, term instances or `Candidate` objects (default: the
            catalogue, `default_candidates`).
        criteria: the family-wise significance level and the score test's variance
            (`Criteria`).
        plan: how the model is searched with each candidate and without (`RefitPlan`:
            starts, swarm, polish, the confirming refit of the effect to add); None: score tests
            only, ranked by their (asymptotic, uncalibrated) p-values.
        calibration: how the refits' statistics are calibrated on null recordings
            (`Calibration`: most null recordings, batch, interval level, ...).
        progress: True: print one line per candidate and show the calibration's progress
            bar on stderr (null recordings, at most ``calibration.replicates``); None: the
            bar alone, on a terminal; False: neither.
    """
    if not isinstance(criteria, Criteria):
        raise TypeError(f"criteria must be a vfjax.Criteria, got {type(criteria).__name__}")
    if plan is not None and not isinstance(plan, RefitPlan):
        raise TypeError(f"plan must be a vfjax.RefitPlan or None, got {type(plan).__name__}")
    if not isinstance(calibration, Calibration):
        raise TypeError(
            f"calibration must be a vfjax.Calibration, got {type(calibration).__name__}"
        )
    if plan is not None:
        check_reachable(criteria.alpha, calibration)
    cands = as_candidates(result.model, candidates)
    if not cands:
        raise ValueError("no candidate effect to test: every one is already in the model")
    comparison = compare(result, recording)
    scores = score_tests(result, recording, cands, variance=criteria.variance)
    by_name = {s.effect: s for s in scores}
    level = criteria.level(len(cands))
    refits, control, cal = {}, None, None
    sse_scale = float(np.sum(np.square(recording.area)))
    if plan is not None:
        # the search: swarms from the fit and from the score tests' estimates
        anchor = anchor_values(result, recording)
        anchored = [anchor] if anchor else []  # no anchor: no second, identical start
        jobs = [(None, [{}] + anchored)]
        for cand, score in zip(cands, scores):
            model = result.model.with_term(cand.term)
            begin = refit_starts(cand, model, recording, score, plan.starts, anchor)
            jobs.append((cand, begin + [{**begin[0], **a} for a in anchored]))
        control, *fitted_each = refit_each(
            result, recording, jobs, plan, family=cands, anchor=anchor
        )

        def confirmed(top):  # a larger search of the control (and candidate top), from the
            # current control and refits
            return confirm(
                result,
                recording,
                jobs,
                control,
                fitted_each,
                top=top,
                plan=plan,
                anchor=anchor,
                family=cands,
            )

        if plan.confirm_iterations is not None:  # the best fit without any effect
            control, fitted_each = confirmed(None)
        # the test: calibrated on null recordings of the best fit without any effect; a
        # larger search for the effect to add (the most significant, if any is), where an
        # extension starts and its interval is computed; an effect that is not needed keeps
        # its quick refit
        base = result if result.nmse <= control.nmse else control

        def refine(tested):
            nonlocal control, fitted_each
            leader = tested.candidates.index(tested.ranking()[0])
            if plan.confirm_iterations is not None and tested.p_values[leader] <= criteria.alpha:
                control, fitted_each = confirmed(leader)
            return fitted_each

        # the search refits worth testing: those that would explain the recording, the only
        # ones the test can name unconfirmed (testing others keeps null recordings coming)
        before = error_before(result, control)
        floor = _noise_nmse(recording, [result, control, *fitted_each], sse_scale)
        tested = [explains(before, f.nmse, floor) for f in fitted_each]
        cal = calibrate(
            base,
            recording,
            cands,
            criteria.alpha,
            calibration,
            fitted_each,
            anchor,
            refine,
            tested_searches=tested,
            search=NullSearch(
                base,
                recording,
                cands,
                plan,
                anchor,
                criteria.variance,
                n_starts=[len(starts) for _, starts in jobs[1:]],
            ),
            progress=progress,
        )
        if progress:
            print(
                f"control (no effect): NMSE {result.nmse:.4g} -> {cal.control_nmse:.4g}; "
                f"{cal.replicates} null recordings"
            )
        ranking = cal.ranking()
        for k, (cand, fitted) in enumerate(zip(cands, fitted_each)):
            off = {n: float(type(cand.term).off_values[n]) for n in cand.tested}
            control_k = cal.controls[k]  # the control in the candidate's sampling
            fall = 1.0 - cal.nmse[k] / control_k if control_k > 0 else 0.0
            refits[cand.name] = EffectRefit(
                cand.name,
                fitted,
                cal.nmse[k],
                fall,
                cal.values[k],
                cal.p_values[k],
                cal.f_p_values[k],
                cal.marginal_p_values[k],
                cal.intervals[k],
                off,
                cal.search_p_values[k],
            )
            if progress:
                print(
                    f"{cand.name}: NMSE {control_k:.4g} -> {cal.nmse[k]:.4g}, "
                    f"p = {cal.p_values[k]:.2g} (F test {cal.f_p_values[k]:.2g})"
                )
        needed = [
            n for n in ranking if refits[n].p_value <= criteria.alpha and refits[n].identified
        ]
    else:
        ranking = sorted(by_name, key=lambda n: (by_name[n].p_value, -by_name[n].statistic))
        needed = [n for n in ranking if by_name[n].p_value < level]
    fits = [result] + ([control] if control else []) + [f.result for f in refits.values()]
    # from the final fits: the confirming refits may have replaced the control and refits
    noise_nmse = _noise_nmse(recording, fits, sse_scale)
    diag = Diagnosis(
        result,
        recording.name,
        comparison,
        by_name,
        refits,
        control,
        ranking,
        needed,
        criteria,
        plan,
        tuple(cands),
        noise_nmse,
        "",
        cal,
        _held(result, recording),
    )
    return dataclasses.replace(diag, verdict=verdict_text(diag))


def _held(result: FitResult, recording: Recording) -> dict:
    """`Diagnosis.held`: what a first fit of ``recording`` adjusts that ``result`` held."""
    values, units = result.model.params(), result.model.parameter_units()
    names = first_fit_parameters(recording, result.model)
    return {n: (float(values[n]), units[n]) for n in names if n not in result.params}


def _noise_nmse(recording, fits, sse_scale) -> float:
    """The NMSE that white measurement noise alone leaves (`noise_level`), from the residual
    of the best of ``fits`` (a misfit with sharp features inflates the estimate); no floor
    exceeds that fit's own error."""
    best = min(fits, key=error)
    noise = noise_level(recording.area, best.fitted_gaw(recording))
    return min(recording.n_frames * noise**2 / sse_scale, best.nmse)


def extend(
    result: FitResult,
    recording: Recording,
    effect: AbstractTerm,
    params: Sequence[str] | None = None,
    **fit_kwargs: Any,
) -> FitResult:
    """Add ``effect`` to the fitted model and refit, warm-started from the current fit.

    Arguments:
        result: the current fit.
        recording: its recording.
        effect: the term to add, with its starting values (e.g. ``GlottalGap()``, or a
            diagnosis's ``refits[name].result.model.term(GlottalGap)``).
        params: the effect's parameters to fit (default: all of them).
        fit_kwargs: passed to `vfjax.fit` (default: 40 swarm iterations, no progress bar, the
            current fit's substeps, and its warm-up or the effect's ``min_warmup`` if longer).
    Returns the new `FitResult`; its model holds the effect.
    """
    model = result.model.with_effect(effect)
    names = tuple(result.params) + tuple(params or type(effect).parameters)
    kwargs = {
        "swarm": Swarm(iterations=40),
        "progress": False,
        "substeps": result.sampling.substeps,
        "warmup": max(result.sampling.warmup, default_warmup(model)),
        **fit_kwargs,
    }
    return fit(model, recording, params=names, **kwargs)
