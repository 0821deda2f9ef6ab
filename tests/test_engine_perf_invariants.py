"""The engine's speed devices (compaction, unrolling, column layout, hashed random
streams) must not change any result: each agent's results depend only on its key and
hyperparameters."""
from __future__ import annotations

import chex
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from absl.testing import parameterized

from vdbejax import engine
from vdbejax.engine import packing, sequential, work_items
from vdbejax.envs.table_cleaning import make_mdp
from vdbejax.methods.agents import AgentOptions, Setting, make_agent, stack_agents
from vdbejax.methods.learners import q_learning_target, sarsa_target
from vdbejax.methods.selection import select_action

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
def test_select_action_on_a_column_batch_equals_one_row_at_a_time(tie_break):
    """The engine's [A, B] layout runs the same select_action as a single Q row."""
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
    got = jax.jit(select_action, static_argnums=4)(
        jnp.asarray(q.T), p, tau, jnp.asarray(u.T), tie_break
    )
    np.testing.assert_array_equal(np.asarray(got), np.asarray(expected))


@pytest.mark.parametrize("learner", ["qlearning", "sarsa"])
def test_learner_targets_on_a_column_batch_equal_one_row_at_a_time(learner):
    rng = np.random.default_rng(1)
    n = 512
    q_next = rng.normal(size=(n, 7)).astype(np.float32)
    reward = rng.normal(size=n).astype(np.float32)
    discount = rng.choice([0.0, 0.9], size=n).astype(np.float32)
    action = rng.integers(0, 7, size=n).astype(np.int32)
    if learner == "qlearning":
        expected = jax.vmap(q_learning_target)(reward, discount, q_next)
        got = q_learning_target(reward, discount, jnp.asarray(q_next.T))
    else:
        expected = jax.vmap(sarsa_target)(reward, discount, q_next, action)
        got = sarsa_target(reward, discount, jnp.asarray(q_next.T), action)
    np.testing.assert_array_equal(np.asarray(got), np.asarray(expected))


def test_compaction_chunking_and_batch_position_do_not_change_results(mdp):
    params, keys = _grid(2)
    base = engine.run_agents(mdp, params, keys, 12,
                             engine.EngineOptions(chunk_episodes=12, compact=False,
                                                  strategy="lockstep"))
    grouped = engine.run_agents(mdp, params, keys, 12,
                                engine.EngineOptions(compact=False, max_batch=5,
                                                     strategy="lockstep"))
    np.testing.assert_array_equal(base.returns, grouped.returns)
    compacted = engine.run_agents(mdp, params, keys, 12,
                                  engine.EngineOptions(chunk_episodes=5, block_iterations=8,
                                                       min_batch=2, max_batch=3,
                                                       strategy="lockstep"))
    np.testing.assert_array_equal(base.returns, compacted.returns)
    np.testing.assert_array_equal(base.lengths, compacted.lengths)
    np.testing.assert_array_equal(base.final_state.q, compacted.final_state.q)
    # One agent alone (the slowest kind: SARSA + VDBE σ = 0.001) equals itself in the batch.
    alone = engine.run_agents(mdp, jax.tree.map(lambda x: x[1:2], params), keys[1:2], 12,
                              engine.EngineOptions(chunk_episodes=5, strategy="lockstep"))
    np.testing.assert_array_equal(alone.returns[0], base.returns[1])
    np.testing.assert_array_equal(alone.lengths[0], base.lengths[1])


def test_lockstep_groups_on_threads_give_the_same_bits(mdp):
    """Groups run on several threads, or one after another, or as one batch: same bits."""
    params, keys = _grid(3)
    # 3 seeds of 30 episodes: the lockstep programs of the strategy tests below serve them.
    one = engine.run_agents(mdp, params, keys, 30,
                            engine.EngineOptions(max_batch=64, threads=1, strategy="lockstep"))
    threaded = engine.run_agents(mdp, params, keys, 30,
                                 engine.EngineOptions(max_batch=2, threads=3, strategy="lockstep"))
    default = engine.run_agents(mdp, params, keys, 30, engine.EngineOptions(strategy="lockstep"))
    # Blocks of a known trip count (the accelerators' default) overshoot harmlessly.
    fixed = engine.run_agents(mdp, params, keys, 30,
                              engine.EngineOptions(strategy="lockstep", block_iterations=7,
                                                   fixed_blocks=True))
    _assert_same_run(one, threaded)
    _assert_same_run(one, default)
    _assert_same_run(one, fixed)
    assert fixed.iterations % 7 == 0 and fixed.iterations >= one.iterations


def _assert_same_run(a: engine.RunResult, b: engine.RunResult) -> None:
    np.testing.assert_array_equal(a.lengths, b.lengths)
    for leaf_a, leaf_b in zip(
        jax.tree.leaves((a.returns, a.final_state)), jax.tree.leaves((b.returns, b.final_state))
    ):
        np.testing.assert_array_equal(leaf_a, leaf_b)


@pytest.mark.parametrize("tie_break", ["random", "first"])
def test_sequential_strategy_equals_lockstep(mdp, tie_break):
    """The CPU engine (one native loop per agent and kind, agents over threads) and the
    vectorised lockstep engine run the same step function and give bit-identical results
    (products are rounded on their own, see vdbejax._numerics), whatever the threads,
    chunks or grouping."""
    options = AgentOptions(tie_break=tie_break)
    params = engine.broadcast_agents(
        stack_agents([make_agent(s, options) for s in SETTINGS]), 3
    )
    keys = np.tile(engine.agent_keys(5, 3), (len(SETTINGS), 1))
    lockstep = engine.run_agents(mdp, params, keys, 30,
                                 engine.EngineOptions(chunk_episodes=30, strategy="lockstep"))
    first = None
    # Chunks of 30, 7 and 20 episodes: buffers of 32, 8 and 32 (the first run's program).
    for threads, chunk in [(1, 30), (2, 7), (3, 20)]:
        sequential = engine.run_agents(mdp, params, keys, 30,
                                       engine.EngineOptions(chunk_episodes=chunk,
                                                            strategy="sequential", threads=threads))
        _assert_same_run(sequential, lockstep)
        assert (sequential.strategy, lockstep.strategy) == ("sequential", "lockstep")
        first = first or sequential
        _assert_same_run(sequential, first)
        assert sequential.iterations == int(sequential.lengths.sum()) + np.count_nonzero(
            sequential.lengths == mdp.max_steps
        ) + len(keys)  # one reset iteration per agent start and per truncation
    assert engine.native_step_loops() is True


def test_sequential_strategy_on_a_stochastic_mdp_equals_lockstep():
    """Stochastic transitions (several outcomes) go through the same two strategies."""
    from vdbejax.envs.tabular import make_tabular_mdp

    rng = np.random.default_rng(3)
    num_states, num_actions, outcomes = 6, 3, 2
    next_state = rng.integers(0, num_states, size=(num_states, num_actions, outcomes))
    probability = np.full((num_states, num_actions, outcomes), 0.5)
    reward = rng.normal(size=(num_states, num_actions, outcomes)).astype(np.float32)
    terminal = np.zeros((num_states, num_actions, outcomes), bool)
    terminal[num_states - 1] = True
    start = np.zeros(num_states)
    start[:2] = 0.5
    stochastic = make_tabular_mdp(next_state, reward, terminal, start, probability=probability,
                                  max_steps=15)
    params, keys = _grid(2)
    lockstep = engine.run_agents(stochastic, params, keys, 20,
                                 engine.EngineOptions(strategy="lockstep"))
    sequential = engine.run_agents(stochastic, params, keys, 20,
                                   engine.EngineOptions(strategy="sequential", threads=2,
                                                        chunk_episodes=6))
    _assert_same_run(sequential, lockstep)


@pytest.mark.parametrize("lanes, seeds", [(1, 3), (2, 3), (4, 3), (4, 8)])
def test_loop_width_changes_nothing(mdp, monkeypatch, lanes, seeds):
    """Agents side by side in a loop (work_items.LANES), each lane taking the next agent
    when its own has finished, give the bits of lockstep, for any number of agents per
    work item: padding rows (3 seeds: items of 3 agents in 4 rows), idle lanes that point
    at a real agent still running in another lane (8 seeds: items of 8 agents)."""
    monkeypatch.setattr(work_items, "LANES", lanes)
    monkeypatch.setattr(sequential, "LANES", lanes)
    params, keys = _grid(seeds)
    # 30 episodes, batches of 2 lanes: the lockstep programs of the groups test above.
    lockstep = engine.run_agents(mdp, params, keys, 30,
                                 engine.EngineOptions(max_batch=2, threads=3, strategy="lockstep"))
    for threads in (1, 3):
        run = engine.run_agents(mdp, params, keys, 30,
                                engine.EngineOptions(chunk_episodes=5, threads=threads,
                                                     strategy="sequential"))
        _assert_same_run(run, lockstep)
        assert run.iterations <= run.lane_iterations


@pytest.mark.parametrize("lanes", [1, 2, 4])
def test_masked_lanes_write_nothing_even_where_another_lane_writes(lanes):
    """An idle lane of the sequential strategy points at another agent's rows: its write
    must leave what a real lane wrote there in the same iteration. (Wide lockstep batches
    never alias: every lane is its own agent.)"""
    from vdbejax.engine.lanes import put_learned

    rng = np.random.default_rng(lanes)
    buffer = jnp.asarray(rng.normal(size=3 * lanes + 2).astype(np.float32))
    index = np.arange(lanes, dtype=np.int32) * 3
    mask = rng.random(lanes) < 0.5
    mask[0] = True
    index[1:][~mask[1:]] = index[0]  # every masked lane aliases lane 0's cell
    new = jnp.asarray(rng.normal(size=lanes).astype(np.float32))
    old = buffer[index]
    expected = np.asarray(buffer).copy()
    expected[index[mask]] = np.asarray(new)[mask]
    got = jax.jit(put_learned)(buffer, jnp.asarray(index), new, old, jnp.asarray(mask))
    np.testing.assert_array_equal(np.asarray(got), expected)
    rows = jnp.asarray(rng.normal(size=(lanes, 2)).astype(np.float32))
    row_old = jnp.stack([buffer[i:i + 2] for i in index])
    expected_rows = np.asarray(buffer).copy()
    for k in np.flatnonzero(mask):
        expected_rows[index[k]:index[k] + 2] = np.asarray(rows[k])
    got_rows = put_learned(buffer, jnp.asarray(index), rows, row_old, jnp.asarray(mask),
                           rows=True)
    np.testing.assert_array_equal(np.asarray(got_rows), expected_rows)


def test_a_self_loop_that_traps_the_agent_is_learned_in_both_strategies():
    """One state whose action 0 loops onto itself: an agent that takes it first is trapped
    (Q(0,0) climbs above Q(0,1), and τ = 1e-4 never tries the goal again). The sequential
    engine once lost that episode's updates to Q(0,0) and left the trap (issue 13)."""
    from vdbejax.envs.tabular import make_tabular_mdp
    from vdbejax.runs import grid_agents

    trap = make_tabular_mdp(np.array([[0, 0]]), np.array([[-0.01, 1.0]], np.float32),
                            np.array([[False, True]]), np.array([1.0]), max_steps=60)
    # 8 agents in one work item of 4 lanes: lanes that run out of agents idle pointing at
    # the last agent's rows (one state: every cell is updated often), and must not write.
    params, keys = grid_agents([Setting("qlearning", "softmax", 1e-4)], 8,
                               options=AgentOptions(q_init=-0.5))
    lockstep = engine.run_agents(trap, params, keys, 5, engine.EngineOptions(strategy="lockstep"))
    sequential_run = engine.run_agents(trap, params, keys, 5,
                                       engine.EngineOptions(strategy="sequential", threads=1))
    _assert_same_run(sequential_run, lockstep)
    trapped = (lockstep.lengths == 60).all(axis=1)
    assert trapped.any() and (lockstep.lengths[~trapped] == 1).all()
    q = lockstep.final_state.q.reshape(8, 2)
    assert (q[trapped, 0] > q[trapped, 1]).all()


def test_many_start_states_in_both_strategies():
    """More start states than sample_categorical unrolls (its cumsum path), shared by a
    batch of agents: both strategies run and agree."""
    from vdbejax.envs.tabular import make_tabular_mdp

    rng = np.random.default_rng(4)
    num_states, num_actions = 60, 4
    next_state = rng.integers(0, num_states, size=(num_states, num_actions))
    reward = np.full((num_states, num_actions), -0.01, np.float32)
    terminal = np.zeros((num_states, num_actions), bool)
    terminal[num_states - 1] = True
    start = np.zeros(num_states)
    start[:40] = rng.random(40)
    many = make_tabular_mdp(next_state, reward, terminal, start / start.sum(), max_steps=20)
    params, keys = _grid(2)
    lockstep = engine.run_agents(many, params, keys, 15, engine.EngineOptions(strategy="lockstep"))
    sequential = engine.run_agents(many, params, keys, 15,
                                   engine.EngineOptions(strategy="sequential"))
    _assert_same_run(sequential, lockstep)
    assert lockstep.lengths.min() >= 1


def test_bad_strategy_or_threads_is_one_line_error(mdp):
    params, keys = _grid(1)
    with pytest.raises(ValueError, match="strategy"):
        engine.run_agents(mdp, params, keys, 2, engine.EngineOptions(strategy="fastest"))
    with pytest.raises(ValueError, match="threads"):
        engine.run_agents(mdp, params, keys, 2, engine.EngineOptions(threads=0))


def test_hashed_stream_depends_only_on_key_and_counter():
    keys = jnp.asarray(engine.agent_keys(3, 5))
    counters = jnp.arange(5, dtype=jnp.uint32) * 7
    batch = engine.uniforms(keys, counters, 5)
    for i in range(5):
        single = engine.uniforms(keys[i], counters[i], 5)
        for draw_batch, draw_single in zip(batch, single):
            assert float(draw_batch[i]) == float(draw_single)
            assert 0.0 <= float(draw_single) < 1.0


def test_rounded_products_never_fuse_into_an_fma():
    """c + rounded(a·b) rounds twice, as numpy does, in scalar and in vectorised code."""
    from vdbejax._numerics import rounded

    rng = np.random.default_rng(7)
    a, b, c = (rng.normal(size=4099).astype(np.float32) for _ in range(3))
    expected = (a * b) + c  # numpy: two float32 roundings
    fused = (a.astype(np.float64) * b + c).astype(np.float32)
    assert (fused != expected).any()  # the inputs do tell the two apart
    got = jax.jit(lambda a, b, c: c + rounded(a * b, a))(a, b, c)
    np.testing.assert_array_equal(np.asarray(got), expected)
    scalar = jax.jit(lambda a, b, c: c + rounded(a * b, a))
    for i in range(0, 4099, 409):
        assert float(scalar(a[i], b[i], c[i])) == float(expected[i])


def test_sequential_work_items_are_equal_sized_cost_balanced_and_cover_every_agent():
    rng = np.random.default_rng(0)
    kinds = np.repeat([0, 1, 3], [40, 37, 23])
    costs = rng.pareto(1.5, kinds.size) * 100 + 10  # a few agents far slower than most
    groups = work_items.sequential_groups(kinds, threads=2, costs=costs)
    everyone = np.sort(np.concatenate(groups))
    np.testing.assert_array_equal(everyone, np.arange(kinds.size))
    group_costs = [costs[group].sum() for group in groups]
    assert group_costs == sorted(group_costs, reverse=True)  # most costly first
    for kind in (0, 1, 3):
        mine = [group for group in groups if kinds[group[0]] == kind]
        assert all((kinds[group] == kind).all() for group in mine)
        sizes = [len(group) for group in mine]
        assert max(sizes) - min(sizes) <= 1
    # Without costs every agent counts the same: sizes still within one of each other.
    plain = work_items.sequential_groups(kinds, threads=2)
    assert sum(len(group) for group in plain) == kinds.size


@pytest.mark.parametrize("host_init_max_bytes", [0, 1 << 40])
def test_agents_kept_in_their_work_items_equal_lockstep_and_checkpoint_the_same(
    mdp, monkeypatch, host_init_max_bytes
):
    """Agents stay in their first work item for the whole run (their tables are updated
    in place, never copied between chunks); large ones are created there, small ones on
    the host first. Either way the results, and the states handed to ``on_chunk``, equal
    lockstep's."""
    monkeypatch.setattr(work_items, "HOST_INIT_MAX_BYTES", host_init_max_bytes)
    params = engine.broadcast_agents(stack_agents([make_agent(s) for s in SETTINGS]), 3)
    keys = np.tile(engine.agent_keys(9, 3), (len(SETTINGS), 1))
    seen = {"sequential": [], "lockstep": []}

    def recorder(name):
        def record(done, agents, returns, lengths, cut):
            seen[name].append((done, jax.tree.map(np.array, agents), returns.copy()))
        return record

    by_items = engine.run_agents(mdp, params, keys, 25,
                                 engine.EngineOptions(chunk_episodes=6, threads=2,
                                                      strategy="sequential"),
                                 engine.ChunkHooks(on_chunk=recorder("sequential")))
    lockstep = engine.run_agents(mdp, params, keys, 25,
                                 engine.EngineOptions(chunk_episodes=6, strategy="lockstep"),
                                 engine.ChunkHooks(on_chunk=recorder("lockstep")))
    _assert_same_run(by_items, lockstep)
    assert [done for done, *_ in seen["sequential"]] == [6, 12, 18, 24, 25]
    for (done_a, agents_a, returns_a), (done_b, agents_b, returns_b) in zip(
        seen["sequential"], seen["lockstep"]
    ):
        assert done_a == done_b
        np.testing.assert_array_equal(returns_a, returns_b)
        for leaf_a, leaf_b in zip(jax.tree.leaves(agents_a), jax.tree.leaves(agents_b)):
            np.testing.assert_array_equal(leaf_a, leaf_b)


@pytest.mark.parametrize("strategy", ["sequential", "lockstep"])
def test_without_the_final_state_results_and_nonfinite_flags_are_the_same(mdp, strategy):
    params = engine.broadcast_agents(stack_agents([make_agent(s) for s in SETTINGS]), 2)
    keys = np.tile(engine.agent_keys(4, 2), (len(SETTINGS), 1))
    full = engine.run_agents(mdp, params, keys, 12,
                             engine.EngineOptions(chunk_episodes=5, strategy=strategy))
    light = engine.run_agents(mdp, params, keys, 12,
                              engine.EngineOptions(chunk_episodes=5, strategy=strategy,
                                                   keep_final_state=False))
    assert light.final_state is None and full.final_state is not None
    np.testing.assert_array_equal(light.returns, full.returns)
    np.testing.assert_array_equal(light.nonfinite, full.nonfinite)


@pytest.mark.parametrize("chunk_episodes", [1, 4, 25])
def test_chunks_that_run_ahead_change_nothing_and_progress_stays_in_order(mdp, chunk_episodes):
    """Without checkpoints an item's next chunk starts while the driver stores the last
    one (no barrier); with them every agent waits at the chunk's end."""
    params, keys = _grid(3)
    calls = []
    ahead = engine.run_agents(mdp, params, keys, 25,
                              engine.EngineOptions(chunk_episodes=chunk_episodes, threads=2,
                                                   strategy="sequential"),
                              engine.ChunkHooks(
                                  progress=lambda done, total, _: calls.append((done, total))))
    barrier = engine.run_agents(mdp, params, keys, 25,
                                engine.EngineOptions(chunk_episodes=chunk_episodes, threads=2,
                                                     strategy="sequential"),
                                engine.ChunkHooks(on_chunk=lambda *_: None))
    lockstep = engine.run_agents(mdp, params, keys, 25, engine.EngineOptions(strategy="lockstep"))
    _assert_same_run(ahead, lockstep)
    _assert_same_run(barrier, lockstep)
    agents = len(keys)
    ends = list(range(chunk_episodes, 25, chunk_episodes)) + [25]
    assert calls == [(0, 25 * agents)] + [(end * agents, 25 * agents) for end in ends]


def test_an_error_between_chunks_stops_the_workers_and_propagates(mdp):
    import threading

    params, keys = _grid(3)
    before = threading.active_count()

    def progress(done, total, elapsed):
        if done >= 2 * len(keys):
            raise RuntimeError("stop here")

    with pytest.raises(RuntimeError, match="stop here"):
        engine.run_agents(mdp, params, keys, 25,
                          engine.EngineOptions(chunk_episodes=2, threads=2, strategy="sequential"),
                          engine.ChunkHooks(progress=progress))
    assert threading.active_count() == before


class PackedRowsTest(parameterized.TestCase):
    """The sequential loops move an agent's scalars as one packed row of 32-bit words:
    packing and unpacking give back every value bit for bit, with and without jit."""

    @chex.variants(with_jit=True, without_jit=True)
    def test_pack_then_unpack_is_exact(self):
        rows = 5
        tree = {
            "flag": np.array([True, False, True, True, False]),
            "small": np.array([-128, -1, 0, 1, 127], np.int8),
            "half": np.array([1.5, -0.0, np.inf, 6.1e-5, 65504.0], np.float16),
            "brain": np.array([1.5, -2.0, 3.0e38, -1e-38, 0.0], jnp.bfloat16),
            "count": np.array([-(2**31), -1, 0, 7, 2**31 - 1], np.int32),
            "counter": np.array([0, 1, 2**31, 2**32 - 1, 12345], np.uint32),
            "value": np.array([-0.0, np.nan, np.inf, -1e-45, 3.25], np.float32),
            "key": np.arange(rows * 2, dtype=np.uint32).reshape(rows, 2) * np.uint32(2654435761),
            # several leaves of one dtype, of one, two and three axes, side by side
            "rate": np.array([0.5, -1.0, np.nan, 2.0**-149, -np.inf], np.float32),
            "grid": np.arange(rows * 6, dtype=np.float32).reshape(rows, 2, 3) - 7.5,
            "steps": np.array([3, -4, 5, -6, 2**30], np.int32),
            "flags": np.array([[True, False], [False, False], [True, True], [False, True],
                               [True, False]]),
            "none": np.zeros((rows, 0), np.int32),
        }
        packed = self.variant(packing.pack)(tree)
        assert packed.dtype == jnp.uint32 and packed.shape == (rows, 19)
        layout = {name: jax.ShapeDtypeStruct(v.shape, v.dtype) for name, v in tree.items()}
        back = self.variant(lambda words: packing.unpack(words, layout))(packed)
        for name, value in tree.items():
            assert back[name].dtype == value.dtype and back[name].shape == value.shape
            np.testing.assert_array_equal(np.asarray(back[name]).view(np.uint8),
                                          value.view(np.uint8))

    def test_float64_rows_take_two_words(self):
        with jax.enable_x64(True):
            value = np.array([np.pi, -2.0**-1074, np.nan], np.float64)
            packed = packing.pack({"v": value})
            assert packed.shape == (3, 2)
            back = packing.unpack(packed, {"v": jax.ShapeDtypeStruct((3,), np.float64)})["v"]
            np.testing.assert_array_equal(np.asarray(back).view(np.uint64), value.view(np.uint64))

