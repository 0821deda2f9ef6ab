"""The record of optimal actions: per episode, the fraction of its steps whose action is
optimal (``RunOptions(record_optimal=True)``, ``--record-optimal``).

An action is **optimal** in a state when it maximises the task's exact optimal action
value ``Q*(s, ·)`` — undiscounted, under the task's step limit, the optimum that
``best_return`` in ``meta.json`` is the value of (:func:`~vdbejax.envs.solvers.best_return`);
on a bandit, an arm of the largest mean. Actions within :data:`TIE_TOLERANCE` of the best
(relative) tie, and every tied action counts as optimal. The mask ``[S, A]`` is computed
once on the host and handed to the engine as data: each step gathers it at ``(s, a)``
and counts (:func:`vdbejax.engine.run_agents`'s ``optimal_action``); a run that does not
record traces the same programs as before, with the same bits.

``GridResult.optimal_actions`` holds each episode's count divided by its steps (NaN for
an episode not run), saved as ``optimal_actions`` in ``returns.npz``; Sutton & Barto's
"% optimal action" (2018, §2.3) is its mean over agents, × 100.
"""
from __future__ import annotations

import numpy as np

from vdbejax.engine.distributed import gather_agents
from vdbejax.envs.solvers import optimal_q_values
from vdbejax.envs.tabular import TabularMDP
from vdbejax.runs.run_state import RunState

#: Relative tolerance below the best ``Q*(s, ·)`` within which an action still counts as
#: optimal (rounding of the float64 value iteration; ties are then all optimal).
TIE_TOLERANCE = 1e-9


def optimal_action_mask(mdp: TabularMDP) -> np.ndarray:
    """bool ``[S, A]``: the actions maximising ``Q*(s, ·)`` (γ = 1, horizon the task's
    step limit, as :func:`~vdbejax.envs.solvers.best_return`), ties included."""
    q = optimal_q_values(mdp, gamma=1.0)
    best = q.max(axis=1, keepdims=True)
    return q >= best - TIE_TOLERANCE * np.maximum(1.0, np.abs(best))


def optimal_fractions(counts: np.ndarray, lengths: np.ndarray) -> np.ndarray:
    """float32 each episode's optimal steps over its steps (NaN where it has none: not run)."""
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(lengths > 0, counts / np.maximum(lengths, 1), np.nan).astype(np.float32)


def collect_optimal(state: RunState, shape: tuple[int, int, int]) -> np.ndarray | None:
    """A finished run's ``[configs, seeds, episodes]`` fractions of optimal actions (every
    process's agents gathered), or None for a run that did not record them."""
    if state.optimal is None:
        return None
    num_agents = shape[0] * shape[1]
    counts, lengths = (gather_agents(array, num_agents).reshape(shape)
                       for array in (state.optimal, state.lengths))
    return optimal_fractions(counts, lengths)
