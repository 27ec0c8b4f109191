"""Bad and unusual input, through the command line and the Python API: each case gets a clear
message naming the problem (CLI: exit code 2, one line on stderr, no traceback), never a
silent success, a crash, or code run from a data file."""

import json
import logging
import os
import pathlib
import re
import select
import signal
import subprocess
import sys
import textwrap
import time
import warnings

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import vfjax
from vfjax.recording import load_contours, load_recording, load_segments
from vfjax.serialise import model_to_dict

FPS = 4000.0


def _gaw(n=201):
    """A periodic, GAW-like area (px): 10 cycles of a half-rectified sine."""
    t = np.arange(n) / FPS
    return np.round(np.clip(np.sin(2 * np.pi * 200.0 * t), 0, None) * 300.0)


def _table(folder, name="rec", rows=None, sidecar=None, header="frame,time_s,area_px"):
    """A GAW table and its sidecar; ``rows`` default to the good 201 frames."""
    if rows is None:
        rows = [f"{i},{i / FPS:.8f},{a:g}" for i, a in enumerate(_gaw())]
    csv = pathlib.Path(folder) / f"{name}.csv"
    csv.write_text("\n".join([header, *rows]) + "\n")
    side = {"fps": FPS, "area_unit": "px"} if sidecar is None else sidecar
    text = side if isinstance(side, str) else json.dumps(side)
    csv.with_suffix(".json").write_text(text)
    return csv


def _good_rows():
    return [f"{i},{i / FPS:.8f},{a:g}" for i, a in enumerate(_gaw())]


# --------------------------------------------------------------------------- the CLI table
def _write_case(tmp, case):
    """Build the files of one CLI case; returns the command's arguments."""
    rows = _good_rows()
    if case == "fps_tiny":
        return ["fit", _table(tmp, sidecar={"fps": 0.001, "area_unit": "px"})]
    if case == "fps_huge":
        return ["fit", _table(tmp, sidecar={"fps": 1e12, "area_unit": "px"})]
    if case == "fps_zero_option":
        return ["fit", _table(tmp), "--fps", "0"]
    if case == "frames_missing":
        return ["fit", _table(tmp, rows=rows[:50] + rows[80:])]
    if case == "time_disagrees":
        rows = [f"{i},{i / 2000.0:.8f},{a:g}" for i, a in enumerate(_gaw())]
        return ["fit", _table(tmp, rows=rows)]
    if case == "repeated_frame":
        return ["fit", _table(tmp, rows=rows[:10] + rows[9:])]
    if case == "invalid_json":
        return ["fit", _table(tmp, sidecar='{"fps": 4000, "area_unit": ')]
    if case == "sidecar_not_object":
        return ["fit", _table(tmp, sidecar="[4000]")]
    if case == "binary_table":
        csv = _table(tmp)
        csv.write_bytes(bytes(range(256)) * 8)
        return ["fit", csv]
    if case == "latin1_table":
        csv = _table(tmp)
        csv.write_bytes("frame,area_px\n0,1\n1,\xe9\n".encode("latin-1"))
        return ["fit", csv]
    if case == "negative_area":
        return ["fit", _table(tmp, rows=rows[:5] + ["5,0.00125,-3"] + rows[6:])]
    if case == "nan_area":
        return ["fit", _table(tmp, rows=rows[:5] + ["5,0.00125,nan"] + rows[6:])]
    if case == "non_numeric":
        return ["fit", _table(tmp, rows=rows[:5] + ["5,0.00125,abc"] + rows[6:])]
    if case == "no_area_column":
        return ["fit", _table(tmp, header="frame,time_s,volume")]
    if case == "ragged_row":
        return ["fit", _table(tmp, rows=rows[:5] + ["5,0.00125"] + rows[6:])]
    if case == "missing_sidecar":
        csv = _table(tmp)
        csv.with_suffix(".json").unlink()
        return ["fit", csv]
    if case == "missing_file":
        return ["fit", pathlib.Path(tmp) / "nothing.csv"]
    if case == "unknown_unit":
        return ["fit", _table(tmp, sidecar={"fps": FPS, "area_unit": "inch2"})]
    if case == "empty_contour":
        path = pathlib.Path(tmp) / "empty_segdata.txt"
        path.write_text("")
        return ["fit", path, "--fps", "8000"]
    if case == "contour_without_fps":
        path = pathlib.Path(tmp) / "c_segdata.txt"
        path.write_text("# c\n1 2\n3 4\n")
        return ["diagnose", path]
    if case == "output_not_empty":
        out = pathlib.Path(tmp) / "out"
        out.mkdir()
        (out / "old_fit.json").write_text("{}")
        return ["fit", _table(tmp), "--out", out]
    if case == "output_file_exists":
        (pathlib.Path(tmp) / "gaw.csv").write_text("x")
        return ["simulate", "N1", "-o", pathlib.Path(tmp) / "gaw.csv"]
    if case == "noise_video":
        path = pathlib.Path(tmp) / "noise.npy"
        rng = np.random.default_rng(0)
        np.save(path, rng.integers(0, 255, (100, 64, 64)).astype(np.uint8))
        return ["extract", path, "--fps", "4000", "-o", pathlib.Path(tmp) / "g.csv"]
    if case == "video_without_fps":
        path = pathlib.Path(tmp) / "v.npy"
        np.save(path, np.zeros((4, 8, 8), np.uint8))
        return ["extract", path, "-o", pathlib.Path(tmp) / "g.csv"]
    if case == "playback_rate_video":
        import imageio.v3 as iio

        path = pathlib.Path(tmp) / "v.avi"
        frames = np.zeros((8, 32, 32, 3), np.uint8)
        iio.imwrite(path, frames, plugin="pyav", codec="ffv1", fps=30)
        return ["extract", path, "-o", pathlib.Path(tmp) / "g.csv"]
    if case == "simulate_bad_frames":
        return ["simulate", "N1", "--frames", "0", "-o", pathlib.Path(tmp) / "s.csv"]
    if case == "simulate_low_fps":
        return ["simulate", "N1", "--fps", "30", "-o", pathlib.Path(tmp) / "s.csv"]
    if case == "zero_cores":
        return ["--cores", "0", "simulate", "N1", "-o", pathlib.Path(tmp) / "s.csv"]
    raise KeyError(case)


CLI_CASES = {  # case: what the one-line message must say
    "fps_tiny": r"rec\.json: fps: a frame rate of 0\.001 Hz .* expected 1000 to 100000 Hz",
    "fps_huge": r"a frame rate of 1e\+12 Hz .* expected 1000 to 100000 Hz",
    "fps_zero_option": r"--fps: a frame rate of 0 Hz",
    "frames_missing": r"rec\.csv: frames missing: frame 49 is followed by frame 80",
    "time_disagrees": r"rec\.csv: time_s disagrees with the sidecar's fps of 4000 Hz",
    "repeated_frame": r"rec\.csv: frame 9 appears more than once",
    "invalid_json": r"rec\.json: invalid JSON",
    "sidecar_not_object": r"rec\.json: a sidecar must be a JSON object",
    "binary_table": r"rec\.csv: a binary file",
    "latin1_table": r"rec\.csv: not a GAW table .* in UTF-8",
    "negative_area": r"rec\.csv: area is negative at frames \[5\]",
    "nan_area": r"rec\.csv: area has NaN or infinite values at frames \[5\]",
    "non_numeric": r"rec\.csv: non-numeric value 'abc' in column area_px, line 7",
    "no_area_column": r"rec\.csv: no area column",
    "ragged_row": r"rec\.csv: line 7 has 2 fields",
    "missing_sidecar": r"no sidecar .*rec\.json",
    "missing_file": r"no recording at .*nothing\.csv",
    "unknown_unit": r"area_unit: 'inch2' is not one of",
    "empty_contour": r"empty_segdata\.txt: no edge lines",
    "contour_without_fps": r"c_segdata\.txt: a contour file carries no frame rate; give --fps",
    "output_not_empty": r"output folder .*out is not empty .* --force",
    "output_file_exists": r"gaw\.csv exists; use --force",
    "noise_video": r"noise\.npy: no glottis found: the dark moving region covers up to \d+%",
    "video_without_fps": r"v\.npy: the frame rate is not in the file; give fps",
    "playback_rate_video": r"v\.avi \(the rate the file states\): a frame rate of 30 Hz .* --fps",
    "simulate_bad_frames": r"n_frames must be an integer >= 1, got 0",
    "simulate_low_fps": r"--fps: a frame rate of 30 Hz",
    "zero_cores": r"--cores / VFJAX_CORES: cores must be >= 1, got 0",
}


def _main(*args, cwd, monkeypatch, capsys):
    """The command line's `main` in this process (a new process costs seconds of imports):
    (exit code, stderr). Its compilation cache is the session's (the one this process uses)
    and the CPU devices stay as they are (JAX's backend runs already)."""
    from vfjax.cli import main

    jax.devices()
    monkeypatch.chdir(cwd)
    monkeypatch.delenv("VFJAX_NO_CACHE", raising=False)
    monkeypatch.delenv("VFJAX_CORES", raising=False)
    monkeypatch.setenv("VFJAX_CACHE_DIR", os.environ["VFJAX_TEST_SESSION_CACHE"])
    capsys.readouterr()
    code = main([str(a) for a in args])
    return code, capsys.readouterr().err


def _one_clear_line(case, code, stderr):
    assert code == 2, (code, stderr[-2000:])
    assert "Traceback" not in stderr, stderr[-2000:]
    lines = [ln for ln in stderr.splitlines() if ln.startswith("vfjax")]
    assert len(lines) == 1 and lines[0].startswith("vfjax: error: "), stderr
    assert re.search(CLI_CASES[case], lines[0]), lines[0]


@pytest.mark.parametrize("case", list(CLI_CASES))
def test_cli_refuses_bad_input_with_one_clear_line(tmp_path, case, monkeypatch, capsys):
    args = _write_case(tmp_path, case)
    _one_clear_line(case, *_main(*args, cwd=tmp_path, monkeypatch=monkeypatch, capsys=capsys))


@pytest.mark.parametrize("case", ["frames_missing", "zero_cores"])
def test_the_command_refuses_bad_input_with_one_clear_line_and_code_2(tmp_path, case, cli):
    """The same through ``python -m vfjax`` in a process of its own: exit code 2."""
    args = _write_case(tmp_path, case)
    run = cli(*args, cwd=tmp_path)
    _one_clear_line(case, run.returncode, run.stderr)


def test_cli_reads_its_own_simulated_output(tmp_path, cli):
    """The simulated table's areas are what a camera sees (clipped at zero), with the model's
    signed area beside them: vfjax's own loader takes it back."""
    run = cli("simulate", "N1", "-o", "sim.csv", cwd=tmp_path)
    assert run.returncode == 0, run.stderr
    rec = load_recording(tmp_path / "sim.csv")
    sim = vfjax.simulate(vfjax.preset("N1"), FPS, 201)
    signed = np.asarray(sim.area)
    assert signed.min() < 0  # N1's folds overlap: the camera sees 0 there
    np.testing.assert_allclose(rec.area, np.clip(signed, 0, None), atol=1e-6)
    table = np.genfromtxt(tmp_path / "sim.csv", delimiter=",", names=True, dtype=None)
    np.testing.assert_allclose(table["model_area_px"], signed, atol=1e-6)


def test_cli_fits_contour_files_and_exits_1_on_a_failed_fit(
    tmp_path, shared_dir, monkeypatch, capsys
):
    """`vfjax fit` takes contour files as `vfjax diagnose` does; a fit that explains nothing
    (areas of 1e12 px) exits 1 with the reason on stderr, and its JSON and report say so."""
    contour = shared_dir / "data" / "real" / "FN003_segdata.txt"
    quick = ("--iterations", "5", "--restarts", "1")
    here = {"cwd": tmp_path, "monkeypatch": monkeypatch, "capsys": capsys}
    code, err = _main("fit", contour, "--fps", "8000", "--out", "c", *quick, **here)
    assert code in (0, 1) and "Traceback" not in err, err
    status = json.loads((tmp_path / "c" / "FN003_fit.json").read_text())["status"]
    assert (status == "successful") == (code == 0)
    # --warmup reaches the fit (its sampling says so); the same compiled programs serve it
    code, err = _main(
        "fit", contour, "--fps", "8000", "--out", "w", "--warmup", "0.05", *quick, **here
    )
    assert code in (0, 1) and "Traceback" not in err, err
    saved = json.loads((tmp_path / "w" / "FN003_fit.json").read_text())
    assert saved["sampling"]["warmup"] == 0.05
    # 120 frames: the contour file's length bucket, so its compiled programs serve again;
    # the glottis stops after its third cycle (frame 60), which is warned of before the fit
    gaw = np.where(np.arange(120) < 60, _gaw(120), 0.0)
    rows = [f"{i},{i / FPS:.8f},{a * 1e10 + 1:g}" for i, a in enumerate(gaw)]
    code, err = _main("fit", _table(tmp_path, rows=rows), *quick, **here)
    assert code == 1, err
    assert "Traceback" not in err
    assert "warning: rec has no glottal cycle in 15.2-29.8 ms" in err, err
    assert "RecordingWarning" not in err  # said once, in the command line's words
    assert "the fit failed: NMSE" in err and "no better than the recording's mean" in err
    saved = json.loads((tmp_path / "vfjax_output" / "rec_fit.json").read_text())
    assert saved["status"] == "worse_than_mean"


def test_cli_keeps_compiled_programs_in_a_persistent_cache(tmp_path, cli):
    """The command line caches compiled programs in a folder (here VFJAX_CACHE_DIR); a folder
    it cannot write leaves the cache off with one warning, and the run goes on."""
    cache = tmp_path / "cache"
    run = cli(
        "simulate", "N1", "-o", "a.csv", cwd=tmp_path, VFJAX_NO_CACHE="", VFJAX_CACHE_DIR=str(cache)
    )
    assert run.returncode == 0, run.stderr
    assert any(p.is_file() and not p.name.startswith(".") for p in cache.rglob("*"))
    blocker = tmp_path / "a_file"
    blocker.write_text("")
    run = cli(
        "simulate",
        "N1",
        "-o",
        "b.csv",
        cwd=tmp_path,
        VFJAX_NO_CACHE="",
        VFJAX_CACHE_DIR=str(blocker / "cache"),
    )
    assert run.returncode == 0, run.stderr
    warnings_seen = [ln for ln in run.stderr.splitlines() if "warning" in ln]
    assert len(warnings_seen) == 1 and "compilation cache off: cannot write" in warnings_seen[0]


def test_cli_interrupt_exits_130_without_a_traceback(tmp_path):
    """Ctrl-C: one line, exit code 130, and no output folder left half-written. Pressed
    once the run is under way (its first subject simulated and written to the folder it is
    making), however long the imports took."""
    code, err, _ = _ctrl_c_when_ready(
        ["-m", "vfjax", "--no-cache", "run", "--out", "out"],
        tmp_path,
        ready=lambda line: line.startswith("N1: f0"),  # inside the simulations or the first fit
        timeout=60,
    )
    assert code == 130, err[-2000:]
    assert "Traceback" not in err
    assert err.strip().splitlines()[-1] == (
        "vfjax: interrupted; the output folder is left as it was"
    )
    assert not (tmp_path / "out").exists()
    assert not list(tmp_path.glob(".out.partial-*"))


def _is_ready(line: str) -> bool:
    return line.strip() == "ready"


def _ctrl_c_when_ready(args, folder, check=None, ready=_is_ready, timeout=30):
    """Run Python with ``args`` (a list: the command line's; a string: a script) in
    ``folder``, press Ctrl-C once its first line of output passes ``ready`` (default: it is
    "ready") and ``check()``, if given, holds, and return its exit code, its stderr and the
    seconds it took to end after the Ctrl-C (at most ``timeout``). Fails, the process
    killed, if no such line comes within 300 s."""
    proc = subprocess.Popen(
        [sys.executable, *(["-c", args] if isinstance(args, str) else args)],
        cwd=folder,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env={**os.environ, "PYTHONUNBUFFERED": "1"},
    )
    waiting, _, _ = select.select([proc.stdout], [], [], 300)
    first = proc.stdout.readline() if waiting else ""
    if not ready(first):
        proc.kill()
        pytest.fail(f"no start: first line {first!r}; {proc.communicate()[1][-2000:]}")
    assert check is None or check()
    start = time.monotonic()
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=timeout)
    return proc.returncode, err, time.monotonic() - start


def test_a_swallowed_interrupt_still_ends_the_run_and_its_staged_output(tmp_path):
    """A Ctrl-C whose KeyboardInterrupt a library catches (or that lands in a finaliser) is
    not lost: the command line's handler ends the process after its grace period, with the
    same line and code, and removes the run's staging folder."""
    script = textwrap.dedent(
        """
        import signal, time
        from vfjax.cli import _InterruptHandler
        from vfjax.io import staged_output

        signal.signal(signal.SIGINT, _InterruptHandler(["out"]))
        with staged_output("out") as stage:
            (stage / "half.txt").write_text("written")
            ready = False
            while True:
                try:  # "ready" inside the try: the interrupt cannot land before it
                    if not ready:
                        print("ready", flush=True)
                        ready = True
                    time.sleep(0.05)
                except KeyboardInterrupt:
                    pass  # swallowed
        """
    )
    code, err, waited = _ctrl_c_when_ready(
        script, tmp_path, lambda: list(tmp_path.glob(".out.partial-*"))
    )
    assert code == 130, err
    assert err.strip().splitlines()[-1] == "vfjax: interrupted; the output folder is left as it was"
    assert 2.0 < waited < 20.0, waited  # the grace period (3 s), not a hang
    assert not (tmp_path / "out").exists()
    assert not list(tmp_path.glob(".out.partial-*"))


def test_an_interrupt_a_library_turns_into_an_error_is_still_an_interrupt(tmp_path):
    """A Ctrl-C whose KeyboardInterrupt a library catches and replaces by an error of its own
    (matplotlib raises "Invalid bounding box" when it lands in a drawing) ends the run as an
    interrupt: code 130 and the one line, not code 2 and the library's message."""
    script = textwrap.dedent(
        """
        import time
        import vfjax.cli as cli

        def drawing(args):
            try:
                print("ready", flush=True)
                while True:
                    time.sleep(0.05)
            except KeyboardInterrupt:
                raise ValueError("Invalid bounding box")

        cli.cmd_simulate = drawing
        raise SystemExit(cli.main(["--no-cache", "simulate", "N1", "-o", "gaw.csv"]))
        """
    )
    code, err, _ = _ctrl_c_when_ready(script, tmp_path)
    assert code == 130, err
    assert "Invalid bounding box" not in err and "Traceback" not in err
    assert err.strip().splitlines()[-1] == "vfjax: interrupted; the output folder is left as it was"


def test_an_interrupt_inside_a_finaliser_ends_the_run_without_a_traceback(tmp_path):
    """A Ctrl-C that lands in a garbage-collection callback or a finaliser (JAX runs one
    on every collection) cannot unwind the stack: the command line's unraisable hook ends
    the process at once, with the one line, code 130 and no traceback."""
    script = textwrap.dedent(
        """
        import gc, sys, time
        from vfjax.cli import _unraisable_hook
        from vfjax.io import staged_output

        sys.unraisablehook = _unraisable_hook(["out"], sys.unraisablehook)

        def callback(phase, info):
            raise KeyboardInterrupt

        with staged_output("out") as stage:
            (stage / "half.txt").write_text("written")
            gc.callbacks.append(callback)
            gc.collect()
            time.sleep(30)
        """
    )
    start = time.monotonic()
    run = subprocess.run(
        [sys.executable, "-c", script], cwd=tmp_path, capture_output=True, text=True
    )
    assert run.returncode == 130, run.stderr
    assert "Traceback" not in run.stderr
    assert run.stderr.strip() == "vfjax: interrupted; the output folder is left as it was"
    assert time.monotonic() - start < 20.0
    assert not (tmp_path / "out").exists()
    assert not list(tmp_path.glob(".out.partial-*"))


def test_an_interrupt_while_vfjax_is_imported_ends_without_a_traceback(tmp_path):
    """The installed ``vfjax`` command (`_vfjax_cli.main`) imports the package after its
    own guard: a Ctrl-C while JAX is still being imported (held there by an import hook that
    says "ready" and waits) ends with the command line's one line and code 130, no
    traceback and no output."""
    from importlib.metadata import entry_points

    (command,) = [e for e in entry_points(group="console_scripts") if e.name == "vfjax"]
    assert command.value == "_vfjax_cli:main"
    script = textwrap.dedent(
        """
        import signal, sys, time

        signal.signal(signal.SIGINT, signal.default_int_handler)  # as a terminal gives it

        class SlowJax:  # a meta-path finder that holds the import of jax
            def find_spec(self, name, path=None, target=None):
                if name == "jax":
                    print("ready", flush=True)
                    time.sleep(120)
                return None

        sys.meta_path.insert(0, SlowJax())
        sys.argv = ["vfjax", "--no-cache", "simulate", "N1", "-o", "gaw.csv"]
        from _vfjax_cli import main

        raise SystemExit(main())
        """
    )
    code, err, waited = _ctrl_c_when_ready(script, tmp_path)
    assert code == 130, err
    assert "Traceback" not in err
    assert err.strip() == "vfjax: interrupted; the output folder is left as it was"
    assert waited < 20.0
    assert not (tmp_path / "gaw.csv").exists()


# ------------------------------------------------------------------------------ security
def _saved_fit(tmp_path):
    """A saved fit result, made without fitting (the file format is what is under test)."""
    model = vfjax.preset("N3")
    result = vfjax.FitResult(
        params={"K": float(model.params()["K"])},
        units={"K": "dyne/cm"},
        time_shift=0.0,
        nmse=0.01,
        pso_trace=[0.02],
        lm_trace=[0.01],
        timings={"total_s": 1.0},
        trace_times=[0.0, 1.0],
        n_simulations=10,
        optimistix_result="successful",
        sampling=vfjax.Sampling(FPS, 201, warmup=0.02, max_time_shift=0.01),
        bounds={"K": [1e5, 1e6]},
        swarm=vfjax.Swarm(),
        model=model,
        recording_name="r",
    )
    path = tmp_path / "fit.json"
    result.to_json(path)
    return path, json.loads(path.read_text())


def test_a_fit_file_cannot_run_code(tmp_path):
    path, d = _saved_fit(tmp_path)
    marker = tmp_path / "pwned"
    evil = json.loads(json.dumps(d))
    evil["model"]["terms"][0] = {
        "class": "subprocess:run",
        "fields": {"args": ["touch", str(marker)]},
    }
    path.write_text(json.dumps(evil))
    with pytest.raises(ValueError, match=r"fit\.json: not a vfjax fit result"):
        vfjax.FitResult.from_json(path)  # schema first: a string field is refused unread
    evil["model"]["terms"][0] = {"class": "subprocess:run", "fields": {"args": 1.0}}
    path.write_text(json.dumps(evil))
    with pytest.raises(ValueError, match=r"fit\.json: refusing term class 'subprocess:run'"):
        vfjax.FitResult.from_json(path)
    evil["model"]["terms"][0] = {"class": "os:system", "fields": {}}
    path.write_text(json.dumps(evil))
    with pytest.raises(ValueError, match="refusing term class 'os:system'"):
        vfjax.FitResult.from_json(path)
    assert not marker.exists()


def test_a_fit_file_is_validated_before_anything_is_built(tmp_path):
    path, d = _saved_fit(tmp_path)
    for change, message in [
        (lambda e: e["model"]["terms"][0]["fields"].update(K="1e5"), "not a vfjax fit result"),
        (lambda e: e["model"]["terms"][0]["fields"].update(spring=1.0), "has no field"),
        (lambda e: e["model"]["terms"][0]["fields"].update(K=-1.0), "K \\(stiffness\\)"),
        (lambda e: e.update(nmse="low"), "nmse"),
        (lambda e: e.pop("params"), "params"),
        (lambda e: e["model"]["subject"].update(mass=[1, 2]), "not a vfjax fit result"),
    ]:
        bad = json.loads(json.dumps(d))
        change(bad)
        path.write_text(json.dumps(bad))
        with pytest.raises(ValueError, match=message):
            vfjax.FitResult.from_json(path)
    path.write_text("{not json")
    with pytest.raises(ValueError, match=r"fit\.json: invalid JSON"):
        vfjax.FitResult.from_json(path)


def test_a_users_own_term_loads_when_passed_on_purpose(tmp_path):
    class Drag(vfjax.AbstractForce):
        b: jax.Array = eqx.field(default=0.0, converter=vfjax.as_parameter)
        parameters = {"b": ("b", "g/cm")}

        def force(self, ctx):
            return -self.b * jnp.abs(ctx.v) * ctx.v

    path, d = _saved_fit(tmp_path)
    model = vfjax.preset("N3").with_term(Drag(b=0.05))
    d["model"] = model_to_dict(model)
    path.write_text(json.dumps(d))
    with pytest.raises(ValueError, match="refusing term class .*Drag"):
        vfjax.FitResult.from_json(path)
    back = vfjax.FitResult.from_json(path, terms=[Drag])
    assert float(back.model.params()["b"]) == 0.05
    assert back.status == "successful"


# -------------------------------------------------------------------------- models and simulate
@pytest.mark.parametrize(
    "change, message",
    [
        (dict(K=-1.0), r"K \(stiffness\) must be > 0, got -1\.0 dyne/cm"),
        (dict(M=0.0), r"M \(mass\) must be > 0, got 0\.0 g"),
        (dict(S=float("nan")), r"S \(scaling factor\) must be finite, got nan px/mm²"),
        (dict(t_c=-1e-3), r"t_c \(closure duration\) must be >= 0"),
        (dict(A_g0=-0.05), r"A_g0 \(rest_area\) must be > 0"),
        (dict(P_s=0.0), r"P_s \(subglottal_pressure\) must be > 0"),
    ],
)
def test_model_set_checks_values_as_the_presets_do(change, message):
    with pytest.raises(ValueError, match=message):
        vfjax.preset("N1").set(**change)


def test_invalid_models_made_otherwise_are_reported_by_simulate():
    m = vfjax.preset("N1")
    negated = jax.tree.map(lambda x: -x, m)  # no check runs here
    with pytest.raises(ValueError, match="must be > 0"):
        negated.check()
    with pytest.raises(ValueError, match="must be > 0"):  # names the parameter, outside jit
        vfjax.simulate(negated, FPS, 51)
    for bad in (negated, eqx.tree_at(lambda m: m.subject.mass, m, jnp.nan)):
        sim = vfjax.simulate(bad, FPS, 51, throw=False)
        assert bool(sim.result == vfjax.RESULTS.invalid_parameters)
        assert not bool(sim.complete) and np.all(np.isnan(np.asarray(sim.area)))
    # inside jit and vmap: a result code, one member at a time
    ks = jnp.array([1.0, -1.0]) * m.params()["K"]
    sims = jax.jit(jax.vmap(lambda k: vfjax.simulate(m.set(K=k), FPS, 51, throw=False)))(ks)
    assert np.asarray(sims.result == vfjax.RESULTS.successful).tolist() == [True, False]
    assert np.asarray(sims.result == vfjax.RESULTS.invalid_parameters).tolist() == [False, True]
    with pytest.raises(Exception, match="outside its admissible range"):
        jax.jit(lambda k: vfjax.simulate(m.set(K=k), FPS, 51).area)(-1.0).block_until_ready()


def test_time_shift_outside_its_range():
    m = vfjax.preset("N1")
    message = r"time_shift must be a number in \[-t_start, max_time_shift\] = \[0, 0\] s"
    with pytest.raises(ValueError, match=message):
        vfjax.simulate(m, FPS, 201, time_shift=0.01)
    with pytest.raises(ValueError, match=r"= \[-0.02, 0.01\] s, got -0.021"):
        vfjax.simulate(m, FPS, 201, t_start=0.02, time_shift=-0.021, max_time_shift=0.01)
    # a shift back into the warm-up is within the integration
    early = vfjax.simulate(m, FPS, 201, t_start=0.02, time_shift=-0.005, max_time_shift=0.01)
    direct = vfjax.simulate(m, FPS, 201, t_start=0.02, max_time_shift=0.01).dense
    np.testing.assert_allclose(early.displacement, direct.displacement(early.time), atol=1e-12)
    traced = jax.jit(
        lambda s: vfjax.simulate(m, FPS, 201, time_shift=s, max_time_shift=0.005, throw=False)
    )(0.01)
    assert bool(traced.result == vfjax.RESULTS.time_shift_out_of_range)
    assert not bool(traced.complete)


def test_simulate_refuses_runs_that_would_not_fit_in_memory():
    m = vfjax.preset("N1")
    with pytest.raises(ValueError, match="more than the 2097152 iterations"):
        vfjax.simulate(m, 0.001, 201)
    with pytest.raises(ValueError, match="more than the"):
        vfjax.simulate(m, FPS, 201, t_start=1e5)
    with pytest.raises(ValueError, match="more than the"):
        vfjax.simulate(m, FPS, 201, max_events=10**9)


def test_frame_counts_are_integers_and_time_shifts_are_data():
    m = vfjax.preset("N3")
    a = vfjax.simulate(m, FPS, np.int64(101)).area
    assert a.shape == (101,)
    for bad in (101.0, np.float64(101), True, "101"):
        with pytest.raises(TypeError, match="n_frames must be an integer"):
            vfjax.simulate(m, FPS, bad)
    vfjax.simulate(m, FPS, 51, time_shift=0.001, max_time_shift=0.01)
    compiled = []

    class Count(logging.Handler):
        def emit(self, record):
            if record.getMessage().startswith("Compiling "):
                compiled.append(record.getMessage()[:80])

    handler = Count()
    logging.getLogger("jax").addHandler(handler)
    try:
        with jax.log_compiles():
            for shift in (0.002, 0.003, np.float64(0.004)):
                vfjax.simulate(m, FPS, 51, time_shift=shift, max_time_shift=0.01)
            vfjax.simulate(m.set(K=7e5), FPS, 51, time_shift=0.002, max_time_shift=0.01)
            # another frame count and frame rate within the same buckets (frames padded to
            # 128, the loop's 480-512 iterations to 512) are data too: not even the cut to
            # the frame count compiles (it is made on the host)
            b = vfjax.simulate(m, FPS, 60, max_time_shift=0.01)
            c = vfjax.simulate(m, 5000.0, 51, max_time_shift=0.01)
    finally:
        logging.getLogger("jax").removeHandler(handler)
    assert compiled == []
    assert b.area.shape == (60,) and c.area.shape == (51,) and b.complete and c.complete
    # the frames within the bucket are those of the simulation alone: 60 frames begin with
    # the 51, and each frame is the motion at its own time (the dense output's)
    np.testing.assert_array_equal(b.area[:51], vfjax.simulate(m, FPS, 51, max_time_shift=0.01).area)
    np.testing.assert_allclose(c.time, np.arange(51) / 5000.0, rtol=0, atol=1e-15)
    np.testing.assert_allclose(c.displacement, c.dense.displacement(c.time), rtol=1e-13)


def test_integer_parameter_leaves_are_refused():
    class Sloppy(vfjax.AbstractForce):
        b: jax.Array = eqx.field(default=0.0, converter=jnp.asarray)
        parameters = {"b": ("b", "g/cm")}

        def force(self, ctx):
            return -self.b * ctx.v

    with pytest.raises(TypeError, match="as_parameter"):
        Sloppy(b=1)

    class Careful(Sloppy):
        b: jax.Array = eqx.field(default=0.0, converter=vfjax.as_parameter)

    term = Careful(b=1)
    grad = eqx.filter_grad(lambda t: t.b * 3.0)(term)
    assert float(grad.b) == 3.0


# -------------------------------------------------------------------------------- fits
@pytest.mark.xdist_group("n3_s_k")  # one worker compiles their swarm
def test_a_fit_that_explains_nothing_is_reported_failed(tmp_path):
    rec = vfjax.Recording(area=_gaw() * 1e10 + 1.0, fps=FPS, name="huge")
    result = vfjax.fit(
        vfjax.preset("N3"),
        rec,
        params=("S", "K"),
        swarm=vfjax.Swarm(iterations=5),
        polish=vfjax.Polish(max_steps=5),
    )
    assert result.status == "worse_than_mean" and result.failed
    of_mean = np.sum((rec.area - rec.area.mean()) ** 2) / np.sum(rec.area**2)
    assert result.nmse_of_mean == pytest.approx(of_mean)
    assert "no better than the recording's mean" in result.status_message()
    result.to_json(tmp_path / "f.json")
    assert json.loads((tmp_path / "f.json").read_text())["status"] == "worse_than_mean"
    assert vfjax.FitResult.from_json(tmp_path / "f.json").failed


@pytest.mark.xdist_group("n3_s_k")  # one worker compiles their swarm
def test_a_fit_that_ends_at_its_box_edge_is_reported_failed():
    """A box that excludes the true K (1.05 to 1.3 times it): the fit ends on the box's edge."""
    truth = vfjax.preset("N3")
    sim = vfjax.simulate(truth, FPS, 201, t_start=0.03)
    rec = vfjax.Recording(area=np.clip(np.asarray(sim.area), 0, None), fps=FPS, name="edge")
    k = float(truth.params()["K"])
    result = vfjax.fit(
        truth.set(K=1.15 * k),
        rec,
        params=("S", "K"),
        bounds={"K": (1.05 * k, 1.3 * k)},
        swarm=vfjax.Swarm(iterations=5),
        polish=None,
    )
    assert result.status == "at_bound" and result.failed
    assert result.params["K"] / k == pytest.approx(1.05, rel=1e-3)
    assert "K = " in result.status_message() and "edge of its search box" in result.status_message()


# ----------------------------------------------------------------------------- loaders
def test_rows_out_of_order_are_sorted_with_a_warning(tmp_path):
    rows = _good_rows()
    csv = _table(tmp_path, rows=rows[100:] + rows[:100])
    with pytest.warns(UserWarning, match="rows out of frame order; sorted"):
        rec = load_recording(csv)
    np.testing.assert_array_equal(rec.area, _gaw())


def test_a_recording_with_gaps_can_be_cut_into_segments(tmp_path):
    rows = _good_rows()
    csv = _table(tmp_path, rows=rows[:50] + rows[80:])
    parts = load_segments(csv)
    assert [p.n_frames for p in parts] == [50, 121]
    assert [p.metadata["first_frame"] for p in parts] == [0, 80]
    np.testing.assert_array_equal(parts[1].area, _gaw()[80:])


def test_video_at_a_playback_rate_is_refused_unless_the_camera_rate_is_given(shared_dir):
    from vfjax.segmentation import frames_to_recording, video_to_recording

    clip = shared_dir / "data" / "hsv_real" / "openhsv_oscillating_vocal_folds.mp4"
    with pytest.raises(ValueError, match="30 Hz .* give it with --fps"):
        video_to_recording(clip)
    rec = video_to_recording(clip, fps=4000.0)
    assert rec.fps == 4000.0 and rec.area.max() > 0
    # `vfjax fit` and `vfjax diagnose` read a video as a cohort does: segmented, split into
    # the folds' areas (which add up to the glottis'), the masks dropped; at the file's 30 fps
    # it is refused with the same words
    from argparse import Namespace

    from vfjax.cli import _load_input

    read = _load_input(Namespace(recording=str(clip), fps=4000.0))
    np.testing.assert_array_equal(read.area, rec.area)
    assert read.masks is None and read.folds.shape == (rec.n_frames, 2)
    np.testing.assert_allclose(read.folds.sum(axis=1), read.area, rtol=1e-9)
    with pytest.raises(ValueError, match="30 Hz .* give it with --fps"):
        _load_input(Namespace(recording=str(clip), fps=None))
    flat = np.random.default_rng(1).normal(100, 1, (64, 32, 32))
    flat[:, 10:20, 10:20] += np.random.default_rng(2).normal(0, 30, (64, 10, 10))
    with pytest.raises(ValueError, match="no glottis found|no vibrating glottis found"):
        frames_to_recording(np.clip(flat, 0, 255), 4000.0)


# hypothesis: random tables and sidecars never crash the loader and never pass garbage
_CELLS = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True).map(repr),
    st.integers(-(10**6), 10**6).map(str),
    st.text(st.characters(blacklist_characters=',"\r\n', blacklist_categories=["Cs"]), max_size=6),
    st.just(""),
)


@settings(
    max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(
    header=st.lists(
        st.sampled_from(["frame", "time_s", "area_px", "area", "area_mm2", "x"]),
        min_size=1,
        max_size=4,
    ),
    cells=st.lists(st.lists(_CELLS, min_size=0, max_size=5), max_size=8),
    sidecar=st.one_of(
        st.dictionaries(
            st.sampled_from(["fps", "area_unit", "sex", "x"]),
            st.one_of(st.floats(), st.integers(), st.text(max_size=5), st.none()),
        ),
        st.text(max_size=20),
    ),
)
def test_random_tables_and_sidecars_never_crash(tmp_path, header, cells, sidecar):
    csv = tmp_path / "r.csv"
    csv.write_text("\n".join([",".join(header)] + [",".join(r) for r in cells]))
    csv.with_suffix(".json").write_text(
        sidecar if isinstance(sidecar, str) else json.dumps(sidecar)
    )
    try:
        rec = load_recording(csv)
    except ValueError:
        return
    # a success is a sound recording of what the table says
    assert rec.n_frames >= 2 and np.all(np.isfinite(rec.area)) and np.all(rec.area >= 0)
    assert 1000.0 <= rec.fps <= 100_000.0
    assert rec.n_frames == len([r for r in cells if any(c.strip() for c in r)])


_CORRUPTIONS = {  # corruption: whether the loader must refuse it
    "none": False,
    "shuffle": False,
    "drop_middle_row": True,
    "duplicate_row": True,
    "bad_cell": True,
    "negative": True,
    "time_at_half_rate": True,
    "fps_out_of_range": True,
    "truncate_json": True,
}


@settings(
    max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(
    n=st.integers(3, 40),
    seed=st.integers(0, 2**16),
    corruption=st.sampled_from(sorted(_CORRUPTIONS)),
)
def test_corrupted_tables_are_refused_and_sound_ones_read_exactly(tmp_path, n, seed, corruption):
    rng = np.random.default_rng(seed)
    area = np.round(rng.uniform(0, 500, n), 3)
    fps = float(rng.choice([2000.0, 4000.0, 8000.0, 20000.0]))
    rows = [f"{i},{i / fps:.9f},{a}" for i, a in enumerate(area)]
    side = json.dumps({"fps": fps, "area_unit": "px"})
    if corruption == "shuffle":
        rows = [rows[i] for i in rng.permutation(n)]
    elif corruption == "drop_middle_row":
        del rows[int(rng.integers(1, n - 1))]
    elif corruption == "duplicate_row":
        i = int(rng.integers(0, n))
        rows.insert(i, rows[i])
    elif corruption == "bad_cell":
        rows[int(rng.integers(0, n))] += "x"
    elif corruption == "negative":
        i = int(rng.integers(0, n))
        rows[i] = f"{i},{i / fps:.9f},-1"
    elif corruption == "time_at_half_rate":
        rows = [f"{i},{2 * i / fps:.9f},{a}" for i, a in enumerate(area)]
    elif corruption == "fps_out_of_range":
        side = json.dumps({"fps": float(rng.choice([0.5, 30.0, 5e5])), "area_unit": "px"})
    elif corruption == "truncate_json":
        side = side[: int(rng.integers(0, len(side) - 1))]
    csv = tmp_path / "t.csv"
    csv.write_text("frame,time_s,area_px\n" + "\n".join(rows) + "\n")
    csv.with_suffix(".json").write_text(side)
    if _CORRUPTIONS[corruption]:
        with pytest.raises(ValueError, match="t.csv|t.json"):
            load_recording(csv)
        return
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        rec = load_recording(csv)
    in_order = rows == sorted(rows, key=lambda r: int(r.split(",")[0]))
    assert any("out of frame order" in str(w.message) for w in caught) == (not in_order)
    np.testing.assert_array_equal(rec.area, area)
    assert rec.fps == fps


def test_contour_files_with_bad_content(tmp_path):
    path = tmp_path / "x_segdata.txt"
    for text, message in [
        ("", "no edge lines"),
        ("# only a comment\n", "no edge lines"),
        ("1 2 3\n", "expected two"),
        ("1 2\n3\n", "different lengths"),
        ("1 a\n1 2\n", "non-numeric"),
        ("1 -2\n1 2\n", "column indices >= 0"),
    ]:
        path.write_text(text)
        with pytest.raises(ValueError, match=message):
            load_contours(path, 8000.0)
    path.write_bytes(b"\x00\x01\x02")
    with pytest.raises(ValueError, match="binary"):
        load_contours(path, 8000.0)
    path.write_text("1 2\n3 4\n")
    with pytest.raises(ValueError, match="frame rate of 30 Hz"):
        load_contours(path, 30.0)


def test_oversized_files_are_refused_before_they_are_read(tmp_path):
    from vfjax.recording import MAX_TEXT_BYTES
    from vfjax.video import MAX_VIDEO_PIXELS, read_video

    csv = _table(tmp_path)
    with csv.open("r+b") as f:  # a sparse file: nothing is written
        f.truncate(MAX_TEXT_BYTES + 1)
    with pytest.raises(ValueError, match=r"rec\.csv: \d+ bytes, more than a GAW table"):
        load_recording(csv)
    path = tmp_path / "long.npy"
    shape = (MAX_VIDEO_PIXELS // (256 * 256) + 1, 256, 256)
    np.lib.format.open_memmap(path, mode="w+", dtype=np.uint8, shape=shape).flush()
    with pytest.raises(ValueError, match=r"long\.npy: 4097 frames of 256 x 256 pixels, more than"):
        read_video(path)


def test_a_model_without_a_sub_critical_displacement_is_refused():
    """F_sa above the aerodynamic force at any area: x_c does not exist."""
    with pytest.raises(ValueError, match="no sub-critical displacement x_c"):
        vfjax.preset("N1").with_term(vfjax.BernoulliForce(separation_force=1e6))
    traced = jax.jit(
        lambda f: vfjax.simulate(
            vfjax.preset("N1").with_term(vfjax.BernoulliForce(separation_force=f)),
            FPS,
            51,
            throw=False,
        )
    )(1e6)
    assert bool(traced.result == vfjax.RESULTS.invalid_parameters)


def test_html_report_shows_markup_from_names_and_never_runs_it(tmp_path, report_html):
    """A report's text carries names from files (a recording's, a cohort folder's); in the
    HTML page any markup or link scheme they hold is shown as text, never interpreted."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from vfjax._html import write_markdown_report

    fig, ax = plt.subplots(figsize=(2, 1))
    ax.plot([0, 1], [0, 1])
    fig.savefig(tmp_path / "figure.png")
    plt.close(fig)
    name = '<script>alert(1)</script><img src=x onerror="alert(2)">'
    text = "\n".join(
        [
            f"# report of {name}",
            "",
            "| recording | link |",
            "|---|---|",
            f"| {name} | [report](javascript:alert(3)) |",
            "| other | [its report](recordings/other/report.md) |",
            "",
            "![figure](figure.png)",
            "",
        ]
    )
    page = report_html(write_markdown_report(tmp_path / "report.md", text))
    assert "&lt;script&gt;alert(1)&lt;/script&gt;" in page
    assert "<script" not in page and page.count("<img") == 1  # the figure alone
    assert 'href="recordings/other/report.html"' in page and "javascript:" not in page


def test_outputs_have_the_permissions_of_any_file_the_user_writes(tmp_path):
    """Files written atomically, a run's staged folder and a cohort recording's folder are
    created as any other file is (0o666 and 0o777 less the umask), not private to their
    owner as temporary files are: a lab's colleagues, or a cluster's workers, read them."""
    from vfjax._cohort._store import CohortFolder
    from vfjax.io import staged_output, write_text

    old = os.umask(0o022)
    try:
        path = write_text(tmp_path / "report.md", "# report\n")
        with staged_output(tmp_path / "out") as stage:
            write_text(stage / "fit.json", "{}")
            write_text(stage / "figures" / "fit.png", "")
        folder = CohortFolder(tmp_path / "cohort").commit("rec", "key", {"status": "done"})
    finally:
        os.umask(old)
    out = tmp_path / "out"
    for file in (path, out / "fit.json", out / "figures" / "fit.png", folder / "result.json"):
        assert file.stat().st_mode & 0o777 == 0o644, file
    for entry in (out, out / "figures", folder):
        assert entry.stat().st_mode & 0o777 == 0o755, entry
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cohort", "out", "report.md"]


def test_the_null_recordings_searched_alike_are_a_command_line_option():
    """``--search-nulls`` of `vfjax diagnose` and `vfjax cohort`: a count, or ``all`` (every
    null recording, `vfjax.Calibration(search_nulls=None)`); the default is the
    calibration's; a negative count or a word is refused with argparse's exit code 2. And
    ``--no-interval-search``."""
    from vfjax.cli import _calibration, build_parser

    parse = build_parser().parse_args
    default = vfjax.Calibration().search_nulls
    assert _calibration(parse(["diagnose", "r.csv"])).search_nulls == default
    assert _calibration(parse(["diagnose", "r.csv", "--search-nulls", "all"])).search_nulls is None
    assert _calibration(parse(["cohort", "d", "--search-nulls", "40"])).search_nulls == 40
    for bad in ("-1", "many"):
        with pytest.raises(SystemExit) as refused:
            parse(["diagnose", "r.csv", "--search-nulls", bad])
        assert refused.value.code == 2
    # the intervals' replicates: searched by default, by the statistic's steps on request
    assert _calibration(parse(["diagnose", "r.csv"])).interval_search is True
    steps = parse(["cohort", "d", "--no-interval-search"])
    assert _calibration(steps).interval_search is False
