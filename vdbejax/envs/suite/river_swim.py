"""RiverSwim and SixArms (Strehl & Littman 2008), and the normalised RiverSwim of Osband,
Russo & Van Roy (2013).

Sources:

* A. L. Strehl and M. L. Littman, "An analysis of model-based Interval Estimation for
  Markov decision processes", *Journal of Computer and System Sciences* 74(8):1309–1331,
  2008 (its RiverSwim and SixArms figures and experiments): both MDPs with their
  transition probabilities and rewards.
* I. Osband, D. Russo and B. Van Roy, "(More) efficient reinforcement learning via
  posterior sampling", NeurIPS 2013 (its RiverSwim figure and experiments): RiverSwim
  with rewards rescaled to [0, 1] (0.005 at the left bank, 1 at the right bank), a
  slightly easier current, the left bank as the start state and episodes of τ = 20
  steps; the form ``benchmarks/rlberry_ucbvi.py`` gives rlberry's ``FiniteMDP``.

**RiverSwim** (``S`` states in a row, default 6; actions 0 = swim left, with the current,
1 = swim right, against it). Swimming left always reaches the state to the left (the left
bank stays put and pays 5). Swimming right, as published: in the middle states it moves
right with probability 0.3, stays with 0.6 and drifts left with 0.1; at the left bank it
moves right with 0.3 and stays with 0.7; at the right bank it stays with 0.3, which pays
10000, and drifts left with 0.7. The agent starts in state 1 or 2 (states numbered 0 to
5 from the left bank), each with probability 1/2. The normalised form moves right with
0.35, stays with 0.6 and drifts left with 0.05 (left bank: right 0.4, stay 0.6; right
bank: stay 0.6, left 0.4), pays 0.005 for swimming left at the left bank and 1 for
swimming right at the right bank (whatever the outcome: rewards of ``(s, a)``), and starts
at the left bank.

**SixArms** (7 states, 6 actions): from the centre, state 0, action ``i`` reaches room
``i + 1`` with probability 1, 0.15, 0.10, 0.05, 0.03, 0.01 (``i = 0 … 5``) and otherwise
stays at the centre, reward 0. In room 1 every action but 4 stays and pays 50 (action 4
returns to the centre); in room ``j = 2 … 6`` action ``j − 1`` stays and pays 133, 300,
800, 1660, 6000 respectively, and any other action returns to the centre, reward 0. The
agent starts at the centre.

Both are continuing tasks (no terminal state; the paper runs each learner for a fixed
number of steps and reports the reward gathered): here an episode is truncated after a
horizon (``max_steps``), long enough that the optimal policy of the horizon is the
continuing task's optimal one for most of the episode (swim right; try for room 6), so
the return that a myopic learner settles for (swimming left, room 1) is far below the
optimum:

* RiverSwim, both forms: :data:`RIVER_SWIM_HORIZON` = 20 steps, Osband et al.'s τ (and
  the UCBVI benchmark's default horizon). Swimming right in every state is then optimal
  from the first step, and its return (6511.5; normalised 3.064) is 70 and 30 times that
  of staying at the left bank (92.5; 0.1). A longer river (``num_states > 6``) needs a
  longer horizon: at 20 steps its far bank is mostly out of reach.
* SixArms: :data:`SIX_ARMS_HORIZON` = 200: room 6 is entered after 100 tries on average;
  at 200 steps trying for it is still optimal at the start (its expected return, about
  6000 · 113, beats room 5's 1660 · 167), while the episode stays short.
"""
from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from vdbejax.validation import check_int

if TYPE_CHECKING:
    from vdbejax.envs.tabular import TabularMDP

# The ``*_model`` functions need numpy alone (the tables' builders import JAX when called):
# ``benchmarks/rlberry_ucbvi.py`` reads this file in rlberry's venv, which has no JAX.

#: Episode horizon of both RiverSwims (Osband et al. 2013's τ; see the module docstring).
RIVER_SWIM_HORIZON = 20
#: Episode horizon of SixArms.
SIX_ARMS_HORIZON = 200

LEFT, RIGHT = 0, 1
ACTION_NAMES = ("left", "right")
#: SixArms: probability that arm ``i`` of the centre reaches room ``i + 1``.
SIX_ARMS_ENTRY = (1.0, 0.15, 0.10, 0.05, 0.03, 0.01)
#: SixArms: the reward of staying in room ``i + 1``.
SIX_ARMS_REWARD = (50.0, 133.0, 300.0, 800.0, 1660.0, 6000.0)


def river_swim_model(num_states: int = 6) -> tuple[np.ndarray, np.ndarray]:
    """The published RiverSwim (Strehl & Littman 2008) as dense arrays.

    Args:
      num_states: ``S >= 3`` (the paper's is 6; more states move the far bank away).

    Returns:
      ``(R, P)``: float64 ``[S, 2, S]`` reward of each transition and ``[S, 2, S]``
      transition probabilities (action 0 = left, 1 = right).

    Raises:
      ValueError: ``num_states`` not an integer >= 3.
    """
    n = check_int("num_states", num_states, 3)
    P = np.zeros((n, 2, n))
    R = np.zeros((n, 2, n))
    for s in range(n):
        P[s, LEFT, max(s - 1, 0)] = 1.0
    P[0, RIGHT, 0], P[0, RIGHT, 1] = 0.7, 0.3
    for s in range(1, n - 1):
        P[s, RIGHT, s - 1], P[s, RIGHT, s], P[s, RIGHT, s + 1] = 0.1, 0.6, 0.3
    P[n - 1, RIGHT, n - 2], P[n - 1, RIGHT, n - 1] = 0.7, 0.3
    R[0, LEFT, 0] = 5.0
    R[n - 1, RIGHT, n - 1] = 10000.0
    return R, P


def normalised_river_swim_model(num_states: int = 6) -> tuple[np.ndarray, np.ndarray]:
    """The normalised RiverSwim (Osband, Russo & Van Roy 2013) as dense arrays.

    Args:
      num_states: ``S >= 3`` (the paper's is 6).

    Returns:
      ``(R, P)``: float64 ``[S, 2]`` reward of each state-action pair and ``[S, 2, S]``
      transition probabilities (action 0 = left, 1 = right), rlberry's ``FiniteMDP``
      layout.

    Raises:
      ValueError: ``num_states`` not an integer >= 3.
    """
    n = check_int("num_states", num_states, 3)
    P = np.zeros((n, 2, n))
    R = np.zeros((n, 2))
    for s in range(n):
        P[s, LEFT, max(s - 1, 0)] = 1.0
        if s == 0:
            P[s, RIGHT, 0], P[s, RIGHT, 1] = 0.6, 0.4
        elif s == n - 1:
            P[s, RIGHT, s], P[s, RIGHT, s - 1] = 0.6, 0.4
        else:
            P[s, RIGHT, s + 1], P[s, RIGHT, s], P[s, RIGHT, s - 1] = 0.35, 0.6, 0.05
    R[0, LEFT] = 0.005
    R[n - 1, RIGHT] = 1.0
    return R, P


def make_river_swim(num_states: int = 6, *, max_steps: int = RIVER_SWIM_HORIZON,
                    name: str = "riverswim") -> TabularMDP:
    """The published RiverSwim as a :class:`~vdbejax.envs.TabularMDP` (``K = 3``).

    Args:
      num_states: ``S >= 3`` (default: the paper's 6).
      max_steps: the episode horizon (default :data:`RIVER_SWIM_HORIZON`).
      name: the MDP's label.

    Returns:
      the MDP; every episode starts in state 1 or 2 (probability 1/2 each).

    Raises:
      ValueError: an invalid ``num_states`` or ``max_steps``.
    """
    from vdbejax.envs.suite._tables import dense_mdp

    R, P = river_swim_model(num_states)
    start = np.zeros(len(P))
    start[[1, 2]] = 0.5
    return dense_mdp(P, R, start, max_steps=max_steps, name=name)


def make_river_swim_normalised(num_states: int = 6, *,
                               max_steps: int = RIVER_SWIM_HORIZON,
                               name: str = "riverswim_normalised") -> TabularMDP:
    """The normalised RiverSwim as a :class:`~vdbejax.envs.TabularMDP` (``K = 3``).

    Args:
      num_states: ``S >= 3`` (default: the paper's 6).
      max_steps: the episode horizon (default :data:`RIVER_SWIM_HORIZON`).
      name: the MDP's label.

    Returns:
      the MDP; every episode starts at the left bank, state 0.

    Raises:
      ValueError: an invalid ``num_states`` or ``max_steps``.
    """
    from vdbejax.envs.suite._tables import dense_mdp

    R, P = normalised_river_swim_model(num_states)
    start = np.zeros(len(P))
    start[0] = 1.0
    return dense_mdp(P, R, start, max_steps=max_steps, name=name)


def six_arms_model() -> tuple[np.ndarray, np.ndarray]:
    """SixArms (Strehl & Littman 2008) as dense arrays.

    Returns:
      ``(R, P)``: float64 ``[7, 6, 7]`` reward of each transition and transition
      probabilities (state 0 = the centre, state ``i + 1`` = room ``i + 1``).
    """
    num_arms = len(SIX_ARMS_ENTRY)
    P = np.zeros((num_arms + 1, num_arms, num_arms + 1))
    R = np.zeros_like(P)
    for arm, (entry, reward) in enumerate(zip(SIX_ARMS_ENTRY, SIX_ARMS_REWARD, strict=True)):
        room = arm + 1
        P[0, arm, room] += entry
        P[0, arm, 0] += 1.0 - entry
        # room 1 pays for every action but 4; room j for action j - 1 only
        staying = [a for a in range(num_arms) if a != 4] if room == 1 else [arm]
        for action in range(num_arms):
            if action in staying:
                P[room, action, room], R[room, action, room] = 1.0, reward
            else:
                P[room, action, 0] = 1.0
    return R, P


def make_six_arms(*, max_steps: int = SIX_ARMS_HORIZON, name: str = "sixarms") -> TabularMDP:
    """SixArms as a :class:`~vdbejax.envs.TabularMDP` (``K = 2``).

    Args:
      max_steps: the episode horizon (default :data:`SIX_ARMS_HORIZON`).
      name: the MDP's label.

    Returns:
      the MDP; every episode starts at the centre, state 0.

    Raises:
      ValueError: an invalid ``max_steps``.
    """
    from vdbejax.envs.suite._tables import dense_mdp

    R, P = six_arms_model()
    start = np.zeros(len(P))
    start[0] = 1.0
    return dense_mdp(P, R, start, max_steps=max_steps, name=name)


__all__ = [
    "ACTION_NAMES", "LEFT", "RIGHT", "RIVER_SWIM_HORIZON",
    "SIX_ARMS_ENTRY", "SIX_ARMS_HORIZON", "SIX_ARMS_REWARD", "make_river_swim",
    "make_river_swim_normalised", "make_six_arms", "normalised_river_swim_model",
    "river_swim_model", "six_arms_model",
]
