"""The sequential strategy's traced loop: :data:`LANES` agents side by side in one native
``while`` loop of steps; a lane whose agent has finished the chunk takes the work item's
next agent. :mod:`vdbejax.engine.sequential` compiles it and runs the work items.
"""
from __future__ import annotations

import dataclasses
from typing import Any

import jax
import jax.numpy as jnp

from vdbejax import _pytree
from vdbejax.engine.kinds import KindSwitch
from vdbejax.engine.lanes import UNROLLED_LANES_MAX, at_lane
from vdbejax.engine.packing import _pack, _unpack
from vdbejax.engine.state import AgentState
from vdbejax.engine.step import optimal_buffer, run_loop
from vdbejax.engine.work_items import LANES
from vdbejax.envs.tabular import TabularMDP

Array = jax.Array


assert LANES <= UNROLLED_LANES_MAX  # wider loops would use scatters: not native


def _row(table: Array, row: Array) -> Array:
    """Row ``row`` (not negative) of a 2-D table, ``[1, width]``."""
    return jax.lax.dynamic_slice(table, (row, 0), (1, table.shape[1]),
                                 allow_negative_indices=False)


def lanes_for(rows: int) -> int:
    """The loop width for a work item of ``rows`` (padded, power-of-two) rows."""
    return min(LANES, rows)


def _run_sequential(mdp: TabularMDP, agent: Any, agents: AgentState, chunk_start: Array,
                    chunk_end: Array, count: Array, support: Any, kind: Array | None = None,
                    *, chunk_length: int, lanes: int
                    ) -> tuple[AgentState, Array, Array, Array, Array, Array | None]:
    """:func:`_chunk_loops` as one native call: its whole body inside a ``while`` loop of
    one trip, which XLA's CPU backend compiles into one function (the loop's contents are
    not dispatched operation by operation, and none waits for a thread of the pool that
    another work item's loop occupies)."""
    num_agents = agents.episode.shape[0]
    zero = jnp.asarray(0, jnp.int32)
    outputs = (agents, jnp.zeros((num_agents, chunk_length), jnp.float32),
               jnp.zeros((num_agents, chunk_length), jnp.int32), zero, zero,
               optimal_buffer(mdp, num_agents, chunk_length))

    def once(carry: tuple) -> tuple:
        _, agents, returns, lengths, _, _, optimal = carry
        return (jnp.asarray(True), *_chunk_loops(
            mdp, agent, agents, returns, lengths, chunk_start, chunk_end, count, support,
            lanes=lanes, kind=kind, optimal=optimal))

    return jax.lax.while_loop(lambda carry: ~carry[0], once,
                              (jnp.asarray(False), *outputs))[1:]


def _chunk_loops(mdp: TabularMDP, agent: Any, agents: AgentState, returns: Array,
                 lengths: Array, chunk_start: Array, chunk_end: Array, count: Array,
                 support: Any, *, lanes: int, kind: Array | None = None,
                 optimal: Array | None = None
                 ) -> tuple[AgentState, Array, Array, Array, Array, Array | None]:
    """Agents ``0 .. count-1`` of the batch run their own step loops to ``chunk_end``,
    ``lanes`` agents at a time side by side, writing their episodes into the zeroed
    ``[agents, chunk_length]`` buffers ``returns`` and ``lengths`` (and ``optimal``, the
    counts of optimal actions, where the task's ``optimal_action`` mask is set).

    The step is :func:`lockstep_iteration` on a batch of ``lanes`` lanes, whose table
    accesses are unrolled dynamic slices, so XLA's CPU backend compiles the loop into one
    native function (given the small-while-loop threshold that :mod:`vdbejax._xla_flags`
    sets) instead of dispatching ~30 kernels per step. When a lane's agent has finished
    the chunk, the loop stops, the lane's agent is written back and the next waiting agent
    takes the lane; once none waits, the lanes run until their agents have all finished.
    ``agent`` holds the work item's hyperparameters, all of one kind: the kind's types
    fix the program, so XLA keeps only the work that kind needs — or, with ``kind``,
    ``agent`` holds every kind's (a tuple) and one program serves them all
    (:class:`~vdbejax.engine.kinds.KindSwitch`). Rows from ``count`` on
    are padding and never run. The batch's tables are updated in place (``agents`` is
    donated): a loop indexes them at its agents' rows.

    Returns:
      ``(agents, returns, lengths, iterations, lane_iterations, optimal)``: the agents' active
      iterations (steps, plus one per episode start after a truncation) and the loops'
      iterations × ``lanes``.
    """
    num_agents = agents.episode.shape[0]
    big = jnp.asarray(jnp.iinfo(jnp.int32).max, jnp.int32)

    def scalars(state: AgentState) -> AgentState:
        # The state without its tables (a tree of the scalar fields): None is no leaf.
        return _pytree.replace(state, q=None, tables=None)

    # Each agent's scalars (and hyperparameters) as one row of 32-bit words: handing a
    # lane another agent then moves one row, not one value per field (a program a
    # quarter smaller, which every process loads from disk).
    fields_layout, agent_layout = scalars(agents), agent
    packed, agent_packed = _pack(fields_layout), _pack(agent)

    def lane_rows(table: Array, rows: Array) -> Array:
        """Rows ``rows`` (clipped to the batch) of a packed table: one per lane."""
        rows = jnp.clip(rows, 0, num_agents - 1)
        return jnp.concatenate([_row(table, at_lane(rows, k)) for k in range(lanes)])

    def refill(carry: tuple) -> tuple:
        """Run the lanes until one finishes; hand finished lanes the next agents."""
        (tables, packed, lane_packed, lane_agent, rows, waiting_from, returns, lengths,
         optimal, trips) = carry
        real = rows < count
        lane_state = dataclasses.replace(_unpack(lane_packed, fields_layout), q=tables[0],
                                         tables=tables[1])
        lane_params = _unpack(lane_agent, agent_layout)
        if kind is not None:
            lane_params = KindSwitch(kinds=lane_params, kind=kind)
        lane_state, returns, lengths, loop_trips, optimal = run_loop(
            mdp, lane_params, lane_state, returns, lengths,
            chunk_start, jnp.where(real, chunk_end, 0), big, 1, support, table_rows=rows,
            stop_at_first_finish=waiting_from < count, optimal=optimal,
        )
        tables = (lane_state.q, lane_state.tables)
        finished = real & (lane_state.episode >= chunk_end)
        lane_packed = _pack(scalars(lane_state))
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
        return (tables, packed, lane_packed, lane_agent, rows, waiting_from, returns, lengths,
                optimal, trips + loop_trips * lanes)

    def any_lane_busy(carry: tuple) -> Array:
        return jnp.any(carry[4] < count)

    lane = jnp.arange(lanes, dtype=jnp.int32)
    rows = jnp.where(lane < count, lane, num_agents)
    zero = jnp.asarray(0, jnp.int32)
    started = agents.counter
    tables, packed, *_, returns, lengths, optimal, lane_iterations = jax.lax.while_loop(
        any_lane_busy, refill,
        ((agents.q, agents.tables), packed, lane_rows(packed, rows),
         lane_rows(agent_packed, rows), rows, jnp.asarray(lanes, jnp.int32), returns,
         lengths, optimal, zero))
    agents = dataclasses.replace(_unpack(packed, fields_layout), q=tables[0], tables=tables[1])
    real_rows = jnp.arange(num_agents) < count
    iterations = jnp.sum(jnp.where(real_rows, agents.counter - started, 0)).astype(jnp.int32)
    return agents, returns, lengths, iterations, lane_iterations, optimal
