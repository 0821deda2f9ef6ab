"""Statistics against hand-computed values (vdbejax.results.stats)."""
import numpy as np
import pytest

from vdbejax.results import bootstrap, curves, stats


def test_moving_average_partial_windows():
    # Window 2 over [1, 3, 5]: the first point averages what is available.
    np.testing.assert_allclose(curves.moving_average([1.0, 3.0, 5.0], window=2), [1.0, 2.0, 4.0])


def test_final_return_is_mean_of_last_episodes():
    returns = np.array([[0.0, 1.0, 2.0, 3.0], [4.0, 4.0, 0.0, 2.0]])
    np.testing.assert_allclose(curves.final_return(returns, last=2), [2.5, 1.0])


def test_bootstrap_weights_match_indices():
    idx = bootstrap.bootstrap_indices(4, 50, seed=3)
    w = bootstrap.bootstrap_weights(4, 50, seed=3)
    x = np.array([1.0, 2.0, 5.0, 7.0])
    np.testing.assert_allclose(w @ x, x[idx].mean(-1))
    np.testing.assert_allclose(w.sum(-1), 1.0)


def test_bootstrap_ci_degenerate_and_contains_mean():
    assert bootstrap.bootstrap_ci(np.full(10, 0.3)) == pytest.approx((0.3, 0.3))
    x = np.arange(20.0)
    low, high = bootstrap.bootstrap_ci(x)
    assert low < x.mean() < high
    assert bootstrap.bootstrap_ci(x) == (low, high)  # deterministic (fixed seed)


def test_mean_curve_ci_identical_seeds_has_zero_width():
    curve = np.linspace(-1, 1, 30)
    mean, low, high = stats.mean_curve_ci(np.tile(curve, (5, 1)), window=3)
    np.testing.assert_allclose(mean, curves.moving_average(curve, 3))
    np.testing.assert_allclose(low, mean)
    np.testing.assert_allclose(high, mean)


def test_mean_curve_ci_brackets_mean():
    rng = np.random.default_rng(0)
    returns = rng.normal(size=(10, 40))
    mean, low, high = stats.mean_curve_ci(returns, window=5)
    assert np.all(low <= mean + 1e-12) and np.all(mean <= high + 1e-12)
    assert np.all(high - low > 0)


def test_final_return_ci():
    returns = np.array([[0.0, 1.0], [0.0, 3.0]])
    mean, low, high = stats.final_return_ci(returns, last=1)
    assert mean == 2.0 and low >= 1.0 and high <= 3.0


def test_interquartile_mean_by_hand():
    # n = 8: trim 2 from each end → mean(3, 4, 5, 6) = 4.5.
    assert bootstrap.interquartile_mean(np.arange(1.0, 9.0)) == 4.5
    # Robust to the outlier: mean(2, 3, 4, 5) = 3.5.
    assert bootstrap.interquartile_mean([0, 1, 2, 3, 4, 5, 6, 100]) == 3.5
    # n = 5: ⌊5/4⌋ = 1 trimmed each end → mean(2, 3, 4) = 3.
    assert bootstrap.interquartile_mean([5, 1, 4, 2, 3]) == 3.0
    # Along an axis.
    np.testing.assert_allclose(bootstrap.interquartile_mean(np.array([[1, 2, 3, 4], [0, 0, 8, 8]]), axis=1),
                               [2.5, 4.0])


def test_interquartile_mean_ci_constant():
    assert bootstrap.interquartile_mean_ci(np.full(8, 2.0)) == (2.0, 2.0, 2.0)


def test_probability_of_improvement_by_hand():
    # Pairs of x = [1, 2, 3] against y = [2, 2, 0]:
    #   1: <, <, > → 1;  2: =, =, > → 2;  3: >, >, > → 3.   Total 6 of 9.
    assert bootstrap.probability_of_improvement([1, 2, 3], [2, 2, 0]) == pytest.approx(6 / 9)
    assert bootstrap.probability_of_improvement([1, 1], [1, 1]) == 0.5
    assert bootstrap.probability_of_improvement([2, 3], [0, 1]) == 1.0
    # Complementary: P(X > Y) + P(Y > X) = 1.
    x, y = np.array([0.1, 0.5, 0.5, 0.9]), np.array([0.5, 0.2])
    assert bootstrap.probability_of_improvement(x, y) + bootstrap.probability_of_improvement(y, x) == pytest.approx(1)


def test_probability_of_improvement_ci():
    p, low, high = bootstrap.probability_of_improvement_ci([2.0, 3.0, 4.0], [0.0, 1.0])
    assert (p, low, high) == (1.0, 1.0, 1.0)
    rng = np.random.default_rng(1)
    x, y = rng.normal(0.2, 1, 20), rng.normal(0, 1, 20)
    p, low, high = bootstrap.probability_of_improvement_ci(x, y)
    assert 0 <= low <= p <= high <= 1 and high > low


def test_percentile_interval_equals_numpy_quantile_bit_for_bit():
    from vdbejax.results.bootstrap import percentile_interval

    rng = np.random.default_rng(7)
    for trial in range(120):
        n = int(rng.integers(1, 2500))
        level = float(rng.choice([0.95, 0.9, 0.99, 0.5, rng.uniform(0.01, 0.999)]))
        x = rng.normal(size=(n, 3) if trial % 2 else (n,)) * rng.choice([1e-3, 1.0, 1e3])
        if trial % 5 == 0:
            x = np.round(x, 1)  # ties
        if trial % 7 == 0:
            x = x.astype(np.float32)
        before = x.copy()
        alpha = (1 - level) / 2
        expected = np.quantile(x, [alpha, 1 - alpha], axis=0)
        low, high = percentile_interval(x, level, axis=0)
        np.testing.assert_array_equal(x, before)  # the input is not sorted in place
        for got, want in zip((low, high), expected):
            assert np.asarray(got).dtype == want.dtype
            np.testing.assert_array_equal(got, want)
    with_nan = np.array([1.0, np.nan, 2.0])
    assert all(np.isnan(v) for v in percentile_interval(with_nan, 0.9))


def test_curve_statistics_equal_the_per_setting_functions_for_any_thread_count():
    rng = np.random.default_rng(3)
    returns = rng.choice([-1.0, 0.2, 0.86], size=(5, 6, 150)).astype(np.float32)
    one = stats.curve_statistics(returns, window=10, last=30, bands=True, workers=1)
    two = stats.curve_statistics(returns, window=10, last=30, bands=True, workers=2)
    for name in ("final", "final_low", "final_high", "final_iqm", "curves", "band_low",
                 "band_high"):
        np.testing.assert_array_equal(getattr(one, name), getattr(two, name))
    for c in range(5):
        assert (one.final[c], one.final_low[c], one.final_high[c]) == stats.final_return_ci(returns[c], 30)
        curve, low, high = stats.mean_curve_ci(returns[c], 10)
        np.testing.assert_array_equal(one.band_low[c], low)
        np.testing.assert_array_equal(one.curves[c], curve)
    assert stats.curve_statistics(returns, window=10, last=30).band_low is None


def test_bootstrap_weights_are_shared_and_read_only():
    w = bootstrap.bootstrap_weights(7, 30, seed=2)
    assert w is bootstrap.bootstrap_weights(7, 30, seed=2)
    with pytest.raises(ValueError):
        w[0, 0] = 1.0


def test_wilson_interval():
    from vdbejax.results.stats import wilson_interval

    # Textbook values (Wilson 1927; e.g. Brown, Cai & DasGupta 2001): 5/10 and 0/10.
    assert wilson_interval(5, 10) == pytest.approx((0.2366, 0.7634), abs=1e-4)
    low, high = wilson_interval(0, 10)
    assert low == 0.0 and high == pytest.approx(0.2775, abs=1e-4)
    assert wilson_interval(10, 10)[1] == 1.0
    with pytest.raises(ValueError, match="successes=11, trials=10"):
        wilson_interval(11, 10)


def test_long_runs_are_resampled_in_blocks_with_the_same_statistics(monkeypatch):
    # 2000 resamples × 10⁷ episodes would be 149 GiB at once: long runs go block by block.
    from vdbejax.results import stats as statistics

    rng = np.random.default_rng(3)
    returns = np.cumsum(rng.normal(0.01, 0.1, (6, 700)), axis=1)
    whole = statistics.curve_statistics(returns[None], bands=True)
    # The paper's run size stays in one block: its numbers are computed exactly as before.
    assert bootstrap.rows_per_block(1000) >= bootstrap.NUM_RESAMPLES
    assert bootstrap.rows_per_block(bootstrap.NUM_RESAMPLES) >= 1000
    assert bootstrap.rows_per_block(200) >= bootstrap.NUM_RESAMPLES  # 10 × 20 agents
    monkeypatch.setattr(bootstrap, "BLOCK_BYTES", 8 * 700 * 37)  # 37 resamples, 7 episodes
    blocked = statistics.curve_statistics(returns[None], bands=True)
    assert blocked.final.tolist() == whole.final.tolist()
    np.testing.assert_allclose(blocked.band_low, whole.band_low, rtol=0, atol=1e-12)
    np.testing.assert_allclose(blocked.band_high, whole.band_high, rtol=0, atol=1e-12)


def test_many_seeds_are_resampled_in_blocks_with_the_same_statistics(monkeypatch):
    # 2000 resamples × 10⁵ seeds made 1.6 GB arrays (a 100,000-agent run peaked at 5 GB in
    # its summary): wide runs go resample block by resample block, the same resamples.
    from vdbejax.results import stats as statistics

    rng = np.random.default_rng(5)
    returns = np.cumsum(rng.normal(0.01, 0.1, (50, 120)), axis=1)
    whole = statistics.curve_statistics(returns[None], bands=True)
    indices = bootstrap.bootstrap_indices(50)
    monkeypatch.setattr(bootstrap, "BLOCK_BYTES", 8 * 50 * 7)  # 7 resamples of 50 seeds
    assert np.array_equal(np.concatenate(list(bootstrap.resample_blocks(50))), indices)
    weights = np.concatenate(list(bootstrap.weight_blocks(50)))
    np.testing.assert_array_equal(weights, bootstrap.bootstrap_weights(50))
    blocked = statistics.curve_statistics(returns[None], bands=True)
    for name in ("final", "final_low", "final_high", "final_iqm"):
        np.testing.assert_array_equal(getattr(blocked, name), getattr(whole, name), name)
    np.testing.assert_allclose(blocked.band_low, whole.band_low, rtol=0, atol=1e-12)
    np.testing.assert_allclose(blocked.band_high, whole.band_high, rtol=0, atol=1e-12)
    iqm = bootstrap.interquartile_mean_ci(returns[:, -1])
    monkeypatch.undo()
    assert iqm == bootstrap.interquartile_mean_ci(returns[:, -1])


def test_one_seeds_bootstrap_is_computed_once_with_the_same_numbers(monkeypatch):
    # Every resample of one seed is that seed: computed once (2,000 curves of 10^7
    # episodes took minutes), the numbers of the full bootstrap bit for bit.
    from vdbejax.results import stats as module

    rng = np.random.default_rng(1)
    t = np.arange(3000)
    one = (-1 + 0.9 * (1 - np.exp(-t / 300)) + 0.05 * rng.normal(size=t.size))[None]
    fast = module.mean_curve_ci(one)
    monkeypatch.setattr(module, "_distinct_weights", bootstrap.weight_blocks)  # all 2,000
    full = module.mean_curve_ci(one)
    for a, b in zip(fast, full, strict=True):
        np.testing.assert_array_equal(a, b)
