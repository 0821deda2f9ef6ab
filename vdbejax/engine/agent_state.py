"""What an agent carries between steps, how it starts, and its random stream."""
from __future__ import annotations

import dataclasses
from functools import partial
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from jax import lax

from vdbejax._pytree import pytree_dataclass
from vdbejax.envs.tabular import TabularMDP
from vdbejax.envs.task_instances import TaskInstances
from vdbejax.methods.agents import AgentParams, table_layout
from vdbejax.methods.contract import TaskFacts
from vdbejax.methods.model import capacity

Array = jax.Array


#: The type of every agent-state array but ``tables`` (float32 each): :func:`init_agent`
#: makes them so, and a checkpoint's state is checked against them.
STATE_DTYPES = {"q": jnp.float32, "state": jnp.int32, "action": jnp.int32,
                "pending_reset": jnp.bool_, "episode": jnp.int32,
                "episode_return": jnp.float32, "episode_length": jnp.int32,
                "counter": jnp.uint32, "key": jnp.uint32, "nonfinite": jnp.bool_}


@pytree_dataclass
class AgentState:
    """Everything one agent carries between iterations (a leading axis for batches).

    Attributes:
      q: ``[S, A]`` action values.
      tables: the explorers' and learners' own tables (``{"epsilon": [S]}`` for VDBE,
        ``{"counts": [S, A]}`` for UCB-1, …); a batch holds the union of its kinds'
        tables, zeros for an agent whose kind does not use one.
      state: current state index.
      action: action already chosen for ``state``.
      pending_reset: the next iteration starts a new episode (first step, truncation).
      episode: number of completed episodes.
      episode_return: return of the running episode so far.
      episode_length: steps of the running episode so far.
      counter: iterations done, the index into the agent's random stream.
      key: the agent's PRNG key (raw ``uint32[2]``).
      nonfinite: a NaN or inf appeared in Q or one of the agent's tables.
    """

    q: Array
    tables: dict
    state: Array
    action: Array
    pending_reset: Array
    episode: Array
    episode_return: Array
    episode_length: Array
    counter: Array
    key: Array
    nonfinite: Array


def table_shape(mdp: TabularMDP, per: str) -> tuple[int, ...]:
    """One agent's table of kind ``per`` (``"state"``, ``"pair"`` or a model's
    ``"outcome"`` list, :mod:`vdbejax.methods.model`)."""
    S, A = mdp.num_states, mdp.num_actions
    if per == "state":
        return (S,)
    if per.startswith("stage:"):  # a learner's stage table (table_layout names its length)
        return (S, A, int(per.split(":", 1)[1]))
    return (S, A) if per == "pair" else (S, A, capacity(S, mdp.num_outcomes))


def init_agent(mdp: TabularMDP, params: AgentParams, key: Array) -> AgentState:
    """Fresh state of one agent: Q and tables at their initial values, a reset pending.

    Args:
      mdp: the task (sets the table shapes).
      params: the agent's row of an :class:`~vdbejax.methods.agents.AgentParams`.
      key: the agent's raw ``uint32[2]`` PRNG key.

    Returns:
      the :class:`AgentState` (no leading batch axis).
    """
    layout = table_layout(params)
    S, A = mdp.num_states, mdp.num_actions
    q = jnp.zeros((S, A), jnp.float32)
    tables = {name: jnp.zeros(table_shape(mdp, per), jnp.float32) for name, per in layout.items()}
    key = jnp.asarray(key, jnp.uint32)
    for k, agent in enumerate(params.kinds):
        mine = params.kind == k
        q = jnp.where(mine, agent.learner.initial_q(key, S, A).astype(jnp.float32), q)
        for owner in (agent.learner, agent.explorer):
            for name, spec in owner.tables().items():
                init = jnp.full(table_shape(mdp, layout[name]), spec.init, jnp.float32)
                tables[name] = jnp.where(mine, init, tables[name])
    values = {"q": q, "state": 0, "action": 0, "pending_reset": True, "episode": 0,
              "episode_return": 0.0, "episode_length": 0, "counter": 0, "key": key,
              "nonfinite": False}
    return AgentState(tables=tables, **{name: jnp.asarray(values[name], dtype)
                                        for name, dtype in STATE_DTYPES.items()})


def init_agents(mdp: TabularMDP, params: AgentParams, keys: Array) -> AgentState:
    """:func:`init_agent` for a batch (leading axis = agents); the engine runs it as one
    of its programs (:mod:`vdbejax.engine.programs`), wrap it in ``jax.jit`` to call it
    alone."""
    return jax.vmap(init_agent, in_axes=(None, 0, 0))(mdp, params, keys)


def _mix32(x: Array) -> Array:
    """lowbias32 integer finaliser (C. Wellons): a cheap, well-mixed uint32 bijection
    (``x`` uint32; lax's primitives: traced several times faster than operators)."""
    x = lax.bitwise_xor(x, lax.shift_right_logical(x, np.uint32(16)))
    x = lax.mul(x, np.uint32(0x7FEB352D))
    x = lax.bitwise_xor(x, lax.shift_right_logical(x, np.uint32(15)))
    x = lax.mul(x, np.uint32(0x846CA68B))
    return lax.bitwise_xor(x, lax.shift_right_logical(x, np.uint32(16)))


def uniforms(key: Array, counter: Array, count: int) -> tuple[Array, ...]:
    """The ``count`` uniforms of one agent iteration: a counter-based hash.

    Draw ``j`` is a pure function of the agent's key (``[..., 2]``), its own iteration
    counter and ``j`` alone, so results do not depend on the batch, the chunking or a
    resume, and asking for more draws (a plug-in that needs more) leaves the first ones
    unchanged. Much cheaper than threefry ``fold_in`` + ``bits``. Returns a tuple of
    arrays shaped like ``counter``; values in [0, 1 − 2⁻²³] (23-bit mantissa), which
    :func:`~vdbejax._numerics.sample_categorical` relies on.
    """
    return uniforms_from(draw_base(key, counter), count)


def draw_base(key: Array, counter: Array) -> Array:
    """The hash of an agent's key and iteration counter that its draws start from
    (:func:`uniforms` = :func:`uniforms_from` of it). A step loop carries it from one
    iteration to the next: computed once per step, not again inside every fusion that
    reads a draw (XLA's CPU backend duplicated it into each, a fifth of the paper grid's
    run)."""
    key = jnp.asarray(key).astype(jnp.uint32)
    counter = jnp.asarray(counter).astype(jnp.uint32)
    last = key.ndim - 1
    first = lax.index_in_dim(key, 0, axis=last, keepdims=False)
    second = lax.index_in_dim(key, 1, axis=last, keepdims=False)
    return _mix32(lax.bitwise_xor(second, _mix32(
        lax.add(first, lax.mul(counter, np.uint32(0x9E3779B9))))))


def uniforms_from(base: Array, count: int) -> tuple[Array, ...]:
    """The ``count`` uniforms of an iteration from its :func:`draw_base`."""
    draws = []
    for j in range(count):
        bits = _mix32(lax.add(base, np.uint32((j * 0x632BE5AB) % 2**32)))
        mantissa = lax.convert_element_type(lax.shift_right_logical(bits, np.uint32(9)),
                                            jnp.float32)
        draws.append(lax.mul(mantissa, np.float32(2.0**-23)))
    return tuple(draws)


#: Mixed into an iteration's :func:`draw_base` for the task's own draw (a reward's noise),
#: a stream apart from the plug-ins' uniforms (any number of them).
_TASK_STREAM = np.uint32(0xB5297A4D)


def reward_uniform(base: Array) -> Array:
    """The uniform in the open interval (0, 1) of an iteration's reward noise
    (:mod:`vdbejax.envs.reward_noise`), from its :func:`draw_base`: a pure function of the
    agent's key and counter, apart from the plug-ins' draws, so a plug-in that asks for
    more uniforms changes no reward. Drawn only for a task with reward noise."""
    bits = _mix32(lax.add(_mix32(lax.bitwise_xor(base, _TASK_STREAM)), _TASK_STREAM))
    mantissa = lax.convert_element_type(lax.shift_right_logical(bits, np.uint32(9)),
                                        jnp.float32)
    # (m + 0.5) · 2⁻²³ is exact and never 0 or 1 (the inverse normal CDF is finite there).
    return lax.mul(lax.add(mantissa, np.float32(0.5)), np.float32(2.0**-23))


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
    # vdbejax's code alone (no plug-in): JAX's own jit cache is enough.
    return np.asarray(_agent_keys(seed=int(seed), num_seeds=int(num_seeds)))


@partial(jax.jit, static_argnames=("seed", "num_seeds"))
def _agent_keys(*, seed: int, num_seeds: int) -> Array:
    root = jax.random.PRNGKey(seed)
    return jax.vmap(lambda i: jax.random.fold_in(root, i))(jnp.arange(num_seeds))


def broadcast_agents(params: Any, repeats: int) -> Any:
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


def task_facts(mdp: TabularMDP | TaskInstances) -> TaskFacts:
    """What a learner is told of ``mdp`` (:class:`~vdbejax.methods.contract.TaskFacts`):
    its rewards' extremes over the outcomes it can give, and whether one is terminal
    (with an instance per agent: over every instance of the run, its ``bounds``)."""
    if isinstance(mdp, TaskInstances):
        low, high, terminates = mdp.bounds
        return TaskFacts(reward_min=low, reward_max=high, terminates=terminates)
    possible = np.asarray(mdp.probability) > 0
    reward = np.asarray(mdp.reward, np.float64)[possible]
    return TaskFacts(reward_min=float(reward.min()), reward_max=float(reward.max()),
                     terminates=bool(np.asarray(mdp.terminal)[possible].any()))


def for_task(params: AgentParams, mdp: TabularMDP | TaskInstances) -> AgentParams:
    """``params`` with every kind's learner set for ``mdp`` (its
    :meth:`~vdbejax.methods.contract.Learner.for_task`): the engine's first act on a batch."""
    facts = task_facts(mdp)
    kinds = tuple(dataclasses.replace(agent, learner=agent.learner.for_task(facts))
                  for agent in params.kinds)
    return dataclasses.replace(params, kinds=kinds)


def state_bytes(mdp: TabularMDP, layout: dict[str, str]) -> int:
    """Bytes of one agent's Q and tables."""
    S, A = mdp.num_states, mdp.num_actions
    return 4 * S * A + sum(4 * int(np.prod(table_shape(mdp, per))) for per in layout.values())
