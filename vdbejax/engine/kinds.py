"""Every kind of a batch in one program: :class:`KindSwitch`.

A kind is a learner type and an explorer type with their static fields; the step rule
(:mod:`vdbejax.engine.step`) traces a kind's plug-ins into its program. With a
:class:`KindSwitch`, each kind's part of the step is one branch of a ``lax.switch`` and the
rest of the step is traced once, so a grid of eight kinds costs one trace of the loop, not
eight. Each branch computes what its kind's program would: the results are the same bits.
With a kind per lane (a mixed batch of the lockstep strategy), every branch runs on every
lane and each lane keeps its own kind's results (:func:`switch_part`).
"""
from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp

from vdbejax import _pytree
from vdbejax.engine.kind_step import StepOperands, kind_part

Array = jax.Array

#: Most kinds of agent one program serves. A switch's compile time grows faster than its
#: branches (a cold process, the table-cleaning task: 9 kinds 3.0 s, 18 kinds 6.0 s, 36
#: kinds 21 s), so more kinds are split into blocks of about equal size, a program each.
MAX_SWITCH_KINDS = 16


def switch_block_size(num_kinds: int) -> int:
    """Kinds per program for a run of ``num_kinds`` kinds: blocks of about equal size, at
    most :data:`MAX_SWITCH_KINDS` (kind ``k`` is branch ``k % size`` of program
    ``k // size``)."""
    blocks = -(-max(num_kinds, 1) // MAX_SWITCH_KINDS)
    return -(-max(num_kinds, 1) // blocks)


@_pytree.pytree_dataclass
class KindSwitch:
    """The hyperparameters of every kind of a batch, and which kind runs.

    One program then serves every kind (:data:`kinds` are traced once each inside a
    ``lax.switch`` on ``kind``, around one trace of the rest of the step), instead of one
    program per kind. ``kind`` is a scalar (a batch's lanes are all of that kind) or int32
    ``[lanes]``, each lane's kind (a mixed batch). Only when :func:`table_forms` finds one
    way of writing every table (:func:`can_switch`).
    """

    kinds: tuple
    kind: Any


def write_form(role: str, per: str) -> str:
    """How a table of this role and shape is written after a step."""
    if role == "learner":
        return "pair_value"  # Q-like: the value at (s, a)
    return "state_value" if per == "state" else "pair_row"  # the explorer's of s


def table_forms(kinds: tuple) -> dict[str, str] | None:
    """Each table's write form over ``kinds``, or None when one name is written two ways
    (a learner's and an explorer's table of one name): those kinds need one program each."""
    forms: dict[str, str] = {}
    for agent in kinds:
        for role, owner in (("learner", agent.learner), ("explorer", agent.explorer)):
            for name, spec in owner.tables().items():
                if forms.setdefault(name, write_form(role, spec.per)) != write_form(
                        role, spec.per):
                    return None
    return forms


def is_whole_kind(agent: Any) -> bool:
    """Whether a kind's learner uses a model, plans or updates its whole table
    (:mod:`vdbejax.engine.whole`)."""
    learner = agent.learner
    return bool(learner.uses_model or learner.updates_whole_table
                or learner.plan_at is not None or has_stage_tables(learner))


def has_stage_tables(learner: Any) -> bool:
    """Whether a learner keeps stage-dependent tables (``Table("stage", ...)``)."""
    return any(spec.per == "stage" for spec in learner.tables().values())


def can_switch(kinds: tuple) -> bool:
    """Whether one :class:`KindSwitch` program can serve ``kinds`` (whole kinds get a
    program each)."""
    return (len(kinds) > 1 and not any(is_whole_kind(k) for k in kinds)
            and table_forms(kinds) is not None)


def switch_part(switch: KindSwitch, operands: StepOperands, *, num_actions: int, forms: dict,
                dtypes: dict) -> tuple[Array, dict, Array, Array]:
    """Every kind's part of an iteration (:func:`~vdbejax.engine.kind_step.kind_part` on
    ``operands``), each lane keeping its own kind's.

    ``forms``: :func:`table_forms` of the switch's kinds; ``dtypes``: each table's dtype.
    A scalar ``switch.kind`` runs one branch of a ``lax.switch``; a kind per lane runs
    every branch on every lane and selects per lane (a branch's values on another kind's
    lanes are discarded unread).

    Returns:
      ``(new_q_sa, writes, next_action, finite)``; ``writes`` maps every table of
      ``forms`` to ``(value [lanes, width], owned)``, ``owned`` whether the lane's kind
      has that table (a scalar for a scalar ``kind``).
    """
    lanes = operands.a.shape[0]

    def branch(kind_agent: Any) -> Any:
        def run(operands: StepOperands) -> tuple:
            new_q_sa, learned, explored, next_action, finite = kind_part(
                kind_agent, operands, num_actions=num_actions)
            mine = {**learned, **explored}
            # Every table of every kind, in one form: the kind's new values where it owns
            # the table, a write that is masked off where it does not.
            writes = {}
            for name, form in forms.items():
                width = num_actions if form == "pair_row" else 1
                value = (mine[name][0].reshape(lanes, width).astype(dtypes[name])
                         if name in mine else jnp.zeros((lanes, width), dtypes[name]))
                writes[name] = (value, jnp.asarray(name in mine))
            return new_q_sa, writes, jnp.asarray(next_action, jnp.int32), finite
        return run

    branches = [branch(k) for k in switch.kinds]
    kind = jnp.asarray(switch.kind, jnp.int32)
    if kind.ndim == 0:
        return jax.lax.switch(kind, branches, operands)
    outputs = [run(operands) for run in branches]

    def per_lane(*values: Array) -> Array:
        if values[0].ndim == 0:  # one flag per kind: each lane's kind's
            return jnp.stack(values)[kind]
        which = jax.lax.broadcast_in_dim(kind, values[0].shape, (0,))
        return jax.lax.select_n(which, *values)

    return jax.tree.map(per_lane, *outputs)
