"""Memory-aware batching: run a sweep in sequential batches that fit a memory budget.

A sweep's agents are independent, so they can run in any grouping with the same results.
When the per-device memory of all agents (Q tables, VDBE ε tables, chunk buffers) exceeds
the budget, :func:`run_batched` runs them in sequential batches of at most
:func:`agents_per_batch` agents, each batch sharded over all devices
(:mod:`vdbejax.distributed`). Progress is kept in a :class:`SweepProgress`, which is what
a checkpoint stores: any run can be resumed whatever the batch size or device count.
"""
from __future__ import annotations

import dataclasses
import os
import shutil
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import jax
import numpy as np

from vdbejax.distributed import run_sharded, take_agents
from vdbejax.engine import AgentState, ProgressCallback
from vdbejax.engine.state import state_bytes
from vdbejax.envs.tabular import TabularMDP
from vdbejax.validation import check_int

#: Fraction of a device's free memory used when no budget is given.
DEFAULT_MEMORY_FRACTION = 0.5
#: Working copies of the agent state the engine may hold at once (the state, its
#: compacted copy, the loop's double buffer): the estimate is deliberately conservative.
STATE_COPIES = 3
#: Bytes of the per-agent scalars (state fields, key, hyperparameters), rounded up.
SCALAR_BYTES = 128


def bytes_per_agent(mdp: TabularMDP, chunk_episodes: int,
                    layout: dict[str, str] | None = None) -> int:
    """Estimated device memory of one agent: Q and its other tables, scalars, chunk buffers.

    Args:
      mdp: the task (sets the table sizes).
      chunk_episodes: episodes per engine chunk (sets the buffer sizes).
      layout: the agents' tables beside Q (:func:`~vdbejax.methods.agents.table_layout`;
        default: one per-state table, the paper's ε(s)).

    Returns:
      bytes, for :data:`STATE_COPIES` working copies.
    """
    tables = state_bytes(mdp, {"epsilon": "state"} if layout is None else layout)
    chunk_buffers = 8 * chunk_episodes  # float32 return + int32 length per episode
    return STATE_COPIES * (tables + SCALAR_BYTES + chunk_buffers)


def mdp_bytes(mdp: TabularMDP) -> int:
    """Device memory of the MDP tables (replicated on every device)."""
    return int(sum(np.asarray(leaf).nbytes for leaf in jax.tree.leaves(mdp)))


def _host_available_bytes() -> int:
    """Free host RAM: ``MemAvailable`` from /proc/meminfo, else total physical memory."""
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")


#: Host bytes per agent-episode of a grid's results: float32 returns and int32 lengths,
#: once as the run's records and once as the returned arrays.
RESULT_BYTES_PER_EPISODE = 16
#: Host bytes per agent besides its episodes (hyperparameters, key, progress, summary).
RESULT_BYTES_PER_AGENT = 512
#: Bytes per agent-episode of a checkpoint's episode log (returns and lengths).
LOG_BYTES_PER_EPISODE = 8


def check_run_size(num_agents: int, num_episodes: int, checkpoint: Any = None,
                   available_bytes: int | None = None) -> int:
    """Refuse, before anything is allocated, a run whose results cannot fit.

    Args:
      num_agents: agents of the run.
      num_episodes: episodes per agent.
      checkpoint: the checkpoint path, if any (its episode log needs disk space).
      available_bytes: free host memory (default: ``MemAvailable``).

    Returns:
      the estimated host bytes of the results.

    Raises:
      ValueError: the results need more memory than is free, or the checkpoint log more
        disk space: one line with the estimate and the limit.
    """
    needed = num_agents * (num_episodes * RESULT_BYTES_PER_EPISODE + RESULT_BYTES_PER_AGENT)
    available = _host_available_bytes() if available_bytes is None else available_bytes
    if needed > available:
        raise ValueError(
            f"num_seeds × num_episodes is too large: {num_agents:,} agents × {num_episodes:,}"
            f" episodes need ≈ {_size(needed)} of memory for their results, but"
            f" {_size(available)} are free: use fewer seeds or episodes, or split the run")
    if checkpoint is not None:
        folder = Path(checkpoint).parent
        log = num_agents * num_episodes * LOG_BYTES_PER_EPISODE
        try:
            free = shutil.disk_usage(folder if folder.exists() else Path.cwd()).free
        except OSError:
            free = None
        if free is not None and log > free:
            raise ValueError(
                f"checkpoint={str(checkpoint)!r} is invalid: its episode log would need ≈"
                f" {_size(log)} of disk, but {_size(free)} are free there")
    return needed


def _size(num_bytes: float) -> str:
    for unit in ("B", "KiB", "MiB", "GiB", "TiB", "PiB"):
        if num_bytes < 1024 or unit == "PiB":
            return f"{num_bytes:,.1f} {unit}" if unit != "B" else f"{int(num_bytes)} B"
        num_bytes /= 1024
    return f"{num_bytes:.1f} PiB"


def device_free_bytes(device: jax.Device) -> int:
    """Free memory of ``device``; CPU devices share the host's free RAM equally."""
    try:
        stats = device.memory_stats()
    except Exception:  # backends without memory statistics (CPU) raise or return None
        stats = None
    if stats and "bytes_limit" in stats:
        return int(stats["bytes_limit"]) - int(stats.get("bytes_in_use", 0))
    same_host = [d for d in jax.local_devices() if d.platform == device.platform]
    return _host_available_bytes() // max(len(same_host), 1)


def default_memory_budget(devices: Sequence[jax.Device] | None = None) -> int:
    """``DEFAULT_MEMORY_FRACTION`` of the smallest free memory among ``devices`` (bytes).

    Args:
      devices: candidate devices (default: this process's); only those of this process
        count, unless none is.

    Returns:
      the per-device budget in bytes.
    """
    devices = list(jax.local_devices() if devices is None else devices)
    local = [d for d in devices if d.process_index == jax.process_index()] or devices
    return int(DEFAULT_MEMORY_FRACTION * min(device_free_bytes(d) for d in local))


def agents_per_batch(
    num_agents: int, per_agent_bytes: int, budget_bytes: int, num_devices: int,
    fixed_bytes: int = 0,
) -> int:
    """Largest batch whose agents fit ``budget_bytes`` on each of ``num_devices`` devices.

    Args:
      num_agents: agents of the whole sweep (no batch is larger).
      per_agent_bytes: device memory of one agent (:func:`bytes_per_agent`).
      budget_bytes: memory budget per device.
      num_devices: devices the batch is sharded over.
      fixed_bytes: memory every device needs whatever the batch (the MDP tables).

    Returns:
      the batch size (a multiple of ``num_devices`` unless it covers every agent).

    Raises:
      ValueError: not even one agent per device fits the budget.
    """
    per_device = (budget_bytes - fixed_bytes) // per_agent_bytes
    if per_device < 1:
        raise ValueError(
            f"memory_budget_bytes={budget_bytes} is invalid: one agent needs about"
            f" {per_agent_bytes + fixed_bytes} bytes per device"
        )
    return int(min(num_agents, per_device * num_devices))


@dataclasses.dataclass
class SweepProgress:
    """Where a (possibly batched) sweep stands: what a checkpoint stores.

    Attributes:
      returns: float32 ``[agents, episodes]`` (zeros past each agent's ``episodes_done``).
      lengths: int32 ``[agents, episodes]``.
      episodes_done: int64 ``[agents]`` completed episodes per agent.
      nonfinite: bool ``[agents]``: NaN/inf appeared (final for finished agents).
      state_rows: int64 ``[m]`` agents that are started but unfinished.
      state: their :class:`~vdbejax.engine.AgentState` (numpy leaves, leading axis m),
        or None when m = 0.
    """

    returns: np.ndarray
    lengths: np.ndarray
    episodes_done: np.ndarray
    nonfinite: np.ndarray
    state_rows: np.ndarray
    state: AgentState | None

    @classmethod
    def fresh(cls, num_agents: int, num_episodes: int) -> SweepProgress:
        """Nothing done yet."""
        return cls(
            returns=np.zeros((num_agents, num_episodes), np.float32),
            lengths=np.zeros((num_agents, num_episodes), np.int32),
            episodes_done=np.zeros(num_agents, np.int64),
            nonfinite=np.zeros(num_agents, bool),
            state_rows=np.zeros(0, np.int64),
            state=None,
        )

    @property
    def num_episodes(self) -> int:
        return int(self.returns.shape[1])

    def record(self, rows: np.ndarray, done: int, agents: AgentState | None,
               returns: np.ndarray, lengths: np.ndarray,
               nonfinite: np.ndarray | None = None) -> None:
        """Store a batch's progress after a chunk (agents ``rows`` have ``done`` episodes).

        ``agents`` may hold device arrays: only what is kept is copied to numpy (the
        states of finished agents are not, and may be ``None`` given ``nonfinite``).
        """
        self.returns[rows, :done] = returns
        self.lengths[rows, :done] = lengths
        self.episodes_done[rows] = done
        if nonfinite is None:
            assert agents is not None  # the states may be None only given nonfinite
            nonfinite = np.asarray(agents.nonfinite)
        self.nonfinite[rows] = np.asarray(nonfinite)
        keep = ~np.isin(self.state_rows, rows)
        row_parts, state_parts = [], []
        if keep.any():
            row_parts.append(self.state_rows[keep])
            state_parts.append(take_agents(self.state, keep))
        if done < self.num_episodes:  # finished agents need no state
            row_parts.append(np.asarray(rows, np.int64))
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


def next_batch(progress: SweepProgress, batch_size: int) -> np.ndarray:
    """Agents of the next batch: up to ``batch_size`` unfinished agents that have all
    done the same number of episodes (in-progress agents first, then fresh ones).

    Args:
      progress: the sweep so far.
      batch_size: most agents per batch.

    Returns:
      int64 agent rows (empty when every agent is finished).
    """
    pending = np.flatnonzero(progress.episodes_done < progress.num_episodes)
    if pending.size == 0:
        return pending
    done = progress.episodes_done[pending]
    group = pending[done == done.max()]
    return group[:batch_size]


def run_batched(
    mdp: TabularMDP,
    params: Any,
    keys: np.ndarray,
    num_episodes: int,
    *,
    batch_size: int,
    devices: Sequence[jax.Device] | None = None,
    chunk_episodes: int = 100,
    progress: ProgressCallback | None = None,
    sweep: SweepProgress | None = None,
    on_checkpoint: Callable[[SweepProgress], None] | None = None,
) -> tuple[SweepProgress, int]:
    """Train all agents in sequential batches of at most ``batch_size`` agents.

    Args:
      mdp: the task.
      params: batched hyperparameters (leading axis = agents).
      keys: uint32 ``[agents, 2]``.
      num_episodes: episodes per agent.
      batch_size: agents per batch (:func:`agents_per_batch`); results do not depend on it.
      devices: devices each batch is sharded over (default: all).
      chunk_episodes: episodes per engine chunk (checkpoint granularity).
      progress: ``progress(done_agent_episodes, total, elapsed)`` over the whole sweep.
      sweep: resume from this progress (default: fresh).
      on_checkpoint: called with the progress after every chunk of every batch.

    Returns:
      ``(final progress, number of batches run)``.
    """
    check_int("batch_size", batch_size, 1)
    keys = np.asarray(keys, np.uint32)
    num_agents = int(keys.shape[0])
    sweep = SweepProgress.fresh(num_agents, num_episodes) if sweep is None else sweep
    total = num_agents * num_episodes
    started = time.perf_counter()
    batches = 0
    while (rows := next_batch(sweep, batch_size)).size:
        done = int(sweep.episodes_done[rows[0]])
        initial = None
        if done:
            initial = (done, sweep.states_of(rows), sweep.returns[rows, :done],
                       sweep.lengths[rows, :done])
        others_done = int(sweep.episodes_done.sum() - sweep.episodes_done[rows].sum())

        def on_chunk(chunk_done: int, agents: AgentState, returns: np.ndarray,
                     lengths: np.ndarray, rows: np.ndarray = rows) -> None:
            sweep.record(rows, chunk_done, agents, returns, lengths)
            if on_checkpoint is not None:
                on_checkpoint(sweep)

        batch_progress = None
        if progress is not None:
            def batch_progress(done_here: int, _total: int, _elapsed: float,
                               base: int = others_done) -> None:
                progress(base + done_here, total, time.perf_counter() - started)

        # Without checkpoints nothing needs the agents between chunks: record the batch
        # once at its end (no per-chunk copy of every agent's tables to the host).
        checkpointing = on_checkpoint is not None
        result = run_sharded(mdp, take_agents(params, rows), keys[rows], num_episodes,
                             devices=devices, initial=initial,
                             on_chunk=on_chunk if checkpointing else None,
                             chunk_episodes=chunk_episodes, progress=batch_progress,
                             keep_final_state=False)  # finished agents keep no state
        if not checkpointing:
            sweep.record(rows, num_episodes, None, result.returns, result.lengths,
                         nonfinite=result.nonfinite)
        batches += 1
    return sweep, batches
