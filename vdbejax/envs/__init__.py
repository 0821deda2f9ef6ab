"""Environments: functional environments and their compiled dense-table form."""
from vdbejax.envs.compiled import compile_env
from vdbejax.envs.tabular import TabularMDP, make_tabular_mdp

__all__ = ["TabularMDP", "compile_env", "make_tabular_mdp"]
