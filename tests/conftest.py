"""Shared fixtures. The shared data folder sits beside the checkout (../shared)."""

import os
import pathlib
import shutil
import tempfile

import pytest

import vfjax  # noqa: F401  (enables float64 before any test builds arrays)
from vfjax.cli import CACHE_MAX_BYTES, CACHE_MIN_COMPILE_S, use_compilation_cache

ROOT = pathlib.Path(__file__).resolve().parents[1]

SHARED = ROOT.parent / "shared"


#: The session's compilation cache, made empty by the main process and passed on to the
#: test workers, the command lines and the notebook kernels they start (through JAX's own
#: environment variables): a program is compiled once per test session, not once per process.
_CACHE_VARIABLE = "VFJAX_TEST_SESSION_CACHE"


def pytest_configure(config):
    if not os.environ.get(_CACHE_VARIABLE):  # the main process (xdist's workers inherit it)
        folder = tempfile.mkdtemp(prefix="vfjax-test-cache-")
        config._vfjax_cache = folder
        os.environ[_CACHE_VARIABLE] = folder
        os.environ["JAX_COMPILATION_CACHE_DIR"] = folder
        # as `use_compilation_cache` sets them, for processes that do not call it
        os.environ["JAX_COMPILATION_CACHE_MAX_SIZE"] = str(CACHE_MAX_BYTES)
        os.environ["JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS"] = str(CACHE_MIN_COMPILE_S)
    use_compilation_cache(os.environ[_CACHE_VARIABLE])


def pytest_unconfigure(config):
    folder = getattr(config, "_vfjax_cache", None)
    if folder:
        shutil.rmtree(folder, ignore_errors=True)


@pytest.fixture(scope="session")
def shared_dir() -> pathlib.Path:
    if not (SHARED / "MODEL_SPEC.md").exists():
        pytest.fail(f"the shared data folder is missing: expected it at {SHARED}")
    return SHARED
