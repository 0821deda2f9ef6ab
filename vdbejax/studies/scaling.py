"""How each exploration method's cost grows with the task: the ``vdbejax scale`` study.

The study's definition: :data:`METHODS` (each a :class:`Method`: an explorer at one
parameter value, with where the value comes from), :data:`LEARNERS`, the family of
variants :data:`SIZES` (``NxK``: :func:`parse_sizes`), the study's size
(:class:`ScalingSize`; ``--quick``'s is :data:`QUICK`) and the episode budget per variant
(:func:`variant_budget`, :func:`auto_chunk`).

Its runner: :func:`run_scaling` runs every method of :data:`METHODS` with both learners on
a family of generated table-cleaning variants of growing size (``variant:NxK``,
:func:`vdbejax.studies.task_names.make_task`), each agent until it has solved the variant or its
budget is spent (:func:`~vdbejax.run_grid` with the stop policy
:class:`~vdbejax.runs.UntilSolved`, as
:func:`~vdbejax.studies.scaling_adaptive.run_until_solved`: up to its stop, an agent's
returns equal bit for bit those of a fixed budget), and writes ``scaling.csv``,
``scaling.md``, ``scaling.png`` (median episodes to solve and fraction solved against
reachable states), ``meta.json`` and each variant's result folder ``runs/NxK/`` (the curves,
written through the pipeline of every training command, :mod:`vdbejax.studies`:
checkpointed, so ``--resume`` continues a study).

Two parts live apart, each imported from its own module:

* :mod:`vdbejax.studies.scaling_adaptive` — training until solved:
  :func:`~vdbejax.studies.scaling_adaptive.run_until_solved` and
  :class:`~vdbejax.studies.scaling_adaptive.AdaptiveRun`.
* :mod:`vdbejax.studies.scaling_report` — the result folder's files and columns,
  ``scaling.md``, ``scaling.png``, :func:`~vdbejax.studies.scaling_report.write_reports` and
  :func:`~vdbejax.studies.scaling_report.load_scaling` (a saved folder redraws without
  training). It imports nothing of this module: the data flow one way, runner → results →
  report.
"""
from __future__ import annotations

import dataclasses
import math
import sys
import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from vdbejax.methods.agents import Setting, make_agent, parameter_name
from vdbejax.results import io
from vdbejax.results.folder_lock import mark, output_folder, unmark
from vdbejax.results.solving import convergence_threshold, summarize_solving
from vdbejax.results.summary import SummaryRow, summary_rows
from vdbejax.runs import RunOptions, UntilSolved
from vdbejax.runs.batching import check_run_size
from vdbejax.runs.estimate import StudyEstimate, announce, estimate_task
from vdbejax.runs.options import SPEED_FIELDS, study_run
from vdbejax.studies.folder import StudyOutputs
from vdbejax.studies.scaling_adaptive import AdaptiveRun, train_until_solved
from vdbejax.studies.scaling_report import (
    CSV_FILE,
    FIGURE_FILE,
    MARKDOWN_FILE,
    META_FILE,
    ROW_COLUMNS,
    RUNS_FOLDER,
    method_label,
    row_setting,
    write_reports,
)
from vdbejax.validation import (
    INT32_MAX,
    UINT32_MAX,
    check_bool,
    check_in_range,
    check_instance,
    check_int,
)


@dataclasses.dataclass(frozen=True)
class Method:
    """One exploration method of the study, at one parameter value.

    Attributes:
      explorer: the registered explorer name.
      param: its swept parameter (ε, τ, σ, c, β).
      hyperparameters: other explorer fields (``{"decay": 0.99}``).
      why: where the value comes from (docs/SCALING.md).
    """

    explorer: str
    param: float | None
    hyperparameters: tuple = ()
    why: str = ""

    def setting(self, learner: str) -> Setting:
        """The method with ``learner``."""
        return Setting(learner, self.explorer, self.param, dict(self.hyperparameters))


#: The methods of the study. The paper's four at the value that does best on the paper's
#: grid (textbook reading, 20 agents × 1000 episodes, ``docs/ablation/spec/summary.csv``):
#: the highest final return averaged over both learners — :func:`best_parameters` applied
#: to that file gives exactly these (tested). The others at the value that does best on the
#: paper's task by the same rule among three candidates (docs/SCALING.md: the candidates,
#: the commands, and the one value a 20-agent check would change).
METHODS: tuple[Method, ...] = (
    Method("egreedy", 0.01, why="paper grid: best ε of {0.01, …, 0.2}"),
    Method("softmax", 0.0001, why="paper grid: best τ of {0.0001, …, 10}"),
    Method("vdbe", 100.0, why="paper grid: best σ of {0.001, …, 100}"),
    Method("vdbe_softmax", 100.0,
           why="paper grid: best σ of {0.001, …, 100} (τ = 0.001, the spec's)"),
    Method("ucb1", 0.001, why="paper task: best c of {0.001, 0.01, 0.1}"),
    Method("count_bonus", 0.005,
           why="paper task: best β of {0.005, 0.05, 0.5}"),
    Method("max_boltzmann", 0.01, why="paper task: best ε of {0.01, 0.1, 0.3} (τ = 0.1)"),
    Method("egreedy_decay", 1.0, (("decay", 0.99),),
           why="paper task, 5-agent pilot: best decay of {0.99, 0.995, 0.999} (ε from 1 to"
               " 0.01); 20 agents prefer 0.995 by SARSA's failing runs (docs/SCALING.md)"),
)
#: The paper's explorers (their values come from the paper's grid).
PAPER_METHODS = ("egreedy", "softmax", "vdbe", "vdbe_softmax")
LEARNERS = ("qlearning", "sarsa")
#: The full-size family of variants (N sections × K goblets), in order of size.
SIZES = ("2x1", "3x1", "4x1", "4x2", "5x2", "6x2", "6x3")
#: Default budget: ``max(EPISODES, EPISODES_PER_STATE × reachable states)`` per variant.
EPISODES = 2000
EPISODES_PER_STATE = 3.0
#: Agents per setting by default.
SEEDS = 10


@dataclasses.dataclass(frozen=True)
class ScalingSize:
    """The study's size: which variants, how many agents, how many episodes each.

    Attributes:
      sizes: variants ``NxK`` (``"2x1,4x2"`` or a sequence; :func:`parse_sizes`).
      seeds: agents per setting.
      episodes: episode budget per agent and variant; with ``episodes_per_state`` the
        smallest one (:func:`variant_budget`).
      episodes_per_state: budget per reachable state (None: ``episodes`` everywhere).
    """

    sizes: str | Sequence[str] = SIZES
    seeds: int = SEEDS
    episodes: int = EPISODES
    episodes_per_state: float | None = EPISODES_PER_STATE


#: ``--quick``: two small variants, few agents and episodes (seconds).
QUICK = ScalingSize(sizes=("2x1", "3x1"), seeds=3, episodes=1000, episodes_per_state=None)


def best_parameters(rows: Sequence[SummaryRow | Mapping[str, Any]]) -> dict[str, float]:
    """Per explorer, the parameter whose final return averaged over the learners is highest
    (the first in ``rows`` on an exact tie).

    Args:
      rows: summary rows (:class:`~vdbejax.results.summary.SummaryRow`, or ``summary.csv``'s rows
        as strings or numbers: :func:`~vdbejax.results.summary.summary_rows`).

    Returns:
      ``{explorer: param}``.

    Raises:
      ValueError: a row that is no summary row, or one of an explorer's default (no
        parameter).
    """
    table: dict[str, dict[float, list[float]]] = {}
    for row in summary_rows(rows):
        table.setdefault(row.explorer, {}).setdefault(row.swept_param(), []).append(
            row.final_return)
    return {explorer: max(by_param, key=lambda p: float(np.mean(by_param[p])))
            for explorer, by_param in table.items()}


def parse_sizes(sizes: str | Sequence[str]) -> list[tuple[int, int]]:
    """``"2x1,3x1"`` or ``["2x1", "3x1"]`` → ``[(2, 1), (3, 1)]`` (N ≥ 2 sections, K ≥ 1
    goblets).

    Raises:
      ValueError: empty, malformed or repeated sizes.
    """
    items = [s for s in (sizes.split(",") if isinstance(sizes, str) else list(sizes)) if str(s)]
    if not items:
        raise ValueError(f"sizes={sizes!r} is invalid: must name at least one variant,"
                         " e.g. 2x1,4x2")
    parsed = []
    for item in items:
        sections, sep, goblets = str(item).strip().lower().partition("x")
        if not (sep and sections.isdigit() and goblets.isdigit()
                and int(sections) >= 2 and int(goblets) >= 1):
            raise ValueError(f"sizes has {item!r}: each size must be NxK with N >= 2 sections"
                             " and K >= 1 goblets, e.g. 4x2")
        if (int(sections), int(goblets)) in parsed:
            raise ValueError(f"sizes has {item!r} twice")
        parsed.append((int(sections), int(goblets)))
    return parsed


def select_methods(names: Sequence[str] | None) -> list[Method]:
    """The methods of :data:`METHODS` named (default: all), in that order.

    Raises:
      ValueError: an unknown or repeated name.
    """
    if names is None:
        return list(METHODS)
    known = {m.explorer: m for m in METHODS}
    names = [n for n in names if n]
    if not names:
        raise ValueError("methods is empty: name at least one of " + ", ".join(known))
    for name in names:
        if name not in known:
            raise ValueError(f"methods has {name!r}: must be among {', '.join(known)}")
    if len(set(names)) != len(names):
        raise ValueError(f"methods={list(names)!r} is invalid: a method is named twice")
    return [known[n] for n in names]


def study_settings(methods: Sequence[Method] = METHODS,
                   learners: Sequence[str] = LEARNERS) -> list[Setting]:
    """The study's settings: learner-major, then the methods in order."""
    return [m.setting(learner) for learner in learners for m in methods]


def variant_budget(states: int, episodes: int, episodes_per_state: float | None) -> int:
    """A variant's episode budget: ``episodes``, or ``max(episodes, ⌈episodes_per_state ×
    states⌉)`` rounded up to a multiple of 100 (episodes to solve grow with the states)."""
    if episodes_per_state is None:
        return int(episodes)
    return max(int(episodes), -(-math.ceil(episodes_per_state * states) // 100) * 100)


def auto_chunk(episodes: int) -> int:
    """Episodes between stop checks for a budget: ``max(100, ⌈budget / 100⌉)``. Each check
    copies the remaining agents' state to the host, so checks are worth spacing out on
    long runs, while the extra episodes a solved agent runs stay within 1 % of the budget."""
    return max(100, -(-int(episodes) // 100))



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
    :func:`~vdbejax.studies.scaling_adaptive.run_until_solved` batch. With ``drop_unsolved``
    a setting none of whose agents solved a variant is not run on the larger ones (its rows
    read ``dropped``): a shortcut
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
      max_steps: episode truncation (default 100, :func:`vdbejax.studies.task_names.make_task`).
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
    from vdbejax.studies.task_names import make_task

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
    "EPISODES",
    "EPISODES_PER_STATE",
    "LEARNERS",
    "METHODS",
    "PAPER_METHODS",
    "QUICK",
    "SCALING_RUN_FIELDS",
    "SEEDS",
    "SIZES",
    "Method",
    "ScalingResult",
    "ScalingSize",
    "auto_chunk",
    "best_parameters",
    "parse_sizes",
    "run_scaling",
    "select_methods",
    "study_settings",
    "variant_budget",
]
