"""How each exploration method's cost grows with the task: ``vdbejax scale``.

:func:`run_scaling` runs every method of :data:`METHODS` with both learners on a family of
generated table-cleaning variants of growing size (``variant:NxK``,
:func:`vdbejax.studies.sweeps.make_task`), each agent until it has solved the variant or its budget
is spent (:func:`~vdbejax.run_grid` with the stop policy :class:`~vdbejax.runs.UntilSolved`,
as :func:`run_until_solved`: up to its stop, an agent's returns equal bit for bit those of a
fixed budget), and writes ``scaling.csv``, ``scaling.md``, ``scaling.png`` (median episodes
to solve and fraction solved against reachable states), ``meta.json`` and each variant's
result folder ``runs/NxK/`` (the curves, written through the pipeline of every training
command, :mod:`vdbejax.studies`: checkpointed, so ``--resume`` continues a study).

This module is the study's runner. Its other parts live apart, and every name of theirs
below is importable from here too:

* :mod:`vdbejax.studies.scaling_study` — the study's definition: :class:`Method`, :data:`METHODS`,
  :data:`LEARNERS`, :data:`SIZES`, the study's size :class:`ScalingSize` and :data:`QUICK`,
  the budgets (:func:`variant_budget`, :func:`auto_chunk`) and :func:`best_parameters`.
* :mod:`vdbejax.studies.scaling_adaptive` — :func:`run_until_solved` and :class:`AdaptiveRun`.
* :mod:`vdbejax.studies.scaling_report` — the result folder's files and columns, ``scaling.md``
  (:func:`scaling_markdown`), ``scaling.png`` (:func:`scaling_figure`),
  :func:`write_reports` and :func:`load_scaling` (a saved folder redraws without
  training). It imports nothing of the runner: the data flow one way, runner → results →
  report.
"""
from __future__ import annotations

import dataclasses
import math
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from vdbejax.methods.agents import Setting, make_agent, parameter_name
from vdbejax.results import io
from vdbejax.results.folder_lock import mark, output_folder, unmark
from vdbejax.results.solving import convergence_threshold, summarize_solving
from vdbejax.runs import RunOptions, UntilSolved
from vdbejax.runs.batching import check_run_size
from vdbejax.runs.estimate import StudyEstimate, announce, estimate_task
from vdbejax.runs.options import SPEED_FIELDS, study_run
from vdbejax.studies.folder import StudyOutputs
from vdbejax.studies.scaling_adaptive import (
    AdaptiveRun,
    run_until_solved,
    train_until_solved,
)
from vdbejax.studies.scaling_report import (
    CSV_FILE,
    META_FILE,
    ROW_COLUMNS,
    RUNS_FOLDER,
    growth_exponents,
    load_scaling,
    method_label,
    row_setting,
    scaling_figure,
    scaling_markdown,
    write_reports,
)
from vdbejax.studies.scaling_report import FIGURE_FILE as FIGURE_FILE
from vdbejax.studies.scaling_report import MARKDOWN_FILE as MARKDOWN_FILE
from vdbejax.studies.scaling_report import VARIANT_COLUMNS as VARIANT_COLUMNS
from vdbejax.studies.scaling_report import param_text as param_text
from vdbejax.studies.scaling_study import EPISODES as EPISODES
from vdbejax.studies.scaling_study import EPISODES_PER_STATE as EPISODES_PER_STATE
from vdbejax.studies.scaling_study import (
    LEARNERS,
    METHODS,
    QUICK,
    SIZES,
    Method,
    ScalingSize,
    auto_chunk,
    best_parameters,
    parse_sizes,
    select_methods,
    study_settings,
    variant_budget,
)
from vdbejax.studies.scaling_study import PAPER_METHODS as PAPER_METHODS
from vdbejax.studies.scaling_study import SEEDS as SEEDS
from vdbejax.validation import (
    INT32_MAX,
    UINT32_MAX,
    check_bool,
    check_in_range,
    check_instance,
    check_int,
)


@dataclasses.dataclass
class ScalingResult:
    """What :func:`run_scaling` wrote: one row per variant × setting and one per variant."""

    rows: list[dict[str, Any]]
    variants: list[dict[str, Any]]
    meta: dict[str, Any]
    runs: dict[str, AdaptiveRun]


#: The run options :func:`run_scaling` takes (it sets the stop itself).
SCALING_RUN_FIELDS = ("chunk_episodes", "progress", "resume", "overwrite", *SPEED_FIELDS)


def run_scaling(
    out_dir: str | Path,
    *,
    size: ScalingSize = ScalingSize(),
    solve: UntilSolved = UntilSolved(),
    seed: int = 0,
    learners: Sequence[str] = LEARNERS,
    methods: Sequence[str] | None = None,
    max_steps: int | None = None,
    drop_unsolved: bool = False,
    outputs: StudyOutputs = StudyOutputs(),
    run: RunOptions | None = None,
) -> ScalingResult:
    """Episodes to solve of every method on growing table-cleaning variants.

    Variants run smallest (reachable states) first, each with every remaining setting in one
    :func:`run_until_solved` batch. With ``drop_unsolved`` a setting none of whose agents
    solved a variant is not run on the larger ones (its rows read ``dropped``): a shortcut
    that assumes a method failing on a task fails on larger ones within the same budget —
    not always so, hence off by default.

    Args:
      out_dir: output folder (created).
      size: the variants, agents per setting and episode budgets (:class:`ScalingSize`;
        :data:`QUICK` is ``--quick``'s).
      solve: the solve criterion (:class:`~vdbejax.runs.UntilSolved` without ``best`` and
        ``baseline``, which the study computes per variant): the ``window``-episode moving
        average of the normalised returns reaching ``fraction``
        (:mod:`vdbejax.results.solving`); ``max_seconds``: a wall-clock budget per variant
        (None: none).
      seed: root seed.
      learners: learner names.
      methods: explorer names of :data:`METHODS` (default all).
      max_steps: episode truncation (default 100, :func:`vdbejax.studies.sweeps.make_task`).
      drop_unsolved: skip settings on larger variants once none of their agents solved
        (off by default: SARSA + VDBE fails 3×1 and solves 4×1 within the same budget).
      outputs: what it writes besides ``scaling.csv``, ``scaling.md`` and ``meta.json``
        (:class:`~vdbejax.studies.StudyOutputs`): ``figures``: ``scaling.png``;
        ``command``: the command line, recorded in ``scaling.md`` and ``meta.json``;
        ``save_runs``: keep each variant's result folder ``runs/NxK/`` (its curves:
        ``returns.npz`` with every agent's returns, NaN past its stop, and
        ``episodes_run``; ``configs.csv``; ``meta.json``).
      run: how it runs (:class:`~vdbejax.runs.RunOptions`, default
        ``RunOptions(progress=True)``; the study sets the stop), the fields of
        :data:`SCALING_RUN_FIELDS`: ``chunk_episodes``: episodes between stop checks
        (default :func:`auto_chunk` of the budget: a solved agent runs at most 1 % of the
        budget past its solve episode); ``progress``: a status line per variant on stderr;
        ``resume`` continues an interrupted study: variants whose result folder is whole
        are loaded, the interrupted one continues from its checkpoint
        (``runs/NxK/checkpoint.npz``), the others run; ``overwrite`` replaces the finished
        results its folders hold (without it, a folder holding one is refused in one line
        before it is trained again); the others change only the speed.

    Returns:
      the :class:`ScalingResult` (also written to ``out_dir``).

    Raises:
      ValueError: any invalid input, before training.
    """
    from vdbejax.envs.solvers import (
        best_return,
        start_states,
        steps_to_goal,
        uniform_random_return,
    )
    from vdbejax.runs.provenance import version_info
    from vdbejax.studies.sweeps import make_task

    knobs = study_run(run, "run_scaling", SCALING_RUN_FIELDS)
    progress, chunk_episodes = knobs.progress, knobs.chunk_episodes
    for name, value, kind in (("size", size, ScalingSize), ("solve", solve, UntilSolved),
                              ("outputs", outputs, StudyOutputs)):
        check_instance(name, value, kind)
    if solve.best is not None:
        raise ValueError(f"solve.best={solve.best!r} is invalid: run_scaling computes each"
                         " variant's best and random returns (leave best and baseline out)")
    check_bool("drop_unsolved", drop_unsolved)
    parsed = parse_sizes(size.sizes)
    seeds = check_int("seeds", size.seeds, 1, INT32_MAX)
    episodes = check_int("episodes", size.episodes, 1, INT32_MAX)
    episodes_per_state = size.episodes_per_state
    if episodes_per_state is not None:
        episodes_per_state = check_in_range("episodes_per_state", episodes_per_state, 0.0,
                                            1e6, low_open=True)
    seed = check_int("seed", seed, 0, UINT32_MAX)
    if solve.window > episodes:  # every agent would be censored without a word
        raise ValueError(f"window={solve.window} is invalid with episodes={episodes}: the"
                         " moving average needs that many episodes before any agent can solve")
    if max_steps is not None:
        max_steps = check_int("max_steps", max_steps, 1, INT32_MAX)
    if isinstance(learners, str) or not learners:
        raise ValueError(f"learners={learners!r} is invalid: must be a non-empty list of names")
    chosen = select_methods(methods)
    settings = study_settings(chosen, learners)
    for setting in settings:  # unknown learners: one line before anything runs
        make_agent(setting)
    tasks = []
    for sections, goblets in parsed:  # every task built and solved before any folder or run
        variant = f"{sections}x{goblets}"
        mdp = make_task(f"variant:{variant}", max_steps=max_steps)
        best, baseline = best_return(mdp), uniform_random_return(mdp)
        UntilSolved(best=best, baseline=baseline)  # one line before training: best > baseline
        shortest = int(steps_to_goal(mdp)[start_states(mdp)].max())
        tasks.append((variant, mdp, best, baseline, shortest))
    tasks.sort(key=lambda task: task[1].num_states)
    # The largest variant's results must fit: refused here, before the folder is made.
    check_run_size(len(settings) * seeds, max(variant_budget(
        task[1].num_states, episodes, episodes_per_state) for task in tasks))
    if progress:  # settings none solves drop out: only the smallest variant runs them all
        announce(StudyEstimate(tuple(
            estimate_task(task[1], len(settings), seeds, budget, statistics=False,
                          fewest_episodes=solve.fewest_episodes(budget) if i == 0 else 0)
            for i, task in enumerate(tasks)
            for budget in [variant_budget(task[1].num_states, episodes, episodes_per_state)])),
            "study")
    out, lock = output_folder(out_dir, own=[CSV_FILE, MARKDOWN_FILE, FIGURE_FILE, META_FILE,
                                            RUNS_FOLDER], overwrite=knobs.overwrite)
    with lock:  # the study's folder, held to its last file

        versions = version_info()  # the code that runs: read before training, not after
        rows: list[dict[str, Any]] = []
        variants: list[dict[str, Any]] = []
        runs: dict[str, AdaptiveRun] = {}
        remaining = list(settings)
        order = {s: i for i, s in enumerate(settings)}
        dropped_on: dict[Setting, str] = {}
        started = time.perf_counter()
        for variant, mdp, best, baseline, shortest in tasks:
            budget = variant_budget(mdp.num_states, episodes, episodes_per_state)
            chunk = auto_chunk(budget) if chunk_episodes is None else chunk_episodes
            base = {"size": variant, "states": int(mdp.num_states), "actions": int(mdp.num_actions),
                    "best_return": float(best), "random_return": float(baseline),
                    "threshold": convergence_threshold(float(best), float(baseline),
                                                      solve.fraction)}
            for setting in settings:
                if setting in dropped_on:
                    rows.append(dict(base, **_setting_columns(setting, order[setting]), status=(
                        f"dropped: none solved {dropped_on[setting]}"), **_empty_row()))
            if not remaining:
                variants.append(dict(base, shortest_solution=shortest, settings_run=0, agents=0,
                                     budget_episodes=budget, chunk_episodes=chunk,
                                     episodes_reached=0, stopped="-", agent_episodes=0,
                                     fixed_budget_agent_episodes=0, agent_steps=0,
                                     training_seconds=0.0, compile_seconds=0.0,
                                     steps_per_second=math.nan))
                continue
            if progress:
                sys.stderr.write(f"{variant} ({mdp.num_states} states): {len(remaining)} settings ×"
                                 f" {seeds} agents, up to {budget} episodes\n")
            trained = train_until_solved(
                out / RUNS_FOLDER / variant, mdp, remaining, seeds=seeds, budget=budget,
                stop=dataclasses.replace(solve, best=best, baseline=baseline),
                seed=seed, options=knobs.replace(chunk_episodes=chunk),
                task=f"variant:{variant}")
            runs[variant] = trained
            if progress:
                sys.stderr.write(
                    f"{variant} ({mdp.num_states} states): {int(trained.solve.solved.sum())}/"
                    f"{trained.solve.solved.size} agents solved, {trained.elapsed_seconds:.1f} s"
                    f" ({trained.steps_per_second / 1e6:.2f} M steps/s)\n")
            reached = int(trained.episodes_run.max())
            for c, setting in enumerate(trained.settings):
                summary = summarize_solving(trained.solve.episodes[c], trained.solve.solved[c])
                rows.append(dict(base, **_setting_columns(setting, order[setting]), status="run",
                                 agents=summary.agents, solved=summary.solved,
                                 fraction_solved=summary.fraction,
                                 fraction_low=summary.fraction_low,
                                 fraction_high=summary.fraction_high,
                                 median_episodes=summary.median, median_low=summary.median_low,
                                 median_high=summary.median_high, budget=summary.budget,
                                 median_text=summary.median_text(),
                                 agent_episodes=int(trained.episodes_run[c].sum()),
                                 nonfinite_agents=int(trained.nonfinite[c].sum())))
                if drop_unsolved and summary.solved == 0:
                    dropped_on[setting] = f"on {variant} in {summary.budget} episodes"
            remaining = [s for s in remaining if s not in dropped_on]
            variants.append(dict(
                base, shortest_solution=shortest, settings_run=len(trained.settings),
                agents=int(trained.episodes_run.size), budget_episodes=budget, chunk_episodes=chunk,
                episodes_reached=reached, stopped=trained.stopped,
                agent_episodes=int(trained.episodes_run.sum()),
                fixed_budget_agent_episodes=int(trained.episodes_run.size) * budget,
                agent_steps=trained.agent_steps, training_seconds=trained.elapsed_seconds,
                compile_seconds=trained.compile_seconds, steps_per_second=trained.steps_per_second))
        rank = {task[0]: i for i, task in enumerate(tasks)}
        rows.sort(key=lambda r: (rank[r["size"]], order[row_setting(r)]))
        options = {"sizes": [t[0] for t in tasks], "seeds": seeds, "episodes": episodes,
                   "episodes_per_state": episodes_per_state, "seconds": solve.max_seconds,
                   "seed": seed, "learners": list(learners),
                   "methods": [dataclasses.asdict(m) for m in chosen],
                   "fraction": solve.fraction, "window": solve.window,
                   "chunk_episodes": chunk_episodes, "max_steps": max_steps,
                   "drop_unsolved": drop_unsolved, "quick": size == QUICK}
        meta = {"command": outputs.command, "options": options,
                "elapsed_seconds": time.perf_counter() - started,
                "settings": [[s.learner, s.explorer, s.param, dict(s.hyperparameters)]
                             for s in settings],
                "parameter_names": {m.explorer: parameter_name(m.explorer) for m in chosen},
                "variants": variants, **versions}
        import jax

        meta.update(jax_version=jax.__version__, backend=jax.default_backend())
        # Marked while the study's files are replaced: a folder killed between scaling.csv and
        # meta.json is recognised (load_scaling refuses it), never read as one study.
        mark(out, "results")
        io.write_csv(out / CSV_FILE, rows, ROW_COLUMNS)
        io.save_json(out / META_FILE, meta)
        write_reports(out, rows, variants, meta, figure=outputs.figures)
        unmark(out)
        outputs.discard_runs([out / RUNS_FOLDER / variant for variant in runs])
        return ScalingResult(rows, variants, meta, runs)


def _setting_columns(setting: Setting, config: int) -> dict[str, Any]:
    return {"config": config, "learner": setting.learner, "explorer": setting.explorer,
            "param": setting.param if setting.param is not None else "",
            "method": method_label(setting), "_setting": setting}


def _empty_row() -> dict[str, Any]:
    return {"agents": 0, "solved": 0, "fraction_solved": math.nan, "fraction_low": math.nan,
            "fraction_high": math.nan, "median_episodes": math.nan, "median_low": math.nan,
            "median_high": math.nan, "budget": 0, "median_text": "-", "agent_episodes": 0,
            "nonfinite_agents": 0}


__all__ = [
    "LEARNERS",
    "METHODS",
    "QUICK",
    "SIZES",
    "AdaptiveRun",
    "Method",
    "ScalingResult",
    "ScalingSize",
    "auto_chunk",
    "best_parameters",
    "growth_exponents",
    "load_scaling",
    "parse_sizes",
    "run_scaling",
    "run_until_solved",
    "scaling_figure",
    "scaling_markdown",
    "select_methods",
    "study_settings",
    "variant_budget",
    "write_reports",
]
