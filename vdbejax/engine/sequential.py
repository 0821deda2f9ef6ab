"""The sequential strategy (the default on a CPU backend): native ``while`` loops of
steps, each running :data:`~vdbejax.engine.work_items.LANES` agents side by side (a lane
whose agent has finished takes the work item's next agent), and work items of agents on
several threads.

With a few lanes every table access is a dynamic slice, so XLA's CPU backend compiles the
whole loop into one native function (see :mod:`vdbejax._xla_flags`). One program serves
every kind of agent of the run, up to
:data:`~vdbejax.engine.kinds.MAX_SWITCH_KINDS` kinds (learner and explorer type, with
their static fields):
each kind's part of the step is a branch of a ``lax.switch`` on the item's kind
(:class:`~vdbejax.engine.kinds.KindSwitch`), so the loop is traced once, not once per
kind — tracing is most of what a run pays besides its steps; a chunk of a work item is
one call of it, a single native function. A work item's chunks follow each other
without waiting for the other items (:meth:`SequentialRun.run_chunks`). Results are
bit-identical to the lockstep strategy (products are rounded on their own,
:mod:`vdbejax._numerics`).
"""
from __future__ import annotations

import dataclasses
import warnings
import weakref
from collections.abc import Generator
from concurrent.futures import Future, ThreadPoolExecutor
from functools import partial
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from vdbejax import _pytree, _xla_flags
from vdbejax.engine.agent_state import AgentState, init_agents
from vdbejax.engine.chunks import ChunkSchedule, Piece, RunCancelled
from vdbejax.engine.kinds import KindSwitch, can_switch, switch_block_size
from vdbejax.engine.lanes import UNROLLED_LANES_MAX, at_lane
from vdbejax.engine.packing import pack, unpack
from vdbejax.engine.programs import Call, Programs
from vdbejax.engine.step import (
    ChunkBounds,
    ChunkBuffers,
    LoopLimits,
    optimal_buffer,
    run_loop,
    start_support,
)
from vdbejax.engine.work_items import LANES, common_rows, padded_rows, sequential_groups
from vdbejax.envs.tabular import TabularMDP
from vdbejax.methods.agents import AgentParams

Array = jax.Array


#: Per-compilation XLA options of the CPU engine: with region analysis, copy insertion
#: proves that an agent's Q-table update can happen in place (no copy of Q per step).
_CPU_COMPILER_OPTIONS = {"xla_cpu_copy_insertion_use_region_analysis": True}


#: Loop iterations of one native call of a work item (:class:`SequentialRun`): a chunk
#: whose agents need more (very long episodes) is run in several calls, each ending where
#: it stands — mid-episode if need be —, so that a stop waits for one call, not for the
#: chunk (one Q-learning agent on a one-state task: a stop 0.27 s after Ctrl-C, 2-core
#: machine, 2026-12-06). The results do not depend on it.
CHUNK_STEPS = 1 << 20


#: Sequential executables checked by :func:`_check_native`: compiled natively? (An entry
#: goes with its executable.)
_NATIVE: weakref.WeakKeyDictionary[Any, bool] = weakref.WeakKeyDictionary()


def native_step_loops() -> bool | None:
    """Whether the sequential executables compiled so far run their step loops natively.

    ``None`` before the first one is compiled. ``False`` means XLA would dispatch every
    operation of a step separately; :func:`run_agents` then uses the lockstep strategy
    instead (same results). Causes: XLA's small-while-loop threshold was not raised
    (JAX's backend started before :mod:`vdbejax` was imported, or
    ``VDBEJAX_XLA_FLAGS=off``; see :mod:`vdbejax._xla_flags`), or the task's tables are
    larger than the threshold.
    """
    return all(_NATIVE.values()) if _NATIVE else None


def _check_native(executable: Any) -> bool:
    """Whether ``executable``'s per-agent loop compiled natively (warns once if not)."""
    native = _NATIVE.get(executable)
    if native is None:
        native = "xla_cpu_small_call" in executable.as_text()
        if not native and all(_NATIVE.values()):
            warnings.warn(
                "vdbejax: XLA would run the per-agent step loop op by op, so the lockstep "
                "strategy is used instead (same results, slower). Raise XLA's "
                "small-while-loop threshold before JAX starts: import vdbejax first (unless "
                "VDBEJAX_XLA_FLAGS=off), or set XLA_FLAGS="
                f"'{_xla_flags.with_small_loop_threshold('')}'.",
                RuntimeWarning,
                stacklevel=4,
            )
        _NATIVE[executable] = native
    return native


@dataclasses.dataclass
class ItemPiece:
    """What one native call of a work item gave (:meth:`SequentialRun._run_item`): its
    agents' ``[agents, chunk_length]`` records of the episodes it finished (``returns``,
    ``lengths``, ``cut``; ``optimal``, the steps of each episode it ran whose action is
    optimal, or ``None``), its ``iterations`` and ``lanes`` (lane iterations), each
    agent's ``episodes`` done after it, whether every agent ``finished`` the chunk, and
    the item's state after it (``copy``, when a snapshot was asked for)."""

    returns: np.ndarray
    lengths: np.ndarray
    cut: np.ndarray
    optimal: np.ndarray | None
    iterations: int
    lanes: int
    episodes: np.ndarray
    finished: bool
    copy: Any


class SequentialRun:
    """The sequential strategy over the chunks of one :func:`run_agents` call.

    Agents are split by kind (learner and explorer type), one program for every kind
    (:func:`_run_sequential` with a :class:`~vdbejax.engine.kinds.KindSwitch`; one per block
    of at most :data:`~vdbejax.engine.kinds.MAX_SWITCH_KINDS` kinds; one per kind where a
    table name is written two ways), and into about ``4 × threads`` work items
    (:func:`~vdbejax.engine.work_items.sequential_groups`); worker threads take items as
    they become free (XLA releases the GIL while a program runs). An item's loop runs
    :data:`~vdbejax.engine.work_items.LANES` agents side by side. An item's arrays are
    padded to a power-of-two number of rows (few shapes to compile; padding rows are not
    run). Each agent's result depends on its own lane only, so the grouping changes nothing.

    Work items are formed once, at the first chunk, and keep their agents for the whole
    run: between chunks an item's state stays in the engine's buffers, which each chunk's
    program updates in place (donated), and no table is copied. (Regrouping agents by
    their cost every chunk balanced the threads no better than lanes that take the next
    waiting agent, and its copies through the host cost more: ``benchmarks/RESULTS.md``.)
    Chunks follow each other without waiting for the slowest item at each chunk's end
    (:meth:`run_chunks`); items start most costly first by the latest chunk's steps
    known when they are queued. :meth:`agents` gathers
    the full state on the host when it is needed (checkpoints, the end of the run).
    """

    def __init__(self, mdp: TabularMDP, params: AgentParams, agents: AgentState | None,
                 keys: Any, threads: int, programs: Programs,
                 chunk_steps: int = CHUNK_STEPS) -> None:
        """``agents=None``: fresh agents, created in their work items (large agents);
        ``chunk_steps``: the most loop iterations of one native call (:meth:`_run_item`)."""
        self.mdp, self.threads, self.run_programs = mdp, threads, programs
        self.chunk_steps = chunk_steps
        self.cancelled = False  # the run stops: items stop at their next native call
        self.params = jax.tree.map(np.asarray, params)
        self.keys = np.asarray(keys, np.uint32)
        self.host = agents  # the full state while host_current (numpy or device arrays)
        self.host_current = True
        self.items: list[tuple[np.ndarray, Any]] | None = None
        self.item_programs: list[tuple[Any, Any]] = []  # per item: executable, hyperparameters
        self.kinds = np.asarray(self.params.kind)
        self.switch = can_switch(tuple(self.params.kinds))
        self.block = switch_block_size(len(self.params.kinds))
        self.item_rows = 0  # every item's padded rows (0: each its own power of two)
        self.support = start_support(mdp)
        self.layout = (jax.eval_shape(partial(init_agents), mdp, self.params, self.keys)
                       if agents is None else
                       jax.tree.map(lambda leaf: jax.ShapeDtypeStruct(leaf.shape, leaf.dtype),
                                    agents))

    def agents(self) -> AgentState:
        """The full state on the host (numpy), the items' rows written back."""
        if self.host is None and self.items is None:  # nothing run yet
            args = (self.mdp, self.params, self.keys)
            self.host = self.run_programs.get(init_agents, args)(*args)
        if not self.host_current:
            assert self.items is not None  # the state moves on in the items once they run
            self._hold(self.items)
        assert self.host is not None  # fresh agents are created above or held by _hold
        return self.host

    def _hold(self, items: list[tuple[np.ndarray, Any]]) -> None:
        """Make the state of ``items`` (index, rows) the full state on the host."""
        # Fresh arrays: ones handed out before (checkpoints) must not change.
        host = jax.tree.map(lambda leaf: np.empty(leaf.shape, leaf.dtype), self.layout)
        for index, state in items:
            for full, rows in zip(jax.tree.leaves(host), jax.tree.leaves(state), strict=True):
                full[index] = np.asarray(rows)[: index.size]
        self.host, self.host_current = host, True

    def nonfinite_flags(self) -> np.ndarray:
        """Each agent's ``nonfinite`` flag, without gathering the tables."""
        if self.host_current:
            return np.asarray(self.agents().nonfinite)
        flags = np.empty(self.keys.shape[0], bool)
        assert self.items is not None  # not host_current: the items have run
        for index, state in self.items:
            flags[index] = np.asarray(state.nonfinite)[: index.size]
        return flags

    def _call(self, index: np.ndarray, agents: Any, chunk: tuple[int, int, int]) -> Call:
        """The program call of an item; ``agents`` may be shapes only."""
        rows = padded_rows(index, self.item_rows)
        kind = int(self.kinds[index[0]])
        # One program for every kind where it can serve them (KindSwitch), else the kind's.
        first = kind - kind % self.block  # the first kind of its program's block
        agent = (self.params.kinds[first:first + self.block] if self.switch
                 else self.params.kinds[kind])
        agent = jax.tree.map(lambda leaf: leaf[rows], agent)
        static = {"chunk_length": chunk[2], "lanes": lanes_for(rows.size)}
        args = self._arguments((agent, kind), agents, index, chunk)
        return Call(_run_sequential, args, static, donate=("agents",),
                    options=_CPU_COMPILER_OPTIONS)

    def _arguments(self, agent: tuple[Any, int], agents: Any, index: np.ndarray,
                   chunk: tuple[int, int, int]) -> tuple:
        """The positional arguments of :func:`_run_sequential` for an item."""
        params, kind = agent
        return (self.mdp, params, agents, np.int32(chunk[0]), np.int32(chunk[1]),
                np.int32(index.size), np.int32(self.chunk_steps), self.support,
                np.int32(kind % self.block) if self.switch else None)

    def _group(self, chunk: tuple[int, int, int]) -> bool:
        """The work items, from the current state; ``False`` if a loop is not native."""
        groups = sequential_groups(self.kinds, self.threads)
        self.item_rows = common_rows(groups) if self.switch else 0

        def shapes(index: np.ndarray) -> Any:  # enough to compile: no copy of the rows
            size = padded_rows(index, self.item_rows).size
            return jax.tree.map(
                lambda leaf: jax.ShapeDtypeStruct((size, *leaf.shape[1:]), leaf.dtype),
                self.layout,
            )

        # Get the programs (one for every kind and item) before running; compiling them
        # or reading JAX's cache runs on the worker threads, mostly outside the GIL.
        calls = [self._call(index, shapes(index), chunk) for index in groups]
        executables = self.run_programs.get_all(calls, self.threads)
        if not all(_check_native(executable) for executable in executables):
            return False
        # Each item's program and hyperparameters, for every chunk (items keep their
        # agents, and a run's chunks have one length, a static argument of the program).
        self.item_programs = [(executable, (call.args[1], int(self.kinds[index[0]])))
                              for executable, call, index in zip(executables, calls, groups,
                                                                 strict=True)]
        fresh = self.host is None  # large fresh agents: created in their item, on the device
        host = None if fresh else self.agents()
        items = []
        for index in groups:
            rows = padded_rows(index, self.item_rows)
            if fresh:
                args = (self.mdp, jax.tree.map(lambda leaf, rows=rows: leaf[rows], self.params),
                        self.keys[rows])
                state = self.run_programs.get(init_agents, args)(*args)
            else:  # on a CPU np.asarray of a device array is a view: one gather, one copy
                # (device_put, not jnp.asarray, which compiles a small program per shape)
                state = jax.tree.map(lambda leaf, rows=rows: jax.device_put(np.asarray(leaf)[rows]),
                                     host)
            items.append((index, state))
        self.items = items
        return True

    def prepare(self, chunk_length: int) -> bool:
        """Form the work items and get their programs (``chunk_length``: every chunk's
        buffers' length); ``False`` (nothing run) if a loop did not compile natively
        (:func:`native_step_loops`)."""
        return self.items is not None or self._group((0, chunk_length, chunk_length))

    def _run_item(self, k: int, chunk: tuple[int, int, int], before: Future | None,
                  snapshot: bool) -> ItemPiece | None:
        """One native call of item ``k`` in a chunk (at most ``chunk_steps`` loop
        iterations: a stop waits for one call, not for the chunk), once its previous call
        (``before``) has returned; with ``snapshot``, also a host copy of the item's state
        after it (taken before its next call updates the state in place). ``None``: not
        run, ``before`` left the item's previous chunk unfinished (its next call is that
        chunk's)."""
        if before is not None:  # started earlier (the pool is FIFO): this does not deadlock
            previous = before.result()
            if previous is None or not previous.finished:
                return None
        if self.cancelled:  # the run stops
            raise RunCancelled
        items = self.items
        assert items is not None  # formed by prepare()
        index, state = items[k]
        executable, agent = self.item_programs[k]
        state, *piece, iterations, lanes, optimal = executable(  # donated
            *self._arguments(agent, state, index, chunk))
        items[k] = (index, state)
        episodes = np.asarray(state.episode)[: index.size].copy()
        copy = (jax.tree.map(lambda leaf: np.array(np.asarray(leaf)[: index.size]), state)
                if snapshot else None)
        returns, lengths, cut = (np.asarray(x)[: index.size] for x in piece)
        return ItemPiece(returns=returns, lengths=lengths, cut=cut,
                         optimal=None if optimal is None else np.asarray(optimal)[: index.size],
                         iterations=int(iterations), lanes=int(lanes), episodes=episodes,
                         finished=bool(episodes.min(initial=chunk[1]) >= chunk[1]), copy=copy)

    def run_chunks(self, bounds: ChunkSchedule, chunk_length: int, ahead: int,
                   snapshots: bool = False) -> Generator[Piece, None, None]:
        """Advance every agent chunk by chunk (after :meth:`prepare`); yields each chunk's
        :class:`~vdbejax.engine.chunks.Piece` s (numpy buffers): one round of native
        calls, one per work item that has not finished the chunk, each of at most
        ``chunk_steps`` loop iterations — the whole chunk unless an item needs more (very
        long episodes): then the chunk takes several pieces, the last one ``finished``.
        ``iterations``: Σ agent iterations (steps, plus one per episode start after a
        truncation); ``lanes``: Σ loop iterations × lanes (idle lanes included).

        ``bounds``: each chunk's ``(first, end)`` episodes (decided as each is queued).
        Up to ``ahead`` later chunks run while a chunk is handed out, so no thread waits
        for the slowest item at each chunk's end (an item that has not finished a chunk
        continues it first). :meth:`agents` returns the state at the end of the piece
        just handed out with ``snapshots`` (from copies each item takes after each call)
        or with ``ahead=0`` (every item waits there until the next piece is asked for);
        otherwise only once the last chunk is handed out. An item's chunks run in order;
        items start most costly first by the steps of the latest chunk known when they
        are queued (their order only affects the balance).
        """
        num_agents = int(self.keys.shape[0])
        items = self.items  # formed by prepare(); the list itself is updated in place
        assert items is not None
        serial = self.threads == 1 or len(items) == 1
        pool = None if serial else ThreadPoolExecutor(max_workers=self.threads)
        pending: dict[tuple[int, int], Any] = {}  # (chunk, item) -> Future or output
        costs = None
        copies: dict[int, Any] = {}  # each item's latest snapshot

        def submit(c: int, k: int, before: Future | None) -> None:
            chunk = (*bounds[c], chunk_length)
            self.host_current = False  # the items move on
            if pool is None:
                pending[c, k] = self._run_item(k, chunk, None, snapshots)
            else:
                pending[c, k] = pool.submit(self._run_item, k, chunk, before, snapshots)

        def queue(c: int) -> None:
            order = sorted(range(len(items)), key=lambda k: -(
                1.0 if costs is None else float(costs[items[k][0]].sum())))
            for k in order:
                submit(c, k, pending.get((c - 1, k)))

        def result(c: int, k: int) -> ItemPiece | None:
            output = pending.pop((c, k))
            return output if pool is None else output.result()

        try:
            queued, c = 0, 0
            while bounds.exists(c):
                while queued < c + 1 + (0 if pool is None else ahead) and bounds.exists(queued):
                    queue(queued)
                    queued += 1
                first, end = bounds[c]
                steps = np.zeros(num_agents, np.int64)  # the chunk's steps, per agent
                running = list(range(len(items)))  # items that have not finished chunk c
                episodes = np.empty(num_agents, np.int64)  # each agent's, after each piece
                while running:
                    returns = np.zeros((num_agents, chunk_length), np.float32)
                    lengths = np.zeros((num_agents, chunk_length), np.int32)
                    cut = np.zeros((num_agents, chunk_length), bool)
                    optimal = (None if self.mdp.optimal_action is None
                               else np.zeros((num_agents, chunk_length), np.int32))
                    iterations = lane_iterations = 0
                    unfinished = []
                    for k in range(len(items)):
                        index = items[k][0]
                        output = result(c, k) if k in running else None
                        if output is None and k in running:  # queued behind an unfinished
                            submit(c, k, None)               # call of the previous chunk
                            output = result(c, k)
                        if output is None:  # finished the chunk in an earlier piece
                            continue
                        returns[index], lengths[index] = output.returns, output.lengths
                        cut[index] = output.cut
                        if optimal is not None:
                            assert output.optimal is not None  # (counted with the mask)
                            optimal[index] = output.optimal
                        iterations += output.iterations
                        lane_iterations += output.lanes
                        episodes[index] = output.episodes
                        copies[k] = output.copy
                        if not output.finished:
                            unfinished.append(k)
                    if snapshots:
                        self._hold([(items[k][0], copies[k]) for k in range(len(items))])
                    steps += lengths.sum(axis=1)
                    yield Piece(c=c, first=first, end=end, returns=returns, lengths=lengths,
                                cut=cut, optimal=optimal, iterations=iterations,
                                lanes=lane_iterations, episodes=episodes.copy(),
                                finished=not unfinished)
                    for k in unfinished:  # the chunk continues where its agents stand
                        submit(c, k, None)
                    running = unfinished
                costs = steps
                c += 1
        finally:
            self.cancelled = True  # a running item stops at its next native call
            if pool is not None:
                pool.shutdown(wait=True, cancel_futures=True)
            self.cancelled = False


assert LANES <= UNROLLED_LANES_MAX  # wider loops would use scatters: not native


def _row(table: Array, row: Array) -> Array:
    """Row ``row`` (not negative) of a 2-D table, ``[1, width]``."""
    return jax.lax.dynamic_slice(table, (row, 0), (1, table.shape[1]),
                                 allow_negative_indices=False)


def lanes_for(rows: int) -> int:
    """The loop width for a work item of ``rows`` (padded, power-of-two) rows."""
    return min(LANES, rows)


def _run_sequential(mdp: TabularMDP, agent: Any, agents: AgentState, chunk_start: Array,
                    chunk_end: Array, count: Array, budget: Array, support: Any,
                    kind: Array | None = None, *, chunk_length: int, lanes: int
                    ) -> tuple[AgentState, Array, Array, Array, Array, Array, Array | None]:
    """:func:`_chunk_loops` as one native call: its whole body inside a ``while`` loop of
    one trip, which XLA's CPU backend compiles into one function (the loop's contents are
    not dispatched operation by operation, and none waits for a thread of the pool that
    another work item's loop occupies)."""
    num_agents = agents.episode.shape[0]
    zero = jnp.asarray(0, jnp.int32)
    outputs = (agents, jnp.zeros((num_agents, chunk_length), jnp.float32),
               jnp.zeros((num_agents, chunk_length), jnp.int32),
               jnp.zeros((num_agents, chunk_length), jnp.bool_), zero, zero,
               optimal_buffer(mdp, num_agents, chunk_length))

    def once(carry: tuple) -> tuple:
        _, agents, returns, lengths, cut, _, _, optimal = carry
        return (jnp.asarray(True), *_chunk_loops(
            mdp, agent, agents, ChunkBuffers(returns=returns, lengths=lengths, cut=cut,
                                             optimal=optimal),
            ChunkBounds(start=chunk_start, end=chunk_end),
            (count, budget), support, lanes=lanes, kind=kind))

    return jax.lax.while_loop(lambda carry: ~carry[0], once,
                              (jnp.asarray(False), *outputs))[1:]


def _chunk_loops(mdp: TabularMDP, agent: Any, agents: AgentState, buffers: ChunkBuffers,
                 chunk: ChunkBounds, work: tuple[Array, Array],
                 support: Any, *, lanes: int, kind: Array | None = None,
                 ) -> tuple[AgentState, Array, Array, Array, Array, Array, Array | None]:
    """Agents ``0 .. count-1`` of the batch run their own step loops to ``chunk_end``,
    ``lanes`` agents at a time side by side, writing their episodes into the zeroed
    ``[agents, chunk_length]`` buffers (:class:`~vdbejax.engine.step.ChunkBuffers`:
    returns, lengths, cut and, where the task's ``optimal_action`` mask is set, the
    counts of optimal actions).

    The step is :func:`lockstep_iteration` on a batch of ``lanes`` lanes, whose table
    accesses are unrolled dynamic slices, so XLA's CPU backend compiles the loop into one
    native function (given the small-while-loop threshold that :mod:`vdbejax._xla_flags`
    sets) instead of dispatching ~30 kernels per step. When a lane's agent has finished
    the chunk, the loop stops, the lane's agent is written back and the next waiting agent
    takes the lane; once none waits, the lanes run until their agents have all finished.
    ``work`` is ``(count, budget)``: the loops stop after ``budget`` iterations, each
    lane's agent written back where it stands (mid-episode, or waiting): a next call
    continues the chunk, its lanes taking the first agents that have not finished it, with
    the same results as one call.
    ``agent`` holds the work item's hyperparameters, all of one kind: the kind's types
    fix the program, so XLA keeps only the work that kind needs — or, with ``kind``,
    ``agent`` holds every kind's (a tuple) and one program serves them all
    (:class:`~vdbejax.engine.kinds.KindSwitch`). Rows from ``count`` on
    are padding and never run. The batch's tables are updated in place (``agents`` is
    donated): a loop indexes them at its agents' rows.

    Returns:
      ``(agents, returns, lengths, cut, iterations, lane_iterations, optimal)``: the agents' active
      iterations (steps, plus one per episode start after a truncation) and the loops'
      iterations × ``lanes``.
    """
    num_agents = agents.episode.shape[0]
    chunk_start, chunk_end = chunk.start, chunk.end
    count, budget = work

    def scalars(state: AgentState) -> AgentState:
        # The state without its tables (a tree of the scalar fields): None is no leaf.
        return _pytree.replace(state, q=None, tables=None)

    # Each agent's scalars (and hyperparameters) as one row of 32-bit words: handing a
    # lane another agent then moves one row, not one value per field (a program a
    # quarter smaller, which every process loads from disk).
    fields_layout, agent_layout = scalars(agents), agent
    packed, agent_packed = pack(fields_layout), pack(agent)

    def lane_rows(table: Array, rows: Array) -> Array:
        """Rows ``rows`` (clipped to the batch) of a packed table: one per lane."""
        rows = jnp.clip(rows, 0, num_agents - 1)
        return jnp.concatenate([_row(table, at_lane(rows, k)) for k in range(lanes)])

    def refill(carry: tuple) -> tuple:
        """Run the lanes until one finishes; hand finished lanes the next agents."""
        (tables, packed, lane_packed, lane_agent, rows, waiting_from, buffers, trips,
         used) = carry
        real = rows < count
        lane_state = dataclasses.replace(unpack(lane_packed, fields_layout), q=tables[0],
                                         tables=tables[1])
        lane_params = unpack(lane_agent, agent_layout)
        if kind is not None:
            lane_params = KindSwitch(kinds=lane_params, kind=kind)
        lane_state, buffers, loop_trips = run_loop(
            mdp, lane_params, lane_state, buffers,
            ChunkBounds(start=chunk_start, end=jnp.where(real, chunk_end, 0)),
            LoopLimits(max_iterations=budget - used, stop_at_first_finish=waiting_from < count),
            support, table_rows=rows,
        )
        tables = (lane_state.q, lane_state.tables)
        finished = real & (lane_state.episode >= chunk_end)
        lane_packed = pack(scalars(lane_state))
        for k in range(lanes):  # write back a finished lane's agent, take the next one
            done, row = at_lane(finished, k), at_lane(rows, k)
            clipped = jnp.clip(row, 0, num_agents - 1)
            packed = jax.lax.dynamic_update_slice(
                packed, jnp.where(done, lane_packed[k:k + 1], _row(packed, clipped)),
                (clipped, 0), allow_negative_indices=False)
            take_next = done & (waiting_from < count)
            rows = rows.at[k].set(jnp.where(done, jnp.where(
                take_next, waiting_from, num_agents), row))
            waiting_from = waiting_from + take_next.astype(jnp.int32)
        lane_packed = jnp.where(finished[:, None], lane_rows(packed, rows), lane_packed)
        lane_agent = jnp.where(finished[:, None], lane_rows(agent_packed, rows), lane_agent)
        return (tables, packed, lane_packed, lane_agent, rows, waiting_from, buffers,
                trips + loop_trips * lanes, used + loop_trips)

    def any_lane_busy(carry: tuple) -> Array:
        return jnp.any(carry[4] < count) & (carry[8] < budget)

    # The lanes start with the first agents that have not finished the chunk (a call that
    # continues one), the others wait in row order (any agent past the last one taken has
    # not started the chunk); the first call of a chunk takes rows 0, 1, ….
    unfinished = (agents.episode < chunk_end) & (jnp.arange(num_agents) < count)
    rows = jnp.nonzero(unfinished, size=lanes, fill_value=num_agents)[0].astype(jnp.int32)
    waiting = jnp.where(jnp.sum(unfinished) > lanes, rows[lanes - 1] + 1, count).astype(
        jnp.int32)
    zero = jnp.asarray(0, jnp.int32)
    started = agents.counter
    (tables, packed, lane_packed, _, rows, _, buffers, lane_iterations,
     _) = jax.lax.while_loop(
        any_lane_busy, refill,
        ((agents.q, agents.tables), packed, lane_rows(packed, rows),
         lane_rows(agent_packed, rows), rows, waiting, buffers, zero, zero))
    for k in range(lanes):  # out of budget: the lanes' agents written back where they stand
        row = at_lane(rows, k)
        clipped = jnp.clip(row, 0, num_agents - 1)
        packed = jax.lax.dynamic_update_slice(
            packed, jnp.where(row < count, lane_packed[k:k + 1], _row(packed, clipped)),
            (clipped, 0), allow_negative_indices=False)
    agents = dataclasses.replace(unpack(packed, fields_layout), q=tables[0], tables=tables[1])
    real_rows = jnp.arange(num_agents) < count
    iterations = jnp.sum(jnp.where(real_rows, agents.counter - started, 0)).astype(jnp.int32)
    return (agents, buffers.returns, buffers.lengths, buffers.cut, iterations, lane_iterations,
            buffers.optimal)
