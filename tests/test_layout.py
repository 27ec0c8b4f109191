"""The package's layout: no module imports one that imports it back, directly or through
others, also where the import sits inside a function (read from the source, not from what
Python happened to import); one version for the package, its build and its command line."""

import ast
import importlib.metadata
import pathlib
import textwrap

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
                    base = package.split(".")[: len(package.split(".")) - node.level + 1]
                    origin = ".".join(base + ([node.module] if node.module else []))
                else:
                    origin = node.module
                targets = [f"{origin}.{a.name}" for a in node.names]
            else:
                continue
            found.update(t for t in map(owner, targets) if t is not None and t != name)
        graph[name] = found
    return graph


def import_loops(graph: dict[str, set[str]]) -> list[list[str]]:
    """The groups of modules that import each other (strongly connected components of more
    than one module), each sorted."""
    order, low, stack, on_stack, loops = {}, {}, [], set(), []

    def visit(v):  # Tarjan's algorithm
        order[v] = low[v] = len(order)
        stack.append(v)
        on_stack.add(v)
        for w in sorted(graph[v]):
            if w not in order:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], order[w])
        if low[v] == order[v]:
            group = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                group.append(w)
                if w == v:
                    break
            if len(group) > 1:
                loops.append(sorted(group))

    for v in sorted(graph):
        if v not in order:
            visit(v)
    return sorted(loops)


def test_no_module_imports_one_that_imports_it_back():
    graph = import_graph(PACKAGE)
    assert {"vfjax", "vfjax._fit._engine", "vfjax._diagnosis._calibration"} <= set(graph)
    assert "vfjax._fit._engine" in graph["vfjax._fit"]  # relative imports are resolved
    assert import_loops(graph) == []


def test_the_check_finds_loops_through_functions_and_the_package(tmp_path):
    """A loop held together by an import inside a function, and one back to the package's
    ``__init__`` (a submodule reading a name the package defines), are both found; an
    import for type checking only is not one."""
    pkg = tmp_path / "pkg"
    (pkg / "sub").mkdir(parents=True)
    files = {
        "__init__.py": "from .a import f\nfrom .c import g\nVERSION = '1'\n",
        "a.py": "def f():\n    from .b import h\n    return h()\n",
        "b.py": "from .a import f\n\ndef h():\n    return 1\n",
        "c.py": "def g():\n    from . import VERSION\n    return VERSION\n",
        "d.py": "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from .e import x\n",
        "e.py": "from .d import TYPE_CHECKING as x\n",
        "sub/__init__.py": "from ..b import h\n",
    }
    for name, text in files.items():
        (pkg / name).write_text(textwrap.dedent(text))
    graph = import_graph(pkg)
    assert graph["pkg.sub"] == {"pkg.b"} and graph["pkg.d"] == set()
    assert import_loops(graph) == [["pkg", "pkg.c"], ["pkg.a", "pkg.b"]]


def test_one_version_for_the_package_its_build_and_its_command_line(capsys):
    """`vfjax/_version.py` is what the installed distribution (pyproject.toml's dynamic
    version) and `vfjax --version` say."""
    assert importlib.metadata.version("vfjax") == vfjax.__version__
    with pytest.raises(SystemExit):
        build_parser().parse_args(["--version"])
    assert capsys.readouterr().out.strip() == f"vfjax {vfjax.__version__}"
