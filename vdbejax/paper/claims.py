"""The paper's six claims (spec, last section), scored against measured results.

Each claim is split into concrete checks on the summary table (final return = mean of the
last 100 episodes over agents; convergence episode as defined in
:mod:`vdbejax.results.stats`). A claim is *reproduced* when every check holds, *not
reproduced* when none does, *partly* otherwise. The rules every check follows:

- "At or near the best return" means within ``NEAR`` (0.05) of it.
- Every figure the paper states as "about" a value lies within ``ABOUT`` (±25 %) of it:
  claim 5's episodes and claim 1's "below about 0.6 / 0.7" (read as: ε-greedy's best
  levels off at about that return, so a collapsed curve far below it does not pass).
- Two returns within ``TIE`` (0.01) of each other are tied: a tie neither wins nor loses
  a comparison ("worse", "lower", "worst").
- The "best" settings of an explorer are ranked by the interquartile mean of the agents'
  final returns (``final_iqm``; the mean for older summaries without it), so one
  heavy-tailed agent cannot lift or sink a setting. "The best ε / τ are a and b" holds
  when a and b rank top two, or no other value ranks above the worse of them by more than
  ``TIE``. An explorer's *best setting* is, among those whose IQM is within ``TIE`` of the
  highest, the one that converges first.

With replicates (:mod:`vdbejax.results.replicates`) :func:`evaluate_claims` scores the
pooled agents and each replicate: a check reports in how many of the R replicates it
holds, a claim each replicate's verdict, and the headline verdict is the pooled one when at
least ``STABLE`` (80 %, 4 of 5) of the replicates agree with it, else *unstable*.

Each claim is one function of a :class:`ClaimTable` (``claim_1`` … ``claim_6``, listed in
:data:`CLAIMS`).
"""
from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping, Sequence
from typing import Any

from vdbejax.paper.claim_table import (
    ABOUT,
    LEARNER_NAMES,
    NEAR,
    STABLE,
    TIE,
    Check,
    ClaimResult,
    ClaimTable,
    _about,
    _apart,
    _finals,
    rank_value,
    stable_count,
)
from vdbejax.results.summary import SummaryRow, episode_text

__all__ = ["ABOUT", "CLAIMS", "LEARNER_NAMES", "NEAR", "STABLE", "TIE", "Check", "ClaimResult",
           "ClaimTable", "evaluate_claims", "rank_value", "stable_count"]



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
        lo, hi, inside = _about(best.final_return, bounds[learner])
        checks.append(Check(f"{name}: best ε's final return {best.final_return:.3f} is about"
                            f" {bounds[learner]} (±{ABOUT:.0%}: {lo:.3g}–{hi:.3g})", inside))
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
                            f" {t.best_return:.2f} ({_finals(low) or 'absent'})",
                            bool(low) and all(r.final_return >= t.near for r in low)))
    return ClaimResult(2, "Softmax: low τ (0.001, 0.0001) are best, ending at or near 0.86.",
                       "best τ ∈ {0.0001, 0.001}, final ≈ 0.86", "; ".join(measured), checks)


def claim_3(t: ClaimTable) -> ClaimResult:
    """VDBE: good from σ = 0.1 (Q-learning) and σ = 1 (SARSA); a σ too low converges
    slowly or not at all, worst with SARSA."""
    measured, checks = [], []
    good_from = {"qlearning": 0.1, "sarsa": 1.0}
    worst = {}
    for learner in t.learners:
        rows_v = t.get(learner, "vdbe")
        if not rows_v:
            continue
        name = LEARNER_NAMES[learner]
        high = [r for r in rows_v if r.swept_param() >= good_from[learner]]
        low = [r for r in rows_v if r.swept_param() < good_from[learner]]
        measured.append(f"{name} σ→final (convergence ep.): " + ", ".join(
            f"{r.swept_param():g}→{r.final_return:.2f} ({episode_text(r.convergence_episode)})"
            for r in rows_v))
        checks.append(Check(f"{name}: every σ ≥ {good_from[learner]:g} ends within {NEAR}"
                            f" of {t.best_return:.2f}",
                            bool(high) and all(r.final_return >= t.near for r in high)))
        if low and high:
            floor = min(r.final_return for r in high)
            high_conv = max(r.convergence_episode for r in high)
            slow = all(r.final_return < floor - TIE or r.convergence_episode > high_conv
                       for r in low)
            checks.append(Check(f"{name}: every σ < {good_from[learner]:g} ends lower (below"
                                f" {floor:.3f} − {TIE}) or converges later than every σ ≥"
                                f" {good_from[learner]:g} (their latest convergence episode:"
                                f" {episode_text(high_conv)})", slow))
        worst[learner] = min(r.final_return for r in rows_v)
    if len(worst) == 2:
        sarsa, qlearning = _apart(worst["sarsa"], worst["qlearning"])
        checks.append(Check(f"too-low σ is worst with SARSA (worst final SARSA {sarsa},"
                            f" Q-learning {qlearning}: SARSA's lower or tied within {TIE})",
                            worst["sarsa"] <= worst["qlearning"] + TIE))
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
                         f" of {t.best_return:.2f}", r.final_return >= t.near)
                   for r in rows_vs]
    return ClaimResult(4, "VDBE-Softmax: good for every σ tried, with either learner.",
                       "every σ ends near 0.86", "; ".join(measured), checks)


def claim_5(t: ClaimTable) -> ClaimResult:
    """Convergence speed: VDBE-Softmax's best setting converges first, after about the
    episodes the paper states.

    Each explorer's best setting is :meth:`ClaimTable.best`'s. A setting that never gets
    near the best return has not "converged" in the paper's sense, however early its flat
    curve hits its own level.
    """
    measured, checks = [], []
    paper_episode = {"qlearning": 280, "sarsa": 300}
    for learner in t.learners:
        name = LEARNER_NAMES[learner]
        bests = {e: t.best(learner, e) for e in ("egreedy", "softmax", "vdbe", "vdbe_softmax")}
        if bests["vdbe_softmax"] is None:
            continue
        found = {e: r for e, r in bests.items() if r is not None}
        conv = {e: r.convergence_episode for e, r in found.items()}
        good = {e: r.final_return >= t.near for e, r in found.items()}
        measured.append(f"{name} convergence episode of each explorer's best setting: " + ", ".join(
            f"{e} ({found[e].swept_param():g}) {episode_text(conv[e])}"
            + ("" if good[e] else " (not near best)") for e in conv)
            + f" (paper: VDBE-Softmax ≈{paper_episode[learner]}, others ≈350)")
        rivals = [e for e in ("softmax", "vdbe") if e in conv]
        # "No later" up to noise: the lower end of VDBE-Softmax's bootstrap interval (when
        # the summary has one) must not exceed the other's convergence episode.
        vs_ci_low = found["vdbe_softmax"].convergence_ci_low
        vs_low = float(conv["vdbe_softmax"]) if vs_ci_low is None else vs_ci_low
        checks.append(Check(f"{name}: VDBE-Softmax ends near the best return and converges "
                            f"({episode_text(conv['vdbe_softmax'])}, CI from"
                            f" {episode_text(vs_low)}) no later than "
                            + ", ".join(f"{e} ({episode_text(conv[e])}"
                                        f"{'' if good[e] else ', never near best'})"
                                        for e in rivals),
                            good["vdbe_softmax"] and all(
                                not good[e] or vs_low <= conv[e] for e in rivals)))
        # Every figure the paper states: VDBE-Softmax ≈ 280 / 300 episodes, the others ≈ 350.
        stated = {"vdbe_softmax": paper_episode[learner], "softmax": 350, "vdbe": 350}
        for explorer, episode in stated.items():
            if explorer in conv:
                lo, hi, inside = _about(conv[explorer], episode)
                checks.append(Check(
                    f"{name}: best {explorer} converges after about {episode} episodes"
                    f" ({episode_text(conv[explorer])}; ±{ABOUT:.0%}: {lo:g}–{hi:g})", inside))
        if learner == "qlearning" and "egreedy" in conv:
            # "About as fast": within ±25 % of VDBE-Softmax or faster; "worse": beyond a tie.
            egreedy_final = found["egreedy"].final_return
            vs_final = found["vdbe_softmax"].final_return
            egreedy_shown, vs_shown = _apart(egreedy_final, vs_final)
            checks.append(Check(
                f"{name}: ε-greedy converges about as fast (episode"
                f" {episode_text(conv['egreedy'])} ≤ {1 + ABOUT:g} ×"
                f" {episode_text(conv['vdbe_softmax'])}) to a worse return ({egreedy_shown} <"
                f" {vs_shown} − {TIE})",
                good["vdbe_softmax"] and conv["egreedy"] <= (1 + ABOUT) * conv["vdbe_softmax"]
                and egreedy_final < vs_final - TIE))
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
            value = best.final_return
            measured.append(f"{name} best {explorer} ({best.swept_param():g}) {value:.3f}")
            shown, near = _apart(value, t.near)
            if explorer == "egreedy":
                checks.append(Check(f"{name}: ε-greedy's best ({shown}) stays below {near}",
                                    value < t.near))
            else:
                checks.append(Check(f"{name}: best {explorer} ({shown}) ends within {NEAR}"
                                    f" of {t.best_return:.2f} (≥ {near})", value >= t.near))
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
    scored = [_score(r, best_return) for r in replicates]
    for index, claims in enumerate(scored):
        shape = [(c.number, len(c.checks)) for c in claims]
        if shape != [(c.number, len(c.checks)) for c in pooled]:
            raise ValueError(f"replicates: replicate {index}'s rows give the claims and check"
                             f" counts {shape}, not the pooled rows' (the same settings needed)")
    for i, claim in enumerate(pooled):
        claim.replicate_verdicts = [claims[i].pooled_verdict for claims in scored]
        for j, check in enumerate(claim.checks):
            check.replicates = len(scored)
            check.replicates_passed = sum(claims[i].checks[j].passed for claims in scored)
    return pooled
