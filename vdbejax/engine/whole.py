"""The step rule's part for model-based, planning and whole-table learners.

A learner that ``uses_model``, ``updates_whole_table`` or has a ``plan_at`` moment
(:mod:`vdbejax.methods.contract`) is a *whole* kind. After its learning step
(:func:`vdbejax.engine.step.lockstep_iteration`: the rows of (s, a), or with
``updates_whole_table`` its whole Q and tables, written back), :func:`after_learning`

1. adds the outcome to the agent's model rows at (s, a) (:func:`vdbejax.methods.model.observe`);
2. where the learner's moment has come, runs its :meth:`plan` on the agent's whole Q,
   tables and model — one lane at a time under a ``cond`` in the CPU engine's loops (a
   lane that does not plan copies nothing), all lanes masked in wide batches;
3. chooses the next action from the tables as they now are (a learner that chooses
   before its update, ``uses_next_action``, has chosen already and cannot plan).

A kind that is none of these never reaches this module: its program is the one it has
always had. Whole kinds get a program each (no :class:`~vdbejax.engine.kinds.KindSwitch`).
"""
from __future__ import annotations

import dataclasses
from typing import Any

import jax
import jax.numpy as jnp

from vdbejax.engine.kinds import has_stage_tables
from vdbejax.engine.lanes import is_unrolled, learner_rows, put_learned, rows_of, take, take_row
from vdbejax.methods.agents import Agent
from vdbejax.methods.contract import Context, Learner, behaviour_values
from vdbejax.methods.model import MODEL_TABLES, Model, observe

Array = jax.Array


def defers_selection(learner: Learner) -> bool:
    """Whether the next action is chosen after the tables are written (planning or a
    whole-table update changes rows other than (s, a); a stage table's rows are read
    whole)."""
    return not learner.uses_next_action and (learner.plan_at is not None
                                             or learner.updates_whole_table
                                             or has_stage_tables(learner))


def whole_blocks(q: Array, tables: dict, learner: Learner, pair_base: Array,
                 size: int, shape: tuple[int, int]) -> tuple[Array, dict]:
    """Each lane's whole Q and learner tables (``[B, S, A]``, stage tables ``[B, S, A,
    length]``)."""
    def block(buffer: Array, width: int = 1, stage: bool = False) -> Array:
        rows = take_row(buffer, pair_base * width, size * width)
        return rows.reshape(-1, *shape, *((width,) if stage else ()))

    return block(q), {name: block(tables[name], spec.width(), spec.per == "stage")
                      for name, spec in learner.tables().items()}


@dataclasses.dataclass(frozen=True)
class LearnedStep:
    """What :func:`after_learning` needs of the iteration (batched over the lanes), and
    the task's ``num_states``, ``num_actions`` and model ``capacity`` (outcomes kept per
    pair, :func:`~vdbejax.methods.model.capacity`)."""

    s: Array
    s_next: Array
    act_state: Array
    reward: Array
    terminal: Array
    sa_index: Array
    pair_base: Array
    state_base: Array
    learn: Array
    active: Array
    resetting: Array
    counter: Array
    select_context: Context
    explorer_uniforms: tuple
    plan_uniforms: tuple
    num_states: int
    num_actions: int
    capacity: int


def after_learning(agent: Agent, q: Array, tables: dict, next_action: Array, finite: Array,
                   step: LearnedStep) -> tuple[Array, dict, Array, Array]:
    """Model, planning and the deferred choice of a whole kind (see the module docstring).

    Returns:
      ``(q, tables, next_action, finite)``.
    """
    learner = agent.learner
    tables = dict(tables)
    old_visits = None
    if learner.uses_model:
        old_visits = take(tables["model_visits"], step.sa_index)
        tables = _observe(tables, step)
    if learner.plan_at is not None:
        moment = _moment(agent, step, old_visits,
                         take(tables["model_visits"], step.sa_index) if old_visits is not None
                         else None)
        q, tables, planned_finite = _plan(agent, q, tables, moment, step)
        finite = finite & planned_finite
    if defers_selection(learner):
        next_action = _select(agent, q, tables, step)
    return q, tables, next_action, finite


def _observe(tables: dict, step: LearnedStep) -> dict:
    """The model rows at (s, a) after the step's outcome (where it learned)."""
    capacity = step.capacity

    def index(per: str) -> tuple[Array, int]:
        return (step.sa_index, 1) if per == "pair" else (step.sa_index * capacity, capacity)

    rows = {}
    for name, per in MODEL_TABLES.items():  # an outcome list is a row, even of one outcome
        at, width = index(per)
        rows[name] = take(tables[name], at) if per == "pair" else take_row(tables[name], at,
                                                                             width)
    new = jax.vmap(observe)(rows, step.s_next, step.reward, step.terminal)
    for name, per in MODEL_TABLES.items():
        at, _ = index(per)
        tables[name] = put_learned(tables[name], at, new[name], rows[name], step.learn,
                                   per != "pair")
    return tables


def _moment(agent: Agent, step: LearnedStep, old_visits: Array | None,
            new_visits: Array | None) -> Array:
    """Whether each lane plans now (its learner's ``plan_at``)."""
    learner = agent.learner
    when = learner.plan_at
    if when == "step":
        return step.learn
    if when == "episode":  # before the first action of every episode
        return step.active & (step.resetting | (step.learn & step.terminal))
    if when == "every":
        period = jnp.asarray(learner.plan_every).astype(jnp.uint32)  # type: ignore[attr-defined]
        return step.learn & ((step.counter + jnp.uint32(1)) % jnp.maximum(period, 1) == 0)
    assert when == "known" and old_visits is not None and new_visits is not None
    known = jnp.asarray(learner.known_visits, jnp.float32)  # type: ignore[attr-defined]
    return step.learn & (old_visits < known) & (new_visits >= known)


def _plan(agent: Agent, q: Array, tables: dict, moment: Array, step: LearnedStep
          ) -> tuple[Array, dict, Array]:
    """Run the learner's plan where ``moment``; returns the buffers and a finite flag."""
    learner = agent.learner
    S, A, K = step.num_states, step.num_actions, step.capacity
    size = S * A
    specs = learner.tables()
    own = list(specs)
    model_names = list(MODEL_TABLES) if learner.uses_model else []

    def per_pair(name: str) -> int:  # entries per (s, a)
        if name in specs:
            return specs[name].width()
        return K if MODEL_TABLES[name] == "outcome" else 1

    def width(name: str) -> int:
        return size * per_pair(name)

    def shape(name: str) -> tuple[int, ...]:
        listed = specs[name].per == "stage" if name in specs else MODEL_TABLES[name] == "outcome"
        return (S, A, per_pair(name)) if listed else (S, A)

    def planned(lane_agent: Any, q_block: Array, blocks: dict, context: Context,
                uniforms: tuple) -> tuple[Array, dict, Array]:
        model = (Model.from_tables({n: blocks[n] for n in model_names})
                 if model_names else None)
        new_q, new_tables = lane_agent.learner.plan(
            q_block, {n: blocks[n] for n in own}, model, context, uniforms)
        new_q = jnp.asarray(new_q, jnp.float32)
        new_tables = {n: jnp.asarray(new_tables[n], jnp.float32) for n in own}
        ok = jnp.all(jnp.asarray([jnp.all(jnp.isfinite(x))
                                  for x in jax.tree.leaves((new_q, new_tables))]))
        return new_q, new_tables, ok

    names = own + model_names
    if is_unrolled(step.pair_base):  # one lane at a time: a lane that does not plan copies nothing
        # A loop over the lanes, not an unrolled one: the plan (a posterior draw, a backward
        # induction) is traced and compiled once, not once per lane.
        def lane_plan(k: Array, carry: tuple) -> tuple:
            q, tables, flags = carry

            def run(buffers: tuple) -> tuple:
                q, tables = buffers
                base = step.pair_base[k]
                q_block = jax.lax.dynamic_slice(q, (base,), (size,)).reshape(S, A)
                blocks = {n: jax.lax.dynamic_slice(
                    tables[n], (base * (width(n) // size),), (width(n),)).reshape(shape(n))
                    for n in names}
                lane = jax.tree.map(lambda x: x[k], (agent, step.select_context,
                                                     step.plan_uniforms))
                new_q, new_tables, ok = planned(lane[0], q_block, blocks, lane[1], lane[2])
                q = jax.lax.dynamic_update_slice(q, new_q.reshape(-1), (base,))
                tables = dict(tables)
                for n in own:
                    tables[n] = jax.lax.dynamic_update_slice(
                        tables[n], new_tables[n].reshape(-1), (base * per_pair(n),))
                return (q, tables), ok

            def skip(buffers: tuple) -> tuple:
                return buffers, jnp.asarray(True)

            (q, tables), ok = jax.lax.cond(moment[k], run, skip, (q, tables))
            return q, tables, flags.at[k].set(ok)

        lanes = step.pair_base.shape[0]
        q, tables, flags = jax.lax.fori_loop(0, lanes, lane_plan,
                                             (q, tables, jnp.ones(lanes, bool)))
        return q, tables, flags
    # wide batches (the lockstep strategy): every lane plans, the moment masks the writes
    q_blocks = take_row(q, step.pair_base, size).reshape(-1, S, A)
    blocks = {n: take_row(tables[n], step.pair_base * (width(n) // size), width(n)).reshape(
        -1, *shape(n)) for n in names}
    new_q, new_tables, ok = jax.vmap(planned)(agent, q_blocks, blocks, step.select_context,
                                              step.plan_uniforms)
    n_lanes = q_blocks.shape[0]
    q = put_learned(q, step.pair_base, new_q.reshape(n_lanes, -1),
                    q_blocks.reshape(n_lanes, -1), moment, True)
    tables = dict(tables)
    for n in own:
        tables[n] = put_learned(tables[n], step.pair_base * per_pair(n),
                                new_tables[n].reshape(n_lanes, -1),
                                blocks[n].reshape(n_lanes, -1), moment, True)
    return q, tables, ok | ~moment


def _select(agent: Agent, q: Array, tables: dict, step: LearnedStep) -> Array:
    """The next action in ``act_state``, from the tables as written."""
    A = step.num_actions
    learner_specs = agent.learner.tables()
    q_next = take_row(q, step.pair_base + step.act_state * A, A)
    learner_next = {name: learner_rows(tables[name], step.pair_base + step.act_state * A, A,
                                       spec)
                    for name, spec in learner_specs.items()}
    explorer_next = rows_of(tables, agent.explorer.tables(), step.act_state, step.pair_base,
                            step.state_base, A)

    def choose(lane_agent: Agent, q_row: Array, learner_row: dict, explorer_row: dict,
               context: Context, uniforms: tuple) -> Array:
        behaviour = behaviour_values(lane_agent.learner, q_row, learner_row, context)
        return jnp.asarray(lane_agent.explorer.select(behaviour, explorer_row, context,
                                                      uniforms), jnp.int32)

    return jax.vmap(choose)(agent, q_next, learner_next, explorer_next, step.select_context,
                            step.explorer_uniforms)
