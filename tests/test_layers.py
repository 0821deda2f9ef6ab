"""Layers point one way: what the results and statistics modules import (at the top of
the module or inside a function, transitively) never reaches the engine or the run path,
and tasks never reach the plug-in surface's agents or the engine."""
from __future__ import annotations

import ast
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "vdbejax"


def _module_file(name: str) -> Path | None:
    parts = name.split(".")[1:]
    base = PACKAGE.joinpath(*parts)
    for candidate in (base.with_suffix(".py"), base / "__init__.py"):
        if candidate.is_file():
            return candidate
    return None


def _imports(name: str) -> set[str]:
    """The vdbejax modules ``name`` imports (its parent packages' ``__init__`` included)."""
    path = _module_file(name)
    if path is None:
        return set()
    found = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            found |= {alias.name for alias in node.names}
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            found.add(node.module)
            found |= {f"{node.module}.{alias.name}" for alias in node.names}
    found = {n for n in found if n.startswith("vdbejax.") and _module_file(n) is not None}
    parents = {".".join(n.split(".")[:i]) for n in found for i in range(2, n.count(".") + 1)}
    return found | {p for p in parents if _module_file(p) is not None}


def reachable(name: str) -> set[str]:
    seen, todo = set(), [name]
    while todo:
        module = todo.pop()
        if module not in seen:
            seen.add(module)
            todo.extend(_imports(module) - seen)
    return seen - {name}


@pytest.mark.parametrize("module", ["vdbejax.grid_result", "vdbejax.stats", "vdbejax.summary",
                                    "vdbejax.analysis", "vdbejax.plotting", "vdbejax.solving",
                                    "vdbejax.scaling_report"])
def test_results_and_statistics_never_reach_the_engine_or_the_run_path(module):
    bad = sorted(m for m in reachable(module)
                 if m.startswith(("vdbejax.engine", "vdbejax.runs", "vdbejax.studies")))
    assert not bad, f"{module} reaches {bad}"


@pytest.mark.parametrize("module", ["vdbejax.envs.tabular", "vdbejax.envs.table_cleaning",
                                    "vdbejax.envs.cruz2018"])
def test_tasks_never_reach_the_engine_or_the_agents(module):
    bad = sorted(m for m in reachable(module)
                 if m.startswith(("vdbejax.engine", "vdbejax.runs", "vdbejax.methods")))
    assert not bad, f"{module} reaches {bad}"


def test_nothing_below_the_paper_imports_it():
    for path in PACKAGE.rglob("*.py"):
        name = "vdbejax." + ".".join(path.relative_to(PACKAGE).with_suffix("").parts)
        name = name.removesuffix(".__init__")
        if name.startswith(("vdbejax.paper", "vdbejax.cli")) or name == "vdbejax":
            continue
        assert not any(m.startswith("vdbejax.paper") for m in _imports(name)), name
