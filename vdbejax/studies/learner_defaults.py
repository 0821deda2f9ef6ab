"""The learner values a sweep's task gives the settings that do not give their own.

**The rule** (``docs/suite.md``, "Learner defaults"): the paper's tasks — ``table_cleaning``,
``cruz2018`` and ``variant:NxK`` — keep the paper's values (α = 0.8, γ = 0.9; the
finite-horizon learners their own γ = 1 and horizon), so the paper grid, the authors'
reading and ``vdbejax scale`` are what they were. Every other task gets the benchmark's
rule (:mod:`vdbejax.studies.bench_methods`): α = 0.1, γ = 1 − 1/H for the discounted
learners and γ = 1 with horizon H for the finite-horizon ones, H the run's ``max_steps``.
A setting's own values (``--set``, ``--axis``, ``--setting``) take precedence, and a sweep
may name the rule (``learner_defaults = "paper"`` or ``"benchmark"``); a finished folder
rerun with ``--config FOLDER`` keeps the rule it ran with.
"""
from __future__ import annotations

import dataclasses
from typing import Any

from vdbejax.methods.agents import AgentOptions, horizon_discount
from vdbejax.methods.learners import PAPER_ALPHA, PAPER_GAMMA
from vdbejax.studies.bench_methods import ALPHA
from vdbejax.validation import check_choice

#: The rules (``learner_defaults``): the benchmark's, the paper's.
RULES = ("benchmark", "paper")


def paper_task(task: str) -> bool:
    """Whether ``task`` is one of the paper's (``table_cleaning``, ``cruz2018``,
    ``variant:NxK``): its default rule is the paper's."""
    return task in ("table_cleaning", "cruz2018") or task.startswith("variant:")


@dataclasses.dataclass(frozen=True)
class LearnerDefaults:
    """The learner values of a run's settings that give none of their own.

    Attributes:
      rule: ``"benchmark"`` or ``"paper"`` (:data:`RULES`).
      horizon: the run's horizon H (``max_steps``).
    """

    rule: str
    horizon: int

    @property
    def options(self) -> AgentOptions:
        """The :class:`~vdbejax.methods.agents.AgentOptions` of the rule (the paper's: the
        default options, as every run before the rule)."""
        if self.rule == "paper":
            return AgentOptions()
        return AgentOptions(alpha=ALPHA, horizon=self.horizon)

    def describe(self) -> dict[str, Any]:
        """``{"rule", "alpha", "gamma", "finite_horizon"}`` as ``meta.json`` records them
        (``finite_horizon``: the finite-horizon learners' ``gamma`` and ``horizon``)."""
        if self.rule == "paper":
            return {"rule": "paper", "alpha": PAPER_ALPHA, "gamma": PAPER_GAMMA,
                    "finite_horizon": "their own (gamma 1 and their horizon field)"}
        return {"rule": "benchmark", "alpha": ALPHA, "gamma": horizon_discount(self.horizon),
                "finite_horizon": {"gamma": 1.0, "horizon": self.horizon}}

    def text(self) -> str:
        """One line: every default value and the rule."""
        if self.rule == "paper":
            return (f"alpha={PAPER_ALPHA:g}, gamma={PAPER_GAMMA:g} (the finite-horizon learners:"
                    " gamma=1 and their own horizon): the paper's values")
        return (f"alpha={ALPHA:g}, gamma={horizon_discount(self.horizon):g} = 1 − 1/H (the"
                f" finite-horizon learners: gamma=1, horizon={self.horizon}): the benchmark's"
                f" rule, H = {self.horizon}")


def learner_defaults(task: str, horizon: int, rule: str | None = None) -> LearnerDefaults:
    """The :class:`LearnerDefaults` of a run on ``task`` with episodes of ``horizon``
    steps; ``rule`` ``None``: the paper's for the paper's tasks (:func:`paper_task`), the
    benchmark's for any other.

    Raises:
      ValueError: a ``rule`` not in :data:`RULES`.
    """
    if rule is None:
        rule = "paper" if paper_task(task) else "benchmark"
    return LearnerDefaults(check_choice("learner_defaults", rule, RULES), int(horizon))
