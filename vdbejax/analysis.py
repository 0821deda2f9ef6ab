"""Statistics over learning curves: smoothing, final return, convergence, bootstrap CIs.

Conventions (used everywhere, stated once):

* **Smoothing**: trailing moving average over ``window`` episodes (the paper uses 20);
  the first ``window − 1`` points average the episodes available so far.
* **Final return**: mean return over the last ``last`` episodes (default 100).
* **Convergence episode**: the first episode (1-based) at which the moving average of the
  seed-mean curve reaches ``L − (1 − fraction)·|L|``, with ``L`` the final return and
  ``fraction = 0.95`` ("95% of its final level", also meaningful when ``L < 0``).
* **Bootstrap intervals** resample seeds with replacement (percentile method).
"""
from __future__ import annotations

import numpy as np

from vdbejax.experiment import GridResult

WINDOW = 20
LAST = 100
FRACTION = 0.95
LEVEL = 0.95
NUM_RESAMPLES = 2000


def moving_average(x: np.ndarray, window: int = WINDOW, axis: int = -1) -> np.ndarray:
    """Trailing moving average along ``axis`` (partial windows at the start)."""
    x = np.moveaxis(np.asarray(x, np.float64), axis, -1)
    csum = np.cumsum(x, axis=-1)
    out = csum.copy()
    out[..., window:] = csum[..., window:] - csum[..., :-window]
    counts = np.minimum(np.arange(1, x.shape[-1] + 1), window)
    return np.moveaxis(out / counts, -1, axis)


def final_return(returns: np.ndarray, last: int = LAST) -> np.ndarray:
    """Mean over the last ``last`` episodes (the episode axis is the last one)."""
    return np.asarray(returns, np.float64)[..., -last:].mean(-1)


def convergence_episode(
    curve: np.ndarray, window: int = WINDOW, last: int = LAST, fraction: float = FRACTION
) -> int:
    """First episode (1-based) at which the smoothed ``curve`` gets within
    ``(1 − fraction)·|L|`` of its final level ``L``."""
    curve = np.asarray(curve, np.float64)
    level = curve[-last:].mean()
    threshold = level - (1.0 - fraction) * abs(level)
    reached = np.flatnonzero(moving_average(curve, window) >= threshold - 1e-12)
    return int(reached[0]) + 1 if reached.size else len(curve)


def bootstrap_indices(num_seeds: int, num_resamples: int = NUM_RESAMPLES, seed: int = 0) -> np.ndarray:
    """``[num_resamples, num_seeds]`` seed indices drawn with replacement."""
    rng = np.random.default_rng(seed)
    return rng.integers(0, num_seeds, size=(num_resamples, num_seeds))


def bootstrap_ci(
    samples: np.ndarray, level: float = LEVEL, num_resamples: int = NUM_RESAMPLES, seed: int = 0
) -> tuple[float, float]:
    """Percentile bootstrap interval of the mean of ``samples`` (one value per seed)."""
    samples = np.asarray(samples, np.float64)
    means = samples[bootstrap_indices(len(samples), num_resamples, seed)].mean(-1)
    alpha = (1.0 - level) / 2.0
    low, high = np.quantile(means, [alpha, 1.0 - alpha])
    return float(low), float(high)


def summarize(result: GridResult, last: int = LAST, window: int = WINDOW) -> list[dict]:
    """One row per config: final return with its 95% bootstrap CI and the convergence episode.

    Columns: ``config, learner, explorer, param, final_return, final_ci_low,
    final_ci_high, convergence_episode, mean_length, nonfinite_agents``.
    """
    rows = []
    last = min(last, result.num_episodes)
    for c, setting in enumerate(result.settings):
        per_seed = final_return(result.returns[c], last)
        low, high = bootstrap_ci(per_seed)
        rows.append(
            {
                "config": c,
                "learner": setting.learner,
                "explorer": setting.explorer,
                "param": setting.param,
                "final_return": float(per_seed.mean()),
                "final_ci_low": low,
                "final_ci_high": high,
                "convergence_episode": convergence_episode(
                    result.returns[c].mean(0), window, last
                ),
                "mean_length": float(result.lengths[c].mean()),
                "nonfinite_agents": int(result.nonfinite[c].sum()),
            }
        )
    return rows


SUMMARY_COLUMNS = [
    "config",
    "learner",
    "explorer",
    "param",
    "final_return",
    "final_ci_low",
    "final_ci_high",
    "convergence_episode",
    "mean_length",
    "nonfinite_agents",
]
