"""What a cohort run does to each recording, as one object."""

import equinox as eqx

from .._diagnosis._options import (
    DEFAULT_CALIBRATION,
    DEFAULT_CRITERIA,
    DEFAULT_PLAN,
    Calibration,
    Criteria,
    RefitPlan,
    check_reachable,
)
from .._fit import FIRST_FIT_RESTARTS, Swarm
from .._fit._engine import DEFAULT_SWARM


class CohortOptions(eqx.Module):
    """The settings of `vfjax.cohort`: each recording gets the first fit of
    `vfjax.fit_recordings` and, with ``diagnose``, the rounds of `vfjax.investigate` from
    that fit, as ``vfjax diagnose`` does for one recording.

    Attributes:
        diagnose: diagnose and extend each fit (`vfjax.investigate`); False: first fits
            only.
        rounds: most effects added per recording.
        restarts: independent searches of each first fit.
        swarm: the first fits' swarm; each extension runs as many iterations.
        candidates: the candidate effects (term classes or instances; default: the
            catalogue), see `vfjax.diagnose`.
        criteria: when an effect is needed (`vfjax.Criteria`).
        plan: the diagnoses' refits (`vfjax.RefitPlan`).
        calibration: the diagnoses' null recordings (`vfjax.Calibration`).
        batch: most recordings fitted together in one batched job (recordings of one length
            bucket and one set of free parameters share a batch).
        seed: seed of the first fits' random draws: every recording draws as
            ``vfjax.fit_recording(..., key=jax.random.key(seed))`` of it alone would.
    """

    diagnose: bool = True
    rounds: int = eqx.field(default=2, converter=int)
    restarts: int = eqx.field(default=FIRST_FIT_RESTARTS, converter=int)
    swarm: Swarm = DEFAULT_SWARM
    candidates: tuple | None = eqx.field(
        default=None, converter=lambda c: None if c is None else tuple(c)
    )
    criteria: Criteria = DEFAULT_CRITERIA
    plan: RefitPlan = DEFAULT_PLAN
    calibration: Calibration = DEFAULT_CALIBRATION
    batch: int = eqx.field(default=16, converter=int)
    seed: int = eqx.field(default=0, converter=int)

    def __check_init__(self):
        if self.rounds < 1 or self.restarts < 1 or self.batch < 1:
            raise ValueError(
                "CohortOptions: rounds, restarts and batch must be >= 1, got "
                f"rounds={self.rounds}, restarts={self.restarts}, batch={self.batch}"
            )
        for name, kind in (
            ("swarm", Swarm),
            ("criteria", Criteria),
            ("plan", RefitPlan),
            ("calibration", Calibration),
        ):
            if not isinstance(getattr(self, name), kind):
                raise TypeError(
                    f"CohortOptions: {name} must be a vfjax.{kind.__name__}, got "
                    f"{type(getattr(self, name)).__name__}"
                )
        if self.candidates == ():
            raise ValueError("CohortOptions: candidates is empty (None: the catalogue)")
        if self.diagnose:
            check_reachable(self.criteria.alpha, self.calibration)


#: The default `CohortOptions`.
DEFAULT_OPTIONS = CohortOptions()
