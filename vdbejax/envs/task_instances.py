"""One instance of a task per agent: :class:`TaskInstances`.

A task family with a generator (a bandit of random arm means, a random MDP) gives every
agent of a run its own instance. The instances share their shape (states, actions,
outcomes), their episode length and whether their rewards are noisy; their tables are
stacked along a leading agent axis, and the engine moves each agent's row with the agent
(:mod:`vdbejax.engine.agent_on_task`), so an agent meets its own instance in the same
vectorised run, bit for bit as if it ran alone on it. The stacked tables stay on the host:
an engine call sends a batch's rows to its devices (and a run's plan counts them,
:mod:`vdbejax.runs.batching`).
"""
from __future__ import annotations

import dataclasses
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import jax
import numpy as np

from vdbejax._pytree import pytree_dataclass, static_field
from vdbejax.envs.tabular import TabularMDP
from vdbejax.validation import UINT32_MAX, check_int


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


#: The parameter every family has: the seed of the instance a setting's agents meet
#: (``None``: each agent its own, drawn from the root seed and its seed index).
INSTANCE = "instance"


@dataclasses.dataclass(frozen=True)
class TaskFamily:
    """A task family with a generator: instance ``i`` of a run is ``generate((seed, i))``.

    Its parameters (a noise scale, …) and :data:`INSTANCE` are a sweep's axes
    (``task.std``, ``task.instance``: a :class:`~vdbejax.methods.agents.Setting`'s
    ``task.`` values): every setting's agents meet the instances its values draw.

    Attributes:
      name: the family's task name (``testbed:10``, …), each instance's label.
      generate: ``generate(entropy, **parameters)``: the instance drawn from the integers
        ``entropy`` (a pure function of them and the parameters: the same entropy and
        values, the same instance); it raises a ``ValueError`` for a bad value.
      description: one line for reports.
      parameters: ``{name: default}`` of ``generate``'s keyword parameters.
      instance: the default of :data:`INSTANCE`: ``None``, each agent its own instance
        (drawn from the root seed and its seed index); an integer ``k``, every agent the
        one instance ``generate((k,))`` (a named task's own, where the family has one).
    """

    name: str
    generate: Callable[..., TabularMDP]
    description: str = ""
    parameters: Mapping[str, Any] = dataclasses.field(default_factory=dict)
    instance: int | None = None

    def resolve(self, values: Mapping[str, Any]) -> dict[str, Any]:
        """``values`` (a setting's ``task.`` values, without the prefix) with the defaults
        of the parameters they leave out, :data:`INSTANCE` among them.

        Raises:
          ValueError: a name the family does not have, or an instance seed that is not
            an integer ≥ 0.
        """
        allowed = [INSTANCE, *self.parameters]
        for name in values:
            if name not in allowed:
                raise ValueError(f"task parameter {name!r} is invalid for {self.name}: must be"
                                 f" one of {', '.join(allowed)}")
        resolved = {INSTANCE: self.instance, **self.parameters, **values}
        instance = resolved[INSTANCE]
        if instance is not None:
            resolved[INSTANCE] = check_int(f"task.{INSTANCE}", instance, 0, UINT32_MAX)
        return resolved

    def draw(self, entropy: tuple[int, ...], values: Mapping[str, Any]) -> TabularMDP:
        """The instance of ``entropy`` under resolved ``values`` (:meth:`resolve`): the one
        of their :data:`INSTANCE` seed where they name one."""
        parameters = {k: v for k, v in values.items() if k != INSTANCE}
        seed = values.get(INSTANCE)
        try:
            return self.generate(entropy if seed is None else (seed,), **parameters)
        except ValueError as error:  # named as the sweep names it
            shown = ", ".join(f"task.{k}={v!r}" for k, v in parameters.items())
            raise ValueError(f"{shown or 'the defaults'} of {self.name}: {error}") from None

    def instances(self, seed: int, num_seeds: int,
                  configs: Sequence[Mapping[str, Any]] = ({},)) -> TaskInstances:
        """The instances of a run's agents, config-major (c0s0, c0s1, …): agent (config
        ``c``, seed index ``i``) of root seed ``seed`` meets ``generate((seed, i))`` under
        ``configs[c]``'s resolved values, whatever else its config holds (common random
        numbers, as its key), so results depend only on the seed and the
        hyperparameters."""
        drawn: dict[tuple, TabularMDP] = {}  # settings that share their values share tables
        rows = []
        for values in configs:
            values = self.resolve(values)
            for i in range(int(num_seeds)):
                key = (i if values[INSTANCE] is None else None, *sorted(values.items()))
                if key not in drawn:
                    drawn[key] = self.draw((int(seed), i), values)
                rows.append(drawn[key])
        return stack_instances(rows)
