"""Which exploration method wins where: ``vdbejax bench``, every method on every task.

Per task (:mod:`vdbejax.envs.suite`), two runs on the one run path, each in its own
result folder through :func:`~vdbejax.studies.train_in_folder` (checkpointed,
``--resume``): ``tune/<task>/`` runs every method's candidates
(:mod:`~vdbejax.studies.bench_methods`) on tuning seeds (root seed ``seed + 1``), and
``runs/<task>/`` runs the chosen candidate of each method on the reported seeds (root seed
``seed``). The scores (:mod:`vdbejax.results.regret`) and the report
(:mod:`~vdbejax.studies.bench_report`) come from the reported runs only. A method whose
per-episode cost on a task exceeds the cost limit (the rule of
:mod:`~vdbejax.studies.bench_methods`) is left out of that task, and the report says so.
"""
from __future__ import annotations

import dataclasses
import functools
import math
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from vdbejax.engine.agent_state import task_facts
from vdbejax.envs.solvers import best_return, uniform_random_return
from vdbejax.envs.tabular import TabularMDP
from vdbejax.methods.agents import Setting, make_agent
from vdbejax.results.folder_lock import check_output_paths, mark, output_folder, unmark
from vdbejax.results.grid_result import GridResult
from vdbejax.results.optimal_actions import optimal_action_summary
from vdbejax.results.policy import policy_summary
from vdbejax.results.regret import cumulative_regret, run_scores
from vdbejax.results.solving import episodes_to_converge, summarize_solving
from vdbejax.runs import RunOptions, prepare_grid
from vdbejax.runs.batching import check_run_size
from vdbejax.runs.estimate import StudyEstimate, announce, estimate_task
from vdbejax.runs.options import SPEED_FIELDS, study_run
from vdbejax.studies.bench_methods import (
    COST_LIMIT,
    QUICK_METHODS,
    BenchMethod,
    TaskScale,
    group_defaults,
    select_methods,
)
from vdbejax.studies.bench_report import bench_meta, output_files, write_report
from vdbejax.studies.folder import StudyOutputs, train_in_folder
from vdbejax.validation import (
    INT32_MAX,
    UINT32_MAX,
    check_bool,
    check_in_range,
    check_instance,
    check_int,
)

#: Agents per method and task in the reported run, and per candidate in tuning.
SEEDS, TUNE_SEEDS = 10, 3
#: Episodes per agent on every task (``--episodes``).
EPISODES = 300
#: ``--quick``: three small tasks, five methods, a few agents and episodes.
QUICK_TASKS = ("chain", "deepsea:6", "riverswim")
QUICK_SEEDS, QUICK_TUNE_SEEDS, QUICK_EPISODES = 3, 2, 40
#: The step limit of a task whose own is a safety cap (the gridworlds and the authors'
#: table have none as published): 13 to 15 times their shortest solutions; the suite's
#: 10,000 would let one exploring agent take 10,000 steps an episode.
CAPPED_HORIZON = 200
#: A run's moving average must reach this share of the way from random to the optimum.
SOLVED = 0.9
#: Folders of the two runs per task.
TUNE_FOLDER, RUNS_FOLDER = "tune", "runs"


@dataclasses.dataclass(frozen=True)
class BenchTask:
    """A task of the benchmark with its exact references."""

    name: str
    mdp: TabularMDP
    best: float
    baseline: float

    @property
    def folder(self) -> str:
        """The task's folder name (``deepsea:10`` → ``deepsea-10``)."""
        return self.name.replace(":", "-")

    def cost(self, method: BenchMethod) -> float:
        """The method's products per agent-episode on this task (the cost rule)."""
        return method.episode_cost(self.mdp.num_states, self.mdp.num_actions,
                                   int(self.mdp.max_steps), task_facts(self.mdp).terminates)

    @functools.cached_property
    def scale(self) -> TaskScale:
        reward = np.abs(np.asarray(self.mdp.reward, np.float64))
        mask = np.asarray(self.mdp.probability) > 0
        return TaskScale(r_max=float(reward[mask].max()) or 1.0,
                         horizon=int(self.mdp.max_steps))


@dataclasses.dataclass(frozen=True)
class MethodChoice:
    """How each task's methods are chosen: which run there, at which candidate.

    Attributes:
      tune: tune each method's knob on separate seeds (root seed ``seed + 1``) and keep
        the candidate of least mean cumulative regret; ``False`` runs each method's middle
        candidate (its published default) and reports a tuning budget of 0.
      tune_seeds: agents per candidate in the tuning run.
      cost_limit: the most products per agent-episode a ``dense_model`` method (PSRL) may
        cost on a task; it is left out of a task above it (``math.inf``: never).
    """

    tune: bool = True
    tune_seeds: int = TUNE_SEEDS
    cost_limit: float = COST_LIMIT


@dataclasses.dataclass
class BenchResult:
    """What :func:`run_bench` wrote: one row per (task, method) that ran, the aggregate
    rows, the meta data and the reported runs (``GridResult`` per task, its configs the
    methods that ran there)."""

    rows: list[dict[str, Any]]
    aggregate: list[dict[str, Any]]
    meta: dict[str, Any]
    runs: dict[str, GridResult]


def make_tasks(names: Sequence[str] | str | None) -> list[BenchTask]:
    """The benchmark's tasks (the default suite by default), built and solved exactly.

    Raises:
      ValueError: an unknown or repeated name, a task whose best return does not exceed
        the random policy's (no room for a normalised score).
    """
    from vdbejax.envs.suite import DEFAULT_SUITE, make_suite_task, task_info

    if names is None:
        names = DEFAULT_SUITE
    if isinstance(names, str):
        names = [n.strip() for n in names.split(",") if n.strip()]
    names = list(names)
    if not names or len(set(names)) != len(names):
        raise ValueError(f"tasks={','.join(names)!r} is invalid: must be distinct task names")
    tasks = []
    for name in names:
        mdp = make_suite_task(name, max_steps=(CAPPED_HORIZON if task_info(name).safety_cap
                                                else None))
        best, baseline = best_return(mdp), uniform_random_return(mdp)
        if not best > baseline + 1e-9:
            raise ValueError(f"tasks holds {name!r}, whose best return {best:g} does not exceed"
                             f" the random policy's {baseline:g}: nothing to explore for")
        tasks.append(BenchTask(name, mdp, best, baseline))
    return tasks


def _train(folder: Path, task: BenchTask, settings: list[Setting], *, seeds: int, episodes: int,
           seed: int, options: RunOptions, phase: str) -> GridResult:
    prepared = prepare_grid(task.mdp, settings, num_seeds=seeds, num_episodes=episodes,
                            seed=seed, run=options)
    result, _ = train_in_folder(folder, prepared, lambda result, stats: None, files=[],
                                statistics=False,
                                annotate=lambda result: result.meta.update(task=task.name,
                                                                           phase=phase))
    return result


def _mean_regret(result: GridResult, best: float) -> np.ndarray:
    """Mean final cumulative regret per config."""
    return cumulative_regret(result.returns, best)[..., -1].mean(-1)


#: The run options :func:`run_bench` takes (``record_optimal`` follows its group).
BENCH_RUN_FIELDS = ("progress", "resume", "overwrite", "evaluate_every", *SPEED_FIELDS)


def run_bench(
    out_dir: str | Path,
    *,
    tasks: Sequence[str] | str | None = None,
    methods: Sequence[str] | str | None = None,
    seeds: int = SEEDS,
    episodes: int = EPISODES,
    seed: int = 0,
    choice: MethodChoice = MethodChoice(),
    quick: bool = False,
    group: str = "suite",
    outputs: StudyOutputs = StudyOutputs(),
    run: RunOptions | None = None,
) -> BenchResult:
    """Run every method on every task and write the ranking (module docstring).

    Args:
      out_dir: the benchmark's folder (created).
      tasks: task names of :mod:`vdbejax.envs.suite` (default: the group's).
      methods: names of :data:`~vdbejax.studies.bench_methods.METHODS` (default: the
        group's).
      seeds: agents per method and task in the reported run.
      episodes: episodes per agent (both runs).
      seed: the reported run's root seed (tuning uses ``seed + 1``).
      choice: how each task's methods are chosen (:class:`MethodChoice`: ``tune``,
        ``tune_seeds``, ``cost_limit``).
      quick: the small benchmark of CI: :data:`QUICK_TASKS`, ``QUICK_METHODS``,
        ``QUICK_SEEDS``, ``QUICK_TUNE_SEEDS``, ``QUICK_EPISODES`` (override those arguments
        and ``choice.tune_seeds``).
      group: ``suite`` or ``bandits`` (:data:`~vdbejax.studies.bench_methods.GROUPS`: the
        default tasks and methods; ``bandits`` also records the fraction of optimal
        actions in the reported runs, % optimal action and reward per step in the ranking).
      outputs: what it writes besides its tables (:class:`~vdbejax.studies.StudyOutputs`):
        ``figures``; ``command``: the command line, recorded in ``meta.json`` and
        ``bench.md``; ``save_runs``: keep each task's result folders ``tune/<task>/`` and
        ``runs/<task>/``.
      run: how it runs (:class:`~vdbejax.runs.RunOptions`, default
        ``RunOptions(progress=True)``), the fields of :data:`BENCH_RUN_FIELDS`:
        ``progress``: status lines and the run's progress bar on stderr; ``resume``
        continues an interrupted benchmark (whole task folders are reused); ``overwrite``
        replaces the finished results its folders hold (without it, a folder holding one
        is refused in one line before it is trained again); ``evaluate_every``: in the
        reported runs, every this many episodes the exact value of each agent's greedy
        policy (:mod:`vdbejax.runs.evaluation`): its gap to the optimum and the share of
        optimal greedy policies in the ranking; the others change only the speed.

    Returns:
      the :class:`BenchResult` (also written to ``out_dir``).

    Raises:
      ValueError: any invalid input, before training.
    """
    run = study_run(run, "run_bench", BENCH_RUN_FIELDS)
    progress, evaluate_every = run.progress, run.evaluate_every
    check_instance("choice", choice, MethodChoice)
    check_instance("outputs", outputs, StudyOutputs)
    tune, tune_seeds, cost_limit = choice.tune, choice.tune_seeds, choice.cost_limit
    for name, flag in (("tune", tune), ("quick", quick)):
        check_bool(name, flag)
    tasks, methods = group_defaults(group, tasks, methods)
    if quick:
        tasks, methods = QUICK_TASKS, QUICK_METHODS
        seeds, tune_seeds, episodes = QUICK_SEEDS, QUICK_TUNE_SEEDS, QUICK_EPISODES
    seeds = check_int("seeds", seeds, 1, INT32_MAX)
    tune_seeds = check_int("tune_seeds", tune_seeds, 1, INT32_MAX)
    episodes = check_int("episodes", episodes, 1, INT32_MAX)
    if evaluate_every is not None:
        evaluate_every = check_int("evaluate_every", evaluate_every, 1, episodes)
    seed = check_int("seed", seed, 0, UINT32_MAX - 1)
    cost_limit = check_in_range("cost_limit", cost_limit, 0.0, math.inf, low_open=True)
    chosen_methods = select_methods(methods)
    knobs = run.replace(evaluate_every=None)  # the tuning runs'
    bench_tasks = make_tasks(tasks)
    ran = {t.name: [m for m in chosen_methods if t.cost(m) <= cost_limit] for t in bench_tasks}
    left_out = [{"task": t.name, "method": m.name, "cost": t.cost(m), "limit": cost_limit}
                for t in bench_tasks for m in chosen_methods if m not in ran[t.name]]
    for task in bench_tasks:
        if not ran[task.name]:
            raise ValueError(f"tasks holds {task.name!r}, where no method of methods runs:"
                             f" each costs more than cost_limit={cost_limit:g} products per"
                             " agent-episode (see the cost rule of vdbejax bench)")
    candidates = {}
    for task in bench_tasks:  # every setting checked before anything trains
        for method in ran[task.name]:
            candidates[task.name, method.name] = method.candidates(task.scale)
            for setting in candidates[task.name, method.name]:
                make_agent(setting)
    # The largest grid (a task's tuning pool or its reported run) must fit: refused before
    # the folder is made.
    pools = [sum(len(candidates[t.name, m.name]) for m in ran[t.name]) for t in bench_tasks]
    check_run_size(max(max(pools) * tune_seeds if tune else 0,
                       max(len(methods_of) for methods_of in ran.values()) * seeds), episodes)
    if progress:  # each task's tuning pool, then its reported run
        parts = []
        for task, pool_size in zip(bench_tasks, pools, strict=True):
            if tune:
                parts.append(estimate_task(task.mdp, pool_size, tune_seeds, episodes,
                                           statistics=False))
            parts.append(estimate_task(task.mdp, len(ran[task.name]), seeds, episodes,
                                       statistics=False))
        announce(StudyEstimate(tuple(parts)), "study")
    files = output_files([t.name for t in bench_tasks], outputs.figures,
                         evaluated=evaluate_every is not None)
    out, lock = output_folder(out_dir, own=[*files, TUNE_FOLDER, RUNS_FOLDER],
                              overwrite=run.overwrite)
    check_output_paths(out, files)
    from vdbejax.runs.provenance import version_info

    versions = version_info()  # the code that runs: read before training, not after
    started = time.perf_counter()
    with lock:
        runs: dict[str, GridResult] = {}
        chosen: dict[str, dict[str, Any]] = {}
        budget = {"agent_episodes": 0, "agent_steps": 0, "seconds": 0.0}
        timing: dict[str, dict[str, float]] = {}
        for i, task in enumerate(bench_tasks):
            pool = [s for m in ran[task.name] for s in candidates[task.name, m.name]]
            if progress:
                sys.stderr.write(f"[{i + 1}/{len(bench_tasks)}] {task.name}"
                                 f" ({task.mdp.num_states} states, best {task.best:g}):"
                                 f" tuning {len(pool)} candidates × {tune_seeds} agents\n")
            tuned_at = time.perf_counter()
            picks = _choose(out / TUNE_FOLDER / task.folder, task, ran[task.name], candidates,
                            tune=tune, seeds=tune_seeds, episodes=episodes, seed=seed + 1,
                            options=knobs, budget=budget)
            tuned_seconds = time.perf_counter() - tuned_at
            budget["seconds"] += tuned_seconds
            chosen[task.name] = {m: dataclasses.asdict(s) for m, s in picks.items()}
            if progress:
                sys.stderr.write(f"[{i + 1}/{len(bench_tasks)}] {task.name}: reported run,"
                                 f" {len(picks)} methods × {seeds} agents\n")
            run_at = time.perf_counter()
            runs[task.name] = _train(out / RUNS_FOLDER / task.folder, task, list(picks.values()),
                                     seeds=seeds, episodes=episodes, seed=seed,
                                     options=knobs.replace(evaluate_every=evaluate_every,
                                                           record_optimal=group == "bandits"),
                                     phase="report")
            timing[task.name] = {"tuning_seconds": tuned_seconds,
                                 "report_seconds": time.perf_counter() - run_at,
                                 "report_agent_steps": float(runs[task.name].lengths.sum())}
        # each agent's normalised score, once per task: the rows and the report share it
        scores = {t.name: run_scores(runs[t.name].returns, t.best, t.baseline)
                  for t in bench_tasks}
        rows = [row for task in bench_tasks
                for row in task_rows(task, ran[task.name], runs[task.name], scores[task.name])]
        meta = bench_meta(outputs.command, bench_tasks, chosen_methods, chosen, budget, timing,
                          time.perf_counter() - started, versions, seeds=seeds,
                          tune_seeds=tune_seeds, episodes=episodes, seed=seed, tune=tune,
                          quick=quick, cost_limit=cost_limit, evaluate_every=evaluate_every,
                          group=group)
        meta["left_out"] = left_out
        mark(out, "results")  # a folder killed while its report is replaced is recognised
        aggregate = write_report(out, bench_tasks, chosen_methods, runs, scores, rows, meta,
                                 ran={t: [m.name for m in ms] for t, ms in ran.items()},
                                 figures=outputs.figures)
        unmark(out)
        outputs.discard_runs([out / folder / task.folder for task in bench_tasks
                              for folder in (TUNE_FOLDER, RUNS_FOLDER)])
    return BenchResult(rows, aggregate, meta, runs)


def _choose(folder: Path, task: BenchTask, methods: list[BenchMethod],
            candidates: dict[tuple[str, str], list[Setting]], *, tune: bool, seeds: int,
            episodes: int, seed: int, options: RunOptions,
            budget: dict[str, Any]) -> dict[str, Setting]:
    """Each method's chosen candidate: least mean cumulative regret on the tuning seeds."""
    picks: dict[str, Setting] = {}
    if not tune:
        return {m.name: m.default_candidate(task.scale) for m in methods}
    pool = [s for m in methods for s in candidates[task.name, m.name]]
    result = _train(folder, task, pool, seeds=seeds, episodes=episodes, seed=seed,
                    options=options, phase="tune")
    budget["agent_episodes"] += int(result.returns.size)
    budget["agent_steps"] += int(result.lengths.sum())
    regret = _mean_regret(result, task.best)
    start = 0
    for m in methods:
        options_of = candidates[task.name, m.name]
        mine = regret[start:start + len(options_of)]
        mine = np.where(np.isfinite(mine), mine, np.inf)  # a diverged candidate never wins
        picks[m.name] = options_of[int(np.argmin(mine))]
        start += len(options_of)
    return picks


def task_rows(task: BenchTask, methods: list[BenchMethod], result: GridResult,
              scores: np.ndarray) -> list[dict[str, Any]]:
    """One row per method of a task's reported run (``scores``: its agents' normalised
    scores, ``[methods, seeds]``): score, realized regret, final return, solving (and,
    with policy evaluations, the greedy policies' gap and optimal share; with a record of
    optimal actions, the % optimal action and reward per step of the last tenth)."""
    from vdbejax.results.bootstrap import bootstrap_ci

    rows = []
    policy = policy_summary(result) if result.policy_values is not None else None
    last = max(1, result.num_episodes // 10)
    optimal = (optimal_action_summary(result, last) if result.optimal_actions is not None
               else None)
    regret = cumulative_regret(result.returns, task.best)[..., -1]
    solve = episodes_to_converge(result.returns, task.best, task.baseline, fraction=SOLVED,
                                 window=min(20, result.num_episodes))
    for c, method in enumerate(methods):
        setting = result.settings[c]
        score_low, score_high = bootstrap_ci(scores[c])
        regret_low, regret_high = bootstrap_ci(regret[c])
        solved = summarize_solving(solve.episodes[c], solve.solved[c])
        value = setting.values.get(method.tuned, math.nan) if method.tuned else math.nan
        rows.append({
            "task": task.name, "method": method.name, "title": method.title,
            "family": method.family, "tuned": method.tuned or "", "value": value,
            "score": float(scores[c].mean()), "score_low": score_low, "score_high": score_high,
            "regret": float(regret[c].mean()), "regret_low": regret_low,
            "regret_high": regret_high,
            "final_return": float(np.nanmean(result.returns[c, :, -last:])),
            "best_return": task.best, "random_return": task.baseline,
            "fraction_solved": solved.fraction, "median_episodes": solved.median,
            "median_text": solved.median_text(),
            "nonfinite_agents": int(result.nonfinite[c].sum()),
            **({} if policy is None else policy[c]),
            **({} if optimal is None else optimal[c]),
        })
    order = sorted(range(len(rows)), key=lambda r: -float(scores[r].mean()))
    for rank, r in enumerate(order, 1):
        rows[r]["rank"] = rank
    return rows


__all__ = ["EPISODES", "QUICK_EPISODES", "QUICK_SEEDS", "QUICK_TASKS", "QUICK_TUNE_SEEDS",
           "SEEDS", "TUNE_SEEDS", "BenchResult", "BenchTask", "MethodChoice", "make_tasks",
           "run_bench", "task_rows"]
