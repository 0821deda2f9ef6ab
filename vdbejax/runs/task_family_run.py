"""A run on a task family (:class:`~vdbejax.envs.task_instances.TaskFamily`) in place of a
task: every agent meets the instance its seed and its setting's task values draw.

Agent (config ``c``, seed index ``i``) of root seed ``seed`` meets the family's instance
``generate((seed, i))`` under config ``c``'s task values (its ``task.`` hyperparameters,
the family's defaults for the rest; an ``instance`` seed ``k`` gives it ``generate((k,))``
instead): configs with the same task values meet the same instances (common random
numbers, like their keys), so results depend only on the seed and the hyperparameters,
and a resumed or reloaded run finds the same instances. The instances' tables and every
config's resolved task values enter the fingerprint. Each instance's exact best return
and the uniformly random policy's are kept in ``meta.json`` (``instance_best_returns``,
``instance_random_returns``: per seed index, or per config and seed index where the
configs' task values differ); ``best_return`` and ``random_return`` are their means, and
the summaries score every agent against its own instance's
(:func:`~vdbejax.results.analysis.task_scale`).
"""
from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from vdbejax.envs.solvers import best_return, uniform_random_return
from vdbejax.envs.tabular import TabularMDP
from vdbejax.envs.task_instances import INSTANCE, TaskFamily, TaskInstances
from vdbejax.methods.agents import TASK_PREFIX, Setting
from vdbejax.runs.batching import check_run_size, instances_host_bytes
from vdbejax.runs.optimal_record import optimal_action_mask
from vdbejax.runs.options import RunOptions


def draw_instances(task: TabularMDP | TaskFamily, run: RunOptions, seed: int, num_seeds: int,
                   settings: Sequence[Setting], num_episodes: int
                   ) -> tuple[TabularMDP, TaskInstances | None, list[dict[str, Any]] | None]:
    """The task that shapes a run (a family's: agent 0's instance), its agents' instances
    (config-major; ``None`` on a plain task) and each config's resolved task values, after
    refusing in one line what such a run does not do and instances that do not fit the
    host.

    Raises:
      ValueError: task values on a plain task, a task value the family does not have,
        or with a family policy evaluations (``evaluate_every``) or a stop policy that
        checks chunks (their references are one task's); instances that, with the run's
        settings and results, need more host memory than is free
        (:func:`~vdbejax.runs.batching.check_run_size`).
    """
    if isinstance(task, TabularMDP):
        named = next((s for s in settings if s.task_values), None)
        if named is not None:
            name = TASK_PREFIX + next(iter(named.task_values))
            raise ValueError(f"hyperparameter {name!r} is invalid for task {task.name}: task"
                             " parameters need a task family with a generator (testbed:N,"
                             " gaussian_bandit:N, …; vdbejax.envs.task_instances.TaskFamily)")
        return task, None, None
    values = [task.resolve(s.task_values) for s in settings]
    if run.evaluate_every is not None:
        raise ValueError(f"evaluate_every={run.evaluate_every} is invalid with a task family"
                         f" ({task.name}): policy evaluations need one shared task")
    if run.stop.checks_chunks:
        raise ValueError(f"stop={type(run.stop).__name__} is invalid with a task family"
                         f" ({task.name}): only a fixed budget (FixedBudget) runs it")
    num_agents = num_seeds * len(settings)
    first = task.draw((int(seed), 0), values[0])  # sizes them all: they share shapes
    check_run_size(num_agents, num_episodes, num_settings=len(settings),
                   task_bytes=instances_host_bytes(first, num_agents, run.record_optimal))
    instances = task.instances(seed, num_seeds, values)
    return instances.instance(0), instances, values


def instance_mode(values: Sequence[dict[str, Any]]) -> str:
    """``per-agent`` where a config's agents meet instances of their own, else
    ``shared`` (each config one instance)."""
    return "per-agent" if any(v[INSTANCE] is None for v in values) else "shared"


def _groups(values: Sequence[dict[str, Any]]) -> tuple[list[int], list[int]]:
    """Each config's group of equal task values, and each group's first config."""
    index: dict[tuple, int] = {}
    groups = [index.setdefault(tuple(sorted(v.items())), len(index)) for v in values]
    first = [groups.index(g) for g in range(len(index))]
    return groups, first


def instance_meta(instances: TaskInstances, num_seeds: int,
                  values: Sequence[dict[str, Any]]) -> dict[str, Any]:
    """``meta.json``'s references of a run's instances: each instance's exact best return
    and random policy's return, per seed index (a list per config where the configs' task
    values differ) and their means as ``best_return`` and ``random_return``."""
    groups, first = _groups(values)
    best, baseline = [], []
    for c in first:
        mdps = [instances.instance(c * num_seeds + i) for i in range(num_seeds)]
        best.append([best_return(mdp) for mdp in mdps])
        baseline.append([uniform_random_return(mdp) for mdp in mdps])
    per_config = len(first) > 1
    return {"instance_best_returns": [best[g] for g in groups] if per_config else best[0],
            "instance_random_returns": ([baseline[g] for g in groups] if per_config
                                        else baseline[0]),
            "best_return": float(np.mean([best[g] for g in groups])),
            "random_return": float(np.mean([baseline[g] for g in groups]))}


def run_task(mdp: TabularMDP, instances: TaskInstances | None, rows: np.ndarray
             ) -> TabularMDP | TaskInstances:
    """What the engine runs agents ``rows`` on: the shared task, or their instances."""
    return mdp if instances is None else instances.take(rows)


def run_mask(mdp: TabularMDP, instances: TaskInstances | None,
             values: Sequence[dict[str, Any]] | None, num_seeds: int,
             rows: np.ndarray) -> np.ndarray:
    """The optimal actions a run records against
    (:func:`~vdbejax.runs.optimal_record.optimal_action_mask`): bool ``[S, A]`` of the
    shared task, or ``[rows, S, A]``, each agent's in its own instance (computed once per
    seed index and task values)."""
    if instances is None or values is None:
        return optimal_action_mask(mdp)
    groups, first = _groups(values)
    masks = [np.stack([optimal_action_mask(instances.instance(c * num_seeds + i))
                       for i in range(num_seeds)]) for c in first]
    return np.concatenate([masks[g] for g in groups])[rows]
