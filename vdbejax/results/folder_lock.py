"""One run's files per result folder: a writer lock, a run marker and leftover cleanup.

* **Lock.** A run takes an exclusive ``flock`` on ``<folder>/.vdbejax.lock`` before it
  trains, and holds it until its last file is written; then it removes the file. A second
  run into the same folder is refused at once with one line (no training). The operating
  system drops the lock when the process ends, however it ends, so a killed run never
  leaves the folder locked (its lock file stays, unlocked, until the next run). A lock
  file deleted during a run is noticed before the results are written
  (:meth:`FolderLock.held`).
* **Run marker.** ``<folder>/.vdbejax-writing`` exists while a run replaces the folder's
  files. Its ``stage`` says how far it got: ``"results"`` while ``returns.npz``,
  ``configs.csv`` and ``meta.json`` are written (they may then mix two runs: loading is
  refused), ``"outputs"`` while the summary, figures and report are (the raw results are
  one run's: ``vdbejax plot`` redraws the rest and removes the marker). A run killed
  while writing leaves the marker, so a half-rewritten folder is recognised, never
  mistaken for a whole one.
* **Leftovers.** Atomic writes go through ``.<name>.<pid>.<random>.tmp`` files; those of
  processes no longer alive (killed during a write) are removed when a run starts.
"""
from __future__ import annotations

import errno
import json
import os
import re
import warnings
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from types import ModuleType
from typing import Any, TypeVar

from vdbejax import _interrupts as interrupts
from vdbejax.results import io
from vdbejax.validation import check_writable_dir, missing_folders

fcntl: ModuleType | None
try:
    import fcntl
except ImportError:  # Windows: no advisory locks; the marker still tells half-written folders
    fcntl = None

LOCK_FILE = ".vdbejax.lock"
MARKER_FILE = ".vdbejax-writing"
#: Stages of the run marker (module docstring).
STAGES = ("results", "outputs")
T = TypeVar("T")
_TEMPORARY = re.compile(r"^\..+\.(\d+)\.[^.]+\.tmp$")


def output_folder(path: Any, name: str = "out", *, own: Sequence[str] = (),
                  overwrite: bool = False) -> tuple[Path, FolderLock]:
    """A command's output folder, made writable (``check_writable_dir``), and its lock
    (not yet taken), which removes the folder and the parents this call made again if
    the lock cannot be taken (a full disk).

    An existing folder that holds entries must be a vdbejax folder: one of its entries is
    named in ``own`` (what the command writes there) or is a run's ``meta.json``, lock,
    marker or atomic-write temporary; a folder of other files is refused in one line
    (nothing created) unless ``overwrite``, so that a run's outputs never mix with a
    user's files without a word.
    """
    made = tuple(missing_folders(path)) if isinstance(path, (str, os.PathLike)) else ()
    if not made and not overwrite and isinstance(path, (str, os.PathLike)) \
            and os.path.isdir(path):
        check_own_folder(Path(path), own, name)
    out = check_writable_dir(name, path)
    return out, FolderLock(out, name, created=made)


def check_own_folder(folder: Path, own: Sequence[str], name: str = "out") -> None:
    """Refuse a folder that holds entries of which none is a vdbejax output (``own``, a
    run's ``meta.json``, lock or marker): :func:`output_folder`.

    Raises:
      ValueError: such a folder, in one line naming a few of its entries.
    """
    try:
        entries = sorted(entry.name for entry in os.scandir(folder))
    except OSError:
        return  # an unreadable folder: check_writable_dir says what is wrong with it
    recognised = {*own, io.META_FILE, LOCK_FILE, MARKER_FILE}
    if not entries or any(e in recognised or _TEMPORARY.match(e) for e in entries):
        return  # empty, or a vdbejax folder (a killed writer's temporaries too)
    shown = ", ".join(entries[:3]) + (f" and {len(entries) - 3} more" if len(entries) > 3
                                      else "")
    raise ValueError(f"{name}={str(folder)!r} is not a vdbejax result folder and holds files"
                     f" ({shown}): choose a new or empty folder, or pass --overwrite"
                     " (overwrite=True) to write into it anyway")


class FolderLock:
    """Exclusive use of a result folder by this process (``with FolderLock(folder): …``).

    Args:
      folder: the result folder.
      name: its parameter name in error messages.
      created: the folders the caller made for this run, ``folder`` first, then the
        parents it made: a lock that cannot be taken (a full disk) removes them again.

    Raises (on entry):
      ValueError: another process (or another writer of this one) holds the folder, or
        the lock file cannot be written (what was made for it is removed again).

    On exit the lock is given back even when its file cannot be removed (a folder made
    unwritable during the run): the file is named at the end of the one-line
    ``ValueError`` the run is failing with, or in a ``RuntimeWarning`` after a run that
    saved its results (an unlocked lock file is harmless: the next run takes it).
    """

    def __init__(self, folder: str | os.PathLike, name: str = "out", *,
                 created: tuple[Path, ...] = ()) -> None:
        self.folder = Path(folder)
        self.name = name
        self.created = created
        self._fd: int | None = None

    def __enter__(self) -> FolderLock:
        self.acquire()
        return self

    def __exit__(self, kind: Any, error: BaseException | None, traceback: Any) -> None:
        not_removed = self.release()
        if isinstance(error, ValueError):  # the run's one line, with what it left
            left = left_behind(self.folder, not_removed)
            if left:
                raise ValueError(f"{error}; {left}") from None
        elif error is None and not_removed:
            warnings.warn(f"{self.name}={str(self.folder)!r}: the results are saved, but"
                          f" {left_behind(self.folder, not_removed, temporaries=False)}",
                          RuntimeWarning,
                          stacklevel=2)

    def acquire(self) -> None:
        """Take the lock, then remove the temporary files of dead writers. A stop asked
        while the lock is taken waits until it is registered for release, and then
        leaves with the lock given back (never a lock file without its holder)."""
        with interrupts.deferred():
            self._take()
        try:
            interrupts.raise_pending()
            remove_stale_temporaries(self.folder)
        except BaseException:
            self.release()
            raise

    def _take(self) -> None:
        path = self.folder / LOCK_FILE
        existed = path.exists()
        while True:
            try:
                fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o666)
            except OSError as error:
                raise ValueError(f"{self.name}={str(self.folder)!r} cannot be locked for"
                                 f" writing: {error.strerror or error} ({path})") from None
            if fcntl is None:
                break
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except OSError as error:
                holder = os.pread(fd, 32, 0).decode(errors="replace").strip() or "?"
                os.close(fd)
                if error.errno not in (errno.EWOULDBLOCK, errno.EAGAIN, errno.EACCES):
                    raise ValueError(f"{self.name}={str(self.folder)!r} cannot be locked for"
                                     f" writing: {error.strerror or error}") from None
                who = "this process" if holder == str(os.getpid()) else f"process {holder}"
                raise ValueError(f"{self.name}={str(self.folder)!r} is being written by another"
                                 f" vdbejax run ({who}): wait for it to finish or choose another"
                                 " folder") from None
            if _same_file(path, fd):
                break
            os.close(fd)  # its holder removed it on release: lock the file there now
        try:
            os.ftruncate(fd, 0)
            os.pwrite(fd, str(os.getpid()).encode(), 0)
        except OSError as error:  # a full disk: undo what this lock made, then one line
            os.close(fd)
            left = left_behind(self.folder, self._undo_failed_lock(path, existed))
            raise ValueError(f"{self.name}={str(self.folder)!r} cannot be locked for writing:"
                             f" {describe_os_error(error)}"
                             f"{'; ' + left if left else ''}") from None
        self._fd = fd
        interrupts.hold(id(self), self.release)  # released too if a watchdog ends the process

    def held(self) -> bool:
        """Whether the lock file is still the one this lock holds (someone may have
        deleted it during the run, letting another writer in)."""
        return self._fd is not None and (fcntl is None
                                         or _same_file(self.folder / LOCK_FILE, self._fd))

    def _undo_failed_lock(self, path: Path, existed: bool) -> dict[Path, str]:
        """Remove the lock file (unless it was there before) and the folders the caller
        made, deepest first; returns what could not be removed, with why."""
        not_removed: dict[Path, str] = {}
        for target, remove in ((path, None if existed else path.unlink),
                               *((made, made.rmdir) for made in self.created)):
            if remove is None:
                continue
            try:
                remove()
            except FileNotFoundError:
                pass
            except OSError as error:
                not_removed[target] = error.strerror or str(error)
                if target != path:
                    break  # a folder left: its parents are not empty
        return not_removed

    def release(self) -> dict[Path, str]:
        """Give the lock back and remove the lock file (a writer that opened it meanwhile
        finds it gone once it holds it, and locks a new one: :meth:`acquire`).

        Returns:
          the lock file, with why, if it could not be removed (the lock is given back
          all the same); else nothing.
        """
        interrupts.let_go(id(self))
        not_removed: dict[Path, str] = {}
        if self._fd is not None:
            fd, self._fd = self._fd, None
            try:
                if fcntl is not None:
                    path = self.folder / LOCK_FILE
                    if _same_file(path, fd):
                        try:
                            path.unlink(missing_ok=True)
                        except OSError as error:  # a folder made unwritable meanwhile
                            not_removed[path] = error.strerror or str(error)
                    fcntl.flock(fd, fcntl.LOCK_UN)
            finally:
                os.close(fd)
        return not_removed


def left_behind(folder: str | os.PathLike, not_removed: dict[Path, str], *,
                temporaries: bool = True) -> str:
    """What a failed run leaves in ``folder`` that is this process's to remove, for the
    end of its one-line error ("" when nothing is left): the files in ``not_removed``
    (with why) and, with ``temporaries``, this process's temporary files."""
    names = [f"{path} ({why})" for path, why in not_removed.items()]
    try:
        entries = sorted(Path(folder).iterdir()) if temporaries else []
    except OSError:
        entries = []
    for entry in entries:
        match = _TEMPORARY.match(entry.name)
        if match and int(match.group(1)) == os.getpid() and entry not in not_removed:
            names.append(str(entry))
    return f"could not remove {', '.join(names)}" if names else ""


def _same_file(path: Path, fd: int) -> bool:
    try:
        return os.stat(path).st_ino == os.fstat(fd).st_ino
    except OSError:
        return False


def check_output_paths(folder: str | os.PathLike, names: list[str], name: str = "out") -> None:
    """Refuse, before any training, output paths that exist but are not files.

    Raises:
      ValueError: ``folder/<one of names>`` is a folder (or another non-file).
    """
    for file_name in names:
        path = Path(folder) / file_name
        if path.exists() and not path.is_file():
            raise ValueError(f"{name}={str(folder)!r} is invalid: {str(path)!r} is not a file,"
                             " so the result cannot be written there")


def remove_stale_temporaries(folder: str | os.PathLike) -> list[Path]:
    """Delete the ``.<name>.<pid>.<random>.tmp`` files of processes no longer alive.

    Returns:
      the files removed.
    """
    removed: list[Path] = []
    try:
        entries = list(Path(folder).iterdir())
    except OSError:
        return removed
    for entry in entries:
        match = _TEMPORARY.match(entry.name)
        if match and not _alive(int(match.group(1))):
            try:
                entry.unlink()
                removed.append(entry)
            except OSError:
                pass
    return removed


def _alive(pid: int) -> bool:
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except (PermissionError, OverflowError, OSError):
        return True  # someone else's live process (or not ours to judge): keep its files
    return True


def mark(folder: str | os.PathLike, stage: str) -> None:
    """Write the run marker: ``stage`` of :data:`STAGES` is being written now."""
    from vdbejax.results.io import atomic_write_text

    if stage not in STAGES:
        raise ValueError(f"stage={stage!r} is invalid: must be one of {', '.join(STAGES)}")
    atomic_write_text(Path(folder) / MARKER_FILE,
                      json.dumps({"stage": stage, "pid": os.getpid()}) + "\n")


def unmark(folder: str | os.PathLike) -> None:
    """Remove the run marker: the folder holds one whole run."""
    (Path(folder) / MARKER_FILE).unlink(missing_ok=True)


def marked_stage(folder: str | os.PathLike) -> str | None:
    """The stage of a run marker left in ``folder`` (``None``: no marker). An unreadable
    marker counts as ``"results"``, the cautious reading."""
    path = Path(folder) / MARKER_FILE
    if not path.exists():
        return None
    try:
        stage = json.loads(path.read_text()).get("stage")
    except (OSError, ValueError, AttributeError):
        return "results"
    return stage if stage in STAGES else "results"


def save_run(
    result: Any,
    out: str | os.PathLike,
    write: Callable[[Any], T],
    *,
    bands: bool,
    on_saved: Callable[[], None] | None = None,
    statistics: bool = True,
    outputs: Sequence[str] = (),
) -> T:
    """Save a trained grid into ``out`` and write its outputs, marking the folder.

    ``returns.npz``, ``configs.csv`` and ``meta.json`` are written on a thread while the
    statistics are computed (zlib and numpy release the GIL); ``write(statistics)`` then
    writes the summary, figures and report. The marker's stages tell how far a killed
    run got (module docstring); ``on_saved`` runs once the results are saved (e.g. to
    delete the run's checkpoint).

    Args:
      result: the :class:`~vdbejax.results.grid_result.GridResult`.
      out: the (locked) result folder.
      write: writes the outputs from the :class:`~vdbejax.results.stats.CurveStatistics`.
      bands: compute Figure 3's bootstrap bands too.
      on_saved: called after the save.
      statistics: compute the statistics (``False``: ``write(None)``).
      outputs: the files ``write`` may write: those it did are added to the folder's
        manifest (:mod:`vdbejax.results.manifest`).

    Returns:
      what ``write`` returns.

    Raises:
      ValueError: an operating-system error while writing (disk full, a path that is a
        folder, permissions): one line naming the path; the computed results are kept,
        in ``out`` if they were saved there, else in a rescue folder the message names.
    """
    from vdbejax.results.manifest import write_manifest
    from vdbejax.results.stats import curve_statistics

    out = Path(out)
    try:
        mark(out, "results")
        with ThreadPoolExecutor(1) as pool:
            saved = pool.submit(result.write_files, out)
            try:
                computed = (curve_statistics(result.returns, bands=bands) if statistics
                            else None)
            finally:
                failure = saved.exception()
            if failure is not None:
                raise failure
    except OSError as error:
        raise ValueError(f"cannot write the results in {str(out)!r}: {describe_os_error(error)};"
                         f" {rescue(result)}") from None
    if on_saved is not None:
        on_saved()
    try:
        mark(out, "outputs")
        value = write(computed)
        write_manifest(out, result.meta, outputs, keep=True)
        unmark(out)
    except OSError as error:
        raise ValueError(f"cannot write the outputs in {str(out)!r}:"
                         f" {describe_os_error(error)}; the"
                         f" results are saved there: 'vdbejax plot --results {out}' writes"
                         " the summary and figures again") from None
    return value


def describe_os_error(error: OSError) -> str:
    """``error``'s reason and, where known, the path it concerns (for one-line errors)."""
    where = f" ({error.filename})" if getattr(error, "filename", None) else ""
    return f"{error.strerror or error}{where}"


def rescue(result: Any) -> str:
    """Save ``result`` in a fresh folder under the temporary directory; say where."""
    import tempfile

    try:
        folder = Path(tempfile.mkdtemp(prefix="vdbejax-rescued-"))
        result.save(folder)
    except OSError as error:
        return f"the results could not be kept elsewhere either ({describe_os_error(error)})"
    return (f"the results were kept in {str(folder)!r}"
            f" ('vdbejax plot --results {folder}' draws them)")
