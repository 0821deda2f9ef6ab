"""Model-based learners with optimism in the face of uncertainty: R-max and MBIE-EB.

Both learn the engine's count model (:mod:`vdbejax.methods.model`) and keep in Q the
optimal values of an optimistic model, found by value iteration
(:func:`~vdbejax.methods.model.value_iteration`, warm-started from the current Q); they
act greedily on it (explorer ``greedy``). A terminal outcome is worth 0, as in the
engine's episodes. Both assume rewards at most ``r_max`` (``v_max = r_max / (1 − γ)``
bounds every return) and ``γ < 1``.
"""
from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import jax
import jax.numpy as jnp

from vdbejax._numerics import rounded
from vdbejax._pytree import pytree_dataclass, static_field
from vdbejax.methods.contract import Context, Learner, LearnerUpdate, Transition
from vdbejax.methods.learners import PAPER_GAMMA
from vdbejax.methods.model import Model, bellman_backup, greedy_values, value_iteration
from vdbejax.methods.registry import learner
from vdbejax.validation import check_finite, check_in_range, check_int

Array = jax.Array


def optimistic_backup(model: Model, q: Array, gamma: float | Array, bonus: Array,
                      known: Array, v_max: float | Array) -> Array:
    """One sweep ``r̂(s,a) + bonus(s,a) + γ Σ_s′ P̂(s′|s,a) max_a′ Q(s′,a′)`` where
    ``known``, ``v_max`` elsewhere."""
    backed = bellman_backup(model.mean_reward() + bonus, gamma, model.expected(greedy_values(q)))
    return jnp.where(known, backed, v_max)


@pytree_dataclass
class _ValueIterationLearner(Learner):
    """A learner whose Q is set by planning alone (its update changes nothing)."""

    gamma: float | Array = PAPER_GAMMA
    r_max: float | Array = 1.0
    tolerance: float | Array = 1e-4
    max_sweeps: int = static_field(1000)
    uses_model = True

    def update(self, t: Transition) -> LearnerUpdate:
        return LearnerUpdate(t.q, {}, jnp.zeros_like(t.q))

    def v_max(self) -> Array:
        return self.r_max / (1.0 - self.gamma)  # type: ignore[return-value]

    def initial_q(self, key: Array, num_states: int, num_actions: int) -> Array:
        return jnp.full((num_states, num_actions), self.v_max(), jnp.float32)

    def solve(self, model: Model, q: Array, bonus: Array, known: Array) -> Array:
        def backup(values: Array) -> Array:
            return optimistic_backup(model, values, self.gamma, bonus, known, self.v_max())

        return value_iteration(backup, q, tolerance=self.tolerance, max_sweeps=self.max_sweeps)

    def validate(self) -> None:
        check_in_range("gamma", self.gamma, 0.0, 1.0, high_open=True)
        check_finite("r_max", self.r_max)
        check_in_range("tolerance", self.tolerance, 0.0, 1e30, low_open=True)
        check_int("max_sweeps", self.max_sweeps, 1)


@learner("rmax", title="R-max")
class RMax(_ValueIterationLearner):
    """R-max (Brafman & Tennenholtz 2002, "R-max – a general polynomial time algorithm
    for near-optimal reinforcement learning", JMLR 3), in its discounted form (Strehl,
    Li & Littman 2009, JMLR 10, Alg. 2).

    A pair is *known* once visited ``known_visits`` (m) times. Q is the optimal value of
    the model in which a known pair has its empirical reward and successors and an unknown
    pair is worth ``v_max = r_max/(1 − γ)``; it is re-planned (value iteration to
    ``tolerance``, at most ``max_sweeps`` sweeps) when a pair becomes known — the moment
    the published algorithm changes its model (``plan_at = "known"``). Where we chose: the
    engine's model keeps counting after m visits, so a re-plan uses every visit so far of
    the known pairs (the original freezes each pair's first m).
    """

    known_visits: float | Array = 5.0
    plan_at = "known"

    def plan(self, q: Array, tables: Mapping[str, Array], model: Any, context: Context,
             uniforms: tuple[Array, ...]) -> tuple[Array, dict[str, Array]]:
        known = model.visits >= self.known_visits
        return self.solve(model, q, jnp.zeros_like(q), known), {}

    def validate(self) -> None:
        super().validate()
        check_in_range("known_visits", self.known_visits, 1.0, 1e9)


@learner("mbie_eb", title="MBIE-EB")
class MBIEEB(_ValueIterationLearner):
    """MBIE-EB (Strehl & Littman 2008, "An analysis of model-based Interval Estimation for
    Markov Decision Processes", JCSS 74, §3.3): Q is the optimal value of the empirical
    model plus the exploration bonus ``beta / √n(s, a)``, an unvisited pair worth
    ``v_max = r_max/(1 − γ)``. The paper solves the model after every step
    (``plan_at = "step"``; value iteration from the current Q to ``tolerance``, at most
    ``max_sweeps`` sweeps).
    """

    beta: float | Array = 0.1
    plan_at = "step"

    def plan(self, q: Array, tables: Mapping[str, Array], model: Any, context: Context,
             uniforms: tuple[Array, ...]) -> tuple[Array, dict[str, Array]]:
        visited = model.visits > 0
        # exact (no rsqrt), and never fused into the next add
        bonus = rounded(self.beta * jnp.sqrt(1.0 / jnp.maximum(model.visits, 1.0)), self.beta)
        return self.solve(model, q, bonus, visited), {}

    def validate(self) -> None:
        super().validate()
        check_in_range("beta", self.beta, 0.0, 1e30)
