"""Finite-horizon methods with stage-dependent values: UCBVI and optimistic Q-learning
(UCB-H); PSRL (:mod:`vdbejax.methods.posterior`) builds on their stage table.

Both keep Q_h(s, a) for the stages h = 0 … H−1 of an episode in a stage table
(``Table("stage", ..., length=H)``, ``[S, A, H]``) and act greedily on Q_h at the episode's
step h (``behaviour_uses_context``: the context's ``step`` is h; from step H on, Q_{H−1}).
**H is the learner's static ``horizon`` field; set it to the task's ``max_steps``** (the
engine truncates episodes there, so the stages are the steps of an episode). On a task
whose episodes end earlier (a terminal step), the values after it are 0, as in the
engine's episodes. The engine's Q holds Q_0 (figures and summaries of Q show the first
stage). Both assume rewards at most ``r_max``; ``v_max_h = r_max + γ v_max_{h+1}`` (with
``v_max_H = 0``) bounds the value from stage h on.
"""
from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from typing import Any

import jax
import jax.numpy as jnp

from vdbejax._numerics import rounded
from vdbejax._pytree import pytree_dataclass, static_field
from vdbejax.methods.contract import (
    Context,
    Learner,
    LearnerUpdate,
    Table,
    TaskFacts,
    Transition,
)
from vdbejax.methods.learners import masked_value
from vdbejax.methods.model import Model, bellman_backup, expected_under
from vdbejax.methods.registry import learner
from vdbejax.validation import check_choice, check_in_range, check_int

Array = jax.Array

#: UCBVI's bonuses.
UCBVI_BONUSES = ("hoeffding", "bernstein")
#: UCBVI's conventions: the paper's, or rlberry-scool's ``UCBVIAgent``'s (a peer to compare
#: with on equal terms, ``benchmarks/rlberry_ucbvi.py``).
UCBVI_CONVENTIONS = ("paper", "rlberry")


def at_stage(row: Array, stage: Array) -> Array:
    """``row[..., stage]`` of a ``[..., H]`` stage row, by a mask (no gather)."""
    return masked_value(row, jnp.arange(row.shape[-1]) == stage, axis=-1)


def stage_values(stage_row: Array, context: Context) -> Array:
    """``[A]`` Q_h(s, ·) of an ``[A, H]`` row at the context's step (the last stage
    after it)."""
    return at_stage(stage_row, jnp.minimum(context.step, stage_row.shape[-1] - 1))


def ucbvi_values(model: Model, bonus: Any, gamma: Any, r_max: Any, horizon: int,
                 convention: str = "paper") -> Array:
    """``[S, A, H]`` Q_h by backward induction on the empirical model, ``V_h = max_a Q_h``,
    ``V_H = 0``; ``bonus(n, v_max_h, h)`` gives b_h; ``v_max_h = r_max + γ v_max_{h+1}``.

    ``"paper"``: ``Q_h = min(r̂ + b_h + γ P̂ V_{h+1}, v_max_h)`` for a visited pair,
    ``v_max_h`` otherwise. ``"rlberry"`` (rlberry-scool 0.7.3's ``UCBVIAgent``, whose
    ``r_max`` is the task's reward range): ``Q_h = r̂ + b_h + γ P̂ V_{h+1}`` unclipped, an
    unvisited pair with r̂ = 0 and P̂ uniform over the states (rlberry's initial
    estimate), and ``V_h = min(max_a Q_h, v_max_0)`` (its ``backward_induction_reward_sd``
    caps every stage's value at the first stage's bound)."""
    visited = model.visits > 0
    reward = model.mean_reward()
    probabilities = model.successor_probabilities()

    def bound(v_max_next: Array, h: Array) -> tuple:
        v_max = r_max + rounded(gamma * v_max_next, gamma)
        return v_max, v_max

    zero = jnp.asarray(0.0, jnp.float32)
    cap = jax.lax.scan(bound, zero, jnp.arange(horizon))[0]  # v_max_0

    def stage(carry: tuple, h: Array) -> tuple:
        values, v_max_next = carry
        v_max = bound(v_max_next, h)[0]
        expected = expected_under(probabilities, model.next_state, values)
        if convention == "rlberry":
            expected = jnp.where(visited, expected, jnp.mean(values))
        backed = bellman_backup(reward + bonus(model.visits, v_max, h), gamma, expected)
        q = (backed if convention == "rlberry"
             else jnp.where(visited, jnp.minimum(backed, v_max), v_max))
        values = jnp.max(q, axis=1)
        if convention == "rlberry":
            values = jnp.minimum(values, cap)
        return (values, v_max), q

    start = (jnp.zeros(model.visits.shape[0], jnp.float32), zero)
    return backward_induction(stage, start, horizon)


def backward_induction(stage: Any, start: Any, horizon: int) -> Array:
    """``[S, A, H]`` Q_h from ``stage(carry, h) -> (carry, Q_h)`` run for h = H − 1 … 0
    (``carry`` holds what the next stage needs, e.g. V_{h+1})."""
    stages: Array = jax.lax.scan(stage, start, jnp.arange(horizon - 1, -1, -1))[1]
    return jnp.flip(stages, axis=0).transpose(1, 2, 0)


@pytree_dataclass
class StageLearner(Learner):
    """The base of the finite-horizon learners (UCBVI, UCB-H, and PSRL,
    :class:`vdbejax.methods.posterior.PSRL`): Q_h in a stage table ``q_stage``, acting on
    the episode step's stage (see the module docstring)."""

    horizon: int = static_field(100)
    behaviour_uses_context = True

    def tables(self) -> dict[str, Table]:
        return {"q_stage": Table("stage", 0.0, length=self.horizon)}

    def behaviour(self, q: Array, tables: Mapping[str, Array],  # type: ignore[override]
                  context: Context) -> Array:
        return stage_values(tables["q_stage"], context)

    def validate(self) -> None:
        check_int("horizon", self.horizon, 1)


@learner("ucbvi", title="UCBVI")
class UCBVI(StageLearner):
    """UCBVI (Azar, Osband & Munos 2017, "Minimax regret bounds for reinforcement
    learning", ICML, Alg. 1): before each episode (``plan_at = "episode"``), Q_h by
    backward induction on the empirical model plus a bonus (:func:`ucbvi_values`).

    Bonuses (``bonus``, static), n = visits of (s, a):

    * ``"hoeffding"`` (Chernoff–Hoeffding, the paper's ``bonus_1``): ``b = c · 7 H L
      √(1/n)``, ``L = ln(5 S A T / δ)``, T = H × the episodes so far (this one included);
      ``c = bonus_scale`` (1: the paper's constant);
    * ``"bernstein"`` (simplified Bernstein, as rlberry's ``UCBVIAgent``): ``b_h = min(c
      √(1/n) + v_max_h / n, v_max_h)``.

    Where we chose: the model is stage-independent (one transition and reward estimate per
    pair, the paper's setting); values are clipped to ``v_max_h`` (the paper clips at H).
    ``convention="rlberry"`` (static) follows rlberry-scool 0.7.3's ``UCBVIAgent`` instead,
    to compare with it on equal terms: its bound ``v_max_h`` is built from the task's
    reward range ``max r − min r`` (``reward_range``, static: the engine sets it from the
    task, :meth:`for_task`; 1 where the range is 0 or infinite, as rlberry), not from
    ``r_max``; the Bernstein bonus of stage h keeps the visits of the pair's last visit
    *at that stage* (``v_max_h`` before one); Q values are not clipped but every stage's
    state value is capped at ``v_max_0``; and an unvisited pair has r̂ = 0 and uniform
    successors.
    """

    gamma: float | Array = 1.0
    bonus_scale: float | Array = 1.0
    delta: float | Array = 0.1
    r_max: float | Array = 1.0
    bonus: str = static_field("bernstein")
    convention: str = static_field("paper")
    reward_range: float | None = static_field(None)
    uses_model = True
    plan_at = "episode"

    def for_task(self, task: TaskFacts) -> UCBVI:
        if self.convention != "rlberry" or self.reward_range is not None:
            return self
        spread = task.reward_range  # rlberry: a range of 0 or ∞ is taken as 1
        return dataclasses.replace(self, reward_range=(
            float(spread) if 0.0 < spread < float("inf") else 1.0))

    def bound_reward(self) -> Any:
        """The reward whose sum over the stages bounds the values: ``r_max``, or the
        task's reward range under ``convention="rlberry"``."""
        if self.convention != "rlberry":
            return self.r_max
        if self.reward_range is None:
            raise ValueError("ucbvi with convention='rlberry' needs the task's reward range:"
                             " run it through the engine (vdbejax.run_grid or run_agents),"
                             " which sets reward_range from the task, or give reward_range")
        return jnp.float32(self.reward_range)

    def tables(self) -> dict[str, Table]:
        tables = super().tables()
        if self.convention == "rlberry":  # visits at each stage's last visit, and in all
            tables["bonus_visits"] = Table("stage", 0.0, length=self.horizon)
            tables["visits"] = Table("pair", 0.0)
        return tables

    def update(self, t: Transition) -> LearnerUpdate:  # the values come from planning
        tables = dict(t.tables)
        if self.convention == "rlberry":
            visits = tables["visits"] + 1.0
            stage = jnp.minimum(jnp.asarray(t.step) - 1, self.horizon - 1)
            tables["visits"] = visits
            tables["bonus_visits"] = jnp.where(jnp.arange(self.horizon) == stage, visits,
                                               tables["bonus_visits"])
        return LearnerUpdate(t.q, tables, jnp.zeros_like(t.q))

    def stage_bonus(self, model: Model, context: Context,
                    tables: Mapping[str, Array] | None = None) -> Any:
        S, A = model.visits.shape
        if self.convention == "rlberry":
            assert tables is not None
            at_visit = tables["bonus_visits"]

            def visited_at_stage(visits: Array, v_max: Array, h: Array) -> Array:
                m = jax.lax.dynamic_index_in_dim(at_visit, h, axis=2, keepdims=False)
                scaled = rounded(self.bonus_scale * jnp.sqrt(1.0 / jnp.maximum(m, 1.0)),
                                 self.bonus_scale)
                return jnp.where(m > 0, jnp.minimum(scaled + v_max / jnp.maximum(m, 1.0),
                                                    v_max), v_max)

            return visited_at_stage
        inverse_root = jnp.sqrt(1.0 / jnp.maximum(model.visits, 1.0))  # exact (no rsqrt)
        if self.bonus == "hoeffding":
            steps = self.horizon * (context.episode.astype(jnp.float32) + 1.0)
            log_term = jnp.log(5.0 * S * A * steps / self.delta)
            factor = self.bonus_scale * 7.0 * self.horizon * log_term
            fixed = rounded(factor * inverse_root, factor)  # never fused into the next add
            return lambda visits, v_max, h: fixed

        def bernstein(visits: Array, v_max: Array, h: Array) -> Array:
            scaled = rounded(self.bonus_scale * inverse_root, self.bonus_scale)
            return jnp.minimum(scaled + v_max / jnp.maximum(visits, 1.0), v_max)

        return bernstein

    def plan(self, q: Array, tables: Mapping[str, Array], model: Any, context: Context,
             uniforms: tuple[Array, ...]) -> tuple[Array, dict[str, Array]]:
        stages = ucbvi_values(model, self.stage_bonus(model, context, tables), self.gamma,
                              self.bound_reward(), self.horizon, self.convention)
        return stages[..., 0], {**tables, "q_stage": stages}

    def validate(self) -> None:
        super().validate()
        check_in_range("gamma", self.gamma, 0.0, 1.0)
        check_in_range("bonus_scale", self.bonus_scale, 0.0, 1e30)
        check_in_range("delta", self.delta, 0.0, 1.0, low_open=True, high_open=True)
        check_in_range("r_max", self.r_max, 0.0, 1e30, low_open=True)
        check_choice("bonus", self.bonus, UCBVI_BONUSES)
        check_choice("convention", self.convention, UCBVI_CONVENTIONS)
        if self.convention == "rlberry" and self.bonus != "bernstein":
            raise ValueError(f"bonus={self.bonus!r} is invalid with convention='rlberry':"
                             " rlberry's UCBVIAgent has the 'bernstein' bonus only")
        if self.reward_range is not None:
            if self.convention != "rlberry":
                raise ValueError(f"reward_range={self.reward_range!r} is invalid with"
                                 f" convention={self.convention!r}: only the rlberry"
                                 " convention takes it (the paper's bounds values with r_max)")
            check_in_range("reward_range", self.reward_range, 0.0, 1e30, low_open=True)


@learner("ucb_h", title="UCB-H")
class UCBH(StageLearner):
    """Q-learning with UCB-Hoeffding exploration (Jin, Allen-Zhu, Bubeck & Jordan 2018,
    "Is Q-learning provably efficient?", NeurIPS, Alg. 1): after the step at stage h,
    with t the visits of (s, a) at stage h, ``Q_h(s,a) ← (1 − α_t) Q_h(s,a) + α_t (r +
    γ V_{h+1}(s′) + b_t)``, ``α_t = (H + 1)/(H + t)``, ``b_t = c √(H³ ι / t)``,
    ``V_{h+1}(s′) = min(v_max_0, max_a Q_{h+1}(s′, a))`` (0 after the last stage or a
    terminal step); Q_h starts at ``v_max_0 = H · r_max``. ``c = bonus_scale``; ``iota``
    stands for the paper's ι = log(SAT/p) (a hyperparameter: S and T are not known to a
    row update).
    """

    gamma: float | Array = 1.0
    bonus_scale: float | Array = 1.0
    iota: float | Array = 1.0
    r_max: float | Array = 1.0

    def v_max(self) -> Array:
        return jnp.asarray(self.horizon * self.r_max, jnp.float32)

    def tables(self) -> dict[str, Table]:
        return {"q_stage": Table("stage", self.v_max(), length=self.horizon),
                "visits_stage": Table("stage", 0.0, length=self.horizon)}

    def initial_q(self, key: Array, num_states: int, num_actions: int) -> Array:
        return jnp.full((num_states, num_actions), self.v_max(), jnp.float32)

    def update(self, t: Transition) -> LearnerUpdate:
        H = self.horizon
        stage = jnp.minimum(jnp.asarray(t.step) - 1, H - 1)
        here = jnp.arange(H) == stage
        visits = at_stage(t.tables["visits_stage"], stage) + 1.0
        rate = (H + 1.0) / (H + visits)
        bonus = rounded(self.bonus_scale * jnp.sqrt(float(H) ** 3 * self.iota / visits),
                        self.bonus_scale)
        later = at_stage(t.tables_next["q_stage"], jnp.minimum(stage + 1, H - 1))
        value_next = jnp.where(stage + 1 < H, jnp.minimum(self.v_max(), jnp.max(later)), 0.0)
        target = t.reward + rounded(t.discount * value_next, t.discount) + bonus
        old = at_stage(t.tables["q_stage"], stage)
        new = old + rounded(rate * (target - old), rate)
        q_stage = jnp.where(here, new, t.tables["q_stage"])
        first = jnp.where(stage == 0, new, t.q)  # the engine's Q holds Q_0
        return LearnerUpdate(first, {"q_stage": q_stage,
                                     "visits_stage": jnp.where(here, visits,
                                                               t.tables["visits_stage"])},
                             first - t.q)

    def validate(self) -> None:
        super().validate()
        check_in_range("gamma", self.gamma, 0.0, 1.0)
        check_in_range("bonus_scale", self.bonus_scale, 0.0, 1e30)
        check_in_range("iota", self.iota, 0.0, 1e30)
        check_in_range("r_max", self.r_max, 0.0, 1e30, low_open=True)
