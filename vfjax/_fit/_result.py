"""The result of a fit, its status, and the compiled simulation of a fitted model."""

import dataclasses
import math

import numpy as np

from .._integrate import Simulation, fitted_simulation
from .._sampling import Sampling
from ..io import write_json
from ..model import VocalFoldModel
from ..recording import Recording
from ..serialise import fit_result_to_dict, read_fit_result
from ._options import Swarm

#: The values of `FitResult.status`.
FIT_STATUSES = ("successful", "at_bound", "worse_than_mean", "not_finite", "unknown")
_EDGE = 1e-3  # a value within this fraction of its box's width from an edge is at it


def fitted_area(model: VocalFoldModel, sampling: Sampling, time_shift: float) -> np.ndarray:
    """The GAW of ``model`` sampled as a fit samples it, clipped at zero: the waveform whose
    error a fit reports (`fitted_simulation`)."""
    return np.clip(np.asarray(fitted_simulation(model, sampling, time_shift).area), 0.0, None)


@dataclasses.dataclass
class FitResult:
    """The outcome of `vfjax.fit`.

    Attributes:
        params: fitted parameter values by name, in the model's units (``units``).
        units: unit of each parameter.
        time_shift: fitted sampling delay after the warm-up (s).
        nmse: normalised squared error of the fitted GAW; of the two folds' areas for a
            model with two folds fitted to a recording's per-fold areas (`vfjax.fit_many`).
        sampling: how the fit sampled the model (frame rate, frames, substeps, warm-up,
            time-shift range).
        bounds: the search box of each fitted parameter, [low, high] in its unit.
        swarm: the swarm's settings.
        pso_trace: best NMSE after each swarm iteration (index 0: the initial swarm); for
            a long recording, the NMSE over its first cycles (`fit_many`).
        lm_trace: NMSE at the polish's start and at its end.
        trace_times: wall time (s since the fit began) of each entry of ``pso_trace``
            followed by each entry of ``lm_trace`` (iterations within a compiled chunk are
            spread evenly over the chunk's time).
        timings: wall time of each stage (s), compilation included.
        n_simulations: simulated recordings (a Jacobian counts as one per column).
        optimistix_result: the polish's result code ("successful", "max_steps_reached", ...).
        model: the fitted model.
        recording_name: the recording's name.
        status: whether the fit can be trusted (`FIT_STATUSES`): "successful"; "at_bound"
            (a parameter ended at an edge of its search box: the box does not hold the
            optimum, widen it with ``bounds``); "worse_than_mean" (the fit explains the
            recording less well than its mean, a constant, does); "not_finite"; "unknown"
            (read from a file of an earlier format).
        nmse_of_mean: NMSE of the recording's mean as a constant waveform: the error of a
            model that explains nothing, which a fit must beat.
        restart_nmse: the NMSE each independent restart of the fit ended at (``restarts``
            of `vfjax.fit`); the fit is the best of them. Close values say the search is
            reproducible; a spread says the landscape has several basins. None for a
            restart culled behind the others (`vfjax.Swarm`'s ``cull_at``) or that ended
            with no finite error.
    """

    params: dict
    units: dict
    time_shift: float
    nmse: float
    sampling: Sampling
    bounds: dict
    swarm: Swarm
    pso_trace: list
    lm_trace: list
    timings: dict
    trace_times: list
    n_simulations: int
    optimistix_result: str
    model: VocalFoldModel | None = None
    recording_name: str = ""
    status: str = "successful"
    nmse_of_mean: float | None = None
    restart_nmse: list | None = None

    @property
    def failed(self) -> bool:
        """Whether the fit failed (``status`` is neither "successful" nor "unknown")."""
        return self.status not in ("successful", "unknown")

    def status_message(self) -> str:
        """The status in words, naming the parameters at their bounds."""
        if self.status == "at_bound":
            edges = []
            for name, (low, high) in self.bounds.items():
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

    def simulate(self, recording: Recording | None = None) -> Simulation:
        """The fitted model's `Simulation` on the fit's frames (motion, phases, and the dense
        output over the frames; `fitted_simulation`). ``recording`` is accepted for symmetry
        and not needed."""
        return fitted_simulation(self.model, self.sampling, self.time_shift)

    def fitted_gaw(self, recording: Recording | None = None) -> np.ndarray:
        """The fitted GAW on the fit's frames, clipped at zero, in the recording's unit: the
        waveform whose error ``nmse`` is."""
        return fitted_area(self.model, self.sampling, self.time_shift)

    def to_json(self, path) -> None:
        """Save as JSON (schema: ``data_schema/fit_result.schema.json``)."""
        write_json(path, fit_result_to_dict(self))

    @classmethod
    def from_json(cls, path, terms=()) -> "FitResult":
        """Load a result saved with `to_json`.

        The file is validated against its schema first, and its model may name only vfjax's
        own term classes and those in ``terms`` (your own effects, passed on purpose): a
        file never makes vfjax import or call anything else.
        """
        fields = read_fit_result(path, terms)
        try:
            fields["sampling"] = Sampling(**fields["sampling"])
            fields["swarm"] = Swarm(**fields["swarm"])
        except (TypeError, ValueError) as err:
            raise ValueError(f"{path}: {err}") from None
        return cls(**fields)


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


def fit_status(measured, nmse, values, bounds, floors) -> tuple[str, float]:
    """`FitResult.status` and the NMSE of the recording's mean. ``values``: fitted values by
    name; ``bounds``: their boxes; ``floors``: physical lower limits by name."""
    measured = np.asarray(measured)
    of_mean = float(np.sum((measured - measured.mean()) ** 2) / np.sum(measured**2))
    if not np.isfinite(nmse):
        return "not_finite", of_mean
    if nmse >= of_mean:
        return "worse_than_mean", of_mean
    for n, (low, high) in bounds.items():
        if n in values and _at_edge(float(values[n]), low, high, floors.get(n)):
            return "at_bound", of_mean
    return "successful", of_mean
