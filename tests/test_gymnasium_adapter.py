"""Gymnasium toy-text environments through the adapter: tables, semantics, learning."""
import subprocess
import sys

import jax
import numpy as np
import pytest

from vdbejax.engine import EngineOptions, agent_keys, broadcast_agents, run_agents
from vdbejax.envs import solvers
from vdbejax.methods.agents import AgentOptions, Setting, make_agent, stack_agents

gym = pytest.importorskip("gymnasium")
from vdbejax.envs.gymnasium_adapter import from_gymnasium  # noqa: E402

ENVS = [
    ("FrozenLake-v1", {"is_slippery": True}),
    ("FrozenLake-v1", {"is_slippery": False}),
    ("CliffWalking-v1", {}),
    ("Taxi-v4", {}),
]


@pytest.mark.parametrize("env_id,kwargs", ENVS)
def test_tables_equal_gymnasium_model(env_id, kwargs):
    env = gym.make(env_id, **kwargs)
    mdp = from_gymnasium(env, max_steps=None if env.spec.max_episode_steps else 100)
    model = env.unwrapped.P
    assert (mdp.num_states, mdp.num_actions) == (env.observation_space.n, env.action_space.n)
    next_state, prob = np.asarray(mdp.next_state), np.asarray(mdp.probability)
    reward, terminal = np.asarray(mdp.reward), np.asarray(mdp.terminal)
    for s in range(mdp.num_states):
        for a in range(mdp.num_actions):
            outcomes = model[s][a]
            k = len(outcomes)
            np.testing.assert_array_equal(next_state[s, a, :k], [o[1] for o in outcomes])
            np.testing.assert_allclose(prob[s, a, :k], [o[0] for o in outcomes], rtol=1e-6)
            np.testing.assert_allclose(reward[s, a, :k], [o[2] for o in outcomes])
            np.testing.assert_array_equal(terminal[s, a, :k], [o[3] for o in outcomes])
            assert np.all(prob[s, a, k:] == 0)  # padding never drawn
    np.testing.assert_allclose(mdp.start_probability, env.unwrapped.initial_state_distrib,
                               rtol=1e-6)
    assert mdp.num_outcomes == (3 if kwargs.get("is_slippery") else 1)


def test_step_limit_name_and_errors():
    assert int(from_gymnasium(gym.make("FrozenLake-v1")).max_steps) == 100
    taxi = from_gymnasium("Taxi-v4")
    assert int(taxi.max_steps) == 200 and taxi.name == "Taxi-v4"
    assert int(from_gymnasium("FrozenLake-v1", max_steps=7).max_steps) == 7
    with pytest.raises(ValueError, match=r"^max_steps is None and the env has no TimeLimit"):
        from_gymnasium("CliffWalking-v1")  # registered without max_episode_steps
    with pytest.raises(ValueError, match=r"has no transition model P"):
        from_gymnasium(gym.make("CartPole-v1"))
    with pytest.raises(ValueError, match=r"^start_probability sums to 2"):
        from_gymnasium("FrozenLake-v1", start_probability=np.full(16, 0.125))


def test_slippery_frozen_lake_optimal_value_matches_gymnasium_rollouts():
    """Value iteration's best return agrees with the optimal policy played in gymnasium."""
    env = gym.make("FrozenLake-v1", is_slippery=True)  # TimeLimit 100
    mdp = from_gymnasium(env)
    q = solvers.optimal_q_values(mdp, gamma=1.0)  # finite horizon = max_steps
    best = solvers.best_return(mdp)
    assert 0.7 < best < 0.8
    # A stationary greedy policy of Q_100 is near-optimal here; its exact value:
    policy = solvers.greedy_policy(q)
    exact = solvers.policy_return(mdp, policy)
    assert exact <= best + 1e-9 and exact > best - 0.01
    rng = np.random.default_rng(0)
    total, episodes = 0.0, 1500
    for _ in range(episodes):
        obs, _ = env.reset(seed=int(rng.integers(2**31)))
        done = False
        while not done:
            obs, reward, terminated, truncated, _ = env.step(int(policy[obs]))
            total += reward
            done = terminated or truncated
    assert total / episodes == pytest.approx(exact, abs=0.04)  # 3.5 standard errors


@pytest.mark.parametrize("env_id,kwargs,max_steps", [
    ("CliffWalking-v1", {}, 100),
    ("FrozenLake-v1", {"is_slippery": False}, None),
])
def test_q_learning_greedy_policy_reaches_the_optimal_return(env_id, kwargs, max_steps):
    mdp = from_gymnasium(gym.make(env_id, **kwargs), max_steps=max_steps)
    best = solvers.best_return(mdp)
    num_seeds = 4
    params = broadcast_agents(stack_agents([make_agent(Setting("qlearning", "egreedy", 0.1),
                                                       AgentOptions(gamma=0.9))]), num_seeds)
    run = run_agents(mdp, params, agent_keys(0, num_seeds), 300,
                     EngineOptions(chunk_episodes=300))
    assert not run.nonfinite.any()
    for q in np.asarray(run.final_state.q):
        assert solvers.policy_return(mdp, solvers.greedy_policy(q)) == pytest.approx(best, abs=1e-5)


def test_core_imports_without_gymnasium():
    code = (
        "import sys; sys.modules['gymnasium'] = None\n"  # any import of it now fails
        "import vdbejax, vdbejax.envs, vdbejax.envs.solvers, vdbejax.runs\n"
        "from vdbejax.envs.gymnasium_adapter import from_gymnasium\n"
        "from vdbejax.envs.table_cleaning import make_variant_mdp\n"
        "try:\n"
        "    from_gymnasium('FrozenLake-v1')\n"
        "except ImportError as err:\n"
        "    assert 'vdbejax[gym]' in str(err)\n"
        "else:\n"
        "    raise AssertionError('no ImportError')\n"
    )
    subprocess.run([sys.executable, "-c", code], check=True)
    assert jax  # the test module itself needs only jax
