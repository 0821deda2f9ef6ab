"""The engine: every agent of a sweep trains inside jitted programs.

Read it one module at a time:

* :mod:`~vdbejax.engine.agent_state` — what an agent carries (:class:`AgentState`), how it
  starts, and its counter-based random stream;
* :mod:`~vdbejax.engine.step` — the step rule (:func:`lockstep_iteration`): one
  iteration of a batch of agents of one kind, calling the plug-ins
  (:mod:`vdbejax.methods`; one kind's part: :mod:`~vdbejax.engine.kind_step`), its tables
  read and written lane by lane (:mod:`~vdbejax.engine.lanes`); the model, planning and
  whole-table learners' part: :mod:`~vdbejax.engine.whole`;
* :mod:`~vdbejax.engine.lockstep` — all agents of a batch advance together, with
  compaction (accelerators, sharded agents);
* :mod:`~vdbejax.engine.sequential` — native step loops of four agents side by side, one
  program for every kind (:mod:`~vdbejax.engine.kinds`), work items on threads
  (:mod:`~vdbejax.engine.work_items`; the default on a CPU);
* :mod:`~vdbejax.engine.chunk_loop` — :func:`run_agents`, the Python loop over chunks, run
  as its :class:`EngineOptions` say, calling its :class:`ChunkHooks` between chunks;
* :mod:`~vdbejax.engine.agent_on_task` — a task instance per agent, riding with its
  hyperparameters.

Both strategies run the same step function, so they compute the same thing, bit for bit
(products are rounded on their own, :mod:`vdbejax._numerics`). Results depend only on each
agent's key and hyperparameters: every iteration draws its uniforms from a hash of
``(agent key, agent counter)``, never from the batch, the chunking or a resume. Memory is
bounded by agents × (table size + chunk length): only per-episode return and length are
recorded.
"""
from vdbejax.engine.agent_state import (
    AgentState,
    agent_keys,
    broadcast_agents,
    init_agent,
    init_agents,
    uniforms,
)
from vdbejax.engine.chunk_loop import (
    STRATEGIES,
    ChunkHooks,
    EngineOptions,
    RunResult,
    available_cpus,
    check_params,
    compile_seconds,
    run_agents,
)
from vdbejax.engine.lockstep import DEFAULT_UNROLL, MAX_SAFE_BATCH, run_chunk
from vdbejax.engine.progress import ProgressCallback, text_progress
from vdbejax.engine.rules import auto_strategy, default_max_batch, mixes_kinds
from vdbejax.engine.sequential import native_step_loops
from vdbejax.engine.step import ChunkBounds, lockstep_iteration, start_support

__all__ = [
    "DEFAULT_UNROLL",
    "MAX_SAFE_BATCH",
    "STRATEGIES",
    "AgentState",
    "ChunkBounds",
    "ChunkHooks",
    "EngineOptions",
    "ProgressCallback",
    "RunResult",
    "agent_keys",
    "auto_strategy",
    "available_cpus",
    "broadcast_agents",
    "check_params",
    "compile_seconds",
    "default_max_batch",
    "init_agent",
    "init_agents",
    "lockstep_iteration",
    "mixes_kinds",
    "native_step_loops",
    "run_agents",
    "run_chunk",
    "start_support",
    "text_progress",
    "uniforms",
]
