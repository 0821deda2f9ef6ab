"""The methods of ``vdbejax bench`` and the one rule that sets their hyperparameters.

**The rule, the same for every method and task.** Quantities a method is entitled to know
about a task are taken from the task: ``r_max`` (its largest reward magnitude), ``H`` (its
horizon, ``max_steps``) and the discount ``γ = 1 − 1/H`` of the discounted learners (an
effective horizon equal to the episode's; the finite-horizon methods use ``γ = 1``, their
own objective). TD learners use ``α = 0.1``. Each method then has **one** tuned
hyperparameter — its exploration knob — with three candidate values spread around its
published default (in units of ``r_max`` where the knob is a value), and nothing else is
tuned. Tuning runs every candidate on *tuning seeds* (another root seed than the reported
run's, so no reported number is a tuning number) and keeps the candidate with the least
mean cumulative regret; ties go to the earlier candidate. The tuning budget is stated in
the benchmark's ``meta.json``.

**The one cost rule.** A method whose planning works on a dense model, ``dense_model``
(PSRL: a Dirichlet draw over every successor of every pair and a backward induction over
it, every episode), costs :func:`episode_cost` ``= S (S + t) A (H + 1)`` products per
agent-episode, whatever it learns: its sampled ``[S + t, S, A]`` table, drawn once and read
by each of the H stages, with ``t = 1`` where the task has terminal outcomes (PSRL's
"terminal" outcome, Osband et al.'s prior) and 0 where it has none. Given a cost limit
(:data:`COST_LIMIT`: none by default), the benchmark leaves such a method out of a task
where that exceeds it: it is stated in the report and ``meta.json``, and the method's
aggregate covers the tasks it ran.

**Groups.** ``suite`` (the default) runs :data:`SUITE_METHODS` on the task suite's
``DEFAULT_SUITE``; ``bandits`` runs :data:`BANDIT_METHODS` — the paper's four, the
sample-average learner of Sutton & Barto (2018, §2.4) with ε-greedy and with Thompson
sampling, and the canon methods whose rule means something with one state — on
:data:`BANDIT_TASKS`, and records each episode's fraction of optimal actions
(:mod:`vdbejax.runs.optimal_record`). Left out of ``bandits``: the methods whose
mechanism needs states or steps to chain (Dyna-Q and Dyna-Q+ replay a model of one pair,
the traces have one step to trace, Expected SARSA and Double Q-learning equal Q-learning
on a one-step episode, Max-Boltzmann is ε-greedy with softmax, PSRL samples successors,
of which a bandit has one, and not its rewards).
"""
from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping, Sequence
from typing import Any

from vdbejax.methods.agents import Setting, horizon_discount, parameter_name

#: The step size of every TD learner.
ALPHA = 0.1
#: The most products per agent-episode a ``dense_model`` method may cost on a task
#: (``--cost-limit``): none by default — every method runs on every task of the default
#: suite within the benchmark's budget (PSRL on Taxi, the costliest: 3.0 × 10⁸ products,
#: 0.14 s per agent-episode on one core). A larger suite may need one.
COST_LIMIT = math.inf


@dataclasses.dataclass(frozen=True)
class TaskScale:
    """What a method may know of a task: its largest reward magnitude and its horizon."""

    r_max: float
    horizon: int

    @property
    def gamma(self) -> float:
        """The discount of the discounted learners, ``1 − 1/H``."""
        return horizon_discount(self.horizon)

    def value(self, unit: str) -> float:
        """The size of a unit: ``"1"``, ``"r_max"`` or ``"r_max_h"`` (``r_max · H``)."""
        return {"1": 1.0, "r_max": self.r_max, "r_max_h": self.r_max * self.horizon}[unit]


@dataclasses.dataclass(frozen=True)
class BenchMethod:
    """One method of the benchmark: a learner, an explorer and its tuned knob.

    Attributes:
      name: short name (``--methods``).
      title: label in tables and figures.
      family: ``paper`` (Cruz et al.'s four), ``undirected``, ``directed`` (counts,
        optimism), ``model-based``, ``posterior`` or ``planning``.
      learner, explorer: registered names.
      tuned: the tuned hyperparameter (the explorer's swept one goes to ``Setting.param``);
        ``None``: nothing tuned.
      grid: its candidate values, in units of ``unit``.
      unit: ``"1"``, ``"r_max"`` or ``"r_max_h"``.
      fixed: other hyperparameters; a value ``("r_max", x)`` means ``x`` units.
      discounted: uses ``γ = 1 − 1/H`` (else the finite-horizon ``γ = 1`` and ``horizon = H``).
      td: a TD learner (``α`` = :data:`ALPHA`).
      dense_model: its planning works on a dense ``[S + t, S, A]`` model every episode
        (see the module's cost rule).
    """

    name: str
    title: str
    family: str
    learner: str
    explorer: str
    tuned: str | None
    grid: tuple[float, ...] = ()
    unit: str = "1"
    fixed: Mapping[str, Any] = dataclasses.field(default_factory=dict)
    discounted: bool = True
    td: bool = True
    dense_model: bool = False

    def episode_cost(self, num_states: int, num_actions: int, horizon: int,
                     terminates: bool) -> float:
        """Products per agent-episode of a ``dense_model`` method, ``S (S + t) A (H + 1)``
        with ``t = 1`` if the task ``terminates`` (has terminal outcomes), else 0 (its draw
        and its H stages); 0 for the others."""
        if not self.dense_model:
            return 0.0
        outcomes = num_states + (1 if terminates else 0)
        return float(num_states) * outcomes * num_actions * (horizon + 1)

    def candidates(self, scale: TaskScale) -> list[Setting]:
        """The tuning candidates on a task of this ``scale`` (one if nothing is tuned)."""
        values: dict[str, Any] = {}
        if self.td:
            values["alpha"] = ALPHA
        if self.discounted:
            values["gamma"] = scale.gamma
        else:
            values.update(gamma=1.0, horizon=int(scale.horizon))
        for key, value in self.fixed.items():
            values[key] = (value[1] * scale.value(value[0]) if isinstance(value, tuple)
                           else value)
        if self.tuned is None:
            return [Setting(self.learner, self.explorer, None, values)]
        swept = self.tuned == parameter_name(self.explorer)
        settings = []
        for multiple in self.grid:
            value = float(multiple * scale.value(self.unit))
            if swept:
                settings.append(Setting(self.learner, self.explorer, value, values))
            else:
                settings.append(Setting(self.learner, self.explorer, None,
                                        {**values, self.tuned: value}))
        return settings

    def default_candidate(self, scale: TaskScale) -> Setting:
        """The candidate run untuned (``--no-tune``): the middle one."""
        options = self.candidates(scale)
        return options[len(options) // 2]


_R = "r_max"
_EPS = (0.01, 0.1, 0.3)
#: Every method of the benchmark, in the order of its tables.
METHODS: tuple[BenchMethod, ...] = (
    BenchMethod("egreedy", "Q-learning ε-greedy", "paper", "qlearning", "egreedy", "epsilon", _EPS),
    BenchMethod("softmax", "Q-learning softmax", "paper", "qlearning", "softmax", "tau",
                (0.01, 0.1, 1.0), _R),
    BenchMethod("vdbe", "Q-learning VDBE", "paper", "qlearning", "vdbe", "sigma",
                (0.1, 1.0, 10.0), _R),
    BenchMethod("vdbe_softmax", "Q-learning VDBE-Softmax", "paper", "qlearning", "vdbe_softmax",
                "sigma", (0.1, 1.0, 10.0), _R, {"tau": (_R, 0.01)}),
    BenchMethod("max_boltzmann", "Q-learning Max-Boltzmann", "undirected", "qlearning",
                "max_boltzmann", "epsilon", _EPS, fixed={"tau": (_R, 0.1)}),
    BenchMethod("expected_sarsa", "Expected SARSA ε-greedy", "undirected", "expected_sarsa",
                "egreedy", "epsilon", _EPS),
    BenchMethod("double_q", "Double Q-learning ε-greedy", "undirected", "double_qlearning",
                "egreedy", "epsilon", _EPS),
    BenchMethod("ucb1", "Q-learning UCB-1", "directed", "qlearning", "ucb1", "c",
                (0.1, 1.0, 10.0), _R),
    BenchMethod("count_bonus", "Q-learning count bonus", "directed", "qlearning", "count_bonus",
                "beta", (0.01, 0.1, 1.0), _R),
    BenchMethod("optimistic_q", "Q-learning, optimistic Q₀", "directed", "qlearning", "greedy",
                "q_init", (0.1, 1.0), "r_max_h"),
    BenchMethod("ucb_h", "UCB-H (optimistic Q-learning)", "directed", "ucb_h", "greedy",
                "bonus_scale", (0.01, 0.1, 1.0), fixed={"r_max": (_R, 1.0)}, discounted=False,
                td=False),
    BenchMethod("delayed_q", "Delayed Q-learning", "directed", "delayed_q", "greedy", "updates",
                (1.0, 5.0, 20.0), fixed={"r_max": (_R, 1.0), "epsilon1": (_R, 0.01)}, td=False),
    BenchMethod("rmax", "R-max", "model-based", "rmax", "greedy", "known_visits",
                (1.0, 5.0, 20.0), fixed={"r_max": (_R, 1.0)}, td=False),
    BenchMethod("mbie_eb", "MBIE-EB", "model-based", "mbie_eb", "greedy", "beta",
                (0.01, 0.1, 1.0), _R, {"r_max": (_R, 1.0)}, td=False),
    BenchMethod("ucbvi", "UCBVI", "model-based", "ucbvi", "greedy", "bonus_scale",
                (0.01, 0.1, 1.0), fixed={"r_max": (_R, 1.0)}, discounted=False, td=False),
    BenchMethod("psrl", "PSRL", "posterior", "psrl", "greedy", "prior", (0.1, 1.0),
                discounted=False, td=False, dense_model=True),
    BenchMethod("dyna_q", "Dyna-Q ε-greedy", "planning", "dyna_q", "egreedy", "epsilon", _EPS),
    BenchMethod("dyna_q_plus", "Dyna-Q+", "planning", "dyna_q_plus", "egreedy", "kappa",
                (1e-4, 1e-3, 1e-2), _R, {"epsilon": 0.1}),
    BenchMethod("sarsa_lambda", "SARSA(λ) ε-greedy", "planning", "sarsa_lambda", "egreedy",
                "epsilon", _EPS, fixed={"lam": 0.9}),
    BenchMethod("q_lambda", "Watkins Q(λ) ε-greedy", "planning", "q_lambda", "egreedy",
                "epsilon", _EPS, fixed={"lam": 0.9}),
    BenchMethod("sample_average", "sample-average ε-greedy", "undirected", "sample_average",
                "egreedy", "epsilon", _EPS, td=False),
    BenchMethod("thompson", "sample-average Thompson (Gaussian)", "posterior", "sample_average",
                "thompson", "scale", (0.3, 1.0, 3.0), td=False),
)
#: name -> method.
BY_NAME = {method.name: method for method in METHODS}
#: The methods of ``--quick``.
QUICK_METHODS = ("egreedy", "vdbe", "ucb1", "rmax", "dyna_q")
#: The methods of the ``suite`` group (the default).
SUITE_METHODS = tuple(m.name for m in METHODS[:20])
#: The ``bandits`` group: its tasks and methods (module docstring).
BANDIT_TASKS = ("gaussian_bandit:10", "bernoulli_bandit:10", "testbed:10")
BANDIT_METHODS = ("egreedy", "softmax", "vdbe", "vdbe_softmax", "sample_average", "thompson",
                  "ucb1", "count_bonus", "optimistic_q", "ucb_h", "delayed_q", "rmax",
                  "mbie_eb", "ucbvi")
#: ``--group``: name -> (its default tasks, or None for the suite's; its methods).
GROUPS: dict[str, tuple[tuple[str, ...] | None, tuple[str, ...]]] = {
    "suite": (None, SUITE_METHODS), "bandits": (BANDIT_TASKS, BANDIT_METHODS)}


def group_defaults(group: str, tasks: Sequence[str] | str | None,
                   methods: Sequence[str] | str | None
                   ) -> tuple[Sequence[str] | str | None, Sequence[str] | str]:
    """The tasks and methods of a run of ``group`` (:data:`GROUPS`): those given, else
    the group's.

    Raises:
      ValueError: an unknown group.
    """
    if group not in GROUPS:
        raise ValueError(f"group={group!r} is invalid: must be one of {', '.join(GROUPS)}")
    group_tasks, group_methods = GROUPS[group]
    return (group_tasks if tasks is None else tasks,
            group_methods if methods is None else methods)


def select_methods(names: Sequence[str] | str | None) -> list[BenchMethod]:
    """The methods named (by default those of the ``suite`` group), in :data:`METHODS`
    order.

    Raises:
      ValueError: an unknown or repeated name, or none.
    """
    if names is None:
        names = SUITE_METHODS
    if isinstance(names, str):
        names = [n.strip() for n in names.split(",") if n.strip()]
    names = list(names)
    unknown = [n for n in names if n not in BY_NAME]
    if unknown or not names or len(set(names)) != len(names):
        raise ValueError(f"methods={','.join(names)!r} is invalid: must be distinct names of"
                         f" {', '.join(BY_NAME)}")
    return [m for m in METHODS if m.name in names]


__all__ = ["ALPHA", "BANDIT_METHODS", "BANDIT_TASKS", "BY_NAME", "COST_LIMIT", "GROUPS", "METHODS",
           "QUICK_METHODS", "SUITE_METHODS", "BenchMethod", "TaskScale", "group_defaults",
           "select_methods"]
