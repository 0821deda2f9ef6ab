"""What there is to run: every registered learner and explorer with its hyperparameters and
their defaults, and every task name with its sizes, horizon and learner defaults
(:mod:`vdbejax.studies.learner_defaults`; ``vdbejax list``), the task families with a
generator of instances marked (``instances``: ``per-agent``)."""
from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from typing import Any

from vdbejax.studies.learner_defaults import learner_defaults

#: The kinds of entries :func:`catalog` lists.
KINDS = ("learners", "explorers", "tasks")


def _fields(cls: Any) -> list[tuple[str, Any]]:
    """A plug-in class's hyperparameters with their defaults (``None``: no default)."""
    fields = []
    for field in dataclasses.fields(cls):
        if field.default is not dataclasses.MISSING:
            default = field.default
        elif field.default_factory is not dataclasses.MISSING:
            default = field.default_factory()
        else:
            default = None
        fields.append((field.name, default))
    return fields


def _plugin_entries(registry: dict[str, Any], swept: bool) -> list[dict[str, Any]]:
    return [{"name": name, "title": cls.title,
             **({"swept": cls.parameter} if swept else {}),
             "module": cls.__module__, "parameters": dict(_fields(cls))}
            for name, cls in sorted(registry.items())]


def _task_entries() -> list[dict[str, Any]]:
    from vdbejax.envs.suite import DEFAULT_SIZES, FAMILY_NAMES, NAMES, task_info

    entries = []
    parameters: dict[str, Any]
    for form in NAMES:
        family, _, size = form.partition(":")
        if size and family in DEFAULT_SIZES:
            parameters = {"N": DEFAULT_SIZES[family]}
            info = task_info(family)
        elif family == "garnet":  # sizes without a default
            parameters = {"S": "states (required)", "A": "actions (required)",
                          "B": "branching (required)"}
            info = dataclasses.replace(task_info("garnet:1x1x1"),
                                       title="Garnet MDP, S states, A actions, branching B")
        elif size:  # variant:NxK: sizes without a default
            parameters = {"N": "sections (required)", "K": "goblets (required)"}
            info = dataclasses.replace(task_info("variant:1x1"),
                                       title="Table cleaning, N sections and K goblets")
        else:
            parameters = {}
            info = task_info(form)
        if family in ("table_cleaning", "variant"):
            parameters["invalid_action"] = "noop"
        defaults = learner_defaults(form, info.horizon).text()
        entries.append({"name": form, "title": info.title, "parameters": {
            **parameters, "max_steps": info.horizon}, "learner_defaults": defaults,
            "source": info.source,
            **({"extra": info.extra} if info.extra else {}),
            **({"instances": "per-agent"} if family in FAMILY_NAMES else {})})
    rule = "the benchmark's rule with H = max_steps (alpha=0.1, gamma=1 − 1/H)"
    entries.append({"name": "gym:<id>", "title": "a gymnasium toy-text environment",
                    "parameters": {"max_steps": "its time limit"}, "learner_defaults": rule,
                    "source": "gymnasium", "extra": "gym"})
    entries.append({"name": "module:function, file.py:function",
                    "title": "your own task: a function of no arguments returning a TabularMDP",
                    "parameters": {"max_steps": "the MDP's own"}, "learner_defaults": rule,
                    "source": "yours"})
    return entries


def catalog(kinds: Sequence[str] = KINDS) -> dict[str, list[dict[str, Any]]]:
    """Every learner, explorer and task by name (registered plug-ins included), each with
    its parameters and their defaults; ``kinds``: those of :data:`KINDS` to list.

    Raises:
      ValueError: a kind not in :data:`KINDS`.
    """
    import vdbejax.methods  # noqa: F401  (registers the built-ins)
    from vdbejax.methods.registry import EXPLORERS, LEARNERS

    for kind in kinds:
        if kind not in KINDS:
            raise ValueError(f"kind={kind!r} is invalid: must be one of {', '.join(KINDS)}")
    build = {"learners": lambda: _plugin_entries(LEARNERS, False),
             "explorers": lambda: _plugin_entries(EXPLORERS, True), "tasks": _task_entries}
    return {kind: build[kind]() for kind in kinds}


def render_catalog(entries: dict[str, list[dict[str, Any]]]) -> str:
    """:func:`catalog` as text: a heading per kind, one line per entry and its parameters
    as ``name=default`` (the explorer's swept parameter marked ``*``; a task family with a
    generator of instances marked ``[--instances per-agent]``)."""
    lines = []
    for kind, items in entries.items():
        lines.append(f"{kind} ({len(items)}):")
        for item in items:
            values = ", ".join(f"{'*' if item.get('swept') == k else ''}{k}={v!r}"
                               for k, v in item["parameters"].items())
            lines.append(f"  {item['name']}  {item['title']}" + (
                f" [needs the {item['extra']} extra]" if item.get("extra") else "") + (
                " [--instances per-agent]" if item.get("instances") else ""))
            if values:
                lines.append(f"      {values}")
            if item.get("learner_defaults"):
                lines.append(f"      learner defaults: {item['learner_defaults']}")
        lines.append("")
    if "explorers" in entries:
        lines.append("* the parameter a setting's param sets (Setting(learner, explorer, param))")
    return "\n".join(lines).rstrip() + "\n"
