"""Source-tract interaction: the inertance of the vocal tract loads the glottal flow.

The air column of a vocal tract of length L_vt (cm) and cross-section A_vt (cm²) has the
inertance I_t = rho L_vt / A_vt (g/cm⁴; about 0.007 for 17 cm and 3 cm², Titze 2008).
Accelerating the glottal flow Q (cm³/s) through it takes a supraglottal pressure
P_e = I_t dQ/dt (Rothenberg 1981), and the flow is driven by the transglottal drop P_s - P_e:

    I_t dQ/dt = P_s - D(Q, A),   D(Q, A) = k_e rho Q² / (2 A²) + 12 mu d l² Q / A³

(the paper's eq. 7 with the drop in place of P_s). `SourceTractInertance` holds the tract's
pressure P_e as its internal state. With Q = Q_qs(A, P_s - P_e), the paper's flow
Q_qs(A, P) = A u(A, P) at the drop, the equation is exactly

    dP_e/dt = (P_1 - P_e) / tau,   P_1 = I_t (dQ_qs/dA) dA/dt,   tau = I_t (dQ_qs/dP),

with dA/dt = 2 l v and both slopes at the drop P_s - P_e. (A subglottal pressure that varies
in time adds dP_s/dt to the rate, i.e. tau dP_s/dt to P_1, which is left out: about 0.001 P_s
for a 10 % modulation at 8 Hz, under 1 % of P_1.) P_e relaxes towards P_1, the pressure of
the quasi-steady flow's rate of change, within the flow's time constant tau: for I_t = 0.007,
0.12 ms (N1) to 0.24 ms (N3) at the presets' widest openings, 1.5-5 % of a period. Near
contact, where the viscous loss grows as 1 / A³, tau falls below a microsecond, beyond the
reach of an explicit RK4 step at camera rates; there the flow is slaved to the opening, and
the state relaxes at no more than 1 / `TAU_MIN` (50 us; P_1 vanishes there with the flow's
slope dQ/dA ~ A²).
While the glottis is closed there is no flow and P_e relaxes to 0 at that rate.

The wall pressures of eqs. 10-11 are measured from the subglottal and the supraglottal side,
P_g1 = P_s - k_in P_g and P_g2 = P_e - k_out P_g, with P_g the dynamic pressure of the drop
P_s - P_e, so the aerodynamic force is

    F_a = (P_g1 + P_g2) l d / 2 = F_a,paper(A, P_s - P_e) + P_e l d.

While the glottis opens (dA/dt > 0) the tract's pressure rises, the drop falls and the force
pushes the folds apart; while it closes the reverse: the inertive load feeds energy into the
oscillation, and it delays the flow behind the area, skewing the flow pulse to the right
(`vfjax.glottal_flow`). The sub-critical displacement x_c and the flow-separation force keep
the paper's quasi-steady definition (at P_s). At I_t = 0, P_1 = 0 and P_e stays 0: the model
is the paper's.
"""

from typing import ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike

from .._validate import as_parameter, nonnegative
from .base import AbstractStatefulForce, Context

#: The shortest relaxation time of the tract's pressure (s): where the flow's own time constant
#: is shorter (near contact), the flow is slaved to the opening and the state relaxes at
#: 1 / TAU_MIN, which an RK4 step of up to 125 us (4 steps a frame at 2 kHz) integrates stably.
TAU_MIN = 5e-5


class SourceTractInertance(AbstractStatefulForce):
    """An inertive vocal tract above the glottis: the supraglottal pressure P_e = I_t dQ/dt,
    held as an internal state (dyne/cm²), lowers the transglottal drop while the flow
    accelerates and raises it while the flow decelerates (the module's docstring states the
    model).

    Off at I_t = 0, where the model is the paper's.

    Arguments:
        I_t: the vocal tract's inertance rho L_vt / A_vt (g/cm⁴), >= 0; about 0.007 for an
            adult tract (17 cm, 3 cm²), several times more for a narrow epilarynx.
    """

    I_t: ArrayLike = eqx.field(default=0.0, converter=as_parameter)
    parameters: ClassVar = {"I_t": ("I_t", "g/cm⁴")}
    off_values: ClassVar = {"I_t": 0.0}
    one_sided: ClassVar = True
    ranges: ClassVar = {"I_t": (0.0, 0.02, 0.002)}

    constraints: ClassVar = (nonnegative("I_t", "I_t (vocal-tract inertance)", "g/cm⁴"),)

    #: The fastest relaxation rate of the state (1/s).
    max_rate: ClassVar[float] = 1.0 / TAU_MIN
    #: The inertive load feeds the oscillation, which grows from rest to a wider limit cycle
    #: over some 100 ms (N3 at one adult tract's I_t: within 2 % after 120 ms).
    min_warmup: ClassVar[float] = 0.15

    def initial_state(self) -> Array:
        return jnp.zeros(())

    def state_rate(self, ctx: Context, p_e: Array) -> Array:
        if ctx.aerodynamics is None:
            return -p_e / TAU_MIN
        drop = _drop(ctx, p_e)
        one = jnp.ones_like(drop)
        _, q_a = jax.jvp(lambda a: _flow(ctx, a, drop), (ctx.area,), (one,))
        _, q_p = jax.jvp(lambda p: _flow(ctx, ctx.area, p), (drop,), (one,))
        target = self.I_t * q_a * ctx.area_rate
        tau = jnp.maximum(self.I_t * q_p, TAU_MIN)
        return jnp.where(ctx.flow, (target - p_e) / tau, -p_e / TAU_MIN)

    def force(self, ctx: Context, p_e: Array) -> Array:
        aero = ctx.aerodynamics
        if aero is None:
            return jnp.zeros_like(jnp.asarray(ctx.x, dtype=float))
        loaded = aero.open_force(
            ctx.area,
            _drop(ctx, p_e),
            ctx.air_density,
            ctx.air_viscosity,
            ctx.thickness,
            ctx.length,
        )
        loaded = loaded + p_e * ctx.length * ctx.thickness
        return jnp.where(ctx.flow, loaded - ctx.aero_force, 0.0)

    def held_state(self, p_e: Array, duration: ArrayLike) -> Array:
        # no flow while the folds rest closed: P_e relaxes to 0
        return p_e * jnp.exp(-duration / TAU_MIN)


def flow_at(ctx: Context, p_e: ArrayLike = 0.0) -> Array:
    """The glottal flow Q (cm³/s) at the instant ``ctx`` (air flowing) with the tract's
    pressure ``p_e`` (dyne/cm²): the paper's flow (eq. 7) at the drop P_s - P_e."""
    return _flow(ctx, ctx.area, _drop(ctx, p_e))


def _flow(ctx: Context, area, drop):
    u = ctx.aerodynamics.particle_velocity(
        area, drop, ctx.air_density, ctx.air_viscosity, ctx.thickness, ctx.length
    )
    return area * u


def _drop(ctx: Context, p_e):
    """The transglottal drop P_s - P_e (dyne/cm²); a tract pressure above P_s drives none."""
    return jnp.maximum(ctx.pressure - p_e, 0.0)
