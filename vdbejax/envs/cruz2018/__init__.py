"""The table-cleaning task as the first author's published code defines it.

The table (``transitions.json``, copied as data from the public repository
``fcruzcl/CS2018``, commit e96087f, 2018-03-12, ``classes/Scenario.py``, author F. Cruz)
differs from the paper's text (:mod:`vdbejax.envs.table_cleaning`, ``docs/task.md``):

* 53 states, 7 actions (``get, drop, go_P0, go_P1, go_P2, clean, abort``; P0 is home),
  deterministic; every episode starts in state 0;
* next state −1 is a **failure**: reward −1, the episode ends; entering state 51 or 52 is
  the **goal**: reward +1, the episode ends; every other transition costs −0.01;
* ``abort`` returns to state 0 and the episode goes on; ``get`` and ``drop`` can fail;
* the published code has no step limit: :data:`STEP_CAP` is a safety cap (an episode
  that reaches it is cut off, as a truncation, and counted in the run's lengths).

The shortest solution takes 15 actions (best return 0.86); all 53 states are reachable.
"""
from __future__ import annotations

import json
from functools import lru_cache
from importlib import resources
from typing import Any

import numpy as np

from vdbejax.envs.tabular import TabularMDP, make_tabular_mdp

#: Episode length at which the authors' task is cut off (their code has no limit).
STEP_CAP = 10_000
ACTION_NAMES = ("get", "drop", "go_P0", "go_P1", "go_P2", "clean", "abort")


@lru_cache(maxsize=1)
def table() -> dict[str, Any]:
    """The published task table (``transitions.json``) as a dict."""
    return json.loads(resources.files(__package__).joinpath("transitions.json").read_text())


def make_authors_mdp(max_steps: int = STEP_CAP) -> TabularMDP:
    """The authors' task as a :class:`~vdbejax.envs.TabularMDP` (validated like any task).

    Failures and goal entries are terminal transitions (their next state is then the
    state itself or the goal state; a terminal step never bootstraps). Rows 51 and 52 are
    never acted in; they loop onto themselves, terminal, with reward 0.

    Args:
      max_steps: the safety cap on an episode's length (default :data:`STEP_CAP`).

    Returns:
      the MDP, named ``cruz2018``.
    """
    data = table()
    transitions = np.asarray(data["transitions"], np.int64)
    num_states, num_actions = transitions.shape
    goals = np.asarray(data["goal_states"])
    rewards = data["rewards"]
    states = np.arange(num_states)[:, None].repeat(num_actions, axis=1)
    failure = transitions == data["failure_next_state"]
    goal_rows = np.isin(states, goals)
    enters_goal = np.isin(transitions, goals) & ~goal_rows
    next_state = np.where(failure | goal_rows, states, transitions)
    reward = np.where(failure, rewards["failure"],
                      np.where(enters_goal, rewards["goal"], rewards["other"]))
    reward = np.where(goal_rows, 0.0, reward)
    terminal = failure | enters_goal | goal_rows
    start = np.zeros(num_states)
    start[data["start_state"]] = 1.0
    return make_tabular_mdp(next_state, reward, terminal, start, max_steps=max_steps,
                            name="cruz2018")


__all__ = ["ACTION_NAMES", "STEP_CAP", "make_authors_mdp", "table"]
