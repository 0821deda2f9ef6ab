"""A run that gives every agent its own task instance (issue 48): a
:class:`~vdbejax.envs.instances.TaskFamily` in place of a task.

Agent (config ``c``, seed index ``i``) of root seed ``seed`` meets the family's instance
``generate((seed, i))``: the same instance for the same seed index in every config (common
random numbers, like its key), so results depend only on the seed and the
hyperparameters, and a resumed or reloaded run finds the same instances. The instances'
tables enter the fingerprint. Each instance's exact best return and the uniformly random
policy's are kept per seed index in ``meta.json`` (``instance_best_returns``,
``instance_random_returns``); ``best_return`` and ``random_return`` are their means,
and the summaries score every agent against its own instance's
(:func:`~vdbejax.results.analysis.task_scale`).
"""
from __future__ import annotations

from typing import Any

import numpy as np

from vdbejax.envs.instances import TaskFamily, TaskInstances
from vdbejax.envs.solvers import best_return, uniform_random_return
from vdbejax.envs.tabular import TabularMDP
from vdbejax.runs.batching import check_run_size, instances_host_bytes
from vdbejax.runs.optimal_actions import optimal_action_mask
from vdbejax.runs.options import RunOptions


def draw_instances(family: TaskFamily, run: RunOptions, seed: int, num_seeds: int,
                   num_configs: int, num_episodes: int) -> tuple[TabularMDP, TaskInstances]:
    """The instances of a run's agents (config-major) and the task that shapes the run
    (agent 0's instance), after refusing in one line what such a run does not do yet and
    a run whose stacked instances do not fit the host.

    Raises:
      ValueError: policy evaluations (``evaluate_every``) or a stop policy that checks
        chunks (their references are one task's); instances that, with the run's settings
        and results, need more host memory than is free
        (:func:`~vdbejax.runs.batching.check_run_size`).
    """
    if run.evaluate_every is not None:
        raise ValueError(f"evaluate_every={run.evaluate_every} is invalid with an instance per"
                         f" agent ({family.name}): policy evaluations need one shared task")
    if run.stop.checks_chunks:
        raise ValueError(f"stop={type(run.stop).__name__} is invalid with an instance per"
                         f" agent ({family.name}): only a fixed budget (FixedBudget) runs it")
    num_agents = num_seeds * num_configs
    first = family.generate((int(seed), 0))  # sizes them all: stacked, they share shapes
    check_run_size(num_agents, num_episodes, num_settings=num_configs,
                   task_bytes=instances_host_bytes(first, num_agents, run.record_optimal))
    instances = family.instances(seed, num_seeds, num_configs)
    return instances.instance(0), instances


def instance_meta(instances: TaskInstances, num_seeds: int) -> dict[str, Any]:
    """``meta.json``'s references of a run's instances: each seed index's exact best
    return and random policy's return (config-major agents: the first ``num_seeds`` rows
    are the seed indices), and their means as ``best_return`` and ``random_return``."""
    first = [instances.instance(i) for i in range(num_seeds)]
    best = [best_return(mdp) for mdp in first]
    baseline = [uniform_random_return(mdp) for mdp in first]
    return {"instances": "per-agent", "instance_best_returns": best,
            "instance_random_returns": baseline, "best_return": float(np.mean(best)),
            "random_return": float(np.mean(baseline))}


def run_task(mdp: TabularMDP, instances: TaskInstances | None, rows: np.ndarray
             ) -> TabularMDP | TaskInstances:
    """What the engine runs agents ``rows`` on: the shared task, or their instances."""
    return mdp if instances is None else instances.take(rows)


def run_mask(mdp: TabularMDP, instances: TaskInstances | None, num_seeds: int,
             rows: np.ndarray) -> np.ndarray:
    """The optimal actions a run records against
    (:func:`~vdbejax.runs.optimal_actions.optimal_action_mask`): bool ``[S, A]`` of the
    shared task, or ``[rows, S, A]``, each agent's in its own instance (computed once per
    seed index)."""
    if instances is None:
        return optimal_action_mask(mdp)
    masks = np.stack([optimal_action_mask(instances.instance(i)) for i in range(num_seeds)])
    return np.tile(masks, (instances.num_agents // num_seeds, 1, 1))[rows]
