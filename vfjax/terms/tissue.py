"""Power-law (fractional) viscoelastic tissue: the seed paper's own next step.

Soft tissue relaxes with a power law rather than a single time constant. The fractional
Kelvin-Voigt force adds, to the paper's spring and damper,

    F_pl = -eta_pl D^alpha x,
    D^alpha x(t) = 1 / Gamma(1 - alpha) int_0^t (t - s)^(-alpha) v(s) ds

(the Caputo derivative of order 0 < alpha < 1 from the start of the simulation at t = 0), which
lies between a spring (alpha -> 0: D^0 x = x - x(0)) and a damper (alpha -> 1: D^1 x = v).
eta_pl is in dyne s^alpha / cm.

Evaluated directly, the derivative needs the whole history at every step. Its kernel is a
superposition of exponentials,

    (t - s)^(-alpha) / Gamma(1 - alpha)
        = sin(pi alpha) / pi  int_0^inf lambda^(alpha - 1) e^(-lambda (t - s)) d lambda,

so with relaxation modes q_k(t) = int_0^t e^(-lambda_k (t - s)) v(s) ds, which obey the ODE
dq_k/dt = v - lambda_k q_k, the derivative is a weighted sum D^alpha x ~ sum_k w_k q_k + c v.
`PowerLawTissue` takes the rates lambda_k at the midpoints of a uniform grid in log lambda from
0.1 to 2e4 1/s (relaxation times from 50 us to 10 s), with the weights of the midpoint rule;
the slower rates (longer than any recording) are one mode at lambda = 0 (q = x - x(0)), the
faster ones a viscous term c v (their modes follow v quasi-statically). The weights are
closed-form in alpha, so alpha is differentiable and fitted like any parameter. Against the
exact power law, the frequency response is within 1 % from 20 to 300 Hz and 4 % at 1 kHz, and
the response to a ramp within 1 % from 0.1 ms to 1 s (for alpha in [0.1, 0.9]); the test suite
checks the simulated force against a Grünwald-Letnikov evaluation of the simulated motion.
"""

import math
from typing import ClassVar

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike

from .._validate import Constraint, as_parameter, nonnegative
from .base import AbstractStatefulForce, Context

#: The relaxation-mode grid: rates (1/s) from `_SLOWEST` to `_FASTEST`, `_PER_E_FOLD` modes per
#: factor e. RK4 integrates a mode of rate lambda stably for lambda h < 2.78: the fastest mode
#: (1.2e4 1/s) needs a step below 2.3e-4 s (`PowerLawTissue.max_rate`; `vfjax.simulate`
#: refuses a coarser step).
_SLOWEST, _FASTEST, _PER_E_FOLD = 0.1, 2.0e4, 1.0


def _grid() -> tuple[np.ndarray, float]:
    lo, hi = math.log(_SLOWEST), math.log(_FASTEST)
    n = math.ceil((hi - lo) * _PER_E_FOLD)
    du = (hi - lo) / n
    return lo + (np.arange(n) + 0.5) * du, du


class PowerLawTissue(AbstractStatefulForce):
    """Power-law viscoelastic tissue: a fractional Kelvin-Voigt force F = -eta_pl D^alpha x.

    Holds its relaxation modes as internal states (see the module's docstring for the
    approximation and its accuracy). Off at eta_pl = 0, where the model is the paper's.

    Arguments:
        eta_pl: power-law damping coefficient (dyne s^alpha / cm), >= 0.
        alpha_pl: order alpha of the derivative (dimensionless), in (0, 1): 0 a spring,
            1 a damper.
    """

    eta_pl: ArrayLike = eqx.field(default=0.0, converter=as_parameter)
    alpha_pl: ArrayLike = eqx.field(default=0.5, converter=as_parameter)

    parameters: ClassVar = {
        "eta_pl": ("eta_pl", "dyne s^alpha/cm"),
        "alpha_pl": ("alpha_pl", "1"),
    }
    constraints: ClassVar = (
        nonnegative("eta_pl", "eta_pl (power-law damping)", "dyne s^alpha/cm"),
        Constraint("alpha_pl", "alpha_pl (power-law order)", 0.0, 1.0, closed_low=False),
    )
    off_values: ClassVar = {"eta_pl": 0.0}
    one_sided: ClassVar = True
    score_grid: ClassVar = tuple({"alpha_pl": a} for a in (0.25, 0.5, 0.75))
    ranges: ClassVar = {"eta_pl": (0.0, 400.0, 40.0), "alpha_pl": (0.05, 0.95, 0.2)}

    #: The fastest relaxation rate (1/s): RK4 steps must satisfy max_rate * h < 2.78.
    max_rate: ClassVar[float] = float(math.exp(_grid()[0][-1]))

    @staticmethod
    def rates() -> Array:
        """The relaxation rates lambda_k (1/s) of the modes, the slow-tail mode (0) first."""
        u, _ = _grid()
        return jnp.asarray(np.concatenate([[0.0], np.exp(u)]))

    def weights(self) -> tuple[Array, Array]:
        """The modes' weights w_k (1/s^alpha), the slow-tail mode's first, and the viscous
        coefficient c of the faster rates (s^(1 - alpha)): D^alpha x = sum_k w_k q_k + c v."""
        u, du = _grid()
        a = self.alpha_pl
        # where alpha is outside (0, 1) the model is invalid (`constraints`); a safe order
        # keeps the weights and their derivatives finite there
        ok = (a > 0.0) & (a < 1.0)
        a = jnp.where(ok, a, 0.5)
        s = jnp.sin(jnp.pi * a) / jnp.pi
        slow = s * _SLOWEST**a / a
        modes = s * jnp.exp(a * jnp.asarray(u)) * du
        fast = s * _FASTEST ** (a - 1.0) / (1.0 - a)
        return jnp.concatenate([slow[None], modes]), fast

    def derivative(self, v: ArrayLike, state: Array) -> Array:
        """D^alpha x (cm / s^alpha) from the velocity ``v`` (cm/s) and the modes ``state``
        (cm; the last axis holds the modes)."""
        w, c = self.weights()
        return jnp.sum(w * state, axis=-1) + c * v

    def initial_state(self) -> Array:
        return jnp.zeros(self.rates().shape)

    def state_rate(self, ctx: Context, state: Array) -> Array:
        return ctx.v - self.rates() * state

    def force(self, ctx: Context, state: Array) -> Array:
        return -self.eta_pl * self.derivative(ctx.v, state)

    def held_state(self, state: Array, duration: ArrayLike) -> Array:
        # at rest (v = 0) each mode relaxes exactly: q_k e^(-lambda_k duration)
        return state * jnp.exp(-self.rates() * duration)


def grunwald_letnikov(x: ArrayLike, dt: float, alpha: float) -> np.ndarray:
    """The Grünwald-Letnikov derivative of order ``alpha`` of samples ``x`` taken every ``dt``
    seconds from time 0, applied to x - x[0] (so that it equals the Caputo derivative from
    time 0): a direct sum over the whole history, first-order accurate in ``dt``.

    Arguments:
        x: the samples (any unit u), shape (n,).
        dt: sampling interval (s).
        alpha: order of the derivative, in (0, 1).

    Returns:
        The derivative at every sample (u / s^alpha), shape (n,).
    """
    y = np.asarray(x, dtype=float) - float(np.asarray(x)[0])
    n = y.shape[0]
    # the weights (-1)^k binomial(alpha, k), by their recurrence
    ratios = (np.arange(1, n) - 1.0 - alpha) / np.arange(1, n)
    g = np.concatenate([[1.0], np.cumprod(ratios)])
    return np.convolve(g, y)[:n] / dt**alpha
