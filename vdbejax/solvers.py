"""Exact reference solutions of a :class:`~vdbejax.envs.TabularMDP` (numpy).

Used for the best-possible-return reference lines, and to check learned policies.
"""
from __future__ import annotations

from collections import deque

import numpy as np

from vdbejax.envs.tabular import TabularMDP


def _tables(mdp: TabularMDP) -> tuple[np.ndarray, ...]:
    return (
        np.asarray(mdp.next_state),
        np.asarray(mdp.probability, np.float64),
        np.asarray(mdp.reward, np.float64),
        np.asarray(mdp.terminal),
    )


def start_states(mdp: TabularMDP) -> np.ndarray:
    """Indices of states with positive start probability."""
    return np.flatnonzero(np.asarray(mdp.start_probability) > 0)


def reachable_states(mdp: TabularMDP) -> np.ndarray:
    """Sorted indices of the non-terminal states reachable from the start states.

    A state counts as reachable when some transition with positive probability leads to it
    without the episode ending on arrival.
    """
    next_state, prob, _, terminal = _tables(mdp)
    seen = np.zeros(mdp.num_states, bool)
    queue = deque(start_states(mdp).tolist())
    seen[list(queue)] = True
    while queue:
        s = queue.popleft()
        live = (prob[s] > 0) & ~terminal[s]
        for nxt in np.unique(next_state[s][live]):
            if not seen[nxt]:
                seen[nxt] = True
                queue.append(int(nxt))
    return np.flatnonzero(seen)


def optimal_values(mdp: TabularMDP, gamma: float = 1.0, horizon: int | None = None) -> np.ndarray:
    """Optimal finite-horizon state values ``V*_h(s)`` (expected return of ≤ h steps).

    With ``gamma = 1`` and ``horizon = max_steps`` this is the best achievable episode
    return (undiscounted, as the paper plots) from each state.

    Args:
      mdp: the MDP.
      gamma: discount.
      horizon: number of remaining steps (default ``mdp.max_steps``).

    Returns:
      float64 ``[S]`` values.
    """
    return optimal_q_values(mdp, gamma, horizon).max(axis=1)


def optimal_q_values(
    mdp: TabularMDP, gamma: float = 0.9, horizon: int | None = None, tol: float = 1e-12
) -> np.ndarray:
    """Optimal action values by value iteration.

    Args:
      mdp: the MDP.
      gamma: discount.
      horizon: if given, exactly ``horizon`` backups (finite-horizon Q*); otherwise
        iterate to convergence (needs ``gamma < 1``, or a proper MDP).
      tol: convergence threshold of the infinite-horizon iteration.

    Returns:
      float64 ``[S, A]`` Q*.
    """
    next_state, prob, reward, terminal = _tables(mdp)
    if horizon is None and gamma >= 1.0:
        horizon = int(mdp.max_steps)
    q = np.zeros(next_state.shape[:2])
    iterations = horizon if horizon is not None else 100_000
    for _ in range(iterations):
        v = q.max(axis=1)
        new_q = (prob * (reward + gamma * np.where(terminal, 0.0, v[next_state]))).sum(-1)
        done = horizon is None and np.abs(new_q - q).max() < tol
        q = new_q
        if done:
            break
    return q


def best_return(mdp: TabularMDP) -> float:
    """Best expected undiscounted episode return from the start distribution."""
    v = optimal_values(mdp, gamma=1.0)
    return float(np.asarray(mdp.start_probability, np.float64) @ v)


def shortest_solution(mdp: TabularMDP, start: int) -> list[int]:
    """Shortest action sequence from ``start`` to a terminal transition with positive reward.

    Breadth-first search over deterministic outcomes (the first outcome of each pair).

    Returns:
      the actions, or an empty list if no goal is reachable.
    """
    next_state, _, reward, terminal = _tables(mdp)
    parent: dict[int, tuple[int, int]] = {start: (-1, -1)}
    queue = deque([start])
    while queue:
        s = queue.popleft()
        for a in range(mdp.num_actions):
            if terminal[s, a, 0] and reward[s, a, 0] > 0:
                path = [a]
                while parent[s][0] >= 0:
                    s, prev_a = parent[s]
                    path.append(prev_a)
                return path[::-1]
            nxt = int(next_state[s, a, 0])
            if not terminal[s, a, 0] and nxt not in parent:
                parent[nxt] = (s, a)
                queue.append(nxt)
    return []
