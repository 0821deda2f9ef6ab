"""The result of a grid run: :class:`GridResult`, its files, their checks on loading, and
its long-format columns (the rows :mod:`vdbejax.results.export` writes)."""
from __future__ import annotations

import dataclasses
import hashlib
import io as io_bytes
import json
import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from vdbejax.methods.agents import (
    TASK_PREFIX,
    Setting,
    agent_hyperparameters,
    make_agent,
    with_parameter_names,
)
from vdbejax.results import io, manifest
from vdbejax.results.record_checks import (
    check_optimal_actions,
    check_policy_values,
    check_truncated,
)
from vdbejax.validation import check_writable_dir


@dataclasses.dataclass
class GridResult:
    """Learning curves of a grid.

    Attributes:
      settings: the configurations, in config-index order.
      returns: float32 ``[configs, seeds, episodes]`` episode returns.
      lengths: int32 ``[configs, seeds, episodes]`` episode lengths.
      nonfinite: bool ``[configs, seeds]``: NaN/inf appeared in that agent's Q or ε.
      meta: run description (seed, options, MDP name, elapsed seconds, …).
      episodes_run: int64 ``[configs, seeds]``, the episodes each agent ran, when a stop
        policy stopped agents early (:class:`~vdbejax.runs.UntilSolved`): their returns
        are NaN and lengths 0 past it. ``None``: every agent ran every episode.
      policy_values: float32 ``[configs, seeds, evaluations]``, the exact expected return
        of each agent's greedy policy after episodes ``evaluate_every · (1, 2, …)``
        (:attr:`evaluation_episodes`; NaN past an agent's stop), with
        ``meta["optimal_return"]`` the optimum V* (:mod:`vdbejax.runs.evaluation`; the
        gaps: :func:`vdbejax.results.policy.policy_gaps`).
        ``None``: a run without ``evaluate_every``.
      optimal_actions: float32 ``[configs, seeds, episodes]``, the fraction of each
        episode's steps whose action is optimal (NaN for an episode not run;
        :mod:`vdbejax.runs.optimal_record`). ``None``: a run without ``record_optimal``.
      truncated: bool ``[configs, seeds, episodes]``: the step limit cut the episode (its
        ``max_steps``-th step was not terminal; an episode whose last allowed step ended
        it on its own is not cut). ``None``: a folder written before the engine recorded
        it (:func:`~vdbejax.results.analysis.truncated_episodes` then falls back to its
        length).
    """

    settings: list[Setting]
    returns: np.ndarray
    lengths: np.ndarray
    nonfinite: np.ndarray
    meta: dict[str, Any]
    episodes_run: np.ndarray | None = None
    policy_values: np.ndarray | None = None
    optimal_actions: np.ndarray | None = None
    truncated: np.ndarray | None = None

    @property
    def evaluation_episodes(self) -> np.ndarray:
        """int64 ``[evaluations]``: the episodes after which :attr:`policy_values` were
        taken (empty without them)."""
        if self.policy_values is None:
            return np.zeros(0, np.int64)
        every = int(self.meta["evaluate_every"])
        return every * np.arange(1, self.policy_values.shape[2] + 1, dtype=np.int64)

    def __repr__(self) -> str:
        """One line: the sizes and the task, never the arrays (millions of numbers)."""
        stopped = "" if self.episodes_run is None else ", stopped early"
        return (f"GridResult({len(self.settings)} settings × {self.num_seeds} agents ×"
                f" {self.num_episodes} episodes, task {self.meta.get('mdp', '?')!r}{stopped})")

    @property
    def num_seeds(self) -> int:
        return int(self.returns.shape[1])

    @property
    def num_episodes(self) -> int:
        return int(self.returns.shape[2])

    def hyperparameters(self, config: int) -> dict[str, Any]:
        """Every hyperparameter of a config's agents (``learner.alpha``, ``explorer.sigma``,
        …; its task's parameters, ``task.std``), as recorded by :func:`run_grid` in
        ``meta["hyperparameters"]`` (or resolved from the setting with spec defaults for
        results without it)."""
        if isinstance(config, bool) or not isinstance(config, (int, np.integer)) or not (
                0 <= config < len(self.settings)):
            raise ValueError(f"config={config!r} is invalid: must be a config index in"
                             f" [0, {len(self.settings) - 1}]")
        setting = self.settings[config]
        task = {TASK_PREFIX + name: value for name, value in setting.task_values.items()}
        recorded = self.meta.get("hyperparameters")
        if isinstance(recorded, list) and len(recorded) == len(self.settings):
            return dict(recorded[config], **task)
        return dict(agent_hyperparameters(make_agent(setting)), **task)

    def to_records(self, all_hyperparameters: bool = False) -> dict[str, np.ndarray]:
        """The curves in long format, one row per agent-episode, as columns: ``config``,
        ``setting`` (its label), ``learner``, ``explorer``, ``param``, the hyperparameters
        (:meth:`hyperparameters`; None where a config has no such field), ``seed``
        (``replicate`` too, with several), ``episode`` (1-based), ``return`` and ``length``
        (and ``optimal_actions``, in a run that records them): the returns table of
        :func:`vdbejax.results.export.export_results` for this run.

        Args:
          all_hyperparameters: a column for every hyperparameter; by default only for
            those whose values differ between configs (the others are in ``meta.json``).

        Returns:
          ``{column: array}``, all of length configs × seeds × episodes, in the order
          config, seed, episode.
        """
        return returns_columns(self, hyperparameter_names([self], all_hyperparameters))

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
        """Write ``returns.npz``, ``configs.csv`` and ``meta.json`` into ``out_dir``, and
        their sha256 into ``manifest.json`` (:mod:`vdbejax.results.manifest`).

        Raises:
          ValueError: ``out_dir`` cannot be created or written (before any file is);
            OSError: a write fails on the way (a full disk).
        """
        self.write_files(check_writable_dir("out_dir", out_dir))

    def write_files(self, out: Path) -> None:
        """:meth:`save` into an existing folder, without checking it first (an operating
        system error is raised as it is: the result-folder pipeline rescues the results)."""
        arrays: dict[str, Any] = {"returns": self.returns, "lengths": self.lengths,
                                  "nonfinite": self.nonfinite}
        if self.episodes_run is not None:
            arrays["episodes_run"] = self.episodes_run
        for name in ("policy_values", "optimal_actions", "truncated"):  # the records kept
            if getattr(self, name) is not None:
                arrays[name] = getattr(self, name)
        meta = dict(self.meta, **{manifest.META_KEY: manifest.MANIFEST_FILE})
        io.atomic_savez(out / io.RETURNS_FILE, **arrays)
        io.save_settings(out / io.CONFIGS_FILE, self.settings)
        io.save_json(out / io.META_FILE, meta)
        manifest.write_manifest(out, meta, io.RESULT_FILES)

    @classmethod
    def load(cls, out_dir: str | os.PathLike) -> GridResult:
        """Read a result saved by :meth:`save` (no recomputation), checked for damage.

        Raises:
          ValueError: the folder lacks the result files, holds a run stopped while writing
            them (:mod:`vdbejax.results.folder_lock`), or a file is unreadable or inconsistent
            (array shapes and types, config indices, non-finite returns): one line naming
            the file.
        """
        from vdbejax.results.folder_lock import MARKER_FILE, marked_stage

        out = Path(out_dir)
        if not out.is_dir():  # a file, or nothing: not a folder's missing files
            what = "is a file" if out.exists() else "does not exist"
            raise ValueError(f"results folder {str(out)!r} {what}: give the folder a run wrote"
                             f" ({io.RETURNS_FILE}, {io.CONFIGS_FILE}, {io.META_FILE})")
        missing = [f for f in (io.RETURNS_FILE, io.CONFIGS_FILE) if not (out / f).exists()]
        if missing:
            raise ValueError(f"results folder {str(out)!r} lacks {', '.join(missing)}")
        if marked_stage(out) == "results":
            raise ValueError(f"results folder {str(out)!r} is half-written: a run was stopped"
                             f" while writing its result files ({MARKER_FILE} is still there);"
                             " run it again")
        returns_path = out / io.RETURNS_FILE
        try:  # read once: the same bytes are hashed for the manifest and loaded
            saved = returns_path.read_bytes()
            with np.load(io_bytes.BytesIO(saved)) as data:
                returns, lengths = data["returns"], data["lengths"]
                nonfinite = (data["nonfinite"] if "nonfinite" in data
                             else np.zeros(returns.shape[:2], bool))
                episodes_run = data.get("episodes_run")
                policy_values = data.get("policy_values")
                optimal_actions = data.get("optimal_actions")
                truncated = data.get("truncated")  # absent from folders of older versions
        except Exception as error:
            raise ValueError(f"results file {str(returns_path)!r} is unreadable:"
                             f" {type(error).__name__}: {error}") from None
        try:
            meta = io.load_json(out / io.META_FILE) if (out / io.META_FILE).exists() else {}
        except (OSError, ValueError) as error:  # ValueError: not JSON
            raise ValueError(f"results file {str(out / io.META_FILE)!r} is unreadable:"
                             f" {type(error).__name__}: {error}") from None
        if not isinstance(meta, dict):
            raise ValueError(f"results file {str(out / io.META_FILE)!r} is invalid: must hold a"
                             f" JSON object, not {type(meta).__name__}")
        manifest.verify_manifest(out, meta, io.RESULT_FILES,
                                 known={io.RETURNS_FILE: hashlib.sha256(saved).hexdigest()})
        settings = io.load_settings(out / io.CONFIGS_FILE)
        _check_saved_arrays(returns_path, len(settings), returns, lengths, nonfinite,
                            episodes_run)
        settings = with_parameter_names(settings, meta.get("parameter_names", {}))
        _check_against_meta(out, meta, settings, returns, lengths, nonfinite, episodes_run)
        check_policy_values(returns_path, meta, returns, policy_values)
        check_optimal_actions(returns_path, returns, lengths, optimal_actions)
        check_truncated(returns_path, meta, lengths, truncated)
        return cls(settings, returns, lengths, nonfinite, meta, episodes_run, policy_values,
                   optimal_actions, truncated)


#: A long table as ``{column: array}``, all of one length.
Columns = dict[str, np.ndarray]


def hyperparameter_names(results: Sequence[GridResult], everything: bool = False) -> list[str]:
    """The hyperparameter columns of ``results``' tables: those whose values differ
    between their settings (all of them with ``everything``), sorted."""
    per_config = [values for result in results
                  for values in (result.hyperparameters(c) for c in range(len(result.settings)))]
    names = sorted({name for values in per_config for name in values})
    if everything:
        return names
    return [n for n in names if len({repr(values.get(n)) for values in per_config}) > 1]


def setting_columns(result: GridResult, names: Sequence[str]) -> Columns:
    """One row per setting: ``config``, ``setting``, ``learner``, ``explorer``, ``param``
    and the hyperparameters ``names`` (None where a setting has no such field)."""
    per_config = [result.hyperparameters(c) for c in range(len(result.settings))]

    def column(values: list[Any]) -> np.ndarray:
        array = np.empty(len(values), dtype=object)
        array[:] = values
        return array

    columns = {"config": np.arange(len(result.settings)),
               "setting": column([s.label for s in result.settings]),
               "learner": column([s.learner for s in result.settings]),
               "explorer": column([s.explorer for s in result.settings]),
               "param": column([s.param for s in result.settings])}
    for name in names:
        columns[name] = column([values.get(name) for values in per_config])
    return columns


def agent_columns(result: GridResult, names: Sequence[str], inner: int) -> Columns:
    """The setting's columns, ``seed`` (and ``replicate``) repeated for ``inner`` rows per
    agent, in the order setting, agent, inner row."""
    configs, seeds = result.returns.shape[:2]
    columns = {name: np.repeat(values, seeds * inner)
               for name, values in setting_columns(result, names).items()}
    seed = np.tile(np.repeat(np.arange(seeds), inner), configs)
    columns["seed"] = seed
    if int(result.meta.get("replicates", 1)) > 1:
        columns["replicate"] = seed // int(result.meta.get("agents_per_replicate") or seeds)
    return columns


def returns_columns(result: GridResult, names: Sequence[str]) -> Columns:
    """The returns table of one run (:mod:`vdbejax.results.export`), ``names`` its
    hyperparameter columns: rows in the order setting, agent, episode (1-based)."""
    configs, seeds, episodes = result.returns.shape
    columns = agent_columns(result, names, episodes)
    columns["episode"] = np.tile(np.arange(1, episodes + 1), configs * seeds)
    columns["return"] = result.returns.reshape(-1)
    columns["length"] = result.lengths.reshape(-1)
    if result.optimal_actions is not None:
        columns["optimal_actions"] = result.optimal_actions.reshape(-1)
    return columns


def _check_saved_arrays(path: Path, num_settings: int, returns: np.ndarray, lengths: np.ndarray,
                        nonfinite: np.ndarray, episodes_run: np.ndarray | None = None) -> None:
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
    ran = np.ones(returns.shape, bool)
    if episodes_run is not None:
        if (episodes_run.shape != returns.shape[:2]
                or not np.issubdtype(episodes_run.dtype, np.integer)
                or (episodes_run.size and (episodes_run.min() < 0
                                           or episodes_run.max() > returns.shape[2]))):
            fail(f"episodes_run must be integer {list(returns.shape[:2])} within"
                 f" [0, {returns.shape[2]}]")
        ran = np.arange(returns.shape[2]) < episodes_run[..., None]
    # NaN or inf returns come only from agents whose values overflowed, which the run flags
    # (or from episodes past an agent's stop, which it did not run).
    unexplained = ~(np.isfinite(returns) | ~ran).all(-1) & ~nonfinite
    if unexplained.any():
        fail(f"{int(unexplained.sum())} agents have NaN or infinite returns that their"
             " nonfinite flags do not account for")
    if lengths.size and lengths[ran].size and lengths[ran].min() < 1:
        fail("episode lengths must be at least 1")


#: Standard errors by which a setting's mean final return may exceed the task's best
#: expected return before the folder is refused (noise of a stochastic task: a false alarm
#: has a probability below 1e-6 per setting).
PLAUSIBLE_SE = 5.0


def _check_against_meta(out: Path, meta: dict[str, Any], settings: list[Setting],
                        returns: np.ndarray, lengths: np.ndarray, nonfinite: np.ndarray,
                        episodes_run: np.ndarray | None) -> None:
    """One-line errors for result files that cannot hold the run ``meta.json`` describes:
    the shapes, the settings, lengths within ``max_steps``, mean returns within the best
    possible, the flagged agents (each check only where ``meta`` records the value)."""
    def fail(file: str, what: str) -> None:
        raise ValueError(f"results file {str(out / file)!r} does not match {io.META_FILE}:"
                         f" {what}")

    expected = (meta.get("num_seeds"), meta.get("num_episodes"))
    if None not in expected and tuple(returns.shape[1:]) != expected:
        fail(io.RETURNS_FILE, f"it holds {returns.shape[1]} agents × {returns.shape[2]}"
             f" episodes per setting, meta.json {expected[0]} × {expected[1]}")
    recorded = meta.get("settings")
    if isinstance(recorded, list):
        if len(recorded) != len(settings):
            fail(io.CONFIGS_FILE, f"it has {len(settings)} configs, meta.json {len(recorded)}")
        for c, (setting, entry) in enumerate(zip(settings, recorded, strict=True)):
            if not _same_setting(setting, entry):
                fail(io.CONFIGS_FILE, f"config {c} is {setting.label}, meta.json says"
                     f" {json.dumps(entry)}")
    max_steps = meta.get("max_steps")
    ran = (np.ones(returns.shape, bool) if episodes_run is None
           else np.arange(returns.shape[2]) < episodes_run[..., None])
    if isinstance(max_steps, int) and lengths[ran].size and lengths[ran].max() > max_steps:
        fail(io.RETURNS_FILE, f"an episode lasts {int(lengths[ran].max())} steps, beyond"
             f" max_steps={max_steps}")
    if isinstance(meta.get("nonfinite_agents"), int) and int(nonfinite.sum()) != meta[
            "nonfinite_agents"]:
        fail(io.RETURNS_FILE, f"{int(nonfinite.sum())} agents are flagged non-finite,"
             f" meta.json says {meta['nonfinite_agents']}")
    best = meta.get("best_return")
    if isinstance(best, (int, float)) and episodes_run is None and returns.size:
        _check_below_best(out / io.RETURNS_FILE, float(best), returns, nonfinite, settings)


def _check_below_best(path: Path, best: float, returns: np.ndarray, nonfinite: np.ndarray,
                      settings: list[Setting]) -> None:
    """Refuse a setting whose agents' mean final return exceeds the task's best expected
    return by more than :data:`PLAUSIBLE_SE` standard errors (+ float32 slack)."""
    last = min(100, returns.shape[2])
    for c in range(returns.shape[0]):
        finals = np.asarray(returns[c, ~nonfinite[c], -last:], np.float64).mean(-1)
        if finals.size == 0:
            continue
        error = finals.std(ddof=1) / np.sqrt(finals.size) if finals.size > 1 else 0.0
        if finals.mean() > best + PLAUSIBLE_SE * error + 1e-5 * max(1.0, abs(best)):
            raise ValueError(f"results file {str(path)!r} is implausible: setting {c}"
                             f" ({settings[c].label}) averages {finals.mean():.6g} over its last"
                             f" {last} episodes, above the task's best possible {best:.6g}")


def _same_setting(setting: Setting, entry: Any) -> bool:
    """Whether a ``configs.csv`` setting is ``meta.json``'s ``[learner, explorer, param,
    [[name, value], …]]`` (values as written there: 6 significant digits)."""
    if not isinstance(entry, list) or len(entry) != 4:
        return False
    learner, explorer, param, pairs = entry
    if (setting.learner, setting.explorer) != (learner, explorer):
        return False
    if (param is None) != (setting.param is None) or (
            param is not None and not _close(setting.param, param)):
        return False
    try:
        values = dict(pairs)
    except (TypeError, ValueError):
        return False
    mine = dict(setting.hyperparameters)
    return mine.keys() == values.keys() and all(
        _close(mine[k], values[k]) if isinstance(values[k], (int, float)) else mine[k] == values[k]
        for k in mine)


def _close(value: Any, wanted: Any) -> bool:
    try:
        return bool(np.isclose(float(value), float(wanted), rtol=1e-5, atol=0.0))
    except (TypeError, ValueError):
        return False


def _same(value: Any, wanted: Any) -> bool:
    if isinstance(value, (int, float)) and isinstance(wanted, (int, float)):
        return bool(np.float32(value) == np.float32(wanted))
    return value == wanted
