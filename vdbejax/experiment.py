"""Grid runs: many settings × seeds through the engine, with checkpoints and resume.

PureJaxRL-style: the jitted engine advances all agents one chunk of episodes at a time,
sharded over every device (:mod:`vdbejax.distributed`) and in sequential batches when they
do not fit the memory budget (:mod:`vdbejax.batching`); after every chunk this module
atomically writes a checkpoint from which ``resume=True`` continues bit-identically.
"""
from __future__ import annotations

import dataclasses
import functools
import hashlib
import json
import os
import platform
import subprocess
import time
import warnings
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import jax
import numpy as np

from vdbejax import io
from vdbejax.batching import (
    SweepProgress,
    agents_per_batch,
    bytes_per_agent,
    check_run_size,
    default_memory_budget,
    mdp_bytes,
    run_batched,
)
from vdbejax.checkpoint import CheckpointWriter, load_checkpoint, remove_checkpoint
from vdbejax.distributed import (
    gather_agents,
    local_devices,
    process_checkpoint_path,
    process_share,
    select_devices,
    take_agents,
)
from vdbejax.engine import (
    ProgressCallback,
    agent_keys,
    broadcast_agents,
    check_params,
    text_progress,
)
from vdbejax.envs.tabular import TabularMDP
from vdbejax.methods.agents import (
    AgentOptions,
    AgentParams,
    Setting,
    agent_hyperparameters,
    make_agent,
    parameter_name,
    remember_parameter_names,
    stack_agents,
    table_layout,
)
from vdbejax.result_folder import remove_stale_temporaries
from vdbejax.validation import (
    INT32_MAX,
    UINT32_MAX,
    check_bool,
    check_int,
    check_writable_dir,
    parse_bytes,
)


@dataclasses.dataclass
class GridResult:
    """Learning curves of a grid.

    Attributes:
      settings: the configurations, in config-index order.
      returns: float32 ``[configs, seeds, episodes]`` episode returns.
      lengths: int32 ``[configs, seeds, episodes]`` episode lengths.
      nonfinite: bool ``[configs, seeds]``: NaN/inf appeared in that agent's Q or ε.
      meta: run description (seed, options, MDP name, elapsed seconds, …).
    """

    settings: list[Setting]
    returns: np.ndarray
    lengths: np.ndarray
    nonfinite: np.ndarray
    meta: dict[str, Any]

    @property
    def num_seeds(self) -> int:
        return int(self.returns.shape[1])

    @property
    def num_episodes(self) -> int:
        return int(self.returns.shape[2])

    def hyperparameters(self, config: int) -> dict[str, Any]:
        """Every hyperparameter of a config's agents (``learner.alpha``, ``explorer.sigma``,
        …), as recorded by :func:`run_grid` in ``meta["hyperparameters"]`` (or resolved
        from the setting with spec defaults for results without it)."""
        recorded = self.meta.get("hyperparameters")
        if isinstance(recorded, list) and len(recorded) == len(self.settings):
            return dict(recorded[config])
        return agent_hyperparameters(make_agent(self.settings[config]))

    def to_records(self, all_hyperparameters: bool = False) -> dict[str, np.ndarray]:
        """The curves in long format, one row per agent-episode, as columns: ``config``,
        ``setting`` (its label), ``learner``, ``explorer``, ``param``, the hyperparameters
        (:meth:`hyperparameters`; blank where a config has no such field), ``seed``,
        ``episode`` (1-based), ``return`` and ``length``.

        Args:
          all_hyperparameters: a column for every hyperparameter; by default only for
            those whose values differ between configs (the others are in ``meta.json``).

        Returns:
          ``{column: array}``, all of length configs × seeds × episodes, in the order
          config, seed, episode.
        """
        configs, seeds, episodes = self.returns.shape
        per_config = [self.hyperparameters(c) for c in range(configs)]
        names = sorted({name for values in per_config for name in values})
        if not all_hyperparameters:
            names = [n for n in names if len({repr(v.get(n, "")) for v in per_config}) > 1]
        rows = seeds * episodes

        def repeat(values: list[Any]) -> np.ndarray:
            return np.repeat(np.asarray(values, dtype=object), rows)

        records = {
            "config": np.repeat(np.arange(configs), rows),
            "setting": repeat([s.label for s in self.settings]),
            "learner": repeat([s.learner for s in self.settings]),
            "explorer": repeat([s.explorer for s in self.settings]),
            "param": repeat(["" if s.param is None else s.param for s in self.settings]),
        }
        for name in names:
            records[name] = repeat([values.get(name, "") for values in per_config])
        records["seed"] = np.tile(np.repeat(np.arange(seeds), episodes), configs)
        records["episode"] = np.tile(np.arange(1, episodes + 1), configs * seeds)
        records["return"] = self.returns.reshape(-1)
        records["length"] = self.lengths.reshape(-1)
        return records

    def to_dataframe(self, all_hyperparameters: bool = False) -> Any:
        """:meth:`to_records` as a ``pandas.DataFrame`` (long format: one row per
        agent-episode; ``pip install pandas``).

        Raises:
          ValueError: pandas is not installed.
        """
        try:
            import pandas
        except ImportError:
            raise ValueError("GridResult.to_dataframe needs pandas: pip install pandas (or"
                             " use to_records(), plain numpy columns)") from None
        return pandas.DataFrame(self.to_records(all_hyperparameters))

    def select(self, learner: str | None = None, explorer: str | None = None,
               **values: Any) -> list[int]:
        """Config indices matching a learner, an explorer and any hyperparameter values.

        Args:
          learner: learner name, or None for any.
          explorer: explorer name, or None for any.
          **values: hyperparameters that must have these values: ``alpha=0.3``,
            ``sigma=1.0`` (matched against the learner's and the explorer's fields) or
            the full names of :meth:`hyperparameters` passed as ``**{"learner.alpha": 0.3}``.

        Returns:
          the matching config indices, in order.
        """
        def matches(i: int) -> bool:
            s = self.settings[i]
            if (learner is not None and s.learner != learner) or (
                    explorer is not None and s.explorer != explorer):
                return False
            if not values:
                return True
            have = self.hyperparameters(i)
            for name, wanted in values.items():
                candidates = [v for k, v in have.items() if k == name or k.split(".", 1)[1] == name]
                if not any(_same(v, wanted) for v in candidates):
                    return False
            return True

        return [i for i in range(len(self.settings)) if matches(i)]

    def save(self, out_dir: str | os.PathLike) -> None:
        """Write ``returns.npz``, ``configs.csv`` and ``meta.json`` into ``out_dir``."""
        out = Path(out_dir)
        io.atomic_savez(
            out / io.RETURNS_FILE,
            returns=self.returns,
            lengths=self.lengths,
            nonfinite=self.nonfinite,
        )
        io.save_settings(out / io.CONFIGS_FILE, self.settings)
        io.save_json(out / io.META_FILE, self.meta)

    @classmethod
    def load(cls, out_dir: str | os.PathLike) -> GridResult:
        """Read a result saved by :meth:`save` (no recomputation), checked for damage.

        Raises:
          ValueError: the folder lacks the result files, holds a run stopped while writing
            them (:mod:`vdbejax.result_folder`), or a file is unreadable or inconsistent
            (array shapes and types, config indices, non-finite returns): one line naming
            the file.
        """
        from vdbejax.result_folder import MARKER_FILE, marked_stage

        out = Path(out_dir)
        missing = [f for f in (io.RETURNS_FILE, io.CONFIGS_FILE) if not (out / f).exists()]
        if missing:
            raise ValueError(f"results folder {str(out)!r} lacks {', '.join(missing)}")
        if marked_stage(out) == "results":
            raise ValueError(f"results folder {str(out)!r} is half-written: a run was stopped"
                             f" while writing its result files ({MARKER_FILE} is still there);"
                             " run it again")
        returns_path = out / io.RETURNS_FILE
        try:
            with np.load(returns_path) as data:
                returns, lengths = data["returns"], data["lengths"]
                nonfinite = (data["nonfinite"] if "nonfinite" in data
                             else np.zeros(returns.shape[:2], bool))
        except Exception as error:
            raise ValueError(f"results file {str(returns_path)!r} is unreadable:"
                             f" {type(error).__name__}: {error}") from None
        meta = io.load_json(out / io.META_FILE) if (out / io.META_FILE).exists() else {}
        if not isinstance(meta, dict):
            raise ValueError(f"results file {str(out / io.META_FILE)!r} is invalid: must hold a"
                             f" JSON object, not {type(meta).__name__}")
        settings = io.load_settings(out / io.CONFIGS_FILE)
        _check_saved_arrays(returns_path, len(settings), returns, lengths, nonfinite)
        remember_parameter_names(meta.get("parameter_names", {}))
        return cls(settings, returns, lengths, nonfinite, meta)


def _check_saved_arrays(path: Path, num_settings: int, returns: np.ndarray, lengths: np.ndarray,
                        nonfinite: np.ndarray) -> None:
    """One-line errors for arrays of ``returns.npz`` that cannot belong to one saved run."""
    def fail(what: str) -> None:
        raise ValueError(f"results file {str(path)!r} is damaged: {what}")

    if returns.ndim != 3 or not np.issubdtype(returns.dtype, np.floating):
        fail(f"returns must be float [configs, seeds, episodes], not {returns.dtype}"
             f" {list(returns.shape)}")
    if returns.shape[0] != num_settings:
        fail(f"its returns cover {returns.shape[0]} configs, which does not match the"
             f" {num_settings} of configs.csv")
    if lengths.shape != returns.shape or not np.issubdtype(lengths.dtype, np.integer):
        fail(f"lengths must be integer {list(returns.shape)} like returns, not {lengths.dtype}"
             f" {list(lengths.shape)}")
    if nonfinite.shape != returns.shape[:2] or nonfinite.dtype != bool:
        fail(f"nonfinite must be bool {list(returns.shape[:2])}, not {nonfinite.dtype}"
             f" {list(nonfinite.shape)}")
    # NaN or inf returns come only from agents whose values overflowed, which the run flags.
    unexplained = ~np.isfinite(returns).all(-1) & ~nonfinite
    if unexplained.any():
        fail(f"{int(unexplained.sum())} agents have NaN or infinite returns that their"
             " nonfinite flags do not account for")
    if lengths.size and lengths.min() < 1:
        fail("episode lengths must be at least 1")


def _same(value: Any, wanted: Any) -> bool:
    if isinstance(value, (int, float)) and isinstance(wanted, (int, float)):
        return bool(np.float32(value) == np.float32(wanted))
    return value == wanted


def _fingerprint(description: dict[str, Any]) -> str:
    return hashlib.sha256(json.dumps(description, sort_keys=True).encode()).hexdigest()[:16]


def nonfinite_message(settings: Sequence[Setting], nonfinite: np.ndarray,
                      options: AgentOptions) -> str | None:
    """One line naming every config whose agents saw NaN/inf in Q or ε, or None.

    Args:
      settings: the grid's configurations.
      nonfinite: bool ``[configs, seeds]``.
      options: the options shared by all agents (part of the config that produced it).
    """
    counts = np.asarray(nonfinite).sum(axis=1)
    bad = [f"{settings[int(c)].label} ({counts[c]}/{nonfinite.shape[1]} agents)"
           for c in np.flatnonzero(counts)]
    if not bad:
        return None
    return (f"NaN or inf appeared in Q or ε, or an invalid action was drawn, for: {'; '.join(bad)}"
            f" [options {dataclasses.asdict(options)}]")


def check_run_options(
    *, num_seeds: Any, num_episodes: Any, seed: Any, chunk_episodes: Any, resume: Any,
    memory_budget_bytes: Any,
) -> int | None:
    """Check :func:`run_grid`'s counts and flags (one-line ``ValueError`` on bad input).

    Args:
      num_seeds, num_episodes, seed, chunk_episodes, resume, memory_budget_bytes: as
        in :func:`run_grid`.

    Returns:
      the memory budget in bytes (``"512M"``-style sizes parsed), or None.
    """
    # Counts and sizes end up in int32 arrays; the seed is a 32-bit key.
    check_int("num_seeds", num_seeds, 1, INT32_MAX)
    check_int("num_episodes", num_episodes, 1, INT32_MAX)
    check_int("seed", seed, 0, UINT32_MAX)
    check_int("chunk_episodes", chunk_episodes, 1, INT32_MAX)
    check_bool("resume", resume)
    if memory_budget_bytes is None:
        return None
    return parse_bytes("memory_budget_bytes", memory_budget_bytes)


def _check_grid_inputs(mdp: Any, settings: list[Any], progress: Any, checkpoint: Any) -> None:
    """Check :func:`run_grid`'s task, settings, progress and checkpoint path."""
    if not isinstance(mdp, TabularMDP):
        raise ValueError(f"mdp={type(mdp).__name__} is invalid: must be a TabularMDP"
                         " (see make_tabular_mdp, compile_env)")
    if not (isinstance(progress, bool) or callable(progress)):
        raise ValueError(f"progress={progress!r} is invalid: must be True, False or a callable"
                         " progress(done, total, elapsed)")
    if not settings:
        raise ValueError("settings is empty: need at least one setting")
    for s in settings:
        if not isinstance(s, Setting):
            raise ValueError(f"settings holds {s!r}: must hold Setting(learner, explorer, param)")
    if checkpoint is not None:
        if not isinstance(checkpoint, (str, os.PathLike)):
            raise ValueError(f"checkpoint={checkpoint!r} is invalid: must be a file path or None")
        check_writable_dir("checkpoint folder", Path(checkpoint).parent)  # fail before training
        if Path(checkpoint).exists() and not Path(checkpoint).is_file():
            raise ValueError(f"checkpoint={str(checkpoint)!r} is invalid: it exists and is not"
                             " a file")


def _checkpointing(
    checkpoint: str | os.PathLike | None, fingerprint: str, resume: bool, shape: tuple[int, int],
    mdp: TabularMDP, layout: dict[str, str],
) -> tuple[SweepProgress | None, CheckpointWriter | None]:
    """The progress to resume from (None: fresh) and the after-chunk checkpoint writer
    (:mod:`vdbejax.checkpoint`)."""
    if checkpoint is None:
        return None, None
    path = process_checkpoint_path(checkpoint)
    remove_stale_temporaries(path.parent)  # what killed writers left (vdbejax.result_folder)
    if resume and path.exists():
        sweep, log_bytes, log_id = load_checkpoint(path, fingerprint, shape, mdp, layout)
        return sweep, CheckpointWriter(path, fingerprint, sweep, log_bytes, log_id)
    remove_checkpoint(path)  # a fresh run: an older checkpoint must not outlive its log
    return None, CheckpointWriter(path, fingerprint)


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


@functools.lru_cache(maxsize=1)
def git_commit() -> str | None:
    """The commit vdbejax is imported from when it runs from a git clone, else None.

    Runs ``git rev-parse HEAD`` in the package's parent folder (once per process, 2 s
    timeout) and checks the package is tracked there, so an installed copy inside some
    other repository (a virtualenv in a clone) is not credited with that commit.
    """
    package = Path(__file__).resolve().parent
    try:
        head = subprocess.run(["git", "rev-parse", "HEAD"], cwd=package.parent,
                              capture_output=True, text=True, timeout=2)
        tracked = subprocess.run(
            ["git", "ls-files", "--error-unmatch", "--", f"{package.name}/__init__.py"],
            cwd=package.parent, capture_output=True, text=True, timeout=2)
    except (OSError, subprocess.SubprocessError, ValueError):
        return None
    commit = head.stdout.strip()
    if head.returncode != 0 or tracked.returncode != 0 or not commit:
        return None
    return commit


def version_info() -> dict[str, Any]:
    """Versions recorded in ``meta.json`` besides JAX's: vdbejax, numpy, Python, the
    platform and the git commit (None outside a git clone)."""
    from vdbejax import __version__

    return {"vdbejax_version": __version__, "numpy_version": np.__version__,
            "python_version": platform.python_version(), "platform": platform.platform(),
            "git_commit": git_commit()}


def run_grid(
    mdp: TabularMDP,
    settings: Sequence[Setting],
    *,
    num_seeds: int = 20,
    num_episodes: int = 1000,
    seed: int = 0,
    options: AgentOptions = AgentOptions(),
    chunk_episodes: int = 100,
    progress: bool | ProgressCallback = False,
    checkpoint: str | os.PathLike | None = None,
    resume: bool = False,
    memory_budget_bytes: int | str | None = None,
    devices: int | None = None,
) -> GridResult:
    """Train ``num_seeds`` agents for every setting, all in one vectorized program.

    Agent ``(config c, seed i)`` uses key ``fold_in(PRNGKey(seed), i)``: the same seed
    index shares its random stream across configs (common random numbers), and an agent
    gives bit-identical results whether run alone or inside any grid, in any batch, on
    any number of devices, resumed or not.

    Args:
      mdp: the task.
      settings: the configurations (e.g. :func:`~vdbejax.methods.agents.paper_settings`).
      num_seeds: agents per setting.
      num_episodes: episodes per agent.
      seed: root seed.
      options: α, γ, q_init, tie-break, δ shared by all agents.
      chunk_episodes: episodes per jitted chunk (progress and checkpoint granularity).
      progress: True for a progress bar on stderr, or a callback.
      checkpoint: file to write after every chunk (atomically), with its episode log
        beside it (``<checkpoint>.episodes``, :mod:`vdbejax.checkpoint`); delete both with
        :func:`vdbejax.checkpoint.remove_checkpoint` once the result is saved.
      resume: continue from ``checkpoint`` if it exists.
      memory_budget_bytes: device memory the agents may use, per device (default:
        half of the free memory of the smallest device); an int or a size such as
        ``"512M"``. Agents that do not fit run in sequential batches; the results do
        not depend on it.
      devices: number of devices to shard the agents over (default: all of
        ``jax.devices()``, every host's after ``jax.distributed.initialize``).

    Returns:
      :class:`GridResult`.

    Raises:
      ValueError: invalid settings, counts, or a checkpoint from a different run.
    """
    settings = list(settings)
    memory_budget_bytes = check_run_options(
        num_seeds=num_seeds, num_episodes=num_episodes, seed=seed,
        chunk_episodes=chunk_episodes, resume=resume, memory_budget_bytes=memory_budget_bytes,
    )
    # Validated above: plain ints from here on (numpy scalars are not JSON).
    num_seeds, num_episodes, seed, chunk_episodes = (
        int(v) for v in (num_seeds, num_episodes, seed, chunk_episodes))
    _check_grid_inputs(mdp, settings, progress, checkpoint)
    check_run_size(len(settings) * num_seeds, num_episodes, checkpoint)  # before allocating
    device_list = select_devices(devices)
    params, keys = grid_agents(settings, num_seeds, seed, options)
    check_params(params, mdp.num_actions)  # a bad plug-in: one line before anything runs
    num_agents = len(settings) * num_seeds
    # Several processes (hosts): each runs its share of the agents on its own devices.
    rows = process_share(num_agents)
    my_devices = local_devices(device_list)
    budget = (default_memory_budget(my_devices) if memory_budget_bytes is None
              else memory_budget_bytes)
    batch_size = agents_per_batch(
        max(len(rows), 1),
        bytes_per_agent(mdp, min(chunk_episodes, num_episodes), table_layout(params)),
        budget,
        len(my_devices), fixed_bytes=mdp_bytes(mdp),
    )
    description = {
        "mdp": mdp.name,
        "mdp_tables": _fingerprint_arrays(mdp),
        "settings": [dataclasses.astuple(s) for s in settings],
        "num_seeds": num_seeds,
        "num_episodes": num_episodes,
        "seed": seed,
        "options": dataclasses.asdict(options),
    }
    # Chunk size, batch size and devices are left out: results do not depend on them.
    fingerprint = _fingerprint(description)
    # A process's checkpoint holds its share only: tie it to the process layout.
    checkpoint_fingerprint = fingerprint if jax.process_count() == 1 else _fingerprint(
        dict(description, process=[jax.process_index(), jax.process_count()]))
    sweep, on_checkpoint = _checkpointing(checkpoint, checkpoint_fingerprint, resume,
                                          (len(rows), num_episodes), mdp, table_layout(params))
    resumed_from = 0 if sweep is None else int(sweep.episodes_done.sum())
    callback = text_progress() if progress is True else (progress or None)
    started = time.perf_counter()
    try:
        sweep, batches = run_batched(
            mdp, take_agents(params, rows), keys[rows], num_episodes, batch_size=batch_size,
            devices=my_devices, chunk_episodes=chunk_episodes, progress=callback, sweep=sweep,
            on_checkpoint=on_checkpoint,
        )
    finally:
        if on_checkpoint is not None:
            on_checkpoint.close()
    elapsed = time.perf_counter() - started
    shape = (len(settings), num_seeds, num_episodes)
    # [agents, episodes] → [configs, seeds, episodes]; nonfinite [agents] → [configs, seeds].
    returns, lengths, nonfinite = (gather_agents(array, num_agents).reshape(shape[: array.ndim + 1])
                                   for array in (sweep.returns, sweep.lengths, sweep.nonfinite))
    message = nonfinite_message(settings, nonfinite, options)
    if message:
        warnings.warn(message, RuntimeWarning, stacklevel=2)
    meta = dict(description, fingerprint=fingerprint, elapsed_seconds=elapsed,
                resumed_from_agent_episodes=resumed_from, max_steps=int(mdp.max_steps),
                nonfinite_agents=int(nonfinite.sum()), nonfinite_message=message,
                devices=len(device_list), processes=jax.process_count(), batches=batches,
                agents_per_batch=batch_size, memory_budget_bytes=int(budget),
                jax_version=jax.__version__, backend=jax.default_backend(),
                **version_info())
    meta.pop("mdp_tables")
    meta["longest_episode"] = int(lengths.max())
    # Episodes cut off at max_steps (on a task without a step limit, e.g. cruz2018, the
    # safety cap: agents that would have looped forever).
    cut = lengths >= mdp.max_steps
    meta["truncated_episodes"] = int(cut.sum())
    meta["agents_truncated"] = int(cut.any(axis=2).sum())
    meta["truncated_episodes_by_config"] = cut.sum(axis=(1, 2)).tolist()
    meta["hyperparameters"] = [agent_hyperparameters(make_agent(s, options)) for s in settings]
    meta["parameter_names"] = {s.explorer: parameter_name(s.explorer) for s in settings}
    return GridResult(settings, returns, lengths, nonfinite, meta)


def _fingerprint_arrays(mdp: TabularMDP) -> str:
    digest = hashlib.sha256()
    for leaf in jax.tree.leaves(mdp):
        digest.update(np.asarray(leaf).tobytes())
    return digest.hexdigest()[:16]
