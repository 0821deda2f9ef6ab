"""Every example runs as written: the README's Python blocks (one script, in a fresh
process and an empty folder) and the docstrings' complete examples (those that begin with
their imports)."""
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


def readme_script() -> str:
    blocks = re.findall(r"^```python\n(.*?)^```", (ROOT / "README.md").read_text("utf-8"),
                        re.S | re.M)
    assert len(blocks) >= 2
    return "\n".join(blocks)


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


def test_the_readme_python_examples_run_as_written(tmp_path):
    done = run_script(readme_script(), tmp_path)
    assert done.returncode == 0, done.stderr[-3000:]
    assert (tmp_path / "out" / "paper" / "report.md").exists()


def test_the_docstring_examples_are_found():
    where = [name for name, _ in docstring_examples()]
    assert "vdbejax/methods/api.py:module" in where and "vdbejax/__init__.py:module" in where


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
