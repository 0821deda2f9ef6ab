"""Grid-level analysis helpers: exact action probabilities, truncation, ε(s) snapshots,
markdown tables, probability-of-improvement matrices."""
import numpy as np
import pytest
from synthetic_grid import synthetic_grid

from vdbejax.envs.table_cleaning import make_mdp
from vdbejax.methods.agents import Setting
from vdbejax.results import analysis
from vdbejax.results.grid_result import GridResult
from vdbejax.results.summary import SUMMARY_COLUMNS
from vdbejax.studies import snapshots

Q = np.array([0.0, 1.0, 1.0, -1.0])


def test_action_probabilities_by_hand():
    # ε-greedy 0.2: 0.2/4 everywhere, greedy mass 0.8 split over the two maximal actions.
    np.testing.assert_allclose(analysis.action_probabilities(Q, "egreedy", 0.2),
                               [0.05, 0.45, 0.45, 0.05])
    np.testing.assert_allclose(analysis.action_probabilities(Q, "egreedy", 0.2, tie_break="first"),
                               [0.05, 0.85, 0.05, 0.05])
    # Softmax τ = 1: weights e^(q − 1).
    w = np.exp(Q - 1.0)
    np.testing.assert_allclose(analysis.action_probabilities(Q, "softmax", 1.0), w / w.sum())
    # VDBE uses ε(s), not its σ.
    np.testing.assert_allclose(analysis.action_probabilities(Q, "vdbe", 10.0, state_epsilon=0.4),
                               [0.1, 0.4, 0.4, 0.1])
    # VDBE-Softmax: ε(s)·softmax(τ=0.001) + (1 − ε(s))·greedy → all mass on the maximal pair.
    np.testing.assert_allclose(analysis.action_probabilities(Q, "vdbe_softmax", 1.0, state_epsilon=0.4),
                               [0.0, 0.5, 0.5, 0.0], atol=1e-12)


def test_truncated_fraction_reads_the_record_and_falls_back_to_lengths_without_it():
    lengths = np.array([[[100, 15, 100, 20], [15, 15, 15, 15]]])
    grid = GridResult([Setting("qlearning", "egreedy", 0.1)], np.zeros(lengths.shape, np.float32),
                      lengths, np.zeros(lengths.shape[:2], bool), {"max_steps": 100})
    grid.truncated = np.zeros(lengths.shape, bool)
    grid.truncated[0, 0, 2] = True  # the episode at 0 ended on its own at its last step
    np.testing.assert_allclose(analysis.truncated_fraction(grid, last=2), [[0.5, 0.0]])
    np.testing.assert_array_equal(analysis.truncated_episodes(grid), grid.truncated)
    grid.truncated = None  # a folder of an older version: every episode of max_steps steps
    np.testing.assert_allclose(analysis.truncated_fraction(grid, last=4), [[0.5, 0.0]])
    grid.meta["step_limit_cuts"] = "never"  # that version's word on a one-pull task
    np.testing.assert_allclose(analysis.truncated_fraction(grid), [[0.0, 0.0]])
    grid.meta = {}
    assert analysis.truncated_episodes(grid) is None
    assert np.isnan(analysis.truncated_fraction(grid)).all()


def test_markdown_table():
    text = analysis.markdown_table([{"a": 0.0001, "b": 1.23456, "c": "x"}], ["a", "b", "c"], digits=2)
    assert text.splitlines() == ["| a | b | c |", "| --- | --- | --- |", "| 0.0001 | 1.23 | x |"]


def test_probability_of_improvement_matrix():
    grid = synthetic_grid()
    # Configs 0 and 45 have the lowest and highest levels of the synthetic grid.
    p, low, high = analysis.probability_of_improvement_matrix(grid, [0, 45], last=20)
    assert p[1, 0] == 1.0 and p[0, 1] == 0.0 and p[0, 0] == 0.5
    assert low[1, 0] <= p[1, 0] <= high[1, 0]


def test_summarize_columns_and_intervals():
    grid = synthetic_grid()
    rows = analysis.summarize(grid)
    assert list(rows[0]) == SUMMARY_COLUMNS[:4] + ["hyperparameters"] + SUMMARY_COLUMNS[4:]
    # The paper's grid has no values beside each explorer's parameter: summary.csv as before.
    assert analysis.summary_columns(grid) == SUMMARY_COLUMNS
    for r in rows:
        assert r["final_ci_low"] <= r["final_return"] <= r["final_ci_high"]
        assert r["convergence_ci_low"] <= r["convergence_ci_high"]


def test_epsilon_snapshots_follow_vdbe():
    mdp = make_mdp(max_steps=20)
    episodes, epsilon, returns = snapshots.epsilon_snapshots(
        mdp, Setting("qlearning", "vdbe", 1.0), num_seeds=2, num_episodes=6, every=2)
    assert episodes.tolist() == [2, 4, 6]
    assert epsilon.shape == (3, 2, mdp.num_states) and returns.shape == (2, 6)
    assert np.all((epsilon >= 0) & (epsilon <= 1))
    assert epsilon.min() < 1.0  # visited states have moved away from ε = 1
    # ε-greedy keeps no ε(s) table; UCB-1's counts can be watched the same way.
    with pytest.raises(ValueError, match="keeps q and no tables of its own"):
        snapshots.epsilon_snapshots(mdp, Setting("qlearning", "egreedy", 0.1),
                                   num_seeds=1, num_episodes=2, every=1)
    _, counts, _ = snapshots.epsilon_snapshots(mdp, Setting("qlearning", "ucb1", 1.0), num_seeds=1,
                                              num_episodes=4, every=2, table="counts")
    assert counts.shape == (2, 1, mdp.num_states, mdp.num_actions)
    assert counts[1].sum() > counts[0].sum() > 0


def test_the_final_q_of_a_setting_is_that_of_the_same_agents_in_a_grid():
    from vdbejax.runs import run_grid

    mdp = make_mdp(max_steps=30)
    setting = Setting("sarsa", "vdbe", 1.0)
    episodes, q, returns = snapshots.table_snapshots(mdp, setting, num_seeds=3,
                                                     num_episodes=8, every=8, table="q")
    assert episodes.tolist() == [8] and q.shape == (1, 3, mdp.num_states, mdp.num_actions)
    grid = run_grid(mdp, [Setting("qlearning", "egreedy", 0.1), setting], num_seeds=3,
                    num_episodes=8)
    np.testing.assert_array_equal(returns, grid.returns[1])  # the same agents, bit for bit
    assert np.any(q[0] != 0)  # learned something


@pytest.mark.parametrize("explorer, param", [("softmax", 1e-4), ("vdbe_softmax", 100.0)])
def test_action_probabilities_sum_to_one(explorer, param):
    p = analysis.action_probabilities(np.array([0.3, -0.2, 0.3001, -1.0]), explorer, param, 0.7)
    assert p.sum() == pytest.approx(1.0) and np.all(np.isfinite(p))
