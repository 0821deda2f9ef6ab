"""Result files: atomic writes, ``returns.npz``, ``configs.csv``, ``meta.json``.

Every file is written to a temporary file in the same folder and renamed into place, so a
run killed at any moment never leaves a half-written result.
"""
from __future__ import annotations

import contextlib
import csv
import io
import json
import os
import secrets
from collections.abc import Iterator
from pathlib import Path
from typing import TYPE_CHECKING, Any, BinaryIO

import numpy as np

from vdbejax.validation import json_plain

if TYPE_CHECKING:  # read at run time only where settings are loaded: importing this module
    from vdbejax.methods.agents import Setting  # (the CLI does) does not import JAX

RETURNS_FILE = "returns.npz"
#: A command's checkpoint in its result folder (``--resume`` continues from it).
CHECKPOINT_FILE = "checkpoint.npz"
CONFIGS_FILE = "configs.csv"
META_FILE = "meta.json"
#: The raw result files of a run (GridResult.save).
RESULT_FILES = (RETURNS_FILE, CONFIGS_FILE, META_FILE)


def atomic_write_bytes(path: str | os.PathLike, data: bytes | memoryview) -> None:
    """Write ``data`` to ``path`` atomically (temporary file + rename)."""
    with atomic_file(path) as f:
        f.write(data)


@contextlib.contextmanager
def atomic_file(path: str | os.PathLike) -> Iterator[BinaryIO]:
    """A binary file that becomes ``path`` when the block ends without an exception
    (written to a temporary file in the same folder and renamed into place; removed on any
    exception, Ctrl-C included)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    # The writer's pid in the name lets a later run remove what a killed one left behind
    # (vdbejax.results.folder_lock.remove_stale_temporaries).
    tmp = None
    try:
        while True:  # named before it exists: a stop at any moment leaves no file unnamed
            tmp = path.parent / f".{path.name}.{os.getpid()}.{secrets.token_hex(4)}.tmp"
            try:  # the umask applies to 0o666, as for any file the user writes
                fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
                break
            except FileExistsError:
                continue
        with os.fdopen(fd, "wb") as f:
            yield f
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
        _fsync_dir(path.parent)  # make the rename itself survive a power loss
    except BaseException:
        if tmp is not None and os.path.exists(tmp):
            with contextlib.suppress(OSError):  # the first error says why (a folder made
                os.unlink(tmp)  # unwritable); the run's one line names the file left
        raise


def _fsync_dir(folder: Path) -> None:
    try:
        fd = os.open(folder, os.O_RDONLY)
    except OSError:  # platforms that cannot open folders
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def atomic_write_text(path: str | os.PathLike, text: str) -> None:
    """Write UTF-8 ``text`` to ``path`` atomically."""
    atomic_write_bytes(path, text.encode("utf-8"))


def atomic_savez(path: str | os.PathLike, *, compressed: bool = True, **arrays: Any) -> None:
    """``np.savez_compressed`` (or ``np.savez`` when not ``compressed``) written atomically.

    Checkpoints, rewritten after every chunk and deleted at the end, are not compressed:
    zlib would cost more than the training of a chunk.
    """
    buffer = io.BytesIO()
    (np.savez_compressed if compressed else np.savez)(buffer, **arrays)
    atomic_write_bytes(path, buffer.getbuffer())  # a view: no second copy of a checkpoint


def save_figure(fig: Any, path: str | os.PathLike) -> None:
    """Save a matplotlib figure as PNG atomically, then free its memory."""
    import matplotlib.pyplot as plt

    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=110)
    atomic_write_bytes(path, buffer.getvalue())
    plt.close(fig)


def write_csv(path: str | os.PathLike, rows: list[dict[str, Any]], columns: list[str]) -> None:
    """Write ``rows`` (dicts) with header ``columns`` atomically; floats with 6 digits."""
    buffer = io.StringIO()
    writer = csv.DictWriter(buffer, fieldnames=columns, lineterminator="\n")
    writer.writeheader()
    for row in rows:
        writer.writerow({c: _format(row[c]) for c in columns})
    atomic_write_text(path, buffer.getvalue())


def _format(value: Any) -> Any:
    if isinstance(value, (float, np.floating)):
        return f"{float(value):.6g}"
    return value


def read_csv(path: str | os.PathLike) -> list[dict[str, str]]:
    """Rows of a CSV file as dicts of strings."""
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


CONFIG_COLUMNS = ["config", "learner", "explorer", "param"]


def save_settings(path: str | os.PathLike, settings: list[Setting]) -> None:
    """``configs.csv``: ``config,learner,explorer,param``, one row per config index, and
    ``hyperparameters`` (the setting's other explicit values, JSON) when any setting has
    some. A blank ``param`` is the explorer's default. (Every agent's resolved
    hyperparameters are in ``meta.json``.)"""
    rows = [
        {"config": i, "learner": s.learner, "explorer": s.explorer,
         "param": "" if s.param is None else s.param, "hyperparameters": s.hyperparameters_json()}
        for i, s in enumerate(settings)
    ]
    columns = list(CONFIG_COLUMNS)
    if any(s.hyperparameters for s in settings):
        columns.append("hyperparameters")
    write_csv(path, rows, columns)


def load_settings(path: str | os.PathLike) -> list[Setting]:
    """Settings of ``configs.csv`` in config-index order.

    Raises:
      ValueError: a missing column, or config indices that are not 0, 1, … once each.
    """
    from vdbejax.methods.agents import Setting

    rows = read_csv(path)
    try:
        indices = [int(r["config"]) for r in rows]
        for r in rows:
            r["learner"], r["explorer"], r["param"]
    except (KeyError, TypeError, ValueError) as error:
        raise ValueError(f"results file {str(path)!r} is damaged:"
                         f" {type(error).__name__}: {error}") from None
    if sorted(indices) != list(range(len(rows))):
        repeated = sorted({i for i in indices if indices.count(i) > 1})
        raise ValueError(f"results file {str(path)!r} is damaged: config indices must be"
                         f" 0…{len(rows) - 1} once each"
                         + (f"; repeated: {repeated[:5]}" if repeated else ""))
    rows = [row for _, row in sorted(zip(indices, rows, strict=True), key=lambda pair: pair[0])]
    try:
        return [Setting(r["learner"], r["explorer"],
                        float(r["param"]) if r["param"] not in ("", None) else None,
                        json.loads(r.get("hyperparameters") or "{}")) for r in rows]
    except ValueError as error:  # a parameter that is no number, hyperparameters no JSON
        raise ValueError(f"results file {str(path)!r} is damaged: {error}") from None


def save_json(path: str | os.PathLike, data: dict[str, Any]) -> None:
    """Write ``data`` as indented, key-sorted JSON atomically (NumPy scalars as numbers)."""
    atomic_write_text(path, json.dumps(data, indent=2, sort_keys=True, default=json_plain) + "\n")


def load_json(path: str | os.PathLike) -> dict[str, Any]:
    """Read a JSON file."""
    with open(path) as f:
        return json.load(f)
