"""The run driver: every run's one loop over batches and chunks.

:func:`drive` takes the next batch of unfinished agents (:meth:`RunState.next_batch`),
runs it through the engine (:meth:`RunPlan.run_engine`: sharded when the plan says so),
and after every chunk applies the run's stages, in this order:

1. **record** the chunk's episodes (and, when a checkpoint needs them, the agents'
   states) in the one :class:`~vdbejax.runs.run_state.RunState`, and after every
   ``evaluate_every``-th episode the value of each agent's greedy policy
   (:mod:`vdbejax.runs.evaluation`);
2. **stop**: the stop policy retires agents (:mod:`vdbejax.runs.stop`; a fixed budget
   retires none, so its batches run to the end in one engine call);
3. **checkpoint** the state (:class:`~vdbejax.runs.checkpoint.CheckpointWriter`);
4. **progress**: ``progress(done, total, elapsed)`` in agent-episodes.

Resuming is starting from a state loaded from the checkpoint: the loop is the same.
"""
from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable

import numpy as np

from vdbejax import _interrupts as interrupts
from vdbejax.engine import AgentState, ChunkHooks
from vdbejax.engine.distributed import take_agents
from vdbejax.engine.programs import Programs
from vdbejax.engine.progress import ProgressCallback
from vdbejax.envs.tabular import TabularMDP
from vdbejax.envs.task_instances import TaskInstances
from vdbejax.methods.agents import AgentParams
from vdbejax.runs.evaluation import greedy_returns
from vdbejax.runs.plan import RunPlan
from vdbejax.runs.run_state import RunState
from vdbejax.runs.stop import StopPolicy


@dataclasses.dataclass
class Drive:
    """What :func:`drive` did.

    Attributes:
      batches: engine calls made.
      elapsed_seconds: wall clock of the loop.
      stopped: ``"solved"`` (the stop policy retired every agent), ``"seconds"`` (its
        wall-clock budget ran out) or ``"episodes"`` (some agent ran the whole budget).
      strategy: the engine strategy that ran last (the sequential one falls back to
        lockstep where its loop would not compile natively).
    """

    batches: int
    elapsed_seconds: float
    stopped: str
    strategy: str


def drive(mdp: TabularMDP | TaskInstances, params: AgentParams, keys: np.ndarray, plan: RunPlan,
          state: RunState, stop: StopPolicy, *,
          checkpoint: Callable[[RunState], None] | None = None,
          progress: ProgressCallback | None = None,
          programs: Programs | None = None,
          evaluate_every: int | None = None,
          optimal_action: np.ndarray | None = None) -> Drive:
    """Train the unfinished agents of ``state`` (rows of ``params`` and ``keys``).

    Args:
      mdp: the task, or each agent's instance (this process's rows; no ``evaluate_every``).
      params, keys: every agent's hyperparameters and key (this process's rows).
      plan: devices, batch size and engine strategy (:func:`~vdbejax.runs.plan.make_plan`).
      state: the run so far (fresh, or loaded from a checkpoint); updated in place.
      stop: the stop policy (resolved for ``mdp``).
      checkpoint: called with the state after every chunk.
      progress: called after every chunk.
      programs: the compiled programs shared by every engine call (default: the run's own).
      evaluate_every: evaluate the agents' greedy policies after every this many episodes
        into ``state.policy_values`` (the plan's chunks end on its multiples).
      optimal_action: bool ``[S, A]`` (``[agents, S, A]`` with instances, this process's
        rows): count each episode's optimal actions into
        ``state.optimal`` (:mod:`vdbejax.runs.optimal_record`).

    Returns:
      :class:`Drive`.
    """
    programs = Programs() if programs is None else programs
    num_episodes = state.num_episodes
    total = state.returns.shape[0] * num_episodes
    started = time.perf_counter()
    batches, timed_out, strategy = 0, False, plan.strategy

    def report() -> None:
        if progress is not None:
            progress(state.episodes_credited(), total, time.perf_counter() - started)

    def after_stop() -> None:  # the stages that follow the stop policy's decision
        if checkpoint is not None:
            checkpoint(state)
        report()
        interrupts.raise_pending()  # a Ctrl-C or SIGTERM swallowed during the chunk

    def evaluate(batch: np.ndarray, done: int, agents: AgentState | None) -> None:
        if evaluate_every is None or done % evaluate_every:
            return
        assert agents is not None and state.policy_values is not None  # asked for below
        assert isinstance(mdp, TabularMDP)  # (prepare_grid refuses evaluations with instances)
        state.policy_values[batch, done // evaluate_every - 1] = greedy_returns(
            mdp, take_agents(params, batch), agents.q, agents.tables, agents.episode)

    report()
    per_chunk = stop.checks_chunks
    chunk = plan.chunk_episodes
    while (batch := state.next_batch(plan.batch_size, chunk if per_chunk else None)).size:
        # A fixed budget runs the batch to its end in one call, the stages after every
        # chunk; a policy that checks chunks gets one call per chunk (multiples of
        # ``chunk`` end them; an agent resumed from a checkpoint taken mid-chunk finishes
        # it with the others) and the stages after it.
        if per_chunk:
            start = state.chunk_start(batch, chunk)
            end = min(start + chunk, num_episodes)
        else:
            start, end = int(state.episodes_done[batch].min()), num_episodes
        recorded = [start]

        def after_chunk(done: int | np.ndarray, agents: AgentState | None,
                        *episodes: np.ndarray, batch: np.ndarray = batch,
                        recorded: list[int] = recorded) -> None:
            # episodes: returns, lengths, cut (and optimal-action counts) up to ``done``, or
            # after a piece of a chunk (``done`` per agent) up to the latest running episode
            first = recorded[0]
            state.add_episodes(batch, first, done, tuple(array[:, first:] for array in episodes))
            recorded[0] = int(np.min(done))
            if np.ndim(done) == 0:  # a chunk's end (a piece ends mid-chunk: no evaluation)
                evaluate(batch, int(done), agents)
            if agents is not None and checkpoint is not None:
                state.set_agents(batch, agents)
            after_stop()  # a fixed budget stops no agent; a piece ends before any stop

        result = plan.run_engine(
            mdp.take(batch) if isinstance(mdp, TaskInstances) else mdp,
            take_agents(params, batch), keys[batch], end,
            initial=state.resume_point(batch),
            hooks=ChunkHooks(on_chunk=after_chunk, pieces_only=per_chunk,
                             chunk_states=checkpoint is not None or evaluate_every is not None),
            keep_final_state=end < num_episodes or (per_chunk and evaluate_every is not None),
            programs=programs, optimal_action=optimal_action if optimal_action is None
            or optimal_action.ndim == 2 else optimal_action[batch])
        batches += 1
        strategy = result.strategy
        if per_chunk:
            state.add_episodes(batch, start, end, tuple(
                array[:, start:end] for array in (result.returns, result.lengths, result.cut,
                                                  result.optimal) if array is not None))
            evaluate(batch, end, result.final_state)
        state.set_agents(batch, result.final_state, nonfinite=result.nonfinite)
        if per_chunk:
            state.stop(batch[stop.newly_stopped(state.returns, batch, start, end)])
            if stop.out_of_time(time.perf_counter() - started) and not state.finished.all():
                state.stop(np.flatnonzero(~state.finished))
                timed_out = True
            after_stop()
        del result  # the batch's states are in ``state``: free the engine's copies
    reached = bool(((state.episodes_done >= num_episodes) & ~state.stopped).any())
    stopped = "seconds" if timed_out else ("episodes" if reached or not stop.checks_chunks
                                           else "solved")
    return Drive(batches, time.perf_counter() - started, stopped, strategy)
