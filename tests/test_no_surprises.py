"""What the README promises is what a newcomer gets, and the last faults end in one line
(issue 49): each test fails without its fix."""
from __future__ import annotations

import re
from pathlib import Path

import pytest

from vdbejax import cli
from vdbejax.results import io
from vdbejax.studies import folder as studies_folder
from vdbejax.studies import sweeps

SWEEP = dict(learners=["qlearning"], explorers=["egreedy"], seeds=2, episodes=12, progress=False)


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
    sweeps.run_sweep(finished, **{**SWEEP, "seeds": 3}, overwrite=True)
    assert trainings and io.load_json(finished / io.META_FILE)["num_seeds"] == 3


def test_resume_continues_only_the_same_run(finished, trainings):
    reused = sweeps.run_sweep(finished, **SWEEP, resume=True)  # a no-op on a finished run
    assert not trainings and reused.num_seeds == 2
    with pytest.raises(ValueError, match=r"finished result of a different run.*--overwrite"):
        sweeps.run_sweep(finished, **{**SWEEP, "episodes": 13}, resume=True)
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
        vdbejax.reproduce(finished, seeds=1, episodes=2, replicates=1, progress=False,
                          figures=False)
    assert not trainings


# ------------------------------------------------------- point 8: NumPy scalars are welcome
def test_reproduce_takes_numpy_scalars_and_labels_its_sizes_and_reading(tmp_path, capsys):
    import numpy as np

    import vdbejax

    out = tmp_path / "paper"
    rep = vdbejax.reproduce(out, seeds=np.int64(2), episodes=np.int64(3), seed=np.int64(2),
                            replicates=np.int64(2), alpha=np.float64(0.1),
                            q_init=np.float32(0.0), chunk_episodes=np.int64(2),
                            progress=np.bool_(True), figures=np.bool_(False))
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
    numpy = sweeps.run_sweep(tmp_path / "numpy", learners=["qlearning"], explorers=["egreedy"],
                             seeds=np.int64(2), episodes=np.int32(12), seed=np.uint32(1),
                             axes={"alpha": [np.float64(0.1), np.float32(0.5)]}, progress=False)
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
