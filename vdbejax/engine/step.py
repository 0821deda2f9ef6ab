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

from vdbejax._numerics import sample_categorical
from vdbejax.engine.instances import lane_optimal, lane_rows, lane_start, lane_transition
from vdbejax.engine.kind_step import kind_part, num_uniforms, uniform_parts
from vdbejax.engine.kinds import KindSwitch, switch_part, table_forms, write_form
from vdbejax.engine.lanes import is_unrolled, put_learned, put_where, take, take_row, write_lanes
from vdbejax.engine.state import AgentState, draw_base, reward_uniform, uniforms_from
from vdbejax.engine.whole import (
    LearnedStep,
    after_learning,
    defers_selection,
    is_whole_kind,
    whole_blocks,
)
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


def lockstep_iteration(
    mdp: TabularMDP,
    agent: Agent | KindSwitch,
    agents: AgentState,
    returns: Array,
    lengths: Array,
    chunk_start: Array,
    chunk_end: Array,
    support: tuple[Array, Array],
    table_rows: Array | None = None,
    base: Array | None = None,
    optimal: Array | None = None,
) -> tuple[AgentState, Array, Array, Array | None]:
    """One lockstep iteration of a batch of one kind: every agent advances by one step.

    ``agents.q``, every table of ``agents.tables``, ``returns`` and ``lengths`` are flat
    1-D arrays (``[B·S·A]``, ``[B·S]`` or ``[B·S·A]``, ``[B·L]``).

    Args:
      mdp: the task shared by all agents (with a task instance per agent, agent 0's: it
        fixes the shapes and the episode length).
      agent: batched hyperparameters of one kind (leading axis = agents), or a
        :class:`KindSwitch` of every kind's and the one that runs; rows that carry each
        agent's own task instance (:class:`~vdbejax.engine.instances.AgentOnTask`) are
        stepped on it.
      agents: batched states, tables flattened as above.
      returns: flat ``[B·L]`` return buffer of the chunk (``L`` episodes per agent).
      lengths: flat ``[B·L]`` length buffer.
      chunk_start: episode index stored in each agent's buffer slot 0.
      chunk_end: episode count at which an agent stops being active.
      support: ``(states, weights)`` of the start distribution (:func:`start_support`).
      table_rows: the tables, ``returns`` and ``lengths`` hold the rows of more agents
        than the batch, lane ``i`` being their agent ``table_rows[i]`` (the sequential
        strategy updates a work item's buffers in place this way).
      base: each agent's :func:`~vdbejax.engine.state.draw_base` of its key and counter,
        if the caller carries it (:func:`run_loop`); else computed here.
      optimal: flat ``[B·L]`` buffer counting each episode's steps whose action is one
        of ``mdp.optimal_action`` (a task that has that mask), else ``None``.

    Returns:
      ``(agents, returns, lengths, optimal)`` after the iteration.
    """
    kinds = agent.kinds if isinstance(agent, KindSwitch) else (agent,)
    num_agents = agents.episode.shape[0]
    S, A = mdp.num_states, mdp.num_actions
    lane = jnp.arange(num_agents, dtype=jnp.int32)
    table_lane = lane if table_rows is None else table_rows
    rows = num_agents if table_rows is None else agents.q.shape[0] // (S * A)
    chunk_length = returns.shape[0] // rows
    pair_base, state_base = table_lane * (S * A), table_lane * S

    active = agents.episode < chunk_end
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
                                else lane_transition(own, lane, s, a, u[1], noise_u))
    length = agents.episode_length + 1
    truncated = ~terminal & (length >= mdp.max_steps)
    if own is None:
        states, weights = support
        s_start = take(states, sample_categorical(weights, u[0]))
    else:
        s_start = lane_start(own, lane, u[0])
    # Choose the next action in s' (in the new episode's start state after a terminal
    # step). That row also serves the target: a terminal step has discount 0, so which
    # row it multiplies does not matter (for finite Q), and one gather is saved.
    act_state = jnp.where(resetting | terminal, s_start, s_next)
    done = learn & (terminal | truncated)

    sa_index = pair_base + s * A + a
    q_sa = take(agents.q, sa_index)
    q_next = take_row(agents.q, pair_base + act_state * A, A)
    update_context = Context(episode=agents.episode, step=length, terminal=terminal)
    select_context = Context(episode=agents.episode + done.astype(jnp.int32),
                             step=jnp.where(resetting | done, 0, length),
                             terminal=jnp.zeros_like(terminal))
    self_loop = ~resetting & (act_state == s)
    operands = (agents.tables, a, s, act_state, q_sa, q_next, reward, terminal, self_loop,
                sa_index, pair_base, state_base, update_context, select_context, u, s_next,
                agents.counter.astype(jnp.int32))

    def index_of(form: str) -> Array:  # where a table of this write form is written
        if form == "pair_value":
            return sa_index
        return state_base + s if form == "state_value" else pair_base + s * A

    tables = dict(agents.tables)
    if not isinstance(agent, KindSwitch):
        whole_kind = is_whole_kind(agent)
        blocks = (whole_blocks(agents.q, agents.tables, agent.learner, pair_base, S * A, (S, A))
                  if agent.learner.updates_whole_table else None)
        new_q_sa, learned, explored, next_action, finite = kind_part(
            agent, *operands, num_actions=A, whole=blocks,
            select_next=not (whole_kind and defers_selection(agent.learner)),
            skip_unchanged=blocks is None)
        if blocks is None:
            q = (agents.q if new_q_sa is None
                 else put_learned(agents.q, sa_index, new_q_sa, q_sa, learn))
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
            tables[name] = put_learned(tables[name], index_of(write_form("explorer", spec.per)),
                                       new, old, learn, spec.per == "pair")
        if whole_kind:
            explorer_u, _, _, plan_u = uniform_parts(agent, u, A)
            q, tables, next_action, finite = after_learning(
                agent, q, tables, next_action, finite, LearnedStep(
                    s=s, s_next=s_next, act_state=act_state, reward=reward, terminal=terminal,
                    sa_index=sa_index, pair_base=pair_base, state_base=state_base, learn=learn,
                    active=active, resetting=resetting, counter=agents.counter,
                    select_context=select_context, explorer_uniforms=explorer_u,
                    plan_uniforms=plan_u),
                num_states=S, num_actions=A, capacity=capacity(S, mdp.num_outcomes))
    else:
        forms = table_forms(kinds)
        assert forms is not None, "see can_switch"
        new_q_sa, writes, next_action, finite = switch_part(
            agent, operands, num_actions=A, forms=forms,
            dtypes={name: table.dtype for name, table in tables.items()})
        q = put_learned(agents.q, sa_index, new_q_sa, q_sa, learn)
        for name, (value, owned) in writes.items():
            form, mask = forms[name], learn & owned
            if is_unrolled(lane):  # a masked lane rewrites what is there
                tables[name] = write_lanes(tables[name], index_of(form), value, mask)
            else:  # where a lane's kind does not own the table, the value read is kept
                width = value.shape[1]
                old = (take(tables[name], index_of(form)) if width == 1
                       else take_row(tables[name], index_of(form), width))
                tables[name] = put_learned(tables[name], index_of(form),
                                           value if width > 1 else value[:, 0], old, mask,
                                           width > 1)

    episode_return = agents.episode_return + reward
    slot = agents.episode - chunk_start
    out = table_lane * chunk_length + slot
    returns = put_where(returns, out, episode_return, done)
    lengths = put_where(lengths, out, length, done)
    if optimal is not None:  # the running episode's slot (only a learning lane's is real)
        assert mdp.optimal_action is not None  # (the run hands the mask with the buffer)
        hit = (take(mdp.optimal_action.reshape(-1), s * A + a) if own is None
               else lane_optimal(own, lane, s, a))
        counted = take(optimal, jnp.clip(out, 0, optimal.shape[0] - 1))
        optimal = put_where(optimal, out, counted + 1, learn & hit)

    def keep(new: Array, old: Array) -> Array:
        return jnp.where(active, new, old)

    agents = AgentState(
        q=q,
        tables=tables,
        state=keep(act_state, s),
        action=keep(next_action, a),
        pending_reset=keep(learn & truncated, resetting),
        episode=agents.episode + done.astype(jnp.int32),
        episode_return=jnp.where(learn, jnp.where(done, 0.0, episode_return),
                                 agents.episode_return),
        episode_length=jnp.where(learn, jnp.where(done, 0, length), agents.episode_length),
        counter=agents.counter + active.astype(jnp.uint32),
        key=agents.key,
        # An action outside [0, A) — what sample_categorical returns for NaN, infinite or
        # all-zero weights, or a plug-in's own draw — is flagged like a NaN in Q when the
        # agent is about to take it (checked on the stored action: cheaper than on the
        # freshly drawn one inside the step's fusions).
        nonfinite=agents.nonfinite | (learn & ~finite) | (active & ~resetting & ~valid_a),
    )
    return agents, returns, lengths, optimal


def run_loop(
    mdp: TabularMDP,
    agent: Agent | KindSwitch,
    agents: AgentState,
    returns: Array,
    lengths: Array,
    chunk_start: Array,
    chunk_end: Array,
    max_iterations: Array,
    unroll: int,
    support: tuple[Array, Array],
    table_rows: Array | None = None,
    stop_at_first_finish: Array | None = None,
    fixed_iterations: int | None = None,
    optimal: Array | None = None,
) -> tuple[AgentState, Array, Array, Array, Array | None]:
    """``while`` any agent is active and fewer than ``max_iterations`` iterations ran;
    or, with ``fixed_iterations`` (static), exactly that many iterations, rounded up to
    a multiple of ``unroll`` (a loop of known trip count: on an accelerator no iteration
    waits for the host to read the loop's condition).

    The body runs ``unroll`` iterations (fewer loop trips); iterations of an agent that
    is no longer active change nothing, so overshooting is harmless. ``table_rows``:
    see :func:`lockstep_iteration`. ``stop_at_first_finish`` (a boolean scalar): where
    true, the loop also stops as soon as one agent has finished the chunk (so that its
    lane can take another agent). ``optimal``: the buffer of :func:`lockstep_iteration`
    (``[B, L]``), or ``None`` (no record: the same program as without it).

    Returns:
      ``(agents, returns, lengths, iterations, optimal)`` (``optimal`` last: a program
      without it has the outputs, and the lowered module, of one before it existed).
    """
    q_shape, out_shape = agents.q.shape, returns.shape
    table_shapes = {name: table.shape for name, table in agents.tables.items()}
    agents = dataclasses.replace(
        agents, q=agents.q.reshape(-1),
        tables={name: table.reshape(-1) for name, table in agents.tables.items()},
    )

    def cond(carry: tuple) -> Array:
        agents, _, _, _, iterations, _ = carry
        active = agents.episode < chunk_end
        go = jnp.any(active) & (iterations < max_iterations)
        if stop_at_first_finish is not None:
            go &= ~stop_at_first_finish | jnp.all(active)
        return go

    def body(carry: tuple) -> tuple:
        agents, returns, lengths, optimal, iterations, base = carry
        for _ in range(unroll):
            agents, returns, lengths, optimal = lockstep_iteration(
                mdp, agent, agents, returns, lengths, chunk_start, chunk_end, support,
                table_rows, base, optimal,
            )
            # The next iteration's hash, carried: the loop's buffers hold it once.
            base = draw_base(agents.key, agents.counter)
        return agents, returns, lengths, optimal, iterations + unroll, base

    zero = jnp.asarray(0, jnp.int32)
    flat_optimal = None if optimal is None else optimal.reshape(-1)
    start = (agents, returns.reshape(-1), lengths.reshape(-1), flat_optimal, zero,
             draw_base(agents.key, agents.counter))
    if fixed_iterations is None:
        agents, returns, lengths, optimal, iterations, _ = jax.lax.while_loop(
            cond, body, start)
    else:
        trips = -(-fixed_iterations // unroll)
        agents, returns, lengths, optimal, iterations, _ = jax.lax.fori_loop(
            0, trips, lambda _, carry: body(carry), start)
    agents = dataclasses.replace(
        agents, q=agents.q.reshape(q_shape),
        tables={name: table.reshape(table_shapes[name]) for name, table in agents.tables.items()},
    )
    optimal = None if optimal is None else optimal.reshape(out_shape)
    return (agents, returns.reshape(out_shape), lengths.reshape(out_shape), iterations,
            optimal)


def optimal_buffer(mdp: TabularMDP, num_agents: int, chunk_length: int,
                   zeros: Callable[..., Any] = jnp.zeros) -> Any:
    """A chunk's zeroed ``[agents, chunk_length]`` counts of optimal actions, for a task
    whose ``optimal_action`` mask is set (a run that records them), else ``None``;
    ``zeros``: ``np.zeros`` for a host buffer."""
    if mdp.optimal_action is None:
        return None
    return zeros((num_agents, chunk_length), np.int32)
