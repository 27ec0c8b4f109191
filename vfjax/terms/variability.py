"""Cycle-to-cycle variability: what makes real (and realistic synthetic) GAWs aperiodic.

Each term holds a random factor per time slot of about one glottal cycle (data, so that a
batch of simulations can draw its own factors each):

- `ClosureJitter`: each closure hold lasts t_c times its slot's factor (the variability of the
  synthetic recordings of ``shared/data/synthetic``);
- `StiffnessJitter`: the stiffness K times a factor varying continuously from slot to slot
  (the tension of the folds fluctuates: period jitter);
- `AmplitudeJitter`: the visible area times such a factor (amplitude jitter, shimmer);
- `TimingJitter`: each cycle seen a little early or late (period jitter without drift, and
  without touching the dynamics: a fit whose folds barely touch would otherwise switch its
  closures on and off at the slightest change of tension).

They have no fitted parameters: they make realistic test data, and the diagnosis simulates
its null recordings with them (`vfjax.diagnose`), since cycle-to-cycle variability is what
it must not mistake for a missing effect.
"""

from typing import ClassVar

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike

from .._validate import as_parameter, check_nonnegative, check_positive, finite, positive
from .base import AbstractForce, AbstractHoldVariability, AbstractObservation, Context


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
        return cls(_random_factors(relative_sd, period, duration, seed), float(period))

    def factor(self, t: ArrayLike) -> Array:
        k = jnp.clip(jnp.floor(t / self.slot).astype(jnp.int32), 0, self.factors.shape[0] - 1)
        return self.factors[k]


def _random_factors(relative_sd: float, period: float, duration: float, seed: int, n=None):
    """Independent factors 1 + relative_sd * N(0, 1), one per slot of ``period`` seconds over
    ``duration`` seconds (or ``n`` of them), kept above 0.05."""
    check_nonnegative("relative_sd (cycle-to-cycle variability)", relative_sd)
    factors = 1.0 + relative_sd * _standard_normal(period, duration, seed, n)
    return np.clip(factors, 0.05, None)


def _standard_normal(period: float, duration: float, seed: int, n=None) -> np.ndarray:
    """Seeded standard normal draws, one per slot of ``period`` seconds over ``duration``
    seconds (or ``n`` of them)."""
    check_positive("period", period, "s")
    n = int(np.ceil(duration / period)) + 1 if n is None else int(n)
    return np.random.default_rng(seed).standard_normal(n)


def _at_time(values, slot, t):
    """Per-slot ``values`` as a continuous function of time ``t`` (s): value k at the middle
    of slot k, linear in between, held at the first and last (the warm-up uses the first)."""
    centres = (jnp.arange(values.shape[0]) + 0.5) * slot
    return jnp.interp(t, centres, values)


class _SlotFactors(eqx.Module):
    """Per-slot random factors of a variability term, as data: a batch of simulations can
    draw its own factors and slot length and still share one compiled program."""

    factors: Array = eqx.field(converter=as_parameter)
    slot: Array = eqx.field(converter=as_parameter)

    def __check_init__(self):
        if jnp.ndim(self.factors) != 1 or jnp.ndim(self.slot) != 0:
            raise ValueError("factors must be a 1-D array (one factor per slot), slot a number")

    @classmethod
    def random(
        cls, relative_sd: float, period: float, duration: float = 0.2, seed: int = 0, n=None
    ):
        """Independent Gaussian factors 1 + relative_sd * N(0, 1) (kept above 0.05), one per
        slot of ``period`` seconds, covering ``duration`` seconds (or ``n`` slots), seeded."""
        return cls(_random_factors(relative_sd, period, duration, seed, n), float(period))

    def value(self, t):
        """The factor at time ``t`` (s), interpolated between slots (`_at_time`)."""
        return _at_time(self.factors, self.slot, t)


class StiffnessJitter(_SlotFactors, AbstractForce):
    """Cycle-to-cycle variability of the folds' tension: the stiffness is K times a factor
    g(t) that varies from one glottal cycle to the next, so that the period varies (jitter).
    Adds -K (g(t) - 1) x to the elastic force -K x; g interpolates the factors linearly
    between the middles of slots of about one period.

    Build one with `StiffnessJitter.random`. (The period is sensitive: on the N3 preset,
    factors of 2 % standard deviation give a local jitter of about 5 %.)

    Arguments:
        factors: the stiffness factor of each slot (dimensionless, > 0).
        slot: length of one slot (s), about one glottal period.
    """

    constraints: ClassVar = (
        positive("factors", "factors (stiffness factors)"),
        positive("slot", "slot (jitter slot length)", "s"),
    )

    def force(self, ctx: Context) -> Array:
        return -ctx.stiffness * (self.value(ctx.t) - 1.0) * ctx.x


class AmplitudeJitter(_SlotFactors, AbstractObservation):
    """Cycle-to-cycle variability of the visible amplitude (shimmer): the area the camera
    sees is multiplied by a factor g(t) that interpolates the factors linearly between the
    middles of slots of about one period. (In the single-mass model the amplitude barely
    follows the subglottal pressure, a 30 % higher P_s raising the N3 preset's peak area by
    about 1 %, so pressure fluctuations do not make shimmer.)

    Build one with `AmplitudeJitter.random`.

    Arguments:
        factors: the amplitude factor of each slot (dimensionless, > 0).
        slot: length of one slot (s), about one glottal period.
    """

    constraints: ClassVar = (
        positive("factors", "factors (amplitude factors)"),
        positive("slot", "slot (jitter slot length)", "s"),
    )

    def observe(self, t, area, displacement_at, length) -> Array:
        return area * self.value(t)


class TimingJitter(AbstractObservation):
    """Cycle-to-cycle timing jitter of the visible motion: the camera sees each cycle a
    little early or late, the area at time t being the one at t + delta(t), where delta(t)
    interpolates the offsets linearly between the middles of slots of about one period. The
    period of cycle k then differs from the model's by the difference of consecutive
    offsets, with no drift of the phase, and the dynamics (contact, closure) stay as they
    are. Area terms listed before it (a gap) are kept: it adds 2 l (x(t + delta) - x(t)).

    Build one with `TimingJitter.random`.

    Arguments:
        offsets: the time offset of each slot (s).
        slot: length of one slot (s), about one glottal period.
    """

    offsets: Array = eqx.field(converter=as_parameter)
    slot: Array = eqx.field(converter=as_parameter)
    needs_history: ClassVar[bool] = True

    constraints: ClassVar = (
        finite("offsets", "offsets (timing offsets)", "s"),
        positive("slot", "slot (jitter slot length)", "s"),
    )

    def __check_init__(self):
        if jnp.ndim(self.offsets) != 1 or jnp.ndim(self.slot) != 0:
            raise ValueError("offsets must be a 1-D array (one offset per slot), slot a number")

    @classmethod
    def random(cls, sd: float, period: float, duration: float = 0.2, seed: int = 0, n=None):
        """Independent Gaussian offsets of standard deviation ``sd`` (s), one per slot of
        ``period`` seconds covering ``duration`` seconds (or ``n`` slots), seeded."""
        check_nonnegative("sd (timing jitter)", sd, "s")
        return cls(sd * _standard_normal(period, duration, seed, n), float(period))

    def observe(self, t, area, displacement_at, length) -> Array:
        delta = _at_time(self.offsets, self.slot, t)
        return area + 2.0 * length * (displacement_at(t + delta) - displacement_at(t))
