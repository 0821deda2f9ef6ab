"""What the README promises is what a newcomer gets, and the last faults end in one line
(issue 49): each test fails without its fix."""
from __future__ import annotations

import re
from pathlib import Path

import pytest

from vdbejax import cli
from vdbejax.methods.agents import AgentOptions
from vdbejax.results import io
from vdbejax.runs import RunOptions
from vdbejax.studies import folder as studies_folder
from vdbejax.studies import sweeps
from vdbejax.studies.sweeps import Sweep

QUIET = RunOptions(progress=False)
SWEEP = dict(sweep=Sweep(learners=["qlearning"], explorers=["egreedy"]), seeds=2, episodes=12,
             run=QUIET)


def one_error_line(capsys) -> str:
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), lines
    return lines[0]


@pytest.fixture
def finished(tmp_path) -> Path:
    out = tmp_path / "run"
    sweeps.run_sweep(out, **SWEEP)
    return out


@pytest.fixture
def trainings(monkeypatch) -> list[int]:
    """Counts the trainings of the result-folder pipeline (after the fixtures trained)."""
    counted: list[int] = []
    real = studies_folder.run_prepared

    def counting(*args, **kwargs):
        counted.append(1)
        return real(*args, **kwargs)

    monkeypatch.setattr(studies_folder, "run_prepared", counting)
    return counted


# ----------------------------------------------------- point 5: a finished folder is not replaced
def test_a_finished_folder_is_not_replaced_without_overwrite(finished, trainings):
    before = (finished / io.RETURNS_FILE).read_bytes()
    with pytest.raises(ValueError, match=r"holds a finished result.*--overwrite"):
        sweeps.run_sweep(finished, **SWEEP)
    with pytest.raises(ValueError, match="holds a finished result"):
        sweeps.run_sweep(finished, **{**SWEEP, "seeds": 3})
    assert not trainings
    assert (finished / io.RETURNS_FILE).read_bytes() == before
    sweeps.run_sweep(finished, **{**SWEEP, "seeds": 3, "run": QUIET.replace(overwrite=True)})
    assert trainings and io.load_json(finished / io.META_FILE)["num_seeds"] == 3


def test_resume_continues_only_the_same_run(finished, trainings):
    reused = sweeps.run_sweep(finished, **{**SWEEP, "run": QUIET.replace(resume=True)})  # a no-op on a finished run
    assert not trainings and reused.num_seeds == 2
    with pytest.raises(ValueError, match=r"finished result of a different run.*--overwrite"):
        sweeps.run_sweep(finished, **{**SWEEP, "episodes": 13,
                                      "run": QUIET.replace(resume=True)})
    assert not trainings


def test_the_command_line_refuses_in_one_line(finished, trainings, capsys):
    argv = ["run", "--learners", "qlearning", "--explorers", "egreedy", "--seeds", "2",
            "--episodes", "12", "--quiet", "--out", str(finished)]
    assert cli.main(argv) == 2
    assert "--overwrite" in one_error_line(capsys)
    assert cli.main([*argv, "--resume"]) == 0 and not trainings
    assert cli.main([*argv, "--overwrite"]) == 0 and trainings


def test_reproduce_after_a_run_is_refused(finished, trainings):
    import vdbejax

    with pytest.raises(ValueError, match="holds a finished result"):
        vdbejax.reproduce(finished, seeds=1, episodes=2, replicates=1, figures=False,
                          run=QUIET)
    assert not trainings


# ------------------------------------------------------- point 8: NumPy scalars are welcome
def test_reproduce_takes_numpy_scalars_and_labels_its_sizes_and_reading(tmp_path, capsys):
    import numpy as np

    import vdbejax

    out = tmp_path / "paper"
    rep = vdbejax.reproduce(out, seeds=np.int64(2), episodes=np.int64(3), seed=np.int64(2),
                            replicates=np.int64(2), figures=np.bool_(False),
                            options=AgentOptions(alpha=np.float64(0.1), q_init=np.float32(0.0)),
                            run=RunOptions(chunk_episodes=np.int64(2), progress=np.bool_(True)))
    meta = io.load_json(out / io.META_FILE)
    assert (meta["replicates"], meta["agents_per_replicate"], meta["num_episodes"]) == (2, 2, 3)
    assert rep.result.returns.shape == (46, 4, 3)
    # point 2: the closing line labels every size; point 1: it and report.md name the reading
    assert ("textbook reading: 46 settings × 2 replicates × 2 agents × 3 episodes"
            in capsys.readouterr().err)
    assert "Reading: **textbook** (the paper's text" in (out / "report.md").read_text()


def test_sweeps_grids_and_options_take_numpy_scalars(tmp_path):
    import numpy as np

    import vdbejax
    from vdbejax.envs.table_cleaning import make_mdp
    from vdbejax.methods import Setting

    plain = sweeps.run_sweep(tmp_path / "plain", **SWEEP, seed=1)
    numpy = sweeps.run_sweep(tmp_path / "numpy", sweeps.Sweep(
        learners=["qlearning"], explorers=["egreedy"],
        axes={"alpha": [np.float64(0.1), np.float32(0.5)]}), seeds=np.int64(2),
        episodes=np.int32(12), seed=np.uint32(1), run=QUIET)
    assert np.array_equal(plain.returns, numpy.returns[:1])
    assert io.load_json(tmp_path / "numpy" / io.META_FILE)["fingerprint"]
    run = vdbejax.RunOptions(chunk_episodes=np.int64(4), devices=np.int64(1),
                             resume=np.bool_(False))
    grid = vdbejax.run_grid(make_mdp(max_steps=np.int64(20)),
                            [Setting("qlearning", "egreedy", np.float64(0.1))],
                            num_seeds=np.int64(2), num_episodes=np.int64(8), seed=np.int64(0),
                            run=run)
    grid.save(tmp_path / "saved")
    assert vdbejax.GridResult.load(tmp_path / "saved").num_seeds == 2


# ------------------------------------------- points 1 and 2: the front page says what happens
ROOT = Path(__file__).resolve().parent.parent
NUMBER_WORDS = ["no", "one", "two", "three", "four", "five", "six", "seven", "eight", "nine"]


def test_the_front_pages_sizes_come_from_the_code():
    import inspect

    from vdbejax.methods.agents import paper_settings
    from vdbejax.paper.reproduce import reproduce

    defaults = {k: v.default for k, v in inspect.signature(reproduce).parameters.items()}
    size = (f"{len(paper_settings())} settings × {defaults['replicates']} replicates ×"
            f" {defaults['seeds']} agents × {defaults['episodes']} episodes")
    notebooks = f"{NUMBER_WORDS[len(list((ROOT / 'notebooks').glob('*.ipynb')))]} notebooks"
    for page in (ROOT / "README.md", ROOT / "docs" / "index.md"):
        text = " ".join(page.read_text(encoding="utf-8").split())
        assert size in text, f"{page.name} does not state the default run's size: {size}"
        assert notebooks in text, f"{page.name} miscounts the notebooks: {notebooks}"
        assert not re.search(r"\b\d+ settings × \d+ agents\b", text), page.name


def test_the_front_page_says_which_command_runs_which_reading():
    from vdbejax.paper.report import reading_line

    text = " ".join((ROOT / "README.md").read_text(encoding="utf-8").split())
    assert "`vdbejax reproduce` runs one reading" in text and "--reading authors" in text
    assert "`vdbejax ablate --sections` runs both" in text
    assert reading_line({"reading": "authors", "details": {"goal_update": "skip"}}).startswith(
        "Reading: **authors** (the first author's published code")
    assert "**textbook**" in reading_line({"mdp": "table_cleaning"})  # saved before readings


# --------------------------------------------------------- point 12: vdbejax list
def test_list_names_every_method_and_task_with_its_defaults(capsys, tmp_path):
    import json

    from vdbejax.envs.suite import NAMES
    from vdbejax.methods.registry import EXPLORERS, LEARNERS

    assert cli.main(["list"]) == 0
    text = capsys.readouterr().out
    for name in [*LEARNERS, *EXPLORERS, *NAMES]:
        assert f"\n  {name}  " in text, name
    assert "*epsilon=0.1" in text and "alpha=0.8, gamma=0.9" in text  # defaults, swept marked
    plugin = tmp_path / "mine.py"
    plugin.write_text("from vdbejax.methods import Explorer, explorer, select_action\n"
                      "@explorer('listed_mine', parameter='eps')\n"
                      "class Mine(Explorer):\n"
                      "    eps: float = 0.25\n"
                      "    def select(self, q, tables, context, uniforms):\n"
                      "        return select_action(q, self.eps, None, uniforms)\n")
    assert cli.main(["list", "explorers", "--json", "--plugin", str(plugin)]) == 0
    listed = json.loads(capsys.readouterr().out)
    assert list(listed) == ["explorers"]
    mine = next(e for e in listed["explorers"] if e["name"] == "listed_mine")
    assert mine["parameters"] == {"eps": 0.25} and mine["swept"] == "eps"
    assert cli.main(["list", "bogus"]) == 2
    assert "must be one of learners, explorers, tasks" in one_error_line(capsys)


# ------------------------------------------------------------------ point 14: rough edges
def test_citation_file_names_this_version_and_the_paper():
    import tomllib

    version = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["version"]
    text = (ROOT / "CITATION.cff").read_text(encoding="utf-8")
    assert "cff-version: 1.2.0" in text and f'version: "{version}"' in text
    assert "Action Selection Methods in a Robotic Reinforcement Learning Scenario" in text


def test_the_estimate_states_no_empty_range_nor_a_zero_second_bound():
    from vdbejax.runs import estimate

    line = estimate.estimate_run(1, 2, 3, statistics=False).describe()
    assert " to " not in line and "training ≥ 0 s" not in line, line
    assert "(6 agent-steps)" in line


def test_a_grid_results_repr_is_one_line(tmp_path):
    import vdbejax
    from vdbejax.envs.table_cleaning import make_mdp
    from vdbejax.methods import Setting

    grid = vdbejax.run_grid(make_mdp(max_steps=5), [Setting("qlearning", "egreedy", 0.1)],
                            num_seeds=2, num_episodes=300)
    assert repr(grid) == ("GridResult(1 settings × 2 agents × 300 episodes,"
                          " task 'table_cleaning')")


def test_plot_names_a_file_or_missing_folder_as_such(tmp_path, capsys):
    (tmp_path / "returns.npz").write_bytes(b"")
    assert cli.main(["plot", "--results", str(tmp_path / "returns.npz")]) == 2
    assert "is a file" in one_error_line(capsys)
    assert cli.main(["plot", "--results", str(tmp_path / "nothing")]) == 2
    assert "does not exist" in one_error_line(capsys)


def test_a_missing_gymnasium_is_said_once(monkeypatch):
    import sys

    from vdbejax.studies.task_names import make_task

    monkeypatch.setitem(sys.modules, "gymnasium", None)  # import gymnasium fails
    for task in ("frozenlake4", "gym:FrozenLake-v1"):
        with pytest.raises(ValueError) as error:
            make_task(task)
        assert str(error.value).count("pip install") == 1, error.value


def test_curves_that_coincide_still_show_every_colour():
    import numpy as np

    from vdbejax.methods import Setting
    from vdbejax.results.grid_result import GridResult
    from vdbejax.results.plotting import figure3

    settings = [Setting("qlearning", "vdbe_softmax", s) for s in (0.01, 0.1, 1.0)]
    returns = np.zeros((3, 2, 30), np.float32)  # three identical curves
    grid = GridResult(settings, returns, np.ones_like(returns, np.int32),
                      np.zeros((3, 2), bool), {"mdp": "table_cleaning"})
    lines = [line for line in figure3(grid, bands=False, window=5).axes[0].get_lines()
             if line.get_label().startswith("σ")]
    widths = [line.get_linewidth() for line in lines]
    assert len({line.get_color() for line in lines}) == 3
    assert widths == sorted(widths, reverse=True) and len(set(widths)) == 3


def test_sensitivity_plots_the_swept_alpha_when_the_explorers_parameter_is_fixed(tmp_path):
    from vdbejax.results.plotting import sensitivity

    sweeps.run_sweep(tmp_path, **{**SWEEP, "sweep": Sweep(learners=["qlearning"],
                     explorers=["egreedy"], axes={"alpha": [0.1, 0.3, 0.8]})}, figures=False)
    figure = sensitivity(io.read_csv(tmp_path / sweeps.SUMMARY_FILE))
    assert figure.axes[1].get_xlabel().startswith("α")
    drawn = [line for line in figure.axes[0].get_lines() if len(line.get_xdata()) == 3]
    assert sorted(drawn[0].get_xdata()) == [0.1, 0.3, 0.8]


# ------------------------------------------------ point 11: every input read before training
def test_ablate_refuses_a_notes_file_that_is_not_utf8_before_training(tmp_path, trainings,
                                                                       capsys):
    notes = tmp_path / "notes.md"
    notes.write_bytes("café".encode("latin-1"))
    out = tmp_path / "doc"
    assert cli.main(["ablate", "--out", str(out), "--variants", "spec", "--seeds", "2",
                     "--episodes", "12", "--replicates", "1", "--quiet",
                     "--notes", str(notes)]) == 2
    line = one_error_line(capsys)
    assert str(notes) in line and "not UTF-8" in line, line
    assert not trainings and not out.exists()


# ------------------------------------------------- point 7: a faulty plug-in is one line
PLUGIN = """
import numpy as np
from vdbejax.methods import Explorer, Table, explorer, select_action

@explorer({name!r}, parameter="eps")
class Faulty(Explorer):
    eps: float = 0.1
    def tables(self):
        return {{"visits": Table("state", {init})}}
    def select(self, q, tables, context, uniforms):
        return select_action(q, self.eps, None, uniforms)
"""


@pytest.mark.parametrize("name, init, shown", [
    ("faulty_string_init", "'zero'", "init='zero'"),
    ("faulty_array_init", "np.zeros(3)", "not an array of shape (3,)")])
def test_a_table_start_value_that_is_no_number_is_one_line(tmp_path, trainings, capsys,
                                                           name, init, shown):
    line = refused_plugin_run(tmp_path, capsys, name, PLUGIN.format(name=name, init=init))
    assert f"explorer {name!r} table 'visits'" in line and shown in line, line
    assert not trainings and not (tmp_path / "out").exists()


def refused_plugin_run(tmp_path, capsys, name: str, source: str) -> str:
    """``vdbejax run`` with the explorer ``name`` of a plug-in file holding ``source``:
    exit 2, and its one error line."""
    plugin = tmp_path / f"{name}.py"
    plugin.write_text(source)
    assert cli.main(["run", "--plugin", str(plugin), "--learners", "qlearning", "--explorers",
                     name, "--seeds", "2", "--episodes", "5", "--quiet", "--out",
                     str(tmp_path / "out")]) == 2
    return one_error_line(capsys)


def test_a_plug_in_that_exits_on_import_is_one_line(tmp_path, capsys):
    plugin = tmp_path / "exits.py"
    plugin.write_text("import sys\nsys.exit(3)\n")
    assert cli.main(["run", "--plugin", str(plugin), "--learners", "qlearning", "--explorers",
                     "egreedy", "--quiet", "--out", str(tmp_path / "out")]) == 2
    line = one_error_line(capsys)
    assert str(plugin) in line and "sys.exit(3)" in line, line


SELECT_PLUGIN = """
import sys

import jax.numpy as jnp

from vdbejax.methods import Explorer, explorer, greedy


@explorer({name!r})
class Faulty(Explorer):
    num_uniforms = 1

    def select(self, q, tables, context, uniforms):
{body}
"""


@pytest.mark.parametrize("name, body, shown", [
    ("exits_0", "        sys.exit(0)", "it called sys.exit(0); a plug-in function returns"),
    ("exits_4", "        sys.exit(4)", "it called sys.exit(4)"),
    ("python_if", "        if q[0] > 0:\n            return jnp.int32(0)\n"
     "        return greedy(q, uniforms[0])", "write it with jnp.where or jax.lax.cond"),
    ("reads_two", "        return greedy(q + uniforms[1], uniforms[0])",
     "IndexError: tuple index out of range (a draw u[i] past those declared? a plug-in gets"
     " num_uniforms uniforms"),
])
def test_a_plug_in_mistake_in_select_is_one_line_that_says_what_to_change(
        tmp_path, trainings, capsys, name, body, shown):
    """sys.exit in a plug-in method is the same one-line error as any exception (exit 2,
    not the plug-in's code); Python control flow on a traced value and a draw past
    num_uniforms say what to change."""
    line = refused_plugin_run(tmp_path, capsys, name, SELECT_PLUGIN.format(name=name, body=body))
    assert f"explorer {name!r} select()" in line and shown in line, line
    assert not trainings and not (tmp_path / "out").exists()


# --------------------------------------------------------------- point 13: vdbejax compare
def test_compare_puts_two_folders_settings_side_by_side(finished, tmp_path, capsys):
    import csv

    other = tmp_path / "other"
    sweeps.run_sweep(other, **{**SWEEP, "sweep": Sweep(learners=["qlearning"],
                                                       explorers=["egreedy", "vdbe"])}, seed=1)
    table = tmp_path / "compare.csv"
    assert cli.main(["compare", str(finished), str(other), "--csv", str(table)]) == 0
    text = capsys.readouterr().out
    assert "| qlearning/egreedy/0.1 | " in text and "| qlearning/vdbe/1 | – |" in text
    rows = list(csv.DictReader(table.open()))
    assert [r["setting"] for r in rows] == ["qlearning/egreedy/0.1", "qlearning/vdbe/1"]
    assert rows[0]["overlap"] in ("True", "False") and rows[1]["overlap"] == ""
    a = io.read_csv(finished / "summary.csv")[0]
    assert float(rows[0]["a_final"]) == pytest.approx(float(a["final_return"]), abs=1e-6)
    assert cli.main(["compare", str(finished), str(tmp_path / "nothing")]) == 2
    assert "has no summary.csv" in one_error_line(capsys)


def test_compare_refuses_folders_of_different_tasks_unless_asked(finished, tmp_path, capsys):
    from vdbejax.results.compare import compare_folders

    chain = tmp_path / "chain"
    sweeps.run_sweep(chain, **SWEEP, task="chain")
    assert cli.main(["compare", str(finished), str(chain)]) == 2
    line = one_error_line(capsys)
    assert f"ran task 'table_cleaning' and b={str(chain)!r} task 'chain'" in line
    assert "--different-tasks" in line
    assert cli.main(["compare", str(finished), str(chain), "--different-tasks"]) == 0
    assert "| qlearning/egreedy/0.1 | " in capsys.readouterr().out
    family = tmp_path / "family"
    sweeps.run_sweep(family, **SWEEP, task="testbed:3", instances="per-agent")
    shared = tmp_path / "shared"
    sweeps.run_sweep(shared, **SWEEP, task="testbed:3")
    with pytest.raises(ValueError, match=r"task 'testbed:3 \(per-agent instances\)'"):
        compare_folders(shared, family)
    assert len(compare_folders(shared, family, different_tasks=True)) == 1
    assert len(compare_folders(family, family)) == 1
