"""A task instance per agent in the engine: each agent's instance rides with its
hyperparameters.

:func:`with_instances` puts each agent's row of a
:class:`~vdbejax.envs.task_instances.TaskInstances` into every kind's batched hyperparameters
(:class:`AgentOnTask`), so every gather, slice, refill, compaction and packed lane of both
strategies moves an agent's instance with it. The step rule then reads lane ``i``'s
instance from row ``i`` of the lane's hyperparameters (:func:`lane_transition`,
:func:`lane_start`, :func:`lane_optimal`): the same values, drawn with the same uniforms,
as the agent alone on its own (unbatched) instance, hence the same bits.
"""
from __future__ import annotations

import dataclasses
from typing import Any

import jax
import numpy as np

from vdbejax._numerics import sample_categorical
from vdbejax._pytree import pytree_dataclass
from vdbejax.engine.kinds import KindSwitch
from vdbejax.engine.lanes import take
from vdbejax.envs.reward_noise import noisy_reward
from vdbejax.envs.tabular import TabularMDP
from vdbejax.envs.task_instances import TaskInstances
from vdbejax.methods.agents import Agent, AgentParams

Array = jax.Array


@pytree_dataclass
class AgentOnTask(Agent):
    """An agent's (or a batch's) hyperparameters with its own task instance.

    Attributes:
      task: the instance's tables (:class:`~vdbejax.envs.tabular.TabularMDP` leaves, a
        leading axis per agent in a batch).
      start_states: int32 ``[M]`` the states of positive start probability (padded with
        state 0 of weight 0 to the largest support of the run's instances).
      start_weights: float32 ``[M]`` their probabilities (the padding's 0).
    """

    task: Any = None
    start_states: Any = None
    start_weights: Any = None


def start_supports(instances: TaskInstances) -> tuple[np.ndarray, np.ndarray]:
    """Each instance's start support, as :func:`~vdbejax.engine.step.start_support` takes
    it, padded at the end with weight-0 states (which add nothing to the prefix sums)."""
    probability = np.asarray(instances.tables.start_probability)
    supports = [np.flatnonzero(row > 0) for row in probability]
    width = max(support.size for support in supports)
    states = np.zeros((len(supports), width), np.int32)
    weights = np.zeros((len(supports), width), np.float32)
    for i, support in enumerate(supports):
        states[i, :support.size] = support
        weights[i, :support.size] = probability[i, support]
    return states, weights


def with_instances(params: AgentParams, instances: TaskInstances) -> AgentParams:
    """``params`` with agent ``i``'s instance in row ``i`` of every kind (each kind holds
    a row for every agent).

    Raises:
      ValueError: a number of instances other than the number of agents.
    """
    num_agents = int(np.shape(params.kind)[0])
    if instances.num_agents != num_agents:
        raise ValueError(f"instances holds {instances.num_agents} instances for {num_agents}"
                         " agents: must hold one per agent")
    tables = jax.tree.map(np.asarray, instances.tables)
    states, weights = start_supports(instances)
    kinds = tuple(AgentOnTask(learner=agent.learner, explorer=agent.explorer, task=tables,
                              start_states=states, start_weights=weights)
                  for agent in params.kinds)
    return dataclasses.replace(params, kinds=kinds)


def instance_template(instances: TaskInstances, optimal_action: Any | None) -> TabularMDP:
    """The task the engine's programs are shaped by: agent 0's instance (with agent 0's
    mask of optimal actions where the run records them, so their buffers exist)."""
    template = instances.instance(0)
    if optimal_action is not None:
        template = dataclasses.replace(
            template, optimal_action=jax.device_put(np.asarray(optimal_action)[0]))
    return template


def with_instance_masks(instances: TaskInstances, optimal_action: Any | None
                        ) -> TaskInstances:
    """``instances`` with each agent's mask of optimal actions (bool ``[agents, S, A]``),
    or as they are for ``None``.

    Raises:
      ValueError: a mask that is not bool ``[agents, S, A]``.
    """
    if optimal_action is None:
        return instances
    mask = np.asarray(optimal_action)
    shape = (instances.num_agents, instances.num_states, instances.num_actions)
    if mask.shape != shape or mask.dtype != np.bool_:
        raise ValueError(f"optimal_action has shape {mask.shape} and dtype {mask.dtype}: must"
                         f" be bool {list(shape)} (agents, states, actions) with instances")
    return TaskInstances(tables=dataclasses.replace(instances.tables,
                                                    optimal_action=jax.device_put(mask)),
                         bounds=instances.bounds)


def lane_rows(agent: Any) -> AgentOnTask | None:
    """The lanes' own instances (``agent``'s rows), or ``None`` for a shared task."""
    first = agent.kinds[0] if isinstance(agent, KindSwitch) else agent
    return first if isinstance(first, AgentOnTask) else None


def lane_transition(rows: AgentOnTask, lane: Array, s: Array, a: Array, u: Array,
                    noise_u: Array | None) -> tuple[Array, Array, Array]:
    """Each lane's transition on its own instance (the computation of
    :func:`~vdbejax.engine.step._transition` on the lane's row)."""
    task: TabularMDP = rows.task
    S, A, K = task.next_state.shape[1:]
    if K != 1:
        return jax.vmap(TabularMDP.transition)(task, s, a, u, noise_u)
    flat = lane * (S * A) + s * A + a

    def at(table: Array) -> Array:
        return take(table.reshape(-1), flat)

    reward = at(task.reward)
    if task.reward_noise is not None:  # static: a task without noise draws nothing
        assert noise_u is not None  # (lockstep_iteration draws it for such a task)
        reward = noisy_reward(reward, at(task.reward_noise.model), at(task.reward_noise.std),
                              noise_u)
    return at(task.next_state), reward, at(task.terminal)


def lane_start(rows: AgentOnTask, lane: Array, u: Array) -> Array:
    """Each lane's start state, drawn from its instance's start support with ``u``."""
    width = rows.start_states.shape[1]
    index = sample_categorical(rows.start_weights.T, u)
    return take(rows.start_states.reshape(-1), lane * width + index)


def lane_optimal(rows: AgentOnTask, lane: Array, s: Array, a: Array) -> Array:
    """Whether each lane's action is optimal in its own instance."""
    mask = rows.task.optimal_action
    S, A = mask.shape[1:]
    return take(mask.reshape(-1), lane * (S * A) + s * A + a)

