"""The ``vdbejax scale`` study's definition: its methods, learners, sizes and budgets.

:data:`METHODS` (each a :class:`Method`: an explorer at one parameter value, with where the
value comes from), :data:`LEARNERS`, the family of variants :data:`SIZES` (``NxK``:
:func:`parse_sizes`), the study's size (:class:`ScalingSize`; ``--quick``'s is
:data:`QUICK`) and the episode budget per variant (:func:`variant_budget`,
:func:`auto_chunk`). :func:`~vdbejax.studies.scaling.run_scaling` runs it
(:mod:`vdbejax.studies.scaling`); every name here is also importable from there.
"""
from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from vdbejax.methods.agents import Setting
from vdbejax.results.summary import SummaryRow, summary_rows


@dataclasses.dataclass(frozen=True)
class Method:
    """One exploration method of the study, at one parameter value.

    Attributes:
      explorer: the registered explorer name.
      param: its swept parameter (ε, τ, σ, c, β).
      hyperparameters: other explorer fields (``{"decay": 0.99}``).
      why: where the value comes from (docs/SCALING.md).
    """

    explorer: str
    param: float | None
    hyperparameters: tuple = ()
    why: str = ""

    def setting(self, learner: str) -> Setting:
        """The method with ``learner``."""
        return Setting(learner, self.explorer, self.param, dict(self.hyperparameters))


#: The methods of the study. The paper's four at the value that does best on the paper's
#: grid (textbook reading, 20 agents × 1000 episodes, ``docs/ablation/spec/summary.csv``):
#: the highest final return averaged over both learners — :func:`best_parameters` applied
#: to that file gives exactly these (tested). The others at the value that does best on the
#: paper's task by the same rule among three candidates (docs/SCALING.md: the candidates,
#: the commands, and the one value a 20-agent check would change).
METHODS: tuple[Method, ...] = (
    Method("egreedy", 0.01, why="paper grid: best ε of {0.01, …, 0.2}"),
    Method("softmax", 0.0001, why="paper grid: best τ of {0.0001, …, 10}"),
    Method("vdbe", 100.0, why="paper grid: best σ of {0.001, …, 100}"),
    Method("vdbe_softmax", 100.0,
           why="paper grid: best σ of {0.001, …, 100} (τ = 0.001, the spec's)"),
    Method("ucb1", 0.001, why="paper task: best c of {0.001, 0.01, 0.1}"),
    Method("count_bonus", 0.005,
           why="paper task: best β of {0.005, 0.05, 0.5}"),
    Method("max_boltzmann", 0.01, why="paper task: best ε of {0.01, 0.1, 0.3} (τ = 0.1)"),
    Method("egreedy_decay", 1.0, (("decay", 0.99),),
           why="paper task, 5-agent pilot: best decay of {0.99, 0.995, 0.999} (ε from 1 to"
               " 0.01); 20 agents prefer 0.995 by SARSA's failing runs (docs/SCALING.md)"),
)
#: The paper's explorers (their values come from the paper's grid).
PAPER_METHODS = ("egreedy", "softmax", "vdbe", "vdbe_softmax")
LEARNERS = ("qlearning", "sarsa")
#: The full-size family of variants (N sections × K goblets), in order of size.
SIZES = ("2x1", "3x1", "4x1", "4x2", "5x2", "6x2", "6x3")
#: Default budget: ``max(EPISODES, EPISODES_PER_STATE × reachable states)`` per variant.
EPISODES = 2000
EPISODES_PER_STATE = 3.0
#: Agents per setting by default.
SEEDS = 10


@dataclasses.dataclass(frozen=True)
class ScalingSize:
    """The study's size: which variants, how many agents, how many episodes each.

    Attributes:
      sizes: variants ``NxK`` (``"2x1,4x2"`` or a sequence; :func:`parse_sizes`).
      seeds: agents per setting.
      episodes: episode budget per agent and variant; with ``episodes_per_state`` the
        smallest one (:func:`variant_budget`).
      episodes_per_state: budget per reachable state (None: ``episodes`` everywhere).
    """

    sizes: str | Sequence[str] = SIZES
    seeds: int = SEEDS
    episodes: int = EPISODES
    episodes_per_state: float | None = EPISODES_PER_STATE


#: ``--quick``: two small variants, few agents and episodes (seconds).
QUICK = ScalingSize(sizes=("2x1", "3x1"), seeds=3, episodes=1000, episodes_per_state=None)


def best_parameters(rows: Sequence[SummaryRow | Mapping[str, Any]]) -> dict[str, float]:
    """Per explorer, the parameter whose final return averaged over the learners is highest
    (the first in ``rows`` on an exact tie).

    Args:
      rows: summary rows (:class:`~vdbejax.results.summary.SummaryRow`, or ``summary.csv``'s rows
        as strings or numbers: :func:`~vdbejax.results.summary.summary_rows`).

    Returns:
      ``{explorer: param}``.

    Raises:
      ValueError: a row that is no summary row, or one of an explorer's default (no
        parameter).
    """
    table: dict[str, dict[float, list[float]]] = {}
    for row in summary_rows(rows):
        table.setdefault(row.explorer, {}).setdefault(row.swept_param(), []).append(
            row.final_return)
    return {explorer: max(by_param, key=lambda p: float(np.mean(by_param[p])))
            for explorer, by_param in table.items()}


def parse_sizes(sizes: str | Sequence[str]) -> list[tuple[int, int]]:
    """``"2x1,3x1"`` or ``["2x1", "3x1"]`` → ``[(2, 1), (3, 1)]`` (N ≥ 2 sections, K ≥ 1
    goblets).

    Raises:
      ValueError: empty, malformed or repeated sizes.
    """
    items = [s for s in (sizes.split(",") if isinstance(sizes, str) else list(sizes)) if str(s)]
    if not items:
        raise ValueError(f"sizes={sizes!r} is invalid: must name at least one variant,"
                         " e.g. 2x1,4x2")
    parsed = []
    for item in items:
        sections, sep, goblets = str(item).strip().lower().partition("x")
        if not (sep and sections.isdigit() and goblets.isdigit()
                and int(sections) >= 2 and int(goblets) >= 1):
            raise ValueError(f"sizes has {item!r}: each size must be NxK with N >= 2 sections"
                             " and K >= 1 goblets, e.g. 4x2")
        if (int(sections), int(goblets)) in parsed:
            raise ValueError(f"sizes has {item!r} twice")
        parsed.append((int(sections), int(goblets)))
    return parsed


def select_methods(names: Sequence[str] | None) -> list[Method]:
    """The methods of :data:`METHODS` named (default: all), in that order.

    Raises:
      ValueError: an unknown or repeated name.
    """
    if names is None:
        return list(METHODS)
    known = {m.explorer: m for m in METHODS}
    names = [n for n in names if n]
    if not names:
        raise ValueError("methods is empty: name at least one of " + ", ".join(known))
    for name in names:
        if name not in known:
            raise ValueError(f"methods has {name!r}: must be among {', '.join(known)}")
    if len(set(names)) != len(names):
        raise ValueError(f"methods={list(names)!r} is invalid: a method is named twice")
    return [known[n] for n in names]


def study_settings(methods: Sequence[Method] = METHODS,
                   learners: Sequence[str] = LEARNERS) -> list[Setting]:
    """The study's settings: learner-major, then the methods in order."""
    return [m.setting(learner) for learner in learners for m in methods]


def variant_budget(states: int, episodes: int, episodes_per_state: float | None) -> int:
    """A variant's episode budget: ``episodes``, or ``max(episodes, ⌈episodes_per_state ×
    states⌉)`` rounded up to a multiple of 100 (episodes to solve grow with the states)."""
    if episodes_per_state is None:
        return int(episodes)
    return max(int(episodes), -(-math.ceil(episodes_per_state * states) // 100) * 100)


def auto_chunk(episodes: int) -> int:
    """Episodes between stop checks for a budget: ``max(100, ⌈budget / 100⌉)``. Each check
    copies the remaining agents' state to the host, so checks are worth spacing out on
    long runs, while the extra episodes a solved agent runs stay within 1 % of the budget."""
    return max(100, -(-int(episodes) // 100))


__all__ = [
    "EPISODES",
    "EPISODES_PER_STATE",
    "LEARNERS",
    "METHODS",
    "PAPER_METHODS",
    "QUICK",
    "SEEDS",
    "SIZES",
    "Method",
    "ScalingSize",
    "auto_chunk",
    "best_parameters",
    "parse_sizes",
    "select_methods",
    "study_settings",
    "variant_budget",
]
