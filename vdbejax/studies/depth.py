"""Depth scaling: how the episodes to solve grow with the depth N of DeepSea and the chain.

``vdbejax depth --out DIR`` (:func:`run_depth`) runs the benchmark's methods
(:mod:`~vdbejax.studies.bench_methods`, each at its untuned middle candidate, the one rule of
``vdbejax bench --no-tune``) on two families of growing depth, each agent until it has
solved the task or its episode budget is spent (the stop policy
:class:`~vdbejax.runs.UntilSolved` on the one run path, as ``vdbejax scale``: one result
folder per task under ``runs/``, checkpointed and resumable):

* ``deepsea`` — DeepSea of size N (:mod:`vdbejax.envs.suite.deep_sea`, bsuite's: N steps
  an episode, the treasure behind N − 1 "right" moves that each cost 0.01/N);
* ``chain`` — the chain of N states without slips and a horizon of 2N steps
  (:func:`vdbejax.envs.suite.chain.make_chain` with ``slip = 0``): going back pays 2 at
  once, the far end 10 a step after N − 1 steps with nothing to show for them. The
  slippery chain of the suite does not scale: its optimal policy stops walking to the end
  for N > 8 (see that module).

"Solved" is the benchmark's: a 20-episode moving average of the normalised return (0 =
the uniformly random policy, 1 = the optimum) reaching 0.9. Per method and family the
study fits, over the depths where at least half of its agents solved (a finite median),
when there are at least :data:`MIN_FITTED_DEPTHS` of them (a line through two points fits
any growth and has no error to show),
the log-log slope of the median episodes to solve against N (the degree of a polynomial
growth) and the log2-linear slope (the doubling rate of an exponential one), each with a
95 % bootstrap interval over agents (each depth's agents resampled on their own; a
resample whose median is censored counts at the budget, a lower bound).
"""
from __future__ import annotations

import dataclasses
import math
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from vdbejax.results import io
from vdbejax.results.curves import WINDOW
from vdbejax.results.folder_lock import check_output_paths, mark, output_folder, unmark
from vdbejax.results.policy import POLICY_COLUMNS
from vdbejax.results.solving import summarize_solving
from vdbejax.runs import RunOptions, UntilSolved
from vdbejax.runs.batching import check_run_size
from vdbejax.runs.estimate import StudyEstimate, announce, estimate_task
from vdbejax.runs.options import SPEED_FIELDS, study_run
from vdbejax.studies.bench import SOLVED, BenchTask
from vdbejax.studies.bench_methods import BenchMethod, select_methods
from vdbejax.studies.depth_report import (
    FIGURE_FILE,
    MARKDOWN_FILE,
    POLICY_FIGURE_FILE,
    write_reports,
)
from vdbejax.studies.folder import StudyOutputs
from vdbejax.studies.scaling import auto_chunk
from vdbejax.studies.scaling_adaptive import AdaptiveRun, train_until_solved
from vdbejax.validation import INT32_MAX, UINT32_MAX, check_bool, check_instance, check_int

FAMILIES = ("deepsea", "chain")
SIZES = (4, 8, 16, 32)
SEEDS = 10
#: Episode budget per agent and task.
EPISODES = 1000
#: The methods by default: every method of the benchmark but PSRL, whose dense sampled
#: model costs S² A per stage and episode (DeepSea 32 has S = 1024).
METHODS = ("egreedy", "softmax", "vdbe", "vdbe_softmax", "max_boltzmann", "ucb1",
           "count_bonus", "optimistic_q", "ucb_h", "delayed_q", "rmax", "mbie_eb", "ucbvi",
           "dyna_q_plus", "q_lambda")
QUICK_SIZES, QUICK_SEEDS, QUICK_EPISODES = (4, 6, 8), 3, 100
#: The fewest depths a growth slope is fitted over.
MIN_FITTED_DEPTHS = 3
QUICK_METHODS = ("egreedy", "vdbe", "ucb1", "rmax")
RESAMPLES = 1000
CSV_FILE, SLOPES_FILE, META_FILE, RUNS_FOLDER = "depth.csv", "depth_slopes.csv", "meta.json", "runs"
ROW_COLUMNS = ["family", "size", "states", "method", "title", "method_family", "agents",
               "solved", "fraction_solved", "median_episodes", "median_low", "median_high",
               "budget", "median_text", "agent_episodes", "agent_steps"]
SLOPE_COLUMNS = ["family", "method", "title", "method_family", "sizes_fitted", "largest_solved",
                 "exponent", "exponent_low", "exponent_high", "doubling", "doubling_low",
                 "doubling_high"]


@dataclasses.dataclass
class DepthResult:
    """What :func:`run_depth` wrote: a row per (family, size, method), a slope row per
    (family, method), the meta data and each task's :class:`AdaptiveRun`."""

    rows: list[dict[str, Any]]
    slopes: list[dict[str, Any]]
    meta: dict[str, Any]
    runs: dict[str, AdaptiveRun]


def depth_task(family: str, size: int) -> BenchTask:
    """The task of ``family`` (:data:`FAMILIES`) at depth ``size``, solved exactly."""
    from vdbejax.envs.solvers import best_return, uniform_random_return
    from vdbejax.envs.suite import chain, make_suite_task

    if family == "deepsea":
        name, mdp = f"deepsea:{size}", make_suite_task(f"deepsea:{size}")
    elif family == "chain":
        name = f"chain_deterministic:{size}"
        mdp = chain.make_chain(size, slip=0.0, max_steps=2 * size,
                               name=f"chain_deterministic_{size}")
    else:
        raise ValueError(f"families holds {family!r}: must be among {', '.join(FAMILIES)}")
    return BenchTask(name, mdp, best_return(mdp), uniform_random_return(mdp))


def _sizes(sizes: Sequence[int] | str) -> list[int]:
    if isinstance(sizes, str):
        try:
            values: list[Any] = [int(s) for s in sizes.split(",")]
        except ValueError:
            raise ValueError(f"sizes={sizes!r} is invalid: must be comma-separated integers"
                             " from 2 to 256") from None
    else:
        values = list(sizes)
    parsed = sorted({check_int("sizes", v, 2, 256) for v in values})
    if len(parsed) < MIN_FITTED_DEPTHS:
        raise ValueError(f"sizes={sizes!r} is invalid: need at least {MIN_FITTED_DEPTHS}"
                         " distinct sizes (2..256) to fit a slope")
    return parsed


def _families(families: Sequence[str] | str) -> list[str]:
    names = ([f.strip() for f in families.split(",") if f.strip()] if isinstance(families, str)
             else list(families))
    if not names or any(f not in FAMILIES for f in names) or len(set(names)) != len(names):
        raise ValueError(f"families={','.join(map(str, names))!r} is invalid: must be distinct"
                         f" names among {', '.join(FAMILIES)}")
    return names


#: The run options :func:`run_depth` takes (it sets the chunks and the stop itself).
DEPTH_RUN_FIELDS = ("progress", "resume", "overwrite", "evaluate_every", *SPEED_FIELDS)


def run_depth(
    out_dir: str | Path,
    *,
    families: Sequence[str] | str = FAMILIES,
    sizes: Sequence[int] | str = SIZES,
    methods: Sequence[str] | str | None = METHODS,
    seeds: int = SEEDS,
    episodes: int = EPISODES,
    seed: int = 0,
    quick: bool = False,
    outputs: StudyOutputs = StudyOutputs(),
    run: RunOptions | None = None,
) -> DepthResult:
    """Episodes to solve of every method on DeepSea and the chain of growing depth.

    Args:
      out_dir: output folder (created).
      families: ``deepsea`` and/or ``chain``.
      sizes: the depths N (at least two).
      methods: names of :data:`vdbejax.studies.bench_methods.METHODS` (None: all).
      seeds: agents per method and task.
      episodes: episode budget per agent and task.
      seed: root seed.
      quick: the ``QUICK_*`` sizes, seeds, episodes and methods (then none of them may be
        given; the CLI refuses them).
      outputs: what it writes besides its tables (:class:`~vdbejax.studies.StudyOutputs`):
        ``figures``: ``depth.png`` (and ``depth_policy_gap.png`` with ``evaluate_every``);
        ``command``: the command line, recorded in ``depth.md`` and ``meta.json``;
        ``save_runs``: keep each task's result folder ``runs/<task>/``.
      run: how it runs (:class:`~vdbejax.runs.RunOptions`, default
        ``RunOptions(progress=True)``; the study sets the chunks and the stop), the fields
        of :data:`DEPTH_RUN_FIELDS`: ``progress``: status lines and progress bars on
        stderr; ``resume`` continues an interrupted study (whole task folders reused, the
        interrupted one continued from its checkpoint); ``overwrite`` replaces the finished
        results its folders hold (without it, a folder holding one is refused in one line
        before it is trained again); ``evaluate_every``: every this many episodes the exact
        value of each agent's greedy policy (:mod:`vdbejax.runs.evaluation`): its gap to
        the optimum and the share of optimal greedy policies per depth in ``depth.csv`` and
        ``depth.md``; the others change only the speed.

    Returns:
      the :class:`DepthResult` (also written to ``out_dir``).

    Raises:
      ValueError: any invalid input, before training.
    """
    from vdbejax.methods.agents import make_agent
    from vdbejax.runs.provenance import version_info

    run = study_run(run, "run_depth", DEPTH_RUN_FIELDS)
    progress, evaluate_every = run.progress, run.evaluate_every
    check_instance("outputs", outputs, StudyOutputs)
    check_bool("quick", quick)
    figure = outputs.figures
    if quick:
        sizes, seeds, episodes, methods = QUICK_SIZES, QUICK_SEEDS, QUICK_EPISODES, QUICK_METHODS
    chosen_families, chosen_sizes = _families(families), _sizes(sizes)
    seeds = check_int("seeds", seeds, 1, INT32_MAX)
    episodes = check_int("episodes", episodes, WINDOW, INT32_MAX)
    seed = check_int("seed", seed, 0, UINT32_MAX)
    if evaluate_every is not None:
        evaluate_every = check_int("evaluate_every", evaluate_every, 1, episodes)
        if evaluate_every % auto_chunk(episodes):  # agents stop at chunk ends: kept as it is
            raise ValueError(f"evaluate_every={evaluate_every} is invalid with episodes="
                             f"{episodes}: must be a multiple of the study's chunk of"
                             f" {auto_chunk(episodes)} episodes, where agents stop")
    chosen: list[BenchMethod] = select_methods(methods)
    tasks = [(family, size, depth_task(family, size)) for family in chosen_families
             for size in chosen_sizes]
    settings = {task.name: [m.default_candidate(task.scale) for m in chosen]
                for _, _, task in tasks}
    for task_settings in settings.values():
        for setting in task_settings:
            make_agent(setting)
    check_run_size(len(chosen) * seeds, episodes)  # every task's grid: refused before the folder
    if progress:
        fewest = UntilSolved().fewest_episodes(episodes)
        announce(StudyEstimate(tuple(
            estimate_task(task.mdp, len(chosen), seeds, episodes, statistics=False,
                          fewest_episodes=fewest) for _, _, task in tasks)), "study")
    files = [CSV_FILE, SLOPES_FILE, MARKDOWN_FILE, META_FILE, *([FIGURE_FILE] if figure else []),
             *([POLICY_FIGURE_FILE] if figure and evaluate_every else [])]
    out, lock = output_folder(out_dir, own=[*files, RUNS_FOLDER], overwrite=run.overwrite)
    check_output_paths(out, files)
    knobs = run.replace(chunk_episodes=auto_chunk(episodes))
    versions = version_info()  # the code that runs: read before training, not after
    started = time.perf_counter()
    with lock:
        rows: list[dict[str, Any]] = []
        runs: dict[str, AdaptiveRun] = {}
        for i, (family, size, task) in enumerate(tasks):
            if progress:
                sys.stderr.write(f"[{i + 1}/{len(tasks)}] {task.name} ({task.mdp.num_states}"
                                 f" states, best {task.best:g}): {len(chosen)} methods ×"
                                 f" {seeds} agents, up to {episodes} episodes\n")
            trained = train_until_solved(
                out / RUNS_FOLDER / task.folder, task.mdp, settings[task.name], seeds=seeds,
                budget=episodes, stop=UntilSolved(best=task.best, baseline=task.baseline,
                                                  fraction=SOLVED),
                seed=seed, options=knobs, task=task.name)
            runs[task.name] = trained
            rows.extend(_task_rows(family, size, task, chosen, trained))
        slopes = growth_slopes(rows, chosen, chosen_families, seed=seed)
        meta = {"command": outputs.command, "elapsed_seconds": time.perf_counter() - started,
                "options": {"families": chosen_families, "sizes": chosen_sizes, "seeds": seeds,
                            "episodes": episodes, "seed": seed, "quick": quick,
                            "solved": SOLVED, "window": WINDOW, "resamples": RESAMPLES,
                            "evaluate_every": evaluate_every},
                "methods": {m.name: dataclasses.asdict(m) for m in chosen},
                "tasks": {task.name: {"best": task.best, "baseline": task.baseline,
                                      "states": int(task.mdp.num_states),
                                      "agent_steps": runs[task.name].agent_steps,
                                      "seconds": runs[task.name].elapsed_seconds}
                          for _, _, task in tasks},
                **versions}
        mark(out, "results")  # a folder killed while its files are replaced is recognised
        io.write_csv(out / CSV_FILE, rows,
                     ROW_COLUMNS + (POLICY_COLUMNS if evaluate_every is not None else []))
        io.write_csv(out / SLOPES_FILE, slopes, SLOPE_COLUMNS)
        io.save_json(out / META_FILE, meta)
        write_reports(out, rows, slopes, meta, figure=figure)
        unmark(out)
        outputs.discard_runs([out / RUNS_FOLDER / task.folder for _, _, task in tasks])
    return DepthResult(rows, slopes, meta, runs)


def _task_rows(family: str, size: int, task: BenchTask, methods: list[BenchMethod],
               run: AdaptiveRun) -> list[dict[str, Any]]:
    rows = []
    for c, method in enumerate(methods):
        summary = summarize_solving(run.solve.episodes[c], run.solve.solved[c])
        rows.append({
            "family": family, "size": size, "states": int(task.mdp.num_states),
            "method": method.name, "title": method.title, "method_family": method.family,
            "agents": summary.agents, "solved": summary.solved,
            "fraction_solved": summary.fraction, "median_episodes": summary.median,
            "median_low": summary.median_low, "median_high": summary.median_high,
            "budget": summary.budget, "median_text": summary.median_text(),
            "agent_episodes": int(run.episodes_run[c].sum()),
            "agent_steps": int(run.lengths[c].sum(dtype=np.int64)),
            "_episodes": np.where(run.solve.solved[c], run.solve.episodes[c], np.inf),
            "_span": task.best - task.baseline,
            **(run.policy[c] if run.policy is not None else {})})
    return rows


def growth_slopes(rows: Sequence[dict[str, Any]], methods: Sequence[BenchMethod],
                  families: Sequence[str], *, seed: int = 0) -> list[dict[str, Any]]:
    """Per (family, method): the log-log and log2-linear slopes of the median episodes to
    solve against N over the depths with a finite median, with 95 % bootstrap intervals
    (module docstring); NaN with fewer than :data:`MIN_FITTED_DEPTHS` such depths."""
    rng = np.random.default_rng(seed)
    slopes = []
    for family in families:
        for method in methods:
            mine = [r for r in rows if r["family"] == family and r["method"] == method.name]
            fitted = [r for r in mine if math.isfinite(r["median_episodes"])]
            row = {"family": family, "method": method.name, "title": method.title,
                   "method_family": method.family, "sizes_fitted": len(fitted),
                   "largest_solved": max((r["size"] for r in fitted), default=0)}
            if len(fitted) < MIN_FITTED_DEPTHS:
                slopes.append(dict(row, **{k: math.nan for k in SLOPE_COLUMNS[6:]}))
                continue
            n = np.array([r["size"] for r in fitted], np.float64)
            medians = np.array([r["median_episodes"] for r in fitted], np.float64)
            draws = np.stack([_resampled_medians(r["_episodes"], r["budget"], rng)
                              for r in fitted])  # [sizes, resamples]
            for name, x in (("exponent", np.log(n)), ("doubling", n)):
                base = np.log(medians) if name == "exponent" else np.log2(medians)
                logs = np.log(draws) if name == "exponent" else np.log2(draws)
                estimate = float(np.polyfit(x, base, 1)[0])
                boot = np.polyfit(x, logs, 1)[0]
                row.update({name: estimate, f"{name}_low": float(np.percentile(boot, 2.5)),
                            f"{name}_high": float(np.percentile(boot, 97.5))})
            slopes.append(row)
    return slopes


def _resampled_medians(episodes: np.ndarray, budget: int, rng: np.random.Generator
                       ) -> np.ndarray:
    """:data:`RESAMPLES` bootstrap medians of one setting's solve episodes (inf: unsolved);
    a censored median counts at ``budget``."""
    picks = rng.integers(0, len(episodes), (RESAMPLES, len(episodes)))
    medians = np.median(np.asarray(episodes, np.float64)[picks], axis=1)
    return np.minimum(medians, float(budget))
