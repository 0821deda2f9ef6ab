"""Checkpoints and resume: an interrupted run, resumed, equals an uninterrupted one bit for
bit (also after SIGKILL of a separate process, with batches, with another chunk size or
memory budget); result and checkpoint files are never half-written."""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pytest
from small_grid import (
    EPISODES,
    SEEDS,
    SETTINGS,
    assert_same_curves,
    budget_for,
    run_small,
    small_mdp,
)

from vdbejax.results import io
from vdbejax.results.grid_result import GridResult

TESTS = Path(__file__).parent


class Interrupted(Exception):
    pass


def interrupt_after(calls: int):
    """A progress callback that raises on its ``calls``-th call (after the checkpoint of
    that chunk was written: the driver checkpoints before it reports progress). The run
    reports once at its start, then after every chunk."""
    seen = []

    def progress(done: int, total: int, elapsed: float) -> None:
        seen.append(done)
        if len(seen) == calls:
            raise Interrupted

    return progress


@pytest.fixture(scope="module")
def reference():
    return run_small()


def checkpoint_progress(path: Path) -> np.ndarray:
    with np.load(path) as data:
        return data["episodes_done"]


def test_interrupted_then_resumed_equals_uninterrupted(tmp_path, reference):
    checkpoint = tmp_path / "ckpt.npz"
    with pytest.raises(Interrupted):
        run_small(checkpoint=checkpoint, progress=interrupt_after(3))  # 1st call is at 0
    done = checkpoint_progress(checkpoint)
    assert (done == 16).all(), done  # two chunks of 8 episodes
    resumed = run_small(checkpoint=checkpoint, resume=True)
    assert resumed.meta["resumed_from_agent_episodes"] == 16 * len(done)
    assert_same_curves(reference, resumed)


def test_resume_with_batches_and_another_budget(tmp_path, reference):
    checkpoint = tmp_path / "ckpt.npz"
    mdp = small_mdp()
    with pytest.raises(Interrupted):  # stop inside the second batch of 4 agents
        run_small(checkpoint=checkpoint, memory_budget_bytes=budget_for(mdp, 4),
                  progress=interrupt_after(5))  # start, 3 chunks of batch 1, 1 of batch 2
    done = checkpoint_progress(checkpoint)
    assert sorted(set(done.tolist())) == [0, 8, EPISODES], done
    resumed = run_small(checkpoint=checkpoint, resume=True,
                        memory_budget_bytes=budget_for(mdp, 12), chunk_episodes=5)
    assert_same_curves(reference, resumed)


def test_resume_without_checkpoint_starts_fresh(tmp_path, reference):
    result = run_small(checkpoint=tmp_path / "none.npz", resume=True)
    assert_same_curves(reference, result)


def test_checkpoint_of_another_run_is_refused(tmp_path):
    checkpoint = tmp_path / "ckpt.npz"
    with pytest.raises(Interrupted):
        run_small(checkpoint=checkpoint, progress=interrupt_after(2))
    with pytest.raises(ValueError, match="belongs to a different run"):
        run_small(checkpoint=checkpoint, resume=True, seed=4)


def test_damaged_checkpoint_is_refused_with_one_line(tmp_path):
    checkpoint = tmp_path / "ckpt.npz"
    checkpoint.write_bytes(b"PK\x03\x04 not really a zip")
    with pytest.raises(ValueError, match="is unreadable") as error:
        run_small(checkpoint=checkpoint, resume=True)
    assert "\n" not in str(error.value)


def test_atomic_write_leaves_old_file_or_new_file_never_a_partial_one(tmp_path, monkeypatch):
    target = tmp_path / "returns.npz"
    io.atomic_savez(target, x=np.arange(3))

    def crash(src, dst):
        raise OSError("killed during rename")

    monkeypatch.setattr(os, "replace", crash)
    with pytest.raises(OSError):
        io.atomic_savez(target, x=np.arange(1000))
    monkeypatch.undo()
    with np.load(target) as data:
        np.testing.assert_array_equal(data["x"], np.arange(3))
    assert [p.name for p in tmp_path.iterdir()] == ["returns.npz"]  # no temp file left


def test_saved_result_round_trips(tmp_path, reference):
    reference.save(tmp_path)
    assert_same_curves(reference, GridResult.load(tmp_path))


#: A sweep in its own process; the sleeping progress callback stands for a long run
#: (it does not touch the results) so the test can kill it between checkpoints.
SWEEP_SCRIPT = textwrap.dedent(
    """
    import sys, time
    sys.path.insert(0, {tests!r})
    from small_grid import run_small
    resume = sys.argv[2] == "resume"
    slow = (lambda done, total, elapsed: time.sleep(0.25)) if not resume else False
    result = run_small(checkpoint=sys.argv[1], resume=resume, chunk_episodes=2, progress=slow)
    result.save(sys.argv[1] + ".out")
    """
)


def test_sigkill_mid_run_then_resume_is_bit_identical(tmp_path, reference):
    script = tmp_path / "sweep.py"
    script.write_text(SWEEP_SCRIPT.format(tests=str(TESTS)))
    checkpoint = tmp_path / "ckpt.npz"
    env = dict(os.environ, JAX_COMPILATION_CACHE_DIR=str(tmp_path / "jax-cache"),
               JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS="0",
               JAX_PERSISTENT_CACHE_MIN_ENTRY_SIZE_BYTES="0")
    victim = subprocess.Popen([sys.executable, str(script), str(checkpoint), "fresh"], env=env,
                              stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    deadline = time.monotonic() + 240
    while not checkpoint.exists():
        assert victim.poll() is None, victim.stderr.read().decode()
        assert time.monotonic() < deadline, "no checkpoint appeared"
        time.sleep(0.02)
    time.sleep(0.3)  # let it run on: the kill lands at an arbitrary point of a later chunk
    os.kill(victim.pid, signal.SIGKILL)
    victim.wait()
    assert victim.returncode == -signal.SIGKILL
    assert not (tmp_path / "ckpt.npz.out").exists()
    done = checkpoint_progress(checkpoint)  # loadable: never half-written
    assert done.min() > 0 and done.max() < EPISODES, done
    assert not [p for p in tmp_path.iterdir() if p.name.endswith(".tmp")]

    resumed = subprocess.run([sys.executable, str(script), str(checkpoint), "resume"], env=env,
                             capture_output=True, text=True, timeout=240)
    assert resumed.returncode == 0, resumed.stderr
    result = GridResult.load(tmp_path / "ckpt.npz.out")
    assert result.meta["resumed_from_agent_episodes"] == int(done.sum())
    assert result.returns.shape == (len(SETTINGS), SEEDS, EPISODES)
    assert_same_curves(reference, result)


def test_atomic_files_get_the_usual_permissions(tmp_path):
    target = tmp_path / "meta.json"
    io.save_json(target, {"a": 1})
    mask = os.umask(0)
    os.umask(mask)
    assert target.stat().st_mode & 0o777 == 0o666 & ~mask


def test_a_run_stopped_before_its_first_checkpoint_leaves_no_file(tmp_path):
    # The episode log starts with the first checkpoint (a lone empty log was left behind).
    from small_grid import run_small

    from vdbejax.runs.checkpoint import log_path

    checkpoint = tmp_path / "ckpt.npz"

    def stop(done, total, elapsed):
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        run_small(checkpoint=checkpoint, progress=stop)
    assert not checkpoint.exists() and not log_path(checkpoint).exists()


def test_the_checkpoint_checksum_hashes_each_arrays_bytes_without_copying_them():
    # Checkpoints written before (whose checksum hashed copies of the bytes) still verify.
    import hashlib

    from vdbejax.runs.checkpoint import contents_digest

    arrays = {"a": np.arange(12, dtype=np.float32).reshape(3, 4)[:, ::2],
              "fingerprint": np.asarray("x" * 16), "version": np.asarray(6),
              "flags": np.zeros(3, bool), "state_rows": np.zeros(0, np.int64),
              "empty_q": np.zeros((0, 2, 3), np.float32)}
    reference = hashlib.sha256()
    for name in sorted(arrays):
        value = np.ascontiguousarray(arrays[name])
        reference.update(f"{name}|{value.dtype.str}|{value.shape}|".encode())
        reference.update(value.tobytes())
    assert contents_digest(arrays) == reference.hexdigest()
