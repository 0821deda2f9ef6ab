"""An agent's model of its task, learned from its own transitions, and planning on it.

A learner with ``uses_model = True`` gets a :class:`Model` in :meth:`Learner.plan
<vdbejax.methods.contract.Learner.plan>`. The engine keeps it per agent and updates it at
every learning step with :func:`observe` (before the learner's own update), from
``(s, a, r, s′, terminal)``. For each (s, a) it counts:

* ``visits`` n(s, a), ``reward_sum`` Σ r, ``reward_squares`` Σ r², ``terminal`` the
  outcomes that ended the episode (their successor's value is 0, whatever it is);
* ``next_state`` / ``next_count``: a list of the non-terminal successors s′ seen from
  (s, a), with their counts, in the order first seen.

The list holds :func:`capacity` ``K = min(S, mdp.num_outcomes)`` successors: the most
distinct successors any (s, a) of the task can reach, so it never overflows, and the model
is exactly the dense count table ``[S, A, S]`` at ``K/S`` of its memory (on the paper's
deterministic task ``K = 1``). Successor indices are stored as float32 (exact below 2²⁴
states) beside the other tables.

The sums over a pair's successors are written out one by one (no reduction whose order
the compiler chooses), so planning gives the same bits in every engine strategy.
"""
from __future__ import annotations

from collections.abc import Callable

import jax
import jax.numpy as jnp

from vdbejax._numerics import rounded
from vdbejax._pytree import pytree_dataclass

Array = jax.Array

#: The engine's tables of a model, by name: ``"pair"`` ``[S, A]``, ``"outcome"``
#: ``[S, A, K]``. The names are reserved (a plug-in's table cannot start with ``model_``).
MODEL_TABLES = {
    "model_visits": "pair",
    "model_reward_sum": "pair",
    "model_reward_squares": "pair",
    "model_terminal": "pair",
    "model_next_state": "outcome",
    "model_next_count": "outcome",
}
MODEL_PREFIX = "model_"


def capacity(num_states: int, num_outcomes: int) -> int:
    """Successors a model lists per (s, a): the most the task can have."""
    return max(1, min(int(num_states), int(num_outcomes)))


@pytree_dataclass
class Model:
    """One agent's counts (see the module docstring): ``visits``, ``reward_sum``,
    ``reward_squares``, ``terminal`` ``[S, A]``; ``next_state``, ``next_count``
    ``[S, A, K]``."""

    visits: Array
    reward_sum: Array
    reward_squares: Array
    terminal: Array
    next_state: Array
    next_count: Array

    @classmethod
    def from_tables(cls, tables: dict[str, Array]) -> Model:
        """The model held in an agent's tables (:data:`MODEL_TABLES`)."""
        return cls(*(tables[name] for name in MODEL_TABLES))

    def mean_reward(self) -> Array:
        """r̂(s, a) = Σ r / n (0 where n = 0)."""
        return self.reward_sum / jnp.maximum(self.visits, 1.0)

    def terminal_probability(self) -> Array:
        """P̂(terminal | s, a) (0 where n = 0)."""
        return self.terminal / jnp.maximum(self.visits, 1.0)

    def successor_probabilities(self) -> Array:
        """``[S, A, K]`` P̂(s′_k | s, a) of the listed successors (0 where n = 0)."""
        return self.next_count / jnp.maximum(self.visits, 1.0)[..., None]

    def expected(self, values: Array) -> Array:
        """``[S, A]`` Σ_s′ P̂(s′ | s, a) · values(s′) over non-terminal outcomes (a
        terminal outcome is worth 0; 0 where n = 0)."""
        return expected_under(self.successor_probabilities(), self.next_state, values)


def expected_under(probabilities: Array, next_state: Array, values: Array) -> Array:
    """``[S, A]`` Σ_k probabilities[..., k] · values[next_state[..., k]], summed in order
    of k (the same bits under any batching)."""
    index = next_state.astype(jnp.int32)
    total = jnp.zeros(probabilities.shape[:-1], values.dtype)
    for k in range(probabilities.shape[-1]):
        p = probabilities[..., k]
        total = total + rounded(p * values[index[..., k]], p)
    return total


def bellman_backup(reward: Array, gamma: float | Array, expected: Array) -> Array:
    """One Bellman backup, ``r(s, a) + γ · E[V(s′) | s, a]``, from the expected next value
    (:func:`expected_under` over listed outcomes, or PSRL's sum over a sampled table).

    The discounted term is rounded before the addition (never fused into an FMA), so value
    iteration, the finite-horizon stages and the evaluation of a policy back up alike, with
    the same bits in every engine strategy.
    """
    return reward + rounded(gamma * expected, gamma)


def observe(rows: dict[str, Array], next_state: Array, reward: Array,
            terminal: Array) -> dict[str, Array]:
    """One (s, a)'s model rows after the outcome ``(r, s′, terminal)``: ``rows`` maps
    each of :data:`MODEL_TABLES` to its value at (s, a) (``[K]`` for the lists)."""
    listed, count = rows["model_next_state"], rows["model_next_count"]
    successor = jnp.asarray(next_state, listed.dtype)
    used = count > 0
    same = used & (listed == successor)
    free = ~used & (jnp.cumsum(~used) == 1)  # the first free slot
    slot = jnp.where(jnp.any(same), same, free) & ~terminal
    return {
        "model_visits": rows["model_visits"] + 1.0,
        "model_reward_sum": rows["model_reward_sum"] + reward,
        "model_reward_squares": rows["model_reward_squares"] + rounded(reward * reward, reward),
        "model_terminal": rows["model_terminal"] + terminal.astype(jnp.float32),
        "model_next_state": jnp.where(slot, successor, listed),
        "model_next_count": count + slot.astype(count.dtype),
    }


def greedy_values(q: Array) -> Array:
    """``[S]`` max_a Q(s, a)."""
    return jnp.max(q, axis=-1)


def value_iteration(backup: Callable[[Array], Array], q: Array, *, tolerance: float | Array,
                    max_sweeps: int) -> Array:
    """Iterate ``q ← backup(q)`` from ``q`` until no entry moves by more than
    ``tolerance`` or ``max_sweeps`` sweeps ran (a ``while`` loop; per agent under vmap)."""

    def go(carry: tuple) -> Array:
        _, change, sweeps = carry
        return (change > tolerance) & (sweeps < max_sweeps)

    def sweep(carry: tuple) -> tuple:
        q, _, sweeps = carry
        new = backup(q)
        return new, jnp.max(jnp.abs(new - q)), sweeps + 1

    start = (q, jnp.asarray(jnp.inf, q.dtype), jnp.asarray(0, jnp.int32))
    return jax.lax.while_loop(go, sweep, start)[0]


__all__ = ["MODEL_TABLES", "Model", "bellman_backup", "capacity", "expected_under",
           "greedy_values", "observe", "value_iteration"]
