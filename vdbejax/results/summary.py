"""The summary table: one typed :class:`SummaryRow` per setting of a grid.

:func:`vdbejax.results.analysis.summarize` builds the rows from a grid's statistics,
:func:`write_summary` writes them to ``summary.csv`` and :func:`read_summary` reads them
back. :func:`summary_rows` is the one place where a row's text (``summary.csv``, or any
mapping of column names to strings or numbers) becomes typed values: every consumer (the
claims, the sensitivity plot, the scaling study's parameter choice, the CLI) takes
:class:`SummaryRow` objects and reads their attributes.

Columns that older summaries lack (``final_iqm``, the convergence interval,
``agents_converged``, ``convergence_budget``, ``truncated_fraction``) and those written
only for some grids (``episodes_cut`` and ``agents_cut``, a task whose step limit is only
a safety cap; the ``policy_gap`` and ``optimal_fraction`` columns, a run that evaluates
its policies; the ``optimal_actions`` and ``reward_per_step`` columns, a run that records
optimal actions) are ``None`` when absent.
"""
from __future__ import annotations

import dataclasses
import math
import os
from collections.abc import Iterable, Iterator, Mapping
from typing import Any

from vdbejax.results import io

#: The summary file of a result folder (replicate 0's where it has replicates).
SUMMARY_FILE = "summary.csv"
#: ``summary.csv``'s columns, in order (``hyperparameters`` goes after ``param`` when a
#: setting has values besides its swept parameter, ``episodes_cut`` and ``agents_cut`` at
#: the end for a task whose step limit is only a safety cap:
#: :func:`vdbejax.results.analysis.summary_columns`).
SUMMARY_COLUMNS = [
    "config",
    "learner",
    "explorer",
    "param",
    "final_return",
    "final_ci_low",
    "final_ci_high",
    "final_iqm",
    "convergence_episode",
    "convergence_ci_low",
    "convergence_ci_high",
    "agents_converged",
    "convergence_budget",
    "truncated_fraction",
    "mean_length",
    "nonfinite_agents",
]


@dataclasses.dataclass(frozen=True, kw_only=True)
class SummaryRow(Mapping[str, Any]):
    """Statistics of one setting of a grid (see :mod:`vdbejax.results.stats` for the conventions).

    Read it by attribute. It is also a read-only mapping from column names to the values
    :func:`vdbejax.results.analysis.summarize` has always returned (``row["final_return"]``;
    ``row["param"]`` is ``""`` for the explorer's default; absent columns are left out),
    which :func:`~vdbejax.results.analysis.markdown_table` and older code use.

    Attributes:
      config: the setting's index in the grid.
      learner, explorer: plug-in names.
      param: the explorer's swept parameter, ``None`` for its default.
      hyperparameters: the setting's other explicit values as compact JSON (``"{}"``).
      final_return, final_ci_low, final_ci_high: mean final return over the agents and
        its 95% bootstrap interval.
      final_iqm: interquartile mean of the agents' final returns.
      convergence_episode, convergence_ci_low, convergence_ci_high: the median over the
        agents of their convergence episodes and its 95% bootstrap interval
        (:mod:`vdbejax.results.solving`: against the task's optimum; the mean of the middle
        two for an even count; +∞, ``inf`` in ``summary.csv``, where censored: half or more
        of the agents never converge; :func:`episode_text`).
      agents_converged: the agents that converged.
      convergence_budget: the episodes a censored agent ran ("> budget").
      truncated_fraction: fraction of the last episodes the step limit cut
        (:func:`vdbejax.results.analysis.truncated_episodes`: an episode that ended on its
        own at its last allowed step is not one; NaN when ``max_steps`` is unknown).
      mean_length: mean episode length.
      nonfinite_agents: agents whose returns are not all finite.
      episodes_cut, agents_cut: episodes (and agents with any) cut at a task's safety cap.
      policy_gap, policy_gap_ci_low, policy_gap_ci_high: mean ``V* − V^π`` of the agents'
        greedy policies at their last evaluation and its 95% bootstrap interval;
        optimal_fraction, optimal_ci_low, optimal_ci_high: the fraction of agents whose
        greedy policy is optimal and its Wilson interval (a run with ``evaluate_every``
        only, :mod:`vdbejax.results.policy`).
      optimal_actions, optimal_actions_ci_low, optimal_actions_ci_high: the agents' mean
        fraction of optimal actions in their last episodes and its 95% bootstrap
        interval; reward_per_step, reward_per_step_ci_low, reward_per_step_ci_high: their
        mean reward per step there (a run with ``record_optimal`` only,
        :mod:`vdbejax.results.optimal_actions`).
    """

    config: int
    learner: str
    explorer: str
    param: float | None
    hyperparameters: str = "{}"
    final_return: float
    final_ci_low: float
    final_ci_high: float
    final_iqm: float | None = None
    convergence_episode: float
    convergence_ci_low: float | None = None
    convergence_ci_high: float | None = None
    agents_converged: int | None = None
    convergence_budget: int | None = None
    truncated_fraction: float | None = None
    mean_length: float
    nonfinite_agents: int
    episodes_cut: int | None = None
    agents_cut: int | None = None
    policy_gap: float | None = None
    policy_gap_ci_low: float | None = None
    policy_gap_ci_high: float | None = None
    optimal_fraction: float | None = None
    optimal_ci_low: float | None = None
    optimal_ci_high: float | None = None
    optimal_actions: float | None = None
    optimal_actions_ci_low: float | None = None
    optimal_actions_ci_high: float | None = None
    reward_per_step: float | None = None
    reward_per_step_ci_low: float | None = None
    reward_per_step_ci_high: float | None = None

    def swept_param(self) -> float:
        """:attr:`param`, for a consumer that compares settings by it.

        Raises:
          ValueError: the row is its explorer's default (no parameter).
        """
        if self.param is None:
            raise ValueError(f"summary row {self.config} ({self.learner}/{self.explorer}) has no"
                             " param: the explorer's default cannot be ranked by parameter")
        return self.param

    def as_dict(self) -> dict[str, Any]:
        """The row as a dict, column by column (``param`` ``""`` for the explorer's
        default; the columns this row lacks left out): what ``summary.csv`` holds."""
        values: dict[str, Any] = {}
        for field in dataclasses.fields(self):
            value = getattr(self, field.name)
            if field.name == "param":
                values["param"] = "" if value is None else value
            elif value is not None:
                values[field.name] = value
        return values

    def __getitem__(self, column: str) -> Any:
        # One column, as as_dict() would give it (without building the whole dict).
        if column not in _FIELDS:
            raise KeyError(column)
        value = getattr(self, column)
        if column == "param":
            return "" if value is None else value
        if value is None:
            raise KeyError(column)
        return value

    def __iter__(self) -> Iterator[str]:
        return iter(self.as_dict())

    def __len__(self) -> int:
        return len(self.as_dict())


_FIELDS = {field.name: field for field in dataclasses.fields(SummaryRow)}
_INTEGERS = {"config", "nonfinite_agents", "episodes_cut", "agents_cut", "agents_converged",
             "convergence_budget"}
_TEXTS = {"learner", "explorer", "hyperparameters"}


def summary_row(row: SummaryRow | Mapping[str, Any]) -> SummaryRow:
    """One row as a :class:`SummaryRow`: itself if it is one, else parsed from a mapping
    of column names to strings (``summary.csv``) or numbers.

    Blank values (``""``, ``None``; ``"None"`` too for ``param``) of a column that may be
    absent count as absent. Unknown columns are ignored.

    Raises:
      ValueError: a required column that is missing or blank, or a value that is not a
        number of the column's kind.
    """
    if isinstance(row, SummaryRow):
        return row
    values: dict[str, Any] = {}
    for name, field in _FIELDS.items():
        raw = row.get(name)
        if raw is None or raw == "" or (name == "param" and raw == "None"):
            if name == "param":
                values[name] = None
            elif field.default is dataclasses.MISSING:
                raise ValueError(f"summary row {dict(row)!r} is invalid: column {name!r} is"
                                 " missing")
            continue
        try:
            values[name] = (str(raw) if name in _TEXTS else int(raw) if name in _INTEGERS
                            else _episode(raw) if name == "convergence_episode" else float(raw))
        except (TypeError, ValueError):
            kind = ("a whole number" if name in _INTEGERS else "a number ≥ 1 or inf"
                    if name == "convergence_episode" else "a number")
            raise ValueError(f"summary row {dict(row)!r} is invalid: {name}={raw!r} must be"
                             f" {kind}") from None
    return SummaryRow(**values)


def _episode(raw: Any) -> float:
    """A convergence episode's value: a number ≥ 1 (a median: whole or halfway between two
    whole numbers), or +∞ (censored)."""
    value = float(raw)
    if not (math.isinf(value) and value > 0) and not (math.isfinite(value) and value >= 1):
        raise ValueError(raw)
    return value


def episode_text(episode: float | None, budget: int | None = None) -> str:
    """A convergence episode (or an end of its interval) as text: ``"> budget"`` where
    censored (+∞; ``"censored"`` when the budget is unknown), else the number."""
    if episode is None:
        return "?"
    if math.isinf(episode):
        return "censored" if budget is None else f"> {budget}"
    return f"{episode:g}"


def summary_rows(rows: Iterable[SummaryRow | Mapping[str, Any]]) -> list[SummaryRow]:
    """:func:`summary_row` of each row, in order."""
    return [summary_row(row) for row in rows]


def write_summary(path: str | os.PathLike, rows: Iterable[SummaryRow],
                  columns: list[str]) -> None:
    """Write ``summary.csv`` atomically: header ``columns``, floats with 6 significant
    digits (:func:`vdbejax.results.io.write_csv`)."""
    io.write_csv(path, [row.as_dict() for row in rows], columns)


def read_summary(path: str | os.PathLike) -> list[SummaryRow]:
    """The rows of a ``summary.csv`` file.

    Raises:
      ValueError: a row with a missing column or a value that is not a number (the
        message names the file).
    """
    try:
        return summary_rows(io.read_csv(path))
    except ValueError as error:
        raise ValueError(f"results file {str(path)!r} is damaged: {error}") from None
