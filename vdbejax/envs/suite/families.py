"""The suite's task families with a generator of instances, by name:
:func:`make_suite_family` (an instance per agent, ``--instances per-agent``; a family's
parameters as sweep axes, ``task.std``, ``task.instance``).

* ``gaussian_bandit:N``, ``bernoulli_bandit:N``, ``testbed:N`` (:func:`.bandits.bandit_family`)
  and ``garnet:SxAxB`` (:func:`.garnet.garnet_family`): instances differ in their random
  tables; the named task is the instance of seed 0, the shared family's default.
* ``variant:NxK`` (:func:`vdbejax.envs.table_cleaning.starts.variant_family`): instances
  are the variant with one start state each; the named task starts from several, so no
  instance is it and there is no shared family.
"""
from __future__ import annotations

from vdbejax.envs.instances import TaskFamily
from vdbejax.envs.suite import bandits, garnet

#: The families (:func:`vdbejax.envs.suite.parse_name`) with a generator of instances.
FAMILY_NAMES = (*bandits.FAMILIES, "garnet", "variant")


def make_suite_family(name: str, *, max_steps: int | None = None, invalid_action: str = "noop",
                      shared: bool = False) -> TaskFamily:
    """A task family of the suite by name (:class:`~vdbejax.envs.instances.TaskFamily`; the
    families of :data:`FAMILY_NAMES`, module docstring): an instance per agent, or with
    ``shared`` every agent the named task's one instance (whose parameters a sweep can
    still vary).

    Args:
      name: ``gaussian_bandit:N``, ``bernoulli_bandit:N``, ``testbed:N``, ``garnet:SxAxB``
        or ``variant:NxK``.
      max_steps: the truncation (default: the named task's horizon).
      invalid_action: ``noop`` or ``fail``, ``variant:NxK`` only.
      shared: every agent the named task (not for ``variant:NxK``).

    Raises:
      ValueError: an unknown name, a task without a generator of instances,
        ``variant:NxK`` with ``shared``, or a bad size, ``max_steps`` or
        ``invalid_action``.
    """
    # the package imports this module: its names only once it is loaded
    from vdbejax.envs.suite import DEFAULT_SIZES, NAMES, parse_name, task_info

    family, sizes = parse_name(name)
    if family not in FAMILY_NAMES:
        forms = [form for form in NAMES if form.partition(":")[0] in FAMILY_NAMES]
        raise ValueError(f"task={name!r} has no generator of instances: an instance per agent"
                         f" and task parameters (task.…) need one of {', '.join(forms)}")
    if family != "variant" and invalid_action != "noop":
        raise ValueError(f"invalid_action={invalid_action!r} is invalid with task={name!r}:"
                         " of the families only variant:NxK has invalid actions")
    horizon = task_info(name).horizon if max_steps is None else max_steps
    if family == "variant":
        if shared:
            raise ValueError(f"task={name!r} has no shared instance (each of its instances"
                             " starts in one state, the task from several): task values"
                             " (task.instance) need an instance per agent, --instances"
                             " per-agent")
        from vdbejax.envs.table_cleaning.starts import variant_family

        sections, goblets = sizes
        return variant_family(sections, goblets, max_steps=horizon,
                              invalid_action=invalid_action, name=name)
    if family == "garnet":
        states, actions, branching = sizes
        return garnet.garnet_family(states, actions, branching, max_steps=horizon, name=name,
                                    instance=garnet.INSTANCE_SEED if shared else None)
    size = sizes[0] if sizes else DEFAULT_SIZES[family]
    return bandits.bandit_family(family, size, pulls=horizon, name=name,
                                 instance=bandits.INSTANCE_SEED if shared else None)
