"""`diagnose`: the score tests, the refits and the verdict of one fit; `extend` by hand."""

import dataclasses
from collections.abc import Sequence

import numpy as np

from .._fit import FitResult, Swarm, default_warmup, fit
from ..compare import compare, noise_level
from ..recording import Recording
from ._candidates import as_candidates
from ._options import DEFAULT_CRITERIA, DEFAULT_PLAN, Criteria, RefitPlan
from ._refits import anchor_values, confirm, error, refit_each, refit_starts
from ._score import period_frames, score_tests
from ._verdict import (
    Diagnosis,
    EffectRefit,
    effective_frames,
    evidence,
    refit_p_value,
    verdict_text,
)


def diagnose(
    result: FitResult,
    recording: Recording,
    candidates: Sequence | None = None,
    *,
    criteria: Criteria = DEFAULT_CRITERIA,
    plan: RefitPlan | None = DEFAULT_PLAN,
    progress: bool = False,
) -> Diagnosis:
    """Find the effect the fitted model misses (see `vfjax.diagnosis`).

    Arguments:
        result: a fit (`vfjax.fit`) of ``recording``.
        recording: the measured GAW.
        candidates: term classes, term instances or `Candidate` objects (default: the
            catalogue, `default_candidates`).
        criteria: when an effect is needed (`Criteria`: significance level, the share of
            the error and the noise floors' worth its refit must remove, the score test's
            variance).
        plan: how the model is refitted with each candidate and without (`RefitPlan`:
            starts, swarm, polish, the confirming refit of the leader); None: score tests
            only, ranked by p-value.
        progress: print one line per refit.
    """
    if not isinstance(criteria, Criteria):
        raise TypeError(f"criteria must be a vfjax.Criteria, got {type(criteria).__name__}")
    if plan is not None and not isinstance(plan, RefitPlan):
        raise TypeError(f"plan must be a vfjax.RefitPlan or None, got {type(plan).__name__}")
    cands = as_candidates(result.model, candidates)
    if not cands:
        raise ValueError("no candidate effect to test: every one is already in the model")
    comparison = compare(result, recording)
    scores = score_tests(result, recording, cands, variance=criteria.variance)
    by_name = {s.effect: s for s in scores}
    level = criteria.level(len(cands))
    refits, control, reference, noise_nmse = {}, None, result.nmse, None
    bandwidth = period_frames(recording)
    sse_scale = float(np.sum(np.square(recording.area)))
    if plan is not None:
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
        # the confirming refit serves the effect to add; when the error is within
        # ``noise_multiple`` noise floors, no effect can be needed and it is skipped
        noise_nmse = _noise_nmse(recording, [result, control, *fitted_each], sse_scale)
        reference = min(result.nmse, control.nmse)
        if plan.confirm_iterations is not None and reference > criteria.noise_multiple * noise_nmse:
            control, fitted_each = confirm(
                result,
                recording,
                jobs,
                control,
                fitted_each,
                plan=plan,
                criteria=criteria,
                anchor=anchor,
                family=cands,
            )
            noise_nmse = None  # from the confirmed fits, below
        reference = min(result.nmse, control.nmse)
        if progress:
            print(f"control (no effect): NMSE {result.nmse:.4g} -> {control.nmse:.4g}")
        before = result if result.nmse <= control.nmse else control
        n_eff = effective_frames(recording.area - before.fitted_gaw(recording), bandwidth)
        for cand, score, fitted in zip(cands, scores, fitted_each):
            values = {n: fitted.params[n] for n in cand.tested + cand.extra}
            fall = 1.0 - fitted.nmse / reference if reference > 0 else 0.0
            p = refit_p_value(
                reference * sse_scale,
                fitted.nmse * sse_scale,
                n_eff,
                len(result.params) + 1,
                len(values),
            )
            refits[cand.name] = EffectRefit(cand.name, fitted, fitted.nmse, fall, values, p)
            if progress:
                print(
                    f"{cand.name}: score p = {score.p_value:.2g}, NMSE {reference:.4g} -> "
                    f"{fitted.nmse:.4g} (refit p = {p:.2g})"
                )
        ranking = sorted(by_name, key=lambda n: (refits[n].nmse, by_name[n].p_value))
    else:
        ranking = sorted(by_name, key=lambda n: (by_name[n].p_value, -by_name[n].statistic))
    if noise_nmse is None:
        fits = [result] + ([control] if control else []) + [f.result for f in refits.values()]
        noise_nmse = _noise_nmse(recording, fits, sse_scale)

    def is_needed(n):
        if evidence(by_name[n], refits.get(n)) >= level:
            return False
        if not refits:
            return True
        f = refits[n]
        # it must remove a share of the error, and several noise floors' worth of it: a few
        # extra parameters fitted to noise and cycle-to-cycle jitter remove less
        return (
            f.fall >= criteria.min_fall
            and reference - f.nmse >= criteria.noise_multiple * noise_nmse
        )

    needed = [n for n in ranking if is_needed(n)]
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
    )
    return dataclasses.replace(diag, verdict=verdict_text(diag))


def _noise_nmse(recording, fits, sse_scale) -> float:
    """The NMSE that white measurement noise alone leaves (`noise_level`), from the residual
    of the best of ``fits`` (a misfit with sharp features inflates the estimate); no floor
    exceeds that fit's own error."""
    best = min(fits, key=error)
    noise = noise_level(recording.area, best.fitted_gaw(recording))
    return min(recording.n_frames * noise**2 / sse_scale, best.nmse)


def extend(result: FitResult, recording: Recording, effect, params=None, **fit_kwargs):
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
