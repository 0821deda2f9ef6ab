"""How each exploration method's cost grows with the task: ``vdbejax scale``.

:func:`run_until_solved` trains a grid chunk by chunk until every agent has solved the task
(:mod:`vdbejax.solving`: its 20-episode moving average reaches 0.9 × the exact best return)
or a budget of episodes or wall-clock seconds is spent. After each chunk the solved agents
leave the batch — they cost no more compute — and the others continue from their state:
each chunk is one :func:`~vdbejax.engine.run_agents` call resumed from ``initial=`` (the
engine is untouched; its resume is bit-identical by design). Every agent draws from its
own random stream, so an agent's returns do not depend on when the others stop: up to its
stop episode they equal, bit for bit, those of a fixed-budget :func:`~vdbejax.run_grid`
with the same settings, seeds and root seed (``tests/test_scaling.py``).

:func:`run_scaling` runs that on a family of generated table-cleaning variants of growing
size (``variant:NxK``, :func:`vdbejax.sweeps.make_task`) for every method of
:data:`METHODS` and both learners, and writes ``scaling.csv``, ``scaling.md``,
``scaling.png`` (median episodes to solve and fraction solved against reachable states),
``meta.json`` and the raw curves (``runs/NxK.npz``) into a folder.
"""
from __future__ import annotations

import dataclasses
import math
import sys
import time
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from vdbejax import io
from vdbejax.methods.agents import (
    AgentOptions,
    Setting,
    make_agent,
    parameter_name,
    remember_parameter_names,
)
from vdbejax.solving import (
    FRACTION,
    TOLERANCE,
    WINDOW,
    SolveTimes,
    episodes_to_solve,
    solve_threshold,
    summarize_solving,
)
from vdbejax.summary import SummaryRow, summary_rows
from vdbejax.validation import (
    INT32_MAX,
    UINT32_MAX,
    check_bool,
    check_in_range,
    check_int,
    check_positive,
    check_writable_dir,
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
#: ``--quick``: two small variants, few agents and episodes (seconds).
QUICK: dict[str, Any] = {"sizes": ("2x1", "3x1"), "seeds": 3, "episodes": 1000,
                         "episodes_per_state": None}
#: Default budget: ``max(EPISODES, EPISODES_PER_STATE × reachable states)`` per variant.
EPISODES = 2000
EPISODES_PER_STATE = 3.0

CSV_FILE = "scaling.csv"
MARKDOWN_FILE = "scaling.md"
FIGURE_FILE = "scaling.png"
META_FILE = "meta.json"
RUNS_FOLDER = "runs"


def best_parameters(rows: Sequence[SummaryRow | Mapping[str, Any]]) -> dict[str, float]:
    """Per explorer, the parameter whose final return averaged over the learners is highest
    (the first in ``rows`` on an exact tie).

    Args:
      rows: summary rows (:class:`~vdbejax.summary.SummaryRow`, or ``summary.csv``'s rows
        as strings or numbers: :func:`~vdbejax.summary.summary_rows`).

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


# --------------------------------------------------------------------------- adaptive runs


@dataclasses.dataclass
class AdaptiveRun:
    """A grid trained until solved or out of budget (:func:`run_until_solved`).

    Attributes:
      settings: the configurations, in config-index order.
      returns: float32 ``[configs, seeds, max_episodes]``; NaN past an agent's stop.
      lengths: int32, same shape; 0 past an agent's stop.
      episodes_run: int64 ``[configs, seeds]``: episodes each agent ran (its stop episode).
      solve: :class:`~vdbejax.solving.SolveTimes` ``[configs, seeds]``.
      nonfinite: bool ``[configs, seeds]``.
      best: the exact best return; ``fraction``, ``window``: the solve criterion.
      max_episodes, max_seconds: the budget.
      stopped: ``"solved"`` (every agent), ``"episodes"`` or ``"seconds"`` (budget spent).
      elapsed_seconds: wall clock of the training (engine programs included).
      compile_seconds: of which getting the engine's programs.
      chunks: engine calls made.
    """

    settings: list[Setting]
    returns: np.ndarray
    lengths: np.ndarray
    episodes_run: np.ndarray
    solve: SolveTimes
    nonfinite: np.ndarray
    best: float
    fraction: float
    window: int
    max_episodes: int
    max_seconds: float | None
    stopped: str
    elapsed_seconds: float
    compile_seconds: float
    chunks: int

    @property
    def agent_steps(self) -> int:
        """Environment steps of every agent together."""
        return int(self.lengths.sum(dtype=np.int64))

    @property
    def steps_per_second(self) -> float:
        """Agent-steps per second of engine time (programs excluded)."""
        return self.agent_steps / max(self.elapsed_seconds - self.compile_seconds, 1e-9)


#: ``progress(episodes_done, active_agents, total_agents, elapsed_seconds)`` after a chunk.
AdaptiveProgress = Callable[[int, int, int, float], None]


def run_until_solved(
    mdp: Any,
    settings: Sequence[Setting],
    *,
    num_seeds: int,
    max_episodes: int,
    max_seconds: float | None = None,
    best: float | None = None,
    fraction: float = FRACTION,
    window: int = WINDOW,
    seed: int = 0,
    options: AgentOptions = AgentOptions(),
    chunk_episodes: int = 100,
    threads: int | None = None,
    progress: AdaptiveProgress | None = None,
) -> AdaptiveRun:
    """Train ``settings × num_seeds`` agents until each has solved ``mdp`` or the budget ends.

    After each chunk of ``chunk_episodes`` episodes, an agent whose moving average has
    reached ``fraction × best`` (:func:`~vdbejax.solving.episodes_to_solve`) stops: it leaves
    the batch at the end of that chunk (its stop episode, :attr:`AdaptiveRun.episodes_run`).
    The run ends when no agent is left, after ``max_episodes`` episodes, or after the first
    chunk that ends past ``max_seconds`` of wall clock (then every remaining agent is
    censored at the same episode; which episode depends on the machine's speed, so the
    episode budget is the reproducible one).

    Agents ``(config c, seed i)`` have the keys and hyperparameters of :func:`~vdbejax.run_grid`
    (``grid_agents``), so an agent's returns up to its stop are bit-identical to that run's.

    Args:
      mdp: the task.
      settings: the configurations.
      num_seeds: agents per setting.
      max_episodes: episode budget per agent.
      max_seconds: wall-clock budget of the whole run (None: no limit).
      best: the exact best return (default :func:`vdbejax.solvers.best_return` of ``mdp``).
      fraction, window: the solve criterion.
      seed: root seed.
      options: values shared by every agent (α, γ, …).
      chunk_episodes: episodes between stop checks (the results do not depend on it; the
        stop episodes do).
      threads: the engine's worker threads (default: the CPUs this process may use).
      progress: called after every chunk.

    Returns:
      the :class:`AdaptiveRun`.

    Raises:
      ValueError: any invalid input, before training.
    """
    import jax

    from vdbejax.distributed import take_agents
    from vdbejax.engine import AgentState, check_params, compile_seconds, run_agents
    from vdbejax.engine.programs import Programs
    from vdbejax.envs.tabular import TabularMDP
    from vdbejax.experiment import grid_agents

    if not isinstance(mdp, TabularMDP):
        raise ValueError(f"mdp={type(mdp).__name__} is invalid: must be a TabularMDP")
    settings = list(settings)
    if not settings or not all(isinstance(s, Setting) for s in settings):
        raise ValueError("settings is invalid: must be a non-empty list of Setting")
    num_seeds = check_int("num_seeds", num_seeds, 1, INT32_MAX)
    max_episodes = check_int("max_episodes", max_episodes, 1, INT32_MAX)
    if max_seconds is not None:
        max_seconds = check_positive("max_seconds", max_seconds)
    window = check_int("window", window, 1)
    seed = check_int("seed", seed, 0, UINT32_MAX)
    chunk_episodes = check_int("chunk_episodes", chunk_episodes, 1, INT32_MAX)
    if best is None:
        from vdbejax.solvers import best_return

        best = best_return(mdp)
    solve_threshold(best, fraction)  # one line before training: best > 0, 0 < fraction ≤ 1
    for setting in settings:
        make_agent(setting, options)
    params, keys = grid_agents(settings, num_seeds, seed, options)
    check_params(params, mdp.num_actions)

    num_agents = len(settings) * num_seeds
    returns = np.full((num_agents, max_episodes), np.nan, np.float32)
    lengths = np.zeros((num_agents, max_episodes), np.int32)
    episodes_run = np.zeros(num_agents, np.int64)
    nonfinite = np.zeros(num_agents, bool)
    active = np.arange(num_agents)
    state: AgentState | None = None  # the active agents' state after `done` episodes
    done, chunks, stopped = 0, 0, "solved"
    chunk = min(chunk_episodes, max_episodes)
    compiled_before = compile_seconds()
    programs = Programs()  # the study's: each program traced once, not once per chunk
    started = time.perf_counter()
    while active.size:
        end = min(done + chunk, max_episodes)
        initial = None
        if done != 0:
            assert state is not None  # kept after every chunk
            initial = (done, state, returns[active, :done], lengths[active, :done])
        result = run_agents(mdp, take_agents(params, active), keys[active], end,
                            chunk_episodes=chunk, initial=initial, threads=threads,
                            programs=programs)
        chunks += 1
        returns[active, done:end] = result.returns[:, done:end]
        lengths[active, done:end] = result.lengths[:, done:end]
        episodes_run[active] = end
        nonfinite[active] = result.nonfinite
        keep = ~_newly_solved(returns, active, start=done, end=end, best=best,
                              fraction=fraction, window=window)
        done = end
        elapsed = time.perf_counter() - started
        if done >= max_episodes and keep.any():
            stopped = "episodes"
        elif max_seconds is not None and elapsed >= max_seconds and keep.any():
            stopped = "seconds"
        active = active[keep]
        if progress is not None:
            progress(done, int(active.size), num_agents, elapsed)
        if stopped != "solved":
            break
        state = jax.tree.map(lambda leaf: np.asarray(leaf)[keep], result.final_state)  # noqa: B023  (run at once)
        del result, initial  # the previous states are not needed during the next chunk
    elapsed = time.perf_counter() - started
    shape = (len(settings), num_seeds)
    solve = episodes_to_solve(returns, best, fraction=fraction, window=window,
                              episodes_run=episodes_run)
    return AdaptiveRun(
        settings=settings, returns=returns.reshape(*shape, max_episodes),
        lengths=lengths.reshape(*shape, max_episodes), episodes_run=episodes_run.reshape(shape),
        solve=SolveTimes(solve.episodes.reshape(shape), solve.solved.reshape(shape)),
        nonfinite=nonfinite.reshape(shape), best=float(best), fraction=float(fraction),
        window=window, max_episodes=max_episodes, max_seconds=max_seconds, stopped=stopped,
        elapsed_seconds=elapsed, compile_seconds=compile_seconds() - compiled_before,
        chunks=chunks,
    )


#: Margin below the threshold under which a cheap check of a chunk's new windows rules an
#: agent out before the exact check (float64 rounding is ~1e-11 on 10^6 episodes).
_SCREEN_MARGIN = 1e-7


def _newly_solved(returns: np.ndarray, active: np.ndarray, *, start: int, end: int,
                  best: float, fraction: float, window: int) -> np.ndarray:
    """Which ``active`` agents (unsolved after ``start`` episodes) have solved by ``end``.

    The decision is :func:`~vdbejax.solving.episodes_to_solve` on each agent's whole
    prefix — the very computation the final result makes — but only for the agents whose
    windows ending in ``[start, end)`` come within :data:`_SCREEN_MARGIN` of the threshold
    (a direct mean per window): the rest cannot have solved, and the per-chunk cost stays
    that of the new episodes rather than of the whole prefix.
    """
    solved = np.zeros(active.size, bool)
    first = max(start, window - 1)  # 0-based columns of full windows to check
    if first >= end:
        return solved
    tail = np.asarray(returns[active, first - window + 1: end], np.float64)
    means = np.lib.stride_tricks.sliding_window_view(tail, window, axis=-1).mean(-1)
    threshold = solve_threshold(best, fraction)
    candidates = np.flatnonzero((means >= threshold - TOLERANCE - _SCREEN_MARGIN).any(-1))
    if candidates.size:
        exact = episodes_to_solve(returns[active[candidates], :end], best, fraction=fraction,
                                  window=window)
        solved[candidates] = exact.solved
    return solved


def text_progress(label: str, stream: Any = None) -> AdaptiveProgress:
    """A one-line status on ``stream`` (stderr), redrawn after every chunk."""
    stream = sys.stderr if stream is None else stream
    shown = [-math.inf]

    def show(done: int, active: int, total: int, elapsed: float) -> None:
        if elapsed - shown[0] < 1.0 and active:
            return  # at most one redraw a second
        shown[0] = elapsed
        stream.write(f"\r{label}: episode {done}, {active}/{total} agents unsolved,"
                     f" {elapsed:6.1f} s   ")
        stream.flush()

    return show


# --------------------------------------------------------------------------- the study


@dataclasses.dataclass
class ScalingResult:
    """What :func:`run_scaling` wrote: one row per variant × setting and one per variant."""

    rows: list[dict[str, Any]]
    variants: list[dict[str, Any]]
    meta: dict[str, Any]
    runs: dict[str, AdaptiveRun]


ROW_COLUMNS = [
    "size", "config", "states", "actions", "best_return", "threshold", "learner", "explorer",
    "param", "method", "status", "agents", "solved", "fraction_solved", "fraction_low",
    "fraction_high",
    "median_episodes", "median_low", "median_high", "budget", "median_text", "agent_episodes",
    "nonfinite_agents",
]
VARIANT_COLUMNS = [
    "size", "states", "actions", "best_return", "shortest_solution", "settings_run", "agents",
    "budget_episodes", "chunk_episodes", "episodes_reached", "stopped", "agent_episodes",
    "fixed_budget_agent_episodes", "agent_steps", "training_seconds", "compile_seconds",
    "steps_per_second",
]


def method_label(setting: Setting) -> str:
    """``Q-learning VDBE-Softmax`` style names (figure legends, tables): the plug-ins'
    titles."""
    from vdbejax.methods.api import explorer_title, learner_title

    return f"{learner_title(setting.learner)} {explorer_title(setting.explorer)}"


def run_scaling(
    out_dir: str | Path,
    *,
    sizes: str | Sequence[str] = SIZES,
    seeds: int = 10,
    episodes: int = EPISODES,
    episodes_per_state: float | None = EPISODES_PER_STATE,
    seconds: float | None = None,
    seed: int = 0,
    learners: Sequence[str] = LEARNERS,
    methods: Sequence[str] | None = None,
    fraction: float = FRACTION,
    window: int = WINDOW,
    chunk_episodes: int | None = None,
    max_steps: int | None = None,
    drop_unsolved: bool = False,
    quick: bool = False,
    progress: bool = True,
    figure: bool = True,
    save_runs: bool = True,
    command: str | None = None,
) -> ScalingResult:
    """Episodes to solve of every method on growing table-cleaning variants.

    Variants run smallest (reachable states) first, each with every remaining setting in one
    :func:`run_until_solved` batch. With ``drop_unsolved`` a setting none of whose agents
    solved a variant is not run on the larger ones (its rows read ``dropped``): a shortcut
    that assumes a method failing on a task fails on larger ones within the same budget —
    not always so, hence off by default.

    Args:
      out_dir: output folder (created).
      sizes: variants ``NxK`` (``"2x1,4x2"`` or a list).
      seeds: agents per setting.
      episodes: episode budget per agent and variant; with ``episodes_per_state`` the
        smallest one (:func:`variant_budget`).
      episodes_per_state: budget per reachable state (None: ``episodes`` everywhere).
      seconds: wall-clock budget per variant (None: none).
      seed: root seed.
      learners: learner names.
      methods: explorer names of :data:`METHODS` (default all).
      fraction, window: the solve criterion (:mod:`vdbejax.solving`).
      chunk_episodes: episodes between stop checks (default :func:`auto_chunk` of the
        budget: a solved agent runs at most 1 % of the budget past its solve episode).
      max_steps: episode truncation (default 100, :func:`vdbejax.sweeps.make_task`).
      drop_unsolved: skip settings on larger variants once none of their agents solved
        (off by default: SARSA + VDBE fails 3×1 and solves 4×1 within the same budget).
      quick: :data:`QUICK` sizes, seeds and episodes (overrides those arguments).
      progress: a status line per variant on stderr.
      figure: write ``scaling.png``.
      save_runs: write the curves to ``runs/NxK.npz``.
      command: the command line, recorded in ``scaling.md`` and ``meta.json``.

    Returns:
      the :class:`ScalingResult` (also written to ``out_dir``).

    Raises:
      ValueError: any invalid input, before training.
    """
    from vdbejax.experiment import version_info
    from vdbejax.solvers import best_return, start_states, steps_to_goal
    from vdbejax.sweeps import make_task

    for name, flag in (("quick", quick), ("progress", progress), ("figure", figure),
                       ("drop_unsolved", drop_unsolved), ("save_runs", save_runs)):
        check_bool(name, flag)
    if quick:
        sizes, seeds, episodes, episodes_per_state = (
            QUICK[k] for k in ("sizes", "seeds", "episodes", "episodes_per_state"))
    parsed = parse_sizes(sizes)
    seeds = check_int("seeds", seeds, 1, INT32_MAX)
    episodes = check_int("episodes", episodes, 1, INT32_MAX)
    if episodes_per_state is not None:
        episodes_per_state = check_in_range("episodes_per_state", episodes_per_state, 0.0,
                                            1e6, low_open=True)
    if seconds is not None:
        seconds = check_positive("seconds", seconds)
    seed = check_int("seed", seed, 0, UINT32_MAX)
    fraction = check_in_range("fraction", fraction, 0.0, 1.0, low_open=True)
    window = check_int("window", window, 1)
    if chunk_episodes is not None:
        chunk_episodes = check_int("chunk_episodes", chunk_episodes, 1, INT32_MAX)
    if max_steps is not None:
        max_steps = check_int("max_steps", max_steps, 1, INT32_MAX)
    if isinstance(learners, str) or not learners:
        raise ValueError(f"learners={learners!r} is invalid: must be a non-empty list of names")
    chosen = select_methods(methods)
    settings = study_settings(chosen, learners)
    for setting in settings:  # unknown learners: one line before anything runs
        make_agent(setting)
    out = check_writable_dir("out", out_dir)

    tasks = []
    for sections, goblets in parsed:  # every task built and solved before any training
        size = f"{sections}x{goblets}"
        mdp = make_task(f"variant:{size}", max_steps=max_steps)
        best = best_return(mdp)
        threshold = solve_threshold(best, fraction)
        shortest = int(steps_to_goal(mdp)[start_states(mdp)].max())
        tasks.append((size, mdp, best, threshold, shortest))
    tasks.sort(key=lambda task: task[1].num_states)

    versions = version_info()  # the code that runs: read before training, not after
    rows: list[dict[str, Any]] = []
    variants: list[dict[str, Any]] = []
    runs: dict[str, AdaptiveRun] = {}
    remaining = list(settings)
    order = {s: i for i, s in enumerate(settings)}
    dropped_on: dict[Setting, str] = {}
    started = time.perf_counter()
    for size, mdp, best, threshold, shortest in tasks:
        budget = variant_budget(mdp.num_states, episodes, episodes_per_state)
        chunk = auto_chunk(budget) if chunk_episodes is None else chunk_episodes
        base = {"size": size, "states": int(mdp.num_states), "actions": int(mdp.num_actions),
                "best_return": float(best), "threshold": float(threshold)}
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
        run = run_until_solved(
            mdp, remaining, num_seeds=seeds, max_episodes=budget, max_seconds=seconds,
            best=best, fraction=fraction, window=window, seed=seed, chunk_episodes=chunk,
            progress=text_progress(f"{size} ({mdp.num_states} states)") if progress else None,
        )
        runs[size] = run
        if progress:
            sys.stderr.write(f"\r{size} ({mdp.num_states} states): {int(run.solve.solved.sum())}/"
                             f"{run.solve.solved.size} agents solved, {run.elapsed_seconds:.1f} s"
                             f" ({run.steps_per_second / 1e6:.2f} M steps/s)          \n")
        if save_runs:
            (out / RUNS_FOLDER).mkdir(exist_ok=True)
            io.atomic_savez(out / RUNS_FOLDER / f"{size}.npz", returns=run.returns,
                            episodes_run=run.episodes_run, solve_episode=run.solve.episodes,
                            solved=run.solve.solved,
                            labels=np.asarray([s.label for s in run.settings]))
        reached = int(run.episodes_run.max())
        for c, setting in enumerate(run.settings):
            summary = summarize_solving(run.solve.episodes[c], run.solve.solved[c])
            rows.append(dict(base, **_setting_columns(setting, order[setting]), status="run",
                             agents=summary.agents, solved=summary.solved,
                             fraction_solved=summary.fraction, fraction_low=summary.fraction_low,
                             fraction_high=summary.fraction_high,
                             median_episodes=summary.median, median_low=summary.median_low,
                             median_high=summary.median_high, budget=summary.budget,
                             median_text=summary.median_text(),
                             agent_episodes=int(run.episodes_run[c].sum()),
                             nonfinite_agents=int(run.nonfinite[c].sum())))
            if drop_unsolved and summary.solved == 0:
                dropped_on[setting] = f"on {size} in {summary.budget} episodes"
        remaining = [s for s in remaining if s not in dropped_on]
        variants.append(dict(
            base, shortest_solution=shortest, settings_run=len(run.settings),
            agents=int(run.episodes_run.size), budget_episodes=budget, chunk_episodes=chunk,
            episodes_reached=reached, stopped=run.stopped,
            agent_episodes=int(run.episodes_run.sum()),
            fixed_budget_agent_episodes=int(run.episodes_run.size) * budget,
            agent_steps=run.agent_steps, training_seconds=run.elapsed_seconds,
            compile_seconds=run.compile_seconds, steps_per_second=run.steps_per_second))
    rank = {task[0]: i for i, task in enumerate(tasks)}
    rows.sort(key=lambda r: (rank[r["size"]], order[_row_setting(r)]))
    options = {"sizes": [t[0] for t in tasks], "seeds": seeds, "episodes": episodes,
               "episodes_per_state": episodes_per_state, "seconds": seconds, "seed": seed,
               "learners": list(learners),
               "methods": [dataclasses.asdict(m) for m in chosen], "fraction": fraction,
               "window": window, "chunk_episodes": chunk_episodes, "max_steps": max_steps,
               "drop_unsolved": drop_unsolved, "quick": quick}
    meta = {"command": command, "options": options,
            "elapsed_seconds": time.perf_counter() - started,
            "settings": [[s.learner, s.explorer, s.param, dict(s.hyperparameters)]
                         for s in settings],
            "parameter_names": {m.explorer: parameter_name(m.explorer) for m in chosen},
            "variants": variants, **versions}
    import jax

    meta.update(jax_version=jax.__version__, backend=jax.default_backend())
    io.write_csv(out / CSV_FILE, rows, ROW_COLUMNS)
    io.save_json(out / META_FILE, meta)
    write_reports(out, rows, variants, meta, figure=figure)
    return ScalingResult(rows, variants, meta, runs)


def write_reports(out_dir: str | Path, rows: Sequence[dict[str, Any]],
                  variants: Sequence[dict[str, Any]], meta: dict[str, Any],
                  figure: bool = True) -> None:
    """``scaling.md`` and (unless ``figure=False``) ``scaling.png`` from a study's rows."""
    out = Path(out_dir)
    io.atomic_write_text(out / MARKDOWN_FILE, scaling_markdown(rows, variants, meta))
    if figure:
        io.save_figure(scaling_figure(rows, variants), out / FIGURE_FILE)


def load_scaling(out_dir: str | Path) -> tuple[list[dict[str, Any]], list[dict[str, Any]],
                                                dict[str, Any]]:
    """``(rows, variants, meta)`` of a folder written by :func:`run_scaling` (no training):
    redraw with :func:`write_reports`, or read the numbers in a notebook.

    Raises:
      ValueError: the folder lacks ``scaling.csv`` or ``meta.json``.
    """
    out = Path(out_dir)
    missing = [f for f in (CSV_FILE, META_FILE) if not (out / f).is_file()]
    if missing:
        raise ValueError(f"scaling folder {str(out)!r} lacks {', '.join(missing)}")
    meta = io.load_json(out / META_FILE)
    remember_parameter_names(meta.get("parameter_names", {}))  # plug-ins not imported here
    settings = [Setting(learner, explorer, param, values)
                for learner, explorer, param, values in meta["settings"]]
    integers = {"config", "states", "actions", "agents", "solved", "budget", "agent_episodes",
                "nonfinite_agents"}
    rows = []
    for raw in io.read_csv(out / CSV_FILE):
        row: dict[str, Any] = {}
        for key, value in raw.items():
            if key in integers:
                row[key] = int(value)
            elif ((key in ROW_COLUMNS[ROW_COLUMNS.index("fraction_solved"):]
                   and key != "median_text")
                  or key in ("best_return", "threshold")):
                row[key] = float(value)
            else:
                row[key] = value
        row["param"] = "" if raw["param"] == "" else float(raw["param"])
        row["_setting"] = settings[row["config"]]
        rows.append(row)
    return rows, list(meta["variants"]), meta


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


def _setting_columns(setting: Setting, config: int) -> dict[str, Any]:
    return {"config": config, "learner": setting.learner, "explorer": setting.explorer,
            "param": setting.param if setting.param is not None else "",
            "method": method_label(setting), "_setting": setting}


def _row_setting(row: dict[str, Any]) -> Setting:
    return row["_setting"]


def _empty_row() -> dict[str, Any]:
    return {"agents": 0, "solved": 0, "fraction_solved": math.nan, "fraction_low": math.nan,
            "fraction_high": math.nan, "median_episodes": math.nan, "median_low": math.nan,
            "median_high": math.nan, "budget": 0, "median_text": "-", "agent_episodes": 0,
            "nonfinite_agents": 0}


# --------------------------------------------------------------------------- outputs


def growth_exponents(rows: Sequence[dict[str, Any]]) -> dict[Setting, tuple[float, int]]:
    """Per setting, the slope of log(median episodes to solve) against log(reachable states)
    (least squares over the variants where its median is defined) and how many variants
    that is; the slope is NaN with fewer than two. 1 = episodes grow in proportion to states.
    """
    points: dict[Setting, list[tuple[float, float]]] = {}
    for r in rows:
        setting = _row_setting(r)
        points.setdefault(setting, [])
        if r["status"] == "run" and math.isfinite(r["median_episodes"]):
            points[setting].append((math.log(r["states"]), math.log(r["median_episodes"])))
    slopes = {}
    for setting, xy in points.items():
        if len({x for x, _ in xy}) < 2:
            slopes[setting] = (math.nan, len(xy))
            continue
        x, y = np.array(xy).T
        slopes[setting] = (float(np.polyfit(x, y, 1)[0]), len(xy))
    return slopes


def scaling_markdown(rows: Sequence[dict[str, Any]], variants: Sequence[dict[str, Any]],
                     meta: dict[str, Any]) -> str:
    """``scaling.md``: the variants, then one row per method with a column per variant
    (median episodes to solve [95% interval], solved/agents) and its growth exponent."""
    from vdbejax.analysis import markdown_table

    options = meta["options"]
    lines = ["# Episodes to solve against task size", ""]
    if meta.get("command"):
        lines += [f"Command: `{meta['command']}`", ""]
    lines += [
        f"Solved = the {options['window']}-episode moving average of an agent's returns reaches"
        f" {options['fraction']:g} × the variant's exact best return (full windows only);"
        f" {options['seeds']} agents per setting; episode budget per variant"
        + (f" max({options['episodes']}, {options['episodes_per_state']:g} × states)"
           if options.get("episodes_per_state") else f" {options['episodes']}")
        + (f", or {options['seconds']:g} s of wall clock" if options.get("seconds") else "")
        + ". Cells: median episodes to solve [95% bootstrap interval] (solved/agents);"
        " \"> B\": censored (half or more of the agents did not solve within B episodes);"
        " \"-\": not run. Exponent: slope of log(median) against log(states) over the variants"
        " with a median (how many in brackets; 1 = proportional to the states).", "",
        "## Variants", ""]
    columns = ["size", "states", "actions", "best_return", "shortest_solution", "settings_run",
               "budget_episodes", "episodes_reached", "stopped", "agent_episodes",
               "fixed_budget_agent_episodes",
               "training_seconds", "compile_seconds", "steps_per_second"]
    table = []
    for v in variants:
        row = dict(v)
        row["steps_per_second"] = (f"{v['steps_per_second'] / 1e6:.2f} M"
                                   if math.isfinite(v["steps_per_second"]) else "-")
        row["training_seconds"] = f"{v['training_seconds']:.1f}"
        row["compile_seconds"] = f"{v['compile_seconds']:.1f}"
        table.append(row)
    lines += [markdown_table(table, columns, digits=2), "", "## Median episodes to solve", ""]
    sizes = [v["size"] for v in variants]
    header = (["method"]
              + [f"{s} ({v['states']})" for s, v in zip(sizes, variants, strict=True)]
              + ["exponent"])
    slopes = growth_exponents(rows)
    pivot: dict[Setting, dict[str, str]] = {}
    for r in rows:
        setting = _row_setting(r)
        cells = pivot.setdefault(setting, {"method": f"{r['method']} ({_param_text(setting)})"})
        cells[f"{r['size']} ({r['states']})"] = (
            "-" if r["status"] != "run" else f"{r['median_text']} ({r['solved']}/{r['agents']})")
    for setting, cells in pivot.items():
        slope, count = slopes[setting]
        cells["exponent"] = "-" if math.isnan(slope) else f"{slope:.2f} ({count})"
    lines += [markdown_table([{c: cells.get(c, "-") for c in header} for cells in pivot.values()],
                             header), ""]
    return "\n".join(lines)


def _param_text(setting: Setting) -> str:
    """``ε = 0.01`` or ``ε = 1, decay = 0.99``: the values the setting sets."""
    symbols = {"epsilon": "ε", "tau": "τ", "sigma": "σ", "beta": "β"}
    values = setting.values
    return ", ".join(f"{symbols.get(k, k)} = {v:g}" if isinstance(v, float) else f"{k} = {v}"
                     for k, v in values.items()) or "default"


def scaling_figure(rows: Sequence[dict[str, Any]], variants: Sequence[dict[str, Any]]) -> Any:
    """One row of panels per learner, one line per method, against reachable states:
    median episodes to solve (log-log, 95% intervals), the same relative to the fastest
    method on each variant (the constant factors the log-log panel hides), and the
    fraction of agents solved within the budget.

    Censored medians are drawn as open triangles at the budget ("> budget"), not joined;
    the methods are spread a little along the state axis so that their bars stay apart.
    """
    import matplotlib

    if "ipykernel" not in sys.modules:  # headless, as vdbejax.plotting; a notebook keeps its own
        matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from vdbejax.methods.api import learner_title

    learners = list(dict.fromkeys(r["learner"] for r in rows))
    explorers = list(dict.fromkeys(r["explorer"] for r in rows))
    colors = {e: plt.get_cmap("tab10")(i % 10) for i, e in enumerate(explorers)}
    height = 3.9 * len(learners) + 0.9
    fig, axes = plt.subplots(len(learners), 3, figsize=(17, height), squeeze=False)
    budgets = [(v["states"], v["episodes_reached"]) for v in variants if v["episodes_reached"]]
    handles: dict[str, Any] = {}
    bars = {"capsize": 2, "elinewidth": 0.8, "markersize": 4}

    def column(mine: list[dict[str, Any]], key: str) -> np.ndarray:
        return np.array([r[key] for r in mine], float)

    for i, learner in enumerate(learners):
        ax_median, ax_relative, ax_fraction = axes[i]
        ran = [r for r in rows if r["learner"] == learner and r["status"] == "run"]
        fastest: dict[str, float] = {}
        for r in ran:
            if math.isfinite(r["median_episodes"]):
                fastest[r["size"]] = min(fastest.get(r["size"], math.inf), r["median_episodes"])
        for j, explorer in enumerate(explorers):
            mine = [r for r in ran if r["explorer"] == explorer]
            if not mine:
                continue
            label = (method_label(_row_setting(mine[0])).split(" ", 1)[1]
                     + f" ({_param_text(_row_setting(mine[0]))})")
            spread = 1.0 + 0.015 * (j - (len(explorers) - 1) / 2)
            x = column(mine, "states") * spread
            median, low, budget = (column(mine, k) for k in ("median_episodes", "median_low",
                                                                "budget"))
            high = column(mine, "median_high")
            high = np.where(np.isfinite(high), high, budget)
            ok = np.isfinite(median)
            line = ax_median.errorbar(x[ok], median[ok], yerr=[median[ok] - low[ok],
                                                               high[ok] - median[ok]],
                                      color=colors[explorer], marker="o", **bars)
            handles.setdefault(label, line)
            if (~ok).any():
                ax_median.plot(x[~ok], budget[~ok], linestyle="none", marker="^",
                               markerfacecolor="none", color=colors[explorer])
            scale = np.array([fastest.get(r["size"], math.nan) for r in mine])
            ax_relative.errorbar(x[ok], median[ok] / scale[ok],
                                 yerr=[(median[ok] - low[ok]) / scale[ok],
                                       (high[ok] - median[ok]) / scale[ok]],
                                 color=colors[explorer], marker="o", **bars)
            fraction = column(mine, "fraction_solved")
            ax_fraction.errorbar(x, fraction, yerr=[fraction - column(mine, "fraction_low"),
                                                    column(mine, "fraction_high") - fraction],
                                 color=colors[explorer], marker="o", alpha=0.85, **bars)
        if budgets:
            bx, by = zip(*budgets, strict=True)
            (budget_line,) = ax_median.plot(bx, by, color="0.6", linestyle=":")
            handles.setdefault("budget (open ▲: median > budget)", budget_line)
        title = learner_title(learner)
        ax_median.set(xscale="log", yscale="log", xlabel="reachable states",
                      ylabel="median episodes to solve", title=f"{title}: episodes to solve")
        ax_relative.set(xscale="log", xlabel="reachable states",
                        ylabel="median / fastest method's median",
                        title=f"{title}: relative to the fastest method")
        ax_fraction.set(xscale="log", ylim=(-0.05, 1.05), xlabel="reachable states",
                        ylabel="fraction of agents solved",
                        title=f"{title}: solved within the budget")
        for ax in (ax_median, ax_relative, ax_fraction):
            ax.grid(alpha=0.3, which="both")
    fig.legend(list(handles.values()), list(handles.keys()), loc="lower center",
               ncol=min(5, len(handles)), fontsize=8, frameon=False)
    fig.tight_layout(rect=(0, 0.9 / height + 0.02, 1, 1))
    return fig


__all__ = [
    "LEARNERS",
    "METHODS",
    "SIZES",
    "AdaptiveRun",
    "Method",
    "ScalingResult",
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
