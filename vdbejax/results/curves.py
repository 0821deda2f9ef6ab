"""Statistics of one learning curve (numpy only): smoothing, final return and the
convergence episode, with the conventions of :mod:`vdbejax.results.stats` (episodes on the last
axis).
"""
from __future__ import annotations

import numpy as np

WINDOW = 20
LAST = 100
FRACTION = 0.95
#: Episodes scanned at a time when finding convergence episodes (the results do not
#: depend on it): most curves converge within the first blocks.
_EPISODE_BLOCK = 128
#: The convergence episode's definition, as documents state it.
CONVERGENCE_TEXT = (
    f"convergence episode = first episode at which the {WINDOW}-episode moving average of the"
    f" agents' mean return reaches {FRACTION:.0%} of its final level; \"never\" (censored) when"
    f" the mean of its first {WINDOW} episodes already does: the curve shows no learning to"
    " time")


def moving_average(x: np.ndarray, window: int = WINDOW, axis: int = -1) -> np.ndarray:
    """Trailing moving average along ``axis`` (partial windows at the start).

    Args:
      x: values.
      window: number of episodes averaged.
      axis: the episode axis.

    Returns:
      float64 array of ``x``'s shape.
    """
    x = np.moveaxis(np.asarray(x, np.float64), axis, -1)
    return np.moveaxis(_trailing_mean(x, window), -1, axis)


def _trailing_mean(x: np.ndarray, window: int) -> np.ndarray:
    """:func:`moving_average` along the last axis of float64 ``x``: differences of one
    cumulative sum (computed in place: numpy reads overlapping inputs as if copied first),
    divided by the number of episodes in each window."""
    out = np.cumsum(x, axis=-1)
    np.subtract(out[..., window:], out[..., :-window], out=out[..., window:])
    counts = np.minimum(np.arange(1, x.shape[-1] + 1), window)
    return np.divide(out, counts, out=out)


def convolve_full(curve: np.ndarray, window: int = WINDOW) -> np.ndarray:
    """The authors' smoothing: ``np.convolve(curve, ones(window) / window)`` ("full"
    mode), ``len(curve) + window − 1`` points. Index ``k ≥ window − 1`` up to the curve's
    end equals :func:`moving_average`'s; the first ``window − 1`` points count missing
    episodes as 0 (the authors plot from episode ``window``), and the last ``window − 1``
    fall off towards 0 as the window runs past the last episode.
    """
    return np.convolve(np.asarray(curve, np.float64), np.ones(window) / window)


def final_return(returns: np.ndarray, last: int = LAST) -> np.ndarray:
    """Mean over the last ``last`` episodes (the episode axis is the last one).

    Args:
      returns: ``[..., episodes]`` episode returns.
      last: number of final episodes averaged.

    Returns:
      float64 ``[...]`` final returns.
    """
    return np.asarray(returns, np.float64)[..., -last:].mean(-1)


def convergence_episodes(
    curves: np.ndarray, window: int = WINDOW, last: int = LAST, fraction: float = FRACTION
) -> np.ndarray:
    """Convergence episode of every curve in a batch (episode axis last).

    A curve converges at the first episode at which its smoothed values reach
    ``L − (1 − fraction)·|L|``, ``L`` its final level. It is **censored** (+∞: no
    convergence episode) when the mean of its first ``window`` episodes already reaches
    that band: the curve shows no learning to time (a setting that never learns is flat
    at its level from the start; "episode 1" would read as the fastest), or when it never
    reaches the band.

    Args:
      curves: ``[..., episodes]`` raw (unsmoothed) mean-return curves.
      window: smoothing window.
      last: episodes defining the final level ``L``.
      fraction: the smoothed curve must reach ``L − (1 − fraction)·|L|``.

    Returns:
      float64 ``[...]`` 1-based episodes, +∞ where censored.
    """
    curves = np.asarray(curves, np.float64)
    level = curves[..., -last:].mean(-1, keepdims=True)
    threshold = level - (1.0 - fraction) * np.abs(level) - 1e-12
    rows = curves.reshape(-1, curves.shape[-1])
    first = _first_reaching(rows, threshold.reshape(-1), window).astype(np.float64)
    flat = rows[:, :window].mean(-1) >= threshold.reshape(-1)
    first[flat | (first > rows.shape[-1])] = np.inf
    return first.reshape(curves.shape[:-1])


def _first_reaching(rows: np.ndarray, thresholds: np.ndarray, window: int) -> np.ndarray:
    """1-based first episode at which each row's :func:`moving_average` reaches its
    threshold (the row length + 1 if never), computed episode block by episode block and only
    for the rows still below: the same sums in the same order as :func:`moving_average`
    (a block's cumulative sum starts from the previous block's last one), so the same
    comparisons, at a fraction of the cost when curves converge early."""
    num_rows, length = rows.shape
    first = np.full(num_rows, length + 1, np.int64)
    active = np.arange(num_rows)
    history = np.zeros((num_rows, 0))  # cumulative sums of the last ≤ window episodes
    start = 0
    while start < length and active.size:
        stop = min(start + _EPISODE_BLOCK, length)
        carry = history[:, -1:] if history.shape[1] else np.zeros((active.size, 1))
        sums = np.cumsum(np.concatenate([carry, rows[active, start:stop]], axis=1), axis=1)[:, 1:]
        sums = np.concatenate([history, sums], axis=1)
        offset = history.shape[1]  # columns before episode `start`: min(window, start)
        episodes = np.arange(start, stop)
        totals = sums[:, offset:].copy()
        lagged = episodes >= window
        totals[:, lagged] -= sums[:, offset + episodes[lagged] - start - window]
        smoothed = totals / np.minimum(episodes + 1, window)
        reached = smoothed >= thresholds[active, None]
        hit = reached.any(1)
        first[active[hit]] = start + np.argmax(reached[hit], axis=1) + 1
        active, history = active[~hit], sums[~hit][:, -window:]
        start = stop
    return first


def convergence_episode(
    curve: np.ndarray, window: int = WINDOW, last: int = LAST, fraction: float = FRACTION
) -> float:
    """First episode (1-based) at which the smoothed ``curve`` gets within
    ``(1 − fraction)·|L|`` of its final level ``L``, +∞ when censored
    (:func:`convergence_episodes`).

    Args:
      curve: ``[episodes]`` raw (unsmoothed) mean-return curve.
      window, last, fraction: see :func:`convergence_episodes`.

    Returns:
      the episode (a whole number), or +∞.
    """
    return float(convergence_episodes(curve, window, last, fraction))
