"""Faults of the file system during a run (issue "Nothing silent", point 5), injected by a
file layer that fails the way a read-only, full or deleted folder does: one line, exit 2,
the last checkpoint kept, and the trained results rescued to a folder the line names.
Rerun the audit with ``pytest tests/test_faults.py``."""
from __future__ import annotations

import errno
import os
import shutil
from pathlib import Path

import numpy as np
import pytest

from vdbejax import cli
from vdbejax.results import io
from vdbejax.results.grid_result import GridResult
from vdbejax.runs import RunOptions
from vdbejax.runs import checkpoint as checkpoints
from vdbejax.studies.sweeps import Sweep, run_sweep

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


def frozen_once_returns_are_written(monkeypatch, folder: Path) -> None:
    """From the moment ``returns.npz`` is in ``folder`` on, nothing in it can be written or
    removed, as after ``chattr +i``: PermissionError (EPERM)."""
    real_write, real_unlink = io.atomic_write_bytes, Path.unlink
    frozen: list[bool] = []

    def denied(path) -> PermissionError:
        return PermissionError(errno.EPERM, "Operation not permitted", str(path))

    def write(path, data):
        if frozen and Path(path).parent == folder:
            raise denied(path)
        real_write(path, data)
        if Path(path) == folder / io.RETURNS_FILE:
            frozen.append(True)

    def unlink(path, missing_ok=False):
        if frozen and path.parent == folder:
            raise denied(path)
        real_unlink(path, missing_ok=missing_ok)

    monkeypatch.setattr(io, "atomic_write_bytes", write)
    monkeypatch.setattr(Path, "unlink", unlink)


def test_a_folder_made_unwritable_while_saving_is_one_line_naming_what_it_left(
        tmp_path, monkeypatch, capsys, clean):
    # The lock file cannot be removed either: the lock is given back all the same, and the
    # file is named at the end of the run's one line (issue 49, point 6).
    out = tmp_path / "out"
    frozen_once_returns_are_written(monkeypatch, out)
    assert run(out) == 2  # returned: no traceback
    line = one_line(capsys)
    assert "Operation not permitted" in line and str(out) in line
    assert line.endswith(f"could not remove {out / '.vdbejax.lock'} (Operation not permitted)")
    np.testing.assert_array_equal(GridResult.load(rescued(line)).returns, clean.returns)
    left = {p.name for p in out.iterdir()}
    assert {".vdbejax.lock", ".vdbejax-writing", io.RETURNS_FILE, "checkpoint.npz"} <= left
    with pytest.raises(ValueError, match=r"lacks configs\.csv"):
        GridResult.load(out)  # half-written (and marked so)
    monkeypatch.undo()  # writable again: the checkpoint resumes, the lock file is reused
    assert run(out, "--resume") == 0
    np.testing.assert_array_equal(GridResult.load(out).returns, clean.returns)
    assert not (out / ".vdbejax.lock").exists()


def no_space_for_the_lock(monkeypatch) -> None:
    """A full disk: the lock file is created (an inode) but its pid cannot be written."""

    def pwrite(fd, data, offset):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(os, "pwrite", pwrite)


def test_a_full_disk_is_one_line_and_leaves_no_folder_and_no_lock(tmp_path, monkeypatch,
                                                                   capsys):
    no_space_for_the_lock(monkeypatch)
    out = tmp_path / "new" / "out"
    assert run(out) == 2
    line = one_line(capsys)
    assert line == (f"error: out={str(out)!r} cannot be locked for writing: No space left on"
                    " device")
    assert not out.exists()  # the folder this run made is gone again, and its parent
    assert not (tmp_path / "new").exists()
    kept = tmp_path / "kept"  # a folder the user made stays, without a lock file
    kept.mkdir()
    with pytest.raises(ValueError, match="cannot be locked for writing: No space left"):
        run_sweep(kept, Sweep(learners=["qlearning"], explorers=["egreedy"]), seeds=1,
                  episodes=5, figures=False, run=RunOptions(progress=False))
    assert list(kept.iterdir()) == []


@pytest.mark.parametrize("command", [
    ["bench", "--quick", "--quiet"],
    ["depth", "--quick", "--quiet"],
    ["scale", "--sizes", "2x1", "--seeds", "2", "--episodes", "300", "--quiet"],
])
def test_every_study_on_a_full_disk_leaves_no_folder(tmp_path, monkeypatch, capsys, command):
    no_space_for_the_lock(monkeypatch)
    out = tmp_path / "new" / "study"
    assert cli.main([command[0], "--out", str(out), *command[1:]]) == 2
    assert one_line(capsys) == (f"error: out={str(out)!r} cannot be locked for writing: No"
                                " space left on device")
    assert not out.exists()  # the folder this command made is gone again, its parent too
    assert list(tmp_path.iterdir()) == []


def test_a_full_disk_while_probing_the_folder_leaves_no_folder(tmp_path, monkeypatch,
                                                               capsys):
    real = Path.write_bytes

    def write_bytes(path, data):
        if path.name.startswith(".write-test-"):
            raise OSError(errno.ENOSPC, "No space left on device", str(path))
        return real(path, data)

    monkeypatch.setattr(Path, "write_bytes", write_bytes)
    assert run(tmp_path / "a" / "b") == 2
    assert "No space left on device" in one_line(capsys)
    assert list(tmp_path.iterdir()) == []


def test_a_folder_that_existed_stays_when_the_lock_fails(tmp_path, monkeypatch, capsys):
    (tmp_path / "mine").mkdir()
    no_space_for_the_lock(monkeypatch)
    assert run(tmp_path / "mine" / "a" / "out") == 2
    one_line(capsys)
    assert [p.name for p in tmp_path.iterdir()] == ["mine"]  # only what the run made went
    assert list((tmp_path / "mine").iterdir()) == []


_CHECKPOINT_FAILS = """
import errno, sys
from pathlib import Path
from vdbejax.results import io

real = io.atomic_write_bytes

def full(path, data):
    if Path(path).name == "checkpoint.npz":
        raise OSError(errno.ENOSPC, "No space left on device", str(path))
    real(path, data)

io.atomic_write_bytes = full
from vdbejax._console import main
sys.argv = ["vdbejax", "run", "--out", sys.argv[1], *sys.argv[2:]]
sys.exit(main())
"""


def test_a_checkpoint_that_cannot_be_written_is_one_warning_line(tmp_path):
    import subprocess
    import sys

    done = subprocess.run([sys.executable, "-c", _CHECKPOINT_FAILS, str(tmp_path / "out"), *RUN],
                          capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1, lines  # no file:line prefix, no source line
    assert lines[0].startswith("warning: checkpoint ") and "No space left on device" in lines[0]
    assert "RuntimeWarning" not in done.stderr
