"""The claims' machinery: the thresholds, a check, a claim's result and the summary table
the checks read (:class:`ClaimTable`); the rules they follow are stated in
:mod:`vdbejax.paper.claims`, which scores the six claims with them.
"""
from __future__ import annotations

import dataclasses
import math
from collections.abc import Iterable, Mapping, Sequence
from typing import Any

from vdbejax.methods import learner_title
from vdbejax.results.summary import SummaryRow, summary_rows

NEAR = 0.05
#: Relative tolerance of a figure the paper gives as "about" a value.
ABOUT = 0.25
#: Returns this close are tied.
TIE = 0.01
#: The share of replicates that must agree with the pooled verdict for it to be the headline.
STABLE = 0.8
#: The paper's learners, with their display names (the plug-ins' titles).
LEARNER_NAMES = {name: learner_title(name) for name in ("qlearning", "sarsa")}


@dataclasses.dataclass
class Check:
    """One check of a claim: what it compares, and whether it held on the pooled agents
    (``passed``) and in how many of the ``replicates`` (``None`` for a single run)."""

    description: str
    passed: bool
    replicates_passed: int | None = None
    replicates: int | None = None

    @property
    def flips(self) -> bool:
        """Some replicates pass it and some do not."""
        return self.replicates is not None and 0 < (self.replicates_passed or 0) < self.replicates


def _verdict(checks: Sequence[bool]) -> str:
    if all(checks):
        return "reproduced"
    return "not reproduced" if not any(checks) else "partly"


def stable_count(replicates: int) -> int:
    """The replicates that must agree with the pooled verdict (``⌈STABLE·R⌉``)."""
    return math.ceil(STABLE * replicates - 1e-9)


@dataclasses.dataclass
class ClaimResult:
    """A claim's checks and verdicts.

    Attributes:
      replicate_verdicts: each replicate's verdict (empty for a single run).
    """

    number: int
    claim: str
    paper: str
    measured: str
    checks: list[Check]
    replicate_verdicts: list[str] = dataclasses.field(default_factory=list)

    @property
    def pooled_verdict(self) -> str:
        """The verdict of the checks on all agents."""
        return _verdict([c.passed for c in self.checks])

    @property
    def agreeing(self) -> int:
        """The replicates whose verdict is the pooled one."""
        return sum(v == self.pooled_verdict for v in self.replicate_verdicts)

    @property
    def verdict(self) -> str:
        """The headline: the pooled verdict, if at least ``⌈STABLE·R⌉`` of the R replicates
        agree with it; otherwise ``"unstable"``."""
        count = len(self.replicate_verdicts)
        if count and self.agreeing < stable_count(count):
            return "unstable"
        return self.pooled_verdict


def rank_value(row: SummaryRow) -> float:
    """The return a setting is ranked by: the IQM of its agents' final returns (the mean
    when the summary has no IQM)."""
    return row.final_return if row.final_iqm is None else row.final_iqm


class ClaimTable:
    """The summary rows the claims are scored on, with lookups by learner and explorer.

    Attributes:
      rows: the rows (:class:`~vdbejax.results.summary.SummaryRow`).
      best_return: the task's best possible return.
      near: the lowest final return "at or near" it (``best_return − NEAR``).
      learners: the paper's learners that have rows, in :data:`LEARNER_NAMES` order.
    """

    def __init__(self, rows: Iterable[SummaryRow | Mapping[str, Any]],
                 best_return: float = 0.86) -> None:
        self.rows = summary_rows(rows)
        self.best_return = best_return
        self.near = best_return - NEAR
        self.learners = [name for name in LEARNER_NAMES
                         if any(r.learner == name for r in self.rows)]

    def get(self, learner: str, explorer: str) -> list[SummaryRow]:
        """The rows of one learner × explorer, by increasing parameter."""
        return sorted((r for r in self.rows if r.learner == learner and r.explorer == explorer),
                      key=SummaryRow.swept_param)

    def best(self, learner: str, explorer: str) -> SummaryRow | None:
        """The best setting of one learner × explorer: among the rows whose
        :func:`rank_value` is within :data:`TIE` of the highest, the first to converge
        (then the highest ranked)."""
        rows = self.get(learner, explorer)
        if not rows:
            return None
        top = max(rank_value(r) for r in rows)
        tied = [r for r in rows if rank_value(r) >= top - TIE]
        return min(tied, key=lambda r: (r.convergence_episode, -rank_value(r)))

    def best_are(self, learner: str, explorer: str, params: set[float]) -> tuple[bool, str]:
        """Whether ``params`` are the best values of one learner × explorer: they rank top
        (by :func:`rank_value`), or no other value ranks above the worse of them by more
        than :data:`TIE`. Returns the verdict and what was measured."""
        rows = sorted(self.get(learner, explorer), key=lambda r: -rank_value(r))
        top = {r.swept_param() for r in rows[:len(params)]}
        chosen = [r for r in rows if r.swept_param() in params]
        if top == params:
            return True, f"top two by IQM {sorted(top)}"
        if len(chosen) < len(params):
            return False, f"top two by IQM {sorted(top)}; {sorted(params)} not all in the grid"
        floor = min(rank_value(r) for r in chosen)
        above = [r for r in rows if r.swept_param() not in params and rank_value(r) > floor + TIE]
        shown = ", ".join(f"{r.swept_param():g} ({rank_value(r):.3f})" for r in above)
        return not above, (f"top two by IQM {sorted(top)}; worse of {sorted(params)}"
                           f" {floor:.3f}, " + (f"above it: {shown}" if above else
                                                f"every other value within {TIE}: a tie"))


def _apart(a: float, b: float) -> tuple[str, str]:
    """``a`` and ``b`` with two decimals, or with as many more (up to six) as it takes to
    tell them apart, so a printed comparison shows why it held or failed (−1.0651 against
    −1.0739 is "−1.065 ≤ −1.074", not "−1.07 ≤ −1.07")."""
    for digits in range(2, 7):
        x, y = f"{a:.{digits}f}", f"{b:.{digits}f}"
        if x != y:
            break
    return x, y


def _finals(rows: list[SummaryRow]) -> str:
    return ", ".join(f"{r.swept_param():g}→{r.final_return:.2f}" for r in rows)


def _about(value: float, stated: float) -> tuple[float, float, bool]:
    """The ±:data:`ABOUT` interval of a stated figure, and whether ``value`` lies in it."""
    lo, hi = (1 - ABOUT) * stated, (1 + ABOUT) * stated
    return lo, hi, lo <= value <= hi
