"""Delayed Q-learning (Strehl, Li, Wiewiora, Langford & Littman 2006, "PAC model-free
reinforcement learning", ICML, Alg. 1).

Q starts at ``r_max/(1 − γ)`` and only ever falls. A pair collects ``m`` targets ``r +
γ max_a′ Q(s′, a′)`` while its ``LEARN`` flag is up; after the m-th it is lowered to their
mean plus ε₁ if that is at least 2ε₁ below Q(s, a) (an *attempted update*, successful),
and the flag drops when an attempt fails and no Q value changed since the pair's previous
attempt; a dropped flag rises again once any Q value has changed since. The paper's
clock t is the agent's iteration count (``Transition.time`` + 1, resets included); t* (the
last successful update) is one value for the whole agent, which is why the learner
updates its whole table (``updates_whole_table``). A terminal step's target is ``r``.
"""
from __future__ import annotations

from collections.abc import Mapping

import jax
import jax.numpy as jnp

from vdbejax._numerics import rounded
from vdbejax.methods.contract import Learner, LearnerUpdate, Table, Transition
from vdbejax.methods.learners import PAPER_GAMMA, masked_value, pair_mask
from vdbejax.methods.registry import learner
from vdbejax.validation import check_in_range

Array = jax.Array


@learner("delayed_q", title="Delayed Q-learning")
class DelayedQ(Learner):
    """Delayed Q-learning: ``m`` (``updates``) targets per attempted update, bonus ε₁
    (``epsilon1``), Q₀ = ``r_max/(1 − γ)``; act greedily (explorer ``greedy``)."""

    gamma: float | Array = PAPER_GAMMA
    updates: float | Array = 5.0
    epsilon1: float | Array = 0.01
    r_max: float | Array = 1.0
    updates_whole_table = True

    def tables(self) -> dict[str, Table]:
        return {"target_sum": Table("pair", 0.0), "targets": Table("pair", 0.0),
                "learning": Table("pair", 1.0), "attempted": Table("pair", 0.0),
                "changed": Table("pair", 0.0)}  # t* in every entry (one value per agent)

    def initial_q(self, key: Array, num_states: int, num_actions: int) -> Array:
        return jnp.full((num_states, num_actions), self.r_max / (1.0 - self.gamma), jnp.float32)

    def update(self, t: Transition) -> LearnerUpdate:  # the engine calls update_table
        raise NotImplementedError("delayed_q updates its whole table (update_table)")

    def update_table(self, q: Array, tables: Mapping[str, Array],
                     t: Transition) -> LearnerUpdate:
        assert t.state is not None and t.action is not None and t.time is not None
        here = pair_mask(q, t.state, t.action)

        def at(table: Array) -> Array:  # the value at (s, a)
            return masked_value(table, here)

        now = jnp.asarray(t.time, jnp.float32) + 1.0
        changed = tables["changed"][0, 0]
        learning = at(tables["learning"]) > 0.5
        total = at(tables["target_sum"]) + t.reward + rounded(
            t.discount * jnp.max(t.q_next), t.discount)
        count = at(tables["targets"]) + 1.0
        attempt = learning & (count >= self.updates)
        mean = total / self.updates
        success = attempt & (t.q - mean >= 2.0 * self.epsilon1)
        new_q_sa = jnp.where(success, mean + self.epsilon1, t.q)
        attempted_before = at(tables["attempted"])
        stop = attempt & ~success & (attempted_before >= changed)
        restart = ~learning & (attempted_before < changed)
        new = {
            "target_sum": jnp.where(learning & ~attempt, total, 0.0),
            "targets": jnp.where(learning & ~attempt, count, 0.0),
            "learning": jnp.where(stop, 0.0, jnp.where(restart, 1.0, at(tables["learning"]))),
            "attempted": jnp.where(attempt, now, attempted_before),
        }
        tables = {name: jnp.where(here, value, tables[name]) for name, value in new.items()}
        tables["changed"] = jnp.full_like(q, jnp.where(success, now, changed))
        return LearnerUpdate(jnp.where(here, new_q_sa, q), tables, new_q_sa - t.q)

    def validate(self) -> None:
        check_in_range("gamma", self.gamma, 0.0, 1.0, high_open=True)
        check_in_range("updates", self.updates, 1.0, 1e9)
        check_in_range("epsilon1", self.epsilon1, 0.0, 1e30)
        check_in_range("r_max", self.r_max, 0.0, 1e30, low_open=True)
