"""The paper's six claims (spec, last section), scored against measured results.

Each claim is split into concrete checks on the summary table (final return = mean of the
last 100 episodes over agents, with its 95% bootstrap interval; convergence episode as
defined in :mod:`vdbejax.results.solving`, the median over agents with its interval).

Every check is decided by the 95% intervals (:class:`Estimate`): it holds
when the intervals lie on its side of the bound or apart from the other setting's in its
direction, fails when they lie on the other side, and is *undecided* when they overlap —
never decided by a difference smaller than the intervals. A claim is *reproduced* when
every check holds, *not reproduced* when every check fails, *partly* when some hold and
some fail, and *undecided* otherwise (the run is too small to decide it). The rules:

- "At or near the best return" means within ``NEAR`` (0.05) of it.
- Every figure the paper states as "about" a value lies within ``ABOUT`` (±25 %) of it:
  claim 5's episodes and claim 1's "below about 0.6 / 0.7" (read as: ε-greedy's best
  levels off at about that return, so a collapsed curve far below it does not pass).
- "Lower", "worse", "later" and "no later" compare two settings' intervals.
- The "best" settings of an explorer are ranked by the interquartile mean of the agents'
  final returns (``final_iqm``; the mean for older summaries without it), so one
  heavy-tailed agent cannot lift or sink a setting. "The best ε / τ are a and b" holds
  when the intervals of a and b lie above every other value's. An explorer's *best
  setting* is, among those whose IQM is within ``TIE`` (0.01) of the highest, the one that
  converges first.

With replicates (:mod:`vdbejax.results.replicates`) :func:`evaluate_claims` scores the
pooled agents and each replicate: a check reports in how many of the R replicates it
holds (and is undecided), a claim each replicate's verdict, and the headline verdict is the
pooled one when at least ``STABLE`` (80 %, 4 of 5) of the replicates agree with it, else
*unstable* (a replicate decides otherwise) or *undecided* (the others are undecided).

Each claim is one function of a :class:`ClaimTable` (``claim_1`` … ``claim_6``, listed in
:data:`CLAIMS`).

The thresholds come first, then the summary table the checks read (:class:`ClaimTable`);
the verdicts, the three-valued comparisons of intervals that decide a check and the
replicate rule are every claim's (:mod:`vdbejax.results.verdicts`).
"""
from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Mapping, Sequence
from typing import Any

from vdbejax.methods import learner_title
from vdbejax.results.summary import SummaryRow, episode_text, summary_rows
from vdbejax.results.verdicts import (
    Check,
    ClaimResult,
    Estimate,
    Outcome,
    all_of,
    any_of,
    at_most,
    convergence_estimate,
    count_replicates,
    estimate_text,
    final_estimate,
    inside,
    less,
    negate,
    point,
)

NEAR = 0.05
#: Relative tolerance of a figure the paper gives as "about" a value.
ABOUT = 0.25
#: Returns this close are tied when an explorer's best setting is chosen (a choice, not a
#: verdict: verdicts come from intervals).
TIE = 0.01
#: The paper's learners, with their display names (the plug-ins' titles).
LEARNER_NAMES = {name: learner_title(name) for name in ("qlearning", "sarsa")}


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
        shown = ", ".join(f"{r.swept_param():g} {estimate_text(final_estimate(r))}" for r in above)
        chosen_shown = ", ".join(f"{r.swept_param():g} {estimate_text(final_estimate(r))}"
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


def _near(t: ClaimTable, row: SummaryRow) -> bool | None:
    """Whether a setting ends within :data:`NEAR` of the best return (its interval)."""
    return at_most(point(t.near), final_estimate(row))


def _episodes(x: Estimate, budget: int | None) -> str:
    """A convergence episode with its interval: ``"118 [117, 120]"`` or ``"> 1000"``."""
    if math.isinf(x.value):
        return episode_text(x.value, budget)
    return (f"{episode_text(x.value)} [{episode_text(x.low, budget)},"
            f" {episode_text(x.high, budget)}]")


def _near_text(near: bool | None) -> str:
    """What a rival's "near the best return" outcome adds to its episode."""
    return "" if near else " (not near best)" if near is False else " (near best: undecided)"


def _conv(row: SummaryRow) -> str:
    return _episodes(convergence_estimate(row), row.convergence_budget)


def claim_1(t: ClaimTable) -> ClaimResult:
    """ε-greedy: the best ε are 0.05 and 0.1; its best final return levels off at about
    the paper's 0.6 (SARSA) and 0.7 (Q-learning)."""
    measured, checks = [], []
    bounds = {"qlearning": 0.7, "sarsa": 0.6}
    for learner in t.learners:
        rows_e = t.get(learner, "egreedy")
        best = t.best(learner, "egreedy")
        if best is None:
            continue
        name = LEARNER_NAMES[learner]
        passed, how = t.best_are(learner, "egreedy", {0.05, 0.1})
        measured.append(f"{name} ε→final: {_finals(rows_e)}")
        checks.append(Check(f"{name}: the best ε are 0.05 and 0.1 ({how})", passed))
        lo, hi, inside = _about(final_estimate(best), bounds[learner])
        checks.append(Check(f"{name}: best ε's final return {best.final_return:.3f}"
                            f" {estimate_text(final_estimate(best))} is about {bounds[learner]}"
                            f" (±{ABOUT:.0%}: {lo:.3g}–{hi:.3g})", inside))
    return ClaimResult(
        1, "ε-greedy: the best ε are 0.1 and 0.05 for both learners; its final average return "
           "stays below about 0.6 (SARSA) and 0.7 (Q-learning).",
        "best ε ∈ {0.05, 0.1}; final ≈ 0.6 (SARSA), ≈ 0.7 (Q-learning)", "; ".join(measured),
        checks)


def claim_2(t: ClaimTable) -> ClaimResult:
    """Softmax: the low τ are best and end near the best return."""
    measured, checks = [], []
    lows = {0.0001, 0.001}
    for learner in t.learners:
        rows_s = t.get(learner, "softmax")
        if not rows_s:
            continue
        name = LEARNER_NAMES[learner]
        passed, how = t.best_are(learner, "softmax", lows)
        low = [r for r in rows_s if r.swept_param() in lows]
        measured.append(f"{name} τ→final: {_finals(rows_s)}")
        checks.append(Check(f"{name}: the best τ are 0.0001 and 0.001 ({how})", passed))
        checks.append(Check(f"{name}: τ ∈ {{0.0001, 0.001}} end within {NEAR} of"
                            f" {t.best_return:.2f} ({_lows(low) or 'absent'})",
                            all_of(_near(t, r) for r in low) if low else False))
    return ClaimResult(2, "Softmax: low τ (0.001, 0.0001) are best, ending at or near 0.86.",
                       "best τ ∈ {0.0001, 0.001}, final ≈ 0.86", "; ".join(measured), checks)


def _lows(rows: list[SummaryRow]) -> str:
    """Each row's parameter and final-return interval."""
    return ", ".join(f"{r.swept_param():g}→{estimate_text(final_estimate(r))}" for r in rows)


def claim_3(t: ClaimTable) -> ClaimResult:
    """VDBE: good from σ = 0.1 (Q-learning) and σ = 1 (SARSA); a σ too low converges
    slowly or not at all, worst with SARSA."""
    measured, checks = [], []
    good_from = {"qlearning": 0.1, "sarsa": 1.0}
    worst: dict[str, SummaryRow] = {}
    for learner in t.learners:
        rows_v = t.get(learner, "vdbe")
        if not rows_v:
            continue
        name = LEARNER_NAMES[learner]
        high = [r for r in rows_v if r.swept_param() >= good_from[learner]]
        low = [r for r in rows_v if r.swept_param() < good_from[learner]]
        measured.append(f"{name} σ→final (convergence ep.): " + ", ".join(
            f"{r.swept_param():g}→{r.final_return:.2f} ({_conv(r)})" for r in rows_v))
        checks.append(Check(f"{name}: every σ ≥ {good_from[learner]:g} ends within {NEAR}"
                            f" of {t.best_return:.2f} ({_lows(high)})",
                            all_of(_near(t, r) for r in high) if high else False))
        if low and high:
            slow = all_of(any_of([
                all_of(less(final_estimate(r), final_estimate(h)) for h in high),
                all_of(less(convergence_estimate(h), convergence_estimate(r)) for h in high)])
                for r in low)
            latest = max(high, key=lambda r: (r.convergence_episode, r.config))
            checks.append(Check(f"{name}: every σ < {good_from[learner]:g} ends lower than every"
                                f" σ ≥ {good_from[learner]:g} or converges later than all of"
                                f" them (their latest: σ = {latest.swept_param():g},"
                                f" {_conv(latest)})", slow))
        worst[learner] = min(rows_v, key=lambda r: r.final_return)
    if len(worst) == 2:
        sarsa, qlearning = worst["sarsa"], worst["qlearning"]
        checks.append(Check(f"too-low σ is worst with SARSA (worst final SARSA"
                            f" {estimate_text(final_estimate(sarsa))}, Q-learning"
                            f" {estimate_text(final_estimate(qlearning))}: SARSA's no higher)",
                            at_most(final_estimate(sarsa), final_estimate(qlearning))))
    return ClaimResult(
        3, "VDBE: Q-learning does well for σ ≥ 0.1, SARSA for σ ≥ 1; a σ too low converges "
           "slowly or not at all, worst with SARSA.",
        "good: σ ≥ 0.1 (Q-learning), σ ≥ 1 (SARSA)", "; ".join(measured), checks)


def claim_4(t: ClaimTable) -> ClaimResult:
    """VDBE-Softmax: every σ ends near the best return, with either learner."""
    measured, checks = [], []
    for learner in t.learners:
        rows_vs = t.get(learner, "vdbe_softmax")
        if not rows_vs:
            continue
        name = LEARNER_NAMES[learner]
        measured.append(f"{name} σ→final: {_finals(rows_vs)}")
        checks += [Check(f"{name} σ={r.swept_param():g} ends within {NEAR}"
                         f" of {t.best_return:.2f} ({estimate_text(final_estimate(r))})",
                         _near(t, r))
                   for r in rows_vs]
    return ClaimResult(4, "VDBE-Softmax: good for every σ tried, with either learner.",
                       "every σ ends near 0.86", "; ".join(measured), checks)


def claim_5(t: ClaimTable) -> ClaimResult:
    """Convergence speed: VDBE-Softmax's best setting converges first, after about the
    episodes the paper states.

    Each explorer's best setting is :meth:`ClaimTable.best`'s. A rival that does not end
    near the best return (decided by its interval) does not compete in "converges first".
    """
    measured, checks = [], []
    paper_episode = {"qlearning": 280, "sarsa": 300}
    for learner in t.learners:
        name = LEARNER_NAMES[learner]
        bests = {e: t.best(learner, e) for e in ("egreedy", "softmax", "vdbe", "vdbe_softmax")}
        if bests["vdbe_softmax"] is None:
            continue
        found = {e: r for e, r in bests.items() if r is not None}
        conv = {e: convergence_estimate(r) for e, r in found.items()}
        good = {e: _near(t, r) for e, r in found.items()}
        measured.append(f"{name} convergence episode of each explorer's best setting: " + ", ".join(
            f"{e} ({found[e].swept_param():g}) {_conv(found[e])}" + _near_text(good[e])
            for e in conv)
            + f" (paper: VDBE-Softmax ≈{paper_episode[learner]}, others ≈350)")
        rivals = [e for e in ("softmax", "vdbe") if e in conv]
        checks.append(Check(
            f"{name}: VDBE-Softmax ends near the best return and converges"
            f" ({_conv(found['vdbe_softmax'])}) no later than "
            + ", ".join(f"{e} ({_conv(found[e])}){_near_text(good[e])}" for e in rivals),
            all_of([good["vdbe_softmax"], *(
                any_of([negate(good[e]), at_most(conv["vdbe_softmax"], conv[e])])
                for e in rivals)])))
        # Every figure the paper states: VDBE-Softmax ≈ 280 / 300 episodes, the others ≈ 350.
        stated = {"vdbe_softmax": paper_episode[learner], "softmax": 350, "vdbe": 350}
        for explorer, episode in stated.items():
            if explorer in conv:
                lo, hi, inside = _about(conv[explorer], episode)
                checks.append(Check(
                    f"{name}: best {explorer} converges after about {episode} episodes"
                    f" ({_conv(found[explorer])}; ±{ABOUT:.0%}: {lo:g}–{hi:g})", inside))
        if learner == "qlearning" and "egreedy" in conv:
            # "About as fast": within ±25 % of VDBE-Softmax or faster; "worse": apart.
            egreedy, vs = final_estimate(found["egreedy"]), final_estimate(found["vdbe_softmax"])
            checks.append(Check(
                f"{name}: ε-greedy converges about as fast (episode"
                f" {_conv(found['egreedy'])} ≤ {1 + ABOUT:g} × {_conv(found['vdbe_softmax'])})"
                f" to a worse return ({estimate_text(egreedy)} below {estimate_text(vs)})",
                all_of([good["vdbe_softmax"],
                        at_most(conv["egreedy"], conv["vdbe_softmax"].scaled(1 + ABOUT)),
                        less(egreedy, vs)])))
    return ClaimResult(
        5, "VDBE-Softmax converges fastest: its best average return after about 280 episodes "
           "(Q-learning) and 300 (SARSA); the others near 350; ε-greedy with Q-learning "
           "converges about as fast but to a worse return.",
        "VDBE-Softmax ≈280 (Q-learning) / ≈300 (SARSA); others ≈350", "; ".join(measured),
        checks)


def claim_6(t: ClaimTable) -> ClaimResult:
    """Final returns: every explorer's best setting but ε-greedy's ends near the best return."""
    measured, checks = [], []
    for learner in t.learners:
        name = LEARNER_NAMES[learner]
        for explorer in ("softmax", "vdbe", "vdbe_softmax", "egreedy"):
            best = t.best(learner, explorer)
            if best is None:
                continue
            value = final_estimate(best)
            measured.append(f"{name} best {explorer} ({best.swept_param():g})"
                            f" {best.final_return:.3f}")
            if explorer == "egreedy":
                checks.append(Check(f"{name}: ε-greedy's best ({estimate_text(value)}) stays below"
                                    f" {t.near:.2f}", less(value, point(t.near))))
            else:
                checks.append(Check(f"{name}: best {explorer} ({estimate_text(value)}) ends within"
                                    f" {NEAR} of {t.best_return:.2f} (≥ {t.near:.2f})",
                                    _near(t, best)))
    return ClaimResult(6, "All methods but ε-greedy end at or near the best return, 0.86.",
                       "softmax, VDBE, VDBE-Softmax ≈ 0.86; ε-greedy lower", "; ".join(measured),
                       checks)


#: The paper's six claims, in order: each scores one claim on a :class:`ClaimTable`.
CLAIMS: list[Callable[[ClaimTable], ClaimResult]] = [
    claim_1, claim_2, claim_3, claim_4, claim_5, claim_6]


def _score(rows: Iterable[SummaryRow | Mapping[str, Any]],
           best_return: float) -> list[ClaimResult]:
    table = ClaimTable(rows, best_return)
    return [result for result in (claim(table) for claim in CLAIMS) if result.checks]


def evaluate_claims(rows: Iterable[SummaryRow | Mapping[str, Any]], best_return: float = 0.86,
                    replicates: Sequence[Iterable[SummaryRow | Mapping[str, Any]]] | None = None,
                    ) -> list[ClaimResult]:
    """Score the six claims (:data:`CLAIMS`) on summary rows (see
    :func:`vdbejax.results.analysis.summarize`).

    Claims whose settings are absent from ``rows`` get no checks and are skipped.

    Args:
      rows: summary rows (:class:`~vdbejax.results.summary.SummaryRow`, or mappings of their
        columns to strings or numbers, as read from ``summary.csv``): the pooled agents'
        when ``replicates`` are given.
      best_return: the task's best possible return ("near" = within :data:`NEAR` of it).
      replicates: each replicate's rows (the same settings as ``rows``), or ``None``.

    Returns:
      one :class:`ClaimResult` per claim that has checks, in claim order; with
      ``replicates``, each check counts the replicates it holds in and each claim lists
      their verdicts.

    Raises:
      ValueError: a replicate's rows give other claims or checks than ``rows``.
    """
    pooled = _score(rows, best_return)
    if replicates is None:
        return pooled
    count_replicates(pooled, [_score(r, best_return) for r in replicates])
    return pooled


__all__ = ["ABOUT", "CLAIMS", "LEARNER_NAMES", "NEAR", "TIE", "ClaimTable", "evaluate_claims",
           "rank_value"]
