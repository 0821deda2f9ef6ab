"""Instances of a generated table-cleaning variant that differ in where they start:
:func:`variant_family`, the generator of ``variant:NxK`` with ``--instances per-agent``.

An instance is the variant itself (:func:`~.generator.make_variant_mdp`: its rules, its
states, its tables) whose episodes all start in one state, drawn from the instance's
entropy uniformly among the **start states** (:func:`start_codes`), states of the same
kind as the variant's own start:

* the hand free at home, so the sponge lies at home;
* each goblet standing on a section (several may share one, as the rules allow); goblets
  are identical, so a start is a multiset of sections and each multiset counts once;
* each section dirty or clean, but **not all clean**: a free hand at home with every
  section clean is the goal, and such an episode would end with +1 at its first step
  whatever the action (nothing to learn).

That makes ``C(n + k - 1, k) · (2^n - 1)`` start states (``variant:2x1``: 6); the
variant's own starts, every section dirty, are among them. Every start state is
reachable from the variant's own start (move the goblets off a section, clean it, put
them back, return the sponge), so the instance keeps the variant's reachable states
(``state_codes``) and tables and only ``start_probability`` differs: instances stack
(:func:`~vdbejax.envs.task_instances.stack_instances`). No instance is harder than the
variant: the variant's plan from the same goblets, less the cleaning of sections already
clean, reaches the goal from a start state (a clean action changes only its section's
bit), so within as many steps as from the variant's own start.

The named task ``variant:NxK`` is not an instance (it starts from its goblets' random
placement, every section dirty), so this family has no default instance that is the
named task: :func:`vdbejax.envs.suite.make_suite_family` refuses it as a shared family.
"""
from __future__ import annotations

import dataclasses
import itertools

import jax.numpy as jnp
import numpy as np

from vdbejax.envs.table_cleaning.core import FREE, mixed_radix_encode
from vdbejax.envs.table_cleaning.generator import TableCleaningGenerator, make_variant_mdp
from vdbejax.envs.tabular import TabularMDP
from vdbejax.envs.task_instances import TaskFamily


def start_codes(num_sections: int, num_goblets: int) -> np.ndarray:
    """The codes (increasing, int64) of the start states of the variant with
    ``num_sections`` sections and ``num_goblets`` goblets (module docstring).

    Raises:
      ValueError: ``num_sections < 2`` or ``num_goblets < 1``.
    """
    generator = TableCleaningGenerator(num_sections, num_goblets)  # checks the sizes
    n, k = num_sections, num_goblets
    fields = [[FREE, generator.home, *goblets, *clean]
              for goblets in itertools.combinations_with_replacement(range(n), k)
              for clean in itertools.product((0, 1), repeat=n) if not all(clean)]
    return np.sort(mixed_radix_encode(np.asarray(fields, np.int64), generator.radices))


def variant_family(num_sections: int, num_goblets: int, *, max_steps: int = 100,
                   invalid_action: str = "noop", name: str | None = None) -> TaskFamily:
    """The variant's instances (module docstring) as a generator
    (:class:`~vdbejax.envs.task_instances.TaskFamily`, no parameters but ``task.instance``):
    instance ``entropy`` starts in start state ``i`` (of :func:`start_codes`, in code
    order) where ``i`` is NumPy's ``default_rng([*entropy, n, k]).integers(count)``.

    Args:
      num_sections: ``n >= 2``.
      num_goblets: ``k >= 1``.
      max_steps: the truncation length.
      invalid_action: ``"noop"`` or ``"fail"`` (:func:`~.generator.make_variant_mdp`).
      name: the family's label (default ``variant:NxK``); each instance keeps the
        variant's own name, ``table_cleaning_nN_kK``.

    Raises:
      ValueError: a bad size, ``max_steps`` or ``invalid_action``, in one line.
    """
    variant = make_variant_mdp(num_sections, num_goblets, max_steps=max_steps,
                               invalid_action=invalid_action)
    starts = variant.index_of(start_codes(num_sections, num_goblets))
    label = name or f"variant:{num_sections}x{num_goblets}"

    def generate(entropy: tuple[int, ...]) -> TabularMDP:
        rng = np.random.default_rng([*entropy, num_sections, num_goblets])
        start = np.zeros(variant.num_states, np.float32)
        start[starts[rng.integers(len(starts))]] = 1.0
        return dataclasses.replace(variant, start_probability=jnp.asarray(start))

    return TaskFamily(label, generate, f"table cleaning, {num_sections} sections and"
                      f" {num_goblets} goblet(s), horizon {max_steps}, an instance per agent"
                      f" (one of {len(starts)} start states drawn from the root seed and"
                      " the agent's seed index)")
