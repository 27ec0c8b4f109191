"""Whether a fit describes a sustained oscillation: the fitted model after a longer warm-up.

A fit simulates the model from rest at contact and samples the recording's frames after a
warm-up (`default_warmup`). A recording of sustained phonation is an oscillation that no
longer depends on how it started. Where the fitted model's oscillation still grows or decays
at the first frame (a glottis that never closes: no closure hold resets the state each
cycle), the fit can match the recording with the start-up itself, and its parameters then
describe a transient that the larynx never shows. `settling` simulates the fitted model
after a longer warm-up and says whether its error changes by more than the recording's
noise explains.
"""

import dataclasses
import math

import jax
import numpy as np

from ..descriptors import noise_level
from ..recording import Recording
from ._engine import DEFAULT_POLISH, polish_slices, stack_strong
from ._problem import fit_sampling, prepare, start_point
from ._result import FitResult

#: The warm-up (s) after which `settling` simulates a fitted model by default: about 25
#: cycles of a low male voice.
SETTLING_WARMUP = 0.2


@dataclasses.dataclass(frozen=True)
class Settling:
    """The fitted model's error after its fit's warm-up and after a longer one.

    Both errors are the fitted model's NMSE with S and the time shift polished afresh (from
    the fit's own at its warm-up; from the best of a grid of shifts half a frame apart at the
    longer one, which moves the phase of the cycle at the first frame), so that the two are
    compared like with like.

    Attributes:
        fit_warmup: the fit's warm-up (s).
        warmup: the longer warm-up (s).
        fit_nmse: NMSE after the fit's warm-up.
        nmse: NMSE after the longer warm-up.
        noise_nmse: the NMSE that the recording's white noise alone leaves
            (`vfjax.descriptors.noise_level` of the fit's residual), at most the fit's own;
            the fit's own where the residual does not show the noise (too few runs of five
            open frames, as at 2 000 fps on a short open phase): the residual holds the
            noise, so its error bounds the noise's.
    """

    fit_warmup: float
    warmup: float
    fit_nmse: float
    nmse: float
    noise_nmse: float

    @property
    def settled(self) -> bool:
        """Whether the longer warm-up changes the error by no more than the noise leaves."""
        return bool(self.nmse <= self.fit_nmse + self.noise_nmse)

    def words(self) -> str:
        """The check in a sentence."""
        numbers = (
            f"NMSE {self.fit_nmse:.3%} after the fit's {self.fit_warmup * 1e3:.0f} ms warm-up, "
            f"{self.nmse:.3%} after {self.warmup * 1e3:.0f} ms (noise floor "
            f"{self.noise_nmse:.3%})"
        )
        if self.settled:
            return f"the fitted oscillation is settled ({numbers})"
        return (
            f"the fit is not settled ({numbers}): it matches the recording with the model's "
            "start-up from rest, not with a sustained oscillation, so its parameters describe "
            f"a transient; fit it again with a warm-up of {self.warmup:g} s (warmup="
            f"{self.warmup:g}; vfjax fit --warmup {self.warmup:g})"
        )


def settling(result: FitResult, recording: Recording, warmup_s: float | None = None) -> Settling:
    """Simulate ``result``'s fitted model after a longer warm-up and compare its error.

    Arguments:
        result: a fit of ``recording`` (`vfjax.fit`, `vfjax.fit_recording`).
        recording: the recording it fitted.
        warmup_s: the longer warm-up (s); default `SETTLING_WARMUP`, or twice the fit's
            warm-up if that is already longer.

    Returns:
        `Settling`: both errors, the noise floor, and ``settled``.
    """
    return settlings([result], [recording], warmup_s)[0]


def settlings(results, recordings, warmup_s: float | None = None) -> list[Settling]:
    """`settling` of each of ``results`` (fits of the ``recordings``, in order): their S and
    time-shift polishes in one batch, dealt to the devices (each recording's pair through
    the same program as alone, so each check is the same as `settling` of it alone)."""
    warmups, pairs, grids, firsts, keys = [], [], [], [], []
    for result, recording in zip(results, recordings):
        if not isinstance(result, FitResult) or not isinstance(recording, Recording):
            raise TypeError("settling needs a vfjax.FitResult and the vfjax.Recording it fitted")
        if recording.n_frames != result.sampling.n_frames or recording.fps != result.sampling.fps:
            raise ValueError(
                f"{recording.name}: {recording.n_frames} frames at {recording.fps:g} fps, but "
                f"the fit sampled {result.sampling.n_frames} at {result.sampling.fps:g}"
            )
        own = float(result.sampling.warmup)
        longer = max(SETTLING_WARMUP, 2.0 * own) if warmup_s is None else float(warmup_s)
        if not (math.isfinite(longer) and longer > own):
            raise ValueError(f"warmup_s must be longer than the fit's {own:g} s, got {warmup_s}")
        # S re-projected for a GAW in pixels; otherwise a held parameter (a fit needs one name)
        params, held = (("S",), ()) if recording.unit == "px" else (("K",), ("K",))
        problems = []
        for w in (own, longer):
            sampling, period = fit_sampling(recording, w, result.sampling.substeps)
            problems.append(
                prepare(result.model, recording, params, sampling, period, None, held)[0]
            )
        # after the fit's warm-up from its own shift at its own S (the problem's reference);
        # after the longer one from the grid's best shift (the phase of the cycle at the
        # first frame moves): half a frame of misalignment on a GAW with sharp closures costs
        # more error than a settled model's drift
        first = np.zeros(problems[0].point_size)
        first[len(problems[0].names)] = result.time_shift / float(problems[0].period)
        point, cost = start_point(problems[1], np.zeros(len(problems[1].names)))[:2]
        pair = jax.tree.map(stack_strong, *problems)
        leaves, tree = jax.tree.flatten(pair)  # a program: its structure and shapes
        keys.append((tree, tuple((np.shape(x), str(getattr(x, "dtype", type(x)))) for x in leaves)))
        warmups.append((own, longer))
        pairs.append(pair)
        grids.append((np.asarray(point), np.asarray(cost)))
        firsts.append(first)
    # S and the shift polished by the fits' own compiled polish (the problems have the
    # structure and sizes of a fit of each result's model, so that program is reused): one
    # slice of two per recording, the first from its point, the second from the grid's; the
    # recordings whose pairs share a program in one batch
    errors = [None] * len(pairs)
    for key in dict.fromkeys(keys):
        mine = [i for i, k in enumerate(keys) if k == key]
        polished = polish_slices(
            jax.tree.map(lambda *x: np.concatenate(x), *[pairs[i] for i in mine]),
            np.ones(2 * len(mine), bool),
            tuple(np.concatenate([np.stack([grids[i][j]] * 2) for i in mine]) for j in range(2)),
            np.concatenate([np.stack([firsts[i], grids[i][0]]) for i in mine]),
            np.tile([True, False], len(mine)),
            DEFAULT_POLISH,
        )
        costs = np.asarray(polished[3])
        for n, i in enumerate(mine):
            errors[i] = (float(costs[2 * n]), float(costs[2 * n + 1]))
    out = []
    for (own, longer), (fit_error, error), result, recording in zip(
        warmups, errors, results, recordings
    ):
        noise = noise_level(recording.area, result.fitted_gaw(recording))
        measured = recording.n_frames * noise**2 / float(np.sum(recording.area**2))
        floor = min(measured, fit_error) if noise > 0 else fit_error
        out.append(Settling(own, longer, fit_error, error, floor))
    return out
