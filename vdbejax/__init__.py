"""vdbejax: a JAX experiment engine for exploration strategies in tabular RL.

Quick start::

    import vdbejax
    rep = vdbejax.reproduce("out/paper")          # the paper's full grid
    print(rep.claims[0].verdict)
"""
from importlib import metadata as _metadata

from vdbejax import _xla_flags

_xla_flags.apply()  # before anything starts JAX's backend (see vdbejax._xla_flags)

try:
    #: The installed distribution's version (pyproject.toml's ``version``).
    __version__ = _metadata.version("vdbejax")
except _metadata.PackageNotFoundError:  # imported from a source tree that is not installed
    __version__ = "0.1.0"

from vdbejax.methods.agents import AgentOptions, AgentParams, Setting, make_agent, paper_settings
from vdbejax.envs import TabularMDP, compile_env, make_tabular_mdp
from vdbejax.experiment import GridResult, run_grid
from vdbejax.paper.reproduce import reproduce

__all__ = [
    "AgentOptions",
    "AgentParams",
    "GridResult",
    "Setting",
    "TabularMDP",
    "compile_env",
    "make_agent",
    "make_tabular_mdp",
    "paper_settings",
    "reproduce",
    "run_grid",
]
