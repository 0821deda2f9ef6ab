"""Estimates before any work (issue "Nothing silent", point 6): memory, disk and time of a
run, and the announcement of a long one before it starts."""
from __future__ import annotations

import pytest

from vdbejax import cli
from vdbejax.runs import estimate
from vdbejax.runs.batching import check_run_size


def test_the_issues_ten_million_episodes_are_a_long_run() -> None:
    # `vdbejax run --seeds 1 --episodes 10000000` trained, then spent minutes on its statistics
    long = estimate.estimate_run(1, 1, 10_000_000)
    assert long.long and long.statistics_seconds > estimate.LONG_SECONDS
    assert long.training_seconds >= 10_000_000 / estimate.MAX_LANE_STEPS_PER_SECOND
    text = long.describe()
    assert "1 agents × 10,000,000 episodes: training ≥" in text
    assert "statistics and figures ≈" in text and "checkpoint ≈ 76.3 MiB" in text


def test_the_paper_grid_is_not_announced() -> None:
    paper = estimate.estimate_run(46, 20, 1000, cores=2)
    assert not paper.long and paper.seconds < 10


def test_memory_counts_the_results_as_the_size_check_does() -> None:
    run = estimate.estimate_run(4, 25, 5000, statistics=False)
    assert run.memory_bytes == check_run_size(100, 5000)
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


@pytest.mark.parametrize("seconds, text", [(42, "42 s"), (210, "3.5 min"),
                                           (7560, "2.1 h")])
def test_durations_read_as_people_say_them(seconds: float, text: str) -> None:
    assert estimate.duration(seconds) == text


def test_a_long_run_is_announced_before_it_starts(tmp_path, capsys, monkeypatch) -> None:
    monkeypatch.setattr(estimate, "LONG_SECONDS", 0.0)
    args = ["run", "--out", str(tmp_path / "r"), "--learners", "qlearning", "--explorers",
            "egreedy", "--axis", "epsilon=0.1", "--seeds", "2", "--episodes", "10"]
    assert cli.main(args) == 0
    err = capsys.readouterr().err
    first = err.strip().splitlines()[0]
    assert first.startswith("a long run: 2 agents × 10 episodes: training ≥"), err
    assert "Ctrl-C keeps its checkpoint, --resume continues" in first
    assert cli.main([*args[:2], str(tmp_path / "q"), *args[3:], "--quiet"]) == 0
    assert "a long run" not in capsys.readouterr().err  # --quiet: no status lines
