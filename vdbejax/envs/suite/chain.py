"""The n-Chain of Dearden, Friedman & Russell (1998).

Source: R. Dearden, N. Friedman and S. Russell, "Bayesian Q-learning", AAAI 1998 (the
"Chain" domain of its experiments); the same task as OpenAI gym's ``NChain-v0`` (``n =
5``, ``slip = 0.2``, rewards 2 and 10, a time limit of 1000 steps).

``n`` states in a row (default 5; the agent starts in the first, state 0) and two
actions: **0 = forward** (``a`` in the paper) moves one state on with reward 0, and in the
last state stays there with reward 10; **1 = back** (``b``) returns to state 0 with
reward 2, from any state. With probability ``slip`` (default 0.2) the agent "slips" and
the other action is performed. The task tests *deep exploration*: the immediate reward
of going back (2 a step) hides the larger reward at the end of the chain, reached only
by ``n − 1`` forward steps with nothing to show for them, and every slip on the way
sends the agent back to the start.

It is a continuing task (the paper runs phases of 1000 steps and reports the reward
gathered in each); here an episode is truncated after :data:`HORIZON` = 1000 steps, the
paper's phase and gym's ``NChain-v0`` time limit: long enough that the long-run rates
decide the optimal policy. Going forward everywhere yields, in the long run,
``2 · slip + 10 · (1 − slip)^n`` a step (the stationary probability of the last state is
``(1 − slip)^(n−1)``): 3.6768 at the defaults, 3677 per 1000 steps, against 1.6 a step
for going back everywhere. The optimal 1000-step return from state 0 is 3665.86 (the
walk to the end costs the difference). Depth scaling has a threshold: with ``slip =
0.2`` the optimal policy goes forward from the start only for ``n <= 8``; for longer
chains it goes back there: the far end, reached only with probability
``(1 − slip)^(n−1)`` per attempt, no longer pays for the walk (``slip = 0`` scales depth
without that cliff).
"""
from __future__ import annotations

import numpy as np

from vdbejax.envs.suite._tables import dense_mdp
from vdbejax.envs.tabular import TabularMDP
from vdbejax.validation import check_in_range, check_int

#: Episode horizon (the paper's 1000-step phases; gym's ``NChain-v0`` time limit).
HORIZON = 1000
FORWARD, BACK = 0, 1
ACTION_NAMES = ("forward", "back")
#: Reward of going back (to state 0), and of staying at the end of the chain.
BACK_REWARD, END_REWARD = 2.0, 10.0


def chain_model(num_states: int = 5, slip: float = 0.2) -> tuple[np.ndarray, np.ndarray]:
    """The chain as dense arrays.

    Args:
      num_states: ``n >= 2``.
      slip: probability in [0, 1] that the other action is performed.

    Returns:
      ``(R, P)``: float64 ``[n, 2, n]`` reward of each transition and ``[n, 2, n]``
      transition probabilities.

    Raises:
      ValueError: ``num_states`` not an integer >= 2, or ``slip`` not in [0, 1].
    """
    n = check_int("num_states", num_states, 2)
    slip = check_in_range("slip", slip, 0.0, 1.0)
    # the effect of performing each action: (next state, reward) of every state
    ahead = np.minimum(np.arange(n) + 1, n - 1)
    ahead_reward = np.where(np.arange(n) == n - 1, END_REWARD, 0.0)
    effects = {FORWARD: (ahead, ahead_reward),
               BACK: (np.zeros(n, np.int64), np.full(n, BACK_REWARD))}
    P = np.zeros((n, 2, n))
    R = np.zeros((n, 2, n))
    rows = np.arange(n)
    for action in (FORWARD, BACK):
        for performed, weight in ((action, 1.0 - slip), (1 - action, slip)):
            target, reward = effects[performed]
            P[rows, action, target] += weight
            R[rows, action, target] = reward  # the two effects never share a next state
    return R, P


def make_chain(num_states: int = 5, slip: float = 0.2, *, max_steps: int = HORIZON,
               name: str = "chain") -> TabularMDP:
    """The chain as a :class:`~vdbejax.envs.TabularMDP` (``K = 2``; ``K = 1`` without slip).

    Args:
      num_states: ``n >= 2`` (default: the paper's 5).
      slip: probability in [0, 1] that the other action is performed (default 0.2).
      max_steps: the episode horizon (default :data:`HORIZON`).
      name: the MDP's label.

    Returns:
      the MDP; every episode starts in state 0.

    Raises:
      ValueError: an invalid ``num_states``, ``slip`` or ``max_steps``.
    """
    R, P = chain_model(num_states, slip)
    start = np.zeros(len(P))
    start[0] = 1.0
    return dense_mdp(P, R, start, max_steps=max_steps, name=name)


__all__ = ["ACTION_NAMES", "BACK", "BACK_REWARD", "END_REWARD", "FORWARD", "HORIZON",
           "chain_model", "make_chain"]
