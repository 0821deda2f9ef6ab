"""Two result folders' settings side by side (``vdbejax compare A B``): each setting's
final return with its 95 % bootstrap interval and its convergence episode, in both.

A folder's summary is its pooled one (``summary_pooled.csv``) where it has replicates,
else ``summary.csv`` (written by every run with statistics; ``vdbejax plot --results``
writes it for a folder without). Settings are matched by learner, explorer, parameter and
other hyperparameters; one that only one folder has is shown with a blank other side.
Folders of different tasks (or instance families) are refused unless asked for
(``different_tasks=True``, ``--different-tasks``).
"""
from __future__ import annotations

import math
import os
from pathlib import Path
from typing import Any

from vdbejax.results import io
from vdbejax.results.markdown import table_lines
from vdbejax.results.replicates import POOLED_SUMMARY_FILE
from vdbejax.results.summary import SUMMARY_FILE, SummaryRow, episode_text, read_summary
from vdbejax.validation import check_bool


def folder_summary(folder: str | os.PathLike, name: str) -> list[SummaryRow]:
    """A result folder's summary rows (the pooled ones where it has replicates).

    Raises:
      ValueError: no summary in the folder, or an unreadable one, naming ``name``.
    """
    path = Path(folder)
    for file in (POOLED_SUMMARY_FILE, SUMMARY_FILE):
        if (path / file).is_file():
            try:
                return read_summary(path / file)
            except (OSError, ValueError) as error:
                raise ValueError(f"{name}={str(path / file)!r} is unreadable: {error}") from None
    raise ValueError(f"{name}={str(path)!r} has no {SUMMARY_FILE}: give a result folder"
                     " ('vdbejax plot --results FOLDER' writes the summary of one without)")


def setting_text(row: SummaryRow) -> str:
    """``learner/explorer/param`` and the other hyperparameters, if any."""
    param = "default" if row.param is None else f"{row.param:g}"
    extra = "" if row.hyperparameters in ("", "{}") else f" {row.hyperparameters}"
    return f"{row.learner}/{row.explorer}/{param}{extra}"


def folder_task(folder: str | os.PathLike) -> str | None:
    """The task a result folder's run trained on, as its ``meta.json`` names it (``mdp``;
    ``"testbed:10 (per-agent instances)"`` for a task family's run; the paper's task for
    ``reproduce``'s folders of either reading, which are compared as two readings of it),
    or None without a readable ``meta.json``."""
    try:
        meta = io.load_json(Path(folder) / io.META_FILE)
    except (OSError, ValueError):
        return None
    if not isinstance(meta, dict) or "mdp" not in meta:
        return None
    if "reading" in meta:
        return "the paper's table cleaning"
    mode = meta.get("instances", "shared")
    return str(meta["mdp"]) + ("" if mode == "shared" else f" ({mode} instances)")


def compare_folders(a: str | os.PathLike, b: str | os.PathLike, *,
                    different_tasks: bool = False) -> list[dict[str, Any]]:
    """The settings of folders ``a`` and ``b`` side by side, ``a``'s order first.

    Args:
      a, b: result folders.
      different_tasks: compare folders of different tasks (or instance families, their
        ``meta.json``'s ``mdp`` and ``instances``); without it that is refused, their
        returns are on different scales.

    Returns:
      one dict per setting: ``setting``; ``a_final``, ``a_low``, ``a_high``,
      ``a_convergence`` and the same for ``b`` (NaN where the folder lacks the setting);
      ``difference`` (b − a) and ``overlap`` (the two intervals overlap; None without both).

    Raises:
      ValueError: a folder without a readable summary; folders of different tasks without
        ``different_tasks``.
    """
    sides = {"a": folder_summary(a, "a"), "b": folder_summary(b, "b")}
    tasks = folder_task(a), folder_task(b)
    if not check_bool("different_tasks", different_tasks) and None not in tasks \
            and tasks[0] != tasks[1]:
        raise ValueError(f"a={str(a)!r} ran task {tasks[0]!r} and b={str(b)!r} task"
                         f" {tasks[1]!r}: their returns are not on one scale; pass"
                         " --different-tasks (different_tasks=True) to compare them anyway")
    keyed = {side: {(r.learner, r.explorer, r.param, r.hyperparameters): r for r in rows}
             for side, rows in sides.items()}
    keys = list(dict.fromkeys([*keyed["a"], *keyed["b"]]))
    table = []
    for key in keys:
        entry: dict[str, Any] = {"setting": setting_text(keyed["a"].get(key)
                                                          or keyed["b"][key])}
        for side in ("a", "b"):
            row = keyed[side].get(key)
            entry.update({f"{side}_final": row.final_return if row else math.nan,
                          f"{side}_low": row.final_ci_low if row else math.nan,
                          f"{side}_high": row.final_ci_high if row else math.nan,
                          f"{side}_convergence": row.convergence_episode if row else math.nan})
        both = key in keyed["a"] and key in keyed["b"]
        entry["difference"] = entry["b_final"] - entry["a_final"]
        entry["overlap"] = (entry["a_low"] <= entry["b_high"] and entry["b_low"] <= entry["a_high"]
                            if both else None)
        table.append(entry)
    return table


def render_comparison(table: list[dict[str, Any]], a: str, b: str) -> str:
    """:func:`compare_folders` as a markdown table."""
    def final(entry: dict[str, Any], side: str) -> str:
        if math.isnan(entry[f"{side}_final"]):
            return "–"
        return (f"{entry[f'{side}_final']:.3f} [{entry[f'{side}_low']:.3f},"
                f" {entry[f'{side}_high']:.3f}]")

    def episode(entry: dict[str, Any], side: str) -> str:
        value = entry[f"{side}_convergence"]
        return "–" if math.isnan(value) else episode_text(value)

    def difference(entry: dict[str, Any]) -> str:
        return "–" if math.isnan(entry["difference"]) else f"{entry['difference']:+.3f}"

    lines = [f"A = {a}, B = {b}: final return (mean of the last 100 episodes, 95 % bootstrap"
             " interval over agents) and convergence episode per setting", "",
             *table_lines(
                 ["setting", "A final", "B final", "B − A", "intervals", "A converges",
                  "B converges"],
                 ([entry["setting"], final(entry, "a"), final(entry, "b"), difference(entry),
                   {True: "overlap", False: "apart", None: "–"}[entry["overlap"]],
                   episode(entry, "a"), episode(entry, "b")] for entry in table))]
    return "\n".join(lines) + "\n"
