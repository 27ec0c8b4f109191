"""Fit, diagnose, extend, repeat: the whole loop of `vfjax diagnose` in one function.

study = vfjax.investigate(recording)        # the paper's model, then up to 2 effects
study.rounds[0].diagnosis.verdict           # what is missing, in words
study.final.nmse                            # the error after the last extension
vfjax.report.write_report(study, recording, "out/")
"""

import dataclasses
from collections.abc import Sequence

from ._fit import FitResult, Swarm, fit
from .diagnosis import CONFIRM, Diagnosis, diagnose
from .presets import initial_model
from .recording import Recording


@dataclasses.dataclass(frozen=True)
class Round:
    """One round: a fit, its diagnosis, and the extended fit if an effect was added.

    Attributes:
        fit: the model's fit at the start of the round.
        diagnosis: `vfjax.diagnose` of that fit.
        added: the effect added (its name), or None (the loop stops).
        extended: the fit with the effect, warm-started from the diagnosis's refit (a full
            swarm + LM fit from there), or None.
    """

    fit: FitResult
    diagnosis: Diagnosis
    added: str | None
    extended: FitResult | None


@dataclasses.dataclass(frozen=True)
class Investigation:
    """The rounds of `investigate`, first to last."""

    recording_name: str
    rounds: list

    @property
    def first(self) -> FitResult:
        """The fit of the starting model."""
        return self.rounds[0].fit

    @property
    def final(self) -> FitResult:
        """The last fit: the extended model after the last round that added an effect; when
        the last round added none and its diagnosis's control (the same model refitted with
        the diagnosis's wider search) reached a lower error, that control refit."""
        last = self.rounds[-1]
        if last.extended is not None:
            return last.extended
        control = last.diagnosis.control
        return control if control is not None and control.nmse < last.fit.nmse else last.fit

    @property
    def added(self) -> list[str]:
        """The effects added, in order."""
        return [r.added for r in self.rounds if r.added]


def extend_from(
    diagnosis: Diagnosis, recording: Recording, effect: str | None = None, iterations: int = 40
) -> FitResult:
    """The fit with ``effect`` (default: the diagnosis's best): a full fit (swarm + LM) of the
    fitted parameters and the effect's, warm-started from the diagnosis's quick refit; the
    better of the two is returned."""
    name = effect or diagnosis.best
    if name is None:
        raise ValueError("the diagnosis found no effect to add; name one with effect=...")
    if name not in diagnosis.refits:
        raise ValueError(
            f"no refit of {name!r} in this diagnosis (refit=False, or not a "
            f"candidate); candidates: {sorted(diagnosis.refits)}"
        )
    start = diagnosis.refits[name].result
    polished = fit(
        start.model,
        recording,
        params=tuple(start.params),
        swarm=Swarm(iterations=iterations),
        warmup=start.sampling.warmup,
        substeps=start.sampling.substeps,
        progress=False,
    )
    return polished if polished.nmse < start.nmse else start


def investigate(
    recording: Recording,
    model=None,
    params: Sequence[str] = ("S", "K", "C_f", "t_c"),
    *,
    rounds: int = 2,
    candidates: Sequence | None = None,
    alpha: float = 0.01,
    min_fall: float = 0.2,
    iterations: int = 60,
    confirm: tuple[int, int] | None = CONFIRM,
    progress: bool = False,
) -> Investigation:
    """Fit ``model`` (default `vfjax.initial_model`), diagnose, add the best effect, refit,
    and repeat up to ``rounds`` times or until no effect is needed.

    Arguments:
        recording: the measured GAW.
        model: the starting model (default: `initial_model(recording)`).
        params: parameters of the first fit.
        rounds: most effects to add.
        candidates, alpha, min_fall: passed to `vfjax.diagnose`.
        iterations: PSO iterations of the first fit and of each extension.
        confirm: the diagnoses' confirming refit, passed to `vfjax.diagnose` (None: quick
            refits only, a few minutes less per round).
        progress: print what happens.
    """
    model = initial_model(recording) if model is None else model
    current = fit(
        model, recording, params=params, swarm=Swarm(iterations=iterations), progress=progress
    )
    if progress:
        print(f"fit: NMSE {current.nmse:.4g}")
    done = []
    for _ in range(max(rounds, 1)):
        remaining = (
            None
            if candidates is None
            else [c for c in candidates if not current.model.has(_kind(c))]
        )
        d = diagnose(
            current,
            recording,
            remaining,
            alpha=alpha,
            min_fall=min_fall,
            confirm=confirm,
            progress=progress,
        )
        if progress:
            print(d.verdict)
        if d.best is None or len(done) >= rounds:
            done.append(Round(current, d, None, None))
            break
        extended = extend_from(d, recording, iterations=iterations)
        done.append(Round(current, d, d.best, extended))
        current = extended
        if len(done) == rounds:
            break
    return Investigation(recording.name, done)


def _kind(candidate) -> type:
    from .diagnosis import Candidate

    if isinstance(candidate, Candidate):
        return type(candidate.term)
    return candidate if isinstance(candidate, type) else type(candidate)
