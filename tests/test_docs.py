"""The documentation site's sources agree with the code: every public name has an entry in
the API reference, every page and notebook is in the site's navigation, and the command-line
page renders every command's help. (`mkdocs build --strict`, which `.ci/run` runs after the
tests, checks links, references and docstrings against signatures.)"""

import pathlib
import re
import runpy
import types

import pytest

import vfjax
from vfjax.cli import build_parser

ROOT = pathlib.Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"


def test_every_public_name_is_in_the_api_reference():
    text = "\n".join(p.read_text() for p in (DOCS / "api").glob("*.md"))
    entries = set(re.findall(r"^::: (vfjax[\w.]*)", text, re.M))
    missing = []
    for name in vfjax.__all__:
        if isinstance(getattr(vfjax, name), types.ModuleType):  # a namespace: one of its names
            if not any(e.startswith(f"vfjax.{name}.") or e == f"vfjax.{name}" for e in entries):
                missing.append(name)
        elif f"vfjax.{name}" not in entries:
            missing.append(name)
    assert missing == []
    for entry in entries:  # and every entry names an object that exists
        module, *attributes = entry.split(".")
        obj = vfjax
        for attribute in attributes:
            obj = getattr(obj, attribute)


def test_every_page_and_notebook_is_in_the_navigation():
    nav = re.findall(r":\s*([\w/.-]+\.(?:md|ipynb))\s*$", (ROOT / "mkdocs.yml").read_text(), re.M)
    pages = {str(p.relative_to(DOCS)) for p in DOCS.rglob("*.md")}
    notebooks = {f"examples/{p.name}" for p in (ROOT / "notebooks").glob("*.ipynb")}
    assert (DOCS / "examples").resolve() == (ROOT / "notebooks").resolve()
    assert set(nav) == pages | notebooks
    assert len(nav) == len(set(nav))


def test_the_command_line_page_renders_every_commands_help():
    hooks = runpy.run_path(str(DOCS / "_hooks.py"))
    page = (DOCS / "cli.md").read_text()
    assert hooks["MARKER"] in page
    rendered = hooks["on_page_markdown"](page, page=None, config=None, files=None)
    assert hooks["MARKER"] not in rendered
    parser = build_parser()
    commands = next(a for a in parser._actions if a.__class__.__name__ == "_SubParsersAction")
    for name, sub in commands.choices.items():
        assert f"## `vfjax {name}`" in rendered
        for action in sub._actions:
            for option in action.option_strings:
                assert option in rendered, (name, option)


@pytest.mark.slow
def test_the_readmes_example_runs():
    """The README's ten-line example as written (a first fit and a calibrated diagnosis of
    a demo recording with nothing hidden: the fit reaches the noise, nothing is needed)."""
    text = (ROOT / "README.md").read_text()
    code = re.search(r"## In ten lines\n\n```python\n(.*?)```", text, re.S).group(1)
    scope = {}
    exec(compile(code, "README.md", "exec"), scope)
    assert scope["fit"].nmse < 1e-3 and scope["d"].needed == []
    assert scope["dgaw_dK"].shape == (201,)
