"""Finite MDPs as dense tables, and compilation of functional environments into them.

A :class:`TabularMDP` stores, for every state-action pair, ``K`` possible outcomes
(next state, probability, reward, terminal flag); a deterministic MDP has ``K = 1``.
The engine only needs :meth:`TabularMDP.start` and :meth:`TabularMDP.transition`,
both pure functions of integer state indices and uniforms, so any finite MDP runs
through the same code.
"""
from __future__ import annotations

from typing import Any, Protocol

import jax
import jax.numpy as jnp
import numpy as np

from vdbejax._pytree import pytree_dataclass, static_field
from vdbejax.explorers import sample_categorical

Array = jax.Array


@pytree_dataclass
class TabularMDP:
    """A finite MDP as dense arrays (``S`` states, ``A`` actions, ``K`` outcomes).

    Attributes:
      next_state: int32 ``[S, A, K]`` next-state indices.
      probability: float32 ``[S, A, K]`` outcome probabilities (rows sum to 1).
      reward: float32 ``[S, A, K]`` rewards.
      terminal: bool ``[S, A, K]`` whether the outcome ends the episode (no bootstrap).
      start_probability: float32 ``[S]`` initial-state distribution.
      max_steps: episode length at which an episode is truncated (bootstraps).
      name: label for reports (static).
    """

    next_state: Array
    probability: Array
    reward: Array
    terminal: Array
    start_probability: Array
    max_steps: Array
    name: str = static_field("mdp")

    @property
    def num_states(self) -> int:
        return int(self.next_state.shape[0])

    @property
    def num_actions(self) -> int:
        return int(self.next_state.shape[1])

    @property
    def num_outcomes(self) -> int:
        return int(self.next_state.shape[2])

    def start(self, u: Array) -> Array:
        """Sample an initial state index with one uniform ``u`` in [0, 1)."""
        return sample_categorical(self.start_probability, u)

    def transition(self, state: Array, action: Array, u: Array) -> tuple[Array, Array, Array]:
        """One transition from integer ``state`` under ``action``.

        Args:
          state: int32 state index.
          action: int32 action index.
          u: uniform in [0, 1) choosing the outcome (unused when ``K = 1``).

        Returns:
          ``(next_state, reward, terminal)``.
        """
        if self.num_outcomes == 1:  # static: deterministic MDPs skip the draw
            k = 0
        else:
            k = sample_categorical(self.probability[state, action], u)
        return (
            self.next_state[state, action, k],
            self.reward[state, action, k],
            self.terminal[state, action, k],
        )


def make_tabular_mdp(
    next_state: Any,
    reward: Any,
    terminal: Any,
    start_probability: Any,
    probability: Any | None = None,
    *,
    max_steps: int = 100,
    name: str = "mdp",
    atol: float = 1e-5,
) -> TabularMDP:
    """Build a validated :class:`TabularMDP` from arrays.

    Deterministic MDPs pass ``[S, A]`` arrays and no ``probability``; stochastic ones pass
    ``[S, A, K]`` arrays and ``probability`` of the same shape. ``terminal`` may also be a
    ``[S]`` array of terminal *states* (an outcome is terminal when its next state is).

    Raises:
      ValueError: wrong shapes, out-of-range indices, probabilities that are negative or do
        not sum to 1, non-finite rewards, or ``max_steps < 1``.
    """
    from vdbejax.validation import check_int

    next_state = np.asarray(next_state)
    if next_state.ndim == 2:
        next_state = next_state[:, :, None]
    if next_state.ndim != 3:
        raise ValueError(
            f"next_state has shape {next_state.shape}: must be [S, A] or [S, A, K]"
        )
    if not np.issubdtype(next_state.dtype, np.integer):
        raise ValueError(f"next_state has dtype {next_state.dtype}: must hold integers")
    shape = next_state.shape
    num_states = shape[0]
    if num_states < 1 or shape[1] < 1 or shape[2] < 1:
        raise ValueError(f"next_state has shape {shape}: every dimension must be >= 1")
    if next_state.min() < 0 or next_state.max() >= num_states:
        raise ValueError(
            f"next_state holds indices in [{next_state.min()}, {next_state.max()}]:"
            f" must be in [0, {num_states - 1}]"
        )

    def outcome_array(label: str, value: Any, dtype: Any) -> np.ndarray:
        arr = np.asarray(value, dtype=dtype)
        if arr.shape == shape[:2] and shape[2] == 1:
            arr = arr[:, :, None]
        if arr.shape != shape:
            raise ValueError(
                f"{label} has shape {np.shape(value)}: must match next_state {shape}"
            )
        return arr

    if probability is None:
        if shape[2] != 1:
            raise ValueError(f"probability is required when next_state has K={shape[2]} outcomes")
        probability = np.ones(shape, np.float32)
    probability = outcome_array("probability", probability, np.float64)
    if not np.all(np.isfinite(probability)) or probability.min() < 0:
        raise ValueError("probability must hold finite non-negative values")
    sums = probability.sum(-1)
    worst = np.abs(sums - 1.0).max()
    if worst > atol:
        s, a = np.unravel_index(np.abs(sums - 1.0).argmax(), sums.shape)
        raise ValueError(
            f"probability of state {s}, action {a} sums to {sums[s, a]:.6g}: must sum to 1"
        )
    reward = outcome_array("reward", reward, np.float32)
    if not np.all(np.isfinite(reward)):
        raise ValueError("reward must hold finite values")
    terminal = np.asarray(terminal)
    if terminal.shape == (num_states,):
        terminal = terminal.astype(bool)[next_state]
    terminal = outcome_array("terminal", terminal, bool)
    start = np.asarray(start_probability, dtype=np.float64)
    if start.shape != (num_states,):
        raise ValueError(
            f"start_probability has shape {start.shape}: must be [{num_states}]"
        )
    if not np.all(np.isfinite(start)) or start.min() < 0 or abs(start.sum() - 1.0) > atol:
        raise ValueError(
            f"start_probability sums to {start.sum():.6g}: must be non-negative and sum to 1"
        )
    check_int("max_steps", max_steps, 1)
    return TabularMDP(
        next_state=jnp.asarray(next_state, jnp.int32),
        probability=jnp.asarray(probability / sums[..., None], jnp.float32),
        reward=jnp.asarray(reward, jnp.float32),
        terminal=jnp.asarray(terminal, bool),
        start_probability=jnp.asarray(start / start.sum(), jnp.float32),
        max_steps=jnp.asarray(max_steps, jnp.int32),
        name=name,
    )


class FunctionalEnv(Protocol):
    """What :func:`compile_env` needs of a functional environment (gymnax-style)."""

    num_actions: int

    def num_codes(self, params: Any) -> int: ...
    def decode(self, code: Array, params: Any) -> Array: ...
    def encode(self, fields: Array, params: Any) -> Array: ...
    def transition(self, fields: Array, action: Array, params: Any) -> tuple[Array, Array, Array]: ...
    def start_distribution(self, params: Any) -> tuple[np.ndarray, np.ndarray]: ...


def compile_env(env: FunctionalEnv, params: Any, *, name: str | None = None) -> TabularMDP:
    """Compile a deterministic functional environment into dense tables.

    The environment's ``transition`` is vmapped over every state code and action, so the
    tables are exactly the environment's step function (state index = mixed-radix code).

    Args:
      env: the environment (e.g. :class:`~vdbejax.envs.table_cleaning.TableCleaning`).
      params: its ``EnvParams``; ``params.max_steps`` becomes the truncation length.
      name: label of the MDP (default: the environment's class name).

    Returns:
      a deterministic :class:`TabularMDP` over all ``env.num_codes(params)`` codes.
    """
    codes = jnp.arange(env.num_codes(params), dtype=jnp.int32)
    actions = jnp.arange(env.num_actions, dtype=jnp.int32)

    def one(code: Array, action: Array) -> tuple[Array, Array, Array]:
        fields = env.decode(code, params)
        next_fields, reward, terminal = env.transition(fields, action, params)
        return env.encode(next_fields, params), reward, terminal

    over_actions = jax.vmap(one, in_axes=(None, 0))
    next_state, reward, terminal = jax.jit(jax.vmap(over_actions, in_axes=(0, None)))(
        codes, actions
    )
    start_codes, start_probs = env.start_distribution(params)
    start = np.zeros(len(codes), np.float64)
    np.add.at(start, np.asarray(start_codes), np.asarray(start_probs, np.float64))
    return make_tabular_mdp(
        np.asarray(next_state),
        np.asarray(reward),
        np.asarray(terminal),
        start,
        max_steps=int(params.max_steps),
        name=name or type(env).__name__,
    )
