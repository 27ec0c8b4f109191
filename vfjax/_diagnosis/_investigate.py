"""`investigate`: fit, diagnose, add the missing effect, refit, and repeat.

study = vfjax.investigate(recording)        # the paper's model, then up to 2 effects
study.rounds[0].diagnosis.verdict           # what is missing, in words
study.final.nmse                            # the error after the last extension
study.outcome(recording).words              # explained, unexplained, or at the noise level
vfjax.report.write_report(study, recording, "out/")
"""

import dataclasses
import math
from collections.abc import Sequence

from .._fit import (
    FIRST_FIT_RESTARTS,
    PRESSURE_RANGE,
    FitResult,
    Settling,
    Swarm,
    fit_recording,
    settling,
)
from .._fit._engine import DEFAULT_SWARM
from ..compare import NO_CLEAR_FAILURE, compare
from ..descriptors import recording_cautions
from ..model import VocalFoldModel
from ..recording import Recording
from ._candidates import offered
from ._diagnose import diagnose
from ._options import (
    DEFAULT_CALIBRATION,
    DEFAULT_CRITERIA,
    DEFAULT_PLAN,
    Calibration,
    Criteria,
    RefitPlan,
)
from ._refits import error, refit_each
from ._verdict import EXPLAINED_SHARE, Diagnosis


@dataclasses.dataclass(frozen=True)
class Round:
    """One round: a fit, its diagnosis, and the extended fit if an effect was added.

    Attributes:
        fit: the model's fit at the start of the round.
        diagnosis: `vfjax.diagnose` of that fit.
        added: the effect added (its name), or None (the loop stops).
        extended: the fit with the effect, warm-started from the diagnosis's refit (a full
            swarm + LM fit from there), or None.
    """

    fit: FitResult
    diagnosis: Diagnosis
    added: str | None
    extended: FitResult | None


@dataclasses.dataclass(frozen=True)
class Investigation:
    """The rounds of `investigate`, first to last."""

    recording_name: str
    rounds: list

    @property
    def first(self) -> FitResult:
        """The fit of the starting model."""
        return self.rounds[0].fit

    @property
    def final(self) -> FitResult:
        """The last fit: the extended model after the last round that added an effect; when
        the last round added none and its diagnosis's control (the same model refitted with
        the diagnosis's wider search) reached a lower error, that control refit."""
        last = self.rounds[-1]
        if last.extended is not None:
            return last.extended
        control = last.diagnosis.control
        return control if control is not None and control.nmse < last.fit.nmse else last.fit

    def _final_calibration(self):
        """The last diagnosis's calibration where it weighed the final fit (the last round
        added no effect), else None."""
        last = self.rounds[-1]
        return last.diagnosis.calibrated if last.extended is None else None

    @property
    def fit_p_value(self) -> float:
        """The final fit's calibrated goodness of fit (`Calibrated.fit_p_value` of the last
        diagnosis, where it weighed the final fit); NaN where no calibration did."""
        cal = self._final_calibration()
        return math.nan if cal is None else cal.fit_p_value

    @property
    def added(self) -> list[str]:
        """The effects added, in order."""
        return [r.added for r in self.rounds if r.added]

    def outcome(self, recording: Recording) -> "Outcome":
        """How far the added effects explain the recording (`Outcome`), in numbers and words.

        Arguments:
            recording: the recording the investigation fitted (for the final fit's
                comparison).
        """
        first, final = self.first.nmse, self.final.nmse
        floor = self.rounds[-1].diagnosis.noise_nmse
        misfit = first - floor
        removed = (first - final) / misfit if misfit > 0 else float("nan")
        evidence = {r.added: r.diagnosis.refits[r.added].p_value for r in self.rounds if r.added}
        failures = compare(self.final, recording).failures()
        added = ", ".join(f"{k} (calibrated p = {p:.2g})" for k, p in evidence.items())
        cal = self._final_calibration()
        goodness = self.fit_p_value
        nulls = 0 if cal is None else len(cal.null_controls)
        beyond = goodness <= self.rounds[-1].diagnosis.criteria.alpha  # (False for NaN)
        if evidence and removed >= EXPLAINED_SHARE:
            status = "explained"
            words = (
                f"{added} removed {removed:.0%} of the misfit above the noise floor (NMSE "
                f"{first:.3%} -> {final:.3%}, floor {floor:.3%})"
            )
        elif misfit <= 0 or (failures[0].startswith(NO_CLEAR_FAILURE) and not beyond):
            status = "at the noise level"
            added = f"{added} added, removing {removed:.0%} of the misfit; " if added else ""
            within = (
                f"an error that noise and cycle-to-cycle variability leave too (calibrated "
                f"p = {goodness:.2g} against {nulls} null recordings of the fitted model)"
                if nulls
                else "no phase or descriptor that the model misses"
            )
            words = (
                f"{added}the fit leaves {within} (NMSE {first:.3%} -> {final:.3%}, noise "
                f"floor {floor:.3%})"
            )
        else:
            status = "unexplained"
            what = (
                "no catalogue effect is needed"
                if not evidence
                else f"{', '.join(evidence)} removed only {removed:.0%} of the misfit"
            )
            words = f"{what} (NMSE {first:.3%} -> {final:.3%}, noise floor {floor:.3%})"
            if beyond:
                words += (
                    f"; the fit's error is above that of all {nulls} null recordings of the "
                    "fitted model with the recording's noise and cycle-to-cycle variability "
                    f"(calibrated p = {goodness:.2g}): it misses something that repeats from "
                    "cycle to cycle"
                )
            missed = (
                "no single phase or descriptor"
                if failures[0].startswith(NO_CLEAR_FAILURE)
                else "; ".join(failures[:3])
            )
            words += f"; the model still misses: {missed}"
        pressure = self.final.params.get("P_s")
        low, high = PRESSURE_RANGE
        if pressure is not None and not low * (1 + 1e-6) < float(pressure) < high * (1 - 1e-6):
            words += (
                f"; the final fit's subglottal pressure P_s = {float(pressure):.3g} dyne/cm² "
                f"reaches the edge of the {low:.0f}-{high:.0f} dyne/cm² of phonation "
                "(vfjax.PRESSURE_RANGE, which no fit leaves): read its parameters with care"
            )
        unconfirmed = self.rounds[-1].diagnosis.unconfirmed
        if unconfirmed:
            words += (
                f"; the search's refits with {', '.join(unconfirmed)} fit better but are "
                "unconfirmed (the calibrated refits do not reach them): compare the fits"
            )
        cycles = self.rounds[-1].diagnosis.variability
        if cycles is not None and cycles.needed(self.rounds[-1].diagnosis.criteria.alpha):
            words += (
                f"; it varies from cycle to cycle beyond its noise (calibrated p = "
                f"{cycles.p_value:.2g}): {cycles.words()}"
            )
        settled = settling(self.final, recording)
        if not settled.settled:
            words += f"; {settled.words()}"
        for caution in recording_cautions(recording.area, recording.fps):
            words += f"; {caution}"
        return Outcome(
            recording_name=self.recording_name,
            status=status,
            fit_p_value=goodness,
            first_nmse=first,
            final_nmse=final,
            noise_nmse=floor,
            removed=removed,
            evidence=evidence,
            failures=failures,
            words=words,
            settling=settled,
        )


@dataclasses.dataclass(frozen=True)
class Outcome:
    """What an investigation concluded about one recording.

    Attributes:
        recording_name: the recording's name.
        status: "explained" (effects added with calibrated evidence removed at least
            `EXPLAINED_SHARE` of the misfit above the noise floor); else "at the noise level"
            (the final fit's comparison finds no phase or descriptor that it misses, and its
            error is not above every null recording's at alpha: ``fit_p_value``) or
            "unexplained" (``failures`` names what the final fit misses; the words say
            when its error lies above every null recording's).
        first_nmse, final_nmse: NMSE of the paper's model's fit and of the final fit.
        noise_nmse: the NMSE that measurement noise alone leaves (the last diagnosis's
            estimate).
        removed: share of the first fit's misfit above the noise floor that the added
            effects removed (NaN at the noise level).
        evidence: each added effect's calibrated family-wise p-value.
        failures: where the final fit still misses, in words (`Comparison.failures`).
        words: the conclusion in a sentence.
        settling: the final fit after a longer warm-up (`vfjax.settling`); the words say
            when the fit is not settled (it matches the recording with the model's
            start-up, and its parameters describe a transient).
        fit_p_value: the final fit's calibrated goodness of fit
            (`Investigation.fit_p_value`); NaN where no calibration weighed it.
    """

    recording_name: str
    status: str
    first_nmse: float
    final_nmse: float
    noise_nmse: float
    removed: float
    evidence: dict
    failures: list
    words: str
    settling: Settling | None = None
    fit_p_value: float = math.nan


def extend_from(
    diagnosis: Diagnosis, recording: Recording, effect: str | None = None, iterations: int = 40
) -> FitResult:
    """The fit with ``effect`` (default: the diagnosis's best): a full search (swarms and
    polish, ``iterations`` swarm iterations) of the fitted parameters and the effect's,
    warm-started from the diagnosis's refit with the effect, through the diagnosis's own
    compiled refit program (`RefitPlan`); the better of the two is returned."""
    name = effect or diagnosis.best
    if name is None:
        raise ValueError("the diagnosis found no effect to add; name one with effect=...")
    if name not in diagnosis.refits:
        raise ValueError(
            f"no refit of {name!r} in this diagnosis (no refits, or not a "
            f"candidate); candidates: {sorted(diagnosis.refits)}"
        )
    refit = diagnosis.refits[name]
    start = refit.result
    (cand,) = [c for c in diagnosis.candidates if c.name == name]
    plan = diagnosis.plan
    # the search's refit, and the effect at the calibrated refit's values
    starts = [dict(start.params)] * max(plan.starts - 1, 1) + [{**start.params, **refit.values}]
    (polished,) = refit_each(
        diagnosis.result,
        recording,
        [(cand, starts)],
        plan,
        family=diagnosis.candidates,
        warmup=start.sampling.warmup,
        iterations=iterations,
    )
    return min(start, polished, key=error)


def investigate(
    recording: Recording,
    model: VocalFoldModel | None = None,
    params: Sequence[str] | None = None,
    *,
    rounds: int = 2,
    candidates: Sequence | None = None,
    criteria: Criteria = DEFAULT_CRITERIA,
    plan: RefitPlan = DEFAULT_PLAN,
    calibration: Calibration = DEFAULT_CALIBRATION,
    swarm: Swarm = DEFAULT_SWARM,
    restarts: int = FIRST_FIT_RESTARTS,
    warmup: float | None = None,
    first: FitResult | None = None,
    progress: bool = False,
) -> Investigation:
    """Fit the recording (`vfjax.fit_recording`), diagnose, add the best effect, refit, and
    repeat up to ``rounds`` times or until no effect is needed.

    Arguments:
        recording: the measured GAW.
        model: the starting model (default: `initial_model(recording)`).
        params: parameters of the first fit (default: `vfjax.first_fit_parameters`: S, K,
            C_f, t_c, and P_s unless the recording states it).
        rounds: most effects to add.
        candidates: the candidate effects (default: the catalogue), see `vfjax.diagnose`.
        criteria: when an effect is needed (`Criteria`).
        plan: the diagnoses' searches (`RefitPlan`); its ``confirm_iterations=None`` skips
            the confirming refits.
        calibration: the diagnoses' calibration on null recordings (`Calibration`).
        swarm: the first fit's swarm; each extension runs as many iterations.
        restarts: independent searches of the first fit.
        warmup: the first fit's simulated time before the first frame (s; default:
            `vfjax.default_warmup`); the diagnoses refit at the same warm-up. Lengthen it
            when the fit is not settled (`vfjax.settling`).
        first: the first fit, made already (e.g. by `vfjax.fit_recordings` of many
            recordings in one batch); ``model``, ``params``, ``restarts`` and ``warmup`` are
            then unused.
        progress: print what happens.
    """
    if not isinstance(plan, RefitPlan):
        raise TypeError(f"plan must be a vfjax.RefitPlan, got {type(plan).__name__}")
    if first is None:
        current = fit_recording(
            recording,
            model,
            params,
            restarts=restarts,
            swarm=swarm,
            warmup=warmup,
            progress=progress,
        )
    elif not isinstance(first, FitResult):
        raise TypeError(f"first must be a vfjax.FitResult, got {type(first).__name__}")
    elif first.recording_name != recording.name:
        raise ValueError(
            f"first is a fit of {first.recording_name!r}, not of the recording {recording.name!r}"
        )
    else:
        current = first
    if progress:
        print(f"fit: NMSE {current.nmse:.4g}")
    done = []
    for _ in range(max(rounds, 1)):
        remaining = None if candidates is None else offered(current.model, candidates)
        d = diagnose(
            current,
            recording,
            remaining,
            criteria=criteria,
            plan=plan,
            calibration=calibration,
            progress=progress,
        )
        if progress:
            print(d.verdict)
        if d.best is None or len(done) >= rounds:
            done.append(Round(current, d, None, None))
            break
        extended = extend_from(d, recording, iterations=swarm.iterations)
        done.append(Round(current, d, d.best, extended))
        current = extended
        if len(done) == rounds:
            break
    return Investigation(recording.name, done)
