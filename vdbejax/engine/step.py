"""The step rule: one iteration of a batch of agents of one kind.

One iteration of one agent (``s, a`` = current state and the action already chosen):

1. If a reset is pending (first step, or after a truncation): ``s ← start``, choose
   ``a`` in it, nothing is learned.
2. Otherwise step ``s, a → s', r``; choose the next action ``a'`` in ``s'`` (in the new
   episode's start state if the transition was terminal). A learner with
   ``uses_next_action`` (SARSA) chooses ``a'`` with the tables *before* updating
   ``Q(s, a)`` (its target needs ``Q(s', a')``); the others choose it *after* the update
   (so a self-loop sees its own new values). Then update ``Q(s, a)`` (and the learner's
   tables at ``(s, a)``) and the explorer's tables of ``s``.

The per-agent part (:func:`~vdbejax.engine.kind_step.agent_step`) calls the plug-ins on
one agent's rows and is ``vmap``-ed over the lanes; around it, :func:`lockstep_iteration`
reads and writes the lanes' tables. Tables are flat 1-D buffers (``[B·S·A]``,
``[B·S]``), so every access is a 1-D gather or scatter of one row per lane, and for a
batch of a few lanes (the sequential strategy) unrolled dynamic slices: XLA's CPU backend
then compiles the whole loop natively.
"""
from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from vdbejax import _pytree
from vdbejax._numerics import sample_categorical
from vdbejax.engine.agent_on_task import lane_optimal, lane_rows, lane_start, lane_transition
from vdbejax.engine.agent_state import AgentState, draw_base, reward_uniform, uniforms_from
from vdbejax.engine.kind_step import StepOperands, kind_part, num_uniforms, uniform_parts
from vdbejax.engine.kinds import KindSwitch, is_whole_kind, switch_part, table_forms, write_form
from vdbejax.engine.lanes import is_unrolled, put_learned, put_where, take, take_row, write_lanes
from vdbejax.engine.whole import LearnedStep, after_learning, defers_selection, whole_blocks
from vdbejax.envs.reward_noise import noisy_reward
from vdbejax.envs.tabular import TabularMDP
from vdbejax.methods.agents import Agent
from vdbejax.methods.contract import Context
from vdbejax.methods.model import capacity

Array = jax.Array

def start_support(mdp: TabularMDP) -> tuple[Array, Array]:
    """States with a positive start probability and their weights (host side if possible).

    Sampling from the support with :func:`sample_categorical` picks the same state as
    sampling from the full distribution (zero weights add nothing to the partial sums),
    but costs a few comparisons per agent instead of ``S``. Under a trace the support is
    unknown and the full distribution is used.
    """
    probability = mdp.start_probability
    if isinstance(probability, jax.core.Tracer):
        return jnp.arange(mdp.num_states, dtype=jnp.int32), probability
    host = np.asarray(probability)
    support = np.flatnonzero(host > 0).astype(np.int32)
    # device_put, not jnp.asarray: that compiles a small program per shape (≈ 10 ms each)
    return jax.device_put(support), jax.device_put(host[support])


def _transition(mdp: TabularMDP, s: Array, a: Array, u: Array, noise_u: Array | None
                ) -> tuple[Array, Array, Array]:
    """Batched :meth:`TabularMDP.transition` (flat 1-D gathers when deterministic)."""
    if mdp.num_outcomes != 1:
        return jax.vmap(mdp.transition)(s, a, u, noise_u)
    flat = s * mdp.num_actions + a

    def at(table: Array) -> Array:
        return take(table.reshape(-1), flat)

    reward = at(mdp.reward)
    if mdp.reward_noise is not None:  # static: a task without noise draws nothing
        assert noise_u is not None  # (lockstep_iteration draws it for such a task)
        noise = mdp.reward_noise
        reward = noisy_reward(reward, at(noise.model), at(noise.std), noise_u)
    return at(mdp.next_state), reward, at(mdp.terminal)


@_pytree.pytree_dataclass
class ChunkBuffers:
    """A chunk's records of each agent's episodes (``[agents, L]``, flat ``[B·L]`` inside
    an iteration): ``returns`` (float32), ``lengths`` (int32), ``cut`` (bool: the step
    limit ended the episode, its last step not terminal) and ``optimal`` (int32,
    each episode's steps whose action is one of ``mdp.optimal_action``; ``None`` for a
    task without that mask: no record, the same program as without it)."""

    returns: Array
    lengths: Array
    cut: Array
    optimal: Array | None = None


@_pytree.pytree_dataclass
class ChunkBounds:
    """The chunk an agent runs: ``start``, the episode index of its buffers' slot 0, and
    ``end``, the episode count at which the agent stops being active (int32 scalars or
    one per lane)."""

    start: Array | np.integer
    end: Array | np.integer


@_pytree.pytree_dataclass
class LoopLimits:
    """When :func:`run_loop` stops.

    Attributes:
      max_iterations: at most this many iterations (int32 scalar).
      stop_at_first_finish: a boolean scalar: where true, the loop also stops as soon as
        one agent has finished the chunk (so that its lane can take another agent);
        ``None``: no such stop.
      unroll: iterations per loop trip (static; results do not depend on it).
      fixed_iterations: (static) exactly this many iterations, rounded up to a multiple
        of ``unroll`` (a loop of known trip count: on an accelerator no iteration waits
        for the host to read the loop's condition); ``None``: ``while`` any agent is
        active.
    """

    max_iterations: Array | np.integer
    stop_at_first_finish: Array | None = None
    unroll: int = _pytree.static_field(1)
    fixed_iterations: int | None = _pytree.static_field(None)


@dataclasses.dataclass(frozen=True)
class LaneOffsets:
    """Where each lane's rows lie in an iteration's flat buffers.

    Attributes:
      lane: each lane's index, ``0 .. B-1``.
      table_lane: the row of each lane's agent in the tables and record buffers (its lane,
        or ``table_rows``: the buffers hold more agents than the batch).
      pair_base: the flat index of each lane's first ``(s, a)`` in a Q-shaped table
        (``table_lane·S·A``).
      state_base: the flat index of each lane's first state in a per-state table
        (``table_lane·S``).
      chunk_length: the episodes of each agent's record buffers.
    """

    lane: Array
    table_lane: Array
    pair_base: Array
    state_base: Array
    chunk_length: int

    @classmethod
    def of(cls, mdp: TabularMDP, agents: AgentState, buffers: ChunkBuffers,
           table_rows: Array | None) -> LaneOffsets:
        num_agents = agents.episode.shape[0]
        S, A = mdp.num_states, mdp.num_actions
        lane = jnp.arange(num_agents, dtype=jnp.int32)
        table_lane = lane if table_rows is None else table_rows
        rows = num_agents if table_rows is None else agents.q.shape[0] // (S * A)
        chunk_length = buffers.returns.shape[0] // rows
        return cls(lane=lane, table_lane=table_lane, pair_base=table_lane * (S * A),
                   state_base=table_lane * S, chunk_length=chunk_length)


@dataclasses.dataclass(frozen=True)
class Move:
    """An iteration's environment step, per lane (:func:`_move`).

    Attributes:
      active: the agent has not finished the chunk.
      resetting: a reset is pending: the step starts an episode and learns nothing.
      learn: active and not resetting: the step is learned from.
      u: the iteration's uniforms (the most any kind of the batch draws).
      s: the state left.
      a: the action taken, clipped to the task's actions.
      valid_a: the stored action was one of the task's.
      s_next: the state reached.
      reward: the step's reward.
      terminal: the step ended its episode.
      length: the episode's steps with this one.
      truncated: the episode reached the task's ``max_steps`` without a terminal step.
      act_state: where the next action is chosen (``s_next``, or the next episode's start
        state after a reset or a terminal step).
      done: a learned step ended the episode (terminal or truncated).
      own: each lane's own task instance, or ``None`` (one shared task).
    """

    active: Array
    resetting: Array
    learn: Array
    u: tuple
    s: Array
    a: Array
    valid_a: Array
    s_next: Array
    reward: Array
    terminal: Array
    length: Array
    truncated: Array
    act_state: Array
    done: Array
    own: Any


def _move(mdp: TabularMDP, agent: Agent | KindSwitch, agents: AgentState, bounds: ChunkBounds,
          support: tuple[Array, Array], at: LaneOffsets, base: Array | None) -> Move:
    """Step 1 of an iteration: the uniforms drawn, every lane's ``s, a → s', r`` and where
    its next action is chosen."""
    kinds = agent.kinds if isinstance(agent, KindSwitch) else (agent,)
    A = mdp.num_actions
    active = agents.episode < bounds.end
    # Draw j depends on (key, counter, j) alone: drawing the most any kind needs gives
    # every kind its own draws.
    if base is None:
        base = draw_base(agents.key, agents.counter)
    u = uniforms_from(base, max(num_uniforms(k, A) for k in kinds))
    resetting = agents.pending_reset
    learn = active & ~resetting
    s, a = agents.state, agents.action
    valid_a = (a >= 0) & (a < A)
    # An invalid action (flagged below) still indexes this agent's own rows only: its
    # neighbours' tables lie next to them in the same buffer.
    a = jnp.clip(a, 0, A - 1)

    noise_u = None if mdp.reward_noise is None else reward_uniform(base)
    own = lane_rows(agent)  # each lane's own task instance, or None (one shared task)
    s_next, reward, terminal = (_transition(mdp, s, a, u[1], noise_u) if own is None
                                else lane_transition(own, at.lane, s, a, u[1], noise_u))
    length = agents.episode_length + 1
    truncated = ~terminal & (length >= mdp.max_steps)
    if own is None:
        states, weights = support
        s_start = take(states, sample_categorical(weights, u[0]))
    else:
        s_start = lane_start(own, at.lane, u[0])
    # Choose the next action in s' (in the new episode's start state after a terminal
    # step). That row also serves the target: a terminal step has discount 0, so which
    # row it multiplies does not matter (for finite Q), and one gather is saved.
    act_state = jnp.where(resetting | terminal, s_start, s_next)
    done = learn & (terminal | truncated)
    return Move(active=active, resetting=resetting, learn=learn, u=u, s=s, a=a,
                valid_a=valid_a, s_next=s_next, reward=reward, terminal=terminal,
                length=length, truncated=truncated, act_state=act_state, done=done, own=own)


def _read(mdp: TabularMDP, agents: AgentState, move: Move, at: LaneOffsets) -> StepOperands:
    """Step 2: the rows of Q the step reads, its contexts, and what the kinds' part reads
    (:class:`~vdbejax.engine.kind_step.StepOperands`)."""
    A = mdp.num_actions
    s, act_state, resetting = move.s, move.act_state, move.resetting
    sa_index = at.pair_base + s * A + move.a
    q_sa = take(agents.q, sa_index)
    q_next = take_row(agents.q, at.pair_base + act_state * A, A)
    update_context = Context(episode=agents.episode, step=move.length, terminal=move.terminal)
    select_context = Context(episode=agents.episode + move.done.astype(jnp.int32),
                             step=jnp.where(resetting | move.done, 0, move.length),
                             terminal=jnp.zeros_like(move.terminal))
    self_loop = ~resetting & (act_state == s)
    return StepOperands(
        tables=agents.tables, a=move.a, s=s, act_state=act_state, q_sa=q_sa, q_next=q_next,
        reward=move.reward, terminal=move.terminal, self_loop=self_loop, sa_index=sa_index,
        pair_base=at.pair_base, state_base=at.state_base, update_context=update_context,
        select_context=select_context, u=move.u, s_next=move.s_next,
        time=agents.counter.astype(jnp.int32))


def _write_index(form: str, operands: StepOperands, num_actions: int) -> Array:
    """Where a table of this write form (:func:`~vdbejax.engine.kinds.write_form`) is
    written: at ``(s, a)``, at ``s``, or ``s``'s row."""
    if form == "pair_value":
        return operands.sa_index
    s = operands.s
    return (operands.state_base + s if form == "state_value"
            else operands.pair_base + s * num_actions)


def _learn(mdp: TabularMDP, agent: Agent, agents: AgentState, move: Move,
           operands: StepOperands) -> tuple[Array, dict, Array, Array]:
    """Step 3 for a batch of one kind: its part of the step (learning and the next
    choice), its rows written back, and a whole kind's model, planning and deferred
    choice (:mod:`vdbejax.engine.whole`).

    Returns:
      ``(q, tables, next_action, finite)``.
    """
    num_agents = agents.episode.shape[0]
    S, A = mdp.num_states, mdp.num_actions
    learn, sa_index, pair_base = move.learn, operands.sa_index, operands.pair_base
    tables = dict(agents.tables)
    whole_kind = is_whole_kind(agent)
    blocks = (whole_blocks(agents.q, agents.tables, agent.learner, pair_base, S * A, (S, A))
              if agent.learner.updates_whole_table else None)
    new_q_sa, learned, explored, next_action, finite = kind_part(
        agent, operands, num_actions=A, whole=blocks,
        select_next=not (whole_kind and defers_selection(agent.learner)),
        skip_unchanged=blocks is None)
    if blocks is None:
        q = (agents.q if new_q_sa is None
             else put_learned(agents.q, sa_index, new_q_sa, operands.q_sa, learn))
        for name, (new, old) in learned.items():
            spec = agent.learner.tables()[name]
            tables[name] = put_learned(tables[name], sa_index * spec.width(), new, old,
                                       learn, spec.per == "stage")
    else:  # the whole Q and learner tables
        assert new_q_sa is not None  # (only rows are left unwritten)
        q = put_learned(agents.q, pair_base, new_q_sa.reshape(num_agents, -1),
                        blocks[0].reshape(num_agents, -1), learn, True)
        for name, (new, old) in learned.items():
            width = agent.learner.tables()[name].width()  # a stage table's block is wider
            tables[name] = put_learned(tables[name], pair_base * width,
                                       new.reshape(num_agents, -1),
                                       old.reshape(num_agents, -1), learn, True)
    for name, spec in agent.explorer.tables().items():
        new, old = explored[name]
        tables[name] = put_learned(
            tables[name], _write_index(write_form("explorer", spec.per), operands, A),
            new, old, learn, spec.per == "pair")
    if whole_kind:
        explorer_u, _, _, plan_u = uniform_parts(agent, move.u, A)
        q, tables, next_action, finite = after_learning(
            agent, q, tables, next_action, finite, LearnedStep(
                s=move.s, s_next=move.s_next, act_state=move.act_state, reward=move.reward,
                terminal=move.terminal, sa_index=sa_index, pair_base=pair_base,
                state_base=operands.state_base, learn=learn, active=move.active,
                resetting=move.resetting, counter=agents.counter,
                select_context=operands.select_context, explorer_uniforms=explorer_u,
                plan_uniforms=plan_u, num_states=S, num_actions=A,
                capacity=capacity(S, mdp.num_outcomes)))
    return q, tables, next_action, finite


def _learn_switch(mdp: TabularMDP, switch: KindSwitch, agents: AgentState, move: Move,
                  operands: StepOperands, at: LaneOffsets) -> tuple[Array, dict, Array, Array]:
    """Step 3 for a :class:`~vdbejax.engine.kinds.KindSwitch`: every kind's part
    (:func:`~vdbejax.engine.kinds.switch_part`), each lane's own kind's rows written back.

    Returns:
      ``(q, tables, next_action, finite)``.
    """
    A = mdp.num_actions
    tables = dict(agents.tables)
    forms = table_forms(switch.kinds)
    assert forms is not None, "see can_switch"
    new_q_sa, writes, next_action, finite = switch_part(
        switch, operands, num_actions=A, forms=forms,
        dtypes={name: table.dtype for name, table in tables.items()})
    q = put_learned(agents.q, operands.sa_index, new_q_sa, operands.q_sa, move.learn)
    for name, (value, owned) in writes.items():
        form, mask = forms[name], move.learn & owned
        index = _write_index(form, operands, A)
        if is_unrolled(at.lane):  # a masked lane rewrites what is there
            tables[name] = write_lanes(tables[name], index, value, mask)
        else:  # where a lane's kind does not own the table, the value read is kept
            width = value.shape[1]
            old = take(tables[name], index) if width == 1 else take_row(tables[name], index,
                                                                         width)
            tables[name] = put_learned(tables[name], _write_index(form, operands, A),
                                       value if width > 1 else value[:, 0], old, mask,
                                       width > 1)
    return q, tables, next_action, finite


def _record(mdp: TabularMDP, agents: AgentState, move: Move, at: LaneOffsets,
            bounds: ChunkBounds, buffers: ChunkBuffers) -> tuple[ChunkBuffers, Array]:
    """Step 4: a finished episode's return, length and whether the step limit cut it
    written to its slot (and the running episode's count of optimal actions).

    Returns:
      ``(buffers, episode_return)``, the running episode's return with this step's reward.
    """
    A = mdp.num_actions
    episode_return = agents.episode_return + move.reward
    slot = agents.episode - bounds.start
    out = at.table_lane * at.chunk_length + slot
    returns = put_where(buffers.returns, out, episode_return, move.done)
    lengths = put_where(buffers.lengths, out, move.length, move.done)
    cut = put_where(buffers.cut, out, move.truncated, move.done)
    optimal = buffers.optimal
    if optimal is not None:  # the running episode's slot (only a learning lane's is real)
        assert mdp.optimal_action is not None  # (the run hands the mask with the buffer)
        hit = (take(mdp.optimal_action.reshape(-1), move.s * A + move.a) if move.own is None
               else lane_optimal(move.own, at.lane, move.s, move.a))
        counted = take(optimal, jnp.clip(out, 0, optimal.shape[0] - 1))
        optimal = put_where(optimal, out, counted + 1, move.learn & hit)
    return (ChunkBuffers(returns=returns, lengths=lengths, cut=cut, optimal=optimal),
            episode_return)


def _advance(agents: AgentState, move: Move, learned: tuple[Array, dict, Array, Array],
             episode_return: Array) -> AgentState:
    """Step 5: every lane's state after the iteration (an inactive lane's as it was)."""
    q, tables, next_action, finite = learned
    active, learn, done = move.active, move.learn, move.done

    def keep(new: Array, old: Array) -> Array:
        return jnp.where(active, new, old)

    return AgentState(
        q=q,
        tables=tables,
        state=keep(move.act_state, move.s),
        action=keep(next_action, move.a),
        pending_reset=keep(learn & move.truncated, move.resetting),
        episode=agents.episode + done.astype(jnp.int32),
        episode_return=jnp.where(learn, jnp.where(done, 0.0, episode_return),
                                 agents.episode_return),
        episode_length=jnp.where(learn, jnp.where(done, 0, move.length),
                                 agents.episode_length),
        counter=agents.counter + active.astype(jnp.uint32),
        key=agents.key,
        # An action outside [0, A) — what sample_categorical returns for NaN, infinite or
        # all-zero weights, or a plug-in's own draw — is flagged like a NaN in Q when the
        # agent is about to take it (checked on the stored action: cheaper than on the
        # freshly drawn one inside the step's fusions).
        nonfinite=(agents.nonfinite | (learn & ~finite)
                   | (active & ~move.resetting & ~move.valid_a)),
    )


def lockstep_iteration(
    mdp: TabularMDP,
    agent: Agent | KindSwitch,
    agents: AgentState,
    buffers: ChunkBuffers,
    bounds: ChunkBounds,
    support: tuple[Array, Array],
    table_rows: Array | None = None,
    base: Array | None = None,
) -> tuple[AgentState, ChunkBuffers]:
    """One lockstep iteration of a batch of one kind: every agent advances by one step.

    ``agents.q``, every table of ``agents.tables`` and the buffers are flat 1-D arrays
    (``[B·S·A]``, ``[B·S]`` or ``[B·S·A]``, ``[B·L]``). The iteration's steps: the
    environment step (:func:`_move`), the rows read (:func:`_read`), the kind's learning
    and the next choice with the rows written back (:func:`_learn`, or
    :func:`_learn_switch` for a :class:`KindSwitch`), the finished episodes recorded
    (:func:`_record`), the agents' state advanced (:func:`_advance`).

    Args:
      mdp: the task shared by all agents (with a task instance per agent, agent 0's: it
        fixes the shapes and the episode length).
      agent: batched hyperparameters of one kind (leading axis = agents), or a
        :class:`KindSwitch` of every kind's and the one that runs; rows that carry each
        agent's own task instance (:class:`~vdbejax.engine.agent_on_task.AgentOnTask`) are
        stepped on it.
      agents: batched states, tables flattened as above.
      buffers: the chunk's flat ``[B·L]`` records (``L`` episodes per agent).
      bounds: the chunk's first episode (each agent's buffer slot 0) and the episode
        count at which an agent stops being active.
      support: ``(states, weights)`` of the start distribution (:func:`start_support`).
      table_rows: the tables and buffers hold the rows of more agents than the batch,
        lane ``i`` being their agent ``table_rows[i]`` (the sequential strategy updates a
        work item's buffers in place this way).
      base: each agent's :func:`~vdbejax.engine.agent_state.draw_base` of its key and counter,
        if the caller carries it (:func:`run_loop`); else computed here.

    Returns:
      ``(agents, buffers)`` after the iteration.
    """
    at = LaneOffsets.of(mdp, agents, buffers, table_rows)
    move = _move(mdp, agent, agents, bounds, support, at, base)
    operands = _read(mdp, agents, move, at)
    learned = (_learn_switch(mdp, agent, agents, move, operands, at)
               if isinstance(agent, KindSwitch) else _learn(mdp, agent, agents, move, operands))
    buffers, episode_return = _record(mdp, agents, move, at, bounds, buffers)
    return _advance(agents, move, learned, episode_return), buffers


def run_loop(
    mdp: TabularMDP,
    agent: Agent | KindSwitch,
    agents: AgentState,
    buffers: ChunkBuffers,
    bounds: ChunkBounds,
    limits: LoopLimits,
    support: tuple[Array, Array],
    table_rows: Array | None = None,
) -> tuple[AgentState, ChunkBuffers, Array]:
    """``while`` any agent is active and fewer than ``limits.max_iterations`` iterations
    ran, or exactly ``limits.fixed_iterations`` (see :class:`LoopLimits`).

    The body runs ``limits.unroll`` iterations (fewer loop trips); iterations of an agent
    that is no longer active change nothing, so overshooting is harmless. ``buffers``:
    ``[B, L]`` (see :class:`ChunkBuffers`); ``table_rows``: see
    :func:`lockstep_iteration`.

    Returns:
      ``(agents, buffers, iterations)``.
    """
    unroll, stop_at_first_finish = limits.unroll, limits.stop_at_first_finish
    q_shape, out_shape = agents.q.shape, buffers.returns.shape
    table_shapes = {name: table.shape for name, table in agents.tables.items()}
    agents = dataclasses.replace(
        agents, q=agents.q.reshape(-1),
        tables={name: table.reshape(-1) for name, table in agents.tables.items()},
    )

    def cond(carry: tuple) -> Array:
        agents, _, iterations, _ = carry
        active = agents.episode < bounds.end
        go = jnp.any(active) & (iterations < limits.max_iterations)
        if stop_at_first_finish is not None:
            go &= ~stop_at_first_finish | jnp.all(active)
        return go

    def body(carry: tuple) -> tuple:
        agents, buffers, iterations, base = carry
        for _ in range(unroll):
            agents, buffers = lockstep_iteration(mdp, agent, agents, buffers, bounds, support,
                                                 table_rows, base)
            # The next iteration's hash, carried: the loop's buffers hold it once.
            base = draw_base(agents.key, agents.counter)
        return agents, buffers, iterations + unroll, base

    zero = jnp.asarray(0, jnp.int32)
    flat = jax.tree.map(lambda record: record.reshape(-1), buffers)  # (optimal may be None)
    start = (agents, flat, zero, draw_base(agents.key, agents.counter))
    if limits.fixed_iterations is None:
        agents, flat, iterations, _ = jax.lax.while_loop(cond, body, start)
    else:
        trips = -(-limits.fixed_iterations // unroll)
        agents, flat, iterations, _ = jax.lax.fori_loop(
            0, trips, lambda _, carry: body(carry), start)
    agents = dataclasses.replace(
        agents, q=agents.q.reshape(q_shape),
        tables={name: table.reshape(table_shapes[name]) for name, table in agents.tables.items()},
    )
    return agents, jax.tree.map(lambda record: record.reshape(out_shape), flat), iterations


def optimal_buffer(mdp: TabularMDP, num_agents: int, chunk_length: int,
                   zeros: Callable[..., Any] = jnp.zeros) -> Any:
    """A chunk's zeroed ``[agents, chunk_length]`` counts of optimal actions, for a task
    whose ``optimal_action`` mask is set (a run that records them), else ``None``;
    ``zeros``: ``np.zeros`` for a host buffer."""
    if mdp.optimal_action is None:
        return None
    return zeros((num_agents, chunk_length), np.int32)
