"""The engine's speed devices (compaction, unrolling, column layout, hashed random
streams) must not change any result: each agent's results depend only on its key and
hyperparameters."""
from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from vdbejax import engine
from vdbejax.agents import Setting, make_agent, stack_agents
from vdbejax.envs.table_cleaning import make_mdp
from vdbejax.explorers import select_action

SETTINGS = [
    Setting("sarsa", "vdbe", 0.001),
    Setting("qlearning", "vdbe_softmax", 1.0),
    Setting("qlearning", "egreedy", 0.1),
    Setting("sarsa", "softmax", 0.0001),
]


@pytest.fixture(scope="module")
def mdp():
    return make_mdp()


def _grid(seeds: int):
    params = engine.broadcast_agents(stack_agents([make_agent(s) for s in SETTINGS]), seeds)
    keys = np.tile(engine.agent_keys(0, seeds), (len(SETTINGS), 1))
    return params, keys


@pytest.mark.parametrize("tie_break", ["random", "first"])
def test_transposed_select_action_matches_explorers(tie_break):
    rng = np.random.default_rng(0)
    n, num_actions = 4096, 7
    q = rng.choice([0.0, -0.01, 0.5, 0.86, -1.0], size=(n, num_actions)).astype(np.float32)
    q += (rng.random((n, num_actions)) < 0.3) * rng.normal(size=(n, num_actions)).astype(
        np.float32
    )
    p = rng.random(n).astype(np.float32)
    tau = rng.choice([1e-4, 1e-3, 0.1, 10.0, np.inf], size=n).astype(np.float32)
    u = (rng.integers(0, 2**23, size=(n, 3)) * 2.0**-23).astype(np.float32)
    expected = jax.vmap(select_action, in_axes=(0, 0, 0, 0, None))(q, p, tau, u, tie_break)
    got = jax.jit(engine._select_action_rows, static_argnums=4)(
        jnp.asarray(q.T), p, tau, tuple(jnp.asarray(u[:, j]) for j in range(3)), tie_break
    )
    np.testing.assert_array_equal(np.asarray(got), np.asarray(expected))


def test_batched_iteration_matches_vmapped_agent_iteration(mdp):
    params, keys = _grid(2)
    agents = jax.vmap(engine.init_agent, in_axes=(None, 0, 0))(mdp, params, keys)
    support = engine._start_support(mdp)
    step = jax.jit(
        jax.vmap(engine.agent_iteration, in_axes=(None, 0, 0, None, None, None)),
    )
    reference = agents
    for _ in range(300):
        reference, _ = step(mdp, params, reference, jnp.int32(0), jnp.int32(10**6), support)
    returns = jnp.zeros((8, 4), jnp.float32)
    batched, _, _, iterations = jax.jit(engine._run_loop, static_argnames="unroll")(
        mdp, params, agents, returns, returns.astype(jnp.int32), jnp.int32(0),
        jnp.int32(10**6), jnp.int32(300), unroll=1, start_support=support,
    )
    assert int(iterations) == 300
    for name in ("q", "epsilon", "state", "action", "episode", "episode_return", "counter"):
        np.testing.assert_array_equal(
            np.asarray(getattr(batched, name)), np.asarray(getattr(reference, name)), name
        )


def test_compaction_chunking_and_batch_position_do_not_change_results(mdp):
    params, keys = _grid(2)
    base = engine.run_agents(mdp, params, keys, 12, chunk_episodes=12, compact=False)
    grouped = engine.run_agents(mdp, params, keys, 12, compact=False, max_batch=5)
    np.testing.assert_array_equal(base.returns, grouped.returns)
    compacted = engine.run_agents(
        mdp, params, keys, 12, chunk_episodes=5, block_iterations=8, min_batch=2, max_batch=3
    )
    np.testing.assert_array_equal(base.returns, compacted.returns)
    np.testing.assert_array_equal(base.lengths, compacted.lengths)
    np.testing.assert_array_equal(base.final_state.q, compacted.final_state.q)
    # One agent alone (the slowest kind: SARSA + VDBE σ = 0.001) equals itself in the batch.
    alone = engine.run_agents(
        mdp, jax.tree.map(lambda x: x[1:2], params), keys[1:2], 12, chunk_episodes=5
    )
    np.testing.assert_array_equal(alone.returns[0], base.returns[1])
    np.testing.assert_array_equal(alone.lengths[0], base.lengths[1])


def test_hashed_stream_depends_only_on_key_and_counter():
    keys = jnp.asarray(engine.agent_keys(3, 5))
    counters = jnp.arange(5, dtype=jnp.uint32) * 7
    batch = engine._uniforms(keys, counters)
    for i in range(5):
        single = engine._uniforms(keys[i], counters[i])
        for draw_batch, draw_single in zip(batch, single):
            assert float(draw_batch[i]) == float(draw_single)
            assert 0.0 <= float(draw_single) < 1.0
