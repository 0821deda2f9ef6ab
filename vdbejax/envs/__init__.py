"""Environments: functional environments and their compiled dense-table form."""
from vdbejax.envs.compiled import compile_env
from vdbejax.envs.tabular import TabularMDP, make_tabular_mdp

#: The public names; the modules among them are imported when first named
#: (``from vdbejax.envs import solvers``).
__all__ = [
    "TabularMDP",
    "compile_env",
    "cruz2018",
    "gymnasium_adapter",
    "make_tabular_mdp",
    "solvers",
    "suite",
    "table_cleaning",
]
