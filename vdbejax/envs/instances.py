"""One instance of a task per agent: :class:`TaskInstances`.

A task family with a generator (a bandit of random arm means, a random MDP) gives every
agent of a run its own instance. The instances share their shape (states, actions,
outcomes), their episode length and whether their rewards are noisy; their tables are
stacked along a leading agent axis, and the engine moves each agent's row with the agent
(:mod:`vdbejax.engine.instances`), so an agent meets its own instance in the same
vectorised run, bit for bit as if it ran alone on it.
"""
from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from typing import Any

import jax
import numpy as np

from vdbejax._pytree import pytree_dataclass
from vdbejax.envs.tabular import TabularMDP

Array = jax.Array


@pytree_dataclass
class TaskInstances:
    """The instances of a run's agents, one per agent, in agent order.

    Attributes:
      tables: a :class:`~vdbejax.envs.tabular.TabularMDP` whose every array leaf carries a
        leading agent axis (``next_state`` ``[agents, S, A, K]``, …): row ``i`` is agent
        ``i``'s instance. Its ``num_states`` … properties do not apply: use this class's.
    """

    tables: TabularMDP

    @property
    def num_agents(self) -> int:
        return int(self.tables.next_state.shape[0])

    @property
    def num_states(self) -> int:
        return int(self.tables.next_state.shape[1])

    @property
    def num_actions(self) -> int:
        return int(self.tables.next_state.shape[2])

    @property
    def num_outcomes(self) -> int:
        return int(self.tables.next_state.shape[3])

    @property
    def name(self) -> str:
        return self.tables.name

    def instance(self, agent: int) -> TabularMDP:
        """Agent ``agent``'s instance, an ordinary (unbatched) task."""
        return jax.tree.map(lambda leaf: leaf[agent], self.tables)


def stack_instances(mdps: Sequence[TabularMDP]) -> TaskInstances:
    """The instances ``mdps`` (one per agent, in agent order) as one :class:`TaskInstances`.

    Raises:
      ValueError: no instance, or instances that differ in their states, actions,
        outcomes, episode length, state codes or in having reward noise.
    """
    mdps = list(mdps)
    if not mdps or not all(isinstance(m, TabularMDP) for m in mdps):
        raise ValueError(f"mdps={type(mdps).__name__} of {len(mdps)} is invalid: must be one"
                         " TabularMDP or more (an instance per agent)")
    first = mdps[0]
    shape, steps = tuple(first.next_state.shape), int(first.max_steps)
    for i, mdp in enumerate(mdps):
        if tuple(mdp.next_state.shape) != shape or int(mdp.max_steps) != steps:
            raise ValueError(
                f"mdps[{i}] has [S, A, K] = {list(mdp.next_state.shape)} and max_steps"
                f" {int(mdp.max_steps)}: every instance must have {list(shape)} and {steps}")
        if (mdp.reward_noise is None) != (first.reward_noise is None) or (
                (mdp.state_codes is None) != (first.state_codes is None)) or (
                (mdp.optimal_action is None) != (first.optimal_action is None)):
            raise ValueError(f"mdps[{i}] differs from mdps[0] in having reward noise, state"
                             " codes or an optimal-action mask: all instances or none")
    if first.state_codes is not None and not all(
            np.array_equal(np.asarray(m.state_codes), np.asarray(first.state_codes))
            for m in mdps):
        raise ValueError("mdps hold different state_codes: every instance must encode its"
                         " states alike")

    # one label (a static field: the trees must match)
    mdps = [dataclasses.replace(m, name=first.name) for m in mdps]

    def stack(*leaves: Any) -> Array:
        return jax.device_put(np.stack([np.asarray(leaf) for leaf in leaves]))

    return TaskInstances(tables=jax.tree.map(stack, *mdps))
