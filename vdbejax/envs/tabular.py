"""Finite MDPs as dense tables, and compilation of functional environments into them.

A :class:`TabularMDP` stores, for every state-action pair, ``K`` possible outcomes
(next state, probability, reward, terminal flag); a deterministic MDP has ``K = 1``.
The engine only needs :meth:`TabularMDP.start` and :meth:`TabularMDP.transition`,
both pure functions of integer state indices and uniforms, so any finite MDP runs
through the same code.

:func:`~vdbejax.envs.compiled.compile_env` (``vdbejax.envs.compiled``) turns a functional
environment into such tables.
"""
from __future__ import annotations

from typing import Any

import jax
import numpy as np

from vdbejax._numerics import sample_categorical
from vdbejax._pytree import pytree_dataclass, static_field
from vdbejax.envs.reward_noise import RewardNoise, make_reward_noise, noisy_reward
from vdbejax.validation import INT32_MAX, check_int, check_positive, first_bad

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
      state_codes: int32 ``[S]`` increasing environment code of each state index, or
        ``None`` when state index = code (dense compilation, MDPs built from arrays).
        ``None`` adds no pytree leaf, so such MDPs keep their fingerprints.
      reward_noise: the outcomes' noise models (:mod:`vdbejax.envs.reward_noise`; ``reward``
        then holds their means), or ``None`` when every reward is its mean: no leaf, no
        draw, the bits and fingerprint of a task without noise.
      optimal_action: bool ``[S, A]``, the actions a run counts as optimal when it records
        the fraction of optimal actions (set on the engine's copy of the task by
        :func:`vdbejax.engine.chunk_loop.with_optimal_action`), or ``None``: no
        record, no leaf (the task's program, bits and fingerprint as without it).
    """

    next_state: Array
    probability: Array
    reward: Array
    terminal: Array
    start_probability: Array
    max_steps: Array
    name: str = static_field("mdp")
    state_codes: Array | None = None
    reward_noise: RewardNoise | None = None
    optimal_action: Array | None = None

    @property
    def num_states(self) -> int:
        return int(self.next_state.shape[0])

    @property
    def num_actions(self) -> int:
        return int(self.next_state.shape[1])

    @property
    def num_outcomes(self) -> int:
        return int(self.next_state.shape[2])

    def index_of(self, codes: Any) -> np.ndarray:
        """State indices of environment codes (numpy, outside jit).

        Args:
          codes: integer code(s) of the environment's state encoding.

        Returns:
          int64 indices, same shape as ``codes``.

        Raises:
          ValueError: a code that is not a state of this MDP.
        """
        codes = np.asarray(codes, np.int64)
        if self.state_codes is None:
            index = codes
            known = (codes >= 0) & (codes < self.num_states)
        else:
            table = np.asarray(self.state_codes, np.int64)
            index = np.minimum(np.searchsorted(table, codes), len(table) - 1)
            known = table[index] == codes
        if not np.all(known):
            bad = codes[~known].ravel()[0]
            raise ValueError(f"codes holds {bad}: not a state of MDP {self.name!r}")
        return index

    def code_of(self, index: Any) -> np.ndarray:
        """Environment codes of state indices (numpy; identity without ``state_codes``).

        Args:
          index: state index (or indices).

        Returns:
          int64 codes, same shape as ``index``.
        """
        index = np.asarray(index, np.int64)
        if self.state_codes is None:
            return index
        return np.asarray(self.state_codes, np.int64)[index]

    def start(self, u: Array) -> Array:
        """Sample an initial state index from ``start_probability``.

        Args:
          u: uniform in [0, 1).

        Returns:
          int32 state index.
        """
        return sample_categorical(self.start_probability, u)

    def transition(self, state: Array, action: Array, u: Array, noise_u: Array | None = None
                   ) -> tuple[Array, Array, Array]:
        """One transition from integer ``state`` under ``action``.

        Args:
          state: int32 state index.
          action: int32 action index.
          u: uniform in [0, 1) choosing the outcome (unused when ``K = 1``).
          noise_u: uniform in (0, 1) drawing the reward around its mean (a task with
            ``reward_noise`` only).

        Returns:
          ``(next_state, reward, terminal)``.

        Raises:
          ValueError: ``noise_u`` missing for a task with reward noise.
        """
        # static: deterministic MDPs skip the draw
        k: int | Array = (0 if self.num_outcomes == 1
                          else sample_categorical(self.probability[state, action], u))
        return (
            self.next_state[state, action, k],
            self.reward_at(state, action, k, noise_u),
            self.terminal[state, action, k],
        )

    def reward_at(self, state: Array, action: Array, k: Any, noise_u: Array | None) -> Array:
        """The reward of outcome ``k`` of ``(state, action)``: its mean, or a draw around it
        with ``noise_u`` where the task has reward noise."""
        mean = self.reward[state, action, k]
        if self.reward_noise is None:  # static: a task without noise draws nothing
            return mean
        if noise_u is None:
            raise ValueError(f"noise_u is None but MDP {self.name!r} has reward noise:"
                             " pass a uniform in (0, 1)")
        return noisy_reward(mean, self.reward_noise.model[state, action, k],
                            self.reward_noise.std[state, action, k], noise_u)


def _as_array(label: str, value: Any, dtype: Any = None) -> np.ndarray:
    """``np.asarray`` whose failures (ragged lists, strings) name the parameter."""
    try:
        return np.asarray(value, dtype=dtype)
    except (TypeError, ValueError) as err:
        first_line = str(err).splitlines()[0] if str(err) else type(err).__name__
        raise ValueError(f"{label} cannot be read as an array ({first_line}):"
                         " must be a rectangular array of numbers") from None


def _on_device(value: Any, dtype: Any) -> Array:
    """``value`` as a device array of ``dtype``, converted on the host (a plain copy to
    the device: ``jnp.asarray`` would compile a small conversion program per shape)."""
    return jax.device_put(np.asarray(value, dtype, order="C"))


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
    state_codes: Any | None = None,
    reward_noise: Any | None = None,
    reward_std: Any | None = None,
) -> TabularMDP:
    """Build a validated :class:`TabularMDP` from arrays.

    Deterministic MDPs pass ``[S, A]`` arrays and no ``probability``; stochastic ones pass
    ``[S, A, K]`` arrays and ``probability`` of the same shape (outcomes of probability 0
    pad pairs with fewer than ``K`` outcomes). ``terminal`` may also be a ``[S]`` array of
    terminal *states* (an outcome is terminal when its next state is).

    Args:
      next_state: int ``[S, A]`` or ``[S, A, K]`` next-state indices in ``[0, S)``.
      reward: ``next_state``-shaped finite rewards.
      terminal: ``next_state``-shaped (or ``[S]``) flags, bool or 0/1.
      start_probability: ``[S]`` non-negative initial-state probabilities summing to 1.
      probability: ``[S, A, K]`` non-negative outcome probabilities, each ``[s, a]`` row
        summing to 1 (required when ``K > 1``).
      max_steps: truncation length (integer >= 1).
      name: label of the MDP.
      atol: tolerance of the sums to 1 (sums are then renormalised exactly).
      state_codes: optional ``[S]`` strictly increasing non-negative integer codes of the
        states in some environment encoding (see :func:`compile_env`).
      reward_noise: ``None`` (rewards are exact), or the noise model of every outcome
        (``"none"``, ``"gaussian"``, ``"bernoulli"``, :mod:`vdbejax.envs.reward_noise`) or
        a ``next_state``-shaped array of them; ``reward`` then holds the means (in [0, 1]
        for Bernoulli outcomes).
      reward_std: the standard deviation of the Gaussian outcomes (a number >= 0 or a
        ``next_state``-shaped array); needed exactly when some outcome is Gaussian.

    Returns:
      the :class:`TabularMDP`.

    Raises:
      ValueError: one line naming the parameter, the offending shape or value, and what is
        allowed (wrong shapes or dtypes, out-of-range indices, negative probabilities or
        sums other than 1, non-finite rewards, ``max_steps`` not in [1, 2**31 − 1], an
        unknown noise model, a negative standard deviation, …).
    """
    if not isinstance(name, str) or not name:
        raise ValueError(f"name={name!r} is invalid: must be a non-empty string")
    check_positive("atol", atol)
    check_int("max_steps", max_steps, 1, INT32_MAX)  # stored as an int32
    next_state = _as_array("next_state", next_state)
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
    if min(shape) < 1:
        raise ValueError(f"next_state has shape {shape}: every dimension must be >= 1")
    first_bad("next_state", next_state, (next_state < 0) | (next_state >= num_states),
               f"must be a state index in [0, {num_states - 1}]")

    def outcome_array(label: str, value: Any, dtype: Any) -> np.ndarray:
        arr = _as_array(label, value)
        if arr.shape == shape[:2] and shape[2] == 1:
            arr = arr[:, :, None]
        if arr.shape != shape:
            allowed = f"{list(shape)}" + (f" or {list(shape[:2])}" if shape[2] == 1 else "")
            raise ValueError(f"{label} has shape {np.shape(value)}: must be {allowed}"
                             " (the shape of next_state)")
        if not (np.issubdtype(arr.dtype, np.number) or arr.dtype == bool):
            raise ValueError(f"{label} has dtype {arr.dtype}: must hold numbers")
        with np.errstate(over="ignore"):  # overflow to inf is reported by the caller
            return arr if dtype is None else arr.astype(dtype, copy=False)

    if probability is None:
        if shape[2] != 1:
            raise ValueError(
                f"probability is None but next_state has K={shape[2]} outcomes per pair:"
                f" pass probability of shape {list(shape)}"
            )
        probability = np.ones(shape, np.float32)  # exact: nothing to check or normalise
    else:
        probability = outcome_array("probability", probability, np.float64)
        first_bad("probability", probability, ~np.isfinite(probability) | (probability < 0),
                   "must be finite and >= 0")
        sums = probability.sum(-1, keepdims=True)
        error = np.abs(sums[..., 0] - 1.0)
        if error.max() > atol:
            s, a = np.unravel_index(error.argmax(), error.shape)
            raise ValueError(
                f"probability[{s}, {a}] sums to {sums[s, a, 0]:.6g}: the outcome probabilities"
                f" of each state-action pair must sum to 1 (atol {atol:g})"
            )
        probability = (probability / sums).astype(np.float32)
    # float32 as stored: a float64 reward beyond float32's range would become inf.
    reward = outcome_array("reward", reward, np.float32)
    first_bad("reward", reward, ~np.isfinite(reward), "must be finite in float32")
    terminal = _as_array("terminal", terminal)
    if terminal.shape == (num_states,):
        terminal = terminal[next_state]  # terminal states -> terminal outcomes
    terminal = outcome_array("terminal", terminal, None)
    if terminal.dtype != bool:
        first_bad("terminal", terminal, (terminal != 0) & (terminal != 1),
                   "must be a bool or 0/1")
        terminal = terminal != 0
    start = _as_array("start_probability", start_probability)
    if start.shape != (num_states,):
        raise ValueError(
            f"start_probability has shape {start.shape}: must be [{num_states}] (one per state)"
        )
    if not np.issubdtype(start.dtype, np.number):
        raise ValueError(f"start_probability has dtype {start.dtype}: must hold numbers")
    start = start.astype(np.float64)
    first_bad("start_probability", start, ~np.isfinite(start) | (start < 0),
               "must be finite and >= 0")
    if abs(start.sum() - 1.0) > atol:
        raise ValueError(
            f"start_probability sums to {start.sum():.6g}: must sum to 1 (atol {atol:g})"
        )
    codes: Array | None = None
    if state_codes is not None:
        given = _as_array("state_codes", state_codes)
        if given.shape != (num_states,) or not np.issubdtype(given.dtype, np.integer):
            raise ValueError(f"state_codes has shape {given.shape} and dtype {given.dtype}:"
                             f" must be [{num_states}] integers")
        if (num_states > 1 and not np.all(np.diff(given) > 0)) or given[0] < 0:
            raise ValueError("state_codes is not strictly increasing and >= 0:"
                             " must list distinct non-negative codes in increasing order")
        if given[-1] > np.iinfo(np.int32).max:
            raise ValueError(f"state_codes holds {given[-1]}: must be < 2**31")
        codes = _on_device(given, np.int32)
    noise = make_reward_noise(reward, reward_noise, reward_std, outcome_array)
    return TabularMDP(
        next_state=_on_device(next_state, np.int32),
        probability=_on_device(probability, np.float32),
        reward=_on_device(reward, np.float32),
        terminal=_on_device(terminal, bool),
        start_probability=_on_device(start / start.sum(), np.float32),
        max_steps=_on_device(max_steps, np.int32),
        name=name,
        state_codes=codes,
        reward_noise=None if noise is None else RewardNoise(
            model=_on_device(noise[0], np.int32), std=_on_device(noise[1], np.float32)),
    )
