"""The engine: every fit runs as a batch (recordings x starts) through compiled programs.

Stage 1, global: a particle swarm (`Swarm`), every particle of every fit simulated in one
call per iteration (the particles of all fits side by side, `MAX_LANES` to a vmapped
simulation), in compiled chunks of iterations (progress is reported between chunks). Stage
2, local: one compiled program of `optimistix.least_squares` solves (`Polish`, by default
Levenberg-Marquardt with the best point kept) from each fit's swarm optimum, the fits one
after the other, with no host round trip per step.

On several devices (CPU devices: `jax_num_cpu_devices`) a batch's fits are split into as many
equal groups (`_device_groups`), which run side by side, one thread each, through the
one-device programs, and the polish's slices are dealt to the groups in turn; a fit computes
the same bits on any number of them. On the CPU every group runs on the first device
(`group_devices`): a CPU executable computes in the thread that calls it, so one compiled copy
of each program serves every core. (A program split over devices by XLA's SPMD partitioner,
as with `jax.shard_map`, rounds otherwise than the same program on one device, and a swarm is
chaotic: such a split can end a fit in another basin.)

What decides the compiled programs: the model's structure (its terms), the parameters it fits
beyond `PROGRAM_PARAMETERS`, the batch size over the devices, rounded up to a power of two
(`batch_bucket`; the padding fits are skipped), the length bucket (`vfjax.Sampling`,
`length_bucket`), the swarm's size and chunk and the polish. Everything else (the
recordings, frame rates, warm-ups, time-shift ranges, starting values, bounds, iteration
counts, which of the program's parameters are fitted, and in linear or log coordinates) is
data. A fit's result does not depend on the batch it ran in, nor on the number of devices.
"""

import dataclasses
import functools
import math
import sys
import time
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array

from .._programs import program
from .._validate import is_count
from ..model import VocalFoldModel
from ..recording import Recording
from ..terms.base import AbstractFoldPair
from ._options import Polish, Swarm
from ._polish import RESULT_NAMES
from ._polish import polish as _polish_one
from ._problem import (
    PLAUSIBLE,
    bounds_in_units,
    default_warmup,
    fit_sampling,
    prepare,
    program_size,
)
from ._result import FitResult, fit_status
from ._swarm import run_chunk, scatter, unvisited

#: The parameters a fit adjusts by default: the paper's S, K and C_f.
DEFAULT_PARAMS = ("S", "K", "C_f")
#: The default swarm (48 particles, 60 iterations) and polish (Levenberg-Marquardt, 40 steps).
DEFAULT_SWARM = Swarm()
DEFAULT_POLISH = Polish()


#: A recording of more cycles than this is fitted by continuation in its length: the basin
#: of its true f0 narrows as 1 / cycles (a relative f0 error of 1 / N slips a whole cycle by
#: the end), too narrow for the swarm. The swarm and a first polish fit its first
#: `FIRST_WINDOW_CYCLES` cycles; each further polish fits `WINDOW_GROWTH` times as many,
#: from the last one's point, up to the whole recording (`_stages`).
LONG_CYCLES = 24
FIRST_WINDOW_CYCLES = 16
WINDOW_GROWTH = 4
#: The fewest frames of a window.
MIN_WINDOW_FRAMES = 64

#: Most particles one device simulates side by side (one vmapped simulation). It must stay
#: within 128, whose single-precision state arrays (4 bytes a particle) fill the 512 bytes
#: under which XLA's CPU runtime runs a loop body's kernels one after another
#: (`vfjax._integrate._events._alone`): one more lane schedules them as a dataflow graph and
#: about doubles a swarm iteration's time (the profiled costs of 96 particles take 13.5 ms,
#: of 128 16.6 ms, of 136 36 ms).
MAX_LANES = 96
#: Lane counts are multiples of this: each particle then sits in a full SIMD vector of the
#: vectorised simulation (of 2, 4 or 8 doubles), where it computes the same bits whatever
#: its lane and its neighbours; in a partial vector it may round differently.
_LANE_ALIGN = 8


def lanes(n_fits: int, n_particles: int) -> int:
    """Particles a device simulates side by side for a group of ``n_fits`` fits (padded) of
    ``n_particles`` each: half of them (so a lone fit's padding partner is skipped), aligned
    to `_LANE_ALIGN`, at most `MAX_LANES`."""
    half = -(-n_fits * n_particles // 2)
    return min(MAX_LANES, _LANE_ALIGN * -(-half // _LANE_ALIGN))


def _swarm_costs(batch, active, positions, width: int):
    """The swarm cost of every particle of every fit, (fits, n, d) -> (fits, n), and the
    rest of each particle's polish point (its profiled time shift and S), (fits, n, a).

    The particles of the active fits are laid out first, fit after fit, then those of the
    others (padding fits, restarts culled: ``active`` False), and simulated ``width`` at a
    time (`lanes`; one vmapped simulation, each particle with its own fit's problem) in a
    `lax.map` of at least two chunks. A chunk of inactive fits only is skipped; an inactive
    particle's cost is inf. A particle's cost does not depend on the batch: its fit's block
    starts at a multiple of ``n`` wherever it is, so (``n`` a multiple of `_LANE_ALIGN`, as
    by default) its lane is in a full SIMD vector of a vmap of the same code whatever the
    batch and whichever fits are active."""
    n_fits, n, d = positions.shape
    n_aux = batch.n_profiled
    share = n_fits * n
    chunks = max(2, -(-share // width))
    pad = chunks * width - share
    # the active fits' particles first (a stable order: fit after fit, as laid out)
    order = jnp.argsort(~jnp.repeat(active, n), stable=True)
    x = jnp.pad(positions.reshape(share, d)[order], ((0, pad), (0, 0))).reshape(chunks, width, d)
    owner = jnp.pad(jnp.repeat(jnp.arange(n_fits), n)[order], (0, pad)).reshape(chunks, width)
    live = jnp.pad(jnp.repeat(active, n)[order], (0, pad)).reshape(chunks, width)

    def chunk(args):
        z, fit, on = args

        def run():
            problems = jax.tree.map(lambda a: a[fit], batch)
            cost, rest = jax.vmap(lambda p, zi: p.swarm_cost(zi))(problems, z)
            return jnp.where(on, cost, jnp.inf), rest

        skip = jnp.full(on.shape, jnp.inf, z.dtype), jnp.zeros(on.shape + (n_aux,), z.dtype)
        return jax.lax.cond(jnp.any(on), run, lambda: skip)

    out = jax.lax.map(chunk, (x, owner, live))

    def laid_out(a):  # back in the batch's order
        flat = a.reshape(chunks * width, *a.shape[2:])[:share]
        return jnp.zeros_like(flat).at[order].set(flat).reshape(n_fits, n, *a.shape[2:])

    return jax.tree.map(laid_out, out)


#: XLA's options for `_swarm_start`: LLVM's -O2 rather than XLA's default -O3. The program
#: is the random bits of the Latin hypercube (threefry, and the sorts of its permutations),
#: which -O3 compiles in about 1.4 s and -O2 in about 0.5 s, to the same bits
#: (`tests/test_fit.py`). The simulating programs keep XLA's default: at -O2 their
#: floating-point results differ in the last bits.
_SWARM_START_OPTIONS = {"xla_backend_optimization_level": 2}


@functools.partial(eqx.filter_jit, compiler_options=_SWARM_START_OPTIONS)
def _swarm_start(lowers, uppers, keys, swarm: Swarm, n_aux: int):
    """Every fit's swarm scattered over its box, particle 0 at the starting model, at rest
    and not yet evaluated (no simulation: the first chunk evaluates them)."""
    positions, keys = jax.vmap(lambda lo, hi, k: scatter(lo, hi, swarm.size, k, 0 * lo))(
        lowers, uppers, keys
    )
    return jax.vmap(lambda x, k: unvisited(x, k, n_aux))(positions, keys)


@program
def _swarm_chunk(batch, active, lowers, uppers, states, live, swarm: Swarm, width: int):
    def costs(x):
        return _swarm_costs(batch, active, x, width)

    return run_chunk(costs, lowers, uppers, swarm, states, live)


def _device_groups(n_batch: int) -> list:
    """The devices (`group_devices`) of the groups into which a batch of ``n_batch`` fits
    (a power of two, `batch_bucket`) is split, equal groups of consecutive fits: as many
    groups as the default backend has devices (a power of two of them) while every group
    keeps at least two fits (see `batch_bucket`). Every group runs the one-device programs,
    so a fit computes the same bits on any number of devices."""
    n = 1
    while 2 * n <= len(jax.devices()) and n_batch // (2 * n) >= 2:
        n *= 2
    return group_devices(n)


def group_devices(n: int) -> list:
    """The devices on which ``n`` groups of work compute side by side, one thread each
    (`side_by_side`): on the CPU, the default device ``n`` times, so that every group runs
    through one compiled copy of each program (a CPU executable computes in the thread that
    calls it, and the threads of one device compute at once); on other backends the first
    ``n`` devices."""
    devices = jax.devices()
    return [devices[0]] * n if devices[0].platform == "cpu" else devices[:n]


def placed(tree, device):
    """``tree`` with its array leaves on ``device`` (its other leaves as they are)."""
    arrays, rest = eqx.partition(tree, eqx.is_array)
    return eqx.combine(jax.device_put(arrays, device), rest)


def _is_key(x) -> bool:
    """Whether ``x`` is an array of typed `jax.random` keys (which NumPy cannot hold)."""
    return isinstance(x, jax.Array) and jax.dtypes.issubdtype(x.dtype, jax.dtypes.prng_key)


def _host(x) -> np.ndarray:
    """``x`` as a NumPy array; typed random keys as their key data (uint32)."""
    return np.asarray(jax.random.key_data(x)) if _is_key(x) else np.asarray(x)


def _placed_like(data: np.ndarray, like, device=None) -> jax.Array:
    """Host ``data`` on ``device`` (default: the default device, uncommitted), as typed
    random keys of ``like``'s implementation where ``like`` holds keys (`_host`'s inverse).
    Neither step compiles a program."""
    on_device = jax.device_put(data, device)
    if _is_key(like):
        return jax.random.wrap_key_data(on_device, impl=jax.random.key_impl(like))
    return on_device


def _split(tree, devices):
    """``tree``'s array leaves cut along their leading axis into ``len(devices)`` equal
    consecutive parts, the k-th placed on ``devices[k]`` (a device may be listed more than
    once; its other leaves as they are). Cut on the host, random keys as their key data: a
    device slice would compile a program per shape."""
    n = len(devices)
    leaves, treedef = jax.tree.flatten(tree)
    host = [_host(x) if eqx.is_array(x) else None for x in leaves]

    def part(k):
        def cut(x, data):
            if data is None:
                return x
            size = data.shape[0] // n
            return _placed_like(data[k * size : (k + 1) * size], x, devices[k])

        return jax.tree.unflatten(treedef, [cut(x, d) for x, d in zip(leaves, host)])

    return [part(k) for k in range(n)]


def _joined(parts):
    """The inverse of `_split`: the parts' array leaves joined along their leading axis on the
    host, as NumPy arrays (a device concatenation would compile a program per shape); random
    keys as keys on the default device."""

    def join(*xs):
        data = np.concatenate([_host(x) for x in xs])
        return _placed_like(data, xs[0]) if _is_key(xs[0]) else data

    return jax.tree.map(join, *parts)


def side_by_side(calls: Sequence[Callable]) -> list:
    """Each of ``calls`` (no arguments) run to its end, in one thread each where there are
    several (a CPU executable computes in the thread that calls it, and XLA releases the
    GIL: the calls compute at once, on one device or several), and their outputs in
    order."""

    def finished(call):
        return jax.block_until_ready(call())

    if len(calls) == 1:
        return [finished(calls[0])]
    with ThreadPoolExecutor(len(calls)) as pool:
        return list(pool.map(finished, calls))


def stack_strong(*xs):
    """The leaves stacked, without JAX's weak type (a leaf built from a Python float is
    weakly typed, one set by `VocalFoldModel.set` is not): a batch's program must not depend
    on how its models were made. Stacked on the host (a device stack would compile a program
    per shape and count), random keys as their key data."""
    return _placed_like(np.stack([_host(x) for x in xs]), xs[0])


def batch_bucket(n_fits: int) -> int:
    """The number of fits a batch of ``n_fits`` is padded to in the compiled programs: the
    next power of two, at least 2 (XLA compiles a loop of one trip, such as a lone fit's
    `lax.map`, into other code, which rounds differently). The padding fits are skipped
    (they cost no simulation)."""
    return 1 << max(int(n_fits) - 1, 1).bit_length()


#: Fits per call of the compiled polish: a batch of any size is polished
#: `POLISH_SLICE` fits at a time through one program, which therefore does not depend on
#: the batch's size (a loop of at least two trips: XLA compiles a loop of one trip into
#: other code, which rounds differently).
POLISH_SLICE = 2


def polish_slices(batch, active, found, points, from_point, polish: Polish | None):
    """`_polish_batch` of a batch (padded to a multiple of `POLISH_SLICE` fits), one slice of
    `POLISH_SLICE` fits per call, the outputs joined in the batch's order. A call polishes
    its fits to the end in one compiled solve; the host is reached between slices only."""
    n = int(active.shape[0])
    if n % POLISH_SLICE:
        raise ValueError(f"a batch of {n} fits is not a multiple of {POLISH_SLICE}")
    # the leaves as host arrays, whose slices are views (a slice of a jax.Array is an op)
    host = jax.tree.map(
        lambda x: np.asarray(x) if eqx.is_array(x) else x,
        (batch, active, found, points, from_point),
    )
    slices = []
    for start in range(0, n, POLISH_SLICE):

        def cut(x, start=start):
            return x[start : start + POLISH_SLICE] if isinstance(x, np.ndarray) else x

        slices.append(jax.tree.map(cut, host))
    # the slices dealt to the groups in turn, each group polishing its own in order
    devices = group_devices(min(len(jax.devices()), len(slices)))
    n_dev = len(devices)

    def polish_on(k):
        mine = slices[k::n_dev]
        return [_polish_batch(*placed(part, devices[k]), polish) for part in mine]

    done = side_by_side([lambda k=k: polish_on(k) for k in range(n_dev)])
    return _joined([done[i % n_dev][i // n_dev] for i in range(len(slices))])


# The polish runs the fits of a slice one after the other (`lax.map`), not side by side:
# each fit's solve is already batched over its Jacobian's columns, a vmapped solve would run
# every fit for as many steps as the slowest one, and each fit then computes exactly what it
# computes alone (a vmapped batch rounds differently from a batch of one). Padding fits
# (``active`` False) are skipped. Where a fit starts (its swarm's best or an earlier stage's
# point) is data: one program serves the first polish and every later stage of a length
# bucket. The swarm's best comes with its polish point and cost (`Problem.swarm_cost`), so
# that only an earlier stage's point is simulated before the solve.
@program
def _polish_batch(batch, active, found, points, from_point, polish: Polish | None):
    """Each fit's polish from its swarm's best ``found`` (its polish points and NMSEs) or,
    where ``from_point``, from ``points`` (full points of the polish's coordinates: an
    earlier stage's): the start's coordinates and NMSE, then (``polish`` not None) the
    solver's best point, its NMSE, steps and result."""

    def one(args):
        p, live, (y_found, cost_found), y_given, given = args

        def swarm_start():
            return y_found, cost_found

        def point_start():
            cost = jnp.sum(p.residual(y_given) ** 2)
            return y_given, jnp.where(jnp.isfinite(cost), cost, jnp.inf)

        def solve():
            y, cost = jax.lax.cond(given, point_start, swarm_start)
            if polish is None:
                return y, cost
            return (y, cost, *_polish_one(p, y, cost, polish))

        # skipped: zero coordinates, infinite costs (entries 1 and 3), no steps, result
        # code 0 ("successful")
        skip = tuple(
            jax.tree.map(
                lambda x, i=i: jnp.full(x.shape, jnp.inf if i in (1, 3) else 0, x.dtype), a
            )
            for i, a in enumerate(jax.eval_shape(solve))
        )
        return jax.lax.cond(live, solve, lambda: skip)

    return jax.lax.map(one, (batch, active, found, points, from_point))


def _survivors(costs, owner, restarts: int, factor: float) -> np.ndarray:
    """Which fits of a padded batch search on after `Swarm.cull_at` iterations: of each
    recording's ``restarts`` (``owner``: each real fit's recording), those whose swarm's
    best NMSE (``costs``) is within ``factor`` times the best of them (all of them where
    none is finite). Padding fits are never kept."""
    n = len(owner)
    keep = np.zeros(len(costs), bool)
    cost = np.where(np.isfinite(costs[:n]), costs[:n], np.inf).reshape(-1, restarts)
    best = cost.min(axis=1, keepdims=True)
    keep[:n] = ((cost <= factor * best) | ~np.isfinite(best)).ravel()
    return keep


def _check_contest(contest, n_recordings: int) -> None:
    """Refuse a ``contest`` that is not ``(groups, best)`` with a group per recording and a
    positive integer ``best`` (a float or a bool is refused, not truncated)."""
    if not isinstance(contest, Sequence) or len(contest) != 2:
        raise ValueError(f"contest must be a pair (groups, best), got {contest!r}")
    groups, best = contest
    if isinstance(groups, str) or np.ndim(groups) != 1 or len(groups) != n_recordings:
        raise ValueError(f"contest needs one group number per recording ({n_recordings})")
    if not is_count(best):
        raise ValueError(f"contest's count of fits polished must be an integer >= 1, got {best!r}")


def _contenders(costs, owner, groups, best: int) -> np.ndarray:
    """Which fits of a padded batch are polished: of each group, the ``best`` whose swarms
    ended lowest (``costs``: each fit's swarm's best NMSE, padding included; ``owner``: each
    real fit's recording; ``groups``: a group number per recording). Ties and non-finite
    costs go by order; padding fits are never chosen."""
    costs = np.asarray(costs)
    group = np.asarray(groups)[np.asarray(owner)]
    chosen = np.zeros(costs.shape[0], bool)
    for g in np.unique(group):
        members = np.flatnonzero(group == g)
        rank = np.where(np.isfinite(costs[members]), costs[members], np.inf)
        chosen[members[np.argsort(rank, kind="stable")[:best]]] = True
    return chosen


def _result_name(codes, index) -> str:
    """The optimistix result of member ``index`` of the polish's codes (`result_index`) as a
    plain string."""
    code = int(np.asarray(codes)[index])
    return RESULT_NAMES[code].removeprefix("nonlinear_") if code < len(RESULT_NAMES) else "unknown"


def _windows(recording: Recording, period: float) -> list[int]:
    """The frames one recording is fitted on, stage by stage (see `LONG_CYCLES`): the whole
    recording where it has at most `LONG_CYCLES` cycles of ``period`` (s); else windows from
    the first frame of `FIRST_WINDOW_CYCLES` cycles (at least `MIN_WINDOW_FRAMES` frames),
    growing `WINDOW_GROWTH`-fold, the last one the whole recording."""
    n = recording.n_frames
    cycles = n / recording.fps / period
    if cycles <= LONG_CYCLES:
        return [n]
    frames, k = [], 0
    while not frames or frames[-1] != n:
        span = FIRST_WINDOW_CYCLES * WINDOW_GROWTH**k
        frames.append(min(n, max(MIN_WINDOW_FRAMES, math.ceil(span * n / cycles))))
        k += 1
    return frames


def _stages(recordings, samplings) -> list[list[int]]:
    """The frames each recording is fitted on, stage by stage: each recording's own windows
    (`_windows`), as many stages as the recording with the most; a recording whose own
    windows have ended is whole at the later stages, where its fit is not polished again (so
    that it does not depend on the batch)."""
    own = [_windows(r, period) for r, (_, period) in zip(recordings, samplings)]
    return [[w[min(k, len(w) - 1)] for w in own] for k in range(max(map(len, own)))]


def fit_many(
    model: VocalFoldModel | Sequence[VocalFoldModel],
    recordings: Sequence[Recording],
    params: Sequence[str] = DEFAULT_PARAMS,
    *,
    bounds: dict | Sequence[dict | None] | None = None,
    swarm: Swarm = DEFAULT_SWARM,
    polish: Polish | None = DEFAULT_POLISH,
    warmup: float | None = None,
    substeps: int | None = None,
    key: Array | None = None,
    hold: Sequence[Sequence[str]] | None = None,
    progress: bool | None = None,
    callback: Callable[[int, float], None] | None = None,
    restarts: int = 1,
    min_batch: int = 1,
    contest: tuple[Sequence[int], int] | None = None,
) -> list[FitResult]:
    """Fit ``params`` of one model structure to many recordings as one batched job.

    Every swarm iteration simulates all particles of all fits in one vmapped call, and the
    polish runs all fits together in one compiled solve. A model with two folds
    (`vfjax.LeftRightAsymmetry`) is fitted to the recordings' per-fold areas where they have
    them (`Recording.folds`): the swarm and the polish minimise the per-fold NMSE,
    sum((dL)² + (dR)²) / sum(L² + R²), which is then the result's ``nmse``.

    The recordings may differ in length, frame rate and f0: they are padded to the longest
    one's length bucket. A recording of more than `LONG_CYCLES` cycles is fitted by
    continuation in its length: the swarm and a first polish on its first
    `FIRST_WINDOW_CYCLES` cycles, then polishes on `WINDOW_GROWTH` times as many, up to the
    whole recording. ``model`` is one model for all, or one model per recording (of one
    structure: the same terms; e.g. several starting points for one recording). Fit i's
    result depends only on its model, recording, hold, restarts and key
    ``jax.random.fold_in(key, i)``, not on the rest of the batch nor on the number of
    devices (a batch of at least four fits is split into one group per device, see the
    module).

    Arguments:
        model: the starting model(s), with every non-fitted parameter set (e.g.
            `vfjax.initial_model(recording)`); the fitted parameters' values are the centre
            of the search.
        recordings: the measured GAWs (`vfjax.Recording`).
        params: names of the parameters to fit (the paper: S, K, C_f; t_c and P_s optional).
        bounds: ``{name: (low, high)}`` in the parameter's unit, for every fit, or a list
            of such dicts (or None), one per recording; defaults: `DEFAULT_FACTORS` times
            the starting value, or `search_range`. They bound the swarm's search (and the
            projected S); the polish is a local, unconstrained refinement from the swarm's
            best.
        swarm: the global stage's settings (`Swarm`: particles, iterations, ...).
        polish: the local stage (`Polish`: an optimistix least-squares solver and its step
            budget); None: the swarm's best point.
        warmup: simulated time before the first frame (s); default: the longest
            `default_warmup` of the models.
        substeps: RK4 steps per frame (default: `vfjax.default_substeps` of each recording's
            frame rate).
        key: `jax.random` key (typed, `jax.random.key`, or raw, `jax.random.PRNGKey`); the
            same key gives the same results. Default: key(0). Or an array of keys, one per
            recording (shape ``(len(recordings),)``, raw: ``(len(recordings), 2)``): fit i
            then draws from ``key[i]`` in place of ``fold_in(key, i)``, so that a
            recording's fit is the same in any batch and at any position in it.
        hold: for each fit, names among ``params`` (S excepted) that stay at that model's
            value: fits of different parameter subsets of one model then share one batch and
            one program (the diagnosis refits every candidate effect this way). A held
            parameter is left out of its `FitResult`'s ``params``.
        progress: show a progress bar (default: on a terminal, for more than 20 iterations).
        callback: called as ``callback(iteration, best_nmse)`` after each compiled chunk of
            swarm iterations and after the polish (best NMSE over the batch).
        restarts: independent searches (swarm and polish) per recording, all in the batch;
            each recording keeps its best (`FitResult.restart_nmse` lists them all). After
            ``swarm.cull_at`` iterations a restart whose swarm lies more than
            ``swarm.cull_factor`` times behind the recording's best stops, unpolished, and
            costs no more simulations (`Swarm`).
            Restart 0 of fit i uses the key ``fold_in(key, i)`` (or ``key[i]``), restart
            r > 0 ``fold_in`` of that key and r.
        min_batch: pad the batch to at least this many fits (skipped; they cost no
            simulation), so that jobs of different sizes up to it share their programs.
        contest: ``(groups, best)``: a group number per recording, the fits of a group
            being alternatives to one another (a diagnosis's refit from several starts), and
            how many of each group are polished, those whose swarms ended lowest; the others
            keep their swarm's best point and its NMSE (``optimistix_result`` "not run"; for
            a recording fitted by continuation, whose swarm searched its first window, the
            point's NMSE on the whole recording). A fit's result still depends on its own
            group alone. None: every fit is polished.

    Returns:
        One `FitResult` per recording (timings are those of the whole batch).
    """
    t_all = time.perf_counter()
    recordings = list(recordings)
    if not recordings:
        raise ValueError("recordings is empty")
    models = [model] * len(recordings) if isinstance(model, VocalFoldModel) else list(model)
    if len(models) != len(recordings):
        raise ValueError(f"got {len(models)} models for {len(recordings)} recordings")
    structure = jax.tree.structure(models[0])
    if any(jax.tree.structure(m) != structure for m in models[1:]):
        raise ValueError("fit_many's models must share one structure (the same terms)")
    if not isinstance(swarm, Swarm):
        raise TypeError(f"swarm must be a vfjax.Swarm, got {type(swarm).__name__}")
    if polish is not None and not isinstance(polish, Polish):
        raise TypeError(f"polish must be a vfjax.Polish or None, got {type(polish).__name__}")
    hold = [()] * len(models) if hold is None else [tuple(h) for h in hold]
    if len(hold) != len(models):
        raise ValueError(f"got {len(hold)} hold lists for {len(recordings)} recordings")
    key = _typed_key(jax.random.key(0) if key is None else key)
    per_fit_keys = jnp.ndim(key) == 1
    if per_fit_keys and len(key) != len(recordings):
        raise ValueError(f"got {len(key)} keys for {len(recordings)} recordings")
    if isinstance(bounds, Sequence):
        bounds = list(bounds)
        if len(bounds) != len(recordings):
            raise ValueError(f"got {len(bounds)} bounds for {len(recordings)} recordings")
    else:
        bounds = [bounds] * len(recordings)
    if not is_count(restarts):
        raise ValueError(f"restarts must be a positive integer, got {restarts!r}")
    if contest is not None:
        _check_contest(contest, len(recordings))
    warmup = max(default_warmup(m) for m in models) if warmup is None else float(warmup)

    for r in recordings:
        if not isinstance(r, Recording):
            raise TypeError(f"recording must be a vfjax.Recording, got {type(r).__name__}")
    samplings = [fit_sampling(r, warmup, substeps) for r in recordings]
    sizes = [program_size(s) for s, _ in samplings]
    size = tuple(max(x) for x in zip(*sizes))
    with_folds = [r.folds is not None for r in recordings]
    two_folds = models[0].has(AbstractFoldPair)
    if two_folds and any(with_folds) and not all(with_folds):
        raise ValueError(
            "fit_many: some recordings have per-fold areas and some do not; a model with two "
            "folds fits them per fold: fit the two kinds in separate batches"
        )
    per_fold = two_folds and all(with_folds)
    prepared = [
        prepare(m, r, params, s, period, b, h, size, per_fold)
        for m, r, (s, period), h, b in zip(models, recordings, samplings, hold, bounds)
    ]
    if len({p.fit_s for p, _, _ in prepared}) > 1:
        raise ValueError("fit_many: S is fitted for pixel recordings only; do not mix units")
    # restarts: fit i's restarts follow each other in the batch (i * restarts + r)
    owner = np.repeat(np.arange(len(prepared)), restarts)
    boxes = [(prepared[i][1], prepared[i][2]) for i in owner]
    # the batch is padded to a power of two with copies of fit 0 that are skipped, so that
    # batches of similar sizes share their programs
    n_fits = len(owner)
    pad = batch_bucket(max(n_fits, int(min_batch))) - n_fits

    def stacked(fits):
        fits = [fits[i] for i in owner]
        return fits, jax.tree.map(stack_strong, *fits, *fits[:1] * pad)

    problems, batch = stacked([p for p, _, _ in prepared])
    # the earlier stages of a long recording's fit: its first cycles (see `LONG_CYCLES`)
    # and, per stage, which fits it polishes: those whose own windows have not ended there
    windows, polished_at = [], []
    stages = _stages(recordings, samplings)
    for frames in stages[:-1]:
        unended = np.array([n != r.n_frames for n, r in zip(frames, recordings)])
        polished_at.append(np.r_[unended[owner], np.zeros(pad, bool)])
        cut = [(dataclasses.replace(s, n_frames=n), t) for (s, t), n in zip(samplings, frames)]
        small = tuple(max(x) for x in zip(*(program_size(s) for s, _ in cut)))
        parts = zip(models, recordings, cut, hold, bounds, frames)
        windows.append(
            stacked(
                [
                    prepare(m, r.crop(0.0, n / r.fps), params, s, t, b, h, small, per_fold)[0]
                    for m, r, (s, t), h, b, n in parts
                ]
            )[1]
        )
    swarm_batch = windows[0] if windows else batch
    # the batch's arrays made on the host (on the device each would compile a program per
    # batch size)
    active = np.arange(n_fits + pad) < n_fits
    lowers = stack_strong(*[lo for lo, _ in boxes], *[boxes[0][0]] * pad)
    uppers = stack_strong(*[hi for _, hi in boxes], *[boxes[0][1]] * pad)
    # fit i's keys depend on i (and the restart) alone, not on the batch's size
    if per_fit_keys:
        key_data = _host(key)  # fit i's key read on the host (a device index compiles)
        keys = [_placed_like(key_data[i], key) for i in range(len(recordings))]
    else:
        keys = [jax.random.fold_in(key, i) for i in range(len(recordings))]
    keys = [k if r == 0 else jax.random.fold_in(k, r) for k in keys for r in range(restarts)]
    keys = stack_strong(*keys, *[keys[0]] * pad)
    program = swarm.program()

    show = progress if progress is not None else (swarm.iterations > 20 and sys.stderr.isatty())
    bar = None
    if show:
        from tqdm.auto import tqdm

        name = recordings[0].name if len(recordings) == 1 else f"{len(recordings)} recordings"
        bar = tqdm(
            total=swarm.iterations + 1 + (1 if polish else 0), desc=f"fit {name}", leave=False
        )

    # Stage 1: the swarm, in chunks, each group of fits in a thread of its own
    t0 = time.perf_counter()
    devices = _device_groups(n_fits + pad)
    width = lanes((n_fits + pad) // len(devices), swarm.size)
    n_aux = problems[0].n_profiled
    states = _split(_swarm_start(lowers, uppers, keys, program, n_aux), devices)
    groups = list(zip(*(_split(a, devices) for a in (swarm_batch, active, lowers, uppers))))
    traces, times = [], []
    done = 0  # evaluations: the initial positions, then one per iteration
    # restarts lost in another regime after `Swarm.cull_at` iterations stop (`_survivors`)
    cut = swarm.cull_at + 1 if swarm.culls(restarts) else None
    searched = active
    evaluations = np.full(n_fits + pad, swarm.iterations + 1)
    while done < swarm.iterations + 1:
        if done == cut:  # the groups' best costs, in the batch's order (`_split`'s parts)
            costs = np.concatenate([_host(st.global_cost) for st in states])
            searched = active & _survivors(costs, owner, restarts, swarm.cull_factor)
            evaluations[~searched] = cut
            groups = [
                (b, on, lo, hi) for (b, _, lo, hi), on in zip(groups, _split(searched, devices))
            ]
        live = min(swarm.chunk, swarm.iterations + 1 - done)
        live = np.int32(live if cut is None or done >= cut else min(live, cut - done))
        out = side_by_side(
            [
                lambda g=g, st=st, live=live: _swarm_chunk(*g, st, live, program, width)
                for g, st in zip(groups, states)
            ]
        )
        states = [st for st, _ in out]
        traces.append(np.concatenate([np.asarray(c) for _, c in out])[:, :live])
        now = time.perf_counter() - t_all
        times += np.linspace(times[-1] if times else 0.0, now, live + 1)[1:].tolist()
        done += int(live)
        best = float(np.min(traces[-1][:, -1]))
        if bar is not None:
            bar.update(live)
            bar.set_postfix(nmse=f"{best:.3g}")
        if callback is not None:
            callback(done - 1, best)
    pso_traces = np.concatenate(traces, axis=1)
    t_pso = time.perf_counter() - t0

    # Stage 2: the polish, `POLISH_SLICE` fits per call of one compiled solve.
    t1 = time.perf_counter()
    # each swarm's best as a polish point (its profiled shift and S beside it) and its NMSE
    states = _joined(states)
    found = (
        np.concatenate([states.global_position, states.global_aux], axis=1),
        states.global_cost,
    )
    n_y = problems[0].point_size
    no_points = np.zeros((n_fits + pad, n_y), found[0].dtype)
    from_swarm = np.zeros(n_fits + pad, bool)
    if contest is None:
        chosen = searched
    else:  # a culled restart's swarm stopped early: it contests nothing
        ranked = np.where(searched, found[1], np.inf)
        chosen = searched & _contenders(ranked, owner, *contest)
    if not windows:
        polished = polish_slices(batch, chosen, found, no_points, from_swarm, polish)
    else:
        # a long recording's own windows, each polish from the last one's point; the other
        # recordings of the batch are polished once, from the swarm's best, as alone
        long = polished_at[0]  # after the first window, from their last window's point
        points, given = no_points, from_swarm
        for stage, on in zip(windows, polished_at):
            start = polish_slices(stage, chosen & on, found, points, given, polish)
            points = np.where(on[:, None], start[2 if polish else 0], points)
            given = long
        polished = polish_slices(batch, chosen, found, points, given, polish)
    y0, c0 = (np.asarray(a) for a in polished[:2])
    if polish is not None:
        y, cost, steps = (np.asarray(a) for a in polished[2:5])
        names = [_result_name(polished[5], j) for j in range(len(problems))]
    else:
        y, cost, steps = y0, c0, np.zeros(len(problems), int)
        names = ["not run"] * len(problems)
    if contest is not None:  # the fits left out keep their swarm's best; culled ones none
        left_out = ~chosen & searched
        out = left_out[: len(problems)]
        if windows and out.any():  # a swarm's cost is its first window's: the whole one's
            found = polish_slices(batch, left_out, found, found[0], searched, None)
        point, swarm_cost = (np.asarray(a)[: len(problems)] for a in found)
        y = np.where(out[:, None], point, y[: len(problems)])
        cost = np.where(out, swarm_cost, cost[: len(problems)])
        c0 = np.where(out, swarm_cost, c0[: len(problems)])
        names = ["not run" if o else n for o, n in zip(out, names)]
    t_lm = time.perf_counter() - t1
    if bar is not None:
        bar.update(1 if polish else 0)
        bar.close()
    if callback is not None and polish is not None:
        callback(swarm.iterations + 1, float(np.min(cost)))
    times.append(times[-1])
    times.append(time.perf_counter() - t_all)

    timings = {
        "pso_s": t_pso,
        "lm_s": t_lm,
        "total_s": time.perf_counter() - t_all,
        "batch_size": len(recordings),
    }
    results = []
    for i, rec in enumerate(recordings):
        runs = np.flatnonzero(owner == i)
        j = int(runs[np.argmin(np.where(np.isfinite(cost[runs]), cost[runs], np.inf))])
        problem, (lo, hi) = problems[j], boxes[j]
        fitted, shift = problem.unpack(jnp.asarray(y[j]))
        fitted_names = tuple(n for n in params if n not in hold[i])
        values = fitted.params()
        box = {n: b for n, b in bounds_in_units(problem, lo, hi).items() if n in fitted_names}
        # a value at its physical floor (a gap of 0) is not at a bound; P_s at the edge of
        # its plausible range is
        floors = {
            n: f for n, f in zip(problem.names, np.asarray(problem.floor)) if n not in PLAUSIBLE
        }
        status, of_mean = fit_status(rec.area, float(cost[j]), values, box, floors)
        units = fitted.parameter_units()
        n_sims = sum(
            swarm.size * int(evaluations[r]) + 1 + int(steps[r]) * (1 + y.shape[1]) for r in runs
        )
        results.append(
            FitResult(
                params={n: float(values[n]) for n in fitted_names},
                units={n: units[n] for n in fitted_names},
                time_shift=shift,
                nmse=float(cost[j]),
                sampling=samplings[i][0],
                bounds=box,
                swarm=swarm,
                pso_trace=pso_traces[j].tolist(),
                lm_trace=[float(c0[j]), float(cost[j])],
                timings=timings,
                trace_times=list(times),
                n_simulations=n_sims,
                optimistix_result=names[j],
                model=fitted,
                recording_name=rec.name,
                status=status,
                nmse_of_mean=of_mean,
                restart_nmse=[float(cost[r]) if np.isfinite(cost[r]) else None for r in runs],
            )
        )
    return results


def _typed_key(key):
    """``key`` as a typed `jax.random` key (array): a raw key of `jax.random.PRNGKey`
    (uint32, shape ``(2,)``, or ``(n, 2)`` for one per recording) is wrapped, so that a raw
    key is one key, not two keys of one number each."""
    key = jnp.asarray(key)
    if _is_key(key):
        return key
    if key.dtype != jnp.uint32 or key.ndim not in (1, 2) or key.shape[-1] != 2:
        raise TypeError(
            "key must be a jax.random key (jax.random.key or jax.random.PRNGKey), or an "
            f"array of them, got {key.dtype} of shape {key.shape}"
        )
    return jax.random.wrap_key_data(key)


def fit(
    model: VocalFoldModel,
    recording: Recording,
    params: Sequence[str] = DEFAULT_PARAMS,
    **options,
) -> FitResult:
    """Fit ``params`` of ``model`` to ``recording``: a particle swarm, then a polish.

    `fit_many` of one recording: the same options (``bounds``, ``swarm``, ``polish``,
    ``warmup``, ``substeps``, ``key``, ``progress``, ``callback``, ``restarts``) and the same
    compiled programs; see there. `vfjax.fit_recording` is a recording's first fit (P_s
    searched, a wider box, restarts).
    """
    refuse_batch_options("fit", options)
    return fit_many(model, [recording], params, **options)[0]


def refuse_batch_options(caller: str, options: dict) -> None:
    """A TypeError if ``options`` of a one-recording fit (``caller``) hold one of
    `fit_many`'s batch options (``hold``, ``min_batch``, ``contest``)."""
    for name in ("hold", "min_batch", "contest"):
        if name in options:
            raise TypeError(f"{caller} takes no {name!r} (that is fit_many's, for batches)")
