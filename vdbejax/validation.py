"""Input checks shared by every public entry point and the CLI.

Each check raises ``ValueError`` with one line naming the parameter, the value and what
is allowed, so the CLI can print it and exit 2.
"""
from __future__ import annotations

import contextlib
import difflib
import itertools
import math
import operator
import os
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import numpy as np

from vdbejax import _interrupts


def _fail(name: str, value: Any, allowed: str) -> None:
    if isinstance(value, (np.ndarray, np.generic)) and np.ndim(value) == 0:
        value = value.item()  # a hyperparameter leaf: show the plain number
    raise ValueError(f"{name}={value!r} is invalid: {allowed}")


def _is_number(value: Any) -> bool:
    if isinstance(value, np.ndarray) and value.dtype == np.bool_:
        return False
    try:
        float(value)
    except (TypeError, ValueError, OverflowError):
        return False
    return not isinstance(value, (bool, np.bool_, str, bytes))


def nearest_names(value: Any, allowed: Iterable[str]) -> str:
    """`` (did you mean a or b?)``: the names of ``allowed`` nearest to a mistyped
    ``value`` (:func:`difflib.get_close_matches`, at most three), or ``""`` if none is
    near (or ``value`` is not a string)."""
    if not isinstance(value, str):
        return ""
    close = difflib.get_close_matches(value, list(allowed), n=3, cutoff=0.6)
    return f" (did you mean {' or '.join(close)}?)" if close else ""


def check_choice(name: str, value: Any, allowed: Iterable[str]) -> str:
    """Check ``value`` is one of the names ``allowed`` (a typo gets the nearest names)."""
    allowed = tuple(allowed)
    if value not in allowed:
        _fail(name, value, "must be one of " + ", ".join(allowed)
              + nearest_names(value, allowed))
    return value


def check_in_range(
    name: str,
    value: Any,
    low: float,
    high: float,
    *,
    low_open: bool = False,
    high_open: bool = False,
) -> float:
    """Check ``value`` is a finite number in the interval (described in the message)."""
    lo_b, hi_b = ("(" if low_open else "["), (")" if high_open else "]")
    interval = f"{lo_b}{low:g}, {high:g}{hi_b}"
    if not _is_number(value) or math.isnan(float(value)):
        _fail(name, value, f"must be a number in {interval}")
    v = float(value)
    ok_low = v > low if low_open else v >= low
    ok_high = v < high if high_open else v <= high
    if not (ok_low and ok_high):
        _fail(name, value, f"must be in {interval}")
    return v


def check_positive(name: str, value: Any, *, allow_inf: bool = False) -> float:
    """Check ``value`` is a number > 0 (finite unless ``allow_inf``)."""
    if not _is_number(value) or math.isnan(float(value)) or float(value) <= 0:
        _fail(name, value, "must be a number > 0")
    if math.isinf(float(value)) and not allow_inf:
        _fail(name, value, "must be a finite number > 0")
    return float(value)


def check_finite(name: str, value: Any) -> float:
    """Check ``value`` is a finite number."""
    if not _is_number(value) or not math.isfinite(float(value)):
        _fail(name, value, "must be a finite number")
    return float(value)


#: Largest value of a signed 32-bit integer (counts, sizes, step limits).
INT32_MAX = 2**31 - 1
#: Largest value of an unsigned 32-bit integer (random seeds).
UINT32_MAX = 2**32 - 1


def check_int(name: str, value: Any, minimum: int = 1, maximum: int | None = None) -> int:
    """Check ``value`` is an integer (not a bool, float or string) >= ``minimum``.

    Args:
      name: the parameter's name, for the message.
      value: the value to check.
      minimum: the smallest allowed value.
      maximum: the largest allowed value, or None for no upper bound.

    Returns:
      ``int(value)``: a plain Python int, also for numpy integers.
    """
    allowed = f"must be an integer >= {minimum}" + (
        "" if maximum is None else f" and <= {maximum}")
    if isinstance(value, (bool, np.bool_)):
        _fail(name, value, allowed)
    try:  # an int or numpy integer; not a float, nor a float array that int() would cut
        number = operator.index(value)
    except TypeError:
        _fail(name, value, allowed)
    if number < minimum or (maximum is not None and number > maximum):
        _fail(name, value, allowed)
    return number


def check_bool(name: str, value: Any) -> bool:
    """Check ``value`` is True or False."""
    if not isinstance(value, (bool, np.bool_)):
        _fail(name, value, "must be True or False")
    return bool(value)


def check_instance(name: str, value: Any, kind: type) -> Any:
    """Check ``value`` is a ``kind`` (one of the dataclasses an entry point takes)."""
    if not isinstance(value, kind):
        article = "an" if kind.__name__[0] in "AEIOU" else "a"
        _fail(name, value, f"must be {article} {kind.__name__}")
    return value


def first_bad(label: str, arr: np.ndarray, bad: np.ndarray, allowed: str) -> None:
    """Raise for the first element of ``arr`` where ``bad`` holds, naming its position
    (``label[i, j, …] = value: allowed``)."""
    if np.any(bad):
        where = tuple(int(i) for i in np.unravel_index(np.argmax(bad), bad.shape))
        value = arr[where]
        value = value.item() if isinstance(value, np.generic) else value
        raise ValueError(f"{label}{list(where)} = {value!r}: {allowed}")


def json_plain(value: Any) -> Any:
    """A NumPy scalar or array as the Python number or list JSON writes (``json.dumps``'s
    ``default``: any other type is refused as JSON refuses it)."""
    if isinstance(value, (np.generic, np.ndarray)):
        return value.tolist()
    raise TypeError(f"Object of type {type(value).__name__} is not JSON serializable")


def missing_folders(path: str | os.PathLike) -> list[Path]:
    """``path`` and its parents that do not exist yet, deepest first (what creating the
    folder makes, and what to remove again if the run fails before writing)."""
    folder = Path(path)
    return list(itertools.takewhile(lambda p: not os.path.lexists(p), (folder, *folder.parents)))


def check_writable_dir(name: str, path: Any) -> Path:
    """Create folder ``path`` if needed and check files can be written into it.

    Raises:
      ValueError: the folder cannot be created or is not writable (a file of that name
        exists, a parent is a file, permissions, read-only file system, …).
    """
    if not isinstance(path, (str, os.PathLike)) or not str(path):
        _fail(name, path, "must be a folder path")
    _interrupts.raise_pending()  # a stop the command line recorded: before any folder exists
    folder = Path(path)
    made = missing_folders(folder)
    try:
        folder.mkdir(parents=True, exist_ok=True)
        probe = folder / f".write-test-{os.getpid()}"
        probe.write_bytes(b"")
        probe.unlink()
    except OSError as error:
        for created in made:  # a full disk: the folders made here go again, deepest first
            with contextlib.suppress(OSError):
                created.rmdir()
        _fail(name, str(folder), f"must be a writable folder ({error.strerror or error})")
    return folder


#: Suffixes accepted by :func:`parse_bytes` (binary multiples).
BYTE_UNITS = {"": 1, "k": 2**10, "m": 2**20, "g": 2**30, "t": 2**40}


def parse_bytes(name: str, text: Any) -> int:
    """A memory size from ``1000``, ``512M``, ``2G``, ``1.5GiB`` … (binary units) in bytes.

    Raises:
      ValueError: not a positive size.
    """
    allowed = "must be a size in bytes > 0, e.g. 1000000, 512M, 2G"
    if hasattr(text, "__index__") and not isinstance(text, (bool, np.bool_)):
        if int(text) < 1:
            _fail(name, text, allowed)
        return int(text)
    raw = str(text).strip().lower().removesuffix("ib").removesuffix("b")
    unit = raw[-1:] if raw[-1:] in BYTE_UNITS else ""
    number = raw[: len(raw) - len(unit)]
    try:
        value = float(number) * BYTE_UNITS[unit]
    except ValueError:
        _fail(name, text, allowed)
    if not math.isfinite(value) or value < 1:
        _fail(name, text, allowed)
    return int(value)


def parse_cli_number(text: str) -> Any:
    """argparse ``type`` for numeric options: int, else float, else the raw text.

    Nothing is rejected here, so the library's checks produce the one-line error (with
    the parameter name and what is allowed) for the CLI and for Python alike.
    """
    for convert in (int, float):
        try:
            return convert(text)
        except ValueError:
            pass
    return text
