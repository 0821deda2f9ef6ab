"""Q-learning and SARSA as pure functions of one transition (rlax style).

``discount`` is γ for a non-terminal transition and 0 for a terminal one, so terminal
transitions use the target ``r`` and truncated ones still bootstrap. Q rows have the
actions on the leading axis: ``[num_actions]`` for one transition, or
``[num_actions, batch...]`` for a batch laid out as the engine does.
"""
from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from vdbejax._numerics import rounded
from vdbejax._pytree import pytree_dataclass

Array = jax.Array

LEARNERS = ("qlearning", "sarsa")
PAPER_ALPHA = 0.8
PAPER_GAMMA = 0.9


def q_learning_target(reward: Array, discount: Array, q_next: Array) -> Array:
    """Q-learning target ``r + discount · max_b Q(s', b)``.

    Args:
      reward: reward of the transition.
      discount: γ, or 0 if ``s'`` is terminal.
      q_next: ``[num_actions, batch...]`` Q row of ``s'``.

    Returns:
      the target (``[batch...]``).
    """
    return reward + rounded(discount * jnp.max(q_next, axis=0), discount)


def sarsa_target(reward: Array, discount: Array, q_next: Array, next_action: Array) -> Array:
    """SARSA target ``r + discount · Q(s', a')``.

    Args:
      reward: reward of the transition.
      discount: γ, or 0 if ``s'`` is terminal.
      q_next: ``[num_actions, batch...]`` Q row of ``s'``.
      next_action: the action ``a'`` the agent takes in ``s'`` (``[batch...]``).

    Returns:
      the target (``[batch...]``).
    """
    # Select Q(s', a') with a masked max rather than a gather: exact, and it vectorises
    # over the batch axis on CPU.
    actions = jnp.arange(q_next.shape[0]).reshape((-1,) + (1,) * (q_next.ndim - 1))
    chosen = jnp.max(jnp.where(actions == next_action, q_next, -jnp.inf), axis=0)
    return reward + rounded(discount * chosen, discount)


def td_update(q_value: Array, target: Array, alpha: Array) -> tuple[Array, Array]:
    """Move ``Q(s,a)`` toward ``target`` by step size α.

    Args:
      q_value: current Q(s, a).
      target: learning target.
      alpha: step size in (0, 1].

    Returns:
      ``(new_q_value, delta_q)`` with ``delta_q = α·(target − Q(s,a))``.
    """
    delta_q = rounded(alpha * (target - q_value), alpha)
    return q_value + delta_q, delta_q


@pytree_dataclass
class LearnerParams:
    """Learner hyperparameters as vmappable leaves.

    Attributes:
      alpha: step size α.
      gamma: discount γ.
      sarsa: True for SARSA, False for Q-learning.
      q_init: initial value of every Q entry.
    """

    alpha: Array
    gamma: Array
    sarsa: Array
    q_init: Array


def make_learner(
    name: str, *, alpha: float = PAPER_ALPHA, gamma: float = PAPER_GAMMA, q_init: float = 0.0
) -> LearnerParams:
    """Learner hyperparameters from a name (``qlearning`` or ``sarsa``).

    Args:
      name: ``qlearning`` or ``sarsa``.
      alpha: step size α.
      gamma: discount γ.
      q_init: initial value of every Q entry.

    Returns:
      LearnerParams with float32 (and bool) scalar numpy leaves.

    Raises:
      ValueError: unknown name or out-of-range α, γ, q_init.
    """
    from vdbejax.validation import check_learner

    check_learner(name, alpha=alpha, gamma=gamma, q_init=q_init)
    # Host (numpy) scalars: building a grid's agents costs no device transfers; jit and
    # vmap take them like JAX arrays.
    f32 = np.float32
    return LearnerParams(
        alpha=np.asarray(alpha, f32),
        gamma=np.asarray(gamma, f32),
        sarsa=np.asarray(name == "sarsa"),
        q_init=np.asarray(q_init, f32),
    )
