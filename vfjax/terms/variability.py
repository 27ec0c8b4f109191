"""Cycle-to-cycle variability: what makes real (and realistic synthetic) GAWs aperiodic.

- `ClosureJitter`: each closure hold lasts t_c times a random factor drawn per time slot
  (about one glottal cycle), as in the synthetic recordings of ``shared/data/synthetic``
  ("cycle-to-cycle jitter of the closure duration"). It has no fitted parameters: it makes
  test data, and it is the variability the diagnosis must not mistake for a missing effect.
"""

from typing import ClassVar

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike

from .._validate import as_parameter, check_nonnegative, check_positive, positive
from .base import AbstractHoldVariability


class ClosureJitter(AbstractHoldVariability):
    """Closure durations that vary from cycle to cycle.

    A hold starting at time t (s from the start of sampling, `vfjax.simulate`'s ``t_start``)
    lasts t_c * factors[k], k = floor(t / slot), clipped to the table (holds of the warm-up
    use factors[0]).
    Build one with `ClosureJitter.random`.

    Arguments:
        factors: the factor of each slot (dimensionless, > 0).
        slot: length of one slot (s), about one glottal period.
    """

    factors: Array = eqx.field(converter=as_parameter)
    slot: float = eqx.field(static=True)

    constraints: ClassVar = (positive("factors", "factors (closure-duration factors)"),)

    def __check_init__(self):
        check_positive("slot (jitter slot length)", self.slot, "s")
        if jnp.ndim(self.factors) != 1:
            raise ValueError("factors must be a 1-D array (one factor per slot)")

    @classmethod
    def random(cls, relative_sd: float, period: float, duration: float = 0.2, seed: int = 0):
        """Independent Gaussian factors 1 + relative_sd * N(0, 1) per slot of ``period``
        seconds, covering ``duration`` seconds (seeded)."""
        check_nonnegative("relative_sd (closure jitter)", relative_sd)
        check_positive("period", period, "s")
        n = int(np.ceil(duration / period)) + 1
        factors = 1.0 + relative_sd * np.random.default_rng(seed).standard_normal(n)
        return cls(factors=np.clip(factors, 0.05, None), slot=float(period))

    def factor(self, t: ArrayLike) -> Array:
        k = jnp.clip(jnp.floor(t / self.slot).astype(jnp.int32), 0, self.factors.shape[0] - 1)
        return self.factors[k]
