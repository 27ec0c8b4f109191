"""The work on a cohort's recordings: reading them, fitting a batch of them as one job, and
diagnosing each; every recording's outputs committed to the cohort's folder as soon as they
are complete, and its table row returned. These functions run in the calling process or in a
Dask worker (`vfjax.cohort`), with the same results."""

import dataclasses
import math
import time
import warnings

import numpy as np

from .._sampling import length_bucket
from ..recording import Recording
from ._inputs import CohortEntry, load_entry
from ._options import CohortOptions
from ._store import CohortFolder

#: The measured GAW's descriptors in the cohort table: (column, `Descriptors` field).
DESCRIPTOR_COLUMNS = (
    ("f0 [Hz]", "f0"),
    ("cycles", "n_cycles"),
    ("open quotient", "open_quotient"),
    ("speed quotient", "speed_quotient"),
    ("closing quotient", "closing_quotient"),
    ("jitter", "jitter"),
    ("shimmer", "shimmer"),
)


@dataclasses.dataclass(frozen=True)
class Task:
    """One recording to process: its entry, its content key and, once read, the
    recording (None until then)."""

    entry: CohortEntry
    key: str
    recording: Recording | None = None


def _reason(err: BaseException) -> str:
    text = str(err).strip().splitlines()
    return f"{type(err).__name__}: {text[0] if text else ''}".rstrip(": ")


def base_row(entry: CohortEntry) -> dict:
    """The columns every row has: the recording's name, file, kind and status."""
    return {
        "recording": entry.id,
        "path": str(entry.path),
        "kind": entry.kind,
        "status": "failed",
        "reason": "",
    }


def failed_row(entry: CohortEntry, reason: str, rec: Recording | None = None) -> dict:
    """The row of a recording that failed (with what was measured on it, if it was read)."""
    measured = {} if rec is None else _measured_columns(rec)
    return {**base_row(entry), "reason": reason, **measured}


def read(task: Task, folder: CohortFolder) -> Task | dict:
    """Read the task's recording; a recording that cannot be read is committed as failed,
    with its reason, and its row returned instead."""
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            rec = load_entry(task.entry)
    except Exception as err:  # any bad input is recorded, and the cohort goes on
        row = failed_row(task.entry, _reason(err))
        folder.commit(task.entry.id, task.key, row)
        return row
    return dataclasses.replace(task, recording=rec)


def batch_kind(recording: Recording) -> tuple:
    """What recordings must share to be fitted in one batch: the length bucket and the unit
    (whether S is fitted). Recordings that state their subglottal pressure and recordings
    that do not share a batch: the fits of the first hold P_s."""
    return (length_bucket(recording.n_frames), recording.unit)


def by_kind(tasks: list[Task]) -> list[list[Task]]:
    """The tasks grouped by `batch_kind` of their recordings, each group in the tasks'
    order."""
    kinds = {}
    for task in tasks:
        kinds.setdefault(batch_kind(task.recording), []).append(task)
    return list(kinds.values())


def _measured_columns(rec: Recording) -> dict:
    """The measured GAW's descriptors (`DESCRIPTOR_COLUMNS`); its `periodicity` where it is
    not periodic, else its `phonation breaks` where it has any, and the `cautions` of both
    and of an f0 outside phonation's (`vfjax.descriptors.recording_cautions`); and,
    for a recording whose folds can be told apart (per-fold areas, contour edges or video
    masks split by the glottal midline), the asymmetry indices ASI and PAI
    (`vfjax.asymmetry`)."""
    from ..asymmetry import asymmetry_indices, fold_areas
    from ..descriptors import (
        MIN_PERIODICITY,
        break_spans,
        describe,
        phonation_breaks,
        phonation_periodicity,
        recording_cautions,
    )

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        d = describe(rec.area, rec.fps)
    row = {"fps [Hz]": rec.fps, "frames": rec.n_frames, "unit": rec.unit}
    for column, field in DESCRIPTOR_COLUMNS:
        row[column] = float(getattr(d, field))
    breaks = phonation_breaks(rec.area, rec.fps)
    score = phonation_periodicity(rec.area, rec.fps, breaks)
    if score < MIN_PERIODICITY:  # no glottal vibration a model of phonation describes
        row["periodicity"] = score
    elif breaks:  # stretches without glottal cycles, which no fit follows
        row["phonation breaks"] = break_spans(breaks)
    cautions = recording_cautions(rec.area, rec.fps, rec.name)
    if cautions:  # (what `vfjax.fit_recordings` warns of, which the cohort keeps here)
        row["cautions"] = "; ".join(cautions)
    try:
        indices = asymmetry_indices(*fold_areas(rec), rec.fps)
    except ValueError:  # a GAW alone, or a glottis that never spans two rows: no midline
        pass
    else:
        row["ASI"], row["PAI"] = indices.asi, indices.pai
    return row


def _parameter_columns(result) -> dict:
    return {f"{n} [{result.units.get(n, '')}]": float(v) for n, v in result.params.items()}


def fit_row(entry: CohortEntry, rec: Recording, first, seconds: float) -> dict:
    """The row of a recording fitted (not diagnosed)."""
    row = {
        **base_row(entry),
        **_measured_columns(rec),
        "first NMSE": first.nmse,
        "final NMSE": first.nmse,
        "fit status": first.status,
        **_parameter_columns(first),
        "seconds": seconds,
    }
    if first.failed:
        row["reason"] = first.status_message()
    else:
        row["status"] = "done"
    return row


def study_row(entry: CohortEntry, rec: Recording, study, seconds: float) -> dict:
    """The row of a recording fitted and diagnosed (`vfjax.Investigation`): NMSE before and
    after, the effects added with their calibrated p-values and intervals, those the final
    round names unconfirmed (`vfjax.Diagnosis.unconfirmed`), the final round's
    test of cycle-to-cycle variability, the final fit's calibrated goodness of fit
    (`vfjax.workflow.Investigation.fit_p_value`, where a calibration weighed it), whether the
    final fit is settled (`vfjax.settling`: its NMSE after the longer warm-up), the outcome
    and the final model's parameters."""
    outcome = study.outcome(rec)
    final = study.final
    row = {
        **base_row(entry),
        **_measured_columns(rec),
        "first NMSE": study.first.nmse,
        "final NMSE": final.nmse,
        "noise NMSE": outcome.noise_nmse,
        "fit status": final.status,
        "settled NMSE": outcome.settling.nmse,
        "settled": "yes" if outcome.settling.settled else "no",
        "outcome": outcome.status,
        "effects needed": "; ".join(study.added),
        # found by the final round's search but not by its calibrated refits
        "effects unconfirmed": "; ".join(study.rounds[-1].diagnosis.unconfirmed),
        **_parameter_columns(final),
    }
    for r in study.rounds:
        if r.added is None:
            continue
        refit = r.diagnosis.refits[r.added]
        row[f"{r.added} p"] = refit.p_value
        for name, (low, high) in (refit.interval or {}).items():
            unit = final.units.get(name, "")
            row[f"{name} low [{unit}]"] = float(low)
            row[f"{name} high [{unit}]"] = float(high)
    cycles = study.rounds[-1].diagnosis.variability
    if cycles is not None:  # cycle-to-cycle variability, tested on the final round
        row["cycle variability p"] = cycles.p_value
        row["timing spread [s]"] = cycles.timing_sd
        row["amplitude spread [1]"] = cycles.amplitude_sd
    if math.isfinite(outcome.fit_p_value):  # the final fit weighed by a calibration
        row["goodness of fit p"] = outcome.fit_p_value
    row["conclusion"] = outcome.words
    row["seconds"] = seconds
    if final.failed:
        row["reason"] = final.status_message()
    else:
        row["status"] = "done"
    return row


def _fit_group(tasks: list[Task], options: CohortOptions) -> list:
    """First fits of recordings of one kind, one batched job; where the job fails, each
    recording alone (so one recording's failure does not take the others down)."""
    import jax

    from .._fit import fit_recordings
    from ..descriptors import RecordingWarning

    recs = [t.recording for t in tasks]
    key = jax.random.key(options.seed)
    common = dict(restarts=options.restarts, swarm=options.swarm, key=key, progress=False)
    with warnings.catch_warnings():  # (each recording's cautions are a column of its row)
        warnings.simplefilter("ignore", RecordingWarning)
        try:
            return fit_recordings(recs, **common)
        except Exception:
            if len(recs) == 1:
                raise
        out = []
        for rec in recs:
            try:
                out.extend(fit_recordings([rec], **common))
            except Exception as err:
                out.append(err)
        return out


def _write_fit(first):
    def write(stage):
        first.to_json(stage / "fit.json")

    return write


def _write_study(study, rec):
    def write(stage):
        from ..report import write_report

        study.first.to_json(stage / "fit.json")
        study.final.to_json(stage / "final_fit.json")
        write_report(study, rec, stage)

    return write


def process_batch(tasks: list[Task], options: CohortOptions, folder, on_done=None) -> list[dict]:
    """Fit a batch of read recordings (one batched job per kind, `batch_kind`), diagnose
    each when the options say so, and commit each recording's folder as soon as its work is
    done. Returns the rows in the tasks' order.

    Arguments:
        tasks: recordings read (`read`).
        options: the cohort's `CohortOptions`.
        folder: the cohort's output folder (a path or `CohortFolder`).
        on_done: called with each row as it is committed.
    """
    import matplotlib.pyplot as plt

    from .._diagnosis import investigate

    folder = folder if isinstance(folder, CohortFolder) else CohortFolder(folder)
    rows = {}

    def commit(task, row, write=None):
        try:
            folder.commit(task.entry.id, task.key, row, write)
        except Exception as err:  # e.g. a report that cannot be drawn
            row = {**row, "status": "failed", "reason": f"writing its outputs: {_reason(err)}"}
            folder.commit(task.entry.id, task.key, row)
        finally:
            plt.close("all")
        rows[task.entry.id] = row
        if on_done is not None:
            on_done(row)

    for group in by_kind(tasks):
        t0 = time.perf_counter()
        try:
            firsts = _fit_group(group, options)
        except Exception as err:
            firsts = [err] * len(group)
        share = (time.perf_counter() - t0) / len(group)
        for task, first in zip(group, firsts):
            rec = task.recording
            if isinstance(first, BaseException):
                reason = f"the first fit: {_reason(first)}"
                commit(task, failed_row(task.entry, reason, rec))
                continue
            if not options.diagnose:
                commit(task, fit_row(task.entry, rec, first, share), _write_fit(first))
                continue
            t1 = time.perf_counter()
            try:
                study = investigate(
                    rec,
                    rounds=options.rounds,
                    candidates=options.candidates,
                    criteria=options.criteria,
                    plan=options.plan,
                    calibration=options.calibration,
                    swarm=options.swarm,
                    first=first,
                )
            except Exception as err:
                row = fit_row(task.entry, rec, first, share)
                row.update(status="failed", reason=f"the diagnosis: {_reason(err)}")
                commit(task, row, _write_fit(first))
                continue
            seconds = share + time.perf_counter() - t1
            commit(task, study_row(task.entry, rec, study, seconds), _write_study(study, rec))
    return [rows[t.entry.id] for t in tasks]


def finite_or_none(value):
    """A float for JSON: None where it is not finite."""
    if isinstance(value, float | np.floating) and not math.isfinite(value):
        return None
    return value
