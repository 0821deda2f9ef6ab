"""``report.md``: the scored claims (:mod:`vdbejax.paper.claims`) as a document.

One run's report lists each claim's verdict and checks. A run with replicates
(:mod:`vdbejax.results.replicates`) also states the headline rule, gives each claim's
pooled verdict and how many replicates agree with it, each check's "k of R replicates",
and names every check and claim whose outcome flips between replicates.
"""
from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from vdbejax.paper.claims import ABOUT, NEAR, TIE
from vdbejax.results.markdown import table_lines
from vdbejax.results.solving import CONVERGENCE_TEXT
from vdbejax.results.verdicts import STABLE, Check, ClaimResult, mark, stable_count


def cap_message(meta: dict[str, Any]) -> str:
    """One line on the episodes cut at a task's safety cap (a task without step limit)."""
    cut, agents = meta.get("truncated_episodes", 0), meta.get("agents_truncated", 0)
    return (f"{cut:,} episodes of {agents} agents ran into the safety cap of"
            f" {meta.get('max_steps', '?'):,} steps and were cut there (the published code would"
            f" never have finished them); longest episode"
            f" {meta.get('longest_episode', '?'):,} steps")


#: What each reading of the paper is (``reproduce(reading=…)``, ``--reading``).
READING_TEXT = {
    "textbook": "the paper's text, as docs/task.md specifies it",
    "authors": "the first author's published code: its task table and agent details",
}


def reading_line(meta: dict[str, Any]) -> str:
    """Which reading of the paper a run is (and the agent details it applies), in one
    sentence; results saved before the reading was recorded are read from their task."""
    reading = meta.get("reading") or {"table_cleaning": "textbook",
                                      "cruz2018": "authors"}.get(meta.get("mdp", ""), "?")
    other = {"textbook": "authors", "authors": "textbook"}.get(reading)
    details = meta.get("details") or {}
    return (f"Reading: **{reading}** ({READING_TEXT.get(reading, 'not recorded')})"
            + (f", agent details {details}" if details else "")
            + (f"; the other reading is `vdbejax reproduce --reading {other}`, and which detail"
               " decides each claim is `vdbejax ablate --sections`" if other else "") + ".")


def headline_rule(replicates: int) -> str:
    """The rule that turns the pooled and the replicates' verdicts into the headline."""
    need = stable_count(replicates)
    return (f"a claim's headline verdict is its pooled verdict when at least {STABLE:.0%} of"
            f" the replicates that decide the claim ({need} of {replicates} when all do) give"
            " the same verdict, otherwise **unstable**; a replicate whose verdict is undecided"
            " (too small to decide the claim) is left out of that count, and a claim the"
            " pooled agents leave undecided is undecided")


#: How checks are decided, as ``report.md`` states it.
DECISION_RULE = (
    "Each check is decided by the 95% bootstrap intervals, never by a difference smaller"
    " than their width: [x] holds (the intervals lie on its side of the bound, or apart from"
    " the other setting's in its direction), [ ] fails (they lie on the other side), [?]"
    " undecided (they overlap: the run is too small to decide it). A claim is reproduced when"
    " every check holds, not reproduced when every check fails, partly when some hold and"
    " some fail, and undecided otherwise.")


def _replicate_outcomes(check: Check) -> str:
    """`` — holds in k of R replicates`` (and how many leave it undecided)."""
    if check.replicates is None:
        return ""
    undecided = (f", undecided in {check.replicates_undecided}"
                 if check.replicates_undecided else "")
    return f" — holds in {check.replicates_passed} of {check.replicates} replicates{undecided}"


def _undecided(claims: Sequence[ClaimResult], agents: str) -> list[str]:
    """The paragraph on the checks the pooled agents leave undecided."""
    count = sum(c.undecided_count for c in claims)
    if not count:
        return ["**Undecided.** None: the intervals decide every check.", ""]
    where = ", ".join(f"claim {c.number} ({c.undecided_count})" for c in claims
                      if c.undecided_count)
    return [f"**Undecided.** {count} checks ({where}): their intervals overlap the bound or"
            f" the other setting's, so this run ({agents} per setting) is too small to decide"
            " them; more agents would narrow the intervals.", ""]


def _flips(claims: Sequence[ClaimResult]) -> list[str]:
    """One item per claim whose decided verdict or some decided check differs between
    replicates (a replicate that leaves it undecided is no flip, but is named)."""
    lines = []
    for c in claims:
        flipping = [(j, k) for j, k in enumerate(c.checks, 1) if k.flips]
        verdicts = dict.fromkeys(v for v in c.replicate_verdicts if v != "undecided")
        undecided = len(c.replicate_verdicts) - c.decided_replicates
        if len(verdicts) <= 1 and not flipping:
            continue
        lines.append(f"- Claim {c.number}: " + (
            "its verdict flips: " + ", ".join(f"{v} in {c.replicate_verdicts.count(v)}"
                                              for v in verdicts) if len(verdicts) > 1 else
            f"its verdict is {c.pooled_verdict} in every replicate that decides it")
            + (f" (undecided in {undecided})" if undecided else "") + ".")
        lines += [f"  - check {j} holds in {k.replicates_passed} of {k.replicates}"
                  + (f" (undecided in {k.replicates_undecided})" if k.replicates_undecided
                     else "") + f": {k.description}" for j, k in flipping]
    return lines


def _summary_table(claims: Sequence[ClaimResult], replicates: int) -> list[str]:
    if not replicates:
        return table_lines(["#", "verdict", "checks passed", "undecided"],
                           ([str(c.number), f"**{c.verdict}**",
                             f"{c.passed_count}/{len(c.checks)}", str(c.undecided_count)]
                            for c in claims))
    rows = []
    for c in claims:
        counts = ", ".join(f"{c.replicate_verdicts.count(v)} {v}"
                           for v in dict.fromkeys(c.replicate_verdicts))
        rows.append([str(c.number), f"**{c.verdict}**", c.pooled_verdict,
                     f"{c.passed_count}/{len(c.checks)}", str(c.undecided_count),
                     f"{c.agreeing} of {replicates}", counts])
    return table_lines(["#", "headline", "pooled", "checks passed (pooled)",
                        "undecided (pooled)", "replicates agreeing", "replicates' verdicts"],
                       rows)


def render_report(claims: Sequence[ClaimResult], meta: dict[str, Any], best_return: float) -> str:
    """``report.md``: each claim with the paper's and our numbers, checks and verdict.

    Args:
      claims: the scored claims (:func:`~vdbejax.paper.claims.evaluate_claims`).
      meta: the run's metadata (task, run size, seed, options; missing keys print ``?``;
        ``replicates`` and ``agents_per_replicate`` for a run with replicates).
      best_return: the task's best possible return.

    Returns:
      markdown text.
    """
    replicates = max((len(c.replicate_verdicts) for c in claims), default=0)
    if replicates:
        per = meta.get("agents_per_replicate", "?")
        agents = (f"{replicates} replicates × {per} agents (pooled"
                  f" {meta.get('num_seeds', '?')})")
    else:
        agents = f"{meta.get('num_seeds', '?')} agents"
    lines = [
        "# Reproduction report: Cruz et al. (2018), claim by claim",
        "",
        reading_line(meta),
        "",
        f"Task `{meta.get('mdp', '?')}`, {agents} × "
        f"{meta.get('num_episodes', '?')} episodes per setting, root seed {meta.get('seed', '?')}, "
        f"options {meta.get('options', {})}, max_steps {meta.get('max_steps', '?')}. "
        f"Best possible return (exact solver): {best_return:.4f}.",
        "",
        f"Final return = mean over the last 100 episodes and all agents; \"near\" = within {NEAR} "
        f"of the best return; {CONVERGENCE_TEXT}; a figure the paper gives as \"about\" a value "
        f"must lie within ±{ABOUT:.0%} of it; settings are "
        "ranked by the IQM of their agents' final returns, an explorer's best setting being "
        f"the first to converge among those within {TIE} of the highest IQM.",
        "",
        DECISION_RULE,
        "",
    ]
    if meta.get("step_cap"):
        by_config = meta.get("truncated_episodes_by_config") or []
        labels = meta.get("config_labels") or []
        where = [f"{labels[c] if c < len(labels) else f'config {c}'} ({n:,})"
                 for c, n in enumerate(by_config) if n]
        lines += [f"**Safety cap.** The task has no step limit: {cap_message(meta)}"
                  + (f". Per setting: {'; '.join(where)}." if where else "."), ""]
    if replicates:
        flips = _flips(claims)
        lines += [f"**Replicates.** Every claim is scored on the pooled agents and on each of"
                  f" the {replicates} replicates (agents {per}·r … {per}·r + {per} − 1 of each"
                  f" setting, r = 0 … {replicates - 1}; `summary.csv` and the figures are"
                  f" replicate 0's, `summary_pooled.csv` the pooled agents'); "
                  f"{headline_rule(replicates)}.", ""]
        lines += (["**Flips between replicates.**", "", *flips, ""] if flips else
                  ["**Flips between replicates.** None: every check holds in all replicates"
                   " that decide it or in none.", ""])
    lines += _undecided(claims, agents)
    lines += _summary_table(claims, replicates)
    for c in claims:
        title = c.verdict if not replicates else (
            f"{c.verdict} (pooled {c.pooled_verdict}; {c.agreeing} of {replicates} replicates"
            " agree)")
        lines += ["", f"## Claim {c.number}: {title}", "", f"> {c.claim}", "",
                  f"- Paper: {c.paper}", f"- Measured: {c.measured}", "- Checks:"]
        lines += [f"  - {mark(k.passed)} {k.description}" + _replicate_outcomes(k)
                  for k in c.checks]
    return "\n".join(lines) + "\n"
