"""Statistics of a grid (:class:`~vdbejax.experiment.GridResult`): the summary table,
pairwise comparisons, truncation diagnostics and ε(s) snapshots.

The array-level statistics and their conventions (smoothing, final return, convergence
episode, bootstrap intervals, IQM, probability of improvement) live in
:mod:`vdbejax.stats` and are re-exported here.
"""
from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from vdbejax.agents import AgentOptions, Setting, make_agent, stack_agents
from vdbejax.engine import AgentState, agent_keys, broadcast_agents, run_agents
from vdbejax.envs.tabular import TabularMDP
from vdbejax.experiment import GridResult
from vdbejax.stats import (  # noqa: F401  (re-exported: the historical home of these names)
    FRACTION,
    LAST,
    LEVEL,
    NUM_RESAMPLES,
    WINDOW,
    bootstrap_ci,
    bootstrap_indices,
    convergence_ci,
    convergence_episode,
    convergence_episodes,
    final_return,
    final_return_ci,
    interquartile_mean,
    mean_curve_ci,
    moving_average,
    probability_of_improvement_ci,
)


def truncated_fraction(lengths: np.ndarray, max_steps: int | None, last: int = LAST) -> np.ndarray:
    """Fraction of the last ``last`` episodes that ran into ``max_steps`` (per leading index).

    An agent stuck in a loop (e.g. SARSA + VDBE with all actions valued ≈ −0.1) shows up
    as a fraction near 1. ``max_steps=None`` (unknown) gives NaN.

    Args:
      lengths: ``[..., episodes]`` episode lengths.
      max_steps: the truncation length, or ``None`` if unknown.
      last: number of final episodes considered.

    Returns:
      float64 ``[...]`` fractions in [0, 1] (NaN when ``max_steps`` is None).
    """
    lengths = np.asarray(lengths)[..., -last:]
    if max_steps is None:
        return np.full(lengths.shape[:-1], np.nan)
    return (lengths >= max_steps).mean((-1,))


def summarize(result: GridResult, last: int = LAST, window: int = WINDOW) -> list[dict]:
    """One row per config: final return and convergence episode, each with its 95%
    bootstrap CI over seeds, and diagnostics.

    Args:
      result: the grid.
      last: episodes defining the final return.
      window: smoothing window of the convergence criterion.

    Returns:
      rows with the columns of :data:`SUMMARY_COLUMNS`: ``config, learner, explorer,
      param, final_return, final_ci_low, final_ci_high, final_iqm, convergence_episode,
      convergence_ci_low, convergence_ci_high, truncated_fraction, mean_length,
      nonfinite_agents``.
    """
    rows = []
    last = min(last, result.num_episodes)
    max_steps = result.meta.get("max_steps")
    for c, setting in enumerate(result.settings):
        returns = result.returns[c]
        final, final_low, final_high = final_return_ci(returns, last)
        episode, episode_low, episode_high = convergence_ci(returns, window, last)
        rows.append(
            {
                "config": c,
                "learner": setting.learner,
                "explorer": setting.explorer,
                "param": setting.param,
                "final_return": final,
                "final_ci_low": final_low,
                "final_ci_high": final_high,
                "final_iqm": float(interquartile_mean(final_return(returns, last))),
                "convergence_episode": episode,
                "convergence_ci_low": episode_low,
                "convergence_ci_high": episode_high,
                # Fraction over all seeds of the last episodes cut off at max_steps.
                "truncated_fraction": float(truncated_fraction(result.lengths[c], max_steps, last).mean()),
                "mean_length": float(result.lengths[c].mean()),
                "nonfinite_agents": int(result.nonfinite[c].sum()),
            }
        )
    return rows


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
    "truncated_fraction",
    "mean_length",
    "nonfinite_agents",
]


def probability_of_improvement_matrix(
    result: GridResult, configs: list[int] | None = None, last: int = LAST
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Pairwise probability that config i beats config j on final return, with CIs.

    Args:
      result: the grid.
      configs: config indices to compare (default all).
      last: episodes defining the final return.

    Returns:
      ``(p, low, high)``, each ``[k, k]`` for the ``k`` configs (diagonal 0.5).
    """
    configs = list(range(len(result.settings))) if configs is None else list(configs)
    finals = final_return(result.returns[configs], min(last, result.num_episodes))
    k = len(configs)
    p, low, high = (np.full((k, k), 0.5) for _ in range(3))
    for i in range(k):
        for j in range(k):
            if i != j:
                p[i, j], low[i, j], high[i, j] = probability_of_improvement_ci(finals[i], finals[j])
    return p, low, high


def epsilon_snapshots(
    mdp: TabularMDP,
    setting: Setting,
    *,
    num_seeds: int = 5,
    num_episodes: int = 300,
    every: int = 10,
    seed: int = 0,
    options: AgentOptions | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Train one setting and record the agents' per-state ε(s) every ``every`` episodes.

    Uses the engine's ``on_chunk`` callback, so the learning itself is the ordinary run
    (bit-identical to the same agents inside any grid).

    Args:
      mdp: the task (:class:`~vdbejax.envs.tabular.TabularMDP`).
      setting: a :class:`~vdbejax.agents.Setting` (VDBE or VDBE-Softmax to see ε(s) move).
      num_seeds: agents.
      num_episodes: episodes per agent.
      every: episodes between snapshots (the chunk size).
      seed: root seed.
      options: :class:`~vdbejax.agents.AgentOptions` (spec defaults if None).

    Returns:
      ``(episodes, epsilon, returns)``: ``[k]`` episode counts of the snapshots,
      ``[k, seeds, S]`` ε(s) after those episodes, ``[seeds, episodes]`` returns.
    """
    options = AgentOptions() if options is None else options
    params = broadcast_agents(stack_agents([make_agent(setting, options)]), num_seeds)
    episodes, snapshots = [], []

    def record(done: int, agents: AgentState, returns: np.ndarray, lengths: np.ndarray) -> None:
        episodes.append(done)
        snapshots.append(np.array(agents.epsilon))

    run = run_agents(mdp, params, agent_keys(seed, num_seeds), num_episodes,
                     chunk_episodes=every, on_chunk=record)
    return np.asarray(episodes), np.stack(snapshots), run.returns


def action_probabilities(
    q: np.ndarray, explorer: str, param: float, state_epsilon: float = 1.0,
    tie_break: str = "random",
) -> np.ndarray:
    """Exact probability of each action under an explorer (what ``select_action`` samples).

    ``P = p·softmax_τ(Q) + (1 − p)·greedy(Q)``, with the explorer's exploration
    probability ``p`` (ε, 1, or ``state_epsilon`` for the VDBE kinds) and temperature ``τ``
    (∞ = uniform); greedy spreads its mass over the maximal actions (random tie-break) or
    puts it on the first (``"first"``).

    Args:
      q: ``[num_actions]`` action values of one state.
      explorer: ``egreedy``, ``softmax``, ``vdbe`` or ``vdbe_softmax``.
      param: its swept parameter (ε, τ or σ).
      state_epsilon: ε(s) for VDBE and VDBE-Softmax.
      tie_break: ``"random"`` or ``"first"``.

    Returns:
      float64 ``[num_actions]`` probabilities summing to 1.
    """
    from vdbejax.explorers import make_explorer, softmax_probabilities

    params = make_explorer(explorer, param, tie_break=tie_break)
    q = np.asarray(q, np.float64)
    explore = state_epsilon if bool(params.adaptive) else float(params.epsilon)
    exploratory = np.asarray(softmax_probabilities(q, float(params.tau)), np.float64)
    maximal = (q == q.max()).astype(np.float64)
    if tie_break == "first":
        maximal = np.eye(len(q))[np.argmax(q)]
    greedy = maximal / maximal.sum()
    return explore * exploratory + (1.0 - explore) * greedy


def markdown_table(rows: Sequence[dict[str, Any]], columns: Sequence[str], digits: int = 3) -> str:
    """Rows as a markdown table (floats rounded to ``digits``), e.g. for notebooks.

    Args:
      rows: dictionaries holding at least ``columns``.
      columns: the columns, in order.
      digits: decimals of float cells.

    Returns:
      markdown text.
    """
    def cell(value: Any) -> str:
        if not isinstance(value, (float, np.floating)):
            return str(value)
        # Tiny parameters (τ = 0.0001) would round to 0: show them in full.
        return f"{value:g}" if 0 < abs(value) < 10.0 ** -digits else f"{value:.{digits}f}"

    lines = ["| " + " | ".join(columns) + " |", "| " + " | ".join("---" for _ in columns) + " |"]
    lines += ["| " + " | ".join(cell(r[c]) for c in columns) + " |" for r in rows]
    return "\n".join(lines)
