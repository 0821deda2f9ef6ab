"""A task of your own for a sweep file: a slippery corridor, built from arrays.

    task = "corridor.py:make_corridor"     # in a sweep file beside this one

``N`` cells in a row; the agent starts in cell 0 and ends the episode with reward 1 on
reaching cell ``N - 1``. Action 0 steps left, action 1 steps right; each move slips the
other way with probability 0.2. Every step costs 0.01 and an episode is cut after 100
steps. Any function of no arguments that returns a :class:`vdbejax.envs.TabularMDP` is a
task (``module:function`` for an importable module, ``path/to/file.py:function`` for a file).
"""
from __future__ import annotations

import numpy as np

from vdbejax.envs import TabularMDP, make_tabular_mdp

LENGTH = 8
SLIP = 0.2
STEP_COST = 0.01


def make_corridor(length: int = LENGTH) -> TabularMDP:
    """The corridor of ``length`` cells (two outcomes per move: intended and slipped)."""
    cells = np.arange(length)
    left, right = np.maximum(cells - 1, 0), np.minimum(cells + 1, length - 1)
    next_state = np.stack([np.stack([left, right], -1),     # action 0: left, slips right
                           np.stack([right, left], -1)], 1)  # action 1: right, slips left
    probability = np.broadcast_to([1 - SLIP, SLIP], next_state.shape)
    terminal = next_state == length - 1
    reward = np.where(terminal, 1.0, 0.0) - STEP_COST
    start = np.eye(length)[0]
    return make_tabular_mdp(next_state, reward, terminal, start, probability, max_steps=100,
                            name=f"corridor{length}")
