"""What a run will take, known before any work: memory, disk and time.

:func:`estimate_run` counts a prepared run's work. Memory and disk are what it will
allocate and write (the results, the checkpoint's episode log, the statistics' blocks).
Time has two parts:

* **training**: a lower bound, since an episode's length is known only once it is run:
  every episode takes at least one step, and the engine does not exceed
  :data:`MAX_STEPS_PER_SECOND` agent-steps per second per CPU core, nor one agent
  :data:`MAX_LANE_STEPS_PER_SECOND` of its own (its steps are sequential);
* **statistics and figures** (the result folder's summary, bands and figures): a
  forecast, since their work is fixed by the sizes: per setting and bootstrap resample,
  a curve of ``episodes`` values is smoothed and searched (convergence, bands), which
  dominates the weighting of the seeds (:data:`STATISTICS_OPS_PER_SECOND`, measured with
  ``python -m benchmarks.estimate_rates``).

The result-folder pipeline (:func:`vdbejax.studies.train_in_folder`) announces a run whose
estimate exceeds :data:`LONG_SECONDS` in one line before it starts.
"""
from __future__ import annotations

import dataclasses

from vdbejax.engine import available_cpus
from vdbejax.results.bootstrap import NUM_RESAMPLES
from vdbejax.runs.batching import _size, log_bytes, result_bytes

#: Agent-steps per second per CPU core that no strategy of the engine exceeds on a CPU
#: (the paper grid's warm run: ≈ 7 M per core, benchmarks/RESULTS.md; twice that here).
MAX_STEPS_PER_SECOND = 15e6
#: Steps per second of a single agent (its steps run one after another).
MAX_LANE_STEPS_PER_SECOND = 5e6
#: Bootstrap curve points (setting × resample × episode) per second: 1 × 1 × 300,000
#: episodes took 6 s beyond the training and start-up, 2 × 50 × 20,000 about 1 s, and
#: 1 × 1 × 10⁷ about 3 min (2-core machine, 2026-12-03).
STATISTICS_OPS_PER_SECOND = 1e8
#: Bytes per setting-episode of the statistics (mean curves, bands, moving averages).
STATISTICS_BYTES_PER_SETTING_EPISODE = 64
#: A run whose estimate exceeds this is announced before it starts.
LONG_SECONDS = 60.0


@dataclasses.dataclass(frozen=True)
class RunEstimate:
    """A run's work, before it starts (module docstring).

    Attributes:
      agents, episodes, settings: the work's size.
      memory_bytes: host memory of the results and their statistics.
      disk_bytes: the checkpoint's episode log at its largest.
      training_seconds: a lower bound of the training's wall time.
      statistics_seconds: a forecast of the statistics' and figures' (0 without them).
    """

    agents: int
    episodes: int
    settings: int
    memory_bytes: int
    disk_bytes: int
    training_seconds: float
    statistics_seconds: float

    @property
    def seconds(self) -> float:
        """The whole run's estimate (training's lower bound + statistics)."""
        return self.training_seconds + self.statistics_seconds

    @property
    def long(self) -> bool:
        """Whether the run is announced (:data:`LONG_SECONDS`)."""
        return self.seconds > LONG_SECONDS

    def describe(self) -> str:
        """One line: ``training ≥ 2 min, statistics and figures ≈ 3 min, …``."""
        return (f"{self.agents:,} agents × {self.episodes:,} episodes: training ≥"
                f" {duration(self.training_seconds)} (every episode at least one step),"
                f" statistics and figures ≈ {duration(self.statistics_seconds)}, memory ≈"
                f" {_size(self.memory_bytes)}, checkpoint ≈ {_size(self.disk_bytes)} of disk")


def duration(seconds: float) -> str:
    """``"42 s"``, ``"3.5 min"`` or ``"2.1 h"``."""
    if seconds < 90:
        return f"{seconds:.0f} s"
    if seconds < 5400:
        return f"{seconds / 60:.1f} min"
    return f"{seconds / 3600:.1f} h"


def estimate_run(settings: int, seeds: int, episodes: int, *, statistics: bool = True,
                 checkpoint: bool = True, cores: int | None = None) -> RunEstimate:
    """The estimate of ``settings × seeds`` agents trained for ``episodes`` episodes.

    Args:
      settings, seeds, episodes: the work.
      statistics: the result folder's statistics and figures follow the training.
      checkpoint: the run keeps an episode log.
      cores: CPU cores the engine uses (default: those this process may use).
    """
    agents = settings * seeds
    if cores is None:
        cores = available_cpus()
    agent_episodes = float(agents) * episodes
    training = max(agent_episodes / (MAX_STEPS_PER_SECOND * max(cores, 1)),
                   episodes / MAX_LANE_STEPS_PER_SECOND)
    memory = result_bytes(agents, episodes)
    seconds = 0.0
    if statistics:
        memory += settings * episodes * STATISTICS_BYTES_PER_SETTING_EPISODE
        seconds = NUM_RESAMPLES * float(settings) * episodes / STATISTICS_OPS_PER_SECOND
    disk = log_bytes(agents, episodes) if checkpoint else 0
    return RunEstimate(agents=agents, episodes=episodes, settings=settings,
                       memory_bytes=int(memory), disk_bytes=int(disk),
                       training_seconds=training, statistics_seconds=seconds)
