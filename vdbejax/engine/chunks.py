"""Where an engine call's chunks end: every ``chunk`` episodes, or sized by time.

A stop (Ctrl-C in a Python session) waits for the chunk that runs — one native call —, so
a chunk's time is what a stop waits. :class:`ChunkSchedule` decides each chunk's bounds
when the chunk is queued:

* **fixed** (``seconds=None``): chunks of ``chunk`` episodes from the first episode to
  run, the last one shorter (a chunk size the user chose; snapshots every K episodes);
* **timed** (``seconds``): every multiple of ``chunk`` still ends a chunk (so chunks of a
  run that evaluates its agents end where the evaluations are due), and between them the
  chunks last about ``seconds``: the first chunks are one episode, each later one is
  sized from the time per episode the latest chunk took, at most :data:`GROWTH` times
  the previous chunk. The work after each chunk (its checkpoint, the evaluations, the
  progress) is measured too: a chunk's training lasts at least :data:`OVERHEAD_RATIO`
  times it, so that the checkpoints of a run with large agents cost at most a fifth of it.

Results never depend on where chunks end (an agent's state at a chunk boundary is the same
whatever the chunk size), so a timed schedule changes no bit of a run.
"""
from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable, Iterator
from typing import Any

import numpy as np

#: A timed chunk is at most this many times the previous one (early episodes, the
#: longest, measured first, make the first estimates cautious).
GROWTH = 4
#: A timed chunk's training lasts at least this many times the work after the previous
#: chunk (checkpoint, evaluations, progress).
OVERHEAD_RATIO = 4


class RunCancelled(Exception):
    """A chunk's work stopped between two native calls: the run is stopping (a stop in
    the main thread; the workers' chunks end at their next call)."""


@dataclasses.dataclass
class Piece:
    """A piece of a chunk ``c`` of episodes ``[first, end)`` (a whole chunk, or what its
    agents ran within ``chunk_steps`` when they had not finished it: mid-episode if need
    be). ``returns``, ``lengths``, ``cut`` and ``optimal`` (``None`` without the mask of
    optimal actions) are ``[agents, chunk_length]`` records of the episodes finished in
    this piece, and the counts of optimal actions of its steps (zeros elsewhere);
    ``iterations`` and ``lanes`` its work; ``episodes`` each agent's episodes done after
    it; ``finished``: every agent has finished the chunk."""

    c: int
    first: int
    end: int
    returns: Any
    lengths: Any
    cut: Any
    optimal: Any
    iterations: int
    lanes: int
    episodes: np.ndarray
    finished: bool


class ChunkSchedule:
    """The bounds ``(first, end)`` of an engine call's chunks (module docstring).

    ``schedule[c]`` is chunk ``c``'s bounds, decided the first time it is asked and
    fixed from then on (``IndexError`` past the last chunk; iterating gives every
    chunk's bounds); :meth:`received` and :meth:`handled` tell a timed schedule when a
    chunk's outputs arrived and when the work after it was done.

    Args:
      done: episodes already run (the first chunk starts there).
      num_episodes: episodes of the call.
      chunk: episodes per chunk (fixed), or the most between two of its multiples (timed).
      seconds: a timed schedule's target time per chunk (None: fixed).
      clock: the time source (tests pass their own).
    """

    def __init__(self, done: int, num_episodes: int, chunk: int, seconds: float | None = None,
                 clock: Callable[[], float] = time.perf_counter) -> None:
        self.done, self.num_episodes, self.chunk, self.seconds = done, num_episodes, chunk, seconds
        self.clock = clock
        self.bounds: list[tuple[int, int]] = []
        self.per_episode: float | None = None  # seconds per episode of the latest chunk
        self.overhead = 0.0  # seconds of the work after the latest chunk
        self.size = 1  # a timed chunk's episodes, before a multiple of ``chunk`` cuts it
        self.mark = clock()  # when the work after the latest chunk ended (or the start)
        self.arrived = self.mark

    def exists(self, c: int) -> bool:
        """Whether chunk ``c`` exists (its bounds are decided here if they were not)."""
        while len(self.bounds) <= c:
            first = self.bounds[-1][1] if self.bounds else self.done
            if first >= self.num_episodes:
                return False
            self.bounds.append((first, self._end(first)))
        return True

    def __getitem__(self, c: int) -> tuple[int, int]:
        if not self.exists(c):
            raise IndexError(c)
        return self.bounds[c]

    def __iter__(self) -> Iterator[tuple[int, int]]:
        c = 0
        while self.exists(c):
            yield self.bounds[c]
            c += 1

    def _end(self, first: int) -> int:
        if self.seconds is None:
            return min(first + self.chunk, self.num_episodes)
        aligned = min((first // self.chunk + 1) * self.chunk, self.num_episodes)
        if self.per_episode is not None:  # the growth counts from the size last decided
            target = max(self.seconds, OVERHEAD_RATIO * self.overhead)  # (before its cut)
            self.size = max(1, min(int(target / max(self.per_episode, 1e-12)),
                                   GROWTH * self.size))
        return min(first + self.size, aligned)

    def start(self) -> None:
        """The chunks start now (after the programs were got)."""
        self.mark = self.arrived = self.clock()

    def received(self, c: int) -> None:
        """Chunk ``c``'s outputs arrived: its time per episode is measured (the wait since
        the work after the previous chunk ended)."""
        self.arrived = self.clock()
        first, end = self.bounds[c]
        self.per_episode = (self.arrived - self.mark) / (end - first)

    def handled(self, c: int) -> None:
        """The work after chunk ``c`` (checkpoint, evaluations, progress) is done."""
        self.mark = self.clock()
        self.overhead = self.mark - self.arrived
