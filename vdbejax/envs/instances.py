"""One instance of a task per agent: :class:`TaskInstances`.

A task family with a generator (a bandit of random arm means, a random MDP) gives every
agent of a run its own instance. The instances share their shape (states, actions,
outcomes), their episode length and whether their rewards are noisy; their tables are
stacked along a leading agent axis, and the engine moves each agent's row with the agent
(:mod:`vdbejax.engine.instances`), so an agent meets its own instance in the same
vectorised run, bit for bit as if it ran alone on it. The stacked tables stay on the host:
an engine call sends a batch's rows to its devices (and a run's plan counts them,
:mod:`vdbejax.runs.batching`).
"""
from __future__ import annotations

import dataclasses
from collections.abc import Callable, Sequence
from typing import Any

import jax
import numpy as np

from vdbejax._pytree import pytree_dataclass, static_field
from vdbejax.envs.tabular import TabularMDP


@pytree_dataclass
class TaskInstances:
    """The instances of a run's agents, one per agent, in agent order.

    Attributes:
      tables: a :class:`~vdbejax.envs.tabular.TabularMDP` whose every array leaf carries a
        leading agent axis (``next_state`` ``[agents, S, A, K]``, …): row ``i`` is agent
        ``i``'s instance (NumPy arrays, on the host). Its ``num_states`` … properties do not
        apply: use this class's.
    """

    tables: TabularMDP
    bounds: tuple = static_field(None)

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

    def take(self, rows: Any) -> TaskInstances:
        """The instances of agents ``rows`` (the run's :attr:`bounds` kept)."""
        rows = np.asarray(rows)
        return TaskInstances(tables=jax.tree.map(lambda leaf: leaf[rows], self.tables),
                             bounds=self.bounds)

    def instance(self, agent: int) -> TabularMDP:
        """Agent ``agent``'s instance, an ordinary (unbatched) task, on the device."""
        return jax.tree.map(lambda leaf: jax.device_put(np.asarray(leaf)[agent]), self.tables)


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

    def stack(*leaves: Any) -> np.ndarray:  # on the host: every agent's, for the whole run
        return np.stack([np.asarray(leaf) for leaf in leaves])

    tables = jax.tree.map(stack, *mdps)
    possible = np.asarray(tables.probability) > 0
    reward = np.asarray(tables.reward, np.float64)[possible]
    return TaskInstances(tables=tables, bounds=(
        float(reward.min()), float(reward.max()),
        bool(np.asarray(tables.terminal)[possible].any())))


@dataclasses.dataclass(frozen=True)
class TaskFamily:
    """A task family with a generator: instance ``i`` of a run is ``generate((seed, i))``.

    Attributes:
      name: the family's task name (``testbed:10``, …), each instance's label.
      generate: ``generate(entropy)``: the instance drawn from the integers ``entropy``
        (a pure function of them: the same entropy, the same instance).
      description: one line for reports.
    """

    name: str
    generate: Callable[[tuple[int, ...]], TabularMDP]
    description: str = ""

    def instances(self, seed: int, num_seeds: int, num_configs: int = 1) -> TaskInstances:
        """The instances of a run's agents, config-major (c0s0, c0s1, …): agent (config
        ``c``, seed index ``i``) of root seed ``seed`` meets ``generate((seed, i))``,
        whatever its config (common random numbers, as its key), so results depend only
        on the seed and the hyperparameters."""
        drawn = [self.generate((int(seed), i)) for i in range(int(num_seeds))]
        return stack_instances(drawn * int(num_configs))
