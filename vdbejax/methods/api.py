"""The plug-in contract: an explorer or a learner is data plus a few pure functions.

An explorer or learner is a frozen dataclass registered as a pytree (rejax style): its
numeric fields are the hyperparameters, pytree leaves, so a sweep is a ``vmap`` over a
batch of instances; fields declared with :func:`static_field` (e.g. ``tie_break``) are
part of the program. Its methods are pure JAX functions of **one agent**: a Q row is
``[num_actions]``, a per-state table value a scalar, a per-(state, action) table a row
``[num_actions]``; the engine ``vmap``s them over its lanes and calls them inside its
jitted step loop (:mod:`vdbejax.engine.step`). The type (class and static fields) is the
*kind* of the agent: each kind's step is its own code (on a CPU one branch of the run's
one program, :mod:`vdbejax.engine.kinds`), so a plug-in costs what its own arithmetic
costs (MushroomRL's "the policy is an object handed to the algorithm", with JAX's "the
object is data").

Write one with :func:`explorer` / :func:`learner`::

    import jax.numpy as jnp
    import vdbejax
    from vdbejax.methods import Explorer, Setting, Table, explorer, greedy

    @explorer("my_count_bonus", parameter="beta")   # count_bonus is a built-in's name
    class CountBonus(Explorer):
        beta: float = 0.1
        def tables(self):                        # N(s, a), starts at 0
            return {"counts": Table("pair", 0.0)}
        def select(self, q, tables, context, uniforms):
            bonus = self.beta / jnp.sqrt(tables["counts"] + 1.0)
            return greedy(q + bonus, uniforms[0])
        def update(self, tables, action, delta_q, context):
            counts = tables["counts"]
            return {"counts": counts + (jnp.arange(counts.shape[0]) == action)}

    from vdbejax.envs.table_cleaning import make_mdp

    grid = vdbejax.run_grid(make_mdp(), [Setting("qlearning", "my_count_bonus", 0.5)])

Contract (checked by :func:`check_plugin` before any training, one-line ``ValueError``):

* **Explorer**: ``select(q, tables, context, uniforms) -> int action``; optional
  ``tables() -> {name: Table}``, ``update(tables, action, delta_q, context) -> tables``
  (after every learning step, with the tables of the state just left), ``probabilities(q,
  tables, context) -> [A]`` (the exact distribution ``select`` samples; Expected SARSA
  and :func:`vdbejax.results.analysis.action_probabilities` use it), ``num_uniforms`` (uniforms in
  [0, 1) handed to ``select``; 3 by default) or, for draws sized from the task or of
  other laws, ``draws(num_actions) -> Draws(uniforms, normals, keys)`` (handed to
  ``select`` in that order; :class:`~vdbejax.methods.contract.Draws`).
* **Learner**: ``update(transition) -> LearnerUpdate`` (new Q(s,a), new values of its own
  tables at (s,a), and ΔQ for the explorer); a ``gamma`` field (the engine passes
  ``discount = 0`` on terminal steps, ``gamma`` otherwise); optional ``tables()`` (extra
  per-(state, action) tables, e.g. Double Q's second table), ``behaviour(q, tables)``
  (the values the explorer acts on), ``initial_q(key, S, A)``, ``uses_next_action``
  (SARSA: a′ is drawn before the update and passed in), ``uses_next_probabilities``
  (Expected SARSA: π(·|s′) passed in), ``num_uniforms`` or ``draws(num_actions)``,
  ``for_task(task) -> learner``
  (the engine hands every learner the facts of its task before training,
  :class:`~vdbejax.methods.contract.TaskFacts`: its reward range and whether it has terminal
  outcomes; a method whose convention depends on them sets its static fields from them,
  e.g. UCBVI's rlberry convention and PSRL's prior).

The random numbers come from the engine's per-agent counter-based stream, so results
depend only on an agent's key and hyperparameters. If your update adds a product to
something, wrap the product in :func:`vdbejax.methods.rounded` when you need the last
bit to be the same in every engine strategy (XLA may fuse it into an FMA differently).

The pieces live in one module each and are re-exported here: the types
(:mod:`vdbejax.methods.contract`), the registry, its decorators and :func:`build`
(:mod:`vdbejax.methods.registry`), and :func:`check_plugin`
(:mod:`vdbejax.methods.plugin_check`).
"""
from __future__ import annotations

from vdbejax._pytree import static_field
from vdbejax.methods.contract import (  # noqa: F401  (re-exported)
    TABLE_KINDS,
    Array,
    Context,
    Draws,
    Explorer,
    Learner,
    LearnerUpdate,
    Table,
    TaskFacts,
    Transition,
)
from vdbejax.methods.plugin_check import check_plugin
from vdbejax.methods.registry import (  # noqa: F401  (re-exported)
    EXPLORERS,
    LEARNERS,
    as_leaf,
    build,
    explorer,
    explorer_title,
    field_names,
    hyperparameters,
    learner,
    learner_title,
    static_names,
)

__all__ = [
    "EXPLORERS",
    "LEARNERS",
    "Context",
    "Draws",
    "Explorer",
    "Learner",
    "LearnerUpdate",
    "Table",
    "TaskFacts",
    "Transition",
    "build",
    "check_plugin",
    "explorer",
    "field_names",
    "hyperparameters",
    "learner",
    "static_field",
]
