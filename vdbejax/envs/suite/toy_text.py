"""FrozenLake and Taxi: gymnasium's toy-text tasks, through
:func:`vdbejax.envs.gymnasium_adapter.from_gymnasium`.

Sources:

* gymnasium's ``FrozenLake-v1`` (``toy_text/frozen_lake.py``; the task of OpenAI gym,
  Brockman et al. 2016): the 4×4 and 8×8 maps, slippery (the default: the intended move
  with probability 1/3, each perpendicular one with 1/3), reward 1 on reaching the goal,
  holes and goal end the episode; time limits 100 (4×4) and 200 (8×8) steps, and the
  registry's stated optima 0.74 and 0.91 (success probabilities within those limits;
  exactly 0.7442 and 0.9132).
* gymnasium's ``Taxi-v3``/``Taxi-v4`` (``toy_text/taxi.py``; T. G. Dietterich,
  "Hierarchical reinforcement learning with the MAXQ value function decomposition",
  *JAIR* 13:227–303, 2000): 500 states (taxi cell, passenger location, destination), 6
  actions, −1 a step, −10 for an illegal pick-up or drop-off, +20 for the delivery, which
  ends the episode; deterministic (``is_rainy`` and ``fickle_passenger`` off), starts
  uniform over its 300 start states; time limit 200 steps. The registry states an
  optimum of 8.46; the exact optimum of the current map and start distribution is 7.93
  (21 minus the mean shortest delivery, 13.07 steps), which the tests check by a search
  over gymnasium's own model.

The horizons are gymnasium's time limits (``TimeLimit``), for which its optima are
stated. FrozenLake tests exploration under heavy noise with a sparse reward (the only
reward is the goal); Taxi tests a long sequence of sub-goals (find, pick up, carry, drop
off) with penalties for trying the wrong action.

gymnasium is an optional extra (``pip install 'vdbejax[gym]'``), imported only when a task
is built.
"""
from __future__ import annotations

from typing import Any

from vdbejax.envs.gymnasium_adapter import from_gymnasium
from vdbejax.envs.tabular import TabularMDP
from vdbejax.validation import check_choice

#: gymnasium's time limits of the tasks.
FROZEN_LAKE_HORIZON = {"4x4": 100, "8x8": 200}
TAXI_HORIZON = 200
#: gymnasium's registry's stated optimum of each task (within its time limit).
STATED_OPTIMUM = {"frozenlake4": 0.74, "frozenlake8": 0.91, "taxi": 8.46}


def _gymnasium(task: str) -> Any:
    """The gymnasium module, or a one-line error naming the extra to install."""
    try:
        import gymnasium
    except ImportError:
        raise ImportError(f"the {task} task needs gymnasium: pip install 'vdbejax[gym]'"
                          ) from None
    return gymnasium


def make_frozen_lake(map_name: str = "4x4", *, max_steps: int | None = None,
                     name: str | None = None) -> TabularMDP:
    """Slippery FrozenLake as a :class:`~vdbejax.envs.TabularMDP` (``K = 3``).

    Args:
      map_name: ``"4x4"`` (16 states) or ``"8x8"`` (64 states).
      max_steps: the truncation (default :data:`FROZEN_LAKE_HORIZON`: 100 or 200).
      name: the MDP's label (default ``frozenlake4`` or ``frozenlake8``).

    Returns:
      the MDP: state ``row · columns + column``, actions 0 = left, 1 = down, 2 = right,
      3 = up (gymnasium's); every episode starts at the top-left cell.

    Raises:
      ImportError: gymnasium is not installed.
      ValueError: an invalid ``map_name`` or ``max_steps``.
    """
    check_choice("map_name", map_name, FROZEN_LAKE_HORIZON)
    gymnasium = _gymnasium("frozenlake")
    env = gymnasium.make("FrozenLake-v1", map_name=map_name, is_slippery=True)
    return from_gymnasium(
        env, max_steps=FROZEN_LAKE_HORIZON[map_name] if max_steps is None else max_steps,
        name=name or f"frozenlake{map_name[0]}")


def make_taxi(*, max_steps: int = TAXI_HORIZON, name: str = "taxi") -> TabularMDP:
    """Taxi as a deterministic :class:`~vdbejax.envs.TabularMDP` (``K = 1``).

    Args:
      max_steps: the truncation (default :data:`TAXI_HORIZON`).
      name: the MDP's label.

    Returns:
      the MDP: gymnasium's 500 state codes and 6 actions (0–3 = south, north, east, west,
      4 = pick up, 5 = drop off); the start is uniform over its 300 start states.

    Raises:
      ImportError: gymnasium is not installed.
      ValueError: an invalid ``max_steps``.
    """
    gymnasium = _gymnasium("taxi")
    # Taxi-v4 (gymnasium >= 1.3, which retires v3) and v3 agree without rain or fickleness
    env_id = "Taxi-v4" if "Taxi-v4" in gymnasium.envs.registry else "Taxi-v3"
    return from_gymnasium(gymnasium.make(env_id), max_steps=max_steps, name=name)


__all__ = ["FROZEN_LAKE_HORIZON", "STATED_OPTIMUM", "TAXI_HORIZON", "make_frozen_lake",
           "make_taxi"]
