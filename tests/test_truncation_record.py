"""The engine's record of the episodes the step limit cut (``RunResult.cut``,
``GridResult.truncated``): exact where an episode can both end on its own at its last
allowed step and be cut there, the same under both strategies, kept by checkpoints."""
from __future__ import annotations

import numpy as np
import pytest
from small_grid import interrupt_then_resume

from vdbejax import engine
from vdbejax.envs.tabular import make_tabular_mdp
from vdbejax.methods.agents import Setting, make_agent, stack_agents
from vdbejax.results.analysis import summarize
from vdbejax.results.grid_result import GridResult
from vdbejax.runs import RunOptions, run_grid

MAX_STEPS = 3


def stop_or_go():
    """One state, two actions: action 0 ends the episode with reward 1, action 1 stays
    with reward 0. An episode's return is 1 exactly when it ended on its own, so the
    episodes of return 0 are exactly those the limit cut; an episode of ``MAX_STEPS``
    steps may be either."""
    return make_tabular_mdp(next_state=[[0, 0]], reward=[[1.0, 0.0]],
                            terminal=[[True, False]], start_probability=[1.0],
                            max_steps=MAX_STEPS, name="stop_or_go")


def explorers(agents: int):
    return engine.broadcast_agents(stack_agents([make_agent(Setting("qlearning", "egreedy",
                                                                    0.9))]), agents)


def test_cut_is_exact_where_the_last_allowed_step_can_end_an_episode_in_both_strategies():
    mdp, agents, episodes = stop_or_go(), 6, 40
    keys = engine.agent_keys(5, agents)
    runs = {strategy: engine.run_agents(mdp, explorers(agents), keys, episodes,
                                        engine.EngineOptions(strategy=strategy,
                                                             chunk_episodes=7))
            for strategy in ("sequential", "lockstep")}
    for run in runs.values():
        assert run.cut.dtype == np.bool_ and run.cut.shape == (agents, episodes)
        np.testing.assert_array_equal(run.cut, run.returns == 0)
        full = run.lengths == MAX_STEPS
        assert (full & run.cut).any() and (full & ~run.cut).any()  # both endings happen
    np.testing.assert_array_equal(runs["sequential"].cut, runs["lockstep"].cut)
    np.testing.assert_array_equal(runs["sequential"].returns, runs["lockstep"].returns)


def test_summary_and_meta_count_only_the_cut_episodes(tmp_path):
    grid = run_grid(stop_or_go(), [Setting("qlearning", "egreedy", 0.9)], num_seeds=5,
                    num_episodes=30, chunk_episodes=10)
    cut = grid.returns == 0
    np.testing.assert_array_equal(grid.truncated, cut)
    assert grid.meta["truncated_episodes"] == int(cut.sum())
    assert int((grid.lengths == MAX_STEPS).sum()) > grid.meta["truncated_episodes"] > 0
    assert summarize(grid)[0].truncated_fraction == pytest.approx(cut.mean())
    grid.save(tmp_path)  # the record goes with the folder
    loaded = GridResult.load(tmp_path)
    np.testing.assert_array_equal(loaded.truncated, grid.truncated)


def test_a_resumed_run_keeps_the_record(tmp_path):
    settings = [Setting("qlearning", "egreedy", 0.9), Setting("sarsa", "egreedy", 0.5)]
    grid = dict(num_seeds=4, num_episodes=30)
    whole = run_grid(stop_or_go(), settings, chunk_episodes=6, **grid)
    resumed = interrupt_then_resume(stop_or_go(), settings, RunOptions(
        chunk_episodes=6, checkpoint=tmp_path / "c.npz", progress=False), stop_at=2 * 4 * 12,
        **grid)
    assert resumed.meta["resumed_from_agent_episodes"] > 0
    np.testing.assert_array_equal(resumed.truncated, whole.truncated)
    np.testing.assert_array_equal(resumed.returns, whole.returns)
    assert whole.truncated.any()


def test_a_damaged_record_is_refused_on_loading(tmp_path):
    grid = run_grid(stop_or_go(), [Setting("qlearning", "egreedy", 0.9)], num_seeds=2,
                    num_episodes=10)
    grid.truncated = grid.truncated | (grid.lengths < MAX_STEPS)
    grid.save(tmp_path)
    with pytest.raises(ValueError, match="truncated marks an episode that did not last"):
        GridResult.load(tmp_path)
