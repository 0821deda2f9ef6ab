"""The claims' machinery: the thresholds, a check, a claim's result, the summary table
the checks read (:class:`ClaimTable`) and the three-valued comparisons of intervals that
decide a check (:class:`Estimate`); the rules they follow are stated in
:mod:`vdbejax.paper.claims`, which scores the six claims with them.

A comparison gives ``True`` or ``False`` only when the 95% intervals decide it (an
interval entirely on one side of a bound, or two intervals apart), and ``None``
("undecided") when they overlap: no difference smaller than the intervals decides a check.
Checks combine as Kleene's three-valued logic (:func:`all_of`, :func:`any_of`).
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
#: Returns this close are tied when an explorer's best setting is chosen (a choice, not a
#: verdict: verdicts come from intervals).
TIE = 0.01
#: The share of replicates that must agree with the pooled verdict for it to be the headline.
STABLE = 0.8
#: The paper's learners, with their display names (the plug-ins' titles).
LEARNER_NAMES = {name: learner_title(name) for name in ("qlearning", "sarsa")}


#: A check's outcome: ``True`` (holds), ``False`` (fails) or ``None`` (undecided: the
#: intervals overlap).
Outcome = bool | None


@dataclasses.dataclass(frozen=True)
class Estimate:
    """A value with its 95% interval (``low == high == value`` where a summary has none)."""

    value: float
    low: float
    high: float

    def scaled(self, factor: float) -> Estimate:
        """The estimate times ``factor`` (> 0)."""
        return Estimate(self.value * factor, self.low * factor, self.high * factor)


def point(value: float) -> Estimate:
    """A value known exactly (a bound)."""
    return Estimate(value, value, value)


def final_estimate(row: SummaryRow) -> Estimate:
    """A setting's final return with its bootstrap interval over agents."""
    low, high = row.final_ci_low, row.final_ci_high
    return Estimate(row.final_return, row.final_return if low is None else low,
                    row.final_return if high is None else high)


def convergence_estimate(row: SummaryRow) -> Estimate:
    """A setting's convergence episode (median over agents) with its bootstrap interval."""
    value, low, high = row.convergence_episode, row.convergence_ci_low, row.convergence_ci_high
    return Estimate(value, value if low is None else low, value if high is None else high)


def less(a: Estimate, b: Estimate) -> Outcome:
    """``a < b`` decided by the intervals: ``True`` when ``a``'s lies entirely below
    ``b``'s, ``False`` when it lies at or above it, ``None`` when they overlap."""
    if a.high < b.low:
        return True
    return False if a.low >= b.high else None


def at_most(a: Estimate, b: Estimate) -> Outcome:
    """``a ≤ b`` decided by the intervals: ``True`` when ``a``'s lies at or below ``b``'s,
    ``False`` when entirely above it, ``None`` when they overlap."""
    if a.high <= b.low:
        return True
    return False if a.low > b.high else None


def inside(x: Estimate, low: float, high: float) -> Outcome:
    """``low ≤ x ≤ high`` decided by the interval: ``None`` when it straddles an end."""
    if low <= x.low and x.high <= high:
        return True
    return False if x.high < low or x.low > high else None


def negate(outcome: Outcome) -> Outcome:
    """Kleene's not: undecided stays undecided."""
    return None if outcome is None else not outcome


def all_of(outcomes: Iterable[Outcome]) -> Outcome:
    """Kleene's and: ``False`` if any fails, else ``None`` if any is undecided."""
    values = list(outcomes)
    if any(v is False for v in values):
        return False
    return None if any(v is None for v in values) else True


def any_of(outcomes: Iterable[Outcome]) -> Outcome:
    """Kleene's or: ``True`` if any holds, else ``None`` if any is undecided."""
    values = list(outcomes)
    if any(v is True for v in values):
        return True
    return None if any(v is None for v in values) else False


def mark(outcome: Outcome) -> str:
    """A check's box in ``report.md``: ``[x]`` holds, ``[ ]`` fails, ``[?]`` undecided."""
    return "[?]" if outcome is None else "[x]" if outcome else "[ ]"


@dataclasses.dataclass
class Check:
    """One check of a claim: what it compares, and its outcome on the pooled agents
    (``passed``: ``True``, ``False`` or ``None``, undecided) and in how many of the
    ``replicates`` it holds and is undecided (``None`` for a single run)."""

    description: str
    passed: Outcome
    replicates_passed: int | None = None
    replicates: int | None = None
    replicates_undecided: int | None = None

    @property
    def replicates_failed(self) -> int:
        """The replicates in which it fails (decided)."""
        return (self.replicates or 0) - (self.replicates_passed or 0) - (
            self.replicates_undecided or 0)

    @property
    def flips(self) -> bool:
        """Some replicates pass it and some fail it (both decided)."""
        return (self.replicates is not None and (self.replicates_passed or 0) > 0
                and self.replicates_failed > 0)


def _verdict(checks: Sequence[Outcome]) -> str:
    """``reproduced`` when every check holds, ``not reproduced`` when every one fails,
    ``partly`` when some hold and some fail, else ``undecided``."""
    if checks and all(c is True for c in checks):
        return "reproduced"
    if checks and all(c is False for c in checks):
        return "not reproduced"
    if any(c is True for c in checks) and any(c is False for c in checks):
        return "partly"
    return "undecided"


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
    def passed_count(self) -> int:
        """The checks that hold on the pooled agents."""
        return sum(c.passed is True for c in self.checks)

    @property
    def undecided_count(self) -> int:
        """The checks the pooled agents' intervals leave undecided."""
        return sum(c.passed is None for c in self.checks)

    @property
    def agreeing(self) -> int:
        """The replicates whose verdict is the pooled one."""
        return sum(v == self.pooled_verdict for v in self.replicate_verdicts)

    @property
    def decided_replicates(self) -> int:
        """The replicates whose verdict is not undecided (a replicate too small to decide
        is no evidence either way)."""
        return sum(v != "undecided" for v in self.replicate_verdicts)

    @property
    def verdict(self) -> str:
        """The headline: the pooled verdict, if at least ``⌈STABLE·D⌉`` of the D replicates
        that decide the claim agree with it (or if the pooled agents leave it undecided:
        the replicates, smaller, cannot decide it better); otherwise ``"unstable"``."""
        decided = self.decided_replicates
        if self.pooled_verdict == "undecided":
            return self.pooled_verdict
        if decided and self.agreeing < stable_count(decided):
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

    def best_are(self, learner: str, explorer: str, params: set[float]) -> tuple[Outcome, str]:
        """Whether ``params`` are the best values of one learner × explorer, decided by the
        intervals of the final returns: ``True`` when each of theirs lies above every other
        value's, ``False`` when another value's lies above one of theirs, else undecided.
        Returns the outcome and what was measured (the top values by :func:`rank_value`)."""
        rows = sorted(self.get(learner, explorer), key=lambda r: -rank_value(r))
        top = sorted(r.swept_param() for r in rows[:len(params)])
        chosen = [r for r in rows if r.swept_param() in params]
        if len(chosen) < len(params):
            return False, f"top two by IQM {top}; {sorted(params)} not all in the grid"
        others = [r for r in rows if r.swept_param() not in params]
        outcome = all_of(less(final_estimate(o), final_estimate(c))
                         for c in chosen for o in others)
        above = [o for o in others
                 if any(less(final_estimate(c), final_estimate(o)) for c in chosen)]
        shown = ", ".join(f"{r.swept_param():g} {_interval(final_estimate(r))}" for r in above)
        chosen_shown = ", ".join(f"{r.swept_param():g} {_interval(final_estimate(r))}"
                                 for r in chosen)
        return outcome, (f"top two by IQM {top}; {chosen_shown}"
                         + (f"; above them: {shown}" if above else
                            "; every other value's interval below theirs" if outcome else
                            "; intervals overlap another value's"))


def _finals(rows: list[SummaryRow]) -> str:
    return ", ".join(f"{r.swept_param():g}→{r.final_return:.2f}" for r in rows)


def _about(value: Estimate, stated: float) -> tuple[float, float, Outcome]:
    """The ±:data:`ABOUT` range of a stated figure, and whether ``value``'s interval lies
    in it (:func:`inside`)."""
    lo, hi = (1 - ABOUT) * stated, (1 + ABOUT) * stated
    return lo, hi, inside(value, lo, hi)


def _interval(x: Estimate, digits: int = 3) -> str:
    """``[low, high]`` of a final return."""
    return f"[{x.low:.{digits}f}, {x.high:.{digits}f}]"
