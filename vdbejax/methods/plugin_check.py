"""The plug-in check: :func:`check_plugin` traces one agent's plug-in functions on abstract
inputs before any training, so that a wrong shape or dtype, a failing function or a side
effect is a one-line ``ValueError`` rather than an error deep inside the engine's program.
"""
from __future__ import annotations

import hashlib
from collections.abc import Callable, Mapping
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from vdbejax.methods.contract import (
    PLAN_MOMENTS,
    TABLE_KINDS,
    Context,
    Draws,
    Explorer,
    Learner,
    LearnerUpdate,
    Table,
    Transition,
    as_draws,
)
from vdbejax.methods.model import Model


def check_plugin(agent_learner: Learner, agent_explorer: Explorer, num_actions: int = 3,
                 num_states: int | None = None) -> str:
    """Trace one agent's plug-in functions on abstract inputs; a one-line ``ValueError``
    for wrong shapes or dtypes, a failing function, or side effects.

    Args:
      agent_learner: one learner instance (scalar leaves).
      agent_explorer: one explorer instance.
      num_actions: actions of the task.
      num_states: states of the task, if known: the learner's ``initial_q`` must give
        ``[num_states, num_actions]``.

    Returns:
      the digest of the traced programs (their equations, not the hyperparameters'
      values): an edited plug-in gets another one, so a run's fingerprint, and hence its
      checkpoint and saved results, tell the code they were made with.
    """
    programs: list[str] = []
    name = f"explorer {agent_explorer.name!r}"
    A = num_actions
    f32 = jnp.float32
    row, scalar = _abstract((A,), f32), _abstract((), f32)
    tables = _table_values(name, agent_explorer.tables(), row, scalar)
    for tname, spec in agent_explorer.tables().items():
        if spec.per == "stage":
            raise ValueError(f"{name} table {tname!r} is per 'stage': stage tables are a"
                             " learner's")
    ltables = _table_values(f"learner {agent_learner.name!r}", agent_learner.tables(), row, scalar)
    lspecs = agent_learner.tables()
    for tname, spec in lspecs.items():
        if spec.per == "state":
            raise ValueError(f"learner {agent_learner.name!r} table {tname!r} is per 'state': a"
                             " learner's extra tables are per 'pair' or 'stage'")
        if spec.per == "stage" and (isinstance(spec.length, bool)
                                    or not isinstance(spec.length, (int, np.integer))
                                    or spec.length < 1):
            raise ValueError(f"learner {agent_learner.name!r} table {tname!r} length="
                             f"{spec.length!r} is invalid: a stage table needs an integer"
                             " length >= 1")
    # a learner's tables at (s, a), their rows at a state, whole
    lpair = {k: _abstract((s.width(),), f32) if s.per == "stage" else scalar
             for k, s in lspecs.items()}
    ltables = {k: _abstract((A, s.width()), f32) if s.per == "stage" else row
               for k, s in lspecs.items()}
    context = Context(_abstract((), jnp.int32), _abstract((), jnp.int32),
                      _abstract((), jnp.bool_))
    uniforms = _abstract_draws(name, agent_explorer, A)

    def traced(what: str, fn: Callable, *args: Any) -> Any:
        try:
            closed = jax.make_jaxpr(fn)(*args)
        except ValueError:
            raise
        except (Exception, SystemExit) as error:
            raise failure(f"{what} fails on one agent's inputs", error) from None
        if closed.effects:
            raise ValueError(f"{what} has side effects ({sorted(map(str, closed.effects))}):"
                             " plug-in functions must be pure")
        if _calls_back(closed.jaxpr):
            raise ValueError(f"{what} calls back into Python (jax.pure_callback): the engine"
                             " runs plug-ins in compiled, vmapped loops, where a host callback"
                             " would run at every step of every agent; write it in jax.numpy")
        programs.append(f"{what}\n{closed.jaxpr}")
        return jax.eval_shape(fn, *args)

    action = traced(f"{name} select()", agent_explorer.select, row, tables, context, uniforms)
    if getattr(action, "shape", None) != () or not jnp.issubdtype(action.dtype, jnp.integer):
        raise ValueError(f"{name} select() returned {_describe(action)}: must be one integer"
                         " action (shape ())")
    action = _abstract((), jnp.int32)
    new = traced(f"{name} update()", agent_explorer.update, tables, action, scalar, context)
    _check_same(f"{name} update()", new, tables)
    _check_actions_in_range(name, agent_explorer, A)
    uses_probabilities = agent_learner.uses_next_probabilities
    if uses_probabilities:
        try:
            probs = traced(f"{name} probabilities()", agent_explorer.probabilities, row,
                           tables, context)
        except ValueError as error:  # name the learner that asks for them
            raise ValueError(f"{error} (learner {agent_learner.name!r} reads them:"
                             " uses_next_probabilities)") from None
        _check_same(f"{name} probabilities()", probs, row)
    lname = f"learner {agent_learner.name!r}"
    if num_states is not None:  # not part of the digest: the programs stay as they were
        try:
            first = jax.eval_shape(lambda key: agent_learner.initial_q(key, num_states, A),
                                   _abstract((2,), jnp.uint32))
        except (Exception, SystemExit) as error:
            raise failure(f"{lname} initial_q() fails on one agent's inputs", error) from None
        if getattr(first, "shape", None) != (num_states, A):
            raise ValueError(f"{lname} initial_q() returned {_describe(first)}: must be the"
                             f" task's [{num_states}, {A}] (states × actions) Q table")
    behaviour = traced(f"{lname} behaviour()", agent_learner.behaviour, row, ltables,
                       *((context,) if agent_learner.behaviour_uses_context else ()))
    _check_same(f"{lname} behaviour()", behaviour, row)
    luniforms = _abstract_draws(lname, agent_learner, A)
    index = _abstract((), jnp.int32)
    transition = Transition(scalar, lpair, scalar, scalar, row, ltables,
                            action, row, luniforms, _abstract((), jnp.bool_), index, index,
                            index, index, index)
    _check_whole_flags(lname, agent_learner)
    if agent_learner.updates_whole_table:
        whole_q = _abstract((_STATES, A), f32)
        whole = _whole_tables(lspecs, A)
        result = traced(f"{lname} update_table()", agent_learner.update_table, whole_q, whole,
                        transition)
        _check_update(f"{lname} update_table()", result, whole_q, whole, scalar)
    else:
        result = traced(f"{lname} update()", agent_learner.update, transition)
        _check_update(f"{lname} update()", result, scalar, lpair, scalar)
        _check_declared_inputs(lname, agent_learner, transition)
    if agent_learner.plan_at is not None:
        _check_plan(lname, agent_learner, A, context, traced)
    # What the engine reads besides the programs: the tables' specifications and the flags.
    declared = [repr(plugin.tables()) + repr([getattr(plugin, flag, None) for flag in _FLAGS])
                for plugin in (agent_explorer, agent_learner)]
    text = "\n".join([*declared, *programs])
    return hashlib.sha256(text.encode()).hexdigest()[:16]


#: JAX's errors for Python control flow on a traced value (``if x > 0:``, ``int(x)``).
_TRACED_IN_PYTHON = (jax.errors.TracerBoolConversionError,
                     jax.errors.TracerIntegerConversionError,
                     jax.errors.ConcretizationTypeError)


def failure(what: str, error: BaseException) -> ValueError:
    """The one-line error for a plug-in function that failed where the check ran it:
    ``what`` (which function, on what), the error's type and first line, and what to change
    where the cause is a known mistake (Python control flow on a traced value, a draw past
    those declared, ``sys.exit`` in a plug-in)."""
    if isinstance(error, SystemExit):
        return ValueError(f"{what}: it called sys.exit({error.code!r}); a plug-in function"
                          " returns its result and never ends the program")
    text = str(error).strip()
    message = f"{what}: {type(error).__name__}: {text.splitlines()[0] if text else ''}".rstrip()
    if isinstance(error, _TRACED_IN_PYTHON):
        message += (" (a Python if, while, and/or, bool() or int() on a traced value:"
                    " write it with jnp.where or jax.lax.cond)")
    elif isinstance(error, IndexError) and "tuple index" in text:
        message += (" (a draw u[i] past those declared? a plug-in gets num_uniforms"
                    " uniforms, or what its draws(num_actions) asks for: raise num_uniforms)")
    return ValueError(message)


#: The contract's flags, part of a plug-in's code digest (:func:`check_plugin`).
_FLAGS = ("num_uniforms", "uses_next_action", "uses_next_probabilities", "redraws_next_action",
          "behaviour_uses_context", "uses_model", "updates_whole_table", "plan_at",
          "plan_uniforms")


def _abstract_draws(name: str, plugin: Explorer | Learner, num_actions: int) -> tuple:
    """Abstract stand-ins of the draws ``plugin`` asks for in a task of ``num_actions``
    actions (scalars; a key ``uint32[2]``), its request checked."""
    _count(name, plugin.num_uniforms)  # what the default draws() hands on
    try:
        draws = plugin.draws(num_actions)
    except (Exception, SystemExit) as error:
        raise failure(f"{name} draws({num_actions}) fails", error) from None
    if type(draws) is not Draws:
        raise ValueError(f"{name} draws({num_actions}) returned {type(draws).__name__}: must"
                         " return Draws(uniforms, normals, keys)")
    for field in ("uniforms", "normals", "keys"):
        _count(f"{name} draws({num_actions}).{field}", getattr(draws, field), "")
    _count(f"{name} draws({num_actions}) in all", draws.slots(), "")
    scalar = _abstract((), jnp.float32)
    return ((scalar,) * (draws.uniforms + draws.normals)
            + (_abstract((2,), jnp.uint32),) * draws.keys)


#: Sample states an explorer's ``select`` is run on by :func:`_check_actions_in_range`.
_SAMPLES = 8


def _check_actions_in_range(name: str, agent_explorer: Explorer, num_actions: int) -> None:
    """Run ``select`` on a few sample states (small Q values, one row all tied, the tables
    at their initial values and after some visits, draws at the stream's extremes and
    between) and refuse an action outside ``[0, num_actions)``: a plug-in sized for
    another task (a hard-coded number of actions) is caught before training, not flagged
    after it."""
    rng = np.random.default_rng(0)
    A, f32 = num_actions, np.float32
    # Small values: a formula that overflows on large ones (an unstabilised softmax at a
    # small τ) is a numerical matter, flagged at run time (nonfinite), not refused here.
    q = (rng.normal(size=(_SAMPLES, A)) * 1e-3).astype(f32)
    q[0] = 0.0  # all tied
    tables = {key: jnp.full((_SAMPLES, *((A,) if spec.per == "pair" else ())), spec.init,
                            jnp.float32)
              for key, spec in agent_explorer.tables().items()}
    context = Context(jnp.arange(_SAMPLES, dtype=jnp.int32), jnp.zeros(_SAMPLES, jnp.int32),
                      jnp.zeros(_SAMPLES, bool))
    visited = jnp.asarray(np.arange(_SAMPLES) >= _SAMPLES // 2)
    for _ in range(3):  # half the states visited a few times, through the explorer's update
        actions = jnp.asarray(rng.integers(0, A, _SAMPLES), jnp.int32)
        delta_q = jnp.asarray(rng.normal(size=_SAMPLES), jnp.float32)
        updated = jax.vmap(agent_explorer.update)(tables, actions, delta_q, context)
        tables = {key: jnp.where(visited.reshape((-1,) + (1,) * (value.ndim - 1)),
                                 jnp.asarray(updated[key], jnp.float32), value)
                  for key, value in tables.items()}
    draws = agent_explorer.draws(A)
    edges = np.linspace(0.0, 1.0 - 2.0**-23, _SAMPLES, dtype=f32)
    uniforms = tuple(jnp.asarray(rng.permutation(edges)) for _ in range(draws.slots()))
    given = as_draws(draws, uniforms)
    try:
        chosen = np.asarray(jax.vmap(agent_explorer.select)(jnp.asarray(q), tables, context,
                                                             given))
    except (Exception, SystemExit) as error:
        raise failure(f"{name} select() fails on sample states", error) from None
    bad = (chosen < 0) | (chosen >= A)
    if bad.any():
        raise ValueError(f"{name} select() returned action {int(chosen[bad][0])} on a"
                         f" sample state of a task with {A} actions: must be in [0, {A - 1}]"
                         " (size its draws and arrays from the Q row it is given)")


#: States and listed successors of the abstract task a whole-table plug-in is traced on.
_STATES, _SUCCESSORS = 4, 2


def _whole_tables(specs: Mapping[str, Table], num_actions: int) -> dict[str, Any]:
    """Abstract whole learner tables: ``[S, A]``, a stage table ``[S, A, length]``."""
    return {k: _abstract((_STATES, num_actions, *((s.width(),) if s.per == "stage" else ())),
                         jnp.float32) for k, s in specs.items()}


def _check_update(what: str, result: Any, q: Any, tables: Any, delta_q: Any) -> None:
    if not isinstance(result, LearnerUpdate):
        raise ValueError(f"{what} returned {type(result).__name__}: must return a"
                         " LearnerUpdate(q, tables, delta_q)")
    _check_same(f"{what} q", result.q, q)
    _check_same(f"{what} delta_q", result.delta_q, delta_q)
    _check_same(f"{what} tables", result.tables, tables)


def _check_whole_flags(lname: str, agent_learner: Learner) -> None:
    """The model, planning and whole-table flags: known values, fields they need, and no
    combination the engine cannot honour."""
    when = agent_learner.plan_at
    if when is not None and when not in PLAN_MOMENTS:
        raise ValueError(f"{lname} plan_at={when!r} is invalid: must be None or one of"
                         f" {', '.join(PLAN_MOMENTS)}")
    for flag in ("uses_model", "updates_whole_table"):
        if not isinstance(getattr(agent_learner, flag), (bool, np.bool_)):
            raise ValueError(f"{lname} {flag}={getattr(agent_learner, flag)!r} is invalid:"
                             " must be True or False")
    _count(f"{lname} plan", agent_learner.plan_uniforms)
    fields = {"every": "plan_every", "known": "known_visits"}
    if when in fields and not hasattr(agent_learner, fields[when]):
        raise ValueError(f"{lname} plan_at={when!r} needs a field {fields[when]!r}")
    if when == "known" and not agent_learner.uses_model:
        raise ValueError(f"{lname} plan_at='known' needs uses_model = True (the visits are the"
                         " model's)")
    if when is not None and agent_learner.uses_next_action:
        raise ValueError(f"{lname} plans (plan_at={when!r}) but declares uses_next_action: a′"
                         " would be chosen before the plan could inform it")
    whole = when is not None or agent_learner.uses_model or agent_learner.updates_whole_table
    if whole and agent_learner.redraws_next_action:
        raise ValueError(f"{lname} redraws its next action, which a model-based, planning or"
                         " whole-table learner cannot do")


def _check_plan(lname: str, agent_learner: Learner, num_actions: int, context: Context,
                traced: Callable) -> None:
    f32 = jnp.float32
    whole_q = _abstract((_STATES, num_actions), f32)
    whole = _whole_tables(agent_learner.tables(), num_actions)
    model = None
    if agent_learner.uses_model:
        lists = _abstract((_STATES, num_actions, _SUCCESSORS), f32)
        model = Model(whole_q, whole_q, whole_q, whole_q, lists, lists)
    uniforms = tuple(_abstract((), f32) for _ in range(agent_learner.plan_uniforms))
    result = traced(f"{lname} plan()", agent_learner.plan, whole_q, whole, model, context,
                    uniforms)
    if not (isinstance(result, tuple) and len(result) == 2):
        raise ValueError(f"{lname} plan() returned {type(result).__name__}: must return"
                         " (q, tables)")
    _check_same(f"{lname} plan() q", result[0], whole_q)
    _check_same(f"{lname} plan() tables", dict(result[1]), whole)


#: What a learner's update may read only when it declares it (the engine passes zeros
#: otherwise, so an undeclared read gives wrong numbers, not an error).
_DECLARED_INPUTS = (("next_action", "uses_next_action"),
                    ("next_probabilities", "uses_next_probabilities"))


def _check_declared_inputs(lname: str, agent_learner: Learner, transition: Transition) -> None:
    """Refuse a learner whose update depends on ``next_action`` or ``next_probabilities``
    without the flag that makes the engine compute it (the traced program shows it)."""
    from jax._src.interpreters import partial_eval

    undeclared = [(field, flag) for field, flag in _DECLARED_INPUTS
                  if not getattr(agent_learner, flag)]
    if not undeclared:
        return

    closed = jax.make_jaxpr(agent_learner.update)(transition)
    _, used = partial_eval.dce_jaxpr(closed.jaxpr, [True] * len(closed.jaxpr.outvars))
    paths = [jax.tree_util.keystr(path)
             for path, _ in jax.tree_util.tree_flatten_with_path(transition)[0]]
    used = [any(u for p, u in zip(paths, used, strict=True) if field in p)
            for field, _ in undeclared]
    for (field, flag), needed in zip(undeclared, used, strict=True):
        if needed:
            raise ValueError(f"{lname} update() reads t.{field} but the learner does not"
                             f" declare {flag} = True: the engine would pass zeros")


def _calls_back(jaxpr: Any) -> bool:
    """Whether ``jaxpr`` (or one nested in it: a cond's branches, a loop's body) calls a
    host function (``jax.pure_callback``; other callbacks are effects)."""
    for eqn in jaxpr.eqns:
        if "callback" in eqn.primitive.name:
            return True
        for value in eqn.params.values():
            for sub in value if isinstance(value, (tuple, list)) else (value,):
                inner = getattr(sub, "jaxpr", sub)  # a ClosedJaxpr's, or a Jaxpr itself
                if hasattr(inner, "eqns") and _calls_back(inner):
                    return True
    return False


def _abstract(shape: tuple[int, ...], dtype: Any) -> Any:
    """A shape-and-dtype stand-in for an array (what ``jax.eval_shape`` traces with), in
    the place of the ``Array`` fields of :class:`Context` and :class:`Transition`."""
    return jax.ShapeDtypeStruct(shape, dtype)


#: Most uniforms a plug-in may draw per step (and per planning call): each is its own
#: operation in the compiled step, so a million would trace and compile for hours.
MAX_UNIFORMS = 4096


def _count(name: str, value: Any, label: str = " num_uniforms") -> int:
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)) or not (
            0 <= value <= MAX_UNIFORMS):
        raise ValueError(f"{name}{label}={value!r} is invalid: must be an integer in"
                         f" [0, {MAX_UNIFORMS}] (each uniform is an operation of the compiled"
                         " step)")
    return int(value)


def _is_number(value: Any) -> bool:
    """A real number: a Python or NumPy one, or a 0-d array (a traced leaf) of one."""
    if isinstance(value, (bool, np.bool_)):
        return False
    if isinstance(value, (int, float, np.integer, np.floating)):
        return True
    dtype = getattr(value, "dtype", None)
    return (dtype is not None and np.ndim(value) == 0
            and (jnp.issubdtype(dtype, jnp.integer) or jnp.issubdtype(dtype, jnp.floating)))


def _table_values(name: str, specs: Any, row: Any, scalar: Any) -> dict[str, Any]:
    if not isinstance(specs, Mapping):
        raise ValueError(f"{name} tables() returned {type(specs).__name__}: must return"
                         " a dict {name: Table(per, init)}")
    values = {}
    for key, spec in specs.items():
        if not isinstance(spec, Table) or spec.per not in TABLE_KINDS:
            raise ValueError(f"{name} table {key!r}={spec!r} is invalid: must be"
                             " Table('state', 'pair' or 'stage', init)")
        if not _is_number(spec.init):
            shape = np.shape(spec.init) if hasattr(spec.init, "shape") else None
            raise ValueError(f"{name} table {key!r} init={spec.init!r} is invalid: must be a"
                             " number, every entry's start value"
                             + (f" (not an array of shape {shape})" if shape else ""))
        values[key] = scalar if spec.per == "state" else row
    return values


def _describe(value: Any) -> str:
    shapes = jax.tree.map(lambda x: f"{x.dtype}{list(x.shape)}", value)
    return str(shapes)


def _check_same(what: str, value: Any, expected: Any) -> None:
    # Shapes and dtypes: an int32 Q, say, would be stored without a word and round the
    # learning away.
    got = jax.tree.map(lambda x: (tuple(x.shape), jnp.dtype(x.dtype).name), value)
    want = jax.tree.map(lambda x: (tuple(x.shape), jnp.dtype(x.dtype).name), expected)
    # jax.tree.structure's return type (PyTreeDef) does not resolve for mypy.
    if (jax.tree.structure(got) != jax.tree.structure(want)  # type: ignore[operator]
            or jax.tree.leaves(got) != jax.tree.leaves(want)):
        raise ValueError(f"{what} returned {_describe(value)}: expected {_describe(expected)}")

