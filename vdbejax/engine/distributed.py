"""Scale-out: the agent axis sharded over every device (one host or many).

Agents never interact, so a sweep is embarrassingly parallel along its leading *agent*
axis. A run's plan (:meth:`vdbejax.runs.plan.RunPlan.run_engine`) pads the agent count to
a multiple of the device count (:func:`pad_agents`, copies of the last agent, dropped
afterwards), places hyperparameters, keys and agent states with
``NamedSharding(mesh, P("agents"))`` (:func:`shard_agents`) and calls the ordinary engine:
jit follows the input sharding, so every device advances its own slice of agents. Each
agent's computation depends only on its own lane, hence the results are bit-identical to
a single-device run.

Multi-host: call ``jax.distributed.initialize()`` in every process before anything
else (see the README). Each process then runs its contiguous share of the agents
(:func:`process_share`) sharded over its own devices, with no communication during the
run, and the results are all-gathered at the end (:func:`gather_agents`).
"""
from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any, TypeVar

import jax
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec

from vdbejax.validation import check_int

#: Name of the mesh axis that agents are split along.
AGENT_AXIS = "agents"
#: How long a process that finished its share waits for the others before the gather
#: (shares of unequal work end far apart; the collectives' own wait is 30 s).
GATHER_WAIT_SECONDS = 7 * 24 * 3600

Tree = TypeVar("Tree")


def select_devices(num_devices: int | None = None) -> list[jax.Device]:
    """The first ``num_devices`` of ``jax.devices()`` (all of them when None).

    Args:
      num_devices: how many devices, or None for all.

    Returns:
      the devices, in ``jax.devices()`` order.

    Raises:
      ValueError: ``num_devices`` is not an integer in ``[1, len(jax.devices())]``.
    """
    available = jax.devices()
    if num_devices is None:
        return list(available)
    check_int("devices", num_devices, 1)
    if num_devices > len(available):
        raise ValueError(
            f"devices={num_devices!r} is invalid: only {len(available)} device(s) available"
        )
    return list(available[:num_devices])


def agent_mesh(devices: Sequence[jax.Device] | None = None) -> Mesh:
    """A one-dimensional mesh over ``devices`` (default: all) with axis ``"agents"``."""
    devices = list(jax.devices() if devices is None else devices)
    return Mesh(np.asarray(devices, dtype=object), (AGENT_AXIS,))


def pad_agents(tree: Tree, multiple: int) -> tuple[Tree, int]:
    """Pad the leading (agent) axis of every leaf to a multiple of ``multiple``.

    Padding rows copy the last agent, so they run valid (and discarded) computations.

    Returns:
      ``(padded_tree, original_count)``.
    """
    count = int(jax.tree.leaves(tree)[0].shape[0])
    extra = -count % multiple
    if extra == 0:
        return tree, count

    def pad(leaf: Any) -> Any:
        leaf = np.asarray(leaf)
        return np.concatenate([leaf, np.repeat(leaf[-1:], extra, axis=0)])

    return jax.tree.map(pad, tree), count


def take_agents(tree: Tree, index: Any) -> Tree:
    """Agents ``index`` (indices or a boolean mask) of every leaf, as numpy."""
    return jax.tree.map(lambda leaf: np.asarray(leaf)[index], tree)


def _process_shares(num_agents: int) -> list[np.ndarray]:
    """Agent rows of every process: ``process_count`` contiguous, near-equal parts."""
    return np.array_split(np.arange(num_agents), jax.process_count())


def process_share(num_agents: int) -> np.ndarray:
    """Agent rows this process runs: a contiguous ``1/process_count`` of the sweep.

    Agents are independent, so hosts need not talk during a run; results are gathered
    once at the end (:func:`gather_agents`). One process: every row.
    """
    return _process_shares(num_agents)[jax.process_index()]


def local_devices(devices: Sequence[jax.Device]) -> list[jax.Device]:
    """The devices of ``devices`` attached to this process.

    Raises:
      ValueError: none of them is.
    """
    mine = [d for d in devices if d.process_index == jax.process_index()]
    if not mine:
        raise ValueError(f"devices={len(devices)} is invalid: selects no device of process"
                         f" {jax.process_index()}; use all devices on several hosts")
    return mine


def gather_agents(local: np.ndarray, num_agents: int) -> np.ndarray:
    """Concatenate every process's :func:`process_share` rows of ``local`` (all processes
    receive the whole ``[num_agents, ...]`` array). One process: ``local`` itself.

    Args:
      local: this process's rows (leading axis = its share of the agents).
      num_agents: agents of the whole sweep.

    Returns:
      the ``[num_agents, ...]`` array of all processes' rows, in agent order.
    """
    if jax.process_count() == 1:
        return local
    from jax.experimental import multihost_utils

    _wait_for_every_process()
    sizes = [len(share) for share in _process_shares(num_agents)]
    padded = np.zeros((max(sizes), *local.shape[1:]), local.dtype)
    padded[: local.shape[0]] = local  # equal shapes for the all-gather
    everything = np.asarray(multihost_utils.process_allgather(padded))
    return np.concatenate([everything[p, :size] for p, size in enumerate(sizes)])


_gathers = 0  # barriers passed: each gather's barrier has its own name


def _wait_for_every_process() -> None:
    """Block until every process reached its gather: a barrier of the distributed
    service (its wait is :data:`GATHER_WAIT_SECONDS`), so the all-gather's collectives,
    which give up after 30 s, start together."""
    from jax._src import distributed  # the service's client (JAX's own savers use it)

    global _gathers
    _gathers += 1
    client = distributed.global_state.client
    if client is not None:
        client.wait_at_barrier(f"vdbejax_gather_{_gathers}", GATHER_WAIT_SECONDS * 1000)


def process_checkpoint_path(path: str | os.PathLike) -> Path:
    """This process's checkpoint file: ``path`` itself, or ``stem.process<i>of<n>.npz``
    when several processes each checkpoint their own share."""
    path = Path(path)
    if jax.process_count() == 1:
        return path
    return path.with_name(
        f"{path.stem}.process{jax.process_index()}of{jax.process_count()}{path.suffix}")


def unpad_agents(tree: Tree, count: int) -> Tree:
    """Drop padding rows: keep the first ``count`` agents of every leaf (as numpy)."""
    return take_agents(tree, slice(0, count))


def shard_agents(tree: Tree, mesh: Mesh) -> Tree:
    """Place every leaf with its leading axis split over the mesh's ``"agents"`` axis."""
    sharding = NamedSharding(mesh, PartitionSpec(AGENT_AXIS))
    return jax.tree.map(lambda leaf: jax.device_put(leaf, sharding), tree)
