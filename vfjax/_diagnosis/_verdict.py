"""What a diagnosis found, the statistics of a refit's error fall, and the verdict in words."""

import dataclasses
import math

from .._fit import FitResult
from ..compare import Comparison
from ._options import Criteria, RefitPlan
from ._score import EffectScore

#: The share of the misfit above the noise floor that added effects must remove for a
#: recording to count as explained (`Investigation.outcome`), and that a search refit must
#: remove to be named unconfirmed (`Diagnosis.unconfirmed`).
EXPLAINED_SHARE = 0.5


def explains(before: float, after: float, floor: float) -> bool:
    """Whether a fit of NMSE ``after`` removes `EXPLAINED_SHARE` of the misfit above the
    noise floor ``floor`` (NMSE) that a fit of NMSE ``before`` leaves."""
    return before - after >= EXPLAINED_SHARE * (before - floor)


def error_before(result, control) -> float:
    """The NMSE the falls are measured from: the fit's (``result``), or the control refit's
    (``control``, the model refitted without any effect; None: no refit) if lower."""
    return min(result.nmse, control.nmse) if control is not None else result.nmse


@dataclasses.dataclass(frozen=True)
class EffectRefit:
    """The refit with one candidate effect, and its calibrated test.

    Attributes:
        effect: the effect's name.
        result: the search's refit (`FitResult`, swarm and polish; its model holds the
            effect), where an extension starts.
        nmse: the error of the calibrated refit (`vfjax.Calibration`: from the control's
            optimum in the candidate's sampling, never above it).
        fall: share of the control's squared error it removes, 1 - nmse / control NMSE,
            the control being the best model without any effect (in the fit's sampling, or
            after the candidate's longer warm-up where that fits better); negative where a
            refit after a longer warm-up ends above the fit's own control.
        values: the effect's fitted parameters (the calibrated refit's).
        p_value: family-wise p-value, calibrated on null recordings of the fitted model (of
            the search's refit, where the null recordings were searched alike and that
            passes: `vfjax.diagnosis.Calibrated.search_p_values`).
        f_p_value: the F test's p-value of the fall (uncalibrated: the standardisation that
            the calibration compares across candidates).
        marginal_p_value: the calibrated p-value against this candidate's null alone.
        interval: ``{parameter: (low, high)}`` at ``Calibration.interval`` (a parametric
            bootstrap), for a significant effect; None otherwise.
        off_values: the values of its tested parameters that switch it off.
        search_p_value: the search's refit (``result``) put to the test
            (`vfjax.diagnosis.Calibrated.search_p_values`): against the null recordings'
            refits from fixed starts, no evidence; where that passes and ``p_value`` does
            not, against the same search on the null recordings; NaN where not computed.
    """

    effect: str
    result: FitResult
    nmse: float
    fall: float
    values: dict
    p_value: float
    f_p_value: float
    marginal_p_value: float
    interval: dict | None
    off_values: dict
    search_p_value: float = math.nan

    @property
    def identified(self) -> bool:
        """Whether the interval of every tested parameter is measured (finite, of positive
        width) and excludes its off-value."""
        if self.interval is None:
            return False
        return all(excludes(self.interval[n], v) for n, v in self.off_values.items())


def excludes(interval, value: float) -> bool:
    """Whether ``interval`` (low, high) is measured (finite, of positive width: bootstrap
    refits that all stay where they start measure nothing) and excludes ``value``."""
    low, high = interval
    return bool(
        math.isfinite(low) and math.isfinite(high) and low < high and not low <= value <= high
    )


@dataclasses.dataclass(frozen=True)
class Diagnosis:
    """What `diagnose` found.

    Attributes:
        result: the fit that was diagnosed.
        recording_name: its recording's name.
        comparison: the measured-vs-fitted `Comparison`.
        scores: score tests by effect name.
        refits: the refits by effect name (empty without refits).
        control: the same refit without any effect (None without refits): the error the
            fitted model itself reaches with the refit's search; falls are measured from the
            lower of its error and the fit's.
        ranking: effect names, best first.
        needed: effects that pass the criteria, best first.
        criteria: the `Criteria` the verdict applied.
        plan: the `RefitPlan` of the refits (None without refits).
        candidates: the candidates tested (`Candidate`), in their order.
        noise_nmse: the NMSE that measurement noise alone would leave (estimated from the
            GAW's frame-to-frame differences), a floor no model can beat.
        verdict: the conclusion in words.
        calibrated: the calibration's record (`vfjax.diagnosis.Calibrated`: null recordings, their
            variability, p-values), None without refits.
        held: the parameters that a first fit of the recording adjusts
            (`vfjax.first_fit_parameters`: S for a GAW in pixels, the closure duration t_c,
            and the subglottal pressure P_s where the recording does not state it) but the
            diagnosed fit held at its model's values, ``{name: (value, unit)}``. The refits
            hold them too, so an effect found may stand in for one of them; the verdict then
            says so.
    """

    result: FitResult
    recording_name: str
    comparison: Comparison
    scores: dict
    refits: dict
    control: FitResult | None
    ranking: list
    needed: list
    criteria: Criteria
    plan: RefitPlan | None
    candidates: tuple
    noise_nmse: float
    verdict: str
    calibrated: object = None
    held: dict = dataclasses.field(default_factory=dict)

    @property
    def level(self) -> float:
        """The level each candidate's evidence is compared with: ``criteria.alpha`` for the
        calibrated (family-wise) p-values, alpha over the candidates for score tests alone."""
        return self.criteria.alpha if self.refits else self.criteria.level(len(self.scores))

    @property
    def nmse_before(self) -> float:
        """The error the falls are measured from: the fit's, or the control refit's if lower."""
        return error_before(self.result, self.control)

    @property
    def variability(self):
        """The test of cycle-to-cycle variability against white noise alone, and its size
        (`vfjax.diagnosis.CycleVariability`), run where no candidate is significant; None
        otherwise, without refits or with fewer than four whole cycles."""
        return None if self.calibrated is None else self.calibrated.cycles

    @property
    def unconfirmed(self) -> list[str]:
        """Candidates whose search refit passes the test against the null recordings'
        refits from fixed starts, and would explain the recording (it removes
        `EXPLAINED_SHARE` of the misfit above the noise floor, as an added effect must in
        `vfjax.workflow.Investigation.outcome`), while their own refit does not pass and no
        search of the null recordings decided it, best search first: the search reached a
        basin that the refits from fixed starts do not, and that alone is no evidence (the
        search chose its basin on the recording). The diagnosis searches the null
        recordings alike (`vfjax.Calibration.search_nulls`), which decides it either way,
        unless that is off or several candidates are so flagged that the null recordings
        cannot reach alpha for each: then the effect is neither needed nor ruled out, and
        the fits are there to compare (`vfjax.workflow.extend_from`)."""
        alpha = self.criteria.alpha
        before, floor = self.nmse_before, self.noise_nmse
        flagged = [
            f
            for f in self.refits.values()
            if f.search_p_value <= alpha
            and f.p_value > alpha
            and f.result.nmse < f.nmse
            and explains(before, f.result.nmse, floor)
        ]
        return [f.effect for f in sorted(flagged, key=lambda f: f.result.nmse)]

    @property
    def best(self) -> str | None:
        """The effect to add (the top needed one), or None."""
        return self.needed[0] if self.needed else None

    @property
    def best_fit(self) -> FitResult | None:
        """The refit with the best needed effect, or None."""
        return self.refits.get(self.best).result if self.best in self.refits else None

    def table(self) -> list[dict]:
        """One row per candidate, in ranking order."""
        rows, unconfirmed = [], self.unconfirmed
        for rank, name in enumerate(self.ranking, 1):
            s = self.scores[name]
            f = self.refits.get(name)
            rows.append(
                {
                    "rank": rank,
                    "effect": name,
                    "statistic": s.statistic,
                    "dof": s.dof,
                    "p_value": s.p_value,
                    "one_sided": s.one_sided,
                    "nmse_after": f.nmse if f else None,
                    "fall": f.fall if f else None,
                    "refit_f_p_value": f.f_p_value if f else None,
                    "calibrated_p_value": f.p_value if f else None,
                    "evidence": evidence(s, f),
                    "significant": evidence(s, f) <= self.level,
                    "values": f.values if f else {},
                    "interval": f.interval if f else None,
                    "needed": name in self.needed,
                    "search_p_value": f.search_p_value if f else None,
                    "unconfirmed": name in unconfirmed,
                }
            )
        return rows


def evidence(score: EffectScore, refit: "EffectRefit | None") -> float:
    """The p-value the verdict reads: the refit's calibrated one, or the score test's
    (asymptotic) without refits."""
    return score.p_value if refit is None else refit.p_value


def _sizes(values: dict, interval: dict | None = None) -> str:
    """An effect's parameter ``values``, each with its interval where ``interval`` has one."""
    parts = []
    for k, v in values.items():
        text = f"{k} = {v:.4g}"
        if interval and k in interval:
            lo, hi = interval[k]
            text += f" [{lo:.3g}, {hi:.3g}]"
        parts.append(text)
    return ", ".join(parts)


def verdict_text(d: Diagnosis) -> str:
    before = d.nmse_before
    floor = f"noise floor about {d.noise_nmse:.3%}"
    lines = []
    if d.result.failed:
        # every fall and p-value below is measured from this fit: a reader must not take "no
        # effect is needed" for a model that describes the recording
        lines.append(
            f"The diagnosed fit {d.result.status_message()}; the effects are weighed against it"
        )
    if d.control is not None and d.control.nmse < 0.8 * d.result.nmse:
        lines.append(
            f"The fit was not the best the model can do: a refit without any effect "
            f"reaches NMSE {d.control.nmse:.3%} (was {d.result.nmse:.3%})"
        )
    cal = d.calibrated
    against = (
        f" against {cal.replicates} null recordings of the fitted model" if cal is not None else ""
    )
    if d.best is not None:
        f = d.refits.get(d.best)
        p = evidence(d.scores[d.best], f)
        k = cal.candidates.index(d.best) if cal is not None else None
        if k is not None and cal.searched_nulls and cal.searched_nulls[k]:
            against += ", each searched as the recording was"
        text = f"{d.best} is missing (p = {p:.2g}{against})"
        if f is not None:
            # the errors of the fits a user goes on with: the best without the effect and
            # the search's refit with it (the calibrated refits' are in the table)
            after = f.result.nmse
            fall = 1.0 - after / before if before > 0 else 0.0
            text += (
                f": adding it lowers the NMSE from {before:.3%} to {after:.3%} "
                f"({fall:.0%} of the squared error; {_sizes(f.values, f.interval)}"
                + (f", {cal.interval_level:.0%} intervals)" if f.interval else ")")
            )
            if d.noise_nmse > 0:
                text += (
                    f". The error left is {after / d.noise_nmse:.1f} times the noise floor; "
                    "diagnose the extended fit for a second round"
                )
        lines.append(text)
        lines += _held_text(d)
        lines += _unassessed_text(d)
        return ". ".join(lines) + "."
    significant = [n for n in d.ranking if evidence(d.scores[n], d.refits.get(n)) <= d.level]
    if significant and d.refits:
        n = significant[0]
        f = d.refits[n]
        lines.append(
            f"No catalogue effect is needed: {n} is detectable (p = {f.p_value:.2g}{against}) "
            f"but not identifiable: its fitted size's interval includes its off-value "
            f"({_sizes(f.values, f.interval)}; NMSE {before:.3%}, {floor})"
        )
    elif significant:
        lines.append(
            f"{significant[0]} is significant (score test p = "
            f"{d.scores[significant[0]].p_value:.2g}, not calibrated); run the refits to "
            "calibrate it and see how much of the error it removes"
        )
    else:
        smallest = min(
            (evidence(d.scores[n], d.refits.get(n)) for n in d.ranking), default=float("nan")
        )
        lines.append(
            f"No candidate effect is needed: none is significant{against} with the "
            f"recording's noise and cycle-to-cycle variability (smallest p = {smallest:.2g}; "
            f"NMSE {before:.3%}, {floor})"
        )
    if significant or d.unconfirmed:
        lines += _held_text(d)
    lines += _unassessed_text(d)
    lines += _unconfirmed_text(d)
    lines += _goodness_text(d)
    cycles = _cycles_text(d)
    if cycles:
        lines.append(cycles)
    failures = d.comparison.failures()
    if failures:
        lines.append("Where the model fails: " + "; ".join(failures[:3]))
    return ". ".join(lines) + "."


#: How far (a share of its NMSE) a candidate's refit may end above the refit without any
#: effect before the verdict names it as not assessed: the two can come from different
#: warm-ups, whose optima differ by rounding where the fitted model fits both alike.
_ABOVE = 0.01


def _held_text(d: Diagnosis) -> list[str]:
    """The sentence on the parameters the diagnosed fit held where a first fit adjusts them
    (`Diagnosis.held`), said wherever an effect is found or nearly found."""
    if not d.held:
        return []
    listed = ", ".join(f"{name} at {value:.4g} {unit}" for name, (value, unit) in d.held.items())
    it = "them" if len(d.held) > 1 else "it"
    return [
        f"Caution: the diagnosed fit held {listed}, where a first fit of the recording "
        f"(vfjax.fit_recording) adjusts {it}, and the refits hold {it} too: an effect found "
        f"here may stand in for {it}. Diagnose a first fit to tell"
    ]


def _unassessed_text(d: Diagnosis) -> list[str]:
    """The sentence on candidates whose calibrated refit ends above the best model without
    any effect (after a longer warm-up, where the fitted model itself fits worse): a search
    that did not reach the control, which is no evidence either way."""
    above = [f for f in d.refits.values() if f.fall < -_ABOVE]
    if not above:
        return []
    listed = ", ".join(
        f"{f.effect} (NMSE {f.nmse:.3%} against {f.nmse / (1.0 - f.fall):.3%})" for f in above
    )
    return [
        f"Not assessed: the refits with {listed} end above the refit without any effect: "
        "after the longer warm-up they need, the fitted model itself fits worse, so their "
        "p-values say nothing against them"
    ]


def _unconfirmed_text(d: Diagnosis) -> list[str]:
    """The sentence on candidates whose search refit the calibrated refits do not reach
    (`Diagnosis.unconfirmed`)."""
    names = d.unconfirmed
    if not names:
        return []
    found = []
    for f in (d.refits[n] for n in names):
        searched = {k: float(f.result.model.params()[k]) for k in f.values}  # the search's
        found.append(
            f"{f.effect} (NMSE {f.result.nmse:.3%} against {f.nmse:.3%}; {_sizes(searched)})"
        )
    listed = ", ".join(found)
    cal = d.calibrated
    counts = {
        cal.searched_nulls[cal.candidates.index(n)]
        for n in names
        if cal is not None and cal.searched_nulls
    }
    most = max(counts, default=0)
    searched = (
        f"searched alike, {most} of the null recordings fell short of it, too few to decide"
        if most > 0
        else "the null recordings were not searched alike"
    )
    if 0 < most < cal.replicates:  # (searched: more can decide it)
        searched += (
            f" (searching all {cal.replicates} decides it, at a search per null recording: "
            "vfjax.Calibration(search_nulls=None), vfjax diagnose --search-nulls all)"
        )
    return [
        f"Unconfirmed: the search's refits with {listed} reach errors that the calibrated "
        "refits, made from fixed starts on the recording as on every null recording, do "
        f"not, and lie beyond the null recordings at alpha = {d.criteria.alpha:g}; "
        f"{searched}, so this is no evidence, but the effect is not ruled out either: "
        "compare the fits (vfjax.workflow.extend_from)"
    ]


def _goodness_text(d: Diagnosis) -> list[str]:
    """The sentence on a fit whose error lies beyond every null recording's
    (`Calibrated.fit_p_value` at most alpha), where no candidate is needed."""
    cal = d.calibrated
    if cal is None or not cal.null_controls or not cal.fit_p_value <= d.criteria.alpha:
        return []
    return [
        f"Yet the fit's error is above that of all {len(cal.null_controls)} null recordings "
        f"(calibrated p = {cal.fit_p_value:.2g}): the recording holds a misfit that repeats "
        "from cycle to cycle, which no candidate describes"
    ]


def _cycles_text(d: Diagnosis) -> str:
    """The sentence on cycle-to-cycle variability, where the recording shows it (tested only
    where no candidate is significant: a missing effect's misfit, such as a gap's, trades
    with the per-cycle factors, so the extended fit's diagnosis is the one to read)."""
    v = d.variability
    if v is None or not v.needed(d.criteria.alpha):
        return ""
    return (
        f"The recording also varies from cycle to cycle beyond its noise (p = {v.p_value:.2g} "
        f"against {v.replicates} recordings of the fitted model with white noise only): "
        f"{v.words()} ({v.level:.0%} intervals)"
    )
