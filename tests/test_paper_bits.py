"""The paper grid to the bit, under both readings: its ``returns.npz`` must not change
unless an issue says it may. The digests are the ones every stop has checked since issue
24: sha256 of ``returns[:, :20]`` and ``lengths[:, :20]`` (the first replicate's 20
agents per setting), as written by ``vdbejax reproduce --reading R --replicates 1``."""
from __future__ import annotations

import hashlib

import jax
import numpy as np
import pytest

import vdbejax
from vdbejax.runs import RunOptions

#: reading -> (returns, lengths): the first 12 hex digits of each sha256.
PINNED = {"textbook": ("e5dc72897ea1", "7a335184bbe8"),
          "authors": ("c0b226b46d32", "a8f052eec369")}


def _digest(values: np.ndarray) -> str:
    return hashlib.sha256(np.ascontiguousarray(values).tobytes()).hexdigest()[:12]


@pytest.mark.skipif(jax.default_backend() != "cpu",
                    reason="the pinned digests are the CPU backend's")
@pytest.mark.parametrize("reading", sorted(PINNED))
def test_the_paper_grid_keeps_its_bits(tmp_path, reading):
    vdbejax.reproduce(tmp_path, reading=reading, replicates=1, figures=False,
                      run=RunOptions(progress=False))
    with np.load(tmp_path / "returns.npz") as data:
        assert data["returns"].shape == (46, 20, 1000)
        digests = _digest(data["returns"][:, :20]), _digest(data["lengths"][:, :20])
    assert digests == PINNED[reading]
