"""Tasks and plug-ins by name: what a sweep file's ``task`` and ``plugins`` keys (and the
command line's ``--task`` and ``--plugin``) resolve to.
"""
from __future__ import annotations

import dataclasses
import importlib
import importlib.util
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import jax
import numpy as np

from vdbejax.envs.tabular import TabularMDP
from vdbejax.validation import INT32_MAX, check_int


def _import_file(path: Path) -> Any:
    """Import a ``.py`` file as a module."""
    spec = importlib.util.spec_from_file_location(f"vdbejax_plugin_{path.stem}", path)
    if spec is None or not path.is_file():
        raise FileNotFoundError(f"no file {str(path)!r}")
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    assert spec.loader is not None  # a .py path gets a source loader
    spec.loader.exec_module(module)
    return module


def load_plugins(plugins: Sequence[str]) -> None:
    """Import files (``path/to/file.py``) or modules that register plug-ins.

    Raises:
      ValueError: a file or module that cannot be imported.
    """
    for plugin in plugins:
        try:
            if str(plugin).endswith(".py"):
                _import_file(Path(plugin))
            else:
                importlib.import_module(plugin)
        except ValueError:
            raise
        except SystemExit as stop:  # a script's exit: not a way to end the run
            raise ValueError(f"plugin={plugin!r} is invalid: it called sys.exit({stop.code!r})"
                             " while being imported (a plug-in file only defines and"
                             " registers its classes)") from None
        except Exception as error:
            raise ValueError(f"plugin={plugin!r} is invalid: cannot import it"
                             f" ({type(error).__name__}: {error})") from None


def _user_task(task: str) -> TabularMDP:
    """``module:function`` or ``file.py:function``: the function's MDP (called without
    arguments)."""
    where, _, name = task.rpartition(":")
    try:
        module = (_import_file(Path(where)) if where.endswith(".py")
                  else importlib.import_module(where))
        function = getattr(module, name)
        mdp = function()
    except ValueError:
        raise
    except (Exception, SystemExit) as error:  # sys.exit() in the task's file too
        raise ValueError(f"task={task!r} is invalid: cannot build it"
                         f" ({type(error).__name__}: {error})") from None
    if not isinstance(mdp, TabularMDP):
        raise ValueError(f"task={task!r} is invalid: {name}() returned"
                         f" {type(mdp).__name__}, must return a TabularMDP"
                         " (vdbejax.envs.make_tabular_mdp)")
    return mdp


def is_user_task(task: str) -> bool:
    """Whether ``task`` names a user's function (``module:function``, ``file.py:function``)."""
    where, colon, name = task.rpartition(":")
    return bool(colon and where and not task.startswith("gym:") and name.isidentifier()
                and (where.endswith(".py") or all(p.isidentifier() for p in where.split("."))))


def make_task(task: str, *, max_steps: int | None = None,
              invalid_action: str = "noop") -> TabularMDP:
    """A task by name.

    Args:
      task: a name of the task suite (:func:`vdbejax.envs.suite.make_suite_task`:
        ``table_cleaning`` (the paper's text), ``cruz2018`` (the first author's published
        table), ``variant:NxK``, ``riverswim``, ``chain:N``, ``deepsea:N``,
        ``cliff_walking``, ``frozenlake4``, …); ``gym:<id>``, a gymnasium toy-text
        environment (:func:`vdbejax.envs.gymnasium_adapter.from_gymnasium`; the ``gym`` extra); or
        ``module:function`` / ``path/to/file.py:function``, a function of no arguments that
        returns a :class:`~vdbejax.envs.TabularMDP`.
      max_steps: truncation length (default: the task's horizon; the table-cleaning
        tasks: 100; ``cruz2018``: its safety cap; ``gym:``: its time limit; a function's
        MDP: its own).
      invalid_action: ``noop`` or ``fail`` (the table-cleaning tasks of the paper's text).

    Raises:
      ValueError: an unknown name, a task that cannot be built, or a bad option, in one
        line naming ``task``.
    """
    from vdbejax.envs.suite import make_suite_task

    if not isinstance(task, str):
        raise ValueError(f"task={task!r} is invalid: must be a task name (a string)")
    if max_steps is not None:
        check_int("max_steps", max_steps, 1, INT32_MAX)
    if (task.startswith("gym:") or is_user_task(task)) and invalid_action != "noop":
        raise ValueError(f"invalid_action={invalid_action!r} is invalid with task={task!r}:"
                         " only table_cleaning and variant:NxK have invalid actions")
    try:
        if task.startswith("gym:"):
            from vdbejax.envs.gymnasium_adapter import from_gymnasium

            return from_gymnasium(task[len("gym:"):], max_steps=max_steps, name=task)
        if is_user_task(task):
            mdp = _user_task(task)
            if max_steps is None:
                return mdp
            return dataclasses.replace(mdp, max_steps=jax.device_put(np.int32(max_steps)))
        return make_suite_task(task, max_steps=max_steps, invalid_action=invalid_action)
    except ImportError:  # gymnasium missing: the extra to install, said once, in one line
        raise ValueError(f"task={task!r} needs gymnasium: pip install 'vdbejax[gym]'"
                         ) from None
    except ValueError as error:  # named as the sweep names it
        text = str(error).replace(f"name={task!r}", f"task={task!r}", 1)
        if task.startswith("gym:"):
            text = text.replace(f"env={task[len('gym:'):]!r}", f"task={task!r}", 1)
        raise ValueError(text) from None
    except Exception as error:  # gymnasium's own errors: an unknown id, …
        raise ValueError(f"task={task!r} is invalid: cannot build it"
                         f" ({type(error).__name__}: {error})") from None
