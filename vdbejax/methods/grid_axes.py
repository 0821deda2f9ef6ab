"""The settings of a sweep: a product of hyperparameter axes over learners × explorers.

:func:`sweep` builds them (each axis applied to the pairs that have its field),
:func:`setting_of` states one setting's explorer parameter (its class default where none
is given), :func:`sweep_size` counts them before any is made, and :data:`MAX_SETTINGS`
bounds a grid.
"""
from __future__ import annotations

import dataclasses
import itertools
import math
from collections.abc import Mapping, Sequence
from typing import Any

from vdbejax.methods.agents import Setting, owners
from vdbejax.methods.explorers import explorer_class


def setting_of(learner: str, explorer: str, values: Mapping[str, Any]) -> Setting:
    """The :class:`Setting` of ``values`` (the explorer's swept parameter among them, by
    name): where they do not set that parameter, its class default is stated as ``param``,
    so that the label and ``configs.csv`` show the value that runs.

    Raises:
      ValueError: an unknown explorer.
    """
    cls: Any = explorer_class(explorer)  # a dataclass (the registry's classes are)
    values = dict(values)
    if not cls.parameter:
        return Setting(learner, explorer, None, values)
    param = values.pop(cls.parameter, None)
    if param is None:
        param = next((f.default for f in dataclasses.fields(cls) if f.name == cls.parameter
                      and f.default is not dataclasses.MISSING), None)
    return Setting(learner, explorer, param, values)


def _same(a: Any, b: Any) -> bool:
    numbers = (int, float)
    if isinstance(a, numbers) and isinstance(b, numbers) and not isinstance(a, bool) \
            and not isinstance(b, bool):
        return float(a) == float(b)
    return bool(a == b)


def setting_matches(setting: Setting, rule: Mapping[str, Any]) -> bool:
    """Whether every key of ``rule`` matches ``setting``: ``learner``, ``explorer``, or one
    of its explicit values (:attr:`Setting.values`, the swept parameter by its name; numbers
    compare as numbers) — how a sweep file's exclusions and claims select settings."""
    values = setting.values
    for key, value in rule.items():
        if key in ("learner", "explorer"):
            if getattr(setting, key) != value:
                return False
        elif key not in values or not _same(values[key], value):
            return False
    return True


#: Most settings one grid holds (:func:`sweep`): each costs host memory before training
#: (its agent, label and summary row: :data:`vdbejax.runs.batching.SETTING_BYTES`, checked
#: against the machine's memory before any is made), and a grid's config index is int32
#: in the engine.
MAX_SETTINGS = 1_000_000


def sweep_size(learners: Sequence[str], explorers: Sequence[str],
               axes: Mapping[str, Sequence[Any]] | None = None) -> int:
    """The number of settings :func:`sweep` makes of these names and axes, counted from
    the axes' sizes before any setting is made (so that a run can estimate and refuse a
    sweep too large for the machine first).

    Raises:
      ValueError: an empty list, an unknown explorer, or more than :data:`MAX_SETTINGS`.
    """
    axes = dict(axes or {})
    for name, values in (("learners", learners), ("explorers", explorers)):
        if isinstance(values, str) or not values:
            raise ValueError(f"{name}={values!r} is invalid: must be a non-empty list of names")
    for name, values in axes.items():
        if isinstance(values, (str, bytes)) or not isinstance(values, Sequence) or not values:
            raise ValueError(f"axis {name}={values!r} is invalid: must be a non-empty list"
                             " of values")
    for explorer in explorers:
        explorer_class(explorer)  # an unknown name: its one-line error before any other
    count = sum(math.prod(len(axes[name]) for name in axes if owners(name, learner, explorer))
                for learner in learners for explorer in explorers)
    if count > MAX_SETTINGS:  # counted before any is made: 10⁸ would take minutes and GBs
        sizes = ", ".join(f"{name} ({len(values)})" for name, values in axes.items())
        raise ValueError(f"the sweep is too large: {len(learners)} learners × {len(explorers)}"
                         f" explorers × the axes {sizes} make {count:,} settings, more than"
                         f" the {MAX_SETTINGS:,} one grid holds: split it into several runs")
    return count


def sweep(learners: Sequence[str], explorers: Sequence[str],
          axes: Mapping[str, Sequence[Any]] | None = None,
          shared: Mapping[str, Any] | None = None) -> list[Setting]:
    """The settings of a product of axes: learners × explorers × every applicable axis.

    An axis applies to a learner × explorer pair when one of them has a field of that
    name (``learner.``/``explorer.`` prefixes allowed); the explorer's swept parameter
    becomes the settings' ``param`` (its class default where no axis or shared value sets
    it, so that the label and ``configs.csv`` state the value that runs). E.g.
    ``sweep(["qlearning", "sarsa"], ["vdbe"], {"alpha": [0.1, 0.3, 0.8], "sigma": [0.01, 1,
    100]})`` gives 2 × 3 × 3 = 18 settings.

    Args:
      learners: learner names.
      explorers: explorer names.
      axes: ``{hyperparameter: values}``.
      shared: ``{hyperparameter: value}`` for every setting that has the field.

    Returns:
      the settings, learner-major, then explorer, then the axes in the given order.

    Raises:
      ValueError: an empty list, an unknown name, or an axis or shared value that applies
        to no learner × explorer pair.
    """
    axes = dict(axes or {})
    shared = dict(shared or {})
    sweep_size(learners, explorers, axes)
    used: set[str] = set()
    settings = []
    for learner in learners:
        for explorer in explorers:
            mine = [name for name in axes if owners(name, learner, explorer)]
            fixed = {name: value for name, value in shared.items()
                     if owners(name, learner, explorer)}
            used.update(mine, fixed)
            for combination in itertools.product(*(axes[name] for name in mine)):
                chosen = dict(fixed, **dict(zip(mine, combination, strict=True)))
                settings.append(setting_of(learner, explorer, chosen))
    unused = [name for name in list(axes) + list(shared) if name not in used]
    if unused:
        raise ValueError(f"axis {unused[0]!r} is invalid: no learner in {list(learners)} or"
                         f" explorer in {list(explorers)} has that field")
    return settings


__all__ = ["MAX_SETTINGS", "setting_matches", "setting_of", "sweep", "sweep_size"]
