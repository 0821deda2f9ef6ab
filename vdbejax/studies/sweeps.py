"""Any sweep, from Python or a file: learners × explorers × hyperparameter axes on a task.

:func:`run_sweep` trains a sweep (:func:`~vdbejax.studies.sweep_file.sweep_settings`: the
product of the axes less its exclusions, then explicit settings) on a task and writes the
same result folder as :func:`~vdbejax.reproduce` (minus the paper's claims report):
``returns.npz``, ``configs.csv``, ``meta.json``, ``summary.csv`` and, unless
``figures=False``, ``fig3.png`` and ``sensitivity.png`` (with ``replicates``:
``summary_pooled.csv`` and ``replicates.csv`` too, :mod:`vdbejax.results.replicates`).
``vdbejax run`` is its command line; a sweep file (TOML or JSON) holds the same keys
(:mod:`vdbejax.studies.sweep_file`).
"""
from __future__ import annotations

import dataclasses
import os
import sys
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from vdbejax.envs.suite import make_suite_family
from vdbejax.methods.grid_axes import sweep_size
from vdbejax.results import io
from vdbejax.results.claim_report import CLAIMS_FILE, CLAIMS_REPORT_FILE, write_claims
from vdbejax.results.claim_scoring import score_claims
from vdbejax.results.claim_spec import check_claims, claims_digest, parse_claims
from vdbejax.results.grid_result import GridResult
from vdbejax.results.replicates import (
    REPLICATE_FILES,
    ReplicateSummaries,
    annotate_replicates,
    check_replicates,
    replicate,
    replicate_count,
    summarize_replicates,
    write_replicates,
)
from vdbejax.results.stats import CurveStatistics
from vdbejax.results.summary import SUMMARY_FILE, SummaryRow, write_summary
from vdbejax.runs import RunOptions, prepare_grid
from vdbejax.runs.batching import check_run_size
from vdbejax.runs.estimate import announce_settings
from vdbejax.runs.options import study_run
from vdbejax.studies import train_in_folder
from vdbejax.studies.learner_defaults import learner_defaults
from vdbejax.studies.sweep_file import absolute_files, sweep_settings
from vdbejax.studies.task_names import (
    load_plugins,
    make_task,
)
from vdbejax.validation import INT32_MAX, check_bool, check_choice, check_int

FIGURE_FILE = "fig3.png"
SENSITIVITY_FILE = "sensitivity.png"
#: The learned policies' gap to the optimum (a run with ``evaluate_every``).
POLICY_FIGURE_FILE = "policy_gap.png"
#: The average reward and the % optimal action (a run with ``record_optimal``).
OPTIMAL_FIGURE_FILE = "optimal_actions.png"


#: Files a run writes into its folder (checked before training: none may be a folder).
RUN_FILES = [io.RETURNS_FILE, io.CONFIGS_FILE, io.META_FILE, SUMMARY_FILE, FIGURE_FILE,
             SENSITIVITY_FILE, POLICY_FIGURE_FILE, OPTIMAL_FIGURE_FILE, *REPLICATE_FILES,
             CLAIMS_REPORT_FILE, CLAIMS_FILE]


def stated_claims(result: GridResult) -> list[Any]:
    """The claims a run's sweep stated before training (``meta.json``; none: ``[]``)."""
    record = result.meta.get("sweep")
    return list(record.get("claims") or []) if isinstance(record, Mapping) else []


def write_study_claims(result: GridResult, out_dir: str | os.PathLike,
                       claims: Sequence[Any] | None = None,
                       rows: list[SummaryRow] | None = None) -> list[Path]:
    """Score a study's claims on its result and write ``claims.md`` and ``claims.csv``
    (:mod:`vdbejax.results.claim_report`); a folder without claims gets neither (an
    earlier run's are removed).

    Args:
      result: the result (all replicates).
      out_dir: where to write.
      claims: claims as data (:func:`~vdbejax.results.claim_spec.parse_claims`); default:
        those the run stated before training (:func:`stated_claims`). The report says which:
        claims whose digest is ``meta.json``'s ``claims_digest`` were stated before training.
      rows: the pooled agents' summary rows, if already computed.

    Returns:
      the files written.

    Raises:
      ValueError: a claim that names what the result does not hold.
    """
    data = stated_claims(result) if claims is None else list(claims)
    out = Path(out_dir)
    if not data:
        for name in (CLAIMS_REPORT_FILE, CLAIMS_FILE):
            (out / name).unlink(missing_ok=True)
        return []
    scores = score_claims(result, parse_claims(data), rows)
    digest, recorded = claims_digest(data), result.meta.get("claims_digest")
    provenance = (f"These claims were stated before training: their digest ({digest[:12]}…)"
                  " is meta.json's claims_digest." if digest == recorded else
                  "These claims were written after the run: "
                  + ("it stated none before training." if recorded is None else
                     f"their digest ({digest[:12]}…) is not meta.json's claims_digest"
                     f" ({str(recorded)[:12]}…), the claims stated before training."))
    return write_claims(out, scores, result.meta, provenance)


def write_outputs(result: GridResult, out_dir: str | os.PathLike, best: float | None,
                  bands: bool = True, figures: bool = True,
                  statistics: CurveStatistics | None = None) -> ReplicateSummaries:
    """Write ``summary.csv`` and (unless ``figures=False``) ``fig3.png`` and
    ``sensitivity.png`` (and ``policy_gap.png`` with policy evaluations,
    ``optimal_actions.png`` with a record of optimal actions) for a grid of
    any kinds; with replicates, these are replicate 0's
    and ``summary_pooled.csv`` and ``replicates.csv`` come beside them
    (:mod:`vdbejax.results.replicates`).

    Args:
      result: the grid.
      out_dir: output folder.
      best: the task's best return (reference lines), if known.
      bands: Figure 3 with 95% bootstrap bands over agents.
      figures: draw the figures.
      statistics: :func:`~vdbejax.results.stats.curve_statistics` of the returns (all
        agents), if already computed (with bands when ``figures and bands`` and the
        result has one replicate).

    Returns:
      the summary rows (:class:`~vdbejax.results.replicates.ReplicateSummaries`: pooled
      and per replicate; one replicate: both are ``summary.csv``'s rows).
    """
    from vdbejax.results.analysis import summarize, summary_columns
    from vdbejax.results.stats import curve_statistics

    out = Path(out_dir)
    count = replicate_count(result)
    first = result if count == 1 else replicate(result, 0)
    # One pass over the returns serves the summary and Figure 3's curves and bands.
    first_statistics = statistics if count == 1 else None
    if first_statistics is None:
        first_statistics = curve_statistics(first.returns, bands=figures and bands)
    summary = summarize(first, statistics=first_statistics)
    columns = summary_columns(first)
    write_summary(out / SUMMARY_FILE, summary, columns)
    if figures:
        from vdbejax.results.plotting import figure3, sensitivity  # matplotlib only when plotting

        io.save_figure(figure3(first, best_return=best, bands=bands,
                               statistics=first_statistics), out / FIGURE_FILE)
        names = {s.explorer: s.parameter for s in result.settings}
        io.save_figure(sensitivity(summary, best_return=best, parameter_names=names),
                       out / SENSITIVITY_FILE)
        if result.policy_values is not None:
            from vdbejax.results.policy import policy_gap_figure

            io.save_figure(policy_gap_figure(first), out / POLICY_FIGURE_FILE)
        if result.optimal_actions is not None:
            from vdbejax.results.plotting import optimal_actions_figure

            io.save_figure(optimal_actions_figure(first), out / OPTIMAL_FIGURE_FILE)
    if count == 1:
        for name in REPLICATE_FILES:  # an earlier run's with replicates would go stale
            (out / name).unlink(missing_ok=True)
        return ReplicateSummaries(summary, [summary])
    summaries = summarize_replicates(result, summary, statistics)
    write_replicates(out, summaries, columns)
    return summaries


@dataclasses.dataclass(frozen=True)
class Sweep:
    """What a sweep trains: the settings (:func:`~vdbejax.studies.sweep_file.sweep_settings`)
    and the plug-ins that register their methods — the sweep file's keys of the same names.

    Attributes:
      learners: learner names of the product (none: ``settings`` only).
      explorers: explorer names (built-in or registered by ``plugins``).
      axes: ``{hyperparameter: values}`` (see :func:`~vdbejax.methods.grid_axes.sweep`).
      shared: ``{hyperparameter: value}`` for every setting that has the field.
      exclude: settings of the product to leave out, as tables of values they match.
      settings: explicit settings, ``{"learner": …, "explorer": …, field: value}``.
      plugins: files or modules to import first (:func:`load_plugins`).
      learner_defaults: the values of the settings that give none of their own,
        ``"benchmark"`` or ``"paper"`` (:mod:`vdbejax.studies.learner_defaults`; ``None``:
        the paper's on the paper's tasks, the benchmark's rule on any other).
      claims: what the study expects, as data (:mod:`vdbejax.results.claim_spec`): checked
        against the settings before training, scored into ``claims.md`` and ``claims.csv``.
    """

    learners: Sequence[str] = ()
    explorers: Sequence[str] = ()
    axes: Mapping[str, Sequence[Any]] | None = None
    shared: Mapping[str, Any] | None = None
    exclude: Sequence[Mapping[str, Any]] = ()
    settings: Sequence[Mapping[str, Any]] = ()
    plugins: Sequence[str] = ()
    learner_defaults: str | None = None
    claims: Sequence[Mapping[str, Any]] = ()


#: The run options :func:`run_sweep` takes (a checkpoint is the folder's, the budget fixed).
SWEEP_RUN_FIELDS = ("chunk_episodes", "progress", "resume", "overwrite", "memory_budget_bytes",
                    "devices", "strategy", "threads", "mix_kinds", "evaluate_every",
                    "record_optimal")


def run_sweep(
    out_dir: str | os.PathLike,
    sweep: Sweep,
    *,
    task: str = "table_cleaning",
    seeds: int = 20,
    episodes: int = 1000,
    seed: int = 0,
    replicates: int = 1,
    max_steps: int | None = None,
    invalid_action: str = "noop",
    instances: str = "shared",
    figures: bool = True,
    run: RunOptions | None = None,
) -> GridResult:
    """Train a sweep on a task and write the result folder.

    Args:
      out_dir: output folder (created if needed).
      sweep: the settings to train (:class:`Sweep`).
      task: a task name (:func:`~vdbejax.studies.task_names.make_task`: the suite's,
        ``gym:<id>``, ``module:function`` or ``file.py:function``).
      seeds: agents per setting (per replicate).
      episodes: episodes per agent.
      seed: root seed.
      replicates: independent groups of ``seeds`` agents (:mod:`vdbejax.results.replicates`):
        ``summary.csv`` and the figures are the first's; with more than one,
        ``summary_pooled.csv`` and ``replicates.csv`` come beside them.
      max_steps: episode truncation length (default: the task's, :func:`make_task`).
      invalid_action: ``noop`` or ``fail``.
      instances: ``"shared"`` (every agent on the one task), or ``"per-agent"``: a task
        family (:data:`~vdbejax.envs.suite.FAMILY_NAMES`: ``testbed:N``, ``garnet:SxAxB``,
        ``variant:NxK``, …) gives every agent its own instance, drawn from the root seed
        and its seed index (:mod:`vdbejax.runs.task_family_run`). Either way a family's
        parameters are axes (``task.std``, ``task.instance``: the instance seed; those of
        ``variant:NxK`` only per agent).
      figures: write ``fig3.png`` and ``sensitivity.png``.
      run: how it runs (:class:`~vdbejax.runs.RunOptions`, default
        ``RunOptions(progress=True)``: a progress bar on stderr), the fields of
        :data:`SWEEP_RUN_FIELDS`: ``resume`` continues an interrupted run from
        ``out_dir/checkpoint.npz`` (written after every chunk, removed once the results are
        saved), or loads ``out_dir``'s finished result of this same run; ``overwrite``
        replaces a finished result (or an interrupted run's checkpoint) that ``out_dir``
        holds (without it that is refused); ``evaluate_every``: every this many episodes,
        the exact value of each agent's greedy policy (:mod:`vdbejax.runs.evaluation`):
        ``policy_values`` in ``returns.npz``, the policy columns of ``summary.csv`` and
        ``policy_gap.png``; ``record_optimal``: each episode's fraction of optimal actions
        (:mod:`vdbejax.runs.optimal_record`): ``optimal_actions`` in ``returns.npz``, the
        ``optimal_actions`` and ``reward_per_step`` columns of ``summary.csv``. The returns
        are the same whatever they are.

    Returns:
      the :class:`~vdbejax.results.grid_result.GridResult` (also saved in ``out_dir``).

    Raises:
      ValueError: any invalid input, before training starts.
    """
    if not isinstance(sweep, Sweep):
        raise ValueError(f"sweep={sweep!r} is invalid: must be a Sweep")
    run = study_run(run, "run_sweep", SWEEP_RUN_FIELDS)
    learners, explorers, axes = sweep.learners, sweep.explorers, sweep.axes
    load_plugins(list(sweep.plugins))
    if bool(learners) != bool(explorers):  # a product needs both: say which to give
        given, missing = ("learners", "explorers") if learners else ("explorers", "learners")
        names = list(learners or explorers)
        raise ValueError(f"{missing} is missing: {given}={names!r} make a product with"
                         f" {missing} (give --{missing} or {missing} = [...]); for explicit"
                         f" settings only (--setting), leave out {given}")
    check_choice("instances", instances, ("shared", "per-agent"))
    mdp = make_task(task, max_steps=max_steps, invalid_action=invalid_action)
    # Named as the caller knows them; prepare_grid checks the rest, creating nothing.
    seeds = check_int("seeds", seeds, 1, INT32_MAX)  # plain ints (NumPy ones welcome)
    episodes = check_int("episodes", episodes, 1, INT32_MAX)
    replicates = check_replicates(replicates, seeds)
    # Counted from the axes before any setting is made: a sweep too large for the machine
    # is refused, and a large one announced, before its settings take the memory.
    planned = (sweep_size(learners, explorers, axes) if learners or explorers or axes else 0) \
        + (len(sweep.settings) if isinstance(sweep.settings, Sequence) else 0)
    check_run_size(planned * seeds * replicates, episodes, num_settings=planned)
    if run.progress:
        announce_settings(planned, planned * seeds * replicates, episodes)
    grid_settings = sweep_settings(learners, explorers, axes, sweep.shared, sweep.exclude,
                                   sweep.settings)
    family = None  # a task family: an instance per agent, or task values (task.std, …)
    if instances == "per-agent" or any(s.task_values for s in grid_settings):
        family = make_suite_family(task, max_steps=max_steps, invalid_action=invalid_action,
                                   shared=instances != "per-agent")
    claims = [dict(claim) for claim in sweep.claims]
    if claims:  # every reference resolved and every metric recorded, before training
        check_claims(parse_claims(claims), grid_settings,
                     [name for name in ("record_optimal", "evaluate_every")
                      if getattr(run, name)])
    figures = check_bool("figures", figures)
    defaults = learner_defaults(task, int(mdp.max_steps), sweep.learner_defaults)
    if run.progress:  # the first line: the values no setting gave, and their rule
        sys.stderr.write(f"learner defaults: {defaults.text()}; a setting's own values take"
                         " precedence\n")
    prepared = prepare_grid(mdp if family is None else family, grid_settings,
                            num_seeds=seeds * replicates, num_episodes=episodes, seed=seed,
                            options=defaults.options, run=run)

    def annotate(result: GridResult) -> None:
        annotate_replicates(result.meta, replicates, seeds)
        # Files as absolute paths: the folder's sweep file (sweep_from_meta) runs anywhere.
        files = absolute_files({"task": task, "plugins": list(sweep.plugins)})
        result.meta.update(invalid_action=invalid_action, task=files["task"],
                           learner_defaults=defaults.describe(),
                           sweep={"learners": list(learners), "explorers": list(explorers),
                                  "axes": {k: list(v) for k, v in (axes or {}).items()},
                                  "shared": dict(sweep.shared or {}),
                                  "exclude": [dict(rule) for rule in sweep.exclude],
                                  "settings": [dict(entry) for entry in sweep.settings],
                                  "plugins": files["plugins"],
                                  "learner_defaults": defaults.rule, "claims": claims})
        if claims:
            result.meta["claims_digest"] = claims_digest(claims)

    # The reference line is the run's own best return (a family's: its instances' mean),
    # solved once by the run, not again here.
    def outputs(result: GridResult, stats: CurveStatistics | None) -> ReplicateSummaries:
        summaries = write_outputs(result, out_dir, result.meta["best_return"],
                                  figures=figures, statistics=stats)
        write_study_claims(result, out_dir, rows=summaries.pooled)
        return summaries

    result, _ = train_in_folder(
        out_dir, prepared, outputs,
        files=RUN_FILES, annotate=annotate, bands=figures and replicates == 1)
    return result
