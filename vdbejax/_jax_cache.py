"""JAX's persistent compilation cache, on by default when :mod:`vdbejax` is imported.

Without it every fresh process compiles the engine's programs again (≈ 5 s for the paper
grid on 2 cores; with it they are read back in a fraction of a second). The cache's key is
the lowered program itself, so it cannot serve a program for other code. It is a
process-wide JAX setting, applied at import unless:

* the user configured a cache of their own: ``JAX_COMPILATION_CACHE_DIR`` in the
  environment, or ``jax.config.jax_compilation_cache_dir`` set before the import (a
  setting made after the import wins as usual);
* ``VDBEJAX_CACHE_DIR=off``.

Location: ``$VDBEJAX_CACHE_DIR``, else ``~/.cache/vdbejax/jax``. Programs that compile in
any time are stored (``jax_persistent_cache_min_compile_time_secs = 0``). Before JAX is
imported the setting is made through JAX's environment variables, which child processes
inherit as they inherit ``XLA_FLAGS``; a child that imports vdbejax decides afresh (its own
``VDBEJAX_CACHE_DIR`` counts, not its parent's choice).
"""
from __future__ import annotations

import os
import sys
from pathlib import Path

#: Set beside ``JAX_COMPILATION_CACHE_DIR`` when vdbejax set that variable (not the user).
_MARK = "VDBEJAX_SET_JAX_CACHE_DIR"


def folder() -> Path | None:
    """Where vdbejax puts JAX's cache, or ``None`` when it leaves the setting alone."""
    if os.environ.get("JAX_COMPILATION_CACHE_DIR"):
        return None  # JAX reads its own variable
    value = os.environ.get("VDBEJAX_CACHE_DIR", str(Path.home() / ".cache" / "vdbejax" / "jax"))
    return None if value.strip().lower() == "off" else Path(value)


def apply() -> None:
    """Turn the cache on (module docstring); an unwritable folder only costs compile time.

    Before JAX is imported this sets JAX's own environment variables (read when JAX
    starts, so importing :mod:`vdbejax` does not import JAX); after, its configuration.
    """
    jax = sys.modules.get("jax")
    inherited = os.environ.pop(_MARK, None)
    undone = False
    if inherited is not None and os.environ.get("JAX_COMPILATION_CACHE_DIR") == inherited:
        del os.environ["JAX_COMPILATION_CACHE_DIR"]  # a parent's choice: decide afresh
        if jax is not None and jax.config.jax_compilation_cache_dir == inherited:
            jax.config.update("jax_compilation_cache_dir", None)
            undone = True
    path = folder()
    if path is None:
        if undone:
            _reset()
        return
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError:
        return
    if jax is None:
        os.environ["JAX_COMPILATION_CACHE_DIR"] = os.environ[_MARK] = str(path)
        os.environ.setdefault("JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS", "0")
        return
    if jax.config.jax_compilation_cache_dir:
        return  # the user's own
    jax.config.update("jax_compilation_cache_dir", str(path))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
    _reset()


def _reset() -> None:
    """Make JAX look at its cache settings again (it decides once, at its first compile)."""
    from jax.experimental.compilation_cache import compilation_cache

    compilation_cache.reset_cache()
