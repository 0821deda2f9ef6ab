"""Bandits as tasks (gaussian_bandit, bernoulli_bandit, testbed) and the sample-average
learner."""
import jax.numpy as jnp
import numpy as np
import pytest

import vdbejax
from vdbejax import engine
from vdbejax.envs import solvers
from vdbejax.envs.reward_noise import BERNOULLI, GAUSSIAN
from vdbejax.envs.suite import NAMES, make_suite_task, task_info
from vdbejax.envs.suite.bandits import arm_means, make_bandit, optimal_arms
from vdbejax.methods.agents import Setting, make_agent, stack_agents
from vdbejax.methods.contract import Transition
from vdbejax.methods.learners import make_learner


@pytest.mark.parametrize("family, model", [("gaussian_bandit", GAUSSIAN),
                                           ("bernoulli_bandit", BERNOULLI),
                                           ("testbed", GAUSSIAN)])
def test_a_bandit_is_a_one_state_task_of_one_pull_per_episode(family, model):
    assert f"{family}:N" in NAMES
    mdp = make_suite_task(f"{family}:7")
    assert (mdp.num_states, mdp.num_actions, mdp.num_outcomes) == (1, 7, 1)
    assert mdp.name == f"{family}:7" and int(mdp.max_steps) == 1
    assert np.all(np.asarray(mdp.terminal)) and np.all(np.asarray(mdp.next_state) == 0)
    np.testing.assert_array_equal(mdp.reward_noise.model, np.full((1, 7, 1), model))
    np.testing.assert_array_equal(mdp.reward_noise.std,
                                  np.full((1, 7, 1), 1.0 if model == GAUSSIAN else 0.0))
    means = np.asarray(mdp.reward)[0, :, 0]
    np.testing.assert_array_equal(means, arm_means(family, 7))  # one instance per name
    if family != "testbed":
        assert means.min() >= 0 and means.max() < 1
    assert solvers.best_return(mdp) == pytest.approx(float(means.max()))
    assert optimal_arms(mdp).sum() == 1 and means[optimal_arms(mdp)][0] == means.max()
    info = task_info(f"{family}:7")
    assert info.horizon == 1 and "7 arms" in info.title
    assert task_info(family).name == family and make_suite_task(family).num_actions == 10
    # A fixed number of pulls: truncated episodes (no terminal pull).
    five = make_suite_task(f"{family}:7", max_steps=5)
    assert int(five.max_steps) == 5 and not np.any(np.asarray(five.terminal))


def test_the_testbeds_means_are_standard_normal_and_fixed():
    means = arm_means("testbed", 2000)
    assert abs(means.mean()) < 0.1 and means.std() == pytest.approx(1.0, abs=0.06)
    np.testing.assert_array_equal(arm_means("testbed", 10), arm_means("testbed", 10))
    assert not np.array_equal(arm_means("testbed", 10), arm_means("testbed", 10, seed=1))


@pytest.mark.parametrize("call, message", [
    (lambda: make_suite_task("testbed:0"), "arms=0 is invalid: must be an integer >= 1"),
    (lambda: arm_means("poisson", 3), "family='poisson' is invalid"),
    (lambda: make_bandit(np.zeros((2, 2)), "gaussian"), "means has shape (2, 2)"),
    (lambda: make_bandit([0.5], "cauchy"), "noise='cauchy' is invalid"),
    (lambda: make_bandit([1.5], "bernoulli"), "reward[0, 0, 0] = 1.5"),
    (lambda: make_suite_task("testbed", max_steps=0), "max_steps=0 is invalid"),
])
def test_bad_bandits_are_one_line_errors(call, message):
    with pytest.raises(ValueError) as err:
        call()
    assert message in str(err.value) and "\n" not in str(err.value)


def test_sample_average_update_is_the_running_mean_of_each_arm():
    learner = make_learner("sample_average", gamma=0.9, q_init=5.0)
    rng = np.random.default_rng(0)
    q, visits = np.full(3, 5.0, np.float32), np.zeros(3, np.float32)
    seen: dict[int, list[float]] = {0: [], 1: [], 2: []}
    for _ in range(60):
        arm, reward = int(rng.integers(3)), float(rng.normal())
        update = learner.update(Transition(
            q=jnp.float32(q[arm]), tables={"visits": jnp.float32(visits[arm])},
            reward=jnp.float32(reward), discount=jnp.float32(0.0), q_next=jnp.asarray(q),
            tables_next={"visits": jnp.asarray(visits)}, next_action=jnp.int32(0),
            next_probabilities=jnp.zeros(3), uniforms=(), terminal=jnp.bool_(True)))
        q[arm], visits[arm] = float(update.q), float(update.tables["visits"])
        seen[arm].append(np.float32(reward))
    for arm, rewards in seen.items():
        assert visits[arm] == len(rewards)
        assert q[arm] == pytest.approx(np.mean(rewards), rel=1e-5, abs=1e-6)
    with pytest.raises(ValueError, match="gamma"):
        make_learner("sample_average", gamma=1.5)


def test_sample_average_q_of_a_one_armed_bandit_is_the_mean_of_its_rewards():
    """In a run: Q of the one arm is the mean of every reward the agent drew."""
    mdp = make_bandit(np.asarray([0.3]), "gaussian", std=2.0, name="one_arm")
    params = engine.broadcast_agents(stack_agents(
        [make_agent(Setting("sample_average", "egreedy", 0.1))]), 3)
    run = engine.run_agents(mdp, params, engine.agent_keys(0, 3), 400,
                            engine.EngineOptions(strategy="lockstep"))
    rewards = np.asarray(run.returns, np.float64)  # one pull per episode: return = reward
    np.testing.assert_allclose(np.asarray(run.final_state.q)[:, 0, 0], rewards.mean(axis=1),
                               rtol=1e-4, atol=1e-5)
    np.testing.assert_array_equal(np.asarray(run.final_state.tables["visits"])[:, 0, 0], 400)


def test_the_testbed_through_run_grid_learns_the_best_arm():
    mdp = make_suite_task("testbed")
    grid = vdbejax.run_grid(mdp, [Setting("sample_average", "egreedy", 0.1),
                                  Setting("qlearning", "vdbe", 1.0)],
                            num_seeds=4, num_episodes=600, chunk_episodes=300)
    assert grid.returns.shape == (2, 4, 600) and np.all(grid.lengths == 1)
    best = float(np.asarray(mdp.reward).max())
    late = grid.returns[0, :, -300:].mean()  # ε = 0.1 after 300 pulls: near the best mean
    assert late > best - 0.5 and late > grid.returns[0, :, :20].mean()


def test_a_one_pull_bandit_has_no_truncated_episodes_and_more_pulls_are_all_cut():
    from vdbejax.results.analysis import summarize

    setting = [Setting("sample_average", "egreedy", 0.1)]
    one = vdbejax.run_grid(make_suite_task("testbed:4"), setting, num_seeds=3, num_episodes=20)
    assert not one.truncated.any() and one.meta["truncated_episodes"] == 0
    assert one.meta["agents_truncated"] == 0 and summarize(one)[0].truncated_fraction == 0.0
    three = vdbejax.run_grid(make_suite_task("testbed:4", max_steps=3), setting, num_seeds=3,
                             num_episodes=20)  # three pulls, then the limit cuts it
    assert three.truncated.all() and three.meta["truncated_episodes"] == 60
    assert summarize(three)[0].truncated_fraction == 1.0


def test_sample_average_on_a_bandit_gives_the_same_bits_in_both_strategies():
    mdp = make_suite_task("bernoulli_bandit:5", max_steps=3)
    params = engine.broadcast_agents(stack_agents(
        [make_agent(Setting("sample_average", "egreedy", 0.1)),
         make_agent(Setting("qlearning", "vdbe_softmax", 1.0))]), 2)
    keys = np.tile(engine.agent_keys(1, 2), (2, 1))
    lockstep = engine.run_agents(mdp, params, keys, 40, engine.EngineOptions(strategy="lockstep"))
    sequential = engine.run_agents(mdp, params, keys, 40,
                                   engine.EngineOptions(strategy="sequential", threads=2,
                                                        chunk_episodes=15))
    np.testing.assert_array_equal(lockstep.returns, sequential.returns)
    np.testing.assert_array_equal(lockstep.final_state.q, sequential.final_state.q)
    assert set(np.unique(lockstep.returns)) <= {0.0, 1.0, 2.0, 3.0}


def test_sweep_files_and_the_command_line_take_the_bandit_names():
    from vdbejax.studies.task_names import make_task

    assert make_task("testbed:4").name == "testbed:4"
    assert int(make_task("bernoulli_bandit", max_steps=20).max_steps) == 20
