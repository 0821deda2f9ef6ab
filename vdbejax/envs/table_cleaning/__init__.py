"""The paper's table-cleaning task."""
from vdbejax.envs.table_cleaning.env import (
    ACTION_NAMES,
    FIELD_NAMES,
    EnvParams,
    EnvState,
    TableCleaning,
    decode,
    encode,
    make_mdp,
    make_params,
)

__all__ = [
    "ACTION_NAMES",
    "FIELD_NAMES",
    "EnvParams",
    "EnvState",
    "TableCleaning",
    "decode",
    "encode",
    "make_mdp",
    "make_params",
]
