"""The result-folder pipeline: every command that trains writes its folder through it.

:func:`train_in_folder` takes a run that is already checked and planned
(:func:`~vdbejax.runs.prepare_grid`: a bad input has failed in one line, and nothing was
created), then:

1. checks the folder (created if needed, writable, no output path that is a folder; an
   existing folder of other files than a run's is refused without ``overwrite``), and
   announces a long run with its estimate (:mod:`vdbejax.runs.estimate`);
2. locks it (:class:`~vdbejax.results.folder_lock.FolderLock`) until its last file is written;
3. refuses, in one line, to replace what the folder already holds unless ``overwrite``:
   a finished result (``meta.json`` of a whole run) and, without ``resume``, a checkpoint
   left by an interrupted run (its progress is not thrown away); ``resume`` continues only
   the same run (same fingerprint): the folder's whole result is loaded instead of
   training again, a checkpoint of another run is refused;
4. runs, checkpointing to ``checkpoint.npz`` after every chunk (continuing from it with
   ``resume``);
5. removes the outputs an earlier run left (figures, exported tables), saves
   ``returns.npz``, ``configs.csv``, ``meta.json`` (marked while written,
   :mod:`vdbejax.results.folder_lock`), removes the checkpoint, and writes the outputs.

A study that trains several such folders under its own (``vdbejax scale``, ``bench``,
``depth``) takes what it writes besides its tables as one :class:`StudyOutputs`.
"""
from __future__ import annotations

import dataclasses
import os
import shutil
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, TypeVar

from vdbejax.engine.distributed import process_checkpoint_path
from vdbejax.results import io
from vdbejax.results.export import EXPORT_FILES
from vdbejax.results.folder_lock import (
    check_output_paths,
    marked_stage,
    output_folder,
    rescue,
    save_run,
)
from vdbejax.results.grid_result import GridResult
from vdbejax.results.io import CHECKPOINT_FILE
from vdbejax.runs.checkpoint import log_path, remove_checkpoint
from vdbejax.runs.estimate import announce, estimate_prepared
from vdbejax.runs.grid import PreparedGrid, run_prepared
from vdbejax.validation import check_bool

T = TypeVar("T")


@dataclasses.dataclass(frozen=True)
class StudyOutputs:
    """What a study (``vdbejax scale``, ``bench``, ``depth``) writes besides its tables.

    Attributes:
      figures: write the study's figures.
      command: the command line, recorded in the study's report and ``meta.json``.
      save_runs: keep the result folder of each task the study trained (its curves,
        ``returns.npz``, ``configs.csv``, ``meta.json``); ``False`` removes them once the
        study's files are written (a later ``resume`` then trains them again).

    Raises:
      ValueError: ``figures`` or ``save_runs`` is not a bool, ``command`` not a string.
    """

    figures: bool = True
    command: str | None = None
    save_runs: bool = True

    def __post_init__(self) -> None:
        check_bool("figures", self.figures)
        check_bool("save_runs", self.save_runs)
        if self.command is not None and not isinstance(self.command, str):
            raise ValueError(f"command={self.command!r} is invalid: must be a string or None")

    def discard_runs(self, folders: Sequence[Path]) -> None:
        """Remove the study's task folders ``folders`` unless :attr:`save_runs`."""
        if not self.save_runs:
            for folder in folders:
                shutil.rmtree(folder, ignore_errors=True)


def checkpoint_files() -> list[str]:
    """The checkpoint's two files in a result folder."""
    return [CHECKPOINT_FILE, log_path(CHECKPOINT_FILE).name]


def finished_fingerprint(out: Path) -> str | None:
    """The fingerprint of the whole run ``out`` holds (``""`` for one saved without a
    fingerprint), or None: no ``meta.json``, an unreadable one, or a run whose saving was
    cut off (its marker is still there, :mod:`vdbejax.results.folder_lock`)."""
    meta_file = out / io.META_FILE
    if not meta_file.is_file() or marked_stage(out) is not None:
        return None
    try:
        meta = io.load_json(meta_file)
    except (OSError, ValueError):
        return None
    return str(meta.get("fingerprint", "")) if isinstance(meta, dict) else None


def check_replaceable(out: Path, prepared: PreparedGrid, name: str) -> None:
    """Refuse to replace what ``out`` holds without ``prepared.run.overwrite`` (module
    docstring, step 3)."""
    run = prepared.run
    if run.overwrite:
        return
    hint = "pass --overwrite (overwrite=True) to replace it, or choose another folder"
    finished = finished_fingerprint(out)
    if finished is not None and not run.resume:
        raise ValueError(f"{name}={str(out)!r} holds a finished result ({io.META_FILE}): {hint};"
                         " --resume (resume=True) loads it if it is this same run")
    if finished is not None and finished != prepared.fingerprint:
        raise ValueError(f"{name}={str(out)!r} holds the finished result of a different run"
                         f" (fingerprint {finished or 'none'}, this run's"
                         f" {prepared.fingerprint}): --resume continues only the same run; {hint}")
    if not run.resume and process_checkpoint_path(out / CHECKPOINT_FILE).exists():
        raise ValueError(
            f"{name}={str(out)!r} holds the checkpoint of an interrupted run"
            f" ({CHECKPOINT_FILE}): resume it (--resume, resume=True), or delete"
            f" {' and '.join(checkpoint_files())} (or pass --overwrite) to start again")


def saved_result(out: Path, fingerprint: str) -> GridResult | None:
    """The whole result of the run with ``fingerprint`` saved in ``out``, or None."""
    meta_file = out / io.META_FILE
    if not meta_file.is_file():
        return None
    try:
        meta = io.load_json(meta_file)
    except (OSError, ValueError):
        return None
    if not isinstance(meta, dict) or meta.get("fingerprint") != fingerprint:
        return None
    try:
        return GridResult.load(out)
    except ValueError:
        return None  # damaged or half-written (GridResult.load): train again


def train_in_folder(
    out_dir: str | os.PathLike,
    prepared: PreparedGrid,
    write: Callable[[GridResult, Any], T],
    *,
    files: Sequence[str],
    annotate: Callable[[GridResult], None] | None = None,
    bands: bool = True,
    statistics: bool = True,
    name: str = "out",
) -> tuple[GridResult, T]:
    """Train ``prepared`` into the result folder ``out_dir`` (module docstring).

    Args:
      out_dir: the result folder (created if needed).
      prepared: the checked, planned run; its ``run.resume`` resumes (or reuses a saved
        whole result of the same run), its ``run.overwrite`` may replace what the folder
        holds.
      write: writes the outputs: ``write(result, statistics)`` with the returns'
        :class:`~vdbejax.results.stats.CurveStatistics` (``None`` with ``statistics=False``).
      files: the files the outputs write (none may be a folder: checked before training).
      annotate: adds to the result's ``meta`` before it is saved (a reused one's too).
      bands: compute Figure 3's bootstrap bands with the statistics.
      statistics: compute the statistics.
      name: the folder's parameter name in error messages.

    Returns:
      ``(result, what write returned)``.

    Raises:
      ValueError: an unwritable folder, an output path that is a folder, a folder another
        run holds, a finished result or checkpoint it may not replace (module docstring);
        an operating-system error while writing
        (the computed results are kept, :func:`~vdbejax.results.folder_lock.save_run`).
    """
    own = [*io.RESULT_FILES, *files, *checkpoint_files()]
    out, lock = output_folder(out_dir, name, own=[*own, *EXPORT_FILES],
                              overwrite=prepared.run.overwrite)
    check_output_paths(out, own, name)
    if prepared.run.progress:
        announce(estimate_prepared(prepared, statistics=statistics), "run")
    with lock:  # held until the last file is written
        checkpoint = out / CHECKPOINT_FILE
        check_replaceable(out, prepared, name)
        if not prepared.run.resume:  # overwrite: an interrupted run's progress is given up
            remove_checkpoint(process_checkpoint_path(checkpoint))
        result = saved_result(out, prepared.fingerprint) if prepared.run.resume else None
        if result is None:
            result = run_prepared(prepared.with_checkpoint(checkpoint))
        elif "random_return" not in result.meta:  # reused from before it was recorded
            from vdbejax.envs.solvers import best_return, uniform_random_return

            result.meta.update(best_return=best_return(prepared.mdp),
                               random_return=uniform_random_return(prepared.mdp))
        if annotate is not None:  # a reused result too: 100 agents may now be 5 × 20
            annotate(result)
        if not lock.held():
            raise ValueError(f"{name}={str(out)!r}: its lock file was deleted during the run, so"
                             f" another run may be writing there; {rescue(result)}")
        # Outputs of an earlier run that this one may not write (figures of a run with
        # figures beside one without, exported tables) must not outlive it.
        for stale in {*files, *EXPORT_FILES} - set(io.RESULT_FILES):
            (out / stale).unlink(missing_ok=True)
        value = save_run(result, out, lambda stats: write(result, stats), bands=bands,
                         statistics=statistics, outputs=files, on_saved=lambda: remove_checkpoint(
                             process_checkpoint_path(checkpoint)))
    return result, value
