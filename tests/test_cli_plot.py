"""`vdbejax plot`: redraw from saved results, never retrain; bad input → exit 2, one line."""
import csv

import pytest
from synthetic_grid import synthetic_grid

from vdbejax import cli


@pytest.fixture()
def saved(tmp_path):
    folder = tmp_path / "results"
    folder.mkdir()
    synthetic_grid().save(folder)
    return folder


def test_plot_writes_all_outputs(saved, tmp_path, capsys):
    out = tmp_path / "plots"
    assert cli.main(["plot", "--results", str(saved), "--out", str(out), "--bands"]) == 0
    for name in ("fig3.png", "sensitivity.png", "summary.csv", "report.md"):
        assert (out / name).stat().st_size > 0
    printed = capsys.readouterr().out.split()
    assert str(out / "fig3.png") in printed
    with open(out / "summary.csv") as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == 46 and "convergence_ci_low" in rows[0]
    assert "Claim 1" in (out / "report.md").read_text()


def test_plot_defaults_to_results_folder(saved):
    assert cli.main(["plot", "--results", str(saved)]) == 0
    assert (saved / "fig3.png").exists()


@pytest.mark.parametrize("setup, message", [
    ("missing", "lacks"),
    ("garbage", "results"),
    ("mismatch", "does not match"),
])
def test_plot_bad_input(tmp_path, capsys, setup, message):
    folder = tmp_path / "bad"
    folder.mkdir()
    if setup == "garbage":
        (folder / "returns.npz").write_text("not an npz")
        (folder / "configs.csv").write_text("config,learner,explorer,param\n")
    elif setup == "mismatch":
        grid = synthetic_grid()
        grid.settings = grid.settings[:3]
        grid.save(folder)
    assert cli.main(["plot", "--results", str(folder)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error:") and message in err[0]


def test_plot_without_flags_redraws_the_figure_the_run_wrote(tmp_path, capsys):
    # One figure definition: `vdbejax plot` draws what `vdbejax run` (and reproduce) drew.
    out = tmp_path / "run"
    assert cli.main(["run", "--out", str(out), "--learners", "qlearning", "--explorers",
                     "vdbe,softmax", "--seeds", "3", "--episodes", "30", "--quiet"]) == 0
    written = {name: (out / name).read_bytes() for name in ("fig3.png", "sensitivity.png")}
    assert cli.main(["plot", "--results", str(out), "--out", str(tmp_path / "again")]) == 0
    for name, data in written.items():
        assert (tmp_path / "again" / name).read_bytes() == data, name
    assert cli.main(["plot", "--results", str(out), "--out", str(tmp_path / "plain"),
                     "--no-bands"]) == 0
    assert (tmp_path / "plain" / "fig3.png").read_bytes() != written["fig3.png"]
    capsys.readouterr()
