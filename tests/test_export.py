"""One export of any result folder (issue 49, point 13): returns, summaries and policy
evaluations as long tables — CSV always, Parquet with pyarrow — that pandas and polars read."""
from __future__ import annotations

import csv
import shutil
import sys

import numpy as np
import pytest

from vdbejax import cli
from vdbejax.results.export import export_results
from vdbejax.results.grid_result import GridResult
from vdbejax.results.summary import read_summary
from vdbejax.runs import RunOptions
from vdbejax.studies.sweeps import Sweep, run_sweep


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    """A run with two replicates and policy evaluations: every table and scope."""
    out = tmp_path_factory.mktemp("export") / "run"
    run_sweep(out, Sweep(learners=["qlearning"], explorers=["egreedy", "vdbe"],
                         axes={"alpha": [0.2, 0.6]}), seeds=2, replicates=2, episodes=8,
              figures=False, run=RunOptions(evaluate_every=4, progress=False))
    return out


def read(path):
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def test_the_csv_tables_hold_every_observation(folder, tmp_path):
    written = export_results(folder, tmp_path)
    assert [p.name for p in written] == ["returns_long.csv", "summaries_long.csv",
                                         "evaluations_long.csv"]
    result = GridResult.load(folder)
    configs, agents, episodes = result.returns.shape
    returns = read(tmp_path / "returns_long.csv")
    assert len(returns) == configs * agents * episodes
    row = returns[(2 * agents + 3) * episodes + 5]  # config 2, agent 3, episode 6
    assert (row["run"], row["config"], row["seed"], row["replicate"], row["episode"]) == (
        ".", "2", "3", "1", "6")
    assert float(row["return"]) == pytest.approx(float(result.returns[2, 3, 5]), abs=1e-5)
    assert row["setting"] == result.settings[2].label and row["task"] == result.meta["mdp"]
    assert float(row["learner.alpha"]) == result.hyperparameters(2)["learner.alpha"]
    assert row["explorer.sigma"] == "1"
    assert returns[0]["explorer.sigma"] == ""  # ε-greedy has no σ: blank, not a made-up value

    summaries = read(tmp_path / "summaries_long.csv")
    scopes = [r["scope"] for r in summaries]
    assert scopes == ["replicate 0"] * 4 + ["pooled"] * 4 + ["replicate 1"] * 4
    pooled = read_summary(folder / "summary_pooled.csv")
    assert [float(r["final_return"]) for r in summaries[4:8]] == pytest.approx(
        [r.final_return for r in pooled], abs=1e-5)
    assert summaries[0]["learner.alpha"] == "0.2" and "policy_gap" in summaries[0]

    evaluations = read(tmp_path / "evaluations_long.csv")
    assert len(evaluations) == configs * agents * 2
    first = evaluations[1]  # config 0, agent 0, evaluation 2
    assert (first["evaluation"], first["episode"]) == ("2", "8")
    value = float(result.policy_values[0, 0, 1])
    assert float(first["policy_value"]) == pytest.approx(value, abs=1e-5)
    assert float(first["policy_gap"]) == pytest.approx(result.meta["optimal_return"] - value,
                                                       abs=1e-4)
    assert first["optimal"] in ("True", "False")


def test_pandas_and_polars_read_the_tables(folder, tmp_path):
    pandas = pytest.importorskip("pandas")
    export_results(folder, tmp_path)
    frame = pandas.read_csv(tmp_path / "returns_long.csv")
    result = GridResult.load(folder)
    means = frame.groupby(["config", "episode"])["return"].mean().unstack().to_numpy()
    np.testing.assert_allclose(means, result.returns.mean(1), rtol=1e-5)
    assert frame.equals(frame.dropna(subset=["return"]))
    polars = pytest.importorskip("polars")
    table = polars.read_csv(tmp_path / "evaluations_long.csv", infer_schema_length=None)
    assert table.height == result.policy_values.size


def test_parquet_has_the_csvs_rows_and_types(folder, tmp_path):
    pytest.importorskip("pyarrow")
    pandas = pytest.importorskip("pandas")
    export_results(folder, tmp_path, format="csv")
    export_results(folder, tmp_path, format="parquet")
    for name in ("returns_long", "summaries_long", "evaluations_long"):
        from_csv = pandas.read_csv(tmp_path / f"{name}.csv")
        from_parquet = pandas.read_parquet(tmp_path / f"{name}.parquet")
        assert list(from_parquet.columns) == list(from_csv.columns)
        assert len(from_parquet) == len(from_csv)
    frame = pandas.read_parquet(tmp_path / "returns_long.parquet")
    assert frame["return"].dtype == np.float32 and frame["episode"].dtype == np.int64
    assert frame["explorer.sigma"].isna().sum() == len(frame) // 2  # null where absent
    evaluations = pandas.read_parquet(tmp_path / "evaluations_long.parquet")
    assert evaluations["optimal"].dtype == bool


def test_parquet_without_pyarrow_is_one_line(folder, tmp_path, monkeypatch, capsys):
    monkeypatch.setitem(sys.modules, "pyarrow", None)  # as if not installed
    assert cli.main(["export", str(folder), "--out", str(tmp_path), "--format",
                     "parquet"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "pip install pyarrow" in err[0], err
    assert not any(tmp_path.iterdir())


def test_a_study_folder_exports_each_of_its_runs(folder, tmp_path, capsys):
    # bench, depth, scale and ablate keep one run folder per task, size or variant.
    study = tmp_path / "study"
    for name in ("runs/a", "runs/b"):
        shutil.copytree(folder, study / name)
    (study / "meta.json").write_text("{}")  # the study's own meta.json is no run
    assert cli.main(["export", str(study), "--tables", "returns,summaries"]) == 0
    assert capsys.readouterr().out.split() == [str(study / "returns_long.csv"),
                                               str(study / "summaries_long.csv")]
    runs = [r["run"] for r in read(study / "returns_long.csv")]
    size = GridResult.load(folder).returns.size
    assert runs == ["runs/a"] * size + ["runs/b"] * size
    assert not (study / "evaluations_long.csv").exists()


def test_existing_tables_are_kept_unless_overwrite(folder, tmp_path, capsys):
    args = ["export", str(folder), "--out", str(tmp_path)]
    assert cli.main(args) == 0
    before = (tmp_path / "returns_long.csv").read_bytes()
    (tmp_path / "returns_long.csv").write_text("mine")
    capsys.readouterr()
    assert cli.main(args) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--overwrite" in err[0] and "returns_long.csv" in err[0], err
    assert (tmp_path / "returns_long.csv").read_text() == "mine"
    assert cli.main([*args, "--overwrite"]) == 0
    assert (tmp_path / "returns_long.csv").read_bytes() == before


@pytest.mark.parametrize("extra, message", [
    (["--format", "xlsx"], "format='xlsx' is invalid"),
    (["--tables", "returns,curves"], "tables='curves' is invalid"),
])
def test_bad_options_are_one_line(folder, tmp_path, capsys, extra, message):
    assert cli.main(["export", str(folder), "--out", str(tmp_path), *extra]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and message in err[0], err


def test_a_folder_without_runs_is_one_line(tmp_path, capsys):
    assert cli.main(["export", str(tmp_path / "missing")]) == 2
    assert "does not exist" in capsys.readouterr().err
    (tmp_path / "empty").mkdir()
    assert cli.main(["export", str(tmp_path / "empty")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "holds a run" in err[0], err
