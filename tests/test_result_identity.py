"""A result folder proves what it holds (issue "Nothing silent"): its manifest ties every
file to the run by sha256, and the files must be plausible for the run meta.json
describes. Each damage below used to be drawn by `vdbejax plot` without a word."""
from __future__ import annotations

import csv
import io as text_io
import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from damaged_results import refresh_manifest

from vdbejax import cli
from vdbejax.results import io
from vdbejax.results.grid_result import GridResult
from vdbejax.results.manifest import MANIFEST_FILE, file_digest, read_manifest
from vdbejax.runs import RunOptions
from vdbejax.studies import sweeps
from vdbejax.studies.sweeps import Sweep

SWEEP = dict(sweep=Sweep(learners=["qlearning"], explorers=["egreedy", "softmax"]), seeds=3,
             episodes=30, run=RunOptions(progress=False))


@pytest.fixture(scope="module")
def runs(tmp_path_factory) -> tuple[Path, Path]:
    """Two runs of one sweep: root seeds 0 and 1."""
    first, second = tmp_path_factory.mktemp("seed0"), tmp_path_factory.mktemp("seed1")
    sweeps.run_sweep(first, **SWEEP)
    sweeps.run_sweep(second, **SWEEP, seed=1)
    return first, second


def _arrays(folder: Path) -> dict[str, np.ndarray]:
    with np.load(folder / io.RETURNS_FILE) as data:
        return {k: data[k].copy() for k in data.files}


def _rewrite(folder: Path, **changes) -> None:
    arrays = _arrays(folder)
    for key, change in changes.items():
        arrays[key] = change(arrays[key])
    np.savez_compressed(folder / io.RETURNS_FILE, **arrays)


def _edit_configs(folder: Path, edit) -> None:
    rows = list(csv.DictReader((folder / io.CONFIGS_FILE).open()))
    edit(rows)
    buffer = text_io.StringIO()
    writer = csv.DictWriter(buffer, fieldnames=list(rows[0]), lineterminator="\n")
    writer.writeheader()
    writer.writerows(rows)
    (folder / io.CONFIGS_FILE).write_text(buffer.getvalue())


def _swap_explorers(rows) -> None:
    rows[0]["explorer"], rows[-1]["explorer"] = rows[-1]["explorer"], rows[0]["explorer"]


def _edit_meta(folder: Path, **values) -> None:
    meta = json.loads((folder / io.META_FILE).read_text())
    meta.update(values)
    (folder / io.META_FILE).write_text(json.dumps(meta))


def _damage(name: str, folder: Path, other: Path) -> None:
    if name == "returns of another seed":
        shutil.copy(other / io.RETURNS_FILE, folder / io.RETURNS_FILE)
    elif name == "returns shifted by 0.5":
        _rewrite(folder, returns=lambda r: r + np.float32(0.5))
    elif name == "returns above the best":
        _rewrite(folder, returns=lambda r: r + np.float32(5.0))
    elif name == "lengths above max_steps":
        _rewrite(folder, lengths=lambda n: np.where(np.arange(n.shape[-1]) == 3, 10_000, n))
    elif name == "episodes cut":
        _rewrite(folder, returns=lambda r: r[..., :20], lengths=lambda n: n[..., :20])
    elif name == "meta of another seed":
        shutil.copy(other / io.META_FILE, folder / io.META_FILE)
    elif name == "seed changed":
        _edit_meta(folder, seed=7)
    elif name == "explorers swapped":
        _edit_configs(folder, _swap_explorers)
    elif name == "param edited":
        _edit_configs(folder, lambda rows: rows[1].update(param="0.07"))
    else:
        raise ValueError(name)


# (damage, the file the manifest names, what the checks beyond the manifest say)
DAMAGES = [
    ("returns of another seed", io.RETURNS_FILE, None),
    ("returns shifted by 0.5", io.RETURNS_FILE, None),
    ("returns above the best", io.RETURNS_FILE, "above the task's best possible"),
    ("lengths above max_steps", io.RETURNS_FILE, "beyond max_steps=100"),
    ("episodes cut", io.RETURNS_FILE, "3 × 30"),
    ("meta of another seed", io.META_FILE, "differ in fingerprint, seed"),
    ("seed changed", io.META_FILE, "differ in seed"),
    ("explorers swapped", io.CONFIGS_FILE, "config 0 is qlearning/softmax"),
    ("param edited", io.CONFIGS_FILE, "=0.07, meta.json says"),
]


def _refused(folder: Path, capsys) -> str:
    assert cli.main(["plot", "--results", str(folder)]) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), lines
    return lines[0]


@pytest.mark.parametrize("damage, file, _", DAMAGES)
def test_a_changed_or_foreign_result_file_is_refused_by_the_manifest(runs, tmp_path, capsys,
                                                                      damage, file, _):
    folder = tmp_path / "copy"
    shutil.copytree(runs[0], folder)
    _damage(damage, folder, runs[1])
    line = _refused(folder, capsys)
    assert str(folder / file) in line
    assert "sha256" in line or "does not belong to the run" in line


@pytest.mark.parametrize("damage, file, message", [d for d in DAMAGES if d[2]])
def test_an_implausible_result_is_refused_even_with_a_rewritten_manifest(
        runs, tmp_path, capsys, damage, file, message):
    folder = tmp_path / "copy"
    shutil.copytree(runs[0], folder)
    _damage(damage, folder, runs[1])
    refresh_manifest(folder)  # as an edit that also rewrote the manifest would
    line = _refused(folder, capsys)
    assert message in line and str(folder) in line


def test_an_untouched_copy_loads_and_the_manifest_lists_every_file(runs, tmp_path):
    folder = tmp_path / "copy"
    shutil.copytree(runs[0], folder)
    refresh_manifest(folder)  # rewriting an undamaged folder's manifest changes nothing
    assert GridResult.load(folder).returns.shape == (2, 3, 30)
    listed = read_manifest(runs[0])
    meta = json.loads((runs[0] / io.META_FILE).read_text())
    assert listed["run"]["fingerprint"] == meta["fingerprint"] and listed["run"]["seed"] == 0
    on_disk = {p.name for p in runs[0].iterdir() if p.is_file() and not p.name.startswith(".")}
    assert set(listed["files"]) == on_disk - {MANIFEST_FILE}
    assert {"returns.npz", "summary.csv", "fig3.png"} <= set(listed["files"])
    assert all(file_digest(runs[0] / n) == d for n, d in listed["files"].items())


def test_plot_keeps_the_manifest_true_to_the_redrawn_outputs(runs, tmp_path):
    folder = tmp_path / "copy"
    shutil.copytree(runs[0], folder)
    assert cli.main(["plot", "--results", str(folder), "--no-bands"]) == 0
    listed = read_manifest(folder)["files"]
    assert file_digest(folder / "fig3.png") == listed["fig3.png"]
    assert GridResult.load(folder).num_episodes == 30


def test_a_folder_written_before_manifests_still_loads(runs, tmp_path):
    folder = tmp_path / "copy"
    shutil.copytree(runs[0], folder)
    (folder / MANIFEST_FILE).unlink()
    with pytest.raises(ValueError, match="lacks a readable manifest.json"):
        GridResult.load(folder)  # its meta.json names one: removing it is noticed
    meta = json.loads((folder / io.META_FILE).read_text())
    del meta["manifest"]  # as meta.json was before manifests
    (folder / io.META_FILE).write_text(json.dumps(meta))
    assert GridResult.load(folder).returns.shape == (2, 3, 30)
