"""Memory-aware batching: batch sizes from a memory budget, never more agents at once
than fit, identical results (see also test_determinism, test_resume, test_sharding)."""
from __future__ import annotations

import numpy as np
import pytest
from small_grid import (
    SEEDS,
    SETTINGS,
    assert_same_curves,
    budget_for,
    run_small,
    small_mdp,
)

from vdbejax.runs import RunState
from vdbejax.runs.batching import (
    agents_per_batch,
    bytes_per_agent,
    default_memory_budget,
    mdp_bytes,
)
from vdbejax.validation import parse_bytes


def test_bytes_per_agent_counts_tables_and_chunk_buffers():
    mdp = small_mdp()
    tables = 4 * 108 * 7 + 4 * 108
    # buffers of 16 episodes against 8 (float32 return, int32 length, bool cut each), 3 copies
    assert bytes_per_agent(mdp, 16) - bytes_per_agent(mdp, 8) == 3 * 8 * 9
    assert bytes_per_agent(mdp, 10) == bytes_per_agent(mdp, 16)  # the programs' buffers
    assert bytes_per_agent(mdp, 0) > tables
    assert mdp_bytes(mdp) > 108 * 7 * 4


def test_agents_per_batch():
    assert agents_per_batch(100, 10, 1000, 1) == 100          # everything fits
    assert agents_per_batch(100, 10, 255, 1) == 25
    assert agents_per_batch(100, 10, 255, 4) == 100           # 25 per device × 4
    assert agents_per_batch(1000, 10, 255, 4) == 100
    assert agents_per_batch(100, 10, 255, 1, fixed_bytes=50) == 20
    with pytest.raises(ValueError, match="memory_budget_bytes=15 is invalid: one agent needs about 25 bytes"):
        agents_per_batch(100, 10, 15, 1, fixed_bytes=15)


def test_default_budget_is_a_positive_share_of_free_memory():
    budget = default_memory_budget()
    assert budget > 0
    assert budget < 2**50


def test_tiny_budget_runs_in_batches_that_fit():
    mdp = small_mdp()
    peak = []

    def progress(done, total, elapsed):
        peak.append(done)

    result = run_small(memory_budget_bytes=budget_for(mdp, 4), progress=progress)
    assert result.meta["agents_per_batch"] == 4
    assert result.meta["batches"] == 3
    assert result.meta["memory_budget_bytes"] == budget_for(mdp, 4)
    assert peak == sorted(peak) and peak[-1] == len(SETTINGS) * SEEDS * 24  # monotone, complete
    assert (result.lengths > 0).all()


def test_budget_too_small_for_one_agent_is_a_clear_error():
    with pytest.raises(ValueError, match=r"memory_budget_bytes=1000 is invalid: one agent needs about \d+ bytes per device"):
        run_small(memory_budget_bytes=1000)


def test_next_batch_finishes_started_agents_first():
    progress = RunState.fresh(6, 10)
    np.testing.assert_array_equal(progress.next_batch(4), [0, 1, 2, 3])
    progress.episodes_done[[2, 3]] = 5
    progress.episodes_done[[0, 1]] = 10
    progress.state_rows = np.array([2, 3])  # started, unfinished: their states are stored
    np.testing.assert_array_equal(progress.next_batch(4), [2, 3])
    progress.episodes_done[:4] = 10
    np.testing.assert_array_equal(progress.next_batch(4), [4, 5])
    progress.episodes_done[:] = 10
    assert progress.next_batch(4).size == 0


def test_a_stop_policys_batch_is_the_chunk_of_its_least_advanced_agent():
    progress = RunState.fresh(5, 10)
    progress.episodes_done[:] = [2, 4, 4, 3, 0]  # a checkpoint taken in chunk [2, 4)
    progress.state_rows = np.arange(4)
    np.testing.assert_array_equal(progress.next_batch(8, chunk=2), [0, 1, 2, 3])
    progress.episodes_done[0] = 4
    progress.episodes_done[3] = 7  # (past the chunk [4, 6))
    np.testing.assert_array_equal(progress.next_batch(8, chunk=2), [0, 1, 2])
    np.testing.assert_array_equal(progress.next_batch(8), [0, 1, 2, 3])


def test_stopped_agents_leave_the_batches():
    progress = RunState.fresh(6, 10)
    progress.episodes_done[:] = 4
    progress.stop(np.array([0, 2]))
    np.testing.assert_array_equal(progress.next_batch(8), [1, 3, 4, 5])
    assert progress.episodes_credited() == 2 * 10 + 4 * 4  # a stopped agent counts as done
    progress.stop(np.array([1, 3, 4, 5]))
    assert progress.next_batch(8).size == 0 and progress.finished.all()


@pytest.mark.parametrize("text, expected", [
    (1000, 1000), ("1000", 1000), ("512M", 512 * 2**20), ("2G", 2 * 2**30), ("1.5GiB", 3 * 2**29),
    ("64k", 65536), ("3MB", 3 * 2**20),
])
def test_parse_bytes(text, expected):
    assert parse_bytes("memory_budget_bytes", text) == expected


@pytest.mark.parametrize("text", ["0", "-1", "abc", "nan", "inf", "", "G", "1.5X", 0, -5, True, None])
def test_parse_bytes_rejects(text):
    with pytest.raises(ValueError, match="memory_budget_bytes=.* is invalid"):
        parse_bytes("memory_budget_bytes", text)


def test_batches_with_or_without_checkpoints_equal_one_batch(tmp_path):
    # Without a checkpoint a batch is recorded once, at its end; with one, after every
    # chunk. Both must give what one batch gives, final states included.
    mdp = small_mdp()
    whole = run_small()
    for checkpoint in (None, tmp_path / "checkpoint.npz"):
        batched = run_small(memory_budget_bytes=budget_for(mdp, 4), checkpoint=checkpoint)
        assert batched.meta["batches"] == 3
        assert_same_curves(batched, whole)
