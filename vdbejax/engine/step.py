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

The per-agent part (:func:`_agent_step`) calls the plug-ins on one agent's rows and is
``vmap``-ed over the lanes; around it, :func:`lockstep_iteration` reads and writes the
lanes' tables. Tables are flat 1-D buffers (``[B·S·A]``, ``[B·S]``), so every access is a
1-D gather or scatter of one row per lane, and for a batch of a few lanes (the
sequential strategy) unrolled dynamic slices: XLA's CPU backend then compiles the whole
loop natively.
"""
from __future__ import annotations

import dataclasses
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from vdbejax._numerics import sample_categorical
from vdbejax.engine.state import AgentState, uniforms
from vdbejax.envs.tabular import TabularMDP
from vdbejax.methods.agents import Agent
from vdbejax.methods.api import Context, Transition

Array = jax.Array

#: Uniforms the engine itself draws per iteration: start state and outcome.
ENGINE_UNIFORMS = 2


def num_uniforms(agent: Agent) -> int:
    """Uniforms one iteration of this kind draws: the engine's, the explorer's, the
    learner's, and the explorer's again when the learner redraws its next action."""
    explorer = int(agent.explorer.num_uniforms)
    redraw = explorer if agent.learner.redraws_next_action else 0
    return ENGINE_UNIFORMS + explorer + int(agent.learner.num_uniforms) + redraw


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


# Per-lane buffer access. A batch of a few lanes (the CPU engine's loops) uses unrolled
# dynamic slices instead of gathers/scatters: XLA's CPU backend then compiles the whole
# loop into one native function (scatters would keep it on the per-op runtime).


#: Batches of at most this many lanes access their rows by unrolled dynamic slices (the
#: sequential strategy's loops, :data:`~vdbejax.engine.sequential.LANES`); wider ones by
#: gathers and scatters.
UNROLLED_LANES_MAX = 4


def _unrolled(index: Array) -> bool:
    return index.ndim == 1 and index.shape[0] <= UNROLLED_LANES_MAX


def take(buffer: Array, index: Array) -> Array:
    """``buffer[index]``, one value per lane (``[B]``)."""
    if _unrolled(index):
        return jnp.concatenate([jax.lax.dynamic_slice(buffer, (index[k],), (1,))
                                for k in range(index.shape[0])])
    return buffer.at[index].get(mode="promise_in_bounds")


def take_row(buffer: Array, index: Array, width: int) -> Array:
    """``buffer[index + j]`` for ``j < width``, one row per lane (``[B, width]``)."""
    if _unrolled(index):
        return jnp.stack([jax.lax.dynamic_slice(buffer, (index[k],), (width,))
                          for k in range(index.shape[0])])
    columns = jnp.arange(width, dtype=index.dtype)[None, :]
    return buffer.at[index[:, None] + columns].get(mode="promise_in_bounds")


def _scatter(buffer: Array, index: Array, value: Array, rows: bool = False) -> Array:
    """``buffer[index] = value`` (``[B]``), or with ``rows`` ``buffer[index + j] =
    value[:, j]`` (``[B, width]``), for distinct in-bounds lanes (wide batches; a few
    lanes write through :func:`_write_lanes`)."""
    value = value.astype(buffer.dtype)
    if not rows:
        return buffer.at[index].set(value, mode="promise_in_bounds", unique_indices=True)
    columns = jnp.arange(value.shape[1], dtype=index.dtype)[None, :]
    return buffer.at[index[:, None] + columns].set(value, mode="promise_in_bounds",
                                                   unique_indices=True)


def _write_lanes(buffer: Array, index: Array, value: Array, mask: Array) -> Array:
    """Unrolled ``buffer[index[k] + j] = value[k, j]`` where ``mask[k]``, lane by lane.

    Each lane reads what it would overwrite just before writing, so a lane without
    ``mask`` rewrites the value that is there, even one another lane has just written: a
    masked lane may point anywhere (an idle lane of the sequential strategy points past
    its work item's agents, clamped onto the last one's rows)."""
    value = value.astype(buffer.dtype).reshape(index.shape[0], -1)
    for k in range(index.shape[0]):
        old = jax.lax.dynamic_slice(buffer, (index[k],), (value.shape[1],))
        buffer = jax.lax.dynamic_update_slice(
            buffer, jnp.where(mask[k], value[k], old), (index[k],))
    return buffer


def put_where(buffer: Array, index: Array, value: Array, mask: Array) -> Array:
    """``buffer[index] = value`` where ``mask``; lanes without it write nothing."""
    if _unrolled(index):
        return _write_lanes(buffer, index, value, mask)
    index = jnp.where(mask, index, buffer.shape[0])  # past the end: dropped
    return buffer.at[index].set(value.astype(buffer.dtype), mode="drop")


def put_learned(buffer: Array, index: Array, new: Array, old: Array, mask: Array,
                rows: bool = False) -> Array:
    """``buffer[index] = new`` where ``mask``, ``old`` (the value read) elsewhere; a few
    lanes write lane by lane, those without ``mask`` nothing (see :func:`_write_lanes`)."""
    if _unrolled(index):
        return _write_lanes(buffer, index, new, mask)
    kept = jnp.where(mask.reshape(mask.shape + (1,) * (new.ndim - 1)), new, old)
    return _scatter(buffer, index, kept, rows)


def _transition(mdp: TabularMDP, s: Array, a: Array, u: Array) -> tuple[Array, Array, Array]:
    """Batched :meth:`TabularMDP.transition` (flat 1-D gathers when deterministic)."""
    if mdp.num_outcomes != 1:
        return jax.vmap(mdp.transition)(s, a, u)
    flat = s * mdp.num_actions + a

    def at(table: Array) -> Array:
        return take(table.reshape(-1), flat)

    return at(mdp.next_state), at(mdp.reward), at(mdp.terminal)


def _agent_step(agent: Agent, a: Array, q_sa: Array, q_next: Array, learner_sa: dict,
                learner_next: dict, explorer_s: dict, explorer_next: dict, reward: Array,
                terminal: Array, self_loop: Array, update_context: Context,
                select_context: Context, explorer_uniforms: tuple, learner_uniforms: tuple,
                redraw_uniforms: tuple) -> tuple[Array, dict, dict, Array, Array]:
    """One agent's learning and choice (vmapped over lanes by :func:`lockstep_iteration`).

    ``self_loop``: the next action is chosen in the state just left (its rows must show
    this step's update for learners that choose after it). ``redraw_uniforms``: for a
    learner that ``redraws_next_action`` (the authors' SARSA), the uniforms of the action
    actually taken, drawn afresh after the update.

    Returns:
      ``(new_q_sa, new_learner_sa, new_explorer_s, next_action, finite)``.
    """
    learner, explorer = agent.learner, agent.explorer
    discount = jnp.where(terminal, 0.0, learner.gamma)
    zero_probabilities = jnp.zeros_like(q_next)

    def learn(next_action: Array, probabilities: Array) -> tuple:
        update = learner.update(Transition(
            q=q_sa, tables=learner_sa, reward=reward, discount=discount, q_next=q_next,
            tables_next=learner_next, next_action=next_action,
            next_probabilities=probabilities, uniforms=learner_uniforms, terminal=terminal,
        ))
        new_explorer_s = explorer.update(explorer_s, a, update.delta_q, update_context)
        return update, new_explorer_s

    def probabilities_next() -> Array:
        if not learner.uses_next_probabilities:
            return zero_probabilities
        behaviour = learner.behaviour(q_next, learner_next)
        return explorer.probabilities(behaviour, explorer_next, select_context)

    def select_after(update: Any, new_explorer_s: dict, uniforms: tuple) -> Array:
        """Choose after the update: where a' is chosen in s itself, its rows show it."""
        patched = self_loop & (jnp.arange(q_next.shape[0]) == a)
        act_q = jnp.where(patched, update.q, q_next)
        act_learner = {name: jnp.where(patched, update.tables[name], row)
                       for name, row in learner_next.items()}
        act_explorer = {name: jnp.where(self_loop, new_explorer_s[name], value)
                        for name, value in explorer_next.items()}
        behaviour = learner.behaviour(act_q, act_learner)
        return explorer.select(behaviour, act_explorer, select_context, uniforms)

    if learner.uses_next_action:
        behaviour = learner.behaviour(q_next, learner_next)
        next_action = explorer.select(behaviour, explorer_next, select_context, explorer_uniforms)
        update, new_explorer_s = learn(next_action, probabilities_next())
        if learner.redraws_next_action:  # the a' of the target is not the one taken
            next_action = select_after(update, new_explorer_s, redraw_uniforms)
    else:
        update, new_explorer_s = learn(jnp.zeros((), jnp.int32), probabilities_next())
        next_action = select_after(update, new_explorer_s, explorer_uniforms)
    finite = jnp.all(jnp.asarray([jnp.all(jnp.isfinite(leaf))
                                  for leaf in jax.tree.leaves((update.q, update.tables,
                                                               new_explorer_s))]))
    return (update.q, update.tables, new_explorer_s,
            jnp.asarray(next_action, jnp.int32), finite)


def lockstep_iteration(
    mdp: TabularMDP,
    agent: Agent,
    agents: AgentState,
    returns: Array,
    lengths: Array,
    chunk_start: Array,
    chunk_end: Array,
    support: tuple[Array, Array],
    table_rows: Array | None = None,
) -> tuple[AgentState, Array, Array]:
    """One lockstep iteration of a batch of one kind: every agent advances by one step.

    ``agents.q``, every table of ``agents.tables``, ``returns`` and ``lengths`` are flat
    1-D arrays (``[B·S·A]``, ``[B·S]`` or ``[B·S·A]``, ``[B·L]``).

    Args:
      mdp: the task (shared by all agents).
      agent: batched hyperparameters of one kind (leading axis = agents).
      agents: batched states, tables flattened as above.
      returns: flat ``[B·L]`` return buffer of the chunk (``L`` episodes per agent).
      lengths: flat ``[B·L]`` length buffer.
      chunk_start: episode index stored in each agent's buffer slot 0.
      chunk_end: episode count at which an agent stops being active.
      support: ``(states, weights)`` of the start distribution (:func:`start_support`).
      table_rows: the tables, ``returns`` and ``lengths`` hold the rows of more agents
        than the batch, lane ``i`` being their agent ``table_rows[i]`` (the sequential
        strategy updates a work item's buffers in place this way).

    Returns:
      ``(agents, returns, lengths)`` after the iteration.
    """
    learner, explorer = agent.learner, agent.explorer
    num_agents = agents.episode.shape[0]
    S, A = mdp.num_states, mdp.num_actions
    lane = jnp.arange(num_agents, dtype=jnp.int32)
    table_lane = lane if table_rows is None else table_rows
    rows = num_agents if table_rows is None else agents.q.shape[0] // (S * A)
    chunk_length = returns.shape[0] // rows
    pair_base, state_base = table_lane * (S * A), table_lane * S

    active = agents.episode < chunk_end
    u = uniforms(agents.key, agents.counter, num_uniforms(agent))
    explorer_end = ENGINE_UNIFORMS + explorer.num_uniforms
    learner_end = explorer_end + learner.num_uniforms
    resetting = agents.pending_reset
    learn = active & ~resetting
    s, a = agents.state, agents.action
    valid_a = (a >= 0) & (a < A)
    # An invalid action (flagged below) still indexes this agent's own rows only: its
    # neighbours' tables lie next to them in the same buffer.
    a = jnp.clip(a, 0, A - 1)

    s_next, reward, terminal = _transition(mdp, s, a, u[1])
    length = agents.episode_length + 1
    truncated = ~terminal & (length >= mdp.max_steps)
    states, weights = support
    s_start = take(states, sample_categorical(weights, u[0]))
    # Choose the next action in s' (in the new episode's start state after a terminal
    # step). That row also serves the target: a terminal step has discount 0, so which
    # row it multiplies does not matter (for finite Q), and one gather is saved.
    act_state = jnp.where(resetting | terminal, s_start, s_next)
    done = learn & (terminal | truncated)

    sa_index = pair_base + s * A + a
    q_sa = take(agents.q, sa_index)
    q_next = take_row(agents.q, pair_base + act_state * A, A)
    learner_specs = learner.tables()
    learner_sa = {name: take(agents.tables[name], sa_index) for name in learner_specs}
    learner_next = {name: take_row(agents.tables[name], pair_base + act_state * A, A)
                    for name in learner_specs}
    explorer_specs = explorer.tables()

    def explorer_rows(state: Array) -> dict:
        return {name: (take(agents.tables[name], state_base + state) if spec.per == "state"
                       else take_row(agents.tables[name], pair_base + state * A, A))
                for name, spec in explorer_specs.items()}

    explorer_s, explorer_next = explorer_rows(s), explorer_rows(act_state)
    update_context = Context(episode=agents.episode, step=length, terminal=terminal)
    select_context = Context(episode=agents.episode + done.astype(jnp.int32),
                             step=jnp.where(resetting | done, 0, length),
                             terminal=jnp.zeros_like(terminal))
    self_loop = ~resetting & (act_state == s)
    new_q_sa, new_learner_sa, new_explorer_s, next_action, finite = jax.vmap(_agent_step)(
        agent, a, q_sa, q_next, learner_sa, learner_next, explorer_s, explorer_next, reward,
        terminal, self_loop, update_context, select_context, u[ENGINE_UNIFORMS:explorer_end],
        u[explorer_end:learner_end], u[learner_end:],
    )

    q = put_learned(agents.q, sa_index, new_q_sa, q_sa, learn)
    tables = dict(agents.tables)
    for name in learner_specs:
        tables[name] = put_learned(tables[name], sa_index, new_learner_sa[name],
                                   learner_sa[name], learn)
    for name, spec in explorer_specs.items():
        index = state_base + s if spec.per == "state" else pair_base + s * A
        tables[name] = put_learned(tables[name], index, new_explorer_s[name],
                                   explorer_s[name], learn, spec.per == "pair")

    episode_return = agents.episode_return + reward
    slot = agents.episode - chunk_start
    out = table_lane * chunk_length + slot
    returns = put_where(returns, out, episode_return, done)
    lengths = put_where(lengths, out, length, done)

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
    return agents, returns, lengths


def run_loop(
    mdp: TabularMDP,
    agent: Agent,
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
) -> tuple[AgentState, Array, Array, Array]:
    """``while`` any agent is active and fewer than ``max_iterations`` iterations ran.

    The body runs ``unroll`` iterations (fewer loop trips); iterations of an agent that
    is no longer active change nothing, so overshooting is harmless. ``table_rows``:
    see :func:`lockstep_iteration`. ``stop_at_first_finish`` (a boolean scalar): where
    true, the loop also stops as soon as one agent has finished the chunk (so that its
    lane can take another agent).
    """
    q_shape, out_shape = agents.q.shape, returns.shape
    table_shapes = {name: table.shape for name, table in agents.tables.items()}
    agents = dataclasses.replace(
        agents, q=agents.q.reshape(-1),
        tables={name: table.reshape(-1) for name, table in agents.tables.items()},
    )

    def cond(carry: tuple) -> Array:
        agents, _, _, iterations = carry
        active = agents.episode < chunk_end
        go = jnp.any(active) & (iterations < max_iterations)
        if stop_at_first_finish is not None:
            go &= ~stop_at_first_finish | jnp.all(active)
        return go

    def body(carry: tuple) -> tuple:
        agents, returns, lengths, iterations = carry
        for _ in range(unroll):
            agents, returns, lengths = lockstep_iteration(
                mdp, agent, agents, returns, lengths, chunk_start, chunk_end, support,
                table_rows,
            )
        return agents, returns, lengths, iterations + unroll

    zero = jnp.asarray(0, jnp.int32)
    agents, returns, lengths, iterations = jax.lax.while_loop(
        cond, body, (agents, returns.reshape(-1), lengths.reshape(-1), zero)
    )
    agents = dataclasses.replace(
        agents, q=agents.q.reshape(q_shape),
        tables={name: table.reshape(table_shapes[name]) for name, table in agents.tables.items()},
    )
    return agents, returns.reshape(out_shape), lengths.reshape(out_shape), iterations
