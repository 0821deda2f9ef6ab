"""How often the agents act optimally, and the reward they earn per step: Sutton &
Barto's two measures of a bandit (2018, §2.3, Figure 2.2), for any task.

A run with ``record_optimal`` (:mod:`vdbejax.runs.optimal_record`) keeps, per episode,
the fraction of its steps whose action is optimal (``GridResult.optimal_actions``). Per
setting, over each agent's last ``last`` episodes:

* **optimal actions**: the agent's mean fraction of optimal actions, averaged over the
  agents with a 95 % bootstrap interval (× 100: "% optimal action");
* **reward per step**: the agent's return over those episodes divided by their steps,
  averaged over the agents with a 95 % bootstrap interval (on a one-pull bandit, the
  mean reward of a pull).

An agent stopped early by a stop policy counts with its last episodes before the stop.
"""
from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

from vdbejax.results.bootstrap import bootstrap_ci

if TYPE_CHECKING:
    from vdbejax.results.grid_result import GridResult

#: ``summary.csv``'s columns of a run that records optimal actions.
OPTIMAL_ACTION_COLUMNS = ["optimal_actions", "optimal_actions_ci_low", "optimal_actions_ci_high",
                          "reward_per_step", "reward_per_step_ci_low",
                          "reward_per_step_ci_high"]


def final_window(result: GridResult, last: int) -> np.ndarray:
    """bool ``[configs, seeds, episodes]``: each agent's last ``last`` episodes run."""
    ran = (np.full(result.returns.shape[:2], result.num_episodes)
           if result.episodes_run is None else result.episodes_run)
    episode = np.arange(result.num_episodes)
    return (episode < ran[..., None]) & (episode >= ran[..., None] - last)


def per_agent_measures(result: GridResult, last: int) -> tuple[np.ndarray, np.ndarray]:
    """float64 ``[configs, seeds]`` each agent's mean fraction of optimal actions and its
    reward per step over its last ``last`` episodes (NaN for an agent without any).

    Raises:
      ValueError: the result did not record optimal actions.
    """
    if result.optimal_actions is None:
        raise ValueError("this result has no record of optimal actions: run it with"
                         " record_optimal=True (CLI --record-optimal)")
    window = final_window(result, last)
    episodes = window.sum(-1)
    with np.errstate(invalid="ignore", divide="ignore"):
        optimal = np.where(window, result.optimal_actions, 0.0).sum(-1, dtype=np.float64) / episodes
        reward = (np.where(window, result.returns, 0.0).sum(-1, dtype=np.float64)
                  / np.where(window, result.lengths, 0).sum(-1))
    return np.where(episodes > 0, optimal, np.nan), np.where(episodes > 0, reward, np.nan)


def optimal_action_summary(result: GridResult, last: int) -> list[dict[str, Any]]:
    """Per setting, the columns :data:`OPTIMAL_ACTION_COLUMNS`: the mean over agents of
    their fraction of optimal actions and of their reward per step in their last ``last``
    episodes, each with its 95 % bootstrap interval over the agents (NaN where no agent
    ran an episode; agents with non-finite returns left out of the reward)."""
    optimal, reward = per_agent_measures(result, last)
    rows = []
    for c in range(len(result.settings)):
        row = dict.fromkeys(OPTIMAL_ACTION_COLUMNS, float("nan"))
        for name, values in (("optimal_actions", optimal[c]), ("reward_per_step", reward[c])):
            values = values[np.isfinite(values)]
            if values.size:
                low, high = bootstrap_ci(values) if values.size > 1 else (float(values[0]),) * 2
                row.update({name: float(values.mean()), f"{name}_ci_low": low,
                            f"{name}_ci_high": high})
        rows.append(row)
    return rows


def step_curves(result: GridResult, config: int) -> tuple[np.ndarray, np.ndarray]:
    """float64 ``[episodes]`` of one setting: the mean over its agents of each episode's
    fraction of optimal actions and of its reward per step (Sutton & Barto's two curves
    when an episode is one pull; NaN where no agent ran the episode)."""
    if result.optimal_actions is None:
        raise ValueError("this result has no record of optimal actions: run it with"
                         " record_optimal=True (CLI --record-optimal)")
    with np.errstate(invalid="ignore", divide="ignore"):
        ran = result.lengths[config] > 0
        count = ran.sum(0)
        optimal = np.where(ran, result.optimal_actions[config], 0.0).sum(0, dtype=np.float64)
        reward = np.where(ran, result.returns[config] / np.maximum(result.lengths[config], 1),
                          0.0).sum(0, dtype=np.float64)
        return (np.where(count > 0, optimal / count, np.nan),
                np.where(count > 0, reward / count, np.nan))
