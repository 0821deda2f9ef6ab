"""Any result folder as long (tidy) tables: CSV, or Parquet with pyarrow installed.

:func:`export_results` (``vdbejax export D``) finds every run a folder holds — the folder
itself and every folder below it with ``returns.npz``, ``configs.csv`` and ``meta.json``:
a ``run`` or ``reproduce`` folder is one run; ``bench`` keeps one per task (and per
tuning pool), ``depth`` and ``scale`` one per task or size, ``ablate`` one per variant —
and writes up to three tables, one row per observation:

* ``returns_long`` — per run × setting × agent × episode: ``return`` and ``length``
  (NaN and 0 past an agent's stop, under a stop policy), and ``optimal_actions`` for runs
  that record them (``record_optimal``; blank for the others);
* ``summaries_long`` — per run × setting × ``scope``: the columns of ``summary.csv``
  (:mod:`vdbejax.results.summary`); ``scope`` is ``all agents``, or with replicates
  ``replicate 0`` (``summary.csv``), ``pooled`` (``summary_pooled.csv``) and ``replicate
  r`` (``replicates.csv``'s rows); a run folder without ``summary.csv`` (``bench``'s) is
  summarised here (:func:`~vdbejax.results.analysis.summarize`);
* ``evaluations_long`` — per run × setting × agent × evaluation, for runs with
  ``evaluate_every`` (:mod:`vdbejax.results.policy`): the ``episode`` after which it was
  taken, ``policy_value`` (``V^π``), ``policy_gap`` (``V* − V^π``) and ``optimal``;
* ``claims_long`` — per run × claim × check × agents (all, or a replicate), for runs that
  scored claims (``claims.csv``, :mod:`vdbejax.results.claim_report`): its columns.

Every table but ``claims_long`` (``run`` and ``task``, then ``claims.csv``'s columns)
starts with the columns that name the setting: ``run`` (the run's folder
relative to the exported one, ``.`` for itself), ``task``, ``config``, ``setting`` (its
label), ``learner``, ``explorer``, ``param`` and one column per hyperparameter whose value
differs between the exported settings (blank where a setting has no such field; every
value is in ``meta.json``), then ``seed`` (the agent's index within its setting) and
``replicate`` (where a run has several). :meth:`GridResult.to_records
<vdbejax.results.grid_result.GridResult.to_records>` is the returns table of one run in
memory.
"""
from __future__ import annotations

import csv
import io as text_io
import os
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from vdbejax.results import io
from vdbejax.results.analysis import summarize
from vdbejax.results.claim_report import CLAIMS_COLUMNS, CLAIMS_FILE
from vdbejax.results.grid_result import (
    Columns,
    GridResult,
    agent_columns,
    hyperparameter_names,
    returns_columns,
    setting_columns,
)
from vdbejax.results.policy import optimal_agents, policy_gaps
from vdbejax.results.replicates import POOLED_SUMMARY_FILE, REPLICATES_FILE
from vdbejax.results.summary import SUMMARY_FILE, read_summary
from vdbejax.validation import check_choice

#: The tables, each written as ``<name>.csv`` or ``<name>.parquet``.
TABLE_FILES = {"returns": "returns_long", "summaries": "summaries_long",
               "evaluations": "evaluations_long", "claims": "claims_long"}
FORMATS = ("csv", "parquet")
#: Every file an export may write into a folder.
EXPORT_FILES = [f"{name}.{ext}" for name in TABLE_FILES.values() for ext in FORMATS]
#: Rows per block of a CSV being written (its text is never held whole).
CSV_BLOCK_ROWS = 100_000

def evaluation_columns(result: GridResult, names: Sequence[str]) -> Columns | None:
    """The evaluations table of one run (None: it has no policy evaluations)."""
    if result.policy_values is None:
        return None
    configs, seeds, evaluations = result.policy_values.shape
    columns = agent_columns(result, names, evaluations)
    columns["evaluation"] = np.tile(np.arange(1, evaluations + 1), configs * seeds)
    columns["episode"] = np.tile(result.evaluation_episodes, configs * seeds)
    columns["policy_value"] = result.policy_values.reshape(-1)
    columns["policy_gap"] = policy_gaps(result).reshape(-1)
    optimal = optimal_agents(result).reshape(-1)
    flags = np.empty(optimal.size, dtype=object)
    flags[:] = [None if np.isnan(v) else bool(v) for v in optimal]
    columns["optimal"] = flags
    return columns


def _summary_scopes(result: GridResult, folder: Path) -> list[tuple[str, list[dict[str, Any]]]]:
    """``(scope, rows)`` of a run's summaries (module docstring), rows as column dicts."""
    replicates = int(result.meta.get("replicates", 1))
    if not (folder / SUMMARY_FILE).is_file():
        return [("all agents", [row.as_dict() for row in summarize(result)])]
    scopes = [("all agents" if replicates == 1 else "replicate 0",
               [row.as_dict() for row in read_summary(folder / SUMMARY_FILE)])]
    if replicates > 1 and (folder / POOLED_SUMMARY_FILE).is_file():
        scopes.append(("pooled", [row.as_dict() for row in
                                  read_summary(folder / POOLED_SUMMARY_FILE)]))
    if replicates > 1 and (folder / REPLICATES_FILE).is_file():
        rows = io.read_csv(folder / REPLICATES_FILE)
        for r in range(1, replicates):
            scopes.append((f"replicate {r}", [
                {k: _number(v) for k, v in row.items() if k != "replicate"}
                for row in rows if row.get("replicate") == str(r)]))
    return scopes


def claims_columns(folder: Path) -> Columns | None:
    """The claims table of one run: ``claims.csv``'s rows (``None`` without one)."""
    if not (folder / CLAIMS_FILE).is_file():
        return None
    rows = io.read_csv(folder / CLAIMS_FILE)
    return {name: _objects([_number(row[name]) if row.get(name) else None for row in rows])
            for name in CLAIMS_COLUMNS}


def _number(text: str) -> Any:
    try:
        return int(text)
    except ValueError:
        try:
            return float(text)
        except ValueError:
            return text


def summary_columns(result: GridResult, folder: Path, names: Sequence[str]) -> Columns:
    """The summaries table of one run: its setting columns, ``scope``, then the summary's
    statistics (the setting's columns ``summary.csv`` repeats are left out)."""
    settings = setting_columns(result, names)
    naming = {"config", "learner", "explorer", "param", "hyperparameters"}
    blocks = []
    for scope, rows in _summary_scopes(result, folder):
        configs = np.array([int(row["config"]) for row in rows], dtype=np.int64)
        block = {name: values[configs] for name, values in settings.items()}
        block["scope"] = np.full(len(rows), scope, dtype=object)
        stats = [k for row in rows for k in row if k not in naming]
        for name in dict.fromkeys(stats):
            block[name] = _objects([row.get(name) for row in rows])
        blocks.append(block)
    return concatenate(blocks)


def _objects(values: list[Any]) -> np.ndarray:
    array = np.empty(len(values), dtype=object)
    array[:] = values
    return array


def concatenate(blocks: Sequence[Columns]) -> Columns:
    """Blocks of columns as one table: every block's columns in order of appearance, None
    where a block lacks one."""
    names = list(dict.fromkeys(name for block in blocks for name in block))
    table: Columns = {}
    for name in names:
        parts = [block[name] if name in block else
                 np.full(len(next(iter(block.values()))), None, dtype=object)
                 for block in blocks]
        if len({part.dtype for part in parts}) > 1:
            parts = [part.astype(object) for part in parts]
        table[name] = np.concatenate(parts)
    return table


def result_folders(folder: str | os.PathLike) -> list[Path]:
    """Every run's folder in ``folder`` (itself, and any below it, with ``returns.npz``,
    ``configs.csv`` and ``meta.json``), the folder itself first, then by path.

    Raises:
      ValueError: ``folder`` is not a folder, or holds no run.
    """
    root = Path(folder)
    if not root.is_dir():
        what = "is a file" if root.exists() else "does not exist"
        raise ValueError(f"folder={str(root)!r} is invalid: it {what}; give a result folder"
                         " (what vdbejax run, reproduce, bench, depth, scale or ablate wrote)")
    found = [meta.parent for meta in root.rglob(io.META_FILE)
             if all((meta.parent / name).is_file() for name in io.RESULT_FILES)]
    if not found:
        raise ValueError(f"folder={str(root)!r} is invalid: neither it nor a folder below it"
                         f" holds a run ({', '.join(io.RESULT_FILES)})")
    return sorted(found, key=lambda path: path.relative_to(root).parts)


def export_results(folder: str | os.PathLike, out: str | os.PathLike | None = None, *,
                   format: str = "csv", tables: Sequence[str] = tuple(TABLE_FILES),
                   overwrite: bool = False) -> list[Path]:
    """Write every run of a result folder as long tables (module docstring).

    Args:
      folder: the result folder (any command's).
      out: the folder the tables are written into (default: ``folder``).
      format: ``csv`` or ``parquet`` (needs ``pip install pyarrow``, the ``export`` extra).
      tables: which of ``returns``, ``summaries``, ``evaluations`` (only where a run
        evaluated its policies), ``claims`` (only where a run scored claims).
      overwrite: replace tables an earlier export wrote there; without it that is refused.

    Returns:
      the files written.

    Raises:
      ValueError: no result folder, a damaged run (:meth:`GridResult.load`), an unknown
        format or table, pyarrow missing for Parquet, a table already there without
        ``overwrite``, or a file that cannot be written.
    """
    format = check_choice("format", format, FORMATS)
    if isinstance(tables, str) or not tables:
        raise ValueError(f"tables={tables!r} is invalid: must be a non-empty list of"
                         f" {', '.join(TABLE_FILES)}")
    for table in tables:
        check_choice("tables", table, tuple(TABLE_FILES))
    if format == "parquet":
        _pyarrow()
    root = Path(folder)
    folders = result_folders(root)
    target = root if out is None else Path(out)
    if target.exists() and not target.is_dir():
        raise ValueError(f"out={str(target)!r} is invalid: it is a file; give a folder")
    files = {table: target / f"{TABLE_FILES[table]}.{format}" for table in tables}
    there = [path.name for path in files.values() if path.exists()]
    if there and not overwrite:
        raise ValueError(f"out={str(target)!r} already holds {', '.join(there)}: pass"
                         " --overwrite (overwrite=True) to replace it, or choose another folder")
    results = [GridResult.load(path) for path in folders]
    names = hyperparameter_names(results)
    written = []
    for table, path in files.items():
        blocks = []
        for run_folder, result in zip(folders, results, strict=True):
            columns = (returns_columns(result, names) if table == "returns"
                       else summary_columns(result, run_folder, names) if table == "summaries"
                       else claims_columns(run_folder) if table == "claims"
                       else evaluation_columns(result, names))
            if columns is None:
                continue
            rows = len(next(iter(columns.values())))
            run = run_folder.relative_to(root).as_posix()
            blocks.append({"run": np.full(rows, run, dtype=object),
                           "task": np.full(rows, str(result.meta.get("mdp", "")), dtype=object),
                           **columns})
        if not blocks:
            path.unlink(missing_ok=True)  # an earlier export's would go stale
            continue
        try:
            (write_csv if format == "csv" else write_parquet)(path, concatenate(blocks))
        except OSError as error:
            raise ValueError(f"cannot write {str(path)!r}: {error.strerror or error}") from None
        written.append(path)
    return written


def write_csv(path: str | os.PathLike, columns: Columns) -> None:
    """Write equal-length ``columns`` as a CSV (header = their names) atomically, block by
    block; floats with 6 significant digits, None as an empty field."""
    rows = len(next(iter(columns.values()))) if columns else 0
    with io.atomic_file(path) as raw:
        text = text_io.TextIOWrapper(raw, encoding="utf-8", newline="")
        writer = csv.writer(text, lineterminator="\n")
        writer.writerow(list(columns))
        for start in range(0, rows, CSV_BLOCK_ROWS):
            block = [_csv_values(values[start:start + CSV_BLOCK_ROWS])
                     for values in columns.values()]
            writer.writerows(zip(*block, strict=True))
        text.flush()
        text.detach()


def _csv_values(values: np.ndarray) -> Any:
    if np.issubdtype(values.dtype, np.floating):
        return np.char.mod("%.6g", values).astype(object)
    if values.dtype != object:
        return values.tolist()  # Python numbers: the csv module writes them fastest
    distinct, inverse = _distinct(values)
    texts = np.empty(len(distinct), dtype=object)
    texts[:] = [_csv_text(value) for value in distinct]
    return texts[inverse]


def _distinct(values: np.ndarray) -> tuple[list[Any], np.ndarray]:
    """An object column as its distinct objects and each row's index among them: a column
    of the settings' values repeats a few objects, each then converted once."""
    ids = np.fromiter(map(id, values), np.int64, len(values))
    _, first, inverse = np.unique(ids, return_index=True, return_inverse=True)
    return [values[i] for i in first], inverse.reshape(-1)


def _csv_text(value: Any) -> Any:
    return f"{value:.6g}" if isinstance(value, (float, np.floating)) else value


def write_parquet(path: str | os.PathLike, columns: Columns) -> None:
    """Write ``columns`` as a Parquet file atomically (pyarrow): numbers as numbers, text
    as text, None as null."""
    pyarrow, parquet = _pyarrow()
    table = pyarrow.table({name: _arrow(pyarrow, values) for name, values in columns.items()})
    with io.atomic_file(path) as raw:
        parquet.write_table(table, raw)


def _arrow(pyarrow: Any, values: np.ndarray) -> Any:
    """One column as a pyarrow array: an object column of numbers (None: null) as
    float64, of booleans as bool, anything else as text."""
    if values.dtype != object:
        return pyarrow.array(values)
    distinct, inverse = _distinct(values)
    present = [v for v in distinct if v is not None]
    convert: Callable[[Any], Any]
    if all(isinstance(v, (bool, np.bool_)) for v in present):
        kind, convert = pyarrow.bool_(), bool
    elif all(isinstance(v, (int, float, np.integer, np.floating)) for v in present):
        kind, convert = pyarrow.float64(), float
    else:
        kind, convert = pyarrow.string(), str
    converted = pyarrow.array([None if v is None else convert(v) for v in distinct], type=kind)
    return converted.take(pyarrow.array(inverse))


def _pyarrow() -> tuple[Any, Any]:
    try:
        import pyarrow
        import pyarrow.parquet as parquet
    except ImportError:
        raise ValueError("format='parquet' needs pyarrow: pip install pyarrow (or"
                         " 'vdbejax[export]'), or use format='csv'") from None
    return pyarrow, parquet


__all__ = ["EXPORT_FILES", "FORMATS", "TABLE_FILES", "export_results", "result_folders",
           "write_csv"]
