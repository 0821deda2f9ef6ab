"""One kind's part of an iteration: its plug-ins' rows read and the learner's and
explorer's step for one agent (:func:`agent_step`), vmapped over the lanes
(:func:`kind_part`). :mod:`vdbejax.engine.step` reads and writes the lanes' tables around
it; on a CPU each kind's part is one branch of the run's program
(:mod:`vdbejax.engine.kinds`).
"""
from __future__ import annotations

from functools import partial
from typing import Any

import jax
import jax.numpy as jnp

from vdbejax import _pytree
from vdbejax.engine.lanes import is_unrolled, learner_rows, rows_of
from vdbejax.methods.agents import Agent
from vdbejax.methods.contract import Context, Transition, as_draws, behaviour_values

Array = jax.Array


#: Uniforms the engine itself draws per iteration: start state and outcome.
ENGINE_UNIFORMS = 2


def _uniform_counts(agent: Agent, num_actions: int) -> tuple[int, int, int, int]:
    """Uniforms of an iteration after the engine's, in order: the explorer's, the
    learner's, the explorer's again when the learner redraws its next action, the plan's
    (a plug-in's :meth:`~vdbejax.methods.contract.Explorer.draws` in the task)."""
    explorer = agent.explorer.draws(num_actions).slots()
    redraw = explorer if agent.learner.redraws_next_action else 0
    return (explorer, agent.learner.draws(num_actions).slots(), redraw,
            int(agent.learner.plan_uniforms))


def num_uniforms(agent: Agent, num_actions: int) -> int:
    """Uniforms one iteration of this kind draws in a task of ``num_actions`` actions (the
    engine's and :func:`uniform_parts`)."""
    return ENGINE_UNIFORMS + sum(_uniform_counts(agent, num_actions))


def uniform_parts(agent: Agent, u: tuple, num_actions: int
                  ) -> tuple[tuple, tuple, tuple, tuple]:
    """An iteration's uniforms ``u`` split into the explorer's, the learner's, the
    redrawn choice's and the plan's (the engine's own are ``u[:ENGINE_UNIFORMS]``), the
    first three as the draws their plug-in asks for
    (:func:`~vdbejax.methods.contract.as_draws`)."""
    parts, start = [], ENGINE_UNIFORMS
    for count in _uniform_counts(agent, num_actions):
        parts.append(u[start:start + count])
        start += count
    explorer_draws = agent.explorer.draws(num_actions)
    return (as_draws(explorer_draws, parts[0]),
            as_draws(agent.learner.draws(num_actions), parts[1]),
            as_draws(explorer_draws, parts[2]) if parts[2] else (), parts[3])


@_pytree.pytree_dataclass
class StepOperands:
    """What a kind's part of an iteration reads (:func:`kind_part`), batched over the lanes;
    :func:`~vdbejax.engine.step.lockstep_iteration` gathers it.

    Attributes:
      tables: the plug-ins' flat tables (every kind's).
      a: the action taken in ``s`` (clipped to the task's actions).
      s: the state left.
      act_state: where the next action is chosen (``s'``, or the next episode's start).
      q_sa: ``Q(s, a)``.
      q_next: Q's ``[A]`` row at ``act_state``.
      reward: the step's reward.
      terminal: the step ended its episode.
      self_loop: the next action is chosen in ``s`` itself (see :func:`agent_step`).
      sa_index: the flat index of ``(s, a)`` in a Q-shaped table.
      pair_base: the flat index of each lane's first ``(s, a)`` in a Q-shaped table.
      state_base: the flat index of each lane's first state in a per-state table.
      update_context: the :class:`~vdbejax.methods.contract.Context` of the update.
      select_context: the :class:`~vdbejax.methods.contract.Context` of the next choice.
      u: the iteration's uniforms (:func:`uniform_parts`).
      s_next: the state reached.
      time: the agent's counter (its iterations so far).
    """

    tables: dict
    a: Array
    s: Array
    act_state: Array
    q_sa: Array
    q_next: Array
    reward: Array
    terminal: Array
    self_loop: Array
    sa_index: Array
    pair_base: Array
    state_base: Array
    update_context: Context
    select_context: Context
    u: tuple
    s_next: Array
    time: Array


@_pytree.pytree_dataclass
class AgentStepInputs:
    """What one agent's step reads (:func:`agent_step`; batched over the lanes by
    :func:`kind_part`).

    Attributes:
      a: the action taken in ``state``.
      q_sa: ``Q(s, a)``.
      q_next: Q's ``[A]`` row where the next action is chosen.
      learner_sa: the learner's tables at ``(s, a)``.
      learner_next: the learner's ``[A]`` rows where the next action is chosen.
      explorer_s: the explorer's tables at ``s``.
      explorer_next: the explorer's tables where the next action is chosen.
      reward: the step's reward.
      terminal: the step ended its episode.
      self_loop: the next action is chosen in the state just left (its rows must show
        this step's update for learners that choose after it).
      update_context: the :class:`~vdbejax.methods.contract.Context` of the update.
      select_context: the :class:`~vdbejax.methods.contract.Context` of the next choice.
      explorer_uniforms: the explorer's draws.
      learner_uniforms: the learner's draws.
      redraw_uniforms: for a learner that ``redraws_next_action`` (the authors' SARSA),
        the draws of the action actually taken, drawn afresh after the update.
      state: the state left.
      next_state: the state reached.
      time: the agent's counter.
    """

    a: Array
    q_sa: Array
    q_next: Array
    learner_sa: dict
    learner_next: dict
    explorer_s: dict
    explorer_next: dict
    reward: Array
    terminal: Array
    self_loop: Array
    update_context: Context
    select_context: Context
    explorer_uniforms: tuple
    learner_uniforms: tuple
    redraw_uniforms: tuple
    state: Array
    next_state: Array
    time: Array


def agent_step(agent: Agent, step: AgentStepInputs, whole: tuple | None = None, *,
               select_next: bool = True, unchanged: set[str] | None = None
               ) -> tuple[Array, dict, dict, Array, Array]:
    """One agent's learning and choice (vmapped over lanes by :func:`kind_part`).

    ``whole``: the agent's whole Q and learner tables, for a learner that
    ``updates_whole_table`` (its update returns them whole). Without ``select_next`` a
    learner that chooses after its update chooses nothing here
    (:mod:`vdbejax.engine.whole` chooses once the tables are written). ``unchanged``
    collects the names (``"q"`` for Q) of the tables the update returns as it received
    them.

    Returns:
      ``(new_q_sa, new_learner_sa, new_explorer_s, next_action, finite)``.
    """
    a, q_sa, q_next = step.a, step.q_sa, step.q_next
    learner_sa, learner_next = step.learner_sa, step.learner_next
    explorer_s, explorer_next = step.explorer_s, step.explorer_next
    terminal, self_loop = step.terminal, step.self_loop
    update_context, select_context = step.update_context, step.select_context
    learner, explorer = agent.learner, agent.explorer
    discount = jnp.where(terminal, 0.0, learner.gamma)
    zero_probabilities = jnp.zeros_like(q_next)

    def learn(next_action: Array, probabilities: Array) -> tuple:
        transition = Transition(
            q=q_sa, tables=learner_sa, reward=step.reward, discount=discount, q_next=q_next,
            tables_next=learner_next, next_action=next_action,
            next_probabilities=probabilities, uniforms=step.learner_uniforms,
            terminal=terminal, state=step.state, action=a, next_state=step.next_state,
            step=update_context.step, time=step.time,
        )
        update = (learner.update(transition) if whole is None
                  else learner.update_table(whole[0], whole[1], transition))
        new_explorer_s = explorer.update(explorer_s, a, update.delta_q, update_context)
        return update, new_explorer_s

    def probabilities_next() -> Array:
        if not learner.uses_next_probabilities:
            return zero_probabilities
        behaviour = behaviour_values(learner, q_next, learner_next, select_context)
        return explorer.probabilities(behaviour, explorer_next, select_context)

    def select_after(update: Any, new_explorer_s: dict, uniforms: tuple) -> Array:
        """Choose after the update: where a' is chosen in s itself, its rows show it."""
        patched = self_loop & (jnp.arange(q_next.shape[0]) == a)
        act_q = jnp.where(patched, update.q, q_next)
        act_learner = {name: jnp.where(patched, update.tables[name], row)
                       for name, row in learner_next.items()}
        act_explorer = {name: jnp.where(self_loop, new_explorer_s[name], value)
                        for name, value in explorer_next.items()}
        behaviour = behaviour_values(learner, act_q, act_learner, select_context)
        return explorer.select(behaviour, act_explorer, select_context, uniforms)

    if learner.uses_next_action:
        behaviour = behaviour_values(learner, q_next, learner_next, select_context)
        next_action = explorer.select(behaviour, explorer_next, select_context,
                                      step.explorer_uniforms)
        update, new_explorer_s = learn(next_action, probabilities_next())
        if learner.redraws_next_action:  # the a' of the target is not the one taken
            next_action = select_after(update, new_explorer_s, step.redraw_uniforms)
    else:
        update, new_explorer_s = learn(jnp.zeros((), jnp.int32), probabilities_next())
        next_action = (select_after(update, new_explorer_s, step.explorer_uniforms) if select_next
                       else jnp.zeros((), jnp.int32))
    # What the update returns as it received it was checked when it was written (and the
    # non-finite flag is sticky): neither checked nor written back again.
    kept = set() if whole is not None else (
        {name for name, row in learner_sa.items() if update.tables.get(name) is row}
        | ({"q"} if update.q is q_sa else set()))
    if unchanged is not None:
        unchanged.update(kept)
    new_values = ({} if "q" in kept else {"q": update.q},
                  {name: value for name, value in update.tables.items() if name not in kept},
                  new_explorer_s)
    finite = all_finite(jax.tree.leaves(new_values))
    return (update.q, update.tables, new_explorer_s,
            jnp.asarray(next_action, jnp.int32), finite)


def all_finite(leaves: list) -> Array:
    """Whether every value of ``leaves`` is finite (integers always are), as lax's
    primitives: one reduction per leaf, traced several times faster than ``jnp.all``."""
    finite = jnp.asarray(True)
    for leaf in leaves:
        leaf = jnp.asarray(leaf)
        if jnp.issubdtype(leaf.dtype, jnp.inexact):
            finite = jax.lax.bitwise_and(finite, jax.lax.reduce_and(
                jax.lax.is_finite(leaf), tuple(range(leaf.ndim))))
    return finite


def kind_part(agent: Agent, operands: StepOperands, *, num_actions: int,
              whole: tuple | None = None, select_next: bool = True,
              skip_unchanged: bool = False
              ) -> tuple[Array | None, dict, dict, Array, Array]:
    """The part of an iteration that depends on the kind: the plug-ins' tables read, the
    learner's and explorer's step (:func:`agent_step`, vmapped over the lanes).
    ``whole``, ``select_next``: see :func:`agent_step` (batched over the lanes).
    ``skip_unchanged``: leave out of ``learned`` the learner's tables that its update
    returns unchanged, and return ``None`` for an unchanged Q: writing them back would
    rewrite what is there. (Where the update returns a stage table unchanged, as UCBVI's
    and PSRL's do, the write made XLA copy the whole table every step.)

    Returns:
      ``(new_q_sa, learner_sa (new, old), explorer_s (new, old), next_action, finite)``,
      the table dicts mapping each of the kind's tables to its new and old values (with
      ``whole``: the new Q and learner tables whole, and their old values).
    """
    tables, s, act_state = operands.tables, operands.s, operands.act_state
    pair_base, state_base = operands.pair_base, operands.state_base
    learner, explorer = agent.learner, agent.explorer
    A = num_actions
    explorer_u, learner_u, redraw_u, _ = uniform_parts(agent, operands.u, A)
    learner_specs = learner.tables()
    learner_sa = {name: learner_rows(tables[name], operands.sa_index, 1, spec)
                  for name, spec in learner_specs.items()}
    learner_next = {name: learner_rows(tables[name], pair_base + act_state * A, A, spec)
                    for name, spec in learner_specs.items()}
    explorer_specs = explorer.tables()

    def explorer_rows(state: Array) -> dict:
        return rows_of(tables, explorer_specs, state, pair_base, state_base, A)

    if is_unrolled(s):
        explorer_s, explorer_next = explorer_rows(s), explorer_rows(act_state)
    else:
        # One read of s's and s′'s rows: it feeds the table's write, so XLA writes the
        # table in place (a read of s′'s rows alone feeds only the next action, and XLA
        # copied the whole table every iteration to keep it).
        both = rows_of(tables, explorer_specs, jnp.concatenate([s, act_state]),
                       jnp.concatenate([pair_base, pair_base]),
                       jnp.concatenate([state_base, state_base]), A)
        half = s.shape[0]
        explorer_s = {name: rows[:half] for name, rows in both.items()}
        explorer_next = {name: rows[half:] for name, rows in both.items()}
    unchanged: set[str] | None = set() if skip_unchanged else None
    step = partial(agent_step, select_next=select_next, unchanged=unchanged)
    inputs = AgentStepInputs(
        a=operands.a, q_sa=operands.q_sa, q_next=operands.q_next, learner_sa=learner_sa,
        learner_next=learner_next, explorer_s=explorer_s, explorer_next=explorer_next,
        reward=operands.reward, terminal=operands.terminal, self_loop=operands.self_loop,
        update_context=operands.update_context, select_context=operands.select_context,
        explorer_uniforms=explorer_u, learner_uniforms=learner_u, redraw_uniforms=redraw_u,
        state=s, next_state=operands.s_next, time=operands.time)
    new_q_sa, new_learner_sa, new_explorer_s, next_action, finite = jax.vmap(step)(
        agent, inputs, *(() if whole is None else (whole,)))
    old = learner_sa if whole is None else whole[1]
    unchanged = unchanged or set()
    learned = {name: (new_learner_sa[name], old[name]) for name in learner_specs
               if name not in unchanged}
    explored = {name: (new_explorer_s[name], explorer_s[name]) for name in explorer_specs}
    return (None if "q" in unchanged else new_q_sa), learned, explored, next_action, finite
