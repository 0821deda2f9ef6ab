"""Compilation of functional environments (integer-coded states) into a :class:`TabularMDP`.

:func:`compile_env` vmaps the environment's transition over its state codes, either over
every code or, with ``reachable_only=True``, over the codes reachable from its start
distribution (found by a vectorised breadth-first search); the kept codes are then stored
in :attr:`TabularMDP.state_codes` (state index ↔ environment code).
"""
from __future__ import annotations

from typing import Any, Protocol

import jax
import numpy as np

from vdbejax.envs.tabular import TabularMDP, make_tabular_mdp

Array = jax.Array


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
