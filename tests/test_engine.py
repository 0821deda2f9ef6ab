"""The engine: exact update order, truncation, VDBE, determinism, agreement with a peer."""
import sys
from pathlib import Path

import numpy as np
import pytest

from vdbejax.engine import agent_keys, run_agents
from vdbejax.envs import make_tabular_mdp
from vdbejax.envs.table_cleaning import make_mdp
from vdbejax.methods.agents import AgentOptions, Setting, make_agent, paper_settings, stack_agents
from vdbejax.runs import run_grid


def loop_or_finish_mdp():
    """State 0: action 0 loops (−0.01), action 1 ends the episode (+1). State 1 is unused."""
    return make_tabular_mdp(
        next_state=[[0, 1], [1, 1]],
        reward=[[-0.01, 1.0], [0.0, 0.0]],
        terminal=[[False, True], [False, False]],
        start_probability=[1.0, 0.0],
        max_steps=100,
    )


def run_one(mdp, setting, episodes, options=AgentOptions(tie_break="first"), seed=0):
    params = stack_agents([make_agent(setting, options)])
    return run_agents(mdp, params, agent_keys(seed, 1), episodes)


def test_q_learning_chooses_after_its_update():
    # Greedy, first tie-break: loop once (Q(0,0) = 0.8·(−0.01) = −0.008), then the
    # updated row prefers action 1 → return 0.99 in 2 steps.
    result = run_one(loop_or_finish_mdp(), Setting("qlearning", "egreedy", 0.0), 1)
    assert result.lengths[0, 0] == 2
    assert result.returns[0, 0] == pytest.approx(0.99)
    np.testing.assert_allclose(result.final_state.q[0, 0], [-0.008, 0.8], rtol=1e-6)


def test_sarsa_chooses_next_action_before_its_update():
    # SARSA picks a' = 0 from the not-yet-updated row (tie), so it loops twice:
    # Q(0,0) = −0.008, then −0.008 + 0.8·(−0.01 + 0.9·0 + 0.008) = −0.0096.
    result = run_one(loop_or_finish_mdp(), Setting("sarsa", "egreedy", 0.0), 1)
    assert result.lengths[0, 0] == 3
    assert result.returns[0, 0] == pytest.approx(0.98)
    np.testing.assert_allclose(result.final_state.q[0, 0], [-0.0096, 0.8], rtol=1e-6)


@pytest.mark.parametrize("learner", ["qlearning", "sarsa"])
def test_truncation_bootstraps_and_resets(learner):
    # 0 → 1 (reward 0, not terminal); max_steps = 1 truncates after one step.
    mdp = make_tabular_mdp(
        next_state=[[1, 1], [1, 1]], reward=[[0.0, 0.0], [0.0, 0.0]],
        terminal=[[False, False], [False, False]], start_probability=[1.0, 0.0], max_steps=1,
    )
    options = AgentOptions(tie_break="first", q_init=0.5)
    result = run_one(mdp, Setting(learner, "egreedy", 0.0), 1, options)
    # Bootstrapped: 0.5 + 0.8·(0 + 0.9·0.5 − 0.5) = 0.46 (a terminal target would give 0.1).
    np.testing.assert_allclose(result.final_state.q[0, 0], [0.46, 0.5], rtol=1e-6)
    assert result.lengths[0, 0] == 1 and result.returns[0, 0] == 0.0
    two = run_one(mdp, Setting(learner, "egreedy", 0.0), 3, options)
    assert two.lengths[0].tolist() == [1, 1, 1]  # each episode restarts from state 0


def test_vdbe_epsilon_follows_its_update_inside_the_engine():
    mdp = loop_or_finish_mdp()
    sigma = 0.05
    result = run_one(mdp, Setting("qlearning", "vdbe", sigma), 1)
    length = int(result.lengths[0, 0])
    # Replay: (length − 1) loops then the finishing action; ε(0) updated after each.
    q, eps = [0.0, 0.0], 1.0
    for step in range(length):
        a = 0 if step < length - 1 else 1
        target = -0.01 + 0.9 * max(q) if a == 0 else 1.0
        dq = 0.8 * (target - q[a])
        q[a] += dq
        x = np.exp(-abs(dq) / sigma)
        eps = 0.1 * (1 - x) / (1 + x) + 0.9 * eps
    np.testing.assert_allclose(result.final_state.q[0, 0], q, rtol=1e-5)
    assert result.final_state.tables["epsilon"][0, 0] == pytest.approx(eps, rel=1e-5)
    assert result.final_state.tables["epsilon"][0, 1] == 1.0  # never updated


def test_explorers_without_tables_keep_none():
    result = run_one(make_mdp(), Setting("qlearning", "softmax", 0.1), 5)
    assert result.final_state.tables == {}


def test_agent_alone_equals_agent_inside_the_full_grid():
    mdp = make_mdp(max_steps=40)
    settings = paper_settings()
    grid = run_grid(mdp, settings, num_seeds=3, num_episodes=40, seed=7)
    for index in (0, 17, 45):
        alone = run_grid(mdp, [settings[index]], num_seeds=3, num_episodes=40, seed=7)
        np.testing.assert_array_equal(alone.returns[0], grid.returns[index])
        np.testing.assert_array_equal(alone.lengths[0], grid.lengths[index])
    fewer_seeds = run_grid(mdp, settings[:5], num_seeds=2, num_episodes=40, seed=7)
    np.testing.assert_array_equal(fewer_seeds.returns, grid.returns[:5, :2])


def test_same_seed_is_bit_identical_and_other_seed_differs():
    mdp = make_mdp(max_steps=40)
    settings = paper_settings()[::5]
    first = run_grid(mdp, settings, num_seeds=4, num_episodes=40, seed=3)
    again = run_grid(mdp, settings, num_seeds=4, num_episodes=40, seed=3)
    assert first.returns.tobytes() == again.returns.tobytes()
    assert first.lengths.tobytes() == again.lengths.tobytes()
    other = run_grid(mdp, settings, num_seeds=4, num_episodes=40, seed=4)
    assert not np.array_equal(first.returns, other.returns)


def test_result_shapes_and_episode_bookkeeping():
    mdp = make_mdp(max_steps=30)
    grid = run_grid(mdp, paper_settings()[:3], num_seeds=2, num_episodes=25)
    assert grid.returns.shape == grid.lengths.shape == (3, 2, 25)
    assert grid.returns.dtype == np.float32 and grid.lengths.dtype == np.int32
    assert grid.lengths.min() >= 1 and grid.lengths.max() <= 30
    # A return is −0.01 per step plus the final ±1 (or −0.01 when truncated).
    truncated = grid.lengths == 30
    non_final = -0.01 * (grid.lengths - 1)
    final = grid.returns - non_final
    assert np.all(np.isclose(final, 1.0, atol=1e-4) | np.isclose(final, -1.0, atol=1e-4)
                  | (truncated & np.isclose(final, -0.01, atol=1e-4)))


@pytest.mark.parametrize(
    "setting",
    [
        Setting("qlearning", "egreedy", 0.05),
        Setting("sarsa", "softmax", 0.01),
        Setting("qlearning", "vdbe", 1.0),
        Setting("sarsa", "vdbe_softmax", 0.1),
    ],
)
def test_curves_agree_with_an_independent_pure_python_implementation(setting):
    """Statistical cross-check against benchmarks/python_loop.py (own env, own RNG)."""
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
    from python_loop import train_agent

    seeds, episodes = 24, 150
    engine = run_grid(make_mdp(), [setting], num_seeds=seeds, num_episodes=episodes).returns[0]
    peer = np.array([
        train_agent(setting.learner, setting.explorer, setting.param, 1000 + s, episodes)[0]
        for s in range(seeds)
    ])
    # Compare per-seed mean returns over three phases of learning (Welch-style z-test).
    for phase in (slice(0, 50), slice(50, 100), slice(100, 150)):
        a, b = engine[:, phase].mean(1), peer[:, phase].mean(1)
        se = np.sqrt(a.var(ddof=1) / seeds + b.var(ddof=1) / seeds) + 0.02
        assert abs(a.mean() - b.mean()) < 4.5 * se, (setting, phase, a.mean(), b.mean())
