"""Agent = learner + explorer hyperparameters, and the settings of a sweep.

A :class:`Setting` names one point of a grid (learner, explorer, swept parameter);
:func:`make_agent` turns it into :class:`AgentParams`, whose leaves are scalars, and
:func:`stack_agents` stacks many into one batch for ``vmap``.
"""
from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from vdbejax._pytree import pytree_dataclass
from vdbejax.explorers import (
    EXPLORERS,
    VDBE_DELTA,
    VDBE_SOFTMAX_TAU,
    ExplorerParams,
    make_explorer,
)
from vdbejax.learners import (
    LEARNERS,
    PAPER_ALPHA,
    PAPER_GAMMA,
    LearnerParams,
    make_learner,
)

#: The paper's swept values (spec, "Exploration").
PAPER_PARAMETERS: dict[str, tuple[float, ...]] = {
    "egreedy": (0.01, 0.05, 0.1, 0.15, 0.2),
    "softmax": (0.0001, 0.001, 0.01, 0.1, 1.0, 10.0),
    "vdbe": (0.001, 0.01, 0.1, 1.0, 10.0, 100.0),
    "vdbe_softmax": (0.001, 0.01, 0.1, 1.0, 10.0, 100.0),
}
#: Name of each explorer's swept parameter.
PARAMETER_NAMES = {"egreedy": "epsilon", "softmax": "tau", "vdbe": "sigma", "vdbe_softmax": "sigma"}


@dataclasses.dataclass(frozen=True)
class Setting:
    """One configuration of a grid: learner, explorer and the explorer's parameter."""

    learner: str
    explorer: str
    param: float

    @property
    def label(self) -> str:
        return f"{self.learner}/{self.explorer}/{PARAMETER_NAMES[self.explorer]}={self.param:g}"


@dataclasses.dataclass(frozen=True)
class AgentOptions:
    """Options shared by every agent of a run (spec defaults)."""

    alpha: float = PAPER_ALPHA
    gamma: float = PAPER_GAMMA
    q_init: float = 0.0
    tie_break: str = "random"
    delta: float = VDBE_DELTA
    vdbe_softmax_tau: float = VDBE_SOFTMAX_TAU


@pytree_dataclass
class AgentParams:
    """All hyperparameters of one agent (or a batch of agents, leading axis)."""

    learner: LearnerParams
    explorer: ExplorerParams


def paper_settings(
    learners: Sequence[str] = LEARNERS, explorers: Sequence[str] = EXPLORERS
) -> list[Setting]:
    """The paper's grid: 2 learners × (5 + 6 + 6 + 6) parameters = 46 settings.

    Args:
      learners: learner names (default both).
      explorers: explorer names (default all four).

    Returns:
      the settings, learner-major, then explorer, then increasing parameter.
    """
    return [
        Setting(learner, explorer, param)
        for learner in learners
        for explorer in explorers
        for param in PAPER_PARAMETERS[explorer]
    ]


def make_agent(setting: Setting, options: AgentOptions = AgentOptions()) -> AgentParams:
    """Validated hyperparameters of one agent.

    Args:
      setting: learner, explorer and the explorer's parameter.
      options: options shared by every agent (spec defaults).

    Returns:
      the :class:`AgentParams` (scalar leaves).

    Raises:
      ValueError: unknown learner/explorer or an out-of-range value.
    """
    return AgentParams(
        learner=make_learner(
            setting.learner, alpha=options.alpha, gamma=options.gamma, q_init=options.q_init
        ),
        explorer=make_explorer(
            setting.explorer,
            setting.param,
            tie_break=options.tie_break,
            delta=options.delta,
            vdbe_softmax_tau=options.vdbe_softmax_tau,
        ),
    )


def stack_agents(agents: Sequence[AgentParams]) -> AgentParams:
    """Stack agents along a new leading axis (all must share static fields).

    Args:
      agents: one or more :class:`AgentParams`.

    Returns:
      :class:`AgentParams` whose leaves have a leading agent axis.

    Raises:
      ValueError: ``agents`` is empty.
    """
    if not agents:
        raise ValueError("agents is empty: need at least one setting")
    return jax.tree.map(_stack, *agents)


def _stack(*leaves: Any) -> Any:
    # On the host when every leaf is (no device round trip for a grid's few scalars).
    if any(isinstance(leaf, jax.Array) for leaf in leaves):
        return jnp.stack(leaves)
    return np.stack(leaves)
