"""Candidate effects that the paper's model lacks (MODEL_SPEC.md's catalogue).

Each is one term with its own parameters and the values that switch it off (``off_values``),
so that it can sit in a model at its off-value (for a score test) or be fitted.

- `GlottalGap`: observed area += a_gap (cm²), a posterior gap in parallel with no aerodynamic
  effect; off at a_gap = 0.
- `CubicStiffness`: F_e = -K (x + eta x³), eta in 1/cm²; off at eta = 0.
- `PressureModulation`: P_s(t) = P_s (1 + a sin(2 pi f_m t + phi)), x_c kept at the mean
  P_s; off at a = 0.
- `MucosalDelay`: the visible area uses min(x(t), x(t - tau)), forces use x(t); off at tau = 0.
"""

import math
from collections.abc import Callable
from typing import ClassVar

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike

from .._validate import as_parameter, finite, in_range, nonnegative
from .base import AbstractForce, AbstractObservation, AbstractPressure, Context


class GlottalGap(AbstractObservation):
    """A gap in parallel with the vibrating glottis (e.g. posterior), seen by the camera
    but not changing the folds' aerodynamics: observed area += a_gap.

    Arguments:
        a_gap: gap area (cm²), >= 0.
    """

    a_gap: ArrayLike = eqx.field(default=0.0, converter=as_parameter)
    parameters: ClassVar = {"a_gap": ("a_gap", "cm²")}
    off_values: ClassVar = {"a_gap": 0.0}
    one_sided: ClassVar = True

    constraints: ClassVar = (nonnegative("a_gap", "a_gap (glottal gap area)", "cm²"),)

    def observe(self, t, area, displacement_at, length) -> Array:
        return area + self.a_gap


class CubicStiffness(AbstractForce):
    """A stiffening spring: adds -K eta x³ to the elastic force (K from the `Elastic` term).

    Arguments:
        eta: cubic stiffness coefficient (1/cm²).
    """

    eta: ArrayLike = eqx.field(default=0.0, converter=as_parameter)
    parameters: ClassVar = {"eta": ("eta", "1/cm²")}
    off_values: ClassVar = {"eta": 0.0}

    constraints: ClassVar = (finite("eta", "eta (cubic stiffness)", "1/cm²"),)

    def force(self, ctx: Context) -> Array:
        return -ctx.stiffness * self.eta * ctx.x**3


class PressureModulation(AbstractPressure):
    """A slow modulation of the subglottal pressure (tremor, breathing):
    P_s(t) = P_s (1 + a sin(2 pi f_m t + phi)). The sub-critical displacement x_c stays at its
    value for the mean pressure.

    Arguments:
        a_pm: relative modulation depth a, in [0, 1).
        f_m: modulation frequency (Hz).
        phi: modulation phase at the start of sampling (rad; `vfjax.simulate`'s ``t_start``,
            the end of a fit's warm-up). A fit's frames start ``time_shift`` later: the
            phase at the recording's first frame is phi + 2 pi f_m time_shift.
    """

    a_pm: ArrayLike = eqx.field(default=0.0, converter=as_parameter)
    f_m: ArrayLike = eqx.field(default=5.0, converter=as_parameter)
    phi: ArrayLike = eqx.field(default=0.0, converter=as_parameter)
    parameters: ClassVar = {"a_pm": ("a_pm", "1"), "f_m": ("f_m", "Hz"), "phi": ("phi", "rad")}
    off_values: ClassVar = {"a_pm": 0.0}
    # f_m and phi do not exist at a = 0: the score test searches f_m on a grid and tests the
    # sine and cosine phases together (2 degrees of freedom)
    score_grid: ClassVar = tuple({"f_m": float(f)} for f in range(2, 21))
    score_directions: ClassVar = ({"phi": 0.0}, {"phi": 0.5 * math.pi})
    # the vibration's amplitude and closed-phase level follow the pressure with a lag (the
    # limit cycle attracts slowly), so the state at the first frame carries the modulation's
    # history. On syn_tremor (N2-like, a = 0.06, 7 Hz) the true model fits to the noise
    # floor from warm-ups of 0.1, 0.2 and 0.25 s (NMSE 4.7e-5 to 4.8e-5), but only to
    # 9.9e-2 from 20 ms
    min_warmup: ClassVar = 0.1

    constraints: ClassVar = (
        in_range("a_pm", "a_pm (modulation depth)", 0.0, 1.0),
        nonnegative("f_m", "f_m (modulation frequency)", "Hz"),
        finite("phi", "phi (modulation phase)", "rad"),
    )

    def pressure(self, t, mean_pressure) -> Array:
        return mean_pressure * (1.0 + self.a_pm * jnp.sin(2.0 * jnp.pi * self.f_m * t + self.phi))


class MucosalDelay(AbstractObservation):
    """The upper margin of the folds follows the lower one with a delay: the camera, looking
    from above, sees the narrower of the two, min(x(t), x(t - tau)). Forces use x(t).

    Arguments:
        tau: delay of the upper margin (s), >= 0.
    """

    tau: ArrayLike = eqx.field(default=0.0, converter=as_parameter)
    parameters: ClassVar = {"tau": ("tau", "s")}
    off_values: ClassVar = {"tau": 0.0}
    one_sided: ClassVar = True
    # min(x(t), x(t - tau)) is not differentiable at tau = 0: take the one-sided derivative
    score_point: ClassVar = {"tau": 1e-9}
    needs_history: ClassVar[bool] = True

    constraints: ClassVar = (nonnegative("tau", "tau (mucosal delay)", "s"),)

    def observe(self, t, area, displacement_at: Callable, length) -> Array:
        now = displacement_at(t)
        upper = displacement_at(t - self.tau)
        return area + 2.0 * length * (jnp.minimum(now, upper) - now)


#: The catalogue of MODEL_SPEC.md, with the paper's own two terms found in `paper.py`.
CATALOGUE = (GlottalGap, CubicStiffness, PressureModulation, MucosalDelay)
