"""What a simulation returns: its dense output (nodes read by cubic Hermite interpolation)
and the frames sampled from it, and what is derived from them (each fold's displacement and
area, the glottal flow)."""

import dataclasses

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Bool, Float, Int

from .. import phases
from .._hermite import hermite, hermite_slope
from ..model import VocalFoldModel
from ..terms.base import AbstractFoldPair, AbstractStatefulTerm
from ..terms.paper import BernoulliForce
from ..terms.tract import SourceTractInertance, flow_at


class DenseOutput(eqx.Module):
    """The integrator's nodes: between two consecutive nodes the motion is smooth.

    Attributes:
        t: node times (s), non-decreasing.
        x: displacement at the nodes (cm).
        v: velocity at the nodes (cm/s).
        phase: phase code of the segment that starts at each node (see `vfjax.phases`).
        z: the stateful terms' internal states at the nodes, one pytree per term (leaves with
            a leading node axis; `VocalFoldModel.initial_state`'s layout); ``()`` without any.
    """

    t: Float[Array, " nodes"]
    x: Float[Array, " nodes"]
    v: Float[Array, " nodes"]
    phase: Int[Array, " nodes"]
    z: tuple = ()

    def _locate(self, times):
        n = self.t.shape[-1]
        j = jnp.clip(jnp.searchsorted(self.t, times, side="right") - 1, 0, n - 2)
        ta, tb = self.t[j], self.t[j + 1]
        span = tb - ta
        ok = span > 0
        theta = jnp.where(ok, (times - ta) / jnp.where(ok, span, 1.0), 1.0)
        return j, theta, span

    def displacement(self, times: ArrayLike) -> Array:
        """Displacement x (cm) at ``times`` (s); clamped to the first and last node."""
        times = jnp.clip(jnp.asarray(times, dtype=float), self.t[0], self.t[-1])
        j, theta, span = self._locate(times)
        return hermite(theta, self.x[j], self.v[j] * span, self.x[j + 1], self.v[j + 1] * span)

    def velocity(self, times: ArrayLike) -> Array:
        """Velocity v (cm/s) at ``times`` (s), the slope of the displacement interpolant."""
        times = jnp.clip(jnp.asarray(times, dtype=float), self.t[0], self.t[-1])
        j, theta, span = self._locate(times)
        ok = span > 0
        slope = hermite_slope(
            theta, self.x[j], self.v[j] * span, self.x[j + 1], self.v[j + 1] * span
        )
        return jnp.where(ok, slope / jnp.where(ok, span, 1.0), self.v[j + 1])

    def internal_state(self, times: ArrayLike) -> tuple:
        """The stateful terms' internal states at ``times`` (s), interpolated linearly between
        the nodes (one RK4 step or less apart); clamped to the first and last node."""
        times = jnp.clip(jnp.asarray(times, dtype=float), self.t[0], self.t[-1])
        j, theta, _ = self._locate(times)

        def read(z):
            w = jnp.reshape(theta, theta.shape + (1,) * (z.ndim - 1))
            return (1.0 - w) * z[j] + w * z[j + 1]

        return jax.tree.map(read, self.z)

    def phase_at(self, times: ArrayLike) -> Array:
        """Phase code at ``times`` (s): that of the segment containing each time."""
        j, _, _ = self._locate(jnp.asarray(times, dtype=float))
        return self.phase[j]


class Simulation(eqx.Module):
    """A simulated recording.

    Attributes:
        time: frame times (s).
        area: observed glottal area waveform, GAW (pixels); NaN after a divergence.
        glottal_area: model glottal area A_g = A_g0 + 2 l x (cm²), negative while the folds
            overlap.
        displacement: fold displacement x (cm) at the frames.
        velocity: fold velocity v (cm/s) at the frames.
        phase: phase code of each frame (0 opening, 1 open, 2 closing, 3 closed).
        diverged: the state left the physical range (|x| > 1 cm) or became non-finite.
        complete: the simulation succeeded: every frame computed (False when the event
            budget ran out, it diverged, or the parameters or time shift were invalid).
        n_events: number of located events (regime switches).
        result: how the simulation ended (`RESULTS`): successful, event budget exhausted,
            diverged, invalid parameters, time shift out of range.
        dense: the integrator's nodes, for reading the motion at any time.
    """

    time: Float[Array, " frames"]
    area: Float[Array, " frames"]
    glottal_area: Float[Array, " frames"]
    displacement: Float[Array, " frames"]
    velocity: Float[Array, " frames"]
    phase: Int[Array, " frames"]
    diverged: Bool[Array, ""]
    complete: Bool[Array, ""]
    n_events: Int[Array, ""]
    result: "RESULTS"
    dense: DenseOutput


def _folds_at(model: VocalFoldModel, dense: DenseOutput, times, x) -> tuple[Array, Array]:
    """(x_left, x_right) in cm at ``times`` (s) where the mean displacement is ``x``."""
    pair = model.term(AbstractFoldPair)
    if pair is None:
        return x, x
    slot = [t for t in model.terms if isinstance(t, AbstractStatefulTerm)].index(pair)
    nodes = dense.z[slot]
    j, theta, span = dense._locate(jnp.clip(times, dense.t[0], dense.t[-1]))

    def read(k):
        # component k with its rate, component k + 1 (the pair's states are (value, rate)
        # pairs), on the step's cubic Hermite interpolant
        y0, r0 = nodes[j, 2 * k], nodes[j, 2 * k + 1]
        y1, r1 = nodes[j + 1, 2 * k], nodes[j + 1, 2 * k + 1]
        return hermite(theta, y0, r0 * span, y1, r1 * span)

    state = jnp.stack([read(k) for k in range(nodes.shape[-1] // 2)], axis=-1)
    return pair.fold_displacements(x, state)


def left_share(model: VocalFoldModel, dense: DenseOutput, times, x) -> Array:
    """The left fold's share of the glottal opening at ``times`` (s), where the mean
    displacement is ``x`` (cm): the part of the opening between the left fold's edge and the
    glottal midline, ``clip(x_left - x_0, 0, w) / w`` with ``w = x_left + x_right - 2 x_0``;
    one half where the glottis is closed (and for a model of one symmetric fold)."""
    left, right = _folds_at(model, dense, times, x)
    x0 = model.contact_displacement
    width = (left - x0) + (right - x0)
    ok = width > 0
    safe = jnp.where(ok, width, 1.0)
    return jnp.where(ok, jnp.clip(left - x0, 0.0, safe) / safe, 0.5)


def fold_displacements(model: VocalFoldModel, simulation: Simulation) -> tuple[Array, Array]:
    """The left and right folds' displacements (cm) at the frames of ``simulation`` (a run
    of ``model``): from a fold pair's states (`vfjax.LeftRightAsymmetry`), read off their
    cubic Hermite interpolant between the integrator's nodes; both the displacement itself
    for a model of one symmetric fold."""
    return _folds_at(model, simulation.dense, simulation.time, simulation.displacement)


def simulated_fold_areas(model: VocalFoldModel, simulation: Simulation) -> tuple[Array, Array]:
    """The simulated left and right GAWs (pixels), split as a glottal midline splits a
    measured one (`vfjax.asymmetry.fold_areas`): each fold's share of the glottis is the
    part of the opening between its edge and the midline (`left_share`), so the two add up
    to the observed GAW (observation terms included). A fold past the midline leaves the
    whole opening to the other; closed, both are half of the (zero or negative)
    `Simulation.area`."""
    share = left_share(model, simulation.dense, simulation.time, simulation.displacement)
    area = simulation.area
    return area * share, area * (1.0 - share)


def glottal_flow(model: VocalFoldModel, simulation: Simulation, t_start: float = 0.0) -> Array:
    """The glottal volume flow Q (cm³/s) at the frames of ``simulation`` (a run of
    ``model``): the paper's Bernoulli flow with viscous loss (eq. 7) at the transglottal
    drop P_s - P_e, with P_e the supraglottal pressure of a `vfjax.SourceTractInertance`
    (its internal state; 0 without one); 0 while the folds are closed.

    Arguments:
        model: the simulated model (with a `BernoulliForce` term).
        simulation: its `Simulation`.
        t_start: the simulation's ``t_start`` (s), the time origin of pressure terms
            (`vfjax.PressureModulation`); frames of a fit: its ``sampling.warmup``.
    """
    if model.term(BernoulliForce) is None:
        raise ValueError("the model has no BernoulliForce term: it has no glottal flow")
    x, v = simulation.displacement, simulation.velocity
    area = model.subject.area(x)
    flow = (simulation.phase != phases.CLOSED) & (area > 0)
    xc = model.subcritical_displacement()
    ctx = model.context(simulation.time - t_start, x, v, flow, x <= xc, v < 0, xc)
    ctx = dataclasses.replace(ctx, area=jnp.where(flow, area, 0.0))
    p_e = 0.0
    stateful = [t for t in model.terms if isinstance(t, AbstractStatefulTerm)]
    for term, z in zip(stateful, simulation.dense.internal_state(simulation.time)):
        if isinstance(term, SourceTractInertance):
            p_e = z
    return jnp.where(flow, flow_at(ctx, p_e), 0.0)


class RESULTS(eqx.Enumeration):
    """How a simulation ended (`Simulation.result`); ``RESULTS[sim.result]`` gives the message.

    With ``throw=True`` (the default) `simulate` raises on anything but ``successful``."""

    successful = ""
    event_budget_exhausted = (
        "The integration used up its event budget before the last frame: the frames after "
        "it are NaN. Raise `max_events` (a vibration faster than ~570 Hz, or chattering "
        "contact)."
    )
    diverged = (
        "The state left the physical range (|x| > 1 cm or |v| > 1e5 cm/s) or became "
        "non-finite: the frames after it are NaN. A mass or stiffness too extreme for the "
        "step (raise `substeps`), or an unstable model."
    )
    invalid_parameters = (
        "A parameter is outside its admissible range (NaN, K <= 0, M <= 0, S <= 0, t_c < 0, "
        "A_g0 <= 0, ...; `VocalFoldModel.check` names it), or the initial state is not "
        "finite: every frame is NaN."
    )
    time_shift_out_of_range = (
        "time_shift is outside [-t_start, max_time_shift]: the shifted frames would leave "
        "the integrated interval. Raise `max_time_shift`."
    )


class SimulationError(RuntimeError):
    """A simulation that did not succeed, raised by `simulate` with ``throw=True`` outside
    jit (inside jit: an `equinox` runtime error with the same message)."""


_FAILURES = ("invalid_parameters", "time_shift_out_of_range", "diverged", "event_budget_exhausted")


def result_message(result: RESULTS) -> str:
    """The message of a (possibly batched) `RESULTS` value: each failure that occurs, once."""
    found = [
        RESULTS[getattr(RESULTS, name)]
        for name in _FAILURES
        if bool(jnp.any(result == getattr(RESULTS, name)))
    ]
    return " ".join(found) if found else "successful"
