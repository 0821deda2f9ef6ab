"""The table-cleaning task: generated variants (n sections, k goblets; rules in
:mod:`.generator`) and the paper's task, the variant n = 2, k = 1 (:mod:`.env`)."""
from vdbejax.envs.table_cleaning.core import EnvParams, EnvState, make_params
from vdbejax.envs.table_cleaning.env import (
    ACTION_NAMES,
    FIELD_NAMES,
    TableCleaning,
    decode,
    encode,
    make_mdp,
)
from vdbejax.envs.table_cleaning.generator import (
    TableCleaningGenerator,
    TableCleaningVariant,
    make_variant,
    make_variant_mdp,
)

__all__ = [
    "ACTION_NAMES",
    "FIELD_NAMES",
    "EnvParams",
    "EnvState",
    "TableCleaning",
    "TableCleaningGenerator",
    "TableCleaningVariant",
    "decode",
    "encode",
    "make_mdp",
    "make_params",
    "make_variant",
    "make_variant_mdp",
]
