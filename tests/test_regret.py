"""Regret, normalised scores and the aggregates across tasks (vdbejax.results.regret), and
the random policy's exact return (vdbejax.envs.solvers.uniform_random_return)."""
from __future__ import annotations

import numpy as np
import pytest

from vdbejax.envs.solvers import best_return, uniform_random_return
from vdbejax.envs.tabular import make_tabular_mdp
from vdbejax.results import regret
from vdbejax.results.bootstrap import interquartile_mean


def test_regret_is_the_gap_to_the_optimum_and_sums_over_episodes() -> None:
    returns = np.array([[0.0, 0.5, 1.0, np.nan]])
    np.testing.assert_allclose(regret.episode_regret(returns, 1.0)[0, :3], [1.0, 0.5, 0.0])
    # an episode not run (an agent stopped once solved) adds nothing
    np.testing.assert_allclose(regret.cumulative_regret(returns, 1.0), [[1.0, 1.5, 1.5, 1.5]])


def test_scores_map_random_to_zero_and_the_optimum_to_one() -> None:
    returns = np.array([[-1.0, 0.0, 3.0], [3.0, 3.0, np.nan]])
    np.testing.assert_allclose(regret.normalised_returns(returns[:1], 3.0, -1.0), [[0, 0.25, 1]])
    # a run's score: the mean over its episodes; episodes past its stop count as solved
    np.testing.assert_allclose(regret.run_scores(returns, 3.0, -1.0), [1.25 / 3, 1.0])
    with pytest.raises(ValueError, match="must exceed the baseline"):
        regret.run_scores(returns, 1.0, 1.0)


def test_aggregate_iqm_pools_every_run_and_its_interval_holds_it() -> None:
    rng = np.random.default_rng(0)
    tasks = [rng.normal(0.5, 0.1, 10), rng.normal(0.8, 0.05, 6)]
    iqm = regret.aggregate_iqm(tasks, num_resamples=400)
    assert iqm.value == pytest.approx(interquartile_mean(np.concatenate(tasks)))
    assert iqm.low < iqm.value < iqm.high
    # one constant task: every resample is the same, the interval collapses
    same = regret.aggregate_iqm([np.full(8, 0.3)], num_resamples=100)
    assert same.low == same.value == same.high == pytest.approx(0.3)
    with pytest.raises(ValueError, match="at least one run"):
        regret.aggregate_iqm([np.array([])])


def test_performance_profile_counts_runs_above_each_threshold() -> None:
    tasks = [np.array([0.1, 0.5, 0.9]), np.array([0.2, 0.6])]
    fraction, low, high = regret.performance_profile(tasks, np.array([0.0, 0.3, 0.7, 1.0]),
                                                     num_resamples=300)
    np.testing.assert_allclose(fraction, [1.0, 0.6, 0.2, 0.0])
    assert np.all(low <= fraction) and np.all(fraction <= high)
    assert low[0] == high[0] == 1.0 and low[-1] == high[-1] == 0.0


def test_probability_of_improvement_averages_over_tasks() -> None:
    better = [np.array([2.0, 3.0]), np.array([1.0, 1.0])]
    worse = [np.array([0.0, 1.0]), np.array([1.0, 1.0])]
    p = regret.task_probability_of_improvement(better, worse, num_resamples=200)
    assert p.value == pytest.approx((1.0 + 0.5) / 2)  # task 2 ties: 1/2
    assert p.low <= p.value <= p.high
    with pytest.raises(ValueError, match="must be the same tasks"):
        regret.task_probability_of_improvement(better, worse[:1])


def _bandit(horizon: int):  # state 0: action 0 pays 0, action 1 pays 1; both stay
    next_state = np.zeros((2, 2), np.int32)
    next_state[1] = 1
    reward = np.array([[0.0, 1.0], [0.0, 0.0]], np.float32)
    return make_tabular_mdp(next_state, reward, np.zeros((2, 2), bool),
                            np.array([1.0, 0.0], np.float32), max_steps=horizon)


def test_the_random_policy_return_is_exact() -> None:
    mdp = _bandit(4)
    assert best_return(mdp) == pytest.approx(4.0)
    assert uniform_random_return(mdp) == pytest.approx(2.0)  # 1/2 per step


def test_the_random_policy_return_matches_monte_carlo_on_a_stochastic_task() -> None:
    rng = np.random.default_rng(1)
    S, A, K, H = 4, 3, 2, 6
    next_state = rng.integers(0, S, (S, A, K)).astype(np.int32)
    reward = rng.normal(size=(S, A, K)).astype(np.float32)
    probability = rng.dirichlet(np.ones(K), (S, A)).astype(np.float32)
    terminal = rng.random((S, A, K)) < 0.1
    mdp = make_tabular_mdp(next_state, reward, terminal, np.full(S, 1 / S, np.float32),
                           probability, max_steps=H)
    p = np.asarray(mdp.probability, np.float64)
    total, runs = 0.0, 40_000
    state = rng.integers(0, S, runs)
    alive = np.ones(runs, bool)
    for _ in range(H):
        action = rng.integers(0, A, runs)
        u = rng.random(runs)
        k = (u[:, None] > np.cumsum(p[state, action], -1)[:, :-1]).sum(-1)
        total += (np.asarray(mdp.reward)[state, action, k] * alive).sum()
        alive &= ~np.asarray(mdp.terminal)[state, action, k]
        state = np.asarray(mdp.next_state)[state, action, k]
    assert uniform_random_return(mdp) == pytest.approx(total / runs, abs=0.05)
