"""The chunk driver: :func:`run_agents` trains a batch of agents chunk by chunk.

PureJaxRL-style, the jitted programs of a strategy (:mod:`~vdbejax.engine.sequential` on a
CPU, :mod:`~vdbejax.engine.lockstep` elsewhere) advance every agent to the end of a chunk
of episodes; between chunks this Python loop reports progress and hands the state to
``on_chunk`` (checkpoints). An agent's state at a chunk boundary is the same whatever the
chunk size, so results do not depend on it.
"""
from __future__ import annotations

import dataclasses
import os
import time
from collections.abc import Callable, Generator
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from vdbejax.engine.agent_on_task import instance_template, with_instance_masks, with_instances
from vdbejax.engine.agent_state import AgentState, for_task, init_agents
from vdbejax.engine.chunks import ChunkSchedule, Piece
from vdbejax.engine.lockstep import DEFAULT_UNROLL, LockstepOptions, run_chunk_lockstep
from vdbejax.engine.programs import Programs
from vdbejax.engine.programs import compile_seconds as _compile_seconds
from vdbejax.engine.progress import ProgressCallback
from vdbejax.engine.rules import auto_strategy, default_max_batch, mixes_kinds
from vdbejax.engine.sequential import CHUNK_STEPS, SequentialRun
from vdbejax.engine.work_items import created_in_items, next_power_of_two
from vdbejax.envs.tabular import TabularMDP
from vdbejax.envs.task_instances import TaskInstances
from vdbejax.methods.agents import AgentParams
from vdbejax.methods.plugin_check import check_plugin
from vdbejax.validation import check_choice, check_int

Array = jax.Array

#: Engine strategies of :func:`run_agents`.
STRATEGIES = ("sequential", "lockstep")

#: A piece of a chunk that ends before its agents finished it (:attr:`EngineOptions.chunk_steps`)
#: is handed to ``on_chunk`` (a checkpoint) once this many seconds have passed since the
#: last hand-out: a stop then loses at most about this much work, and a piece of a few
#: milliseconds (one agent: 10⁶ steps in ≈ 25 ms) does not pay a checkpoint each.
PIECE_SECONDS = 1.0


@dataclasses.dataclass
class RunResult:
    """Output of :func:`run_agents`.

    Attributes:
      returns: float32 ``[agents, episodes]`` undiscounted episode returns.
      lengths: int32 ``[agents, episodes]`` episode lengths (steps).
      cut: bool ``[agents, episodes]``: the step limit ended the episode (its
        ``max_steps``-th step was not terminal; an episode whose last allowed step ended
        it on its own is not cut).
      nonfinite: bool ``[agents]``: a NaN or inf appeared in the agent's Q or ε.
      iterations: lockstep iterations executed; for the sequential strategy, the agents'
        own iterations (steps, plus one per episode start after a truncation).
      final_state: the agents' states after the last episode (numpy leaves; ``None``
        with :attr:`EngineOptions.keep_final_state` ``False``).
      lane_iterations: Σ over executed loop iterations of the batch width (the
        agent-iterations paid for, idle lanes included; lower with compaction).
      strategy: the strategy that ran (``"sequential"`` or ``"lockstep"``; the last one
        if the sequential strategy fell back, see :func:`native_step_loops`).
      optimal: int32 ``[agents, episodes]`` each episode's steps whose action is optimal
        (with ``optimal_action``), else ``None``.
    """

    returns: np.ndarray
    lengths: np.ndarray
    cut: np.ndarray
    nonfinite: np.ndarray
    iterations: int
    final_state: AgentState | None
    lane_iterations: int = 0
    strategy: str = "lockstep"
    optimal: np.ndarray | None = None


@dataclasses.dataclass(frozen=True)
class EngineOptions:
    """How :func:`run_agents` runs its agents. None of it changes a result, only the speed
    (as long as ``max_batch`` ≤ :data:`~vdbejax.engine.lockstep.MAX_SAFE_BATCH`; on a CPU,
    the default) and what the result keeps (``keep_final_state``). ``None`` leaves a choice
    to the backend (:mod:`~vdbejax.engine.rules`). A bad value fails here, in one line.

    Attributes:
      strategy: ``"sequential"`` (native step loops of a few agents side by side; agents are
        spread over ``threads`` threads; the fast choice on CPU), ``"lockstep"`` (all
        agents of a batch advance together, one vectorised step per iteration, with
        compaction and groups as below; for accelerators, sharded agents and large
        batches), or ``"auto"`` (:func:`~vdbejax.engine.rules.auto_strategy`).
      threads: worker threads on a CPU (default: the CPUs this process may use): the
        sequential strategy's work items, or the lockstep strategy's groups, run on them.
      chunk_episodes: episodes per jitted chunk (progress/checkpoint granularity; the
        results do not depend on it).
      chunk_seconds: size chunks by time: about this many seconds each, every multiple
        of ``chunk_episodes`` still a chunk end (:mod:`~vdbejax.engine.chunks`; a stop
        waits for the chunk that runs). None: chunks of ``chunk_episodes``.
      chunk_steps: chunks are bounded by steps as well as episodes: the sequential
        strategy's native calls stop after this many loop iterations (a loop runs a few
        agents side by side), the lockstep strategy's groups after the block (without
        ``compact``: the loop trip) in which they reach this many iterations, or on an
        accelerator after the block that passes :data:`PIECE_SECONDS`, each agent where
        it stands, mid-episode if need be. A chunk that needs more (very long episodes)
        is run in pieces: ``on_chunk`` gets each piece (:class:`ChunkHooks`), so a
        checkpoint may fall mid-episode, and a stop waits for one call, not for the
        chunk. The results do not depend on it.
      compact: between blocks of ``block_iterations`` lockstep iterations, gather the
        still-active agents into a smaller power-of-two batch (at least ``min_batch``
        lanes) once at most half the lanes are active, so finished agents stop costing
        work.
      block_iterations: lockstep iterations between compaction checks.
      unroll: lockstep iterations per loop trip.
      min_batch: smallest batch (lanes) compaction shrinks to.
      max_batch: lanes of a lockstep batch (larger groups of agents stream through it;
        default :func:`~vdbejax.engine.rules.default_max_batch`:
        :data:`~vdbejax.engine.lockstep.MAX_SAFE_BATCH` on a CPU, every agent of a group
        on an accelerator).
      fixed_blocks: the lockstep strategy's blocks are exactly ``block_iterations``
        iterations, loops of known trip count (default: on accelerators, where a loop
        condition that depends on the data costs a round trip to the host per
        iteration; on a CPU the condition is free and a block stops when its lanes do).
      mix_kinds: the lockstep strategy runs agents of several kinds in one batch, each
        lane its own kind (:func:`~vdbejax.engine.rules.mixes_kinds`: default on
        accelerators), instead of kind after kind.
      keep_final_state: ``False`` leaves :attr:`RunResult.final_state` ``None``, which
        spares gathering every agent's tables on the host at the end (large tasks).
      programs: the compiled programs to share with other calls of one study
        (:class:`~vdbejax.engine.programs.Programs`; default: the call's own; either
        way a program traced before in this process for the same plug-in code is reused).
    """

    strategy: str = "auto"
    threads: int | None = None
    chunk_episodes: int = 100
    chunk_seconds: float | None = None
    chunk_steps: int = CHUNK_STEPS
    compact: bool = True
    block_iterations: int = 256
    unroll: int = DEFAULT_UNROLL
    min_batch: int = 8
    max_batch: int | None = None
    fixed_blocks: bool | None = None
    mix_kinds: bool | None = None
    keep_final_state: bool = True
    programs: Programs | None = None

    def __post_init__(self) -> None:
        check_int("chunk_episodes", self.chunk_episodes, 1)
        check_int("block_iterations", self.block_iterations, 1)
        check_int("chunk_steps", self.chunk_steps, 1, 2**31 - 1)
        check_int("unroll", self.unroll, 1)
        check_int("min_batch", self.min_batch, 1)
        if self.max_batch is not None:
            check_int("max_batch", self.max_batch, 1)
        check_choice("strategy", self.strategy, (*STRATEGIES, "auto"))
        if self.threads is not None:
            check_int("threads", self.threads, 1)


@dataclasses.dataclass(frozen=True)
class ChunkHooks:
    """What :func:`run_agents` calls between its chunks.

    Attributes:
      progress: called as ``progress(done_agent_episodes, total, elapsed_seconds)`` at the
        start and after each chunk.
      on_chunk: called after each chunk with ``(episodes_done, agents, returns, lengths,
        cut)`` (numpy arrays covering episodes ``[0, episodes_done)``, see
        :class:`RunResult`), and ``optimal`` after them with ``optimal_action``; used for
        checkpoints. After a piece of a chunk that ended before its agents finished it
        (:attr:`EngineOptions.chunk_steps`), ``episodes_done`` is each agent's (int64
        ``[agents]``), the arrays cover the episodes up to the latest running one, and
        ``agents`` are the agents where they stand (mid-episode: their state, step
        count, partial return, random-stream position and pending reset; the running
        episodes' counts of optimal actions so far are in ``optimal``).
      chunk_states: ``False`` hands ``on_chunk`` ``None`` for the agents (no copy of
        every agent's tables after each chunk, when only the episodes are wanted).
      pieces_only: ``on_chunk`` only after the pieces that end mid-chunk, not at a
        chunk's end (a caller that takes each chunk's end from the result: one call
        per chunk, as a stop policy's driver makes).
    """

    progress: ProgressCallback | None = None
    on_chunk: Callable[..., None] | None = None
    chunk_states: bool = True
    pieces_only: bool = False


def run_agents(
    mdp: TabularMDP | TaskInstances,
    params: AgentParams,
    keys: Any,
    num_episodes: int,
    options: EngineOptions = EngineOptions(),
    hooks: ChunkHooks = ChunkHooks(),
    *,
    initial: tuple[Any, ...] | None = None,
    optimal_action: Any | None = None,
) -> RunResult:
    """Train a batch of agents for ``num_episodes`` episodes each.

    Args:
      mdp: the task, or a :class:`~vdbejax.envs.task_instances.TaskInstances` (one instance per
        agent, in agent order: each agent's results are those of the agent alone on its
        instance, in any batch, under either strategy).
      params: batched hyperparameters, leading axis = agents.
      keys: uint32 ``[agents, 2]`` PRNG keys.
      num_episodes: episodes per agent.
      options: how the agents run (:class:`EngineOptions`: strategy, threads, chunks,
        batches; none changes a result).
      hooks: what is called between chunks (:class:`ChunkHooks`: progress, checkpoints).
      initial: resume from ``(episodes_done, agents, returns, lengths, cut)`` (and
        ``optimal`` after them with ``optimal_action``): what ``on_chunk`` was given
        (``episodes_done`` an int or one per agent; the arrays cover at least each
        agent's episodes done).
      optimal_action: bool ``[S, A]`` (``[agents, S, A]`` with instances), the actions
        that count as optimal: each episode's steps taking one are counted
        (:attr:`RunResult.optimal`). ``None`` (default):
        no count, the same programs and results as without it.

    Every kind's learner is first set for the task (:func:`~vdbejax.engine.agent_state.for_task`:
    the facts of ``mdp`` a method's convention depends on).

    Returns:
      :class:`RunResult`.
    """
    check_int("num_episodes", num_episodes, 1)
    check_params(params, mdp.num_actions)
    if isinstance(mdp, TaskInstances):  # each agent's instance rides with its params
        instances = with_instance_masks(mdp, optimal_action)
        params = with_instances(for_task(params, instances), instances)
        mdp = instance_template(instances, optimal_action)
    else:
        params = for_task(params, mdp)
        mdp = with_optimal_action(mdp, optimal_action)
    threads = available_cpus() if options.threads is None else options.threads
    num_agents = int(np.shape(keys)[0])
    strategy = options.strategy
    if strategy == "auto":
        strategy, _ = auto_strategy(num_agents, sharded=_is_sharded(params, keys))
    keys = jnp.asarray(keys, jnp.uint32)
    chunk = min(options.chunk_episodes, num_episodes)
    buffer = chunk_buffer_length(chunk)
    returns = np.zeros((num_agents, num_episodes), np.float32)
    lengths = np.zeros((num_agents, num_episodes), np.int32)
    cut = np.zeros((num_agents, num_episodes), bool)
    optimal = None if optimal_action is None else np.zeros_like(lengths)
    programs = Programs() if options.programs is None else options.programs
    agents: AgentState | None
    if initial is None:
        done = np.zeros(num_agents, np.int64)
        agents = None  # created by the sequential strategy in its work items
        if strategy != "sequential" or not created_in_items(mdp, params):
            agents = programs.get(init_agents, (mdp, params, keys))(mdp, params, keys)
    else:
        agents = jax.tree.map(jnp.asarray, initial[1])
        done = np.broadcast_to(np.asarray(initial[0], np.int64), (num_agents,)).copy()
        for array, given in zip((returns, lengths, cut, optimal), initial[2:], strict=False):
            if array is not None:  # (an agent may be past this call's episodes: a stop
                # policy's chunk resumed from a checkpoint taken before its end)
                array[:, : given.shape[1]] = given[:, :num_episodes]
    iterations = lane_iterations = 0
    started = time.perf_counter()
    progress, on_chunk = hooks.progress, hooks.on_chunk
    if progress:
        progress(int(done.sum()), num_episodes * num_agents, 0.0)
    # The sequential strategy keeps the agents' state in its work items; ``agents`` is
    # the state only while the lockstep strategy runs.
    sequential = None
    if strategy == "sequential":
        sequential = SequentialRun(mdp, params, agents, keys, threads, programs,
                                   options.chunk_steps)

    def current_agents() -> AgentState:
        if sequential is not None:
            return sequential.agents()
        assert agents is not None  # created above unless the sequential strategy holds them
        return agents

    # The first chunk starts at the agent that has done the fewest episodes (a run resumed
    # from a checkpoint taken mid-chunk: the others wait, or go on, where they stand).
    bounds = ChunkSchedule(int(done.min(initial=num_episodes)), num_episodes, chunk,
                           options.chunk_seconds)
    if sequential is not None and bounds.exists(0) and not sequential.prepare(buffer):
        # not compiled natively: lockstep is faster
        strategy, agents, sequential = "lockstep", sequential.agents(), None

    def lockstep_chunks() -> Generator[Piece, None, None]:
        nonlocal agents
        assert agents is not None  # lockstep: the agents' state is here
        lockstep = _lockstep_options(options, threads, agents, params, buffer)
        for c, (first, end) in enumerate(bounds):
            finished = False
            while not finished:  # pieces of about chunk_steps iterations a group
                (agents, piece_returns, piece_lengths, piece_cut, piece_optimal,
                 piece_iterations, piece_lanes) = run_chunk_lockstep(
                    mdp, params, agents, first, end, buffer, lockstep, programs)
                episodes = np.asarray(agents.episode).astype(np.int64)
                finished = bool(episodes.min(initial=end) >= end)
                yield Piece(c=c, first=first, end=end, returns=piece_returns,
                            lengths=piece_lengths, cut=piece_cut, optimal=piece_optimal,
                            iterations=piece_iterations, lanes=piece_lanes,
                            episodes=episodes, finished=finished)

    # The sequential strategy runs the next chunk while this loop stores one; a checkpoint
    # then gets the copies each work item takes at the chunk's end, unless the agents are
    # large (a second copy of every table): those wait at each chunk's end instead.
    # With ``pieces_only`` (one chunk a call, as a rule) no chunk waits to be handed out:
    # the items wait at each piece's end instead of copying their states after each call.
    states = on_chunk is not None and hooks.chunk_states
    wait = states and (created_in_items(mdp, params) or hooks.pieces_only)
    chunks = (lockstep_chunks() if sequential is None else
              sequential.run_chunks(bounds, buffer, ahead=0 if wait else 1,
                                    snapshots=states and not wait))
    bounds.start()
    handed = time.perf_counter()  # when on_chunk was last called
    try:
        for piece in chunks:
            first, end, width = piece.first, piece.end, piece.end - piece.first
            # Each piece records the episodes its agents finished (length ≥ 1) and counts
            # the optimal actions of its steps: an episode that spans pieces (or a resumed
            # run's checkpoint) counts its steps in each.
            ran = np.asarray(piece.lengths)[:, :width] > 0
            for array, part in ((returns, piece.returns), (lengths, piece.lengths),
                                (cut, piece.cut)):
                array[:, first:end] = np.where(ran, np.asarray(part)[:, :width],
                                               array[:, first:end])
            if optimal is not None:
                optimal[:, first:end] += np.asarray(piece.optimal)[:, :width]
            iterations += piece.iterations
            lane_iterations += piece.lanes
            done = piece.episodes
            if piece.finished:
                bounds.received(piece.c)
            if on_chunk and (not hooks.pieces_only if piece.finished
                             else time.perf_counter() - handed >= PIECE_SECONDS):
                # A whole chunk: its end; a piece: each agent's episodes done, the records
                # to the running episodes (their counts of optimal actions so far).
                upto = end if piece.finished else min(int(done.max()) + 1, num_episodes)
                on_chunk(end if piece.finished else done.copy(),
                         current_agents() if states else None, returns[:, :upto],
                         lengths[:, :upto], cut[:, :upto],
                         *(() if optimal is None else (optimal[:, :upto],)))
                handed = time.perf_counter()
            if progress:
                progress(int(done.sum()), num_episodes * num_agents,
                         time.perf_counter() - started)
            if piece.finished:
                bounds.handled(piece.c)
    finally:  # the workers stop (and none is left running) whatever happens here
        chunks.close()
    if options.keep_final_state:
        final = jax.tree.map(np.asarray, current_agents())
        nonfinite = np.asarray(final.nonfinite)
    else:  # the flags alone: no tables gathered
        final = None
        if sequential is None:
            assert agents is not None  # lockstep: the agents' state is here
            nonfinite = np.asarray(agents.nonfinite)
        else:
            nonfinite = sequential.nonfinite_flags()
    return RunResult(returns, lengths, cut, nonfinite, iterations, final, lane_iterations,
                     strategy, optimal)


def _lockstep_options(options: EngineOptions, threads: int, agents: AgentState,
                      params: AgentParams, buffer: int) -> LockstepOptions:
    """``options`` as the lockstep strategy runs them on this backend: each choice left to
    the backend made (:mod:`~vdbejax.engine.rules`), one thread on an accelerator."""
    backend = jax.default_backend()
    on_cpu = backend == "cpu"
    return LockstepOptions(
        compact=options.compact, block_iterations=options.block_iterations,
        unroll=options.unroll, min_batch=options.min_batch,
        max_batch=(default_max_batch(agents, params, buffer, backend)
                   if options.max_batch is None else options.max_batch),
        threads=threads if on_cpu else 1,
        fixed_blocks=not on_cpu if options.fixed_blocks is None else options.fixed_blocks,
        mix_kinds=mixes_kinds(backend) if options.mix_kinds is None else options.mix_kinds,
        chunk_steps=options.chunk_steps,
        # On a CPU a piece's iterations bound its time (and keep the iterations counted
        # the same from run to run); on an accelerator an iteration of a large batch may
        # take milliseconds, so a piece also ends after the block that passes a second.
        piece_seconds=None if on_cpu else PIECE_SECONDS)


def with_optimal_action(mdp: TabularMDP, optimal_action: Any | None) -> TabularMDP:
    """``mdp`` carrying the mask of optimal actions its steps are counted against
    (:attr:`~vdbejax.envs.tabular.TabularMDP.optimal_action`), or as it is for ``None``.

    Raises:
      ValueError: a mask that is not ``[S, A]`` or not boolean.
    """
    if optimal_action is None:
        return mdp
    mask = np.asarray(optimal_action)
    if mask.shape != (mdp.num_states, mdp.num_actions) or mask.dtype != np.bool_:
        raise ValueError(f"optimal_action has shape {mask.shape} and dtype {mask.dtype}: must"
                         f" be bool [{mdp.num_states}, {mdp.num_actions}] (states, actions)")
    return dataclasses.replace(mdp, optimal_action=jax.device_put(mask))


def chunk_buffer_length(chunk_episodes: int) -> int:
    """The episodes a chunk's programs hold buffers for: ``chunk_episodes`` rounded up to
    a power of two, at least 8. The buffer's length is part of a program's shapes, so runs
    of 5, 6 or 8 episodes (or chunks of 90 and 100) share one program instead of
    compiling one each; episodes past the chunk's end stay unwritten."""
    return max(8, next_power_of_two(int(chunk_episodes)))


def available_cpus() -> int:
    """CPUs this process may run on (its affinity mask where the OS has one)."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        return os.cpu_count() or 1


def _is_sharded(params: AgentParams, keys: Any) -> bool:
    for leaf in jax.tree.leaves((params, keys)):
        sharding = getattr(leaf, "sharding", None)
        if sharding is not None and len(sharding.device_set) > 1:
            return True
    return False


def compile_seconds() -> float:
    """Seconds this process spent getting the engine's programs (tracing, lowering and
    compiling them, or reading them from a cache; see :mod:`vdbejax.engine.programs`)."""
    return _compile_seconds()


def check_params(params: Any, num_actions: int,
                 num_states: int | None = None) -> dict[str, str]:
    """Check a batch's hyperparameters: an :class:`AgentParams` whose every kind's
    plug-ins trace on one agent (:func:`~vdbejax.methods.plugin_check.check_plugin`; with
    ``num_states``, their initial Q has the task's shape).

    Returns:
      ``{"learner/explorer": digest}`` of every kind with a user plug-in (its traced
      programs, :func:`~vdbejax.methods.plugin_check.check_plugin`); built-ins are the package's.
    """
    if not isinstance(params, AgentParams):
        raise ValueError(f"params={type(params).__name__} is invalid: must be an AgentParams"
                         " (see vdbejax.methods.stack_agents)")
    digests: dict[str, str] = {}
    for agent in params.kinds:
        builtin = all(type(p).__module__.startswith("vdbejax.")
                      for p in (agent.learner, agent.explorer))
        if builtin:
            continue
        # Checked at every call, not remembered: a plug-in edited or patched since its
        # last check is checked as it is now (a trace on one agent: milliseconds).
        one = jax.tree.map(lambda leaf: np.asarray(leaf)[0], agent)
        digests[f"{one.learner.name}/{one.explorer.name}"] = check_plugin(
            one.learner, one.explorer, num_actions, num_states)
    return digests
