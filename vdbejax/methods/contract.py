"""The plug-in contract: an explorer or a learner is data plus a few pure functions.

An explorer or learner is a frozen dataclass registered as a pytree (rejax style): its
numeric fields are the hyperparameters, pytree leaves, so a sweep is a ``vmap`` over a
batch of instances; fields declared with :func:`vdbejax.methods.static_field` (e.g.
``tie_break``) are part of the program. Its methods are pure JAX functions of **one
agent**: a Q row is ``[num_actions]``, a per-state table value a scalar, a per-(state,
action) table a row ``[num_actions]``; the engine ``vmap``s them over its lanes and calls
them inside its jitted step loop (:mod:`vdbejax.engine.step`). The type (class and static
fields) is the *kind* of the agent: each kind's step is its own code (on a CPU one branch
of the run's one program, :mod:`vdbejax.engine.kinds`), so a plug-in costs what its own
arithmetic costs (MushroomRL's "the policy is an object handed to the algorithm", with
JAX's "the object is data").

Write one with :func:`~vdbejax.methods.registry.explorer` /
:func:`~vdbejax.methods.registry.learner`::

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

Contract (checked by :func:`~vdbejax.methods.plugin_check.check_plugin` before any
training, one-line ``ValueError``):

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

The types are this module's: the :class:`Explorer` and :class:`Learner` base classes, the
:class:`Table` an agent keeps, and what the engine hands a plug-in (:class:`TaskFacts`,
:class:`Context`, :class:`Transition`, :class:`Draws`) and takes back
(:class:`LearnerUpdate`). The registry, its decorators and
:func:`~vdbejax.methods.registry.build` are :mod:`vdbejax.methods.registry`'s, and
:func:`~vdbejax.methods.plugin_check.check_plugin` is
:mod:`vdbejax.methods.plugin_check`'s; :mod:`vdbejax.methods` lists the plug-in surface
in one import.
"""
from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from typing import Any, ClassVar

import jax
import jax.numpy as jnp

from vdbejax._pytree import pytree_dataclass

Array = jax.Array

#: What a table holds one value of (``"stage"``: one per (state, action, stage), a
#: learner's stage-dependent values, ``length`` stages).
TABLE_KINDS = ("state", "pair", "stage")

#: When the engine calls a learner's :meth:`Learner.plan` (``plan_at``):
#:
#: * ``"step"``: after every learning step;
#: * ``"episode"``: before each episode's first action (after the update of the step that
#:   ended the previous one);
#: * ``"every"``: after every learning step that is the agent's ``plan_every``-th
#:   iteration (its iteration counter, resets included, a multiple of ``plan_every``);
#: * ``"known"``: after the learning step that brings the visits of its (s, a) to
#:   ``known_visits`` (R-max's "the pair becomes known"; needs ``uses_model``).
PLAN_MOMENTS = ("step", "episode", "every", "known")


@dataclasses.dataclass(frozen=True)
class Table:
    """A table an agent keeps per state (``"state"``: ``[S]``), per (state, action)
    (``"pair"``: ``[S, A]``) or, for a learner, per (state, action, stage) (``"stage"``:
    ``[S, A, length]``, e.g. the Q_h of finite-horizon methods), every entry starting at
    ``init``."""

    per: str
    init: Any = 0.0
    length: int | None = None

    def width(self) -> int:
        """Entries per (state, action) of a learner's table (``length`` of a stage table)."""
        return int(self.length) if self.per == "stage" and self.length is not None else 1


@dataclasses.dataclass(frozen=True)
class Draws:
    """The random draws a plug-in asks for per step (:meth:`Explorer.draws`,
    :meth:`Learner.draws`), handed to it as one tuple in this order: ``uniforms`` uniforms
    in [0, 1), ``normals`` standard normals, ``keys`` PRNG keys (raw ``uint32[2]``) for any
    other distribution (``jax.random.gamma``, ``jax.random.beta``, …, with parameters the
    plug-in computes). All come from the agent's own stream: results still depend only on
    its key and hyperparameters."""

    uniforms: int = 0
    normals: int = 0
    keys: int = 0

    def slots(self) -> int:
        """Uniforms of the agent's stream they take (a key takes two)."""
        return self.uniforms + self.normals + 2 * self.keys


def as_draws(draws: Draws, uniforms: tuple) -> tuple:
    """The draws ``draws`` asks for from its :meth:`Draws.slots` uniforms of the stream
    (uniforms ``m · 2⁻²³``, ``m`` a 23-bit integer): the uniforms as they are, a normal
    from one uniform (the inverse normal CDF at the open interval's ``u + 2⁻²⁴``), a key
    from two (their 23-bit integers)."""
    if draws.normals == 0 and draws.keys == 0:
        return tuple(uniforms)
    from jax.scipy.special import ndtri

    first = draws.uniforms + draws.normals
    normals = tuple(ndtri(u + jnp.float32(2.0**-24)) for u in uniforms[draws.uniforms:first])
    words = [(u * jnp.float32(2.0**23)).astype(jnp.uint32) for u in uniforms[first:]]
    keys = tuple(jnp.stack(words[2 * k: 2 * k + 2], axis=-1) for k in range(draws.keys))
    return (*uniforms[:draws.uniforms], *normals, *keys)


@dataclasses.dataclass(frozen=True)
class TaskFacts:
    """What the engine tells a learner about its task before training
    (:meth:`Learner.for_task`): a method's convention may depend on them, and a method may
    not read the task itself (methods know nothing of tasks).

    Attributes:
      reward_min, reward_max: the smallest and largest reward of an outcome the task can
        give (probability > 0).
      terminates: some outcome of the task ends its episode (a terminal outcome; the step
        limit is not one).
    """

    reward_min: float
    reward_max: float
    terminates: bool

    @property
    def reward_range(self) -> float:
        """``reward_max − reward_min``."""
        return self.reward_max - self.reward_min


@pytree_dataclass
class Context:
    """Where the agent is: ``episode`` (0-based index of the episode the action belongs
    to), ``step`` (steps already taken in it) and ``terminal`` (the transition just made
    ended its episode; ``False`` when selecting)."""

    episode: Array
    step: Array
    terminal: Array


@pytree_dataclass
class Transition:
    """What a learner's update sees (one agent).

    Attributes:
      q: Q(s, a) before the update.
      tables: the learner's own tables at (s, a) (scalars).
      reward: the transition's reward.
      discount: γ, or 0 when ``s'`` is terminal.
      q_next: ``[A]`` Q row of ``s'`` (of the next episode's start state after a
        terminal step; multiplied by discount 0 then).
      tables_next: the learner's tables at ``s'`` (``[A]`` rows).
      next_action: a′ (only with ``uses_next_action``; else 0).
      next_probabilities: ``[A]`` π(·|s′) (only with ``uses_next_probabilities``; else
        zeros).
      uniforms: the learner's draws (:meth:`Learner.draws`: by default ``num_uniforms``
        uniforms in [0, 1)).
      terminal: the transition ended its episode (a failure has a negative reward, a goal
        a positive one, on the tasks of vdbejax).
      state, action, next_state: s, a and s′ (int32 scalars; s′ is the state the
        transition reached, also when it is terminal).
      step: the steps taken in the episode, this one included (1 on an episode's first
        step: where traces of the previous episode are cleared after a truncation).
      time: the agent's iterations before this one (its counter: steps, plus one per
        episode start after a truncation; int32).
    """

    q: Array
    tables: dict
    reward: Array
    discount: Array
    q_next: Array
    tables_next: dict
    next_action: Array
    next_probabilities: Array
    uniforms: tuple
    terminal: Array
    # The engine always passes these; a learner's own unit test may leave them out.
    state: Array | None = None
    action: Array | None = None
    next_state: Array | None = None
    step: Array | None = None
    time: Array | None = None


@pytree_dataclass
class LearnerUpdate:
    """A learner's result: new Q(s,a), new values of its tables at (s,a), and ΔQ (from
    :meth:`Learner.update_table`: the whole new Q ``[S, A]`` and tables)."""

    q: Array
    tables: dict
    delta_q: Array


class Explorer:
    """Base class of action-selection methods (the contract: the module docstring)."""

    name: ClassVar[str] = ""
    #: The name figures and tables show (``"VDBE-Softmax"``; default: :attr:`name`).
    title: ClassVar[str] = ""
    #: The hyperparameter a :class:`~vdbejax.methods.agents.Setting`'s ``param`` sets.
    parameter: ClassVar[str | None] = None
    #: Uniforms ``select`` receives (the :meth:`draws` of a plug-in that does not
    #: override it).
    num_uniforms: ClassVar[int] = 3
    #: Grid-wide option names this explorer takes under another field name.
    option_aliases: ClassVar[dict[str, str]] = {}

    def draws(self, num_actions: int) -> Draws:
        """The draws ``select`` receives each step (as its ``uniforms`` tuple), sized from
        the task's number of actions where need be; ``num_uniforms`` uniforms by default."""
        return Draws(uniforms=self.num_uniforms)

    def tables(self) -> dict[str, Table]:
        """The tables this explorer keeps (none by default)."""
        return {}

    def select(self, q: Array, tables: Mapping[str, Array], context: Context,
               uniforms: tuple[Array, ...]) -> Array:
        """The action to take (int32 scalar) given the state's Q row and tables."""
        raise NotImplementedError

    def probabilities(self, q: Array, tables: Mapping[str, Array], context: Context) -> Array:
        """``[A]`` probability of each action under :meth:`select`."""
        raise NotImplementedError(f"explorer {self.name!r} does not define probabilities()")

    def update(self, tables: Mapping[str, Array], action: Array, delta_q: Array,
               context: Context) -> dict[str, Array]:
        """The state's tables after a learning step in it (unchanged by default)."""
        return dict(tables)

    def validate(self) -> None:
        """Raise a one-line ``ValueError`` for out-of-range hyperparameters."""


class Learner:
    """Base class of learning rules (the contract: the module docstring)."""

    name: ClassVar[str] = ""
    #: The name figures and tables show (``"Q-learning"``; default: :attr:`name`).
    title: ClassVar[str] = ""
    num_uniforms: ClassVar[int] = 0
    uses_next_action: ClassVar[bool] = False
    uses_next_probabilities: ClassVar[bool] = False
    option_aliases: ClassVar[dict[str, str]] = {}
    #: The engine keeps the agent's model of the task (:class:`~vdbejax.methods.model.Model`:
    #: visits, rewards and observed successors of every (s, a)) and hands it to :meth:`plan`.
    uses_model: ClassVar[bool] = False
    #: :meth:`update_table` replaces :meth:`update`: the whole Q and tables every step
    #: (eligibility traces).
    updates_whole_table: ClassVar[bool] = False
    #: When :meth:`plan` runs (one of :data:`PLAN_MOMENTS`), or ``None``: never.
    plan_at: ClassVar[str | None] = None
    #: Uniforms :meth:`plan` receives.
    plan_uniforms: ClassVar[int] = 0
    #: :meth:`behaviour` takes the :class:`Context` of the choice as a third argument
    #: (stage-dependent values: the step within the episode picks the stage).
    behaviour_uses_context: ClassVar[bool] = False
    #: The discount γ: every learner has this field (:func:`learner` checks it).
    gamma: float | Array

    @property
    def redraws_next_action(self) -> bool:
        """With ``uses_next_action``: the action taken in s′ is drawn afresh after the
        update (the a′ of the target only serves the target; the authors' SARSA). A class
        attribute, or a property where it is an option."""
        return False

    def draws(self, num_actions: int) -> Draws:
        """The draws ``update`` receives each step (``transition.uniforms``), sized from the
        task's number of actions where need be; ``num_uniforms`` uniforms by default."""
        return Draws(uniforms=self.num_uniforms)

    def tables(self) -> dict[str, Table]:
        """Extra per-(state, action) tables (none by default)."""
        return {}

    def behaviour(self, q: Array, tables: Mapping[str, Array]) -> Array:
        """The ``[A]`` values the explorer acts on (Q itself by default)."""
        return q

    def for_task(self, task: TaskFacts) -> Learner:
        """This learner on a task with facts ``task``: the engine calls it once before
        training, on each kind of a batch (a batched instance: change static fields only).
        Itself by default; raise a one-line ``ValueError`` where the task does not suit."""
        return self

    def initial_q(self, key: Array, num_states: int, num_actions: int) -> Array:
        """The agent's initial Q table (``q_init`` everywhere by default)."""
        return jnp.full((num_states, num_actions), getattr(self, "q_init", 0.0), jnp.float32)

    def update(self, transition: Transition) -> LearnerUpdate:
        raise NotImplementedError

    def update_table(self, q: Array, tables: Mapping[str, Array],
                     transition: Transition) -> LearnerUpdate:
        """With ``updates_whole_table``: the whole new Q ``[S, A]`` and tables (each at
        its full shape) after ``transition``, and ΔQ(s, a) for the explorer."""
        raise NotImplementedError(f"learner {self.name!r} does not define update_table()")

    def plan(self, q: Array, tables: Mapping[str, Array], model: Any, context: Context,
             uniforms: tuple[Array, ...]) -> tuple[Array, dict[str, Array]]:
        """With ``plan_at``: the new whole Q ``[S, A]`` and the learner's whole tables,
        planned on the agent's model (``None`` without ``uses_model``). ``context`` is
        where the agent chooses its next action."""
        raise NotImplementedError(f"learner {self.name!r} does not define plan()")

    def validate(self) -> None:
        """Raise a one-line ``ValueError`` for out-of-range hyperparameters."""



def behaviour_values(learner: Learner, q: Array, tables: Mapping[str, Array],
                     context: Context) -> Array:
    """The ``[A]`` values ``learner``'s explorer acts on in a state (its :meth:`Learner.
    behaviour`, given the context where it asks for it)."""
    if learner.behaviour_uses_context:
        return learner.behaviour(q, tables, context)  # type: ignore[call-arg]
    return learner.behaviour(q, tables)
