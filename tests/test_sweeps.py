"""Any hyperparameter as a sweep axis, `vdbejax run`, and user plug-ins end to end."""
from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from vdbejax.envs.table_cleaning import make_mdp
from vdbejax.methods import AgentOptions, Setting, sweep
from vdbejax.paper.reproduce import replot
from vdbejax.results.analysis import summarize
from vdbejax.results.grid_result import GridResult
from vdbejax.runs import run_grid

ROOT = Path(__file__).resolve().parents[1]
EXAMPLE = ROOT / "examples" / "custom_explorer.py"
AXES = {"alpha": [0.1, 0.3, 0.8], "sigma": [0.01, 1.0, 100.0]}


def run_cli(*args: str, cwd: Path | None = None) -> subprocess.CompletedProcess:
    env = {k: v for k, v in os.environ.items() if k != "JAX_COMPILATION_CACHE_DIR"}
    env["VDBEJAX_CACHE_DIR"] = "off"
    return subprocess.run([sys.executable, "-m", "vdbejax", *args], capture_output=True,
                          text=True, cwd=cwd or ROOT, env=env, timeout=300)


def test_sweep_builds_the_product_of_the_axes_that_apply():
    settings = sweep(["qlearning", "sarsa"], ["vdbe", "egreedy"], AXES)
    # vdbe: 3 α × 3 σ; ε-greedy has no σ: 3 α, its ε at its default, stated as its param
    # (the label and configs.csv say what runs).
    assert len(settings) == 2 * (9 + 3)
    assert Setting("sarsa", "vdbe", 100.0, {"alpha": 0.8}) in settings
    assert Setting("qlearning", "egreedy", 0.1, {"alpha": 0.3}) in settings
    assert Setting("qlearning", "egreedy", 0.1, {"alpha": 0.3}).label == (
        "qlearning/egreedy/epsilon=0.1,alpha=0.3")
    with pytest.raises(ValueError, match="axis 'omega'"):
        sweep(["qlearning"], ["vdbe"], {"omega": [1.0]})
    with pytest.raises(ValueError, match="learners"):
        sweep([], ["vdbe"])


def test_three_axis_sweep_in_one_call_equals_each_setting_alone():
    mdp = make_mdp(max_steps=40)
    settings = sweep(["qlearning", "sarsa"], ["vdbe"], AXES)
    grid = run_grid(mdp, settings, num_seeds=2, num_episodes=25, seed=1)
    assert grid.returns.shape == (18, 2, 25)
    # α as a per-agent axis gives exactly what a grid-wide α gives.
    for c in (0, 8, 13):
        s = settings[c]
        alpha = dict(s.hyperparameters)["alpha"]
        alone = run_grid(mdp, [Setting(s.learner, s.explorer, s.param)], num_seeds=2,
                         num_episodes=25, seed=1, options=AgentOptions(alpha=alpha))
        np.testing.assert_array_equal(grid.returns[c], alone.returns[0])
    assert grid.hyperparameters(4)["learner.alpha"] == pytest.approx(0.3)
    assert grid.hyperparameters(4)["explorer.sigma"] == pytest.approx(1.0)
    assert grid.select(alpha=0.3) == [3, 4, 5, 12, 13, 14]
    assert grid.select(learner="sarsa", sigma=100.0) == [11, 14, 17]
    assert grid.select(**{"learner.alpha": 0.8}, explorer="vdbe") == [6, 7, 8, 15, 16, 17]


def test_results_with_hyperparameters_survive_save_and_load(tmp_path):
    settings = [Setting("qlearning", "ucb1", 2.0, {"alpha": 0.3}),
                Setting("double_qlearning", "max_boltzmann", None, {"tau": 0.5})]
    grid = run_grid(make_mdp(max_steps=30), settings, num_seeds=2, num_episodes=10)
    grid.save(tmp_path)
    loaded = GridResult.load(tmp_path)
    assert loaded.settings == settings
    assert loaded.hyperparameters(1) == grid.hyperparameters(1)
    assert loaded.settings[1].label == "double_qlearning/max_boltzmann/tau=0.5"
    rows = summarize(loaded)
    assert rows[0]["hyperparameters"] == '{"alpha":0.3}' and rows[1]["param"] == ""


def test_vdbejax_run_with_flags_and_with_a_sweep_file_writes_one_result(tmp_path):
    flags = run_cli("run", "--out", str(tmp_path / "flags"), "--learners", "qlearning,sarsa",
                    "--explorers", "vdbe", "--axis", "alpha=0.1,0.3,0.8",
                    "--axis", "sigma=0.01,1,100", "--seeds", "2", "--episodes", "20",
                    "--max-steps", "40", "--quiet")
    assert flags.returncode == 0, flags.stderr
    assert len([line for line in flags.stdout.splitlines() if "final return" in line]) == 18
    (tmp_path / "sweep.toml").write_text(
        'learners = ["qlearning", "sarsa"]\nexplorers = ["vdbe"]\nseeds = 2\nepisodes = 20\n'
        'max_steps = 40\n[axes]\nalpha = [0.1, 0.3, 0.8]\nsigma = [0.01, 1, 100]\n')
    from_file = run_cli("run", "--out", str(tmp_path / "file"), "--config",
                        str(tmp_path / "sweep.toml"), "--quiet", "--no-figures")
    assert from_file.returncode == 0, from_file.stderr
    a, b = GridResult.load(tmp_path / "flags"), GridResult.load(tmp_path / "file")
    assert a.settings == b.settings and len(a.settings) == 18
    np.testing.assert_array_equal(a.returns, b.returns)
    assert (tmp_path / "flags" / "fig3.png").exists() and not (tmp_path / "file" / "fig3.png").exists()
    assert not (tmp_path / "flags" / "report.md").exists()  # claims belong to the paper's grid
    written = replot(tmp_path / "flags")
    assert all(path.exists() for path in written) and not (tmp_path / "flags" / "report.md").exists()


@pytest.mark.parametrize("args, message", [
    (["--learners", "qlearning", "--explorers", "vdbe", "--axis", "omega=1,2"], "axis 'omega'"),
    (["--explorers", "vdbe"], "learners is missing"),
    (["--learners", "qlearning", "--explorers", "nope"], "explorer='nope'"),
    (["--learners", "qlearning", "--explorers", "vdbe", "--axis", "sigma"], "NAME=VALUE"),
    (["--learners", "qlearning", "--explorers", "vdbe", "--task", "maze"], "task='maze'"),
    (["--learners", "qlearning", "--explorers", "vdbe", "--plugin", "no_such_module_x"],
     "plugin='no_such_module_x'"),
])
def test_vdbejax_run_refuses_bad_input_with_one_line(tmp_path, capsys, args, message):
    # In this process (a real process's refusal: tests/test_validation.py).
    from vdbejax import cli

    assert cli.main(["run", "--out", str(tmp_path / "x"), *args]) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error:") and message in lines[0], lines
    assert not (tmp_path / "x" / "returns.npz").exists()


def test_the_custom_explorer_example_runs_and_its_results_plot(tmp_path):
    done = subprocess.run([sys.executable, str(EXAMPLE), "--seeds", "2", "--episodes", "30",
                           "--out", str(tmp_path)], capture_output=True, text=True, timeout=300,
                          cwd=ROOT)
    assert done.returncode == 0, done.stderr
    lines = [line for line in done.stdout.splitlines() if "final return" in line]
    assert len(lines) == 5 and lines[0].startswith("qlearning/visit_epsilon/epsilon0=0.5")
    # `vdbejax plot` redraws a grid of plug-ins it has never imported, without a claims report.
    plotted = run_cli("plot", "--results", str(tmp_path))
    assert plotted.returncode == 0, plotted.stderr
    assert (tmp_path / "fig3.png").exists() and (tmp_path / "sensitivity.png").exists()
    assert not (tmp_path / "report.md").exists()
    meta = json.loads((tmp_path / "meta.json").read_text())
    assert meta["parameter_names"]["visit_epsilon"] == "epsilon0"
    assert any("explorer.epsilon0" in values for values in meta["hyperparameters"])


def test_vdbejax_run_takes_user_plugins(tmp_path):
    done = run_cli("run", "--out", str(tmp_path), "--plugin", str(EXAMPLE), "--learners",
                   "mellow_q", "--explorers", "visit_epsilon,vdbe_softmax", "--axis",
                   "omega=5,50", "--seeds", "2", "--episodes", "15", "--quiet", "--no-figures")
    assert done.returncode == 0, done.stderr
    grid = GridResult.load(tmp_path)
    assert [s.label for s in grid.settings] == [  # the explorers' defaults stated
        "mellow_q/visit_epsilon/epsilon0=0.5,omega=5", "mellow_q/visit_epsilon/epsilon0=0.5,omega=50",
        "mellow_q/vdbe_softmax/sigma=1,omega=5", "mellow_q/vdbe_softmax/sigma=1,omega=50"]
    assert np.all(np.isfinite(grid.returns))
