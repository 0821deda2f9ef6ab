"""Finite MDPs as dense tables, and compilation of functional environments into them.

A :class:`TabularMDP` stores, for every state-action pair, ``K`` possible outcomes
(next state, probability, reward, terminal flag); a deterministic MDP has ``K = 1``.
The engine only needs :meth:`TabularMDP.start` and :meth:`TabularMDP.transition`,
both pure functions of integer state indices and uniforms, so any finite MDP runs
through the same code.

:func:`compile_env` turns a functional environment (integer-coded states) into such tables,
either over every state code or, with ``reachable_only=True``, over the codes reachable from
its start distribution (found by a vectorised breadth-first search); the kept codes are then
stored in :attr:`TabularMDP.state_codes` (state index ↔ environment code).
"""
from __future__ import annotations

from typing import Any, Protocol

import jax
import numpy as np

from vdbejax._numerics import sample_categorical
from vdbejax._pytree import pytree_dataclass, static_field

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
    """

    next_state: Array
    probability: Array
    reward: Array
    terminal: Array
    start_probability: Array
    max_steps: Array
    name: str = static_field("mdp")
    state_codes: Array | None = None

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

    def transition(self, state: Array, action: Array, u: Array) -> tuple[Array, Array, Array]:
        """One transition from integer ``state`` under ``action``.

        Args:
          state: int32 state index.
          action: int32 action index.
          u: uniform in [0, 1) choosing the outcome (unused when ``K = 1``).

        Returns:
          ``(next_state, reward, terminal)``.
        """
        # static: deterministic MDPs skip the draw
        k: int | Array = (0 if self.num_outcomes == 1
                          else sample_categorical(self.probability[state, action], u))
        return (
            self.next_state[state, action, k],
            self.reward[state, action, k],
            self.terminal[state, action, k],
        )


def _as_array(label: str, value: Any, dtype: Any = None) -> np.ndarray:
    """``np.asarray`` whose failures (ragged lists, strings) name the parameter."""
    try:
        return np.asarray(value, dtype=dtype)
    except (TypeError, ValueError) as err:
        first_line = str(err).splitlines()[0] if str(err) else type(err).__name__
        raise ValueError(f"{label} cannot be read as an array ({first_line}):"
                         " must be a rectangular array of numbers") from None


def _first_bad(label: str, arr: np.ndarray, bad: np.ndarray, allowed: str) -> None:
    """Raise for the first element of ``arr`` where ``bad`` holds, naming its position."""
    if np.any(bad):
        where = tuple(int(i) for i in np.unravel_index(np.argmax(bad), bad.shape))
        raise ValueError(f"{label}{list(where)} = {arr[where].item()!r}: {allowed}")


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

    Returns:
      the :class:`TabularMDP`.

    Raises:
      ValueError: one line naming the parameter, the offending shape or value, and what is
        allowed (wrong shapes or dtypes, out-of-range indices, negative probabilities or
        sums other than 1, non-finite rewards, ``max_steps`` not in [1, 2**31 − 1], …).
    """
    from vdbejax.validation import INT32_MAX, check_int, check_positive

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
    _first_bad("next_state", next_state, (next_state < 0) | (next_state >= num_states),
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
        _first_bad("probability", probability, ~np.isfinite(probability) | (probability < 0),
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
    _first_bad("reward", reward, ~np.isfinite(reward), "must be finite in float32")
    terminal = _as_array("terminal", terminal)
    if terminal.shape == (num_states,):
        terminal = terminal[next_state]  # terminal states -> terminal outcomes
    terminal = outcome_array("terminal", terminal, None)
    if terminal.dtype != bool:
        _first_bad("terminal", terminal, (terminal != 0) & (terminal != 1),
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
    _first_bad("start_probability", start, ~np.isfinite(start) | (start < 0),
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
    return TabularMDP(
        next_state=_on_device(next_state, np.int32),
        probability=_on_device(probability, np.float32),
        reward=_on_device(reward, np.float32),
        terminal=_on_device(terminal, bool),
        start_probability=_on_device(start / start.sum(), np.float32),
        max_steps=_on_device(max_steps, np.int32),
        name=name,
        state_codes=codes,
    )


class FunctionalEnv(Protocol):
    """What :func:`compile_env` needs of a functional environment (gymnax-style)."""

    num_actions: int

    def num_codes(self, params: Any) -> int: ...
    def decode(self, code: Array, params: Any) -> Array: ...
    def encode(self, fields: Array, params: Any) -> Array: ...
    def transition(self, fields: Array, action: Array, params: Any
                   ) -> tuple[Array, Array, Array]: ...
    def start_distribution(self, params: Any) -> tuple[np.ndarray, np.ndarray]: ...


#: Largest number of state codes :func:`compile_env` handles (codes are int32 in JAX).
MAX_CODES = 2**31 - 1


def _vmapped_step(env: FunctionalEnv, params: Any) -> Any:
    """``step(codes [B], actions [A]) -> (next_codes, reward, terminal)``, each ``[B, A]``."""

    def one(code: Array, action: Array) -> tuple[Array, Array, Array]:
        fields = env.decode(code, params)
        next_fields, reward, terminal = env.transition(fields, action, params)
        return env.encode(next_fields, params), reward, terminal

    return jax.vmap(jax.vmap(one, in_axes=(None, 0)), in_axes=(0, None))


def _code_stepper(env: FunctionalEnv, params: Any) -> tuple[Any, np.ndarray]:
    """``(step, actions)``: jitted ``step(codes [B], actions) -> (next_codes, reward,
    terminal)``, each ``[B, A]``, and the int32 action indices.

    A fresh ``jax.jit`` per call, so the environment is traced as it is now (a patched
    constant or an edited method is seen), with ``params`` baked in.
    """
    actions = np.arange(env.num_actions, dtype=np.int32)
    return jax.jit(_vmapped_step(env, params)), actions


def _step_codes(step: Any, actions: np.ndarray, codes: np.ndarray, batch_size: int
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Apply ``step`` to ``codes`` in batches padded to ``batch_size`` or, for a short
    last batch, to ``batch_size / 16``: two shapes at most, as each costs a compilation
    (~1–3 s) while padding wastes run time (~0.5 s per 65536 codes of a large variant).
    """
    outputs = []
    small = max(1, batch_size // 16)
    for begin in range(0, len(codes), batch_size):
        part = codes[begin: begin + batch_size]
        padded = np.zeros(small if len(part) <= small else batch_size, np.int32)
        padded[: len(part)] = part
        next_codes, reward, terminal = step(padded, actions)
        outputs.append((np.asarray(next_codes)[: len(part)], np.asarray(reward)[: len(part)],
                        np.asarray(terminal)[: len(part)]))
    # zip(*outputs): the batches' (next_codes, reward, terminal), three arrays each.
    next_codes, reward, terminal = (np.concatenate(arrays)
                                    for arrays in zip(*outputs, strict=True))
    return next_codes, reward, terminal


def _reachable_codes(step: Any, actions: np.ndarray, start_codes: np.ndarray, num_codes: int,
                     batch_size: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Closure of ``start_codes`` under every action: level-synchronous BFS over codes.

    Terminal outcomes are followed too, so the kept codes are closed under the transition
    table and the result is exactly the dense table restricted to them. Membership is a
    ``num_codes``-byte boolean map (hash-based ``np.unique`` was 10x slower).

    Returns:
      ``(codes, next_codes, reward, terminal)`` with ``codes`` sorted increasingly and the
      other arrays in the same row order.
    """
    seen = np.zeros(num_codes, bool)
    seen[start_codes] = True
    frontier = np.flatnonzero(seen)
    rows: list[list[np.ndarray | None]] = []
    while frontier.size:
        next_codes, reward, terminal = _step_codes(step, actions, frontier, batch_size)
        rows.append([frontier, next_codes, reward, terminal])
        fresh = next_codes.ravel()
        fresh = np.sort(fresh[~seen[fresh]])
        frontier = fresh[np.r_[True, fresh[1:] != fresh[:-1]]] if fresh.size else fresh
        seen[frontier] = True
    del seen
    order = np.argsort(np.concatenate([row[0] for row in rows]))
    # One table at a time, freeing each level's pieces (peak memory at 10^7 states).
    columns = []
    for column in range(4):
        table = np.concatenate([row[column] for row in rows])
        for row in rows:
            row[column] = None
        columns.append(table[order])
        del table
    codes, next_codes, reward, terminal = columns
    return codes, next_codes, reward, terminal


def compile_env(
    env: FunctionalEnv,
    params: Any,
    *,
    name: str | None = None,
    reachable_only: bool = False,
    batch_size: int = 1 << 14,
) -> TabularMDP:
    """Compile a deterministic functional environment into dense tables.

    The environment's ``transition`` is vmapped over state codes and actions, so the
    tables are exactly the environment's step function.

    Args:
      env: the environment (e.g. :class:`~vdbejax.envs.table_cleaning.TableCleaning`).
      params: its ``EnvParams``; ``params.max_steps`` becomes the truncation length.
      name: label of the MDP (default: the environment's class name).
      reachable_only: keep only the codes reachable from the start distribution (a
        vectorised breadth-first search that evaluates only reachable codes; memory: one
        byte per code for the visited map, plus the tables of the reachable states). State
        ``i`` is then the ``i``-th smallest reachable code, kept in ``mdp.state_codes``
        (see :meth:`TabularMDP.index_of`). Otherwise state index = code, over all
        ``env.num_codes(params)`` codes.
      batch_size: codes evaluated per jitted call (bounds memory, not the result).

    Returns:
      a deterministic :class:`TabularMDP`.

    Raises:
      ValueError: more than :data:`MAX_CODES` codes, or invalid ``batch_size``.
    """
    from vdbejax.validation import check_int

    check_int("batch_size", batch_size, 1)
    num_codes = int(env.num_codes(params))
    if num_codes > MAX_CODES:
        raise ValueError(f"env.num_codes(params)={num_codes} is invalid: must be <= 2**31 - 1"
                         " (int32 state codes)")
    step, actions = _code_stepper(env, params)
    batch_size = min(batch_size, 1 << (num_codes - 1).bit_length())  # small envs: small pad
    start_codes, start_probs = env.start_distribution(params)
    start_codes = np.asarray(start_codes, np.int64)
    if reachable_only:
        state_codes, next_codes, reward, terminal = _reachable_codes(
            step, actions, start_codes, num_codes, batch_size
        )
        next_state = np.searchsorted(state_codes, next_codes).astype(np.int32)
        del next_codes
        start_index = np.searchsorted(state_codes, start_codes)
    else:
        state_codes = None
        next_state, reward, terminal = _step_codes(
            step, actions, np.arange(num_codes, dtype=np.int32), batch_size
        )
        start_index = start_codes
    start = np.zeros(len(next_state), np.float64)
    np.add.at(start, start_index, np.asarray(start_probs, np.float64))
    return make_tabular_mdp(
        next_state,
        reward,
        terminal,
        start,
        max_steps=int(params.max_steps),
        name=name or type(env).__name__,
        state_codes=state_codes,
    )
