"""The learned policy's value: the exact expected return of every agent's greedy policy.

With ``RunOptions(evaluate_every=K)`` the run driver (:mod:`vdbejax.runs.driver`) calls
:func:`greedy_returns` on the agents' tables after every K-th episode (at the episode
boundary, between chunks: the plan aligns its chunks on K, or under a stop policy K is
a multiple of the chunk). It does not touch the
agents, their random streams or the training programs, so the returns are those of the
same run without evaluation, bit for bit.

**The greedy policy** of an agent is the one its explorer's greedy branch follows: in
state ``s`` (with ``t`` steps of the episode taken), uniform over the actions that
maximise the values the explorer acts on — the learner's
:meth:`~vdbejax.methods.contract.Learner.behaviour` values (Q for the TD learners,
Q + Q₂ for double Q-learning, the planned optimistic Q of R-max, MBIE-EB and PSRL, the
stage values Q_t of UCBVI and UCB-H) — with ties split as the explorer splits them
(:func:`~vdbejax.methods.selection.greedy_probabilities`: uniformly, or the first
maximal action under ``tie_break="first"``). An explorer's own bonus (UCB-1's, the
count bonus) is exploration and not part of it.

**Its value** is exact, not sampled: policy evaluation by backward induction on the
known task under its step limit ``H = max_steps`` (the benchmark's capped horizon where
it caps), ``V_H = 0``, ``V_t(s) = Σ_a π_t(a|s) (r̄(s,a) + Σ_k p_k(s,a) [¬terminal_k]
V_{t+1}(s'_k))``, undiscounted, and ``V^π = Σ_s start(s) V_0(s)``: the expected
episode return the engine's episodes of that policy would average (the same
``γ = 1``, ``H`` and start distribution as the optimum
:func:`~vdbejax.envs.solvers.best_return`, ``V*``). It runs in JAX, batched over the
agents (``vmap``), in float32 like the agents' tables; a stationary policy stops at a
fixed point of ``V`` (every further backup gives the same values).

**Optimal**: an agent's greedy policy counts as optimal when ``V* − V^π ≤ tolerance``,
``tolerance =`` :data:`OPTIMAL_TOLERANCE` ``· H · max |r|`` (``H · max |r|`` bounds
every return's size; H float32 backups, each rounding by a relative 6·10⁻⁸, stay below it
for H up to about 10³). The gap ``V* − V^π`` is ≥ 0 up to that rounding; a stationary
greedy policy can fall short of ``V*`` where the finite-horizon optimum acts differently
near the step limit.
"""
from __future__ import annotations

from functools import partial
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from vdbejax.engine.distributed import gather_agents
from vdbejax.envs.solvers import best_return
from vdbejax.envs.tabular import TabularMDP
from vdbejax.methods.agents import AgentParams
from vdbejax.methods.contract import Context, Learner, behaviour_values
from vdbejax.methods.model import bellman_backup
from vdbejax.methods.selection import greedy_probabilities
from vdbejax.runs.options import RunOptions
from vdbejax.runs.run_state import RunState

Array = jax.Array

#: Relative tolerance of "the greedy policy is optimal" (module docstring).
OPTIMAL_TOLERANCE = 1e-4
#: Elements (agents × states × actions × outcomes) one evaluation program gathers at
#: a time: more agents are evaluated in groups, so its memory stays bounded.
GROUP_ELEMENTS = 1 << 24


def optimal_tolerance(mdp: TabularMDP) -> float:
    """The gap below which a greedy policy counts as optimal on ``mdp`` (module
    docstring)."""
    largest = float(np.abs(np.asarray(mdp.reward)).max()) if mdp.reward.size else 0.0
    return OPTIMAL_TOLERANCE * int(mdp.max_steps) * max(largest, float(np.finfo(np.float32).tiny))


def evaluation_meta(mdp: TabularMDP, evaluate_every: int) -> dict[str, Any]:
    """What ``meta.json`` records of a run's evaluations: ``evaluate_every``, the
    optimum ``optimal_return`` (V*, :func:`~vdbejax.envs.solvers.best_return`) and the
    ``optimal_tolerance`` of :func:`optimal_tolerance`."""
    return {"evaluate_every": int(evaluate_every), "optimal_return": best_return(mdp),
            "optimal_tolerance": optimal_tolerance(mdp)}


def evaluations(num_episodes: int, run: RunOptions) -> int | None:
    """The evaluations a run of ``num_episodes`` takes (None: it takes none)."""
    return None if run.evaluate_every is None else num_episodes // run.evaluate_every


def collect_evaluations(state: RunState, mdp: TabularMDP, run: RunOptions,
                        shape: tuple[int, ...], meta: dict[str, Any]) -> np.ndarray | None:
    """A finished run's ``[configs, seeds, evaluations]`` policy values (every process's
    agents gathered; ``shape`` starts with configs and seeds), its :func:`evaluation_meta`
    added to ``meta``; None for a run without evaluation."""
    if state.policy_values is None or run.evaluate_every is None:
        return None
    meta.update(evaluation_meta(mdp, run.evaluate_every))
    return gather_agents(state.policy_values, shape[0] * shape[1]).reshape((*shape[:2], -1))


def evaluation_operations(mdp: TabularMDP, params: AgentParams) -> int:
    """Multiply-adds of one evaluation of every agent of ``params`` at most: ``H`` backups
    of ``S · A · K`` outcomes each, and for a learner whose greedy action depends on the
    step (stage values), its ``S · A · L`` stage table read again at every backup (a
    stationary policy often stops earlier)."""
    total = 0
    for k, agent in enumerate(params.kinds):
        width = 0
        if type(agent.learner).behaviour_uses_context:
            width = max((spec.width() for spec in agent.learner.tables().values()), default=1)
        total += params.rows_of(k).size * (mdp.num_outcomes + width)
    return int(mdp.max_steps) * mdp.num_states * mdp.num_actions * total


def greedy_returns(mdp: TabularMDP, params: AgentParams, q: Any, tables: dict[str, Any],
                   episode: Any) -> np.ndarray:
    """The exact expected episode return of every agent's greedy policy (module docstring).

    Args:
      mdp: the task.
      params: the agents' hyperparameters (leading axis = agents).
      q: ``[agents, S, A]`` action values (host or device arrays).
      tables: the agents' tables (``{name: [agents, ...]}``, :class:`~vdbejax.engine.
        AgentState`'s).
      episode: int ``[agents]`` episodes each agent has completed.

    Returns:
      float32 ``[agents]`` values ``V^π`` (NaN where an agent's values are not finite).
    """
    num_agents = int(np.shape(episode)[0])
    values = np.full(num_agents, np.nan, np.float32)
    per_agent = max(mdp.num_states * mdp.num_actions * mdp.num_outcomes, 1)
    group = max(1, GROUP_ELEMENTS // per_agent)
    for k, agent in enumerate(params.kinds):
        rows = params.rows_of(k)
        tie_break = str(getattr(agent.explorer, "tie_break", "random"))
        names = sorted(agent.learner.tables())
        for first in range(0, rows.size, group):
            index = rows[first:first + group]
            learner = jax.tree.map(lambda leaf, index=index: np.asarray(leaf)[index],
                                   agent.learner)
            mine = {name: tables[name][index] for name in names}
            values[index] = np.asarray(_policy_returns(
                mdp, learner, q[index], mine, jnp.asarray(np.asarray(episode)[index]),
                tie_break=tie_break))
    return values


def _greedy_policy(learner: Learner, q: Array, tables: dict[str, Array], episode: Array,
                   step: Array, tie_break: str) -> Array:
    """``[agents, S, A]`` greedy probabilities with ``step`` steps of the episode taken."""
    def one_agent(learner: Learner, q: Array, tables: dict[str, Array],
                  episode: Array) -> Array:
        def one_state(q_row: Array, table_rows: dict[str, Array]) -> Array:
            context = Context(episode=episode, step=step, terminal=jnp.asarray(False))
            return greedy_probabilities(
                behaviour_values(learner, q_row, table_rows, context), tie_break)

        return jax.vmap(one_state)(q, tables)

    return jax.vmap(one_agent)(learner, q, tables, episode)


@partial(jax.jit, static_argnames=("tie_break",))
def _policy_returns(mdp: TabularMDP, learner: Learner, q: Array, tables: dict[str, Array],
                    episode: Array, *, tie_break: str) -> Array:
    """:func:`greedy_returns` of agents of one kind (``learner`` batched)."""
    probability = mdp.probability.astype(jnp.float32)
    expected_reward = (probability * mdp.reward).sum(-1)  # [S, A]
    weight = jnp.where(mdp.terminal, 0.0, probability)  # [S, A, K]: no value after the end
    stationary = not type(learner).behaviour_uses_context
    horizon = jnp.asarray(mdp.max_steps, jnp.int32)
    episode = episode.astype(jnp.int32)

    def policy(step: Array) -> Array:
        return _greedy_policy(learner, q.astype(jnp.float32), tables, episode,
                              step.astype(jnp.int32), tie_break)

    fixed = policy(jnp.int32(0)) if stationary else None

    def backup(carry: tuple) -> tuple:
        # ``value``: V with H − steps_left steps to go; this backup's action comes after
        # steps_left − 1 steps of the episode.
        steps_left, value, _ = carry
        pi = fixed if fixed is not None else policy(steps_left - 1)
        # [agents, S, A]; the compiler's sum over outcomes (an ordered one, as the model's
        # expected_under, would give other bits than these returns always had)
        future = (weight * value[:, mdp.next_state]).sum(-1)
        new = (pi * bellman_backup(expected_reward, 1.0, future)).sum(-1)  # undiscounted
        same = jnp.all((new == value) | (jnp.isnan(new) & jnp.isnan(value)))
        return steps_left - 1, new, same

    def more(carry: tuple) -> Array:
        steps_left, _, same = carry
        # A stationary policy at a fixed point: every further backup gives the same V.
        return (steps_left > 0) & ~(same & stationary)

    value = jnp.zeros(q.shape[:2], jnp.float32)
    _, value, _ = jax.lax.while_loop(more, backup, (horizon, value, jnp.asarray(False)))
    return value @ mdp.start_probability.astype(jnp.float32)
