"""Statistics over learning curves (numpy only): smoothing, final return,
bootstrap intervals over seeds, interquartile mean and probability of improvement.

Conventions (used everywhere, stated once):

* **Smoothing**: trailing moving average over ``window`` episodes (the paper uses 20);
  the first ``window − 1`` points average the episodes available so far.
* **Final return**: mean return over the last ``last`` episodes (default 100).
* **Convergence episode**: per agent, against the task's optimum, and its median over a
  setting's agents with censoring: :mod:`vdbejax.results.solving`.
* **Bootstrap intervals** resample seeds with replacement (percentile method, ``level``
  0.95, 2000 resamples, fixed seed so that every figure and table is deterministic).
* **Interquartile mean** (IQM, Agarwal et al. 2021, "rliable"): the mean of the middle
  half of the values — ``⌊n/4⌋`` are trimmed from each end, as ``scipy.stats.trim_mean(x,
  0.25)`` does.
* **Probability of improvement** ``P(X > Y)``: over all pairs of one seed of X and one of
  Y, the fraction where X's value is larger, ties counting one half (rliable).

Array layout: seeds on the first axis, episodes on the last (``[seeds, episodes]``).

The pieces live in one module each: the statistics of one curve (smoothing, final return)
in :mod:`vdbejax.results.curves`; those of one value per seed (bootstrap resamples and
intervals, IQM, probability of improvement) in :mod:`vdbejax.results.bootstrap`. This module
holds the intervals of curves, the per-setting statistics of a grid (:func:`curve_statistics`)
and the Wilson interval of a rate.
"""
from __future__ import annotations

import dataclasses
import os
from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor

import numpy as np

from vdbejax.results.bootstrap import (
    LEVEL,
    NUM_RESAMPLES,
    bootstrap_ci,
    interquartile_mean,
    percentile_interval,
    rows_per_block,
    weight_blocks,
)
from vdbejax.results.curves import LAST, WINDOW, final_return, moving_average


def mean_curve_ci(
    returns: np.ndarray,
    window: int = WINDOW,
    level: float = LEVEL,
    num_resamples: int = NUM_RESAMPLES,
    seed: int = 0,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Smoothed seed-mean learning curve with a pointwise bootstrap band.

    Args:
      returns: ``[seeds, episodes]`` episode returns.
      window: moving-average window applied to each resampled mean curve.
      level: confidence level.
      num_resamples: bootstrap resamples.
      seed: resampling seed.

    Returns:
      ``(mean, low, high)``, each ``[episodes]``: the smoothed mean curve and the band's
      lower and upper edges.
    """
    returns = np.asarray(returns, np.float64)
    mean = moving_average(returns.mean(0), window)
    # Smoothing is linear, so smoothing each seed once and then resampling equals
    # resampling then smoothing every resample, at a fraction of the cost.
    smoothed = moving_average(returns, window)
    # Episode block by episode block, and resample block by resample block for many seeds
    # (one block each unless the run is long or wide: memory bounded).
    columns = rows_per_block(num_resamples)
    edges = [percentile_interval(np.concatenate([
        weights @ smoothed[:, i:i + columns]
        for weights in _distinct_weights(len(returns), num_resamples, seed)]), level)
        for i in range(0, smoothed.shape[-1], columns)]
    return (mean, np.concatenate([lo for lo, _ in edges]),
            np.concatenate([hi for _, hi in edges]))


def final_return_ci(
    returns: np.ndarray, last: int = LAST, level: float = LEVEL,
    num_resamples: int = NUM_RESAMPLES, seed: int = 0,
) -> tuple[float, float, float]:
    """Final return (mean over seeds of each seed's last-``last``-episode mean) and its CI.

    Args:
      returns: ``[seeds, episodes]`` episode returns.
      last: episodes averaged at the end.
      level, num_resamples, seed: bootstrap settings.

    Returns:
      ``(mean, low, high)``.
    """
    per_seed = final_return(returns, last)
    low, high = bootstrap_ci(per_seed, level, num_resamples, seed)
    return float(per_seed.mean()), low, high


def _distinct_weights(num_seeds: int, num_resamples: int, seed: int) -> Iterator[np.ndarray]:
    """:func:`weight_blocks`, except that one seed gives one row of weight 1: all its
    resamples are that seed (the same numbers; a percentile interval over two equal rows
    is the one over all of them, and 2,000 curves of 10⁷ episodes took minutes)."""
    if num_seeds == 1:
        yield np.ones((min(num_resamples, 2), 1))
        return
    yield from weight_blocks(num_seeds, num_resamples, seed)


@dataclasses.dataclass(frozen=True)
class CurveStatistics:
    """Per-setting statistics of a grid's returns, computed once for the summary table,
    Figure 3 and the claims (arrays over settings; see the module's conventions).

    Attributes:
      window, last: the smoothing window and the final-return episodes used.
      final, final_low, final_high: final return and its 95% bootstrap interval, ``[C]``.
      final_iqm: interquartile mean of the seeds' final returns, ``[C]``.
      curves: smoothed seed-mean learning curves, ``[C, episodes]``.
      band_low, band_high: pointwise bootstrap band of ``curves`` (``None`` unless asked).
    """

    window: int
    last: int
    final: np.ndarray
    final_low: np.ndarray
    final_high: np.ndarray
    final_iqm: np.ndarray
    curves: np.ndarray
    band_low: np.ndarray | None = None
    band_high: np.ndarray | None = None


def curve_statistics(
    returns: np.ndarray, window: int = WINDOW, last: int = LAST, bands: bool = False,
    workers: int | None = None,
) -> CurveStatistics:
    """:class:`CurveStatistics` of ``[settings, seeds, episodes]`` returns.

    Every setting uses the same bootstrap resamples
    (:func:`~vdbejax.results.bootstrap.bootstrap_weights`) and the same functions as one
    setting alone (:func:`final_return_ci`, :func:`mean_curve_ci`),
    so the numbers are those, bit for bit; the per-setting curves and bands run on
    ``workers`` threads (default: the CPU count), which numpy's array operations let run
    in parallel.

    Args:
      returns: ``[C, seeds, episodes]`` episode returns.
      window: smoothing window.
      last: episodes defining the final return (at most the episode count).
      bands: also the pointwise bootstrap band of every curve (Figure 3's shading).
      workers: threads (1: sequential; default: the CPU count with ``bands``, else 1, as
        the rest is too fine-grained to gain from threads).

    Returns:
      the statistics.
    """
    returns = np.asarray(returns)
    last = min(last, returns.shape[-1])

    def one(c: int) -> tuple:
        setting = returns[c]
        final = final_return_ci(setting, last)
        iqm = float(interquartile_mean(final_return(setting, last)))
        if bands:
            curve, low, high = mean_curve_ci(setting, window)
        else:
            curve = moving_average(np.asarray(setting, np.float64).mean(0), window)
            low, high = None, None
        return final, iqm, curve, low, high

    if workers is None:
        workers = (os.cpu_count() or 1) if bands else 1
    workers = max(1, min(workers, len(returns)))
    if workers == 1:
        rows = [one(c) for c in range(len(returns))]
    else:
        with ThreadPoolExecutor(workers) as pool:
            rows = list(pool.map(one, range(len(returns))))
    final_cis, iqms, curves, lows, highs = zip(*rows, strict=True) if rows else ([],) * 5
    finals = np.array(final_cis).reshape(-1, 3)
    episodes = returns.shape[-1]
    return CurveStatistics(
        window=window, last=last,
        final=finals[:, 0], final_low=finals[:, 1], final_high=finals[:, 2],
        final_iqm=np.array(iqms, np.float64),
        curves=np.array(curves, np.float64).reshape(-1, episodes),
        band_low=np.array(lows).reshape(-1, episodes) if bands else None,
        band_high=np.array(highs).reshape(-1, episodes) if bands else None,
    )


def wilson_interval(successes: int, trials: int, z: float = 1.96) -> tuple[float, float]:
    """The Wilson score interval of a rate ``successes / trials`` (95 % for ``z = 1.96``):
    unlike the normal approximation it stays inside [0, 1] and is not empty at 0 or n.

    Raises:
      ValueError: ``trials`` < 1 or ``successes`` outside 0 … ``trials``.
    """
    if trials < 1 or not 0 <= successes <= trials:
        raise ValueError(f"successes={successes}, trials={trials}: need 0 ≤ successes ≤ trials"
                         " and trials ≥ 1")
    rate = successes / trials
    centre = (rate + z * z / (2 * trials)) / (1 + z * z / trials)
    half = (z / (1 + z * z / trials)) * np.sqrt(rate * (1 - rate) / trials
                                                + z * z / (4 * trials * trials))
    return max(0.0, float(centre - half)), min(1.0, float(centre + half))
