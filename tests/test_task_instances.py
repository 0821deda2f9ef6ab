"""A task instance per agent (issue 48, point 2): every agent of a run meets its own
instance in the same vectorised run, bit for bit as if it ran alone on it."""
from __future__ import annotations

import numpy as np
import pytest

from vdbejax import engine
from vdbejax.envs.suite.bandits import arm_means, make_bandit
from vdbejax.envs.tabular import make_tabular_mdp
from vdbejax.envs.task_instances import stack_instances
from vdbejax.methods.agents import Setting, make_agent, stack_agents

SETTINGS = [Setting("qlearning", "egreedy", 0.1), Setting("sarsa", "vdbe", 0.001),
            Setting("qlearning", "vdbe_softmax", 1.0)]
SEEDS = 3
EPISODES = 12


def bandit_instance(seed: int):
    return make_bandit(arm_means("testbed", 4, seed), "gaussian", pulls=3, name="testbed:4")


def random_mdp(seed: int):
    """4 states, 3 actions, 2 outcomes per pair, 1 to 3 start states, noisy rewards."""
    rng = np.random.default_rng(seed)
    shape = (4, 3, 2)
    probability = rng.random(shape) + 0.1
    start = np.zeros(4)
    start[rng.choice(4, 1 + seed % 3, replace=False)] = 1.0
    return make_tabular_mdp(
        rng.integers(0, 4, shape), rng.normal(size=shape), rng.random(shape) < 0.1,
        start / start.sum(), probability / probability.sum(-1, keepdims=True),
        max_steps=9, name="random", reward_noise="gaussian", reward_std=0.5)


def grid():
    params = engine.broadcast_agents(stack_agents([make_agent(s) for s in SETTINGS]), SEEDS)
    keys = np.tile(engine.agent_keys(0, SEEDS), (len(SETTINGS), 1))
    return params, keys


def one(params, agent: int):
    return engine.broadcast_agents(stack_agents([make_agent(SETTINGS[agent // SEEDS])]), 1)


@pytest.mark.parametrize("family", [bandit_instance, random_mdp], ids=["testbed", "random_mdp"])
def test_every_agent_gets_the_bits_of_its_instance_alone(family):
    params, keys = grid()
    mdps = [family(100 + i) for i in range(len(keys))]
    instances = stack_instances(mdps)
    runs = [engine.run_agents(instances, params, keys, EPISODES, engine.EngineOptions(**options))
            for options in ({"strategy": "sequential"},
                            # a chunk ends at 9; buffers of 16, the first run's program
                            {"strategy": "sequential", "chunk_episodes": 9},
                            {"strategy": "lockstep"},
                            {"strategy": "lockstep", "max_batch": 2, "min_batch": 1,
                             "chunk_episodes": 7},
                            {"strategy": "lockstep", "compact": False})]
    for run in runs[1:]:
        assert np.array_equal(run.returns, runs[0].returns)
        assert np.array_equal(run.lengths, runs[0].lengths)
    for agent in (0, 4, len(keys) - 1):
        for strategy in ("sequential", "lockstep"):
            alone = engine.run_agents(mdps[agent], one(params, agent), keys[agent:agent + 1],
                                      EPISODES, engine.EngineOptions(strategy=strategy))
            assert np.array_equal(alone.returns[0], runs[0].returns[agent])
            assert np.array_equal(alone.lengths[0], runs[0].lengths[agent])
    # the instances differ, and so do the agents' results on them
    shared = engine.run_agents(mdps[0], params, keys, EPISODES,
                               engine.EngineOptions(strategy="sequential"))
    assert not np.array_equal(shared.returns, runs[0].returns)
    assert np.array_equal(shared.returns[0], runs[0].returns[0])


def test_an_agent_with_its_instance_is_itself_in_a_batch_of_mixed_instances():
    params, keys = grid()
    mine = bandit_instance(7)
    mixed = [bandit_instance(200 + i) for i in range(len(keys))]
    mixed[5] = mine
    batch = engine.run_agents(stack_instances(mixed), params, keys, EPISODES,
                              engine.EngineOptions(strategy="lockstep", max_batch=4, min_batch=1))
    alone = engine.run_agents(stack_instances([mine]), one(params, 5), keys[5:6], EPISODES,
                              engine.EngineOptions(strategy="sequential"))
    assert np.array_equal(alone.returns[0], batch.returns[5])


def test_the_optimal_actions_are_counted_against_each_instance():
    params, keys = grid()
    mdps = [bandit_instance(300 + i) for i in range(len(keys))]
    masks = np.stack([np.asarray(m.reward)[:, :, 0] == np.asarray(m.reward)[:, :, 0].max()
                      for m in mdps])
    records = [engine.run_agents(stack_instances(mdps), params, keys, EPISODES,
                                 engine.EngineOptions(strategy=strategy),
                                 optimal_action=masks).optimal
               for strategy in ("sequential", "lockstep")]
    assert np.array_equal(records[0], records[1]) and records[0].sum() > 0
    agent = 7
    alone = engine.run_agents(mdps[agent], one(params, agent), keys[agent:agent + 1], EPISODES,
                              optimal_action=masks[agent])
    assert np.array_equal(alone.optimal[0], records[0][agent])


def test_bad_instances_are_one_line():
    params, keys = grid()
    with pytest.raises(ValueError, match=r"^instances holds 2 instances for 9 agents: must"
                                         r" hold one per agent$"):
        engine.run_agents(stack_instances([bandit_instance(0), bandit_instance(1)]), params,
                          keys, 2)
    with pytest.raises(ValueError, match=r"^mdps\[1\] has \[S, A, K\] = \[1, 5, 1\] and"
                                         r" max_steps 3: every instance must have"):
        stack_instances([bandit_instance(0), make_bandit(np.zeros(5), "gaussian", pulls=3)])
    with pytest.raises(ValueError, match=r"^mdps\[1\] differs from mdps\[0\] in having reward"):
        stack_instances([bandit_instance(0), make_tabular_mdp(np.zeros((1, 4), np.int32),
                                                      np.zeros((1, 4)), np.zeros((1, 4)),
                                                      [1.0], max_steps=3)])
    with pytest.raises(ValueError, match=r"^mdps=list of 0 is invalid"):
        stack_instances([])
    with pytest.raises(ValueError, match=r"^optimal_action has shape \(1, 4\) and dtype bool"):
        engine.run_agents(stack_instances([bandit_instance(i) for i in range(9)]), params, keys, 2,
                          optimal_action=np.ones((1, 4), bool))


# A run of a task family (vdbejax.runs.task_family_run): an instance per agent from its seed.

RUN_SETTINGS = [Setting("qlearning", "egreedy", 0.1), Setting("qlearning", "vdbe", 1.0)]


def test_a_family_run_gives_each_agent_the_instance_of_its_seed_index():
    from vdbejax.envs.suite import make_suite_family
    from vdbejax.runs import run_grid

    family = make_suite_family("testbed:5")
    result = run_grid(family, RUN_SETTINGS, num_seeds=3, num_episodes=20, seed=4)
    keys = engine.agent_keys(4, 3)
    for c, setting in enumerate(RUN_SETTINGS):
        for i in range(3):
            alone = engine.run_agents(family.generate((4, i)), engine.broadcast_agents(
                stack_agents([make_agent(setting)]), 1), keys[i:i + 1], 20)
            assert np.array_equal(alone.returns[0], result.returns[c, i])
    meta = result.meta
    assert meta["instances"] == "per-agent" and len(meta["instance_best_returns"]) == 3
    assert meta["best_return"] == pytest.approx(np.mean(meta["instance_best_returns"]))
    means = [np.asarray(family.generate((4, i)).reward).max() for i in range(3)]
    assert meta["instance_best_returns"] == pytest.approx(means)
    # another root seed draws other instances: another fingerprint, other returns
    other = run_grid(family, RUN_SETTINGS, num_seeds=3, num_episodes=20, seed=5)
    assert other.meta["fingerprint"] != meta["fingerprint"]
    assert other.meta["instance_best_returns"] != meta["instance_best_returns"]


def test_a_family_run_resumes_to_the_same_bits(tmp_path):
    from small_grid import interrupt_then_resume

    from vdbejax.envs.suite import make_suite_family
    from vdbejax.runs import RunOptions, run_grid

    family = make_suite_family("bernoulli_bandit:4")
    grid = {"num_seeds": 3, "num_episodes": 24, "seed": 1}
    whole = run_grid(family, RUN_SETTINGS, record_optimal=True, **grid)
    resumed = interrupt_then_resume(
        family, RUN_SETTINGS, RunOptions(checkpoint=tmp_path / "run.npz", chunk_episodes=8,
                                         record_optimal=True), 60, **grid)
    assert np.array_equal(resumed.returns, whole.returns)
    assert np.array_equal(resumed.optimal_actions, whole.optimal_actions, equal_nan=True)
    assert resumed.meta["fingerprint"] == whole.meta["fingerprint"]


def test_what_a_family_run_refuses_is_one_line():
    from vdbejax.envs.suite import make_suite_family
    from vdbejax.runs import prepare_grid
    from vdbejax.runs.stop import UntilSolved

    family = make_suite_family("testbed:3")
    with pytest.raises(ValueError, match=r"^evaluate_every=5 is invalid with a task family"
                                         r" \(testbed:3\)"):
        prepare_grid(family, RUN_SETTINGS, num_seeds=2, num_episodes=10,
                     run=run_options(evaluate_every=5))
    with pytest.raises(ValueError, match=r"^stop=UntilSolved is invalid with a task family"):
        prepare_grid(family, RUN_SETTINGS, num_seeds=2, num_episodes=10,
                     run=run_options(stop=UntilSolved()))
    with pytest.raises(ValueError, match=r"^task='chain:5' has no generator of instances"):
        make_suite_family("chain:5")


def run_options(**options):
    from vdbejax.runs import RunOptions

    return RunOptions(**options)


def test_a_learner_is_told_the_facts_of_every_instance_whatever_the_batch():
    # UCBVI under rlberry's convention takes its reward range from the task's facts: an
    # agent's bits must not depend on which instances share its batch.
    from vdbejax.engine.agent_state import task_facts

    ucbvi = Setting("ucbvi", "greedy", None, hyperparameters={"convention": "rlberry"})
    params = engine.broadcast_agents(stack_agents([make_agent(ucbvi)]), 4)
    keys = engine.agent_keys(2, 4)
    instances = stack_instances([bandit_instance(400 + i) for i in range(4)])
    facts = task_facts(instances)
    assert facts.reward_min == min(float(np.asarray(instances.instance(i).reward).min())
                                   for i in range(4))
    whole = engine.run_agents(instances, params, keys, 8)
    part = engine.run_agents(instances.take([2, 3]), engine.broadcast_agents(
        stack_agents([make_agent(ucbvi)]), 2), keys[2:], 8,
        engine.EngineOptions(strategy="lockstep"))
    assert np.array_equal(part.returns, whole.returns[2:])


# The results of such a run: every agent scored against its own instance.

def test_summaries_score_every_agent_against_its_own_instance():
    from vdbejax.envs.suite import make_suite_family
    from vdbejax.results.analysis import summarize, task_scale
    from vdbejax.results.replicates import replicate
    from vdbejax.results.solving import episodes_to_converge, summarize_solving
    from vdbejax.runs import run_grid

    family = make_suite_family("testbed:4")
    result = run_grid(family, RUN_SETTINGS, num_seeds=4, num_episodes=60, seed=2)
    best, baseline = task_scale(result)
    assert np.shape(best) == (4, 1) and np.shape(baseline) == (4, 1)
    assert best[:, 0].tolist() == result.meta["instance_best_returns"]
    rows = summarize(result, window=5)
    for c, row in enumerate(rows):
        own = episodes_to_converge(result.returns[c], best, baseline, window=5)
        for i in range(4):  # each agent against its instance's references
            alone = episodes_to_converge(result.returns[c, i], best[i, 0], baseline[i, 0],
                                         window=5)
            assert (own.episodes[i], own.solved[i]) == (alone.episodes, alone.solved)
        summary = summarize_solving(*own)
        assert (row.convergence_episode, row.agents_converged) == (summary.median,
                                                                   summary.solved)
    half = replicate(marked_as_replicates(result, 2), 1)
    assert half.meta["instance_best_returns"] == result.meta["instance_best_returns"][2:]
    assert half.meta["best_return"] == pytest.approx(np.mean(half.meta["instance_best_returns"]))


def marked_as_replicates(result, count):
    result.meta.update(replicates=count, agents_per_replicate=result.num_seeds // count)
    return result


def test_a_normalised_score_per_run_and_its_bad_scale():
    from vdbejax.results.regret import normalised_returns, run_scores

    returns = np.array([[0.0, 1.0], [2.0, 4.0]])
    best, baseline = np.array([[1.0], [4.0]]), np.array([[0.0], [2.0]])
    assert normalised_returns(returns, best, baseline).tolist() == [[0.0, 1.0], [0.0, 1.0]]
    assert run_scores(returns, best, baseline).tolist() == [0.5, 0.5]
    assert normalised_returns(returns, 4.0, 0.0).tolist() == [[0.0, 0.25], [0.5, 1.0]]
    with pytest.raises(ValueError, match=r"^best and baseline at \[1, 0\] are invalid: each"
                                         r" run's best return must exceed its baseline's"):
        normalised_returns(returns, best, np.array([[0.0], [5.0]]))


def test_the_cli_runs_an_instance_per_agent(tmp_path):
    import json

    from vdbejax import cli

    out = tmp_path / "run"
    code = cli.main(["run", "--task", "testbed:5", "--instances", "per-agent", "--learners",
                     "sample_average", "--explorers", "egreedy", "--axis", "epsilon=0.1",
                     "--seeds", "3", "--episodes", "20", "--record-optimal", "--no-figures",
                     "--quiet", "--out", str(out)])
    assert code in (0, None)
    meta = json.loads((out / "meta.json").read_text())
    assert meta["instances"] == "per-agent" and len(meta["instance_best_returns"]) == 3
    again = tmp_path / "again"
    assert cli.main(["run", "--config", str(out), "--no-figures", "--quiet",
                     "--out", str(again)]) in (0, None)
    assert json.loads((again / "meta.json").read_text())["fingerprint"] == meta["fingerprint"]
    assert cli.main(["run", "--task", "chain:5", "--instances", "per-agent", "--learners",
                     "qlearning", "--explorers", "egreedy", "--seeds", "2", "--episodes", "2",
                     "--quiet", "--out", str(tmp_path / "bad")]) == 2


def test_a_random_mdp_family_runs_an_instance_per_agent():
    from vdbejax.envs.suite.garnet import garnet_family
    from vdbejax.results.analysis import summarize
    from vdbejax.runs import run_grid

    family = garnet_family(5, 3, 2, max_steps=6)
    one, two = family.generate((0, 0)), family.generate((0, 1))
    assert np.asarray(one.probability).sum(-1) == pytest.approx(1.0)
    assert not np.array_equal(np.asarray(one.next_state), np.asarray(two.next_state))
    result = run_grid(family, RUN_SETTINGS, num_seeds=3, num_episodes=15, seed=0,
                      record_optimal=True)
    keys = engine.agent_keys(0, 3)
    alone = engine.run_agents(two, engine.broadcast_agents(stack_agents(
        [make_agent(RUN_SETTINGS[1])]), 1), keys[1:2], 15)
    assert np.array_equal(alone.returns[0], result.returns[1, 1])
    assert len(summarize(result, window=5)) == 2
    with pytest.raises(ValueError, match=r"^branching=9 is invalid"):
        garnet_family(5, 3, 9)


# The memory of such a run: every agent carries its own instance's tables.

def memory_grids(budget=None):
    """A garnet family run and the same run with agent 0's instance shared (6 states, 3
    actions, 2 outcomes; 20 agents, record_optimal), prepared on one device."""
    from vdbejax.envs.suite.garnet import garnet_family
    from vdbejax.runs import prepare_grid

    family = garnet_family(6, 3, 2, max_steps=6)
    run = run_options(devices=1, chunk_episodes=20, record_optimal=True,
                      memory_budget_bytes=budget)
    grid = {"num_seeds": 10, "num_episodes": 20, "seed": 0}
    return (prepare_grid(family, RUN_SETTINGS, run=run, **grid),
            prepare_grid(family.generate((0, 0)), RUN_SETTINGS, run=run, **grid))


#: One garnet(6, 3, 2) instance's tables: next_state int32, probability and reward float32
#: (4 × 36 each), terminal bool (36), start_probability float32 (4 × 6), max_steps int32.
GARNET_ROW = 3 * 4 * 36 + 36 + 4 * 6 + 4
#: Its mask of optimal actions (bool, 6 × 3) and its start support (1 state: int32 + float32).
GARNET_MASK, GARNET_SUPPORT = 6 * 3, 8


def test_a_plan_counts_each_agents_own_instance():
    from vdbejax.methods.agents import table_layout
    from vdbejax.runs.batching import STATE_COPIES, bytes_per_agent, instance_bytes, mdp_bytes

    instanced, shared = memory_grids()
    assert GARNET_ROW == 496
    assert instance_bytes(instanced.instances) == GARNET_ROW + GARNET_SUPPORT
    own = instance_bytes(instanced.instances, record_optimal=True)
    assert own == GARNET_ROW + GARNET_SUPPORT + GARNET_MASK
    task = shared.mdp  # the one task every device holds: agent 0's instance in both runs
    assert mdp_bytes(task) == GARNET_ROW and mdp_bytes(instanced.mdp) == GARNET_ROW
    agent = bytes_per_agent(task, 20, table_layout(shared.params))
    # A budget of 12 shared-task agents: 12 of them fit, and fewer that carry their tables.
    budget = mdp_bytes(task) + 12 * agent
    instanced, shared = memory_grids(budget)
    assert shared.plan.batch_size == 12
    assert instanced.plan.batch_size == (12 * agent) // (agent + STATE_COPIES * own) < 12
    # and exactly as many as the instances' count says: a byte less, one agent less
    with_tables = agent + STATE_COPIES * own
    for fit in (7, 11):
        assert memory_grids(mdp_bytes(task) + fit * with_tables)[0].plan.batch_size == fit
        assert memory_grids(mdp_bytes(task) + fit * with_tables - 1)[0].plan.batch_size == fit - 1


def test_the_estimate_and_the_size_check_count_the_instances(monkeypatch):
    from vdbejax.runs import batching
    from vdbejax.runs.estimate import estimate_prepared

    instanced, shared = memory_grids()
    tasks = batching.HOST_INSTANCE_COPIES * 20 * (GARNET_ROW + GARNET_MASK)
    assert batching.instances_host_bytes(shared.mdp, 20, record_optimal=True) == tasks
    assert batching.instances_host_bytes(shared.mdp, 20) == tasks * GARNET_ROW // (
        GARNET_ROW + GARNET_MASK)
    more, less = estimate_prepared(instanced), estimate_prepared(shared)
    assert (more.task_bytes, less.task_bytes) == (tasks, 0)
    # the agents' states carry each agent's instance rows too (counted on their own)
    assert more.memory_bytes - less.memory_bytes == tasks + more.agents_bytes - less.agents_bytes
    assert "the task instances ≈ 40.2 KiB" in more.describe()
    assert "task instances" not in less.describe()
    # The machine's check, before the instances are stacked: exactly what they need fits.
    needed = batching.result_bytes(20, 20) + batching.settings_bytes(2) + tasks
    monkeypatch.setattr(batching, "_host_available_bytes", lambda: needed)
    memory_grids()
    monkeypatch.setattr(batching, "_host_available_bytes", lambda: needed - 1)
    with pytest.raises(ValueError, match=r"^the run is too large for this machine: 2 settings"
                                         r" \(20 agents\) × 20 episodes need ≈ .* their task"
                                         r" instances ≈ 40\.2 KiB\), but"):
        memory_grids()
    assert batching.check_run_size(20, 20, num_settings=2) < needed - 1  # shared: it fits
