"""Regret against the exact optimum, normalised scores and aggregates across tasks (numpy).

A task's optimum is the best expected episode return ``best``
(:func:`vdbejax.envs.solvers.best_return`); its zero is the uniformly random policy's
expected return ``baseline`` (:func:`vdbejax.envs.solvers.uniform_random_return`).

* **Regret** of an episode: ``best − return`` (an estimate of the expected regret: one
  episode's return is a sample, so one episode's regret may be negative); **cumulative
  regret**: its sum over the episodes so far.
* **Normalised score** of a run: its mean episode return, mapped so that ``baseline`` is 0
  and ``best`` is 1 — one minus its mean regret in units of ``best − baseline``; the area
  under the normalised learning curve, so it rewards learning fast as well as well.
* **Across tasks**, as rliable (Agarwal et al. 2021) does: the interquartile mean of all
  (task, run) scores, performance profiles (the fraction of runs above each score) and the
  probability of improvement averaged over tasks, each with a *stratified* bootstrap
  interval (every task's runs resampled on their own). These few functions replace a
  dependency on rliable, whose stack (arch, scipy, seaborn) exceeds this package's.

Episodes past an agent's stop (NaN returns under a stop policy) count as solved: their
regret is 0 in cumulative sums and they are left out of means (``nanmean``).
"""
from __future__ import annotations

from collections.abc import Sequence
from typing import NamedTuple

import numpy as np

from vdbejax.results.bootstrap import (
    LEVEL,
    NUM_RESAMPLES,
    bootstrap_indices,
    interquartile_mean,
    percentile_interval,
    probability_of_improvement,
)

#: A task's best or baseline return: one number, or one per run (an instance per agent:
#: an array that broadcasts against the runs' ``returns[..., :1]``).
Scale = float | np.ndarray


def _check_scale(best: Scale, baseline: Scale) -> Scale:
    if np.ndim(best) == 0 and np.ndim(baseline) == 0:
        span = float(best) - float(baseline)
        if not np.isfinite(span) or span <= 0.0:
            raise ValueError(f"best={best!r} and baseline={baseline!r} are invalid: the best"
                             " return must exceed the baseline's for a normalised score")
        return span
    spans = np.asarray(best, np.float64) - np.asarray(baseline, np.float64)
    bad = ~np.isfinite(spans) | (spans <= 0.0)
    if spans.size == 0 or bad.any():
        where = [int(i) for i in np.unravel_index(np.argmax(bad), bad.shape)] if spans.size else []
        raise ValueError(f"best and baseline at {where} are invalid: each run's best return"
                         " must exceed its baseline's for a normalised score")
    return spans


def as_scale(value: Scale) -> Scale:
    """A :data:`Scale` as a float, or as a float64 array (one per run)."""
    return float(value) if np.ndim(value) == 0 else np.asarray(value, np.float64)


def episode_regret(returns: np.ndarray, best: Scale) -> np.ndarray:
    """``best − returns`` per episode (NaN where the episode was not run).

    Args:
      returns: ``[..., episodes]`` episode returns.
      best: the task's best expected episode return (:data:`Scale`: per run where every
        agent has its own task instance).

    Returns:
      float64 regrets of the same shape.
    """
    return as_scale(best) - np.asarray(returns, np.float64)


def cumulative_regret(returns: np.ndarray, best: Scale) -> np.ndarray:
    """Cumulative regret over the episode axis (episodes not run add 0).

    Args:
      returns: ``[..., episodes]`` episode returns.
      best: the task's best expected episode return.

    Returns:
      float64 ``[..., episodes]`` cumulative sums.
    """
    return np.cumsum(np.nan_to_num(episode_regret(returns, best), nan=0.0), axis=-1)


def normalised_returns(returns: np.ndarray, best: Scale, baseline: Scale) -> np.ndarray:
    """Episode returns with ``baseline`` mapped to 0 and ``best`` to 1.

    Args:
      returns: ``[..., episodes]`` episode returns.
      best: the task's best expected episode return (:data:`Scale`: per run where every
        agent has its own task instance).
      baseline: the uniformly random policy's expected episode return (likewise).

    Returns:
      float64 normalised returns of the same shape.

    Raises:
      ValueError: ``best`` not above ``baseline``.
    """
    span = _check_scale(best, baseline)
    return (np.asarray(returns, np.float64) - as_scale(baseline)) / span


def run_scores(returns: np.ndarray, best: Scale, baseline: Scale) -> np.ndarray:
    """Each run's normalised score: its mean normalised return over the episodes it ran
    (an agent stopped once solved scores 1 on the episodes it did not run).

    Args:
      returns: ``[..., episodes]`` episode returns (NaN past a stop).
      best, baseline: as :func:`normalised_returns`.

    Returns:
      float64 ``[...]`` scores (1 = the optimum from the first episode on).
    """
    normalised = normalised_returns(returns, best, baseline)
    return np.where(np.isnan(normalised), 1.0, normalised).mean(axis=-1)


class Interval(NamedTuple):
    """A point estimate with its bootstrap interval."""

    value: float
    low: float
    high: float


def _stratified(scores: Sequence[np.ndarray], num_resamples: int, seed: int) -> list[np.ndarray]:
    """Per task, ``[num_resamples, runs]`` resampled runs (each task its own stream)."""
    return [np.asarray(s, np.float64)[bootstrap_indices(len(s), num_resamples, seed + t)]
            for t, s in enumerate(scores)]


def _check_tasks(scores: Sequence[np.ndarray], name: str) -> list[np.ndarray]:
    rows = [np.asarray(s, np.float64).ravel() for s in scores]
    if not rows or any(r.size == 0 for r in rows):
        raise ValueError(f"{name} is invalid: must hold at least one run for each of at least"
                         " one task")
    return rows


def aggregate_iqm(scores: Sequence[np.ndarray], level: float = LEVEL,
                  num_resamples: int = NUM_RESAMPLES, seed: int = 0) -> Interval:
    """Interquartile mean of every (task, run) score, with a stratified bootstrap interval.

    Args:
      scores: per task, ``[runs]`` normalised scores of one method.
      level, num_resamples, seed: bootstrap settings.

    Returns:
      the :class:`Interval`.
    """
    rows = _check_tasks(scores, "scores")
    resampled = np.concatenate(_stratified(rows, num_resamples, seed), axis=1)
    low, high = percentile_interval(interquartile_mean(resampled), level)
    return Interval(float(interquartile_mean(np.concatenate(rows))), float(low), float(high))


def performance_profile(scores: Sequence[np.ndarray], thresholds: np.ndarray,
                        level: float = LEVEL, num_resamples: int = NUM_RESAMPLES,
                        seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The fraction of (task, run) scores above each threshold, with stratified bootstrap
    bands (rliable's run-score distribution; every task weighs by its number of runs).

    Args:
      scores: per task, ``[runs]`` normalised scores of one method.
      thresholds: ``[T]`` score thresholds.
      level, num_resamples, seed: bootstrap settings.

    Returns:
      ``(fraction, low, high)``, each float64 ``[T]``.
    """
    rows = _check_tasks(scores, "scores")
    thresholds = np.asarray(thresholds, np.float64)
    pooled = np.concatenate(rows)
    fraction = (pooled[:, None] > thresholds).mean(0)
    resampled = np.concatenate(_stratified(rows, num_resamples, seed), axis=1)
    low, high = percentile_interval((resampled[..., None] > thresholds).mean(1), level)
    return fraction, low, high


def task_probability_of_improvement(x: Sequence[np.ndarray], y: Sequence[np.ndarray],
                                    level: float = LEVEL, num_resamples: int = NUM_RESAMPLES,
                                    seed: int = 0) -> Interval:
    """``P(X > Y)`` averaged over tasks (rliable), with a stratified bootstrap interval.

    Args:
      x: per task, ``[runs]`` scores of method X.
      y: per task (the same tasks), ``[runs]`` scores of method Y.
      level, num_resamples, seed: bootstrap settings (Y resampled with other seeds).

    Returns:
      the :class:`Interval` of the average probability.

    Raises:
      ValueError: different numbers of tasks.
    """
    xs, ys = _check_tasks(x, "x"), _check_tasks(y, "y")
    if len(xs) != len(ys):
        raise ValueError(f"x has {len(xs)} tasks and y {len(ys)}: must be the same tasks")
    value = np.mean([probability_of_improvement(a, b) for a, b in zip(xs, ys, strict=True)])
    rx = _stratified(xs, num_resamples, seed)
    ry = _stratified(ys, num_resamples, seed + len(xs))
    resampled = np.mean([probability_of_improvement(a, b) for a, b in zip(rx, ry, strict=True)],
                        axis=0)
    low, high = percentile_interval(resampled, level)
    return Interval(float(value), float(low), float(high))


__all__ = [
    "Interval",
    "aggregate_iqm",
    "cumulative_regret",
    "episode_regret",
    "normalised_returns",
    "performance_profile",
    "run_scores",
    "task_probability_of_improvement",
]
