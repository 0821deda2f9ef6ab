"""The plug-in surface: explorers, learners and the agents built from them.

* :mod:`vdbejax.methods.api` — the contract (:class:`Explorer`, :class:`Learner`,
  :class:`Table`, :class:`Context`, :class:`Transition`) and the registering decorators.
* :mod:`vdbejax.methods.explorers` — ε-greedy, softmax, VDBE, VDBE-Softmax, Max-Boltzmann,
  decaying ε-greedy and softmax, UCB-1, count bonus.
* :mod:`vdbejax.methods.learners` — Q-learning, SARSA, Expected SARSA, Double Q-learning.
* :mod:`vdbejax.methods.agents` — :class:`Setting`, :func:`sweep`, :func:`make_agent`.
"""
from vdbejax._numerics import rounded, sample_categorical
from vdbejax._pytree import static_field
from vdbejax.methods import explorers, learners
from vdbejax.methods.agents import (
    Agent,
    AgentOptions,
    AgentParams,
    Setting,
    make_agent,
    paper_settings,
    stack_agents,
    sweep,
)
from vdbejax.methods.api import (
    EXPLORERS,
    LEARNERS,
    Context,
    Explorer,
    Learner,
    LearnerUpdate,
    Table,
    Transition,
    check_plugin,
    explorer,
    explorer_title,
    learner,
    learner_title,
)
from vdbejax.methods.explorers import greedy, select_action, softmax_weights

__all__ = [
    "EXPLORERS", "LEARNERS", "Agent", "AgentOptions", "AgentParams", "Context", "Explorer",
    "Learner", "LearnerUpdate", "Setting", "Table", "Transition", "check_plugin", "explorer",
    "explorer_title", "explorers", "greedy", "learner", "learner_title", "learners",
    "make_agent", "paper_settings", "rounded",
    "sample_categorical", "select_action", "softmax_weights", "stack_agents", "static_field",
    "sweep",
]
