"""What a diagnosis found, the statistics of a refit's error fall, and the verdict in words."""

import dataclasses

import numpy as np
from scipy import stats

from .._fit import FitResult
from ..compare import Comparison
from ._options import Criteria, RefitPlan
from ._score import EffectScore


@dataclasses.dataclass(frozen=True)
class EffectRefit:
    """The refit with one candidate effect (the confirming refit's, for the leader).

    Attributes:
        effect: the effect's name.
        result: the refit (`FitResult`; its model holds the effect).
        nmse: the error it reaches.
        fall: share of the current squared error it removes, 1 - nmse / nmse_before.
        values: the effect's fitted parameters.
        p_value: F test of the error fall against the control refit, on the effective
            number of independent frames (`effective_frames`).
    """

    effect: str
    result: FitResult
    nmse: float
    fall: float
    values: dict
    p_value: float


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

    @property
    def level(self) -> float:
        """The significance level of each candidate: ``criteria.alpha`` over their number."""
        return self.criteria.level(len(self.scores))

    @property
    def nmse_before(self) -> float:
        """The error the falls are measured from: the fit's, or the control refit's if lower."""
        return min(self.result.nmse, self.control.nmse) if self.control else self.result.nmse

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
        rows = []
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
                    "refit_p_value": f.p_value if f else None,
                    "evidence": evidence(s, f),
                    "significant": evidence(s, f) < self.level,
                    "values": f.values if f else {},
                    "needed": name in self.needed,
                }
            )
        return rows


def effective_frames(residual: np.ndarray, bandwidth: int) -> float:
    """Frames' worth of independent information in a correlated residual: n over the
    long-run variance ratio 1 + 2 sum_l w_l rho_l (Bartlett weights, lags up to
    ``bandwidth``), kept within [n / (bandwidth + 1), n]."""
    r = np.asarray(residual, dtype=float) - np.mean(residual)
    n, c0 = r.size, float(r @ r)
    if c0 == 0:
        return float(n)
    ratio = 1.0 + 2.0 * sum(
        (1.0 - lag / (bandwidth + 1.0)) * float(r[lag:] @ r[:-lag]) / c0
        for lag in range(1, min(bandwidth, n - 1) + 1)
    )
    return float(np.clip(n / max(ratio, 1e-12), n / (bandwidth + 1.0), n))


def refit_p_value(sse0, sse1, n_eff, n_fitted, n_added):
    """F test of the refit's error fall, on ``n_eff`` effective frames."""
    dof = n_eff - n_fitted - n_added
    if sse1 <= 0 or dof <= 0:
        return 0.0 if sse1 < sse0 else 1.0
    f = max(sse0 - sse1, 0.0) / n_added / (sse1 / dof)
    return float(stats.f.sf(f, n_added, dof))


def evidence(score: EffectScore, refit: "EffectRefit | None") -> float:
    """Combined p-value: the smaller of the score test's and the refit's, doubled."""
    if refit is None:
        return score.p_value
    return min(1.0, 2.0 * min(score.p_value, refit.p_value))


def verdict_text(d: Diagnosis) -> str:
    before = d.nmse_before
    floor = f"noise floor about {d.noise_nmse:.3%}"
    lines = []
    if d.control is not None and d.control.nmse < 0.8 * d.result.nmse:
        lines.append(
            f"The fit was not the best the model can do: a refit without any effect "
            f"reaches NMSE {d.control.nmse:.3%} (was {d.result.nmse:.3%})"
        )
    if d.best is not None:
        f = d.refits.get(d.best)
        text = f"{d.best} is missing (evidence p = {evidence(d.scores[d.best], f):.2g})"
        if f is not None:
            values = ", ".join(f"{k} = {v:.4g}" for k, v in f.values.items())
            text += (
                f": adding it lowers the NMSE from {before:.3%} to {f.nmse:.3%} "
                f"({f.fall:.0%} of the squared error; {values})"
            )
            if f.nmse > 2.0 * d.noise_nmse and f.nmse > 0.002:
                text += (
                    f". The error left is above the noise ({floor}): something else is "
                    "still missing; diagnose the extended fit for a second round"
                )
        lines.append(text)
        return ". ".join(lines) + "."
    significant = [n for n in d.ranking if evidence(d.scores[n], d.refits.get(n)) < d.level]
    f = d.refits.get(significant[0]) if significant else None
    if before <= 2.0 * d.noise_nmse:
        lines.append(
            f"No effect is needed: the NMSE {before:.3%} is at the noise level "
            f"({floor}) and no candidate removes {d.criteria.min_fall:.0%} of it"
        )
    elif significant and f is None:
        lines.append(
            f"{significant[0]} is significant (score test p = "
            f"{d.scores[significant[0]].p_value:.2g}); run the refits to see how "
            "much of the error it removes"
        )
    elif significant:
        floors = d.criteria.noise_multiple
        why = (
            f"removes only {f.fall:.0%} of the squared error"
            if f.fall < d.criteria.min_fall
            else f"removes only {before - f.nmse:.3%} of NMSE, less than {floors:g} "
            f"noise floors ({floors * d.noise_nmse:.3%}): no more than fitting "
            "noise and cycle-to-cycle variability would"
        )
        lines.append(
            f"No catalogue effect is needed: {significant[0]} is statistically "
            f"detectable (p = {evidence(d.scores[significant[0]], f):.2g}) but {why} "
            f"(NMSE {before:.3%}, {floor})"
        )
    else:
        lines.append(
            f"No candidate effect is significant (NMSE {before:.3%}, {floor}): the "
            "misfit left is not one the catalogue describes"
        )
    failures = d.comparison.failures()
    if failures and before > 2.0 * d.noise_nmse:
        lines.append("Where the model fails: " + "; ".join(failures[:3]))
    return ". ".join(lines) + "."
