"""The table-cleaning task's rules, for ``n`` sections, ``k`` goblets and one sponge.

This module is the one implementation of the rules, and this docstring their statement in
the code (``docs/task.md`` states the paper's task in words). The paper's task,
:class:`~vdbejax.envs.table_cleaning.env.TableCleaning`, is the variant ``n = 2, k = 1``:
sections 0 and 1 are its left and right sides, ``goblet_0`` is its ``goblet_pos``,
``clean_0`` and ``clean_1`` are ``left_clean`` and ``right_clean``, and its seven actions are
``get, drop, go_left, go_right, go_home, clean, abort`` (108 codes).

**State.** The integer vector
``<hand_obj, hand_pos, goblet_0, …, goblet_{k-1}, clean_0, …, clean_{n-1}>``:

| field | values |
| --- | --- |
| hand_obj | 0 free, 1 sponge, 2 goblet |
| hand_pos | ``0 … n-1`` a section, ``n`` home |
| goblet_j | ``0 … n-1`` the section it stands on, ``n`` in the hand |
| clean_i | 0 dirty, 1 clean |

encoded mixed-radix (radices ``3, n+1, (n+1)×k, 2×n``; ``hand_obj`` most significant), so
there are ``3·(n+1)^(k+1)·2^n`` codes. Goblets are identical: the goblet fields are kept
sorted increasingly (a multiset), which removes the ``k!`` relabellings of a state. The
sponge lies at home whenever the hand does not hold it.

**Several goblets may share a section** (they are small; it also keeps every ``k`` solvable:
with one goblet per section at most, ``k = n`` would leave no section to clean first).

**Actions** (``n + 5``): ``0 get, 1 drop, 2 … n+1 go to section 0 … n-1, n+2 go home,
n+3 clean, n+4 abort`` — for ``n = 2`` exactly the paper's seven.

| action | effect |
| --- | --- |
| get | hand free at home: take the sponge. Hand free at a section holding goblets: take one. Otherwise nothing. |
| drop | sponge at home: put it back. Goblet at a section: put it there (also beside other goblets). Otherwise nothing. |
| go_i / go_home | the hand, with what it holds, moves there. |
| clean | **failure** if the hand holds a goblet, or if its section holds a goblet. Sponge at a section: that section becomes clean. Otherwise nothing. |
| abort | failure. |

``invalid_action="fail"`` makes any action that changes nothing (moves excepted) a failure.

**Rewards.** Goal (``GOAL_REWARD`` = +1, terminal): after a transition that is no failure,
the hand is free at home and every section is clean. Failure (``FAILURE_REWARD`` = -1,
terminal). Otherwise ``STEP_REWARD`` = -0.01. ``max_steps`` truncates (not terminal). The
three rewards are constants of :mod:`vdbejax.envs.table_cleaning.core`, read when a
transition is traced: a patched constant is seen by the paper's task and every variant.

**Initial state** (:class:`TableCleaningGenerator`): hand free at home, every section
dirty, each goblet placed independently and uniformly at random on one of the ``n``
sections (so a multiset of positions has multinomial probability; ``n = 2, k = 1``: left
or right with probability 1/2, as in the paper).
"""  # noqa: E501  (the action table's rows: Markdown table rows cannot be wrapped)
from __future__ import annotations

import dataclasses
import itertools
from typing import TYPE_CHECKING, Any

import jax
import jax.numpy as jnp
import numpy as np

from vdbejax.envs.table_cleaning import core
from vdbejax.envs.table_cleaning.core import (
    FREE,
    GOBLET,
    SPONGE,
    EnvParams,
    EnvState,
    TimeLimitedStep,
    make_params,
    mixed_radix_decode,
    mixed_radix_encode,
)

if TYPE_CHECKING:
    from vdbejax.envs.tabular import TabularMDP

Array = jax.Array

GET, DROP = 0, 1
#: First move action; section ``i`` is ``GO_FIRST + i``, home is ``GO_FIRST + n``.
GO_FIRST = 2


def _sort_small(values: Array) -> Array:
    """Sort a short vector with a compare-exchange network (odd-even transposition).

    For a handful of goblets this is much faster under ``vmap`` than ``jnp.sort``.
    """
    items = [values[i] for i in range(values.shape[0])]
    for round_ in range(len(items)):
        for i in range(round_ % 2, len(items) - 1, 2):
            items[i], items[i + 1] = (jnp.minimum(items[i], items[i + 1]),
                                      jnp.maximum(items[i], items[i + 1]))
    return jnp.stack(items)


def _first(mask: Array) -> Array:
    """One-hot of the first true entry of a boolean vector (entry 0 when none is true: on
    codes no episode reaches, where the hand holds a goblet but no goblet field is "in the
    hand", drop puts goblet 0 down, as the paper's tables over all 108 codes have it)."""
    return jnp.arange(mask.shape[0]) == jnp.argmax(mask)


@dataclasses.dataclass(frozen=True)
class TableCleaningGenerator:
    """Makes instances of a variant: its initial states (jumanji-style ``Generator``).

    Attributes:
      num_sections: ``n >= 2`` table sections.
      num_goblets: ``k >= 1`` goblets.
    """

    num_sections: int = 2
    num_goblets: int = 1

    def __post_init__(self) -> None:
        from vdbejax.validation import check_int

        check_int("num_sections", self.num_sections, 2)
        check_int("num_goblets", self.num_goblets, 1)

    @property
    def home(self) -> int:
        """``hand_pos`` of home, and ``goblet_j`` of a goblet in the hand."""
        return self.num_sections

    @property
    def radices(self) -> tuple[int, ...]:
        n, k = self.num_sections, self.num_goblets
        return (3, n + 1) + (n + 1,) * k + (2,) * n

    def initial_fields(self, goblet_positions: Any) -> Any:
        """Initial field vector(s) for goblet positions (sorted here).

        Args:
          goblet_positions: ``[..., k]`` section of each goblet (numpy or jnp).

        Returns:
          ``[..., 2 + k + n]`` field vectors, same array type and dtype.
        """
        xp = jnp if isinstance(goblet_positions, jax.Array) else np
        goblets = xp.sort(goblet_positions, axis=-1)
        batch = goblets.shape[:-1]
        hand = xp.broadcast_to(xp.asarray([FREE, self.home]), (*batch, 2))
        dirty = xp.zeros((*batch, self.num_sections), goblets.dtype)
        return xp.concatenate([hand.astype(goblets.dtype), goblets, dirty], axis=-1)

    def __call__(self, key: Array) -> EnvState:
        """Sample an initial state: each goblet on a uniformly random section."""
        positions = jax.random.randint(key, (self.num_goblets,), 0, self.num_sections)
        fields = self.initial_fields(positions.astype(jnp.int32)).astype(jnp.int32)
        return EnvState(fields=fields, time=jnp.asarray(0, jnp.int32))

    def start_distribution(self) -> tuple[np.ndarray, np.ndarray]:
        """Exact distribution of :meth:`__call__`.

        Returns:
          ``(codes, probabilities)``: distinct initial codes (increasing) and their
          probabilities (multinomial: placements / ``n^k``).
        """
        placements = np.array(
            list(itertools.product(range(self.num_sections), repeat=self.num_goblets)),
            np.int64,
        )
        codes = mixed_radix_encode(self.initial_fields(placements), self.radices)
        unique, counts = np.unique(codes, return_counts=True)
        return unique, counts / len(placements)


class TableCleaningVariant(TimeLimitedStep):
    """A table-cleaning task (FunctionalEnv protocol, gymnax-style API; rules: module doc).

    Args:
      generator: the variant's generator, or ``None`` for the paper's ``n = 2, k = 1``.
    """

    def __init__(self, generator: TableCleaningGenerator | None = None) -> None:
        self.generator = generator or TableCleaningGenerator()
        n = self.generator.num_sections
        self.num_sections = n
        self.num_goblets = self.generator.num_goblets
        self.num_actions = n + 5
        self.clean_action = n + 3
        self.abort_action = n + 4
        self.action_names = (
            "get", "drop", *(f"go_{i}" for i in range(n)), "go_home", "clean", "abort",
        )
        self.field_names = (
            "hand_obj", "hand_pos",
            *(f"goblet_{j}" for j in range(self.num_goblets)),
            *(f"clean_{i}" for i in range(n)),
        )

    # --- encoding (FunctionalEnv protocol) ---------------------------------------------
    def num_codes(self, params: Any = None) -> int:
        return int(np.prod(self.generator.radices, dtype=object))

    def encode(self, fields: Array, params: Any = None) -> Array:
        """Mixed-radix int32 code of a field vector."""
        fields = jnp.asarray(fields, jnp.int32)
        return mixed_radix_encode(fields, self.generator.radices).astype(jnp.int32)

    def decode(self, code: Array, params: Any = None) -> Array:
        """Field vector of a code."""
        return mixed_radix_decode(code, self.generator.radices)

    def start_distribution(self, params: Any = None) -> tuple[np.ndarray, np.ndarray]:
        """See :meth:`TableCleaningGenerator.start_distribution`."""
        return self.generator.start_distribution()

    # --- dynamics ------------------------------------------------------------------------
    def transition(
        self, fields: Array, action: Array, params: EnvParams
    ) -> tuple[Array, Array, Array]:
        """The generalised transition rule (module docstring), without time.

        Args:
          fields: int32 ``[2 + k + n]`` state vector.
          action: int32 action index.
          params: options (``invalid_action`` is used).

        Returns:
          ``(next_fields, reward, terminal)``.
        """
        n, k, home = self.num_sections, self.num_goblets, self.generator.home
        # A Python int action would make the masks below Python bools, whose ``~`` is an int.
        action = jnp.asarray(action, jnp.int32)
        hand_obj, hand_pos = fields[0], fields[1]
        goblets = _sort_small(fields[2: 2 + k])  # canonical multiset, also for unsorted codes
        clean = fields[2 + k:]
        at_section = hand_pos < home
        free, sponge, goblet = hand_obj == FREE, hand_obj == SPONGE, hand_obj == GOBLET
        goblet_here = at_section & jnp.any(goblets == hand_pos)

        get_sponge = free & ~at_section
        get_goblet = free & goblet_here
        drop_sponge = sponge & ~at_section
        drop_goblet = goblet & at_section
        clean_fails = goblet | goblet_here
        cleans = sponge & at_section & ~clean_fails

        is_get, is_drop = action == GET, action == DROP
        is_clean = action == self.clean_action
        is_move = (action >= GO_FIRST) & (action <= GO_FIRST + n)

        new_hand_obj = jnp.select(
            [is_get & get_sponge, is_get & get_goblet, is_drop & (drop_sponge | drop_goblet)],
            [SPONGE, GOBLET, FREE],
            hand_obj,
        )
        new_hand_pos = jnp.where(is_move, action - GO_FIRST, hand_pos)
        # Take the first goblet standing here / put down the first one in the hand (masks,
        # not scatters: much faster under vmap); re-sorting restores the canonical order.
        taken = jnp.where(_first(goblets == hand_pos), home, goblets)
        dropped = jnp.where(_first(goblets == home), hand_pos, goblets)
        new_goblets = jnp.select(
            [is_get & get_goblet, is_drop & drop_goblet], [taken, dropped], goblets
        )
        new_goblets = _sort_small(new_goblets)
        sweep = is_clean & cleans & (jnp.arange(n) == hand_pos)
        new_clean = jnp.where(sweep, 1, clean)
        next_fields = jnp.concatenate(
            [jnp.stack([new_hand_obj, new_hand_pos]), new_goblets, new_clean]
        ).astype(jnp.int32)

        failure = (action == self.abort_action) | (is_clean & clean_fails)
        if params.invalid_action == "fail":
            canonical = jnp.concatenate([fields[:2], goblets, clean])
            failure = failure | (jnp.all(next_fields == canonical) & ~is_move)
        goal = (
            ~failure
            & (new_hand_obj == FREE)
            & (new_hand_pos == home)
            & jnp.all(new_clean == 1)
        )
        # The rewards are looked up now (at trace time): a patched constant is seen.
        reward = jnp.select([failure, goal], [core.FAILURE_REWARD, core.GOAL_REWARD],
                            core.STEP_REWARD)
        return next_fields, reward.astype(jnp.float32), failure | goal

    # --- gymnax-style API ----------------------------------------------------------------
    def reset(self, key: Array, params: EnvParams | None = None) -> tuple[Array, EnvState]:
        """Sample an initial state with the generator.

        Returns:
          ``(observation, state)``; the observation is the field vector.
        """
        state = self.generator(key)
        return state.fields, state


def make_variant(
    num_sections: int = 2, num_goblets: int = 1
) -> TableCleaningVariant:
    """The variant environment with ``num_sections`` sections and ``num_goblets`` goblets.

    Args:
      num_sections: ``n >= 2``.
      num_goblets: ``k >= 1``.

    Returns:
      the :class:`TableCleaningVariant`.
    """
    return TableCleaningVariant(TableCleaningGenerator(num_sections, num_goblets))


def make_variant_mdp(
    num_sections: int = 2,
    num_goblets: int = 1,
    *,
    max_steps: int = 100,
    invalid_action: str = "noop",
    reachable_only: bool = True,
) -> TabularMDP:
    """A variant compiled into a :class:`~vdbejax.envs.TabularMDP`.

    Args:
      num_sections: ``n >= 2``.
      num_goblets: ``k >= 1``.
      max_steps: truncation length.
      invalid_action: ``"noop"`` or ``"fail"``.
      reachable_only: keep only the states reachable from the start distribution (state
        index ↔ code in ``mdp.state_codes``); ``False`` gives one state per code, which for
        ``n = 2, k = 1`` gives the tables of :func:`~vdbejax.envs.table_cleaning.make_mdp`.

    Returns:
      the deterministic MDP, named ``table_cleaning_n{n}_k{k}``.
    """
    from vdbejax.envs.compiled import compile_env

    env = make_variant(num_sections, num_goblets)
    return compile_env(
        env,
        make_params(max_steps, invalid_action),
        name=f"table_cleaning_n{num_sections}_k{num_goblets}",
        reachable_only=reachable_only,
    )
