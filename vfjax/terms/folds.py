"""Left-right asymmetry: two folds of different tension, coupled through the shared glottis.

Steinecke and Herzel's asymmetry parameter Q (1995), on the paper's single mass: the left
fold has the subject's mass M and the model's stiffness K, the right fold mass M / Q and
stiffness Q K, so that the right fold's natural frequency is Q times the left's. Each fold
obeys the paper's equation of motion,

    M       d²x_l/dt² = F(x_l, v_l)
    (M / Q) d²x_r/dt² = F(x_r, v_r) - (Q - 1) K x_r

where F(x, v) is the force of the model's force terms on a fold at displacement x and
velocity v (the spring -K x, the damping with its displacement-dependent coefficient, the
flow separation's share of the effective length), and both folds feel the same aerodynamic
force: the glottal area ``A = A_g0 + l (x_l + x_r)`` sets the flow, and the contact and the
closure hold start where A reaches 0 (`MODEL_SPEC.md`). The regimes (flow, inside x_c,
closing) are the glottis's, decided by the folds' mean displacement.

The integrator's displacement is the mean x = (x_l + x_r) / 2 (every event is located on it,
as in the paper's model); the term's internal states are the half difference
d = (x_l - x_r) / 2 (cm) and its rate w (cm/s):

    d²x/dt² = (a_l + a_r) / 2,   dd/dt = w,   dw/dt = (a_l - a_r) / 2,

with x_l = x + d, x_r = x - d. The folds start together (d = w = 0). At Q = 1 both folds
feel the same force, d stays 0 and the motion is the paper's, bit for bit. During a closure
hold both folds rest: d keeps its value, w is 0 at the release. Stateful forces (power-law
tissue, ...) act on the mean, as on the paper's fold.
"""

from typing import ClassVar

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike

from .._validate import as_parameter, positive
from .base import AbstractFoldPair, Context


class LeftRightAsymmetry(AbstractFoldPair):
    """A left and a right fold: the right one with mass M / Q and stiffness Q K.

    Off at Q = 1, where the model is the paper's. Q > 1: the right fold is the stiffer and
    lighter, it vibrates faster and with a smaller amplitude; Q < 1 the reverse.

    Arguments:
        Q: asymmetry ratio (dimensionless, > 0): the right fold's natural frequency over the
            left's.
    """

    Q: ArrayLike = eqx.field(default=1.0, converter=as_parameter)

    parameters: ClassVar = {"Q": ("Q", "1")}
    constraints: ClassVar = (positive("Q", "Q (left-right asymmetry)"),)
    off_values: ClassVar = {"Q": 1.0}

    def initial_state(self) -> Array:
        # (d, w): half the folds' difference (cm) and its rate (cm/s)
        return jnp.zeros(2)

    def fold_rates(self, ctx: Context, state: Array, force) -> tuple[Array, Array]:
        d, w = state[..., 0], state[..., 1]
        x_right = ctx.x - d
        f_left = force(ctx.x + d, ctx.v + w)
        f_right = force(x_right, ctx.v - w) - (self.Q - 1.0) * ctx.stiffness * x_right
        a_left = f_left / ctx.mass
        a_right = self.Q * f_right / ctx.mass
        rate = jnp.stack([w, 0.5 * (a_left - a_right)], axis=-1)
        return 0.5 * (a_left + a_right), rate

    def fold_displacements(self, x: ArrayLike, state: Array) -> tuple[Array, Array]:
        d = state[..., 0]
        return x + d, x - d

    def held_state(self, state: Array, duration: ArrayLike) -> Array:
        # the folds rest in contact: the difference stays, its rate is 0 at the release
        return state * jnp.asarray([1.0, 0.0])
