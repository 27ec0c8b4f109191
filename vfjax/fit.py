"""Fitting the model to a measured GAW: a batched particle swarm, then Levenberg-Marquardt.

Protocol (the paper gives none). A recording starts at an arbitrary point of the glottal
cycle, while the model starts from rest at contact. vfjax simulates ``warmup`` seconds to reach
the limit cycle (20 ms, or longer where a term of the model needs it: `default_warmup`) and
then samples the recording's frames from ``warmup + time_shift``, where
the time shift is a fitted, differentiable parameter in [0, ~1.25 T0] (T0: the recording's
cycle length, from its f0). Parameters are searched in O(1) coordinates: log(p / p_ref) for
each fitted physical parameter, and time_shift / T0 for the shift.

Stage 1, global: particle swarm optimisation (PSO). The whole swarm is simulated as one
vmapped call per iteration. Two parameters are profiled out of the swarm's search: the scale
S enters the GAW linearly, so for each particle it is solved in closed form (variable
projection); and the time shift, periodic and so highly multimodal, is chosen per particle on
a grid of 48 shifts read from the same simulation's dense output. The swarm searches only the
physical parameters (K, C_f, ...).
Stage 2, local: `optimistix.LevenbergMarquardt` on the residual vector (forward-mode Jacobian
through the simulator, whose event times carry their derivatives), S included. The best point
seen is kept, so the polish never returns anything worse than the swarm's best.

Cost: NMSE = sum((A_exp - A_sim)²) / sum(A_exp²) (`vfjax.cost`). The simulated GAW is clipped at
zero area before it is compared: a camera sees no negative area.
"""

import dataclasses
import math
import sys
import time
from collections.abc import Callable, Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx

from .descriptors import fundamental_frequency
from .integrator import DEFAULT_SUBSTEPS, simulate
from .model import VocalFoldModel
from .pso import SwarmSettings, init_swarm, run_chunk
from .recording import Recording

#: Default search box per parameter, as factors of the starting value.
DEFAULT_FACTORS = {
    "K": (0.4, 2.5),
    "C_f": (0.05, 20.0),
    "t_c": (0.25, 4.0),
    "P_s": (0.5, 2.0),
    "S": (0.1, 10.0),
}
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

#: Simulated time before the first frame (s) of a fit whose terms need no more.
WARMUP = 0.02


def default_warmup(model: VocalFoldModel) -> float:
    """The warm-up (s) a fit of ``model`` uses by default: `WARMUP`, or the longest that one
    of its terms needs (``min_warmup``, e.g. 0.1 s for a pressure modulation)."""
    return max([WARMUP] + [float(type(t).min_warmup) for t in model.terms])


def search_range(model: VocalFoldModel, name: str) -> tuple[float, float, float] | None:
    """(low, high, scale) of a linearly searched parameter: the term's own ``ranges`` entry,
    else `LINEAR`'s, else None."""
    for term in model.terms:
        if name in term.parameters and name in getattr(term, "ranges", {}):
            return tuple(float(v) for v in term.ranges[name])
    return LINEAR.get(name)


_SHIFT_GRID = 0.005  # s: the largest time shift is rounded up to a multiple of this
_SHIFTS_PER_FRAME = 2  # the swarm tries time shifts half a frame apart
_DEFAULT_SWARM = SwarmSettings()
_AREA_TO_PX_SCALE = {"mm2": 1.0, "cm2": 0.01}  # S that turns model mm² per mm² into the unit


@dataclasses.dataclass
class FitResult:
    """The outcome of `fit`.

    Attributes:
        params: fitted parameter values by name, in the model's units (``units``).
        units: unit of each parameter.
        time_shift: fitted sampling delay after the warm-up (s).
        nmse: normalised squared error of the fitted GAW.
        pso_trace: best NMSE after each PSO iteration (index 0: the initial swarm).
        lm_trace: best NMSE after each Levenberg-Marquardt step (index 0: the start).
        trace_times: wall time (s since the fit began) of each entry of ``pso_trace`` followed
            by each entry of ``lm_trace`` (PSO iterations within a jitted chunk are spread
            evenly over the chunk's time).
        timings: wall time of each stage (s), compilation included, and the compile time.
        n_simulations: simulated recordings (a Jacobian counts as one per column).
        optimistix_result: the polish's result code ("successful", "max_steps_reached", ...).
        settings: the fit's settings (fitted names, bounds, swarm, warm-up, ...).
        model: the fitted model.
        recording_name: the recording's name.
        status: whether the fit can be trusted (`FIT_STATUSES`): "successful"; "at_bound"
            (a parameter ended at an edge of its search box: the box does not hold the
            optimum, widen it with ``bounds``); "worse_than_mean" (the fit explains the
            recording less well than its mean, a constant, does); "not_finite"; "unknown"
            (read from a file of an earlier format).
        nmse_of_mean: NMSE of the recording's mean as a constant waveform: the error of a
            model that explains nothing, which a fit must beat.
    """

    params: dict
    units: dict
    time_shift: float
    nmse: float
    pso_trace: list
    lm_trace: list
    timings: dict
    trace_times: list
    n_simulations: int
    optimistix_result: str
    settings: dict
    model: VocalFoldModel | None = None
    recording_name: str = ""
    status: str = "successful"
    nmse_of_mean: float | None = None

    @property
    def failed(self) -> bool:
        """Whether the fit failed (``status`` is neither "successful" nor "unknown")."""
        return self.status not in ("successful", "unknown")

    def status_message(self) -> str:
        """The status in words, naming the parameters at their bounds."""
        if self.status == "at_bound":
            edges = []
            for name, (low, high) in self.settings.get("bounds", {}).items():
                value = self.params.get(name)
                if value is not None and _at_edge(value, low, high):
                    edges.append(
                        f"{name} = {value:.6g} {self.units.get(name, '')} at the edge "
                        f"of its search box [{low:.6g}, {high:.6g}]"
                    )
            return (
                "failed: "
                + "; ".join(edges or ["a parameter at its bound"])
                + ": the box does not hold the optimum (widen it with bounds=...)"
            )
        if self.status == "worse_than_mean":
            return (
                f"failed: NMSE {self.nmse:.4g} is no better than the recording's mean as a "
                f"constant ({self.nmse_of_mean:.4g}): the model does not describe this "
                "waveform (check the area unit, the frame rate and the starting model)"
            )
        if self.status == "not_finite":
            return "failed: the fitted error is not finite (the simulation failed)"
        return self.status

    def simulate(self, recording: Recording):
        """The fitted model's `Simulation` on the recording's frames."""
        return simulate(
            self.model,
            recording.fps,
            recording.n_frames,
            substeps=self.settings["substeps"],
            t_start=self.settings["warmup"],
            time_shift=self.time_shift,
            max_time_shift=self.settings["max_time_shift"],
            throw=False,
        )

    def fitted_gaw(self, recording: Recording) -> np.ndarray:
        """The fitted GAW on the recording's frames, clipped at zero, in the recording's unit."""
        return np.clip(np.asarray(self.simulate(recording).area), 0.0, None)

    def to_json(self, path) -> None:
        """Save as JSON (schema: ``data_schema/fit_result.schema.json``)."""
        from .io import write_json
        from .serialise import fit_result_to_dict

        write_json(path, fit_result_to_dict(self))

    @classmethod
    def from_json(cls, path, terms=()) -> "FitResult":
        """Load a result saved with `to_json`.

        The file is validated against its schema first, and its model may name only vfjax's
        own term classes and those in ``terms`` (your own effects, passed on purpose): a
        file never makes vfjax import or call anything else.
        """
        from .serialise import read_fit_result

        return read_fit_result(path, terms)


class _Problem(eqx.Module):
    """Everything the cost and residual functions need, as a pytree (vmappable over data)."""

    model: VocalFoldModel
    measured: jax.Array  # (frames,)
    reference: jax.Array  # (n_params,) starting values of the non-S fitted parameters
    scale: jax.Array  # (n_params,) coordinate scale of the linear ones (unused for log ones)
    floor: jax.Array  # (n_params,) physical lower limit of the linear ones (-inf: none)
    free: jax.Array  # (n_params,) 1 for a fitted parameter, 0 for one held (`fit_many`'s hold)
    s_reference: jax.Array  # () starting (or fixed) S
    period: jax.Array  # () T0 estimate (s)
    s_bounds: jax.Array  # (2,) search bounds of S (px/mm²)
    names: tuple = eqx.field(static=True)  # fitted physical parameters, S excluded
    linear: tuple = eqx.field(static=True)  # per name: linear (True) or log coordinate
    fit_s: bool = eqx.field(static=True)
    fps: float = eqx.field(static=True)
    n_frames: int = eqx.field(static=True)
    warmup: float = eqx.field(static=True)
    max_time_shift: float = eqx.field(static=True)
    substeps: int = eqx.field(static=True)

    def model_at(self, z, log_s=None):
        # linear coordinates of parameters that cannot be negative (a gap, a delay) are held
        # at zero from below, so that an unconstrained LM step stays physical
        # a held parameter's coordinate is multiplied by 0: it stays at its reference value
        z = z[: len(self.names)] * self.free
        values = {
            n: jnp.maximum(self.reference[i] + self.scale[i] * z[i], self.floor[i])
            if lin
            else self.reference[i] * jnp.exp(z[i])
            for i, (n, lin) in enumerate(zip(self.names, self.linear))
        }
        s = self.s_reference if log_s is None else self.s_reference * jnp.exp(log_s)
        return self.model.set(**values, S=s)

    def shift(self, z):
        return z[len(self.names)] * self.period

    @property
    def held(self) -> tuple[str, ...]:
        return tuple(n for n, f in zip(self.names, np.asarray(self.free)) if f == 0)

    def shape(self, z):
        """Simulated GAW at S = 1 (clipped at 0) and whether the simulation is valid."""
        # forward mode is all the LM needs (`_residual`): the early-stopping loop's own jvp
        sim = simulate(
            self.model_at(z, log_s=None).set(S=1.0),
            self.fps,
            self.n_frames,
            substeps=self.substeps,
            t_start=self.warmup,
            time_shift=self.shift(z),
            max_time_shift=self.max_time_shift,
            reverse_mode=False,
            throw=False,
        )
        ok = sim.complete
        g = jnp.where(ok, sim.area, 0.0)
        return jnp.maximum(g, 0.0), ok

    def projected_scale(self, mg, gg):
        """The S minimising the squared error of a shape g (closed form), kept within its
        bounds, from the products ``mg`` = measured . g and ``gg`` = g . g (any shape,
        elementwise)."""
        if not self.fit_s:
            return jnp.broadcast_to(self.s_reference, jnp.shape(mg))
        s = mg / jnp.maximum(gg, 1e-300)
        return jnp.clip(s, self.s_bounds[0], self.s_bounds[1])

    def profile(self, z_phys):
        """Best cost over a grid of time shifts, S projected for each; returns (cost, shift
        as a fraction of T0, projected S).

        One simulation serves every shift. The shifts are half a frame apart, so every
        shifted frame time lies on one regular grid of half-frame spacing: the observed area
        is read from the dense output once on that grid, and the products that the
        projected S and the cost need at every shift are correlations of the measured GAW
        with the grid's even and odd samples. (Observation terms act pointwise in time.)"""
        model = self.model_at(jnp.concatenate([z_phys, jnp.zeros(1)])).set(S=1.0)
        sim = simulate(
            model,
            self.fps,
            self.n_frames,
            substeps=self.substeps,
            t_start=self.warmup,
            max_time_shift=self.max_time_shift,
            throw=False,
        )
        ok = sim.complete
        q, n = _SHIFTS_PER_FRAME, self.n_shifts
        length = q * (-(-n // q) + self.n_frames - 1)  # whole rows of q samples
        times = sim.time[0] + jnp.arange(length) / (q * self.fps)
        fine = model.observe(times, sim.dense.displacement(times), sim.dense.displacement)
        fine = jnp.maximum(jnp.where(ok, fine, 0.0), 0.0)
        # shift j = q a + b reads the frames from parity[b][a:]: correlations over a
        parity = fine.reshape(-1, q).T

        def per_shift(signal, kernel):
            out = jax.vmap(lambda p: jnp.correlate(p, kernel, mode="valid"))(signal)
            return out.T.reshape(-1)[:n]

        mg = per_shift(parity, self.measured)
        gg = per_shift(parity**2, jnp.ones(self.n_frames))
        s = self.projected_scale(mg, gg)
        mm = jnp.sum(self.measured**2)
        costs = jnp.maximum(mm - 2.0 * s * mg + s * s * gg, 0.0) / mm
        i = jnp.argmin(costs)
        shift = i / (q * self.fps)
        return jnp.where(ok, costs[i], jnp.inf), shift / self.period, s[i]

    @property
    def n_shifts(self) -> int:
        """Number of time shifts the swarm tries (half a frame apart, up to the largest)."""
        return int(math.floor(self.max_time_shift * _SHIFTS_PER_FRAME * self.fps + 1e-9)) + 1

    def swarm_cost(self, z_phys):
        return self.profile(z_phys)[0]

    def residual(self, y):
        """Residuals whose sum of squares is the NMSE; y = (z..., log S) or z."""
        z = y[: len(self.names) + 1]
        s = self.s_reference * jnp.exp(y[-1]) if self.fit_s else self.s_reference
        g, ok = self.shape(z)
        r = (s * g - self.measured) / jnp.sqrt(jnp.sum(self.measured**2))
        # outside the valid range: a large, finite residual (LM rejects the step)
        return jnp.where(ok, r, 1.0)

    def start(self, z_phys):
        """Swarm point (physical parameters) -> LM point (with its best grid shift and, if
        fitted, log(S / S_ref) of the projected S) and its cost."""
        cost, shift, s = self.profile(z_phys)
        y = jnp.concatenate([z_phys, shift[None]])
        if self.fit_s:
            y = jnp.concatenate([y, jnp.log(s / self.s_reference)[None]])
        return y, cost


def estimate_closure_duration(recording: Recording, levels=(0.1, 0.2)) -> float | None:
    """Closed-phase duration (s) measured on the GAW, or None if the glottis never closes.

    For each closed phase, the times at which the area falls through and rises back through
    ``levels`` (fractions of the peak) are located to a fraction of a frame, and the width of
    the closed phase is extrapolated linearly to zero level: ``2 w(L1) - w(L2)``. The longest
    complete closed phase is returned: the hold lasts t_c in every cycle that closes fully,
    while cycles that barely close (a modulated pressure, a gap) give shorter ones. The paper
    takes t_c from the measured GAW; this gives it without the bias of counting frames under
    a threshold.
    """
    a = recording.area
    peak = a.max()
    l1, l2 = levels
    low = a <= l1 * peak
    if not low.any() or low.all():
        return None

    def crossing(i, level, down):
        # fractional frame index where a crosses level*peak between frames i and i+1
        thr = level * peak
        return (
            i + (a[i] - thr) / (a[i] - a[i + 1]) if down else i + (thr - a[i]) / (a[i + 1] - a[i])
        )

    edges = np.diff(np.r_[0, low.astype(int), 0])
    starts, ends = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)
    widths = []
    for s0, e0 in zip(starts, ends):
        if s0 == 0 or e0 >= a.size:
            continue  # a closed phase cut by the recording's ends
        w = []
        for level in (l1, l2):
            i = s0 - 1
            while i > 0 and a[i] <= level * peak:
                i -= 1
            j = e0 - 1
            while j < a.size - 1 and a[j + 1] <= level * peak:
                j += 1
            if a[i] <= level * peak or j >= a.size - 1:
                break
            w.append(crossing(j, level, down=False) - crossing(i, level, down=True))
        if len(w) == 2:
            widths.append(2 * w[0] - w[1])
    if not widths or max(widths) <= 0:
        return None  # no closed phase long enough to measure
    return float(np.max(widths)) / recording.fps


def initial_model(recording: Recording, template: str | None = None) -> VocalFoldModel:
    """A starting model for ``recording``: the paper's preset for its sex (N1 male, N3
    female, or ``template``), with the sidecar's fold mass and length if given, and the closure
    duration t_c measured on the GAW (`estimate_closure_duration`), as the paper did."""
    from .presets import preset

    sex = recording.metadata.get("sex")
    model = preset(template or ("N3" if sex == "female" else "N1"))
    if "vocal_fold_length_cm" in recording.metadata:
        model = model.set(l=recording.metadata["vocal_fold_length_cm"])
    if "vocal_fold_mass_g" in recording.metadata:
        model = model.set(M=recording.metadata["vocal_fold_mass_g"])
    t_c = estimate_closure_duration(recording)
    if t_c is not None and model.closure_duration is not None:
        model = model.set(t_c=t_c)
    return match_fundamental_frequency(model, recording)


def match_fundamental_frequency(model: VocalFoldModel, recording: Recording, steps: int = 4):
    """``model`` with K scaled so that its f0 matches the recording's (secant steps in log K
    against log f0). A start at the right f0 keeps the swarm away from the sub-harmonic
    minima (a model at half the f0 fitting every other pulse)."""
    target = fundamental_frequency(recording.area, recording.fps)
    if not np.isfinite(target):
        return model
    n = max(recording.n_frames, int(0.08 * recording.fps))

    def f0_of(k):
        sim = simulate(model.set(K=k), recording.fps, n, t_start=0.02, throw=False)
        if not bool(sim.complete):
            return float("nan")
        return fundamental_frequency(np.asarray(sim.area), recording.fps)

    k0 = float(model.params()["K"])
    f_0 = f0_of(k0)
    if not np.isfinite(f_0):
        return model
    k1 = k0 * (target / f_0) ** 2
    for _ in range(steps):
        f_1 = f0_of(k1)
        if not np.isfinite(f_1) or abs(f_1 / target - 1) < 0.005:
            break
        slope = (np.log(f_1) - np.log(f_0)) / (np.log(k1) - np.log(k0)) if k1 != k0 else 0.5
        slope = slope if slope > 0.05 else 0.5
        k0, f_0 = k1, f_1
        k1 = k1 * np.exp(np.log(target / f_1) / slope)
    return model.set(K=k1) if np.isfinite(f0_of(k1)) else model


def _is_linear(model, name, ref):
    ranged = search_range(model, name) is not None
    return ranged and (ref == 0.0 or name not in ("t_c", "C_min")) or ref == 0.0


def _bounds(names, model, bounds):
    params = model.params()
    lo, hi = [], []
    for n in names:
        ref = float(params[n])
        if _is_linear(model, n, ref):
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
            if not (0 < a < ref < b):
                raise ValueError(
                    f"bounds for {n} must satisfy 0 < low < start ({ref}) < high, got {bounds[n]}"
                )
            lo.append(math.log(a / ref))
            hi.append(math.log(b / ref))
        else:
            fa, fb = DEFAULT_FACTORS.get(n, (0.2, 5.0))
            lo.append(math.log(fa))
            hi.append(math.log(fb))
    return np.array(lo), np.array(hi)


def _bounds_in_units(problem, i, a, b):
    ref, scale = float(problem.reference[i]), float(problem.scale[i])
    if problem.linear[i]:
        return [ref + scale * float(a), ref + scale * float(b)]
    return [ref * math.exp(float(a)), ref * math.exp(float(b))]


def _prepare(model, recording, params, warmup, substeps, bounds, held=()):
    if not isinstance(recording, Recording):
        raise TypeError(f"recording must be a vfjax.Recording, got {type(recording).__name__}")
    params = tuple(params)
    units = model.parameter_units()
    unknown = [n for n in params if n not in units]
    if unknown:
        raise ValueError(f"cannot fit {unknown}: the model's parameters are {sorted(units)}")
    if len(set(params)) != len(params) or not params:
        raise ValueError(f"params must be distinct parameter names, got {params}")
    if float(np.sum(recording.area**2)) == 0.0:
        raise ValueError("the recording's area is zero everywhere: there is nothing to fit")
    f0 = fundamental_frequency(recording.area, recording.fps)
    if not np.isfinite(f0):
        raise ValueError(
            f"{recording.name}: fewer than two glottal cycles found in {recording.n_frames} "
            "frames; a fit needs at least one full cycle"
        )
    period = 1.0 / f0
    fit_s = "S" in params
    if recording.unit != "px":
        if fit_s:
            raise ValueError(
                f"S converts model mm² to pixels; the recording is in "
                f"{recording.unit}, so S is fixed and cannot be fitted"
            )
        model = model.set(S=_AREA_TO_PX_SCALE[recording.unit])
    names = tuple(n for n in params if n != "S")
    held = tuple(held)
    if any(n not in names for n in held):
        raise ValueError(
            f"only fitted parameters other than S can be held, got {held} for params {params}"
        )
    lo, hi = _bounds(names, model, bounds)
    free = np.array([n not in held for n in names], dtype=float)
    lo, hi = lo * free, hi * free  # a held parameter's search interval is [0, 0]
    s_lo, s_hi = _bounds(("S",), model, bounds) if fit_s else (None, None)
    # static (it sizes the integration): rounded up to 5 ms so that recordings of similar
    # f0 share one compiled fit
    max_shift = math.ceil(1.25 * period / _SHIFT_GRID) * _SHIFT_GRID
    problem = _Problem(
        model=model,
        measured=jnp.asarray(recording.area),
        reference=jnp.asarray([float(model.params()[n]) for n in names]),
        scale=jnp.asarray([(search_range(model, n) or (0.0, 1.0, 0.1))[2] for n in names]),
        floor=jnp.asarray(
            [0.0 if (search_range(model, n) or (-1.0,))[0] >= 0 else -jnp.inf for n in names]
        ),
        free=jnp.asarray(free),
        linear=tuple(_is_linear(model, n, float(model.params()[n])) for n in names),
        s_reference=jnp.asarray(float(model.params()["S"])),
        period=jnp.asarray(period),
        s_bounds=jnp.asarray(np.exp(np.r_[s_lo, s_hi]) * float(model.params()["S"]))
        if fit_s
        else jnp.asarray([0.0, jnp.inf]),
        names=names,
        fit_s=fit_s,
        fps=recording.fps,
        n_frames=recording.n_frames,
        warmup=float(warmup),
        max_time_shift=float(max_shift),
        substeps=substeps,
    )
    return problem, jnp.asarray(lo), jnp.asarray(hi), (s_lo, s_hi)


@eqx.filter_jit
def _start(problem, z_phys):
    """The swarm's best point -> the LM's starting point (best shift, projected S), and
    its cost."""
    return problem.start(z_phys)


@eqx.filter_jit
def _swarm_init(problem, lower, upper, n, key, start):
    cost = jax.vmap(problem.swarm_cost)
    return init_swarm(cost, lower, upper, n, key, start)


@eqx.filter_jit
def _swarm_chunk(problem, lower, upper, settings, state, n):
    return run_chunk(jax.vmap(problem.swarm_cost), lower, upper, settings, state, n)


def _lm_solver(rtol, atol):
    return optx.LevenbergMarquardt(rtol=rtol, atol=atol)


def _lm_fn(y, problem):
    return _residual(y, problem), None


@jax.custom_jvp
def _residual(y, problem):
    """`_Problem.residual`, whose linearisation is its Jacobian matrix.

    optimistix linearises the residual function (`jax.linearize`) at every LM step and keeps
    the linearisation in its state. Through the simulator that keeps every intermediate of
    the scan (hundreds of arrays per integration step): slow to compile and to carry. This
    rule computes the Jacobian columns at once (forward mode, one batched jvp) and returns
    J @ dy, so the linearisation is one (frames, params) matrix. Differentiates in ``y``
    only (the LM's variable)."""
    return problem.residual(y)


@_residual.defjvp
def _residual_jvp(primals, tangents):
    y, problem = primals
    dy, _ = tangents
    basis = jnp.eye(y.shape[0], dtype=y.dtype)
    r, jac = jax.vmap(lambda t: jax.jvp(problem.residual, (y,), (t,)), out_axes=(None, 1))(basis)
    return r, jac @ dy


@eqx.filter_jit
def _lm_init(problem, y, rtol, atol):
    solver = _lm_solver(rtol, atol)
    f_struct = jax.eval_shape(problem.residual, y)
    return solver.init(_lm_fn, y, problem, {"jac": "fwd"}, f_struct, None, frozenset())


@eqx.filter_jit
def _lm_step(problem, y, state, rtol, atol):
    solver = _lm_solver(rtol, atol)
    y, state, _ = solver.step(_lm_fn, y, problem, {"jac": "fwd"}, state, frozenset())
    done, result = solver.terminate(_lm_fn, y, problem, {"jac": "fwd"}, state, frozenset())
    # the state's residual is the one at the returned y (the step evaluated it)
    return y, state, done, result, jnp.sum(state.f_info.residual**2)


@eqx.filter_jit
def _cost_alone(problem, y):
    """The cost (NMSE) at ``y`` of one problem, unbatched."""
    return jnp.sum(problem.residual(y) ** 2)


def _unpack(problem, y) -> tuple[VocalFoldModel, float]:
    z = y[: len(problem.names) + 1]
    log_s = y[-1] if problem.fit_s else None
    model = problem.model_at(z, log_s)
    return model, float(problem.shift(z))


def fit(
    model: VocalFoldModel,
    recording: Recording,
    params: Sequence[str] = ("S", "K", "C_f"),
    *,
    bounds: dict | None = None,
    swarm_size: int = 48,
    iterations: int = 60,
    chunk: int = 10,
    key=None,
    polish: bool = True,
    lm_steps: int = 40,
    rtol: float = 1e-6,
    atol: float = 1e-9,
    warmup: float | None = None,
    substeps: int = DEFAULT_SUBSTEPS,
    settings: SwarmSettings = _DEFAULT_SWARM,
    progress: bool | None = None,
    callback: Callable[[int, float], None] | None = None,
) -> FitResult:
    """Fit ``params`` of ``model`` to ``recording``: batched PSO, then Levenberg-Marquardt.

    Arguments:
        model: the model with every non-fitted parameter set (e.g. `vfjax.preset`, or
            `initial_model(recording)`); its values of the fitted ones are the search centre.
        recording: the measured GAW (`vfjax.Recording`).
        params: names of the parameters to fit (the paper: S, K, C_f; t_c and P_s optional).
        bounds: ``{name: (low, high)}`` in the parameter's unit; defaults: `DEFAULT_FACTORS`
            times the starting value. They bound the swarm's search (and the projected S);
            the LM polish is a local, unconstrained refinement from the swarm's best.
        swarm_size: particles (one vmapped simulation per iteration evaluates them all).
        iterations: PSO iterations (0: LM from the model's values).
        chunk: PSO iterations per jitted chunk (between chunks: progress bar, callback).
        key: `jax.random` key; the same key gives the same result. Default: key(0).
        polish: run the Levenberg-Marquardt polish.
        lm_steps: maximum LM steps.
        rtol, atol: LM tolerances (on the O(1) coordinates).
        warmup: simulated time before sampling starts (s); default: `default_warmup`.
        substeps: RK4 steps per frame.
        settings: PSO constants and boundary handling.
        progress: show a progress bar (default: on a terminal, for more than 20 iterations).
        callback: called as ``callback(iteration, best_nmse)`` after each PSO chunk and each
            LM step (iteration counts PSO iterations, then continues through the LM steps).
    """
    t_all = time.perf_counter()
    key = jax.random.key(0) if key is None else key
    warmup = default_warmup(model) if warmup is None else warmup
    problem, lower, upper, _ = _prepare(model, recording, params, warmup, substeps, bounds)
    start = jnp.zeros(lower.shape[0])
    show = progress if progress is not None else (iterations > 20 and sys.stderr.isatty())
    bar = None
    if show:
        from tqdm.auto import tqdm

        bar = tqdm(
            total=iterations + (lm_steps if polish else 0),
            desc=f"fit {recording.name}",
            leave=False,
        )

    # Stage 1: the swarm.
    t0 = time.perf_counter()
    state = _swarm_init(problem, lower, upper, swarm_size, key, start)
    jax.block_until_ready(state)
    t_first = time.perf_counter() - t0
    pso_trace = [float(state.global_cost)]
    trace_times = [time.perf_counter() - t_all]
    done_iters = 0
    compile_s = t_first
    while done_iters < iterations:
        n = min(chunk, iterations - done_iters)
        tc = time.perf_counter()
        state, costs = _swarm_chunk(problem, lower, upper, settings, state, n)
        costs = np.asarray(costs)
        if done_iters == 0:
            compile_s += time.perf_counter() - tc  # first chunk includes its compilation
        pso_trace += costs.tolist()
        now = time.perf_counter() - t_all
        trace_times += np.linspace(trace_times[-1], now, n + 1)[1:].tolist()
        done_iters += n
        if bar is not None:
            bar.update(n)
            bar.set_postfix(nmse=f"{pso_trace[-1]:.3g}")
        if callback is not None:
            callback(done_iters, pso_trace[-1])
    t_pso = time.perf_counter() - t0
    n_sims = swarm_size * (1 + iterations)

    # Stage 2: the polish.
    t1 = time.perf_counter()
    y, best_cost = _start(problem, state.global_position)
    best_y, best_cost = y, float(best_cost)
    lm_trace = [best_cost]
    trace_times.append(time.perf_counter() - t_all)
    result_name = "not run"
    if polish:
        lm_state = _lm_init(problem, y, rtol, atol)
        result_name = "max_steps_reached"
        for i in range(lm_steps):
            y, lm_state, done, result, cost = _lm_step(problem, y, lm_state, rtol, atol)
            cost = float(cost)
            n_sims += 1 + y.shape[0]
            if np.isfinite(cost) and cost < best_cost:
                best_cost, best_y = cost, y
            lm_trace.append(best_cost)
            trace_times.append(time.perf_counter() - t_all)
            if bar is not None:
                bar.update(1)
                bar.set_postfix(nmse=f"{best_cost:.3g}")
            if callback is not None:
                callback(iterations + i + 1, best_cost)
            if bool(done):
                result_name = _result_name(result)
                break
    t_lm = time.perf_counter() - t1
    if bar is not None:
        bar.close()

    return _make_result(
        problem,
        recording,
        params,
        best_y,
        best_cost,
        pso_trace=pso_trace,
        lm_trace=lm_trace,
        trace_times=trace_times,
        timings={
            "pso_s": t_pso,
            "lm_s": t_lm,
            "total_s": time.perf_counter() - t_all,
            "first_swarm_s": t_first,
            "compile_s": compile_s,
        },
        n_simulations=n_sims,
        optimistix_result=result_name,
        lower=lower,
        upper=upper,
        swarm=(swarm_size, iterations, lm_steps, substeps, settings),
    )


def _make_result(
    problem,
    recording,
    params,
    y,
    nmse,
    *,
    pso_trace,
    lm_trace,
    trace_times,
    timings,
    n_simulations,
    optimistix_result,
    lower,
    upper,
    swarm,
) -> FitResult:
    """The `FitResult` of the fitted point ``y`` (shared by `fit` and `fit_many`)."""
    swarm_size, iterations, lm_steps, substeps, settings = swarm
    fitted, shift = _unpack(problem, y)
    params = tuple(n for n in params if n not in problem.held)
    units = fitted.parameter_units()
    values = fitted.params()
    bounds = {
        n: _bounds_in_units(problem, i, a, b)
        for i, (n, a, b) in enumerate(zip(problem.names, np.asarray(lower), np.asarray(upper)))
        if n in params
    }
    if problem.fit_s:
        bounds["S"] = [float(v) for v in np.asarray(problem.s_bounds)]
    status, nmse_of_mean = _status(problem, params, values, bounds, float(nmse))
    return FitResult(
        params={n: float(values[n]) for n in params},
        units={n: units[n] for n in params},
        time_shift=shift,
        nmse=float(nmse),
        pso_trace=list(pso_trace),
        lm_trace=list(lm_trace),
        trace_times=list(trace_times),
        timings=timings,
        n_simulations=int(n_simulations),
        optimistix_result=optimistix_result,
        settings={
            "params": list(params),
            "bounds": bounds,
            "swarm_size": swarm_size,
            "iterations": iterations,
            "lm_steps": lm_steps,
            "warmup": problem.warmup,
            "max_time_shift": problem.max_time_shift,
            "substeps": substeps,
            "fps": recording.fps,
            "n_frames": recording.n_frames,
            "pso": settings._asdict(),
        },
        model=fitted,
        recording_name=recording.name,
        status=status,
        nmse_of_mean=nmse_of_mean,
    )


#: The values of `FitResult.status`.
FIT_STATUSES = ("successful", "at_bound", "worse_than_mean", "not_finite", "unknown")
_EDGE = 1e-3  # a value within this fraction of its box's width from an edge is at it


def _at_edge(value, low, high, floor=None) -> bool:
    """Whether ``value`` ended on an edge of its search box [low, high] (within `_EDGE` of
    the box's width, in log coordinates when both are > 0): where the swarm's search stopped
    it and the polish could not move it away. A lower edge at the physical ``floor`` (a gap
    of 0) does not count, and neither does a value the polish carried well beyond the box (a
    local optimum of its own, outside the swarm's reach)."""
    if low > 0 and high > 0 and value > 0:
        value, low_c, high_c = math.log(value), math.log(low), math.log(high)
    else:
        low_c, high_c = low, high
    margin = _EDGE * (high_c - low_c)
    at_low = abs(value - low_c) <= margin and not (floor is not None and low <= floor)
    return at_low or abs(value - high_c) <= margin


def _status(problem, params, values, bounds, nmse) -> tuple[str, float]:
    """`FitResult.status` and the NMSE of the recording's mean."""
    measured = np.asarray(problem.measured)
    of_mean = float(np.sum((measured - measured.mean()) ** 2) / np.sum(measured**2))
    if not np.isfinite(nmse):
        return "not_finite", of_mean
    if nmse >= of_mean:
        return "worse_than_mean", of_mean
    floors = dict(zip(problem.names, np.asarray(problem.floor)))
    for n in params:
        low, high = bounds[n]
        if _at_edge(float(values[n]), low, high, floors.get(n)):
            return "at_bound", of_mean
    return "successful", of_mean


def _result_name(result, index=None) -> str:
    """optimistix's result code as a plain string (``index``: element of a batched code)."""
    for name in (
        "successful",
        "max_steps_reached",
        "nonlinear_max_steps_reached",
        "nonlinear_divergence",
        "singular",
    ):
        member = getattr(optx.RESULTS, name, None)
        if member is None:
            continue
        same = np.asarray(result == member)
        if bool(same if index is None else same[index]):
            return name
    return "unknown"


def fit_many(
    model: VocalFoldModel | Sequence[VocalFoldModel],
    recordings: Sequence[Recording],
    params: Sequence[str] = ("S", "K", "C_f"),
    *,
    bounds: dict | None = None,
    swarm_size: int = 48,
    iterations: int = 60,
    key=None,
    polish: bool = True,
    lm_steps: int = 40,
    rtol: float = 1e-6,
    atol: float = 1e-9,
    warmup: float | None = None,
    substeps: int = DEFAULT_SUBSTEPS,
    settings: SwarmSettings = _DEFAULT_SWARM,
    hold: Sequence[Sequence[str]] | None = None,
) -> list[FitResult]:
    """Fit many recordings of one model structure as one batched job.

    Every PSO iteration simulates all particles of all recordings in one vmapped call, and the
    LM polish steps all recordings together. The recordings must share frame rate, frame count
    and area unit. ``model`` is one model for all, or one model per recording (of one
    structure: the same terms; e.g. several starting points for one recording).

    ``hold``, if given, names for each recording the parameters of ``params`` (S excepted)
    that stay at that model's value: fits of different parameter subsets of one model then
    share one batch and one compiled program (the diagnosis refits every candidate effect
    this way, with the others held at their off-values). A held parameter is left out of its
    `FitResult`'s ``params``.

    The swarm stage runs as one compiled program (no progress bar, no callback). Other
    arguments as for `fit`; returns one `FitResult` per recording (timings are those of the
    whole batch).
    """
    recordings = list(recordings)
    if not recordings:
        raise ValueError("recordings is empty")
    models = [model] * len(recordings) if isinstance(model, VocalFoldModel) else list(model)
    if len(models) != len(recordings):
        raise ValueError(f"got {len(models)} models for {len(recordings)} recordings")
    structure = jax.tree.structure(models[0])
    if any(jax.tree.structure(m) != structure for m in models[1:]):
        raise ValueError("fit_many's models must share one structure (the same terms)")
    first = recordings[0]
    for r in recordings[1:]:
        if (r.fps, r.n_frames, r.unit) != (first.fps, first.n_frames, first.unit):
            raise ValueError(
                "fit_many needs recordings of equal fps, frame count and unit; "
                f"{r.name} differs from {first.name}"
            )
    t_all = time.perf_counter()
    key = jax.random.key(0) if key is None else key
    hold = [()] * len(models) if hold is None else [tuple(h) for h in hold]
    if len(hold) != len(models):
        raise ValueError(f"got {len(hold)} hold lists for {len(recordings)} recordings")
    warmup = max(default_warmup(m) for m in models) if warmup is None else warmup
    prepared = [
        _prepare(m, r, params, warmup, substeps, bounds, h)
        for m, r, h in zip(models, recordings, hold)
    ]
    shift = max(p.max_time_shift for p, _, _, _ in prepared)
    linear = _common_coordinates([p for p, _, _, _ in prepared])
    problems = [
        dataclasses.replace(p, max_time_shift=shift, linear=linear) for p, _, _, _ in prepared
    ]
    lowers = jnp.stack([lo for _, lo, _, _ in prepared])
    uppers = jnp.stack([hi for _, _, hi, _ in prepared])
    batch = jax.tree.map(lambda *xs: jnp.stack(xs), *problems)
    starts = jnp.zeros(lowers.shape)
    keys = jax.random.split(key, len(problems))

    t0 = time.perf_counter()
    # the whole swarm stage (and the LM's starting points) is one compiled program
    y, cost0, pso_traces = _many_search(
        batch, lowers, uppers, keys, starts, swarm_size, settings, iterations
    )
    pso_traces = np.asarray(pso_traces)
    t_pso = time.perf_counter() - t0

    t1 = time.perf_counter()
    best_y, best_cost = y, np.asarray(cost0)
    lm_traces = [best_cost.copy()]
    results = ["not run"] * len(problems)
    n_lm = 0
    if polish:
        lm_state = _many_lm_init(batch, y, rtol, atol)
        finished = np.zeros(len(problems), bool)
        for _ in range(lm_steps):
            y, lm_state, done_flags, res, cost = _many_lm_step(batch, y, lm_state, rtol, atol)
            n_lm += 1
            cost = np.asarray(cost)
            better = np.isfinite(cost) & (cost < best_cost) & ~finished
            best_cost = np.where(better, cost, best_cost)
            best_y = jnp.where(jnp.asarray(better)[:, None], y, best_y)
            lm_traces.append(best_cost.copy())
            newly = np.asarray(done_flags) & ~finished
            for i in np.flatnonzero(newly):
                results[i] = _result_name(res, i)
            finished |= np.asarray(done_flags)
            if finished.all():
                break
        results = [r if r != "not run" else "max_steps_reached" for r in results]
    t_lm = time.perf_counter() - t1
    lm_traces = np.stack(lm_traces, axis=1)
    # Each fit's NMSE as one simulation of it alone gives it (as `FitResult.fitted_gaw` and
    # `fit` do): batched and unbatched code round differently, which decides whether a hold
    # starts where a fit sits on a grazing closure (benchmarks/README.md, "Fitting").
    best_cost = np.array([float(_cost_alone(p, best_y[i])) for i, p in enumerate(problems)])

    trace_times = np.r_[
        np.linspace(0, t_pso, pso_traces.shape[1]), t_pso + np.linspace(0, t_lm, lm_traces.shape[1])
    ].tolist()
    timings = {
        "pso_s": t_pso,
        "lm_s": t_lm,
        "total_s": time.perf_counter() - t_all,
        "batch_size": len(recordings),
    }
    n_sims = swarm_size * (1 + iterations) + n_lm * (1 + best_y.shape[1])
    return [
        _make_result(
            problem,
            rec,
            params,
            best_y[i],
            best_cost[i],
            pso_trace=pso_traces[i].tolist(),
            lm_trace=lm_traces[i].tolist(),
            trace_times=trace_times,
            timings=timings,
            n_simulations=n_sims,
            optimistix_result=results[i],
            lower=lowers[i],
            upper=uppers[i],
            swarm=(swarm_size, iterations, lm_steps, substeps, settings),
        )
        for i, (rec, problem) in enumerate(zip(recordings, problems))
    ]


def _common_coordinates(problems) -> tuple[bool, ...]:
    """The coordinate (linear or log) of each parameter, shared by a batch: a held
    parameter takes the one its fitted counterparts use (either keeps it at its value)."""
    common = []
    for i, name in enumerate(problems[0].names):
        kinds = {p.linear[i] for p in problems if p.free[i]} or {problems[0].linear[i]}
        if len(kinds) > 1:
            raise ValueError(
                f"fit_many: {name} starts at 0 in some fits (linear search) and "
                "away from 0 in others (log search); start them alike"
            )
        common.append(kinds.pop())
    return tuple(common)


@eqx.filter_jit
def _many_search(batch, lowers, uppers, keys, starts, swarm_size, settings, iterations):
    """The swarm stage of every fit in the batch, then each one's LM starting point and its
    cost; returns (y, cost, best cost after each iteration)."""

    def one(p, lo, hi, k, s0):
        cost = jax.vmap(p.swarm_cost)
        state = init_swarm(cost, lo, hi, swarm_size, k, s0)
        first = state.global_cost[None]
        state, trace = run_chunk(cost, lo, hi, settings, state, iterations)
        y, cost = _start(p, state.global_position)
        return y, cost, jnp.concatenate([first, trace])

    return jax.vmap(one)(batch, lowers, uppers, keys, starts)


@eqx.filter_jit
def _many_lm_init(batch, y, rtol, atol):
    return eqx.filter_vmap(lambda p, y: _lm_init(p, y, rtol, atol))(batch, y)


@eqx.filter_jit
def _many_lm_step(batch, y, state, rtol, atol):
    return eqx.filter_vmap(lambda p, y, s: _lm_step(p, y, s, rtol, atol))(batch, y, state)
