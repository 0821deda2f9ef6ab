"""The sweep file: what ``vdbejax run`` trains, as data (TOML or JSON).

Every key, with its default (``docs/sweeps.md`` is the user's page;
``examples/sweep.toml`` a file that runs)::

    task = "table_cleaning"   # a suite name ("riverswim", "chain:8", "variant:4x2", …),
                              # "gym:FrozenLake-v1", "module:function" or "file.py:function"
    learners = ["qlearning", "sarsa"]      # the product: learners × explorers × axes
    explorers = ["vdbe", "ucb1"]
    plugins = ["my_plugins.py"]            # files or modules that register plug-ins
    seeds = 20                             # agents per setting and replicate
    replicates = 1
    episodes = 1000
    seed = 0
    max_steps = 100                        # default: the task's own
    invalid_action = "noop"                # the table-cleaning tasks: "noop" or "fail"
    chunk_episodes = 100                   # episodes per compiled chunk (speed only; default:
                                           # ≥ 100 and 20,000 agent-episodes, ≤ 10,000)
    evaluate_every = 50                    # the greedy policies' exact values every 50
                                           # episodes (default: none; returns unchanged)
    record_optimal = true                  # each episode's fraction of optimal actions
                                           # (default: false; returns unchanged)
    instances = "per-agent"                # a family task (testbed:10, …): every agent its
                                           # own instance (default: "shared", one task)
    learner_defaults = "paper"             # the values no setting gives: "paper" (α 0.8,
                                           # γ 0.9) or "benchmark" (α 0.1, γ 1 − 1/H);
                                           # default: the paper's on its tasks, else the
                                           # benchmark's (docs/suite.md)

    [axes]                                 # every axis applies where a field has its name
    alpha = [0.1, 0.3, 0.8]
    sigma = [0.01, 1, 100]

    [shared]                               # one value for every setting with the field
    gamma = 0.9

    [[exclude]]                            # settings of the product left out: all keys match
    learner = "sarsa"
    alpha = 0.8

    [[settings]]                           # explicit settings, run after the product
    learner = "qlearning"
    explorer = "egreedy"
    epsilon = 0.05

    [[claims]]                             # what the study expects, scored after the run
    claim = "ε = 0.05 ends above 0.5"      # (vdbejax.results.claim_spec: claims.md,
    checks = [{setting = "qlearning/egreedy/epsilon=0.05", above = 0.5}]  # claims.csv)

Paths in a sweep file (``plugins`` files, a ``file.py:function`` task) are relative to the
sweep file's folder; paths given as command-line flags are relative to the working
directory. :func:`sweep_from_meta` gives back the sweep file of a finished run (``vdbejax
sweep-file RESULTS``), so that a result folder says how to rerun it.
"""
from __future__ import annotations

import json
import os
import tomllib
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

from vdbejax.methods.agents import Setting, owners
from vdbejax.methods.explorers import explorer_class
from vdbejax.methods.grid_axes import setting_matches, setting_of, sweep
from vdbejax.methods.learners import learner_class
from vdbejax.studies.task_names import is_user_task

#: Keys a sweep file may hold.
SWEEP_KEYS = ("task", "learners", "explorers", "axes", "shared", "exclude", "settings",
              "seeds", "episodes", "seed", "max_steps", "invalid_action", "chunk_episodes",
              "plugins", "replicates", "evaluate_every", "record_optimal", "instances",
              "learner_defaults", "claims")
#: The keys of a run's ``meta.json`` ``sweep`` record (the rest come from the run's meta).
SPEC_KEYS = ("learners", "explorers", "axes", "shared", "exclude", "settings", "plugins",
             "learner_defaults", "claims")


def _tables(entries: Any, key: str) -> list[dict[str, Any]]:
    if isinstance(entries, Mapping) or not isinstance(entries, Sequence) \
            or isinstance(entries, str):
        raise ValueError(f"{key}={entries!r} is invalid: must be a list of tables"
                         " {name: value}")
    for i, entry in enumerate(entries):
        if not isinstance(entry, Mapping) or not entry:
            raise ValueError(f"{key}[{i}]={entry!r} is invalid: must be a non-empty table"
                             " {name: value}")
    return [dict(entry) for entry in entries]


def _explicit(i: int, entry: dict[str, Any], shared: Mapping[str, Any]) -> Setting:
    """One ``[[settings]]`` entry as a :class:`Setting` (shared values where it has them)."""
    learner, explorer = entry.pop("learner", None), entry.pop("explorer", None)
    if not isinstance(learner, str) or not isinstance(explorer, str):
        raise ValueError(f"settings[{i}] is invalid: needs learner = \"…\" and"
                         " explorer = \"…\" (names)")
    learner_class(learner)  # an unknown name: the registry's one-line error
    explorer_class(explorer)
    for name in entry:
        if not owners(name, learner, explorer):
            raise ValueError(f"settings[{i}] is invalid: neither learner {learner!r} nor"
                             f" explorer {explorer!r} has a field {name!r}")
    values = {name: value for name, value in shared.items() if owners(name, learner, explorer)}
    values.update(entry)
    return setting_of(learner, explorer, values)


def sweep_settings(learners: Sequence[str] = (), explorers: Sequence[str] = (),
                   axes: Mapping[str, Sequence[Any]] | None = None,
                   shared: Mapping[str, Any] | None = None,
                   exclude: Sequence[Mapping[str, Any]] = (),
                   settings: Sequence[Mapping[str, Any]] = ()) -> list[Setting]:
    """The settings of a sweep: the product (:func:`~vdbejax.methods.sweep`) less its
    exclusions, then the explicit settings.

    Args:
      learners: learner names of the product (none: explicit settings only).
      explorers: explorer names of the product.
      axes: ``{hyperparameter: values}`` of the product.
      shared: ``{hyperparameter: value}`` for every setting (product or explicit) that has
        the field; an explicit setting's own value wins.
      exclude: tables ``{key: value}``; a setting of the product whose every key matches
        (``learner``, ``explorer`` or a value of its hyperparameters, as named in the
        axes) is left out. Each must leave out at least one setting.
      settings: tables ``{"learner": …, "explorer": …, field: value, …}``.

    Returns:
      the settings, the product's first (learner-major), in order.

    Raises:
      ValueError: an exclusion that matches nothing, an explicit setting with an unknown
        field or twice the same setting, a shared value no setting has, or no settings.
    """
    shared = dict(shared or {})
    product: list[Setting] = []
    if learners or explorers or axes:
        pairs = [(learner, explorer) for learner in learners for explorer in explorers]
        mine = {name: value for name, value in shared.items()
                if any(owners(name, *pair) for pair in pairs)}
        product = sweep(learners, explorers, axes, mine)
    for i, rule in enumerate(_tables(exclude, "exclude")):
        kept = [s for s in product if not setting_matches(s, rule)]
        if len(kept) == len(product):
            raise ValueError(f"exclude[{i}]={rule!r} is invalid: it matches no setting of the"
                             " product (keys: learner, explorer or an axis as named in axes)")
        product = kept
    explicit = [_explicit(i, entry, shared)
                for i, entry in enumerate(_tables(settings, "settings"))]
    unused = [name for name in shared
              if not any(owners(name, s.learner, s.explorer) for s in product + explicit)]
    if unused:
        raise ValueError(f"shared {unused[0]!r} is invalid: no setting of the sweep has that"
                         " field")
    every = product + explicit
    for i, setting in enumerate(explicit):
        if every.count(setting) > 1:
            raise ValueError(f"settings[{i}] is invalid: {setting.label} is already in the"
                             " sweep; give each setting once")
    if not every:
        raise ValueError("the sweep has no settings: give learners and explorers, or"
                         " settings = [...]")
    return every


def _names(value: Any) -> bool:
    return isinstance(value, list) and all(isinstance(v, str) for v in value)


def _scalar(value: Any) -> bool:
    return isinstance(value, (int, float, str, bool))


def _scalar_tables(value: Any) -> bool:
    return isinstance(value, list) and all(
        isinstance(x, dict) and x and all(map(_scalar, x.values())) for x in value)


#: The type of every sweep-file key: ``(check, what is allowed)``.
_KEY_TYPES: dict[str, tuple[Any, str]] = {
    "task": (lambda v: isinstance(v, str), "a task name (a string)"),
    "learners": (_names, "a list of names"),
    "explorers": (_names, "a list of names"),
    "plugins": (_names, "a list of files or module names"),
    "axes": (lambda v: isinstance(v, dict) and all(
        isinstance(x, list) and x and all(map(_scalar, x)) for x in v.values()),
        "a table {name: [values]} of non-empty lists of numbers or strings"),
    "shared": (lambda v: isinstance(v, dict) and all(map(_scalar, v.values())),
               "a table {name: value} of numbers or strings"),
    "exclude": (_scalar_tables, "a list of tables {name: value}"),
    "settings": (_scalar_tables, "a list of tables {learner: …, explorer: …, name: value}"),
    "invalid_action": (lambda v: isinstance(v, str), "noop or fail"),
    "record_optimal": (lambda v: isinstance(v, bool), "true or false"),
    "instances": (lambda v: v in ("shared", "per-agent"), "shared or per-agent"),
    "learner_defaults": (lambda v: v in ("benchmark", "paper"), "benchmark or paper"),
    "claims": (lambda v: isinstance(v, list) and all(isinstance(x, dict) for x in v),
               "a list of tables {claim = \"…\", checks = [...]} (docs/claims.md)"),
    **{key: (lambda v: isinstance(v, int) and not isinstance(v, bool), "an integer")
       for key in ("seeds", "episodes", "seed", "max_steps", "chunk_episodes", "replicates",
                   "evaluate_every")},
}


def check_sweep_keys(data: Mapping[str, Any], source: str) -> None:
    """Refuse unknown keys and keys of the wrong type, in one line naming the key.

    Raises:
      ValueError: the first unknown or mistyped key of ``data``.
    """
    unknown = sorted(set(data) - set(SWEEP_KEYS))
    if unknown:
        raise ValueError(f"{source} has unknown key {unknown[0]!r}: allowed are"
                         f" {', '.join(SWEEP_KEYS)}")
    for key in SWEEP_KEYS:
        if key in data and not _KEY_TYPES[key][0](data[key]):
            raise ValueError(f"{source}: {key}={data[key]!r} is invalid: must be"
                             f" {_KEY_TYPES[key][1]}")


def _resolve(path: str, folder: Path) -> str:
    return path if os.path.isabs(path) else str((folder / path).resolve())


def map_files(spec: Mapping[str, Any], path: Callable[[str], str]) -> dict[str, Any]:
    """``spec`` with ``path`` applied to every file it names: each ``.py`` of its
    ``plugins`` and the file of a ``file.py:function`` task (made absolute when read,
    relative to the written file when written back)."""
    spec = dict(spec)
    if "plugins" in spec:
        spec["plugins"] = [path(str(p)) if str(p).endswith(".py") else p
                           for p in spec["plugins"]]
    task = spec.get("task")
    if isinstance(task, str) and is_user_task(task) and task.rpartition(":")[0].endswith(".py"):
        where, _, name = task.rpartition(":")
        spec["task"] = f"{path(where)}:{name}"
    return spec


def absolute_files(spec: Mapping[str, Any], folder: str | os.PathLike = ".") -> dict[str, Any]:
    """``spec`` with the files it names made absolute from ``folder``."""
    return map_files(spec, lambda file: _resolve(file, Path(folder)))


def read_sweep_file(path: str | os.PathLike) -> dict[str, Any]:
    """The keys of a TOML (``.toml``) or JSON sweep file, or of a finished run's folder
    (its ``meta.json``, :func:`sweep_from_meta`); file paths in it made absolute from the
    file's folder.

    Raises:
      ValueError: unreadable, not a table/object, or an unknown key.
    """
    path = Path(path)
    if path.is_dir():
        meta_file = path / "meta.json"
        try:
            return sweep_from_meta(json.loads(meta_file.read_text()))
        except (OSError, ValueError) as error:
            raise ValueError(f"config={str(path)!r} is a folder without a run's meta.json:"
                             f" {error}") from None
    try:
        text = path.read_text()
        data = tomllib.loads(text) if path.suffix == ".toml" else json.loads(text)
    except (OSError, ValueError) as error:
        raise ValueError(f"sweep file {str(path)!r} is unreadable: {error}") from None
    if not isinstance(data, dict):
        raise ValueError(f"sweep file {str(path)!r} must hold a table of keys, not"
                         f" {type(data).__name__}")
    check_sweep_keys(data, f"sweep file {str(path)!r}")
    return absolute_files(data, path.resolve().parent)


def sweep_from_meta(meta: Mapping[str, Any]) -> dict[str, Any]:
    """The sweep file of a finished ``vdbejax run`` (from its ``meta.json``): training it
    again gives the same results.

    Raises:
      ValueError: the meta has no sweep record (not written by ``vdbejax run``).
    """
    record = meta.get("sweep")
    if not isinstance(record, Mapping) or "task" not in meta:
        raise ValueError("meta.json has no sweep record: only vdbejax run's result folders"
                         " can be rerun from their folder")
    spec: dict[str, Any] = {"task": meta["task"]}
    spec.update({key: record[key] for key in SPEC_KEYS if record.get(key)})
    # A run from before the rule ran with the paper's values: a rerun keeps them.
    spec["learner_defaults"] = record.get("learner_defaults") or "paper"
    replicates = int(meta.get("replicates", 1))
    spec.update(seeds=int(meta["num_seeds"]) // replicates, replicates=replicates,
                episodes=int(meta["num_episodes"]), seed=int(meta["seed"]),
                max_steps=int(meta["max_steps"]),
                invalid_action=meta.get("invalid_action", "noop"))
    if meta.get("evaluate_every") is not None:
        spec["evaluate_every"] = int(meta["evaluate_every"])
    if meta.get("record_optimal"):
        spec["record_optimal"] = True
    if meta.get("instances") == "per-agent":
        spec["instances"] = "per-agent"
    return spec


def read_claims_file(path: str | os.PathLike) -> list[Any]:
    """The ``claims`` of a TOML (``.toml``) or JSON file: a file of claims alone, or a
    sweep file (``vdbejax plot --claims``).

    Raises:
      ValueError: unreadable, or without a list of claims.
    """
    path = Path(path)
    try:
        text = path.read_text()
        data = tomllib.loads(text) if path.suffix == ".toml" else json.loads(text)
    except (OSError, ValueError) as error:
        raise ValueError(f"claims file {str(path)!r} is unreadable: {error}") from None
    claims = data.get("claims") if isinstance(data, dict) else None
    if not isinstance(claims, list) or not claims:
        raise ValueError(f"claims={str(path)!r} is invalid: the file must hold claims = [...]"
                         " ([[claims]] tables in TOML)")
    return claims


def write_sweep_file(spec: Mapping[str, Any], path: str | os.PathLike) -> Path:
    """Write a sweep file as JSON (a sweep file ``vdbejax run --config`` reads), its
    plug-in files relative to the file's folder.

    Raises:
      ValueError: a name that is not ``.json``.
    """
    path = Path(path)
    if path.suffix != ".json":
        raise ValueError(f"out={str(path)!r} is invalid: the sweep file is written as JSON,"
                         " name it *.json")
    folder = path.resolve().parent
    spec = map_files(spec, lambda file: os.path.relpath(file, folder) if os.path.isabs(file)
                     else file)
    path.write_text(json.dumps(spec, indent=2) + "\n")
    return path
