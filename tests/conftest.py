"""Shared fixtures. The shared data folder sits beside the checkout (../shared)."""

import pathlib

import jax
import pytest

import vfjax  # noqa: F401  (enables float64 before any test builds arrays)

ROOT = pathlib.Path(__file__).resolve().parents[1]
# One persistent compilation cache for the test workers: a program compiled by one xdist
# worker (a candidate's refit, say) is read back by the other instead of compiled twice.
jax.config.update("jax_compilation_cache_dir", str(ROOT / ".pytest_cache" / "jax"))
jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.5)
SHARED = ROOT.parent / "shared"


@pytest.fixture(scope="session")
def shared_dir() -> pathlib.Path:
    if not (SHARED / "MODEL_SPEC.md").exists():
        pytest.fail(f"the shared data folder is missing: expected it at {SHARED}")
    return SHARED
