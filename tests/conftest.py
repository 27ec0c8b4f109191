"""Shared fixtures. The shared data folder sits beside the checkout (../shared)."""

import pathlib

import pytest

import vfjax  # noqa: F401  (enables float64 before any test builds arrays)

ROOT = pathlib.Path(__file__).resolve().parents[1]

SHARED = ROOT.parent / "shared"


@pytest.fixture(scope="session")
def shared_dir() -> pathlib.Path:
    if not (SHARED / "MODEL_SPEC.md").exists():
        pytest.fail(f"the shared data folder is missing: expected it at {SHARED}")
    return SHARED


def _memory_maps() -> int:
    try:
        with open("/proc/self/maps") as f:
            return sum(1 for _ in f)
    except OSError:  # not Linux
        return 0


@pytest.fixture(autouse=True)
def _release_compiled_code():
    """Each compiled fit holds ~2500 memory maps of JIT code, and Linux allows 65530 per
    process (vm.max_map_count): a worker that compiles many model structures would fail
    with "LLVM compilation error: Cannot allocate memory". Past half the limit, JAX's caches
    are cleared (later tests recompile what they need)."""
    yield
    if _memory_maps() > 30_000:
        import jax

        jax.clear_caches()
