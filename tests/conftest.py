"""Shared fixtures. The shared data folder sits beside the checkout (../shared)."""

import gc
import os
import pathlib
import shutil
import subprocess
import sys
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


def pytest_runtest_logfinish(nodeid, location):
    """After each test, its garbage collected and what it leaves alive frozen
    (`gc.freeze`): Python's full collections then walk only what later tests make. A test
    process holds over a million objects after a few fits (JAX's traces and caches, the
    imported libraries), and each full collection walks them all: without this, a test that
    makes many objects (a video decoded by PyAV) spends seconds collecting."""
    gc.collect()
    gc.freeze()


@pytest.fixture(scope="session")
def shared_dir() -> pathlib.Path:
    if not (SHARED / "MODEL_SPEC.md").exists():
        pytest.fail(f"the shared data folder is missing: expected it at {SHARED}")
    return SHARED


def check_report_html(markdown_path) -> str:
    """Check the self-contained HTML page beside a report's Markdown against the Markdown
    (parsed with the standard library's HTML parser, not with the code that wrote it):
    one title, as many tables with as many rows as the Markdown has, every figure the
    Markdown names embedded with its PNG's exact bytes, and nothing that runs or is fetched
    (no script, stylesheet link, frame or external source). Returns the page's text."""
    import base64
    import html.parser
    import re

    markdown_path = pathlib.Path(markdown_path)
    text = markdown_path.read_text()
    page = markdown_path.with_suffix(".html").read_text()

    class Parser(html.parser.HTMLParser):
        def __init__(self):
            super().__init__()
            self.tags, self.images, self.rows, self.title = [], [], 0, ""
            self._in_title = False

        def handle_starttag(self, tag, attrs):
            self.tags.append(tag)
            attrs = dict(attrs)
            if tag == "img":
                self.images.append(attrs.get("src", ""))
            if tag == "tr":
                self.rows += 1
            for name in ("src", "href"):
                value = attrs.get(name) or ""
                assert not value.startswith(("http:", "https:", "//", "javascript:")), value
            self._in_title = tag == "title"

        def handle_data(self, data):
            if self._in_title:
                self.title += data

        def handle_endtag(self, tag):
            self._in_title = False

    parser = Parser()
    parser.feed(page)
    assert page.startswith("<!DOCTYPE html>")
    assert parser.tags.count("h1") == 1 and parser.tags.count("main") == 1
    assert parser.title == text.splitlines()[0].removeprefix("# ")
    for tag in ("script", "link", "iframe", "object", "embed"):
        assert tag not in parser.tags, tag
    # tables: one per Markdown table, one row per Markdown table line but the separator
    table_lines = [line for line in text.splitlines() if line.startswith("|")]
    separators = [line for line in table_lines if re.fullmatch(r"\|(\s*:?-+:?\s*\|)+", line)]
    assert parser.tags.count("table") == len(separators)
    assert parser.rows == len(table_lines) - len(separators)
    # figures: each Markdown image, in order, embedded with its file's bytes
    figures = re.findall(r"!\[[^\]]*\]\(([^)]+)\)", text)
    assert len(parser.images) == len(figures) >= 1
    for src, name in zip(parser.images, figures):
        head, _, data = src.partition(",")
        assert head == "data:image/png;base64", head
        assert base64.b64decode(data) == (markdown_path.parent / name).read_bytes()
    return page


def run_cli(*args, cwd=None, timeout=300, **env_vars):
    """The command line in a new process, with the test session's compilation cache and one
    CPU device (``VFJAX_CORES="2"`` among ``env_vars`` for two)."""
    env = {k: v for k, v in os.environ.items() if k != "VFJAX_NO_CACHE"}
    cache = os.environ[_CACHE_VARIABLE]
    # one CPU device, as the test processes have: the same programs, from the session cache
    env.update({"PYTHONUNBUFFERED": "1", "VFJAX_CACHE_DIR": cache, "VFJAX_CORES": "1"})
    env.update(env_vars)
    return subprocess.run(
        [sys.executable, "-m", "vfjax", *map(str, args)],
        cwd=cwd,
        capture_output=True,
        text=True,
        timeout=timeout,
        env=env,
    )


@pytest.fixture
def cli():
    """`run_cli`, for the tests that run the command line."""
    return run_cli


@pytest.fixture
def report_html():
    """`check_report_html`, for the tests that write a report."""
    return check_report_html
