"""The options of a diagnosis, as objects: when an effect is needed, how it is refitted, and
how its verdicts are calibrated by simulation."""

import math

import equinox as eqx

from .._fit import Polish, Swarm
from .._validate import is_count


class Criteria(eqx.Module):
    """When a candidate effect counts as needed (see `vfjax.diagnose`).

    Attributes:
        alpha: family-wise significance level over the candidates: a needed effect's
            calibrated p-value (`vfjax.Calibration`) is at most alpha. Without refits, the
            score tests' p-values are compared with alpha over the number of candidates
            (Bonferroni; asymptotic, not calibrated).
        variance: variance of the score statistic: ``"hac"`` (autocorrelation-robust,
            Newey-West over one glottal period) or ``"iid"``.
    """

    alpha: float = eqx.field(default=0.01, converter=float)
    variance: str = "hac"

    def level(self, n_candidates: int) -> float:
        """The score tests' level for each of ``n_candidates`` candidates (Bonferroni)."""
        return self.alpha / max(int(n_candidates), 1)

    def __check_init__(self):
        if not 0 < self.alpha < 1:
            raise ValueError(f"Criteria: alpha must lie in (0, 1), got {self.alpha}")
        if self.variance not in ("hac", "iid"):
            raise ValueError(f"Criteria: variance must be 'hac' or 'iid', got {self.variance!r}")


class RefitPlan(eqx.Module):
    """How a diagnosis refits the model with each candidate effect (and without: the control).

    Every refit of a diagnosis runs through one compiled program: the fitted model extended
    by all the candidates (each refit holding the others at their off-values), swarms of
    ``swarm.size`` particles, batches padded to ``batch`` fits. A larger search is more
    swarms or more iterations (both data), never more particles.

    Attributes:
        starts: starting points per candidate in the quick refits (one swarm each; a
            candidate with a score grid adds a lattice of starts over it).
        swarm: the quick refits' swarm (its size and coefficients serve every refit).
        polish: the refits' polish.
        box: the fitted parameters are searched within this factor of their current values
            (and of the starting model's, and of every start's).
        polished: of a refit's swarms (one per start), how many are polished: those that
            ended lowest (None: all). Polishing every swarm is most of a refit's cost (a
            modulation's refit has 19 starts); in the modulation's searches measured, the
            four best swarms held the best refit in seven of nine, the others ending 5.5 %
            and 0.25 % higher (benchmarks/README.md).
        confirm_iterations: swarm iterations of the confirming refits: of the control
            (before the calibration, which simulates from the best fit without any effect)
            and of the effect to add with the control again (the most significant candidate,
            when its calibrated p-value reaches alpha); None: quick refits only.
        confirm_swarms: independent swarms of the confirming refit, each from one of the
            candidate's best starts, for a candidate of one parameter; they double per
            further parameter and the iterations grow by a quarter per further parameter
            (the basins of interacting parameters, such as a modulation's frequency and
            phase, are narrow).
        confirm_polish: the polish of the confirming refits, whose fits are reported and
            whose effect sizes the intervals centre on, and of the interval's replicates
            (`vfjax.diagnosis.refit_replicates`): more steps than ``polish``, since an
            effect that trades off with the fitted parameters leaves a long, curved valley
            (a hidden mucosal delay of 0.4 ms on N3: 30 steps stop at tau 0.27 ms, K 18 %
            above the truth and an NMSE 18 % above the valley's floor, 100 reach tau 0.41
            ms; `tests/test_diagnosis.py`, the hidden-effect matrix).
        batch: fits per compiled batch (the programs are shared by batches up to it).
    """

    starts: int = eqx.field(default=3, converter=int)
    swarm: Swarm = Swarm(size=24, iterations=30)
    polish: Polish = Polish(max_steps=30)
    box: float = eqx.field(default=1.6, converter=float)
    polished: int | None = 4
    confirm_iterations: int | None = 100
    confirm_swarms: int = eqx.field(default=3, converter=int)
    confirm_polish: Polish = Polish(max_steps=100)
    batch: int = eqx.field(default=64, converter=int)

    def __check_init__(self):
        if self.starts < 1 or self.confirm_swarms < 1 or self.batch < 1:
            raise ValueError(
                "RefitPlan: starts, confirm_swarms and batch must be >= 1, got "
                f"{self.starts}, {self.confirm_swarms}, {self.batch}"
            )
        if not isinstance(self.swarm, Swarm) or not all(
            isinstance(p, Polish) for p in (self.polish, self.confirm_polish)
        ):
            raise TypeError(
                "RefitPlan: swarm must be a vfjax.Swarm, polish and confirm_polish vfjax.Polish"
            )
        if not self.box > 1:
            raise ValueError(f"RefitPlan: box must be a factor > 1, got {self.box}")
        for name in ("polished", "confirm_iterations"):
            n = getattr(self, name)
            if n is not None and not is_count(n):
                raise ValueError(f"RefitPlan: {name} must be a positive integer or None, got {n!r}")

    def confirm_search(self, n_params: int) -> tuple[int, int]:
        """(swarms, iterations) of the confirming refit for a candidate of ``n_params``
        parameters."""
        extra = max(n_params - 1, 0)
        return self.confirm_swarms * 2**extra, int(round(self.confirm_iterations * (1 + extra / 4)))


#: The default criteria and refit plan.
DEFAULT_CRITERIA = Criteria()
DEFAULT_PLAN = RefitPlan()


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
        interval_replicates: recordings simulated from the model with the effect, each
            refitted for its interval (a parametric bootstrap of the estimate), with the
            recording itself.
        interval_search: refit the interval's replicates by a search, as the estimate is
            made (`vfjax.diagnosis.refit_replicates`); False: by the statistic's ``steps``
            from their truth (faster). Where the effect trades with the fitted parameters
            along a valley of several basins (a mucosal delay and K), steps from the truth
            stay in its basin and the interval understates the estimate's scatter: on the
            injection-recovery benchmark's medium delay the truth lies inside 4 of 12
            intervals so made, and a cubic stiffness is needed beside the delay on 4 of its
            6 female recordings, against 12 of 12 and none searched (benchmarks/README.md).
        steps: Levenberg-Marquardt steps of each candidate's refits in the statistic (a few
            suffice: they start at the fit's optimum, the null recordings' truth); the
            control's refit takes twice as many.
        jacobian_every: the refits compute their Jacobian (forward mode, most of a step's
            cost) at the first step and every ``jacobian_every``-th after it, and update
            it by Broyden's secant rule from the steps' trials in between (1: at every
            step).
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
            first null recording whose search falls as far (the second, on the no-effect N1
            at 1 px, seed 1, of the injection-recovery benchmark); one that every null
            recording's falls short of costs this many searches (on a 401-frame N1, the
            modulation's takes about 10 s a null recording on 2 cores: about 3 minutes for
            19, 18 for 111).
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
    interval_search: bool = True
    steps: int = eqx.field(default=10, converter=int)
    jacobian_every: int = eqx.field(default=3, converter=int)
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
        if self.jacobian_every < 1 or self.steps < 0:
            raise ValueError(
                "Calibration: jacobian_every must be >= 1 and steps >= 0, got "
                f"{self.jacobian_every}, {self.steps}"
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
