"""One run's files per folder, OS errors, leftovers, crafted checkpoints and damaged result
folders (issue 14, defects 2, 7, 8, 9 and 10): each test fails without its fix."""
from __future__ import annotations

import dataclasses
import errno
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from damaged_results import damaged_copy
from small_grid import run_small

from vdbejax import cli
from vdbejax.results import folder_lock, io
from vdbejax.results.folder_lock import FolderLock
from vdbejax.results.grid_result import GridResult
from vdbejax.runs import RunOptions
from vdbejax.runs.checkpoint import CHECKSUM_KEY, contents_digest, log_path
from vdbejax.studies import folder as studies_folder
from vdbejax.studies import sweeps
from vdbejax.studies.sweeps import Sweep

QUIET = RunOptions(progress=False)
SWEEP = dict(sweep=Sweep(learners=["qlearning"], explorers=["egreedy"]), seeds=2, episodes=12,
             run=QUIET)


@pytest.fixture(scope="module")
def saved(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("run")
    sweeps.run_sweep(out, **SWEEP)
    return out


def one_error_line(capsys) -> str:
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), lines
    return lines[0]


# ------------------------------------------------------------------ defect 2: one run per folder
def test_a_second_writer_is_refused_before_training(tmp_path, monkeypatch):
    trained = []
    monkeypatch.setattr(studies_folder, "run_prepared", lambda *a, **k: trained.append(1))
    with FolderLock(tmp_path):
        with pytest.raises(ValueError, match="is being written by another vdbejax run"):
            sweeps.run_sweep(tmp_path, **SWEEP)
    assert not trained


def test_the_lock_is_released_by_the_os_when_the_holder_dies(tmp_path):
    holder = subprocess.Popen([sys.executable, "-c", (
        "import sys, time; from vdbejax.results.folder_lock import FolderLock;"
        f" FolderLock({str(tmp_path)!r}).acquire(); print('locked', flush=True); time.sleep(60)")],
        stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "locked"
        with pytest.raises(ValueError, match=f"process {holder.pid}"):
            FolderLock(tmp_path).acquire()
    finally:
        holder.kill()
        holder.wait()
    with FolderLock(tmp_path):  # free again: a killed run never leaves the folder locked
        pass


def test_a_run_stopped_while_saving_leaves_a_marker_that_loading_refuses(tmp_path, monkeypatch, saved):
    for name in ("returns.npz", "configs.csv", "meta.json"):
        (tmp_path / name).write_bytes((saved / name).read_bytes())

    def killed(self, out):  # the process dies half-way through the result files
        io.atomic_write_bytes(Path(out) / io.RETURNS_FILE, b"new")
        raise KeyboardInterrupt

    monkeypatch.setattr(GridResult, "write_files", killed)
    with pytest.raises(KeyboardInterrupt):
        sweeps.run_sweep(tmp_path, **{**SWEEP, "run": QUIET.replace(overwrite=True)})  # replaced (point 5)
    assert folder_lock.marked_stage(tmp_path) == "results"
    with pytest.raises(ValueError, match="half-written"):
        GridResult.load(tmp_path)


def test_a_run_stopped_while_drawing_is_finished_by_plot(tmp_path, monkeypatch, capsys):
    def killed(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(sweeps, "write_outputs", killed)
    with pytest.raises(KeyboardInterrupt):
        sweeps.run_sweep(tmp_path, **SWEEP)
    assert folder_lock.marked_stage(tmp_path) == "outputs"
    GridResult.load(tmp_path)  # the raw results are one run's
    monkeypatch.undo()
    assert cli.main(["plot", "--results", str(tmp_path)]) == 0
    assert folder_lock.marked_stage(tmp_path) is None
    assert (tmp_path / "summary.csv").exists()


def test_a_whole_run_leaves_no_marker(saved):
    assert folder_lock.marked_stage(saved) is None
    assert not (saved / folder_lock.MARKER_FILE).exists()


# ------------------------------------------------------------------ defect 7: OS errors
def test_an_output_path_that_is_a_folder_is_refused_before_training(tmp_path, capsys, monkeypatch):
    (tmp_path / "summary.csv").mkdir()
    trained = []
    monkeypatch.setattr(studies_folder, "run_prepared", lambda *a, **k: trained.append(1))
    assert cli.main(["run", "--out", str(tmp_path), "--learners", "qlearning", "--explorers",
                     "egreedy", "--seeds", "2", "--episodes", "5", "--quiet"]) == 2
    assert "summary.csv" in one_error_line(capsys) and not trained


def test_a_checkpoint_path_that_is_a_folder_is_refused(tmp_path):
    (tmp_path / "ckpt").mkdir()
    with pytest.raises(ValueError, match="checkpoint=.*not a file"):
        run_small(checkpoint=tmp_path / "ckpt")


def test_disk_full_while_saving_keeps_the_results_elsewhere(tmp_path, monkeypatch):
    real = io.atomic_write_bytes

    def full(path, data):
        if Path(path).parent == tmp_path:
            raise OSError(errno.ENOSPC, "No space left on device", str(path))
        real(path, data)

    monkeypatch.setattr(io, "atomic_write_bytes", full)
    with pytest.raises(ValueError) as caught, pytest.warns(RuntimeWarning, match=(
            "checkpoint .* cannot be written .*No space left on device.*: the run goes on")):
        sweeps.run_sweep(tmp_path, **SWEEP)
    message = str(caught.value)
    assert "No space left on device" in message and "\n" not in message
    kept = Path(message.split("kept in '")[1].split("'")[0])
    monkeypatch.undo()
    rescued = GridResult.load(kept)
    assert rescued.returns.shape == (1, 2, 12)


def test_failing_outputs_keep_the_saved_results(tmp_path, monkeypatch, capsys):
    def broken(*args, **kwargs):
        raise PermissionError(errno.EACCES, "Permission denied", str(tmp_path / "fig3.png"))

    monkeypatch.setattr(io, "save_figure", broken)
    assert cli.main(["run", "--out", str(tmp_path), "--learners", "qlearning", "--explorers",
                     "egreedy", "--seeds", "2", "--episodes", "12", "--quiet"]) == 2
    line = one_error_line(capsys)
    assert "Permission denied" in line and "fig3.png" in line and "vdbejax plot" in line
    assert GridResult.load(tmp_path).returns.shape == (1, 2, 12)


def test_ablate_into_a_read_only_folder_is_refused_before_training(tmp_path, capsys,
                                                                   monkeypatch):
    if os.geteuid() == 0:  # root writes into read-only folders: its write is refused instead
        write_bytes = Path.write_bytes

        def refused(self, data):
            if self.name.startswith(".write-test-"):
                raise PermissionError(13, "Permission denied", str(self))
            return write_bytes(self, data)

        monkeypatch.setattr(Path, "write_bytes", refused)
    tmp_path.chmod(0o500)
    try:
        assert cli.main(["ablate", "--out", str(tmp_path / "x"), "--seeds", "2",
                         "--episodes", "5"]) == 2
    finally:
        tmp_path.chmod(0o700)
    assert "out=" in one_error_line(capsys)


def test_ablate_checks_its_folders_before_training(tmp_path, capsys, monkeypatch):
    (tmp_path / "ablation").write_text("a file where a folder must go")
    from vdbejax.paper import ablation

    trained = []
    monkeypatch.setattr(ablation, "run_variant", lambda *a, **k: trained.append(1))
    assert cli.main(["ablate", "--out", str(tmp_path), "--seeds", "2", "--episodes", "5"]) == 2
    assert "writable folder" in one_error_line(capsys) and not trained


# ------------------------------------------------------------------ defect 8: leftovers
def dead_pid() -> int:
    child = subprocess.Popen([sys.executable, "-c", "pass"])
    child.wait()
    return child.pid


def test_temporary_files_of_dead_writers_are_removed_when_a_run_starts(tmp_path):
    stale = tmp_path / f".checkpoint.npz.{dead_pid()}.abc123.tmp"
    mine = tmp_path / f".summary.csv.{os.getpid()}.xyz.tmp"
    other = tmp_path / "notes.tmp"
    for path in (stale, mine, other):
        path.write_bytes(b"x" * 1000)
    sweeps.run_sweep(tmp_path, **SWEEP)
    assert not stale.exists() and mine.exists() and other.exists()


def test_run_grid_removes_stale_checkpoint_temporaries(tmp_path):
    stale = tmp_path / f".ckpt.npz.{dead_pid()}.q1w2e3.tmp"
    stale.write_bytes(b"x")
    run_small(checkpoint=tmp_path / "ckpt.npz")
    assert not stale.exists()


def test_sigterm_during_a_run_leaves_no_temporary_file(tmp_path):
    env = dict(os.environ, VDBEJAX_CACHE_DIR=str(tmp_path / "cache"))
    out = tmp_path / "out"
    run = subprocess.Popen([sys.executable, "-m", "vdbejax", "run", "--out", str(out),
                            "--learners", "qlearning", "--explorers", "egreedy", "--seeds", "2",
                            "--episodes", "400000", "--chunk-episodes", "50", "--quiet"],
                           env=env, stderr=subprocess.PIPE, text=True)
    deadline = time.time() + 120
    while not (out / folder_lock.LOCK_FILE).exists() and time.time() < deadline:
        time.sleep(0.05)
    time.sleep(2.0)  # training by now (400,000 episodes take far longer)
    run.send_signal(signal.SIGTERM)
    _, err = run.communicate(timeout=120)
    assert run.returncode == 143, err
    assert "interrupted" in err and "Traceback" not in err
    assert not list(out.glob(".*.tmp"))


# ------------------------------------------------------------------ defect 9: crafted checkpoints
@pytest.fixture(scope="module")
def checkpoint(tmp_path_factory) -> Path:
    from test_resume import Interrupted, interrupt_after

    path = tmp_path_factory.mktemp("ckpt") / "ckpt.npz"
    with pytest.raises(Interrupted):
        run_small(checkpoint=path, progress=interrupt_after(2))
    return path


def crafted(checkpoint: Path, tmp_path: Path, checksum: bool = True, **changes) -> Path:
    """A copy of ``checkpoint`` with ``changes`` applied and (by default) its checksum
    recomputed, as a deliberate edit would: the range and type checks must catch it."""
    with np.load(checkpoint) as data:
        arrays = {k: data[k] for k in data.files}
    for key, change in changes.items():
        arrays[key] = change(arrays[key])
    if checksum:
        arrays[CHECKSUM_KEY] = np.asarray(contents_digest(arrays))
    path = tmp_path / "ckpt.npz"
    np.savez(path, **arrays)
    shutil.copy(log_path(checkpoint), log_path(path))
    return path


@pytest.mark.parametrize("key, change, message", [
    ("agent_q", lambda q: q[..., :-1], "Q must be"),
    ("episodes_done", lambda d: d + 10_000, "episodes_done must lie"),
    ("agent_state", lambda s: s + 10_000, "agent states must lie"),
    ("state_rows", lambda r: np.r_[r, r[:1]], "state_rows"),
    ("agent_table_epsilon", lambda t: t[:, :3], "table 'epsilon'"),
    ("agent_q", lambda q: q.astype(np.int32), "agent q must be float32, not int32"),
    ("agent_table_epsilon", lambda t: t.astype(np.float64), "table 'epsilon' must be float32"),
    ("agent_key", lambda k: k ^ np.uint32(1), "random keys are not those of this run"),
])
def test_a_crafted_checkpoint_is_refused_naming_it(checkpoint, tmp_path, key, change, message):
    path = crafted(checkpoint, tmp_path, **{key: change})
    with pytest.raises(ValueError, match=message) as caught:
        run_small(checkpoint=path, resume=True)
    assert str(path) in str(caught.value)


@pytest.mark.parametrize("key, change", [
    ("agent_q", lambda q: q * 2),  # Q scaled by 2
    ("agent_counter", lambda c: c + np.uint32(1)),  # the random stream moved on
    ("agent_table_epsilon", lambda t: np.full_like(t, 5.0)),  # ε tables set to 5.0
    ("episodes_done", lambda d: d),  # unchanged values, but one flipped bit below
])
def test_a_changed_bit_in_a_checkpoint_is_refused(checkpoint, tmp_path, key, change):
    path = crafted(checkpoint, tmp_path, checksum=False, **{key: change})
    if key == "episodes_done":  # a flipped bit in the stored bytes of Q
        raw = bytearray(path.read_bytes())
        with np.load(path) as data:
            q = data["agent_q"]
        at = bytes(raw).index(q.tobytes()) + q.nbytes // 2
        raw[at] ^= 0x10
        path.write_bytes(bytes(raw))
    # An edit saved as a new file fails our checksum; a flipped bit in the file, the zip
    # member's own CRC-32 first.
    match = "Bad CRC-32" if key == "episodes_done" else "do not match its checksum"
    with pytest.raises(ValueError, match=match) as caught:
        run_small(checkpoint=path, resume=True)
    assert str(path) in str(caught.value) and "\n" not in str(caught.value)


def test_a_changed_bit_in_the_episode_log_is_refused(checkpoint, tmp_path):
    path = crafted(checkpoint, tmp_path)
    raw = bytearray(log_path(path).read_bytes())
    raw[-20] ^= 0x01  # inside the last record's lengths
    log_path(path).write_bytes(bytes(raw))
    with pytest.raises(ValueError, match="does not match its checksum") as caught:
        run_small(checkpoint=path, resume=True)
    assert str(log_path(path)) in str(caught.value)


def test_an_untouched_copy_of_a_checkpoint_resumes(checkpoint, tmp_path):
    # The fixtures above are not vacuous: the same copy without a change resumes, and equals
    # the run without interruption.
    path = crafted(checkpoint, tmp_path)
    assert np.array_equal(run_small(checkpoint=path, resume=True).returns,
                          run_small().returns)


def test_a_garbage_checkpoint_error_names_the_file(tmp_path):
    path = tmp_path / "ckpt.npz"
    path.write_bytes(b"garbage")
    with pytest.raises(ValueError, match="unreadable") as caught:
        run_small(checkpoint=path, resume=True)
    assert str(path) in str(caught.value)


# ------------------------------------------------------------------ defect 10: damaged folders
@pytest.mark.parametrize("damage, message", [
    ("empty returns", "unreadable"),
    ("meta list", "JSON object"),
    ("nonfinite shape", "nonfinite must be"),
    ("lengths shape", "lengths must be"),
    ("duplicate config", "repeated"),
    ("nan returns", "NaN or infinite"),
    ("missing column", "damaged"),
    ("param not a number", "damaged"),
])
def test_plot_refuses_a_damaged_folder_with_one_line(saved, tmp_path, capsys, damage, message):
    folder = damaged_copy(saved, tmp_path / "copy", damage)
    assert cli.main(["plot", "--results", str(folder)]) == 2
    line = one_error_line(capsys)
    assert message in line and str(folder) in line


def test_plot_accepts_an_explorer_it_does_not_know(saved, tmp_path):
    folder = damaged_copy(saved, tmp_path / "copy", "unknown explorer")
    assert cli.main(["plot", "--results", str(folder)]) == 0  # a plug-in's results: drawn by name
    assert "my_plugin" in (folder / "summary.csv").read_text()


def test_damaged_copy_really_damages(saved, tmp_path):
    # The fixture is not a no-op: every damaged copy differs from the saved folder.
    for damage in ("empty returns", "meta list", "duplicate config", "nan returns"):
        folder = damaged_copy(saved, tmp_path / damage.replace(" ", "_"), damage)
        differs = [n for n in ("returns.npz", "meta.json", "configs.csv")
                   if (folder / n).read_bytes() != (saved / n).read_bytes()]
        assert differs, damage
    assert json.loads((saved / "meta.json").read_text())


# ------------------------------------------------------------------ defect 4: checkpoint cost
def test_checkpoint_writes_grow_with_the_chunk_not_with_the_run(tmp_path):
    from vdbejax.runs.checkpoint import log_path

    path = tmp_path / "ckpt.npz"
    sizes = []

    def progress(done, total, elapsed):
        if path.exists():
            sizes.append((path.stat().st_size, log_path(path).stat().st_size))

    run_small(checkpoint=path, num_episodes=96, chunk_episodes=8, progress=progress)
    small = [s for s, _ in sizes]
    growth = np.diff([g for _, g in sizes])
    assert len(sizes) >= 10
    # The rewritten file does not grow with the episodes (the last holds no agent state).
    assert len(set(small[:-1])) == 1 and small[-1] <= small[0]
    # Each chunk appends its own episodes only: 12 agents × 8 episodes × 9 bytes + headers.
    assert growth.min() == growth.max() and 12 * 8 * 9 <= growth.max() <= 12 * 8 * 9 + 200


def test_a_resumed_run_ignores_what_a_killed_run_appended_to_the_log(tmp_path):
    from small_grid import assert_same_curves
    from test_resume import Interrupted, interrupt_after

    from vdbejax.runs.checkpoint import log_path

    path = tmp_path / "ckpt.npz"
    with pytest.raises(Interrupted):
        run_small(checkpoint=path, progress=interrupt_after(2))
    with open(log_path(path), "ab") as log:  # a record the killed run had begun
        log.write(b"\x07" * 37)
    assert_same_curves(run_small(), run_small(checkpoint=path, resume=True))


def test_a_log_that_misses_episodes_is_refused(tmp_path):
    from test_resume import Interrupted, interrupt_after

    from vdbejax.runs.checkpoint import log_path

    path = tmp_path / "ckpt.npz"
    with pytest.raises(Interrupted):
        run_small(checkpoint=path, progress=interrupt_after(3))
    data = log_path(path).read_bytes()
    log_path(path).write_bytes(data[: len(data) // 2])
    with pytest.raises(ValueError, match="checkpoint log .* is damaged"):
        run_small(checkpoint=path, resume=True)


# ------------------------------------------------------------------ defect 3: size estimate
def test_a_huge_run_is_refused_at_once_with_its_estimate(capsys):
    started = time.perf_counter()
    assert cli.main(["reproduce", "--out", "/nonexistent-never-created", "--seeds", "10000000",
                     "--episodes", "10000000"]) == 2
    line = one_error_line(capsys)
    assert "PiB of memory" in line and "free" in line
    assert time.perf_counter() - started < 30  # refused before anything is allocated
    assert not Path("/nonexistent-never-created").exists()


def test_the_size_estimate_counts_results_and_the_checkpoint_log(tmp_path, monkeypatch):
    from vdbejax.runs import batching

    needed = batching.check_run_size(10, 1000, available_bytes=10**9)
    assert needed == 10 * (1000 * 18 + 512)
    with pytest.raises(ValueError, match="need ≈ 180.8 KiB of memory.*100.0 KiB are free"):
        batching.check_run_size(10, 1000, available_bytes=100 * 1024)
    monkeypatch.setattr(batching.shutil, "disk_usage", lambda path: type("U", (), {"free": 1000})())
    with pytest.raises(ValueError, match="episode log would need ≈ 87.9 KiB of disk"):
        batching.check_run_size(10, 1000, tmp_path / "ckpt.npz", available_bytes=10**9)


def test_loading_a_grid_of_unregistered_plugins_keeps_the_process_state(tmp_path):
    """The swept parameter's name of an explorer this process never imported comes with
    the loaded settings (meta.json), not from a process-wide table that loading fills."""
    from vdbejax.methods.agents import Setting, parameter_name, with_parameter_names

    grid = run_small()  # saved as the results of an explorer this process never imported
    settings = [dataclasses.replace(s, explorer="never_imported") if s.explorer == "egreedy"
                else s for s in grid.settings]
    meta = dict(grid.meta, parameter_names=dict(grid.meta["parameter_names"],
                                                never_imported="eps0"),
                settings=json.loads(json.dumps([(s.learner, s.explorer, s.param,
                                                 s.hyperparameters) for s in settings])))
    GridResult(settings, grid.returns, grid.lengths, grid.nonfinite, meta).save(tmp_path)
    loaded = GridResult.load(tmp_path)
    renamed = [s for s in loaded.settings if s.explorer == "never_imported"]
    assert renamed and all(s.label.startswith(f"{s.learner}/never_imported/eps0=")
                           for s in renamed if s.param is not None)
    assert parameter_name("never_imported") == "param"  # nothing process-wide changed
    plain = Setting("qlearning", "never_imported", 0.5)
    assert plain.label == "qlearning/never_imported/param=0.5"
    named = with_parameter_names([plain], {"never_imported": "eps0"})[0]
    assert named == plain and named.label == "qlearning/never_imported/eps0=0.5"
    assert len(grid.settings) == len(loaded.settings)


def test_a_broken_meta_or_a_bad_config_index_is_one_line_naming_it(tmp_path):
    from synthetic_grid import synthetic_grid

    from vdbejax.results.grid_result import GridResult

    grid = synthetic_grid(seeds=2, episodes=10)
    grid.save(tmp_path)
    with pytest.raises(ValueError, match=r"config=99 is invalid: must be a config index in"
                                         r" \[0, 45\]"):
        grid.hyperparameters(99)
    (tmp_path / "meta.json").write_text("{broken")
    with pytest.raises(ValueError, match="meta.json' is unreadable: JSONDecodeError") as error:
        GridResult.load(tmp_path)
    assert "\n" not in str(error.value)



def test_a_stop_at_any_moment_of_an_atomic_write_leaves_no_temporary(tmp_path, monkeypatch):
    # The temporary is named before it is created: a stop (here: os.open's caller
    # interrupted right after the file exists) finds it and removes it.
    from vdbejax.results import io as result_io

    real_open = os.open

    def open_then_stop(*args, **kwargs):
        real_open(*args, **kwargs)
        raise KeyboardInterrupt  # as SIGINT would, between creating and naming the file

    monkeypatch.setattr(result_io.os, "open", open_then_stop)
    with pytest.raises(KeyboardInterrupt):
        result_io.atomic_write_bytes(tmp_path / "x.bin", b"data")
    assert list(tmp_path.iterdir()) == []
    monkeypatch.setattr(result_io.os, "open", real_open)
    result_io.atomic_write_bytes(tmp_path / "x.bin", b"data")
    assert (tmp_path / "x.bin").read_bytes() == b"data"
    assert (tmp_path / "x.bin").stat().st_mode & 0o777 == 0o666 & ~_current_umask()


def _current_umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def test_a_folder_of_other_files_is_refused_unless_overwrite(tmp_path, capsys, monkeypatch):
    from vdbejax.studies import depth, scaling

    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "thesis.tex").write_text("my own file")
    args = ["run", "--out", str(mine), "--learners", "qlearning", "--explorers", "egreedy",
            "--seeds", "2", "--episodes", "4", "--quiet", "--no-figures"]
    assert cli.main(args) == 2
    line = one_error_line(capsys)
    assert f"out={str(mine)!r} is not a vdbejax result folder and holds files (thesis.tex)" \
        in line and "--overwrite" in line
    assert sorted(p.name for p in mine.iterdir()) == ["thesis.tex"]  # nothing created
    for study, kwargs in ((scaling.run_scaling, {"size": scaling.QUICK}),
                          (depth.run_depth, {"quick": True})):
        with pytest.raises(ValueError, match="is not a vdbejax result folder"):
            study(mine, run=QUIET, **kwargs)
    assert sorted(p.name for p in mine.iterdir()) == ["thesis.tex"]
    # an empty folder, a folder of a run and --overwrite are written into
    empty = tmp_path / "empty"
    empty.mkdir()
    assert cli.main([*args[:2], str(empty), *args[3:]]) == 0
    assert cli.main([*args, "--overwrite"]) == 0
    assert (mine / io.META_FILE).is_file() and (mine / "thesis.tex").read_text() == "my own file"
    assert cli.main([*args, "--overwrite"]) == 0  # now a vdbejax folder: --overwrite as ever
    assert cli.main([*args, "--resume"]) == 0
