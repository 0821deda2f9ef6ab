"""Reward noise in TabularMDP: validation, the draws' distribution, and the engine's
strategies giving the same bits per agent; a task without noise keeps its bits."""
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from vdbejax import engine
from vdbejax.engine.agent_state import draw_base, reward_uniform
from vdbejax.envs import make_tabular_mdp, solvers
from vdbejax.envs.reward_noise import BERNOULLI, GAUSSIAN, noisy_reward
from vdbejax.methods.agents import Setting, make_agent, stack_agents


def one_state(**overrides):
    """A one-state, three-action task whose every pull ends the episode."""
    args = dict(next_state=[[0, 0, 0]], reward=[[0.2, 0.5, 0.9]],
                terminal=[[True, True, True]], start_probability=[1.0])
    args.update(overrides)
    return args


BAD_NOISE = [
    (dict(reward_noise="poisson"), "reward_noise='poisson' is invalid",
     "must be one of none, gaussian, bernoulli"),
    (dict(reward_noise=[["none", "gaussian"]], reward_std=1.0), "reward_noise has shape (1, 2)",
     "must be a name or [1, 3, 1] names"),
    (dict(reward_noise=[["none", "laplace", "none"]]), "reward_noise[0, 1, 0] = 'laplace'",
     "must be one of"),
    (dict(reward_noise="gaussian"), "reward_std is None but reward_noise has Gaussian",
     "pass their standard deviation"),
    (dict(reward_noise="gaussian", reward_std=-1.0), "reward_std[0, 0, 0] = -1.0",
     "must be finite and >= 0"),
    (dict(reward_noise="bernoulli", reward_std=1.0), "reward_std=1.0 is invalid",
     "no outcome has Gaussian noise"),
    (dict(reward_std=1.0), "reward_std=1.0 is invalid without reward_noise",
     "needs Gaussian outcomes"),
    (dict(reward_noise="bernoulli", reward=[[0.2, 1.5, 0.0]]), "reward[0, 1, 0] = 1.5",
     "must lie in [0, 1] for a Bernoulli outcome"),
    (dict(reward_noise="gaussian", reward_std=[1.0, 2.0]), "reward_std has shape (2,)",
     "must be [1, 3, 1] or [1, 3]"),
]


@pytest.mark.parametrize("overrides, named, allowed", BAD_NOISE)
def test_bad_noise_is_a_one_line_error_naming_the_parameter(overrides, named, allowed):
    with pytest.raises(ValueError) as err:
        make_tabular_mdp(**one_state(**overrides))
    message = str(err.value)
    assert "\n" not in message and named in message and allowed in message


def test_a_task_without_noise_stores_none_and_keeps_its_leaves():
    plain = make_tabular_mdp(**one_state())
    for noise in ("none", [["none"] * 3]):
        same = make_tabular_mdp(**one_state(reward_noise=noise))
        assert same.reward_noise is None
        for a, b in zip(jax.tree.leaves(plain), jax.tree.leaves(same), strict=True):
            np.testing.assert_array_equal(a, b)
    noisy = make_tabular_mdp(**one_state(reward_noise=[["none", "gaussian", "bernoulli"]],
                                         reward_std=2.0))
    np.testing.assert_array_equal(noisy.reward_noise.model, [[[0], [1], [2]]])
    np.testing.assert_array_equal(noisy.reward_noise.std, [[[0.0], [2.0], [0.0]]])
    # Exact solvers use the means.
    assert solvers.best_return(noisy) == pytest.approx(0.9)
    with pytest.raises(ValueError, match="noise_u is None but MDP 'mdp' has reward noise"):
        noisy.transition(jnp.int32(0), jnp.int32(1), jnp.float32(0.5))


def test_reward_uniforms_lie_in_the_open_interval_and_draw_gaussian_and_bernoulli_rewards():
    counters = jnp.arange(200_000, dtype=jnp.uint32)
    u = reward_uniform(draw_base(jnp.asarray([7, 11], jnp.uint32), counters))
    assert float(u.min()) > 0.0 and float(u.max()) < 1.0
    mean = jnp.full(u.shape, 1.5, jnp.float32)
    gauss = np.asarray(noisy_reward(mean, jnp.full(u.shape, GAUSSIAN), jnp.full(u.shape, 2.0),
                                    u), np.float64)
    # 200,000 draws: standard errors 0.0045 (mean) and 0.0063 (variance 4 → relative 0.3 %).
    assert gauss.mean() == pytest.approx(1.5, abs=0.03)
    assert gauss.var() == pytest.approx(4.0, rel=0.03)
    assert np.isfinite(gauss).all()
    coin = np.asarray(noisy_reward(jnp.full(u.shape, 0.3, jnp.float32),
                                   jnp.full(u.shape, BERNOULLI), jnp.zeros(u.shape), u))
    assert set(np.unique(coin)) == {0.0, 1.0}
    assert coin.mean() == pytest.approx(0.3, abs=0.01)


def _agents(seeds: int):
    settings = [Setting("qlearning", "egreedy", 0.1), Setting("sarsa", "vdbe", 1.0),
                Setting("qlearning", "softmax", 0.5)]
    params = engine.broadcast_agents(stack_agents([make_agent(s) for s in settings]), seeds)
    keys = np.tile(engine.agent_keys(3, seeds), (len(settings), 1))
    return params, keys


def _same(a, b):
    np.testing.assert_array_equal(a.lengths, b.lengths)
    for x, y in zip(jax.tree.leaves((a.returns, a.final_state)),
                    jax.tree.leaves((b.returns, b.final_state)), strict=True):
        np.testing.assert_array_equal(x, y)


@pytest.mark.parametrize("outcomes", [1, 2])
def test_noisy_rewards_give_the_same_bits_in_both_strategies(outcomes):
    """Each agent's rewards come from its own stream: lockstep, sequential, any threads
    and chunks, and the agent alone give the same bits (one outcome: flat gathers; two:
    the vmapped transition)."""
    rng = np.random.default_rng(0)
    # Another S per case: programs.py keys init_agents by its lowered module, from which
    # JAX prunes the unused outcome tables (a K=1 and a K=2 task of one S, A collide).
    S, A = 3 + outcomes, 3
    next_state = rng.integers(0, S, size=(S, A, outcomes))
    noise = rng.choice(["none", "gaussian", "bernoulli"], size=(S, A, outcomes))
    reward = rng.random((S, A, outcomes)).astype(np.float32)
    terminal = np.zeros((S, A, outcomes), bool)
    terminal[S - 1] = True
    mdp = make_tabular_mdp(next_state, reward, terminal, np.full(S, 1 / S),
                           probability=np.full((S, A, outcomes), 1 / outcomes),
                           max_steps=12, reward_noise=noise, reward_std=0.7)
    params, keys = _agents(2)
    lockstep = engine.run_agents(mdp, params, keys, 25, engine.EngineOptions(strategy="lockstep"))
    sequential = engine.run_agents(mdp, params, keys, 25,
                                   engine.EngineOptions(strategy="sequential", threads=2,
                                                        chunk_episodes=7))
    _same(sequential, lockstep)
    alone = engine.run_agents(mdp, jax.tree.map(lambda x: x[3:4], params), keys[3:4], 25,
                              engine.EngineOptions(strategy="lockstep", chunk_episodes=9))
    np.testing.assert_array_equal(alone.returns[0], lockstep.returns[3])
    # The noise is drawn: returns are not all sums of the means.
    plain = engine.run_agents(make_tabular_mdp(next_state, reward, terminal, np.full(S, 1 / S),
                                               probability=np.full((S, A, outcomes),
                                                                   1 / outcomes),
                                               max_steps=12),
                              params, keys, 25, engine.EngineOptions(strategy="lockstep"))
    assert not np.array_equal(plain.returns, lockstep.returns)


def test_a_gaussian_one_pull_task_returns_its_mean_and_variance_on_average():
    mdp = make_tabular_mdp(**one_state(next_state=[[0]], reward=[[2.0]], terminal=[[True]],
                                       reward_noise="gaussian", reward_std=3.0))
    params, keys = _agents(4)
    run = engine.run_agents(mdp, params, keys, 1000, engine.EngineOptions(chunk_episodes=1000))
    returns = np.asarray(run.returns, np.float64)  # 12,000 pulls: se 0.027 and 0.12
    assert returns.mean() == pytest.approx(2.0, abs=0.15)
    assert returns.var() == pytest.approx(9.0, rel=0.08)
    # Agents of different seeds draw differently.
    assert not np.array_equal(returns[0], returns[1])
