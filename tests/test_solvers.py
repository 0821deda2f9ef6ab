"""Exact solvers: value iteration, policy evaluation and searches against plain references."""
from collections import deque

import numpy as np
import pytest

from vdbejax.envs import make_tabular_mdp, solvers
from vdbejax.envs.table_cleaning import make_mdp


def random_mdp(seed, num_states=30, num_actions=3, num_outcomes=2, max_steps=20):
    """A random stochastic MDP with some terminal outcomes."""
    rng = np.random.default_rng(seed)
    shape = (num_states, num_actions, num_outcomes)
    probability = rng.dirichlet(np.ones(num_outcomes), size=shape[:2])
    return make_tabular_mdp(
        rng.integers(0, num_states, shape),
        rng.normal(size=shape),
        rng.random(shape) < 0.1,
        rng.dirichlet(np.ones(num_states)),
        probability,
        max_steps=max_steps,
    )


def naive_q(mdp, gamma, backups):
    """Exactly ``backups`` Bellman backups with explicit loops (the textbook definition)."""
    ns, p = np.asarray(mdp.next_state), np.asarray(mdp.probability, np.float64)
    r, t = np.asarray(mdp.reward, np.float64), np.asarray(mdp.terminal)
    q = np.zeros((mdp.num_states, mdp.num_actions))
    for _ in range(backups):
        v = q.max(1)
        new = np.zeros_like(q)
        for s in range(mdp.num_states):
            for a in range(mdp.num_actions):
                for k in range(mdp.num_outcomes):
                    new[s, a] += p[s, a, k] * (r[s, a, k] + (0 if t[s, a, k] else gamma * v[ns[s, a, k]]))
        q = new
    return q


@pytest.mark.parametrize("gamma,horizon", [(1.0, 20), (0.9, 7), (1.0, 3)])
def test_value_iteration_equals_textbook_backups(gamma, horizon):
    mdp = random_mdp(1)
    np.testing.assert_allclose(solvers.optimal_q_values(mdp, gamma, horizon),
                               naive_q(mdp, gamma, horizon), atol=1e-9)


def growing_mdp(seed):
    """No terminal outcome, integer rewards, outcomes of probability 1/2: values grow with
    the horizon, and the best action may change late."""
    rng = np.random.default_rng(seed)
    shape = (6, 3, 2)
    return make_tabular_mdp(rng.integers(0, 6, shape), rng.integers(-2, 4, shape).astype(float),
                            np.zeros(shape, bool), np.full(6, 1 / 6), np.full(shape, 0.5),
                            max_steps=60)


def test_values_that_grow_steadily_are_extrapolated_exactly(monkeypatch):
    """Once V grows by the same step twice and the maximal actions grow the most, the
    rest of a long horizon is that step times the backups left: the same Q as every
    backup made (against the textbook loop), and a fixed policy's values too."""
    steady = []
    check = solvers._steady_growth
    monkeypatch.setattr(solvers, "_steady_growth",
                        lambda *args: steady.append(check(*args)) or steady[-1])
    # Staying in state 0 earns 1 a step; moving to state 1 costs 3, then earns 2 a step:
    # V grows by 1 a few times before moving pays, so Q's growth must be checked too.
    turn = make_tabular_mdp(next_state=[[0, 1], [1, 1]], reward=[[1.0, -3.0], [2.0, 2.0]],
                            terminal=[[False, False], [False, False]],
                            start_probability=[1.0, 0.0], max_steps=50)
    np.testing.assert_array_equal(solvers.optimal_q_values(turn, 1.0, 50), naive_q(turn, 1.0, 50))
    for seed in range(8):
        mdp = growing_mdp(seed)
        np.testing.assert_allclose(solvers.optimal_q_values(mdp, 1.0, 60),
                                   naive_q(mdp, 1.0, 60), rtol=1e-14)
        policy = np.arange(6) % 3
        # (policy evaluation: the textbook loop on the policy's actions alone)
        rows = np.arange(6), policy
        one = make_tabular_mdp(np.asarray(mdp.next_state)[rows][:, None],
                               np.asarray(mdp.reward)[rows][:, None], np.zeros((6, 1, 2), bool),
                               np.full(6, 1 / 6), np.full((6, 1, 2), 0.5), max_steps=60)
        np.testing.assert_allclose(solvers.policy_values(mdp, policy, horizon=60),
                                   naive_q(one, 1.0, 60)[:, 0], rtol=1e-14)
    assert sum(steady) >= 3  # extrapolated on several of the tasks


def test_an_episode_of_two_billion_steps_costs_a_few_backups():
    """One state, a reward of 1 a step: the best return is the horizon, at once."""
    mdp = make_tabular_mdp(next_state=[[0, 0]], reward=[[0.0, 1.0]],
                           terminal=[[False, False]], start_probability=[1.0],
                           max_steps=2_000_000_000)
    assert solvers.best_return(mdp) == 2_000_000_000
    assert solvers.uniform_random_return(mdp) == 1_000_000_000


def test_infinite_horizon_q_satisfies_bellman_optimality():
    mdp = random_mdp(2)
    q = solvers.optimal_q_values(mdp, gamma=0.9)
    np.testing.assert_allclose(naive_q_from(mdp, q, 0.9), q, atol=1e-9)


def naive_q_from(mdp, q, gamma):
    p, r = np.asarray(mdp.probability, np.float64), np.asarray(mdp.reward, np.float64)
    cont = np.where(np.asarray(mdp.terminal), 0.0, q.max(1)[np.asarray(mdp.next_state)])
    return (p * (r + gamma * cont)).sum(-1)


def test_policy_evaluation_of_the_greedy_optimal_policy_gives_the_optimal_values():
    mdp = random_mdp(3)
    q = solvers.optimal_q_values(mdp, gamma=1.0)  # horizon = max_steps
    # A stationary policy may be worse than the non-stationary finite-horizon optimum,
    # never better; with one step left, the greedy policy of Q_1 is optimal.
    values = solvers.policy_values(mdp, solvers.greedy_policy(q))
    assert np.all(values <= q.max(1) + 1e-9)
    q1 = solvers.optimal_q_values(mdp, gamma=1.0, horizon=1)
    np.testing.assert_allclose(
        solvers.policy_values(mdp, solvers.greedy_policy(q1), horizon=1), q1.max(1))
    with pytest.raises(ValueError, match=r"^policy has shape \(2,\)"):
        solvers.policy_values(mdp, np.zeros(2, int))
    with pytest.raises(ValueError, match=r"^policy holds actions in \[0, 3\]"):
        solvers.policy_values(mdp, np.arange(30) % 4)


def test_reachable_states_equals_plain_bfs():
    for mdp in (random_mdp(4), make_mdp()):
        ns, p, t = (np.asarray(mdp.next_state), np.asarray(mdp.probability),
                    np.asarray(mdp.terminal))
        seen = set(solvers.start_states(mdp).tolist())
        queue = deque(seen)
        while queue:
            s = queue.popleft()
            for a in range(mdp.num_actions):
                for k in range(mdp.num_outcomes):
                    if p[s, a, k] > 0 and not t[s, a, k] and ns[s, a, k] not in seen:
                        seen.add(int(ns[s, a, k]))
                        queue.append(int(ns[s, a, k]))
        np.testing.assert_array_equal(solvers.reachable_states(mdp), sorted(seen))


def test_paper_task_best_return_and_shortest_solution_from_both_starts():
    mdp = make_mdp()
    starts = solvers.start_states(mdp)
    assert len(starts) == 2
    values = solvers.optimal_values(mdp, gamma=1.0)
    np.testing.assert_allclose(values[starts], 0.86, atol=1e-6)
    steps = solvers.steps_to_goal(mdp)
    for start in starts:
        path = solvers.shortest_solution(mdp, int(start))
        assert len(path) == steps[start] == 15
    assert solvers.best_return(mdp) == pytest.approx(0.86)
    # The shortest solution's return is the best return (it is a greedy optimal policy).
    assert solvers.policy_return(mdp, solvers.greedy_policy(
        solvers.optimal_q_values(mdp, gamma=1.0))) == pytest.approx(0.86)


def test_steps_to_goal_agrees_with_forward_search_everywhere():
    mdp = make_mdp()
    steps = solvers.steps_to_goal(mdp)
    for state in solvers.reachable_states(mdp):
        assert len(solvers.shortest_solution(mdp, int(state))) == max(steps[state], 0)
    # No goal from a state whose every action fails: none here, so all reachable have one.
    assert np.all(steps[solvers.reachable_states(mdp)] > 0)
