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
