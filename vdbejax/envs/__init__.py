"""Environments: functional environments and their compiled dense-table form."""
from vdbejax.envs.tabular import TabularMDP, compile_env, make_tabular_mdp

__all__ = ["TabularMDP", "compile_env", "make_tabular_mdp"]
