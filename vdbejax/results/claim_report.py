"""Scored claims as documents: the text every claims report shares (the decision and
replicate rules, the verdict table, flips between replicates) — ``report.md``'s
(:mod:`vdbejax.paper.report`) and a study's ``claims.md`` — and a study's ``claims.csv``
(one row per claim, check and replicate).
"""
from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from vdbejax.results import io
from vdbejax.results.claim_scoring import ClaimScores
from vdbejax.results.markdown import table_lines
from vdbejax.results.verdicts import STABLE, Check, ClaimResult, Reading, mark, stable_count

#: A study's claims report (markdown) and its tidy table, beside ``summary.csv``.
CLAIMS_REPORT_FILE = "claims.md"
CLAIMS_FILE = "claims.csv"
#: ``claims.csv``'s columns: one row per claim × check × (pooled agents, each replicate).
CLAIMS_COLUMNS = ["claim", "sentence", "check", "description", "metric", "setting",
                  "estimate", "low", "high", "other_setting", "other_estimate", "other_low",
                  "other_high", "bound", "agents", "replicate", "outcome", "claim_verdict",
                  "headline"]
OUTCOME_WORDS = {True: "holds", False: "fails", None: "undecided"}


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


def replicate_outcomes(check: Check) -> str:
    """`` — holds in k of R replicates`` (and how many leave it undecided)."""
    if check.replicates is None:
        return ""
    undecided = (f", undecided in {check.replicates_undecided}"
                 if check.replicates_undecided else "")
    return f" — holds in {check.replicates_passed} of {check.replicates} replicates{undecided}"


def undecided_lines(claims: Sequence[ClaimResult], agents: str) -> list[str]:
    """The paragraph on the checks the pooled agents leave undecided."""
    count = sum(c.undecided_count for c in claims)
    if not count:
        return ["**Undecided.** None: the intervals decide every check.", ""]
    where = ", ".join(f"claim {c.number} ({c.undecided_count})" for c in claims
                      if c.undecided_count)
    return [f"**Undecided.** {count} checks ({where}): their intervals overlap the bound or"
            f" the other setting's, so this run ({agents} per setting) is too small to decide"
            " them; more agents would narrow the intervals.", ""]


def flip_lines(claims: Sequence[ClaimResult]) -> list[str]:
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


def verdict_table(claims: Sequence[ClaimResult], replicates: int) -> list[str]:
    """The claims' verdicts as a markdown table (with replicates: headline, pooled verdict,
    replicates agreeing and their verdicts)."""
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


def reading_columns(reading: Reading) -> dict[str, Any]:
    """A check's reading as ``claims.csv``'s columns (empty where it has none)."""
    columns: dict[str, Any] = {"metric": reading.metric, "setting": reading.setting,
                               "other_setting": reading.other_setting,
                               "bound": "" if reading.bound is None else float(reading.bound)}
    for prefix, x in (("", reading.estimate), ("other_", reading.other_estimate)):
        columns.update({f"{prefix}estimate": "" if x is None else x.value,
                        f"{prefix}low": "" if x is None else x.low,
                        f"{prefix}high": "" if x is None else x.high})
    return columns


def claims_rows(scores: ClaimScores) -> list[dict[str, Any]]:
    """``claims.csv``'s rows: each check's description and what it read (``metric``, the
    ``setting`` and its ``estimate`` with its interval ``low``–``high``, the other setting's,
    the ``bound``: :func:`reading_columns`) and outcome, and its claim's verdict, on all
    agents (``agents`` = ``all agents``, ``replicate`` empty) and on each replicate
    (``replicate r``, ``replicate`` = r); ``headline`` is the claim's headline verdict."""
    rows = []
    scopes: list[tuple[int | str, list[ClaimResult]]] = [
        ("", scores.claims), *enumerate(scores.replicates)]
    for r, claims in scopes:
        for claim, pooled in zip(claims, scores.claims, strict=True):
            rows += [{"claim": claim.number, "sentence": claim.claim, "check": j,
                      "description": check.description, **reading_columns(check.reading),
                      "agents": "all agents" if r == "" else f"replicate {r}",
                      "replicate": r, "outcome": OUTCOME_WORDS[check.passed],
                      "claim_verdict": claim.pooled_verdict, "headline": pooled.verdict}
                     for j, check in enumerate(claim.checks, 1)]
    return rows


def render_claims(scores: ClaimScores, meta: dict[str, Any], provenance: str) -> str:
    """A study's ``claims.md``: the rules, the verdicts and every check.

    Args:
      scores: the scored claims (:func:`~vdbejax.results.claim_scoring.score_claims`).
      meta: the run's ``meta.json`` (task, agents, episodes).
      provenance: one sentence on when the claims were stated (before training or after).
    """
    claims, replicates = scores.claims, len(scores.replicates)
    per = meta.get("agents_per_replicate", meta.get("num_seeds", "?"))
    agents = (f"{replicates} replicates × {per} agents (pooled {meta.get('num_seeds', '?')})"
              if replicates else f"{meta.get('num_seeds', '?')} agents")
    lines = ["# Claims", "", f"Task `{meta.get('task', meta.get('mdp', '?'))}`, {agents} ×"
             f" {meta.get('num_episodes', '?')} episodes per setting, root seed"
             f" {meta.get('seed', '?')}. {provenance}", "", DECISION_RULE, ""]
    if replicates:
        lines += [f"**Replicates.** {headline_rule(replicates)[0].upper()}"
                  f"{headline_rule(replicates)[1:]}.", ""]
        lines += flips_block(claims)
    lines += undecided_lines(claims, agents)
    lines += verdict_table(claims, replicates)
    lines += claim_sections(claims, replicates, "Stated")
    return "\n".join(lines) + "\n"


def flips_block(claims: Sequence[ClaimResult]) -> list[str]:
    """The paragraph on the claims and checks whose verdicts differ between replicates."""
    flips = flip_lines(claims)
    return (["**Flips between replicates.**", "", *flips, ""] if flips else
            ["**Flips between replicates.** None: every check holds in all replicates"
             " that decide it or in none.", ""])


def claim_sections(claims: Sequence[ClaimResult], replicates: int, source: str) -> list[str]:
    """Each claim's section: its verdict, its sentence, what its source states (the line
    ``- {source}: …``, left out where the claim states nothing more), what was measured and
    every check with its replicates' outcomes."""
    lines: list[str] = []
    for c in claims:
        title = c.verdict if not replicates else (
            f"{c.verdict} (pooled {c.pooled_verdict}; {c.agreeing} of {replicates} replicates"
            " agree)")
        lines += ["", f"## Claim {c.number}: {title}", "", f"> {c.claim}", ""]
        if c.paper:
            lines.append(f"- {source}: {c.paper}")
        lines += [f"- Measured: {c.measured}", "- Checks:"]
        lines += [f"  - {mark(k.passed)} {k.description}" + replicate_outcomes(k)
                  for k in c.checks]
    return lines


def write_claims(out_dir: str | os.PathLike, scores: ClaimScores, meta: dict[str, Any],
                 provenance: str) -> list[Path]:
    """Write ``claims.md`` (:func:`render_claims`) and ``claims.csv`` (:func:`claims_rows`)
    into ``out_dir``; returns their paths."""
    out = Path(out_dir)
    io.write_csv(out / CLAIMS_FILE, claims_rows(scores), CLAIMS_COLUMNS)
    io.atomic_write_text(out / CLAIMS_REPORT_FILE, render_claims(scores, meta, provenance))
    return [out / CLAIMS_REPORT_FILE, out / CLAIMS_FILE]


__all__ = [
    "CLAIMS_COLUMNS",
    "CLAIMS_FILE",
    "CLAIMS_REPORT_FILE",
    "DECISION_RULE",
    "OUTCOME_WORDS",
    "claim_sections",
    "claims_rows",
    "flip_lines",
    "flips_block",
    "headline_rule",
    "reading_columns",
    "render_claims",
    "replicate_outcomes",
    "undecided_lines",
    "verdict_table",
    "write_claims",
]
