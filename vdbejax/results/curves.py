"""Statistics of one learning curve (numpy only): smoothing and final return, with the
conventions of :mod:`vdbejax.results.stats` (episodes on the last axis). The convergence
episode is measured against the task's optimum, per agent: :mod:`vdbejax.results.solving`.
"""
from __future__ import annotations

import numpy as np

WINDOW = 20
LAST = 100


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
