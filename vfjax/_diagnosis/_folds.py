"""Do the folds differ? A calibrated test of left-right asymmetry on per-fold areas.

The catalogue's candidates are tested on the total GAW, which hardly tells two folds apart.
Where a recording has each fold's area (`Recording.folds`, or edges and masks that a glottal
midline splits), `asymmetry_test` asks whether the fitted model with two folds
(`vfjax.LeftRightAsymmetry`) describes them better than the symmetric fitted model, whose
folds each make half of its GAW:

- the statistic is the fall of the per-fold NMSE, sum((dL)² + (dR)²) / sum(L² + R²), from
  the symmetric model to two folds, each refitted to the per-fold areas with the same
  search: the symmetric model is refitted, then searched again from there as it is and
  with two folds (at Q = 1, which contains it), so that what a second search alone gains
  on a fit that had not converged is not read as asymmetry;
- it is calibrated by simulation: null recordings of the symmetric fitted model, each fold
  half of its GAW, with white noise at the recording's levels on the total and on the left
  fold's area (the right fold's is the rest); the recording and the null recordings go
  through the same two refits (the recording first in the first batch), and p = (1 + null
  falls at least as large) / (1 + null recordings), in batches that stop once the verdict
  is decided;
- the reported refit is a longer search of the two folds from the symmetric fit (which it
  contains, so a refit that ends higher is a search failure, reported): Q, its NMSE and
  the start of the interval;
- Q's interval is a parametric bootstrap: recordings simulated from the two folds' fit
  with the same noise, each refitted from it; the interval is centred on the estimate less
  the bias the refits show and reaches Student's t quantile times their spread either way
  (`bootstrap_interval`, as the catalogue's effects get).

Asymmetry is needed when p <= alpha and Q's interval is measured (finite, of positive
width) and excludes Q = 1.
"""

import dataclasses

import jax
import numpy as np

from .._fit import FitResult, Swarm, fit_many
from .._integrate import simulated_fold_areas
from ..asymmetry import with_fold_areas
from ..compare import noise_level
from ..recording import Recording
from ..terms.base import AbstractFoldPair
from ..terms.folds import LeftRightAsymmetry
from ._calibration import bootstrap_interval
from ._options import DEFAULT_CALIBRATION, Calibration
from ._verdict import excludes

#: The search box of Q in the two folds' refits.
Q_BOUNDS = (0.5, 2.0)
#: The refits' swarm: small, as they start from the symmetric fit (the null recordings'
#: truth, or the recording's fit), whose point is particle 0; the recording's own refit
#: runs longer through the same program (the iteration count is data).
_REFIT_SWARM = Swarm(size=16, iterations=10)
_RECORDING_ITERATIONS = 40


@dataclasses.dataclass(frozen=True)
class AsymmetryTest:
    """The verdict of `asymmetry_test`.

    Attributes:
        symmetric_nmse: per-fold NMSE of the symmetric fit (each fold half of its GAW).
        nmse: per-fold NMSE of the two folds' refit.
        fall: the statistic on the recording: the per-fold NMSE's fall from the symmetric
            model to two folds, each refitted to the folds with the same search (see the
            module).
        p_value: the fall's calibrated p-value.
        replicates: null recordings simulated.
        Q: the refit's asymmetry ratio (the right fold's natural frequency over the left's).
        interval: Q's bootstrap interval (low, high) at the calibration's level.
        alpha: the significance level.
        refit: the two folds' `FitResult` (its model has `LeftRightAsymmetry`).
        search_failure: the refit ended above the symmetric fit it contains.
    """

    symmetric_nmse: float
    nmse: float
    fall: float
    p_value: float
    replicates: int
    Q: float
    interval: tuple[float, float]
    alpha: float
    refit: FitResult
    search_failure: bool

    @property
    def identified(self) -> bool:
        """Whether Q's interval is measured (finite, of positive width: bootstrap refits
        that all stay where they start measure nothing) and excludes 1."""
        return excludes(self.interval, 1.0)

    @property
    def needed(self) -> bool:
        """Significant, with an interval of Q that is measured and excludes 1."""
        return self.p_value <= self.alpha and self.identified and not self.search_failure

    @property
    def words(self) -> str:
        """The verdict in a sentence."""
        sizes = (
            f"Q = {self.Q:.3f} [{self.interval[0]:.3f}, {self.interval[1]:.3f}], per-fold NMSE "
            f"{self.symmetric_nmse:.3%} -> {self.nmse:.3%}, calibrated p = {self.p_value:.2g} "
            f"against {self.replicates} null recordings"
        )
        if self.search_failure:
            return (
                "Left-right asymmetry not assessed: its refit ended above the symmetric fit "
                f"({sizes})."
            )
        if self.needed:
            return f"Left-right asymmetry is needed: {sizes}."
        if self.p_value <= self.alpha:
            return f"Left-right asymmetry is detectable but not identifiable: {sizes}."
        return f"Left-right asymmetry is not needed: {sizes}."


def per_fold_nmse(left, right, folds) -> float:
    """The per-fold NMSE, sum((dL)² + (dR)²) / sum(L² + R²), of model areas ``left`` and
    ``right`` against measured ``folds`` (frames, 2)."""
    folds = np.asarray(folds, dtype=float)
    err = (np.asarray(left) - folds[:, 0]) ** 2 + (np.asarray(right) - folds[:, 1]) ** 2
    return float(np.sum(err) / np.sum(folds**2))


def _fold_gaws(result: FitResult) -> tuple[np.ndarray, np.ndarray]:
    """The fit's total and left GAWs on its frames (clipped at zero)."""
    sim = result.simulate()
    left, _ = simulated_fold_areas(result.model, sim)
    total = np.clip(np.asarray(sim.area), 0.0, None)
    return total, np.where(total > 0, np.asarray(left), 0.0)


def _noisy(recording, total, left, sd_total, sd_left, rng, name) -> Recording:
    """A recording of the GAW ``total`` whose left fold shows ``left``, with white noise."""
    area = np.clip(total + rng.normal(0.0, sd_total, total.size), 0.0, None)
    share = np.clip(left + rng.normal(0.0, sd_left, total.size), 0.0, area)
    return Recording(
        area=area,
        fps=recording.fps,
        unit=recording.unit,
        metadata=recording.metadata,
        name=name,
        folds=np.stack([share, area - share], axis=1),
    )


def _refits(models, recordings, params, key_seed, batch, swarm=_REFIT_SWARM) -> list[FitResult]:
    # padded to the calibration's batch: the recording's refit, the null recordings' and the
    # bootstrap's share their programs
    return fit_many(
        models,
        recordings,
        params,
        min_batch=batch,
        bounds={"Q": Q_BOUNDS} if "Q" in params else None,
        swarm=swarm,
        key=jax.random.key(key_seed),
        progress=False,
    )


def _statistic(model, recordings, params, calibration, done) -> list[float]:
    """The fall of the per-fold NMSE from the symmetric ``model`` to two folds, each refitted
    to every recording's per-fold areas with the same search: the symmetric model is refitted,
    then searched again from there, once as it is and once with two folds (at Q = 1), so that
    what a second search alone gains (a recording whose fit had not converged) is not read as
    asymmetry; 0 where the two folds end higher."""
    plain = _refits(
        [model] * len(recordings),
        recordings,
        params,
        calibration.seed + done + 1,
        calibration.batch,
    )
    key = calibration.seed + done + 2  # the second searches' (the same draws for both)
    again = _refits([f.model for f in plain], recordings, params, key, calibration.batch)
    two = _refits(
        [f.model.with_term(LeftRightAsymmetry(Q=1.0)) for f in plain],
        recordings,
        params + ("Q",),
        key,
        calibration.batch,
    )
    falls = []
    for p, a, t, rec in zip(plain, again, two, recordings):
        base = min(_symmetric_nmse(f.fitted_gaw(), rec.folds) for f in (p, a))
        falls.append(1.0 - min(t.nmse, base) / base)
    return falls


def _symmetric_nmse(gaw, folds) -> float:
    """The per-fold NMSE of a symmetric model's GAW ``gaw`` against the measured ``folds``
    (frames, 2), each fold half of the GAW."""
    half = 0.5 * np.asarray(gaw)
    return per_fold_nmse(half, half, folds)


def asymmetry_test(
    result: FitResult,
    recording: Recording,
    *,
    alpha: float = 0.01,
    calibration: Calibration = DEFAULT_CALIBRATION,
) -> AsymmetryTest:
    """Test whether the folds differ: the fitted (symmetric) model against the same model
    with two folds (`vfjax.LeftRightAsymmetry`), on each fold's area (see the module).

    Arguments:
        result: a fit of a model with one symmetric fold (`vfjax.fit`,
            `vfjax.fit_recording`, an investigation's last fit).
        recording: its recording, with per-fold areas (`Recording.folds`) or the edges or
            masks that a glottal midline splits into them.
        alpha: significance level.
        calibration: the null recordings (``replicates``, ``batch``, ``seed``) and Q's
            bootstrap (``interval``, ``interval_replicates``); its variability setting is
            not used (white noise only).

    Raises:
        ValueError: for a recording without per-fold areas, or a fit whose model already
            has two folds.
    """
    if result.model.has(AbstractFoldPair):
        raise ValueError("the fitted model has two folds already: test a symmetric fit")
    if recording.folds is None:
        if recording.edges is None and recording.masks is None:
            raise ValueError(
                f"{recording.name}: the asymmetry test needs each fold's area (folds, or "
                "edges or masks to split by the glottal midline)"
            )
        recording = with_fold_areas(recording)
    if not 0.0 < alpha < 1.0:
        raise ValueError(f"alpha must lie in (0, 1), got {alpha}")
    params = tuple(result.params)
    folds = recording.folds
    total = np.asarray(result.fitted_gaw())
    symmetric = _symmetric_nmse(total, folds)
    two_params = params + ("Q",)
    (refit,) = _refits(
        [result.model.with_term(LeftRightAsymmetry(Q=1.0))],
        [recording],
        two_params,
        calibration.seed,
        calibration.batch,
        dataclasses.replace(_REFIT_SWARM, iterations=_RECORDING_ITERATIONS),
    )
    two_total, two_left = _fold_gaws(refit)
    sd_total = noise_level(recording.area, two_total)
    sd_left = noise_level(folds[:, 0], two_left)
    rng = np.random.default_rng(calibration.seed)

    # the statistic, alike on the recording (first of the first batch) and on the null
    # recordings (the symmetric fit, each fold half of it): the symmetric model refitted to
    # the per-fold areas, then the two folds refitted from it; a fall from the symmetric fit
    # itself would count what refitting the shared parameters gains, which the null
    # recordings' truth does not offer
    observed = None
    falls: list[float] = []
    while len(falls) < calibration.replicates:
        first = observed is None
        n = min(calibration.batch - first, calibration.replicates - len(falls))
        recs = [recording] if first else []
        recs += [
            _noisy(recording, total, 0.5 * total, sd_total, sd_left, rng, f"null {len(falls) + i}")
            for i in range(n)
        ]
        here = _statistic(result.model, recs, params, calibration, len(falls))
        if first:
            observed, here = here[0], here[1:]
        falls += here
        beyond = sum(f >= observed for f in falls)
        if (1 + beyond) / (1 + calibration.replicates) > alpha:
            break  # no more null recordings can bring p to alpha
    p_value = (1 + beyond) / (1 + len(falls))

    # Q's interval: recordings of the two folds' fit, refitted from it
    copies = [
        _noisy(recording, two_total, two_left, sd_total, sd_left, rng, f"bootstrap {i}")
        for i in range(calibration.interval_replicates)
    ]
    boot = _refits(
        [refit.model] * len(copies),
        copies,
        two_params,
        calibration.seed + 10_000,
        calibration.batch,
    )
    q_hat = float(refit.params["Q"])
    qs = [f.params["Q"] for f in boot if np.isfinite(f.nmse)]
    interval = bootstrap_interval(q_hat, qs, calibration.interval)  # as the catalogue's
    return AsymmetryTest(
        symmetric_nmse=symmetric,
        nmse=refit.nmse,
        fall=observed,
        p_value=p_value,
        replicates=len(falls),
        Q=q_hat,
        interval=interval,
        alpha=alpha,
        refit=refit,
        search_failure=bool(refit.nmse > symmetric * (1.0 + 1e-6)),
    )
