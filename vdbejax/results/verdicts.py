"""Verdicts decided by intervals: the one rule every claim is scored by (the paper's six,
:mod:`vdbejax.paper.claims`, and any study's, :mod:`vdbejax.results.claim_scoring`).

A comparison of 95% intervals (:class:`Estimate`) gives ``True`` or ``False`` only when the
intervals decide it (an interval entirely on one side of a bound, or two intervals apart),
and ``None`` ("undecided") when they overlap — never a difference smaller than the
intervals (:func:`less`, :func:`at_most`, :func:`inside`); checks combine as Kleene's
three-valued logic (:func:`all_of`, :func:`any_of`, :func:`negate`). A claim is
*reproduced* when every check holds, *not reproduced* when every check fails, *partly*
when some hold and some fail, and *undecided* otherwise (:func:`claim_verdict`).

With replicates (:mod:`vdbejax.results.replicates`) a claim is scored on the pooled agents
and on each replicate (:func:`count_replicates`): a check reports in how many of the R
replicates it holds (and is undecided), a claim each replicate's verdict, and the headline
(:attr:`ClaimResult.verdict`) is the pooled verdict when at least ``STABLE`` (80 %) of the
replicates that decide it agree, else *unstable*.
"""
from __future__ import annotations

import dataclasses
import math
from collections.abc import Iterable, Sequence

from vdbejax.results.summary import SummaryRow

#: The share of replicates that must agree with the pooled verdict for it to be the headline.
STABLE = 0.8


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


@dataclasses.dataclass(frozen=True)
class Reading:
    """What a check read, as columns (``claims.csv``): the metric, the setting checked and
    its estimate, the other setting's (a comparison of two settings) and the number it is
    compared with (``bound``: ``above``'s, ``below``'s, ``about``'s figure, ``near_best``'s
    lowest return, the level of ``P(A > B)``, an axis's rank), each absent where the check
    has none (an axis's ``best``, a combination)."""

    metric: str = ""
    setting: str = ""
    estimate: Estimate | None = None
    other_setting: str = ""
    other_estimate: Estimate | None = None
    bound: float | None = None


@dataclasses.dataclass
class Check:
    """One check of a claim: what it compares, and its outcome on the pooled agents
    (``passed``: ``True``, ``False`` or ``None``, undecided) and in how many of the
    ``replicates`` it holds and is undecided (``None`` for a single run); ``reading``: what
    it read, as columns (a study's checks; the paper's give it in ``description``)."""

    description: str
    passed: Outcome
    replicates_passed: int | None = None
    replicates: int | None = None
    replicates_undecided: int | None = None
    reading: Reading = Reading()

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


def claim_verdict(checks: Sequence[Outcome]) -> str:
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
        return claim_verdict([c.passed for c in self.checks])

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


def estimate_text(x: Estimate, digits: int = 3) -> str:
    """``[low, high]`` of an estimate (a final return, an episode), as checks print it."""
    return f"[{x.low:.{digits}f}, {x.high:.{digits}f}]"



def count_replicates(pooled: list[ClaimResult], scored: Sequence[list[ClaimResult]]) -> None:
    """Record on the pooled claims each replicate's verdict and, per check, in how many
    replicates it holds and is undecided.

    Args:
      pooled: the claims scored on all agents (changed in place).
      scored: per replicate, the same claims scored on its agents.

    Raises:
      ValueError: a replicate gives other claims or check counts than the pooled agents.
    """
    for index, claims in enumerate(scored):
        shape = [(c.number, len(c.checks)) for c in claims]
        if shape != [(c.number, len(c.checks)) for c in pooled]:
            raise ValueError(f"replicates: replicate {index}'s rows give the claims and check"
                             f" counts {shape}, not the pooled rows' (the same settings needed)")
    for i, claim in enumerate(pooled):
        claim.replicate_verdicts = [claims[i].pooled_verdict for claims in scored]
        for j, check in enumerate(claim.checks):
            outcomes = [claims[i].checks[j].passed for claims in scored]
            check.replicates = len(scored)
            check.replicates_passed = sum(o is True for o in outcomes)
            check.replicates_undecided = sum(o is None for o in outcomes)


__all__ = ["STABLE", "Check", "ClaimResult", "Estimate", "Outcome", "Reading", "all_of", "any_of",
           "at_most", "claim_verdict", "convergence_estimate", "count_replicates",
           "estimate_text", "final_estimate", "inside", "less", "mark", "negate", "point",
           "stable_count"]
