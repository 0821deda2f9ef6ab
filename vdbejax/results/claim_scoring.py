"""A study's claims (:mod:`vdbejax.results.claim_spec`) scored on its result, by the
verdict rules every claim follows (:mod:`vdbejax.results.verdicts`).

:func:`score_claims` takes a result and claims and returns the verdicts: each check is
decided by its 95% intervals (holds, fails or undecided — never by a difference inside
them), each claim is reproduced, partly, not reproduced or undecided, and a result with
replicates is scored on the pooled agents and on each replicate (stable or unstable).
"""
from __future__ import annotations

import dataclasses
from collections.abc import Callable, Sequence

import numpy as np

from vdbejax.results.analysis import config_scale, summarize, task_scale
from vdbejax.results.bootstrap import interquartile_mean_ci, probability_of_improvement_ci
from vdbejax.results.claim_spec import (
    LOWER_IS_BETTER,
    TIE,
    CheckSpec,
    ClaimSpec,
    Ranked,
    Selector,
    axis_members,
    axis_settings,
    candidates,
    check_claims,
    scored_checks,
)
from vdbejax.results.curves import LAST, final_return
from vdbejax.results.grid_result import GridResult
from vdbejax.results.regret import run_scores
from vdbejax.results.replicates import replicate, replicate_count
from vdbejax.results.summary import SummaryRow, episode_text
from vdbejax.results.verdicts import (
    Check,
    ClaimResult,
    Estimate,
    Outcome,
    Reading,
    all_of,
    any_of,
    at_most,
    count_replicates,
    inside,
    less,
    negate,
    point,
)

#: The ``metric`` a ``beats`` check reads (``claims.csv``): the probability of improvement
#: ``P(A > B)`` of the agents' final returns.
PROBABILITY = "probability_of_improvement"


def _row_estimate(row: SummaryRow, metric: str) -> Estimate:
    """A summary row's metric with its interval (the value alone where it has none)."""
    prefix = {"final_return": "final_ci", "convergence_episode": "convergence_ci"}.get(
        metric, f"{metric}_ci")
    value = getattr(row, metric)
    if value is None:
        raise ValueError(f"metric={metric!r} is invalid: the result does not record it")
    low, high = getattr(row, f"{prefix}_low"), getattr(row, f"{prefix}_high")
    return Estimate(value, value if low is None else low, value if high is None else high)


@dataclasses.dataclass
class _Reader:
    """One result's estimates, each computed once."""

    result: GridResult
    rows: list[SummaryRow]
    cache: dict[tuple[int, str], Estimate] = dataclasses.field(default_factory=dict)
    shown: dict[str, None] = dataclasses.field(default_factory=dict)

    def finals(self, config: int) -> np.ndarray:
        return final_return(self.result.returns[config], min(LAST, self.result.num_episodes))

    def estimate(self, config: int, metric: str) -> Estimate:
        key = (config, metric)
        if key not in self.cache:
            if metric == "final_iqm":
                self.cache[key] = Estimate(*interquartile_mean_ci(self.finals(config)))
            elif metric == "normalised_score":
                best, baseline = task_scale(self.result)
                scores = run_scores(self.result.returns[config], config_scale(best, config),
                                    config_scale(baseline, config))
                self.cache[key] = Estimate(*interquartile_mean_ci(scores))
            else:
                self.cache[key] = _row_estimate(self.rows[config], metric)
            self.shown[self.text(config, metric)] = None
        return self.cache[key]

    def pick(self, selector: Selector, where: str, key: str) -> int:
        """The setting a selector names (a :class:`Ranked` one: chosen by this result's
        estimates)."""
        found = candidates(selector, self.result.settings, where, key)
        if not isinstance(selector, Ranked):
            return found[0]
        sign = -1.0 if selector.by in LOWER_IS_BETTER else 1.0
        value = {c: sign * self.estimate(c, selector.by).value for c in found}
        if selector.pick == "worst":
            return min(found, key=lambda c: value[c])
        top = max(value.values())
        tied = [c for c in found if value[c] >= top - TIE]
        return min(tied, key=lambda c: (self.rows[c].convergence_episode, -value[c]))

    def text(self, config: int, metric: str) -> str:
        x = self.cache[(config, metric)]
        label = self.result.settings[config].label
        if metric == "convergence_episode":
            budget = self.rows[config].convergence_budget
            return (f"{label} {metric} {episode_text(x.value, budget)}"
                    f" [{episode_text(x.low, budget)}, {episode_text(x.high, budget)}]")
        return f"{label} {metric} {x.value:.3g} [{x.low:.3g}, {x.high:.3g}]"


def _better(reader: _Reader, a: int, b: int, metric: str) -> Outcome:
    """Whether setting ``a``'s metric is better than ``b``'s (intervals apart)."""
    x, y = reader.estimate(a, metric), reader.estimate(b, metric)
    return less(x, y) if metric in LOWER_IS_BETTER else less(y, x)


def _leaf(check: CheckSpec, reader: _Reader) -> Check:
    settings = reader.result.settings
    if check.kind in ("best", "rank"):
        values = axis_settings(check, settings)
        chosen = axis_members(check, settings)
        others = [c for c in values if c not in chosen]
        for c in values:
            reader.estimate(c, check.metric)
        name = f"{check.axis} among {settings[chosen[0]].learner}/{settings[chosen[0]].explorer}"
        if check.kind == "best":
            outcome = all_of(_better(reader, c, o, check.metric) for c in chosen for o in others)
            return Check(f"{check.metric}: the best {check.axis} are"
                         f" {', '.join(map(str, check.values))} ({name}: their intervals"
                         " above every other value's)", outcome,
                         reading=Reading(check.metric))
        (mine,) = chosen
        above = sum(_better(reader, o, mine, check.metric) is True for o in others)
        below = sum(_better(reader, mine, o, check.metric) is True for o in others)
        outcome = (False if above > check.rank - 1 or below > len(values) - check.rank else
                   True if above == check.rank - 1 and below == len(values) - check.rank
                   else None)
        return Check(f"{check.metric}: {check.axis} = {check.values[0]} ranks {check.rank} of"
                     f" {len(values)} ({name}: {above} apart above it, {below} apart below)",
                     outcome, reading=Reading(check.metric, settings[mine].label,
                                              reader.estimate(mine, check.metric),
                                              bound=check.rank))
    assert check.setting is not None
    mine = reader.pick(check.setting, check.where, "setting")
    label = settings[mine].label
    if check.kind == "beats":
        assert check.other is not None
        other = reader.pick(check.other, check.where, check.kind)
        p = Estimate(*probability_of_improvement_ci(reader.finals(mine), reader.finals(other)))
        text = (f"P({label} > {settings[other].label}) {p.value:.3g} [{p.low:.3g},"
                f" {p.high:.3g}] above {check.bound:g}")
        reader.shown[text] = None
        return Check(text, less(point(check.bound), p), reading=Reading(
            PROBABILITY, label, p, settings[other].label, bound=check.bound))
    x = reader.estimate(mine, check.metric)
    shown = reader.text(mine, check.metric)
    if check.other is not None:
        other = reader.pick(check.other, check.where, check.kind)
        y = reader.estimate(other, check.metric).scaled(check.factor)
        decide: dict[str, Callable[[], Outcome]] = {
            "higher_than": lambda: less(y, x), "lower_than": lambda: less(x, y),
            "earlier_than": lambda: less(x, y), "no_later_than": lambda: at_most(x, y)}
        word = check.kind.replace("_", " ") + (
            f" {check.factor:g} ×" if check.factor != 1 else "")
        return Check(f"{shown} {word} {reader.text(other, check.metric)}",
                     decide[check.kind](), reading=Reading(
                         check.metric, label, x, settings[other].label, y))
    if check.kind == "above":
        return Check(f"{shown} above {check.bound:g}", less(point(check.bound), x),
                     reading=Reading(check.metric, label, x, bound=check.bound))
    if check.kind == "below":
        return Check(f"{shown} below {check.bound:g}", less(x, point(check.bound)),
                     reading=Reading(check.metric, label, x, bound=check.bound))
    if check.kind == "about":
        low, high = (1 - check.tolerance) * check.bound, (1 + check.tolerance) * check.bound
        return Check(f"{shown} about {check.bound:g} (±{check.tolerance:.0%}:"
                     f" {low:.4g}–{high:.4g})", inside(x, min(low, high), max(low, high)),
                     reading=Reading(check.metric, label, x, bound=check.bound))
    best = float(reader.result.meta["best_return"])
    return Check(f"{shown} within {check.bound:g} of the best return {best:.4g}",
                 at_most(point(best - check.bound), x),
                 reading=Reading(check.metric, label, x, bound=best - check.bound))


def _check(check: CheckSpec, reader: _Reader) -> Check:
    if not check.parts:
        return _leaf(check, reader)
    parts = [_check(part, reader) for part in check.parts]
    if check.kind == "not":
        return Check(f"not ({parts[0].description})", negate(parts[0].passed))
    combine = all_of if check.kind == "all" else any_of
    return Check(f"{check.kind} of: " + "; ".join(f"({part.description})" for part in parts),
                 combine(part.passed for part in parts))


def _score(result: GridResult, rows: list[SummaryRow],
           claims: Sequence[ClaimSpec]) -> list[ClaimResult]:
    scored = []
    for number, claim in enumerate(claims, 1):
        reader = _Reader(result, rows)
        checks = [_check(check, reader) for check in scored_checks(claim, result.settings)]
        if not checks:  # every check optional, and their settings absent
            continue
        scored.append(ClaimResult(number, claim.claim, claim.stated, "; ".join(reader.shown),
                                  checks))
    return scored


@dataclasses.dataclass
class ClaimScores:
    """A study's claims scored.

    Attributes:
      claims: each claim's pooled result, with its replicates' counts and verdicts (its
        headline: :attr:`~vdbejax.results.verdicts.ClaimResult.verdict`); a claim whose
        checks are all optional and absent from the run is left out (the others keep
        their numbers).
      replicates: per replicate, the claims scored on its agents (empty for one).
    """

    claims: list[ClaimResult]
    replicates: list[list[ClaimResult]]


def recorded_metrics(result: GridResult) -> list[str]:
    """The optional records a result holds (as :func:`check_claims` names them)."""
    return [name for name, array in (("record_optimal", result.optimal_actions),
                                     ("evaluate_every", result.policy_values))
            if array is not None]


def score_claims(result: GridResult, claims: Sequence[ClaimSpec],
                 rows: list[SummaryRow] | None = None) -> ClaimScores:
    """Score a study's claims on its result.

    Args:
      result: the result (all replicates).
      claims: :func:`~vdbejax.results.claim_spec.parse_claims`'s.
      rows: the pooled agents' summary rows, if already computed
        (:func:`~vdbejax.results.analysis.summarize`).

    Returns:
      the :class:`ClaimScores`.

    Raises:
      ValueError: a claim that names what the result does not hold.
    """
    check_claims(claims, result.settings, recorded_metrics(result))
    pooled = _score(result, summarize(result) if rows is None else rows, claims)
    count = replicate_count(result)
    if count == 1:
        return ClaimScores(pooled, [])
    parts = [replicate(result, r) for r in range(count)]
    scored = [_score(part, summarize(part), claims) for part in parts]
    count_replicates(pooled, scored)
    return ClaimScores(pooled, scored)


__all__ = ["PROBABILITY", "ClaimScores", "recorded_metrics", "score_claims"]
