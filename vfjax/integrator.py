"""The integrator: RK4 in a `lax.scan`, with located events, sampled at the camera rate.

Why events are located. The model switches between regimes (air flows or not, inside x_c or
not, closing or opening, held closed or free). A fixed-step scan that switches with
`jnp.where` masks evaluated at the RK4 stages has a zero derivative through every switch, so the
sensitivity of the switching *times* to the parameters is lost (`MODEL_SPEC.md`, "the trap").

How. Each scan iteration advances from the current time towards the next point of a uniform
step grid with the regime flags frozen (the vector field is then smooth). If a flag's
switching function changes sign over the trial step, the crossing is located on the step's
cubic Hermite interpolant, the iteration stops there (the state moves onto the switching
surface), the flag flips, and the next iteration continues from the event. The event time
comes from a Newton step on live values, so it carries its derivative (implicit function
theorem), and so does everything after it. The closure hold freezes the state for t_c from a
located start, so one iteration takes it to its release, whose time is differentiable too.

The state is the displacement and velocity plus the internal states of any stateful term
(`vfjax.AbstractStatefulForce`: relaxation modes, ...), stepped by the same RK4 and read off
their own Hermite cubics at an event. The result is a list of nodes (time, displacement,
velocity, internal states) with smooth dynamics between consecutive nodes. Frames are read
off this dense output by cubic Hermite interpolation at the camera times, so they too are
differentiable in every parameter and in the sampling time.

The iterations run in a loop that stops once every member of a batch has reached the last
frame (a member that finishes early idles). Its length is bounded by the steps on the grid plus
a budget for events; a recording that is held closed for half of each cycle needs about half
of that. A while loop has no reverse mode, so derivatives (forward and reverse) are taken
through a `lax.scan` of the bound's length that computes the same values.
"""

import dataclasses
import functools
import math
from typing import NamedTuple

import equinox as eqx
import equinox.internal as eqxi
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Bool, Float, Int

from . import phases
from ._hermite import hermite, hermite_root, hermite_slope
from ._sampling import Sampling, default_substeps, length_bucket
from .model import VocalFoldModel
from .terms.base import AbstractFoldPair, AbstractStatefulTerm
from .terms.paper import BernoulliForce
from .terms.tract import SourceTractInertance, flow_at

#: Event budget per second of simulated time. A glottal cycle has up to 7 events, so the
#: default budget covers f0 up to ~570 Hz; beyond it `Simulation.complete` may turn False
#: (each closure hold spares the grid steps it spans, so a recording that closes can go beyond).
EVENTS_PER_SECOND = 4000.0
#: Scan iterations per loop trip (the scan's ``unroll``). Each copy of the iteration's body is
#: compiled into every program that simulates: a second copy makes a fit's polish take about
#: half again as long to compile and its swarm a fifth longer, and runs no faster
#: (benchmarks/README.md).
_UNROLL = 1
#: Iterations per trip of the early-stopping loop: a scan of 16, whose rows are written as one
#: block (writing each iteration's row on its own was slower: by a third at batch 1, 6 % at 64,
#: 14 % at 256). The loop's length is rounded up to a multiple of it, so it overshoots the last
#: needed iteration by at most 15.
_CHUNK = 16
#: A state beyond these bounds is reported as diverged (cm, cm/s).
_X_LIMIT = 1.0
_V_LIMIT = 1.0e5


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


# The regime flags travel in the scan's carry as bits of one integer: one array to update
# per step instead of five (each a separate kernel on CPU).
_FLOW, _INNER, _CLOSING, _HOLD, _DIVERGED = 1, 2, 4, 8, 16


def _pack(flow, inner, closing, hold):
    """The regime flags as one integer (the divergence bit is or-ed in where it is found)."""
    bits = (flow, inner, closing, hold)
    weights = (_FLOW, _INNER, _CLOSING, _HOLD)
    return sum(jnp.where(b, w, 0) for b, w in zip(bits, weights)).astype(jnp.int32)


class _Carry(NamedTuple):
    t: Array
    x: Array
    v: Array
    hold_left: Array
    step: Array  # index of the last grid point reached
    flags: Array  # regime flags, packed (`_pack`)
    events: Array  # regime switches so far (located events and hold releases)
    z: tuple  # internal states of the stateful terms (`VocalFoldModel.initial_state`)

    def flag(self, bit):
        return (self.flags & bit) != 0

    def phase_code(self):
        return _phase_code(
            self.flag(_FLOW), self.flag(_INNER), self.flag(_CLOSING), self.flag(_HOLD)
        )

    def active(self, n_steps):
        return (self.step < n_steps) & ~self.flag(_DIVERGED)


def _phase_code(flow, inner, closing, hold):
    code = jnp.where(inner, jnp.where(closing, phases.CLOSING, phases.OPENING), phases.OPEN)
    return jnp.where(hold | ~flow, phases.CLOSED, code)


def _axpy(y, scale, dy):
    """The internal states ``y + scale * dy`` (pytrees of the same structure)."""
    return jax.tree.map(lambda a, b: a + scale * b, y, dy)


def _rk4(model, t, x, v, z, dt, mode, xc, origin, one):
    """One RK4 step of (x, v, z) with the mode flags frozen. Returns the new state and the
    derivatives at both ends of the step (a and dz/dt), for the step's Hermite cubics."""
    # a time-dependent pressure is computed once per stage time (see `_computed_once`:
    # otherwise its sine is re-derived in every consumer, 2.5x slower)
    timed = model.varies_pressure

    def pressure(t):
        return _computed_once(model.pressure(t - origin), one) if timed else None

    def rates(t, x, v, z, p):
        return model.rates(t - origin, x, v, z, *mode, xc, p)

    p_start, p_mid, p_end = pressure(t), pressure(t + 0.5 * dt), pressure(t + dt)
    a1, dz1 = rates(t, x, v, z, p_start)
    x2, v2, z2 = x + 0.5 * dt * v, v + 0.5 * dt * a1, _axpy(z, 0.5 * dt, dz1)
    a2, dz2 = rates(t + 0.5 * dt, x2, v2, z2, p_mid)
    x3, v3, z3 = x + 0.5 * dt * v2, v + 0.5 * dt * a2, _axpy(z, 0.5 * dt, dz2)
    a3, dz3 = rates(t + 0.5 * dt, x3, v3, z3, p_mid)
    x4, v4, z4 = x + dt * v3, v + dt * a3, _axpy(z, dt, dz3)
    a4, dz4 = rates(t + dt, x4, v4, z4, p_end)
    x_new = x + dt / 6.0 * (v + 2.0 * v2 + 2.0 * v3 + v4)
    v_new = v + dt / 6.0 * (a1 + 2.0 * a2 + 2.0 * a3 + a4)
    z_new = jax.tree.map(
        lambda y, k1, k2, k3, k4: y + dt / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4),
        z,
        dz1,
        dz2,
        dz3,
        dz4,
    )
    a_end, dz_end = rates(t + dt, x_new, v_new, z_new, p_end)
    return x_new, v_new, z_new, a1, dz1, a_end, dz_end


def _computed_once(value, one):
    """``value`` unchanged, computed once per step.

    XLA's CPU fusion copies cheap elementwise producers into each of their consumers. The
    event arithmetic (the live Newton step of the roots, the state at the event) feeds about
    ten consumers (the carry's fields), so it was re-derived ten times per step. A division
    by a run-time one is an op XLA will not duplicate, so the value is materialised once
    instead (1.6-2.4x more recordings per second; `benchmarks/throughput.py`)."""
    return value / one


def _locate_event(x, v, flow, inner, closing, x1, v1, a0, a1, dt, x0, xc, one):
    """The first regime switch on a trial step, located on the step's Hermite cubics.

    Returns (event, theta, x_e, v_e, is_flow, is_inner, is_dir): whether a switch happened,
    its fraction of the step, the state there (projected onto the switching surface) and
    which switch it was (contact x_0, sub-critical x_c, or velocity reversal).
    """
    xs = (x, v * dt, x1, v1 * dt)
    vs = (v, a0 * dt, v1, a1 * dt)
    cross_flow = flow != (x1 > x0)
    cross_inner = inner != (x1 <= xc)
    cross_dir = closing != (v1 < 0)
    # Of the two displacement surfaces x_c is met first on the way down (x_0 < x_c) and x_0
    # first on the way up: one root of the displacement cubic serves both.
    x_first_is_flow = cross_flow & ~(cross_inner & (x1 < x))
    x_target = jnp.where(x_first_is_flow, x0, xc)
    roots = hermite_root(*(jnp.stack([p, q]) for p, q in zip(xs + (x_target,), vs + (0.0,))))
    theta_x = _computed_once(jnp.where(cross_flow | cross_inner, roots[0], 1.0), one)
    theta_v = _computed_once(jnp.where(cross_dir, roots[1], 1.0), one)
    event = cross_flow | cross_inner | cross_dir
    x_first = (cross_flow | cross_inner) & (~cross_dir | (theta_x <= theta_v))
    theta = jnp.where(event, jnp.where(x_first, theta_x, theta_v), 1.0)
    is_flow = x_first & x_first_is_flow
    is_inner = x_first & ~x_first_is_flow
    is_dir = event & ~x_first
    xe = jnp.where(is_flow, x0, jnp.where(is_inner, xc, hermite(theta, *xs)))
    ve = jnp.where(is_dir, 0.0, hermite(theta, *vs))
    theta, xe, ve = (_computed_once(y, one) for y in (theta, xe, ve))
    return event, theta, xe, ve, is_flow, is_inner, is_dir


#: Compression (cm) over which a closure hold grows from nothing to its full length: the
#: hold of a fold that turns at a depth d <= 0 below x_0 lasts t_c min(d / _HOLD_RAMP, 1).
#: The paper's hold (the full t_c for any contact) makes the GAW jump where the turning
#: point grazes x_0, so that whether a grazing cycle is held closed depends on the last bit
#: of rounding (a batched and a single simulation then differ by a whole closed phase). The
#: ramp makes the motion continuous there; 1e-8 cm (0.1 nm) is far below anything a camera
#: resolves and far above rounding (~1e-18 cm).
_HOLD_RAMP = 1e-8


def _hold_ramp(depth):
    """Share of the closure hold for a turning point ``depth`` (cm) below x_0."""
    return jnp.clip(depth / _HOLD_RAMP, 0.0, 1.0)


def _iteration(model: VocalFoldModel, h: float, n_steps: int, origin):
    """One scan iteration: a full grid step, a step up to an event, or a stretch of hold.

    The model's time-dependent terms see time measured from ``origin`` (`simulate`'s
    ``t_start``)."""
    has_hold = model.closure_duration is not None
    x0, xc = model.contact_displacement, model.subcritical_displacement()
    # the last grid point, as `t_target` computes it (h, n_steps and origin may be traced)
    t_end = jnp.asarray(n_steps).astype(float) * h

    def body(c: _Carry, _):
        c_flow, c_inner, c_closing = c.flag(_FLOW), c.flag(_INNER), c.flag(_CLOSING)
        c_hold, active = c.flag(_HOLD), c.active(n_steps)
        one = jnp.where(c.events >= 0, 1.0, 2.0)  # always 1: see `_computed_once`
        t_target = (c.step + 1).astype(float) * h
        dt = t_target - c.t

        # Free motion: trial RK4 step with the regime flags frozen.
        mode = (c_flow, c_inner, c_closing)
        x1, v1, z1, a0, dz0, a1, dz1 = _rk4(model, c.t, c.x, c.v, c.z, dt, mode, xc, origin, one)
        event, theta, xe, ve, is_flow, is_inner, is_dir = _locate_event(
            c.x, c.v, *mode, x1, v1, a0, a1, dt, x0, xc, one
        )
        # the internal states at the event, on their own Hermite cubics over the step
        ze = jax.tree.map(
            lambda y0, r0, y1, r1: hermite(theta, y0, r0 * dt, y1, r1 * dt), c.z, dz0, z1, dz1
        )
        flow, inner, closing = c_flow ^ is_flow, c_inner ^ is_inner, c_closing ^ is_dir
        # A velocity reversal can fall beyond a surface the same step grazed (in and out of
        # contact within one step): the position flags then follow the reversal point.
        flow = jnp.where(is_dir, xe > x0, flow)
        inner = jnp.where(is_dir, xe <= xc, inner)
        starts_hold = is_dir & c_closing & (xe <= x0) if has_hold else jnp.zeros((), bool)
        free = _Carry(
            t=jnp.where(event, c.t + theta * dt, t_target),
            x=jnp.where(event, xe, x1),
            v=jnp.where(event, ve, v1),
            hold_left=jnp.where(
                starts_hold,
                model.hold_duration(c.t + theta * dt - origin) * _hold_ramp(x0 - xe),
                c.hold_left,
            )
            if has_hold
            else c.hold_left,
            step=jnp.where(event, c.step, c.step + 1),
            flags=_pack(
                flow & ~starts_hold, inner | starts_hold, closing & ~starts_hold, starts_hold
            ),
            events=c.events + event.astype(c.events.dtype),
            z=jax.tree.map(lambda a, b: jnp.where(event, a, b), ze, z1),
        )

        # Closure hold: the state rests until the hold runs out, so one iteration takes it to
        # the release (or to the end of the run). Its step index is the last grid point before
        # the release, so the next free step ends on the grid as if the hold had been stepped.
        t_release = c.t + c.hold_left
        release = t_release <= t_end
        t_held = jnp.where(release, t_release, t_end)
        k = jnp.ceil(t_release / h).astype(c.step.dtype) - 1
        k = jnp.clip(jnp.where((k + 1).astype(float) * h < t_release, k + 1, k), c.step, n_steps)
        held = _Carry(
            t=t_held,
            x=c.x,
            v=jnp.zeros_like(c.v),
            hold_left=jnp.where(release, 0.0, t_release - t_end),
            step=jnp.where(release, k, n_steps),
            flags=_pack(c.x > x0, c.x <= xc, False, ~release),
            events=c.events + release.astype(c.events.dtype),
            z=model.held_state(c.z, jnp.maximum(t_held - c.t, 0.0)),
        )

        new = jax.tree.map(lambda a, b: jnp.where(c_hold, a, b), held, free)
        new = new._replace(
            **{k: _computed_once(getattr(new, k), one) for k in ("t", "x", "v", "hold_left")}
        )
        bad = (
            ~jnp.isfinite(new.x)
            | ~jnp.isfinite(new.v)
            | (jnp.abs(new.x) > _X_LIMIT)
            | (jnp.abs(new.v) > _V_LIMIT)
        )
        for leaf in jax.tree.leaves(new.z):
            bad = bad | ~jnp.all(jnp.isfinite(leaf))
        keep = ~active | bad
        out = jax.tree.map(lambda old, nw: jnp.where(keep, old, nw), c, new)
        out = out._replace(flags=out.flags | jnp.where(active & bad, _DIVERGED, 0))
        code = _phase_code(c_flow, c_inner, c_closing, c_hold)
        return out, (out.t, out.x, out.v, code, out.z)

    return body


def _integrate_scan(model, start, *, h, n_steps, n_iter, origin, limit=None):
    """The iterations as a `lax.scan` of fixed length: every member of a batch runs ``n_iter``
    of them, idling once done (and from iteration ``limit`` on, where it is given: the budget
    as data, within the program's ``n_iter``). Differentiable in both modes."""
    body = _iteration(model, h, n_steps, origin)
    if limit is None:
        end, rows = jax.lax.scan(body, start, None, length=n_iter, unroll=_UNROLL)
        return end, _batch_first(rows)

    def limited(c, i):
        new, row = body(c, None)
        idle = i >= limit  # as an iteration after the end: the carry and its row unchanged
        new = jax.tree.map(lambda a, b: jnp.where(idle, a, b), c, new)
        row = jax.tree.map(lambda a, b: jnp.where(idle, a, b), _row(c), row)
        return new, row

    iterations = jnp.arange(n_iter, dtype=jnp.int32)
    end, rows = jax.lax.scan(limited, start, iterations, unroll=_UNROLL)
    return end, _batch_first(rows)


def _row(c: _Carry) -> tuple:
    """The dense-output row of the carry ``c``, as an iteration that ends there writes it."""
    return (c.t, c.x, c.v, c.phase_code(), c.z)


def _integrate_loop(model, start, *, h, n_steps, n_iter, origin, warm=None, limit=None):
    """As `_integrate_scan`, bit for bit, but stopping once every member of the batch is done.

    A hold takes one iteration, so a recording that closes for half of each cycle needs about
    half of the scan's iterations. The loop's condition ignores the batch (``unvmap_any``), so
    under `jax.vmap` it stays one loop whose rows are written in place; members that are done
    idle, as in the scan, and the rows never reached are filled with the final state, as the
    scan's idle iterations would have written them. A `lax.while_loop` has no reverse mode:
    `_integrate` differentiates `_integrate_scan` instead.

    ``warm``: ``(first_step, budget)``, a stretch of motion kept in no row that comes first:
    the iterations up to the grid step ``first_step``, at most ``budget`` of them (rounded up
    to whole trips). It runs through the same loop, so the iteration's body is compiled once.
    Returns ``(begin, end, rows)``, ``begin`` being the state where the rows start; without
    ``warm``, ``(end, rows)``.

    ``limit``: the iterations to run at most (a multiple of `_CHUNK`, traced), where fewer
    than the ``n_iter`` rows; the rows after it hold the final state.
    """
    final = _row(start)
    rows = jax.tree.map(lambda y: jnp.zeros((n_iter,) + jnp.shape(y), jnp.result_type(y)), final)

    def advance(c, rows, j, last_step):
        """One trip: ``_CHUNK`` iterations towards the grid step ``last_step``, their rows
        written from row ``j``."""
        body = _iteration(model, h, last_step, origin)
        new, chunk = jax.lax.scan(body, c, None, length=_CHUNK, unroll=_UNROLL)
        rows = jax.tree.map(
            lambda a, r: jax.lax.dynamic_update_slice_in_dim(a, r, j, 0), rows, chunk
        )
        return new, rows

    def kept(j, c):
        return (j < (n_iter if limit is None else limit)) & eqxi.unvmap_any(c.active(n_steps))

    zero = jnp.zeros((), jnp.int32)
    if warm is None:  # the loop alone: its steps' count stays a constant of the program

        def trip(state):
            j, c, rows = state
            c, rows = advance(c, rows, j, n_steps)
            return j + _CHUNK, c, rows

        j, end, rows = jax.lax.while_loop(lambda s: kept(s[0], s[1]), trip, (zero, start, rows))
    else:
        first_step, budget = warm

        def warming_after(i, c):
            return eqxi.unvmap_any((i < budget) & c.active(first_step))

        def trip(state):
            warming, i, j, begin, c, rows = state
            # a warm-up trip's rows land where the first kept trip writes its own
            new, rows = advance(c, rows, j, jnp.where(warming, first_step, n_steps))
            # while warming, the members beyond their budget stay where they are
            c = jax.tree.map(lambda a, b: jnp.where(warming & (i >= budget), b, a), new, c)
            i = jnp.where(warming, i + _CHUNK, i)
            j = jnp.where(warming, j, j + _CHUNK)
            begin = jax.tree.map(lambda a, b: jnp.where(warming, a, b), c, begin)
            return warming & warming_after(i, c), i, j, begin, c, rows

        def running(state):
            warming, _, j, _, c, _ = state
            return warming | kept(j, c)

        state = (warming_after(zero, start), zero, zero, start, start, rows)
        _, _, j, begin, end, rows = jax.lax.while_loop(running, trip, state)
    done = jnp.arange(n_iter) >= j
    final = _row(end)

    def fill(f, r):
        return jnp.where(jnp.reshape(done, done.shape + (1,) * jnp.ndim(f)), f, r)

    rows = _batch_first(jax.tree.map(fill, final, rows))
    return (end, rows) if warm is None else (begin, end, rows)


def _batch_first(rows):
    """``rows`` (a pytree) unchanged, with any `jax.vmap` batch axis placed first.

    `_integrate`'s two implementations must return their outputs with the same batch axes:
    JAX (0.10) batches a `custom_jvp` function and its derivative rule separately and keeps
    the primal's axes for both, while a scan stacks its rows behind the batch axis and a while
    loop's carry puts it in front. A reshape's batching rule moves the batch axis first."""
    return jax.tree.map(lambda r: jax.lax.reshape(jax.lax.reshape(r, (r.size, 1)), r.shape), rows)


@eqx.filter_custom_jvp
def _integrate(model, start, *, h, n_steps, n_iter, origin, limit=None):
    """The integration: end state and per-iteration rows (t, x, v, phase code, internal
    states).

    Evaluated by the early-stopping `_integrate_loop`; differentiated (forward, and so reverse)
    through `_integrate_scan`, which computes the same values."""
    return _integrate_loop(
        model, start, h=h, n_steps=n_steps, n_iter=n_iter, origin=origin, limit=limit
    )


@_integrate.def_jvp
def _integrate_jvp(primals, tangents, *, h, n_steps, n_iter, origin, limit=None):
    scan = functools.partial(
        _integrate_scan, h=h, n_steps=n_steps, n_iter=n_iter, origin=origin, limit=limit
    )
    return eqx.filter_jvp(scan, primals, tangents)


#: The most loop iterations (grid steps plus the event budget) one simulation may take. Each
#: iteration keeps one row of dense output per simulated recording (28 bytes; a reverse-mode
#: derivative keeps more): 2^21 rows are about 60 MB. A frame rate of 0.001 Hz, a horizon of
#: days or a budget of 10^9 events is refused before anything is allocated.
MAX_ITERATIONS = 2**21


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


def _as_count(name: str, value, minimum: int) -> int:
    """A Python int from an int or NumPy integer; floats (even 201.0) and bools are refused."""
    if isinstance(value, jax.core.Tracer):
        raise TypeError(
            f"{name} must be a concrete integer (it fixes array shapes), not a traced value"
        )
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)):
        raise TypeError(f"{name} must be an integer, got {value!r} ({type(value).__name__})")
    value = int(value)
    if value < minimum:
        raise ValueError(f"{name} must be an integer >= {minimum}, got {value}")
    return value


def _as_seconds(name: str, value, *, positive: bool = False) -> float:
    """A Python float from a real number or NumPy scalar (a value that sizes the program)."""
    if isinstance(value, jax.core.Tracer):
        raise TypeError(
            f"{name} must be a concrete number (it sizes the integration), not a traced value"
        )
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.number)):
        raise TypeError(f"{name} must be a number, got {value!r} ({type(value).__name__})")
    value = float(value)
    if not math.isfinite(value) or value < 0 or (positive and value == 0):
        raise ValueError(
            f"{name} must be a finite number {'>' if positive else '>='} 0, got {value}"
        )
    return value


def simulate(
    model: VocalFoldModel,
    fps: float | Sampling,
    n_frames: int | None = None,
    *,
    substeps: int | None = None,
    t_start: float | None = None,
    time_shift: ArrayLike = 0.0,
    max_time_shift: float | None = None,
    initial_displacement: ArrayLike | None = None,
    initial_velocity: ArrayLike = 0.0,
    max_events: int | None = None,
    reverse_mode: bool = True,
    throw: bool = True,
) -> Simulation:
    """Simulate a glottal area waveform (GAW) sampled at the camera's frame rate.

    The folds start at ``initial_displacement`` (default: at rest at contact, x = x_0) at time
    0; frames are taken at ``t_start + time_shift + k / fps`` for k = 0 .. n_frames - 1.
    Time-dependent terms (`PressureModulation`, `ClosureJitter`) see time measured from
    ``t_start`` (the first frame when ``time_shift`` is 0): ``time_shift`` moves the frames
    within one simulation, and moves nothing else (so a fit can read every shift from one
    simulation's dense output).

    Jit-compiled, once per model structure, `length_bucket` of the frame count and size
    class of the iteration budget (`iteration_bucket` of the grid's steps over the simulated
    time plus ``max_events``). The frame rate, step, ``t_start``, ``max_time_shift``, the
    frame count and budget within their buckets, the model's leaves, ``time_shift`` and the
    initial state are data: new values within the same buckets reuse the program.
    Differentiable (forward and reverse) in every array leaf of ``model`` and in
    ``time_shift``; vmappable over models with batched leaves.

    Arguments:
        model: the model (`vfjax.paper_model`, `vfjax.preset`, ...).
        fps: camera frame rate (Hz), a concrete number; or a `vfjax.Sampling` (frame rate,
            frames, substeps, warm-up as ``t_start``, time-shift range), as a fit samples
            the model (`FitResult.sampling`): then ``n_frames``, ``substeps``, ``t_start``
            and ``max_time_shift`` are not given.
        n_frames: number of frames, an integer (a NumPy integer is accepted; 201.0 is not).
        substeps: RK4 steps per frame (the step is 1 / (substeps * fps)); default
            `default_substeps` of ``fps`` (4, more below 4 kHz: the step stays within
            1/16 000 s).
        t_start: start of sampling (s), e.g. to skip the onset transient; default 0.
        time_shift: extra, differentiable delay of the sampling (s), in [-t_start,
            max_time_shift] (the frames must lie in the integrated interval).
        max_time_shift: the largest ``time_shift`` that will be used (s); extends the
            integration so the shifted frames stay inside it.
        initial_displacement: x at t = 0 (cm); default x_0.
        initial_velocity: v at t = 0 (cm/s).
        max_events: budget of regime switches: a run that makes at most this many completes
            (one with closure holds may make more). Default: 4 per ms of simulated time plus
            16.
        reverse_mode: keep reverse-mode derivatives (`jax.grad`, `jax.vjp`) available; they
            are then taken through a scan of the full iteration budget. False: derivatives
            are taken through the early-stopping loop itself, in forward mode only
            (`jax.jvp`, `jax.jacfwd`; reverse mode raises), which is faster when the folds
            close. The values are the same either way.
        throw: raise an error when the simulation does not succeed (`RESULTS`; under `vmap`,
            when any member does not). False: return it with ``result`` set and the frames
            it could not compute NaN, for batched searches that must go on.

    Returns:
        A `Simulation`: the GAW in pixels and the model's area, motion and phases per frame,
        with ``result`` and the ``diverged`` and ``complete`` flags.

    Raises:
        TypeError, ValueError: for arguments that cannot be simulated (a float frame count,
            a negative frame rate, a concrete time shift outside [-t_start, max_time_shift], a run
            longer than `MAX_ITERATIONS`, ...), before anything is allocated.
    """
    if isinstance(fps, Sampling):
        given = {
            "n_frames": n_frames,
            "substeps": substeps,
            "t_start": t_start,
            "max_time_shift": max_time_shift,
        }
        clash = [name for name, value in given.items() if value is not None]
        if clash:
            raise TypeError(
                f"simulate: {', '.join(clash)} given with a Sampling, which sets them; give "
                "either a Sampling or fps and n_frames"
            )
        sampling = fps
        fps, n_frames, substeps = sampling.fps, sampling.n_frames, sampling.substeps
        t_start, max_time_shift = sampling.warmup, sampling.max_time_shift
    elif n_frames is None:
        raise TypeError("simulate: give n_frames with a frame rate (or a vfjax.Sampling)")
    t_start = 0.0 if t_start is None else t_start
    max_time_shift = 0.0 if max_time_shift is None else max_time_shift
    fps = _as_seconds("fps (frame rate, Hz)", fps, positive=True)
    substeps = default_substeps(fps) if substeps is None else substeps
    n_frames = _as_count("n_frames", n_frames, 1)
    substeps = _as_count("substeps", substeps, 1)
    t_start = _as_seconds("t_start", t_start)
    max_time_shift = _as_seconds("max_time_shift", max_time_shift)
    if max_events is not None:
        max_events = _as_count("max_events", max_events, 0)
    h = 1.0 / (substeps * fps)
    model.check_step(h)
    horizon = t_start + max_time_shift + (n_frames - 1) / fps
    n_steps = max(1, math.ceil(horizon / h - 1e-9))
    if max_events is None:
        max_events = int(EVENTS_PER_SECOND * horizon) + 16
    n_iter = _CHUNK * -(-(n_steps + max_events) // _CHUNK)
    if n_iter > MAX_ITERATIONS:
        raise ValueError(
            f"simulating {horizon:.6g} s at {substeps} steps per frame of {fps:g} Hz needs "
            f"{n_steps} steps and a budget of {max_events} events, more than the "
            f"{MAX_ITERATIONS} iterations one simulation may take (about 60 MB per "
            "recording): check the frame rate, frame count, t_start and max_events"
        )
    time_shift = jnp.asarray(time_shift, dtype=float)
    if not isinstance(time_shift, jax.core.Tracer):
        shift = np.asarray(time_shift)
        if shift.shape != () or not (-t_start - 1e-12 <= float(shift) <= max_time_shift + 1e-12):
            raise ValueError(
                "time_shift must be a number in [-t_start, max_time_shift] = "
                f"[{-t_start or 0.0:g}, {max_time_shift:g}] s, got {shift.tolist()}: the shifted "
                "frames must lie in the integrated interval (raise max_time_shift)"
            )
    x_init = None if initial_displacement is None else jnp.asarray(initial_displacement, float)
    # the frame rate, step, step count, start, shift range, frame count and budget are data
    # (traced): only their buckets and the mode shape the compiled program
    i32 = jnp.int32
    sim = _simulate(
        model,
        time_shift,
        x_init,
        jnp.asarray(initial_velocity, dtype=float),
        jnp.asarray(fps, dtype=float),
        jnp.asarray(h, dtype=float),
        jnp.asarray(n_steps, dtype=i32),
        jnp.asarray(t_start, dtype=float),
        jnp.asarray(max_time_shift, dtype=float),
        jnp.asarray(n_frames, dtype=i32),
        jnp.asarray(n_iter, dtype=i32),
        n_out=length_bucket(n_frames),
        n_rows=iteration_bucket(n_iter),
        reverse_mode=bool(reverse_mode),
    )
    sim = _first_frames(sim, n_frames)
    if throw:
        failed = sim.result != RESULTS.successful
        if isinstance(failed, jax.core.Tracer):
            area = sim.result.error_if(sim.area, failed)
            sim = eqx.tree_at(lambda s: s.area, sim, area)
        elif bool(jnp.any(failed)):
            if bool(jnp.any(sim.result == RESULTS.invalid_parameters)):
                model.check()  # names the parameter, where it is concrete
            raise SimulationError(result_message(sim.result))
    return sim


def iteration_bucket(n_iter: int) -> int:
    """The loop length a simulation of ``n_iter`` iterations (a multiple of `_CHUNK`) is
    compiled for: the next of 2^k and 3 * 2^(k - 1) (so at most a third more). Within it
    the budget is data; an early-stopping loop ends where it ends, a differentiated scan runs
    the bucket's idle iterations too."""
    n = max(int(n_iter), _CHUNK)
    k = (n - 1).bit_length()
    return 3 << (k - 2) if (3 << (k - 2)) >= n else 1 << k


#: The `Simulation` fields with one entry per frame (cut to a frame count after a program
#: that pads the frames to a bucket).
_PER_FRAME = ("time", "area", "glottal_area", "displacement", "velocity", "phase")


@eqx.filter_jit
def _first_frames(sim: Simulation, n_frames: int) -> Simulation:
    """``sim`` with its per-frame arrays cut to the first ``n_frames`` (one small program per
    bucket and count, in place of a simulation's program per count)."""
    return eqx.tree_at(
        lambda s: [getattr(s, f) for f in _PER_FRAME],
        sim,
        [getattr(sim, f)[:n_frames] for f in _PER_FRAME],
    )


@eqx.filter_jit
def _simulate(
    model,
    time_shift,
    x_init,
    v_init,
    fps,
    h,
    n_steps,
    t_start,
    max_time_shift,
    n_frames,
    n_iter,
    *,
    n_out,
    n_rows,
    reverse_mode,
) -> Simulation:
    """`simulate`'s program: ``n_frames`` frames (traced) padded to ``n_out``, ``n_iter``
    iterations at most (traced) in ``n_rows`` rows."""
    x_init = model.contact_displacement if x_init is None else x_init
    x_init = jnp.asarray(x_init, dtype=float)
    valid_model = model.is_valid() & jnp.isfinite(x_init) & jnp.isfinite(v_init)
    start = _start(model, x_init, v_init)
    integrate = _integrate if reverse_mode else _integrate_loop
    end, rows = integrate(
        model, start, h=h, n_steps=n_steps, n_iter=n_rows, origin=t_start, limit=n_iter
    )
    shift_ok = (time_shift >= -t_start - 1e-12) & (time_shift <= max_time_shift + 1e-12)
    times = t_start + time_shift + jnp.arange(n_out) / fps
    counted = jnp.arange(n_out) < n_frames
    return _sampled(model, start, end, rows, times, n_steps, valid_model, shift_ok, counted)


def _start(model, x_init, v_init) -> _Carry:
    """The carry at time 0: the folds at ``x_init`` (cm) moving at ``v_init`` (cm/s)."""
    x0, xc = model.contact_displacement, model.subcritical_displacement()
    return _Carry(
        t=jnp.zeros((), float),
        x=x_init,
        v=v_init,
        hold_left=jnp.zeros((), float),
        step=jnp.zeros((), jnp.int32),
        flags=_pack(x_init > x0, x_init <= xc, v_init < 0, False),
        events=jnp.zeros((), jnp.int32),
        z=jax.tree.map(lambda y: jnp.asarray(y, float), model.initial_state()),
    )


def _sampled(
    model, begin, end, rows, times, n_steps, valid_model, shift_ok, counted=None, warmed=True
) -> Simulation:
    """The `Simulation` of an integration from the carry ``begin`` to ``end`` with dense
    ``rows`` (t, x, v, phase code, internal states), read at the frame ``times``.
    ``counted``: which frames count (the others are padding, of zero area); ``warmed``:
    whether the motion before the rows ran to its end."""
    ts, xs, vs, codes, zs = rows
    dense = DenseOutput(
        t=jnp.concatenate([begin.t[None], ts]),
        x=jnp.concatenate([begin.x[None], xs]),
        v=jnp.concatenate([begin.v[None], vs]),
        phase=jnp.concatenate([codes, codes[-1:]]),
        z=jax.tree.map(lambda z0, z: jnp.concatenate([z0[None], z]), begin.z, zs),
    )
    x = dense.displacement(times)
    valid = times <= end.t + 1e-12
    area = model.observe(times, x, dense.displacement)
    if counted is not None:
        valid = valid | ~counted
        area = jnp.where(counted, area, 0.0)
    valid = valid & valid_model
    diverged = end.flag(_DIVERGED)
    reached = (end.step >= n_steps) & jnp.all(valid) & warmed
    result = RESULTS.where(
        ~valid_model,
        RESULTS.invalid_parameters,
        RESULTS.where(
            ~shift_ok,
            RESULTS.time_shift_out_of_range,
            RESULTS.where(
                diverged,
                RESULTS.diverged,
                RESULTS.where(reached, RESULTS.successful, RESULTS.event_budget_exhausted),
            ),
        ),
    )
    nan = jnp.nan
    return Simulation(
        time=times,
        area=jnp.where(valid, area, nan),
        glottal_area=jnp.where(valid, model.subject.area(x), nan),
        displacement=jnp.where(valid, x, nan),
        velocity=jnp.where(valid, dense.velocity(times), nan),
        phase=dense.phase_at(times),
        diverged=diverged,
        complete=result == RESULTS.successful,
        n_events=end.events,
        result=result,
        dense=dense,
    )


# ----------------------------------------------------------------- the fits' compiled sampling
#: Motion kept before the first frame (s): observation terms may read the displacement at
#: earlier times (a mucosal delay reads x(t - tau), tau <= 1 ms).
LOOKBACK = 0.002
#: Event budget of a fit's simulation, per frame of its window.
_EVENTS_PER_FRAME = 2
#: A fit's dense output has rows for at least this many RK4 steps a frame (more round up to
#: a power of two), so that every camera of 2 kHz or faster (`default_substeps` 8 to 4)
#: shares one program per length bucket. Rows beyond those a simulation reaches cost no
#: iterations (the loop stops when done): the compiled fits of 4 kHz recordings run as fast
#: with rows for 8 steps a frame as with rows for 4 (`benchmarks/engine.py`, part c).
_ROW_SUBSTEPS = 8


class SampledGrid(eqx.Module):
    """A `Sampling` as data, so that one compiled program serves every frame rate, warm-up
    and time-shift range (`simulate_frames`). Build it with `sampled_grid`.

    Attributes:
        fps: frame rate (Hz).
        h: RK4 step (s).
        t_start: warm-up, the time of the first frame before any shift (s).
        max_time_shift: largest time shift (s).
        n_frames: frames that count (the rest of a length bucket is padding).
        n_steps: grid steps to the last frame at the largest shift.
        window_step: grid step where the kept motion begins (`LOOKBACK` before t_start).
        warm_budget: most iterations before the window (steps plus an event budget).
    """

    fps: Array
    h: Array
    t_start: Array
    max_time_shift: Array
    n_frames: Array
    n_steps: Array
    window_step: Array
    warm_budget: Array


def sampled_grid(sampling: Sampling) -> SampledGrid:
    """``sampling`` as a `SampledGrid` (concrete arrays)."""
    h = sampling.step
    n_steps = max(1, math.ceil(sampling.horizon / h - 1e-9))
    window_step = max(0, math.floor((sampling.warmup - LOOKBACK) / h))
    warm_budget = window_step + int(EVENTS_PER_SECOND * sampling.warmup) + 16
    if n_steps + warm_budget > MAX_ITERATIONS:
        raise ValueError(
            f"simulating {sampling.horizon:.6g} s at {sampling.substeps} steps per frame of "
            f"{sampling.fps:g} Hz needs more than the {MAX_ITERATIONS} iterations one "
            "simulation may take: check the frame rate, frame count and warm-up"
        )
    i32 = np.int32
    return SampledGrid(
        fps=jnp.asarray(sampling.fps),
        h=jnp.asarray(h),
        t_start=jnp.asarray(sampling.warmup),
        max_time_shift=jnp.asarray(sampling.max_time_shift),
        n_frames=jnp.asarray(sampling.n_frames, i32),
        n_steps=jnp.asarray(n_steps, i32),
        window_step=jnp.asarray(window_step, i32),
        warm_budget=jnp.asarray(warm_budget, i32),
    )


def window_size(sampling: Sampling) -> tuple[int, int]:
    """The static sizes of a compiled fit's simulation: (frames, rows). Frames: the
    `length_bucket` of the frame count; rows: the dense output's length, enough for the
    frames, the time-shift range and the lookback (bucketed alike) at `_ROW_SUBSTEPS` steps
    a frame (or ``substeps`` rounded up to a power of two, where more) and
    `_EVENTS_PER_FRAME` events per frame. The frame rate and the steps a frame are then
    data for every camera of 2 kHz or faster."""
    extra = sampling.shift_frames + math.ceil(LOOKBACK * sampling.fps) + 2
    frames = length_bucket(sampling.n_frames)
    steps = max(_ROW_SUBSTEPS, 1 << (sampling.substeps - 1).bit_length())
    rows = (steps + _EVENTS_PER_FRAME) * (frames + length_bucket(extra))
    return frames, _CHUNK * -(-rows // _CHUNK)


# Compiled as a program of its own, nested where it is called: a fit's or a diagnosis's
# program simulates in several places (a shift profile, residuals, their Jacobian), and JAX
# then traces the integrator once for all of them (tracing is paid in every process, even when
# the persistent compilation cache holds the program).
@eqx.filter_jit
def simulate_frames(model, grid: SampledGrid, time_shift, *, n_out: int, n_rows: int):
    """The frames of one simulation for the compiled fits: as `simulate` with
    ``reverse_mode=False`` and ``throw=False``, but with every size that depends on the
    recording traced (``grid``) and the frames padded to ``n_out`` (`window_size`).

    The motion up to the window (`LOOKBACK` before the first frame) runs in a loop that keeps
    no rows and whose length is data; the window's motion is kept in ``n_rows`` rows, so
    ``Simulation.dense`` covers the window only. ``time_shift`` (s) may lie in [-LOOKBACK / 2,
    ``grid.max_time_shift``]. Padding frames (beyond ``grid.n_frames``) have zero area.
    Forward-mode derivatives only (`jax.jvp`, `jax.jacfwd`).
    """
    start = _start(model, jnp.asarray(model.contact_displacement, float), jnp.zeros((), float))
    begin, end, rows = _integrate_loop(
        model,
        start,
        h=grid.h,
        n_steps=grid.n_steps,
        n_iter=n_rows,
        origin=grid.t_start,
        warm=(grid.window_step, grid.warm_budget),
    )
    warmed = ~begin.active(grid.window_step) | begin.flag(_DIVERGED)
    counted = jnp.arange(n_out) < grid.n_frames
    times = grid.t_start + time_shift + jnp.arange(n_out) / grid.fps
    # a polish may move the frames a little before the warm-up's end (half the lookback)
    shift_ok = (time_shift >= -0.5 * LOOKBACK) & (time_shift <= grid.max_time_shift + 1e-12)
    return _sampled(
        model,
        begin,
        end,
        rows,
        times,
        grid.n_steps,
        model.is_valid(),
        shift_ok,
        counted,
        warmed,
    )


def fitted_simulation(model: VocalFoldModel, sampling: Sampling, time_shift=0.0) -> Simulation:
    """The `Simulation` of ``model`` sampled as a fit samples it (``sampling``, frames shifted
    by ``time_shift`` s); its dense output covers the frames and a short lookback before
    them. One compiled program per model structure and length bucket (`window_size`),
    whatever the frame rate, frame count within the bucket and warm-up; forward-mode
    derivatives only (`simulate_frames`)."""
    n_out, n_rows = window_size(sampling)
    model.check_step(sampling.step)
    shift = jnp.asarray(float(time_shift))
    sim = simulate_frames(model, sampled_grid(sampling), shift, n_out=n_out, n_rows=n_rows)
    n = sampling.n_frames
    # the recording's frames cut off the bucket on the host (a device slice would compile a
    # program per frame count)
    return eqx.tree_at(
        lambda s: [getattr(s, f) for f in _PER_FRAME],
        sim,
        [np.asarray(getattr(sim, f))[:n] for f in _PER_FRAME],
    )
