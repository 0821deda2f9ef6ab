"""Stop policies: when an agent of a run stops training.

* :class:`FixedBudget` — every agent runs the run's ``num_episodes`` (the paper's grid).
* :class:`UntilSolved` — after every chunk, an agent whose moving average has reached a
  normalised score of ``fraction`` (:mod:`vdbejax.results.solving`: 0 the uniformly random
  policy's expected return, 1 the exact best) stops: it leaves its batch and costs no more
  compute; the others continue from their state. An optional wall-clock budget stops every
  remaining agent at the end of the first chunk past it.

Every agent draws from its own random stream, so an agent's returns do not depend on when
the others stop: up to its stop they equal, bit for bit, those of a fixed budget.
"""
from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from vdbejax.results.curves import WINDOW
from vdbejax.results.regret import normalised_returns
from vdbejax.results.solving import FRACTION, TOLERANCE, episodes_to_converge
from vdbejax.validation import check_in_range, check_int, check_positive


@dataclasses.dataclass(frozen=True)
class FixedBudget:
    """Every agent trains for the run's ``num_episodes``."""

    #: Whether the driver checks the policy after every chunk (else it never stops early).
    checks_chunks = False

    def resolve(self, mdp: Any) -> FixedBudget:
        """The policy with its task-dependent defaults filled in (none here)."""
        return self

    def describe(self) -> dict[str, Any]:
        """What the policy is, for ``meta.json`` and the run's fingerprint."""
        return {"policy": "fixed_budget"}

    def newly_stopped(self, returns: np.ndarray, rows: np.ndarray, start: int,
                      end: int) -> np.ndarray:
        """None of ``rows`` stops before the budget."""
        return np.zeros(rows.size, bool)

    def out_of_time(self, elapsed: float) -> bool:
        return False

    def fewest_episodes(self, num_episodes: int) -> int:
        """The fewest episodes an agent of a ``num_episodes`` run trains (estimates)."""
        return num_episodes


@dataclasses.dataclass(frozen=True)
class UntilSolved:
    """Train each agent until it has solved the task, within the run's episode budget.

    Solved is the one rule of every report (:func:`vdbejax.results.solving.episodes_to_converge`):
    the ``window``-episode moving average of the agent's normalised returns reaches
    ``fraction``.

    Attributes:
      best: the task's exact best return (default :func:`vdbejax.envs.solvers.best_return` of
        the run's task, filled in by :meth:`resolve`).
      baseline: the uniformly random policy's expected return, the normalised score's 0
        (default :func:`vdbejax.envs.solvers.uniform_random_return`); given with ``best``.
      fraction, window: the solve criterion.
      max_seconds: wall-clock budget of the whole run (None: none); which episode the
        remaining agents are stopped at then depends on the machine's speed, so the
        episode budget is the reproducible one.
    """

    best: float | None = None
    baseline: float | None = None
    fraction: float = FRACTION
    window: int = WINDOW
    max_seconds: float | None = None

    checks_chunks = True

    def __post_init__(self) -> None:
        check_in_range("fraction", self.fraction, 0.0, 1.0, low_open=True)
        object.__setattr__(self, "window", check_int("window", self.window, 1))
        if self.max_seconds is not None:
            object.__setattr__(self, "max_seconds", check_positive("max_seconds",
                                                                   self.max_seconds))
        if (self.best is None) != (self.baseline is None):
            raise ValueError(f"best={self.best!r} and baseline={self.baseline!r} are invalid:"
                             " give both (the task's best and random returns) or neither")
        if self.best is not None and self.baseline is not None:
            normalised_returns(np.zeros(0), self.best, self.baseline)  # best > baseline
            object.__setattr__(self, "best", float(self.best))
            object.__setattr__(self, "baseline", float(self.baseline))

    def resolve(self, mdp: Any) -> UntilSolved:
        """The policy with ``best`` and ``baseline`` computed for ``mdp`` when not given."""
        if self.best is not None:
            return self
        from vdbejax.envs.solvers import best_return, uniform_random_return

        return dataclasses.replace(self, best=float(best_return(mdp)),
                                   baseline=float(uniform_random_return(mdp)))

    def describe(self) -> dict[str, Any]:
        """What the policy is (``max_seconds`` included: it may censor agents)."""
        return {"policy": "until_solved", "best": self.best, "baseline": self.baseline,
                "fraction": self.fraction, "window": self.window,
                "max_seconds": self.max_seconds}

    def newly_stopped(self, returns: np.ndarray, rows: np.ndarray, start: int,
                      end: int) -> np.ndarray:
        """Which ``rows`` (unsolved after ``start`` episodes) have solved by ``end``.

        The decision is :func:`~vdbejax.results.solving.episodes_to_converge` on each agent's
        whole prefix — the computation the final result makes — but only for the agents
        whose windows ending in ``[start, end)`` come within :data:`SCREEN_MARGIN` of the
        threshold (a direct mean per window): the rest cannot have solved, and the check
        costs the new episodes rather than the whole prefix.
        """
        assert self.best is not None and self.baseline is not None  # resolved before the run
        solved = np.zeros(rows.size, bool)
        first = max(start, self.window - 1)  # 0-based columns of full windows to check
        if first >= end:
            return solved
        tail = normalised_returns(returns[rows, first - self.window + 1: end], self.best,
                                  self.baseline)
        means = np.lib.stride_tricks.sliding_window_view(tail, self.window, axis=-1).mean(-1)
        candidates = np.flatnonzero(
            (means >= self.fraction - TOLERANCE - SCREEN_MARGIN).any(-1))
        if candidates.size:
            exact = episodes_to_converge(returns[rows[candidates], :end], self.best,
                                         self.baseline, fraction=self.fraction,
                                         window=self.window)
            solved[candidates] = exact.solved
        return solved

    def out_of_time(self, elapsed: float) -> bool:
        return self.max_seconds is not None and elapsed >= self.max_seconds

    def fewest_episodes(self, num_episodes: int) -> int:
        """The fewest episodes an agent of a ``num_episodes`` run trains (estimates): a
        full window before it can have solved, or one with a wall-clock budget."""
        return 1 if self.max_seconds is not None else min(self.window, num_episodes)


#: Margin below the threshold under which a cheap check of a chunk's new windows rules an
#: agent out before the exact check (float64 rounding is ~1e-11 on 10^6 episodes).
SCREEN_MARGIN = 1e-7

#: A stop policy (either class; a user's own needs the same methods).
StopPolicy = FixedBudget | UntilSolved


def check_stop(stop: Any) -> StopPolicy:
    """``stop`` if it is a stop policy, else a one-line ``ValueError``."""
    if not isinstance(stop, (FixedBudget, UntilSolved)):
        raise ValueError(f"stop={stop!r} is invalid: must be FixedBudget() or UntilSolved(...)"
                         " (vdbejax.runs)")
    return stop


__all__ = ["SCREEN_MARGIN", "FixedBudget", "StopPolicy", "UntilSolved", "check_stop"]
