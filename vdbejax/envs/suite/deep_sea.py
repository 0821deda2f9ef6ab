"""DeepSea (Osband et al. 2019; bsuite, Osband et al. 2020), deterministic.

Sources:

* I. Osband, B. Van Roy, D. J. Russo and Z. Wen, "Deep exploration via randomized value
  functions", *Journal of Machine Learning Research* 20(124):1–62, 2019 (the "deep sea"
  example).
* I. Osband et al., "Behaviour Suite for Reinforcement Learning", ICLR 2020: bsuite's
  ``bsuite/environments/deep_sea.py`` (the definition below, with its defaults) and its
  ``deep_sea`` experiment (sizes 10 to 50, ``mapping_seed = 42``, 10 000 episodes).

An ``N × N`` grid; the agent starts at the top-left cell (row 0, column 0) and every step
goes down one row, and left or right one column (clipped at the edges); the episode ends
after ``N`` steps, on leaving the bottom row. Moving right costs ``0.01 / N``; moving
right from the rightmost column pays 1 (only the all-right path gets there, so the
treasure is collected at the last step). Actions 0 and 1 mean left and right *per cell*:
with ``randomize_actions`` (bsuite's default and, bsuite warns, the only proper DeepSea)
action ``mapping[row, column]`` is "right", with ``mapping`` the ``[N, N]`` draws
``numpy.random.RandomState(seed).binomial(1, 0.5, [N, N])``, exactly bsuite's
``mapping_seed`` draws, so a seed gives bsuite's own task; otherwise action 1 is right
everywhere. Dynamics are deterministic (bsuite's default ``deterministic=True``).

State ``row · N + column`` (all ``N²`` cells, as bsuite's one-hot observation; the
cells right of the diagonal are never reached). The horizon is the episode itself,
``N`` steps (every episode terminates there; ``max_steps = N`` never truncates).

The task tests *deep exploration*: the optimal return is ``1 − 0.01 = 0.99`` (bsuite's
``_optimal_return``), every other policy gets at most 0 (never right: 0; any left move
forfeits the treasure), and the uniformly random policy finds the treasure with
probability ``2^−N`` (its expected return is ``2^−N − 0.005``), so dithering exploration
needs about ``2^N`` episodes while the move cost discourages going right.
"""
from __future__ import annotations

import numpy as np

from vdbejax.envs.tabular import TabularMDP, make_tabular_mdp
from vdbejax.validation import UINT32_MAX, check_bool, check_finite, check_int

#: bsuite's ``deep_sea`` experiment's ``mapping_seed``.
BSUITE_MAPPING_SEED = 42
#: Largest size (``N²`` states must be int32 indices).
MAX_SIZE = 46_340


def action_mapping(size: int, randomize_actions: bool = True,
                   seed: int = BSUITE_MAPPING_SEED) -> np.ndarray:
    """Which action means "right" in each cell.

    Args:
      size: ``N`` in [1, :data:`MAX_SIZE`].
      randomize_actions: draw the mapping (bsuite's default); else action 1 everywhere.
      seed: the draw's seed (bsuite's ``mapping_seed``), an integer in [0, 2**32 − 1].

    Returns:
      int64 ``[N, N]`` of 0 and 1.

    Raises:
      ValueError: an invalid ``size``, ``randomize_actions`` or ``seed``.
    """
    size = check_int("size", size, 1, MAX_SIZE)
    if not check_bool("randomize_actions", randomize_actions):
        return np.ones((size, size), np.int64)
    seed = check_int("seed", seed, 0, UINT32_MAX)
    return np.random.RandomState(seed).binomial(1, 0.5, [size, size]).astype(np.int64)


def make_deep_sea(size: int = 10, *, randomize_actions: bool = True,
                  seed: int = BSUITE_MAPPING_SEED, unscaled_move_cost: float = 0.01,
                  max_steps: int | None = None, name: str | None = None) -> TabularMDP:
    """DeepSea as a deterministic :class:`~vdbejax.envs.TabularMDP`.

    Args:
      size: ``N`` in [1, :data:`MAX_SIZE`] (default 10, bsuite's smallest experiment).
      randomize_actions: per-cell action meanings drawn from ``seed`` (default True).
      seed: bsuite's ``mapping_seed`` (default :data:`BSUITE_MAPPING_SEED`).
      unscaled_move_cost: the cost of moving right, times ``N`` (finite; default 0.01).
      max_steps: the truncation length (default ``N``: the episode's own length).
      name: the MDP's label (default ``deepsea:N``).

    Returns:
      the MDP (``N²`` states, 2 actions); every episode starts in state 0.

    Raises:
      ValueError: an invalid parameter.
    """
    mapping = action_mapping(size, randomize_actions, seed)
    cost = check_finite("unscaled_move_cost", unscaled_move_cost)
    n = len(mapping)
    row, column = np.divmod(np.arange(n * n), n)
    actions = np.arange(2)
    right = actions[None, :] == mapping.reshape(-1)[:, None]  # [S, 2]
    new_column = np.clip(column[:, None] + np.where(right, 1, -1), 0, n - 1)
    reward = np.where(right, -cost / n, 0.0) + (right & (column[:, None] == n - 1))
    terminal = np.broadcast_to((row == n - 1)[:, None], right.shape)
    states = np.arange(n * n)[:, None]
    # a terminal step never bootstraps: its next state is left as the state itself
    next_state = np.where(terminal, states, (row[:, None] + 1) * n + new_column)
    start = np.zeros(n * n)
    start[0] = 1.0
    return make_tabular_mdp(next_state, reward, terminal, start,
                            max_steps=n if max_steps is None else max_steps,
                            name=f"deepsea:{n}" if name is None else name)


__all__ = ["BSUITE_MAPPING_SEED", "MAX_SIZE", "action_mapping", "make_deep_sea"]
