"""The plan of a run: where its agents run, in what batches, with which engine strategy.

:func:`make_plan` decides it once, from the options and the agents' memory, before
anything trains; ``meta.json`` states it (:meth:`RunPlan.describe`). Nothing below
rewrites an option: a choice the options leave open (``strategy="auto"``) is made here and
written down, a contradictory one (the sequential strategy for agents sharded over several
devices) is refused in one line.

* **Processes** (hosts after ``jax.distributed.initialize``): each runs its contiguous
  share of the agents (:func:`~vdbejax.engine.distributed.process_share`) on its own devices.
* **Devices**: with several, every batch's agent axis is sharded over them
  (:meth:`RunPlan.run_engine`): padded to a multiple of the device count, placed with
  ``NamedSharding(mesh, P("agents"))``; each agent's lane depends on itself only, so the
  results are those of one device. Sharded agents run the lockstep strategy without
  compaction (which would gather the active agents across shards).
* **Batches**: agents that do not fit the memory budget run in sequential batches of
  :attr:`RunPlan.batch_size` (:mod:`vdbejax.runs.batching`). With an instance per agent,
  each agent's instance counts as its own (it moves with the agent); the task every device
  holds whatever the batch is then agent 0's, the engine's template.
"""
from __future__ import annotations

import dataclasses
import math
from typing import Any

import jax
import numpy as np

from vdbejax.engine import (
    AgentState,
    ChunkHooks,
    EngineOptions,
    RunResult,
    auto_strategy,
    mixes_kinds,
    run_agents,
)
from vdbejax.engine.distributed import (
    agent_mesh,
    local_devices,
    pad_agents,
    process_share,
    select_devices,
    shard_agents,
    unpad_agents,
)
from vdbejax.engine.programs import Programs
from vdbejax.envs.tabular import TabularMDP
from vdbejax.envs.task_instances import TaskInstances
from vdbejax.methods.agents import AgentParams, table_layout
from vdbejax.runs.batching import (
    agents_per_batch,
    bytes_per_agent,
    default_memory_budget,
    instance_bytes,
    mdp_bytes,
)
from vdbejax.runs.options import RunOptions


@dataclasses.dataclass(frozen=True)
class RunPlan:
    """Where and how a run's agents run (:func:`make_plan`).

    Attributes:
      devices: the devices of the run (every process's).
      local: this process's devices among them.
      rows: the agent rows this process runs.
      batch_size: agents per sequential batch.
      memory_budget_bytes: the per-device budget the batch size was computed for.
      strategy: the engine strategy asked of every batch.
      strategy_rule: why: ``"asked"`` (the options named it) or ``"auto: …"``
        (:func:`~vdbejax.engine.auto_strategy`'s reason).
      compact: the lockstep strategy's compaction.
      mix_kinds: the lockstep strategy runs several kinds in one batch
        (:func:`~vdbejax.engine.mixes_kinds`: on accelerators).
      chunk_episodes: episodes per engine chunk (with ``chunk_seconds``: the most
        between two of its multiples).
      threads: worker threads of the sequential strategy (None: the engine's default).
      chunk_seconds: the engine sizes chunks to about this many seconds
        (:mod:`vdbejax.engine.chunks`): a stop waits for one chunk. None: chunks of
        ``chunk_episodes`` (the user's chunk, or a stop policy's: its chunks decide where
        agents stop).
    """

    devices: tuple[jax.Device, ...]
    local: tuple[jax.Device, ...]
    rows: np.ndarray
    batch_size: int
    memory_budget_bytes: int
    strategy: str
    compact: bool
    chunk_episodes: int
    threads: int | None
    strategy_rule: str = "asked"
    chunk_seconds: float | None = None
    mix_kinds: bool = False

    @property
    def sharded(self) -> bool:
        return len(self.local) > 1

    def describe(self) -> dict[str, Any]:
        """The plan as ``meta.json`` states it."""
        return {"devices": len(self.devices), "processes": jax.process_count(),
                "sharded": self.sharded, "strategy": self.strategy,
                "strategy_rule": self.strategy_rule, "compact": self.compact,
                "mix_kinds": self.mix_kinds and self.strategy == "lockstep",
                "agents_per_batch": self.batch_size,
                "memory_budget_bytes": int(self.memory_budget_bytes)}

    def run_engine(self, mdp: TabularMDP | TaskInstances, params: AgentParams, keys: np.ndarray,
                   num_episodes: int, *, initial: tuple | None, hooks: ChunkHooks,
                   keep_final_state: bool, programs: Programs,
                   optimal_action: np.ndarray | None = None) -> RunResult:
        """One engine call on a batch (sharded over :attr:`local` when there are several):
        :func:`~vdbejax.engine.run_agents` to ``num_episodes`` episodes, ``hooks`` called
        between its chunks (with the padding agents of a sharded batch left out)."""
        options = EngineOptions(chunk_episodes=self.chunk_episodes, strategy=self.strategy,
                                compact=self.compact, threads=self.threads,
                                mix_kinds=self.mix_kinds, chunk_seconds=self.chunk_seconds,
                                keep_final_state=keep_final_state, programs=programs)
        if not self.sharded:
            return run_agents(mdp, params, keys, num_episodes, options, hooks, initial=initial,
                              optimal_action=optimal_action)
        mesh = agent_mesh(self.local)
        (params, keys), count = pad_agents((params, np.asarray(keys, np.uint32)),
                                           len(self.local))
        if isinstance(mdp, TaskInstances):  # the padding agents' instances: the last one's
            mdp = mdp.take(pad_agents(np.arange(count), len(self.local))[0])
            if optimal_action is not None:
                optimal_action = pad_agents(optimal_action, len(self.local))[0]
        params, keys = shard_agents((params, keys), mesh)
        if initial is not None:
            done, agents, *episodes = initial  # returns, lengths, cut (and optimal counts)
            if np.ndim(done):  # one per agent
                done = pad_agents(np.asarray(done), len(self.local))[0]
            (agents, *episodes), _ = pad_agents((agents, *episodes), len(self.local))
            initial = (done, shard_agents(agents, mesh), *episodes)
        if hooks.on_chunk is not None:
            real = hooks.on_chunk

            def unpadded(done: int | np.ndarray, agents: AgentState | None,
                         *episodes: np.ndarray) -> None:
                real(done if np.ndim(done) == 0 else np.asarray(done)[:count],
                     None if agents is None else unpad_agents(agents, count),
                     *(array[:count] for array in episodes))

            hooks = dataclasses.replace(hooks, on_chunk=unpadded)
        result = run_agents(mdp, params, keys, num_episodes, options, hooks, initial=initial,
                            optimal_action=optimal_action)
        final = result.final_state
        return dataclasses.replace(
            result, returns=result.returns[:count], lengths=result.lengths[:count],
            cut=result.cut[:count],
            nonfinite=result.nonfinite[:count],
            optimal=None if result.optimal is None else result.optimal[:count],
            final_state=None if final is None else unpad_agents(final, count))


#: A chunk the plan sizes holds at least this many agent-episodes: each chunk costs a
#: call, a stop check and a checkpoint (≈ 2 ms), which a few agents' 100 episodes do not
#: repay (one agent × 200,000 episodes: 4.2 s in chunks of 100, 0.7 s in chunks of 10,000).
CHUNK_AGENT_EPISODES = 20_000
#: The episodes of a chunk the plan sizes: at least (the paper grid's chunk), at most.
CHUNK_EPISODES_MIN, CHUNK_EPISODES_MAX = 100, 10_000


#: Seconds a chunk lasts when the plan sizes the chunks (a Ctrl-C waits for the chunk that
#: runs: one native call).
CHUNK_SECONDS = 1.0


def default_chunk_episodes(num_agents: int, num_episodes: int) -> int:
    """Episodes per chunk when the run leaves it to the plan: :data:`CHUNK_AGENT_EPISODES`
    over the agents, within ``[CHUNK_EPISODES_MIN, CHUNK_EPISODES_MAX]``. Results never
    depend on it."""
    wanted = -(-CHUNK_AGENT_EPISODES // max(int(num_agents), 1))
    return max(CHUNK_EPISODES_MIN, min(wanted, CHUNK_EPISODES_MAX, max(int(num_episodes), 1)))


def evaluation_chunk(chunk_episodes: int, evaluate_every: int) -> int:
    """The chunk of a run that evaluates its agents every ``evaluate_every`` episodes:
    every multiple of it must end a chunk, so the largest divisor of it not above
    ``chunk_episodes``; ``evaluate_every`` itself where that divisor is below a quarter
    of ``chunk_episodes`` (a prime, say: chunks of a few episodes would cost more than a
    longer chunk's buffers). Results never depend on it."""
    divisors = {d for i in range(1, math.isqrt(evaluate_every) + 1) if evaluate_every % i == 0
                for d in (i, evaluate_every // i)}
    largest = max(d for d in divisors if d <= chunk_episodes)
    return largest if 4 * largest >= min(chunk_episodes, evaluate_every) else evaluate_every


def make_plan(mdp: TabularMDP, params: AgentParams, num_agents: int, num_episodes: int,
              run: RunOptions, instances: TaskInstances | None = None) -> RunPlan:
    """Decide a run's plan (module docstring).

    ``mdp`` is the run's task; with ``instances`` (an instance per agent), agent 0's.

    Raises:
      ValueError: more devices than there are, devices of no process of this one, the
        sequential strategy for sharded agents, a budget no agent fits, or under a stop
        policy an ``evaluate_every`` that is not a multiple of the chunk.
    """
    devices = select_devices(run.devices)
    local = local_devices(devices)
    rows = process_share(num_agents)
    sharded = len(local) > 1
    strategy = run.strategy
    if sharded and strategy == "sequential":
        raise ValueError(f"strategy='sequential' is invalid with devices={len(local)}: agents"
                         " sharded over several devices run the lockstep strategy (use"
                         " devices=1 for the sequential one)")
    budget = (default_memory_budget(local) if run.memory_budget_bytes is None
              else int(run.memory_budget_bytes))
    chunk = (default_chunk_episodes(num_agents, num_episodes) if run.chunk_episodes is None
             else run.chunk_episodes)
    if run.evaluate_every is not None and not run.stop.checks_chunks:
        chunk = evaluation_chunk(chunk, run.evaluate_every)
    elif run.evaluate_every is not None and run.evaluate_every % chunk:
        # A stop policy stops agents at chunk ends: another chunk would change the results.
        raise ValueError(f"evaluate_every={run.evaluate_every} is invalid with"
                         f" chunk_episodes={chunk} under a stop policy: must be a multiple of"
                         " the chunk (its chunks decide where agents stop)")
    own = 0 if instances is None else instance_bytes(instances, run.record_optimal)
    batch_size = agents_per_batch(
        max(len(rows), 1),
        bytes_per_agent(mdp, min(chunk, num_episodes), table_layout(params), own),
        budget, len(local), fixed_bytes=mdp_bytes(mdp))
    strategy_rule = "asked"
    if strategy == "auto":  # per batch: a batch is one engine call
        strategy, why = auto_strategy(min(batch_size, max(len(rows), 1)), sharded=sharded)
        strategy_rule = f"auto: {why}"
    return RunPlan(devices=tuple(devices), local=tuple(local), rows=rows,
                   batch_size=batch_size, memory_budget_bytes=budget, strategy=strategy,
                   strategy_rule=strategy_rule,
                   compact=not sharded, chunk_episodes=chunk,
                   mix_kinds=mixes_kinds() if run.mix_kinds is None else run.mix_kinds,
                   threads=run.threads,
                   chunk_seconds=(CHUNK_SECONDS if run.chunk_episodes is None
                                  and not run.stop.checks_chunks else None))
