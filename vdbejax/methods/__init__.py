"""The plug-in surface: explorers, learners and the agents built from them.

* the plug-in surface, importable from here (``__all__``): the contract
  (:mod:`vdbejax.methods.contract`, whose docstring states it: :class:`Explorer`,
  :class:`Learner`, :class:`Table`, :class:`TaskFacts`, :class:`Context`,
  :class:`Transition`, :class:`Draws`), the registry and its decorators
  (:mod:`vdbejax.methods.registry`) and the plug-in check
  (:mod:`vdbejax.methods.plugin_check`).
* :mod:`vdbejax.methods.selection` — the action-selection rules as pure functions
  (greedy, softmax, the paper's one rule, the VDBE ε(s) update).
* :mod:`vdbejax.methods.explorers` — greedy, ε-greedy, softmax, VDBE, VDBE-Softmax, Max-Boltzmann,
  decaying ε-greedy and softmax, UCB-1, count bonus; :mod:`vdbejax.methods.thompson` —
  Thompson sampling (Gaussian and Beta posteriors).
* :mod:`vdbejax.methods.learners` — Q-learning, SARSA, Expected SARSA, Double Q-learning,
  sample average.
* :mod:`vdbejax.methods.model` — the agent's count model of its task and planning on it;
  :mod:`vdbejax.methods.model_based` — R-max, MBIE-EB; :mod:`vdbejax.methods.traces` —
  SARSA(λ), Watkins Q(λ); :mod:`vdbejax.methods.dyna` — Dyna-Q, Dyna-Q+;
  :mod:`vdbejax.methods.finite_horizon` — UCBVI, UCB-H; :mod:`vdbejax.methods.posterior` —
  PSRL;
  :mod:`vdbejax.methods.delayed_q` — Delayed Q-learning.
* :mod:`vdbejax.methods.agents` — :class:`Setting`, :func:`make_agent`;
  :mod:`vdbejax.methods.grid_axes` — :func:`sweep`.
"""
from vdbejax._numerics import rounded, sample_categorical
from vdbejax._pytree import static_field
from vdbejax.methods import (
    delayed_q,
    dyna,
    explorers,
    finite_horizon,
    learners,
    model,
    model_based,
    posterior,
    thompson,
    traces,
)
from vdbejax.methods.agents import (
    Agent,
    AgentOptions,
    AgentParams,
    Setting,
    make_agent,
    paper_settings,
    stack_agents,
)
from vdbejax.methods.contract import (
    Context,
    Draws,
    Explorer,
    Learner,
    LearnerUpdate,
    Table,
    TaskFacts,
    Transition,
)
from vdbejax.methods.grid_axes import sweep
from vdbejax.methods.plugin_check import check_plugin
from vdbejax.methods.registry import (
    EXPLORERS,
    LEARNERS,
    explorer,
    explorer_title,
    learner,
    learner_title,
)
from vdbejax.methods.selection import greedy, select_action, softmax_weights

__all__ = [
    "EXPLORERS",
    "LEARNERS",
    "Agent",
    "AgentOptions",
    "AgentParams",
    "Context",
    "Draws",
    "Explorer",
    "Learner",
    "LearnerUpdate",
    "Setting",
    "Table",
    "TaskFacts",
    "Transition",
    "check_plugin",
    "delayed_q",
    "dyna",
    "explorer",
    "explorer_title",
    "explorers",
    "finite_horizon",
    "greedy",
    "learner",
    "learner_title",
    "learners",
    "make_agent",
    "model",
    "model_based",
    "paper_settings",
    "posterior",
    "rounded",
    "sample_categorical",
    "select_action",
    "softmax_weights",
    "stack_agents",
    "static_field",
    "sweep",
    "thompson",
    "traces",
]
