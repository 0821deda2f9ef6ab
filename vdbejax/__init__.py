"""vdbejax: a JAX experiment engine for exploration strategies in tabular RL.

Quick start::

    import vdbejax
    rep = vdbejax.reproduce("out/small", seeds=2, replicates=1, episodes=100)  # small
    print(rep.claims[0].verdict)   # defaults: the paper's full grid ("out/paper")
"""
from importlib import metadata as _metadata
from typing import Any as _Any

from vdbejax import _jax_cache, _xla_flags

_xla_flags.apply()  # before anything starts JAX's backend (see vdbejax._xla_flags)
_jax_cache.apply()  # JAX's persistent compilation cache (see vdbejax._jax_cache)

try:
    #: The installed distribution's version (pyproject.toml's ``version``).
    __version__ = _metadata.version("vdbejax")
except _metadata.PackageNotFoundError:  # imported from a source tree that is not installed
    __version__ = "0.2.0"

# The public names are imported on first use (PEP 562), so that ``import vdbejax``,
# ``vdbejax --help`` and ``vdbejax --version`` do not pay for importing JAX.
_PUBLIC = {
    "AgentOptions": "vdbejax.methods.agents",
    "AgentParams": "vdbejax.methods.agents",
    "Setting": "vdbejax.methods.agents",
    "make_agent": "vdbejax.methods.agents",
    "paper_settings": "vdbejax.methods.agents",
    "TabularMDP": "vdbejax.envs",
    "compile_env": "vdbejax.envs",
    "make_tabular_mdp": "vdbejax.envs",
    "GridResult": "vdbejax.results.grid_result",
    "run_grid": "vdbejax.runs",
    "RunOptions": "vdbejax.runs",
    "FixedBudget": "vdbejax.runs",
    "UntilSolved": "vdbejax.runs",
    "reproduce": "vdbejax.paper.reproduce",
}


def __getattr__(name: str) -> _Any:
    module = _PUBLIC.get(name)
    if module is None:
        raise AttributeError(f"module 'vdbejax' has no attribute {name!r}")
    import importlib

    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted([*globals(), *_PUBLIC])


__all__ = [
    "AgentOptions",
    "AgentParams",
    "FixedBudget",
    "GridResult",
    "RunOptions",
    "Setting",
    "TabularMDP",
    "UntilSolved",
    "compile_env",
    "make_agent",
    "make_tabular_mdp",
    "paper_settings",
    "reproduce",
    "run_grid",
]
