"""Where the default test suite's time goes: every XLA compilation in its test processes,
by program and by test, against the tests' own time.

Run: python benchmarks/suite_compiles.py [pytest arguments, e.g. tests/test_fit.py]

Runs the README's test command (`python -m pytest`, with its workers and the session's
shared compilation cache) with this file as a pytest plugin. Each test process logs every
program that JAX compiles or loads from the compilation cache (`jax_log_compiles`: the
program's name and the seconds it took; a load takes a fraction of a second) against the
test that was running, and each test's setup, call and teardown time. Then prints the
compilations and their seconds by program, the tests that compile longest, and the compile
time against the tests' total (worker-seconds). Command lines and notebook kernels that
tests start run in processes of their own and are not counted.
"""

import collections
import logging
import os
import pathlib
import re
import subprocess
import sys
import tempfile
import time

#: Where the test processes write their logs (set by the script for the run it starts).
_FOLDER = "VFJAX_COMPILE_LOG"
_FINISHED = re.compile(r"Finished XLA compilation of (.+?) in ([0-9.eE+-]+) sec")


# ----------------------------------------------------------------- the plugin (test processes)
class _Log:
    """One test process's log: ``compile <TAB> test <TAB> program <TAB> seconds`` and
    ``test <TAB> test <TAB> phase <TAB> seconds`` lines."""

    def __init__(self, path: pathlib.Path):
        self.file = open(path, "a", encoding="utf-8")  # closed at the session's end
        self.test = "(outside a test)"

    def write(self, kind: str, name: str, seconds: float) -> None:
        self.file.write(f"{kind}\t{self.test}\t{name}\t{seconds:.6f}\n")
        self.file.flush()


class _Compiles(logging.Handler):
    def __init__(self, log: _Log):
        super().__init__()
        self.log = log

    def emit(self, record: logging.LogRecord) -> None:
        found = _FINISHED.search(record.getMessage())
        if found:
            self.log.write("compile", found.group(1), float(found.group(2)))


_log: _Log | None = None


def pytest_configure(config):
    global _log
    folder = os.environ.get(_FOLDER)
    distributing = bool(config.getoption("numprocesses", None) or 0)
    if not folder or (distributing and not hasattr(config, "workerinput")):
        return  # (xdist's controller runs no test: its workers log theirs)
    import jax

    worker = os.environ.get("PYTEST_XDIST_WORKER", "main")
    _log = _Log(pathlib.Path(folder) / f"{worker}.tsv")
    jax.config.update("jax_log_compiles", True)
    logger = logging.getLogger("jax")
    logger.addHandler(_Compiles(_log))
    logger.setLevel(logging.WARNING)  # JAX logs its compilations as warnings


def pytest_runtest_logstart(nodeid, location):
    if _log is not None:
        _log.test = nodeid


def pytest_runtest_logreport(report):
    if _log is not None and report.when in ("setup", "call", "teardown"):
        _log.write("test", report.when, float(report.duration))  # the test logstart named


def pytest_unconfigure(config):
    if _log is not None:
        _log.file.close()


# ---------------------------------------------------------------------- the script (summary)
def _program(name: str) -> str:
    """``jit(_polish_batch)`` -> ``_polish_batch``."""
    return name[4:-1] if name.startswith("jit(") and name.endswith(")") else name


def summarise(folder: pathlib.Path, top: int = 25) -> None:
    """Print the tables of the logs in ``folder``."""
    by_program = collections.defaultdict(lambda: [0, 0.0])
    by_test = collections.defaultdict(lambda: [0, 0.0, 0.0])  # compilations, seconds, test time
    small = [0, 0.0]  # compilations of under 0.5 s: array operations, tiny programs
    for path in sorted(folder.glob("*.tsv")):
        for line in path.read_text(encoding="utf-8").splitlines():
            kind, test, name, seconds = line.split("\t")
            seconds = float(seconds)
            if kind == "compile":
                program = by_program[_program(name)]
                program[0] += 1
                program[1] += seconds
                by_test[test][0] += 1
                by_test[test][1] += seconds
                if seconds < 0.5:
                    small[0] += 1
                    small[1] += seconds
            else:
                by_test[test][2] += seconds
    compiled = sum(s for _, s in by_program.values())
    count = sum(n for n, _ in by_program.values())
    tested = sum(t for *_, t in by_test.values())
    print(
        f"{count} compilations, {compiled:.0f} s of XLA compilation in {tested:.0f} s of tests "
        f"(worker-seconds): {compiled / max(tested, 1e-9):.0%}"
    )
    print(f"of which {small[0]} compilations of under 0.5 s each, {small[1]:.0f} s together")
    print("\nby program (compile seconds, compilations), those of 1 s or more:")
    for name, (n, s) in sorted(by_program.items(), key=lambda kv: -kv[1][1]):
        if s >= 1.0:
            print(f"  {s:7.1f} s {n:4d}  {name}")
    print(f"\nthe {top} tests that compile longest (compile seconds, compilations, test seconds):")
    ranked = sorted(by_test.items(), key=lambda kv: -kv[1][1])[:top]
    for test, (n, s, t) in ranked:
        print(f"  {s:7.1f} s {n:4d} {t:7.1f} s  {test}")


def main(argv: list[str]) -> int:
    here = pathlib.Path(__file__).resolve().parent
    with tempfile.TemporaryDirectory(prefix="vfjax-compiles-") as folder:
        env = dict(os.environ)
        env[_FOLDER] = folder
        env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(here), env.get("PYTHONPATH")]))
        command = [sys.executable, "-m", "pytest", "-p", "suite_compiles", "-q", *argv]
        print("$", " ".join(command[1:]), flush=True)
        t0 = time.perf_counter()
        run = subprocess.run(command, cwd=here.parent, env=env)
        print(f"\nthe suite: exit code {run.returncode}, {time.perf_counter() - t0:.0f} s wall\n")
        summarise(pathlib.Path(folder))
    return run.returncode


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
