"""The table-cleaning task of Cruz et al. (2018), exactly as `docs/task.md`.

State: integer vector ``<hand_obj, hand_pos, goblet_pos, left_clean, right_clean>``
encoded mixed-radix (radices 3, 3, 3, 2, 2; ``hand_obj`` most significant) into 108 codes.
The environment is gymnax-style: ``reset(key, params)`` and
``step(key, state, action, params)``, with the pure transition rule in
:meth:`TableCleaning.transition` so it can be compiled into tables
(:func:`vdbejax.envs.compile_env`).
"""
from __future__ import annotations

from typing import TYPE_CHECKING, Any

import jax
import jax.numpy as jnp
import numpy as np

from vdbejax._numerics import sample_categorical
from vdbejax._pytree import pytree_dataclass, static_field

if TYPE_CHECKING:
    from vdbejax.envs.tabular import TabularMDP

Array = jax.Array

# Field values.
FREE, SPONGE, GOBLET = 0, 1, 2  # hand_obj
LEFT, RIGHT, HOME = 0, 1, 2  # hand_pos; goblet_pos uses LEFT, RIGHT and IN_HAND
IN_HAND = 2
# Actions.
GET, DROP, GO_LEFT, GO_RIGHT, GO_HOME, CLEAN, ABORT = range(7)
ACTION_NAMES = ("get", "drop", "go_left", "go_right", "go_home", "clean", "abort")
FIELD_NAMES = ("hand_obj", "hand_pos", "goblet_pos", "left_clean", "right_clean")
RADICES = (3, 3, 3, 2, 2)

STEP_REWARD = -0.01
GOAL_REWARD = 1.0
FAILURE_REWARD = -1.0
INVALID_ACTIONS = ("noop", "fail")


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

    Shared by the paper's task and its generated variants.

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


class TimeLimitedStep:
    """gymnax-style ``step`` for environments with a pure ``transition`` rule.

    Adds the step count and the ``max_steps`` truncation to ``self.transition``; shared
    by the paper's task and its generated variants.
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


class TableCleaning(TimeLimitedStep):
    """The paper's table-cleaning MDP (7 actions, 108 state codes)."""

    num_actions = len(ACTION_NAMES)
    action_names = ACTION_NAMES
    field_names = FIELD_NAMES

    # --- encoding (FunctionalEnv protocol) ---------------------------------------------
    def num_codes(self, params: EnvParams | None = None) -> int:
        return int(np.prod(RADICES))

    def encode(self, fields: Array, params: Any = None) -> Array:
        return encode(fields)

    def decode(self, code: Array, params: Any = None) -> Array:
        return decode(code)

    def start_distribution(self, params: Any = None) -> tuple[np.ndarray, np.ndarray]:
        """Hand free at home, both sides dirty, goblet left or right with probability 1/2."""
        starts = np.array([(FREE, HOME, side, 0, 0) for side in (LEFT, RIGHT)], np.int32)
        return mixed_radix_encode(starts, RADICES), np.full(2, 0.5)

    # --- dynamics ------------------------------------------------------------------------
    def transition(
        self, fields: Array, action: Array, params: EnvParams
    ) -> tuple[Array, Array, Array]:
        """The spec's transition rule, without time.

        Args:
          fields: int32 ``[5]`` state vector.
          action: int32 action index.
          params: options (``invalid_action`` is used).

        Returns:
          ``(next_fields, reward, terminal)``.
        """
        hand_obj, hand_pos, goblet_pos, left_clean, right_clean = (fields[i] for i in range(5))
        at_side = hand_pos != HOME
        free, sponge, goblet = hand_obj == FREE, hand_obj == SPONGE, hand_obj == GOBLET

        # get: sponge at home, goblet where it stands.
        get_sponge = free & (hand_pos == HOME)
        get_goblet = free & at_side & (hand_pos == goblet_pos)
        # drop: sponge back at home, goblet on a side.
        drop_sponge = sponge & (hand_pos == HOME)
        drop_goblet = goblet & at_side
        # clean: failure while holding the goblet or at the goblet's side.
        clean_fails = goblet | (at_side & (hand_pos == goblet_pos))
        cleans = sponge & at_side & ~clean_fails

        is_get, is_drop, is_clean = action == GET, action == DROP, action == CLEAN
        is_move = (action >= GO_LEFT) & (action <= GO_HOME)

        new_hand_obj = jnp.select(
            [is_get & get_sponge, is_get & get_goblet, is_drop & (drop_sponge | drop_goblet)],
            [SPONGE, GOBLET, FREE],
            hand_obj,
        )
        new_hand_pos = jnp.where(is_move, action - GO_LEFT, hand_pos)
        new_goblet_pos = jnp.select(
            [is_get & get_goblet, is_drop & drop_goblet], [IN_HAND, hand_pos], goblet_pos
        )
        new_left = jnp.where(is_clean & cleans & (hand_pos == LEFT), 1, left_clean)
        new_right = jnp.where(is_clean & cleans & (hand_pos == RIGHT), 1, right_clean)
        next_fields = jnp.stack(
            [new_hand_obj, new_hand_pos, new_goblet_pos, new_left, new_right]
        ).astype(jnp.int32)

        failure = (action == ABORT) | (is_clean & clean_fails)
        if params.invalid_action == "fail":
            unchanged = jnp.all(next_fields == fields)
            failure = failure | (unchanged & ~is_move)
        goal = (
            ~failure
            & (new_hand_obj == FREE)
            & (new_hand_pos == HOME)
            & (new_left == 1)
            & (new_right == 1)
        )
        reward = jnp.select([failure, goal], [FAILURE_REWARD, GOAL_REWARD], STEP_REWARD)
        return next_fields, reward.astype(jnp.float32), failure | goal

    # --- gymnax-style API ----------------------------------------------------------------
    def reset(self, key: Array, params: EnvParams | None = None) -> tuple[Array, EnvState]:
        """Sample an initial state.

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
    from vdbejax.envs.tabular import compile_env

    return compile_env(
        TableCleaning(), make_params(max_steps, invalid_action), name="table_cleaning"
    )
