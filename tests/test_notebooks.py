"""Every notebook runs from top to bottom, so none can rot."""

import pathlib

import nbformat
import pytest
from nbclient import NotebookClient

NOTEBOOKS = sorted((pathlib.Path(__file__).parents[1] / "notebooks").glob("*.ipynb"))


def test_there_are_notebooks():
    assert NOTEBOOKS, "notebooks/ is empty"


#: Notebooks that diagnose a recording of the shared tests' length bucket with the default
#: candidates, refit plan and calibration batch of `test_diagnosis.QUICK_LEVEL`: run by the
#: worker of the diagnosis tests, after them, so that the notebook's kernel finds their
#: compiled programs in the session's compilation cache.
_AFTER_DIAGNOSIS = ("03_missing_physics.ipynb",)


def _marks(path):
    return [pytest.mark.xdist_group("diagnosis")] if path.name in _AFTER_DIAGNOSIS else []


@pytest.mark.parametrize("path", [pytest.param(p, id=p.name, marks=_marks(p)) for p in NOTEBOOKS])
def test_notebook_executes(path, monkeypatch):
    # notebooks with a long full study (03: four real recordings) run one case here; the
    # kernel inherits this process's environment
    monkeypatch.setenv("VFJAX_NOTEBOOK_QUICK", "1")
    nb = nbformat.read(path, as_version=4)
    client = NotebookClient(
        nb, timeout=600, kernel_name="python3", resources={"metadata": {"path": str(path.parent)}}
    )
    client.execute()
    errors = [
        o
        for c in nb.cells
        if c.cell_type == "code"
        for o in c.get("outputs", [])
        if o.get("output_type") == "error"
    ]
    assert not errors
