"""Dyna-Q and Dyna-Q+ (Sutton & Barto, *Reinforcement Learning: An Introduction*, 2nd ed.
2018, §8.2, Fig. 8.2, and §8.3).

After every real step (a Q-learning update of (s, a)), ``planning_steps`` simulated
updates (``plan_at = "step"``): a pair drawn uniformly among those seen, an outcome drawn
from the agent's count model (:mod:`vdbejax.methods.model`), and a Q-learning update of
that pair with the model's mean reward. Where we chose: the book's model stores the last
outcome of a pair (a deterministic task); ours samples the observed outcomes in
proportion to their counts, which is the same on a deterministic task and the natural
generalisation on a stochastic one.

Dyna-Q+ adds ``kappa · √τ`` to a simulated reward, τ the agent's iterations since the
pair was last tried (a ``last_tried`` table), and, as the book's footnote says, may also
plan with actions never tried in a state seen: they "lead back to the same state with a
reward of zero".
"""
from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import jax
import jax.numpy as jnp

from vdbejax._numerics import rounded, sample_categorical
from vdbejax._pytree import static_field
from vdbejax.methods.contract import Context, LearnerUpdate, Table, Transition
from vdbejax.methods.learners import QLearning, td_update
from vdbejax.methods.model import Model
from vdbejax.methods.registry import learner
from vdbejax.validation import check_in_range, check_int

Array = jax.Array


def simulated_update(q: Array, model: Model, s: Array, a: Array, u: Array, alpha: Any,
                     gamma: Any, bonus: Array, untried: Array) -> Array:
    """One Dyna planning update of (s, a) on the flat ``[S·A]`` Q: an outcome drawn from
    the model with ``u`` (an untried pair: back to ``s``, reward 0), then Q-learning."""
    A = model.visits.shape[1]
    K = model.next_count.shape[2]
    counts = model.next_count[s, a]
    weights = jnp.concatenate([counts, model.terminal[s, a][None]])
    k = sample_categorical(weights, u)
    ends = (k >= K) & ~untried
    listed = model.next_state[s, a, jnp.minimum(k, K - 1)].astype(jnp.int32)
    s_next = jnp.where(untried, s, listed)
    reward = jnp.where(untried, 0.0, model.mean_reward()[s, a]) + bonus
    row = jax.lax.dynamic_slice(q, (s_next * A,), (A,))
    discount = jnp.where(ends, 0.0, gamma)
    target = reward + rounded(discount * jnp.max(row), discount)
    index = s * A + a
    new, _ = td_update(jax.lax.dynamic_slice(q, (index,), (1,))[0], target, alpha)
    return jax.lax.dynamic_update_slice(q, new[None], (index,))


@learner("dyna_q", title="Dyna-Q")
class DynaQ(QLearning):
    """Dyna-Q (Sutton 1990; Sutton & Barto 2018, Fig. 8.2): Q-learning plus
    ``planning_steps`` (n, static) simulated updates per step on the count model."""

    planning_steps: int = static_field(5)
    uses_model = True
    plan_at = "step"

    @property
    def plan_uniforms(self) -> int:  # type: ignore[override]
        return 2 * self.planning_steps

    def planning_bonus(self, q: Array, tables: Mapping[str, Array]) -> Array:
        """``[S, A]`` bonus added to simulated rewards (none for Dyna-Q)."""
        return jnp.zeros_like(q)

    def plannable(self, model: Model) -> Array:
        """``[S, A]`` pairs planning may draw: those seen."""
        return model.visits > 0

    def plan(self, q: Array, tables: Mapping[str, Array], model: Any, context: Context,
             uniforms: tuple[Array, ...]) -> tuple[Array, dict[str, Array]]:
        S, A = q.shape
        candidates = self.plannable(model).reshape(-1).astype(jnp.float32)
        bonus = self.planning_bonus(q, tables).reshape(-1)
        flat = q.reshape(-1)
        for i in range(self.planning_steps):
            pair = sample_categorical(candidates, uniforms[2 * i])
            pair = jnp.minimum(pair, S * A - 1)  # none seen yet: weights all 0
            s, a = pair // A, pair % A
            updated = simulated_update(flat, model, s, a, uniforms[2 * i + 1], self.alpha,
                                       self.gamma, bonus[pair], model.visits[s, a] == 0)
            flat = jnp.where(jnp.any(candidates > 0), updated, flat)
        return flat.reshape(S, A), dict(tables)

    def validate(self) -> None:
        super().validate()
        check_int("planning_steps", self.planning_steps, 0)


@learner("dyna_q_plus", title="Dyna-Q+")
class DynaQPlus(DynaQ):
    """Dyna-Q+ (Sutton & Barto 2018, §8.3): Dyna-Q whose simulated rewards get ``kappa ·
    √τ`` (τ: iterations since the pair was last tried), planning also with the untried
    actions of states seen (back to the same state, reward 0)."""

    kappa: float | Array = 1e-3

    def tables(self) -> dict[str, Table]:
        return {"last_tried": Table("pair", 0.0)}

    def update(self, t: Transition) -> LearnerUpdate:
        result = super().update(t)
        return LearnerUpdate(result.q, {"last_tried": jnp.asarray(t.time, jnp.float32) + 1.0},
                             result.delta_q)

    def planning_bonus(self, q: Array, tables: Mapping[str, Array]) -> Array:
        last = tables["last_tried"]
        now = jnp.max(last)  # the pair just tried holds the current time
        return rounded(self.kappa * jnp.sqrt(now - last), self.kappa)

    def plannable(self, model: Model) -> Array:
        seen_states = jnp.any(model.visits > 0, axis=1, keepdims=True)
        return jnp.broadcast_to(seen_states, model.visits.shape)

    def validate(self) -> None:
        super().validate()
        check_in_range("kappa", self.kappa, 0.0, 1e30)
