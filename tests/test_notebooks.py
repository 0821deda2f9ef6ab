"""Every notebook runs top to bottom (small settings: VDBEJAX_NOTEBOOK_SMALL=1)."""
from pathlib import Path

import pytest

nbformat = pytest.importorskip("nbformat")
nbclient = pytest.importorskip("nbclient")

NOTEBOOKS = sorted((Path(__file__).resolve().parents[1] / "notebooks").glob("*.ipynb"))


@pytest.fixture(autouse=True)
def small_settings(monkeypatch):
    # The kernel inherits the environment: notebooks shrink seeds and episodes.
    monkeypatch.setenv("VDBEJAX_NOTEBOOK_SMALL", "1")
    monkeypatch.setenv("MPLBACKEND", "Agg")


def test_notebooks_exist():
    names = [p.name for p in NOTEBOOKS]
    assert "01_reproduce_paper.ipynb" in names and "02_explorers_up_close.ipynb" in names
    assert "05_your_own_method.ipynb" in names  # the engine: a plug-in on a task of its own


@pytest.mark.parametrize("path", NOTEBOOKS, ids=lambda p: p.stem)
def test_a_notebook_uses_the_public_api_only(path):
    """No private name, no engine internals: what a notebook needs, the public API gives."""
    import re

    notebook = nbformat.read(path, as_version=4)
    code = "\n".join(c.source for c in notebook.cells if c.cell_type == "code")
    imports = re.findall(r"^\s*from (vdbejax[\w.]*) import \(?([^)\n]*)", code, re.M)
    imports += [(module, "") for module in re.findall(r"^\s*import (vdbejax[\w.]*)", code, re.M)]
    assert imports, "a notebook on vdbejax imports it"
    for module, names in imports:
        assert not module.startswith("vdbejax.engine"), (module, "engine internals")
        assert not any(part.startswith("_") for part in module.split(".")), module
        assert not any(n.strip().startswith("_") for n in names.split(",")), (module, names)
    private = re.findall(r"\b(?:vdbejax|[a-z_]+)\.(_[a-z]\w*)", code)
    assert not [p for p in private if not p.startswith("__")], private


@pytest.mark.parametrize("path", NOTEBOOKS, ids=lambda p: p.stem)
def test_notebook_runs(path):
    notebook = nbformat.read(path, as_version=4)
    client = nbclient.NotebookClient(notebook, timeout=600, kernel_name="python3",
                                     resources={"metadata": {"path": str(path.parent)}})
    client.execute()  # raises CellExecutionError with the failing cell's traceback
    errors = [o for c in notebook.cells if c.cell_type == "code" for o in c.outputs
              if o.output_type == "error"]
    assert not errors
    # Every figure cell produced an image.
    images = [o for c in notebook.cells if c.cell_type == "code" for o in c.outputs
              if "image/png" in o.get("data", {})]
    assert images, f"{path.name} drew no figure"


RENDERED = Path(__file__).resolve().parents[1] / "docs" / "notebooks"


@pytest.mark.parametrize("path", NOTEBOOKS, ids=lambda p: p.stem)
def test_rendered_copy_is_an_execution_of_the_current_source(path):
    # docs/notebooks/ holds executed copies (python notebooks/render.py) for browsing;
    # a source edited without re-rendering fails here.
    copy = RENDERED / path.name
    assert copy.exists(), f"render it: python notebooks/render.py {path.stem[:2]}"
    source = nbformat.read(path, as_version=4)
    rendered = nbformat.read(copy, as_version=4)
    assert [c.source for c in rendered.cells] == [c.source for c in source.cells]
    code = [c for c in rendered.cells if c.cell_type == "code"]
    assert all(c.outputs for c in code[1:]), "every code cell after the imports has outputs"
    assert not [o for c in code for o in c.outputs if o.output_type == "error"]
    assert copy.stat().st_size < 3_000_000  # small enough to browse
