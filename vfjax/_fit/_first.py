"""The first fit of a recording: its starting model, the parameters the recording leaves
free (the subglottal pressure, unless stated), a box that reaches the model's regimes
(closing or not, with or without a closure hold), and independent restarts.

A fit from one start in a narrow box often stops short of the best the model can do: the
closure hold and contact switch the dynamics between regimes, so the error surface has
basins far apart, and the paper gives no subglottal pressure (on the shared real
recordings, the first fit's NMSE falls by up to 10x when P_s is searched with the others;
`benchmarks/restarts.py`).

A first fit describes sustained phonation. Simulated from rest after the default warm-up
(`default_warmup`), a model whose oscillation has not settled by the first frame can match a
recording with its own start-up, and its parameters then describe a transient that the
larynx never shows (on the shared FN003 the 20 ms fit's model leaves 9.6 times its error
0.2 s later). So a first fit made at the default warm-up is checked (`settling`), and one
that is not settled is made again after `SETTLING_WARMUP`, which replaces it.
"""

import warnings
from collections.abc import Sequence
from typing import Any

import jax
import numpy as np
from jaxtyping import Array

from ..descriptors import RecordingWarning, recording_cautions
from ..model import VocalFoldModel
from ..presets import PRESSURE_KEY, initial_model
from ..recording import Recording
from ._engine import fit_many, refuse_batch_options, stack_strong
from ._problem import plausible_range
from ._result import FitResult
from ._settling import SETTLING_WARMUP, settlings

#: The first fit's box for the stiffness and the damping factor, as factors of the
#: starting model's values (K matched to the recording's f0).
REGIME_FACTORS = {"K": (0.1, 10.0), "C_f": (0.01, 100.0)}
#: The closure duration is searched from 0 (no hold) to this multiple of its starting value
#: (measured on the GAW).
HOLD_FACTOR = 4.0
#: Independent searches of a first fit.
FIRST_FIT_RESTARTS = 4


def first_fit_parameters(recording: Recording, model: VocalFoldModel) -> tuple[str, ...]:
    """The parameters a first fit of ``recording`` adjusts: S (for a GAW in pixels), K, C_f,
    the closure duration t_c (if the model holds closures) and the subglottal pressure P_s,
    unless the recording's sidecar states it (``subglottal_pressure_dyne_per_cm2``)."""
    names = ["S"] if recording.unit == "px" else []
    names += ["K", "C_f"]
    if model.closure_duration is not None:
        names.append("t_c")
    if PRESSURE_KEY not in recording.metadata:
        names.append("P_s")
    return tuple(names)


def first_fit_bounds(model: VocalFoldModel, params: Sequence[str]) -> dict:
    """The first fit's search box ``{name: (low, high)}`` in the parameters' units, around
    ``model``'s values: K and C_f within `REGIME_FACTORS`, t_c from 0 to `HOLD_FACTOR`
    times its value, P_s over `PRESSURE_RANGE` (widened to hold its value); others (S) keep
    the fit's defaults."""
    values = {n: float(v) for n, v in model.params().items()}
    box = {}
    for name in params:
        value = values[name]
        if name in REGIME_FACTORS and value > 0:
            low, high = REGIME_FACTORS[name]
            box[name] = (low * value, high * value)
        elif name == "t_c" and value > 0:
            box[name] = (0.0, HOLD_FACTOR * value)
        elif name == "P_s":
            box[name] = plausible_range(name, value)
    return box


def fit_recording(
    recording: Recording,
    model: VocalFoldModel | None = None,
    params: Sequence[str] | None = None,
    *,
    restarts: int = FIRST_FIT_RESTARTS,
    bounds: dict | None = None,
    settle: bool = True,
    **options: Any,
) -> FitResult:
    """Fit the model to a recording as a first fit should: from `initial_model`, with the
    subglottal pressure searched when the recording does not state it, in a box that reaches
    the model's regimes, best of ``restarts`` independent searches (one batch), after a
    warm-up that leaves a settled oscillation. Warns (`vfjax.descriptors.RecordingWarning`)
    of what such a model cannot describe in the recording as given
    (`vfjax.descriptors.recording_cautions`).

    Arguments:
        recording: the measured GAW (`vfjax.Recording`).
        model: the starting model (default: `vfjax.initial_model(recording)`).
        params: the parameters to fit (default: `first_fit_parameters`).
        restarts: independent searches (swarm and polish); the best is kept, and
            ``FitResult.restart_nmse`` lists where each ended.
        bounds: ``{name: (low, high)}`` in the parameters' units, replacing
            `first_fit_bounds`' entries.
        settle: where no ``warmup`` is given, check the fit at the default warm-up with
            `vfjax.settling` and, if it is not settled, fit again (the same search, the same
            key) after `SETTLING_WARMUP` s and return that fit, unless its search failed:
            its ``sampling.warmup`` says which one it is. False: the fit at the default
            warm-up, as it ends.
        options: the rest of `vfjax.fit`'s options (``swarm``, ``polish``, ``warmup``,
            ``substeps``, ``key``, ``progress``, ``callback``).
    """
    if not isinstance(recording, Recording):
        raise TypeError(f"recording must be a vfjax.Recording, got {type(recording).__name__}")
    refuse_batch_options("fit_recording", options)
    models = None if model is None else [model]
    return fit_recordings(
        [recording], models, params, restarts=restarts, bounds=bounds, settle=settle, **options
    )[0]


def _settled_or_first(first: FitResult, again: FitResult) -> FitResult:
    """The fit after `SETTLING_WARMUP` (``again``) in place of the first fit, unless its
    search failed (``status`` "worse_than_mean" or "not_finite": the model fitted there does
    not describe the waveform), where the first fit, whose settling says what it is, is
    kept."""
    return first if again.status in ("worse_than_mean", "not_finite") else again


def _to_settle(settle: bool, options: dict, results, recordings) -> list[int]:
    """Which of ``results`` (first fits at the default warm-up, unless ``options`` name
    one) are to be fitted again after `SETTLING_WARMUP`: those whose fitted model is not
    settled (`settling`); none where ``settle`` is off or a warm-up was given."""
    if not settle or options.get("warmup") is not None:
        return []
    due = [
        i
        for i, r in enumerate(results)
        if np.isfinite(r.nmse) and r.sampling.warmup < SETTLING_WARMUP
    ]
    checks = settlings([results[i] for i in due], [recordings[i] for i in due])
    return [i for i, check in zip(due, checks) if not check.settled]


def fit_recordings(
    recordings: Sequence[Recording],
    models: Sequence[VocalFoldModel] | None = None,
    params: Sequence[str] | None = None,
    *,
    restarts: int = FIRST_FIT_RESTARTS,
    bounds: dict | None = None,
    key: Array | None = None,
    settle: bool = True,
    **options: Any,
) -> list[FitResult]:
    """`fit_recording` of many recordings as one batched job (`vfjax.fit_many`): each
    recording's first fit, from its own starting model and in its own box, with the same
    random draws as `fit_recording` of it alone (``fold_in(key, 0)``), so that its result
    does not depend on the batch (to rounding). The fits that are not settled are made again
    after `SETTLING_WARMUP`, as one batch of their own. A recording that a model of
    sustained phonation does not describe as given (stretches without glottal cycles, an
    f0 outside phonation's: `vfjax.descriptors.recording_cautions`) is warned of first
    (`vfjax.descriptors.RecordingWarning`), and fitted all the same.

    Arguments:
        recordings: the measured GAWs, all in one unit. Each fit frees the parameters
            `first_fit_parameters` gives for its recording (P_s where the recording does not
            state it) and holds the rest at its model's values, all in one program.
        models: one starting model per recording, of one structure (default:
            `vfjax.initial_model` of each).
        params: the parameters to fit, the same for every recording (default: each
            recording's `first_fit_parameters`).
        restarts: independent searches per recording; the best is kept.
        bounds: ``{name: (low, high)}`` in the parameters' units, replacing
            `first_fit_bounds`' entries for every recording.
        key: `jax.random` key (default: key(0)).
        settle: as `fit_recording`'s.
        options: the rest of `vfjax.fit_many`'s options (``swarm``, ``polish``, ``warmup``,
            ``substeps``, ``progress``, ``callback``, ``min_batch``).
    """
    recordings = list(recordings)
    for r in recordings:
        if not isinstance(r, Recording):
            raise TypeError(f"recording must be a vfjax.Recording, got {type(r).__name__}")
    for r in recordings:  # what no first fit can describe, said before it is made
        for words in recording_cautions(r.area, r.fps, r.name):
            warnings.warn(words, RecordingWarning, stacklevel=2)
    models = [initial_model(r) for r in recordings] if models is None else list(models)
    if len(models) != len(recordings):
        raise ValueError(f"got {len(models)} models for {len(recordings)} recordings")
    if params is None:
        free = [first_fit_parameters(r, m) for r, m in zip(recordings, models)]
        if len({"S" in f for f in free}) > 1:
            raise ValueError(
                "fit_recordings: S is fitted for pixel recordings only; fit recordings in "
                "pixels and in mm² or cm² in separate batches"
            )
        params = tuple(dict.fromkeys(n for f in free for n in f))
        hold = [tuple(n for n in params if n not in f) for f in free]
    else:
        params, hold = tuple(params), None
    boxes = [{**first_fit_bounds(m, params), **(bounds or {})} for m in models]
    key = jax.random.key(0) if key is None else key
    keys = stack_strong(*[jax.random.fold_in(key, 0)] * len(recordings))
    results = fit_many(
        models, recordings, params, bounds=boxes, restarts=restarts, key=keys, hold=hold, **options
    )
    again = _to_settle(settle, options, results, recordings)
    if again:
        refits = fit_many(
            [models[i] for i in again],
            [recordings[i] for i in again],
            params,
            bounds=[boxes[i] for i in again],
            hold=None if hold is None else [hold[i] for i in again],
            restarts=restarts,
            key=keys[np.asarray(again)],
            **{**options, "warmup": SETTLING_WARMUP},
        )
        for i, r in zip(again, refits):
            results[i] = _settled_or_first(results[i], r)
    return results
