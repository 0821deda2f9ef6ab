"""Grid runs: many settings × seeds through the one run path, with checkpoints and resume.

:func:`run_grid` is :func:`prepare_grid` (every check, the agents, the plan; nothing is
created or trained) followed by :func:`run_prepared` (the checkpoint, the driver, the
result). A result-folder command prepares first and creates its folder only once the
work is known to be valid (:mod:`vdbejax.studies`).

Agent ``(config c, seed i)`` uses key ``fold_in(PRNGKey(seed), i)``: the same seed index
shares its random stream across configs (common random numbers), and an agent gives
bit-identical results whether run alone or inside any grid, in any batch, on any number
of devices, resumed or not.
"""
from __future__ import annotations

import dataclasses
import hashlib
import json
import os
import warnings
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import jax
import numpy as np

from vdbejax.engine import agent_keys, broadcast_agents, check_params, text_progress
from vdbejax.engine.distributed import gather_agents, process_checkpoint_path, take_agents
from vdbejax.engine.programs import Programs
from vdbejax.envs.solvers import best_return, uniform_random_return
from vdbejax.envs.tabular import TabularMDP
from vdbejax.envs.task_instances import TaskFamily, TaskInstances
from vdbejax.methods.agents import (
    AgentOptions,
    AgentParams,
    Setting,
    agent_hyperparameters,
    make_agent,
    recorded_options,
    stack_agents,
    table_layout,
)
from vdbejax.results.folder_lock import describe_os_error, remove_stale_temporaries
from vdbejax.results.grid_result import GridResult
from vdbejax.runs.batching import check_run_size
from vdbejax.runs.checkpoint import CheckpointWriter, load_checkpoint, remove_checkpoint, writing
from vdbejax.runs.driver import drive
from vdbejax.runs.evaluation import collect_evaluations, evaluations
from vdbejax.runs.optimal_record import collect_optimal
from vdbejax.runs.options import RunOptions
from vdbejax.runs.plan import RunPlan, make_plan
from vdbejax.runs.provenance import version_info
from vdbejax.runs.run_state import RunState, nonfinite_message
from vdbejax.runs.stop import StopPolicy
from vdbejax.runs.task_family_run import (
    draw_instances,
    instance_meta,
    instance_mode,
    run_mask,
    run_task,
)
from vdbejax.validation import INT32_MAX, UINT32_MAX, check_int, check_writable_dir, json_plain


def grid_agents(settings: Sequence[Setting], num_seeds: int, seed: int = 0,
                options: AgentOptions = AgentOptions()) -> tuple[AgentParams, np.ndarray]:
    """Hyperparameters and keys of a grid's agents, config-major (c0s0, c0s1, …).

    Seed ``i`` of every setting gets the same key (common random numbers).

    Args:
      settings: the grid's settings.
      num_seeds: agents per setting.
      seed: root seed of the keys.
      options: options shared by every agent.

    Returns:
      ``(params, keys)``: batched :class:`AgentParams` and uint32 ``[agents, 2]`` keys.
    """
    params = broadcast_agents(stack_agents([make_agent(s, options) for s in settings]), num_seeds)
    return params, np.tile(agent_keys(seed, num_seeds), (len(settings), 1))


@dataclasses.dataclass(frozen=True)
class PreparedGrid:
    """A grid run checked and planned, not started (:func:`prepare_grid`).

    Attributes:
      mdp, settings, num_seeds, num_episodes, seed, options: the work.
      run: the run options.
      stop: the stop policy, resolved for the task.
      params, keys: every agent's hyperparameters and key.
      plan: devices, batches and engine strategy (:class:`~vdbejax.runs.plan.RunPlan`).
      description: what decides the results (the fingerprint's input, in ``meta.json``).
      instances: each agent's task instance (a :class:`~vdbejax.envs.task_instances.TaskFamily`
        run, :mod:`vdbejax.runs.task_family_run`; ``mdp`` is then agent 0's), else ``None``.
    """

    mdp: TabularMDP
    settings: tuple[Setting, ...]
    num_seeds: int
    num_episodes: int
    seed: int
    options: AgentOptions
    run: RunOptions
    stop: StopPolicy
    params: AgentParams
    keys: np.ndarray
    plan: RunPlan
    description: dict[str, Any]
    instances: TaskInstances | None = None

    @property
    def num_agents(self) -> int:
        return len(self.settings) * self.num_seeds

    @property
    def task_values(self) -> list[dict[str, Any]] | None:
        """Each config's resolved task values (a task family's run), else ``None``."""
        return self.description.get("task_parameters")

    @property
    def fingerprint(self) -> str:
        return _fingerprint(self.description)

    def with_checkpoint(self, path: str | os.PathLike) -> PreparedGrid:
        """The same run, checkpointed to ``path`` (its folder must exist or be creatable)."""
        run = self.run.replace(checkpoint=path)
        check_writable_dir("checkpoint folder", Path(path).parent)
        check_run_size(self.num_agents, self.num_episodes, path)  # the log's disk space
        return dataclasses.replace(self, run=run)


def prepare_grid(
    mdp: TabularMDP | TaskFamily,
    settings: Sequence[Setting],
    *,
    num_seeds: int = 20,
    num_episodes: int = 1000,
    seed: int = 0,
    options: AgentOptions = AgentOptions(),
    run: RunOptions | None = None,
) -> PreparedGrid:
    """Check a grid run and plan it, creating nothing (one-line ``ValueError`` on bad input).

    Args: as in :func:`run_grid`.

    Returns:
      the :class:`PreparedGrid` that :func:`run_prepared` trains.
    """
    run = RunOptions() if run is None else run
    if not isinstance(run, RunOptions):
        raise ValueError(f"run={run!r} is invalid: must be a RunOptions")
    # Counts and sizes end up in int32 arrays; the seed is a 32-bit key.
    num_seeds = check_int("num_seeds", num_seeds, 1, INT32_MAX)
    num_episodes = check_int("num_episodes", num_episodes, 1, INT32_MAX)
    seed = check_int("seed", seed, 0, UINT32_MAX)
    if run.evaluate_every is not None and run.evaluate_every > num_episodes:
        raise ValueError(f"evaluate_every={run.evaluate_every} is invalid with num_episodes="
                         f"{num_episodes}: must be at most the episodes (or no policy would be"
                         " evaluated)")
    if not isinstance(mdp, (TabularMDP, TaskFamily)):
        raise ValueError(f"mdp={type(mdp).__name__} is invalid: must be a TabularMDP"
                         " (see make_tabular_mdp, compile_env) or a TaskFamily")
    if not isinstance(settings, (list, tuple)):
        raise ValueError(f"settings={settings!r} is invalid: must be a list of Setting"
                         " (e.g. [Setting('qlearning', 'vdbe', 1.0)])")
    if not isinstance(options, AgentOptions):
        raise ValueError(f"options={options!r} is invalid: must be an AgentOptions"
                         " (e.g. AgentOptions(alpha=0.5))")
    settings = tuple(settings)
    if not settings:
        raise ValueError("settings is empty: need at least one setting")
    for s in settings:
        if not isinstance(s, Setting):
            raise ValueError(f"settings holds {s!r}: must hold Setting(learner, explorer, param)")
    if run.checkpoint is not None:  # fail before training
        check_writable_dir("checkpoint folder", Path(run.checkpoint).parent)
    check_run_size(len(settings) * num_seeds, num_episodes, run.checkpoint, len(settings))
    mdp, instances, task_values = draw_instances(mdp, run, seed, num_seeds, settings,
                                                 num_episodes)
    stop = run.stop.resolve(mdp)
    window = getattr(stop, "window", None)
    if stop.checks_chunks and window is not None and window > num_episodes:
        raise ValueError(f"window={window} is invalid with num_episodes={num_episodes}: no"
                         " agent could ever solve the task (a window needs that many episodes)")
    params, keys = grid_agents(settings, num_seeds, seed, options)
    # A bad plug-in: one line before anything runs; a user plug-in's code digest enters the
    # fingerprint, so that a checkpoint or a saved result of other code is never taken.
    plugin_code = check_params(params, mdp.num_actions, mdp.num_states)
    plan = make_plan(mdp, params, len(settings) * num_seeds, num_episodes, run, instances)
    description = {
        "mdp": mdp.name,
        "mdp_tables": _fingerprint_arrays(mdp if instances is None else instances),
        "settings": [(s.learner, s.explorer, s.param, s.hyperparameters) for s in settings],
        "num_seeds": num_seeds,
        "num_episodes": num_episodes,
        "seed": seed,
        "options": recorded_options(options, settings),
    }
    if stop.checks_chunks:  # a fixed budget leaves the fingerprint of earlier runs as it was
        description["stop"] = stop.describe()
    if run.evaluate_every is not None:  # its checkpoints hold evaluations: not another's
        description["evaluate_every"] = run.evaluate_every
    if task_values is not None:  # a task family's run (vdbejax.runs.task_family_run)
        description.update(instances=instance_mode(task_values), task_parameters=task_values)
    if run.record_optimal:  # its checkpoints hold the counts of optimal actions
        description["record_optimal"] = True
    if plugin_code:  # built-ins only: the fingerprint of earlier runs, as it was
        description["plugin_code"] = dict(sorted(plugin_code.items()))
    return PreparedGrid(mdp, settings, num_seeds, num_episodes, seed, options, run, stop,
                        params, keys, plan, description, instances)


def run_grid(
    mdp: TabularMDP,
    settings: Sequence[Setting],
    *,
    num_seeds: int = 20,
    num_episodes: int = 1000,
    seed: int = 0,
    options: AgentOptions = AgentOptions(),
    run: RunOptions | None = None,
    **run_options: Any,
) -> GridResult:
    """Train ``num_seeds`` agents for every setting, all in one vectorized program.

    Args:
      mdp: the task.
      settings: the configurations (e.g. :func:`~vdbejax.methods.agents.paper_settings`).
      num_seeds: agents per setting.
      num_episodes: episodes per agent (the budget, under a stop policy).
      seed: root seed.
      options: α, γ, q_init, tie-break, δ shared by all agents.
      run: how the run runs (:class:`~vdbejax.runs.RunOptions`: chunk size, progress,
        checkpoint and resume, memory budget, devices, stop policy, strategy).
      **run_options: fields of :class:`~vdbejax.runs.RunOptions` given one by one
        (``chunk_episodes=50, checkpoint="run.npz", resume=True``), applied over ``run``.

    Returns:
      :class:`~vdbejax.results.grid_result.GridResult`.

    Raises:
      ValueError: invalid settings, counts or options, or a checkpoint from a different
        run; before anything trains.
    """
    run = (RunOptions() if run is None else run).replace(**run_options)
    prepared = prepare_grid(mdp, settings, num_seeds=num_seeds, num_episodes=num_episodes,
                            seed=seed, options=options, run=run)
    return run_prepared(prepared)


def _resume_state(prepared: PreparedGrid, fingerprint: str
                  ) -> tuple[RunState | None, CheckpointWriter | None]:
    """The state to resume from (None: fresh) and the after-chunk checkpoint writer."""
    run = prepared.run
    if run.checkpoint is None:
        return None, None
    path = process_checkpoint_path(run.checkpoint)
    remove_stale_temporaries(path.parent)  # what killed writers left (vdbejax.results.folder_lock)
    shape = (len(prepared.plan.rows), prepared.num_episodes)
    if run.resume and path.exists():
        state, log_bytes, log_id = load_checkpoint(path, fingerprint, shape, prepared.mdp,
                                                   table_layout(prepared.params),
                                                   prepared.keys[prepared.plan.rows],
                                                   evaluations(prepared.num_episodes, run),
                                                   run.record_optimal)
        return state, CheckpointWriter(path, fingerprint, state, log_bytes, log_id)
    remove_checkpoint(path)  # a fresh run: an older checkpoint must not outlive its log
    return None, CheckpointWriter(path, fingerprint)


def run_prepared(prepared: PreparedGrid, programs: Programs | None = None) -> GridResult:
    """Train a :class:`PreparedGrid` and collect its :class:`GridResult`.

    Args:
      prepared: the run (:func:`prepare_grid`).
      programs: compiled programs shared with other runs of one study (default: the
        run's own).
    """
    plan, run = prepared.plan, prepared.run
    fingerprint = prepared.fingerprint
    # A process's checkpoint holds its share only: tie it to the process layout.
    checkpoint_fingerprint = fingerprint if jax.process_count() == 1 else _fingerprint(
        dict(prepared.description, process=[jax.process_index(), jax.process_count()]))
    state, writer = _resume_state(prepared, checkpoint_fingerprint)
    state = (RunState.fresh(len(plan.rows), prepared.num_episodes, run.evaluate_every,
                            run.record_optimal) if state is None else state)
    resumed_from = int(state.episodes_done.sum())
    progress = text_progress() if run.progress is True else (run.progress or None)
    mask = (run_mask(prepared.mdp, prepared.instances, prepared.task_values,
                     prepared.num_seeds, plan.rows) if run.record_optimal else None)
    with writing(writer):  # closed at the end; a Ctrl-C names the checkpoint
        done = drive(run_task(prepared.mdp, prepared.instances, plan.rows),
                     take_agents(prepared.params, plan.rows),
                     prepared.keys[plan.rows], plan, state, prepared.stop,
                     checkpoint=None if writer is None else _failing_quietly(writer),
                     progress=progress, programs=programs, evaluate_every=run.evaluate_every,
                     optimal_action=mask)
    return _collect(prepared, state, fingerprint, resumed_from, done)


def _failing_quietly(writer: CheckpointWriter) -> Callable[[RunState], None]:
    """The checkpoint stage: a checkpoint that cannot be written (disk full) stops the
    checkpoints, not the run (what it computes is saved at its end, or kept elsewhere)."""
    failed: list[OSError] = []

    def write(state: RunState) -> None:
        if failed:
            return
        try:
            writer(state)
        except OSError as error:
            failed.append(error)
            warnings.warn(f"checkpoint {str(writer.path)!r} cannot be written"
                          f" ({describe_os_error(error)}): the run goes on without checkpoints",
                          RuntimeWarning, stacklevel=2)

    return write


def _collect(prepared: PreparedGrid, state: RunState, fingerprint: str, resumed_from: int,
             done: Any) -> GridResult:
    """The :class:`GridResult` of a finished run (every process's agents gathered)."""
    settings, options, mdp = list(prepared.settings), prepared.options, prepared.mdp
    num_agents = prepared.num_agents
    shape = (len(settings), prepared.num_seeds, prepared.num_episodes)
    # [agents, episodes] → [configs, seeds, episodes]; per agent → [configs, seeds].
    returns, lengths, cut, nonfinite, episodes_run = (
        gather_agents(array, num_agents).reshape(shape[: array.ndim + 1])
        for array in (state.returns, state.lengths, state.cut, state.nonfinite,
                      state.episodes_done))
    stopped_early = bool((episodes_run < prepared.num_episodes).any())
    if stopped_early:
        past = np.arange(prepared.num_episodes) >= episodes_run[..., None]
        returns = np.where(past, np.float32(np.nan), returns)
    message = nonfinite_message(settings, nonfinite, options)
    if message:
        warnings.warn(message, RuntimeWarning, stacklevel=3)
    meta = dict(prepared.description, fingerprint=fingerprint,
                elapsed_seconds=done.elapsed_seconds, resumed_from_agent_episodes=resumed_from,
                max_steps=int(mdp.max_steps), nonfinite_agents=int(nonfinite.sum()),
                nonfinite_message=message, plan=prepared.plan.describe(),
                devices=len(prepared.plan.devices), processes=jax.process_count(),
                batches=done.batches, agents_per_batch=prepared.plan.batch_size,
                memory_budget_bytes=int(prepared.plan.memory_budget_bytes),
                strategy=done.strategy, stop=prepared.stop.describe(), stopped=done.stopped,
                jax_version=jax.__version__, backend=jax.default_backend(), **version_info())
    meta.pop("mdp_tables")
    ran = lengths[lengths > 0]
    meta["longest_episode"] = int(ran.max()) if ran.size else 0
    # Episodes the step limit cut (on a task without a step limit: its safety cap), as the
    # engine recorded them; an episode whose last allowed step ended it on its own is not one.
    # best and random returns: the references of the summary's convergence episode
    meta.update(truncated_episodes=int(cut.sum()),
                agents_truncated=int(cut.any(axis=2).sum()),
                truncated_episodes_by_config=cut.sum(axis=(1, 2)).tolist(),
                hyperparameters=[agent_hyperparameters(make_agent(s, options)) for s in settings],
                parameter_names={s.explorer: s.parameter for s in settings},
                best_return=best_return(mdp), random_return=uniform_random_return(mdp))
    if prepared.instances is not None and prepared.task_values is not None:  # per instance
        meta.update(instance_meta(prepared.instances, prepared.num_seeds, prepared.task_values))
    policy_values = collect_evaluations(state, mdp, prepared.run, shape, meta)
    return GridResult(settings, returns, lengths, nonfinite, meta,
                      episodes_run.astype(np.int64) if stopped_early else None, policy_values,
                      collect_optimal(state, shape), cut)


def _fingerprint(description: dict[str, Any]) -> str:
    text = json.dumps(description, sort_keys=True, default=json_plain)  # NumPy scalars too
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def _fingerprint_arrays(mdp: TabularMDP | TaskInstances) -> str:
    digest = hashlib.sha256()
    for leaf in jax.tree.leaves(mdp):
        digest.update(np.asarray(leaf).tobytes())
    return digest.hexdigest()[:16]
