"""The package's structure, checked from its source (docs/architecture.md states the same):

* layers import one way: a module imports only from its own layer or the layers before it,
  whatever the depth of the import (function-level imports included);
* no import circle anywhere, between layers or within one;
* no underscore *name* is imported from another module (a private module such as
  ``vdbejax._interrupts`` is importable: its name says the whole module is internal);
* one import path per name: a module's ``__all__`` lists only what it defines, no module
  re-exports a name (``from x import a as a``, ``A = x.A``), and a name is imported from
  the module that defines it; a package's ``__init__`` is its public surface and lists what
  its modules define.
"""
from __future__ import annotations

import ast
import re
from functools import cache
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "vdbejax"
ARCHITECTURE = PACKAGE.parent / "docs" / "architecture.md"

#: The dependency order, lowest first. ``methods`` and ``envs`` share the lowest rank of
#: the package proper and may not import each other (tasks know nothing of methods).
ORDER = ["base", "methods", "envs", "engine", "results", "runs", "studies", "paper", "cli",
         "facade"]
#: Same rank: neither may import the other.
FORBIDDEN = {("envs", "methods"), ("methods", "envs")}


def layer(module: str) -> str:
    parts = module.split(".")
    # _console: the console script, which loads the command line after its signal handlers
    if len(parts) == 1 or parts[1] in {"__main__", "_console"}:
        return "facade"
    if parts[1] in ORDER:
        return parts[1]
    if parts[1].startswith("_") or parts[1] == "validation":
        return "base"
    raise AssertionError(f"{module} belongs to no layer: add it to ORDER or move it")


def module_name(path: Path) -> str:
    return ".".join(("vdbejax", *path.relative_to(PACKAGE).with_suffix("").parts)
                    ).removesuffix(".__init__")


@cache
def modules() -> dict[str, ast.Module]:
    return {module_name(path): ast.parse(path.read_text())
            for path in sorted(PACKAGE.rglob("*.py"))}


def resolve(importer: str, node: ast.ImportFrom) -> str:
    """The absolute module an ``ImportFrom`` reads, relative imports included."""
    if not node.level:
        return node.module or ""
    is_package = (PACKAGE / Path(*importer.split(".")[1:]) / "__init__.py").exists()
    base = importer.split(".") if is_package else importer.split(".")[:-1]
    base = base[:len(base) - (node.level - 1)]
    return ".".join(base + ([node.module] if node.module else []))


def home(name: str) -> str | None:
    """The package module a dotted name lives in (a module, or an attribute of one)."""
    while name and name not in modules():
        name = name.rpartition(".")[0]
    return name or None


def imported(module: str) -> list[tuple[str, str]]:
    """``(module read, name taken)`` for every import of the package in ``module``."""
    found = []
    for node in ast.walk(modules()[module]):
        if isinstance(node, ast.ImportFrom):
            target = resolve(module, node)
            if target == "vdbejax" or target.startswith("vdbejax."):
                # the distribution's version, ``from vdbejax import __version__``, is
                # metadata the front reads once, not a name of a layer
                found += [(target, alias.name) for alias in node.names
                          if not (target == "vdbejax" and alias.name.startswith("__"))]
        elif isinstance(node, ast.Import):
            found += [(alias.name, "") for alias in node.names
                      if alias.name == "vdbejax" or alias.name.startswith("vdbejax.")]
    return found


def edges() -> list[tuple[str, str]]:
    """Module → module it imports (a name of a package resolves to its submodule)."""
    found = set()
    for module in modules():
        for target, name in imported(module):
            dep = home(f"{target}.{name}" if name else target)
            if dep and dep != module:
                found.add((module, dep))
    return sorted(found)


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Every strongly connected group of more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    groups = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        for w in graph.get(v, ()):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            group = []
            while True:
                w = stack.pop()
                group.append(w)
                if w == v:
                    break
            if len(group) > 1:
                groups.append(sorted(group))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return groups


def test_the_walk_finds_the_package() -> None:
    found = edges()
    assert ("vdbejax.runs.grid", "vdbejax.engine.programs") in found
    assert ("vdbejax.cli.paper_commands", "vdbejax.paper.reproduce") in found


@pytest.mark.parametrize("edge", edges(), ids=lambda e: f"{e[0]}->{e[1]}")
def test_imports_point_one_way(edge: tuple[str, str]) -> None:
    source, target = edge
    a, b = layer(source), layer(target)
    if target == "vdbejax" and a != "facade":
        raise AssertionError(f"{source} imports {target}: import from the module that "
                             "defines the name")
    assert ORDER.index(b) <= ORDER.index(a), f"{source} ({a}) imports {target} ({b}), a later layer"
    assert (a, b) not in FORBIDDEN, f"{source} ({a}) imports {target} ({b})"


def test_a_check_of_the_rule_fails_on_an_upward_import() -> None:
    assert layer("vdbejax.results.stats") == "results"
    with pytest.raises(AssertionError, match="a later layer"):
        test_imports_point_one_way(("vdbejax.results.stats", "vdbejax.runs.grid"))
    with pytest.raises(AssertionError, match=r"imports vdbejax\.methods"):
        test_imports_point_one_way(("vdbejax.envs.tabular", "vdbejax.methods.contract"))
    with pytest.raises(AssertionError, match="defines the name"):
        test_imports_point_one_way(("vdbejax.studies.scaling", "vdbejax"))


def test_no_import_circle() -> None:
    graph: dict[str, set[str]] = {}
    for a, b in edges():
        graph.setdefault(a, set()).add(b)
    assert not cycles(graph), f"modules that import each other: {cycles(graph)}"


def test_the_circle_check_finds_a_circle() -> None:
    assert cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
    assert cycles({"a": {"b"}, "b": set()}) == []


def private_imports() -> list[str]:
    found = []
    for module in modules():
        for target, name in imported(module):
            if name.startswith("_") and not name.startswith("__") and (
                    f"{target}.{name}" not in modules()):
                found.append(f"{module} imports {name} from {target}")
    return found


def test_no_private_name_is_imported_from_another_module() -> None:
    assert not private_imports(), "make the name public or keep it in one module: " + \
        "; ".join(private_imports())


def test_the_private_name_check_reads_relative_and_function_level_imports() -> None:
    tree = ast.parse("def f():\n    from .lockstep import _helper\n")
    node = next(n for n in ast.walk(tree) if isinstance(n, ast.ImportFrom))
    assert resolve("vdbejax.engine.rules", node) == "vdbejax.engine.lockstep"
    assert node.names[0].name == "_helper"


def is_package(module: str) -> bool:
    return (PACKAGE / Path(*module.split(".")[1:]) / "__init__.py").exists()


def defined(tree: ast.Module) -> set[str]:
    """The names a module's top level defines (functions, classes, assignments)."""
    names = set()
    for node in tree.body:
        if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef | ast.ClassDef):
            names.add(node.name)
        elif isinstance(node, ast.Assign | ast.AnnAssign):
            targets = node.targets if isinstance(node, ast.Assign) else [node.target]
            names |= {n.id for target in targets for n in ast.walk(target)
                      if isinstance(n, ast.Name)}
    return names


def reexports(module: str, tree: ast.Module) -> list[str]:
    """The names ``module`` re-exports: imported as themselves (``import a as a``), bound to
    a package module's name of the same name (``A = m.A``) or, in a module that is no
    package, listed in its ``__all__`` without being defined there."""
    found, package_names = [], set()
    for node in tree.body:
        if isinstance(node, ast.Import | ast.ImportFrom):
            found += [f"{module} re-exports {alias.name}" for alias in node.names
                      if alias.asname and alias.asname == alias.name.rpartition(".")[2]]
            package_names |= {alias.asname or alias.name for alias in node.names
                              if (alias.name if isinstance(node, ast.Import)
                                  else resolve(module, node)).startswith("vdbejax")}
        elif isinstance(node, ast.Assign):
            pairs = [(target, node.value) for target in node.targets]
            pairs += [pair for target, value in pairs if isinstance(target, ast.Tuple)
                      and isinstance(value, ast.Tuple)
                      for pair in zip(target.elts, value.elts, strict=False)]
            found += [f"{module} re-exports {target.id}" for target, value in pairs
                      if isinstance(target, ast.Name) and isinstance(value, ast.Attribute)
                      and value.attr == target.id and isinstance(value.value, ast.Name)
                      and value.value.id in package_names]
            if [n.id for n in node.targets if isinstance(n, ast.Name)] == ["__all__"] \
                    and isinstance(node.value, ast.List | ast.Tuple) and not is_package(module):
                found += [f"{module}.__all__ lists {e.value}, defined elsewhere"
                          for e in node.value.elts if isinstance(e, ast.Constant)
                          and e.value not in defined(tree)]
    return found


def imports_not_from_home() -> list[str]:
    """``from vdbejax.m import N`` where ``m`` is a module (no package) that does not define
    ``N``: the name has a home elsewhere."""
    found = []
    for module in modules():
        for target, name in imported(module):
            if (name and target in modules() and not is_package(target)
                    and f"{target}.{name}" not in modules()
                    and name not in defined(modules()[target])):
                found.append(f"{module} imports {name} from {target}")
    return found


def test_one_import_path_per_name() -> None:
    found = [line for module, tree in modules().items() for line in reexports(module, tree)]
    found += imports_not_from_home()
    assert not found, "import each name from its home: " + "; ".join(found)


def test_the_reexport_check_finds_each_kind() -> None:
    tree = ast.parse("import jax\nfrom vdbejax.a import b as b\nfrom vdbejax.a import c, m\n"
                     "E, F = m.E, m.G\nArray = jax.Array\ndef d():\n    pass\n"
                     "__all__ = ['c', 'd']\n")
    assert reexports("vdbejax.studies.x", tree) == [
        "vdbejax.studies.x re-exports b", "vdbejax.studies.x re-exports E",
        "vdbejax.studies.x.__all__ lists c, defined elsewhere"]
    assert reexports("vdbejax.studies", tree) == ["vdbejax.studies re-exports b",
                                                  "vdbejax.studies re-exports E"]
    assert "WINDOW" in defined(modules()["vdbejax.results.curves"])


def test_the_architecture_page_states_the_same_order() -> None:
    """docs/architecture.md's first paragraph names the layers in this test's order."""
    text = ARCHITECTURE.read_text()
    sentence = text.split("## The map of the package", 1)[1].split("\n\n", 2)[1]
    stated = re.findall(r"`(\w+)/`", sentence.split(". ")[0])
    assert stated[:len(ORDER) - 2] == [name for name in ORDER[1:-1]], stated
