"""The engine: every agent of a sweep trains inside jitted programs, in one of two ways.

Both strategies run the same step function (:func:`lockstep_iteration`, batched over
agent lanes), so they compute the same thing; :func:`run_agents` picks one:

* **sequential** (the default on a CPU backend): each agent runs its own ``while`` loop of
  steps, one lane wide, agents one after another inside a program and groups of agents on
  several threads. With one lane every table access is a dynamic slice, so XLA's CPU
  backend compiles the whole loop into one native function (see
  :mod:`vdbejax._xla_flags`), and no agent ever waits for another. One program is
  compiled per kind of agent (learner, VDBE or not). On the paper grid this is ≈ 2.5×
  faster than lockstep on the 2-core development machine and gives bit-identical
  returns (``benchmarks/RESULTS.md``; products are rounded on their own,
  :mod:`vdbejax._numerics`, so no program fuses them into FMAs differently).
* **lockstep** (accelerators, agents sharded over devices): all agents of a batch advance
  together, one vectorised step per loop iteration, as described below.

Design of the lockstep strategy (why it looks like this):

* **Step-synchronous lockstep.** Agents do not wait for each other at episode
  boundaries: each agent has its own episode counter and starts its next episode as soon
  as the previous one ends. One ``lax.while_loop`` iteration advances every active agent
  by one environment step, so a batch costs ``max_agent(total steps)`` iterations instead
  of ``Σ_episodes max_agent(episode length)``.
* **Chunks.** A chunk runs until every agent has finished episode ``chunk_end``; the
  Python driver loops over chunks to show progress and write checkpoints. An agent's
  state at a chunk boundary is the same whatever the chunk size.
* **Per-agent random streams.** Each iteration of an agent draws its uniforms from a
  counter-based hash of ``(agent_key, agent_counter)`` (lowbias32 rounds, far cheaper than
  threefry): results depend only on the agent's key and hyperparameters, never on the
  batch, the chunking or a resume.
* **Compaction.** Lockstep makes a batch run until its slowest agent finishes; finished
  lanes would idle. :func:`run_agents` runs blocks of ``block_iterations`` iterations and,
  once at most half the lanes are active, gathers the active agents into a batch of the
  next power-of-two size (few shapes to compile). Bit-identical to running without it.
* **CPU layout.** The batched step (:func:`lockstep_iteration`) keeps Q, ε and the
  output buffers flat (1-D) and lays gathered Q rows out ``[A, B]`` (batch = fast axis),
  so every operation vectorises over the batch; the explorers and learners of
  :mod:`vdbejax.explorers` / :mod:`vdbejax.learners` work on that layout directly.
* **One code path for all agents.** Learners and explorers are data (pytree leaves), see
  :mod:`vdbejax.explorers`; nothing branches on the kind of agent.
* Memory is bounded by agents × (table size + chunk length): only per-episode return
  and length are recorded.

One iteration of one agent (``s, a`` = current state and the action already chosen):

1. If a reset is pending (first step, or after a truncation): ``s ← start``, choose
   ``a`` in it, nothing is learned.
2. Otherwise step ``s, a → s', r``; choose the next action ``a'`` in ``s'`` (in the new
   episode's start state if the transition was terminal). SARSA chooses ``a'`` with the
   Q-table *before* updating ``Q(s, a)`` (its target needs ``Q(s', a')``); Q-learning
   chooses it *after* the update. Then update ``Q(s, a)`` and, for VDBE, ``ε(s)``.
"""
from __future__ import annotations

import dataclasses
import os
import sys
import time
import warnings
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from functools import partial
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from vdbejax import _executables, _xla_flags
from vdbejax._pytree import pytree_dataclass
from vdbejax.agents import AgentParams
from vdbejax.envs.tabular import TabularMDP
from vdbejax.explorers import sample_categorical, select_action, vdbe_epsilon_update
from vdbejax.learners import q_learning_target, sarsa_target, td_update
from vdbejax.validation import check_choice, check_int

Array = jax.Array

#: Uniforms drawn per agent iteration: start state, outcome, and the 3 of select_action.
_NUM_UNIFORMS = 5


@pytree_dataclass
class AgentState:
    """Everything one agent carries between iterations (a leading axis for batches).

    Attributes:
      q: ``[S, A]`` action values.
      epsilon: ``[S]`` VDBE per-state exploration probabilities (1 for other explorers).
      state: current state index.
      action: action already chosen for ``state``.
      pending_reset: the next iteration starts a new episode (first step, truncation).
      episode: number of completed episodes.
      episode_return: return of the running episode so far.
      episode_length: steps of the running episode so far.
      counter: iterations done, the index into the agent's random stream.
      key: the agent's PRNG key (raw ``uint32[2]``).
      nonfinite: a NaN or inf appeared in Q or ε.
    """

    q: Array
    epsilon: Array
    state: Array
    action: Array
    pending_reset: Array
    episode: Array
    episode_return: Array
    episode_length: Array
    counter: Array
    key: Array
    nonfinite: Array


def init_agent(mdp: TabularMDP, params: AgentParams, key: Array) -> AgentState:
    """Fresh state of one agent: Q = q_init, ε(s) = 1, a reset pending.

    Args:
      mdp: the task (sets the table shapes).
      params: the agent's hyperparameters (``q_init``).
      key: the agent's raw ``uint32[2]`` PRNG key.

    Returns:
      the :class:`AgentState` (no leading batch axis).
    """
    zero = jnp.asarray(0, jnp.int32)
    return AgentState(
        q=jnp.full((mdp.num_states, mdp.num_actions), params.learner.q_init, jnp.float32),
        epsilon=jnp.ones((mdp.num_states,), jnp.float32),
        state=zero,
        action=zero,
        pending_reset=jnp.asarray(True),
        episode=zero,
        episode_return=jnp.asarray(0.0, jnp.float32),
        episode_length=zero,
        counter=jnp.asarray(0, jnp.uint32),
        key=jnp.asarray(key, jnp.uint32),
        nonfinite=jnp.asarray(False),
    )


@jax.jit
def _init_agents(mdp: TabularMDP, params: AgentParams, keys: Array) -> AgentState:
    return jax.vmap(init_agent, in_axes=(None, 0, 0))(mdp, params, keys)


def _mix32(x: Array) -> Array:
    """lowbias32 integer finaliser (C. Wellons): a cheap, well-mixed uint32 bijection."""
    x = x ^ (x >> 16)
    x = x * jnp.uint32(0x7FEB352D)
    x = x ^ (x >> 15)
    x = x * jnp.uint32(0x846CA68B)
    return x ^ (x >> 16)


def _uniforms(key: Array, counter: Array) -> tuple[Array, ...]:
    """The ``_NUM_UNIFORMS`` uniforms of one agent iteration: a counter-based hash.

    A pure function of the agent's key (``[..., 2]``) and its own iteration counter, so
    results do not depend on the batch, the chunking or a resume; much cheaper than
    threefry ``fold_in`` + ``bits``. Returns a tuple of arrays shaped like ``counter``
    (one vector per draw, which XLA's CPU backend vectorises well).
    """
    key = key.astype(jnp.uint32)
    counter = counter.astype(jnp.uint32)
    base = _mix32(key[..., 1] ^ _mix32(key[..., 0] + counter * jnp.uint32(0x9E3779B9)))
    draws = []
    for j in range(_NUM_UNIFORMS):
        bits = _mix32(base + jnp.uint32((j * 0x632BE5AB) % 2**32))
        # 23-bit mantissa: values in [0, 1 − 2⁻²³], which sample_categorical relies on.
        draws.append((bits >> 9).astype(jnp.float32) * jnp.float32(2.0**-23))
    return tuple(draws)


def _start_support(mdp: TabularMDP) -> tuple[Array, Array]:
    """States with a positive start probability and their weights (host side if possible).

    Sampling from the support with :func:`sample_categorical` picks the same state as
    sampling from the full distribution (zero weights add nothing to the partial sums),
    but costs a few comparisons per agent instead of ``S``. Under a trace the support is
    unknown and the full distribution is used.
    """
    probability = mdp.start_probability
    if isinstance(probability, jax.core.Tracer):
        return jnp.arange(mdp.num_states, dtype=jnp.int32), probability
    probability = np.asarray(probability)
    support = np.flatnonzero(probability > 0).astype(np.int32)
    return jnp.asarray(support), jnp.asarray(probability[support])


# Per-lane buffer access. A batch of one lane (the CPU engine's per-agent loop) uses
# dynamic slices instead of gathers/scatters: XLA's CPU backend then compiles the whole
# loop into one native function (scatters would keep it on the per-op runtime).


def _take(buffer: Array, index: Array, width: int = 1) -> Array:
    """``buffer[index + j]`` for ``j < width``, shaped ``[width, B]`` (``[B]`` if width 1)."""
    if index.shape == (1,):
        values = jax.lax.dynamic_slice(buffer, (index[0],), (width,))
        return values if width == 1 else values[:, None]
    if width == 1:
        return buffer.at[index].get(mode="promise_in_bounds")
    columns = jnp.arange(width, dtype=index.dtype)[:, None]
    return buffer.at[index[None] + columns].get(mode="promise_in_bounds")


def _put(buffer: Array, index: Array, value: Array) -> Array:
    """``buffer[index] = value`` for distinct in-bounds indices, one per lane."""
    value = value.astype(buffer.dtype)
    if index.shape == (1,):
        return jax.lax.dynamic_update_slice(buffer, value, (index[0],))
    return buffer.at[index].set(value, mode="promise_in_bounds", unique_indices=True)


def _put_where(buffer: Array, index: Array, value: Array, mask: Array) -> Array:
    """``buffer[index] = value`` where ``mask``; lanes without it write nothing."""
    if index.shape == (1,):
        index = jnp.clip(index, 0, buffer.shape[0] - 1)
        return _put(buffer, index, jnp.where(mask, value, _take(buffer, index)))
    index = jnp.where(mask, index, buffer.shape[0])  # past the end: dropped
    return buffer.at[index].set(value.astype(buffer.dtype), mode="drop")


def _transition(mdp: TabularMDP, s: Array, a: Array, u: Array) -> tuple[Array, Array, Array]:
    """Batched :meth:`TabularMDP.transition` (flat 1-D gathers when deterministic)."""
    if mdp.num_outcomes != 1:
        return jax.vmap(mdp.transition)(s, a, u)
    flat = s * mdp.num_actions + a

    def take(table: Array) -> Array:
        return _take(table.reshape(-1), flat)

    return take(mdp.next_state), take(mdp.reward), take(mdp.terminal)


def lockstep_iteration(
    mdp: TabularMDP,
    params: AgentParams,
    agents: AgentState,
    returns: Array,
    lengths: Array,
    chunk_start: Array,
    chunk_end: Array,
    start_support: tuple[Array, Array],
    table_offset: Array | None = None,
) -> tuple[AgentState, Array, Array]:
    """One lockstep iteration of a batch: every agent advances by one step (module docstring).

    Written for XLA's CPU backend:
    ``agents.q``, ``agents.epsilon``, ``returns`` and ``lengths`` are flat 1-D arrays
    (``[B·S·A]``, ``[B·S]``, ``[B·L]``) so that every table access is a 1-D gather or
    scatter of one element per agent; a gathered Q row is laid out ``[A, B]`` (the batch
    is the fast axis), which XLA vectorises.

    Args:
      mdp: the task (shared by all agents).
      params: batched hyperparameters (leading axis = agents).
      agents: batched states, ``q`` and ``epsilon`` flattened as above.
      returns: flat ``[B·L]`` return buffer of the chunk (``L`` episodes per agent).
      lengths: flat ``[B·L]`` length buffer.
      chunk_start: episode index stored in each agent's buffer slot 0.
      chunk_end: episode count at which an agent stops being active.
      start_support: ``(states, weights)`` of the start distribution
        (:func:`_start_support`).
      table_offset: ``agents.q`` and ``agents.epsilon`` hold the tables of more agents
        than the batch, whose lane ``i`` is their agent ``table_offset + i`` (the
        sequential strategy updates a work item's tables in place this way).

    Returns:
      ``(agents, returns, lengths)`` after the iteration.
    """
    learner, explorer = params.learner, params.explorer
    num_agents = agents.episode.shape[0]
    S, A = mdp.num_states, mdp.num_actions  # noqa: N806
    chunk_length = returns.shape[0] // num_agents
    lane = jnp.arange(num_agents, dtype=jnp.int32)
    table_lane = lane if table_offset is None else lane + table_offset
    q_base, eps_base = table_lane * (S * A), table_lane * S

    columns = jnp.arange(A, dtype=jnp.int32)[:, None]

    def q_row(state: Array) -> Array:  # [A, B]: the batch is the fast axis
        return _take(agents.q, q_base + state * A, A)

    def eps_at(state: Array) -> Array:
        return _take(agents.epsilon, eps_base + state)

    active = agents.episode < chunk_end
    u = _uniforms(agents.key, agents.counter)
    resetting = agents.pending_reset
    learn = active & ~resetting
    s, a = agents.state, agents.action

    s_next, reward, terminal = _transition(mdp, s, a, u[1])
    length = agents.episode_length + 1
    truncated = ~terminal & (length >= mdp.max_steps)
    support, weights = start_support
    s_start = _take(support, sample_categorical(weights, u[0]))

    sa_index = q_base + s * A + a
    q_sa = _take(agents.q, sa_index)
    # Choose the next action in s' (in the new episode's start state after a terminal
    # step). That row also serves the target: a terminal step has discount 0, so which
    # row it multiplies does not matter (for finite Q), and one gather is saved.
    act_state = jnp.where(resetting | terminal, s_start, s_next)
    q_next = q_row(act_state)
    discount = jnp.where(terminal, 0.0, learner.gamma)
    q_learning_value, q_learning_dq = td_update(
        q_sa, q_learning_target(reward, discount, q_next), learner.alpha
    )

    act_q = q_next
    act_epsilon = eps_at(act_state)
    patch = ~learner.sarsa & ~resetting & (act_state == s)
    act_q = jnp.where(patch & (a == columns), q_learning_value, act_q)
    act_epsilon = jnp.where(
        patch & explorer.adaptive,
        vdbe_epsilon_update(act_epsilon, q_learning_dq, explorer.sigma, explorer.delta),
        act_epsilon,
    )
    explore_probability = jnp.where(explorer.adaptive, act_epsilon, explorer.epsilon)
    next_action = select_action(
        act_q, explore_probability, explorer.tau, u[2:], explorer.tie_break
    )

    sarsa_value, sarsa_dq = td_update(
        q_sa, sarsa_target(reward, discount, q_next, next_action), learner.alpha
    )
    new_q_sa = jnp.where(learner.sarsa, sarsa_value, q_learning_value)
    delta_q = jnp.where(learner.sarsa, sarsa_dq, q_learning_dq)
    eps_s = eps_at(s)
    new_eps_s = vdbe_epsilon_update(eps_s, delta_q, explorer.sigma, explorer.delta)
    q = _put(agents.q, sa_index, jnp.where(learn, new_q_sa, q_sa))
    epsilon = _put(
        agents.epsilon, eps_base + s, jnp.where(learn & explorer.adaptive, new_eps_s, eps_s)
    )

    episode_return = agents.episode_return + reward
    done = learn & (terminal | truncated)
    slot = agents.episode - chunk_start
    out = lane * chunk_length + slot
    returns = _put_where(returns, out, episode_return, done)
    lengths = _put_where(lengths, out, length, done)

    def keep(new: Array, old: Array) -> Array:
        return jnp.where(active, new, old)

    agents = AgentState(
        q=q,
        epsilon=epsilon,
        state=keep(act_state, s),
        action=keep(next_action, a),
        pending_reset=keep(learn & truncated, resetting),
        episode=agents.episode + done.astype(jnp.int32),
        episode_return=jnp.where(learn, jnp.where(done, 0.0, episode_return), agents.episode_return),
        episode_length=jnp.where(learn, jnp.where(done, 0, length), agents.episode_length),
        counter=agents.counter + active.astype(jnp.uint32),
        key=agents.key,
        nonfinite=agents.nonfinite
        | (learn & ~(jnp.isfinite(new_q_sa) & jnp.isfinite(new_eps_s))),
    )
    return agents, returns, lengths


def _run_loop(mdp, params, agents, returns, lengths, chunk_start, chunk_end, max_iterations,
              unroll, start_support, table_offset=None):
    """``while`` any agent is active and fewer than ``max_iterations`` iterations ran.

    The body runs ``unroll`` iterations (fewer loop trips); iterations of an agent that
    is no longer active change nothing, so overshooting is harmless. ``table_offset``:
    see :func:`lockstep_iteration`.
    """
    q_shape, eps_shape, out_shape = agents.q.shape, agents.epsilon.shape, returns.shape
    agents = dataclasses.replace(
        agents, q=agents.q.reshape(-1), epsilon=agents.epsilon.reshape(-1)
    )

    def cond(carry: tuple) -> Array:
        agents, _, _, iterations = carry
        return jnp.any(agents.episode < chunk_end) & (iterations < max_iterations)

    def body(carry: tuple) -> tuple:
        agents, returns, lengths, iterations = carry
        for _ in range(unroll):
            agents, returns, lengths = lockstep_iteration(
                mdp, params, agents, returns, lengths, chunk_start, chunk_end, start_support,
                table_offset,
            )
        return agents, returns, lengths, iterations + unroll

    zero = jnp.asarray(0, jnp.int32)
    agents, returns, lengths, iterations = jax.lax.while_loop(
        cond, body, (agents, returns.reshape(-1), lengths.reshape(-1), zero)
    )
    agents = dataclasses.replace(
        agents, q=agents.q.reshape(q_shape), epsilon=agents.epsilon.reshape(eps_shape)
    )
    return agents, returns.reshape(out_shape), lengths.reshape(out_shape), iterations


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
    params: AgentParams,
    agents: AgentState,
    chunk_start: Array,
    chunk_end: Array,
    chunk_length: int,
    unroll: int = DEFAULT_UNROLL,
) -> tuple[AgentState, Array, Array, Array]:
    """Advance a batch of agents until each has completed ``chunk_end`` episodes.

    One jitted program, no compaction (see :func:`run_agents` for the compacting
    driver; both give identical results).

    Args:
      mdp: the task (shared by all agents).
      params: batched agent hyperparameters (leading axis = agents).
      agents: batched agent states.
      chunk_start: episode index of the chunk's first episode.
      chunk_end: episode count at which an agent stops (≤ ``chunk_start + chunk_length``).
      chunk_length: static buffer length.
      unroll: lockstep iterations per loop trip (static; results do not depend on it).

    Note: keep batches ≤ :data:`MAX_SAFE_BATCH` lanes for results independent of the
    batch (:func:`run_agents` splits larger ones into groups).

    Returns:
      ``(agents, returns, lengths, iterations)``: returns/lengths are
      ``[agents, chunk_length]`` (episodes past ``chunk_end`` stay 0), ``iterations``
      the number of lockstep iterations executed (a multiple of ``unroll``).
    """
    return _run_chunk_jit(
        mdp, params, agents, chunk_start, chunk_end, chunk_length, unroll, _start_support(mdp)
    )


@partial(jax.jit, static_argnames=("chunk_length", "unroll"))
def _run_chunk_jit(mdp, params, agents, chunk_start, chunk_end, chunk_length, unroll,
                   start_support):
    num_agents = agents.episode.shape[0]
    returns = jnp.zeros((num_agents, chunk_length), jnp.float32)
    lengths = jnp.zeros((num_agents, chunk_length), jnp.int32)
    big = jnp.asarray(jnp.iinfo(jnp.int32).max, jnp.int32)
    return _run_loop(
        mdp, params, agents, returns, lengths, chunk_start, chunk_end, big, unroll, start_support
    )


@partial(jax.jit, static_argnames=("unroll",))
def _run_block(mdp, params, agents, returns, lengths, chunk_start, chunk_end, max_iterations,
               start_support, *, unroll):
    """Up to ``max_iterations`` lockstep iterations; also returns each lane's activity."""
    agents, returns, lengths, iterations = _run_loop(
        mdp, params, agents, returns, lengths, chunk_start, chunk_end, max_iterations, unroll,
        start_support,
    )
    return agents, returns, lengths, iterations, agents.episode < chunk_end


@partial(jax.jit, static_argnames=("chunk_length", "kind"), donate_argnames=("agents",))
def _run_sequential(mdp, params, agents, chunk_start, chunk_end, count, start_support, *,
                    chunk_length, kind):
    """Agents ``0 .. count-1`` of the batch in turn run their own step loop to ``chunk_end``.

    The step is :func:`lockstep_iteration` on a batch of one lane, which uses dynamic
    slices only, so XLA's CPU backend compiles an agent's whole loop into one native
    function (given the small-while-loop threshold that :mod:`vdbejax._xla_flags` sets)
    instead of dispatching ~30 kernels per step. ``kind`` = ``(sarsa, adaptive)`` shared by
    all these agents is baked in as constants: XLA then drops the other learner's target
    and, without VDBE, the ε(s) updates (≈ 140 → 90 ns per step). Rows from
    ``count`` on are padding and left as they are. The batch's tables are updated in
    place (``agents`` is donated): an agent's loop indexes them at its own offset.
    """
    num_agents = agents.episode.shape[0]
    big = jnp.asarray(jnp.iinfo(jnp.int32).max, jnp.int32)
    sarsa, adaptive = kind

    def one_agent(i: Array, carry: tuple) -> tuple:
        agents, returns, lengths, iterations = carry

        def pick(leaf: Array) -> Array:
            return jax.lax.dynamic_slice_in_dim(leaf, i, 1)

        def put(full: Array, new: Array) -> Array:
            return jax.lax.dynamic_update_slice_in_dim(full, new, i, 0)

        agent_params = jax.tree.map(pick, params)
        agent_params = dataclasses.replace(
            agent_params,
            learner=dataclasses.replace(agent_params.learner, sarsa=jnp.full((1,), sarsa)),
            explorer=dataclasses.replace(
                agent_params.explorer, adaptive=jnp.full((1,), adaptive)
            ),
        )
        # The agent's scalars are sliced out and written back; its Q and ε(s) are updated
        # in the item's tables (``table_offset``): no copy of a table per agent.
        def scalars(state: AgentState) -> AgentState:
            return dataclasses.replace(state, q=None, epsilon=None)

        agent = dataclasses.replace(
            jax.tree.map(pick, scalars(agents)), q=agents.q, epsilon=agents.epsilon
        )
        agent, agent_returns, agent_lengths, agent_iterations = _run_loop(
            mdp, agent_params, agent, pick(returns), pick(lengths),
            chunk_start, chunk_end, big, 1, start_support, table_offset=i,
        )
        agents = dataclasses.replace(
            jax.tree.map(put, scalars(agents), scalars(agent)), q=agent.q, epsilon=agent.epsilon
        )
        return (agents, put(returns, agent_returns), put(lengths, agent_lengths),
                iterations + agent_iterations)

    returns = jnp.zeros((num_agents, chunk_length), jnp.float32)
    lengths = jnp.zeros((num_agents, chunk_length), jnp.int32)
    zero = jnp.asarray(0, jnp.int32)
    return jax.lax.fori_loop(0, count, one_agent, (agents, returns, lengths, zero))


#: Per-compilation XLA options of the CPU engine: with region analysis, copy insertion
#: proves that an agent's Q-table update can happen in place (no copy of Q per step).
_CPU_COMPILER_OPTIONS = {"xla_cpu_copy_insertion_use_region_analysis": True}


def compile_seconds() -> float:
    """Seconds this process spent getting the engine's executables (tracing, lowering and
    compiling them, or loading them from the caches; see :mod:`vdbejax._executables`)."""
    return _executables.compile_seconds()


@jax.jit
def _gather_rows(tree: Any, index: Array) -> Any:
    return jax.tree.map(lambda leaf: jnp.take(leaf, index, axis=0, mode="clip"), tree)


@partial(jax.jit, donate_argnums=(0,))
def _scatter_rows(tree: Any, index: Array, rows: Any) -> Any:
    return jax.tree.map(lambda leaf, new: leaf.at[index].set(new, mode="drop"), tree, rows)


def _next_power_of_two(n: int) -> int:
    return 1 << max(0, (n - 1).bit_length())


def _run_chunk_compacting(
    mdp: TabularMDP,
    params: AgentParams,
    agents: AgentState,
    chunk_start: int,
    chunk_end: int,
    chunk_length: int,
    *,
    block_iterations: int,
    unroll: int,
    min_batch: int,
) -> tuple[AgentState, Array, Array, int, int]:
    """:func:`run_chunk` with compaction of the still-active agents between blocks.

    The batch runs ``block_iterations`` lockstep iterations at a time. When at most half
    of its lanes are still active, the active agents are gathered into a batch of the next
    power-of-two size (at least ``min_batch``; padding lanes duplicate a real agent and are
    never written back), so few shapes are compiled. Each agent's computation depends only
    on its own lane, hence the results are identical to :func:`run_chunk`.

    Returns:
      ``(agents, returns, lengths, iterations, lane_iterations)``.
    """
    num_agents = int(agents.episode.shape[0])
    full = (agents, jnp.zeros((num_agents, chunk_length), jnp.float32),
            jnp.zeros((num_agents, chunk_length), jnp.int32))
    index = None  # rows of the full batch held by the current batch (None: all, in order)
    cur_params, cur = params, full
    size = num_agents
    iterations = lane_iterations = 0
    start, end = jnp.int32(chunk_start), jnp.int32(chunk_end)
    block = jnp.int32(block_iterations)
    support = _start_support(mdp)

    def written_back() -> tuple[AgentState, Array, Array]:
        """The full batch with the current batch's rows written back (padding dropped)."""
        return cur if index is None else _scatter_rows(full, jnp.asarray(index), cur)

    while True:
        args = (mdp, cur_params, *cur, start, end, block, support)
        cur_agents, cur_returns, cur_lengths, done_iterations, active = _executables.compiled(
            _run_block, args, {"unroll": unroll}
        )(*args)
        cur = (cur_agents, cur_returns, cur_lengths)
        done_iterations = int(done_iterations)
        iterations += done_iterations
        lane_iterations += done_iterations * size
        active = np.array(active)
        if index is not None:
            active &= index < num_agents  # padding lanes do not count
        num_active = int(active.sum())
        if num_active == 0:
            break
        target = max(_next_power_of_two(num_active), min_batch)
        if target * 2 > size:
            continue
        # Write the current batch back, then gather the active agents.
        full = written_back()
        keep = np.flatnonzero(active) if index is None else index[active]
        index = np.full(target, num_agents, np.int32)
        index[: keep.size] = keep
        gather = np.where(index < num_agents, index, keep[0]).astype(np.int32)
        cur_params = _gather_rows(params, jnp.asarray(gather))
        cur = _gather_rows(full, jnp.asarray(gather))
        size = target
    return (*written_back(), iterations, lane_iterations)


#: Sequential executables checked by :func:`_check_native` (by id): compiled natively?
_NATIVE: dict[int, bool] = {}


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
    native = _NATIVE.get(id(executable))
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
        _NATIVE[id(executable)] = native
    return native


def _sequential_groups(kinds: np.ndarray, threads: int, costs: np.ndarray | None = None
                       ) -> list[np.ndarray]:
    """Agent indices per work item: one kind each, ≈ ``4 × threads`` items in all.

    ``costs`` estimates each agent's work (its steps in the previous chunk; ``None``: all
    equal). Within a kind, the agents are dealt to the kind's items in order of
    decreasing cost, back and forth, so the items have equal sizes (few shapes to
    compile) and similar costs; items are returned most costly first, so that the last
    items to start are short ones and the threads finish together.
    """
    num_agents = kinds.shape[0]
    costs = np.ones(num_agents) if costs is None else np.asarray(costs, np.float64)
    target = max(1, -(-num_agents // (4 * threads)))  # agents per item
    groups = []
    for kind in np.unique(kinds):
        members = np.flatnonzero(kinds == kind)
        parts = -(-members.size // target)
        ordered = members[np.argsort(-costs[members], kind="stable")]
        deal = np.arange(ordered.size) % (2 * parts)
        deal = np.where(deal < parts, deal, 2 * parts - 1 - deal)  # 0,1,..,p-1,p-1,..,0
        groups += [np.sort(ordered[deal == k]) for k in range(parts)]
    return sorted(groups, key=lambda group: (-costs[group].sum(), -len(group)))


#: Agents whose state (Q, ε(s)) is at most this many bytes are regrouped into new work
#: items every chunk (cost balance); larger agents stay in their first work item for the
#: whole run, their tables never leaving the engine's buffers between chunks.
REGROUP_MAX_BYTES = 1 << 20


def _padded(index: np.ndarray) -> np.ndarray:
    """A work item's rows, repeated up to a power of two (few shapes to compile)."""
    return np.resize(index, _next_power_of_two(index.size))


def _kept_in_items(mdp: TabularMDP) -> bool:
    """Whether an agent's tables exceed :data:`REGROUP_MAX_BYTES` (see _SequentialRun)."""
    return mdp.num_states * (mdp.num_actions + 1) * 4 > REGROUP_MAX_BYTES


class _SequentialRun:
    """The sequential strategy over the chunks of one :func:`run_agents` call.

    Agents are split by kind (learner, VDBE or not), each kind compiled with those flags
    as constants (:func:`_run_sequential`), and into about ``4 × threads`` work items
    (:func:`_sequential_groups`); worker threads take items as they become free (XLA
    releases the GIL while a program runs). An item's arrays are padded to a power-of-two
    number of rows (few shapes to compile; padding rows are not run). Each agent's result
    depends on its own lane only, so the grouping changes nothing.

    Between chunks an item's state stays in the engine's buffers, which each chunk's
    program updates in place (donated). Small agents are regrouped by cost every chunk
    (the state goes through the host, cheap for them); agents larger than
    :data:`REGROUP_MAX_BYTES` keep their first item, so their tables are not copied per
    chunk. :meth:`agents` gathers the full state on the host when it is needed
    (checkpoints, the end of the run).
    """

    def __init__(self, mdp: TabularMDP, params: AgentParams, agents: AgentState | None,
                 keys: Any, threads: int) -> None:
        """``agents=None``: fresh agents, created in their work items (large agents)."""
        self.mdp, self.threads = mdp, threads
        self.params = jax.tree.map(np.asarray, params)
        self.keys = np.asarray(keys, np.uint32)
        self.host = agents  # the full state while host_current (numpy or device arrays)
        self.host_current = True
        self.items: list[tuple[np.ndarray, Any]] | None = None
        self.kinds = 2 * self.params.learner.sarsa.astype(np.int64) + self.params.explorer.adaptive
        self.regroup = not _kept_in_items(mdp)
        self.support = _start_support(mdp)
        self.layout = (jax.eval_shape(_init_agents, mdp, self.params, self.keys)
                       if agents is None else
                       jax.tree.map(lambda leaf: jax.ShapeDtypeStruct(leaf.shape, leaf.dtype),
                                    agents))

    def agents(self) -> AgentState:
        """The full state on the host (numpy), the items' rows written back."""
        if self.host is None and self.items is None:  # nothing run yet
            self.host = _executables.compiled(
                _init_agents, (self.mdp, self.params, self.keys), {}
            )(self.mdp, self.params, self.keys)
        if not self.host_current:
            # Fresh arrays: ones handed out before (checkpoints) must not change.
            host = jax.tree.map(lambda leaf: np.empty(leaf.shape, leaf.dtype), self.layout)
            for index, state in self.items:
                for full, rows in zip(jax.tree.leaves(host), jax.tree.leaves(state)):
                    full[index] = np.asarray(rows)[: index.size]
            self.host, self.host_current = host, True
        return self.host

    def nonfinite_flags(self) -> np.ndarray:
        """Each agent's ``nonfinite`` flag, without gathering the tables."""
        if self.host_current:
            return np.asarray(self.agents().nonfinite)
        flags = np.empty(self.keys.shape[0], bool)
        for index, state in self.items:
            flags[index] = np.asarray(state.nonfinite)[: index.size]
        return flags

    def _call(self, index: np.ndarray, agents: Any, chunk: tuple[int, int, int]) -> tuple:
        """``(executable, args)`` of an item; ``agents`` may be shapes only."""
        chunk_start, chunk_end, chunk_length = chunk
        rows = _padded(index)
        params = jax.tree.map(lambda leaf: leaf[rows], self.params)
        kind = int(self.kinds[index[0]])
        static = {"chunk_length": chunk_length, "kind": (bool(kind // 2), bool(kind % 2))}
        args = (self.mdp, params, agents, jnp.int32(chunk_start), jnp.int32(chunk_end),
                jnp.int32(index.size), self.support)
        return _executables.compiled(_run_sequential, args, static, _CPU_COMPILER_OPTIONS), args

    def _group(self, costs: np.ndarray | None, chunk: tuple[int, int, int]) -> bool:
        """New work items from the current state; ``False`` if a loop is not native."""
        groups = _sequential_groups(self.kinds, self.threads, costs)

        def shapes(index: np.ndarray) -> Any:  # enough to compile: no copy of the rows
            size = _padded(index).size
            return jax.tree.map(
                lambda leaf: jax.ShapeDtypeStruct((size, *leaf.shape[1:]), leaf.dtype),
                self.layout,
            )

        # Compile on this thread (one program per kind and padded size) before running.
        if not all(_check_native(self._call(index, shapes(index), chunk)[0]) for index in groups):
            return False
        fresh = self.host is None  # large fresh agents: created in their item, on the device
        host = None if fresh else self.agents()
        items = []
        for index in groups:
            rows = _padded(index)
            if fresh:
                args = (self.mdp, jax.tree.map(lambda leaf, rows=rows: leaf[rows], self.params),
                        self.keys[rows])
                state = _executables.compiled(_init_agents, args, {})(*args)
            else:  # on a CPU np.asarray of a device array is a view: one gather, one copy
                state = jax.tree.map(lambda leaf, rows=rows: jnp.asarray(np.asarray(leaf)[rows]),
                                     host)
            items.append((index, state))
        self.items = items
        return True

    def run_chunk(self, chunk_start: int, chunk_end: int, chunk_length: int,
                  costs: np.ndarray | None) -> tuple[np.ndarray, np.ndarray, int] | None:
        """Advance every agent to ``chunk_end`` episodes.

        Returns:
          ``(returns, lengths, iterations)``: numpy ``[agents, chunk_length]`` buffers and
          Σ agent loop iterations (steps, plus one per episode start after a truncation);
          ``None`` (nothing run) if a loop did not compile natively
          (:func:`native_step_loops`).
        """
        chunk = (chunk_start, chunk_end, chunk_length)
        if (self.items is None or self.regroup) and not self._group(costs, chunk):
            return None
        # Items most costly first (one kind each; their order only affects the balance).
        order = sorted(range(len(self.items)), key=lambda k: -(
            1.0 if costs is None else float(costs[self.items[k][0]].sum())))

        def run(k: int) -> tuple:
            index, state = self.items[k]
            executable, args = self._call(index, state, chunk)
            new_state, returns, lengths, iterations = executable(*args)  # state donated
            self.items[k] = (index, new_state)
            return (np.asarray(returns)[: index.size], np.asarray(lengths)[: index.size],
                    int(iterations))

        self.host_current = False
        if self.threads == 1 or len(order) == 1:
            outputs = [run(k) for k in order]
        else:
            with ThreadPoolExecutor(max_workers=self.threads) as pool:
                outputs = list(pool.map(run, order))
        num_agents = int(self.keys.shape[0])
        returns = np.zeros((num_agents, chunk_length), np.float32)
        lengths = np.zeros((num_agents, chunk_length), np.int32)
        iterations = 0
        for k, (item_returns, item_lengths, item_iterations) in zip(order, outputs):
            index = self.items[k][0]
            returns[index], lengths[index] = item_returns, item_lengths
            iterations += item_iterations
        return returns, lengths, iterations


def _run_chunk_lockstep(
    mdp: TabularMDP,
    params: AgentParams,
    agents: AgentState,
    chunk_start: int,
    chunk_end: int,
    chunk_length: int,
    *,
    compact: bool,
    block_iterations: int,
    unroll: int,
    min_batch: int,
    max_batch: int,
) -> tuple[AgentState, Array, Array, int, int]:
    """One chunk of the lockstep strategy, in groups of at most ``max_batch`` lanes.

    Groups run one after another: a group's tables stay cache-sized, and per-agent results
    do not depend on the grouping (options as in :func:`run_agents`).

    Returns:
      ``(agents, returns, lengths, iterations, lane_iterations)``.
    """
    num_agents = int(agents.episode.shape[0])
    pieces = []
    iterations = lane_iterations = 0
    for lo in range(0, num_agents, max_batch):
        hi = min(lo + max_batch, num_agents)
        whole = lo == 0 and hi == num_agents

        def part(tree: Any, lo: int = lo, hi: int = hi, whole: bool = whole) -> Any:
            return tree if whole else jax.tree.map(lambda leaf: leaf[lo:hi], tree)

        if compact:
            *piece, group_iterations, group_lanes = _run_chunk_compacting(
                mdp, part(params), part(agents), chunk_start, chunk_end, chunk_length,
                block_iterations=block_iterations, unroll=unroll, min_batch=min_batch,
            )
        else:
            *piece, group_iterations = run_chunk(
                mdp, part(params), part(agents), jnp.int32(chunk_start), jnp.int32(chunk_end),
                chunk_length, unroll,
            )
            group_iterations = int(group_iterations)
            group_lanes = group_iterations * (hi - lo)
        pieces.append(piece)
        iterations += group_iterations
        lane_iterations += group_lanes
    if len(pieces) == 1:
        agents, returns, lengths = pieces[0]
    else:
        agents, returns, lengths = jax.tree.map(lambda *leaves: jnp.concatenate(leaves), *pieces)
    return agents, returns, lengths, iterations, lane_iterations


@dataclasses.dataclass
class RunResult:
    """Output of :func:`run_agents`.

    Attributes:
      returns: float32 ``[agents, episodes]`` undiscounted episode returns.
      lengths: int32 ``[agents, episodes]`` episode lengths (steps).
      nonfinite: bool ``[agents]``: a NaN or inf appeared in the agent's Q or ε.
      iterations: lockstep iterations executed (for efficiency statistics).
      final_state: the agents' states after the last episode (numpy leaves; ``None``
        with ``keep_final_state=False``).
      lane_iterations: Σ over executed lockstep iterations of the batch width (the
        agent-iterations paid for, idle lanes included; lower with compaction).
      strategy: the strategy that ran (``"sequential"`` or ``"lockstep"``; the last one
        if the sequential strategy fell back, see :func:`native_step_loops`).
    """

    returns: np.ndarray
    lengths: np.ndarray
    nonfinite: np.ndarray
    iterations: int
    final_state: AgentState | None
    lane_iterations: int = 0
    strategy: str = "lockstep"


ProgressCallback = Callable[[int, int, float], None]


def text_progress(stream: Any = None) -> ProgressCallback:
    """A progress bar on ``stream`` (stderr by default): ``done/total`` agent-episodes.

    Args:
      stream: a text stream (default ``sys.stderr``).

    Returns:
      a :data:`ProgressCallback` that redraws the bar on each call.
    """
    stream = sys.stderr if stream is None else stream

    def show(done: int, total: int, elapsed: float) -> None:
        width = 30
        filled = int(width * done / max(total, 1))
        bar = "#" * filled + "." * (width - filled)
        end = "\n" if done >= total else ""
        stream.write(f"\r[{bar}] {100 * done / max(total, 1):5.1f}%  {elapsed:6.1f}s{end}")
        stream.flush()

    return show


def agent_keys(seed: int, num_seeds: int) -> np.ndarray:
    """Keys of agents 0..num_seeds-1: ``fold_in(PRNGKey(seed), i)`` (uint32 ``[n, 2]``).

    Every configuration uses the same key for the same seed index (common random numbers),
    so an agent gives the same result alone or in any grid.

    Args:
      seed: root seed.
      num_seeds: number of agents (seed indices).

    Returns:
      uint32 ``[num_seeds, 2]`` raw keys.
    """
    # One small cached program per (seed, count): no tracing in a warm process.
    static = {"seed": int(seed), "num_seeds": int(num_seeds)}
    return np.asarray(_executables.compiled(_agent_keys, (), static)())


@partial(jax.jit, static_argnames=("seed", "num_seeds"))
def _agent_keys(*, seed: int, num_seeds: int) -> Array:
    root = jax.random.PRNGKey(seed)
    return jax.vmap(lambda i: jax.random.fold_in(root, i))(jnp.arange(num_seeds))


def run_agents(
    mdp: TabularMDP,
    params: AgentParams,
    keys: Any,
    num_episodes: int,
    *,
    chunk_episodes: int = 100,
    progress: ProgressCallback | None = None,
    on_chunk: Callable[[int, AgentState, np.ndarray, np.ndarray], None] | None = None,
    initial: tuple[int, AgentState, np.ndarray, np.ndarray] | None = None,
    compact: bool = True,
    block_iterations: int = 256,
    unroll: int = DEFAULT_UNROLL,
    min_batch: int = 8,
    max_batch: int = MAX_SAFE_BATCH,
    strategy: str = "auto",
    threads: int | None = None,
    keep_final_state: bool = True,
) -> RunResult:
    """Train a batch of agents for ``num_episodes`` episodes each.

    Args:
      mdp: the task.
      params: batched hyperparameters, leading axis = agents.
      keys: uint32 ``[agents, 2]`` PRNG keys.
      num_episodes: episodes per agent.
      chunk_episodes: episodes per jitted chunk (progress/checkpoint granularity; the
        results do not depend on it).
      progress: called as ``progress(done_agent_episodes, total, elapsed_seconds)``.
      on_chunk: called after each chunk with ``(episodes_done, agents, returns, lengths)``
        (numpy arrays covering episodes ``[0, episodes_done)``); used for checkpoints.
      initial: resume from ``(episodes_done, agents, returns, lengths)``.
      compact: between blocks of ``block_iterations`` lockstep iterations, gather the
        still-active agents into a smaller power-of-two batch (at least ``min_batch``
        lanes) once at most half the lanes are active, so finished agents stop costing
        work.
      block_iterations: lockstep iterations between compaction checks.
      unroll: lockstep iterations per loop trip.
      min_batch: smallest batch (lanes) compaction shrinks to.
      max_batch: agents run in groups of at most this many lanes, one group after
        another (keeps each group's Q tables cache-sized, so throughput per agent-step
        does not fall as the number of agents grows).

      strategy: ``"sequential"`` (each agent runs its own native step loop; agents are
        spread over ``threads`` threads; the fast choice on CPU), ``"lockstep"`` (all
        agents of a batch advance together, one vectorised step per iteration, with
        compaction and groups as above; for accelerators and sharded agents), or
        ``"auto"``: sequential when the default backend is the CPU and the agents are not
        sharded over several devices, lockstep otherwise.
      threads: worker threads of the sequential strategy (default: the CPUs this
        process may use).

      None of ``compact`` … ``threads`` change the results, only the speed, as long as
      ``max_batch`` ≤ :data:`MAX_SAFE_BATCH` (see there).
      keep_final_state: ``False`` leaves :attr:`RunResult.final_state` ``None``, which
        spares gathering every agent's tables on the host at the end (large tasks).

    Returns:
      :class:`RunResult`.
    """
    check_int("num_episodes", num_episodes, 1)
    check_int("chunk_episodes", chunk_episodes, 1)
    check_int("block_iterations", block_iterations, 1)
    check_int("unroll", unroll, 1)
    check_int("min_batch", min_batch, 1)
    check_int("max_batch", max_batch, 1)
    check_choice("strategy", strategy, STRATEGIES + ("auto",))
    if threads is None:
        threads = available_cpus()
    check_int("threads", threads, 1)
    if strategy == "auto":
        strategy = _auto_strategy(params, keys)
    keys = jnp.asarray(keys, jnp.uint32)
    num_agents = int(keys.shape[0])
    chunk = min(chunk_episodes, num_episodes)
    returns = np.zeros((num_agents, num_episodes), np.float32)
    lengths = np.zeros((num_agents, num_episodes), np.int32)
    if initial is None:
        done = 0
        agents = None  # created by the sequential strategy in its work items
        if strategy != "sequential" or not _kept_in_items(mdp):
            agents = _executables.compiled(_init_agents, (mdp, params, keys), {})(mdp, params, keys)
    else:
        done, agents, returns[:, : initial[0]], lengths[:, : initial[0]] = initial
        agents = jax.tree.map(jnp.asarray, agents)
    iterations = lane_iterations = 0
    costs = None
    started = time.perf_counter()
    if progress:
        progress(done * num_agents, num_episodes * num_agents, 0.0)
    # The sequential strategy keeps the agents' state in its work items; ``agents`` is
    # the state only while the lockstep strategy runs.
    sequential = None
    if strategy == "sequential":
        sequential = _SequentialRun(mdp, params, agents, keys, threads)

    def current_agents() -> AgentState:
        return agents if sequential is None else sequential.agents()

    while done < num_episodes:
        end = min(done + chunk, num_episodes)
        result = None
        if sequential is not None:
            result = sequential.run_chunk(done, end, chunk, costs)
            if result is None:  # not compiled natively: lockstep is faster
                strategy, agents, sequential = "lockstep", sequential.agents(), None
        if result is not None:
            chunk_returns, chunk_lengths, chunk_iterations = result
            chunk_lanes = chunk_iterations  # one lane per loop iteration
        else:
            agents, chunk_returns, chunk_lengths, chunk_iterations, chunk_lanes = (
                _run_chunk_lockstep(
                    mdp, params, agents, done, end, chunk, compact=compact,
                    block_iterations=block_iterations, unroll=unroll, min_batch=min_batch,
                    max_batch=max_batch,
                )
            )
        costs = np.asarray(chunk_lengths).sum(axis=1)  # the next chunk's work, roughly
        returns[:, done:end] = np.asarray(chunk_returns)[:, : end - done]
        lengths[:, done:end] = np.asarray(chunk_lengths)[:, : end - done]
        iterations += chunk_iterations
        lane_iterations += chunk_lanes
        done = end
        if on_chunk:
            on_chunk(done, current_agents(), returns[:, :done], lengths[:, :done])
        if progress:
            progress(done * num_agents, num_episodes * num_agents, time.perf_counter() - started)
    if keep_final_state:
        final = jax.tree.map(np.asarray, current_agents())
        nonfinite = np.asarray(final.nonfinite)
    else:  # the flags alone: no tables gathered
        final = None
        nonfinite = (np.asarray(agents.nonfinite) if sequential is None
                     else sequential.nonfinite_flags())
    return RunResult(returns, lengths, nonfinite, iterations, final, lane_iterations, strategy)


#: Engine strategies of :func:`run_agents`.
STRATEGIES = ("sequential", "lockstep")


def available_cpus() -> int:
    """CPUs this process may run on (its affinity mask where the OS has one)."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        return os.cpu_count() or 1


def _auto_strategy(params: AgentParams, keys: Any) -> str:
    """``"sequential"`` on a CPU backend with unsharded agents, else ``"lockstep"``."""
    if jax.default_backend() != "cpu":
        return "lockstep"
    for leaf in jax.tree.leaves((params, keys)):
        sharding = getattr(leaf, "sharding", None)
        if sharding is not None and len(sharding.device_set) > 1:
            return "lockstep"
    return "sequential"


def broadcast_agents(params: AgentParams, repeats: int) -> AgentParams:
    """Repeat each agent ``repeats`` times (config-major order: c0s0, c0s1, …).

    Args:
      params: hyperparameters with a leading config axis.
      repeats: agents (seeds) per config.

    Returns:
      the hyperparameters with a leading axis of ``configs × repeats`` agents.
    """
    def repeat(leaf: Any) -> Any:
        # On the host unless the leaf lives on a device (or is traced).
        return (jnp if isinstance(leaf, jax.Array) else np).repeat(leaf, repeats, axis=0)

    return jax.tree.map(repeat, params)
