"""What the engine chooses by the backend and the work, by fixed rules measured once
(never timed at run time): the strategy (:func:`auto_strategy`), whether the lockstep's
kinds share a batch (:func:`mixes_kinds`) and its batches' width
(:func:`default_max_batch`).
"""
from __future__ import annotations

import jax
import numpy as np

from vdbejax.engine.agent_state import AgentState
from vdbejax.engine.lanes import lanes_within_index
from vdbejax.engine.lockstep import MAX_SAFE_BATCH
from vdbejax.methods.agents import AgentParams


def auto_strategy(num_agents: int, *, backend: str | None = None,
                  sharded: bool = False) -> tuple[str, str]:
    """The strategy ``"auto"`` runs, and why: lockstep on an accelerator or for agents
    sharded over several devices; sequential on a CPU, at every number of agents
    (``python -m benchmarks.auto_rule``: on 2 cores the sequential strategy was the faster
    at 920, 9,200 and 46,000 agents, ``benchmarks/RESULTS.md``; measured once, not timed
    at run time).

    Returns:
      ``(strategy, reason)``; the reason is one line for ``meta.json``.
    """
    backend = jax.default_backend() if backend is None else backend
    if sharded:
        return "lockstep", "agents sharded over several devices"
    if backend != "cpu":
        return "lockstep", f"backend {backend}"
    return "sequential", f"cpu, {num_agents} agents (sequential is the faster on a CPU)"


def default_max_batch(agents: AgentState, params: AgentParams, chunk_length: int,
                      backend: str) -> int:
    """Lanes of a lockstep batch by default. On a CPU :data:`MAX_SAFE_BATCH` (larger
    batches were not bit-identical there). On an accelerator every agent of a group in one
    batch: its chunk then takes as many iterations as its slowest agent, where batches of
    :data:`MAX_SAFE_BATCH` lanes take that for every batch of agents streamed through
    them, and an iteration costs its kernels' launches whatever the lanes (results there
    agree with the CPU's statistically, not to the bit). Either way no more lanes than
    ``int32`` indexes in the flat buffers: tables, episode buffers of ``chunk_length``
    and the agents' own task instances in ``params``
    (:func:`~vdbejax.engine.lanes.lanes_within_index`)."""
    num_agents = int(agents.episode.shape[0])
    per_agent = max([chunk_length] + [int(np.prod(getattr(leaf, "shape", ())[1:])) for leaf in
                                      jax.tree.leaves((agents.q, agents.tables, params))])
    lanes = MAX_SAFE_BATCH if backend == "cpu" else max(num_agents, 1)
    return min(lanes, lanes_within_index(per_agent))


def mixes_kinds(backend: str | None = None) -> bool:
    """Whether the lockstep strategy runs several kinds in one batch by default: on an
    accelerator, where an iteration costs its kernels' launches whatever the lanes do,
    so one batch of every kind takes the iterations of its slowest agent instead of
    the sum over kinds; not on a CPU, where an iteration costs the lanes' work and a
    mixed batch does every kind's work on every lane (``python -m benchmarks.lockstep``,
    its mixed row; ``benchmarks/RESULTS.md``)."""
    return (jax.default_backend() if backend is None else backend) != "cpu"
