"""The ablation's variants: each :class:`Variant` is one setting of the spec's open details
(or of the authors' agent details), grouped by mode (:data:`MODES`): the two readings and
one factor at a time (:data:`VARIANTS`), the authors' details one at a time
(:data:`ATTRIBUTION_VARIANTS`) and a factorial of four of them
(:data:`FACTORIAL_VARIANTS`); :class:`VariantResult` is one variant's scored outcome.

:mod:`vdbejax.paper.ablation` runs them; :mod:`vdbejax.paper.ablation_document` writes
the document.
"""
from __future__ import annotations

import dataclasses
import itertools
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from vdbejax.envs.cruz2018 import STEP_CAP
from vdbejax.methods.agents import AgentOptions
from vdbejax.methods.learners import PAPER_ALPHA
from vdbejax.paper.reproduce import AUTHORS_DETAILS
from vdbejax.results.summary import SummaryRow
from vdbejax.results.verdicts import ClaimResult


@dataclasses.dataclass(frozen=True)
class Variant:
    """One setting of the spec's options (defaults = the spec's)."""

    name: str
    description: str
    max_steps: int = 100
    invalid_action: str = "noop"
    tie_break: str = "random"
    q_init: float = 0.0
    alpha: float = PAPER_ALPHA  # stated by the paper, not an open detail: probed once
    reading: str = "textbook"
    #: The authors' agent details applied, as ``(name, value)`` pairs.
    details: tuple = ()

    def options(self) -> dict[str, Any]:
        """Keyword arguments of :func:`~vdbejax.paper.reproduce.reproduce`."""
        return {"max_steps": self.max_steps, "invalid_action": self.invalid_action,
                "options": AgentOptions(alpha=self.alpha, q_init=self.q_init,
                                        tie_break=self.tie_break),
                "reading": self.reading, "details": dict(self.details)}


#: The authors' reading: their task table and every agent detail (:data:`AUTHORS_DETAILS`).
AUTHORS_OPTIONS: dict[str, Any] = {"reading": "authors", "max_steps": STEP_CAP,
                                   "tie_break": "first",
                                   "details": tuple(AUTHORS_DETAILS.items())}

#: The two readings side by side, then one factor at a time away from the spec's defaults,
#: plus one combination.
VARIANTS: tuple[Variant, ...] = (
    Variant("spec", "the spec's defaults (the textbook reading)"),
    Variant("authors", "the authors' code: their task and every agent detail", **AUTHORS_OPTIONS),
    Variant("invalid_fail",
            "invalid_action = fail (an action that changes nothing ends the episode, −1)",
            invalid_action="fail"),
    Variant("tie_first", "tie_break = first (greedy takes the lowest-index maximal action)",
            tie_break="first"),
    Variant("max_steps_50", "max_steps = 50", max_steps=50),
    Variant("max_steps_200", "max_steps = 200", max_steps=200),
    Variant("q_init_pos", "q_init = +0.5 (optimistic)", q_init=0.5),
    Variant("q_init_neg", "q_init = −0.5 (pessimistic)", q_init=-0.5),
    Variant("fail_optimistic", "invalid_action = fail and q_init = +0.5",
            invalid_action="fail", q_init=0.5),
    # Not an open detail (the paper states α = 0.8), but the one change we found that
    # rescues SARSA: a diagnostic, reported as such.
    Variant("alpha_0.1", "α = 0.1 (beyond the spec's options: the paper states α = 0.8)",
            alpha=0.1),
)


def _attribution_variants() -> tuple[Variant, ...]:
    """From each reading, each detail of the other one switched alone (and the task)."""
    details = list(AUTHORS_DETAILS.items())
    authors = AUTHORS_OPTIONS
    variants = [Variant("textbook", "the paper's text (docs/task.md)"),
                Variant("authors", "the authors' code: their task and every agent detail",
                        **authors)]
    for name, value in details:
        variants.append(Variant(f"textbook+{name}", f"textbook, with {name} = {value!r}",
                                details=((name, value),)))
    variants += [
        Variant("textbook+tie_first", "textbook, with greedy ties to the first index",
                tie_break="first"),
        Variant("textbook+no_step_limit", f"textbook, with no step limit (cap {STEP_CAP})",
                max_steps=STEP_CAP),
        Variant("textbook+authors_task", "the authors' task table, the textbook agent",
                reading="authors", max_steps=STEP_CAP, details=()),
    ]
    for name, value in details:
        variants.append(Variant(f"authors-{name}", f"authors, without {name} = {value!r}",
                                **{**authors,
                                   "details": tuple(d for d in details if d[0] != name)}))
    variants += [
        Variant("authors-tie_first", "authors, with random greedy ties",
                **{**authors, "tie_break": "random"}),
        Variant("authors-no_step_limit", "authors, with the textbook's 100-step limit",
                **{**authors, "max_steps": 100}),
        Variant("authors-authors_task", "the authors' agent on the textbook task",
                **{**authors, "reading": "textbook", "max_steps": 100}),
    ]
    return tuple(variants)


#: The attribution mode (``vdbejax ablate --mode attribution``): which single detail of
#: the authors' code turns a claim's verdict.
ATTRIBUTION_VARIANTS: tuple[Variant, ...] = _attribution_variants()

#: The factorial mode's factors: the details that matter most, all combinations.
FACTORIAL_FACTORS: dict[str, tuple[Any, ...]] = {
    "failure_update": ("td", "overwrite"),
    "goal_update": ("td", "skip"),
    "alpha": (0.1, 0.3, PAPER_ALPHA),
    "q_init_distribution": ("constant", "uniform"),
}


def _factorial_variants() -> tuple[Variant, ...]:
    """Every combination of :data:`FACTORIAL_FACTORS`, from each reading (the other
    details of the reading kept)."""
    variants = []
    for base, options in (("textbook", {}), ("authors", AUTHORS_OPTIONS)):
        others = tuple((k, v) for k, v in dict(options.get("details", ())).items()
                       if k not in FACTORIAL_FACTORS)
        for failure, goal, alpha, q_init in itertools.product(*FACTORIAL_FACTORS.values()):
            details = (*others, ("failure_update", failure), ("goal_update", goal),
                       ("q_init_distribution", q_init))
            name = f"{base}-{failure}-{goal}-alpha{alpha:g}-{q_init}"
            description = (f"{base} reading, failure {failure}, goal {goal}, α = {alpha:g},"
                           f" initial Q {q_init}")
            variants.append(Variant(name, description, alpha=alpha,
                                    **{**options, "details": details}))
    return tuple(variants)


#: The factorial mode (``vdbejax ablate --mode factorial``): failure update × goal update
#: × α × initial Q, from each reading.
FACTORIAL_VARIANTS: tuple[Variant, ...] = _factorial_variants()
#: Document and figure folder of each mode.
MODES = {"options": ("ablation_scorecard.md", "ablation"),
         "attribution": ("ATTRIBUTION.md", "attribution"),
         "factorial": ("FACTORIAL.md", "factorial")}


@dataclasses.dataclass
class VariantResult:
    """Scored outcome of one variant."""

    variant: Variant
    summary: list[SummaryRow]
    claims: list[ClaimResult]
    best_return: float
    folder: Path
    #: How its results came: "trained", "reused" (a saved result of the same run) or
    #: "continued" (from an interrupted run's checkpoint).
    how: str = "trained"


def mode_variants(mode: str) -> tuple[Variant, ...]:
    """The variants of ``mode`` (:data:`MODES`; an unknown mode: :data:`VARIANTS`)."""
    return {"attribution": ATTRIBUTION_VARIANTS,
            "factorial": FACTORIAL_VARIANTS}.get(mode, VARIANTS)


def select_variants(names: str | Sequence[str] | None, mode: str = "options") -> list[Variant]:
    """Variants by name (comma-separated string or list); ``None`` = all of the mode's
    (:data:`VARIANTS` or :data:`ATTRIBUTION_VARIANTS`).

    Args:
      names: variant names, or ``None``.

    Returns:
      the variants, in the order named.

    Raises:
      ValueError: an unknown name (the message lists the known ones).
    """
    if mode not in MODES:
        raise ValueError(f"mode={mode!r} is invalid: must be one of {', '.join(MODES)}")
    if names is None:
        return list(mode_variants(mode))
    if isinstance(names, str):
        names = [n.strip() for n in names.split(",") if n.strip()]
    known = {v.name: v for v in mode_variants(mode)}
    unknown = [n for n in names if n not in known]
    if unknown or not names:
        raise ValueError(f"unknown variant(s) {unknown or names}: choose from {', '.join(known)}")
    return [known[n] for n in names]
