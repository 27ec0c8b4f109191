"""`vfjax.cohort`: fit and diagnose every recording of a folder or manifest in one resumable
job, in this process or on a Dask cluster."""

import logging
import math
import pathlib
import time
from os import PathLike
from typing import TYPE_CHECKING

from .._version import __version__
from ._inputs import CohortEntry, content_key, find_entries, read_manifest
from ._options import DEFAULT_OPTIONS, CohortOptions
from ._report import write_cohort_report
from ._store import CohortFolder
from ._table import table, write_table
from ._work import Task, by_kind, finite_or_none, process_batch, read

if TYPE_CHECKING:
    import pandas


def _entries(source, fps, out) -> tuple[list[CohortEntry], list[str]]:
    source = pathlib.Path(source)
    if source.is_dir():
        return find_entries(source, fps, exclude=out), []
    if not source.exists():
        raise FileNotFoundError(f"cohort input {source} does not exist")
    entries = read_manifest(source, fps)
    return entries, list(entries[0].groups)


def _batches(tasks: list[Task], size: int, split: int = 1) -> list[list[Task]]:
    """Tasks grouped by `batch_kind` (in their order), each group cut into batches of at
    most ``size``, and into at least ``split`` batches where it has as many tasks (so that
    every worker gets a share)."""
    batches = []
    for group in by_kind(tasks):
        n = max(math.ceil(len(group) / size), min(split, len(group)))
        per = math.ceil(len(group) / n)
        batches += [group[i : i + per] for i in range(0, len(group), per)]
    return batches


def _settings(options: CohortOptions) -> dict:
    return {"vfjax": __version__, "options": repr(options)}


def cohort(
    source: str | PathLike,
    out: str | PathLike,
    options: CohortOptions = DEFAULT_OPTIONS,
    *,
    fps: float | None = None,
    workers: int | None = None,
    scheduler: object = None,
    retry_failed: bool = False,
    progress: bool = False,
) -> "pandas.DataFrame":
    """Fit (and diagnose) every recording of a cohort; returns the cohort table.

    Each recording's results are written to ``out/recordings/<name>/`` as soon as they are
    complete (a whole folder or none), keyed by the content of its files and the settings:
    a rerun skips the recordings whose results are current and redoes the others, so a run
    that was killed goes on where it stopped. A recording that cannot be read or fitted is
    recorded as failed, with its reason, and the cohort goes on. Recordings of one length
    bucket share one batched first fit (`vfjax.fit_recordings`); each is then diagnosed as
    `vfjax.investigate` does, from that fit. A recording's results do not depend on the
    batch it ran in, nor on the process or worker.

    Writes ``out/cohort.csv`` and ``out/cohort.parquet`` (the table) and ``out/report.md``
    (parameter distributions by group, effects found, error before and after, failures).

    Arguments:
        source: a folder (searched recursively for GAW tables with JSON sidecars, contour
            files ``.txt`` and videos) or a manifest (CSV: ``path``, optional ``fps`` in Hz,
            and grouping columns such as subject, sex, condition).
        out: the output folder (new, empty, or an earlier run's of this cohort).
        options: what is done to each recording (`CohortOptions`).
        fps: frame rate (Hz) for files that state none (contour files) and manifest rows
            that leave it empty.
        workers: run on a local Dask cluster of this many worker processes (one core each).
        scheduler: a running Dask cluster: its scheduler's address (e.g.
            ``tcp://host:8786``) or a ``distributed.Client``; its workers must see
            ``source`` and ``out`` at the same paths. Each worker gives JAX one CPU device
            per thread it has (a fit's swarm is split over them).
        retry_failed: redo the recordings that failed in an earlier run, although their
            inputs did not change.
        progress: show one progress bar for the cohort, with the time left.

    Returns:
        The cohort table (`pandas.DataFrame`), one row per recording in the input's order:
        the recording, its groups, status and reason, the measured GAW's descriptors, NMSE
        of the first and final fits, the effects added with calibrated p-values and
        intervals, the final model's parameters (units in the column names).
    """
    from ._table import pandas

    pandas()
    if not isinstance(options, CohortOptions):
        raise TypeError(f"options must be a vfjax.CohortOptions, got {type(options).__name__}")
    if workers is not None and (isinstance(workers, bool) or int(workers) < 1):
        raise ValueError(f"workers must be a positive number of processes, got {workers!r}")
    if workers is not None and scheduler is not None:
        raise ValueError("give workers (a local cluster) or scheduler (a running one), not both")
    t0 = time.perf_counter()
    folder = CohortFolder(out)
    entries, groups = _entries(source, fps, folder.root)
    folder.check()

    import filelock

    folder.root.mkdir(parents=True, exist_ok=True)
    lock = filelock.FileLock(str(folder.root / ".cohort.lock"))
    try:
        lock.acquire(timeout=0)
    except filelock.Timeout:
        raise OSError(f"another cohort run is writing to {folder.root}") from None
    try:
        settings = _settings(options)
        folder.prepare(settings)
        text = repr(sorted(settings.items()))
        tasks, rows = [], {}
        for entry in entries:
            key = content_key(entry, text)
            row = folder.done(entry.id, key)
            if row is not None and (row.get("status") == "done" or not retry_failed):
                rows[entry.id] = row
            else:
                tasks.append(Task(entry, key))
        bar = None
        if progress:
            from tqdm.auto import tqdm

            bar = tqdm(total=len(entries), initial=len(rows), desc="cohort", unit="recording")
        try:
            if tasks:
                run = _run_serial if workers is None and scheduler is None else _run_dask
                for row in run(tasks, options, folder, workers, scheduler):
                    rows[row["recording"]] = row
                    if bar is not None:
                        bar.update(1)
        finally:
            if bar is not None:
                bar.close()
        ordered = []
        for entry in entries:
            row = {k: finite_or_none(v) for k, v in rows[entry.id].items()}
            ordered.append({**row, **entry.groups})
        frame = table(ordered, groups)
        write_table(frame, folder.root)
        write_cohort_report(frame, folder.root, groups, time.perf_counter() - t0)
    finally:
        lock.release()
    return frame


def _run_serial(tasks, options, folder, workers, scheduler):
    """Read, fit and diagnose in this process; yields each row as it is committed."""
    read_ok = []
    for task in tasks:
        result = read(task, folder)
        if isinstance(result, dict):
            yield result
        else:
            read_ok.append(result)
    for batch in _batches(read_ok, options.batch):
        done = []
        process_batch(batch, options, folder, on_done=done.append)
        yield from done


def _configure(setup: dict) -> None:
    """A worker's JAX: one CPU device per thread of the Dask worker, the compilation cache
    of the calling process (idempotent; before the worker's first computation)."""
    import jax
    from distributed import get_worker

    from .._runtime import use_compilation_cache, use_cpu_cores

    use_cpu_cores(get_worker().state.nthreads)
    if setup["cache"] is not None:
        use_compilation_cache(setup["cache"])
    else:
        jax.config.update("jax_enable_compilation_cache", False)


def _remote_read(task: Task, root: str):
    return read(task, CohortFolder(root))


def _remote_batch(tasks, options, root: str, setup: dict):
    _configure(setup)
    return process_batch(tasks, options, root)


def _run_dask(tasks, options, folder, workers, scheduler):
    """Read, fit and diagnose on a Dask cluster (local worker processes, or the one at
    ``scheduler``); yields each row as its batch completes."""
    import jax

    try:
        from distributed import Client, LocalCluster, as_completed
    except ImportError as err:  # pragma: no cover - the cohort extra is installed in tests
        raise ImportError(
            "a cohort on a cluster needs Dask distributed: pip install 'vfjax[cohort]'"
        ) from err

    cache = (
        jax.config.jax_compilation_cache_dir if jax.config.jax_enable_compilation_cache else None
    )
    cluster, own = None, True
    if scheduler is None:
        cluster = LocalCluster(
            n_workers=int(workers),
            threads_per_worker=1,
            processes=True,
            dashboard_address=None,
            silence_logs=logging.ERROR,
        )
        client = Client(cluster)
    elif isinstance(scheduler, Client):
        client, own = scheduler, False
    else:
        client = Client(scheduler)
    setup = {"cache": cache}
    root = str(folder.root.resolve())
    try:
        n_workers = max(len(client.scheduler_info()["workers"]), 1)
        read_ok = []
        for future in as_completed(client.map(_remote_read, tasks, root=root, pure=False)):
            result = future.result()
            if isinstance(result, dict):
                yield result
            else:
                read_ok.append(result)
        order = {t.entry.id: i for i, t in enumerate(tasks)}
        read_ok.sort(key=lambda t: order[t.entry.id])
        futures = [
            client.submit(_remote_batch, batch, options, root, setup, pure=False)
            for batch in _batches(read_ok, options.batch, split=n_workers)
        ]
        for future in as_completed(futures):
            yield from future.result()
    finally:
        if own:
            client.close()
        if cluster is not None:
            cluster.close()
