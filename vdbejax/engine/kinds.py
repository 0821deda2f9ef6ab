"""Every kind of a batch in one program: :class:`KindSwitch`.

A kind is a learner type and an explorer type with their static fields; the step rule
(:mod:`vdbejax.engine.step`) traces a kind's plug-ins into its program. With a
:class:`KindSwitch`, each kind's part of the step is one branch of a ``lax.switch`` and the
rest of the step is traced once, so a grid of eight kinds costs one trace of the loop, not
eight. Each branch computes what its kind's program would: the results are the same bits.
"""
from __future__ import annotations

from typing import Any

from vdbejax import _pytree


@_pytree.pytree_dataclass
class KindSwitch:
    """The hyperparameters of every kind of a batch, and which kind runs.

    One program then serves every kind (:data:`kinds` are traced once each inside a
    ``lax.switch`` on ``kind``, around one trace of the rest of the step), instead of one
    program per kind. ``kind`` is a scalar: a batch's lanes are all of that kind. Only for
    batches of a few lanes (unrolled table writes), and only when
    :func:`table_forms` finds one way of writing every table (:func:`can_switch`).
    """

    kinds: tuple
    kind: Any


def _write_form(role: str, per: str) -> str:
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
                if forms.setdefault(name, _write_form(role, spec.per)) != _write_form(
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
