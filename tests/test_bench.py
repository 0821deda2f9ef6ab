"""``vdbejax bench``: the methods' one rule, the tuning on other seeds, the report, resume
and the command line (the --quick benchmark end to end)."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from vdbejax import cli
from vdbejax.methods.agents import make_agent
from vdbejax.methods.registry import EXPLORERS, LEARNERS
from vdbejax.results.grid_result import GridResult
from vdbejax.results.regret import cumulative_regret
from vdbejax.runs import RunOptions
from vdbejax.studies import StudyOutputs, bench
from vdbejax.studies.bench_methods import METHODS, TaskScale, select_methods

QUIET = RunOptions(progress=False)
#: Each method at its middle candidate, PSRL left out where it costs over 3e4 products.
UNTUNED_3E4 = bench.MethodChoice(tune=False, cost_limit=3e4)


def test_every_method_follows_the_one_rule() -> None:
    scale = TaskScale(r_max=2.0, horizon=10)
    for method in METHODS:
        assert method.learner in LEARNERS and method.explorer in EXPLORERS, method.name
        settings = method.candidates(scale)
        assert len(settings) == max(1, len(method.grid))
        for multiple, setting in zip(method.grid, settings, strict=True):
            values = setting.values
            assert values[method.tuned] == pytest.approx(multiple * scale.value(method.unit))
            assert values["gamma"] == (pytest.approx(0.9) if method.discounted else 1.0)
            if not method.discounted:
                assert values["horizon"] == 10
            if method.td:
                assert values["alpha"] == 0.1
            make_agent(setting)  # every candidate builds


def test_method_names_are_checked() -> None:
    assert [m.name for m in select_methods("vdbe,egreedy")] == ["egreedy", "vdbe"]
    for bad in ("nope", "vdbe,vdbe", ""):
        with pytest.raises(ValueError, match="methods="):
            select_methods(bad)


@pytest.fixture(scope="module")
def quick(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, bench.BenchResult]:
    out = tmp_path_factory.mktemp("bench")
    return out, bench.run_bench(out, quick=True,
                                run=RunOptions(progress=False, evaluate_every=20))


def test_quick_benchmark_writes_its_report(quick: tuple[Path, bench.BenchResult]) -> None:
    out, result = quick
    for name in ("bench.md", "ranking.csv", "aggregate.csv", "meta.json", "aggregate.png",
                 *(f"regret_{t.replace(':', '-')}.png" for t in bench.QUICK_TASKS)):
        assert (out / name).is_file(), name
    assert len(result.rows) == len(bench.QUICK_TASKS) * len(bench.QUICK_METHODS)
    for task in bench.QUICK_TASKS:
        ranks = sorted(r["rank"] for r in result.rows if r["task"] == task)
        assert ranks == list(range(1, len(bench.QUICK_METHODS) + 1))
    for row in result.rows:  # a score is a mean normalised return: at most 1 in expectation
        assert np.isfinite(row["score"]) and row["score"] < 1.2
        assert row["score_low"] <= row["score"] <= row["score_high"]
    meta = json.loads((out / "meta.json").read_text())
    assert meta["tuning_budget"]["agent_episodes"] > 0
    assert {a["method"] for a in result.aggregate} == set(bench.QUICK_METHODS)
    text = (out / "bench.md").read_text()
    assert "## Across tasks" in text and "tuning budget" in text
    # --evaluate-every: the greedy policies' gap and optimal share beside realized regret
    assert "realized regret [95 % CI]" in text and "policy gap [95 % CI]" in text
    for row in result.rows:
        assert row["policy_gap_ci_low"] <= row["policy_gap"] <= row["policy_gap_ci_high"]
        assert 0.0 <= row["optimal_fraction"] <= 1.0
    assert "optimal_fraction" in (out / "ranking.csv").read_text().splitlines()[0]
    for task in bench.QUICK_TASKS:
        assert (out / f"policy_gap_{task.replace(':', '-')}.png").is_file()


def test_tuning_runs_on_other_seeds_and_keeps_the_least_regret(
        quick: tuple[Path, bench.BenchResult]) -> None:
    out, result = quick
    tasks = {t.name: t for t in bench.make_tasks(bench.QUICK_TASKS)}
    for name, task in tasks.items():
        tuned = GridResult.load(out / "tune" / task.folder)
        reported = GridResult.load(out / "runs" / task.folder)
        assert tuned.meta["seed"] == 1 and reported.meta["seed"] == 0
        regret = cumulative_regret(tuned.returns, task.best)[..., -1].mean(-1)
        start = 0
        for c, method in enumerate(select_methods(bench.QUICK_METHODS)):
            n = len(method.grid)
            assert reported.settings[c] == tuned.settings[start + int(np.argmin(
                regret[start:start + n]))]
            start += n
        # the reported numbers are the reported run's, not the tuning run's
        row = next(r for r in result.rows if r["task"] == name)
        assert reported.num_seeds == bench.QUICK_SEEDS and row["task"] == name


def test_resume_reuses_whole_task_folders(quick: tuple[Path, bench.BenchResult]) -> None:
    out, result = quick
    # the same run: --resume takes it as it is
    again = bench.run_bench(out, quick=True,
                            outputs=StudyOutputs(figures=False, save_runs=False),
                            run=RunOptions(progress=False, resume=True, evaluate_every=20))
    assert [r["score"] for r in again.rows] == [r["score"] for r in result.rows]
    assert not (out / "aggregate.png").exists()  # no figure of the earlier run survives
    # save_runs=False: the task folders go once the report is written
    assert (out / "bench.md").is_file() and (out / "ranking.csv").is_file()
    assert not [*(out / "tune").glob("*"), *(out / "runs").glob("*")]


def test_bad_input_is_one_line_before_training(tmp_path: Path,
                                               capsys: pytest.CaptureFixture[str]) -> None:
    for argv, message in ((["--tasks", "nope"], "nope"), (["--methods", "nope"], "methods="),
                          (["--quick", "--seeds", "3"], "--quick sets"),
                          (["--episodes", "0"], "episodes="),
                          (["--quick", "--evaluate-every", "41"], "evaluate_every=41")):
        assert cli.main(["bench", "--out", str(tmp_path / "b"), "--quiet", *argv]) == 2
        err = capsys.readouterr().err
        assert err.startswith("error: ") and err.count("\n") == 1 and message in err, err
    assert not (tmp_path / "b" / "runs").exists()


def test_a_safety_capped_task_runs_at_the_benchmarks_horizon() -> None:
    # 10,000 steps (the suite's cap for tasks without a step limit) let one exploring agent
    # take 10,000 steps an episode: the first full run reached 8 GB in windy's tuning.
    from vdbejax.envs.suite import task_info

    capped = [name for name in ("windy_gridworld", "cliff_walking", "cruz2018", "taxi",
                                "chain", "table_cleaning") if task_info(name).safety_cap]
    assert capped == ["windy_gridworld", "cliff_walking", "cruz2018"]
    windy, taxi = bench.make_tasks("windy_gridworld,taxi")
    assert windy.mdp.max_steps == bench.CAPPED_HORIZON and windy.scale.horizon == 200
    assert windy.best == -15.0  # the optimum lies well within the cap
    assert taxi.mdp.max_steps == task_info("taxi").horizon  # its own limit (gymnasium's)


def test_a_cost_limit_of_1e7_would_leave_psrl_out_of_the_two_largest_tasks() -> None:
    from vdbejax.envs.suite import DEFAULT_SUITE

    psrl = select_methods("psrl")[0]
    assert bench.COST_LIMIT == float("inf")  # by default every method runs everywhere
    over = [t.name for t in bench.make_tasks(DEFAULT_SUITE) if t.cost(psrl) > 1e7]
    assert over == ["taxi", "variant:3x1"]
    taxi = bench.make_tasks("taxi")[0]
    assert taxi.cost(psrl) == 500 * 501 * 6 * 201  # a "terminal" outcome: Taxi has them
    riverswim = bench.make_tasks("riverswim")[0]
    assert riverswim.cost(psrl) == 6 * 6 * 2 * 21  # none: RiverSwim never terminates
    assert all(taxi.cost(m) == 0 for m in METHODS if m.name != "psrl")


def test_a_method_over_the_cost_limit_is_left_out_and_said(tmp_path: Path) -> None:
    # PSRL costs 36·37·2·7 ≈ 1.9e4 on DeepSea 6 and 5·5·2·1001 ≈ 5.0e4 on the chain
    result = bench.run_bench(tmp_path / "b", tasks="deepsea:6,chain", methods="egreedy,psrl",
                             seeds=2, episodes=10, choice=UNTUNED_3E4, run=QUIET)
    ran = {(r["task"], r["method"]) for r in result.rows}
    assert ran == {("deepsea:6", "egreedy"), ("deepsea:6", "psrl"), ("chain", "egreedy")}
    assert result.meta["left_out"] == [{"task": "chain", "method": "psrl", "cost": 50050.0,
                                        "limit": 3e4}]
    assert len(GridResult.load(tmp_path / "b" / "runs" / "chain").settings) == 1
    by_method = {a["method"]: a for a in result.aggregate}
    assert by_method["egreedy"]["tasks"] == 2 and by_method["psrl"]["tasks"] == 1
    assert [a["method"] for a in result.aggregate][-1] == "psrl"  # partial coverage last
    text = (tmp_path / "b" / "bench.md").read_text()
    assert "Left out by the cost rule" in text and "Not run here (cost rule): PSRL." in text
    assert "| 1 of 2 |" in text
    with pytest.raises(ValueError, match="no method of methods runs"):
        bench.run_bench(tmp_path / "c", tasks="chain", methods="psrl", seeds=2, episodes=10,
                        choice=UNTUNED_3E4, run=QUIET)
    assert not (tmp_path / "c").exists()
    with pytest.raises(ValueError, match="cost_limit="):
        bench.run_bench(tmp_path / "d", quick=True, choice=bench.MethodChoice(cost_limit=0),
                        run=QUIET)


def test_the_bandits_group_ranks_its_methods_with_optimal_actions(tmp_path: Path) -> None:
    from vdbejax.studies.bench_methods import (
        BANDIT_METHODS,
        BANDIT_TASKS,
        SUITE_METHODS,
        group_defaults,
    )

    assert group_defaults("bandits", None, None) == (BANDIT_TASKS, BANDIT_METHODS)
    assert group_defaults("suite", None, "vdbe") == (None, "vdbe")
    assert [m.name for m in select_methods(None)] == list(SUITE_METHODS)  # the suite's 20
    assert set(BANDIT_METHODS) <= {m.name for m in METHODS}
    with pytest.raises(ValueError, match=r"^group='nope' is invalid: must be one of suite,"):
        bench.run_bench(tmp_path / "x", group="nope", run=QUIET)
    result = bench.run_bench(tmp_path / "b", group="bandits", tasks="bernoulli_bandit:3",
                             methods="egreedy,thompson", seeds=3, episodes=30,
                             choice=bench.MethodChoice(tune=False),
                             outputs=StudyOutputs(figures=False), run=QUIET)
    assert result.meta["options"]["group"] == "bandits"
    for row in result.rows:
        assert 0 <= row["optimal_actions_ci_low"] <= row["optimal_actions"] <= 1
        assert row["reward_per_step"] == pytest.approx(row["final_return"])
    header = (tmp_path / "b" / "ranking.csv").read_text().splitlines()[0]
    assert "optimal_actions" in header and "reward_per_step" in header
    assert "% optimal action [95 % CI]" in (tmp_path / "b" / "bench.md").read_text()
    run = GridResult.load(tmp_path / "b" / "runs" / "bernoulli_bandit-3")
    assert run.optimal_actions is not None
