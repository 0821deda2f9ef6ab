"""Results depend only on the seed and the configuration: not on the chunk size, the
batch composition (memory batches, other settings in the grid, their order) or a resume
(tests/test_resume.py) or the number of devices (tests/test_sharding.py)."""
from __future__ import annotations

import numpy as np
import pytest
from small_grid import SETTINGS, assert_same_curves, budget_for, run_small, small_mdp


@pytest.fixture(scope="module")
def reference():
    return run_small()


# One other chunk size only: each new size costs a compilation. 5 does not divide 24.
@pytest.mark.parametrize("chunk_episodes", [5])
def test_chunk_size_does_not_change_results(reference, chunk_episodes):
    assert_same_curves(reference, run_small(chunk_episodes=chunk_episodes))


@pytest.mark.parametrize("agents_per_batch", [4])
def test_memory_batches_do_not_change_results(reference, agents_per_batch):
    result = run_small(memory_budget_bytes=budget_for(small_mdp(), agents_per_batch))
    assert result.meta["agents_per_batch"] == agents_per_batch
    assert result.meta["batches"] == -(-len(SETTINGS) * 3 // agents_per_batch)
    assert_same_curves(reference, result)


def test_other_settings_and_their_order_do_not_change_results(reference):
    reordered = run_small(settings=SETTINGS[::-1])
    alone = run_small(settings=[SETTINGS[2]])
    np.testing.assert_array_equal(reordered.returns[::-1], reference.returns)
    np.testing.assert_array_equal(reordered.lengths[::-1], reference.lengths)
    np.testing.assert_array_equal(alone.returns[0], reference.returns[2])


def test_the_seed_matters(reference):
    other = run_small(seed=4)
    assert not np.array_equal(other.returns, reference.returns)
