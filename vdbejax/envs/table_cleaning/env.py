"""The table-cleaning task of Cruz et al. (2018), as ``docs/task.md`` states it.

The paper's task is the generated variant with 2 sections and 1 goblet: :class:`TableCleaning`
is :class:`~vdbejax.envs.table_cleaning.generator.TableCleaningVariant` for ``n = 2, k = 1``,
so its state codes, action indices and transitions are that variant's, and the rules are
stated once, in :mod:`vdbejax.envs.table_cleaning.generator`. Under the paper's names:

state ``<hand_obj, hand_pos, goblet_pos, left_clean, right_clean>`` (the variant's
``hand_obj, hand_pos, goblet_0, clean_0, clean_1``), encoded mixed-radix (radices 3, 3, 3,
2, 2; ``hand_obj`` most significant) into 108 codes; actions ``get, drop, go_left,
go_right, go_home, clean, abort``. The environment is gymnax-style: ``reset(key, params)``
and ``step(key, state, action, params)``, with the pure transition rule in
:meth:`TableCleaning.transition` so it can be compiled into tables
(:func:`vdbejax.envs.compile_env`, :func:`make_mdp`).

The task's rewards are those of every variant, :mod:`vdbejax.envs.table_cleaning.core`'s
``STEP_REWARD``, ``GOAL_REWARD`` and ``FAILURE_REWARD``.
"""
from __future__ import annotations

from typing import TYPE_CHECKING

import jax
import jax.numpy as jnp

from vdbejax._numerics import sample_categorical
from vdbejax.envs.table_cleaning.core import (
    EnvParams,
    EnvState,
    make_params,
    mixed_radix_decode,
    mixed_radix_encode,
)
from vdbejax.envs.table_cleaning.generator import TableCleaningGenerator, TableCleaningVariant

if TYPE_CHECKING:
    from vdbejax.envs.tabular import TabularMDP

__all__ = [
    "ABORT", "ACTION_NAMES", "CLEAN", "DROP", "FIELD_NAMES", "GET", "GO_HOME", "GO_LEFT",
    "GO_RIGHT", "HOME", "IN_HAND", "LEFT", "RADICES", "RIGHT", "TableCleaning", "decode",
    "encode", "make_mdp",
]

Array = jax.Array

# Field values (hand_obj: core's FREE, SPONGE, GOBLET).
LEFT, RIGHT, HOME = 0, 1, 2  # hand_pos; goblet_pos uses LEFT, RIGHT and IN_HAND
IN_HAND = 2
# Actions.
GET, DROP, GO_LEFT, GO_RIGHT, GO_HOME, CLEAN, ABORT = range(7)
ACTION_NAMES = ("get", "drop", "go_left", "go_right", "go_home", "clean", "abort")
FIELD_NAMES = ("hand_obj", "hand_pos", "goblet_pos", "left_clean", "right_clean")
#: The paper's generator: 2 sections, 1 goblet.
_PAPER = TableCleaningGenerator(num_sections=2, num_goblets=1)
RADICES = _PAPER.radices  # (3, 3, 3, 2, 2)


def encode(fields: Array) -> Array:
    """Mixed-radix int32 code of a field vector (``hand_obj`` most significant).

    Args:
      fields: ``[5]`` integer field vector.

    Returns:
      int32 code in ``[0, 108)``.
    """
    return mixed_radix_encode(jnp.asarray(fields, jnp.int32), RADICES).astype(jnp.int32)


def decode(code: Array) -> Array:
    """Field vector of a mixed-radix code.

    Args:
      code: integer code in ``[0, 108)``.

    Returns:
      int32 ``[5]`` field vector.
    """
    return mixed_radix_decode(code, RADICES)


class TableCleaning(TableCleaningVariant):
    """The paper's table-cleaning MDP (7 actions, 108 state codes): the variant ``n = 2,
    k = 1`` under the paper's action and field names (:data:`ACTION_NAMES`,
    :data:`FIELD_NAMES`), whose :meth:`reset` draws the start as it always has."""

    num_actions = len(ACTION_NAMES)
    action_names = ACTION_NAMES
    field_names = FIELD_NAMES

    def __init__(self) -> None:
        super().__init__(_PAPER)
        self.action_names, self.field_names = ACTION_NAMES, FIELD_NAMES

    def reset(self, key: Array, params: EnvParams | None = None) -> tuple[Array, EnvState]:
        """Sample an initial state: the goblet left or right with probability 1/2.

        One uniform picks from :meth:`start_distribution` (not the generator's draw, so that
        a key gives the start it gave before the task became the 2×1 variant).

        Returns:
          ``(observation, state)``; the observation is the field vector.
        """
        codes, probs = self.start_distribution(params)
        u = jax.random.uniform(key)
        code = jnp.asarray(codes)[sample_categorical(jnp.asarray(probs, jnp.float32), u)]
        fields = decode(code)
        return fields, EnvState(fields=fields, time=jnp.asarray(0, jnp.int32))


def make_mdp(max_steps: int = 100, invalid_action: str = "noop") -> TabularMDP:
    """The table-cleaning task compiled into a :class:`~vdbejax.envs.TabularMDP`.

    Args:
      max_steps: truncation length.
      invalid_action: ``"noop"`` or ``"fail"``.

    Returns:
      the deterministic MDP over all 108 codes (state index = code), named
      ``table_cleaning``.
    """
    from vdbejax.envs.compiled import compile_env

    return compile_env(
        TableCleaning(), make_params(max_steps, invalid_action), name="table_cleaning"
    )

