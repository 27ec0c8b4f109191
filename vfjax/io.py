"""Writing files safely, and writing recordings (a CSV table of the GAW plus a JSON sidecar).

Every file vfjax writes is written atomically: to a temporary file beside it, then renamed
over the target, so that an interrupted run never leaves a half-written file, and a reader
sees either the old file or the new one. The command line writes each run's outputs into a
staging folder and moves them into the output folder once the run has finished
(`staged_output`).
"""

import contextlib
import json
import os
import pathlib
import secrets
import shutil

import numpy as np

from .phases import PHASE_NAMES


def new_entry(parent, prefix: str, suffix: str = "", folder: bool = False) -> pathlib.Path:
    """Create a new, uniquely named empty file (or ``folder``) in ``parent``: ``prefix`` +
    random characters + ``suffix``. Unlike `tempfile`'s, whose entries only their owner may
    read, it has the permissions of any file or folder the user creates (the umask's), so
    that outputs renamed from it are as readable as the rest of the output folder."""
    parent = pathlib.Path(parent)
    while True:
        path = parent / f"{prefix}{secrets.token_hex(4)}{suffix}"
        try:
            if folder:
                os.mkdir(path, 0o777)
            else:
                os.close(os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666))
            return path
        except FileExistsError:
            continue


@contextlib.contextmanager
def atomic_path(path):
    """A temporary path beside ``path`` to write to; renamed to ``path`` when the block ends
    without an error, removed otherwise. The temporary name keeps the suffix, so writers that
    choose a format by it (matplotlib's ``savefig``) write the right one."""
    path = pathlib.Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = new_entry(path.parent, f".{path.stem}.{os.getpid()}.", f".partial{path.suffix}")
    try:
        yield tmp
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)


def remove_partials(folder, pid: int | None = None) -> None:
    """Remove the staging folders and temporary files that process ``pid`` (default: this
    one) left in ``folder`` (`staged_output`, `atomic_path`): for an exit that cannot unwind
    the stack (a second Ctrl-C, or one that a library swallowed)."""
    pid = os.getpid() if pid is None else pid
    folder = pathlib.Path(folder)
    if not folder.is_dir():
        return
    for entry in folder.glob(f".*.partial-{pid}-*"):
        shutil.rmtree(entry, ignore_errors=True)
    for entry in folder.glob(f".*.{pid}.*.partial*"):
        if entry.is_file():
            entry.unlink(missing_ok=True)


def write_text(path, text: str) -> pathlib.Path:
    """Write ``text`` to ``path`` atomically (UTF-8); returns the path."""
    path = pathlib.Path(path)
    with atomic_path(path) as tmp:
        tmp.write_text(text, encoding="utf-8")
    return path


def write_json(path, data) -> pathlib.Path:
    """Write ``data`` as indented JSON to ``path`` atomically; returns the path."""
    return write_text(path, json.dumps(data, indent=1) + "\n")


def save_figure(fig, path, **kwargs) -> pathlib.Path:
    """``fig.savefig(path, **kwargs)``, atomically; returns the path."""
    path = pathlib.Path(path)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, **kwargs)
    return path


def check_output_file(path, force: bool) -> pathlib.Path:
    """``path``, or ValueError if a file is there already and ``force`` is False."""
    path = pathlib.Path(path)
    if path.is_dir():
        raise ValueError(f"{path} is a folder; name a file to write")
    if path.exists() and not force:
        raise ValueError(f"{path} exists; use --force to overwrite it, or name another file")
    return path


def check_output_folder(folder, force: bool) -> pathlib.Path:
    """``folder``, or ValueError unless it is missing, empty, or ``force`` is given."""
    folder = pathlib.Path(folder)
    if folder.exists() and not folder.is_dir():
        raise ValueError(f"{folder} exists and is not a folder")
    if folder.is_dir() and any(folder.iterdir()) and not force:
        n = sum(1 for _ in folder.iterdir())
        raise ValueError(
            f"output folder {folder} is not empty ({n} entries): use --force to "
            "overwrite its files, or name another folder with --out"
        )
    return folder


@contextlib.contextmanager
def staged_output(folder, force: bool = False):
    """A staging folder for one run's outputs, moved into ``folder`` when the block ends.

    ``folder`` must be missing or empty unless ``force``; with ``force`` the run's files
    replace their namesakes (other files stay). The staging folder is a hidden sibling of
    ``folder``; on an error or an interrupt it is removed and ``folder`` is left as it was.
    """
    folder = check_output_folder(folder, force)
    folder.parent.mkdir(parents=True, exist_ok=True)
    stage = new_entry(folder.parent, f".{folder.name}.partial-{os.getpid()}-", folder=True)
    try:
        yield stage
        folder.mkdir(exist_ok=True)
        for src in sorted(stage.rglob("*")):
            if src.is_file():
                dest = folder / src.relative_to(stage)
                dest.parent.mkdir(parents=True, exist_ok=True)
                os.replace(src, dest)
    finally:
        shutil.rmtree(stage, ignore_errors=True)


def write_simulation(sim, path, *, metadata: dict | None = None) -> pathlib.Path:
    """Write a `Simulation` as ``path`` (CSV) and a JSON sidecar, both readable by
    `vfjax.load_recording`.

    Columns: ``frame``, ``time_s`` (s, from the first frame), ``area_px`` (what a camera sees:
    the GAW clipped at zero), ``model_area_px`` (the model's signed area, negative while the
    folds overlap) and ``phase``. The sidecar, ``path`` with the suffix ``.json``, holds the
    frame rate (Hz), the area unit and ``metadata``. Returns the CSV path.
    """
    path = pathlib.Path(path)
    t = np.asarray(sim.time)
    area = np.asarray(sim.area)
    phase = np.asarray(sim.phase)
    lines = ["frame,time_s,area_px,model_area_px,phase"]
    for i, (ti, ai, pi) in enumerate(zip(t - t[0], area, phase)):
        lines.append(f"{i},{ti:.9f},{max(ai, 0.0):.6f},{ai:.6f},{PHASE_NAMES[int(pi)]}")
    fps = 1.0 / float(np.median(np.diff(t))) if len(t) > 1 else None
    sidecar = {
        "fps": round(fps, 6) if fps else None,
        "area_unit": "px",
        "source": "vfjax",
        "t_start_s": float(t[0]),
    }
    sidecar.update(metadata or {})
    write_text(path, "\n".join(lines) + "\n")
    write_json(path.with_suffix(".json"), sidecar)
    return path


def write_recording(recording, path, columns: dict | None = None) -> pathlib.Path:
    """Write a `Recording` as ``path`` (CSV: frame, time_s, area_<unit>, and
    area_left_<unit>, area_right_<unit> where it has per-fold areas) and its sidecar.

    Arguments:
        recording: the recording.
        path: the table's path; the sidecar is written beside it (``.json``).
        columns: further columns, name -> one value per frame.
    """
    path = pathlib.Path(path)
    columns = {} if columns is None else dict(columns)
    if recording.folds is not None:
        unit = recording.unit
        sides = {
            f"area_left_{unit}": recording.folds[:, 0],
            f"area_right_{unit}": recording.folds[:, 1],
        }
        columns = {**sides, **columns}
    for name, values in columns.items():
        if len(values) != recording.n_frames:
            raise ValueError(
                f"column {name} has {len(values)} values for {recording.n_frames} frames"
            )
    names = [f"area_{recording.unit}", *columns]
    lines = [",".join(["frame", "time_s", *names])]
    values = np.column_stack([recording.area, *columns.values()])
    for i, (t, row) in enumerate(zip(recording.time, values)):
        lines.append(f"{i},{t:.9f}," + ",".join(f"{a:.6f}" for a in row))
    write_text(path, "\n".join(lines) + "\n")
    sidecar = {"fps": recording.fps, "area_unit": recording.unit, **recording.metadata}
    write_json(path.with_suffix(".json"), sidecar)
    return path
