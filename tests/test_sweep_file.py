"""Sweep files a study can live in: exclusions, explicit settings, tasks of any source,
paths relative to the file, and the sweep file written back from a finished run."""
from __future__ import annotations

import json
import re
import shutil
import textwrap
from pathlib import Path

import numpy as np
import pytest

from vdbejax import cli
from vdbejax.envs import TabularMDP
from vdbejax.methods import Setting, sweep
from vdbejax.results.grid_result import GridResult
from vdbejax.runs import RunOptions
from vdbejax.studies.sweep_file import (
    read_sweep_file,
    sweep_from_meta,
    sweep_settings,
    write_sweep_file,
)
from vdbejax.studies.sweeps import Sweep, run_sweep
from vdbejax.studies.task_names import make_task

ROOT = Path(__file__).resolve().parents[1]
EXAMPLES = ROOT / "examples"
AXES = {"alpha": [0.1, 0.8], "sigma": [0.01, 1]}


def labels(settings: list[Setting]) -> list[str]:
    return [s.label for s in settings]


def one_line_error(capsys: pytest.CaptureFixture, *argv: str) -> str:
    assert cli.main(list(argv)) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error:"), lines
    return lines[0]


def test_an_exclusion_leaves_out_the_settings_whose_every_key_matches():
    full = sweep(["qlearning", "sarsa"], ["vdbe"], AXES)
    kept = sweep_settings(["qlearning", "sarsa"], ["vdbe"], AXES,
                          exclude=[{"learner": "sarsa", "alpha": 0.8}, {"sigma": 1}])
    expected = [s for s in full if not (s.learner == "sarsa" and s.values["alpha"] == 0.8)
                and s.values["sigma"] != 1]
    assert labels(kept) == labels(expected) and len(kept) == 3
    # An integer in the file matches the float of the setting (TOML's `sigma = 1`).
    assert sweep_settings(["qlearning"], ["vdbe"], {"sigma": [1.0, 2.0]},
                          exclude=[{"sigma": 1}]) == [Setting("qlearning", "vdbe", 2.0)]


@pytest.mark.parametrize("rule", [{"learner": "expected_sarsa"}, {"alpha": 0.3},
                                  {"omega": 1}, {"learner": "sarsa", "explorer": "egreedy"}])
def test_an_exclusion_that_matches_nothing_is_refused(rule):
    with pytest.raises(ValueError, match=r"exclude\[0\]=.* matches no setting"):
        sweep_settings(["qlearning", "sarsa"], ["vdbe"], AXES, exclude=[rule])


def test_explicit_settings_follow_the_product_with_shared_values_unless_their_own():
    settings = sweep_settings(
        ["qlearning"], ["vdbe"], {"sigma": [1]}, {"gamma": 0.95},
        settings=[{"learner": "sarsa", "explorer": "egreedy", "epsilon": 0.05},
                  {"learner": "sarsa", "explorer": "softmax", "tau": 0.1, "gamma": 0.5}])
    assert settings == [Setting("qlearning", "vdbe", 1.0, {"gamma": 0.95}),
                        Setting("sarsa", "egreedy", 0.05, {"gamma": 0.95}),
                        Setting("sarsa", "softmax", 0.1, {"gamma": 0.5})]
    # Explicit settings alone; a shared value only they have is used.
    alone = sweep_settings(settings=[{"learner": "qlearning", "explorer": "vdbe_softmax",
                                      "sigma": 2}], shared={"tau": 0.01})
    assert alone == [Setting("qlearning", "vdbe_softmax", 2.0, {"tau": 0.01})]


@pytest.mark.parametrize("entry, message", [
    ({"learner": "qlearning", "explorer": "vdbe", "omega": 1}, "has a field 'omega'"),
    ({"learner": "qlearning"}, "needs learner"),
    ({"learner": "qlearning", "explorer": "nope"}, "explorer='nope'"),
    ({"learner": "qlearning", "explorer": "vdbe", "sigma": 1}, "already in the sweep"),
])
def test_a_bad_explicit_setting_is_refused_in_one_line(entry, message):
    with pytest.raises(ValueError, match=message) as error:
        sweep_settings(["qlearning"], ["vdbe"], {"sigma": [1]}, settings=[entry])
    assert "\n" not in str(error.value)


def test_an_empty_sweep_or_an_unused_shared_value_is_refused():
    with pytest.raises(ValueError, match="no settings"):
        sweep_settings()
    with pytest.raises(ValueError, match="shared 'omega'"):
        sweep_settings(["qlearning"], ["vdbe"], shared={"omega": 1})
    with pytest.raises(ValueError, match=r"exclude=.*list of tables"):
        sweep_settings(["qlearning"], ["vdbe"], exclude={"learner": "qlearning"})


def write_task_module(folder: Path) -> None:
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "user_tasks.py").write_text(textwrap.dedent("""
        from examples_corridor import make_corridor

        def five():
            return make_corridor(5)

        def not_an_mdp():
            return 42
    """))
    shutil.copy(EXAMPLES / "corridor.py", folder / "examples_corridor.py")


def test_a_task_from_a_file_a_module_or_gymnasium(tmp_path, monkeypatch):
    write_task_module(tmp_path)
    monkeypatch.syspath_prepend(str(tmp_path))
    by_module = make_task("user_tasks:five")
    by_file = make_task(f"{tmp_path / 'user_tasks.py'}:five", max_steps=7)
    from examples_corridor import make_corridor

    expected = make_corridor(5)
    for mdp in (by_module, by_file):
        assert isinstance(mdp, TabularMDP) and mdp.num_states == 5
        np.testing.assert_array_equal(mdp.next_state, expected.next_state)
        np.testing.assert_array_equal(mdp.reward, expected.reward)
    assert int(by_module.max_steps) == 100 and int(by_file.max_steps) == 7
    # Suite names with a size are not module:function.
    assert make_task("chain:7").num_states == 7
    pytest.importorskip("gymnasium")
    from vdbejax.envs.gymnasium_adapter import from_gymnasium

    lake = make_task("gym:FrozenLake-v1")
    np.testing.assert_array_equal(lake.next_state, from_gymnasium("FrozenLake-v1").next_state)
    assert lake.name == "gym:FrozenLake-v1" and int(lake.max_steps) == 100


@pytest.mark.parametrize("task, message", [
    ("user_tasks:not_an_mdp", "returned int, must return a TabularMDP"),
    ("user_tasks:missing", "cannot build it (AttributeError"),
    ("no_such_module_q:make", "cannot build it (ModuleNotFoundError"),
    ("nowhere/tasks.py:make", "cannot build it (FileNotFoundError"),
    ("gym:NoSuchEnv-v0", "task='gym:NoSuchEnv-v0'"),
    ("maze", "task='maze' is invalid"),
])
def test_a_task_that_cannot_be_built_is_one_line_naming_task(tmp_path, monkeypatch, task,
                                                             message):
    write_task_module(tmp_path)
    monkeypatch.syspath_prepend(str(tmp_path))
    if task.startswith("gym:"):
        pytest.importorskip("gymnasium")
    with pytest.raises(ValueError, match=re.escape(message)) as error:
        make_task(task)
    assert "\n" not in str(error.value) and "task=" in str(error.value)
    with pytest.raises(ValueError, match="invalid_action='fail'"):
        make_task("user_tasks:five", invalid_action="fail")


def test_paths_in_a_sweep_file_are_relative_to_its_folder(tmp_path, monkeypatch):
    study = tmp_path / "study"
    write_task_module(study)
    shutil.copy(EXAMPLES / "custom_explorer.py", study)  # same module name: no clash
    (study / "sweep.toml").write_text(textwrap.dedent("""
        task = "user_tasks.py:five"
        plugins = ["custom_explorer.py"]
        learners = ["qlearning"]
        explorers = ["visit_epsilon"]
    """))
    # user_tasks.py imports its neighbour as a module: the folder on sys.path for that.
    monkeypatch.syspath_prepend(str(study))
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    monkeypatch.chdir(elsewhere)
    spec = read_sweep_file(Path("..") / "study" / "sweep.toml")
    assert spec["task"] == f"{study.resolve() / 'user_tasks.py'}:five"
    assert spec["plugins"] == [str(study.resolve() / "custom_explorer.py")]
    sweep = Sweep(plugins=spec.pop("plugins"), learners=spec.pop("learners"),
                  explorers=spec.pop("explorers"))
    result = run_sweep(tmp_path / "out", sweep, seeds=2, episodes=5, figures=False,
                       run=RunOptions(progress=False), **spec)
    assert result.settings[0].explorer == "visit_epsilon" and result.returns.shape[:2] == (1, 2)


def test_the_example_sweep_file_runs_and_its_folder_gives_the_sweep_back(tmp_path, capsys):
    first, again, from_folder = tmp_path / "first", tmp_path / "again", tmp_path / "folder"
    size = ["--seeds", "2", "--episodes", "12", "--quiet", "--no-figures"]
    assert cli.main(["run", "--config", str(EXAMPLES / "sweep.toml"), "--out", str(first),
                     *size]) == 0
    grid = GridResult.load(first)
    assert [s.label for s in grid.settings][-1] == (
        "mellow_q/visit_epsilon/epsilon0=0.3,gamma=0.95,omega=20")
    assert len(grid.settings) == 11  # 2 × 3 × 2 less SARSA ε-greedy's 2, plus 1 explicit
    assert not any(s.learner == "sarsa" and s.explorer == "egreedy" for s in grid.settings)
    assert grid.meta["mdp"] == "corridor8"
    capsys.readouterr()

    written = tmp_path / "sub" / "sweep.json"
    written.parent.mkdir()
    assert cli.main(["sweep-file", "--results", str(first), "--out", str(written)]) == 0
    spec = json.loads(written.read_text())
    # Files relative to the written file's folder.
    assert not Path(spec["plugins"][0]).is_absolute()
    assert (written.parent / spec["plugins"][0]).resolve() == EXAMPLES / "custom_explorer.py"
    assert spec["seeds"] == 2 and spec["replicates"] == 2 and spec["episodes"] == 12
    assert spec["exclude"] == [{"learner": "sarsa", "explorer": "egreedy"}]
    assert cli.main(["run", "--config", str(written), "--out", str(again), "--quiet",
                     "--no-figures"]) == 0
    assert cli.main(["run", "--config", str(first), "--out", str(from_folder), "--quiet",
                     "--no-figures"]) == 0
    for other in (again, from_folder):
        rerun = GridResult.load(other)
        assert rerun.settings == grid.settings
        np.testing.assert_array_equal(rerun.returns, grid.returns)
        np.testing.assert_array_equal(rerun.lengths, grid.lengths)
    assert sweep_from_meta(json.loads((first / "meta.json").read_text()))["task"].endswith(
        "corridor.py:make_corridor")


def test_flags_exclude_and_add_settings(tmp_path, capsys):
    out = tmp_path / "flags"
    assert cli.main(["run", "--out", str(out), "--learners", "qlearning,sarsa", "--explorers",
                     "vdbe", "--axis", "sigma=0.1,1", "--exclude", "learner=sarsa,sigma=1",
                     "--setting", "learner=sarsa,explorer=egreedy,epsilon=0.2",
                     "--seeds", "2", "--episodes", "5", "--quiet", "--no-figures"]) == 0
    assert labels(GridResult.load(out).settings) == [
        "qlearning/vdbe/sigma=0.1", "qlearning/vdbe/sigma=1", "sarsa/vdbe/sigma=0.1",
        "sarsa/egreedy/epsilon=0.2"]
    capsys.readouterr()


@pytest.mark.parametrize("argv, message", [
    (["run", "--learners", "qlearning", "--explorers", "vdbe", "--exclude", "sigma"],
     "--exclude='sigma' is invalid: must be NAME=VALUE"),
    (["run", "--learners", "qlearning", "--explorers", "vdbe", "--exclude", "learner=sarsa"],
     "matches no setting"),
    (["run", "--setting", "learner=qlearning"], "needs learner"),
    (["run", "--learners", "qlearning", "--explorers", "vdbe", "--task", "gym:"],
     "task='gym:'"),
])
def test_run_refuses_bad_sweep_flags_before_training(tmp_path, capsys, argv, message):
    out = tmp_path / "x"
    line = one_line_error(capsys, *argv[:1], "--out", str(out), *argv[1:])
    assert message in line
    assert not (out / "returns.npz").exists()


def test_sweep_file_refuses_what_it_cannot_write(tmp_path, capsys):
    assert "must be a result folder" in one_line_error(
        capsys, "sweep-file", "--results", str(tmp_path / "none"))
    (tmp_path / "paper").mkdir()
    (tmp_path / "paper" / "meta.json").write_text(json.dumps({"task": "table_cleaning"}))
    assert "no sweep record" in one_line_error(capsys, "sweep-file", "--results",
                                               str(tmp_path / "paper"))
    with pytest.raises(ValueError, match=r"name it \*\.json"):
        write_sweep_file({"learners": ["qlearning"]}, tmp_path / "sweep.toml")


@pytest.mark.parametrize("text, message", [
    ('axes = ["alpha"]', "axes=['alpha'] is invalid: must be a table"),
    ('axes = {alpha = 0.1}', "axes={'alpha': 0.1} is invalid"),
    ('shared = [1]', "shared=[1] is invalid"),
    ('plugins = "mine.py"', "plugins='mine.py' is invalid: must be a list"),
    ('learners = "qlearning"', "learners='qlearning' is invalid: must be a list of names"),
    ('seeds = 2.5', "seeds=2.5 is invalid: must be an integer"),
    ('seeds = "20"', "seeds='20' is invalid"),
    ('exclude = {learner = "sarsa"}', "exclude={'learner': 'sarsa'} is invalid"),
    ('task = 3', "task=3 is invalid"),
    ('colour = "red"', "unknown key 'colour'"),
])
def test_a_sweep_file_key_of_the_wrong_type_is_one_line(tmp_path, capsys, text, message):
    learners = "" if text.startswith("learners") else 'learners = ["qlearning"]\n'
    (tmp_path / "sweep.toml").write_text(f'{learners}explorers = ["vdbe"]\n{text}\n')
    line = one_line_error(capsys, "run", "--config", str(tmp_path / "sweep.toml"), "--out",
                          str(tmp_path / "out"))
    assert message in line and "sweep file" in line
    assert not (tmp_path / "out").exists()  # refused before any folder is made
