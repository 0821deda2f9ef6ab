"""Training until solved, the adaptive budget of ``vdbejax scale``.

:func:`run_until_solved` trains a grid chunk by chunk until every agent has solved the task
(:mod:`vdbejax.solving`: its 20-episode moving average reaches 0.9 × the exact best return)
or a budget of episodes or wall-clock seconds is spent. After each chunk the solved agents
leave the batch — they cost no more compute — and the others continue from their state:
each chunk is one :func:`~vdbejax.engine.run_agents` call resumed from ``initial=`` (the
engine is untouched; its resume is bit-identical by design). Every agent draws from its
own random stream, so an agent's returns do not depend on when the others stop: up to its
stop episode they equal, bit for bit, those of a fixed-budget :func:`~vdbejax.run_grid`
with the same settings, seeds and root seed (``tests/test_scaling.py``). Every name here is
also importable from :mod:`vdbejax.scaling`.
"""
from __future__ import annotations

import dataclasses
import math
import sys
import time
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from vdbejax.methods.agents import AgentOptions, Setting, make_agent
from vdbejax.solving import (
    FRACTION,
    TOLERANCE,
    WINDOW,
    SolveTimes,
    episodes_to_solve,
    solve_threshold,
)
from vdbejax.validation import INT32_MAX, UINT32_MAX, check_int, check_positive


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


__all__ = [
    "AdaptiveProgress",
    "AdaptiveRun",
    "run_until_solved",
    "text_progress",
]
