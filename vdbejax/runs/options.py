"""The engine's knobs of a run, in one frozen object: :class:`RunOptions`.

The work of a run (task, settings, seeds, episodes, root seed, agent options) decides its
results; these knobs decide how it runs — chunking, progress, checkpoint and resume,
memory budget and devices, the engine strategy — and, through :attr:`RunOptions.stop`,
when agents stop. Every field is checked when the object is made, so a bad value fails in
one line before anything is created or trained.
"""
from __future__ import annotations

import dataclasses
import os
from collections.abc import Collection
from pathlib import Path
from typing import Any

import numpy as np

from vdbejax.engine.progress import ProgressCallback
from vdbejax.runs.stop import FixedBudget, StopPolicy, check_stop
from vdbejax.validation import INT32_MAX, check_bool, check_choice, check_int, parse_bytes

#: Engine strategies a run may ask for (``"auto"``: the plan decides, :mod:`vdbejax.runs.plan`).
STRATEGIES = ("auto", "sequential", "lockstep")
#: The fields that change only the speed of a run, which every study takes.
SPEED_FIELDS = ("memory_budget_bytes", "devices", "strategy", "threads", "mix_kinds")


@dataclasses.dataclass(frozen=True)
class RunOptions:
    """How a run runs (none of it changes an agent's results, except ``stop``).

    Attributes:
      chunk_episodes: episodes per jitted chunk (progress, checkpoint and stop-check
        granularity; None: the plan's, :func:`~vdbejax.runs.plan.default_chunk_episodes`).
      progress: True for a progress bar on stderr, or ``progress(done, total, elapsed)``
        in agent-episodes.
      checkpoint: file written after every chunk (atomically), with its episode log
        beside it (:mod:`vdbejax.runs.checkpoint`).
      resume: continue from ``checkpoint`` if it exists.
      overwrite: a result folder (:func:`~vdbejax.studies.train_in_folder`) may replace
        the finished result (or discard the checkpoint) it already holds; without it that
        is refused in one line.
      memory_budget_bytes: device memory the agents may use, per device (an int or a
        size such as ``"512M"``; default: half the free memory of the smallest device).
        Agents that do not fit run in sequential batches.
      devices: devices to shard the agents over (default: all of ``jax.devices()``).
      stop: the stop policy (:class:`~vdbejax.runs.stop.FixedBudget` or
        :class:`~vdbejax.runs.stop.UntilSolved`).
      strategy: the engine strategy, ``"auto"`` (:func:`~vdbejax.engine.auto_strategy`:
        lockstep on accelerators and for sharded agents, sequential on a CPU;
        ``meta.json`` states the rule that chose), ``"sequential"`` or ``"lockstep"``.
      mix_kinds: the lockstep strategy runs agents of several kinds in one batch, each
        lane its own kind, instead of kind after kind (None: on accelerators,
        :func:`~vdbejax.engine.mixes_kinds`; ``meta.json``'s plan states it).
      threads: worker threads on a CPU (default: the CPUs this process may use).
      evaluate_every: every this many episodes, the exact expected return of each
        agent's greedy policy (:mod:`vdbejax.runs.evaluation`), kept beside the returns
        (``GridResult.policy_values``); None: no evaluation. It changes no return.
      record_optimal: record, per episode, the fraction of its steps whose action is
        optimal (:mod:`vdbejax.runs.optimal_record`; ``GridResult.optimal_actions``).
        It changes no return.
    """

    chunk_episodes: int | None = None
    progress: bool | ProgressCallback = False
    checkpoint: str | os.PathLike | None = None
    resume: bool = False
    overwrite: bool = False
    memory_budget_bytes: int | str | None = None
    devices: int | None = None
    stop: StopPolicy = dataclasses.field(default_factory=FixedBudget)
    strategy: str = "auto"
    threads: int | None = None
    mix_kinds: bool | None = None
    evaluate_every: int | None = None
    record_optimal: bool = False

    def __post_init__(self) -> None:
        def fix(name: str, value: Any) -> None:
            object.__setattr__(self, name, value)

        if self.chunk_episodes is not None:
            fix("chunk_episodes", check_int("chunk_episodes", self.chunk_episodes, 1,
                                            INT32_MAX))
        if isinstance(self.progress, np.bool_):
            fix("progress", bool(self.progress))
        if not (isinstance(self.progress, bool) or callable(self.progress)):
            raise ValueError(f"progress={self.progress!r} is invalid: must be True, False or a"
                             " callable progress(done, total, elapsed)")
        if self.checkpoint is not None:
            if not isinstance(self.checkpoint, (str, os.PathLike)):
                raise ValueError(f"checkpoint={self.checkpoint!r} is invalid: must be a file"
                                 " path or None")
            if Path(self.checkpoint).exists() and not Path(self.checkpoint).is_file():
                raise ValueError(f"checkpoint={str(self.checkpoint)!r} is invalid: it exists"
                                 " and is not a file")
        fix("resume", check_bool("resume", self.resume))
        fix("overwrite", check_bool("overwrite", self.overwrite))
        fix("record_optimal", check_bool("record_optimal", self.record_optimal))
        if self.memory_budget_bytes is not None:
            fix("memory_budget_bytes", parse_bytes("memory_budget_bytes",
                                                   self.memory_budget_bytes))
        if self.devices is not None:
            fix("devices", check_int("devices", self.devices, 1))
        check_stop(self.stop)
        check_choice("strategy", self.strategy, STRATEGIES)
        if self.mix_kinds is not None:
            fix("mix_kinds", check_bool("mix_kinds", self.mix_kinds))
        if self.threads is not None:
            fix("threads", check_int("threads", self.threads, 1))
        if self.evaluate_every is not None:
            fix("evaluate_every", check_int("evaluate_every", self.evaluate_every, 1,
                                            INT32_MAX))

    def replace(self, **changes: Any) -> RunOptions:
        """A copy with ``changes`` (checked like the original).

        Raises:
          ValueError: a name that is not a field of :class:`RunOptions`.
        """
        unknown = sorted(set(changes) - {f.name for f in dataclasses.fields(self)})
        if unknown:
            raise ValueError(f"{unknown[0]} is not a run option: the options are"
                             f" {', '.join(f.name for f in dataclasses.fields(self))}")
        return dataclasses.replace(self, **changes)


def study_run(run: RunOptions | None, caller: str, takes: Collection[str],
              default: RunOptions | None = None) -> RunOptions:
    """The run options of a study's entry point ``caller`` (``run_sweep``, …): ``run``, or
    ``default`` (``RunOptions(progress=True)``) when None.

    Raises:
      ValueError: ``run`` is not a :class:`RunOptions`, or sets a field the study does not
        take (one not in ``takes``, away from its default): it would be ignored.
    """
    if run is None:
        return RunOptions(progress=True) if default is None else default
    if not isinstance(run, RunOptions):
        raise ValueError(f"run={run!r} is invalid: must be a RunOptions")
    plain = RunOptions()
    for field in dataclasses.fields(run):
        value = getattr(run, field.name)
        if field.name not in takes and value != getattr(plain, field.name):
            raise ValueError(f"run.{field.name}={value!r} is invalid: {caller} does not take it"
                             f" (it takes {', '.join(sorted(takes))})")
    return run
