"""What every table-cleaning task shares: its options, its rewards, its state, the
mixed-radix state codes and the time-limited gymnax-style ``step``.

The tasks themselves are :class:`~vdbejax.envs.table_cleaning.generator.TableCleaningVariant`
(``n`` sections, ``k`` goblets; its module states the rules) and the paper's task,
:class:`~vdbejax.envs.table_cleaning.env.TableCleaning`, the variant ``n = 2, k = 1``.
"""
from __future__ import annotations

from typing import TYPE_CHECKING, Any

import jax
import jax.numpy as jnp

from vdbejax._pytree import pytree_dataclass, static_field

Array = jax.Array

# Values of the hand_obj field.
FREE, SPONGE, GOBLET = 0, 1, 2
#: The values of the ``invalid_action`` option.
INVALID_ACTIONS = ("noop", "fail")

# The rewards of the paper's task and of every variant, read when a transition is traced
# (a patched constant is seen by every task compiled after).
STEP_REWARD = -0.01
GOAL_REWARD = 1.0
FAILURE_REWARD = -1.0


@pytree_dataclass
class EnvParams:
    """Options of the task (spec defaults).

    Attributes:
      max_steps: episode length at which an episode is truncated (not terminal).
      invalid_action: ``"noop"`` (actions that change nothing do nothing) or ``"fail"``
        (they end the episode as a failure; moves to where the hand already is excepted).
    """

    max_steps: int | Array = 100
    invalid_action: str = static_field("noop")


@pytree_dataclass
class EnvState:
    """Environment state: the integer field vector and the step count."""

    fields: Array
    time: Array


def make_params(max_steps: int = 100, invalid_action: str = "noop") -> EnvParams:
    """Validated :class:`EnvParams`.

    Args:
      max_steps: truncation length (integer >= 1).
      invalid_action: ``"noop"`` or ``"fail"``.

    Returns:
      the :class:`EnvParams`.

    Raises:
      ValueError: ``max_steps < 1`` or unknown ``invalid_action``.
    """
    from vdbejax.validation import check_choice, check_int

    check_int("max_steps", max_steps, 1)
    check_choice("invalid_action", invalid_action, INVALID_ACTIONS)
    return EnvParams(max_steps=max_steps, invalid_action=invalid_action)


def mixed_radix_encode(fields: Any, radices: tuple[int, ...]) -> Any:
    """Mixed-radix code of the last axis of ``fields`` (first field most significant).

    Args:
      fields: ``[..., len(radices)]`` integer fields (jnp or numpy).
      radices: the radix of each field.

    Returns:
      ``[...]`` codes, in the array type and dtype of ``fields``.
    """
    code = fields[..., 0] * 0
    for i, radix in enumerate(radices):
        code = code * radix + fields[..., i]
    return code


def mixed_radix_decode(code: Array, radices: tuple[int, ...]) -> Array:
    """Field vector of a mixed-radix code (inverse of :func:`mixed_radix_encode`).

    Args:
      code: int32 code.
      radices: the radix of each field.

    Returns:
      int32 ``[len(radices)]`` fields.
    """
    code = jnp.asarray(code, jnp.int32)
    out = []
    for radix in reversed(radices):
        out.append(code % radix)
        code = code // radix
    return jnp.stack(out[::-1]).astype(jnp.int32)


class TimeLimitedStep:
    """gymnax-style ``step`` for environments with a pure ``transition`` rule.

    Adds the step count and the ``max_steps`` truncation to ``self.transition``.
    """

    if TYPE_CHECKING:  # what a subclass defines
        def transition(
            self, fields: Array, action: Array, params: EnvParams
        ) -> tuple[Array, Array, Array]: ...

    def default_params(self) -> EnvParams:
        """The spec's default options."""
        return EnvParams()

    def step(
        self, key: Array, state: EnvState, action: Array, params: EnvParams | None = None
    ) -> tuple[Array, EnvState, Array, Array, dict[str, Array]]:
        """One environment step (no auto-reset).

        Args:
          key: PRNG key (unused: the dynamics are deterministic).
          state: current state.
          action: int32 action index.
          params: options (default :meth:`default_params`).

        Returns:
          ``(observation, state, reward, done, info)`` where ``done`` is terminal or
          truncated and ``info`` holds ``terminal`` and ``truncated`` separately.
        """
        params = self.default_params() if params is None else params
        next_fields, reward, terminal = self.transition(state.fields, action, params)
        time = state.time + 1
        truncated = ~terminal & (time >= params.max_steps)
        new_state = EnvState(fields=next_fields, time=time)
        info = {"terminal": terminal, "truncated": truncated}
        return next_fields, new_state, reward, terminal | truncated, info
