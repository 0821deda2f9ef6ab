"""Eligibility traces: SARSA(λ) and Watkins's Q(λ) (Sutton & Barto, *Reinforcement
Learning: An Introduction*, 1998, §7.5 and §7.6, Figs. 7.11 and 7.14; 2nd ed. 2018, ch. 12).

Each keeps a trace ``e(s, a)`` per pair (a learner table) and updates its whole Q every
step (``updates_whole_table``): with δ the TD error of (s, a), first ``e(s, a) ← e(s, a) +
1`` (``accumulating``) or ``← 1`` (``replacing``), then ``Q ← Q + α δ e`` and ``e ← γ λ
e`` everywhere. Both choose a′ before the update (``uses_next_action``). Traces are
cleared at each episode's first step (after a terminal step or a truncation alike), so
no credit crosses an episode boundary.
"""
from __future__ import annotations

from collections.abc import Mapping

import jax
import jax.numpy as jnp

from vdbejax._numerics import rounded
from vdbejax._pytree import pytree_dataclass, static_field
from vdbejax.methods.contract import Learner, LearnerUpdate, Table, Transition
from vdbejax.methods.learners import PAPER_ALPHA, PAPER_GAMMA, pair_mask, sarsa_target
from vdbejax.methods.registry import learner
from vdbejax.validation import check_choice, check_finite, check_in_range

Array = jax.Array

#: How the visited pair's trace grows.
TRACE_KINDS = ("accumulating", "replacing")


def trace_update(q: Array, trace: Array, state: Array, action: Array, td_error: Array,
                 alpha: float | Array, decay: float | Array, kind: str,
                 first_step: Array) -> tuple[Array, Array]:
    """``(Q + α δ e, decay · e)`` after marking (s, a) in ``e`` (cleared on the episode's
    first step); ``decay`` is γλ, or 0 to cut the traces (Watkins's exploratory a′)."""
    trace = jnp.where(first_step, 0.0, trace)
    visited = pair_mask(q, state, action)
    trace = jnp.where(visited, trace + 1.0 if kind == "accumulating" else 1.0, trace)
    step = rounded(alpha * td_error, alpha)
    return q + rounded(step * trace, step), rounded(decay * trace, decay)


@pytree_dataclass
class _TraceLearner(Learner):
    alpha: float | Array = PAPER_ALPHA
    gamma: float | Array = PAPER_GAMMA
    lam: float | Array = 0.9
    q_init: float | Array = 0.0
    trace: str = static_field("replacing")
    uses_next_action = True
    updates_whole_table = True

    def tables(self) -> dict[str, Table]:
        return {"trace": Table("pair", 0.0)}

    def update(self, t: Transition) -> LearnerUpdate:  # the engine calls update_table
        raise NotImplementedError(f"{self.name}: updates its whole table (update_table)")

    def target_and_decay(self, t: Transition) -> tuple[Array, Array]:
        raise NotImplementedError

    def update_table(self, q: Array, tables: Mapping[str, Array],
                     t: Transition) -> LearnerUpdate:
        assert t.state is not None and t.action is not None and t.step is not None
        target, decay = self.target_and_decay(t)
        td_error = target - t.q
        new_q, trace = trace_update(q, tables["trace"], t.state, t.action, td_error,
                                    self.alpha, decay, self.trace, jnp.asarray(t.step) == 1)
        return LearnerUpdate(new_q, {"trace": trace}, new_q[t.state, t.action] - t.q)

    def validate(self) -> None:
        check_in_range("alpha", self.alpha, 0.0, 1.0, low_open=True)
        check_in_range("gamma", self.gamma, 0.0, 1.0)
        check_in_range("lam", self.lam, 0.0, 1.0)
        check_finite("q_init", self.q_init)
        check_choice("trace", self.trace, TRACE_KINDS)


@learner("sarsa_lambda", title="SARSA(λ)")
class SarsaLambda(_TraceLearner):
    """SARSA(λ) (Rummery & Niranjan 1994; Sutton & Barto 1998, Fig. 7.11): δ = r + γ
    Q(s′, a′) − Q(s, a) with the a′ taken next; traces decay by γλ."""

    def target_and_decay(self, t: Transition) -> tuple[Array, Array]:
        return (sarsa_target(t.reward, t.discount, t.q_next, t.next_action),
                jnp.asarray(self.gamma * self.lam))


@learner("q_lambda", title="Watkins Q(λ)")
class WatkinsQLambda(_TraceLearner):
    """Watkins's Q(λ) (Watkins 1989; Sutton & Barto 1998, Fig. 7.14): δ = r + γ max_b
    Q(s′, b) − Q(s, a); the traces decay by γλ after a greedy a′ (one that ties for the
    maximum counts as greedy) and are cut to 0 after an exploratory one."""

    def target_and_decay(self, t: Transition) -> tuple[Array, Array]:
        best = jnp.max(t.q_next)
        taken = jnp.max(jnp.where(jnp.arange(t.q_next.shape[0]) == t.next_action,
                                  t.q_next, -jnp.inf))
        target = t.reward + rounded(t.discount * best, t.discount)
        return target, jnp.where(taken == best, self.gamma * self.lam, 0.0)
