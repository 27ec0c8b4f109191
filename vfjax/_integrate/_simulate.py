"""`simulate`: validated arguments, one compiled program per model structure and frame
bucket, its result (`RESULTS`, `SimulationError`) and the `Simulation` read off the dense
output."""

import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import ArrayLike

from .._batching import batched_like
from .._programs import program
from .._sampling import Sampling, default_substeps, length_bucket
from ..model import VocalFoldModel
from ._events import (
    _CHUNK,
    _DIVERGED,
    EVENTS_PER_SECOND,
    _Carry,
    _integrate,
    _integrate_loop,
    _pack,
)
from ._output import RESULTS, DenseOutput, Simulation, SimulationError, result_message

#: The most loop iterations (grid steps plus the event budget) one simulation may take. Each
#: iteration keeps one row of dense output per simulated recording (28 bytes; a reverse-mode
#: derivative keeps more): 2^21 rows are about 60 MB. A frame rate of 0.001 Hz, a horizon of
#: days or a budget of 10^9 events is refused before anything is allocated.
MAX_ITERATIONS = 2**21


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
            `default_substeps` of ``fps`` (4 at 4 kHz; the step stays within 1/16 000 s at
            any frame rate: more steps a frame below 4 kHz, fewer above).
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


def _first_frames(sim: Simulation, n_frames: int) -> Simulation:
    """``sim`` with its per-frame arrays cut to the first ``n_frames``: on the host where they
    are concrete and uncommitted (no program), else by `_first_frames_traced`."""
    arrays = [getattr(sim, f) for f in _PER_FRAME]
    if any(isinstance(x, jax.core.Tracer) or x.committed for x in arrays):
        return _first_frames_traced(sim, n_frames)
    cut = [jax.device_put(np.asarray(x)[:n_frames]) for x in arrays]
    return eqx.tree_at(lambda s: [getattr(s, f) for f in _PER_FRAME], sim, cut)


@program(store=False)
def _first_frames_traced(sim: Simulation, n_frames: int) -> Simulation:
    """`_first_frames` as a program (under a transformation, or for arrays committed to a
    device): one small program per bucket and count, in place of a simulation's program
    per count."""
    return eqx.tree_at(
        lambda s: [getattr(s, f) for f in _PER_FRAME],
        sim,
        [getattr(sim, f)[:n_frames] for f in _PER_FRAME],
    )


@program(store=False)
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
    start = _Carry(
        t=jnp.zeros((), float),
        x=x_init,
        v=v_init,
        hold_left=jnp.zeros((), float),
        step=jnp.zeros((), jnp.int32),
        flags=_pack(x_init > x0, x_init <= xc, v_init < 0, False),
        events=jnp.zeros((), jnp.int32),
        z=jax.tree.map(lambda y: jnp.asarray(y, float), model.initial_state()),
    )
    # under vmap the integration makes every field batched: so it is from the loop's first
    # trace (see `batched_like`)
    return batched_like((model, x_init, v_init), start)


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
