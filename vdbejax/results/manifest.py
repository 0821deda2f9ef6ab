"""A result folder's manifest: which files belong to which run, with their sha256.

``manifest.json`` is written beside the result files (:meth:`GridResult.save
<vdbejax.results.grid_result.GridResult.save>`) and extended with the outputs drawn from
them (summary, figures, report). It names the run (``meta.json``'s fingerprint — of the
settings, seeds, options, task and every user plug-in's traced code —, the seed, and
vdbejax's version and commit) and lists
every file with its sha256. :meth:`GridResult.load` — and so ``vdbejax plot``, ``ablate``'s
reuse of a variant and ``--resume``'s reuse of a whole result — verifies the result files
against it and refuses, in one line naming the file, one that was changed or comes from
another run. A folder written before manifests existed (its ``meta.json`` does not name
one) is read without this check; the plausibility checks of
:func:`~vdbejax.results.grid_result.GridResult.load` still apply.
"""
from __future__ import annotations

import hashlib
import json
import os
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

from vdbejax.results import io

MANIFEST_FILE = "manifest.json"
#: ``meta.json``'s key naming the manifest (its presence means the folder must have one).
META_KEY = "manifest"
_RUN_FIELDS = ("fingerprint", "seed", "vdbejax_version", "git_commit")


def file_digest(path: str | os.PathLike) -> str:
    """sha256 of a file's bytes (hex)."""
    digest = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def run_identity(meta: dict[str, Any]) -> dict[str, Any]:
    """What names the run in a manifest: its fingerprint (settings, seeds, options, task,
    user plug-ins' code), seed, vdbejax version and commit."""
    return {name: meta.get(name) for name in _RUN_FIELDS}


def write_manifest(folder: str | os.PathLike, meta: dict[str, Any], names: Iterable[str],
                   keep: bool = False) -> None:
    """(Re)write ``folder/manifest.json`` for the run of ``meta`` with the files ``names``
    (those that exist); with ``keep``, also the entries it already lists for this run
    (outputs added to the result files)."""
    folder = Path(folder)
    files: dict[str, str] = {}
    old = read_manifest(folder) if keep else None
    if old is not None and old.get("run") == run_identity(meta):
        files.update({name: digest for name, digest in old.get("files", {}).items()
                      if (folder / name).is_file()})
    for name in names:
        if (folder / name).is_file():
            files[name] = file_digest(folder / name)
    io.atomic_write_text(folder / MANIFEST_FILE, json.dumps(
        {"run": run_identity(meta), "files": dict(sorted(files.items()))}, indent=2,
        sort_keys=True) + "\n")


def read_manifest(folder: str | os.PathLike) -> dict[str, Any] | None:
    """The manifest of ``folder`` (``None`` if it has none or it is unreadable)."""
    try:
        data = json.loads((Path(folder) / MANIFEST_FILE).read_text())
    except (OSError, ValueError):
        return None
    return data if isinstance(data, dict) else None


def verify_manifest(folder: str | os.PathLike, meta: dict[str, Any],
                    names: Iterable[str], known: Mapping[str, str] | None = None) -> None:
    """Check the files ``names`` of ``folder`` against its manifest (``known``: digests of
    files the caller has just read, by name, so that they are not read again).

    Raises:
      ValueError: ``meta`` names a manifest the folder lacks (or cannot be read), the
        manifest belongs to another run than ``meta.json``, or a file is missing from it
        or differs from the sha256 it records: one line naming the file.
    """
    folder = Path(folder)
    if not meta.get(META_KEY):
        return  # written before manifests existed
    manifest = read_manifest(folder)
    path = folder / MANIFEST_FILE
    if manifest is None or not isinstance(manifest.get("files"), dict):
        raise ValueError(f"results folder {str(folder)!r} lacks a readable {MANIFEST_FILE},"
                         " which its meta.json names: the folder was changed after the run;"
                         " run it again or restore the file")
    recorded = manifest.get("run")
    if recorded != run_identity(meta):
        differs = [k for k in _RUN_FIELDS if (recorded or {}).get(k) != meta.get(k)]
        raise ValueError(f"results file {str(folder / io.META_FILE)!r} does not belong to the"
                         f" run of {str(path)!r} (they differ in {', '.join(differs)}): a"
                         " meta.json of another run, or an edited one")
    for name in names:
        expected = manifest["files"].get(name)
        if expected is None:
            raise ValueError(f"results file {str(folder / name)!r} is not in {str(path)!r}:"
                             " it was not written by this run")
        found = (known or {}).get(name) or file_digest(folder / name)
        if found != expected:
            raise ValueError(f"results file {str(folder / name)!r} does not match its sha256 in"
                             f" {str(path)!r} ({found[:12]}…, recorded {expected[:12]}…): it"
                             " was changed after the run or comes from another run")


__all__ = ["MANIFEST_FILE", "file_digest", "read_manifest", "run_identity", "verify_manifest",
           "write_manifest"]
