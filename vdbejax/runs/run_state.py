"""Where a run stands: :class:`RunState`, the one resume state (what a checkpoint stores).

A run's agents are independent, so they can run in any grouping with the same results;
the state records, per agent, the episodes done, whether it stopped early (a stop policy,
:mod:`vdbejax.runs.stop`), its NaN flag, and the full engine state of the agents started
but unfinished. Any run resumes from it whatever the batch size, device count or chunk
size.
"""
from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import jax
import numpy as np

from vdbejax.engine import AgentState
from vdbejax.engine.distributed import take_agents
from vdbejax.methods.agents import AgentOptions, Setting


@dataclasses.dataclass
class RunState:
    """Progress of a (possibly batched) run.

    Attributes:
      returns: float32 ``[agents, episodes]`` (zeros past each agent's ``episodes_done``).
      lengths: int32 ``[agents, episodes]``.
      cut: bool ``[agents, episodes]``: the step limit ended the episode
        (:attr:`~vdbejax.engine.RunResult.cut`).
      episodes_done: int64 ``[agents]`` completed episodes per agent.
      stopped: bool ``[agents]``: the agent stopped before ``episodes`` (stop policy).
      nonfinite: bool ``[agents]``: NaN/inf appeared (final for finished agents).
      state_rows: int64 ``[m]`` agents that are started but unfinished.
      state: their :class:`~vdbejax.engine.AgentState` (numpy leaves, leading axis m),
        or None when m = 0.
      policy_values: float32 ``[agents, evaluations]``, the expected return of each
        agent's greedy policy after every ``evaluate_every``-th episode (NaN where not
        evaluated yet, or past an agent's stop; :mod:`vdbejax.runs.evaluation`), or None
        for a run without evaluation.
      optimal: int32 ``[agents, episodes]``, each episode's steps whose action is optimal
        (:mod:`vdbejax.runs.optimal_record`), or None for a run that does not record them.
    """

    returns: np.ndarray
    lengths: np.ndarray
    cut: np.ndarray
    episodes_done: np.ndarray
    stopped: np.ndarray
    nonfinite: np.ndarray
    state_rows: np.ndarray
    state: AgentState | None
    policy_values: np.ndarray | None = None
    optimal: np.ndarray | None = None

    @classmethod
    def fresh(cls, num_agents: int, num_episodes: int,
              evaluate_every: int | None = None, record_optimal: bool = False) -> RunState:
        """Nothing done yet (``evaluate_every``: room for the evaluations;
        ``record_optimal``: for the counts of optimal actions)."""
        return cls(
            returns=np.zeros((num_agents, num_episodes), np.float32),
            lengths=np.zeros((num_agents, num_episodes), np.int32),
            cut=np.zeros((num_agents, num_episodes), bool),
            episodes_done=np.zeros(num_agents, np.int64),
            stopped=np.zeros(num_agents, bool),
            nonfinite=np.zeros(num_agents, bool),
            state_rows=np.zeros(0, np.int64),
            state=None,
            policy_values=(None if evaluate_every is None else np.full(
                (num_agents, num_episodes // evaluate_every), np.nan, np.float32)),
            optimal=(np.zeros((num_agents, num_episodes), np.int32) if record_optimal
                     else None),
        )

    @property
    def num_episodes(self) -> int:
        return int(self.returns.shape[1])

    @property
    def finished(self) -> np.ndarray:
        """bool ``[agents]``: ran its budget or stopped early."""
        return self.stopped | (self.episodes_done >= self.num_episodes)

    def add_episodes(self, rows: np.ndarray, start: int, done: int | np.ndarray,
                     episodes: tuple[np.ndarray, ...]) -> None:
        """Store the episodes of agents ``rows`` from ``start`` on: ``episodes`` is
        ``(returns, lengths, cut)`` and, in a run that records them, ``optimal`` after
        them, each ``[rows, width]`` (zeros past each agent's episodes done, but for the
        running episode's count of optimal actions so far); they have done ``done``
        episodes (one number, or one per agent)."""
        returns, lengths, cut, *optimal_part = episodes
        optimal = optimal_part[0] if optimal_part else None
        stop = start + returns.shape[1]
        self.returns[rows, start:stop] = returns
        self.lengths[rows, start:stop] = lengths
        self.cut[rows, start:stop] = cut
        if self.optimal is not None:
            assert optimal is not None  # the engine counts them in a run that records them
            self.optimal[rows, start:stop] = optimal
        self.episodes_done[rows] = done

    def set_agents(self, rows: np.ndarray, agents: AgentState | None,
                   nonfinite: np.ndarray | None = None) -> None:
        """Store the states of agents ``rows`` where they are unfinished, and their NaN
        flags (``nonfinite``, or those of ``agents``).

        ``agents`` may hold device arrays: only what is kept is copied to numpy; it may be
        ``None`` given ``nonfinite`` when no row needs its state kept.
        """
        if nonfinite is None:
            assert agents is not None  # the states may be None only given nonfinite
            nonfinite = np.asarray(agents.nonfinite)
        self.nonfinite[rows] = np.asarray(nonfinite)
        unfinished = self.episodes_done[rows] < self.num_episodes
        kept = rows  # (the finished ones' states are dropped)
        if unfinished.any():
            assert agents is not None, "unfinished agents need their states"
            if not unfinished.all():
                kept, agents = rows[unfinished], take_agents(agents, unfinished)
        else:
            agents = None
        self._keep_states(rows, kept, agents)

    def stop(self, rows: np.ndarray) -> None:
        """Agents ``rows`` stop where they are (a stop policy): their states are dropped."""
        self.stopped[rows] = True
        self._keep_states(rows, rows, None)

    def _keep_states(self, rows: np.ndarray, kept: np.ndarray,
                     agents: AgentState | None) -> None:
        """The states of agents ``rows`` replaced by ``agents``, those of ``kept``."""
        keep = ~np.isin(self.state_rows, rows)
        row_parts, state_parts = [], []
        if keep.any():
            row_parts.append(self.state_rows[keep])
            state_parts.append(take_agents(self.state, keep))
        if agents is not None:
            row_parts.append(np.asarray(kept, np.int64))
            state_parts.append(jax.tree.map(np.asarray, agents))
        self.state_rows = np.concatenate(row_parts) if row_parts else np.zeros(0, np.int64)
        self.state = (jax.tree.map(lambda *leaves: np.concatenate(leaves), *state_parts)
                      if state_parts else None)

    def states_of(self, rows: np.ndarray) -> AgentState:
        """The stored states of agents ``rows`` (each must be started and unfinished)."""
        position = {int(r): i for i, r in enumerate(self.state_rows)}
        try:
            index = np.asarray([position[int(r)] for r in rows])
        except KeyError as missing:
            raise ValueError(f"checkpoint lacks the state of agent {missing}") from None
        assert self.state is not None  # agents in progress: their states are stored
        return take_agents(self.state, index)

    def resume_point(self, rows: np.ndarray) -> tuple | None:
        """The engine's ``initial=`` for agents ``rows`` (all started, or none: then
        None), with their records up to their latest running episode (its count of
        optimal actions so far: a checkpoint may fall mid-episode)."""
        if not np.isin(rows, self.state_rows).any():
            return None
        done = self.episodes_done[rows]
        upto = min(int(done.max()) + 1, self.num_episodes)
        point = (done, self.states_of(rows), self.returns[rows, :upto],
                 self.lengths[rows, :upto], self.cut[rows, :upto])
        return point if self.optimal is None else (*point, self.optimal[rows, :upto])

    def next_batch(self, batch_size: int, chunk: int | None = None) -> np.ndarray:
        """Agents of the next batch: up to ``batch_size`` unfinished agents, the started
        ones (whose state is stored) first, then fresh ones; empty when every agent is
        finished. With ``chunk`` (a stop policy's chunks, ended by its multiples), only
        agents in the chunk of the least advanced one (its end included: an agent of a
        checkpoint taken mid-chunk may have finished the chunk before the others)."""
        pending = np.flatnonzero(~self.finished)
        if pending.size == 0:
            return pending
        started = np.isin(pending, self.state_rows)
        group = pending[started] if started.any() else pending
        if chunk is not None:
            group = group[self.episodes_done[group] <= self.chunk_start(group, chunk) + chunk]
        return group[:batch_size]

    def chunk_start(self, rows: np.ndarray, chunk: int) -> int:
        """The first episode of the chunk (of a stop policy's, ended by the multiples of
        ``chunk``) that holds the least advanced of agents ``rows``."""
        least = int(self.episodes_done[rows].min())
        return least - least % chunk

    def episodes_credited(self) -> int:
        """Agent-episodes done, a stopped agent credited with its whole budget (what a
        progress bar counts: it reaches the total when every agent is finished)."""
        return int(np.where(self.stopped, self.num_episodes, self.episodes_done).sum())


def nonfinite_message(settings: Sequence[Setting], nonfinite: np.ndarray,
                      options: AgentOptions) -> str | None:
    """One line naming every config whose agents saw NaN/inf in Q or ε, or None.

    Args:
      settings: the grid's configurations.
      nonfinite: bool ``[configs, seeds]``.
      options: the options shared by all agents (part of the config that produced it).
    """
    counts = np.asarray(nonfinite).sum(axis=1)
    bad = [f"{settings[int(c)].label} ({counts[c]}/{nonfinite.shape[1]} agents)"
           for c in np.flatnonzero(counts)]
    if not bad:
        return None
    return (f"NaN or inf appeared in Q or ε, or an invalid action was drawn, for: {'; '.join(bad)}"
            f" [options {dataclasses.asdict(options)}]")
