"""Memory estimates of a run: how many agents fit a device, and whether the results fit.

A run's agents are independent, so they can run in any grouping with the same results.
When the per-device memory of all agents (Q tables, VDBE ε tables, chunk buffers, and with
an instance per agent each agent's own task tables) exceeds the budget, the run's plan
(:mod:`vdbejax.runs.plan`) runs them in sequential batches of at most
:func:`agents_per_batch` agents; :func:`check_run_size` refuses, before anything is
allocated, a run whose settings, results and task instances cannot fit the host.
"""
from __future__ import annotations

import os
import shutil
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import jax
import numpy as np

from vdbejax.engine.agent_state import state_bytes
from vdbejax.engine.chunk_loop import chunk_buffer_length
from vdbejax.envs.tabular import TabularMDP
from vdbejax.envs.task_instances import TaskInstances

#: Fraction of a device's free memory used when no budget is given.
DEFAULT_MEMORY_FRACTION = 0.5
#: Working copies of the agent state the engine may hold at once (the state, its
#: compacted copy, the loop's double buffer): the estimate is deliberately conservative.
STATE_COPIES = 3
#: Bytes of the per-agent scalars (state fields, key, hyperparameters), rounded up.
SCALAR_BYTES = 128


def bytes_per_agent(mdp: TabularMDP, chunk_episodes: int,
                    layout: dict[str, str] | None = None, task_bytes: int = 0) -> int:
    """Estimated device memory of one agent: Q and its other tables, scalars, chunk
    buffers, and its own task instance if it has one.

    Args:
      mdp: the task (sets the table sizes).
      chunk_episodes: episodes per engine chunk (sets the buffer sizes).
      layout: the agents' tables beside Q (:func:`~vdbejax.methods.agents.table_layout`;
        default: one per-state table, the paper's ε(s)).
      task_bytes: the agent's own task instance (:func:`instance_bytes`; 0: a shared task):
        it rides with the agent's hyperparameters, gathered and compacted with its state.

    Returns:
      bytes, for :data:`STATE_COPIES` working copies.
    """
    tables = state_bytes(mdp, {"epsilon": "state"} if layout is None else layout)
    # float32 return + int32 length + bool cut per episode of the chunk's (rounded up)
    # buffers
    chunk_buffers = 9 * chunk_buffer_length(chunk_episodes)
    return STATE_COPIES * (tables + task_bytes + SCALAR_BYTES + chunk_buffers)


def mdp_bytes(mdp: TabularMDP | TaskInstances) -> int:
    """Memory of the MDP tables (of a shared task: replicated on every device)."""
    return int(sum(np.asarray(leaf).nbytes for leaf in jax.tree.leaves(mdp)))


def instance_bytes(instances: TaskInstances, record_optimal: bool = False) -> int:
    """Device memory of one agent's own task instance (an instance per agent,
    :mod:`vdbejax.engine.agent_on_task`): its row of every table, its start support (int32
    states and float32 weights, padded to the run's widest) and, where the run records
    them, its bool mask of optimal actions."""
    row = mdp_bytes(instances) // instances.num_agents
    width = int((np.asarray(instances.tables.start_probability) > 0).sum(axis=1).max())
    mask = (instances.num_states * instances.num_actions
            if record_optimal and instances.tables.optimal_action is None else 0)
    return row + 8 * width + mask


#: Host copies of a run's instance tables at once, at most: the stacked tables, this
#: process's rows of them, a batch's rows, and that batch padded for several devices.
HOST_INSTANCE_COPIES = 4


def instances_host_bytes(instance: TabularMDP, num_agents: int,
                         record_optimal: bool = False) -> int:
    """Host memory of a run's instances, one per agent, each shaped as ``instance``
    (:data:`HOST_INSTANCE_COPIES` copies of the stacked tables, with each agent's mask of
    optimal actions where the run records them)."""
    mask = (instance.num_states * instance.num_actions
            if record_optimal and instance.optimal_action is None else 0)
    return HOST_INSTANCE_COPIES * num_agents * (mdp_bytes(instance) + mask)


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


#: Host bytes per agent-episode of a grid's results: float32 returns, int32 lengths and
#: a bool cut flag, once as the run's records and once as the returned arrays.
RESULT_BYTES_PER_EPISODE = 18
#: Host bytes per agent besides its episodes (hyperparameters, key, progress, summary).
RESULT_BYTES_PER_AGENT = 512
#: Host bytes per setting of a grid, besides its agents' results: the :class:`Setting`,
#: its agent while the grid's hyperparameters are stacked, its entries in the run's
#: fingerprint and ``meta.json``, its label and summary row. A sweep of 10⁵ settings (one
#: agent each) peaked ≈ 2 KiB per setting above the process's start while it was prepared
#: (``resource.getrusage``, 2026-12-05); twice that covers what the finished run keeps of
#: each (its hyperparameter record, label and summary row). Its agents' hyperparameters
#: and keys are in :data:`RESULT_BYTES_PER_AGENT`.
SETTING_BYTES = 4096
#: Bytes per agent-episode of a checkpoint's episode log (returns, lengths, cut flag).
LOG_BYTES_PER_EPISODE = 9


def result_bytes(num_agents: int, num_episodes: int) -> int:
    """Host bytes of a run's results (:data:`RESULT_BYTES_PER_EPISODE`, ``…_PER_AGENT``)."""
    return num_agents * (num_episodes * RESULT_BYTES_PER_EPISODE + RESULT_BYTES_PER_AGENT)


def log_bytes(num_agents: int, num_episodes: int) -> int:
    """Disk bytes of a checkpoint's episode log at its largest."""
    return num_agents * num_episodes * LOG_BYTES_PER_EPISODE


def settings_bytes(num_settings: int) -> int:
    """Host bytes of a grid's settings themselves (:data:`SETTING_BYTES` each)."""
    return num_settings * SETTING_BYTES


def check_run_size(num_agents: int, num_episodes: int, checkpoint: Any = None,
                   num_settings: int = 0, available_bytes: int | None = None,
                   task_bytes: int = 0) -> int:
    """Refuse, before anything is allocated, a run whose settings, results and task
    instances cannot fit.

    Args:
      num_agents: agents of the run.
      num_episodes: episodes per agent.
      checkpoint: the checkpoint path, if any (its episode log needs disk space).
      num_settings: the run's settings (:func:`settings_bytes`; 0: the results only).
      available_bytes: free host memory (default: ``MemAvailable``).
      task_bytes: host bytes of the run's task instances (:func:`instances_host_bytes`;
        0: a shared task).

    Returns:
      the estimated host bytes of the settings, the results and the instances.

    Raises:
      ValueError: they need more memory than is free, or the checkpoint log more disk
        space: one line with the sizes, the estimate, the limit and what fits.
    """
    results = result_bytes(num_agents, num_episodes)
    needed = results + settings_bytes(num_settings) + task_bytes
    available = _host_available_bytes() if available_bytes is None else available_bytes
    tasks = f", their task instances ≈ {size_text(task_bytes)}" if task_bytes else ""
    if needed > available and num_settings:
        per_setting = needed / num_settings  # the same agents and episodes per setting
        fit = int(available // per_setting)
        raise ValueError(
            f"the run is too large for this machine: {num_settings:,} settings"
            f" ({num_agents:,} agents) × {num_episodes:,} episodes need ≈ {size_text(needed)} of"
            f" memory (the settings ≈ {size_text(settings_bytes(num_settings))}, their results ≈"
            f" {size_text(results)}{tasks}), but {size_text(available)} are free: at most {fit:,}"
            " settings of this size fit; use fewer settings, seeds or episodes, or split the"
            " run")
    if needed > available:
        what = "their results and task instances" if task_bytes else "their results"
        raise ValueError(
            f"num_seeds × num_episodes is too large: {num_agents:,} agents × {num_episodes:,}"
            f" episodes need ≈ {size_text(needed)} of memory for {what}, but"
            f" {size_text(available)} are free: use fewer seeds or episodes, or split the run")
    if checkpoint is not None:
        folder = Path(checkpoint).parent
        log = log_bytes(num_agents, num_episodes)
        try:
            free = shutil.disk_usage(folder if folder.exists() else Path.cwd()).free
        except OSError:
            free = None
        if free is not None and log > free:
            raise ValueError(
                f"checkpoint={str(checkpoint)!r} is invalid: its episode log would need ≈"
                f" {size_text(log)} of disk, but {size_text(free)} are free there")
    return needed


def size_text(num_bytes: float) -> str:
    """``num_bytes`` for a message: ``"512 B"``, ``"1.5 MiB"`` (binary units, up to PiB)."""
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
