"""The five terms of the seed paper's single-mass model (CGS units throughout)."""

from typing import ClassVar

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike

from .._validate import as_parameter, finite, nonnegative, positive
from ..descriptors import estimate_closure_duration
from .base import AbstractForce, AbstractTerm, Context


class Elastic(AbstractForce):
    """Linear spring, F_e = -K x (eq. 1).

    Arguments:
        K: stiffness (dyne/cm). The paper's Table 4 gives N/m: use `Elastic.from_n_per_m`.
    """

    K: ArrayLike = eqx.field(converter=as_parameter)
    parameters: ClassVar = {"K": ("K", "dyne/cm")}

    constraints: ClassVar = (positive("K", "K (stiffness)", "dyne/cm"),)

    @classmethod
    def from_n_per_m(cls, K_n_per_m: float) -> "Elastic":
        """Build from a stiffness in N/m (the paper's unit); stored in dyne/cm."""
        return cls(K=K_n_per_m * 1000.0)

    def force(self, ctx: Context) -> Array:
        return -self.K * ctx.x


class TanhDamping(AbstractForce):
    """Displacement-dependent damping, F_d = -C v (eqs. 2, 24).

    ``C = C_min + C_f tanh((x_c - x) / length_scale)`` inside the sub-critical displacement
    (x <= x_c), else ``C_min``. `MODEL_SPEC.md` settles the tanh argument as the displacement in
    cm, i.e. ``length_scale = 1 cm``: the reading under which the paper's Table 4 reproduces.

    Arguments:
        C_f: damping amplification factor (g/s).
        C_min: minimum damping coefficient (g/s); 0 in the paper.
        length_scale: displacement scale of the tanh (cm), a static constant.
    """

    C_f: ArrayLike = eqx.field(converter=as_parameter)
    C_min: ArrayLike = eqx.field(default=0.0, converter=as_parameter)
    length_scale: float = eqx.field(default=1.0, static=True)
    parameters: ClassVar = {"C_f": ("C_f", "g/s"), "C_min": ("C_min", "g/s")}

    constraints: ClassVar = (
        nonnegative("C_f", "C_f (damping amplification)", "g/s"),
        nonnegative("C_min", "C_min (minimum damping)", "g/s"),
    )

    def __check_init__(self):
        if not self.length_scale > 0:
            raise ValueError(f"length_scale must be > 0 cm, got {self.length_scale}")

    def coefficient(self, ctx: Context) -> Array:
        """The damping coefficient C (g/s)."""
        ramp = self.C_f * jnp.tanh((ctx.xc - ctx.x) / self.length_scale)
        return self.C_min + jnp.where(ctx.inner, ramp, 0.0)

    def force(self, ctx: Context) -> Array:
        return -self.coefficient(ctx) * ctx.v


class BernoulliForce(AbstractForce):
    """Aerodynamic force of a Bernoulli flow with viscous loss (eqs. 6-11).

    The flow rate solves ``k_e rho Q² / (2 A²) + 12 mu d l² Q / A³ = P`` (eq. 7). With the
    particle velocity ``u = Q / A`` its positive root is written in the cancellation-free form
    ``u = 2 P A² / (c + sqrt(c² + 2 k_e rho P A⁴))``, ``c = 12 mu d l²``, which is smooth for every
    A (including A <= 0, where the integrator only ever uses it as the smooth continuation of
    the open-glottis field up to a located contact event). Then ``P_g = rho u² / 2``,
    ``P_g1 = P - k_in P_g``, ``P_g2 = -k_out P_g`` and ``F_a = (P_g1 + P_g2) l d / 2`` while air
    flows (x > x_0), else 0.

    Arguments:
        entrance_loss: k_e, the 0.875 of eq. 7 (dimensionless).
        inlet_coefficient: k_in, the 1.37 of eq. 10 (dimensionless).
        outlet_coefficient: k_out, the 1/2 of eq. 11 (dimensionless).
        separation_force: F_s.a., the aerodynamic force that defines x_c (dyne); 0 in Table 2.
    """

    entrance_loss: ArrayLike = eqx.field(default=0.875, converter=as_parameter)
    inlet_coefficient: ArrayLike = eqx.field(default=1.37, converter=as_parameter)
    outlet_coefficient: ArrayLike = eqx.field(default=0.5, converter=as_parameter)
    separation_force: ArrayLike = eqx.field(default=0.0, converter=as_parameter)
    parameters: ClassVar = {"F_sa": ("separation_force", "dyne")}

    constraints: ClassVar = (
        positive("entrance_loss", "entrance_loss"),
        positive("inlet_coefficient", "inlet_coefficient"),
        finite("outlet_coefficient", "outlet_coefficient"),
        finite("separation_force", "F_sa (separation_force)", "dyne"),
    )

    def particle_velocity(self, area, pressure, rho, mu, thickness, length):
        """Mean air velocity u = Q / A in the glottis (cm/s) for area ``area`` (cm²)."""
        c = 12.0 * mu * thickness * length**2
        a2 = area * area
        root = jnp.sqrt(c * c + 2.0 * self.entrance_loss * rho * pressure * a2 * a2)
        return 2.0 * pressure * a2 / (c + root)

    def open_force(self, area, pressure, rho, mu, thickness, length):
        """F_a (dyne) for an open glottis of area ``area`` (cm²) at pressure ``pressure``."""
        u = self.particle_velocity(area, pressure, rho, mu, thickness, length)
        dynamic = 0.5 * rho * u * u
        mean_wall_pressure = pressure - (self.inlet_coefficient + self.outlet_coefficient) * dynamic
        return 0.5 * mean_wall_pressure * length * thickness

    def subcritical_area(self, pressure, rho, mu, thickness, length):
        """Area (cm²) at which F_a equals F_s.a., in closed form (requires it to exist)."""
        c = 12.0 * mu * thickness * length**2
        k = self.inlet_coefficient + self.outlet_coefficient
        dynamic = (pressure - 2.0 * self.separation_force / (length * thickness)) / k
        u = jnp.sqrt(2.0 * dynamic / rho)
        return jnp.sqrt(c * u / (pressure - 0.5 * self.entrance_loss * rho * u * u))

    def force(self, ctx: Context) -> Array:
        return ctx.aero_force


class FlowSeparation(AbstractForce):
    """The paper's flow-separation force in the closing phase (eqs. 12-13).

    While closing inside x_c (x_0 < x <= x_c, v < 0) the aerodynamic force acts only on the
    shrinking effective length, which adds ``F_f.s. = -F_a (x - x_c) / (x_0 - x_c)``.

    Arguments:
        fs_strength: scale of the force: 1 is the paper's, 0 switches it off in place (the
            diagnosis's off-value); or remove the term.
    """

    fs_strength: ArrayLike = eqx.field(default=1.0, converter=as_parameter)
    parameters: ClassVar = {"fs_strength": ("fs_strength", "1")}
    off_values: ClassVar = {"fs_strength": 0.0}
    one_sided: ClassVar = True

    constraints: ClassVar = (nonnegative("fs_strength", "fs_strength (flow-separation strength)"),)

    def force(self, ctx: Context) -> Array:
        share = (ctx.x - ctx.xc) / (ctx.x0 - ctx.xc)
        active = ctx.flow & ctx.inner & ctx.closing
        return jnp.where(active, -self.fs_strength * ctx.aero_force * share, 0.0)


class ClosureHold(AbstractTerm):
    """The closure hold (eqs. 14-17, 22 read consistently, as in `MODEL_SPEC.md`).

    Once the folds are in contact (x <= x_0) and their velocity reaches zero (maximum
    compression), the contact force cancels the elastic force and the folds rest for the
    closure duration; then it is removed and the elastic force reopens the glottis. The
    integrator locates the start and the release in time, so both carry derivatives.

    Arguments:
        t_c: closure duration (s).
    """

    t_c: ArrayLike = eqx.field(converter=as_parameter)
    parameters: ClassVar = {"t_c": ("t_c", "s")}
    #: a hold of zero length leaves the motion unchanged: the hold's off-value
    off_values: ClassVar = {"t_c": 0.0}
    one_sided: ClassVar = True

    @classmethod
    def guess(cls, recording) -> dict[str, float]:
        """t_c: the closed-phase duration measured on the GAW."""
        t_c = estimate_closure_duration(recording)
        return {} if t_c is None else {"t_c": t_c}

    constraints: ClassVar = (nonnegative("t_c", "t_c (closure duration)", "s"),)
