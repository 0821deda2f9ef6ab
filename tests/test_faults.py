"""Faults of the file system during a run (issue "Nothing silent", point 5), injected by a
file layer that fails the way a read-only, full or deleted folder does: one line, exit 2,
the last checkpoint kept, and the trained results rescued to a folder the line names.
Rerun the audit with ``pytest tests/test_faults.py``."""
from __future__ import annotations

import errno
import shutil
from pathlib import Path

import numpy as np
import pytest

from vdbejax import cli
from vdbejax.experiment import GridResult
from vdbejax.results import io
from vdbejax.runs import checkpoint as checkpoints

RUN = ["--learners", "qlearning", "--explorers", "egreedy,vdbe", "--seeds", "2", "--episodes",
       "40", "--chunk-episodes", "10", "--quiet", "--no-figures"]


def run(out: Path, *extra: str) -> int:
    return cli.main(["run", "--out", str(out), *RUN, *extra])


@pytest.fixture(scope="module")
def clean(tmp_path_factory) -> GridResult:
    out = tmp_path_factory.mktemp("clean")
    assert run(out) == 0
    return GridResult.load(out)


def after_first_checkpoint(monkeypatch, fault) -> None:
    """Call ``fault()`` once, right after the run's first checkpoint is written."""
    real = checkpoints.CheckpointWriter.__call__
    done: list[bool] = []

    def writing(self, state):
        real(self, state)
        if not done:
            done.append(True)
            fault()

    monkeypatch.setattr(checkpoints.CheckpointWriter, "__call__", writing)


def failing_writes(monkeypatch, folder: Path, number: int, reason: str) -> None:
    """From now on, every atomic write into ``folder`` fails with ``number``."""
    real = io.atomic_write_bytes

    def write(path, data):
        if Path(path).parent == folder:
            raise OSError(number, reason, str(path))
        real(path, data)

    monkeypatch.setattr(io, "atomic_write_bytes", write)


def one_line(capsys) -> str:
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), lines
    return lines[0]


def rescued(line: str) -> Path:
    return Path(line.split("kept in '")[1].split("'")[0])


@pytest.mark.parametrize("number, reason", [(errno.EROFS, "Read-only file system"),
                                            (errno.ENOSPC, "No space left on device"),
                                            (errno.EPERM, "Operation not permitted")])
def test_a_folder_that_stops_taking_writes_mid_run_keeps_checkpoint_and_results(
        tmp_path, monkeypatch, capsys, clean, number, reason):
    out = tmp_path / "out"
    after_first_checkpoint(monkeypatch, lambda: failing_writes(monkeypatch, out, number, reason))
    with pytest.warns(RuntimeWarning, match=f"cannot be written .*{reason}.*goes on"):
        assert run(out) == 2
    line = one_line(capsys)
    assert reason in line and str(out) in line
    np.testing.assert_array_equal(GridResult.load(rescued(line)).returns, clean.returns)
    monkeypatch.undo()  # the folder takes writes again: its last checkpoint resumes
    assert (out / "checkpoint.npz").exists()
    assert run(out, "--resume") == 0
    np.testing.assert_array_equal(GridResult.load(out).returns, clean.returns)


def test_a_folder_deleted_mid_run_is_noticed_and_the_results_kept(tmp_path, monkeypatch,
                                                                  capsys, clean):
    out = tmp_path / "out"
    after_first_checkpoint(monkeypatch, lambda: shutil.rmtree(out))
    assert run(out) == 2
    line = one_line(capsys)
    assert "lock file was deleted" in line
    np.testing.assert_array_equal(GridResult.load(rescued(line)).returns, clean.returns)
