"""Agents = a learner and an explorer; the settings of a sweep and their batches.

A :class:`Setting` names one point of a grid: learner, explorer, the explorer's swept
parameter and any other hyperparameter values. :func:`make_agent` resolves it into an
:class:`Agent` (two plug-in instances, :mod:`vdbejax.methods.contract`), and
:func:`stack_agents` batches agents of any kinds into one :class:`AgentParams` pytree for
the engine. The settings of a product of axes: :func:`vdbejax.methods.grid_axes.sweep`.
"""
from __future__ import annotations

import dataclasses
import json
from collections.abc import Mapping, Sequence
from typing import Any

import jax
import numpy as np

from vdbejax._pytree import pytree_dataclass
from vdbejax.methods.contract import Explorer, Learner
from vdbejax.methods.explorers import PAPER_EXPLORERS, explorer_class
from vdbejax.methods.learners import PAPER_ALPHA, PAPER_GAMMA, PAPER_LEARNERS, learner_class
from vdbejax.methods.model import MODEL_PREFIX, MODEL_TABLES
from vdbejax.methods.registry import EXPLORERS, build, field_names, hyperparameters, static_names
from vdbejax.methods.selection import VDBE_DELTA, VDBE_SOFTMAX_TAU
from vdbejax.validation import check_int

#: The paper's swept values (spec, "Exploration").
PAPER_PARAMETERS: dict[str, tuple[float, ...]] = {
    "egreedy": (0.01, 0.05, 0.1, 0.15, 0.2),
    "softmax": (0.0001, 0.001, 0.01, 0.1, 1.0, 10.0),
    "vdbe": (0.001, 0.01, 0.1, 1.0, 10.0, 100.0),
    "vdbe_softmax": (0.001, 0.01, 0.1, 1.0, 10.0, 100.0),
}


def parameter_name(explorer: str) -> str:
    """The name of a registered explorer's swept parameter (``"param"`` if it is unknown:
    a saved result's settings carry their own, :func:`with_parameter_names`)."""
    cls = EXPLORERS.get(explorer)
    return (cls.parameter if cls is not None else None) or "param"


def with_parameter_names(settings: Sequence[Setting], names: Any) -> list[Setting]:
    """``settings`` whose explorers are not registered in this process (a saved grid of
    user plug-ins, e.g. ``vdbejax plot``) with the swept parameter's name a saved result
    recorded (``meta.json["parameter_names"]``, ``{explorer: name}``)."""
    names = names if isinstance(names, Mapping) else {}
    return [dataclasses.replace(s, param_name=str(names[s.explorer]))
            if s.explorer not in EXPLORERS and s.explorer in names else s for s in settings]


def _plain(value: Any) -> Any:
    """numpy and JAX scalars (0-d arrays too) as Python numbers (hashable,
    JSON-serialisable); anything else as it is (its validation names it)."""
    if getattr(value, "shape", None) == () and hasattr(value, "dtype"):
        value = np.asarray(value)[()]
    if isinstance(value, (np.bool_, bool)):
        return bool(value)
    if isinstance(value, np.integer):
        return int(value)
    if isinstance(value, np.floating):
        return float(value)
    return value


#: The prefix of a setting's values that are its task's parameters (``task.std``).
TASK_PREFIX = "task."


@dataclasses.dataclass(frozen=True)
class Setting:
    """One configuration of a grid.

    Attributes:
      learner: a registered learner name (``qlearning``, ``sarsa``, …).
      explorer: a registered explorer name (``egreedy``, ``vdbe_softmax``, …).
      param: the explorer's swept parameter (ε, τ, σ, c …), or ``None`` for its default.
      hyperparameters: other values, ``{name: value}`` (a field of the learner or the
        explorer, e.g. ``alpha``, ``gamma``, ``q_init``, ``delta``, ``tau``; prefix with
        ``learner.`` / ``explorer.`` when both have it; ``task.`` names a parameter of a
        task family, :class:`~vdbejax.envs.task_instances.TaskFamily`); kept as sorted pairs.
    """

    learner: str
    explorer: str
    param: float | None = None
    hyperparameters: Any = ()
    #: The swept parameter's name where the explorer is not registered here (a saved
    #: result's, :func:`with_parameter_names`); not part of the setting's identity.
    param_name: str | None = dataclasses.field(default=None, compare=False, repr=False)

    def __post_init__(self) -> None:
        values = self.hyperparameters
        pairs = values.items() if isinstance(values, Mapping) else values
        try:
            pairs = tuple(sorted((str(k), _plain(v)) for k, v in pairs))
        except (TypeError, ValueError):
            raise ValueError(f"hyperparameters={values!r} is invalid: must be a dict"
                             " {name: value}") from None
        object.__setattr__(self, "hyperparameters", pairs)
        param = _plain(self.param)
        if isinstance(param, int) and not isinstance(param, bool):
            param = float(param)
        object.__setattr__(self, "param", param)

    @property
    def values(self) -> dict[str, Any]:
        """The explicit values: the swept parameter (under its name) and the rest."""
        values = dict(self.hyperparameters)
        if self.param is not None:
            values = {self.parameter: self.param, **values}
        return values

    @property
    def parameter(self) -> str:
        """The name of the explorer's swept parameter (``epsilon``, ``sigma``, …)."""
        return self.param_name or parameter_name(self.explorer)

    @property
    def label(self) -> str:
        """``learner/explorer/name=value,…`` (the swept parameter first)."""
        values = ",".join(f"{k}={_format(v)}" for k, v in self.values.items())
        return f"{self.learner}/{self.explorer}" + (f"/{values}" if values else "")

    @property
    def task_values(self) -> dict[str, Any]:
        """The task family's parameters this setting sets (its ``task.`` values, by the
        parameter's name)."""
        return {name[len(TASK_PREFIX):]: value for name, value in self.hyperparameters
                if name.startswith(TASK_PREFIX)}

    def hyperparameters_json(self) -> str:
        """The explicit hyperparameters as compact JSON (``configs.csv``)."""
        return json.dumps(dict(self.hyperparameters), sort_keys=True, separators=(",", ":"))


def _format(value: Any) -> str:
    return f"{value:g}" if isinstance(value, float) else str(value)


def horizon_discount(horizon: int) -> float:
    """The discount of a discounted learner on episodes of ``horizon`` steps, ``1 − 1/H``
    (an effective horizon equal to the episode's)."""
    return 1.0 - 1.0 / horizon


@dataclasses.dataclass(frozen=True)
class AgentOptions:
    """Values shared by every agent of a run where its learner or explorer has the field
    (spec defaults); a setting's own values take precedence. ``gamma`` ``None`` (the
    default): each learner's own default γ (the paper's learners: 0.9; the finite-horizon
    UCBVI, PSRL and UCB-H: 1). ``horizon`` (default ``None``: each learner's own): the
    task's horizon H, the finite-horizon learners' ``horizon``, and with ``gamma`` ``None``
    the discounted learners' γ = 1 − 1/H (:func:`horizon_discount`)."""

    alpha: float = PAPER_ALPHA
    gamma: float | None = None
    q_init: float = 0.0
    tie_break: str = "random"
    delta: float = VDBE_DELTA
    vdbe_softmax_tau: float = VDBE_SOFTMAX_TAU
    horizon: int | None = None


@pytree_dataclass
class Agent:
    """One agent's learner and explorer (or a batch of one kind: leading axis)."""

    learner: Learner
    explorer: Explorer


@pytree_dataclass
class AgentParams:
    """The hyperparameters of a batch of agents of any kinds, as one pytree.

    Attributes:
      kind: int32 ``[agents]``: each agent's index into ``kinds``.
      kinds: one batched :class:`Agent` per kind (learner and explorer type with their
        static fields), each with a row for *every* agent (rows of agents of other kinds
        repeat the kind's first agent and are never run), so that taking, padding and
        sharding rows works leaf by leaf.
    """

    kind: Any
    kinds: tuple

    def rows_of(self, k: int) -> np.ndarray:
        """Indices of the agents of kind ``k``."""
        return np.flatnonzero(np.asarray(self.kind) == k)


def owners(name: str, learner: str, explorer: str) -> list[str]:
    """Which of ``"learner"`` and ``"explorer"`` a hyperparameter name sets for a learner ×
    explorer pair: ``alpha`` wherever a field of that name exists, ``learner.alpha`` only
    in the learner (empty: neither has it); ``["task"]`` for a task parameter
    (``task.std``: every pair has it, the run's task family checks it)."""
    role, _, field = name.rpartition(".")
    if name.startswith(TASK_PREFIX):
        return ["task"] if field else []
    classes = (("learner", learner_class(learner)), ("explorer", explorer_class(explorer)))
    return [r for r, cls in classes if role in ("", r) and field in field_names(cls)]


def make_agent(setting: Setting, options: AgentOptions = AgentOptions()) -> Agent:
    """Validated hyperparameters of one agent.

    Values are resolved per field: the setting's hyperparameters, then its ``param``, then
    ``options`` (where the learner or explorer has the field and the option is not
    ``None``), then the class default.

    Args:
      setting: learner, explorer, swept parameter and other values.
      options: values shared by every agent.

    Returns:
      the :class:`Agent` (scalar host leaves).

    Raises:
      ValueError: unknown learner/explorer/hyperparameter or an out-of-range value.
    """
    if not isinstance(setting, Setting):
        raise ValueError(f"setting={setting!r} is invalid: must be a Setting(learner, explorer,"
                         " param, hyperparameters)")
    explorer_cls = explorer_class(setting.explorer)
    classes: dict[str, type[Learner] | type[Explorer]] = {
        "learner": learner_class(setting.learner), "explorer": explorer_cls}
    values: dict[str, dict[str, Any]] = {"learner": {}, "explorer": {}}
    for name, value in dataclasses.asdict(options).items():
        if value is None:  # the class's own default
            continue
        for role, cls in classes.items():
            field = cls.option_aliases.get(name, name)
            if field in field_names(cls):
                values[role][field] = value
    learner_fields = field_names(classes["learner"])
    if options.horizon is not None:
        check_int("horizon", options.horizon, 1)
    if options.gamma is None and options.horizon is not None and "gamma" in learner_fields \
            and "horizon" not in learner_fields:  # a discounted learner: γ = 1 − 1/H
        values["learner"]["gamma"] = horizon_discount(options.horizon)
    if setting.param is not None:
        if explorer_cls.parameter is None:
            raise ValueError(f"param={setting.param!r} is invalid: explorer {setting.explorer!r}"
                             " has no swept parameter (give hyperparameters instead)")
        values["explorer"][explorer_cls.parameter] = setting.param
    for name, value in setting.hyperparameters:
        if name.startswith(TASK_PREFIX):  # the task's, not the agent's
            continue
        roles = owners(name, setting.learner, setting.explorer)
        if not roles:
            fields = [f"{role}.{f}" for role, cls in classes.items() for f in field_names(cls)]
            raise ValueError(f"hyperparameter {name!r} is invalid for {setting.learner}/"
                             f"{setting.explorer}: must be one of {', '.join(fields)}")
        for role in roles:
            values[role][name.rpartition(".")[2]] = value
    return Agent(*(build(classes[role], values[role], role) for role in ("learner", "explorer")))


def recorded_options(options: AgentOptions, settings: Sequence[Setting]) -> dict[str, Any]:
    """``options`` as a run's fingerprint records them (:func:`vdbejax.runs.grid.prepare_grid`).

    Where γ is left to each learner (``gamma=None``) and every setting's learner gets the
    paper's γ, which every learner got from the options before, the record says that γ:
    the runs are the same runs, so their earlier results and checkpoints are found again.
    """
    described = dataclasses.asdict(options)
    if options.horizon is None:  # the record of the runs before the option, as it was
        del described["horizon"]
    if options.gamma is None and options.horizon is None:
        before = dataclasses.replace(options, gamma=PAPER_GAMMA)
        if all(float(make_agent(s, options).learner.gamma)
               == float(make_agent(s, before).learner.gamma) for s in settings):
            described["gamma"] = PAPER_GAMMA
    return described


def agent_hyperparameters(agent: Agent) -> dict[str, Any]:
    """Every hyperparameter of one agent, ``learner.alpha``-style names."""
    return {**{f"learner.{k}": v for k, v in hyperparameters(agent.learner).items()},
            **{f"explorer.{k}": v for k, v in hyperparameters(agent.explorer).items()}}


def paper_settings(
    learners: Sequence[str] = PAPER_LEARNERS, explorers: Sequence[str] = PAPER_EXPLORERS
) -> list[Setting]:
    """The paper's grid: 2 learners × (5 + 6 + 6 + 6) parameters = 46 settings.

    Args:
      learners: learner names (default both).
      explorers: explorer names (default all four).

    Returns:
      the settings, learner-major, then explorer, then increasing parameter.
    """
    return [
        Setting(learner, explorer, param)
        for learner in learners
        for explorer in explorers
        for param in PAPER_PARAMETERS[explorer]
    ]


def kind_key(agent: Agent) -> tuple:
    """What makes an agent's kind: learner and explorer classes with their static fields."""
    def of(plugin: Any) -> tuple:
        return (type(plugin), tuple(getattr(plugin, name) for name in static_names(type(plugin))))

    return of(agent.learner) + of(agent.explorer)


def stack_agents(agents: Sequence[Agent]) -> AgentParams:
    """Batch agents of any kinds into one :class:`AgentParams` (kinds in order of first
    appearance).

    Args:
      agents: one or more :class:`Agent`.

    Returns:
      the batch: leaves with a leading agent axis.

    Raises:
      ValueError: ``agents`` is empty.
    """
    if not agents:
        raise ValueError("agents is empty: need at least one setting")
    structures: list[Any] = []
    kind = np.empty(len(agents), np.int32)
    for i, agent in enumerate(agents):
        structure = kind_key(agent)
        if structure not in structures:
            structures.append(structure)
        kind[i] = structures.index(structure)
    kinds = []
    for k in range(len(structures)):
        template = agents[int(np.flatnonzero(kind == k)[0])]
        rows = [agent if kind[i] == k else template for i, agent in enumerate(agents)]
        kinds.append(jax.tree.map(lambda *leaves: np.stack(leaves), *rows))
    return AgentParams(kind=kind, kinds=tuple(kinds))


def table_layout(params: AgentParams) -> dict[str, str]:
    """Every table the batch's agents keep beside Q: ``{name: "state" | "pair" |
    "outcome"}`` (``"outcome"``: ``[S, A, K]``, a model's successor lists).

    Raises:
      ValueError: two kinds use one table name for tables of different shapes.
    """
    layout: dict[str, str] = {}
    for agent in params.kinds:
        if agent.learner.uses_model:
            layout.update(MODEL_TABLES)
        for owner in (agent.learner, agent.explorer):
            for name, spec in owner.tables().items():
                if name == "q" or name.startswith(MODEL_PREFIX):
                    raise ValueError(f"{type(owner).__name__}: table name {name!r} is reserved"
                                     f" (for Q and the model's tables, {MODEL_PREFIX}*)")
                per = f"stage:{spec.width()}" if spec.per == "stage" else spec.per
                if layout.setdefault(name, per) != per:
                    raise ValueError(f"table {name!r} is per {layout[name]!r} for one kind and per"
                                     f" {per!r} for another: rename one of them")
    return layout


__all__ = [
    "PAPER_PARAMETERS",
    "TASK_PREFIX",
    "Agent",
    "AgentOptions",
    "AgentParams",
    "Setting",
    "agent_hyperparameters",
    "horizon_discount",
    "make_agent",
    "owners",
    "paper_settings",
    "parameter_name",
    "recorded_options",
    "stack_agents",
    "table_layout",
    "with_parameter_names",
]
