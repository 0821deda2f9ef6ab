"""Replicates: a grid's agents split into R independent groups of the same size.

A run with ``replicates=R`` of ``n`` agents each trains ``R × n`` agents per setting in
one grid; replicate ``r`` (0-based) is agents ``r·n … r·n + n − 1``. Every agent has its
own random stream (``fold_in(PRNGKey(seed), agent)``, :func:`vdbejax.engine.agent_state.agent_keys`)
and gives the same result alone or in any grid, so replicate 0 is, bit for bit, the run of
``n`` agents from the same root seed, and the replicates are as independent as R root seeds
would be: no new random stream.

The result folder keeps ``summary.csv`` (and the figures) for replicate 0, so a run with
``replicates=1`` writes exactly the files it always did; with R > 1 it adds
``summary_pooled.csv`` (the statistics of all ``R × n`` agents, the same columns) and
``replicates.csv`` (each replicate's final return and convergence episode per setting).
``meta.json`` records ``replicates`` and ``agents_per_replicate``.
"""
from __future__ import annotations

import dataclasses
import os
from pathlib import Path

import numpy as np

from vdbejax.results import io
from vdbejax.results.analysis import summarize
from vdbejax.results.grid_result import GridResult
from vdbejax.results.stats import CurveStatistics
from vdbejax.results.summary import SummaryRow, write_summary
from vdbejax.validation import INT32_MAX, check_int

POOLED_SUMMARY_FILE = "summary_pooled.csv"
REPLICATES_FILE = "replicates.csv"
#: Files a run with replicates writes besides the others.
REPLICATE_FILES = [POOLED_SUMMARY_FILE, REPLICATES_FILE]
#: ``replicates.csv``'s columns: one row per replicate × setting.
REPLICATE_COLUMNS = ["replicate", "config", "learner", "explorer", "param", "final_return",
                     "final_ci_low", "final_ci_high", "final_iqm", "convergence_episode"]


def check_replicates(replicates: int, agents: int) -> int:
    """``replicates`` checked (a whole number ≥ 1 whose ``replicates × agents`` fits)."""
    return check_int("replicates", replicates, 1, max(1, INT32_MAX // max(1, agents)))


def annotate_replicates(meta: dict, replicates: int, per: int) -> None:
    """Record ``replicates`` of ``per`` agents in a result's ``meta`` (nothing for one
    replicate, whose ``meta.json`` stays as it always was)."""
    if replicates > 1:
        meta.update(replicates=replicates, agents_per_replicate=per)
    else:
        for key in ("replicates", "agents_per_replicate", "replicate"):
            meta.pop(key, None)


def replicate_count(result: GridResult) -> int:
    """The replicates a result holds (``meta["replicates"]``; 1 for older results)."""
    return int(result.meta.get("replicates", 1))


def replicate(result: GridResult, index: int) -> GridResult:
    """Replicate ``index`` (0-based) of a result: its agents, as a grid of their own.

    Raises:
      ValueError: ``index`` is not one of the result's replicates.
    """
    count = replicate_count(result)
    check_int("index", index, 0, count - 1)
    per = int(result.meta.get("agents_per_replicate", result.num_seeds))
    agents = slice(index * per, (index + 1) * per)
    meta = dict(result.meta, num_seeds=per, replicates=1, agents_per_replicate=per,
                replicate=index)
    if "instance_best_returns" in meta:  # an instance per agent: the replicate's own
        for key, mean in (("instance_best_returns", "best_return"),
                          ("instance_random_returns", "random_return")):
            mine = np.asarray(meta[key], np.float64)[..., agents]  # per config where two
            meta[key], meta[mean] = mine.tolist(), float(mine.mean())
    return GridResult(result.settings, result.returns[:, agents], result.lengths[:, agents],
                      result.nonfinite[:, agents], meta,
                      None if result.episodes_run is None else result.episodes_run[:, agents],
                      None if result.policy_values is None else result.policy_values[:, agents],
                      None if result.optimal_actions is None
                      else result.optimal_actions[:, agents],
                      None if result.truncated is None else result.truncated[:, agents])


@dataclasses.dataclass
class ReplicateSummaries:
    """The summary rows of a result with replicates.

    Attributes:
      pooled: the rows of all agents (``summary_pooled.csv``).
      replicates: one list of rows per replicate (``replicates[0]`` is ``summary.csv``).
    """

    pooled: list[SummaryRow]
    replicates: list[list[SummaryRow]]


def summarize_replicates(result: GridResult, first: list[SummaryRow],
                         statistics: CurveStatistics | None = None) -> ReplicateSummaries:
    """The pooled rows and each replicate's rows of a result.

    Args:
      result: the whole grid (all replicates).
      first: replicate 0's rows, already computed (``summary.csv``).
      statistics: the whole grid's statistics, if already computed.
    """
    pooled = summarize(result, statistics=statistics)
    others = [summarize(replicate(result, r)) for r in range(1, replicate_count(result))]
    return ReplicateSummaries(pooled, [first, *others])


def write_replicates(out_dir: str | os.PathLike, summaries: ReplicateSummaries,
                     columns: list[str]) -> None:
    """Write ``summary_pooled.csv`` (``columns``, as ``summary.csv``) and ``replicates.csv``."""
    out = Path(out_dir)
    write_summary(out / POOLED_SUMMARY_FILE, summaries.pooled, columns)
    rows = [{"replicate": r, **{name: row[name] for name in REPLICATE_COLUMNS[1:]}}
            for r, replicate_rows in enumerate(summaries.replicates) for row in replicate_rows]
    io.write_csv(out / REPLICATES_FILE, rows, REPLICATE_COLUMNS)
