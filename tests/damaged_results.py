"""Copies of a saved result folder with one kind of damage (for `vdbejax plot` tests)."""
from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np


def _rewrite_npz(folder: Path, **changes) -> None:
    with np.load(folder / "returns.npz") as data:
        arrays = {k: data[k] for k in data.files}
    arrays.update(changes)
    np.savez(folder / "returns.npz", **arrays)


def damaged_copy(saved: Path, folder: Path, damage: str) -> Path:
    """``saved`` copied to ``folder``, then damaged as ``damage`` says."""
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
    elif damage == "unknown explorer":
        configs.write_text(configs.read_text().replace("egreedy", "my_plugin"))
    else:
        raise ValueError(f"unknown damage {damage!r}")
    return folder
