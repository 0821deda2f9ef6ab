"""``report.md``: the paper's scored claims (:mod:`vdbejax.paper.claims`) as a document.

One run's report lists each claim's verdict and checks, and names the settings whose
agents all end at one value (with where the docs explain it). A run with replicates
(:mod:`vdbejax.results.replicates`) also states the headline rule, gives each claim's
pooled verdict and how many replicates agree with it, each check's "k of R replicates",
and names every check and claim whose outcome flips between replicates.
"""
from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from typing import Any

import numpy as np

from vdbejax.methods.registry import explorer_title, learner_title
from vdbejax.results.analysis import truncated_fraction
from vdbejax.results.claim_report import (
    DECISION_RULE,
    claim_sections,
    flips_block,
    headline_rule,
    undecided_lines,
    verdict_table,
)
from vdbejax.results.claim_spec import ABOUT, NEAR, TIE
from vdbejax.results.curves import LAST, final_return
from vdbejax.results.grid_result import GridResult
from vdbejax.results.solving import CONVERGENCE_TEXT
from vdbejax.results.verdicts import ClaimResult

#: Where the docs explain a setting whose agents all end at one value (``report.md``
#: names it; notebook 04 shows it).
TRAP_DOCS = "docs/reproduce.md, section \"The SARSA trap\" (notebooks/04_the_sarsa_trap.ipynb)"


@dataclasses.dataclass(frozen=True)
class OneValue:
    """The settings of one learner and explorer whose agents all end at one final return.

    Attributes:
      learner, explorer: plug-in names.
      parameter: the name of the explorer's swept parameter.
      params: the settings' parameters, in config order.
      final_return: the one final return (mean of the last episodes) of all their agents.
      truncated: the fraction of those last episodes the step limit cut (NaN: unknown).
    """

    learner: str
    explorer: str
    parameter: str
    params: tuple[float | None, ...]
    final_return: float
    truncated: float


def one_value_settings(result: GridResult, best_return: float, last: int = LAST
                       ) -> list[OneValue]:
    """The settings (of more than one agent) whose every agent ends at the same final
    return, bit for bit, and not near the best one (farther than the claims' ``NEAR``),
    grouped by learner, explorer and that value: no spread to estimate, agents caught at
    one fixed point short of the goal (the SARSA trap of the textbook reading). Agents that
    all end at the best return learned the task; they are not listed."""
    finals = final_return(result.returns, min(last, result.num_episodes))
    cuts = truncated_fraction(result, last)
    groups: dict[tuple[str, str, float], list[int]] = {}
    for c, setting in enumerate(result.settings):
        values = finals[c]
        if (values.size > 1 and np.isfinite(values).all() and (values == values[0]).all()
                and abs(values[0] - best_return) > NEAR):
            groups.setdefault((setting.learner, setting.explorer, float(values[0])),
                              []).append(c)
    return [OneValue(learner, explorer, result.settings[configs[0]].parameter,
                     tuple(result.settings[c].param for c in configs), value,
                     float(cuts[configs].mean()))
            for (learner, explorer, value), configs in groups.items()]


def _one_value_lines(settings: Sequence[OneValue], meta: dict[str, Any]) -> list[str]:
    """The paragraph on settings whose agents all end at one value (none: no paragraph)."""
    if not settings:
        return []
    items = []
    for s in settings:
        params = ", ".join("default" if p is None else f"{p:g}" for p in s.params)
        cut = ("" if np.isnan(s.truncated) else
               f"; {s.truncated:.0%} of their last episodes cut at the step limit of"
               f" {meta.get('max_steps', '?')}")
        items.append(f"- {learner_title(s.learner)} with {explorer_title(s.explorer)}"
                     f" ({s.parameter} = {params}): every agent ends at exactly"
                     f" {s.final_return:.3f}{cut}.")
    return ["**Settings whose agents all end at one value.** Every agent of these settings"
            " ends at the same final return, away from the best: no spread between agents is"
            " no sign of a stable learner here, the agents are caught at one fixed point and"
            " repeat the same episode (why, for SARSA with VDBE under the textbook reading:"
            f" {TRAP_DOCS}). Their verdicts and counts below stand as measured.", "",
            *items, ""]


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


def render_report(claims: Sequence[ClaimResult], meta: dict[str, Any], best_return: float,
                  one_value: Sequence[OneValue] = ()) -> str:
    """``report.md``: each claim with the paper's and our numbers, checks and verdict.

    Args:
      claims: the scored claims (:func:`~vdbejax.results.claim_scoring.score_claims` of
        :func:`~vdbejax.paper.claims.paper_claims`).
      meta: the run's metadata (task, run size, seed, options; missing keys print ``?``;
        ``replicates`` and ``agents_per_replicate`` for a run with replicates).
      best_return: the task's best possible return.
      one_value: the settings whose agents all end at one value
        (:func:`one_value_settings`): a paragraph names them and where the docs explain it.

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
        lines += [f"**Replicates.** Every claim is scored on the pooled agents and on each of"
                  f" the {replicates} replicates (agents {per}·r … {per}·r + {per} − 1 of each"
                  f" setting, r = 0 … {replicates - 1}; `summary.csv` and the figures are"
                  f" replicate 0's, `summary_pooled.csv` the pooled agents'); "
                  f"{headline_rule(replicates)}.", ""]
        lines += flips_block(claims)
    lines += _one_value_lines(one_value, meta)
    lines += undecided_lines(claims, agents)
    lines += verdict_table(claims, replicates)
    lines += claim_sections(claims, replicates, "Paper")
    return "\n".join(lines) + "\n"
