"""One call reproduces the paper: the full grid, Figure 3, the summary and the claims report."""
from __future__ import annotations

import csv
import dataclasses
import json
import os
import sys
import time
import zipfile
from pathlib import Path
from typing import Any

from vdbejax.envs.cruz2018 import STEP_CAP, make_authors_mdp
from vdbejax.envs.solvers import best_return, uniform_random_return
from vdbejax.envs.table_cleaning import make_mdp
from vdbejax.methods.agents import AgentOptions, Setting, owners, paper_settings
from vdbejax.paper.claims import paper_claims
from vdbejax.paper.report import cap_message, one_value_settings, render_report
from vdbejax.results import io
from vdbejax.results.claim_report import CLAIMS_FILE, CLAIMS_REPORT_FILE
from vdbejax.results.claim_scoring import recorded_metrics, score_claims
from vdbejax.results.claim_spec import check_claims, parse_claims
from vdbejax.results.folder_lock import FolderLock, check_output_paths, describe_os_error, unmark
from vdbejax.results.grid_result import GridResult
from vdbejax.results.manifest import write_manifest
from vdbejax.results.replicates import (
    REPLICATE_FILES,
    annotate_replicates,
    check_replicates,
    replicate_count,
)
from vdbejax.results.stats import CurveStatistics
from vdbejax.results.summary import SUMMARY_FILE, SummaryRow
from vdbejax.results.verdicts import ClaimResult
from vdbejax.runs import RunOptions, prepare_grid
from vdbejax.runs.options import SPEED_FIELDS, study_run
from vdbejax.studies import sweeps, train_in_folder
from vdbejax.studies.sweep_file import read_claims_file
from vdbejax.studies.sweeps import FIGURE_FILE, SENSITIVITY_FILE
from vdbejax.validation import INT32_MAX, check_bool, check_choice, check_int, check_writable_dir

REPORT_FILE = "report.md"
#: Figure 3 smoothed and cut as the authors plot it (the authors' reading only).
AUTHORS_FIGURE_FILE = "fig3_authors.png"


@dataclasses.dataclass
class Reproduction:
    """What :func:`reproduce` computed and where it wrote it."""

    result: GridResult
    summary: list[SummaryRow]
    claims: list[ClaimResult]
    best_return: float
    out_dir: Path
    elapsed_seconds: float


def write_outputs(
    result: GridResult, out_dir: str | os.PathLike, best: float, bands: bool = True,
    figures: bool = True, statistics: CurveStatistics | None = None,
) -> tuple[list[SummaryRow], list[ClaimResult]]:
    """Write ``summary.csv``, ``fig3.png``, ``sensitivity.png`` and ``report.md`` for a
    (saved) result of the paper's grid.

    Args:
      result: the grid.
      out_dir: output folder.
      best: the best possible return (reference lines, "near" in the claims).
      bands: Figure 3 with 95% bootstrap bands over agents.
      figures: draw the figures.
      statistics: the returns' statistics, if already computed (see
        :func:`vdbejax.studies.sweeps.write_outputs`).

    With replicates (:mod:`vdbejax.results.replicates`) the claims are scored on the pooled
    agents and on each replicate (:func:`~vdbejax.results.claim_scoring.score_claims` of
    :func:`~vdbejax.paper.claims.paper_claims`).

    Returns:
      the summary rows (:class:`~vdbejax.results.summary.SummaryRow`; replicate 0's) and
      the scored claims.
    """
    out = Path(out_dir)
    summaries = sweeps.write_outputs(result, out, best, bands=bands, figures=figures,
                                     statistics=statistics)
    if figures and result.meta.get("reading") == "authors":
        from vdbejax.results.plotting import figure3  # matplotlib only when plotting

        # Figure 3 as the first author's code draws it (np.convolve "full", from episode 20).
        io.save_figure(figure3(result, best_return=best, smoothing="authors"),
                       out / AUTHORS_FIGURE_FILE)
    several = replicate_count(result) > 1
    claims = score_claims(result, paper_claims(), summaries.pooled,
                          summaries.replicates if several else None, best).claims
    io.atomic_write_text(out / REPORT_FILE, render_report(claims, result.meta, best,
                                                          one_value_settings(result, best)))
    return summaries.replicates[0], claims


def is_paper_grid(result: GridResult) -> bool:
    """Whether a result is the paper's grid (its 46 settings under one of its readings),
    the only one its claims report applies to."""
    if result.meta.get("mdp") not in ("table_cleaning", "cruz2018"):
        return False
    grid = [(s.learner, s.explorer, s.param) for s in result.settings]
    return grid == [(s.learner, s.explorer, s.param) for s in paper_settings()]


#: The two readings of the paper: its text (``docs/task.md``) and the first author's code.
READINGS = ("textbook", "authors")
#: The authors' agent details (docs/task.md, "The authors' code"), per field; each applies
#: to the learners and explorers that have the field.
AUTHORS_DETAILS = {
    "failure_update": "overwrite",
    "goal_update": "skip",
    "q_init_distribution": "uniform",
    "next_action": "redrawn",
    "epsilon_init": 0.1,
    "update_on_terminal": False,
    "softmax_numerics": "float64",
}


def reading_settings(reading: str, details: dict | None = None) -> list[Setting]:
    """The paper's 46 settings under a reading, with agent ``details`` where the learner or
    explorer has the field: by default none for the textbook, :data:`AUTHORS_DETAILS` for
    the authors (greedy ties to the first index come as the grid-wide ``tie_break``)."""
    check_choice("reading", reading, READINGS)
    if details is None:
        details = AUTHORS_DETAILS if reading == "authors" else {}
    if not isinstance(details, dict):
        raise ValueError(f"details={details!r} is invalid: must be a dict {{name: value}}")
    for name in details:  # a name no agent has would be dropped without a word
        if not any(owners(name, s.learner, s.explorer) for s in paper_settings()):
            raise ValueError(f"details has {name!r}: no learner or explorer of the paper's grid"
                             f" has it (the authors' details are {', '.join(AUTHORS_DETAILS)})")
    if not details:
        return paper_settings()
    return [Setting(s.learner, s.explorer, s.param,
                    {k: v for k, v in details.items() if owners(k, s.learner, s.explorer)})
            for s in paper_settings()]


def reading_options(reading: str, tie_break: str | None = None,
                    **values: Any) -> AgentOptions:
    """The agent options of ``reading``: greedy ties broken at random for the textbook
    reading, to the first index for the authors' (unless ``tie_break`` is given);
    ``values``: other fields of :class:`~vdbejax.methods.AgentOptions`."""
    if tie_break is None:
        tie_break = "first" if reading == "authors" else "random"
    return AgentOptions(tie_break=tie_break, **values)


#: The run options :func:`reproduce` takes.
REPRODUCE_RUN_FIELDS = ("chunk_episodes", "progress", "resume", "overwrite", *SPEED_FIELDS)


def reproduce(
    out_dir: str | os.PathLike,
    *,
    reading: str = "textbook",
    details: dict | None = None,
    seeds: int = 20,
    episodes: int = 1000,
    seed: int = 0,
    replicates: int = 5,
    max_steps: int | None = None,
    invalid_action: str = "noop",
    options: AgentOptions | None = None,
    figures: bool = True,
    run: RunOptions | None = None,
) -> Reproduction:
    """Run the paper's 46 settings × ``replicates`` × ``seeds`` agents × ``episodes`` and
    write all outputs.

    Writes into ``out_dir``: ``returns.npz``, ``configs.csv``, ``meta.json``,
    ``summary.csv``, ``fig3.png`` (with bootstrap bands), ``sensitivity.png``,
    ``report.md`` (and, for the authors' reading, ``fig3_authors.png``: Figure 3 smoothed
    as their code plots it); with more than one replicate, ``summary_pooled.csv`` and
    ``replicates.csv`` (:mod:`vdbejax.results.replicates`). A checkpoint
    (``checkpoint.npz`` and its episode log ``checkpoint.npz.episodes``) is written after
    every chunk and removed once the results are saved.

    Args:
      out_dir: output folder (created if needed).
      reading: ``"textbook"`` (the paper's text, ``docs/task.md``; the default) or
        ``"authors"`` (the first author's code: the ``cruz2018`` task and the agent
        details of :data:`AUTHORS_DETAILS`, greedy ties to the first index).
      details: the agent details to apply (names and values as in
        :data:`AUTHORS_DETAILS`; default: none for the textbook, all for the authors) —
        :mod:`vdbejax.paper.ablation` switches them one at a time.
      seeds: agents per setting and replicate (the paper's 20).
      episodes: episodes per agent.
      seed: root random seed.
      replicates: independent groups of ``seeds`` agents (default 5): ``summary.csv`` and
        the figures are the first's, the claims are scored on the pooled agents and on each
        replicate, and the report's headline verdict says how stable each is
        (:mod:`vdbejax.paper.claims`). ``replicates=1`` writes the files of a single run.
      max_steps: episode truncation length (textbook default 100; authors: the task's
        safety cap, 10,000).
      invalid_action: ``"noop"`` or ``"fail"`` (the textbook reading's option).
      options: the values shared by every agent (:class:`~vdbejax.methods.AgentOptions`:
        ``tie_break`` ``"random"`` or ``"first"``, ``q_init`` the initial Q value (the
        spec's option), ``alpha`` the learning rate, default the paper's, …); default the
        reading's, :func:`reading_options`.
      figures: draw ``fig3.png`` and ``sensitivity.png`` (``False``: the numbers only;
        ``vdbejax plot`` draws them later from the saved results).
      run: how it runs (:class:`~vdbejax.runs.RunOptions`, default
        ``RunOptions(progress=True)``), the fields of :data:`REPRODUCE_RUN_FIELDS`:
        ``chunk_episodes``: episodes per jitted chunk (checkpoint granularity; None: the
        plan's, :func:`~vdbejax.runs.plan.default_chunk_episodes`: 100 for the paper
        grid); ``progress``: a progress bar and a closing status line on stderr;
        ``resume`` continues an interrupted run from ``out_dir/checkpoint.npz``
        (bit-identically), or loads ``out_dir``'s finished result of this same run;
        ``overwrite`` replaces a finished result (or an interrupted run's checkpoint) that
        ``out_dir`` holds (without it that is refused,
        :func:`~vdbejax.studies.train_in_folder`); the others change only the speed,
        never the results.

    Returns:
      :class:`Reproduction`: the grid, summary rows, scored claims, the task's best
      return, the output folder and the elapsed seconds.

    Raises:
      ValueError: an invalid option (message names it and what is allowed), or an
        output folder that cannot be written.
    """
    run = study_run(run, "reproduce", REPRODUCE_RUN_FIELDS)
    check_choice("reading", reading, READINGS)
    if reading == "authors":
        if invalid_action != "noop":
            raise ValueError(f"invalid_action={invalid_action!r} is invalid with reading="
                             "'authors': the published table decides every action's effect")
        mdp = make_authors_mdp(STEP_CAP if max_steps is None else max_steps)
        capped = True  # the published task has no step limit: any max_steps is a cap
    else:
        mdp = make_mdp(max_steps=100 if max_steps is None else max_steps,
                       invalid_action=invalid_action)
        capped = False
    if options is None:
        options = reading_options(reading)
    elif not isinstance(options, AgentOptions):
        raise ValueError(f"options={options!r} is invalid: must be an AgentOptions")
    settings = reading_settings(reading, details)
    # Named as the caller knows them; prepare_grid checks the rest, creating nothing.
    # Plain ints from here on (a NumPy integer is welcome, and meta.json is JSON).
    seeds = check_int("seeds", seeds, 1, INT32_MAX)
    episodes = check_int("episodes", episodes, 1, INT32_MAX)
    replicates = check_replicates(replicates, seeds)
    figures = check_bool("figures", figures)
    prepared = prepare_grid(mdp, settings, num_seeds=seeds * replicates, num_episodes=episodes,
                            seed=seed, options=options, run=run)
    best = best_return(mdp)

    def annotate(result: GridResult) -> None:
        annotate_replicates(result.meta, replicates, seeds)
        if result.meta.get("nonfinite_message"):
            print(f"warning: {result.meta['nonfinite_message']}", file=sys.stderr)
        if capped and result.meta["truncated_episodes"]:
            print(f"warning: {cap_message(result.meta)}", file=sys.stderr)
        result.meta["invalid_action"] = invalid_action
        result.meta["reading"] = reading
        result.meta["details"] = dict(AUTHORS_DETAILS if details is None and reading == "authors"
                                      else details or {})
        result.meta["best_return"] = best  # lets `vdbejax plot` redraw without the MDP
        # The authors' task has no step limit: its max_steps is a safety cap, and episodes cut
        # there are episodes the published code would never have finished (summary, report).
        result.meta["step_cap"] = capped
        result.meta["config_labels"] = [f"{s.learner}/{s.explorer}/{s.param:g}"
                                        for s in result.settings]

    started = time.perf_counter()
    result, (summary, claims) = train_in_folder(
        out_dir, prepared,
        lambda result, stats: write_outputs(result, out_dir, best, figures=figures,
                                            statistics=stats),
        files=[*sweeps.RUN_FILES, REPORT_FILE, AUTHORS_FIGURE_FILE], annotate=annotate,
        bands=figures and replicates == 1)
    elapsed = time.perf_counter() - started
    out = Path(out_dir)
    if run.progress:
        agents = (f"{replicates} replicates × {seeds} agents" if replicates > 1
                  else f"{seeds} agents")
        print(f"{reading} reading: {len(result.settings)} settings × {agents} × {episodes}"
              " episodes: "
              f"training {result.meta['elapsed_seconds']:.1f} s, total {elapsed:.1f} s "
              f"→ {out}", file=sys.stderr)
    return Reproduction(result, summary, claims, best, out, elapsed)


def saved_references(result: GridResult) -> float:
    """The best possible return of a saved result's task, with ``meta["best_return"]`` and
    ``meta["random_return"]`` (the uniformly random policy's expected return: the
    convergence episode's zero) filled in where an older ``meta.json`` lacks them.

    Read from ``meta.json`` (written by :func:`~vdbejax.runs.run_grid`); older results
    without them are recomputed with the exact solver from their task (``meta["task"]`` of
    a sweep, else ``meta["mdp"]``) and options.

    Args:
      result: a result loaded with :meth:`GridResult.load`.

    Returns:
      the best return.

    Raises:
      ValueError: neither is possible (a task that cannot be built again).
    """
    meta = result.meta
    if "best_return" not in meta or "random_return" not in meta:
        from vdbejax.studies.task_names import make_task

        task = meta.get("task") or meta.get("mdp")
        try:
            mdp = make_task(str(task), max_steps=meta.get("max_steps"),
                            invalid_action=meta.get("invalid_action", "noop"))
        except ValueError as error:
            raise ValueError(f"meta.json has no best_return and random_return, and its task"
                             f" cannot be built again ({error}): cannot draw the reference"
                             " line, measure convergence or score the claims") from None
        meta.setdefault("best_return", best_return(mdp))
        meta["random_return"] = uniform_random_return(mdp)
    return float(meta["best_return"])


def replot(
    results_dir: str | os.PathLike, out_dir: str | os.PathLike | None = None, bands: bool = True,
    claims: str | os.PathLike | None = None,
) -> list[Path]:
    """Redraw Figure 3, the sensitivity plot and the summary from saved results (and
    ``optimal_actions.png`` for a run that recorded optimal actions), and the claims
    report for the paper's grid (:func:`is_paper_grid`; other grids get none).

    Nothing is retrained: only ``returns.npz``, ``configs.csv`` and ``meta.json`` are read.

    Args:
      results_dir: a folder written by :func:`reproduce`, ``vdbejax run`` or
        :meth:`GridResult.save`.
      out_dir: where to write (default: ``results_dir``).
      bands: 95% bootstrap bands on Figure 3 (the default, as ``reproduce`` and ``vdbejax
        run`` draw it: the same figure as the run wrote).
      claims: a file of claims (:func:`~vdbejax.studies.sweep_file.read_claims_file`) to
        score into ``claims.md`` and ``claims.csv`` (default: the claims the run stated
        before training, if any: :func:`~vdbejax.studies.sweeps.write_study_claims`).

    Returns:
      the files written.

    Raises:
      ValueError: missing or unreadable result files, or an unwritable output folder.
    """
    try:
        result = GridResult.load(results_dir)
    except (OSError, KeyError, zipfile.BadZipFile, json.JSONDecodeError, csv.Error) as error:
        raise ValueError(f"cannot read results in {str(results_dir)!r}: {error}") from None
    stated = None if claims is None else read_claims_file(claims)
    if stated is not None:  # every reference checked before anything is written
        check_claims(parse_claims(stated), result.settings, recorded_metrics(result))
    out = check_writable_dir("out", results_dir if out_dir is None else out_dir)
    check_output_paths(out, [FIGURE_FILE, SENSITIVITY_FILE, SUMMARY_FILE, REPORT_FILE,
                             sweeps.OPTIMAL_FIGURE_FILE, *REPLICATE_FILES, CLAIMS_REPORT_FILE,
                             CLAIMS_FILE])
    written = [out / name for name in (FIGURE_FILE, SENSITIVITY_FILE, SUMMARY_FILE)]
    if result.optimal_actions is not None:
        written.append(out / sweeps.OPTIMAL_FIGURE_FILE)
    if replicate_count(result) > 1:
        written += [out / name for name in REPLICATE_FILES]
    paper = is_paper_grid(result)
    if paper:
        written.append(out / REPORT_FILE)
    with FolderLock(out):
        try:
            best = saved_references(result)
            if paper:
                write_outputs(result, out, best, bands=bands)
            else:
                sweeps.write_outputs(result, out, best, bands=bands)
            written += sweeps.write_study_claims(result, out, stated)
        except OSError as error:
            raise ValueError(f"cannot write the outputs in {str(out)!r}:"
                             f" {describe_os_error(error)}") from None
        if Path(out).resolve() == Path(results_dir).resolve():
            # Summary, figures and report now belong to the saved results.
            write_manifest(out, result.meta, [p.name for p in written], keep=True)
            unmark(out)
    return written
