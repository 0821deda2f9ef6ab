"""Every example runs as written: the Python blocks of the README and of every docs page
(a page's blocks as one script, in a fresh process and an empty folder) and the docstrings'
complete examples (those that begin with their imports)."""
from __future__ import annotations

import ast
import os
import re
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "vdbejax"


def page_script(page: Path) -> str:
    """A page's Python blocks, in order, as one script."""
    return "\n".join(re.findall(r"^```python\n(.*?)^```", page.read_text("utf-8"),
                                re.S | re.M))


#: The README and every docs page with a Python block (issue 49: every one runs).
PAGES = [p for p in [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
         if page_script(p)]


def covering_page(page: Path) -> Path | None:
    """The first other page whose script begins with the whole of ``page``'s script (the
    site's home page repeats the README's first block): run in a fresh process and an empty
    folder, that script runs ``page``'s code exactly as ``page``'s own script would, then
    goes on, so ``page`` is run there and not twice."""
    script = page_script(page)
    return next((other for other in PAGES
                 if other != page and page_script(other).startswith(script)), None)


#: The pages run as a script of their own (every other page: :func:`covering_page`).
RUN_PAGES = [page for page in PAGES if covering_page(page) is None]


def docstring_examples() -> list[tuple[str, str]]:
    """``(where, code)`` of every literal block (``::``) of a docstring of the package that
    begins with an import: a complete example, not a fragment."""
    found = []
    for path in sorted(PACKAGE.rglob("*.py")):
        tree = ast.parse(path.read_text("utf-8"))
        for node in ast.walk(tree):  # the module first, then every node once
            if not isinstance(node, (ast.Module, ast.FunctionDef, ast.ClassDef)):
                continue
            doc = ast.get_docstring(node)
            for match in re.finditer(r"::\n\n((?:[ \t]+.*\n|\n)+)", (doc or "") + "\n"):
                code = textwrap.dedent(match.group(1))
                if code.lstrip().startswith(("import ", "from ")):
                    name = getattr(node, "name", "module")
                    found.append((f"{path.relative_to(ROOT)}:{name}", code))
    return found


def run_script(code: str, folder: Path) -> subprocess.CompletedProcess:
    script = folder / "example.py"
    script.write_text(code)
    return subprocess.run([sys.executable, str(script)], capture_output=True, text=True,
                          cwd=folder, timeout=900, env={**os.environ, "MPLBACKEND": "Agg"})


@pytest.mark.parametrize("page", RUN_PAGES, ids=lambda page: page.name)
def test_the_python_examples_of_every_page_run_as_written(tmp_path, page):
    done = run_script(page_script(page), tmp_path)
    assert done.returncode == 0, f"{page.name}: {done.stderr[-3000:]}"
    if page.name == "README.md":
        assert len(PAGES) > 2 and (tmp_path / "out" / "small" / "report.md").exists()
        assert ROOT / "docs" / "tutorial.md" in PAGES
    if page.name == "tutorial.md":  # the tutorial's figure and its table with intervals
        assert (tmp_path / "my_study.png").exists() and "| halving_epsilon | " in done.stdout


def test_a_page_whose_script_begins_another_runs_there():
    """The home page's block is the README's first: run by the README's script, which
    begins with it."""
    index, readme = ROOT / "docs" / "index.md", ROOT / "README.md"
    assert covering_page(index) == readme and index not in RUN_PAGES
    assert covering_page(readme) is None and readme in RUN_PAGES
    assert all(covering_page(page) in RUN_PAGES for page in PAGES if page not in RUN_PAGES)
    assert len(RUN_PAGES) >= len(PAGES) - 1  # only the home page repeats another page


def test_the_docstring_examples_are_found():
    where = [name for name, _ in docstring_examples()]
    assert "vdbejax/methods/contract.py:module" in where and "vdbejax/__init__.py:module" in where


@pytest.mark.parametrize("where, code", docstring_examples(),
                         ids=lambda value: value if ".py:" in str(value) else "")
def test_a_docstring_example_runs_as_written(tmp_path, where, code):
    done = run_script(code, tmp_path)
    assert done.returncode == 0, f"{where}: {done.stderr[-3000:]}"


def test_the_readme_sweep_file_is_an_excerpt_of_the_example_that_runs():
    import tomllib

    blocks = re.findall(r"^```toml\n(.*?)^```", (ROOT / "README.md").read_text("utf-8"),
                        re.S | re.M)
    example = tomllib.loads((ROOT / "examples" / "sweep.toml").read_text("utf-8"))
    assert blocks
    for block in blocks:
        excerpt = tomllib.loads(block)
        for key, value in excerpt.items():
            if isinstance(value, list) and value and isinstance(value[0], dict):
                assert all(entry in example[key] for entry in value), key
            elif isinstance(value, dict):
                assert value.items() <= example[key].items(), key
            else:
                assert example[key] == value, key


def test_the_sweep_page_shows_the_example_file_as_it_is():
    import tomllib

    page = (ROOT / "docs" / "sweeps.md").read_text("utf-8")
    (block,) = re.findall(r"^```toml\n(.*?)^```", page, re.S | re.M)
    assert tomllib.loads(block) == tomllib.loads(
        (ROOT / "examples" / "sweep.toml").read_text("utf-8"))
