"""The vectorized engine: every agent of a sweep advances inside one jitted program.

Design (why it looks like this):

* **Step-synchronous lockstep.** Agents do not wait for each other at episode
  boundaries: each agent has its own episode counter and starts its next episode as soon
  as the previous one ends. One ``lax.while_loop`` iteration advances every active agent
  by one environment step, so a batch costs ``max_agent(total steps)`` iterations instead
  of ``Σ_episodes max_agent(episode length)``.
* **Chunks.** A chunk runs until every agent has finished episode ``chunk_end``; the
  Python driver loops over chunks to show progress and write checkpoints. An agent's
  state at a chunk boundary is the same whatever the chunk size.
* **Per-agent random streams.** Each iteration of an agent draws its uniforms from
  ``fold_in(agent_key, agent_counter)``: results depend only on the agent's key and
  hyperparameters, never on the batch, the chunking or a resume.
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
import math
import sys
import time
from collections.abc import Callable
from functools import partial
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from vdbejax._pytree import pytree_dataclass
from vdbejax.agents import AgentParams
from vdbejax.envs.tabular import TabularMDP
from vdbejax.explorers import select_action, vdbe_epsilon_update
from vdbejax.learners import q_learning_target, sarsa_target, td_update

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
    """Fresh state of one agent: Q = q_init, ε(s) = 1, a reset pending."""
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


def _uniforms(key: Array, counter: Array) -> Array:
    bits = jax.random.bits(jax.random.fold_in(key, counter), (_NUM_UNIFORMS,), jnp.uint32)
    # 23-bit mantissa: values in [0, 1 − 2⁻²³], which sample_categorical relies on.
    return (bits >> 9).astype(jnp.float32) * jnp.float32(2.0**-23)


def agent_iteration(
    mdp: TabularMDP,
    params: AgentParams,
    agent: AgentState,
    chunk_start: Array,
    chunk_end: Array,
) -> tuple[AgentState, tuple[Array, Array, Array]]:
    """Advance one agent by one iteration (see the module docstring).

    Returns:
      ``(new_agent, (slot, episode_return, episode_length))`` where ``slot`` is the
      finished episode's index within the chunk, or -1 when no episode finished.
    """
    learner, explorer = params.learner, params.explorer
    active = agent.episode < chunk_end
    u = _uniforms(agent.key, agent.counter)
    resetting = agent.pending_reset
    learn = active & ~resetting
    s, a = agent.state, agent.action

    s_next, reward, terminal = mdp.transition(s, a, u[1])
    length = agent.episode_length + 1
    truncated = ~terminal & (length >= mdp.max_steps)
    s_start = mdp.start(u[0])

    q_sa = agent.q[s, a]
    q_next = agent.q[s_next]
    discount = jnp.where(terminal, 0.0, learner.gamma)
    q_learning_value, q_learning_dq = td_update(
        q_sa, q_learning_target(reward, discount, q_next), learner.alpha
    )

    # Choose the next action (in the new episode's start state after a terminal step).
    act_state = jnp.where(resetting | terminal, s_start, s_next)
    act_q = agent.q[act_state]
    act_epsilon = agent.epsilon[act_state]
    # Q-learning chooses after its update: patch the row when acting in the updated state.
    patch = ~learner.sarsa & ~resetting & (act_state == s)
    act_q = jnp.where(patch, act_q.at[a].set(q_learning_value), act_q)
    act_epsilon = jnp.where(
        patch & explorer.adaptive,
        vdbe_epsilon_update(act_epsilon, q_learning_dq, explorer.sigma, explorer.delta),
        act_epsilon,
    )
    explore_probability = jnp.where(explorer.adaptive, act_epsilon, explorer.epsilon)
    next_action = select_action(act_q, explore_probability, explorer.tau, u[2:], explorer.tie_break)

    # Learn from (s, a, r, s').
    sarsa_value, sarsa_dq = td_update(
        q_sa, sarsa_target(reward, discount, q_next, next_action), learner.alpha
    )
    new_q_sa = jnp.where(learner.sarsa, sarsa_value, q_learning_value)
    delta_q = jnp.where(learner.sarsa, sarsa_dq, q_learning_dq)
    eps_s = agent.epsilon[s]
    new_eps_s = vdbe_epsilon_update(eps_s, delta_q, explorer.sigma, explorer.delta)
    q = agent.q.at[s, a].set(jnp.where(learn, new_q_sa, q_sa))
    epsilon = agent.epsilon.at[s].set(jnp.where(learn & explorer.adaptive, new_eps_s, eps_s))

    # Episode bookkeeping.
    episode_return = agent.episode_return + reward
    done = learn & (terminal | truncated)
    slot = jnp.where(done, agent.episode - chunk_start, -1)

    def keep(new: Array, old: Array) -> Array:
        return jnp.where(active, new, old)

    new_agent = AgentState(
        q=q,
        epsilon=epsilon,
        state=keep(act_state, s),
        action=keep(next_action, a),
        pending_reset=keep(learn & truncated, resetting),
        episode=agent.episode + done.astype(jnp.int32),
        episode_return=jnp.where(learn, jnp.where(done, 0.0, episode_return), agent.episode_return),
        episode_length=jnp.where(learn, jnp.where(done, 0, length), agent.episode_length),
        counter=agent.counter + active.astype(jnp.uint32),
        key=agent.key,
        nonfinite=agent.nonfinite
        | (learn & ~(jnp.isfinite(new_q_sa) & jnp.isfinite(new_eps_s))),
    )
    return new_agent, (slot, episode_return, length)


@partial(jax.jit, static_argnames=("chunk_length",))
def run_chunk(
    mdp: TabularMDP,
    params: AgentParams,
    agents: AgentState,
    chunk_start: Array,
    chunk_end: Array,
    chunk_length: int,
) -> tuple[AgentState, Array, Array, Array]:
    """Advance a batch of agents until each has completed ``chunk_end`` episodes.

    Args:
      mdp: the task (shared by all agents).
      params: batched agent hyperparameters (leading axis = agents).
      agents: batched agent states.
      chunk_start: episode index of the chunk's first episode.
      chunk_end: episode count at which an agent stops (≤ ``chunk_start + chunk_length``).
      chunk_length: static buffer length.

    Returns:
      ``(agents, returns, lengths, iterations)``: returns/lengths are
      ``[agents, chunk_length]`` (episodes past ``chunk_end`` stay 0), ``iterations``
      the number of lockstep iterations executed.
    """
    num_agents = agents.episode.shape[0]
    rows = jnp.arange(num_agents)
    step = jax.vmap(agent_iteration, in_axes=(None, 0, 0, None, None))

    def cond(carry: tuple) -> Array:
        return jnp.any(carry[0].episode < chunk_end)

    def body(carry: tuple) -> tuple:
        agents, returns, lengths, iterations = carry
        agents, (slot, episode_return, episode_length) = step(
            mdp, params, agents, chunk_start, chunk_end
        )
        slot = jnp.where(slot < 0, chunk_length, slot)  # out of bounds: dropped
        returns = returns.at[rows, slot].set(episode_return, mode="drop")
        lengths = lengths.at[rows, slot].set(episode_length, mode="drop")
        return agents, returns, lengths, iterations + 1

    returns = jnp.zeros((num_agents, chunk_length), jnp.float32)
    lengths = jnp.zeros((num_agents, chunk_length), jnp.int32)
    return jax.lax.while_loop(cond, body, (agents, returns, lengths, jnp.asarray(0, jnp.int32)))


@dataclasses.dataclass
class RunResult:
    """Output of :func:`run_agents`.

    Attributes:
      returns: float32 ``[agents, episodes]`` undiscounted episode returns.
      lengths: int32 ``[agents, episodes]`` episode lengths (steps).
      nonfinite: bool ``[agents]``: a NaN or inf appeared in the agent's Q or ε.
      iterations: lockstep iterations executed (for efficiency statistics).
      final_state: the agents' states after the last episode (numpy leaves).
    """

    returns: np.ndarray
    lengths: np.ndarray
    nonfinite: np.ndarray
    iterations: int
    final_state: AgentState


ProgressCallback = Callable[[int, int, float], None]


def text_progress(stream: Any = None) -> ProgressCallback:
    """A progress bar on ``stream`` (stderr by default): ``done/total`` agent-episodes."""
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
    """
    root = jax.random.PRNGKey(seed)
    return np.asarray(jax.vmap(lambda i: jax.random.fold_in(root, i))(jnp.arange(num_seeds)))


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

    Returns:
      :class:`RunResult`.
    """
    from vdbejax.validation import check_int

    check_int("num_episodes", num_episodes, 1)
    check_int("chunk_episodes", chunk_episodes, 1)
    keys = jnp.asarray(keys, jnp.uint32)
    num_agents = int(keys.shape[0])
    chunk = min(chunk_episodes, num_episodes)
    returns = np.zeros((num_agents, num_episodes), np.float32)
    lengths = np.zeros((num_agents, num_episodes), np.int32)
    if initial is None:
        done = 0
        agents = jax.vmap(init_agent, in_axes=(None, 0, 0))(mdp, params, keys)
    else:
        done, agents, returns[:, : initial[0]], lengths[:, : initial[0]] = initial
        agents = jax.tree.map(jnp.asarray, agents)
    iterations = 0
    started = time.perf_counter()
    if progress:
        progress(done * num_agents, num_episodes * num_agents, 0.0)
    while done < num_episodes:
        end = min(done + chunk, num_episodes)
        agents, chunk_returns, chunk_lengths, chunk_iterations = run_chunk(
            mdp, params, agents, jnp.int32(done), jnp.int32(end), chunk
        )
        returns[:, done:end] = np.asarray(chunk_returns)[:, : end - done]
        lengths[:, done:end] = np.asarray(chunk_lengths)[:, : end - done]
        iterations += int(chunk_iterations)
        done = end
        if on_chunk:
            on_chunk(done, agents, returns[:, :done], lengths[:, :done])
        if progress:
            progress(done * num_agents, num_episodes * num_agents, time.perf_counter() - started)
    final = jax.tree.map(np.asarray, agents)
    return RunResult(returns, lengths, np.asarray(final.nonfinite), iterations, final)


def broadcast_agents(params: AgentParams, repeats: int) -> AgentParams:
    """Repeat each agent ``repeats`` times (config-major order: c0s0, c0s1, …)."""
    return jax.tree.map(lambda leaf: jnp.repeat(leaf, repeats, axis=0), params)


def steps_per_iteration_efficiency(lengths: np.ndarray, iterations: int) -> float:
    """Fraction of lockstep lanes doing real environment steps."""
    lanes = iterations * lengths.shape[0]
    return float(lengths.sum() / lanes) if lanes else math.nan
