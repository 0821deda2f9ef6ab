"""Estimates before any work (issue "Nothing silent", point 6): memory, disk and time of a
run, and the announcement of a long one before it starts."""
from __future__ import annotations

import pytest

from vdbejax import cli
from vdbejax.runs import estimate
from vdbejax.runs.batching import check_run_size


def test_ten_million_episodes_of_two_seeds_are_a_long_run() -> None:
    # `vdbejax run --seeds 1 --episodes 10000000` trained, then spent minutes on its
    # statistics; one seed's bootstrap is now computed once (29 s in all), two seeds' is not
    long = estimate.estimate_run(1, 2, 10_000_000)
    assert long.long and long.statistics_seconds > estimate.LONG_SECONDS
    assert long.training_seconds >= 10_000_000 / estimate.MAX_LANE_STEPS_PER_SECOND
    text = long.describe()
    assert "2 agents × 10,000,000 episodes: training ≥" in text
    assert "statistics and figures ≈" in text and "checkpoint ≈ 171.7 MiB" in text
    one_seed = estimate.estimate_run(1, 1, 10_000_000)
    assert one_seed.statistics_seconds < 1.0 and not one_seed.long


def test_the_paper_grid_is_not_announced() -> None:
    paper = estimate.estimate_run(46, 20, 1000, cores=2)
    assert not paper.long and paper.seconds < 10


def test_memory_counts_the_results_as_the_size_check_does() -> None:
    run = estimate.estimate_run(4, 25, 5000, statistics=False)
    assert run.memory_bytes == check_run_size(100, 5000, num_settings=4)
    assert run.statistics_seconds == 0.0
    with_statistics = estimate.estimate_run(4, 25, 5000)
    assert with_statistics.memory_bytes > run.memory_bytes
    assert estimate.estimate_run(4, 25, 5000, checkpoint=False).disk_bytes == 0


def test_training_is_bounded_by_the_cores_and_by_one_agents_steps() -> None:
    wide = estimate.estimate_run(1000, 100, 100, statistics=False, cores=2)
    assert wide.training_seconds == pytest.approx(
        1000 * 100 * 100 / (2 * estimate.MAX_STEPS_PER_SECOND))
    deep = estimate.estimate_run(1, 1, 10**8, statistics=False, cores=2)
    assert deep.training_seconds == pytest.approx(10**8 / estimate.MAX_LANE_STEPS_PER_SECOND)


@pytest.mark.parametrize("seconds, text", [(0.04, "0.04 s"), (3.456, "3.5 s"), (42, "42 s"),
                                           (210, "3.5 min"),
                                           (7560, "2.1 h")])
def test_durations_read_as_people_say_them(seconds: float, text: str) -> None:
    assert estimate.duration(seconds) == text


def test_a_long_run_is_announced_before_it_starts(tmp_path, capsys, monkeypatch) -> None:
    monkeypatch.setattr(estimate, "LONG_SECONDS", 0.0)
    args = ["run", "--out", str(tmp_path / "r"), "--learners", "qlearning", "--explorers",
            "egreedy", "--axis", "epsilon=0.1", "--seeds", "2", "--episodes", "10"]
    assert cli.main(args) == 0
    err = capsys.readouterr().err
    defaults, first = err.strip().splitlines()[:2]  # the learner values, then the plan
    assert defaults.startswith("learner defaults: "), err
    assert first.startswith("a long run: 2 agents × 10 episodes: training ≥"), err
    assert "Ctrl-C keeps its checkpoint, --resume continues" in first
    assert cli.main([*args[:2], str(tmp_path / "q"), *args[3:], "--quiet"]) == 0
    assert "a long run" not in capsys.readouterr().err  # --quiet: no status lines


def _mdp(next_state, terminal, probability=None, max_steps=50):
    import numpy as np

    from vdbejax.envs import make_tabular_mdp

    next_state = np.asarray(next_state, np.int32)
    start = np.zeros(next_state.shape[0])
    start[0] = 1.0
    return make_tabular_mdp(next_state, np.zeros(next_state.shape, np.float32),
                            np.asarray(terminal, bool), start, probability=probability,
                            max_steps=max_steps)


def test_an_episode_is_at_least_the_tasks_shortest_one() -> None:
    from vdbejax.envs.solvers import shortest_episode
    from vdbejax.studies.task_names import make_task

    # 0 -> 1 -> 2 -> end, or 0 -> 0 forever: three steps at the fewest
    chain = _mdp([[[1], [0]], [[2], [1]], [[2], [2]]],
                 [[[False], [False]], [[False], [False]], [[True], [False]]])
    assert shortest_episode(chain) == 3
    # an unlikely outcome counts: action 1 of state 0 ends the episode with probability 0.1
    rare = _mdp([[[1, 1], [0, 2]], [[2, 2], [1, 1]], [[2, 2], [2, 2]]],
                [[[False] * 2, [False, True]], [[False] * 2] * 2, [[True] * 2] * 2],
                probability=[[[0.5, 0.5], [0.9, 0.1]], [[0.5, 0.5]] * 2, [[0.5, 0.5]] * 2])
    assert shortest_episode(rare) == 1
    # nothing ends an episode early: every one runs to the step limit
    assert shortest_episode(make_task("riverswim")) == int(make_task("riverswim").max_steps)
    assert shortest_episode(make_task("deepsea:6")) == 6
    assert shortest_episode(make_task("chain:8", max_steps=40)) == 40


def test_the_training_bound_counts_the_shortest_episode_and_the_stop_policy() -> None:
    from vdbejax.methods import Setting
    from vdbejax.runs import RunOptions, UntilSolved, prepare_grid
    from vdbejax.studies.task_names import make_task

    mdp = make_task("riverswim")
    settings = [Setting("qlearning", "egreedy", 0.1)]
    fixed = estimate.estimate_prepared(prepare_grid(mdp, settings, num_seeds=4,
                                                    num_episodes=300))
    assert fixed.fewest_steps == fixed.most_steps == 4 * 300 * 20  # no early end
    assert "(24.0 k agent-steps)" in fixed.describe()  # a range only when there is one
    one_step = estimate.estimate_run(1, 4, 300, statistics=False)
    assert fixed.training_seconds == pytest.approx(20 * one_step.training_seconds)
    solving = estimate.estimate_prepared(prepare_grid(
        mdp, settings, num_seeds=4, num_episodes=300, run=RunOptions(stop=UntilSolved(
            window=25))))
    assert (solving.fewest_steps, solving.most_steps) == (4 * 25 * 20, 4 * 300 * 20)
    assert UntilSolved(max_seconds=5.0).fewest_episodes(300) == 1


def test_a_long_study_is_announced_whole_before_its_folder_is_made(
        tmp_path, capsys, monkeypatch) -> None:
    from vdbejax.studies import bench

    class Stop(Exception):
        pass

    def refuse(*args, **kwargs):
        raise Stop

    monkeypatch.setattr(bench, "output_folder", refuse)
    methods = ["egreedy", "rmax"]
    with pytest.raises(Stop):  # 2 tasks × (tuning + reported run), 10^6 episodes each
        bench.run_bench(tmp_path / "b", tasks=["riverswim", "deepsea:6"], methods=methods,
                        episodes=10**6, seeds=2, choice=bench.MethodChoice(tune_seeds=1))
    err = capsys.readouterr().err
    assert err.startswith("a study: 4 runs: training ≥"), err
    parts = []
    for task in bench.make_tasks(["riverswim", "deepsea:6"]):
        pool = sum(len(m.candidates(task.scale)) for m in bench.select_methods(methods))
        parts += [estimate.estimate_task(task.mdp, pool, 1, 10**6, statistics=False),
                  estimate.estimate_task(task.mdp, 2, 2, 10**6, statistics=False)]
    assert f"training ≥ {estimate.duration(sum(p.training_seconds for p in parts))}" in err
    assert not (tmp_path / "b").exists()


MILLION_AXES = ["--axis", "alpha=" + ",".join(f"{0.001 * (i + 1):.3f}" for i in range(1000)),
                "--axis", "sigma=" + ",".join(str(i + 1) for i in range(1000))]


def test_a_sweep_of_a_million_settings_is_refused_before_any_is_made(tmp_path, monkeypatch):
    # Issue 49, point 9: 10⁶ settings passed MAX_SETTINGS and took > 7 GiB before any
    # estimate. Counted from the axes, its settings and results are checked first.
    import time
    import tracemalloc

    from vdbejax.runs import RunOptions, batching
    from vdbejax.studies.sweeps import Sweep, run_sweep

    monkeypatch.setattr(batching, "_host_available_bytes", lambda: 8 * 2**30)
    axes = {"alpha": [0.001 * (i + 1) for i in range(1000)], "sigma": list(range(1, 1001))}
    started = time.perf_counter()
    tracemalloc.start()
    try:
        with pytest.raises(ValueError) as refused:
            run_sweep(tmp_path / "big", Sweep(learners=["qlearning"], explorers=["vdbe"],
                                              axes=axes), seeds=1, episodes=1000, run=RunOptions(progress=False))
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 16 * 2**20  # nothing of the million settings was made
    assert time.perf_counter() - started < 10
    message = str(refused.value)
    assert message.startswith("the run is too large for this machine: 1,000,000 settings")
    assert "the settings ≈ 3.8 GiB" in message and "8.0 GiB are free" in message
    fit = 8 * 2**30 // (batching.SETTING_BYTES + batching.result_bytes(1, 1000))
    assert f"at most {fit:,} settings of this size fit" in message
    assert not (tmp_path / "big").exists()


def test_the_cli_refuses_it_in_one_line(tmp_path, capsys, monkeypatch):
    from vdbejax.runs import batching

    monkeypatch.setattr(batching, "_host_available_bytes", lambda: 8 * 2**30)
    args = ["run", "--out", str(tmp_path / "big"), "--learners", "qlearning", "--explorers",
            "vdbe", *MILLION_AXES]
    assert cli.main(args) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: the run is too large"), lines
    assert "1,000,000 settings (20,000,000 agents) × 1,000 episodes" in lines[0]
    assert not (tmp_path / "big").exists()


def test_the_printed_plan_states_the_settings_memory(tmp_path, capsys, monkeypatch) -> None:
    text = estimate.estimate_run(10**6, 1, 10).describe()
    assert "memory ≈ 5.1 GiB (the 1,000,000 settings ≈ 3.8 GiB)" in text
    monkeypatch.setattr(estimate, "LONG_SECONDS", 0.0)
    monkeypatch.setattr(estimate, "LARGE_SWEEP_SETTINGS", 2)  # a large sweep: announced first
    args = ["run", "--out", str(tmp_path / "r"), "--learners", "qlearning", "--explorers",
            "egreedy", "--axis", "epsilon=0.1,0.2", "--seeds", "2", "--episodes", "10"]
    assert cli.main(args) == 0
    first, defaults, second = capsys.readouterr().err.strip().splitlines()[:3]
    assert defaults.startswith("learner defaults: ")
    assert first.startswith("a sweep of 2 settings (4 agents × 10 episodes): preparing them ≈")
    assert "(the settings ≈ 8.0 KiB)" in first
    assert second.startswith("a long run: 4 agents × 10 episodes")
    assert "(the 2 settings ≈ 8.0 KiB, the agents' states ≈" in second


def test_a_run_that_needs_much_memory_is_announced_with_its_agents_states(
        tmp_path, capsys, monkeypatch) -> None:
    from vdbejax.engine.agent_state import state_bytes
    from vdbejax.envs.table_cleaning import make_mdp
    from vdbejax.methods.agents import Setting, table_layout
    from vdbejax.runs import prepare_grid
    from vdbejax.runs.batching import SCALAR_BYTES, bytes_per_agent

    prepared = prepare_grid(make_mdp(), [Setting("qlearning", "egreedy")], num_seeds=100_000,
                            num_episodes=20)
    run = estimate.estimate_prepared(prepared)
    plan = prepared.plan  # the states of a batch, as the engine holds them
    layout = table_layout(prepared.params)
    per_agent = bytes_per_agent(prepared.mdp, min(plan.chunk_episodes, 20), layout) + (
        estimate.CHECKPOINT_STATE_COPIES * (state_bytes(prepared.mdp, layout) + SCALAR_BYTES))
    assert run.agents_bytes == min(plan.batch_size, 100_000) * per_agent > 0
    assert run.memory_bytes >= run.agents_bytes > 2 * 2**30  # the CLI peaked at 2.5 GiB
    monkeypatch.setattr(estimate, "LARGE_MEMORY_BYTES", 1)  # every run is large, then
    assert cli.main(["run", "--out", str(tmp_path / "r"), "--learners", "qlearning",
                     "--explorers", "egreedy", "--seeds", "2", "--episodes", "10"]) == 0
    defaults, first = capsys.readouterr().err.strip().splitlines()[:2]
    assert defaults.startswith("learner defaults: ")
    assert first.startswith("a run: 2 agents × 10 episodes: training ≥"), first
    assert "the agents' states ≈" in first
