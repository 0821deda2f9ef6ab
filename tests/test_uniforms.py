"""The engine's random stream (engine.state.uniforms, a lowbias32 counter hash): uniform
on its 2^23 values, and no correlation between consecutive counters, between the draws of
one iteration, or between neighbouring agents' keys. The stream is a pure function of its
inputs, so these checks give the same answer on every run."""
import itertools
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from vdbejax.engine import agent_keys, uniforms

N = 1 << 16  # counters per key
BINS = 64


def _draws(key: np.ndarray, count: int = 3) -> np.ndarray:
    counter = jnp.arange(N, dtype=jnp.uint32)
    keys = jnp.broadcast_to(jnp.asarray(key, jnp.uint32), (N, 2))
    return np.stack([np.asarray(d) for d in jax.jit(uniforms, static_argnums=2)(
        keys, counter, count)])


def _chi_square_p(values: np.ndarray) -> float:
    """Upper-tail p-value of Pearson's chi-square for equal bins (Wilson–Hilferty)."""
    observed = np.bincount(np.minimum((values * BINS).astype(int), BINS - 1), minlength=BINS)
    expected = values.size / BINS
    statistic = float(((observed - expected) ** 2 / expected).sum())
    dof = BINS - 1
    z = ((statistic / dof) ** (1 / 3) - (1 - 2 / (9 * dof))) / math.sqrt(2 / (9 * dof))
    return 0.5 * math.erfc(z / math.sqrt(2))


def _correlation(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.corrcoef(a, b)[0, 1])


#: |r| of independent uniforms exceeds this with probability ≈ 1e-6 at N samples.
R_MAX = 5.0 / math.sqrt(N)


@pytest.fixture(scope="module")
def streams():
    return [_draws(key) for key in agent_keys(0, 3)]


def test_draws_lie_in_the_documented_range(streams):
    for draws in streams:
        assert draws.min() >= 0.0 and draws.max() <= 1.0 - 2.0**-23
        steps = draws * 2.0**23
        np.testing.assert_array_equal(steps, np.round(steps))  # 23-bit values


def test_every_draw_is_uniform_by_chi_square(streams):
    for draws in streams:
        for j in range(draws.shape[0]):
            assert _chi_square_p(draws[j]) > 1e-6
            assert abs(draws[j].mean() - 0.5) < 5 * math.sqrt(1 / 12 / N)


def test_no_serial_correlation_between_consecutive_counters(streams):
    for draws in streams:
        for j in range(draws.shape[0]):
            for lag in (1, 2, 7):
                assert abs(_correlation(draws[j][:-lag], draws[j][lag:])) < R_MAX


def test_no_correlation_between_the_draws_of_one_iteration(streams):
    for draws in streams:
        for i in range(draws.shape[0]):
            for j in range(i + 1, draws.shape[0]):
                assert abs(_correlation(draws[i], draws[j])) < R_MAX


def test_no_correlation_between_neighbouring_agents(streams):
    for a, b in itertools.pairwise(streams):
        assert abs(_correlation(a[0], b[0])) < R_MAX


def test_pairs_of_consecutive_draws_fill_the_square_evenly(streams):
    """Chi-square on 16 × 16 cells of (u_t, u_{t+1}): catches structure that a correlation
    coefficient misses."""
    draws = streams[0][0]
    cells = (np.minimum((draws[:-1] * 16).astype(int), 15) * 16
             + np.minimum((draws[1:] * 16).astype(int), 15))
    observed = np.bincount(cells, minlength=256)
    expected = cells.size / 256
    statistic = float(((observed - expected) ** 2 / expected).sum())
    dof = 255
    z = ((statistic / dof) ** (1 / 3) - (1 - 2 / (9 * dof))) / math.sqrt(2 / (9 * dof))
    assert 0.5 * math.erfc(z / math.sqrt(2)) > 1e-6
