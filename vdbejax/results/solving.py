"""Episodes to solve a task, per agent, and honest summaries of censored samples (numpy only).

Conventions (stated once, used by every report: the summary's convergence episode,
:mod:`vdbejax.studies.bench`, :mod:`vdbejax.studies.depth`, :mod:`vdbejax.studies.scaling`
and notebook 03):

* **Converged**, or **solved** (one rule, :func:`episodes_to_converge`: the convergence
  episode of ``summary.csv``, the sensitivity figure and the claims, and the episodes to
  solve of ``bench``, ``depth`` and ``scale``, whose stop policy
  :class:`~vdbejax.runs.UntilSolved` applies it during training): the first episode ``e``
  (1-based) at which the trailing :func:`~vdbejax.results.curves.moving_average` over
  ``window`` episodes (default :data:`~vdbejax.results.curves.WINDOW` = 20, the paper's
  smoothing) of an agent's *normalised* returns (:mod:`vdbejax.results.regret`: 0 the
  uniformly random policy's expected return, 1 the exact best) reaches ``fraction`` = 0.9,
  i.e. its returns' average reaches ``baseline + 0.9 × (best − baseline)``
  (:func:`convergence_threshold`). An absolute reference: a setting that never learns stays
  censored however flat its curve, and one that learns at once converges at its first full
  window. Only full windows count (``e ≥ window``): the moving average's partial windows at
  the start would let one lucky first episode "solve" the task. Returns are float32, so
  the comparison allows :data:`TOLERANCE`. A setting's convergence episode is the median
  over its agents with censoring and its bootstrap interval (:func:`summarize_solving`).
* **Censored**: an agent that never reaches the threshold within the episodes it ran is
  censored at that count (its budget): all we know is that it needs more.
* **Fraction solved**: the mean of the solved indicators, with the percentile bootstrap
  interval of :func:`vdbejax.results.bootstrap.bootstrap_ci` (agents are the sample).
* **Median episodes to solve**: censored agents count as ``> budget`` (+∞ in the order),
  so the median is defined while fewer than half of the agents are censored; otherwise it
  is reported as censored, ``"> budget"`` — never as a mean or median of censoring points.
  Its interval: the same bootstrap resamples of agents
  (:func:`vdbejax.results.bootstrap.bootstrap_indices`,
  2000 resamples, fixed seed), each resample's median (+∞ when censored), and the order
  statistics just outside the percentile positions (numpy's ``"lower"`` / ``"higher"``
  quantile methods: no interpolation between a finite median and +∞). An upper bound of +∞
  reads "> budget". Ranking censored agents above every solved one is exact when they share
  a budget at least as large as every solve episode, as in a run with one episode budget.

Array layout as in :mod:`vdbejax.results.stats`: episodes on the last axis.
"""
from __future__ import annotations

import dataclasses
import math
from typing import Any, NamedTuple

import numpy as np

from vdbejax.results import bootstrap, curves
from vdbejax.results.curves import WINDOW
from vdbejax.results.regret import Scale, normalised_returns
from vdbejax.validation import check_in_range, check_int

#: Default normalised score that counts as solved (0 = random policy, 1 = the exact best).
FRACTION = 0.9
#: Slack of the threshold comparison: returns are float32 sums of float32 rewards.
TOLERANCE = 1e-6


class SolveTimes(NamedTuple):
    """Per-agent result of :func:`episodes_to_converge`.

    Attributes:
      episodes: int64 ``[...]``: the 1-based solve episode, or the censoring point (the
        episodes the agent ran) where it did not solve.
      solved: bool ``[...]``.
    """

    episodes: np.ndarray
    solved: np.ndarray


def _episodes_run(episodes_run: Any, shape: tuple[int, ...], length: int) -> np.ndarray:
    """``episodes_run`` checked and broadcast to ``shape`` (default: every episode)."""
    if episodes_run is None:
        return np.full(shape, length, np.int64)
    run = np.asarray(episodes_run)
    if run.dtype == np.bool_ or not np.issubdtype(run.dtype, np.integer):
        raise ValueError(f"episodes_run has dtype {run.dtype}: must hold integers")
    if run.size and (run.min() < 0 or run.max() > length):
        raise ValueError(f"episodes_run holds {int(run.min())}..{int(run.max())}: must be in"
                         f" [0, {length}] (the episodes recorded)")
    try:
        return np.broadcast_to(run.astype(np.int64), shape)
    except ValueError:
        raise ValueError(f"episodes_run has shape {run.shape}: must broadcast to the agents'"
                         f" shape {shape}") from None


def _first_window_reaching(values: np.ndarray, threshold: float, window: int,
                           episodes_run: Any) -> SolveTimes:
    """First full window of ``values`` ``[..., episodes]`` whose mean reaches ``threshold``."""
    window = check_int("window", window, 1)
    length = values.shape[-1]
    run = _episodes_run(episodes_run, values.shape[:-1], length)
    if length == 0:
        return SolveTimes(run.copy(), np.zeros(run.shape, bool))
    smoothed = curves.moving_average(values, window)  # a column depends on earlier ones only
    columns = np.arange(length)
    eligible = (columns >= window - 1) & (columns < run[..., None])
    with np.errstate(invalid="ignore"):  # NaN padding past an agent's stop never counts
        reached = eligible & (smoothed >= threshold - TOLERANCE)
    solved = np.any(reached, axis=-1)
    first = np.argmax(reached, axis=-1) + 1
    return SolveTimes(np.where(solved, first, run).astype(np.int64), solved)


def convergence_threshold(best: float, baseline: float, fraction: float = FRACTION) -> float:
    """The return at a normalised score of ``fraction``: ``baseline + fraction × (best −
    baseline)`` (what :func:`episodes_to_converge` asks of the moving average, in returns)."""
    return baseline + fraction * (best - baseline)


def episodes_to_converge(
    returns: Any,
    best: Scale,
    baseline: Scale,
    *,
    fraction: float = FRACTION,
    window: int = WINDOW,
    episodes_run: Any = None,
) -> SolveTimes:
    """First episode at which each agent's moving average of its normalised returns
    (:func:`~vdbejax.results.regret.normalised_returns`) reaches ``fraction``: the
    convergence episode of every report (see the module's conventions).

    Args:
      returns: ``[..., episodes]`` episode returns (one row per agent).
      best: the task's exact best expected return (:func:`vdbejax.envs.solvers.best_return`;
        per agent, ``[..., 1]``, where every agent has its own task instance).
      baseline: the uniformly random policy's expected return
        (:func:`vdbejax.envs.solvers.uniform_random_return`); below ``best``.
      fraction: the normalised score to reach, in (0, 1] (default 0.9).
      window: moving-average window (default 20); only full windows count.
      episodes_run: int ``[...]`` episodes each agent actually ran (the rest of its row is
        ignored: padding of an agent stopped early); default every column.

    Returns:
      :class:`SolveTimes`: the episode (1-based, ``≥ window``) and ``solved``; agents that
      never converge are censored at their ``episodes_run``.

    Raises:
      ValueError: ``best`` not above ``baseline``, or a bad ``fraction``, ``window``,
        ``episodes_run`` or ``returns``.
    """
    fraction = check_in_range("fraction", fraction, 0.0, 1.0, low_open=True)
    values = np.asarray(returns)
    if values.ndim < 1 or not (np.issubdtype(values.dtype, np.floating)
                               or np.issubdtype(values.dtype, np.integer)):
        raise ValueError(f"returns has shape {values.shape} and dtype {values.dtype}: must be"
                         " a numeric [..., episodes] array")
    return _first_window_reaching(normalised_returns(values, best, baseline), fraction, window,
                                  episodes_run)


#: The convergence episode's definition, as documents state it.
CONVERGENCE_TEXT = (
    f"convergence episode = the median over a setting's agents of the first episode at which"
    f" an agent's {WINDOW}-episode moving average (full windows: from episode {WINDOW})"
    f" reaches a normalised score of {FRACTION:g}"
    " (0 = the uniformly random policy's expected return, 1 = the exact best), with a 95%"
    " bootstrap interval over agents; an agent that never does is censored at its budget,"
    " and the setting reads \"> budget\" while half or more of its agents are")


def _check_sample(episodes: Any, solved: Any) -> tuple[np.ndarray, np.ndarray]:
    episodes = np.asarray(episodes)
    solved = np.asarray(solved)
    if episodes.ndim != 1 or episodes.size == 0 or episodes.shape != solved.shape:
        raise ValueError(f"episodes {episodes.shape} and solved {solved.shape} are invalid:"
                         " must be two non-empty 1-D arrays of the same length (one per agent)")
    if solved.dtype != np.bool_:
        raise ValueError(f"solved has dtype {solved.dtype}: must be bool")
    if not np.issubdtype(episodes.dtype, np.number) or np.isnan(episodes.astype(float)).any():
        raise ValueError("episodes is invalid: must hold numbers (no NaN)")
    return episodes.astype(np.float64), solved


def censored_values(episodes: Any, solved: Any) -> np.ndarray:
    """Solve episodes with every censored agent as +∞ (float64): the order the medians use."""
    episodes, solved = _check_sample(episodes, solved)
    return np.where(solved, episodes, np.inf)


def _medians(values: np.ndarray) -> np.ndarray:
    """Median along the last axis of float ``values`` that may hold +∞ (sorted order
    statistics: the middle one, or the mean of the middle two; +∞ once either is)."""
    ordered = np.sort(values, axis=-1)
    n = ordered.shape[-1]
    low, high = ordered[..., (n - 1) // 2], ordered[..., n // 2]
    with np.errstate(invalid="ignore"):
        middle = np.where(np.isinf(high), np.inf, (low + high) / 2.0)
    return middle


def median_episodes(episodes: Any, solved: Any) -> float:
    """Median episodes to solve, +∞ when at least half the agents are censored.

    Args:
      episodes: ``[agents]`` solve episodes (censoring points where not solved).
      solved: bool ``[agents]``.

    Returns:
      the median (a float: the mean of the middle two for an even count), or ``inf``.
    """
    return float(_medians(censored_values(episodes, solved)))


@dataclasses.dataclass(frozen=True)
class SolveSummary:
    """Summary of one setting's agents (see the module's conventions).

    Attributes:
      agents: number of agents.
      solved: agents that solved the task.
      fraction, fraction_low, fraction_high: fraction solved and its bootstrap interval.
      median, median_low, median_high: median episodes to solve and its interval; ``inf``
        = censored ("> budget").
      budget: the censoring point quoted as "> budget": the fewest episodes any censored
        agent ran (the most any agent ran when none is censored).
    """

    agents: int
    solved: int
    fraction: float
    fraction_low: float
    fraction_high: float
    median: float
    median_low: float
    median_high: float
    budget: int

    @property
    def median_censored(self) -> bool:
        """Whether the median is censored (at least half the agents did not solve)."""
        return math.isinf(self.median)

    def median_text(self) -> str:
        """``"1234 [900, 1500]"``, ``"1234 [900, > 5000]"`` or ``"> 5000"``."""
        def one(value: float) -> str:
            return f"> {self.budget}" if math.isinf(value) else f"{value:.0f}"

        if self.median_censored:
            return one(self.median)
        return f"{one(self.median)} [{one(self.median_low)}, {one(self.median_high)}]"

    def fraction_text(self) -> str:
        """``"8/10 (0.80 [0.50, 1.00])"``."""
        return (f"{self.solved}/{self.agents} ({self.fraction:.2f}"
                f" [{self.fraction_low:.2f}, {self.fraction_high:.2f}])")


def summarize_solving(
    episodes: Any,
    solved: Any,
    *,
    level: float = bootstrap.LEVEL,
    num_resamples: int = bootstrap.NUM_RESAMPLES,
    seed: int = 0,
) -> SolveSummary:
    """Fraction solved and median episodes to solve of one setting, with bootstrap intervals.

    Args:
      episodes: ``[agents]`` solve episodes, censoring points where not solved
        (:attr:`SolveTimes.episodes`).
      solved: bool ``[agents]``.
      level, num_resamples, seed: bootstrap settings (:mod:`vdbejax.results.bootstrap`).

    Returns:
      the :class:`SolveSummary`.

    Raises:
      ValueError: mismatched, empty or non-numeric inputs, or bad bootstrap settings.
    """
    level = check_in_range("level", level, 0.0, 1.0, low_open=True, high_open=True)
    num_resamples = check_int("num_resamples", num_resamples, 1)
    seed = check_int("seed", seed, 0)
    counts, solved = _check_sample(episodes, solved)
    values = np.where(solved, counts, np.inf)
    # Resample block by resample block (the same indices as bootstrap_indices): 2000
    # resamples of 10⁵ agents at once were 3 GiB (the indices and their values).
    medians = np.sort(np.concatenate([_medians(values[block]) for block in
                                      bootstrap.resample_blocks(values.size, num_resamples,
                                                                seed)]))
    alpha = (1.0 - level) / 2.0
    low = medians[math.floor((num_resamples - 1) * alpha)]
    high = medians[math.ceil((num_resamples - 1) * (1.0 - alpha))]
    fraction_low, fraction_high = bootstrap.bootstrap_ci(solved.astype(np.float64), level,
                                                     num_resamples, seed)
    censored = counts[~solved]
    budget = int(censored.min()) if censored.size else int(counts.max())
    return SolveSummary(
        agents=int(values.size), solved=int(solved.sum()), fraction=float(solved.mean()),
        fraction_low=fraction_low, fraction_high=fraction_high,
        median=float(_medians(values)), median_low=float(low), median_high=float(high),
        budget=budget,
    )


def solving_rows(
    returns: Any,
    best: float,
    baseline: float,
    labels: list[str] | None = None,
    *,
    fraction: float = FRACTION,
    window: int = WINDOW,
    episodes_run: Any = None,
) -> list[dict[str, Any]]:
    """One summary row per setting of ``[settings, agents, episodes]`` returns.

    Args:
      returns: ``[C, agents, episodes]``
        (e.g. :attr:`vdbejax.results.grid_result.GridResult.returns`).
      best, baseline: the task's exact best and uniformly random returns.
      labels: one name per setting (default ``"0"``, ``"1"``, …).
      fraction, window: the solve criterion (:func:`episodes_to_converge`).
      episodes_run: int ``[C, agents]`` episodes each agent ran (default: all).

    Returns:
      rows with ``setting, agents, solved, fraction_solved, fraction_low, fraction_high,
      median_episodes, median_low, median_high, budget, median_text`` (``inf`` = censored).
    """
    values = np.asarray(returns)
    if values.ndim != 3:
        raise ValueError(f"returns has shape {values.shape}: must be [settings, agents, episodes]")
    labels = [str(c) for c in range(values.shape[0])] if labels is None else list(labels)
    if len(labels) != values.shape[0]:
        raise ValueError(f"labels has {len(labels)} names for {values.shape[0]} settings")
    times = episodes_to_converge(values, best, baseline, fraction=fraction, window=window,
                                 episodes_run=episodes_run)
    rows = []
    for c, label in enumerate(labels):
        s = summarize_solving(times.episodes[c], times.solved[c])
        rows.append({"setting": label, "agents": s.agents, "solved": s.solved,
                     "fraction_solved": s.fraction, "fraction_low": s.fraction_low,
                     "fraction_high": s.fraction_high, "median_episodes": s.median,
                     "median_low": s.median_low, "median_high": s.median_high,
                     "budget": s.budget, "median_text": s.median_text()})
    return rows


__all__ = [
    "CONVERGENCE_TEXT",
    "FRACTION",
    "TOLERANCE",
    "SolveSummary",
    "SolveTimes",
    "censored_values",
    "convergence_threshold",
    "episodes_to_converge",
    "median_episodes",
    "solving_rows",
    "summarize_solving",
]
