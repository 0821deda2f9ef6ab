"""What ran: the versions and the git commit a result records (``meta.json``)."""
from __future__ import annotations

import functools
import platform
import subprocess
from pathlib import Path
from typing import Any

import numpy as np


@functools.lru_cache(maxsize=1)
def git_commit() -> str | None:
    """The commit vdbejax is imported from when it runs from a git clone, else None.

    Runs ``git rev-parse HEAD`` in the package's parent folder (once per process, 2 s
    timeout) and checks the package is tracked there, so an installed copy inside some
    other repository (a virtualenv in a clone) is not credited with that commit.
    """
    package = Path(__file__).resolve().parents[1]
    try:
        head = subprocess.run(["git", "rev-parse", "HEAD"], cwd=package.parent,
                              capture_output=True, text=True, timeout=2)
        tracked = subprocess.run(
            ["git", "ls-files", "--error-unmatch", "--", f"{package.name}/__init__.py"],
            cwd=package.parent, capture_output=True, text=True, timeout=2)
    except (OSError, subprocess.SubprocessError, ValueError):
        return None
    commit = head.stdout.strip()
    if head.returncode != 0 or tracked.returncode != 0 or not commit:
        return None
    return commit


def version_info() -> dict[str, Any]:
    """Versions recorded in ``meta.json`` besides JAX's: vdbejax, numpy, Python, the
    platform and the git commit (None outside a git clone)."""
    from vdbejax import __version__

    return {"vdbejax_version": __version__, "numpy_version": np.__version__,
            "python_version": platform.python_version(), "platform": platform.platform(),
            "git_commit": git_commit()}
