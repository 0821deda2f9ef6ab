"""The package's layers import one way (docs/architecture.md): a module imports only from
its own layer or the layers before it, whatever the depth of the import (function-level
imports included)."""
from __future__ import annotations

import ast
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "vdbejax"

#: The dependency order. ``results`` (data and statistics, numpy) comes before ``runs``:
#: a run produces a GridResult, while statistics never train.
ORDER = ["base", "methods", "envs", "engine", "results", "runs", "studies", "paper", "cli",
         "facade"]
#: Within one rank neither may import the other: tasks know nothing of methods.
FORBIDDEN = {("envs", "methods"), ("methods", "envs")}


def layer(module: str) -> str:
    parts = module.split(".")
    # The package's front (``vdbejax``) is only for users: the package itself imports each
    # name from the module that defines it. _console: the console script, which loads the
    # command line after its signal handlers.
    if len(parts) == 1 or parts[1] in {"__main__", "_console"}:
        return "facade"
    if parts[1] in ORDER:
        return parts[1]
    if parts[1].startswith("_") or parts[1] == "validation":
        return "base"
    raise AssertionError(f"{module} belongs to no layer: add it to ORDER or move it")


def imports() -> list[tuple[str, str]]:
    edges = []
    for path in sorted(PACKAGE.rglob("*.py")):
        module = ".".join(("vdbejax", *path.relative_to(PACKAGE).with_suffix("").parts))
        module = module.removesuffix(".__init__")
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                if node.module == "vdbejax":
                    edges += [(module, f"vdbejax.{a.name}") for a in node.names]
                elif node.module.startswith("vdbejax."):
                    edges.append((module, node.module))
            elif isinstance(node, ast.Import):
                edges += [(module, a.name) for a in node.names if a.name.startswith("vdbejax.")]
    return edges


def test_the_walk_finds_the_package() -> None:
    edges = imports()
    assert ("vdbejax.runs.grid", "vdbejax.engine.programs") in edges
    assert ("vdbejax.cli.paper_commands", "vdbejax.paper.reproduce") in edges


@pytest.mark.parametrize("edge", imports(), ids=lambda e: f"{e[0]}->{e[1]}")
def test_imports_point_one_way(edge: tuple[str, str]) -> None:
    source, target = edge
    a, b = layer(source), layer(target)
    assert b != "facade" or a == "facade", \
        f"{source} imports {target}: import from the module that defines the name"
    assert ORDER.index(b) <= ORDER.index(a), f"{source} ({a}) imports {target} ({b}), a later layer"
    assert (a, b) not in FORBIDDEN, f"{source} ({a}) imports {target} ({b})"


def test_a_check_of_the_rule_fails_on_an_upward_import() -> None:
    assert layer("vdbejax.results.stats") == "results"
    assert ORDER.index(layer("vdbejax.runs.grid")) > ORDER.index(layer("vdbejax.results.stats"))
    with pytest.raises(AssertionError, match="a later layer"):
        test_imports_point_one_way(("vdbejax.results.stats", "vdbejax.runs.grid"))
    with pytest.raises(AssertionError, match=r"imports vdbejax\.methods"):
        test_imports_point_one_way(("vdbejax.envs.tabular", "vdbejax.methods.agents"))
    with pytest.raises(AssertionError, match="defines the name"):
        test_imports_point_one_way(("vdbejax.studies.scaling", "vdbejax"))


#: "No module a maintainer must read past about 400 lines to change one thing" (issue 21).
MODULE_LINES_MAX = 400


def test_no_module_is_longer_than_400_lines():
    long = {str(path.relative_to(PACKAGE)): n for path in PACKAGE.rglob("*.py")
            if (n := len(path.read_text().splitlines())) > MODULE_LINES_MAX}
    assert not long, f"modules past {MODULE_LINES_MAX} lines (split them): {long}"
