"""A fit's problem: the recording, the model, and the coordinates the search moves in.

Parameters are searched in O(1) coordinates: log(p / p_ref) for each fitted physical
parameter whose value is positive, (p - p_ref) / scale for those whose off-value is 0 or that
may be negative (`search_range`), and time_shift / T0 for the shift (T0: the recording's cycle
length, from its f0). Two parameters are profiled out of the swarm's search: the scale S,
which enters the GAW linearly, is solved in closed form per particle (variable projection),
and the time shift, periodic and so highly multimodal, is chosen per particle on a grid of
shifts half a frame apart, read from the same simulation's dense output.

Everything that depends on the recording (its samples, frame rate, warm-up, shift range,
starting values, bounds) is data, and so is which parameters are fitted: a problem carries
every parameter of `PROGRAM_PARAMETERS` that its model has, those not fitted held at their
values, so that fits of any of them (and S) share one compiled program per model structure
and length bucket.
"""

import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._integrate import (
    SampledGrid,
    integrate_window,
    integrate_window_single,
    left_share,
    sample_window,
    sampled_grid,
    simulate_frames,
    window_size,
)
from .._programs import program
from .._sampling import Sampling, length_bucket
from ..descriptors import fundamental_frequency
from ..model import VocalFoldModel
from ..recording import Recording

#: Default search box per parameter, as factors of the starting value.
DEFAULT_FACTORS = {
    "K": (0.4, 2.5),
    "C_f": (0.05, 20.0),
    "t_c": (0.25, 4.0),
    "P_s": (0.5, 2.0),
    "S": (0.1, 10.0),
}
#: The subglottal pressures (dyne/cm²) of phonation, about 1 to 30 cm H2O, from below the
#: phonation threshold to loud voice: a first fit searches them when the recording states
#: none, and no fit (swarm or polish) moves P_s outside them, or outside its starting value
#: and the fit's bounds where those lie beyond.
PRESSURE_RANGE = (1000.0, 30000.0)
#: Physical limits of a fitted parameter that its search coordinate alone does not keep.
PLAUSIBLE = {"P_s": PRESSURE_RANGE}
#: Parameters searched in linear coordinates (their off-value is 0, or they may be negative):
#: name -> (default low, default high, scale), in the parameter's unit. Any other parameter
#: whose starting value is 0 is searched linearly too, with the entry here or (0, 1, 0.1).
LINEAR = {
    "a_gap": (0.0, 0.05, 0.01),
    "eta": (-3000.0, 3000.0, 500.0),
    "tau": (0.0, 1e-3, 2e-4),
    "fs_strength": (0.0, 3.0, 0.5),
    "a_pm": (0.0, 0.5, 0.05),
    "phi": (-math.pi, math.pi, 1.0),
    "f_m": (0.5, 30.0, 5.0),
    "t_c": (0.0, 0.01, 1e-3),
    "C_min": (0.0, 500.0, 50.0),
}

#: The physical parameters whose fit never changes the compiled program: every problem
#: carries those of them that its model has, the ones not fitted held at their values (their
#: search interval [0, 0]), so that fits of any subset of them share one program. A fitted
#: parameter outside them (an effect's) joins them, in the model's order of parameters.
PROGRAM_PARAMETERS = ("K", "C_f", "t_c", "P_s")

#: Simulated time before the first frame (s) of a fit whose terms need no more.
WARMUP = 0.02
#: The largest time shift of a fit: this many cycles of the recording's f0, rounded up to a
#: multiple of `SHIFT_STEP` (a recording made with a slow modulation or drift is not periodic,
#: so a shift beyond one cycle can still fit better).
SHIFT_CYCLES = 1.25
SHIFT_STEP = 0.005
_SHIFTS_PER_FRAME = 2  # the swarm tries time shifts half a frame apart
_AREA_TO_PX_SCALE = {"mm2": 1.0, "cm2": 0.01}  # S that turns model mm² per mm² into the unit


def default_warmup(model: VocalFoldModel) -> float:
    """The warm-up (s) a fit of ``model`` uses by default: `WARMUP`, or the longest that one
    of its terms needs (``min_warmup``, e.g. 0.1 s for a pressure modulation)."""
    return max([WARMUP] + [float(type(t).min_warmup) for t in model.terms])


def plausible_range(name: str, *values: float) -> tuple[float, float]:
    """``name``'s `PLAUSIBLE` interval, widened to hold ``values`` (a starting value, the
    bounds a user gave)."""
    low, high = PLAUSIBLE[name]
    return min(low, *values), max(high, *values)


def search_range(model: VocalFoldModel, name: str) -> tuple[float, float, float] | None:
    """(low, high, scale) of a linearly searched parameter, in its unit: the term's own
    ``ranges`` entry, else `LINEAR`'s, else None."""
    for term in model.terms:
        if name in term.parameters and name in getattr(term, "ranges", {}):
            return tuple(float(v) for v in term.ranges[name])
    return LINEAR.get(name)


class Problem(eqx.Module):
    """One fit as a pytree: every array is data (vmappable over a batch of fits); the static
    fields fix the compiled program."""

    model: VocalFoldModel
    grid: SampledGrid
    measured: jax.Array  # (frames bucket,) the GAW, zero beyond the recording
    counted: jax.Array  # (frames bucket,) 1 for a frame of the recording, 0 for padding
    reference: jax.Array  # (n_params,) starting values of the non-S fitted parameters
    scale: jax.Array  # (n_params,) coordinate scale of the linear ones (unused for log ones)
    floor: jax.Array  # (n_params,) physical lower limit (-inf: none)
    ceiling: jax.Array  # (n_params,) physical upper limit (inf: none)
    free: jax.Array  # (n_params,) 1 for a fitted parameter, 0 for a held one
    linear: jax.Array  # (n_params,) True: linear coordinate, False: log(p / p_ref)
    s_reference: jax.Array  # () starting (or fixed) S
    period: jax.Array  # () T0 estimate (s)
    s_bounds: jax.Array  # (2,) search bounds of S (px/mm²)
    difference: jax.Array  # (frames bucket,) left minus right fold's area (per-fold fits)
    names: tuple = eqx.field(static=True)  # `program_names`: S excluded, held ones included
    fit_s: bool = eqx.field(static=True)
    n_out: int = eqx.field(static=True)  # frames bucket
    n_rows: int = eqx.field(static=True)  # dense-output rows
    n_shifts: int = eqx.field(static=True)  # shifts the swarm tries (a bucket)
    per_fold: bool = eqx.field(static=True, default=False)  # fit the folds' areas

    @property
    def point_size(self) -> int:
        """Length of a polish point: the physical coordinates, the time shift (in periods)
        and, if S is fitted, log(S / S_ref)."""
        return len(self.names) + 1 + int(self.fit_s)

    def model_at(self, z, log_s=None):
        """The model at coordinates ``z`` (physical parameters first; S at ``log_s``)."""
        # each value is clipped to its physical limits (a gap or a delay cannot be negative,
        # P_s stays within `PLAUSIBLE`), so that an unconstrained polish step stays physical;
        # a held parameter's coordinate is multiplied by 0: it stays at its reference value
        z = z[: len(self.names)] * self.free
        # both coordinates computed, one kept (the exponent of a linear one set to 0, so that
        # neither it nor its derivative overflows)
        on_scale = self.reference + self.scale * z
        in_log = self.reference * jnp.exp(jnp.where(self.linear, 0.0, z))
        values = jnp.clip(jnp.where(self.linear, on_scale, in_log), self.floor, self.ceiling)
        values = {n: values[i] for i, n in enumerate(self.names)}
        s = self.s_reference if log_s is None else self.s_reference * jnp.exp(log_s)
        return self.model.set(**values, S=s)

    def shift(self, z):
        """The time shift (s) of coordinates ``z``."""
        return z[len(self.names)] * self.period

    def simulate(self, model, shift):
        """`simulate_frames` of ``model`` on this problem's sampling."""
        return simulate_frames(model, self.grid, shift, n_out=self.n_out, n_rows=self.n_rows)

    def shape(self, z, integration=None):
        """Simulated GAW at S = 1 (clipped at 0, zero on padding) and whether it is valid;
        for a per-fold fit, the left minus the right fold's area too (else None).
        ``integration``: the model's `integrate_window` at ``z`` where already computed (the
        frames' time shift moves them over one integration)."""
        model = self.model_at(z).set(S=1.0)
        if integration is None:
            integration = integrate_window(model, self.grid, n_rows=self.n_rows)
        sim = sample_window(model, self.grid, self.shift(z), integration, n_out=self.n_out)
        ok = sim.complete
        g = jnp.maximum(jnp.where(ok, sim.area, 0.0), 0.0)
        if not self.per_fold:
            return g, None, ok
        # left minus right, as the swarm's profile reads it
        share = left_share(model, sim.dense, sim.time, sim.displacement)
        return g, g * (2.0 * share - 1.0), ok

    def projected_scale(self, mg, gg):
        """The S minimising the squared error of a shape g (closed form), kept within its
        bounds, from the products ``mg`` = measured . g and ``gg`` = g . g (any shape,
        elementwise)."""
        if not self.fit_s:
            return jnp.broadcast_to(self.s_reference, jnp.shape(mg))
        s = mg / jnp.maximum(gg, 1e-300)
        return jnp.clip(s, self.s_bounds[0], self.s_bounds[1])

    def profile(self, z_phys):
        """Best cost over the grid of time shifts, S projected for each; returns (cost, shift
        as a fraction of T0, projected S).

        One simulation serves every shift. The shifts are half a frame apart, so every
        shifted frame time lies on one regular grid of half-frame spacing: the observed area
        is read from the dense output once on that grid, and the products that the
        projected S and the cost need at every shift are correlations of the measured GAW
        with the grid's even and odd samples. (Observation terms act pointwise in time.)"""
        model = self.model_at(jnp.concatenate([z_phys, jnp.zeros(1)])).set(S=1.0)
        integration = integrate_window_single(model, self.grid, n_rows=self.n_rows)
        sim = sample_window(model, self.grid, 0.0, integration, n_out=self.n_out)
        ok = sim.complete
        q, n = _SHIFTS_PER_FRAME, self.n_shifts
        length = q * (-(-n // q) + self.n_out - 1)  # whole rows of q samples
        times = self.grid.t_start + jnp.arange(length) / (q * self.grid.fps)
        x = sim.dense.displacement(times)
        fine = model.observe(times, x, sim.dense.displacement)
        fine = jnp.maximum(jnp.where(ok, fine, 0.0), 0.0)
        # shift j = q a + b reads the frames from parity[b][a:]: correlations over a
        parity = fine.reshape(-1, q).T
        rows = parity.shape[1]

        def per_shift(signal, kernel):
            # by FFT: a convolution whose kernel is batched (the measured GAW of each fit of
            # a batch) is a grouped convolution, slow in XLA; rows >= a + k for every term
            # of the valid correlation, so no product wraps around
            spectrum = jnp.fft.rfft(signal, rows) * jnp.conj(jnp.fft.rfft(kernel, rows))
            out = jnp.fft.irfft(spectrum, rows)[:, : rows - self.n_out + 1]
            return out.T.reshape(-1)[:n]

        mg = per_shift(parity, self.measured)
        gg = per_shift(parity**2, self.counted)
        mm = jnp.sum(self.measured**2)
        if self.per_fold:
            # the folds' difference, left minus right, correlated alike (one S for both)
            diff = (fine * (2.0 * left_share(model, sim.dense, times, x) - 1.0)).reshape(-1, q).T
            mg = mg + per_shift(diff, self.difference)
            gg = gg + per_shift(diff**2, self.counted)
            mm = mm + jnp.sum(self.difference**2)
        s = self.projected_scale(mg, gg)
        costs = jnp.maximum(mm - 2.0 * s * mg + s * s * gg, 0.0) / mm
        shifts = jnp.arange(n) / (q * self.grid.fps)
        costs = jnp.where(shifts <= self.grid.max_time_shift + 1e-12, costs, jnp.inf)
        i = jnp.argmin(costs)
        return jnp.where(ok, costs[i], jnp.inf), shifts[i] / self.period, s[i]

    def swarm_cost(self, z_phys):
        """The swarm's cost of a point of the physical parameters (shift and S profiled),
        and the rest of its polish point (`start`'s: the shift and log(S / S_ref))."""
        y, cost = self.start(z_phys)
        return cost, y[z_phys.shape[0] :]

    @property
    def n_profiled(self) -> int:
        """The polish point's coordinates that the swarm's profile finds: the time shift
        and, if fitted, log(S / S_ref)."""
        return 2 if self.fit_s else 1

    def residual(self, y, integration=None):
        """Residuals whose sum of squares is the NMSE; y = (z..., log S) or z.
        ``integration``: as for `shape`.

        A per-fold fit's residuals are those of the total and of the left minus the right
        fold's area, over the norm of both: their sum of squares is the per-fold NMSE,
        sum((dL)² + (dR)²) / sum(L² + R²)."""
        z = y[: len(self.names) + 1]
        s = self.s_reference * jnp.exp(y[-1]) if self.fit_s else self.s_reference
        g, diff, ok = self.shape(z, integration)
        r = self.counted * (s * g - self.measured)
        norm = jnp.sum(self.measured**2)
        if self.per_fold:
            r = jnp.concatenate([r, self.counted * (s * diff - self.difference)])
            norm = norm + jnp.sum(self.difference**2)
        # outside the valid range: a large, finite residual (the polish rejects the step)
        return jnp.where(ok, r / jnp.sqrt(norm), jnp.tile(self.counted, r.size // self.n_out))

    def residual_and_jacobian(self, y, basis):
        """The residual at ``y`` and its derivatives along the rows of ``basis`` as columns
        (forward mode): ``(residual, (len(residual), len(basis)))``.

        The last ``point_size - len(names)`` rows of ``basis`` must not move a physical
        coordinate (they move the time shift, log S or nothing); the others may move any
        (every search basis has the free physical coordinates first, then the time shift
        and S, then any zero rows of padding).

        Neither the shift nor S changes the integration, which only samples it later: the
        integration is differentiated along the rows but the last (one batched jvp, a
        tangent per row), then the sampling along every row, with the integration's tangents
        (zero for the last rows). The columns are those of one jvp through both, bit for
        bit, with two fewer tangents through the integrator (a fit's Jacobian of four
        physical parameters: about a quarter less time)."""
        n = len(self.names)
        m = self.point_size - n  # the time shift and log S

        def motion(point):
            """The integration's inexact leaves (differentiated), the rest as aux."""
            model = self.model_at(point[: n + 1]).set(S=1.0)
            integration = integrate_window(model, self.grid, n_rows=self.n_rows)
            return eqx.partition(integration, eqx.is_inexact_array)

        physical = basis[:-m].at[:, n:].set(0.0)
        moving, moved, fixed = jax.vmap(
            lambda t: jax.jvp(motion, (y,), (t,), has_aux=True), out_axes=(None, 0, None)
        )(physical)
        # the last rows move the motion not at all
        moved = jax.tree.map(
            lambda d: jnp.concatenate([d, jnp.zeros((m,) + d.shape[1:], d.dtype)]), moved
        )

        def sampled(point, motion):
            return self.residual(point, eqx.combine(motion, fixed))

        return jax.vmap(lambda t, d: jax.jvp(sampled, (y, moving), (t, d)), out_axes=(None, 1))(
            basis, moved
        )

    def start(self, z_phys):
        """Swarm point (physical parameters) -> polish point (with its best grid shift and,
        if fitted, log(S / S_ref) of the projected S) and its cost."""
        cost, shift, s = self.profile(z_phys)
        y = jnp.concatenate([z_phys, shift[None]])
        if self.fit_s:
            y = jnp.concatenate([y, jnp.log(s / self.s_reference)[None]])
        return y, cost

    def unpack(self, y) -> tuple[VocalFoldModel, float]:
        """The fitted model and time shift (s) at the point ``y`` (one fit, concrete)."""
        z = y[: len(self.names) + 1]
        return self.model_at(z, y[-1] if self.fit_s else None), float(self.shift(z))


@program
def start_point(problem: Problem, z):
    """`Problem.start` of the search point ``z`` as one compiled program (stored across
    processes): its polish point, with the best time shift of the grid and the projected S,
    and its NMSE."""
    return problem.start(z)


def program_names(model: VocalFoldModel, params) -> tuple[str, ...]:
    """The physical parameters of a problem fitting ``params`` of ``model`` (S excluded):
    those of `PROGRAM_PARAMETERS` the model has, in that order, then the other fitted ones
    in the model's order of parameters. Fits of one model structure whose fitted parameters
    lie among the same names share one compiled program."""
    units = model.parameter_units()
    core = tuple(n for n in PROGRAM_PARAMETERS if n in units)
    return core + tuple(n for n in units if n in params and n not in core and n != "S")


def program_size(sampling: Sampling) -> tuple[int, int, int]:
    """The static sizes of a fit's program for ``sampling``: (frames, dense rows, shifts)."""
    n_out, n_rows = window_size(sampling)
    shifts = _SHIFTS_PER_FRAME * length_bucket(sampling.shift_frames + 1) + 1
    return n_out, n_rows, shifts


def _is_linear(model, name, ref, bounds=None):
    """Whether ``name`` is searched in linear coordinates: an effect's parameter with a
    default range (`LINEAR`), one that starts at 0, or one whose given box starts at 0 or
    below (a closure duration searched from no hold at all); else in log coordinates."""
    if bounds and name in bounds and bounds[name][0] <= 0:
        return True
    ranged = search_range(model, name) is not None
    return ranged and (ref == 0.0 or name not in ("t_c", "C_min")) or ref == 0.0


def _bounds(names, model, bounds):
    params = model.params()
    lo, hi = [], []
    for n in names:
        ref = float(params[n])
        if _is_linear(model, n, ref, bounds):
            a, b, scale = search_range(model, n) or (0.0, 1.0, 0.1)
            # a warm start may sit outside a term's default range (a phase past pi after a
            # polish): the default range then widens to include it; a user's bounds do not
            a, b = min(a, ref), max(b, ref)
            if bounds and n in bounds:
                a, b = bounds[n]
            if not (a <= ref <= b and a < b):
                raise ValueError(
                    f"bounds for {n} must satisfy low <= start ({ref}) <= high, got {(a, b)}"
                )
            lo.append((a - ref) / scale)
            hi.append((b - ref) / scale)
        elif bounds and n in bounds:
            a, b = bounds[n]
            if not (0 < a <= ref <= b and a < b):
                raise ValueError(
                    f"bounds for {n} must satisfy 0 < low <= start ({ref}) <= high and "
                    f"low < high, got {bounds[n]}"
                )
            lo.append(math.log(a / ref))
            hi.append(math.log(b / ref))
        else:
            fa, fb = DEFAULT_FACTORS.get(n, (0.2, 5.0))
            lo.append(math.log(fa))
            hi.append(math.log(fb))
    return np.array(lo), np.array(hi)


def _limits(names, model, bounds) -> tuple[np.ndarray, np.ndarray]:
    """Physical limits (floor, ceiling) of each fitted parameter: 0 from below for a linearly
    searched one whose range starts at 0 or above, `PLAUSIBLE`'s interval (widened to hold
    the starting value and the fit's bounds) where it has one, else none."""
    params = model.params()
    floor, ceiling = [], []
    for n in names:
        low, high = -np.inf, np.inf
        if (search_range(model, n) or (-1.0,))[0] >= 0:
            low = 0.0
        if n in PLAUSIBLE:
            ref = float(params[n])
            low, high = plausible_range(n, ref, *(float(v) for v in (bounds or {}).get(n, ())))
        floor.append(low)
        ceiling.append(high)
    return np.array(floor), np.array(ceiling)


def bounds_in_units(problem: Problem, lower, upper) -> dict:
    """The search box {name: [low, high]} in the parameters' units (S included if fitted),
    of one unbatched problem: the coordinates' box within the parameters' physical limits."""
    out = {}
    # host copies: indexing the problem's device arrays would run an operation per entry
    columns = (problem.linear, problem.reference, problem.scale, problem.floor, problem.ceiling)
    rows = zip(problem.names, np.asarray(lower), np.asarray(upper), *map(np.asarray, columns))
    for n, a, b, linear, ref, scale, floor, ceiling in rows:
        if linear:
            low, high = ref + scale * float(a), ref + scale * float(b)
        else:
            low, high = ref * math.exp(float(a)), ref * math.exp(float(b))
        out[n] = [float(min(max(low, floor), ceiling)), float(max(min(high, ceiling), floor))]
    if problem.fit_s:
        out["S"] = [float(v) for v in np.asarray(problem.s_bounds)]
    return out


def fit_sampling(
    recording: Recording, warmup: float, substeps: int | None
) -> tuple[Sampling, float]:
    """The `Sampling` of a fit of ``recording`` and the recording's cycle length T0 (s);
    ``substeps`` None: `Sampling`'s default for the recording's frame rate."""
    f0 = fundamental_frequency(recording.area, recording.fps)
    if not np.isfinite(f0):
        raise ValueError(
            f"{recording.name}: fewer than two glottal cycles found in {recording.n_frames} "
            "frames; a fit needs at least one full cycle"
        )
    period = 1.0 / f0
    sampling = Sampling(
        recording.fps,
        recording.n_frames,
        substeps=substeps,
        warmup=warmup,
        max_time_shift=math.ceil(SHIFT_CYCLES * period / SHIFT_STEP - 1e-9) * SHIFT_STEP,
    )
    return sampling, period


def prepare(model, recording, params, sampling, period, bounds, held=(), size=None, per_fold=False):
    """A `Problem` for fitting ``params`` of ``model`` to ``recording`` and its search box
    (lower, upper) in the search coordinates. ``size``: the program's static sizes
    (`program_size`; default: those of ``sampling``). ``per_fold``: fit the recording's
    per-fold areas (`Recording.folds`) as well as the total."""
    params = tuple(params)
    model.check_step(sampling.step)
    units = model.parameter_units()
    unknown = [n for n in params if n not in units]
    if unknown:
        raise ValueError(f"cannot fit {unknown}: the model's parameters are {sorted(units)}")
    if len(set(params)) != len(params) or not params:
        raise ValueError(f"params must be distinct parameter names, got {params}")
    if float(np.sum(recording.area**2)) == 0.0:
        raise ValueError("the recording's area is zero everywhere: there is nothing to fit")
    fit_s = "S" in params
    if recording.unit != "px":
        if fit_s:
            raise ValueError(
                f"S converts model mm² to pixels; the recording is in "
                f"{recording.unit}, so S is fixed and cannot be fitted"
            )
        model = model.set(S=_AREA_TO_PX_SCALE[recording.unit])
    held = tuple(held)
    if any(n not in params or n == "S" for n in held):
        raise ValueError(
            f"only fitted parameters other than S can be held, got {held} for params {params}"
        )
    names = program_names(model, params)
    # the program's parameters that are not fitted are held at the model's values; bounds
    # apply to the fitted ones
    held += tuple(n for n in names if n not in params)
    bounds = {n: b for n, b in (bounds or {}).items() if n in params and n not in held}
    lo, hi = _bounds(names, model, bounds)
    floor, ceiling = _limits(names, model, bounds)
    free = np.array([n not in held for n in names], dtype=float)
    lo, hi = lo * free, hi * free  # a held parameter's search interval is [0, 0]
    values = {n: float(v) for n, v in model.params().items() if np.ndim(v) == 0}
    s_ref = values["S"]
    if fit_s:
        s_lo, s_hi = _bounds(("S",), model, bounds)
        s_bounds = np.exp(np.r_[s_lo, s_hi]) * s_ref
    else:
        s_bounds = np.array([0.0, np.inf])
    n_out, n_rows, n_shifts = size or program_size(sampling)
    measured = np.zeros(n_out)
    measured[: recording.n_frames] = recording.area
    difference = np.zeros(n_out)
    if per_fold:
        if recording.folds is None:
            raise ValueError(f"{recording.name}: a per-fold fit needs the recording's folds")
        difference[: recording.n_frames] = recording.folds[:, 0] - recording.folds[:, 1]
    problem = Problem(
        model=model,
        grid=sampled_grid(sampling),
        # placed, not converted: `jnp.asarray` of a NumPy array or a list compiles a program
        # per shape (the two scalars stay weakly typed, as a Python float makes them)
        measured=_placed(measured),
        counted=_placed((np.arange(n_out) < recording.n_frames).astype(float)),
        reference=_placed([values[n] for n in names], float),
        scale=_placed([(search_range(model, n) or (0.0, 1.0, 0.1))[2] for n in names], float),
        floor=_placed(floor, float),
        ceiling=_placed(ceiling, float),
        free=_placed(free),
        linear=_placed([_is_linear(model, n, values[n], bounds) for n in names], bool),
        s_reference=jnp.asarray(s_ref),
        period=jnp.asarray(period),
        s_bounds=_placed(s_bounds, float),
        difference=_placed(difference),
        names=names,
        fit_s=fit_s,
        n_out=n_out,
        n_rows=n_rows,
        n_shifts=n_shifts,
        per_fold=bool(per_fold),
    )
    return problem, _placed(lo, float), _placed(hi, float)


def _placed(values, dtype=None) -> jax.Array:
    """Host values (a NumPy array, a list) as an array on the default device, without the
    small conversion program that `jnp.asarray` of host data compiles per shape."""
    return jax.device_put(np.asarray(values, dtype))
