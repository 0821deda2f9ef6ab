"""Episodes to solve on hand-made curves, and the censored summaries (vdbejax.results.solving)."""
from __future__ import annotations

import math

import numpy as np
import pytest

from vdbejax.methods.agents import Setting
from vdbejax.results.analysis import summarize
from vdbejax.results.bootstrap import bootstrap_ci, bootstrap_indices
from vdbejax.results.curves import moving_average
from vdbejax.results.grid_result import GridResult
from vdbejax.results.solving import (
    CONVERGENCE_TEXT,
    SolveSummary,
    convergence_threshold,
    episodes_to_converge,
    median_episodes,
    solving_rows,
    summarize_solving,
)


def step_curve(length: int, jump: int, low: float = 0.0, high: float = 1.0) -> np.ndarray:
    """``low`` for the first ``jump`` episodes, ``high`` afterwards (float32, like the engine)."""
    curve = np.full(length, low, np.float32)
    curve[jump:] = high
    return curve


# ---------------------------------------------------------------- episodes to solve


def test_solved_at_the_first_full_window_above_the_threshold():
    # Window 5, threshold 0.9: episodes 11..15 are 1.0, so the mean of episodes 11..15 is
    # the first that reaches 0.9 (episode 14's window holds one 0: 0.8).
    times = episodes_to_converge(step_curve(50, 10), 1.0, 0.0, fraction=0.9, window=5)
    assert times.solved.item() and times.episodes.item() == 15


def test_the_threshold_is_a_normalised_score_and_returns_may_be_negative():
    # best 0.8, random 0 → threshold 0.72; failures score −1. With window 4, three successes and a
    # failure average (3 · 0.8 − 1) / 4 = 0.35 < 0.72; four successes in a row: 0.8.
    curve = np.array([-1, -1, 0.8, 0.8, 0.8, -1, 0.8, 0.8, 0.8, 0.8, 0.8], np.float32)
    times = episodes_to_converge(curve, 0.8, 0.0, fraction=0.9, window=4)
    assert times.solved.item() and times.episodes.item() == 10
    assert convergence_threshold(0.8, 0.0, 0.9) == pytest.approx(0.72)
    # 0.7 ≥ 0.9 × 0.8 fails; a lower fraction accepts it.
    flat = np.full(30, 0.7, np.float32)
    assert not episodes_to_converge(flat, 0.8, 0.0, window=4).solved.item()
    assert episodes_to_converge(flat, 0.8, 0.0, fraction=0.85, window=4).episodes.item() == 4


def test_never_solved_is_censored_at_the_budget():
    times = episodes_to_converge(np.full(40, 0.5, np.float32), 1.0, 0.0, window=5)
    assert not times.solved.item() and times.episodes.item() == 40


def test_solved_exactly_at_the_last_episode():
    times = episodes_to_converge(step_curve(15, 10), 1.0, 0.0, fraction=0.9, window=5)
    assert times.solved.item() and times.episodes.item() == 15
    one_short = episodes_to_converge(step_curve(14, 10), 1.0, 0.0, fraction=0.9, window=5)
    assert not one_short.solved.item() and one_short.episodes.item() == 14


def test_partial_windows_at_the_start_do_not_count():
    # A lucky first episode: the moving average's partial window (1 episode) would be 1.0.
    curve = np.zeros(30, np.float32)
    curve[0] = 1.0
    assert moving_average(curve, 5)[0] == 1.0
    assert not episodes_to_converge(curve, 1.0, 0.0, window=5).solved.item()
    # A whole run shorter than the window is never solved.
    short = episodes_to_converge(np.ones(3, np.float32), 1.0, 0.0, window=5)
    assert not short.solved.item() and short.episodes.item() == 3


def test_float32_returns_at_the_threshold_count():
    # float32(0.9) < 0.9 in float64: the tolerance accepts returns equal to the threshold.
    curve = np.full(10, 0.9, np.float32)
    assert float(curve[0]) < 0.9
    assert episodes_to_converge(curve, 1.0, 0.0, fraction=0.9, window=3).episodes.item() == 3


def test_moving_average_is_stats_trailing_one():
    rng = np.random.default_rng(1)
    curves = rng.uniform(-1, 1, size=(6, 200)).astype(np.float32)
    best, baseline, window = 0.5, -0.3, 7
    times = episodes_to_converge(curves, best, baseline, fraction=0.9, window=window)
    smoothed = moving_average((curves.astype(np.float64) - baseline) / 0.8, window)
    for row, episode, solved in zip(smoothed, times.episodes, times.solved):
        hits = np.flatnonzero(row[window - 1:] >= 0.9 - 1e-6) + window
        assert solved == bool(hits.size)
        assert episode == (hits[0] if hits.size else 200)


def test_batched_shapes_and_episodes_run_ignore_the_padding():
    curves = np.stack([step_curve(60, 10), step_curve(60, 30), np.zeros(60, np.float32)])
    curves[0, 20:] = np.nan  # agent 0 stopped after 20 episodes: NaN padding
    times = episodes_to_converge(curves[None], 1.0, 0.0, window=5,
                              episodes_run=np.array([[20, 60, 45]]))
    assert times.episodes.shape == (1, 3)
    np.testing.assert_array_equal(times.episodes, [[15, 35, 45]])
    np.testing.assert_array_equal(times.solved, [[True, True, False]])
    # A solve after an agent's stop does not count.
    late = episodes_to_converge(step_curve(60, 30), 1.0, 0.0, window=5, episodes_run=34)
    assert not late.solved.item() and late.episodes.item() == 34


@pytest.mark.parametrize("kwargs,match", [
    ({"best": 0.0}, "best=0.0 and baseline=0.0 are invalid"),
    ({"best": -0.5}, "best=-0.5 and baseline=0.0 are invalid"),
    ({"best": float("nan")}, "best=nan and baseline=0.0 are invalid"),
    ({"best": 1.0, "fraction": 0.0}, "fraction=0.0 is invalid"),
    ({"best": 1.0, "fraction": 1.5}, "fraction=1.5 is invalid"),
    ({"best": 1.0, "window": 0}, "window=0 is invalid"),
    ({"best": 1.0, "episodes_run": 11}, "episodes_run holds 11"),
    ({"best": 1.0, "episodes_run": np.array([3, 4])}, "episodes_run has shape"),
    ({"best": 1.0, "episodes_run": 2.5}, "episodes_run has dtype"),
])
def test_bad_inputs_are_one_line_value_errors(kwargs, match):
    with pytest.raises(ValueError, match=match) as error:
        episodes_to_converge(np.zeros(10, np.float32), baseline=0.0, **kwargs)
    assert "\n" not in str(error.value)


# ---------------------------------------------------------------- summaries


def test_all_solved_summary():
    episodes = np.array([100, 120, 110, 130, 90])
    s = summarize_solving(episodes, np.ones(5, bool))
    assert (s.agents, s.solved, s.fraction) == (5, 5, 1.0)
    assert (s.fraction_low, s.fraction_high) == (1.0, 1.0)
    assert s.median == 110.0 and s.median_low <= 110.0 <= s.median_high
    assert s.median_low >= 90 and s.median_high <= 130
    assert not s.median_censored and s.budget == 130
    assert s.median_text() == f"110 [{s.median_low:.0f}, {s.median_high:.0f}]"


def test_median_is_defined_while_fewer_than_half_are_censored():
    solved_at = np.array([10, 20, 30, 40, 50, 60], float)
    # 10 agents, 4 censored at the budget 1000: the middle two are the 5th and 6th solved.
    episodes = np.concatenate([solved_at, np.full(4, 1000)])
    solved = np.arange(10) < 6
    assert median_episodes(episodes, solved) == 55.0
    s = summarize_solving(episodes, solved)
    assert s.median == 55.0 and s.fraction == 0.6 and s.budget == 1000
    assert math.isinf(s.median_high)  # resamples with ≥ half censored: "> 1000"
    assert s.median_text() == f"55 [{s.median_low:.0f}, > 1000]"
    # 5 of 10 censored: the 6th value is "> budget", so the median is censored — it is not
    # the mean of the censoring points nor of anything else.
    solved5 = np.arange(10) < 5
    s5 = summarize_solving(np.where(solved5, episodes, 1000), solved5)
    assert s5.median_censored and math.isinf(s5.median) and s5.median_text() == "> 1000"
    # Odd count: 2 of 5 censored → the 3rd value is finite; 3 of 5 → censored.
    assert median_episodes([10, 20, 30, 99, 99], [True, True, True, False, False]) == 30.0
    assert math.isinf(median_episodes([10, 20, 30, 99, 99], [True, True, False, False, False]))


def test_none_solved():
    s = summarize_solving(np.full(4, 500), np.zeros(4, bool))
    assert s.solved == 0 and s.fraction == 0.0 and (s.fraction_low, s.fraction_high) == (0.0, 0.0)
    assert s.median_censored and math.isinf(s.median_low) and s.median_text() == "> 500"
    assert s.fraction_text() == "0/4 (0.00 [0.00, 0.00])"


def test_fraction_interval_is_stats_bootstrap_of_the_indicators():
    solved = np.array([True, False, True, True, False, True, True, False])
    episodes = np.where(solved, 50, 200)
    s = summarize_solving(episodes, solved)
    assert (s.fraction_low, s.fraction_high) == bootstrap_ci(solved.astype(float))
    assert s.fraction_low <= s.fraction <= s.fraction_high


def test_median_interval_uses_the_stats_resamples():
    rng = np.random.default_rng(3)
    episodes = rng.integers(100, 1000, size=12)
    s = summarize_solving(episodes, np.ones(12, bool), num_resamples=500, seed=2)
    medians = np.sort(np.median(episodes[bootstrap_indices(12, 500, 2)], axis=1))
    assert s.median_low == medians[int(np.floor(499 * 0.025))]
    assert s.median_high == medians[int(np.ceil(499 * 0.975))]
    assert s.median == np.median(episodes)


def test_budget_is_the_smallest_censoring_point():
    s = summarize_solving([10, 300, 400], [True, False, False])
    assert s.budget == 300 and s.median_text() == "> 300"


@pytest.mark.parametrize("episodes,solved,match", [
    ([], [], "non-empty"),
    ([1, 2], [True], "same length"),
    ([1, 2], [1, 0], "solved has dtype"),
    ([1.0, float("nan")], [True, True], "no NaN"),
])
def test_bad_summary_inputs(episodes, solved, match):
    with pytest.raises(ValueError, match=match):
        summarize_solving(np.asarray(episodes), np.asarray(solved))


def test_solving_rows_of_a_grid():
    returns = np.stack([
        np.stack([step_curve(40, 5), step_curve(40, 8)]),          # both solve
        np.stack([step_curve(40, 5), np.zeros(40, np.float32)]),   # one of two: censored
    ])
    rows = solving_rows(returns, 1.0, 0.0, ["fast", "half"], window=5)
    assert [r["setting"] for r in rows] == ["fast", "half"]
    assert rows[0]["solved"] == 2 and rows[0]["median_episodes"] == 11.5
    assert rows[1]["solved"] == 1 and rows[1]["median_text"] == "> 40"
    with pytest.raises(ValueError, match="must be \\[settings, agents, episodes\\]"):
        solving_rows(returns[0], 1.0, 0.0)
    assert isinstance(summarize_solving([1], [True]), SolveSummary)


# ------------------------------------------------- convergence against the task's optimum
#: A task like the paper's: the random policy's return −1, the best 1 (threshold 0.8).
BEST, RANDOM = 1.0, -1.0


def convergence_grid(curves: dict[str, np.ndarray], agents: int = 6) -> GridResult:
    """One setting per named curve, each of ``agents`` agents with that curve plus noise."""
    rng = np.random.default_rng(0)
    settings = [Setting("qlearning", "egreedy", 0.01 * (c + 1)) for c in range(len(curves))]
    returns = np.stack([curve + rng.normal(0, 0.02, (agents, curve.size))
                        for curve in curves.values()]).astype(np.float32)
    episodes = returns.shape[-1]
    meta = {"mdp": "test", "num_seeds": agents, "num_episodes": episodes, "max_steps": 100,
            "best_return": BEST, "random_return": RANDOM}
    return GridResult(settings, returns, np.full(returns.shape, 10, np.int32),
                      np.zeros(returns.shape[:2], bool), meta)


def test_convergence_is_measured_on_the_normalised_scale():
    assert convergence_threshold(BEST, RANDOM) == pytest.approx(0.8)
    # The same returns on a task whose random policy scores 0.5: threshold 0.95.
    times = episodes_to_converge(np.full((2, 30), 0.9, np.float32), BEST, 0.5, window=5)
    assert not times.solved.any() and times.episodes.tolist() == [30, 30]
    times = episodes_to_converge(np.full((2, 30), 0.9, np.float32), BEST, RANDOM, window=5)
    assert times.solved.all() and times.episodes.tolist() == [5, 5]  # the first full window
    with pytest.raises(ValueError, match="best=1.0 and baseline=2.0 are invalid"):
        episodes_to_converge(np.zeros(30), BEST, 2.0)


def test_a_never_learning_setting_is_censored_and_an_immediate_one_converges_first():
    # The old rule measured each curve against its own final level: a flat curve at the
    # random return "converged" at episode 1 and read as the fastest of all.
    episodes = 200
    t = np.arange(episodes)
    grid = convergence_grid({
        "never": np.full(episodes, RANDOM),                  # flat at the random policy's
        "immediate": np.full(episodes, 0.95),                # at the optimum from the start
        "late": np.where(t < 120, RANDOM, 0.95),             # learns at episode 121
    })
    never, immediate, late = summarize(grid, window=20)
    assert math.isinf(never.convergence_episode) and never.agents_converged == 0
    assert math.isinf(never.convergence_ci_low) and never.convergence_budget == episodes
    assert immediate.convergence_episode == 20 and immediate.agents_converged == 6
    assert (immediate.convergence_ci_low, immediate.convergence_ci_high) == (20, 20)
    # Window 20 at 0.8: (k·0.95 − (20 − k)) / 20 ≥ 0.8 needs k ≥ 18.5 of the new episodes.
    assert late.convergence_episode == 120 + 19 and late.agents_converged == 6
    assert immediate.convergence_episode < late.convergence_episode < never.convergence_episode


def test_a_setting_reads_censored_while_half_of_its_agents_never_converge():
    episodes = 100
    curves = {"half": np.full(episodes, 0.95)}
    grid = convergence_grid(curves, agents=4)
    grid.returns[0, 2:] = RANDOM  # two of four never learn
    (row,) = summarize(grid, window=10)
    assert row.agents_converged == 2 and math.isinf(row.convergence_episode)
    grid.returns[0, 2] = 0.95  # three of four: the median is the middle two's mean
    (row,) = summarize(grid, window=10)
    assert row.agents_converged == 3 and row.convergence_episode == 10
    assert row.convergence_ci_low == 10 and math.isinf(row.convergence_ci_high)
    assert "normalised score of 0.9" in CONVERGENCE_TEXT and "> budget" in CONVERGENCE_TEXT


def test_summarize_needs_the_tasks_references():
    grid = convergence_grid({"x": np.zeros(30)})
    del grid.meta["random_return"]
    with pytest.raises(ValueError, match="no best_return and random_return"):
        summarize(grid)
    assert summarize(grid, best=BEST, baseline=RANDOM)[0].agents_converged == 0


def test_convergence_of_a_wide_run_is_found_block_by_block(monkeypatch):
    from vdbejax.results import analysis

    t = np.arange(60)
    grid = convergence_grid({"a": np.where(t < 30, RANDOM, 0.95), "b": np.full(60, 0.95)},
                            agents=7)
    whole = summarize(grid, window=5)
    monkeypatch.setattr(analysis, "CONVERGENCE_BLOCK", 2 * 60)  # two agents at a time
    assert summarize(grid, window=5) == whole


def test_the_median_interval_of_many_agents_is_computed_in_blocks_with_the_same_bits(
        monkeypatch):
    import math

    from vdbejax.results import bootstrap, solving

    rng = np.random.default_rng(3)
    episodes = rng.integers(1, 500, size=3001)
    solved = rng.random(3001) < 0.7
    values = np.where(solved, episodes, np.inf)
    whole = np.sort(solving._medians(values[bootstrap.bootstrap_indices(values.size, 2000)]))
    monkeypatch.setattr(bootstrap, "BLOCK_BYTES", 8 * 3001 * 7)  # blocks of 7 resamples
    s = summarize_solving(episodes, solved)
    assert s.median_low == whole[math.floor(1999 * 0.025)]
    assert s.median_high == whole[math.ceil(1999 * 0.975)]
