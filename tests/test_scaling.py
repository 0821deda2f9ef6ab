"""Adaptive budgets equal a fixed budget for every agent they let finish; the scaling
study end to end from the command line; bad inputs fail in one line before training; the
report imports nothing of the runner."""
from __future__ import annotations

import ast
import csv
import json
from pathlib import Path

import numpy as np
import pytest
from small_grid import assert_fixed_budget_up_to_each_stop

from vdbejax import cli
from vdbejax.envs import solvers
from vdbejax.envs.table_cleaning import make_mdp
from vdbejax.methods.agents import Setting
from vdbejax.results.grid_result import GridResult
from vdbejax.results.solving import convergence_threshold, episodes_to_converge
from vdbejax.runs import RunOptions, UntilSolved, run_grid
from vdbejax.studies import scaling, scaling_adaptive, scaling_report

REPO = Path(__file__).resolve().parents[1]
#: Fast learners, slow ones and one that never solves the paper's task (SARSA + VDBE).
SETTINGS = [
    Setting("qlearning", "vdbe_softmax", 1.0),
    Setting("qlearning", "softmax", 0.001),
    Setting("qlearning", "egreedy_decay", 1.0),
    Setting("sarsa", "vdbe", 1.0),
]
SEEDS, EPISODES, CHUNK, SEED = 3, 360, 40, 5


@pytest.fixture(scope="module")
def task():
    mdp = make_mdp()
    return mdp, solvers.best_return(mdp), solvers.uniform_random_return(mdp)


@pytest.fixture(scope="module")
def fixed(task):
    return run_grid(task[0], SETTINGS, num_seeds=SEEDS, num_episodes=EPISODES, seed=SEED)


@pytest.fixture(scope="module")
def adaptive(task):
    return scaling_adaptive.run_until_solved(task[0], SETTINGS, num_seeds=SEEDS, max_episodes=EPISODES,
                                    seed=SEED, best=task[1], baseline=task[2],
                                    run=RunOptions(chunk_episodes=CHUNK))


def test_adaptive_stopping_equals_the_fixed_budget_up_to_each_stop(adaptive, fixed, task):
    run = adaptive
    stop = run.episodes_run
    assert run.stopped == "episodes"  # SARSA + VDBE never solves: censored at the budget
    assert (stop[:2] < EPISODES).all() and (stop[3] == EPISODES).all()
    assert (stop % CHUNK == 0).all()  # agents leave at the end of a chunk
    assert_fixed_budget_up_to_each_stop(run, fixed, stop)
    # The same solve episodes as measured on the fixed run's full curves.
    full = episodes_to_converge(fixed.returns, task[1], task[2])
    np.testing.assert_array_equal(run.solve.solved, full.solved)
    np.testing.assert_array_equal(run.solve.episodes, full.episodes)
    # A solved agent stops at the end of the chunk in which it solved.
    solved = run.solve.solved
    assert (stop[solved] == -(-run.solve.episodes[solved] // CHUNK) * CHUNK).all()
    # Solved agents cost no more compute: fewer agent-episodes than the fixed budget.
    assert run.episodes_run.sum() < stop.size * EPISODES
    assert run.agent_steps == int(fixed.lengths[np.arange(EPISODES) < stop[..., None]].sum())
    np.testing.assert_array_equal(run.nonfinite, fixed.nonfinite)


def test_stop_episodes_depend_on_the_chunk_but_solve_episodes_do_not(adaptive, task):
    other = scaling_adaptive.run_until_solved(task[0], SETTINGS[:2], num_seeds=SEEDS,
                                     max_episodes=EPISODES, seed=SEED, best=task[1],
                                     baseline=task[2], run=RunOptions(chunk_episodes=25))
    np.testing.assert_array_equal(other.solve.episodes, adaptive.solve.episodes[:2])
    assert other.stopped == "solved" and (other.episodes_run % 25 == 0).all()
    common = np.minimum(other.episodes_run, adaptive.episodes_run[:2])
    for c in range(2):
        for i in range(SEEDS):
            np.testing.assert_array_equal(other.returns[c, i, :common[c, i]],
                                          adaptive.returns[c, i, :common[c, i]])


def test_a_seconds_budget_censors_every_remaining_agent_at_one_episode(task):
    run = scaling_adaptive.run_until_solved(task[0], SETTINGS[3:], num_seeds=2, max_episodes=10_000,
                                   max_seconds=1e-6, best=task[1], baseline=task[2],
                                   run=RunOptions(chunk_episodes=CHUNK))
    assert run.stopped == "seconds" and run.chunks == 1
    assert (run.episodes_run == CHUNK).all() and not run.solve.solved.any()


@pytest.mark.parametrize("kwargs,match", [
    ({"num_seeds": 0}, "num_seeds=0 is invalid"),
    ({"max_episodes": 0}, "max_episodes=0 is invalid"),
    ({"max_seconds": -1}, "max_seconds=-1 is invalid"),
    ({"best": -1.5}, "best=-1.5 and baseline=-1.047"),
    ({"baseline": None}, "give both"),
    ({"fraction": 2.0}, "fraction=2.0 is invalid"),
    ({"run": RunOptions(stop=UntilSolved(fraction=0.5))}, "run.stop=.* run_until_solved"),
])
def test_run_until_solved_bad_inputs(task, kwargs, match):
    options = dict(num_seeds=2, max_episodes=10, best=task[1], baseline=task[2])
    options.update(kwargs)
    with pytest.raises(ValueError, match=match) as error:
        scaling_adaptive.run_until_solved(task[0], SETTINGS[:1], **options)
    assert "\n" not in str(error.value)


def test_the_paper_methods_are_the_paper_grids_best_settings():
    rows = list(csv.DictReader(open(REPO / "docs" / "ablation" / "spec" / "summary.csv")))
    chosen = scaling.best_parameters(rows)
    for method in scaling.METHODS:
        if method.explorer in scaling.PAPER_METHODS:
            assert chosen[method.explorer] == method.param, method


def test_parse_sizes():
    assert scaling.parse_sizes("2x1, 4X2") == [(2, 1), (4, 2)]
    assert scaling.parse_sizes(["6x3"]) == [(6, 3)]
    for bad, match in (("", "at least one"), ("1x1", "N >= 2"), ("4x0", "K >= 1"),
                       ("4by2", "NxK"), ("2x1,2x1", "twice")):
        with pytest.raises(ValueError, match=match):
            scaling.parse_sizes(bad)


# ---------------------------------------------------------------- the command line


def test_scale_cli_end_to_end(tmp_path, capsys):
    out = tmp_path / "scale"
    code = cli.main(["scale", "--out", str(out), "--sizes", "2x1", "--seeds", "2",
                     "--episodes", "300", "--chunk-episodes", "60", "--quiet"])
    assert code == 0, capsys.readouterr().err
    for name in ("scaling.csv", "scaling.md", "scaling.png", "meta.json", "runs/2x1/returns.npz"):
        assert (out / name).is_file(), name
    rows = list(csv.DictReader(open(out / "scaling.csv")))
    # Every method of the study with both learners, the count-bonus plug-in included.
    assert len(rows) == 2 * len(scaling.METHODS)
    assert {r["explorer"] for r in rows} == {m.explorer for m in scaling.METHODS}
    assert {r["learner"] for r in rows} == {"qlearning", "sarsa"}
    assert all(r["size"] == "2x1" and r["states"] == "60" and r["agents"] == "2" for r in rows)
    # Solved is the one rule of every report: a normalised score of 0.9 (0 = random policy).
    mdp = make_mdp()
    best, random = solvers.best_return(mdp), solvers.uniform_random_return(mdp)
    assert float(rows[0]["random_return"]) == pytest.approx(random, rel=1e-4)
    assert float(rows[0]["threshold"]) == pytest.approx(convergence_threshold(best, random), rel=1e-4)
    solved = scaling_adaptive.adaptive_run(GridResult.load(out / "runs" / "2x1"))
    expected = episodes_to_converge(solved.returns, best, random,
                                    episodes_run=solved.episodes_run)
    np.testing.assert_array_equal(solved.solve.episodes, expected.episodes)
    vdbe_softmax = next(r for r in rows if r["learner"] == "qlearning"
                        and r["explorer"] == "vdbe_softmax")
    assert vdbe_softmax["solved"] == "2" and 20 <= float(vdbe_softmax["median_episodes"]) <= 300
    markdown = (out / "scaling.md").read_text()
    assert "Command: `vdbejax scale --out" in markdown and "| method | 2x1 (60) |" in markdown
    meta = json.loads((out / "meta.json").read_text())
    assert meta["options"]["sizes"] == ["2x1"] and meta["variants"][0]["agent_steps"] > 0
    printed = capsys.readouterr().out
    assert "2x1" in printed and "VDBE-Softmax" in printed
    # The saved folder redraws without training: the same table.
    loaded_rows, variants, loaded_meta = scaling_report.load_scaling(out)
    assert [r["_setting"] for r in loaded_rows] == scaling.study_settings()
    again = tmp_path / "again"
    again.mkdir()
    scaling_report.write_reports(again, loaded_rows, variants, loaded_meta)
    assert (again / "scaling.md").read_text() == markdown and (again / "scaling.png").is_file()


@pytest.mark.parametrize("args,match", [
    (["--sizes", "1x1"], "sizes has '1x1'"),
    (["--seeds", "0"], "seeds=0 is invalid"),
    (["--episodes", "ten"], "episodes='ten' is invalid"),
    (["--seconds", "0"], "seconds=0 is invalid"),
    (["--fraction", "1.5"], "fraction=1.5 is invalid"),
    (["--window", "0"], "window=0 is invalid"),
    (["--methods", "egreedy,telepathy"], "methods has 'telepathy'"),
    (["--learners", "qlearning,oracle"], "learner='oracle' is invalid"),
    (["--memory-budget", "lots"], "memory_budget_bytes='lots' is invalid"),
    (["--devices", "0"], "devices=0 is invalid"),
])
def test_scale_cli_bad_input_is_one_line_before_training(tmp_path, capsys, monkeypatch,
                                                        args, match):
    def no_training(*_args, **_kwargs):
        raise AssertionError("training started")

    monkeypatch.setattr(scaling, "train_until_solved", no_training)
    code = cli.main(["scale", "--out", str(tmp_path / "bad"), "--quiet", *args])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and err[0].startswith("error: "), err
    assert match in err[0]
    assert not (tmp_path / "bad" / "scaling.csv").exists()


@pytest.mark.parametrize("kwargs,match", [
    ({"size": {"seeds": 3}}, "size={'seeds': 3} is invalid: must be a ScalingSize"),
    ({"size": scaling.ScalingSize(seeds=0)}, "seeds=0 is invalid"),
    ({"size": scaling.ScalingSize(sizes="2x1", episodes=10)},
     "window=20 is invalid with episodes=10"),
    ({"solve": UntilSolved(best=1.0, baseline=0.0)}, "solve.best=1.0 is invalid"),
    ({"solve": 0.9}, "solve=0.9 is invalid: must be an UntilSolved"),
    ({"outputs": "scaling.png"}, "outputs='scaling.png' is invalid: must be a StudyOutputs"),
])
def test_run_scaling_bad_inputs_fail_in_one_line_before_anything_is_written(
        tmp_path, kwargs, match):
    with pytest.raises(ValueError, match=match) as error:
        scaling.run_scaling(tmp_path / "bad", run=RunOptions(progress=False), **kwargs)
    assert "\n" not in str(error.value) and not (tmp_path / "bad").exists()


def test_scale_resumes_an_interrupted_study(tmp_path, monkeypatch, capsys):
    from vdbejax.runs import grid

    small = ["--sizes", "2x1,3x1", "--seeds", "2", "--episodes", "200", "--chunk-episodes",
             "20", "--methods", "egreedy,vdbe_softmax", "--learners", "qlearning", "--quiet"]
    whole, out = tmp_path / "whole", tmp_path / "resumed"
    assert cli.main(["scale", "--out", str(whole), *small]) == 0
    real, calls = grid.drive, []

    def drive_then_stop(*args, **kwargs):  # the second variant stops after its 3rd chunk
        calls.append(1)
        if len(calls) == 2:
            def stop(done, total, elapsed, seen=[]):
                seen.append(done)
                if len(seen) == 4:
                    raise KeyboardInterrupt
            kwargs["progress"] = stop
        return real(*args, **kwargs)

    monkeypatch.setattr(grid, "drive", drive_then_stop)
    assert cli.main(["scale", "--out", str(out), *small]) == 130
    assert (out / "runs" / "2x1" / "returns.npz").is_file()
    assert (out / "runs" / "3x1" / "checkpoint.npz").is_file()
    monkeypatch.setattr(grid, "drive", real)
    assert cli.main(["scale", "--out", str(out), *small, "--resume"]) == 0
    assert (out / "scaling.csv").read_text() == (whole / "scaling.csv").read_text()
    resumed = json.loads((out / "runs" / "3x1" / "meta.json").read_text())
    assert resumed["resumed_from_agent_episodes"] > 0
    assert not (out / "runs" / "3x1" / "checkpoint.npz").exists()


# ---------------------------------------------------------------- the modules
def _imported_modules(module) -> set[str]:
    """Every module ``module``'s source imports, at the top or inside a function."""
    tree = ast.parse(Path(module.__file__).read_text(encoding="utf-8"))
    names = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names |= {alias.name for alias in node.names}
        elif isinstance(node, ast.ImportFrom) and node.module:
            names |= {node.module} | {f"{node.module}.{alias.name}" for alias in node.names}
    return names


def test_the_report_imports_nothing_of_the_runner():
    # The data flow one way: runner -> results -> report; training until solved needs
    # neither the study nor its report.
    runner = {"vdbejax.studies.scaling", "vdbejax.studies.scaling_adaptive"}
    assert not _imported_modules(scaling_report) & runner
    assert not _imported_modules(scaling_adaptive) & (runner | {"vdbejax.studies.scaling_report"})
    assert "vdbejax.studies.scaling_report" in _imported_modules(scaling)  # the check can fail
