"""A task family's parameters as sweep axes (issue 48, point 2): a setting's ``task.``
values (``task.std``, ``task.instance``) draw the instances its agents meet."""
from __future__ import annotations

import json

import numpy as np
import pytest

from vdbejax import engine
from vdbejax.envs.suite import make_suite_family, make_suite_task
from vdbejax.methods import sweep
from vdbejax.methods.agents import Setting, make_agent, stack_agents
from vdbejax.runs import prepare_grid, run_grid

SEEDS, EPISODES = 3, 16


def alone(mdp, setting, seed_index, seed=0):
    """One agent's run on its own task."""
    params = engine.broadcast_agents(stack_agents([make_agent(setting)]), 1)
    keys = engine.agent_keys(seed, SEEDS)[seed_index:seed_index + 1]
    return engine.run_agents(mdp, params, keys, EPISODES).returns[0]


def test_task_values_are_the_tasks_not_the_agents():
    plain = Setting("qlearning", "egreedy", 0.1)
    noisy = Setting("qlearning", "egreedy", 0.1, {"task.std": 2.0, "alpha": 0.3})
    assert noisy.task_values == {"std": 2.0} and plain.task_values == {}
    assert make_agent(noisy) == make_agent(Setting("qlearning", "egreedy", 0.1, {"alpha": 0.3}))
    assert "task.std=2" in noisy.label
    settings = sweep(["qlearning"], ["egreedy", "vdbe"], {"task.std": [0.5, 2.0]})
    assert [s.task_values["std"] for s in settings] == [0.5, 2.0, 0.5, 2.0]


def test_every_agent_meets_the_instance_its_seed_and_task_values_draw():
    family = make_suite_family("testbed:4")
    settings = [*sweep(["qlearning"], ["egreedy"], {"task.std": [0.25, 4.0]}),
                Setting("qlearning", "vdbe", 1.0, {"task.std": 0.25})]
    result = run_grid(family, settings, num_seeds=SEEDS, num_episodes=EPISODES, seed=0)
    for c, setting in enumerate(settings):
        for i in range(SEEDS):
            mine = family.generate((0, i), std=setting.task_values["std"])
            assert np.array_equal(alone(mine, setting, i), result.returns[c, i])
    # the arm means are the seed index's whatever the noise; the noise is the setting's
    prepared = prepare_grid(family, settings, num_seeds=SEEDS, num_episodes=EPISODES)
    tables = prepared.instances.tables
    reward = np.asarray(tables.reward)
    assert np.array_equal(reward[:SEEDS], reward[SEEDS:2 * SEEDS])
    std = np.asarray(tables.reward_noise.std)
    assert std[0].max() == 0.25 and std[SEEDS].max() == 4.0 and std[2 * SEEDS].max() == 0.25
    assert result.meta["task_parameters"] == [{"instance": None, "std": 0.25},
                                              {"instance": None, "std": 4.0},
                                              {"instance": None, "std": 0.25}]


def test_a_shared_family_with_its_default_values_is_the_named_task_bit_for_bit():
    settings = [Setting("qlearning", "egreedy", 0.1, {"task.std": 1.0}),
                Setting("sarsa", "vdbe", 1.0, {"task.std": 1.0})]
    shared = make_suite_family("testbed:5", shared=True)
    result = run_grid(shared, settings, num_seeds=SEEDS, num_episodes=EPISODES, seed=3)
    named = run_grid(make_suite_task("testbed:5"),
                     [Setting("qlearning", "egreedy", 0.1), Setting("sarsa", "vdbe", 1.0)],
                     num_seeds=SEEDS, num_episodes=EPISODES, seed=3)
    assert np.array_equal(result.returns, named.returns)
    assert result.meta["instances"] == "shared"
    assert result.meta["best_return"] == pytest.approx(named.meta["best_return"])


def test_an_instance_seed_axis_gives_a_settings_agents_one_instance():
    family = make_suite_family("bernoulli_bandit:3")
    settings = sweep(["qlearning"], ["egreedy"], {"task.instance": [7, 8]})
    result = run_grid(family, settings, num_seeds=SEEDS, num_episodes=EPISODES, seed=1)
    for c, seed in enumerate((7, 8)):
        for i in range(SEEDS):
            assert np.array_equal(alone(family.generate((seed,)), settings[c], i, seed=1),
                                  result.returns[c, i])
    best = result.meta["instance_best_returns"]  # per config: their instances differ
    assert np.shape(best) == (2, SEEDS) and best[0] != best[1]
    assert best[0] == [best[0][0]] * SEEDS
    assert result.meta["instances"] == "shared"


def test_each_config_is_scored_against_its_own_instances():
    from vdbejax.results.analysis import summarize, task_scale
    from vdbejax.results.replicates import replicate

    family = make_suite_family("testbed:4")
    settings = sweep(["qlearning"], ["egreedy"], {"task.instance": [1, 2], "epsilon": [0.1]})
    whole = run_grid(family, settings, num_seeds=4, num_episodes=40, seed=0)
    best, _ = task_scale(whole)
    assert np.shape(best) == (2, 4, 1)
    for c in range(2):  # a config's row is the row of a run of that config alone
        own = run_grid(family, settings[c:c + 1], num_seeds=4, num_episodes=40, seed=0)
        mine, theirs = summarize(whole, window=5)[c], summarize(own, window=5)[0]
        assert (mine.convergence_episode, mine.agents_converged, mine.final_return) == (
            theirs.convergence_episode, theirs.agents_converged, theirs.final_return)
    whole.meta.update(replicates=2, agents_per_replicate=2)
    second = replicate(whole, 1)
    assert second.meta["instance_best_returns"] == [row[2:] for row in
                                                    whole.meta["instance_best_returns"]]
    assert len(summarize(second, window=5)) == 2


def test_what_task_values_refuse_is_one_line():
    family = make_suite_family("testbed:3")
    grid = {"num_seeds": 2, "num_episodes": 4}
    with pytest.raises(ValueError, match=r"^task parameter 'noise' is invalid for testbed:3:"
                                         r" must be one of instance, std$"):
        prepare_grid(family, [Setting("qlearning", "egreedy", 0.1, {"task.noise": 1})], **grid)
    with pytest.raises(ValueError, match=r"^task.std=-1.0 of testbed:3: reward_std"):
        prepare_grid(family, [Setting("qlearning", "egreedy", 0.1, {"task.std": -1.0})], **grid)
    with pytest.raises(ValueError, match=r"^task.instance=-2 is invalid"):
        prepare_grid(family, [Setting("qlearning", "egreedy", 0.1, {"task.instance": -2})],
                     **grid)
    with pytest.raises(ValueError, match=r"^task parameter 'std' is invalid for"
                                         r" bernoulli_bandit:3: must be one of instance$"):
        prepare_grid(make_suite_family("bernoulli_bandit:3"),
                     [Setting("qlearning", "egreedy", 0.1, {"task.std": 1.0})], **grid)
    with pytest.raises(ValueError, match=r"^hyperparameter 'task.std' is invalid for task"
                                         r" chain:4: task parameters need a task family"):
        prepare_grid(make_suite_task("chain:4"),
                     [Setting("qlearning", "egreedy", 0.1, {"task.std": 1.0})], **grid)


def test_the_cli_sweeps_a_task_parameter(tmp_path):
    from vdbejax import cli

    out = tmp_path / "noise"
    argv = ["run", "--task", "testbed:4", "--learners", "qlearning", "--explorers", "egreedy",
            "--axis", "task.std=0.5,2", "--seeds", "3", "--episodes", "20", "--no-figures",
            "--quiet", "--out"]
    assert cli.main([*argv, str(out)]) in (0, None)
    meta = json.loads((out / "meta.json").read_text())
    assert meta["instances"] == "shared" and np.shape(meta["instance_best_returns"]) == (2, 3)
    summary = (out / "summary.csv").read_text()
    assert "task.std" in summary
    again = tmp_path / "again"  # the folder's sweep file reruns the same run
    assert cli.main(["run", "--config", str(out), "--no-figures", "--quiet",
                     "--out", str(again)]) in (0, None)
    assert json.loads((again / "meta.json").read_text())["fingerprint"] == meta["fingerprint"]
    assert cli.main([*argv[:9], "--task", "chain:4", "--seeds", "2", "--quiet", "--out",
                     str(tmp_path / "bad")]) == 2
    assert not (tmp_path / "bad").exists()
