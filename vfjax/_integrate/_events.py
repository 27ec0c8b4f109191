"""The event-located RK4 stepping: one iteration advances to the next grid point with the
regime flags frozen, or stops at a located event and flips its flag; the iterations run in
an early-stopping loop, or in a `lax.scan` of the same values where derivatives are taken
(a custom JVP)."""

import functools
import math
from typing import NamedTuple

import equinox as eqx
import equinox.internal as eqxi
import jax
import jax.numpy as jnp
from jaxtyping import Array

from .. import phases
from .._batching import batched_like
from .._hermite import hermite, hermite_root, hermite_roots
from ..model import VocalFoldModel

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
#: block (writing each iteration's row on its own is slower: by a third at batch 1, 6 % at 64,
#: 14 % at 256). The loop's length is rounded up to a multiple of it, so it overshoots the last
#: needed iteration by at most 15.
_CHUNK = 16
#: A state beyond these bounds is reported as diverged (cm, cm/s).
_X_LIMIT = 1.0
_V_LIMIT = 1.0e5


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


def _locate_event(x, v, flow, inner, closing, x1, v1, a0, a1, dt, x0, xc, one, apart=False):
    """The first regime switch on a trial step, located on the step's Hermite cubics.

    Returns (event, theta, x_e, v_e, is_flow, is_inner, is_dir): whether a switch happened,
    its fraction of the step, the state there (projected onto the switching surface) and
    which switch it was (contact x_0, sub-critical x_c, or velocity reversal). ``apart``:
    the displacement's and the velocity's roots solved as separate arrays, not stacked (for
    `_integrate_apart`: a stack of the two doubles the batch's arrays, which then pass the
    512 bytes of `_alone` from 64 single-precision lanes on), their Newton iterations
    unrolled (`hermite_roots`).
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
    if apart:
        roots = hermite_roots(xs + (x_target,), vs + (0.0,), unrolled=True)
    else:
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
#: resolves and far above double precision's rounding (~1e-18 cm); single precision's (the
#: swarm's simulations, `integrate_window_single`) is about 1e-9 cm at the folds' amplitude.
_HOLD_RAMP = 1e-8


def _hold_ramp(depth):
    """Share of the closure hold for a turning point ``depth`` (cm) below x_0."""
    return jnp.clip(depth / _HOLD_RAMP, 0.0, 1.0)


def _iteration(model: VocalFoldModel, h: float, n_steps: int, origin, apart=False):
    """One scan iteration: a full grid step, a step up to an event, or a stretch of hold.

    The model's time-dependent terms see time measured from ``origin`` (`simulate`'s
    ``t_start``). ``apart``: as for `_locate_event`."""
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
            c.x, c.v, *mode, x1, v1, a0, a1, dt, x0, xc, one, apart
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
        return out, _row_of(c, out)

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
    return _row_of(c, c)


def _row_of(before: _Carry, after: _Carry) -> tuple:
    """The dense-output row of the iteration from ``before`` to ``after``: the state reached
    and the phase of the segment that ends there."""
    return (after.t, after.x, after.v, before.phase_code(), after.z)


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
    rows = batched_like(start, rows)  # written with batched rows (see `batched_like`)

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

        def trip(state):
            warming, i, j, begin, c, rows = state
            # a warm-up trip's rows land where the first kept trip writes its own
            last_step = _last_step(warming, i, first_step, budget, n_steps)
            c, rows = advance(c, rows, j, last_step)
            return _counted(warming, i, j, begin, c, _CHUNK, first_step, budget) + (rows,)

        def running(state):
            warming, _, j, _, c, _ = state
            return warming | kept(j, c)

        state = (_warming(zero, start, first_step, budget), zero, zero, start, start, rows)
        _, _, j, begin, end, rows = jax.lax.while_loop(running, trip, state)
    rows = _batch_first(_filled(rows, j, end))
    return (end, rows) if warm is None else (begin, end, rows)


def _filled(rows, j, end: _Carry):
    """``rows`` (a pytree of `_row`'s layout, a leading row axis) with every row from ``j``
    on the final state ``end``'s, as the scan's idle iterations would have written them."""
    final = _row(end)

    def fill(f, r):
        done = jnp.arange(r.shape[0]) >= j
        return jnp.where(jnp.reshape(done, done.shape + (1,) * jnp.ndim(f)), f, r)

    return jax.tree.map(fill, final, rows)


def _integrate_apart(model, start, *, h, n_steps, n_iter, origin, warm):
    """`_integrate_loop` with ``warm``, each iteration run as a program of its own (`_alone`)
    and its row written by the loop around it; the same motion, not the same bits (XLA
    compiles the iteration's arithmetic otherwise there).

    For a batch whose state's arrays are small: at most 128 lanes in single precision (the
    swarm's simulations, `integrate_window_single`), 64 in double. There the iteration's
    kernels run one after another; for larger batches they are scheduled as a dataflow graph
    in either loop, and this one then costs more (a conditional and a loop trip per
    iteration): 48 particles' profiled costs take 8.3 ms against 10.1-10.7 ms, 96 take 13.1
    against 14.6 ms, but 192 take 48 against 26 ms."""
    packing = _RowPacking(_row(start))
    rows = batched_like(start, jnp.zeros((packing.width, n_iter), packing.dtype))
    first_step, budget = warm
    budget = _CHUNK * -(-budget // _CHUNK)  # in whole trips, as `_integrate_loop` counts it

    def iteration(state):
        warming, i, j, begin, c = state
        last_step = _last_step(warming, i, first_step, budget, n_steps)
        body = _iteration(model, h, last_step, origin, apart=True)
        c = body(c, None)[0]
        return _counted(warming, i, j, begin, c, 1, first_step, budget)

    def trip(state):
        *state, rows = state
        before, j = state[4], state[2]
        new = _alone(iteration, tuple(state), once=j >= 0)
        # a warm-up iteration's row lands where the first kept iteration writes its own
        row = packing.pack(_row_of(before, new[4]))
        return new + (jax.lax.dynamic_update_slice_in_dim(rows, row[:, None], j, 1),)

    def running(state):
        warming, _, j, _, c, _ = state
        return warming | ((j < n_iter) & eqxi.unvmap_any(c.active(n_steps)))

    zero = jnp.zeros((), jnp.int32)
    state = (_warming(zero, start, first_step, budget), zero, zero, start, start, rows)
    _, _, j, begin, end, rows = jax.lax.while_loop(running, trip, state)
    return begin, end, _batch_first(_filled(packing.unpack(rows), j, end))


def _warming(i, c: _Carry, first_step, budget):
    """Whether a warm-up goes on after ``i`` of its iterations: some member has not reached
    the grid step ``first_step`` and the ``budget`` of iterations is not spent."""
    return eqxi.unvmap_any((i < budget) & c.active(first_step))


def _last_step(warming, i, first_step, budget, n_steps):
    """The grid step a warm-up loop's next iterations run to, per member: ``first_step``
    while warming, 0 for a member beyond its ``budget`` (data per member; it then idles
    where it stopped, whatever its batch-mates' budgets), and ``n_steps`` once the kept
    rows begin."""
    return jnp.where(warming, jnp.where(i >= budget, 0, first_step), n_steps)


def _counted(warming, i, j, begin, c: _Carry, n, first_step, budget):
    """A warm-up loop's state after ``n`` iterations that ended at ``c``: whether it is still
    warming, its warm-up iterations ``i``, its kept rows ``j`` and ``begin``, the state where
    the kept rows start."""
    i = jnp.where(warming, i + n, i)
    j = jnp.where(warming, j, j + n)
    begin = jax.tree.map(lambda a, b: jnp.where(warming, a, b), c, begin)
    return warming & _warming(i, c, first_step, budget), i, j, begin, c


def _alone(step, state, *, once):
    """``step(state)`` run as a program of its own: the branch of a conditional whose
    predicate ``once`` is always True (but traced, so that XLA keeps the conditional).

    XLA's CPU runtime runs the kernels of a loop's body one after another where each buffer
    they use is small (at most 512 bytes) or where there are few kernels (at most 8), and
    otherwise schedules them as a dataflow graph, which costs about as much per kernel as the
    step's arithmetic on a few dozen lanes. The rows, a large buffer written in the
    iteration's own body, make all of its ~50 kernels pay that cost. As a branch of its own
    the iteration uses the state's arrays alone, and the loop's body around it (the
    conditional and the row's write) has few kernels."""
    return jax.lax.cond(once, step, lambda state: state, state)


class _RowPacking:
    """A dense-output row (`_row`: t, x, v, phase code, internal states) as one vector and
    back, exactly (the phase code, a small integer, is exact in any floating type): a loop
    then writes one array per iteration, not one per field."""

    def __init__(self, row):
        leaves, self.tree = jax.tree.flatten(row)
        self.shapes = [jnp.shape(y) for y in leaves]
        self.dtypes = [jnp.result_type(y) for y in leaves]
        self.dtype = jnp.result_type(*(d for d in self.dtypes if jnp.issubdtype(d, jnp.floating)))
        self.sizes = [math.prod(s) for s in self.shapes]
        self.width = sum(self.sizes)

    def pack(self, row):
        """``row`` as a vector of `width` values."""
        return jnp.concatenate([jnp.ravel(y).astype(self.dtype) for y in jax.tree.leaves(row)])

    def unpack(self, rows):
        """Packed ``rows`` (`width` x rows) as the row's pytree, each leaf with a leading row
        axis."""
        n, leaves, at = rows.shape[1], [], 0
        for shape, dtype, size in zip(self.shapes, self.dtypes, self.sizes):
            leaf = rows[at] if shape == () else rows[at : at + size].T.reshape((n,) + shape)
            leaves.append(leaf.astype(dtype))
            at += size
        return jax.tree.unflatten(self.tree, leaves)


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
