"""Fitting the model to a measured GAW: a batched particle swarm, then a least-squares polish.

Protocol (the paper gives none). A recording starts at an arbitrary point of the glottal
cycle, while the model starts from rest at contact. vfjax simulates a warm-up to reach the
limit cycle (`default_warmup`) and samples the recording's frames from ``warmup +
time_shift``, where the time shift is a fitted, differentiable parameter in [0, 1.25 T0]
(rounded up to 5 ms: `SHIFT_CYCLES`, `SHIFT_STEP`).

- ``_problem``: the problem of one fit and its search coordinates;
- ``_swarm``: the particle swarm;
- ``_polish``: the optimistix polish;
- ``_options``: `Swarm` and `Polish`;
- ``_result``: `FitResult` and its status;
- ``_engine``: `fit_many` and `fit`, which run every fit as a batch of compiled programs;
- ``_settling``: `settling`, whether a fitted oscillation is sustained (the fitted model
  after a longer warm-up);
- ``_first``: `fit_recording`, a recording's first fit (free pressure, a box that reaches the
  model's regimes, restarts), and `fit_recordings`, many first fits as one batch.

Cost: NMSE = sum((A_exp - A_sim)²) / sum(A_exp²) (`vfjax.nmse`). The simulated GAW is clipped
at zero area before it is compared: a camera sees no negative area.
"""

from ._engine import DEFAULT_PARAMS, fit, fit_many
from ._first import (
    FIRST_FIT_RESTARTS,
    first_fit_bounds,
    first_fit_parameters,
    fit_recording,
    fit_recordings,
)
from ._options import Polish, Swarm
from ._problem import (
    DEFAULT_FACTORS,
    LINEAR,
    PRESSURE_RANGE,
    WARMUP,
    default_warmup,
    search_range,
)
from ._result import FIT_STATUSES, FitResult, fitted_area
from ._settling import SETTLING_WARMUP, Settling, settling

__all__ = [
    "DEFAULT_FACTORS",
    "DEFAULT_PARAMS",
    "FIRST_FIT_RESTARTS",
    "FIT_STATUSES",
    "LINEAR",
    "PRESSURE_RANGE",
    "SETTLING_WARMUP",
    "Settling",
    "WARMUP",
    "FitResult",
    "Polish",
    "Swarm",
    "default_warmup",
    "fit",
    "first_fit_bounds",
    "first_fit_parameters",
    "fit_many",
    "fit_recording",
    "settling",
    "fit_recordings",
    "fitted_area",
    "search_range",
]
