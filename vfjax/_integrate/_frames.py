"""A fit's compiled sampling: the `Sampling` as data (`SampledGrid`), so that one program
per model structure and length bucket serves every frame rate, warm-up and time-shift range
(`simulate_frames`, `fitted_simulation`)."""

import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array

from .._programs import program
from .._sampling import Sampling, length_bucket
from ..model import VocalFoldModel
from ._events import _CHUNK, _DIVERGED, EVENTS_PER_SECOND, _integrate_apart, _integrate_loop
from ._output import Simulation
from ._simulate import _PER_FRAME, MAX_ITERATIONS, _sampled, _start

#: Motion kept before the first frame (s): observation terms may read the displacement at
#: earlier times (a mucosal delay reads x(t - tau), tau <= 1 ms).
LOOKBACK = 0.002
#: Event budget of a fit's simulation, per frame of its window.
_EVENTS_PER_FRAME = 2
#: A fit's dense output has rows for at least this many RK4 steps a frame (more round up to
#: a power of two), so that every camera of 2 kHz or faster (`default_substeps` 8 to 1)
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
def integrate_window(model, grid: SampledGrid, *, n_rows: int, small_batch: bool = False):
    """The integration behind `simulate_frames`: ``(begin, end, rows)``, the carry where the
    kept rows start, the final carry and the ``n_rows`` dense rows of the window.

    The motion up to the window (`LOOKBACK` before the first frame) runs in a loop that keeps
    no rows and whose length is data. It does not depend on the frames' time shift: a fit
    moves the frames over one integration (`sample_window`). Forward-mode derivatives only.
    ``small_batch``: vmapped over at most 128 members in single precision (or 64 in double),
    each internal state of the model's terms one value a member, so that each iteration runs
    as a program of its own (`_integrate_apart`)."""
    start = _start(model, jnp.asarray(model.contact_displacement, float), jnp.zeros((), float))
    integrate = _integrate_apart if small_batch else _integrate_loop
    return integrate(
        model,
        start,
        h=grid.h,
        n_steps=grid.n_steps,
        n_iter=n_rows,
        origin=grid.t_start,
        warm=(grid.window_step, grid.warm_budget),
    )


def _with_precision(tree, single: bool):
    """``tree`` with its floating arrays in single (``single``) or double precision and, for
    single, its 64-bit integers in 32 bits."""

    def cast(x):
        if not eqx.is_array(x):
            return x
        if jnp.issubdtype(x.dtype, jnp.floating):
            return x.astype(jnp.float32 if single else jnp.float64)
        if single and x.dtype == jnp.int64:
            return x.astype(jnp.int32)
        return x

    return jax.tree.map(cast, tree)


def integrate_window_single(model, grid: SampledGrid, *, n_rows: int):
    """`integrate_window` in single precision, its output returned in double.

    For the swarm's shift profile, which ranks candidate points and needs no derivatives: a
    vmapped single-precision integration takes about half the time of a double one on a CPU
    (twice the lanes per vector instruction). Every constant of the integration and of the
    model's terms is traced in single precision too (JAX's 64-bit mode off while tracing).
    The polish and every reported figure use the double-precision integration.

    The swarm simulates at most `vfjax._fit._engine.MAX_LANES` particles side by side: a
    small batch (``small_batch``) where each internal state of the model's terms is one value
    a particle, whose arrays then stay within 512 bytes. A term whose state has several
    values a particle (the folds' pair, a power-law tissue's elements) makes them larger, and
    its model keeps the chunked loop (which it runs up to twice as fast). The choice depends
    on the model's structure alone, so a particle's bits do not depend on its batch."""
    small = all(math.prod(jnp.shape(z)) == 1 for z in jax.tree.leaves(model.initial_state()))
    with jax.enable_x64(False):
        out = integrate_window(
            _with_precision(model, True),
            _with_precision(grid, True),
            n_rows=n_rows,
            small_batch=small,
        )
    return _with_precision(out, False)


def sample_window(model, grid: SampledGrid, time_shift, integration, *, n_out: int):
    """The frames of ``integration`` (`integrate_window`'s output for ``model``) shifted by
    ``time_shift`` (s), padded to ``n_out``: `simulate_frames`'s `Simulation`."""
    begin, end, rows = integration
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


@program(store=False)
def simulate_frames(model, grid: SampledGrid, time_shift, *, n_out: int, n_rows: int):
    """The frames of one simulation for the compiled fits: as `simulate` with
    ``reverse_mode=False`` and ``throw=False``, but with every size that depends on the
    recording traced (``grid``) and the frames padded to ``n_out`` (`window_size`).

    ``Simulation.dense`` covers the window only (`integrate_window`). ``time_shift`` (s) may
    lie in [-LOOKBACK / 2, ``grid.max_time_shift``]. Padding frames (beyond
    ``grid.n_frames``) have zero area. Forward-mode derivatives only (`jax.jvp`,
    `jax.jacfwd`).
    """
    integration = integrate_window(model, grid, n_rows=n_rows)
    return sample_window(model, grid, time_shift, integration, n_out=n_out)


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
