"""Execute every notebook at full size and store the executed copy in docs/notebooks/, so
that the notebooks render with their outputs where users browse (GitHub shows .ipynb
outputs); CI executes the sources themselves at small size (tests/test_notebooks.py), and
checks that every copy is an execution of its source's current code.

    python notebooks/render.py            # all notebooks
    python notebooks/render.py 04         # those whose name starts with 04
"""
from __future__ import annotations

import os
import sys
import time
from pathlib import Path

import nbclient
import nbformat

HERE = Path(__file__).resolve().parent
RENDERED = HERE.parent / "docs" / "notebooks"


def render(path: Path) -> Path:
    """Execute ``path`` (full size) and write the executed copy; return its path."""
    notebook = nbformat.read(path, as_version=4)
    env = {k: v for k, v in os.environ.items() if k != "VDBEJAX_NOTEBOOK_SMALL"}
    os.environ.clear()
    os.environ.update(env, MPLBACKEND="module://matplotlib_inline.backend_inline")
    client = nbclient.NotebookClient(notebook, timeout=3600, kernel_name="python3",
                                     resources={"metadata": {"path": str(path.parent)}})
    client.execute()
    for cell in notebook.cells:  # keep the copies small and stable
        cell.metadata.pop("execution", None)
    RENDERED.mkdir(parents=True, exist_ok=True)
    out = RENDERED / path.name
    nbformat.write(notebook, out)
    return out


def main(argv: list[str]) -> int:
    prefixes = argv or [""]
    for path in sorted(HERE.glob("*.ipynb")):
        if any(path.name.startswith(p) for p in prefixes):
            started = time.perf_counter()
            out = render(path)
            print(f"{out} ({time.perf_counter() - started:.0f} s, {out.stat().st_size / 1e3:.0f} kB)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
