"""The options of a diagnosis, as objects: when an effect is needed, and how it is refitted."""

import equinox as eqx

from .._fit import Polish, Swarm


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
        confirm_iterations: swarm iterations of the confirming refits: of the control
            (before the calibration, which simulates from the best fit without any effect)
            and of the effect to add with the control again (the most significant candidate,
            when its calibrated p-value reaches alpha); None: quick refits only.
        confirm_swarms: independent swarms of the confirming refit, each from one of the
            candidate's best starts, for a candidate of one parameter; they double per
            further parameter and the iterations grow by a quarter per further parameter
            (the basins of interacting parameters, such as a modulation's frequency and
            phase, are narrow).
        batch: fits per compiled batch (the programs are shared by batches up to it).
    """

    starts: int = eqx.field(default=3, converter=int)
    swarm: Swarm = Swarm(size=24, iterations=30)
    polish: Polish = Polish(max_steps=30)
    box: float = eqx.field(default=1.6, converter=float)
    confirm_iterations: int | None = 100
    confirm_swarms: int = eqx.field(default=3, converter=int)
    batch: int = eqx.field(default=64, converter=int)

    def __check_init__(self):
        if self.starts < 1 or self.confirm_swarms < 1 or self.batch < 1:
            raise ValueError(
                "RefitPlan: starts, confirm_swarms and batch must be >= 1, got "
                f"{self.starts}, {self.confirm_swarms}, {self.batch}"
            )
        if not isinstance(self.swarm, Swarm) or not isinstance(self.polish, Polish):
            raise TypeError("RefitPlan: swarm must be a vfjax.Swarm and polish a vfjax.Polish")
        if not self.box > 1:
            raise ValueError(f"RefitPlan: box must be a factor > 1, got {self.box}")
        c = self.confirm_iterations
        if c is not None and (isinstance(c, bool) or not isinstance(c, int) or c < 1):
            raise ValueError(
                f"RefitPlan: confirm_iterations must be a positive integer or None, got {c!r}"
            )

    def confirm_search(self, n_params: int) -> tuple[int, int]:
        """(swarms, iterations) of the confirming refit for a candidate of ``n_params``
        parameters."""
        extra = max(n_params - 1, 0)
        return self.confirm_swarms * 2**extra, int(round(self.confirm_iterations * (1 + extra / 4)))


#: The default criteria and refit plan.
DEFAULT_CRITERIA = Criteria()
DEFAULT_PLAN = RefitPlan()
