"""Old import paths of modules that moved, kept importable (CHANGELOG.md lists the moves).

``import vdbejax.stats`` gives the module object of ``vdbejax.results.stats`` itself (the
same object, so a patch through either name reaches both), with a ``DeprecationWarning``
naming the new import: the old names are kept for one release.
"""
from __future__ import annotations

import importlib
import importlib.abc
import importlib.machinery
import sys
import warnings
from collections.abc import Callable
from types import ModuleType
from typing import Any

#: old module name -> its home now.
MOVED = {
    "vdbejax.agents": "vdbejax.methods.agents",
    "vdbejax.analysis": "vdbejax.results.analysis",
    "vdbejax.batching": "vdbejax.runs.batching",
    "vdbejax.bootstrap": "vdbejax.results.bootstrap",
    "vdbejax.checkpoint": "vdbejax.runs.checkpoint",
    "vdbejax.curves": "vdbejax.results.curves",
    "vdbejax.distributed": "vdbejax.engine.distributed",
    "vdbejax.grid_result": "vdbejax.results.grid_result",
    "vdbejax.io": "vdbejax.results.io",
    "vdbejax.plotting": "vdbejax.results.plotting",
    "vdbejax.progress": "vdbejax.engine.progress",
    "vdbejax.result_folder": "vdbejax.results.folder_lock",
    "vdbejax.scaling": "vdbejax.studies.scaling",
    "vdbejax.scaling_adaptive": "vdbejax.studies.scaling_adaptive",
    "vdbejax.scaling_report": "vdbejax.studies.scaling_report",
    "vdbejax.scaling_study": "vdbejax.studies.scaling_study",
    "vdbejax.snapshots": "vdbejax.studies.snapshots",
    "vdbejax.solvers": "vdbejax.envs.solvers",
    "vdbejax.solving": "vdbejax.results.solving",
    "vdbejax.stats": "vdbejax.results.stats",
    "vdbejax.summary": "vdbejax.results.summary",
    "vdbejax.sweeps": "vdbejax.studies.sweeps",
}


class _MovedFinder(importlib.abc.MetaPathFinder, importlib.abc.Loader):
    """Finds an old name and loads it as the module at its new home."""

    def find_spec(self, name: str, path: object = None,
                  target: object = None) -> importlib.machinery.ModuleSpec | None:
        if name not in MOVED:
            return None
        return importlib.machinery.ModuleSpec(name, self)

    def create_module(self, spec: importlib.machinery.ModuleSpec) -> None:
        return None  # a placeholder; exec_module swaps the real module in

    def exec_module(self, module: ModuleType) -> None:
        # The import system returns whatever sys.modules holds under the name after this
        # call; the moved module's own __spec__ and __name__ stay untouched.
        new = MOVED[module.__name__]
        warnings.warn(f"{module.__name__} moved to {new}: import {new} (the old name is kept"
                      " for one release; CHANGELOG.md)", DeprecationWarning, stacklevel=2)
        sys.modules[module.__name__] = importlib.import_module(new)


def install() -> None:
    """Put the finder on ``sys.meta_path`` (once)."""
    if not any(isinstance(f, _MovedFinder) for f in sys.meta_path):
        sys.meta_path.append(_MovedFinder())


def moved_names(module: str, home: str, names: tuple[str, ...]) -> Callable[[str], Any]:
    """A module ``__getattr__`` for ``module``: each of ``names`` now lives in ``home``;
    importing it from ``module`` still works, with a ``DeprecationWarning``."""
    def attribute(name: str) -> Any:
        if name in names:
            warnings.warn(f"{module}.{name} moved: import it from {home} (the old name is"
                          " kept for one release; CHANGELOG.md)", DeprecationWarning,
                          stacklevel=2)
            return getattr(importlib.import_module(home), name)
        raise AttributeError(f"module {module!r} has no attribute {name!r}")

    return attribute

