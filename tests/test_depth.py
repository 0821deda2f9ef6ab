"""``vdbejax depth``: the tasks of growing depth, the solve criterion (the benchmark's), the
growth slopes, resume and the command line (the --quick study end to end)."""
from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from vdbejax import cli
from vdbejax.envs.solvers import best_return
from vdbejax.results.regret import normalised_returns
from vdbejax.results.solving import episodes_to_converge
from vdbejax.runs import RunOptions
from vdbejax.studies import StudyOutputs, depth
from vdbejax.studies.bench import SOLVED
from vdbejax.studies.bench_methods import select_methods


def test_the_chain_of_the_study_is_deterministic_and_rewards_the_far_end() -> None:
    for n in (4, 16):
        task = depth.depth_task("chain", n)
        assert task.mdp.max_steps == 2 * n
        assert np.isin(np.asarray(task.mdp.probability), (0.0, 1.0)).all()
        # forward all the way: n − 1 steps for nothing, then 10 a step for the rest
        assert task.best == pytest.approx(10.0 * (2 * n - (n - 1)))
        assert task.best > 4 * task.baseline
    sea = depth.depth_task("deepsea", 8)
    assert sea.mdp.max_steps == 8 and sea.best == pytest.approx(best_return(sea.mdp))


def test_growth_slopes_recover_a_polynomial_and_an_exponential() -> None:
    methods = select_methods("egreedy,rmax")
    rows = []
    for n in (4, 8, 16):
        for method, episodes in (("egreedy", 2.0 ** n), ("rmax", 3.0 * n ** 2)):
            rows.append({"family": "deepsea", "size": n, "method": method,
                         "median_episodes": episodes, "budget": 10 ** 6,
                         "_episodes": np.full(7, episodes)})
    slopes = {s["method"]: s for s in depth.growth_slopes(rows, methods, ["deepsea"])}
    assert slopes["rmax"]["exponent"] == pytest.approx(2.0)
    assert slopes["egreedy"]["doubling"] == pytest.approx(1.0)
    assert slopes["egreedy"]["exponent"] > 2.5  # log-log: steeper than any square
    for s in slopes.values():  # no spread among the agents: the intervals are points
        assert s["exponent_low"] == pytest.approx(s["exponent"])
        assert s["doubling_high"] == pytest.approx(s["doubling"])
        assert s["sizes_fitted"] == 3 and s["largest_solved"] == 16
    rows[-1]["median_episodes"] = math.inf  # rmax censored at N = 16: two depths, no fit
    slopes = {s["method"]: s for s in depth.growth_slopes(rows, methods, ["deepsea"])}
    assert slopes["rmax"]["sizes_fitted"] == 2 and slopes["rmax"]["largest_solved"] == 8
    assert math.isnan(slopes["rmax"]["exponent"]) and math.isnan(slopes["rmax"]["doubling"])


@pytest.fixture(scope="module")
def quick(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, depth.DepthResult]:
    out = tmp_path_factory.mktemp("depth")
    return out, depth.run_depth(out, quick=True,
                                run=RunOptions(progress=False, evaluate_every=100))


def test_quick_study_writes_its_report(quick: tuple[Path, depth.DepthResult]) -> None:
    out, result = quick
    for name in ("depth.md", "depth.csv", "depth_slopes.csv", "depth.png",
                 "depth_policy_gap.png", "meta.json"):
        assert (out / name).is_file(), name
    families, sizes = depth.FAMILIES, depth.QUICK_SIZES
    assert len(result.rows) == len(families) * len(sizes) * len(depth.QUICK_METHODS)
    assert len(result.slopes) == len(families) * len(depth.QUICK_METHODS)
    rmax = [r for r in result.rows if r["method"] == "rmax" and r["family"] == "deepsea"]
    assert all(r["solved"] == r["agents"] for r in rmax)  # R-max solves small seas
    meta = json.loads((out / "meta.json").read_text())
    assert meta["options"]["sizes"] == list(sizes)
    # evaluate_every: the greedy policies per depth (R-max's are optimal once solved)
    assert all(r["optimal_fraction"] == 1.0 and abs(r["policy_gap"]) < 1e-3 for r in rmax)
    assert "Greedy policies at each agent's last evaluation" in (out / "depth.md").read_text()
    text = (out / "depth.md").read_text()
    assert "## DeepSea" in text and "| R-max |" in text


def test_solved_is_the_benchmarks_criterion(quick: tuple[Path, depth.DepthResult]) -> None:
    _, result = quick
    for name, run in result.runs.items():
        family, size = name.split(":")
        task = depth.depth_task(family.replace("chain_deterministic", "chain"), int(size))
        returns = np.where(np.isnan(run.returns), 0.0, run.returns)
        expected = episodes_to_converge(normalised_returns(returns, task.best, task.baseline),
                                        1.0, 0.0, fraction=SOLVED,
                                        episodes_run=run.episodes_run)
        np.testing.assert_array_equal(run.solve.solved, expected.solved)
        np.testing.assert_array_equal(run.solve.episodes, expected.episodes)


def test_resume_reuses_whole_task_folders(quick: tuple[Path, depth.DepthResult]) -> None:
    out, result = quick
    again = depth.run_depth(out, quick=True, outputs=StudyOutputs(save_runs=False),
                            run=RunOptions(  # the same run
                                progress=False, resume=True, evaluate_every=100))
    for name, run in result.runs.items():
        np.testing.assert_array_equal(again.runs[name].returns, run.returns)
    assert [r["median_text"] for r in again.rows] == [r["median_text"] for r in result.rows]
    # save_runs=False: the task folders go once the study's files are written
    assert (out / "depth.md").is_file() and not any((out / "runs").glob("*"))


@pytest.mark.parametrize("args, message", [
    (["--families", "deepsea,nope"], "families='deepsea,nope' is invalid"),
    (["--sizes", "8,16"], "need at least 3 distinct sizes"),
    (["--sizes", "4,1"], "sizes=1 is invalid"),
    (["--methods", "nope"], "methods="),
    (["--episodes", "5"], "episodes=5 is invalid"),
    (["--quick", "--seeds", "2"], "--quick sets the depth study's size: leave out --seeds"),
    (["--quick", "--evaluate-every", "50"], "evaluate_every=50 is invalid with episodes=100"),
])
def test_bad_input_is_one_line_before_anything_is_written(tmp_path: Path, capsys, args,
                                                          message) -> None:
    out = tmp_path / "d"
    assert cli.main(["depth", "--out", str(out), *args]) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: ") and message in lines[0], lines
    assert not out.exists()
