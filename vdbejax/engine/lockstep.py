"""The lockstep strategy (accelerators, agents sharded over devices): all agents of a
batch advance together, one vectorised step per loop iteration.

* **Step-synchronous lockstep.** Agents do not wait for each other at episode
  boundaries: each agent has its own episode counter and starts its next episode as soon
  as the previous one ends. One ``lax.while_loop`` iteration advances every active agent
  by one environment step, so a batch costs ``max_agent(total steps)`` iterations instead
  of ``Σ_episodes max_agent(episode length)``.
* **Compaction.** Lockstep makes a batch run until its slowest agent finishes; finished
  lanes would idle. :func:`run_chunk_lockstep` runs blocks of ``block_iterations``
  iterations and, once at most half the lanes are active, gathers the active agents into
  a batch of the next power-of-two size (few shapes to compile). Bit-identical to running
  without it.
* **Kinds.** A batch holds agents of one kind (learner and explorer type), kind after
  kind; or, with ``mix_kinds``, agents of up to
  :data:`~vdbejax.engine.kinds.MAX_SWITCH_KINDS` kinds in one batch
  (:class:`~vdbejax.engine.kinds.KindSwitch` with a kind per lane), so a chunk takes as
  many iterations as its slowest agent, not the sum over kinds of each kind's slowest.
"""
from __future__ import annotations

import dataclasses
import threading
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from functools import partial
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from vdbejax.engine.agent_state import AgentState
from vdbejax.engine.chunks import RunCancelled
from vdbejax.engine.kinds import KindSwitch, can_switch, is_whole_kind, switch_block_size
from vdbejax.engine.programs import Programs
from vdbejax.engine.step import (
    ChunkBounds,
    ChunkBuffers,
    LoopLimits,
    optimal_buffer,
    run_loop,
    start_support,
)
from vdbejax.engine.work_items import next_power_of_two
from vdbejax.envs.tabular import TabularMDP
from vdbejax.methods.agents import Agent, AgentParams

Array = jax.Array

#: Largest batch (lanes) run as one program by :func:`run_agents`. Batches of up to 2048
#: lanes were verified to give every agent bit-identical results (10,000 agents in groups
#: of 37 and of 2048 lanes agree); single batches of 4096 and of 10,000 lanes did not: XLA's
#: CPU backend rounded some Q updates differently in the last bit (deterministically, but
#: depending on the lane; cause not found), so larger batches are split.
MAX_SAFE_BATCH = 2048

#: Lockstep iterations per while-loop trip (amortises XLA's per-trip overhead).
DEFAULT_UNROLL = 1


def run_chunk(
    mdp: TabularMDP,
    params: Agent | AgentParams | KindSwitch,
    agents: AgentState,
    bounds: ChunkBounds,
    chunk_length: int,
    unroll: int = DEFAULT_UNROLL,
    programs: Programs | None = None,
    steps: int | None = None,
) -> tuple[AgentState, Array, Array, Array, Array, Array | None]:
    """Advance a batch of agents until each has completed ``bounds.end`` episodes (or with
    ``steps``, for at least that many iterations at most: its agents then stand where
    they are, mid-episode if need be, and a next call continues with the same results).

    One jitted program, no compaction (see :func:`run_agents` for the compacting
    driver; both give identical results).

    Args:
      mdp: the task (shared by all agents).
      params: batched agent hyperparameters (leading axis = agents).
      agents: batched agent states.
      bounds: the chunk: ``start``, the episode index of its first episode, and ``end``,
        the episode count at which an agent stops (≤ ``start + chunk_length``).
      chunk_length: static buffer length.
      unroll: lockstep iterations per loop trip (static; results do not depend on it).
      programs: the run's programs (:class:`~vdbejax.engine.programs.Programs`; default:
        this call's own).
      steps: stop after the loop trip in which the iterations reach this many (a value,
        not a shape: one program for any); ``None``: at the chunk's end.

    Note: keep batches ≤ :data:`MAX_SAFE_BATCH` lanes for results independent of the
    batch (:func:`run_agents` splits larger ones into groups).

    Returns:
      ``(agents, returns, lengths, cut, iterations, optimal)``: returns, lengths and cut
      (the step limit ended the episode) are ``[agents, chunk_length]`` (episodes past
      ``bounds.end`` stay 0), ``iterations``
      the number of lockstep iterations executed (a multiple of ``unroll``), ``optimal``
      the episodes' counts of optimal actions where ``mdp.optimal_action`` is set (else
      ``None``).
    """
    if isinstance(params, AgentParams):
        if len(params.kinds) != 1:
            raise ValueError(f"params holds {len(params.kinds)} kinds of agent: run_chunk runs"
                             " one kind (use run_agents for several)")
        params = params.kinds[0]
    limit = jnp.iinfo(jnp.int32).max if steps is None else steps
    bounds = ChunkBounds(start=jnp.asarray(bounds.start, jnp.int32),
                         end=jnp.asarray(bounds.end, jnp.int32))
    args = (mdp, params, agents, bounds, jnp.asarray(limit, jnp.int32), start_support(mdp))
    program = (programs or Programs()).get(
        _run_chunk, args, {"chunk_length": chunk_length, "unroll": unroll})
    return program(*args)


def _run_chunk(mdp: TabularMDP, params: Agent | KindSwitch, agents: AgentState,
               bounds: ChunkBounds, max_iterations: Array, start_support: Any, *,
               chunk_length: int,
               unroll: int) -> tuple[AgentState, Array, Array, Array, Array, Array | None]:
    num_agents = agents.episode.shape[0]
    returns = jnp.zeros((num_agents, chunk_length), jnp.float32)
    lengths = jnp.zeros((num_agents, chunk_length), jnp.int32)
    buffers = ChunkBuffers(returns=returns, lengths=lengths,
                           cut=jnp.zeros((num_agents, chunk_length), jnp.bool_),
                           optimal=optimal_buffer(mdp, num_agents, chunk_length))
    agents, buffers, iterations = run_loop(
        mdp, params, agents, buffers, bounds,
        LoopLimits(max_iterations=max_iterations, unroll=unroll), start_support)
    return (agents, buffers.returns, buffers.lengths, buffers.cut, iterations,
            buffers.optimal)


def block_program(mdp: TabularMDP, params: Agent | KindSwitch, agents: AgentState,
                  buffers: ChunkBuffers, bounds: ChunkBounds, limits: LoopLimits,
                  start_support: Any) -> tuple[AgentState, ChunkBuffers, Array, Array]:
    """The lockstep iterations of one block (:func:`~vdbejax.engine.step.run_loop`:
    up to ``limits.max_iterations``, or exactly ``limits.fixed_iterations``); also
    returns each lane's activity.

    Returns:
      ``(agents, buffers, iterations, active)``.
    """
    agents, buffers, iterations = run_loop(mdp, params, agents, buffers, bounds, limits,
                                           start_support)
    return agents, buffers, iterations, agents.episode < bounds.end


@jax.jit
def _gather_rows(tree: Any, index: Array) -> Any:
    return jax.tree.map(lambda leaf: jnp.take(leaf, index, axis=0, mode="clip"), tree)


@partial(jax.jit, donate_argnums=(0,))
def _scatter_rows(tree: Any, index: Array, rows: Any) -> Any:
    return jax.tree.map(lambda leaf, new: leaf.at[index].set(new, mode="drop"), tree, rows)


def _whole(tree: Any) -> Any:
    """A group that is the whole batch: the tree itself."""
    return tree


def _row_slice(tree: Any, first: int, count: int) -> Any:
    """Rows ``first .. first + count - 1`` of every leaf (a slice keeps the sharding)."""
    return jax.tree.map(lambda leaf: leaf[first:first + count], tree)


def _row_gather(tree: Any, rows: np.ndarray) -> Any:
    """Rows ``rows`` of every leaf."""
    return _gather_rows(tree, jnp.asarray(rows, jnp.int32))


def _on_one_cpu(tree: Any) -> bool:
    """Every leaf a host array or a JAX array on one CPU device (its rows can be viewed
    on the host)."""
    for leaf in jax.tree.leaves(tree):
        if isinstance(leaf, np.ndarray | np.generic):
            continue
        devices = getattr(getattr(leaf, "sharding", None), "device_set", None)
        if not devices or len(devices) != 1 or next(iter(devices)).platform != "cpu":
            return False
    return True


def _on_one_device(tree: Any) -> bool:
    """No leaf spread over several devices."""
    return all(len(getattr(getattr(leaf, "sharding", None), "device_set", ())) <= 1
               for leaf in jax.tree.leaves(tree))


def _run_stream(
    mdp: TabularMDP,
    params: Agent | KindSwitch,
    agents: AgentState,
    chunk_start: int,
    chunk_end: int,
    chunk_length: int,
    *,
    lanes: int,
    limits: LoopLimits,
    min_batch: int,
    support: Any,
    block: Callable[[tuple], Any],
    steps: int | None = None,
    seconds: float | None = None,
) -> tuple[AgentState, Array, Array, Array, Array | None, int, int]:
    """:func:`run_chunk` of a stream of agents of one kind through a batch of at most
    ``lanes`` lanes, refilled and compacted between blocks; with ``steps`` (or
    ``seconds``), only until its iterations reach ``steps`` (or ``seconds`` have passed;
    checked between blocks): its agents are then written back where they stand,
    mid-episode if need be, and a next call continues the chunk with the same results.

    The batch holds the first ``lanes`` agents and runs a block of lockstep iterations
    (``limits``) at a time. Between blocks, a lane whose agent has finished the chunk takes
    the next waiting agent (the finished one is written back). Once no agent waits and at
    most half of the lanes are active, the active agents are gathered into a batch of the
    next power-of-two size (at least ``min_batch``; padding lanes duplicate a real agent
    and are never written back), so few shapes are compiled. Each agent's computation
    depends only on its own lane, hence the results are identical to :func:`run_chunk`.

    ``block(args)`` gets the block program for ``args`` (one per batch size).

    Returns:
      ``(agents, returns, lengths, cut, optimal, iterations, lane_iterations)``.
    """
    num_agents = int(agents.episode.shape[0])
    zeros = np.zeros if isinstance(agents.episode, np.ndarray) else jnp.zeros
    full = (agents, ChunkBuffers(returns=zeros((num_agents, chunk_length), np.float32),
                                 lengths=zeros((num_agents, chunk_length), np.int32),
                                 cut=zeros((num_agents, chunk_length), np.bool_),
                                 optimal=optimal_buffer(mdp, num_agents, chunk_length, zeros)))
    size = min(lanes, num_agents)
    waiting = size  # the next agent to take a lane
    # Rows of ``full`` the batch holds (None: all of them, in order).
    index = None if size == num_agents else np.arange(size, dtype=np.int32)
    cur_params, cur = params, full
    if index is not None:
        cur_params, cur = _gather_rows((params, full), jnp.asarray(index))
    iterations = lane_iterations = 0
    bounds = ChunkBounds(start=np.int32(chunk_start), end=np.int32(chunk_end))
    began = time.perf_counter()

    def written_back() -> tuple[AgentState, ChunkBuffers]:
        """The full batch with the current batch's rows written back (padding dropped)."""
        return cur if index is None else _scatter_rows(full, jnp.asarray(index), cur)

    while True:
        args = (mdp, cur_params, *cur, bounds, limits, support)
        cur_agents, cur_buffers, done_iterations, active = block(args)(*args)
        cur = (cur_agents, cur_buffers)
        done_iterations = int(done_iterations)
        iterations += done_iterations
        lane_iterations += done_iterations * size
        active = np.array(active)
        if index is not None:
            active &= index < num_agents  # padding lanes do not count
        if ((steps is not None and iterations >= steps)
                or (seconds is not None and time.perf_counter() - began >= seconds)):
            break  # the agents where they stand (the finished and the waiting ones too)
        free = np.flatnonzero(~active)
        if index is not None and waiting < num_agents and free.size:
            # Refill: finished agents written back, the next ones in their lanes.
            full = written_back()
            take = min(free.size, num_agents - waiting)
            index = index.copy()
            index[free[:take]] = np.arange(waiting, waiting + take, dtype=np.int32)
            waiting += take
            cur_params, cur = _gather_rows((params, full), jnp.asarray(index))
            continue
        num_active = int(active.sum())
        if num_active == 0:
            break
        target = max(next_power_of_two(num_active), min_batch)
        if target * 2 > size:
            continue
        # Compaction: the current batch written back, then the active agents gathered.
        full = written_back()
        keep = np.flatnonzero(active) if index is None else index[active]
        index = np.full(target, num_agents, np.int32)
        index[: keep.size] = keep
        gather = np.where(index < num_agents, index, keep[0]).astype(np.int32)
        cur_params, cur = _gather_rows((params, full), jnp.asarray(gather))
        size = target
    agents, buffers = written_back()
    return (agents, buffers.returns, buffers.lengths, buffers.cut, buffers.optimal, iterations,
            lane_iterations)


def _kind_groups(params: AgentParams, kinds: np.ndarray, mix_kinds: bool
                 ) -> list[tuple[Agent | KindSwitch, np.ndarray]]:
    """The batches' parameters and their agents: one kind each, or with ``mix_kinds``
    the kinds one program can serve together (:func:`~vdbejax.engine.kinds.can_switch`)
    as a :class:`~vdbejax.engine.kinds.KindSwitch` per block of them, each agent's kind
    its index in the block (whole kinds still run one kind each)."""
    present = [k for k in range(len(params.kinds)) if np.any(kinds == k)]
    mixed = [k for k in present if not is_whole_kind(params.kinds[k])]
    if not (mix_kinds and len(mixed) > 1 and can_switch(tuple(params.kinds[k] for k in mixed))):
        mixed = []
    groups: list[tuple[Agent | KindSwitch, np.ndarray]] = [
        (params.kinds[k], np.flatnonzero(kinds == k)) for k in present if k not in mixed]
    size = switch_block_size(len(mixed))
    for first in range(0, len(mixed), size):
        block = mixed[first:first + size]
        within = np.zeros(kinds.shape, np.int32)  # rows of other kinds are never run
        for position, k in enumerate(block):
            within[kinds == k] = position
        groups.append((KindSwitch(kinds=tuple(params.kinds[k] for k in block), kind=within),
                       np.flatnonzero(np.isin(kinds, block))))
    return groups


@dataclasses.dataclass(frozen=True)
class LockstepOptions:
    """How :func:`run_chunk_lockstep` runs a chunk (none changes a result, given
    ``max_batch`` ≤ :data:`MAX_SAFE_BATCH`): the lockstep part of a call's
    :class:`~vdbejax.engine.EngineOptions`, each choice it leaves to the backend made
    (by :func:`~vdbejax.engine.run_agents`).

    Attributes:
      compact: a group is a stream of a kind's agents through a batch of ``max_batch``
        lanes, refilled and compacted between blocks (:func:`_run_stream`).
      block_iterations: lockstep iterations per block.
      unroll: lockstep iterations per loop trip.
      min_batch: smallest batch compaction shrinks to.
      max_batch: lanes of a batch.
      threads: groups run on this many threads (a CPU: a group's loop is one native
        function on one core; XLA runs a program outside the GIL).
      fixed_blocks: each block is exactly ``block_iterations`` iterations, a loop of
        known trip count (on accelerators, where a data-dependent loop condition costs a
        round trip to the host per iteration).
      mix_kinds: the kinds together in blocks of
        :func:`~vdbejax.engine.kinds.switch_block_size` where one program can serve them
        (:func:`~vdbejax.engine.kinds.can_switch`), instead of kind by kind.
      chunk_steps: a group stops after the block (with ``compact``; else the loop trip)
        in which its iterations reach this many, its agents where they stand (the call
        then ends before the chunk does; ``None``: at the chunk's end).
      piece_seconds: with ``compact``, a group also stops after the block in which this
        many seconds have passed since the call began (on an accelerator an iteration
        of a large batch may take milliseconds: a piece of ``chunk_steps`` iterations
        would be long); ``None``: no bound in time.
    """

    compact: bool
    block_iterations: int
    unroll: int
    min_batch: int
    max_batch: int
    threads: int = 1
    fixed_blocks: bool = False
    mix_kinds: bool = False
    chunk_steps: int | None = None
    piece_seconds: float | None = None


def run_chunk_lockstep(
    mdp: TabularMDP,
    params: AgentParams,
    agents: AgentState,
    chunk_start: int,
    chunk_end: int,
    chunk_length: int,
    options: LockstepOptions,
    programs: Programs,
) -> tuple[AgentState, Array, Array, Array, Array | None, int, int]:
    """One chunk of the lockstep strategy (or with ``options.chunk_steps`` the part of it
    each group runs within that many iterations: the agents' episode counters say
    which have finished it): kind by kind (or, with ``options.mix_kinds``,
    the kinds together where one program can serve them), in groups of at most
    ``options.max_batch`` lanes, the groups spread over ``options.threads`` threads
    (:class:`LockstepOptions`). Per-agent results do not depend on the grouping.

    Returns:
      ``(agents, returns, lengths, cut, optimal, iterations, lane_iterations)``.
    """
    compact, max_batch, unroll = options.compact, options.max_batch, options.unroll
    threads, block_iterations = options.threads, options.block_iterations
    num_agents = int(agents.episode.shape[0])
    if _on_one_cpu((agents, params)):  # groups cut as host views: no dispatch per leaf
        agents, params = jax.tree.map(np.asarray, (agents, params))
    groups: list[tuple[Agent | KindSwitch, np.ndarray]] = []
    kinds = np.asarray(params.kind)
    for agent, members in _kind_groups(params, kinds, options.mix_kinds):
        if compact:  # streams through batches of max_batch lanes, a few per kind for threads
            streams = max(1, min(threads, -(-members.size // max_batch)))
            groups.extend((agent, rows) for rows in np.array_split(members, streams))
        else:
            groups.extend((agent, members[lo:lo + max_batch])
                          for lo in range(0, members.size, max_batch))

    support = start_support(mdp)
    limits = LoopLimits(max_iterations=np.int32(block_iterations), unroll=unroll,
                        fixed_iterations=block_iterations if options.fixed_blocks else None)
    block_programs: dict[tuple, Any] = {}

    stopping = threading.Event()  # the run stops: the other groups stop at their next block

    def run_group(group: tuple[Agent | KindSwitch, np.ndarray]) -> tuple[Any, int, int]:
        agent, rows = group
        first, count = int(rows[0]), rows.size
        part: Callable[[Any], Any]
        if count == num_agents:
            part = _whole
        elif int(rows[-1]) - first + 1 == count:  # contiguous: a slice (keeps sharding)
            part = partial(_row_slice, first=first, count=count)
        else:
            part = partial(_row_gather, rows=rows)
        if compact:
            def block(args: tuple) -> Any:  # one lookup per kind, batch size and placement
                if stopping.is_set():
                    raise RunCancelled
                episode = args[2].episode
                key = (id(agent), episode.shape, getattr(episode, "sharding", None),
                       getattr(jax.tree.leaves(args[1])[0], "sharding", None))
                if key not in block_programs:
                    block_programs[key] = programs.get(  # the batch's buffers updated in place
                        block_program, args, donate=("agents", "buffers"))
                return block_programs[key]

            *piece, group_iterations, group_lanes = _run_stream(
                mdp, part(agent), part(agents), chunk_start, chunk_end, chunk_length,
                lanes=max_batch, limits=limits, min_batch=options.min_batch,
                support=support, block=block, steps=options.chunk_steps,
                seconds=options.piece_seconds,
            )
            return piece, group_iterations, group_lanes
        *piece, run_iterations, optimal = run_chunk(
            mdp, part(agent), part(agents), ChunkBounds(start=np.int32(chunk_start),
                                                     end=np.int32(chunk_end)),
            chunk_length, unroll, programs, options.chunk_steps,
        )
        return [*piece, optimal], int(run_iterations), int(run_iterations) * count

    # Groups of agents sharded over several devices run one after another: two programs
    # over the same devices at once can deadlock on a CPU, each device waiting in the
    # other program's collective (seen with two processes × 2 devices).
    if threads > 1 and len(groups) > 1 and _on_one_device(agents):
        with ThreadPoolExecutor(max_workers=min(threads, len(groups))) as pool:
            try:
                done = list(pool.map(run_group, groups))
            except BaseException:  # a stop (Ctrl-C): the pool waits for one block a group
                stopping.set()
                raise
    else:
        done = [run_group(group) for group in groups]
    pieces = [piece for piece, _, _ in done]
    iterations = sum(group_iterations for _, group_iterations, _ in done)
    lane_iterations = sum(group_lanes for _, _, group_lanes in done)
    if len(pieces) == 1:
        agents, returns, lengths, cut, optimal = pieces[0]
    else:
        agents, returns, lengths, cut, optimal = jax.tree.map(
            lambda *leaves: jnp.concatenate(leaves), *pieces)
        rows_order = np.concatenate([rows for _, rows in groups])
        if not np.array_equal(rows_order, np.arange(num_agents)):
            inverse = jnp.asarray(np.argsort(rows_order), jnp.int32)
            agents, returns, lengths, cut, optimal = _gather_rows(
                (agents, returns, lengths, cut, optimal), inverse)
    return agents, returns, lengths, cut, optimal, iterations, lane_iterations
