"""Shared table builders of the suite: dense ``[S, A, S']`` models to outcome tables."""
from __future__ import annotations

from typing import Any

import numpy as np

from vdbejax.envs.tabular import TabularMDP, make_tabular_mdp


def outcome_tables(probability: Any, reward: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(next_state, probability, reward)`` ``[S, A, K]`` of a dense model.

    Each pair lists its next states of positive probability in increasing order; ``K`` is
    the most any pair has, and shorter lists are padded with probability-0 outcomes that
    stay in ``s`` with reward 0.

    Args:
      probability: ``[S, A, S']`` transition probabilities.
      reward: ``[S, A, S']`` reward of each transition, or ``[S, A]`` (one per pair).

    Returns:
      the three ``[S, A, K]`` arrays (int64, float64, float64).
    """
    probability = np.asarray(probability, np.float64)
    reward = np.asarray(reward, np.float64)
    if reward.ndim == 2:
        reward = np.broadcast_to(reward[..., None], probability.shape)
    positive = probability > 0
    width = int(positive.sum(-1).max())
    # a stable sort of "not positive" puts the positive next states first, in order
    order = np.argsort(~positive, axis=-1, kind="stable")[..., :width]
    kept = np.take_along_axis(positive, order, -1)
    states = np.arange(probability.shape[0])[:, None, None]
    next_state = np.where(kept, order, states)
    outcome_probability = np.where(kept, np.take_along_axis(probability, order, -1), 0.0)
    outcome_reward = np.where(kept, np.take_along_axis(reward, order, -1), 0.0)
    return next_state, outcome_probability, outcome_reward


def dense_mdp(probability: Any, reward: Any, start_probability: Any, *, max_steps: int,
              name: str) -> TabularMDP:
    """A continuing task (no terminal transition) from a dense ``[S, A, S']`` model.

    Args:
      probability: ``[S, A, S']`` transition probabilities.
      reward: ``[S, A, S']`` or ``[S, A]`` rewards.
      start_probability: ``[S]`` start distribution.
      max_steps: the episode horizon (every episode is truncated there).
      name: the MDP's label.

    Returns:
      the validated MDP.
    """
    next_state, outcome_probability, outcome_reward = outcome_tables(probability, reward)
    return make_tabular_mdp(next_state, outcome_reward, np.zeros(next_state.shape, bool),
                            start_probability, outcome_probability, max_steps=max_steps,
                            name=name)
