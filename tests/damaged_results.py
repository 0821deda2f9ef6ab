"""Copies of a saved result folder with one kind of damage (for `vdbejax plot` tests)."""
from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np

from vdbejax.results.manifest import file_digest


def _rewrite_npz(folder: Path, **changes) -> None:
    with np.load(folder / "returns.npz") as data:
        arrays = {k: data[k] for k in data.files}
    arrays.update(changes)
    np.savez(folder / "returns.npz", **arrays)


def damaged_copy(saved: Path, folder: Path, damage: str, manifest: bool = False) -> Path:
    """``saved`` copied to ``folder``, then damaged as ``damage`` says.

    Unless ``manifest``, the folder's manifest is made to match the damaged files (as an
    edit that also rewrote it would, or a folder written before manifests): what is then
    tested are the checks beyond the manifest. With ``manifest`` it is left as the run
    wrote it, so that it must refuse the damage first.
    """
    _damage(saved, folder, damage)
    if not manifest:
        refresh_manifest(folder)
    return folder


def refresh_manifest(folder: Path) -> None:
    """Make ``folder``'s manifest list the sha256 its result files have now."""
    if (folder / "manifest.json").exists():
        listed = json.loads((folder / "manifest.json").read_text())
        for name in ("returns.npz", "configs.csv", "meta.json"):
            listed["files"][name] = file_digest(folder / name)
        (folder / "manifest.json").write_text(json.dumps(listed))


def _damage(saved: Path, folder: Path, damage: str) -> None:
    shutil.copytree(saved, folder)
    configs = folder / "configs.csv"
    if damage == "empty returns":
        (folder / "returns.npz").write_bytes(b"")
    elif damage == "meta list":
        (folder / "meta.json").write_text("[1, 2]\n")
    elif damage == "nonfinite shape":
        _rewrite_npz(folder, nonfinite=np.zeros(3, bool))
    elif damage == "lengths shape":
        with np.load(folder / "returns.npz") as data:
            lengths = data["lengths"][..., :-1]
        _rewrite_npz(folder, lengths=lengths)
    elif damage == "nan returns":
        with np.load(folder / "returns.npz") as data:
            returns = data["returns"].copy()
        returns[0, 0, 0] = np.nan
        _rewrite_npz(folder, returns=returns)
    elif damage == "duplicate config":
        lines = configs.read_text().splitlines()
        configs.write_text("\n".join(lines + lines[1:2]) + "\n")
        with np.load(folder / "returns.npz") as data:  # as many result rows as configs
            arrays = {k: np.concatenate([data[k], data[k][:1]]) for k in data.files}
        np.savez(folder / "returns.npz", **arrays)
    elif damage == "missing column":
        configs.write_text(configs.read_text().replace("explorer", "explorr", 1))
    elif damage == "param not a number":
        lines = configs.read_text().splitlines()
        head, row = lines[0].split(","), lines[1].split(",")
        row[head.index("param")] = "abc"
        configs.write_text("\n".join([lines[0], ",".join(row), *lines[2:]]) + "\n")
    elif damage == "unknown explorer":  # the results of a plug-in not registered here
        for name in ("configs.csv", "meta.json"):
            (folder / name).write_text((folder / name).read_text().replace("egreedy",
                                                                           "my_plugin"))
    else:
        raise ValueError(f"unknown damage {damage!r}")
