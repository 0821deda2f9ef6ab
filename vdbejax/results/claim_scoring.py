"""A study's claims (:mod:`vdbejax.results.claim_spec`) scored on its result, by the
verdict rules every claim follows (:mod:`vdbejax.results.verdicts`).

:func:`score_claims` takes a result and claims and returns the verdicts: each check is
decided by its 95% intervals (holds, fails or undecided — never by a difference inside
them), each claim is reproduced, partly, not reproduced or undecided, and a result with
replicates is scored on the pooled agents and on each replicate (stable or unstable).
"""
from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Iterable, Mapping, Sequence
from typing import Any

import numpy as np

from vdbejax.methods.agents import Setting
from vdbejax.results.analysis import config_scale, summarize, task_scale
from vdbejax.results.bootstrap import interquartile_mean_ci, probability_of_improvement_ci
from vdbejax.results.claim_spec import (
    LOWER_IS_BETTER,
    RANK_BY,
    RECORDED_BY,
    TIE,
    CheckSpec,
    ClaimSpec,
    Every,
    Ranked,
    Selector,
    axis_members,
    axis_settings,
    candidates,
    check_claims,
    scored_checks,
    selector_text,
)
from vdbejax.results.curves import LAST, final_return
from vdbejax.results.grid_result import GridResult
from vdbejax.results.regret import run_scores
from vdbejax.results.replicates import replicate, replicate_count
from vdbejax.results.summary import SummaryRow, episode_text, summary_rows
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
    estimate_text,
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
    low, high = getattr(row, f"{prefix}_low", None), getattr(row, f"{prefix}_high", None)
    return Estimate(value, value if low is None else low, value if high is None else high)


def best_index(values: Sequence[float], convergence: Sequence[float]) -> int:
    """The best of some settings (a :class:`~vdbejax.results.claim_spec.Ranked` ``best``):
    among those whose ranking value is within :data:`~vdbejax.results.claim_spec.TIE` of the
    highest, the one that converges first, then the better ranked, then the first."""
    top = max(values)
    tied = [i for i, v in enumerate(values) if v >= top - TIE]
    return min(tied, key=lambda i: (convergence[i], -values[i]))


def best_row(rows: Sequence[SummaryRow]) -> SummaryRow:
    """The best of some settings' summary rows by their IQM (:func:`best_index`; the mean
    for a summary without IQM)."""
    values = [r.final_return if r.final_iqm is None else r.final_iqm for r in rows]
    return rows[best_index(values, [r.convergence_episode for r in rows])]


@dataclasses.dataclass
class _Reader:
    """One scoring's estimates, each computed once: the settings and their summary rows,
    with the result where a metric needs the agents' returns."""

    settings: Sequence[Setting]
    rows: list[SummaryRow]
    result: GridResult | None
    best_return: float | None
    cache: dict[tuple[int, str], Estimate] = dataclasses.field(default_factory=dict)
    shown: dict[str, None] = dataclasses.field(default_factory=dict)
    seen: set[str] = dataclasses.field(default_factory=set)

    def returns(self, metric: str) -> GridResult:
        if self.result is None:
            raise ValueError(f"metric={metric!r} is invalid here: it needs the agents' returns,"
                             " not only summary rows")
        return self.result

    def finals(self, config: int, metric: str = "final_return") -> np.ndarray:
        result = self.returns(metric)
        return final_return(result.returns[config], min(LAST, result.num_episodes))

    def best(self, where: str) -> float:
        if self.best_return is None:
            raise ValueError(f"{where}: the task's best return is unknown (meta.json has no"
                             " best_return)")
        return self.best_return

    def estimate(self, config: int, metric: str) -> Estimate:
        key = (config, metric)
        if key not in self.cache:
            if metric == "final_iqm":
                self.cache[key] = Estimate(*interquartile_mean_ci(self.finals(config, metric)))
            elif metric == "normalised_score":
                result = self.returns(metric)
                best, baseline = task_scale(result)
                scores = run_scores(result.returns[config], config_scale(best, config),
                                    config_scale(baseline, config))
                self.cache[key] = Estimate(*interquartile_mean_ci(scores))
            else:
                self.cache[key] = _row_estimate(self.rows[config], metric)
            self.shown[self.text(config, metric)] = None
        return self.cache[key]

    def rank_value(self, config: int, by: str) -> float:
        """What a setting is ranked by (higher is better): the summary's IQM where ``by`` is
        ``final_iqm`` (the mean for a summary without it), else the estimate."""
        row = self.rows[config]
        if by == "final_iqm":
            return row.final_return if row.final_iqm is None else row.final_iqm
        value = self.estimate(config, by).value
        return -value if by in LOWER_IS_BETTER else value

    def members(self, selector: Selector, where: str, key: str) -> list[int]:
        """The settings a selector names: one, or every one an :class:`Every` names."""
        if isinstance(selector, Every):
            return candidates(selector, self.settings, where, key)
        return [self.pick(selector, where, key)]

    def pick(self, selector: Selector, where: str, key: str) -> int:
        """The setting a selector names (a :class:`Ranked` one: chosen by these estimates)."""
        found = candidates(selector, self.settings, where, key)
        if not isinstance(selector, Ranked):
            return found[0]
        value = [self.rank_value(c, selector.by) for c in found]
        if selector.pick == "worst":
            return found[min(range(len(found)), key=lambda i: value[i])]
        return found[best_index(value, [self.rows[c].convergence_episode for c in found])]

    def text(self, config: int, metric: str) -> str:
        x = self.cache[(config, metric)]
        label = self.settings[config].label
        if metric == "convergence_episode":
            budget = self.rows[config].convergence_budget
            if math.isinf(x.value):
                return f"{label} {metric} {episode_text(x.value, budget)}"
            return (f"{label} {metric} {episode_text(x.value)}"
                    f" [{episode_text(x.low, budget)}, {episode_text(x.high, budget)}]")
        return f"{label} {metric} {x.value:.3f} {estimate_text(x)}"

    def once(self, config: int, metric: str) -> str:
        """A setting's metric as a check shows it, once per check (then ``(as above)``)."""
        self.estimate(config, metric)
        text = self.text(config, metric)
        if text in self.seen:
            return f"{self.settings[config].label} {metric} (as above)"
        self.seen.add(text)
        return text


def _better(reader: _Reader, a: int, b: int, metric: str) -> Outcome:
    """Whether setting ``a``'s metric is better than ``b``'s (intervals apart)."""
    x, y = reader.estimate(a, metric), reader.estimate(b, metric)
    return less(x, y) if metric in LOWER_IS_BETTER else less(y, x)


def _axis(check: CheckSpec, reader: _Reader) -> Check:
    settings = reader.settings
    values = axis_settings(check, settings)
    chosen = axis_members(check, settings)
    for c in values:
        reader.estimate(c, check.metric)
    # Shown in ranking order (by RANK_BY), the run's order on ties.
    ranked = sorted(values, key=lambda c: -reader.rank_value(c, RANK_BY))
    others = [c for c in ranked if c not in chosen]
    name = f"{check.axis} among {settings[chosen[0]].learner}/{settings[chosen[0]].explorer}"
    if check.kind == "best":
        outcome = all_of(_better(reader, c, o, check.metric) for c in chosen for o in others)
        top = sorted((values[c] for c in ranked[:len(chosen)]), key=_order)
        ahead = [o for o in others
                 if any(_better(reader, o, c, check.metric) is True for c in chosen)]
        mine = ", ".join(reader.once(c, check.metric) for c in ranked if c in chosen)
        tail = ("; ahead of them: " + ", ".join(reader.once(o, check.metric) for o in ahead)
                if ahead else "; every other value's interval behind theirs" if outcome else
                "; intervals overlap another value's")
        return Check(f"{check.metric}: the best {check.axis} are"
                     f" {', '.join(map(str, check.values))} ({name}; top {len(chosen)} by"
                     f" {RANK_BY} [{', '.join(map(repr, top))}]; {mine}{tail})", outcome,
                     reading=Reading(check.metric))
    (mine_c,) = chosen
    above = sum(_better(reader, o, mine_c, check.metric) is True for o in others)
    below = sum(_better(reader, mine_c, o, check.metric) is True for o in others)
    outcome = (False if above > check.rank - 1 or below > len(values) - check.rank else
               True if above == check.rank - 1 and below == len(values) - check.rank
               else None)
    return Check(f"{check.metric}: {check.axis} = {check.values[0]} ranks {check.rank} of"
                 f" {len(values)} ({name}: {above} apart above it, {below} apart below)",
                 outcome, reading=Reading(check.metric, settings[mine_c].label,
                                          reader.estimate(mine_c, check.metric),
                                          bound=check.rank))


def _order(value: Any) -> tuple[int, Any]:
    """Axis values in order: numbers by value, the rest by their text after them."""
    numeric = isinstance(value, (int, float)) and not isinstance(value, bool)
    return (0, value) if numeric else (1, str(value))


def _near_note(near: Outcome) -> str:
    """What a rival's "near the best return" outcome adds to it."""
    return "" if near else " (not near best)" if near is False else " (near best: undecided)"


def _versus(check: CheckSpec, reader: _Reader, a: int, others: list[int]) -> Outcome:
    """A comparison of setting ``a`` with each of ``others`` (Kleene's and)."""
    if check.kind == "worse_than":
        final, episode = "final_return", "convergence_episode"
        return any_of([
            all_of(less(reader.estimate(a, final), reader.estimate(b, final)) for b in others),
            all_of(less(reader.estimate(b, episode), reader.estimate(a, episode))
                   for b in others)])
    decide: dict[str, Callable[[Estimate, Estimate], Outcome]] = {
        "higher_than": lambda x, y: less(y, x), "lower_than": less,
        "no_higher_than": at_most, "earlier_than": less, "no_later_than": at_most}
    x = reader.estimate(a, check.metric)
    return all_of(decide[check.kind](x, reader.estimate(b, check.metric).scaled(check.factor))
                  for b in others)


def _converges_first(check: CheckSpec, reader: _Reader, mine: int) -> Check:
    best = reader.best(check.where)
    near = point(best - check.bound)
    rivals = [reader.pick(rival, check.where, f"converges_first[{i}]")
              for i, rival in enumerate(check.others)]
    good = {c: at_most(near, reader.estimate(c, "final_return")) for c in (mine, *rivals)}
    episode = "convergence_episode"
    outcome = all_of([good[mine], *(
        any_of([negate(good[r]), at_most(reader.estimate(mine, episode),
                                          reader.estimate(r, episode))]) for r in rivals)])
    shown = reader.once(mine, episode)
    return Check(f"{shown} ends within {check.bound:g} of the best return {best:.4g} and"
                 " converges no later than each rival near it: "
                 + ", ".join(reader.once(r, episode) + _near_note(good[r]) for r in rivals),
                 outcome, reading=Reading(episode, reader.settings[mine].label,
                                          reader.estimate(mine, episode)))


def _leaf(check: CheckSpec, reader: _Reader) -> Check:
    settings = reader.settings
    if check.kind in ("best", "rank"):
        return _axis(check, reader)
    assert check.setting is not None
    if check.kind == "beats":
        mine = reader.pick(check.setting, check.where, "setting")
        label = settings[mine].label
        assert check.other is not None
        other = reader.pick(check.other, check.where, check.kind)
        p = Estimate(*probability_of_improvement_ci(reader.finals(mine),
                                                    reader.finals(other)))
        text = (f"P({label} > {settings[other].label}) {p.value:.3g} [{p.low:.3g},"
                f" {p.high:.3g}] above {check.bound:g}")
        reader.shown[text] = None
        return Check(text, less(point(check.bound), p), reading=Reading(
            PROBABILITY, label, p, settings[other].label, bound=check.bound))
    members = reader.members(check.setting, check.where, "setting")
    if check.kind == "converges_first":
        parts = [_converges_first(check, reader, c) for c in members]
        if len(parts) == 1:
            return parts[0]
        return Check("; ".join(p.description for p in parts), all_of(p.passed for p in parts))
    every = isinstance(check.setting, Every)
    one = None if every else members[0]

    def reading(other: str = "", other_estimate: Estimate | None = None,
                bound: float | None = None) -> Reading:
        if one is None:
            return Reading(check.metric, "; ".join(settings[c].label for c in members),
                           other_setting=other, bound=bound)
        return Reading(check.metric, settings[one].label, reader.estimate(one, check.metric),
                       other, other_estimate, bound)

    prefix = f"{selector_text(check.setting)}: " if every else ""
    if check.kind == "worse_than":
        assert check.other is not None
        rivals = reader.members(check.other, check.where, check.kind)
        outcome = all_of(_versus(check, reader, a, rivals) for a in members)
        latest = max(rivals, key=lambda c: (reader.rows[c].convergence_episode, c))
        names = (selector_text(check.setting) if every else settings[members[0]].label)
        return Check(f"{names} ends lower than {selector_text(check.other)} or converges"
                     " later than all of them (their latest: "
                     f"{reader.once(latest, 'convergence_episode')})", outcome,
                     reading=Reading("final_return, convergence_episode",
                                     "; ".join(settings[c].label for c in members),
                                     other_setting="; ".join(settings[c].label
                                                             for c in rivals)))
    shown = prefix + ", ".join(reader.once(c, check.metric) for c in members)
    if check.other is not None:
        rivals = reader.members(check.other, check.where, check.kind)
        outcome = all_of(_versus(check, reader, a, rivals) for a in members)
        word = check.kind.replace("_", " ") + (
            f" {check.factor:g} ×" if check.factor != 1 else "")
        other_shown = (f"{selector_text(check.other)}: "
                       if isinstance(check.other, Every) else "") + ", ".join(
            reader.once(c, check.metric) for c in rivals)
        single = len(rivals) == 1 and not isinstance(check.other, Every)
        return Check(f"{shown} {word} {other_shown}", outcome, reading=reading(
            "; ".join(settings[c].label for c in rivals),
            reader.estimate(rivals[0], check.metric).scaled(check.factor) if single else None))
    xs = [reader.estimate(c, check.metric) for c in members]
    if check.kind == "above":
        return Check(f"{shown} above {check.bound:g}",
                     all_of(less(point(check.bound), x) for x in xs),
                     reading=reading(bound=check.bound))
    if check.kind == "below":
        return Check(f"{shown} below {check.bound:g}",
                     all_of(less(x, point(check.bound)) for x in xs),
                     reading=reading(bound=check.bound))
    if check.kind == "about":
        low, high = (1 - check.tolerance) * check.bound, (1 + check.tolerance) * check.bound
        return Check(f"{shown} about {check.bound:g} (±{check.tolerance:.0%}:"
                     f" {low:.4g}–{high:.4g})",
                     all_of(inside(x, min(low, high), max(low, high)) for x in xs),
                     reading=reading(bound=check.bound))
    best = reader.best(check.where)
    return Check(f"{shown} within {check.bound:g} of the best return {best:.4g}",
                 all_of(at_most(point(best - check.bound), x) for x in xs),
                 reading=reading(bound=best - check.bound))


def _check(check: CheckSpec, reader: _Reader) -> Check:
    if not check.parts:
        return _leaf(check, reader)
    parts = [_check(part, reader) for part in check.parts]
    if check.kind == "not":
        return Check(f"not ({parts[0].description})", negate(parts[0].passed))
    combine = all_of if check.kind == "all" else any_of
    return Check(f"{check.kind} of: " + "; ".join(f"({part.description})" for part in parts),
                 combine(part.passed for part in parts))


def _top(check: CheckSpec, reader: _Reader) -> Check:
    """A claim's check, with its words (``text``) before what it read."""
    reader.seen = set()
    scored = _check(check, reader)
    if check.text:
        scored.description = f"{check.text} ({scored.description})"
    return scored


def _score(reader_of: Callable[[], _Reader], claims: Sequence[ClaimSpec]) -> list[ClaimResult]:
    scored = []
    for number, claim in enumerate(claims, 1):
        reader = reader_of()
        checks = [_top(check, reader) for check in scored_checks(claim, reader.settings)]
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


def _readers(result: GridResult, rows: list[SummaryRow],
             best: float | None) -> Callable[[], _Reader]:
    """A fresh reader of a result per claim."""
    return lambda: _Reader(result.settings, rows, result, best)


def score_claims(result: GridResult, claims: Sequence[ClaimSpec],
                 rows: list[SummaryRow] | None = None,
                 replicate_rows: Sequence[list[SummaryRow]] | None = None,
                 best_return: float | None = None) -> ClaimScores:
    """Score a study's claims on its result.

    Args:
      result: the result (all replicates).
      claims: :func:`~vdbejax.results.claim_spec.parse_claims`'s.
      rows: the pooled agents' summary rows, if already computed
        (:func:`~vdbejax.results.analysis.summarize`).
      replicate_rows: each replicate's summary rows, if already computed.
      best_return: the task's best return (``near_best``, ``converges_first``; default
        ``meta["best_return"]``).

    Returns:
      the :class:`ClaimScores`.

    Raises:
      ValueError: a claim that names what the result does not hold.
    """
    check_claims(claims, result.settings, recorded_metrics(result))
    best = result.meta.get("best_return") if best_return is None else best_return
    best = None if best is None else float(best)
    pooled_rows = summarize(result) if rows is None else rows
    pooled = _score(_readers(result, pooled_rows, best), claims)
    count = replicate_count(result)
    if count == 1:
        return ClaimScores(pooled, [])
    parts = [replicate(result, r) for r in range(count)]
    part_rows = ([summarize(part) for part in parts] if replicate_rows is None
                 else list(replicate_rows))
    scored = [_score(_readers(part, r_rows, best), claims)
              for part, r_rows in zip(parts, part_rows, strict=True)]
    count_replicates(pooled, scored)
    return ClaimScores(pooled, scored)


def score_rows(rows: Iterable[SummaryRow | Mapping[str, Any]], claims: Sequence[ClaimSpec],
               best_return: float,
               replicates: Sequence[Iterable[SummaryRow | Mapping[str, Any]]] | None = None,
               ) -> ClaimScores:
    """Score claims on summary rows alone (``summary.csv``'s, or made by hand): the settings
    are the rows' learner, explorer and swept parameter, and a check may read only what the
    rows hold (not ``beats``, ``final_iqm``'s interval or ``normalised_score``).

    Args:
      rows: the pooled agents' rows (:class:`~vdbejax.results.summary.SummaryRow`, or
        mappings of their columns to strings or numbers).
      claims: :func:`~vdbejax.results.claim_spec.parse_claims`'s.
      best_return: the task's best return.
      replicates: each replicate's rows (the same settings), or ``None``.

    Raises:
      ValueError: a claim that names what the rows do not hold; a replicate's rows that give
        other claims or checks than ``rows``.
    """
    def reader_of(part: Iterable[SummaryRow | Mapping[str, Any]]) -> Callable[[], _Reader]:
        typed = summary_rows(part)
        settings = [Setting(r.learner, r.explorer, r.param) for r in typed]
        return lambda: _Reader(settings, typed, None, best_return)

    pooled_reader = reader_of(rows)
    check_claims(claims, pooled_reader().settings, tuple(RECORDED_BY.values()))
    pooled = _score(pooled_reader, claims)
    if replicates is None:
        return ClaimScores(pooled, [])
    scored = [_score(reader_of(part), claims) for part in replicates]
    count_replicates(pooled, scored)
    return ClaimScores(pooled, scored)


__all__ = ["PROBABILITY", "ClaimScores", "best_index", "best_row", "recorded_metrics",
           "score_claims", "score_rows"]
