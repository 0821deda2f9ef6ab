"""Learning rules as pure functions of one transition (rlax style), and the learners
(plug-ins, :mod:`vdbejax.methods.contract`) built on them: Q-learning, SARSA, Expected SARSA,
Double Q-learning and the sample average.

``discount`` is γ for a non-terminal transition and 0 for a terminal one, so terminal
transitions use the target ``r`` and truncated ones still bootstrap. Q rows have the
actions on the leading axis: ``[num_actions]`` for one transition, or
``[num_actions, batch...]`` for a batch laid out as the engine does.
"""
from __future__ import annotations

from collections.abc import Mapping

import jax
import jax.numpy as jnp

from vdbejax._numerics import rounded
from vdbejax._pytree import pytree_dataclass, static_field
from vdbejax.methods.contract import Learner, LearnerUpdate, Table, Transition
from vdbejax.methods.registry import LEARNERS, build, learner
from vdbejax.validation import check_choice, check_finite, check_in_range

Array = jax.Array

#: The paper's learners.
PAPER_LEARNERS = ("qlearning", "sarsa")
PAPER_ALPHA = 0.8
PAPER_GAMMA = 0.9


def q_learning_target(reward: Array, discount: Array, q_next: Array) -> Array:
    """Q-learning target ``r + discount · max_b Q(s', b)``.

    Args:
      reward: reward of the transition.
      discount: γ, or 0 if ``s'`` is terminal.
      q_next: ``[num_actions, batch...]`` Q row of ``s'``.

    Returns:
      the target (``[batch...]``).
    """
    return reward + rounded(discount * jnp.max(q_next, axis=0), discount)


def sarsa_target(reward: Array, discount: Array, q_next: Array, next_action: Array) -> Array:
    """SARSA target ``r + discount · Q(s', a')``.

    Args:
      reward: reward of the transition.
      discount: γ, or 0 if ``s'`` is terminal.
      q_next: ``[num_actions, batch...]`` Q row of ``s'``.
      next_action: the action ``a'`` the agent takes in ``s'`` (``[batch...]``).

    Returns:
      the target (``[batch...]``).
    """
    # Select Q(s', a') with a masked max rather than a gather: exact, and it vectorises
    # over the batch axis on CPU.
    actions = jnp.arange(q_next.shape[0]).reshape((-1,) + (1,) * (q_next.ndim - 1))
    chosen = jnp.max(jnp.where(actions == next_action, q_next, -jnp.inf), axis=0)
    return reward + rounded(discount * chosen, discount)


def td_update(q_value: Array, target: Array, alpha: float | Array) -> tuple[Array, Array]:
    """Move ``Q(s,a)`` toward ``target`` by step size α.

    Args:
      q_value: current Q(s, a).
      target: learning target.
      alpha: step size in (0, 1].

    Returns:
      ``(new_q_value, delta_q)`` with ``delta_q = α·(target − Q(s,a))``.
    """
    delta_q = rounded(alpha * (target - q_value), alpha)
    return q_value + delta_q, delta_q


def expected_sarsa_target(reward: Array, discount: Array, q_next: Array,
                          probabilities: Array) -> Array:
    """Expected SARSA target ``r + discount · Σ_b π(b|s') Q(s', b)``.

    Args:
      reward: reward of the transition.
      discount: γ, or 0 if ``s'`` is terminal.
      q_next: ``[num_actions, batch...]`` Q row of ``s'``.
      probabilities: π(·|s'), shaped like ``q_next``.

    Returns:
      the target (``[batch...]``).
    """
    expected = jnp.sum(probabilities * q_next, axis=0)
    return reward + rounded(discount * expected, discount)


def double_q_learning_target(reward: Array, discount: Array, q_next_value: Array,
                             q_next_selector: Array) -> Array:
    """Double Q-learning target ``r + discount · Q_value(s', argmax_b Q_selector(s', b))``
    (ties: the lowest index), the other table valuing the first table's greedy action.
    """
    best = jnp.argmax(q_next_selector, axis=0)
    actions = jnp.arange(q_next_value.shape[0]).reshape((-1,) + (1,) * (q_next_value.ndim - 1))
    value = jnp.max(jnp.where(actions == best, q_next_value, -jnp.inf), axis=0)
    return reward + rounded(discount * value, discount)


def pair_mask(q: Array, state: Array, action: Array) -> Array:
    """``[S, A]`` True at (s, a) only (whole-table learners select by it: no gather or
    scatter in the engine's native loops)."""
    return ((jnp.arange(q.shape[0])[:, None] == state)
            & (jnp.arange(q.shape[1])[None, :] == action))


def masked_value(table: Array, mask: Array, axis: int | None = None) -> Array:
    """The entry of ``table`` where ``mask`` holds (one per slice along ``axis``), read
    by a mask (exact: the other entries are −∞ to the max)."""
    return jnp.max(jnp.where(mask, table, -jnp.inf), axis=axis)


#: How a TD learner treats a failure (a terminal step with a negative reward): a TD
#: update toward ``r`` (the textbook), or ``Q(s,a) ← failure_value`` (the authors' code).
FAILURE_UPDATES = ("td", "overwrite")
#: How it treats a goal (a terminal step with a positive reward): a TD update, or none
#: (the authors' code ends the episode before writing Q(s,a)).
GOAL_UPDATES = ("td", "skip")
#: Initial Q tables: ``q_init`` everywhere, or uniform in ``[q_init, q_init + q_init_spread)``
#: per entry and agent (the authors' code: [0, 0.01)).
Q_INIT_DISTRIBUTIONS = ("constant", "uniform")


@pytree_dataclass
class TDLearner(Learner):
    """A learner that moves Q(s,a) toward a target by α (subclasses define ``target``).

    The options of the authors' code (``failure_update``, ``goal_update``,
    ``q_init_distribution``) are static fields: the textbook defaults compile exactly the
    textbook program.
    """

    alpha: float | Array = PAPER_ALPHA
    gamma: float | Array = PAPER_GAMMA
    q_init: float | Array = 0.0
    failure_value: float | Array = -0.1
    q_init_spread: float | Array = 0.01
    failure_update: str = static_field("td")
    goal_update: str = static_field("td")
    q_init_distribution: str = static_field("constant")

    def target(self, t: Transition) -> Array:
        raise NotImplementedError

    def update(self, t: Transition) -> LearnerUpdate:
        new, delta_q = td_update(t.q, self.target(t), self.alpha)
        if self.failure_update == "overwrite":
            failure = t.terminal & (t.reward < 0)
            new = jnp.where(failure, self.failure_value, new)
            delta_q = jnp.where(failure, new - t.q, delta_q)
        if self.goal_update == "skip":
            goal = t.terminal & (t.reward > 0)
            new = jnp.where(goal, t.q, new)
            delta_q = jnp.where(goal, 0.0, delta_q)
        return LearnerUpdate(new, {}, delta_q)

    def initial_q(self, key: Array, num_states: int, num_actions: int) -> Array:
        if self.q_init_distribution == "constant":
            return super().initial_q(key, num_states, num_actions)
        # Its own stream (threefry on a folded key), apart from the per-step hash stream.
        uniform = jax.random.uniform(jax.random.fold_in(key, 0x51A17), (num_states, num_actions))
        return self.q_init + self.q_init_spread * uniform

    def validate(self) -> None:
        check_in_range("alpha", self.alpha, 0.0, 1.0, low_open=True)
        check_in_range("gamma", self.gamma, 0.0, 1.0)
        check_finite("q_init", self.q_init)
        check_finite("failure_value", self.failure_value)
        check_in_range("q_init_spread", self.q_init_spread, 0.0, 1e30)
        check_choice("failure_update", self.failure_update, FAILURE_UPDATES)
        check_choice("goal_update", self.goal_update, GOAL_UPDATES)
        check_choice("q_init_distribution", self.q_init_distribution, Q_INIT_DISTRIBUTIONS)


@learner("qlearning", title="Q-learning")
class QLearning(TDLearner):
    """Q-learning (Watkins 1989): ``Q(s,a) += α(r + γ max_b Q(s',b) − Q(s,a))``; a′ is
    chosen after the update."""

    def target(self, t: Transition) -> Array:
        return q_learning_target(t.reward, t.discount, t.q_next)


@learner("sarsa", title="SARSA")
class SARSA(TDLearner):
    """SARSA (Rummery & Niranjan 1994): target ``r + γ Q(s',a')`` with the a′ the agent
    takes next, chosen before the update."""

    #: ``"executed"``: a′ is the action taken next (textbook); ``"redrawn"``: the action
    #: taken in s′ is drawn afresh after the update (the authors' code).
    next_action: str = static_field("executed")
    uses_next_action = True

    @property
    def redraws_next_action(self) -> bool:
        return self.next_action == "redrawn"

    def target(self, t: Transition) -> Array:
        return sarsa_target(t.reward, t.discount, t.q_next, t.next_action)

    def validate(self) -> None:
        super().validate()
        check_choice("next_action", self.next_action, ("executed", "redrawn"))


@learner("expected_sarsa", title="Expected SARSA")
class ExpectedSARSA(TDLearner):
    """Expected SARSA (van Seijen et al. 2009): target ``r + γ Σ_b π(b|s') Q(s',b)`` with
    the explorer's own probabilities (before the update); a′ is chosen after it."""

    uses_next_probabilities = True

    def target(self, t: Transition) -> Array:
        return expected_sarsa_target(t.reward, t.discount, t.q_next, t.next_probabilities)


@learner("double_qlearning", title="Double Q-learning")
class DoubleQLearning(TDLearner):
    """Double Q-learning (van Hasselt 2010): two tables; each step one of them, chosen
    with probability ½, moves toward the other's value of its own greedy action. The
    explorer acts on their sum; ΔQ is the change of the updated table."""

    num_uniforms = 1

    def tables(self) -> dict[str, Table]:
        return {"q2": Table("pair", self.q_init)}

    def behaviour(self, q: Array, tables: Mapping[str, Array]) -> Array:
        return q + tables["q2"]

    def update(self, t: Transition) -> LearnerUpdate:
        first = t.uniforms[0] < 0.5
        q2, q2_next = t.tables["q2"], t.tables_next["q2"]
        target = jnp.where(first,
                           double_q_learning_target(t.reward, t.discount, q2_next, t.q_next),
                           double_q_learning_target(t.reward, t.discount, t.q_next, q2_next))
        new, delta_q = td_update(jnp.where(first, t.q, q2), target, self.alpha)
        return LearnerUpdate(jnp.where(first, new, t.q), {"q2": jnp.where(first, q2, new)}, delta_q)


@learner("sample_average", title="Sample average")
class SampleAverage(Learner):
    """Sample averages (Sutton & Barto 2018, §2.4): ``Q(s,a) += (target − Q(s,a)) / n(s,a)``
    with ``n(s,a)`` the visits of (s, a), this one included (step size α = 1/n), and the
    Q-learning target ``r + γ max_b Q(s',b)``. On a bandit (every pull terminal: target
    ``r``) Q(a) is the mean of the rewards arm ``a`` has paid; ``q_init`` is forgotten at
    the first visit."""

    gamma: float | Array = PAPER_GAMMA
    q_init: float | Array = 0.0

    def tables(self) -> dict[str, Table]:
        return {"visits": Table("pair", 0.0)}

    def update(self, t: Transition) -> LearnerUpdate:
        visits = t.tables["visits"] + 1.0
        delta_q = (q_learning_target(t.reward, t.discount, t.q_next) - t.q) / visits
        return LearnerUpdate(t.q + delta_q, {"visits": visits}, delta_q)

    def validate(self) -> None:
        check_in_range("gamma", self.gamma, 0.0, 1.0)
        check_finite("q_init", self.q_init)


def make_learner(name: str, **values: object) -> Learner:
    """A registered learner from its name and any fields (α, γ, q_init, …).

    Raises:
      ValueError: unknown name, unknown field or out-of-range value.
    """
    return build(learner_class(name), values, "learner")


def learner_class(name: str) -> type[Learner]:
    """The learner class registered as ``name`` (one-line ``ValueError`` if none)."""
    if name not in LEARNERS:
        check_choice("learner", name, LEARNERS)
    return LEARNERS[name]
