"""Training until solved, the adaptive budget of ``vdbejax scale``.

:func:`run_until_solved` is :func:`~vdbejax.run_grid` with the stop policy
:class:`~vdbejax.runs.UntilSolved`: chunk by chunk until every agent has solved the task
(:mod:`vdbejax.results.solving`: its 20-episode moving average reaches a normalised score of
0.9, 0 the uniformly random policy's expected return and 1 the exact best) or a budget of
episodes or wall-clock seconds is spent. After each chunk the solved agents
leave the batch — they cost no more compute — and the others continue from their state.
Every agent draws from its own random stream, so an agent's returns do not depend on when
the others stop: up to its stop episode they equal, bit for bit, those of a fixed-budget
:func:`~vdbejax.run_grid` with the same settings, seeds and root seed
(``tests/test_scaling.py``).
"""
from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from vdbejax.methods.agents import AgentOptions, Setting
from vdbejax.results.curves import WINDOW
from vdbejax.results.grid_result import GridResult
from vdbejax.results.policy import policy_summary
from vdbejax.results.solving import FRACTION, SolveTimes, episodes_to_converge
from vdbejax.runs.options import RunOptions, study_run


@dataclasses.dataclass
class AdaptiveRun:
    """A grid trained until solved or out of budget (:func:`run_until_solved`).

    Attributes:
      settings: the configurations, in config-index order.
      returns: float32 ``[configs, seeds, max_episodes]``; NaN past an agent's stop.
      lengths: int32, same shape; 0 past an agent's stop.
      episodes_run: int64 ``[configs, seeds]``: episodes each agent ran (its stop episode).
      solve: :class:`~vdbejax.results.solving.SolveTimes` ``[configs, seeds]``.
      nonfinite: bool ``[configs, seeds]``.
      best, baseline: the exact best return and the uniformly random policy's;
        ``fraction``, ``window``: the solve criterion (a normalised score).
      max_episodes, max_seconds: the budget.
      stopped: ``"solved"`` (every agent), ``"episodes"`` or ``"seconds"`` (budget spent).
      elapsed_seconds: wall clock of the training (engine programs included).
      compile_seconds: of which getting the engine's programs.
      chunks: engine calls made.
      policy: per config, :func:`~vdbejax.results.policy.policy_summary` of the agents'
        greedy policies (a run with ``evaluate_every``; else None).
    """

    settings: list[Setting]
    returns: np.ndarray
    lengths: np.ndarray
    episodes_run: np.ndarray
    solve: SolveTimes
    nonfinite: np.ndarray
    best: float
    baseline: float
    fraction: float
    window: int
    max_episodes: int
    max_seconds: float | None
    stopped: str
    elapsed_seconds: float
    compile_seconds: float
    chunks: int
    policy: list[dict[str, Any]] | None = None

    @property
    def agent_steps(self) -> int:
        """Environment steps of every agent together."""
        return int(self.lengths.sum(dtype=np.int64))

    @property
    def steps_per_second(self) -> float:
        """Agent-steps per second of engine time (programs excluded)."""
        return self.agent_steps / max(self.elapsed_seconds - self.compile_seconds, 1e-9)


#: The run options :func:`run_until_solved` takes (its stop policy is built from its
#: arguments).
UNTIL_SOLVED_RUN_FIELDS = tuple(field.name for field in dataclasses.fields(RunOptions)
                                if field.name != "stop")


def run_until_solved(
    mdp: Any,
    settings: Sequence[Setting],
    *,
    num_seeds: int,
    max_episodes: int,
    max_seconds: float | None = None,
    best: float | None = None,
    baseline: float | None = None,
    fraction: float = FRACTION,
    window: int = WINDOW,
    seed: int = 0,
    options: AgentOptions = AgentOptions(),
    run: RunOptions | None = None,
) -> AdaptiveRun:
    """Train ``settings × num_seeds`` agents until each has solved ``mdp`` or the budget ends.

    :func:`~vdbejax.run_grid` with the stop policy :class:`~vdbejax.runs.UntilSolved`:
    after each chunk of ``run.chunk_episodes`` episodes, an agent whose moving average has
    reached a normalised score of ``fraction``
    (:func:`~vdbejax.results.solving.episodes_to_converge`) stops at the
    end of that chunk (its stop episode, :attr:`AdaptiveRun.episodes_run`). The run ends
    when no agent is left, after ``max_episodes`` episodes, or after the first chunk that
    ends past ``max_seconds`` of wall clock (then every remaining agent is censored there;
    which episode depends on the machine's speed, so the episode budget is the
    reproducible one). Checkpoints, resume, batching and sharding come with ``run``.

    Agents ``(config c, seed i)`` have the keys and hyperparameters of :func:`~vdbejax.run_grid`,
    so an agent's returns up to its stop are bit-identical to a fixed budget's.

    Args:
      mdp: the task.
      settings: the configurations.
      num_seeds: agents per setting.
      max_episodes: episode budget per agent.
      max_seconds: wall-clock budget of the whole run (None: no limit).
      best: the exact best return (default :func:`vdbejax.envs.solvers.best_return` of ``mdp``).
      baseline: the uniformly random policy's expected return, given with ``best``
        (default :func:`vdbejax.envs.solvers.uniform_random_return` of ``mdp``).
      fraction, window: the solve criterion (a normalised score, 0.9 by default).
      seed: root seed.
      options: values shared by every agent (α, γ, …).
      run: how it runs (:class:`~vdbejax.runs.RunOptions`: chunks, progress, threads,
        checkpoint, resume, devices, memory budget; its stop is the one above).
        ``run.chunk_episodes`` is the episodes between stop checks (default 100; the
        results do not depend on it, the stop episodes do).

    Returns:
      the :class:`AdaptiveRun`.

    Raises:
      ValueError: any invalid input, before training.
    """
    from vdbejax.engine import compile_seconds
    from vdbejax.runs import UntilSolved, run_grid
    from vdbejax.validation import INT32_MAX, check_int

    run = study_run(run, "run_until_solved", UNTIL_SOLVED_RUN_FIELDS, RunOptions())
    check_int("max_episodes", max_episodes, 1, INT32_MAX)  # named as the caller knows it
    stop = UntilSolved(best=best, baseline=baseline, fraction=fraction, window=window,
                       max_seconds=max_seconds)
    run = run.replace(stop=stop, chunk_episodes=run.chunk_episodes or 100)
    compiled_before = compile_seconds()
    result = run_grid(mdp, settings, num_seeds=num_seeds, num_episodes=max_episodes, seed=seed,
                      options=options, run=run)
    return adaptive_run(result, compile_seconds() - compiled_before)


def adaptive_run(result: GridResult, compile_seconds: float = 0.0) -> AdaptiveRun:
    """The :class:`AdaptiveRun` view of a result trained :class:`~vdbejax.runs.UntilSolved`."""
    stop = result.meta["stop"]
    if stop.get("baseline") is None:
        raise ValueError("the result's stop policy has no baseline: it was trained before"
                         " 'solved' became a normalised score of 0.9; train it again")
    max_episodes = result.num_episodes
    episodes_run = (np.full(result.returns.shape[:2], max_episodes, np.int64)
                    if result.episodes_run is None else result.episodes_run)
    solve = episodes_to_converge(result.returns, stop["best"], stop["baseline"],
                                 fraction=stop["fraction"], window=stop["window"],
                                 episodes_run=episodes_run)
    return AdaptiveRun(
        settings=list(result.settings), returns=result.returns, lengths=result.lengths,
        episodes_run=episodes_run, solve=solve, nonfinite=result.nonfinite,
        best=float(stop["best"]), baseline=float(stop["baseline"]),
        fraction=float(stop["fraction"]), window=int(stop["window"]),
        max_episodes=max_episodes, max_seconds=stop["max_seconds"], stopped=result.meta["stopped"],
        elapsed_seconds=float(result.meta["elapsed_seconds"]), compile_seconds=compile_seconds,
        chunks=int(result.meta["batches"]),
        policy=policy_summary(result) if result.policy_values is not None else None,
    )


def train_until_solved(folder: Path, mdp: Any, settings: list[Setting], *, seeds: int,
                       budget: int, stop: Any, seed: int, options: RunOptions,
                       task: str) -> AdaptiveRun:
    """``settings × seeds`` agents trained until solved (``stop``, an
    :class:`~vdbejax.runs.UntilSolved`) into the result folder ``folder``
    (:func:`~vdbejax.studies.train_in_folder`: checkpointed, resumable); ``task`` is
    recorded in its ``meta.json``."""
    from vdbejax.engine import compile_seconds
    from vdbejax.runs import prepare_grid
    from vdbejax.studies.folder import train_in_folder

    prepared = prepare_grid(mdp, settings, num_seeds=seeds, num_episodes=budget, seed=seed,
                            run=options.replace(stop=stop))
    compiled_before = compile_seconds()
    result, _ = train_in_folder(
        folder, prepared, lambda result, stats: None, files=[], statistics=False,
        annotate=lambda result: result.meta.update(
            task=task, compile_seconds=compile_seconds() - compiled_before))
    return adaptive_run(result, float(result.meta.get("compile_seconds", 0.0)))


__all__ = [
    "AdaptiveRun",
    "run_until_solved",
    "train_until_solved",
]
