"""The package's layout: no module imports one that imports it back, directly or through
others, also where the import sits inside a function (read from the source, not from what
Python happened to import); one version for the package, its build and its command line."""

import ast
import graphlib
import importlib.metadata
import pathlib

import pytest

import vfjax
from vfjax.cli import build_parser

PACKAGE = pathlib.Path(vfjax.__file__).resolve().parent


def _module_names(folder: pathlib.Path) -> dict[str, pathlib.Path]:
    """Dotted name -> file of every module under the package ``folder``."""
    names = {}
    for path in folder.rglob("*.py"):
        parts = path.relative_to(folder.parent).with_suffix("").parts
        if parts[-1] == "__init__":
            parts = parts[:-1]
        names[".".join(parts)] = path
    return names


def _typing_only(tree: ast.Module) -> set[int]:
    """The nodes under ``if TYPE_CHECKING:`` blocks (imports that never run)."""
    skipped = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test):
            for child in node.body:
                skipped.update(id(n) for n in ast.walk(child))
    return skipped


def import_graph(folder: pathlib.Path) -> dict[str, set[str]]:
    """Module -> the package's modules it imports, at module level or inside a function (a
    ``from X import name`` of a name defined in X counts as importing X; of a submodule, as
    importing the submodule). Imports under ``if TYPE_CHECKING:`` are left out."""
    modules = _module_names(folder)

    def owner(name: str) -> str | None:
        while name and name not in modules:
            name = name.rpartition(".")[0]
        return name or None

    graph = {}
    for name, path in modules.items():
        tree = ast.parse(path.read_text(encoding="utf-8"))
        skipped = _typing_only(tree)
        package = name if path.name == "__init__.py" else name.rpartition(".")[0]
        found = set()
        for node in ast.walk(tree):
            if id(node) in skipped:
                continue
            if isinstance(node, ast.Import):
                targets = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                if node.level:
                    parts = package.split(".")
                    base = parts[: len(parts) - node.level + 1]
                    origin = ".".join(base + ([node.module] if node.module else []))
                else:
                    origin = node.module
                targets = [f"{origin}.{a.name}" for a in node.names]
            else:
                continue
            found.update(t for t in map(owner, targets) if t is not None and t != name)
        graph[name] = found
    return graph


def import_loop(graph: dict[str, set[str]]) -> list[str] | None:
    """One loop of modules that import each other back (sorted), or None where there is
    none: `graphlib`'s topological sort refuses a graph with a cycle and names it."""
    try:
        graphlib.TopologicalSorter(graph).prepare()
    except graphlib.CycleError as err:
        return sorted(set(err.args[1]))
    return None


def _package(folder: pathlib.Path, files: dict[str, str]) -> dict[str, set[str]]:
    """The import graph of a made-up package ``folder`` with ``files`` (name -> source)."""
    for name, text in files.items():
        (folder / name).parent.mkdir(parents=True, exist_ok=True)
        (folder / name).write_text(text)
    return import_graph(folder)


def test_no_module_imports_one_that_imports_it_back():
    graph = import_graph(PACKAGE)
    assert {"vfjax", "vfjax._fit._engine", "vfjax._diagnosis._calibration"} <= set(graph)
    assert "vfjax._fit._engine" in graph["vfjax._fit"]  # relative imports are resolved
    assert import_loop(graph) is None


def test_the_check_finds_loops_through_functions_and_the_package(tmp_path):
    """A loop held together by an import inside a function, and one back to the package's
    ``__init__`` (a submodule reading a name the package defines), are both found; an
    import for type checking only is not one."""
    shared = {
        "d.py": "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from .e import x\n",
        "e.py": "from .d import TYPE_CHECKING as x\n",
        "sub/__init__.py": "from ..b import h\n",
        "b.py": "def h():\n    return 1\n",
    }
    through_a_function = _package(
        tmp_path / "pkg",
        {
            **shared,
            "__init__.py": "from .a import f\n",
            "a.py": "def f():\n    from .b import h\n    return h()\n",
            "b.py": "from .a import f\n\ndef h():\n    return 1\n",
        },
    )
    assert through_a_function["pkg.sub"] == {"pkg.b"} and through_a_function["pkg.d"] == set()
    assert import_loop(through_a_function) == ["pkg.a", "pkg.b"]
    back_to_the_package = _package(
        tmp_path / "other" / "pkg",
        {
            **shared,
            "__init__.py": "from .c import g\nVERSION = '1'\n",
            "c.py": "def g():\n    from . import VERSION\n    return VERSION\n",
        },
    )
    assert import_loop(back_to_the_package) == ["pkg", "pkg.c"]
    assert import_loop(_package(tmp_path / "clean" / "pkg", shared)) is None


def test_one_version_for_the_package_its_build_and_its_command_line(capsys):
    """`vfjax/_version.py` is what the installed distribution (pyproject.toml's dynamic
    version) and `vfjax --version` say."""
    assert importlib.metadata.version("vfjax") == vfjax.__version__
    with pytest.raises(SystemExit):
        build_parser().parse_args(["--version"])
    assert capsys.readouterr().out.strip() == f"vfjax {vfjax.__version__}"
