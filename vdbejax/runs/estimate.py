"""What a run will take, known before any work: memory, disk and time.

:func:`estimate_run` counts a prepared run's work. Memory and disk are what it will
allocate and write (the results, the checkpoint's episode log, the statistics' blocks).
Time has two parts:

* **training**: a lower bound, since an episode's length is known only once it is run:
  every episode takes at least the task's shortest episode
  (:func:`vdbejax.envs.solvers.shortest_episode`: one step, or up to ``max_steps`` where no
  early end is possible), every agent trains at least its stop policy's fewest episodes,
  and the engine does not exceed :data:`MAX_STEPS_PER_SECOND` agent-steps per second per
  CPU core, nor one agent :data:`MAX_LANE_STEPS_PER_SECOND` of its own (its steps are
  sequential). The estimate also states the run's agent-steps from that fewest to the
  most (every episode of the budget to the step limit): what a method costs per step
  (a model's planning, say) is the user's to weigh;
* **statistics and figures** (the result folder's summary, bands and figures): a
  forecast, since their work is fixed by the sizes: per setting and bootstrap resample,
  a curve of ``episodes`` values is smoothed (bands; each agent's is searched once for its
  convergence episode), which
  dominates the weighting of the seeds (:data:`STATISTICS_OPS_PER_SECOND`, measured with
  ``python -m benchmarks.estimate_rates``).

A run that evaluates its agents' greedy policies (``evaluate_every``) adds a forecast of
the evaluations (:data:`EVALUATION_OPS_PER_SECOND`). The result-folder pipeline
(:func:`vdbejax.studies.train_in_folder`) announces a run whose estimate exceeds
:data:`LONG_SECONDS`, that evaluates its policies, or that needs at least
:data:`LARGE_MEMORY_BYTES`, in one line before it starts. A
study of several result folders (``scale``, ``bench``, ``depth``) adds its runs'
estimates into one :class:`StudyEstimate`, always announced (unless quiet) before its
folder is made.
"""
from __future__ import annotations

import dataclasses
import sys
from typing import TYPE_CHECKING

from vdbejax.engine import available_cpus
from vdbejax.engine.agent_state import state_bytes
from vdbejax.envs.solvers import shortest_episode
from vdbejax.envs.tabular import TabularMDP
from vdbejax.methods.agents import table_layout
from vdbejax.results.bootstrap import NUM_RESAMPLES
from vdbejax.runs.batching import (
    SCALAR_BYTES,
    bytes_per_agent,
    instance_bytes,
    instances_host_bytes,
    log_bytes,
    result_bytes,
    settings_bytes,
    size_text,
)
from vdbejax.runs.evaluation import evaluation_operations

if TYPE_CHECKING:
    from vdbejax.runs.grid import PreparedGrid

#: Agent-steps per second per CPU core that no strategy of the engine exceeds on a CPU
#: (the paper grid's warm run: ≈ 7 M per core, benchmarks/RESULTS.md; twice that here).
MAX_STEPS_PER_SECOND = 15e6
#: Steps per second of a single agent (its steps run one after another).
MAX_LANE_STEPS_PER_SECOND = 5e6
#: Bootstrap curve points (setting × resample × episode) per second: 1 × 1 × 300,000
#: episodes took 6 s beyond the training and start-up, 2 × 50 × 20,000 about 1 s, and
#: 1 × 1 × 10⁷ about 3 min (2-core machine, 2026-12-03).
STATISTICS_OPS_PER_SECOND = 1e8
#: Multiply-adds per second of the policy evaluation (:mod:`vdbejax.runs.evaluation`): 64
#: Q-learning agents on a 2,000-state task (2 outcomes, H = 200) took 0.75 s for
#: 3.1 × 10⁸ (counted as :func:`~vdbejax.runs.evaluation.evaluation_operations` does), 16
#: UCB-H agents 4.4 s for 2.6 × 10⁹ (2-core machine, 2026-12-05): the slower, rounded down.
EVALUATION_OPS_PER_SECOND = 2.5e8
#: Bytes per setting-episode of the statistics (mean curves, bands, moving averages).
STATISTICS_BYTES_PER_SETTING_EPISODE = 64
#: A run whose estimate exceeds this is announced before it starts.
LONG_SECONDS = 60.0
#: Host copies of the agents' states a checkpointed run holds at a chunk's end: the work
#: items' copies, the gathered state, the run's stored state, the checkpoint's buffer, and
#: one more passing (100,000 table-cleaning agents × 20 episodes: 2.5 GiB at the peak,
#: 1.1 GiB without checkpoints, 2-core machine, 2026-12-06).
CHECKPOINT_STATE_COPIES = 5
#: A run whose estimated memory reaches this is announced before it starts too.
LARGE_MEMORY_BYTES = 1 << 30
#: Seconds to prepare one setting before training (its agent made, checked and stacked
#: with the others: 10⁵ settings took 150 s on a busy 2-core machine, 2026-12-05).
PREPARE_SECONDS_PER_SETTING = 1.5e-3
#: A sweep of at least this many settings is announced before its settings are made
#: (:func:`announce_settings`): preparing them takes about 15 s or more.
LARGE_SWEEP_SETTINGS = 10_000


@dataclasses.dataclass(frozen=True)
class RunEstimate:
    """A run's work, before it starts (module docstring).

    Attributes:
      agents, episodes, settings: the work's size (``episodes``: the budget).
      memory_bytes: host memory of the settings, the results and their statistics (and
        of the task instances, with an instance per agent, and of the agents' states,
        from :func:`estimate_prepared`).
      settings_bytes: the settings' share of it (:data:`~vdbejax.runs.batching.SETTING_BYTES`
        each: a sweep of 10⁶ settings takes gigabytes before any agent trains).
      task_bytes: the task instances' share of it
        (:func:`~vdbejax.runs.batching.instances_host_bytes`; 0: a shared task).
      agents_bytes: the agents' share of it, a batch's states as the engine holds them
        (:func:`~vdbejax.runs.batching.bytes_per_agent`) and their copies at a checkpoint
        (:data:`CHECKPOINT_STATE_COPIES`); 0: not counted.
      disk_bytes: the checkpoint's episode log at its largest.
      training_seconds: a lower bound of the training's wall time.
      statistics_seconds: a forecast of the statistics' and figures' (0 without them).
      fewest_steps, most_steps: the run's agent-steps at the fewest (every agent its
        fewest episodes, each the task's shortest) and at the most (every episode of the
        budget to the step limit).
    """

    agents: int
    episodes: int
    settings: int
    memory_bytes: int
    disk_bytes: int
    training_seconds: float
    statistics_seconds: float
    fewest_steps: int = 0
    most_steps: int = 0
    evaluations: int = 0
    evaluation_operations: int = 0
    settings_bytes: int = 0
    task_bytes: int = 0
    agents_bytes: int = 0

    @property
    def evaluation_seconds(self) -> float:
        """A forecast of the policy evaluations' time (:data:`EVALUATION_OPS_PER_SECOND`)."""
        return self.evaluation_operations / EVALUATION_OPS_PER_SECOND

    @property
    def seconds(self) -> float:
        """The whole run's estimate (training's lower bound + statistics + evaluations)."""
        return self.training_seconds + self.statistics_seconds + self.evaluation_seconds

    @property
    def long(self) -> bool:
        """Whether the run is announced: its estimate exceeds :data:`LONG_SECONDS`, it
        evaluates its policies (work the user asked for, whose cost it states), or it
        needs at least :data:`LARGE_MEMORY_BYTES` of memory."""
        return (self.seconds > LONG_SECONDS or self.evaluations > 0
                or self.memory_bytes >= LARGE_MEMORY_BYTES)

    def describe(self) -> str:
        """One line: ``training ≥ 2 min (…), statistics and figures ≈ 3 min, …``."""
        evaluation = (f", policy evaluation ≈ {duration(self.evaluation_seconds)}"
                      f" ({self.evaluations:,} evaluations of every agent,"
                      f" ≤ {count(self.evaluation_operations)} multiply-adds)"
                      if self.evaluations else "")
        tasks = f", the task instances ≈ {size_text(self.task_bytes)}" if self.task_bytes else ""
        if self.agents_bytes:
            tasks += f", the agents' states ≈ {size_text(self.agents_bytes)}"
        return (f"{self.agents:,} agents × {self.episodes:,} episodes: {_common(self)}"
                f"{evaluation}, memory ≈ {size_text(self.memory_bytes)} (the {self.settings:,}"
                f" settings ≈ {size_text(self.settings_bytes)}{tasks}), checkpoint ≈"
                f" {size_text(self.disk_bytes)} of disk")


@dataclasses.dataclass(frozen=True)
class StudyEstimate:
    """A study's runs (one result folder each, trained one after another), estimated
    together before the study starts. Memory and disk are the largest run's.

    Attributes:
      parts: every run's estimate.
    """

    parts: tuple[RunEstimate, ...]

    @property
    def training_seconds(self) -> float:
        return sum(part.training_seconds for part in self.parts)

    @property
    def statistics_seconds(self) -> float:
        return sum(part.statistics_seconds for part in self.parts)

    @property
    def seconds(self) -> float:
        return self.training_seconds + self.statistics_seconds

    @property
    def fewest_steps(self) -> int:
        return sum(part.fewest_steps for part in self.parts)

    @property
    def most_steps(self) -> int:
        return sum(part.most_steps for part in self.parts)

    @property
    def long(self) -> bool:
        """A study is always announced: it runs one result folder after another."""
        return True

    def describe(self) -> str:
        """One line: runs, training's bound and agent-steps, statistics, the largest run's
        memory and checkpoint."""
        memory = max((part.memory_bytes for part in self.parts), default=0)
        disk = max((part.disk_bytes for part in self.parts), default=0)
        return (f"{len(self.parts)} runs: {_common(self)}, memory ≈ {size_text(memory)} and"
                f" checkpoint ≈ {size_text(disk)} of disk at the largest run")


def _common(estimate: RunEstimate | StudyEstimate) -> str:
    """Training's bound with its agent-steps, and the statistics' forecast."""
    fewest, most = count(estimate.fewest_steps), count(estimate.most_steps)
    steps = fewest if fewest == most else f"{fewest} to {most}"
    return (f"training ≥ {duration(estimate.training_seconds)} ({steps} agent-steps),"
            f" statistics and figures ≈ {duration(estimate.statistics_seconds)}")


def announce(estimate: RunEstimate | StudyEstimate, what: str) -> None:
    """Write ``a long run: …`` (``a study: …``) to stderr when ``estimate`` is long."""
    if estimate.long:
        label = (f"a long {what}" if isinstance(estimate, RunEstimate)
                 and estimate.seconds > LONG_SECONDS else f"a {what}")
        sys.stderr.write(f"{label}: {estimate.describe()}; Ctrl-C keeps its checkpoint,"
                         " --resume continues\n")


def announce_settings(settings: int, agents: int, episodes: int) -> None:
    """Write ``a sweep of N settings: …`` to stderr for a sweep of at least
    :data:`LARGE_SWEEP_SETTINGS` settings, before any is made: the time to prepare them and
    the memory of the settings and their results (the run's own estimate follows once
    they are made)."""
    if settings < LARGE_SWEEP_SETTINGS:
        return
    memory = result_bytes(agents, episodes) + settings_bytes(settings)
    sys.stderr.write(f"a sweep of {settings:,} settings ({agents:,} agents × {episodes:,}"
                     f" episodes): preparing them ≈"
                     f" {duration(settings * PREPARE_SECONDS_PER_SETTING)} before training,"
                     f" memory ≈ {size_text(memory)} (the settings ≈"
                     f" {size_text(settings_bytes(settings))})\n")


def count(number: float) -> str:
    """``"950"``, ``"1.5 k"``, ``"3.2 M"`` or ``"4.0 G"``."""
    for scale, suffix in ((1e9, " G"), (1e6, " M"), (1e3, " k")):
        if number >= scale:
            return f"{number / scale:.1f}{suffix}"
    return f"{number:.0f}"


def duration(seconds: float) -> str:
    """``"0.4 s"``, ``"42 s"``, ``"3.5 min"`` or ``"2.1 h"`` (two significant digits below
    10 s: a short bound is not rounded to a vacuous "0 s")."""
    if seconds < 10:
        return f"{seconds:.2g} s"
    if seconds < 90:
        return f"{seconds:.0f} s"
    if seconds < 5400:
        return f"{seconds / 60:.1f} min"
    return f"{seconds / 3600:.1f} h"


def estimate_run(settings: int, seeds: int, episodes: int, *, statistics: bool = True,
                 checkpoint: bool = True, cores: int | None = None,
                 steps_per_episode: int = 1, fewest_episodes: int | None = None,
                 max_steps: int | None = None) -> RunEstimate:
    """The estimate of ``settings × seeds`` agents trained for ``episodes`` episodes.

    Args:
      settings, seeds, episodes: the work.
      steps_per_episode: the fewest steps of an episode (the task's shortest episode).
      fewest_episodes: the fewest episodes an agent trains (a stop policy's; default
        ``episodes``).
      max_steps: the step limit of an episode (default ``steps_per_episode``).
      statistics: the result folder's statistics and figures follow the training.
      checkpoint: the run keeps an episode log.
      cores: CPU cores the engine uses (default: those this process may use).
    """
    agents = settings * seeds
    max_steps = steps_per_episode if max_steps is None else max_steps
    if cores is None:
        cores = available_cpus()
    fewest = episodes if fewest_episodes is None else min(fewest_episodes, episodes)
    steps = float(agents) * fewest * steps_per_episode
    training = max(steps / (MAX_STEPS_PER_SECOND * max(cores, 1)),
                   fewest * steps_per_episode / MAX_LANE_STEPS_PER_SECOND) if agents else 0.0
    memory = result_bytes(agents, episodes) + settings_bytes(settings)
    seconds = 0.0
    if statistics:
        memory += settings * episodes * STATISTICS_BYTES_PER_SETTING_EPISODE
        # One seed's resamples are all that seed: computed once (vdbejax.results.stats).
        resamples = 2 if seeds == 1 else NUM_RESAMPLES
        seconds = resamples * float(settings) * episodes / STATISTICS_OPS_PER_SECOND
    disk = log_bytes(agents, episodes) if checkpoint else 0
    return RunEstimate(agents=agents, episodes=episodes, settings=settings,
                       memory_bytes=int(memory), disk_bytes=int(disk),
                       training_seconds=training, statistics_seconds=seconds,
                       fewest_steps=int(steps), most_steps=int(agents * episodes * max_steps),
                       settings_bytes=settings_bytes(settings))


def estimate_task(mdp: TabularMDP, settings: int, seeds: int, episodes: int, *,
                  fewest_episodes: int | None = None, statistics: bool = True,
                  checkpoint: bool = True) -> RunEstimate:
    """:func:`estimate_run` on ``mdp``: every episode at least its shortest
    (:func:`~vdbejax.envs.solvers.shortest_episode`)."""
    return estimate_run(settings, seeds, episodes, statistics=statistics,
                        checkpoint=checkpoint, steps_per_episode=shortest_episode(mdp),
                        fewest_episodes=fewest_episodes, max_steps=int(mdp.max_steps))


def estimate_prepared(prepared: PreparedGrid, *, statistics: bool = True) -> RunEstimate:
    """The estimate of a prepared grid run (its task, work and stop policy; its task
    instances, with an instance per agent; its policy evaluations,
    :mod:`vdbejax.runs.evaluation`, at most one per ``evaluate_every`` episodes of the
    budget)."""
    estimate = estimate_task(prepared.mdp, len(prepared.settings), prepared.num_seeds,
                             prepared.num_episodes, statistics=statistics,
                             fewest_episodes=prepared.stop.fewest_episodes(
                                 prepared.num_episodes))
    own = 0
    if prepared.instances is not None:  # prepared.mdp is agent 0's: shaped as every one
        tasks = instances_host_bytes(prepared.mdp, prepared.num_agents,
                                     prepared.run.record_optimal)
        own = instance_bytes(prepared.instances, prepared.run.record_optimal)
        estimate = dataclasses.replace(estimate, task_bytes=tasks,
                                       memory_bytes=estimate.memory_bytes + tasks)
    plan, layout = prepared.plan, table_layout(prepared.params)
    # A batch of agents at once, as the engine holds them, and the host's copies of their
    # states at a checkpoint.
    agents = min(plan.batch_size, len(plan.rows)) * (
        bytes_per_agent(prepared.mdp, min(plan.chunk_episodes, prepared.num_episodes),
                        layout, own)
        + CHECKPOINT_STATE_COPIES * (state_bytes(prepared.mdp, layout) + SCALAR_BYTES))
    estimate = dataclasses.replace(estimate, agents_bytes=agents,
                                   memory_bytes=estimate.memory_bytes + agents)
    every = prepared.run.evaluate_every
    if every is None:
        return estimate
    evaluations = prepared.num_episodes // every
    return dataclasses.replace(
        estimate, evaluations=evaluations,
        memory_bytes=estimate.memory_bytes + 4 * estimate.agents * evaluations,
        evaluation_operations=evaluations * evaluation_operations(prepared.mdp,
                                                                  prepared.params))

