"""Watching an agent's tables evolve: train one setting and record a table (VDBE's ε(s),
UCB-1's counts, the action values Q, …) every few episodes (:func:`table_snapshots`; with
``every = num_episodes``, the agents' final tables).

A study on the engine's run path (its ``on_chunk`` callback), not a statistic: it trains.
"""
from __future__ import annotations

import numpy as np

from vdbejax.engine import (
    AgentState,
    ChunkHooks,
    EngineOptions,
    agent_keys,
    broadcast_agents,
    run_agents,
)
from vdbejax.envs.tabular import TabularMDP
from vdbejax.methods.agents import AgentOptions, Setting, make_agent, stack_agents, table_layout


def table_snapshots(
    mdp: TabularMDP,
    setting: Setting,
    *,
    num_seeds: int = 5,
    num_episodes: int = 300,
    every: int = 10,
    seed: int = 0,
    options: AgentOptions | None = None,
    table: str = "epsilon",
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Train one setting and record one of the agents' tables (VDBE's per-state ε(s) by
    default, UCB-1's ``"counts"``, the action values ``"q"``, …) every ``every`` episodes.

    Uses the engine's ``on_chunk`` callback, so the learning itself is the ordinary run
    (bit-identical to the same agents inside any grid).

    Args:
      mdp: the task (:class:`~vdbejax.envs.tabular.TabularMDP`).
      setting: a :class:`~vdbejax.methods.agents.Setting` (VDBE or VDBE-Softmax to see ε(s) move).
      num_seeds: agents.
      num_episodes: episodes per agent.
      every: episodes between snapshots (the chunk size).
      seed: root seed.
      options: :class:`~vdbejax.methods.agents.AgentOptions` (spec defaults if None).
      table: the table to record: ``"q"`` (every agent's ``[S, A]`` action values) or a
        table of the setting's explorer or learner.

    Returns:
      ``(episodes, snapshots, returns)``: ``[k]`` episode counts of the snapshots,
      ``[k, seeds, S]`` (or ``[k, seeds, S, A]``) table values after those episodes,
      ``[seeds, episodes]`` returns.

    Raises:
      ValueError: the setting's agents keep no table ``table``.
    """
    options = AgentOptions() if options is None else options
    params = broadcast_agents(stack_agents([make_agent(setting, options)]), num_seeds)
    kept = table_layout(params)
    if table != "q" and table not in kept:
        raise ValueError(f"table={table!r} is invalid: {setting.label} keeps"
                         f" q and {', '.join(kept) or 'no tables of its own'}")
    episodes, snapshots = [], []

    def record(done: int | np.ndarray, agents: AgentState | None, returns: np.ndarray,
               lengths: np.ndarray, cut: np.ndarray) -> None:
        if np.ndim(done):  # a piece of a chunk of very long episodes: no snapshot there
            return
        assert agents is not None  # chunk states are on by default
        episodes.append(done)
        snapshots.append(np.array(agents.q if table == "q" else agents.tables[table]))

    run = run_agents(mdp, params, agent_keys(seed, num_seeds), num_episodes,
                     EngineOptions(chunk_episodes=every), ChunkHooks(on_chunk=record))
    return np.asarray(episodes), np.stack(snapshots), run.returns


#: The former name (ε(s) is the default table).
epsilon_snapshots = table_snapshots
