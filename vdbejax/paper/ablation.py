"""Ablation of the paper's open details: the claims scorecard under each spec option.

The paper does not say what an invalid action does, how greedy ties are broken, when an
episode is cut off, or how Q is initialised; the spec fixes defaults and makes each an
option. :func:`ablate` reruns the full grid once per
:class:`~vdbejax.paper.ablation_variants.Variant` (one factor at a time from the spec
defaults, plus a combination), scores the six claims for each, and
writes ``ablation_scorecard.md``: the claims × variants table, per-variant numbers and figures,
and (if given) a hand-written discussion.

Regenerate the committed document with::

    vdbejax ablate --out docs --results out --replicates 10 --notes docs/ablation_notes.md

(the document quotes the exact command that produced it).

This module runs the variants (:func:`run_variant`, :func:`ablate`); the variants
themselves are in :mod:`vdbejax.paper.ablation_variants` and the document's rendering in
:mod:`vdbejax.paper.ablation_document`.
"""
from __future__ import annotations

import contextlib
import os
import sys
import time
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

from vdbejax.paper.ablation_document import render_document
from vdbejax.paper.ablation_variants import (
    MODES,
    VARIANTS,
    Variant,
    VariantResult,
    mode_variants,
)
from vdbejax.paper.reproduce import reproduce
from vdbejax.results import io
from vdbejax.results.replicates import REPLICATE_FILES, check_replicates
from vdbejax.runs import RunOptions
from vdbejax.runs.options import SPEED_FIELDS, study_run
from vdbejax.studies.sweeps import FIGURE_FILE, SENSITIVITY_FILE
from vdbejax.validation import INT32_MAX, UINT32_MAX, check_int, check_writable_dir


def _matches(meta: dict[str, Any], variant: Variant, seeds: int, episodes: int, seed: int,
             replicates: int = 1) -> bool:
    """Does a saved result belong to this variant and run size (so it can be reused)?"""
    options = meta.get("options", {})
    return (meta.get("num_seeds") == seeds * replicates
            and meta.get("replicates", 1) == replicates
            and meta.get("agents_per_replicate", seeds) == seeds
            and meta.get("num_episodes") == episodes
            and meta.get("seed") == seed and meta.get("max_steps") == variant.max_steps
            and meta.get("invalid_action") == variant.invalid_action
            and options.get("tie_break") == variant.tie_break
            and float(options.get("q_init", float("nan"))) == variant.q_init
            and float(options.get("alpha", float("nan"))) == variant.alpha
            and meta.get("reading", "textbook") == variant.reading
            and meta.get("details", {}) == dict(variant.details))


def run_variant(
    variant: Variant, results_dir: str | os.PathLike, *, seeds: int = 20, episodes: int = 1000,
    seed: int = 0, replicates: int = 1, reuse: bool = True, run: RunOptions | None = None,
    figures: bool = True,
) -> VariantResult:
    """Run (or reuse) the full grid of one variant and score the claims.

    Args:
      variant: the options.
      results_dir: folder for this variant's raw results and outputs.
      seeds, episodes, seed: run size.
      replicates: independent groups of ``seeds`` agents (:mod:`vdbejax.results.replicates`).
      reuse: load a saved result of the same variant and size instead of rerunning (a
        folder a killed run left half-written is continued from its checkpoint instead);
        ``False`` retrains and replaces what the folder holds.
      run: how the variant's run runs (:class:`~vdbejax.runs.RunOptions`, the fields
        :func:`~vdbejax.paper.reproduce.reproduce` takes; default ``RunOptions()``: no
        progress bar).
      figures: draw the variant's figures (``False``: numbers and report only, and no
        figure of an earlier run is left in ``results_dir``; ``vdbejax plot --results
        FOLDER`` draws them).

    Returns:
      :class:`~vdbejax.paper.ablation_variants.VariantResult`.
    """
    run = RunOptions() if run is None else run
    folder = Path(results_dir)
    meta_file = folder / io.META_FILE
    try:
        saved = io.load_json(meta_file) if reuse and meta_file.exists() else None
    except (OSError, ValueError):  # unreadable: not a result to reuse
        saved = None
    if isinstance(saved, dict) and _matches(saved, variant, seeds, episodes, seed, replicates):
        # Reused (or, half-written by a killed run, continued) through reproduce, whose
        # fingerprint check retrains a result of other code and which annotates it afresh.
        run = run.replace(resume=True)
    rep = reproduce(folder, seeds=seeds, episodes=episodes, seed=seed, replicates=replicates,
                    figures=figures, run=run.replace(overwrite=run.overwrite or not reuse),
                    **variant.options())
    meta = rep.result.meta
    how = ("reused" if isinstance(saved, dict) and saved.get("elapsed_seconds") is not None
           and meta.get("elapsed_seconds") == saved.get("elapsed_seconds")
           else "continued" if meta.get("resumed_from_agent_episodes") else "trained")
    return VariantResult(variant, rep.summary, rep.claims, rep.best_return, folder, how)


#: Files of a variant's folder copied next to the document (small; no raw arrays).
DOCUMENT_ASSETS = (FIGURE_FILE, SENSITIVITY_FILE, "report.md", "summary.csv")
#: The same for documents that link reports only (attribution, factorial, sections).
REPORT_ASSETS = ("report.md", "summary.csv")


#: The run options :func:`ablate` takes.
ABLATE_RUN_FIELDS = ("progress", "resume", "overwrite", *SPEED_FIELDS)


def ablate(
    out_dir: str | os.PathLike,
    *,
    results_dir: str | os.PathLike | None = None,
    variants: Sequence[Variant] = VARIANTS,
    seeds: int = 20,
    episodes: int = 1000,
    seed: int = 0,
    replicates: int = 5,
    notes: str | os.PathLike | None = None,
    reuse: bool = True,
    mode: str = "options",
    sections: bool = False,
    run: RunOptions | None = None,
) -> list[VariantResult]:
    """Run every variant, score the claims, write ``ablation_scorecard.md`` (mode ``options``),
    ``ATTRIBUTION.md`` (mode ``attribution``) or ``FACTORIAL.md`` (mode ``factorial``)
    and its figures.

    Args:
      out_dir: document folder: ``ablation_scorecard.md`` and ``ablation/<variant>/`` (figures,
        summary, report).
      results_dir: raw results (``<variant>/returns.npz`` …); default ``out_dir/ablation``,
        i.e. next to the figures.
      variants: the variants (the first is the baseline).
      seeds, episodes, seed: run size of every variant.
      replicates: independent groups of ``seeds`` agents per variant (default 5): every
        verdict is the headline of :mod:`vdbejax.results.verdicts` (the pooled verdict when at
        least 4 of 5 replicates agree, else *unstable*).
      notes: a hand-written markdown file appended as the discussion.
      reuse: reuse saved results of the same variant and size.
      mode: ``"options"`` (the two readings and the spec's open details),
        ``"attribution"`` (the authors' details one at a time,
        :data:`~vdbejax.paper.ablation_variants.ATTRIBUTION_VARIANTS`) or ``"factorial"``
        (:data:`~vdbejax.paper.ablation_variants.FACTORIAL_VARIANTS`): the document's name
        and figure folder (:data:`~vdbejax.paper.ablation_variants.MODES`).
      sections: (mode ``options``) also run the attribution and factorial variants and
        add their claims tables to the document, so that ``ablation_scorecard.md`` shows which
        detail of which reading decides each claim (results in ``results_dir``'s
        ``attribution/`` and ``factorial/`` subfolders, reports beside the document).
      run: how every variant's run runs (:class:`~vdbejax.runs.RunOptions`, default
        ``RunOptions(progress=True)``), the fields of :data:`ABLATE_RUN_FIELDS`:
        ``progress``: one status line per variant on stderr (no progress bar);
        ``resume``: an interrupted variant continues from its checkpoint; ``overwrite``: a
        variant's folder holding a finished result of another size or code is retrained
        and replaced (without it that is refused in one line); the others change only the
        speed.

    Returns:
      the scored variants.

    Raises:
      ValueError: no variants, duplicate names, or a notes file that is missing, unreadable
        or not UTF-8 text (all before anything trains).
    """
    run = study_run(run, "ablate", ABLATE_RUN_FIELDS)
    variants = list(variants)
    if not variants:
        raise ValueError("variants is empty: need at least one variant")
    if len({v.name for v in variants}) != len(variants):
        raise ValueError("variant names must be unique")
    notes_text = read_notes(notes)  # read now: a bad file fails before anything trains
    if mode not in MODES:
        raise ValueError(f"mode={mode!r} is invalid: must be one of {', '.join(MODES)}")
    document, figures_dir = MODES[mode]
    knobs = run.replace(progress=False)  # the variants' runs: a status line each, no bar
    # The run's size is checked before any folder is made (a refusal leaves nothing behind).
    check_int("seeds", seeds, 1, INT32_MAX)
    check_replicates(replicates, seeds)
    check_int("episodes", episodes, 1, INT32_MAX)
    check_int("seed", seed, 0, UINT32_MAX)
    # Every folder written must be writable before the first variant trains; those made
    # here are removed again (when still empty) if a variant's run is refused.
    wanted = [out_dir, results_dir]
    if isinstance(out_dir, (str, os.PathLike)):
        wanted.append(Path(out_dir) / figures_dir)
    made = [Path(p) for p in wanted if isinstance(p, (str, os.PathLike)) and str(p)
            and not Path(p).exists()]
    with _removed_if_refused(made):
        return _ablate(out_dir, figures_dir, results_dir, document, variants, seeds, episodes,
                       seed, replicates, notes, notes_text, reuse, bool(run.progress), mode,
                       sections, knobs)


def read_notes(notes: str | os.PathLike | None) -> str | None:
    """The notes file's text (None without one).

    Raises:
      ValueError: a missing or unreadable file, or one that is not UTF-8 text, naming it.
    """
    if notes is None:
        return None
    if not isinstance(notes, (str, os.PathLike)) or not Path(notes).is_file():
        raise ValueError(f"notes file {str(notes)!r} does not exist")
    try:
        return Path(notes).read_text(encoding="utf-8")
    except UnicodeDecodeError as error:
        raise ValueError(f"notes file {str(notes)!r} is not UTF-8 text (byte {error.start}:"
                         f" {error.reason}): save it as UTF-8") from None
    except OSError as error:
        raise ValueError(f"notes file {str(notes)!r} is unreadable:"
                         f" {error.strerror or error}") from None


@contextlib.contextmanager
def _removed_if_refused(folders: list[Path]) -> Iterator[None]:
    """Remove ``folders`` that are still empty (deepest first) when a ValueError leaves."""
    try:
        yield
    except ValueError:
        for folder in sorted(folders, key=lambda p: len(p.parts), reverse=True):
            with contextlib.suppress(OSError):  # not empty (something was written): kept
                folder.rmdir()
        raise


def _ablate(out_dir: str | os.PathLike, figures_dir: str, results_dir: str | os.PathLike | None,
            document: str, variants: list[Variant], seeds: int, episodes: int, seed: int,
            replicates: int, notes: str | os.PathLike | None, text: str | None, reuse: bool,
            progress: bool, mode: str, sections: bool, knobs: RunOptions
            ) -> list[VariantResult]:
    """:func:`ablate` once its options are checked."""
    out = check_writable_dir("out", out_dir)
    figures = check_writable_dir("out", out / figures_dir)
    raw = check_writable_dir("results_dir", results_dir) if results_dir is not None else figures
    # The options document shows figures; the others link reports only (size).
    assets = DOCUMENT_ASSETS if mode == "options" else REPORT_ASSETS
    size = (seeds, episodes, seed, replicates)
    results = [_run_reporting(v, raw, figures, assets, size, reuse, progress, knobs)
               for v in variants]
    extra = []
    if sections and mode == "options":
        for section_mode, title in SECTION_TITLES.items():
            section_dir = MODES[section_mode][1]
            section_raw = (Path(results_dir) / section_dir if results_dir is not None
                           else out / section_dir)
            extra.append((title, SECTION_INTROS[section_mode], section_dir, [
                _run_reporting(v, section_raw, out / section_dir, REPORT_ASSETS, size, reuse,
                               progress, knobs) for v in mode_variants(section_mode)]))
    command = _command(out, raw, figures, variants, size, mode, sections, notes)
    io.atomic_write_text(out / document, render_document(results, figures_dir, command, text,
                                                         figures=mode == "options",
                                                         sections=extra))
    return results


#: Titles and introductions of ablation_scorecard.md's sections from the other modes.
SECTION_TITLES = {"attribution": "Which single detail decides each claim",
                  "factorial": "Factorial: failure update × goal update × α × initial Q"}
SECTION_INTROS = {
    "attribution": ("From each reading, one detail of the other reading switched alone "
                    "(`textbook+X`: the textbook reading with the authors' X; `authors-X`: "
                    "the authors' reading without it). A verdict that changes against its "
                    "reading's row is decided by that detail."),
    "factorial": ("Every combination of the four details that matter most, from each "
                  "reading (its other details kept); α = 0.8 is the paper's."),
}


def _run_reporting(variant: Variant, raw: Path, reports: Path, assets: Sequence[str],
                   size: tuple[int, int, int, int], reuse: bool, progress: bool,
                   run: RunOptions) -> VariantResult:
    """Run (or reuse) a variant in ``raw``; copy its ``assets`` beside the document (into
    ``reports``) when the raw results live elsewhere; one status line if ``progress``.
    The variant's figures are drawn only if ``assets`` holds them."""
    started = time.perf_counter()
    seeds, episodes, seed, replicates = size
    # Figures only where the document shows them: drawing them costs more than a small
    # variant's training (≈ 1.5–2.5 s each).
    result = run_variant(variant, raw / variant.name, seeds=seeds, episodes=episodes, seed=seed,
                         replicates=replicates, reuse=reuse, run=run,
                         figures=FIGURE_FILE in assets)
    if raw != reports:
        for name in [*assets, *(REPLICATE_FILES if replicates > 1 else [])]:
            io.atomic_write_bytes(reports / variant.name / name,
                                  (result.folder / name).read_bytes())
    if progress:
        verdicts = ", ".join(f"{c.number}:{c.verdict}" for c in result.claims)
        print(f"{variant.name}: {verdicts} ({result.how}, {time.perf_counter() - started:.1f} s)",
              file=sys.stderr, flush=True)
    return result


def _command(out: Path, raw: Path, figures: Path, variants: Sequence[Variant],
             size: tuple[int, int, int, int], mode: str = "options", sections: bool = False,
             notes: str | os.PathLike[str] | None = None) -> str:
    """The ``vdbejax ablate`` command line that reproduces this call."""
    parts = ["vdbejax ablate", f"--out {out}"]
    if mode != "options":
        parts.append(f"--mode {mode}")
    elif sections:
        parts.append("--sections")
    if raw != figures:
        parts.append(f"--results {raw}")
    if [v.name for v in variants] != [v.name for v in mode_variants(mode)]:
        parts.append("--variants " + ",".join(v.name for v in variants))
    seeds, episodes, seed, replicates = size
    for flag, value, default in (("--seeds", seeds, 20), ("--episodes", episodes, 1000),
                                 ("--seed", seed, 0), ("--replicates", replicates, 5)):
        if value != default:
            parts.append(f"{flag} {value}")
    if notes is not None:
        parts.append(f"--notes {notes}")
    return " ".join(parts)


__all__ = ["ablate", "run_variant"]
