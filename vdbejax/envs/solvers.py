"""Exact reference solutions of a :class:`~vdbejax.envs.TabularMDP` (vectorised numpy).

Used for the best-possible-return reference lines, and to check learned policies. Every
routine works on whole arrays (no Python loop over states), so MDPs of 10^5–10^6 states
(e.g. generated table-cleaning variants) solve in seconds.
"""
from __future__ import annotations

from typing import Any, NamedTuple

import numpy as np

from vdbejax.envs.tabular import TabularMDP


class _Tables(NamedTuple):
    next_state: np.ndarray  # int32 [S, A, K]
    probability: np.ndarray  # float64 [S, A, K]
    reward: np.ndarray  # float64 [S, A, K]
    terminal: np.ndarray  # bool [S, A, K]


def _tables(mdp: TabularMDP) -> _Tables:
    return _Tables(
        np.asarray(mdp.next_state),  # int32: half the memory of int64 indices
        np.asarray(mdp.probability, np.float64),
        np.asarray(mdp.reward, np.float64),
        np.asarray(mdp.terminal),
    )


def _first_outcomes(mdp: TabularMDP) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(next_state, live, goal)``, each ``[S, A]``, of the first outcome of every pair:
    the graph the breadth-first searches walk (``live``: the episode goes on; ``goal``: a
    terminal transition with positive reward). Reads the tables as stored (no float64 copy).
    """
    terminal = np.asarray(mdp.terminal)[..., 0]
    goal = terminal & (np.asarray(mdp.reward)[..., 0] > 0)
    return np.asarray(mdp.next_state)[..., 0], ~terminal, goal


def start_states(mdp: TabularMDP) -> np.ndarray:
    """Indices of states with positive start probability.

    Args:
      mdp: the MDP.

    Returns:
      int64 increasing state indices.
    """
    return np.flatnonzero(np.asarray(mdp.start_probability) > 0)


def reachable_states(mdp: TabularMDP) -> np.ndarray:
    """Sorted indices of the non-terminal states reachable from the start states.

    A state counts as reachable when it is a start state or some transition with positive
    probability leads to it without the episode ending on arrival.

    Args:
      mdp: the MDP.

    Returns:
      int64 increasing state indices.
    """
    next_state = np.asarray(mdp.next_state)
    live = (np.asarray(mdp.probability) > 0) & ~np.asarray(mdp.terminal)
    seen = np.zeros(mdp.num_states, bool)
    frontier = start_states(mdp)
    seen[frontier] = True
    while frontier.size:
        successors = next_state[frontier][live[frontier]]
        successors = np.unique(successors)
        frontier = successors[~seen[successors]]
        seen[frontier] = True
    return np.flatnonzero(seen)


def _backup_terms(tables: _Tables, gamma: float) -> tuple[np.ndarray, np.ndarray]:
    """``(expected reward [S, A], continuation weight [S, A, K])`` of a Bellman backup.

    ``Q(s, a) = expected_reward(s, a) + Σ_k weight(s, a, k) · V(next_state(s, a, k))``, with
    weight ``γ · p`` on non-terminal outcomes and 0 on terminal ones (no bootstrap).
    """
    expected_reward = (tables.probability * tables.reward).sum(-1)
    weight = np.where(tables.terminal, 0.0, gamma * tables.probability)
    return expected_reward, weight


def _iterate(
    mdp: TabularMDP,
    gamma: float,
    horizon: int | None,
    tol: float,
    policy: np.ndarray | None = None,
) -> np.ndarray:
    """Value iteration (``policy=None``) or policy evaluation (``policy``: int ``[S]``
    actions, or float ``[S, A]`` action probabilities); returns ``Q [S, A]``.

    With a ``horizon``: exactly ``horizon`` backups, stopping early once ``V`` is a fixed
    point (every further backup then gives the same ``Q``, so the result is exact), or
    once it grows by the same step twice with the maximising actions keeping the largest
    growth (:func:`_steady_growth`: every further backup then adds the same step, so the
    rest is that step times the backups left; an episode of 2·10⁹ steps with a reward at
    each costs two backups, not 2·10⁹). Otherwise: until the largest change of ``V`` is
    below ``tol``.
    """
    if horizon is not None and horizon < 1:
        return np.zeros((mdp.num_states, mdp.num_actions))
    tables = _tables(mdp)
    expected_reward, weight = _backup_terms(tables, gamma)
    next_state = tables.next_state
    del tables  # frees the float64 copies of probability and reward (GiBs at 10^7 states)
    deterministic = mdp.num_outcomes == 1
    if deterministic:  # skip the outcome axis: 2-D gathers are several times faster
        next_state, weight = next_state[..., 0], weight[..., 0]
    rows = np.arange(mdp.num_states)

    def value(q: np.ndarray) -> np.ndarray:
        if policy is None:
            return q.max(axis=1)
        if policy.ndim == 2:
            return (q * policy).sum(axis=1)
        return q[rows, policy]

    def growth(step: np.ndarray) -> np.ndarray:  # what a backup adds to Q given V's step
        grown = np.take(step, next_state) * weight
        return grown if deterministic else grown.sum(-1)

    q = expected_reward.copy()  # one backup from V = 0
    v = value(q)
    step = None  # V's last change
    buffer = np.empty_like(weight)
    iterations = horizon if horizon is not None else 100_000
    for done in range(2, iterations + 1):  # backups done after this one
        np.take(v, next_state, out=buffer)  # in place: no [S, A] temporaries
        buffer *= weight
        if not deterministic:
            q = buffer.sum(-1)
            q += expected_reward
        else:
            np.add(buffer, expected_reward, out=q)
        new_v = value(q)
        new_step = new_v - v
        change = np.abs(new_step).max()
        v = new_v
        if change == 0.0 or (horizon is None and change < tol):
            break
        if horizon is not None and step is not None and np.array_equal(new_step, step):
            q_step = growth(new_step)
            if (_steady_growth(q, v, q_step, new_step) if policy is None
                    else np.array_equal(value(q_step), new_step)):
                return q + (iterations - done) * q_step
        step = new_step
    return q


def _steady_growth(q: np.ndarray, v: np.ndarray, q_step: np.ndarray,
                   v_step: np.ndarray) -> bool:
    """Whether every further backup of value iteration adds ``q_step`` to ``q`` (and
    ``v_step`` to ``v = max q``): ``V`` grew by ``v_step`` in the last two backups, the next
    adds ``q_step`` (:func:`_iterate`), and the actions maximal now grow the most, by
    ``v_step`` (the argmax then never changes; under a fixed policy it suffices that the
    policy's part of ``q_step`` is ``v_step``)."""
    maximal = q == v[:, None]
    on_max = np.where(maximal, q_step, -np.inf).max(axis=1)
    return bool(np.array_equal(on_max, q_step.max(axis=1)) and np.array_equal(on_max, v_step))


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
        iterate to convergence (with ``gamma >= 1``: ``mdp.max_steps`` backups).
      tol: convergence threshold of the infinite-horizon iteration.

    Returns:
      float64 ``[S, A]`` Q*.
    """
    if horizon is None and gamma >= 1.0:
        horizon = int(mdp.max_steps)
    return _iterate(mdp, gamma, horizon, tol)


def _expected_from_start(mdp: TabularMDP, values: np.ndarray) -> float:
    """Expectation of per-state ``values`` ``[S]`` under the start distribution."""
    return float(np.asarray(mdp.start_probability, np.float64) @ values)


def best_return(mdp: TabularMDP) -> float:
    """Best expected undiscounted episode return from the start distribution.

    Args:
      mdp: the MDP.

    Returns:
      the start-distribution mean of :func:`optimal_values` (``gamma = 1``, horizon
      ``mdp.max_steps``).
    """
    return _expected_from_start(mdp, optimal_values(mdp, gamma=1.0))


def greedy_policy(q: Any) -> np.ndarray:
    """The first maximal action of each row of ``q``.

    Args:
      q: ``[S, A]`` action values (e.g. a learned Q table).

    Returns:
      int64 ``[S]`` actions.
    """
    return np.asarray(q).argmax(axis=1)


def policy_values(
    mdp: TabularMDP, policy: Any, gamma: float = 1.0, horizon: int | None = None
) -> np.ndarray:
    """Exact expected return of a deterministic policy from every state.

    Args:
      mdp: the MDP.
      policy: int ``[S]`` action of each state.
      gamma: discount.
      horizon: steps (default ``mdp.max_steps``: an episode's return before truncation).

    Returns:
      float64 ``[S]`` values.

    Raises:
      ValueError: ``policy`` of the wrong shape or with an action out of range.
    """
    policy = np.asarray(policy)
    if policy.shape != (mdp.num_states,) or not np.issubdtype(policy.dtype, np.integer):
        raise ValueError(f"policy has shape {policy.shape} and dtype {policy.dtype}:"
                         f" must be [{mdp.num_states}] integers")
    if policy.min() < 0 or policy.max() >= mdp.num_actions:
        raise ValueError(f"policy holds actions in [{policy.min()}, {policy.max()}]:"
                         f" must be in [0, {mdp.num_actions - 1}]")
    horizon = int(mdp.max_steps) if horizon is None else horizon
    q = _iterate(mdp, gamma, horizon, 0.0, policy=policy)
    return q[np.arange(mdp.num_states), policy]


def policy_return(mdp: TabularMDP, policy: Any) -> float:
    """Expected undiscounted episode return of a deterministic policy (start distribution).

    Args:
      mdp: the MDP.
      policy: int ``[S]`` action of each state (e.g. :func:`greedy_policy` of a learned Q).

    Returns:
      the start-distribution mean of :func:`policy_values` (``gamma = 1``, horizon
      ``mdp.max_steps``).

    Raises:
      ValueError: ``policy`` of the wrong shape or with an action out of range.
    """
    return _expected_from_start(mdp, policy_values(mdp, policy))


def uniform_random_return(mdp: TabularMDP) -> float:
    """Expected undiscounted episode return of the uniformly random policy (every action
    with probability 1/A in every state), from the start distribution within
    ``mdp.max_steps`` steps: the zero of normalised scores (rliable's "random" baseline).

    Args:
      mdp: the MDP.

    Returns:
      the expected return.
    """
    uniform = np.full((mdp.num_states, mdp.num_actions), 1.0 / mdp.num_actions)
    q = _iterate(mdp, 1.0, int(mdp.max_steps), 0.0, policy=uniform)
    return _expected_from_start(mdp, (q * uniform).sum(axis=1))


def shortest_solution(mdp: TabularMDP, start: int) -> list[int]:
    """Shortest action sequence from ``start`` to a terminal transition with positive reward.

    Breadth-first search over deterministic outcomes (the first outcome of each pair),
    level by level over whole arrays; among equally short solutions the one found first in
    FIFO order (lowest action first) is returned.

    Args:
      mdp: the MDP.
      start: the state index to start from.

    Returns:
      the actions, or an empty list if no goal is reachable.
    """
    next_state, live, goal = _first_outcomes(mdp)
    parent = np.full(mdp.num_states, -1, np.int64)
    parent_action = np.full(mdp.num_states, -1, np.int64)
    seen = np.zeros(mdp.num_states, bool)
    seen[start] = True
    frontier = np.array([start], np.int64)  # in FIFO discovery order
    while frontier.size:
        hits = goal[frontier]
        if hits.any():
            position, action = np.unravel_index(np.argmax(hits), hits.shape)
            state, path = int(frontier[position]), [int(action)]
            while state != start:
                path.append(int(parent_action[state]))
                state = int(parent[state])
            return path[::-1]
        candidates = np.where(live[frontier], next_state[frontier], -1).ravel()
        # First discovery of each new state, kept in (parent order, action order).
        states, first = np.unique(candidates, return_index=True)
        fresh = (states >= 0) & ~seen[np.maximum(states, 0)]
        states, first = states[fresh], first[fresh]
        order = np.argsort(first)
        states, first = states[order], first[order]
        parent[states] = frontier[first // mdp.num_actions]
        parent_action[states] = first % mdp.num_actions
        seen[states] = True
        frontier = states
    return []


def steps_to_goal(mdp: TabularMDP) -> np.ndarray:
    """Length of the shortest solution from every state, by one backward search.

    Over deterministic outcomes (the first of each pair), as :func:`shortest_solution`,
    but for all states at once: level ``d`` holds the states with an action into a goal
    transition (``d = 1``) or a non-terminal action into level ``d - 1``.

    Args:
      mdp: the MDP.

    Returns:
      int64 ``[S]``: number of actions of a shortest solution, ``-1`` where no goal is
      reachable.
    """
    next_state, live, goal = _first_outcomes(mdp)
    steps = np.where(goal.any(1), 1, -1)
    level = 1
    while True:
        into_level = (live & (steps[next_state] == level)).any(1) & (steps < 0)
        if not into_level.any():
            return steps
        level += 1
        steps[into_level] = level


def shortest_episode(mdp: TabularMDP) -> int:
    """The fewest steps any episode of ``mdp`` takes: a forward search from the start
    states over every outcome of positive probability, to the first terminal outcome,
    capped at ``max_steps`` (truncation). Estimates use it as a lower bound per episode.

    Args:
      mdp: the MDP.

    Returns:
      the number of steps, ``1 .. max_steps``.
    """
    max_steps = int(mdp.max_steps)
    next_state = np.asarray(mdp.next_state)
    possible = np.asarray(mdp.probability) > 0
    ends = np.asarray(mdp.terminal) & possible
    seen = np.zeros(mdp.num_states, bool)
    frontier = start_states(mdp)
    seen[frontier] = True
    for steps in range(1, max_steps):
        if not frontier.size or ends[frontier].any():
            return steps if frontier.size else max_steps
        successors = next_state[frontier][possible[frontier] & ~ends[frontier]]
        frontier = np.unique(successors[~seen[successors]])
        seen[frontier] = True
    return max_steps
