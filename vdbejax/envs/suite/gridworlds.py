"""The windy gridworld and cliff walking of Sutton & Barto (2018), Examples 6.5 and 6.6.

Source: R. S. Sutton and A. G. Barto, *Reinforcement Learning: An Introduction*, 2nd
edition, MIT Press, 2018, Chapter 6: Example 6.5 (Windy Gridworld, with its Sarsa
figure) and Example 6.6 (Cliff Walking, Sarsa against Q-learning). gymnasium's
``CliffWalking-v1`` is the same cliff walk (and the same tables; the tests check it).

Both are grids of cells ``(row, column)``, row 0 at the top, state ``row · columns +
column`` (every cell, as gymnasium numbers them; the goal and cliff cells are never
occupied), with the four moves **0 = up, 1 = right, 2 = down, 3 = left** (gymnasium's
order); a move off the grid leaves the agent at the edge. Every step costs 1
(undiscounted, episodic), and entering the goal ends the episode.

**Windy gridworld** (Example 6.5): 7 rows × 10 columns, start (3, 0), goal (3, 7); an
upward wind of strength ``(0, 0, 0, 1, 1, 1, 2, 2, 1, 0)`` in the agent's column adds
that many cells up to each move (clipped at the top). The shortest episode takes 15
steps (the book's figure: Sarsa's episodes approach 15 steps): best return −15. It tests
exploration that has to discover how the wind moves the agent (no reward but −1 until
the goal).

**Cliff walking** (Example 6.6): 4 rows × 12 columns, start (3, 0), goal (3, 11); the
cells (3, 1) … (3, 10) between them are the cliff: stepping into it costs 100 and sends
the agent back to the start (the episode goes on). The optimal path runs along the cliff
edge, 13 steps: best return −13. It tests the price of exploring next to a cliff: an
ε-greedy agent learns the safe path's values with Sarsa, the optimal edge path with
Q-learning, and falls off now and then.

The book runs every episode to the goal (no time limit, and gymnasium's
``CliffWalking-v1`` has none either); here an episode is truncated after
:data:`HORIZON` = 10 000 steps, a safety cap as for the authors' table-cleaning task
(:data:`vdbejax.envs.cruz2018.STEP_CAP`), about 700 times the optimal lengths. It cuts
off only walks that are still close to random: the uniformly random policy reaches the
goal within 10 000 steps with probability 0.81 in the windy gridworld and 0.79 in cliff
walking (within 1000 steps: 0.14 in both), and a learner whose values already push it
away from visited cells gets there far sooner.
"""
from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from vdbejax.envs.tabular import TabularMDP, make_tabular_mdp

#: Episode truncation of both gridworlds (a safety cap; see the module docstring).
HORIZON = 10_000
UP, RIGHT, DOWN, LEFT = range(4)
ACTION_NAMES = ("up", "right", "down", "left")
#: Row and column change of each move.
MOVES = np.array([[-1, 0], [0, 1], [1, 0], [0, -1]])
#: Example 6.5's wind strength of each column.
WIND = (0, 0, 0, 1, 1, 1, 2, 2, 1, 0)


def _moves(shape: tuple[int, int], wind: Sequence[int]) -> tuple[np.ndarray, np.ndarray]:
    """``(row, column)`` ``[S, 4]`` after each move (and the wind) from every cell."""
    rows, columns = shape
    row, column = np.divmod(np.arange(rows * columns), columns)
    push = np.asarray(wind)[column]
    new_row = np.clip(row[:, None] + MOVES[None, :, 0] - push[:, None], 0, rows - 1)
    new_column = np.clip(column[:, None] + MOVES[None, :, 1], 0, columns - 1)
    return new_row, new_column


def _grid_mdp(shape: tuple[int, int], start: tuple[int, int], goal: tuple[int, int],
              wind: Sequence[int], cliff: np.ndarray, max_steps: int, name: str
              ) -> TabularMDP:
    rows, columns = shape
    new_row, new_column = _moves(shape, wind)
    start_index = start[0] * columns + start[1]
    falls = cliff[new_row, new_column]
    next_state = np.where(falls, start_index, new_row * columns + new_column)
    reward = np.where(falls, -100.0, -1.0)
    terminal = (new_row == goal[0]) & (new_column == goal[1]) & ~falls
    start_probability = np.zeros(rows * columns)
    start_probability[start_index] = 1.0
    return make_tabular_mdp(next_state, reward, terminal, start_probability,
                            max_steps=max_steps, name=name)


def make_windy_gridworld(*, max_steps: int = HORIZON,
                         name: str = "windy_gridworld") -> TabularMDP:
    """Example 6.5's windy gridworld as a deterministic :class:`~vdbejax.envs.TabularMDP`.

    Args:
      max_steps: the episode truncation (default :data:`HORIZON`).
      name: the MDP's label.

    Returns:
      the MDP (70 states, 4 actions); every episode starts at (3, 0), state 30.

    Raises:
      ValueError: an invalid ``max_steps``.
    """
    shape = (7, 10)
    return _grid_mdp(shape, (3, 0), (3, 7), WIND, np.zeros(shape, bool), max_steps, name)


def make_cliff_walking(*, max_steps: int = HORIZON, name: str = "cliff_walking") -> TabularMDP:
    """Example 6.6's cliff walking as a deterministic :class:`~vdbejax.envs.TabularMDP`.

    Args:
      max_steps: the episode truncation (default :data:`HORIZON`).
      name: the MDP's label.

    Returns:
      the MDP (48 states, 4 actions); every episode starts at (3, 0), state 36.

    Raises:
      ValueError: an invalid ``max_steps``.
    """
    shape = (4, 12)
    cliff = np.zeros(shape, bool)
    cliff[3, 1:-1] = True
    return _grid_mdp(shape, (3, 0), (3, 11), (0,) * 12, cliff, max_steps, name)


__all__ = ["ACTION_NAMES", "DOWN", "HORIZON", "LEFT", "MOVES", "RIGHT", "UP", "WIND",
           "make_cliff_walking", "make_windy_gridworld"]
