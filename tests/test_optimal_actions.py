"""The record of optimal actions (issue 48, point 3): per episode, the fraction of its
steps whose action maximises the task's exact Q*, beside the returns, without changing
them, the same in every strategy, batch and chunking, kept through save, load and resume."""
from __future__ import annotations

import numpy as np
import pytest
from small_grid import interrupt_then_resume

from vdbejax import cli, engine
from vdbejax.envs.suite import make_suite_task
from vdbejax.envs.table_cleaning import make_mdp
from vdbejax.envs.tabular import make_tabular_mdp
from vdbejax.methods.agents import Setting, make_agent, stack_agents
from vdbejax.results.analysis import summarize, summary_columns
from vdbejax.results.grid_result import GridResult
from vdbejax.results.optimal_actions import (
    OPTIMAL_ACTION_COLUMNS,
    optimal_action_summary,
    step_curves,
)
from vdbejax.runs import RunOptions, prepare_grid, run_grid, run_prepared
from vdbejax.runs.optimal_record import optimal_action_mask

SETTINGS = [Setting("sarsa", "vdbe", 0.001), Setting("qlearning", "egreedy", 0.1),
            Setting("qlearning", "vdbe_softmax", 1.0)]


def one_state(rewards, max_steps: int = 1):
    """One state whose action ``a`` pays ``rewards[a]`` (no noise): the return of an
    episode tells how many of its steps took a best-paying action."""
    rewards = np.asarray(rewards, np.float32)[None]
    return make_tabular_mdp(np.zeros(rewards.shape, np.int32), rewards,
                            np.full(rewards.shape, max_steps == 1), [1.0], max_steps=max_steps)


def test_the_mask_is_the_argmax_of_q_star_with_ties():
    assert optimal_action_mask(one_state([0.0, 1.0, 0.5])).tolist() == [[False, True, False]]
    assert optimal_action_mask(one_state([1.0, 0.2, 1.0], 4)).tolist() == [[True, False, True]]
    bandit = make_suite_task("testbed:10")
    means = np.asarray(bandit.reward)[0, :, 0]
    assert optimal_action_mask(bandit)[0].tolist() == (means == means.max()).tolist()
    mask = optimal_action_mask(make_mdp())
    assert mask.shape == (make_mdp().num_states, make_mdp().num_actions) and mask.any(1).all()


def test_the_fraction_counts_the_optimal_steps_exactly():
    # Every optimal step pays 1 (a tie: actions 1 and 3), every other 0: an episode's
    # return is its count of optimal steps.
    mdp = one_state([0.0, 1.0, 0.0, 1.0], max_steps=7)
    result = run_grid(mdp, [Setting("qlearning", "egreedy", 0.5)], num_seeds=3,
                      num_episodes=12, record_optimal=True)
    np.testing.assert_allclose(result.optimal_actions, result.returns / result.lengths,
                               rtol=0, atol=1e-6)
    assert 0 < result.optimal_actions.mean() < 1


@pytest.mark.parametrize("mdp", [make_mdp(), make_suite_task("bernoulli_bandit:5")],
                         ids=["table_cleaning", "bernoulli_bandit"])
def test_every_strategy_batch_and_chunking_gives_every_agent_the_same_record(mdp):
    seeds = 3
    params = engine.broadcast_agents(stack_agents([make_agent(s) for s in SETTINGS]), seeds)
    keys = np.tile(engine.agent_keys(0, seeds), (len(SETTINGS), 1))
    mask = optimal_action_mask(mdp)
    plain = engine.run_agents(mdp, params, keys, 12, engine.EngineOptions(strategy="sequential"))
    assert plain.optimal is None
    records = []
    for options in ({"strategy": "sequential"}, {"strategy": "sequential", "chunk_episodes": 5},
                    {"strategy": "lockstep"}, {"strategy": "lockstep", "max_batch": 2,
                                               "chunk_episodes": 7, "min_batch": 1},
                    {"strategy": "lockstep", "compact": False}):
        run = engine.run_agents(mdp, params, keys, 12, engine.EngineOptions(**options),
                                optimal_action=mask)
        assert np.array_equal(run.returns, plain.returns)
        assert np.array_equal(run.lengths, plain.lengths)
        records.append(run.optimal)
    for record in records[1:]:
        assert np.array_equal(record, records[0])
    assert (records[0] <= plain.lengths).all() and records[0].sum() > 0
    # An agent alone has the record it has in the grid (its last agent, run alone).
    alone = engine.run_agents(mdp, engine.broadcast_agents(stack_agents(
        [make_agent(SETTINGS[-1])]), 1), keys[-1:], 12, optimal_action=mask)
    assert np.array_equal(alone.optimal, records[0][-1:])


def test_a_bad_mask_is_one_line():
    mdp = one_state([0.0, 1.0])
    params = stack_agents([make_agent(SETTINGS[1])])
    with pytest.raises(ValueError, match=r"^optimal_action has shape \(2,\) and dtype bool: must"
                                         r" be bool \[1, 2\]"):
        engine.run_agents(mdp, params, engine.agent_keys(0, 1), 2,
                          optimal_action=np.array([True, False]))


def test_the_record_is_saved_summarised_and_leaves_the_returns(tmp_path):
    mdp = make_suite_task("testbed:10")
    settings = [Setting("sample_average", "egreedy", 0.1), Setting("sample_average", "greedy")]
    plain = run_grid(mdp, settings, num_seeds=4, num_episodes=40)
    recorded = run_grid(mdp, settings, num_seeds=4, num_episodes=40, record_optimal=True)
    assert np.array_equal(plain.returns, recorded.returns)
    assert plain.optimal_actions is None and recorded.optimal_actions.shape == (2, 4, 40)
    assert plain.meta["fingerprint"] != recorded.meta["fingerprint"]
    assert "record_optimal" not in plain.meta and recorded.meta["record_optimal"] is True
    assert not set(OPTIMAL_ACTION_COLUMNS) & set(summary_columns(plain))
    recorded.save(tmp_path)
    loaded = GridResult.load(tmp_path)
    assert np.array_equal(loaded.optimal_actions, recorded.optimal_actions)
    rows = summarize(loaded, last=10)
    assert summary_columns(loaded)[-6:] == OPTIMAL_ACTION_COLUMNS
    table = optimal_action_summary(loaded, 10)
    for row, entry in zip(rows, table, strict=True):
        assert row.optimal_actions == entry["optimal_actions"]
        assert row.optimal_actions_ci_low <= row.optimal_actions <= row.optimal_actions_ci_high
        # One pull per episode: the reward per step is the final return.
        assert row.reward_per_step == pytest.approx(row.final_return)
    optimal, reward = step_curves(loaded, 0)
    assert optimal.shape == reward.shape == (40,)
    np.testing.assert_allclose(optimal, recorded.optimal_actions[0].mean(0), atol=1e-6)
    assert "optimal_actions" in loaded.to_records()
    # A damaged record is refused in one line.
    arrays = dict(np.load(tmp_path / "returns.npz"))
    arrays["optimal_actions"] = arrays["optimal_actions"] * 2
    np.savez(tmp_path / "bad.npz", **arrays)
    from vdbejax.results.record_checks import check_optimal_actions
    with pytest.raises(ValueError, match="optimal_actions must lie in"):
        check_optimal_actions(tmp_path / "bad.npz", arrays["returns"], arrays["lengths"],
                              arrays["optimal_actions"])


def test_a_resume_keeps_the_record(tmp_path):
    mdp = make_suite_task("chain:4")
    settings = [Setting("qlearning", "egreedy", 0.2), Setting("rmax", "greedy")]
    run = RunOptions(record_optimal=True, checkpoint=tmp_path / "c.npz", chunk_episodes=10)
    whole = run_grid(mdp, settings, num_seeds=2, num_episodes=40, record_optimal=True)
    resumed = interrupt_then_resume(mdp, settings, run, 2 * 2 * 20, num_seeds=2,
                                    num_episodes=40)
    assert resumed.meta["resumed_from_agent_episodes"] > 0
    assert np.array_equal(resumed.optimal_actions, whole.optimal_actions, equal_nan=True)
    # A checkpoint of a run that did not record is another run's.
    with pytest.raises(ValueError, match="belongs to a different run"):
        run_prepared(prepare_grid(mdp, settings, num_seeds=2, num_episodes=40,
                                  run=run.replace(resume=True, record_optimal=False)))


def test_the_cli_flag_writes_the_columns(tmp_path, capsys):
    out = tmp_path / "run"
    code = cli.main(["run", "--task", "bernoulli_bandit:3", "--learners", "sample_average",
                     "--explorers", "egreedy", "--axis", "epsilon=0.1", "--seeds", "3",
                     "--episodes", "30", "--record-optimal", "--no-figures", "--quiet",
                     "--out", str(out)])
    assert code in (0, None)
    header = (out / "summary.csv").read_text().splitlines()[0].split(",")
    assert set(OPTIMAL_ACTION_COLUMNS) <= set(header)
    assert "optimal_actions" in np.load(out / "returns.npz").files


def test_the_cli_draws_the_books_two_panels_and_plot_redraws_them(tmp_path, capsys):
    import matplotlib.pyplot as plt

    from vdbejax.results.grid_result import GridResult
    from vdbejax.results.optimal_actions import step_curves
    from vdbejax.results.plotting import optimal_actions_figure

    out = tmp_path / "run"
    code = cli.main(["run", "--task", "testbed:4", "--learners", "sample_average",
                     "--explorers", "egreedy", "--axis", "epsilon=0,0.1", "--seeds", "3",
                     "--episodes", "30", "--record-optimal", "--quiet", "--out", str(out)])
    assert code in (0, None)
    assert (out / "optimal_actions.png").stat().st_size > 0
    result = GridResult.load(out)
    fig = optimal_actions_figure(result)
    reward, optimal = fig.axes
    assert (reward.get_ylabel(), optimal.get_ylabel()) == ("average reward", "% optimal action")
    assert reward.get_xlabel() == optimal.get_xlabel() == "pulls"  # one pull an episode
    fraction, per_step = step_curves(result, 1)
    np.testing.assert_allclose(optimal.get_lines()[1].get_ydata(), 100 * fraction)
    np.testing.assert_allclose(reward.get_lines()[1].get_ydata(), per_step)
    assert [t.get_text() for t in fig.legends[0].get_texts()] == [
        "Sample average, ε-greedy ε=0", "Sample average, ε-greedy ε=0.1"]
    plt.close(fig)
    (out / "optimal_actions.png").unlink()
    assert cli.main(["plot", "--results", str(out)]) in (0, None)
    assert (out / "optimal_actions.png").stat().st_size > 0
    # a run without the record has no such figure, and says what to do
    result.optimal_actions = None
    with pytest.raises(ValueError, match="record_optimal=True"):
        optimal_actions_figure(result)


def test_a_replicate_keeps_its_agents_record():
    from vdbejax.results.replicates import replicate

    mdp = make_suite_task("bernoulli_bandit:4")
    result = run_grid(mdp, [Setting("sample_average", "egreedy", 0.1)], num_seeds=4,
                      num_episodes=10, record_optimal=True)
    result.meta.update(replicates=2, agents_per_replicate=2)
    second = replicate(result, 1)
    assert np.array_equal(second.optimal_actions, result.optimal_actions[:, 2:])
