"""The plug-in contract: an explorer or a learner is data plus a few pure functions.

An explorer or learner is a frozen dataclass registered as a pytree (rejax style): its
numeric fields are the hyperparameters, pytree leaves, so a sweep is a ``vmap`` over a
batch of instances; fields declared with :func:`static_field` (e.g. ``tie_break``) are
part of the program. Its methods are pure JAX functions of **one agent**: a Q row is
``[num_actions]``, a per-state table value a scalar, a per-(state, action) table a row
``[num_actions]``; the engine ``vmap``s them over its lanes and calls them inside its
jitted step loop (:mod:`vdbejax.engine.step`). The type (class and static fields) is the
*kind* of the agent: the engine compiles one program per kind, so a plug-in costs what
its own arithmetic costs (MushroomRL's "the policy is an object handed to the
algorithm", with JAX's "the object is data").

Write one with :func:`explorer` / :func:`learner`::

    @vdbejax.methods.explorer("count_bonus", parameter="beta")
    class CountBonus(vdbejax.methods.Explorer):
        beta: float = 0.1
        def tables(self):                        # N(s, a), starts at 0
            return {"counts": Table("pair", 0.0)}
        def select(self, q, tables, context, uniforms):
            bonus = self.beta / jnp.sqrt(tables["counts"] + 1.0)
            return greedy(q + bonus, uniforms[0])
        def update(self, tables, action, delta_q, context):
            return {"counts": tables["counts"] + (jnp.arange(q.shape[0]) == action)}

Contract (checked by :func:`check_plugin` before any training, one-line ``ValueError``):

* **Explorer**: ``select(q, tables, context, uniforms) -> int action``; optional
  ``tables() -> {name: Table}``, ``update(tables, action, delta_q, context) -> tables``
  (after every learning step, with the tables of the state just left), ``probabilities(q,
  tables, context) -> [A]`` (the exact distribution ``select`` samples; Expected SARSA
  and :func:`vdbejax.analysis.action_probabilities` use it), ``num_uniforms`` (uniforms in
  [0, 1) handed to ``select``; 3 by default).
* **Learner**: ``update(transition) -> LearnerUpdate`` (new Q(s,a), new values of its own
  tables at (s,a), and ΔQ for the explorer); a ``gamma`` field (the engine passes
  ``discount = 0`` on terminal steps, ``gamma`` otherwise); optional ``tables()`` (extra
  per-(state, action) tables, e.g. Double Q's second table), ``behaviour(q, tables)``
  (the values the explorer acts on), ``initial_q(key, S, A)``, ``uses_next_action``
  (SARSA: a′ is drawn before the update and passed in), ``uses_next_probabilities``
  (Expected SARSA: π(·|s′) passed in), ``num_uniforms``.

The random numbers come from the engine's per-agent counter-based stream, so results
depend only on an agent's key and hyperparameters. If your update adds a product to
something, wrap the product in :func:`vdbejax.methods.rounded` when you need the last
bit to be the same in every engine strategy (XLA may fuse it into an FMA differently).
"""
from __future__ import annotations

import dataclasses
from collections.abc import Callable, Mapping
from typing import Any, ClassVar, TypeVar, dataclass_transform

import jax
import jax.numpy as jnp
import numpy as np

from vdbejax._pytree import pytree_dataclass, static_field

Array = jax.Array
ExplorerT = TypeVar("ExplorerT", bound="Explorer")
LearnerT = TypeVar("LearnerT", bound="Learner")

#: What a table holds one value of.
TABLE_KINDS = ("state", "pair")


@dataclasses.dataclass(frozen=True)
class Table:
    """A table an agent keeps per state (``"state"``: ``[S]``) or per (state, action)
    (``"pair"``: ``[S, A]``), every entry starting at ``init``."""

    per: str
    init: Any = 0.0


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
      uniforms: the learner's ``num_uniforms`` uniforms in [0, 1).
      terminal: the transition ended its episode (a failure has a negative reward, a goal
        a positive one, on the tasks of vdbejax).
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


@pytree_dataclass
class LearnerUpdate:
    """A learner's result: new Q(s,a), new values of its tables at (s,a), and ΔQ."""

    q: Array
    tables: dict
    delta_q: Array


class Explorer:
    """Base class of action-selection methods (see the module docstring)."""

    name: ClassVar[str] = ""
    #: The name figures and tables show (``"VDBE-Softmax"``; default: :attr:`name`).
    title: ClassVar[str] = ""
    #: The hyperparameter a :class:`~vdbejax.methods.agents.Setting`'s ``param`` sets.
    parameter: ClassVar[str | None] = None
    #: Uniforms ``select`` receives.
    num_uniforms: ClassVar[int] = 3
    #: Grid-wide option names this explorer takes under another field name.
    option_aliases: ClassVar[dict[str, str]] = {}

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
    """Base class of learning rules (see the module docstring)."""

    name: ClassVar[str] = ""
    #: The name figures and tables show (``"Q-learning"``; default: :attr:`name`).
    title: ClassVar[str] = ""
    num_uniforms: ClassVar[int] = 0
    uses_next_action: ClassVar[bool] = False
    uses_next_probabilities: ClassVar[bool] = False
    option_aliases: ClassVar[dict[str, str]] = {}
    #: The discount γ: every learner has this field (:func:`learner` checks it).
    gamma: float | Array

    @property
    def redraws_next_action(self) -> bool:
        """With ``uses_next_action``: the action taken in s′ is drawn afresh after the
        update (the a′ of the target only serves the target; the authors' SARSA). A class
        attribute, or a property where it is an option."""
        return False

    def tables(self) -> dict[str, Table]:
        """Extra per-(state, action) tables (none by default)."""
        return {}

    def behaviour(self, q: Array, tables: Mapping[str, Array]) -> Array:
        """The ``[A]`` values the explorer acts on (Q itself by default)."""
        return q

    def initial_q(self, key: Array, num_states: int, num_actions: int) -> Array:
        """The agent's initial Q table (``q_init`` everywhere by default)."""
        return jnp.full((num_states, num_actions), getattr(self, "q_init", 0.0), jnp.float32)

    def update(self, transition: Transition) -> LearnerUpdate:
        raise NotImplementedError

    def validate(self) -> None:
        """Raise a one-line ``ValueError`` for out-of-range hyperparameters."""


#: Registered plug-ins by name (built-ins and any user class decorated below).
EXPLORERS: dict[str, type[Explorer]] = {}
LEARNERS: dict[str, type[Learner]] = {}


@dataclass_transform(frozen_default=True, field_specifiers=(dataclasses.field,))
def explorer(name: str, parameter: str | None = None,
             title: str | None = None) -> Callable[[type[ExplorerT]], type[ExplorerT]]:
    """Class decorator: make ``cls`` a pytree dataclass and register it as explorer ``name``.

    Args:
      name: the name settings use (``Setting(learner, name, param)``).
      parameter: the field a setting's ``param`` sets (its swept parameter).
      title: the name figures and tables show (default: ``name``).

    Raises:
      ValueError: ``cls`` is not an :class:`Explorer` or lacks ``select``.
    """
    def register(cls: type[ExplorerT]) -> type[ExplorerT]:
        _check_class(cls, Explorer, "explorer", name, ("select",))
        cls = pytree_dataclass(cls)
        cls.name, cls.parameter, cls.title = name, parameter, title or name
        if parameter is not None and parameter not in field_names(cls):
            raise ValueError(f"explorer {name!r}: parameter={parameter!r} is not one of its fields"
                             f" {field_names(cls)}")
        EXPLORERS[name] = cls
        return cls

    return register


@dataclass_transform(frozen_default=True, field_specifiers=(dataclasses.field,))
def learner(name: str,
            title: str | None = None) -> Callable[[type[LearnerT]], type[LearnerT]]:
    """Class decorator: make ``cls`` a pytree dataclass and register it as learner ``name``
    (``title``: the name figures and tables show; default ``name``).

    Raises:
      ValueError: ``cls`` is not a :class:`Learner`, lacks ``update`` or a ``gamma`` field.
    """
    def register(cls: type[LearnerT]) -> type[LearnerT]:
        _check_class(cls, Learner, "learner", name, ("update",))
        cls = pytree_dataclass(cls)
        cls.name, cls.title = name, title or name
        if "gamma" not in field_names(cls):
            raise ValueError(f"learner {name!r} has no gamma field: the engine needs the discount")
        LEARNERS[name] = cls
        return cls

    return register


def explorer_title(name: str) -> str:
    """The display name of registered explorer ``name`` (``name`` itself if unknown)."""
    cls = EXPLORERS.get(name)
    return cls.title if cls is not None and cls.title else name


def learner_title(name: str) -> str:
    """The display name of registered learner ``name`` (``name`` itself if unknown)."""
    cls = LEARNERS.get(name)
    return cls.title if cls is not None and cls.title else name


def _check_class(cls: Any, base: type, role: str, name: str, required: tuple[str, ...]) -> None:
    if not isinstance(name, str) or not name or "/" in name or "," in name:
        raise ValueError(f"{role} name={name!r} is invalid: must be a non-empty string without"
                         " '/' or ','")
    if not (isinstance(cls, type) and issubclass(cls, base)):
        raise ValueError(f"{role} {name!r}: {cls!r} must be a subclass of vdbejax.methods."
                         f"{base.__name__}")
    for method in required:
        if getattr(cls, method) is getattr(base, method):
            raise ValueError(f"{role} {name!r} ({cls.__name__}) must define {method}()")


def field_names(cls: Any) -> list[str]:
    """The dataclass fields of a plug-in class (hyperparameters, static ones included)."""
    return [f.name for f in dataclasses.fields(cls)]


def static_names(cls: Any) -> list[str]:
    """The static (compile-time) fields of a plug-in class."""
    return [f.name for f in dataclasses.fields(cls) if f.metadata.get("static", False)]


def hyperparameters(instance: Any) -> dict[str, Any]:
    """Every field of a plug-in instance as Python values (scalars or strings)."""
    values = {}
    for name in field_names(type(instance)):
        value = getattr(instance, name)
        if isinstance(value, (np.ndarray, np.generic, jax.Array)):
            array = np.asarray(value)
            if array.dtype == np.float32:  # the shortest decimal that is this float32
                value = [float(str(v)) for v in array.ravel()]
                value = value[0] if array.ndim == 0 else np.reshape(value, array.shape).tolist()
            else:
                value = array.item() if array.ndim == 0 else array.tolist()
        values[name] = value
    return values


def as_leaf(name: str, value: Any) -> Any:
    """A hyperparameter value as a host scalar leaf (float32, int32 or bool).

    Raises:
      ValueError: not a number, or a number that float32 turns into 0 or ±inf (or a
        subnormal, which loses precision): the engine computes in float32.
    """
    if isinstance(value, (bool, np.bool_)):
        return np.asarray(value, np.bool_)
    if isinstance(value, (int, np.integer)) and abs(int(value)) < 2**31:
        return np.asarray(value, np.int32)
    if isinstance(value, (str, bytes)):
        raise ValueError(f"{name}={value!r} is invalid: must be a finite number")
    try:
        number = float(value)
    except (TypeError, ValueError, OverflowError):
        raise ValueError(f"{name}={value!r} is invalid: must be a finite number") from None
    with np.errstate(over="ignore"):
        single = np.float32(number)
    tiny = float(np.finfo(np.float32).tiny)
    if np.isfinite(number) and (not np.isfinite(single) or 0 < abs(number) < tiny):
        raise ValueError(f"{name}={value!r} is invalid: float32 (the engine's precision) cannot"
                         f" hold it; nonzero values need a magnitude in [{tiny:.3g},"
                         f" {float(np.finfo(np.float32).max):.3g}]")
    return np.asarray(single)


def build(cls: Any, values: Mapping[str, Any], role: str) -> Any:
    """An instance of plug-in class ``cls`` from ``values`` (host scalar leaves), validated.

    Raises:
      ValueError: a field without a default is missing, or :meth:`validate` refuses.
    """
    static = set(static_names(cls))
    unknown = sorted(set(values) - set(field_names(cls)))
    if unknown:
        raise ValueError(f"{role} {cls.name!r} has no field {unknown[0]!r}: its fields are"
                         f" {', '.join(field_names(cls)) or 'none'}")
    kwargs = {}
    for f in dataclasses.fields(cls):
        if f.name in values:
            value = values[f.name]
        elif f.default is not dataclasses.MISSING:
            value = f.default
        else:
            raise ValueError(f"{role} {cls.name!r} needs a value for {f.name!r}: give it as the"
                             " setting's param, a hyperparameter or a sweep axis")
        kwargs[f.name] = value if f.name in static else as_leaf(f.name, value)
    instance = cls(**kwargs)
    instance.validate()
    return instance


def check_plugin(agent_learner: Learner, agent_explorer: Explorer, num_actions: int = 3) -> None:
    """Trace one agent's plug-in functions on abstract inputs; a one-line ``ValueError``
    for wrong shapes or dtypes, a failing function, or side effects.

    Args:
      agent_learner: one learner instance (scalar leaves).
      agent_explorer: one explorer instance.
      num_actions: actions of the task.
    """
    name = f"explorer {agent_explorer.name!r}"
    A = num_actions
    f32 = jnp.float32
    row, scalar = _abstract((A,), f32), _abstract((), f32)
    tables = _table_values(name, agent_explorer.tables(), row, scalar)
    ltables = _table_values(f"learner {agent_learner.name!r}", agent_learner.tables(), row, scalar)
    for lname, spec in agent_learner.tables().items():
        if spec.per != "pair":
            raise ValueError(f"learner {agent_learner.name!r} table {lname!r} is per {spec.per!r}:"
                             " a learner's extra tables must be per 'pair'")
    context = Context(_abstract((), jnp.int32), _abstract((), jnp.int32),
                      _abstract((), jnp.bool_))
    uniforms = tuple(scalar for _ in range(_count(name, agent_explorer.num_uniforms)))

    def traced(what: str, fn: Callable, *args: Any) -> Any:
        try:
            closed = jax.make_jaxpr(fn)(*args)
        except ValueError:
            raise
        except Exception as error:
            message = (str(error).strip().splitlines()[0] if str(error).strip()
                       else type(error).__name__)
            raise ValueError(f"{what} fails on one agent's inputs: {type(error).__name__}: "
                             f"{message}") from None
        if closed.effects:
            raise ValueError(f"{what} has side effects ({sorted(map(str, closed.effects))}):"
                             " plug-in functions must be pure")
        return jax.eval_shape(fn, *args)

    action = traced(f"{name} select()", agent_explorer.select, row, tables, context, uniforms)
    if getattr(action, "shape", None) != () or not jnp.issubdtype(action.dtype, jnp.integer):
        raise ValueError(f"{name} select() returned {_describe(action)}: must be one integer"
                         " action (shape ())")
    action = _abstract((), jnp.int32)
    new = traced(f"{name} update()", agent_explorer.update, tables, action, scalar, context)
    _check_same(f"{name} update()", new, tables)
    uses_probabilities = agent_learner.uses_next_probabilities
    if uses_probabilities:
        probs = traced(f"{name} probabilities()", agent_explorer.probabilities, row, tables,
                       context)
        _check_same(f"{name} probabilities()", probs, row)
    lname = f"learner {agent_learner.name!r}"
    behaviour = traced(f"{lname} behaviour()", agent_learner.behaviour, row, ltables)
    _check_same(f"{lname} behaviour()", behaviour, row)
    luniforms = tuple(scalar for _ in range(_count(lname, agent_learner.num_uniforms)))
    transition = Transition(scalar, {k: scalar for k in ltables}, scalar, scalar, row, ltables,
                            action, row, luniforms, _abstract((), jnp.bool_))
    result = traced(f"{lname} update()", agent_learner.update, transition)
    if not isinstance(result, LearnerUpdate):
        raise ValueError(f"{lname} update() returned {type(result).__name__}: must return a"
                         " LearnerUpdate(q, tables, delta_q)")
    _check_same(f"{lname} update() q", result.q, scalar)
    _check_same(f"{lname} update() delta_q", result.delta_q, scalar)
    _check_same(f"{lname} update() tables", result.tables, {k: scalar for k in ltables})


def _abstract(shape: tuple[int, ...], dtype: Any) -> Any:
    """A shape-and-dtype stand-in for an array (what ``jax.eval_shape`` traces with), in
    the place of the ``Array`` fields of :class:`Context` and :class:`Transition`."""
    return jax.ShapeDtypeStruct(shape, dtype)


def _count(name: str, value: Any) -> int:
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)) or value < 0:
        raise ValueError(f"{name} num_uniforms={value!r} is invalid: must be an integer >= 0")
    return int(value)


def _table_values(name: str, specs: Any, row: Any, scalar: Any) -> dict[str, Any]:
    if not isinstance(specs, Mapping):
        raise ValueError(f"{name} tables() returned {type(specs).__name__}: must return"
                         " a dict {name: Table(per, init)}")
    values = {}
    for key, spec in specs.items():
        if not isinstance(spec, Table) or spec.per not in TABLE_KINDS:
            raise ValueError(f"{name} table {key!r}={spec!r} is invalid: must be"
                             " Table('state' or 'pair', init)")
        values[key] = scalar if spec.per == "state" else row
    return values


def _describe(value: Any) -> str:
    shapes = jax.tree.map(lambda x: f"{x.dtype}{list(x.shape)}", value)
    return str(shapes)


def _check_same(what: str, value: Any, expected: Any) -> None:
    got = jax.tree.map(lambda x: tuple(x.shape), value)
    want = jax.tree.map(lambda x: tuple(x.shape), expected)
    # jax.tree.structure's return type (PyTreeDef) does not resolve for mypy.
    if (jax.tree.structure(got) != jax.tree.structure(want)  # type: ignore[operator]
            or jax.tree.leaves(got) != jax.tree.leaves(want)):
        raise ValueError(f"{what} returned {_describe(value)}: expected {_describe(expected)}")


__all__ = [
    "EXPLORERS",
    "LEARNERS",
    "Context",
    "Explorer",
    "Learner",
    "LearnerUpdate",
    "Table",
    "Transition",
    "build",
    "check_plugin",
    "explorer",
    "field_names",
    "hyperparameters",
    "learner",
    "static_field",
]
