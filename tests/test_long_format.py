"""Results in the form analysts use: GridResult.to_records / to_dataframe and --long-csv."""
from __future__ import annotations

import csv

import numpy as np
import pytest

from vdbejax import cli
from vdbejax.methods import Setting
from vdbejax.results.grid_result import GridResult
from vdbejax.runs import RunOptions
from vdbejax.studies.sweeps import Sweep, run_sweep


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    out = tmp_path_factory.mktemp("long")
    run_sweep(out, Sweep(learners=["qlearning", "sarsa"], explorers=["egreedy"],
                         axes={"epsilon": [0.05, 0.2]}, shared={"alpha": 0.5}), seeds=3,
              episodes=7, figures=False, run=RunOptions(progress=False))
    return out


def test_records_are_one_row_per_agent_episode_in_order(folder):
    result = GridResult.load(folder)
    records = result.to_records()
    configs, seeds, episodes = result.returns.shape
    assert {len(v) for v in records.values()} == {configs * seeds * episodes}
    # Row (c, s, e) holds returns[c, s, e].
    c, s, e = 2, 1, 4
    row = (c * seeds + s) * episodes + e
    assert (records["config"][row], records["seed"][row], records["episode"][row]) == (c, s, e + 1)
    assert records["return"][row] == result.returns[c, s, e]
    assert records["length"][row] == result.lengths[c, s, e]
    assert records["setting"][row] == result.settings[c].label
    # Only varying hyperparameters get columns; the shared α does not vary.
    assert "explorer.epsilon" in records and "learner.alpha" not in records
    assert "learner.alpha" in result.to_records(all_hyperparameters=True)


def test_dataframe_matches_the_arrays(folder):
    pandas = pytest.importorskip("pandas")
    result = GridResult.load(folder)
    frame = result.to_dataframe()
    assert isinstance(frame, pandas.DataFrame)
    means = frame.groupby(["config", "episode"])["return"].mean().unstack().to_numpy()
    np.testing.assert_allclose(means, result.returns.mean(1), rtol=1e-6)
    assert set(frame.loc[frame["learner"] == "sarsa", "config"]) == {2, 3}


def test_long_csv_from_the_cli(folder, tmp_path, capsys):
    out = tmp_path / "plotted"
    assert cli.main(["plot", "--results", str(folder), "--out", str(out), "--long-csv"]) == 0
    path = out / "returns_long.csv"
    assert str(path) in capsys.readouterr().out
    with open(path, newline="") as f:
        rows = list(csv.DictReader(f))
    result = GridResult.load(folder)
    assert len(rows) == result.returns.size
    assert float(rows[8]["return"]) == pytest.approx(float(result.returns.reshape(-1)[8]), abs=1e-5)
    assert rows[0]["setting"] == result.settings[0].label


def test_records_of_a_result_without_recorded_hyperparameters():
    result = GridResult([Setting("qlearning", "egreedy", 0.1), Setting("sarsa", "vdbe", 1.0)],
                        np.zeros((2, 2, 3), np.float32), np.ones((2, 2, 3), np.int32),
                        np.zeros((2, 2), bool), {})
    records = result.to_records()
    assert records["explorer.epsilon"][0] == 0.1 and records["explorer.epsilon"][-1] is None
    assert records["explorer.sigma"][-1] == 1.0
