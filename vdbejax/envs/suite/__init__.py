"""A suite of classic exploration tasks, each a :class:`~vdbejax.envs.TabularMDP`, by name.

One module per task family, each citing its source and building the task as published:

* :mod:`.river_swim`: RiverSwim and SixArms (Strehl & Littman 2008), and the normalised
  RiverSwim of Osband, Russo & Van Roy (2013);
* :mod:`.chain`: the n-Chain of Dearden, Friedman & Russell (1998);
* :mod:`.deep_sea`: DeepSea (Osband et al. 2019; bsuite 2020);
* :mod:`.gridworlds`: the windy gridworld and cliff walking of Sutton & Barto (2018);
* :mod:`.toy_text`: gymnasium's FrozenLake (4×4, 8×8) and Taxi (needs the ``gym`` extra);
* :mod:`.bandits`: k-armed Gaussian and Bernoulli bandits and Sutton & Barto's testbed
  (2018), one-state tasks with random rewards;
* :mod:`.garnet`: random MDPs, the Garnet family of Archibald, McKinnon & Thomas (1995);

and the table-cleaning family that :mod:`vdbejax.envs.table_cleaning` and
:mod:`vdbejax.envs.cruz2018` define. :func:`make_suite_task` builds a task from its name
(``riverswim``, ``chain:8``, ``deepsea:20``, ``variant:3x1``, …; :data:`NAMES` lists the
forms), :func:`task_info` describes it (:class:`TaskInfo`), :func:`make_suite_family`
gives the families with a generator of instances, and
:data:`DEFAULT_SUITE` / :func:`suite_tasks` are the default benchmark. Each MDP is named
by its registry name, except ``variant:NxK``, which keeps its builder's name
``table_cleaning_nN_kK`` so that it is the very MDP that
``vdbejax.studies.task_names.make_task`` has always built (the name enters run
fingerprints). Exact optima: :func:`vdbejax.envs.solvers.best_return`.
"""
from __future__ import annotations

import dataclasses

from vdbejax.envs.suite import (
    bandits,
    chain,
    deep_sea,
    garnet,
    gridworlds,
    river_swim,
    toy_text,
)
from vdbejax.envs.tabular import TabularMDP
from vdbejax.envs.task_instances import TaskFamily
from vdbejax.validation import nearest_names


@dataclasses.dataclass(frozen=True)
class TaskInfo:
    """What a task of the suite is.

    Attributes:
      name: its registry name (:func:`make_suite_task`).
      title: a human-readable title.
      source: the publication (and code) that defines it.
      tests: what the task tests, in one sentence.
      horizon: the episode length ``max_steps`` at which episodes are truncated.
      horizon_reason: why that horizon.
      extra: the optional dependency (``pip install 'vdbejax[EXTRA]'``) it needs, or None.
      safety_cap: ``horizon`` is a cap of this repository's (the task as published has no
        step limit), not the task's own.
    """

    name: str
    title: str
    source: str
    tests: str
    horizon: int
    horizon_reason: str
    extra: str | None = None
    safety_cap: bool = False


_STREHL_LITTMAN = ("Strehl & Littman 2008, An analysis of model-based Interval Estimation"
                  " for Markov decision processes, JCSS 74(8)")
_SOURCES = {
    "riverswim": _STREHL_LITTMAN,
    "riverswim_normalised": "Osband, Russo & Van Roy 2013, (More) efficient reinforcement"
                            " learning via posterior sampling, NeurIPS (after "
                            + _STREHL_LITTMAN + ")",
    "sixarms": _STREHL_LITTMAN,
    "chain": "Dearden, Friedman & Russell 1998, Bayesian Q-learning, AAAI (gym's NChain-v0)",
    "deepsea": "Osband, Van Roy, Russo & Wen 2019, Deep exploration via randomized value"
               " functions, JMLR 20; bsuite (Osband et al. 2020, ICLR), deep_sea.py",
    "windy_gridworld": "Sutton & Barto 2018, Reinforcement Learning: An Introduction (2nd"
                       " ed.), Example 6.5",
    "cliff_walking": "Sutton & Barto 2018, Reinforcement Learning: An Introduction (2nd"
                     " ed.), Example 6.6",
    "frozenlake4": "gymnasium FrozenLake-v1 (toy_text/frozen_lake.py), 4x4 map, slippery",
    "frozenlake8": "gymnasium FrozenLake-v1 (toy_text/frozen_lake.py), 8x8 map, slippery",
    "taxi": "gymnasium Taxi-v3/v4 (toy_text/taxi.py); Dietterich 2000, MAXQ, JAIR 13",
    "table_cleaning": "Cruz et al. 2018, the table-cleaning task as its text states it"
                      " (docs/task.md; vdbejax.envs.table_cleaning)",
    "cruz2018": "Cruz et al. 2018, the first author's published table (fcruzcl/CS2018;"
                " vdbejax.envs.cruz2018)",
    "variant": "generated variants of the table-cleaning task"
               " (vdbejax.envs.table_cleaning.generator)",
    "gaussian_bandit": "the k-armed bandit with Gaussian rewards (Sutton & Barto 2018,"
                       " Reinforcement Learning: An Introduction (2nd ed.), ch. 2)",
    "bernoulli_bandit": "the k-armed Bernoulli bandit (Chapelle & Li 2011, An empirical"
                        " evaluation of Thompson sampling, NeurIPS)",
    "testbed": "Sutton & Barto 2018, Reinforcement Learning: An Introduction (2nd ed.),"
               " §2.3, the 10-armed testbed",
    "garnet": "Archibald, McKinnon & Thomas 1995, On the generation of Markov decision"
              " processes, JORS 46 (vdbejax.envs.suite.garnet)",
}

#: The forms of names :func:`make_suite_task` accepts (``N``, ``K``, ``S``, ``A``, ``B``:
#: integers).
NAMES = ("riverswim", "riverswim:N", "riverswim_normalised", "riverswim_normalised:N",
         "sixarms", "chain", "chain:N", "deepsea", "deepsea:N", "windy_gridworld",
         "cliff_walking", "frozenlake4", "frozenlake8", "taxi", "table_cleaning", "cruz2018",
         "variant:NxK", "gaussian_bandit:N", "bernoulli_bandit:N", "testbed:N",
         "garnet:SxAxB")
#: The default benchmark: every family once, at its published size.
DEFAULT_SUITE = ("riverswim", "riverswim_normalised", "sixarms", "chain", "deepsea:10",
                 "windy_gridworld", "cliff_walking", "frozenlake4", "frozenlake8", "taxi",
                 "table_cleaning", "cruz2018", "variant:3x1")
#: Families whose name may carry a size (``family:N``), with their default size.
DEFAULT_SIZES = {"riverswim": 6, "riverswim_normalised": 6, "chain": 5, "deepsea": 10,
                 "gaussian_bandit": 10, "bernoulli_bandit": 10, "testbed": 10}
#: The table-cleaning tasks' default truncation (``vdbejax.studies.task_names.make_task``'s).
TABLE_CLEANING_HORIZON = 100
#: The families (:func:`parse_name`) with a generator of instances.
FAMILY_NAMES = (*bandits.FAMILIES, "garnet", "variant")


def _invalid(name: object) -> ValueError:
    # A typo's nearest names, a sized name's with its size: chian:8 → chain:8.
    size = name.partition(":")[2] if isinstance(name, str) else ""
    forms = [form.replace(":N", f":{size}") for form in NAMES if form.endswith(":N")] \
        if size else NAMES
    return ValueError(f"name={name!r} is invalid: must be one of {', '.join(NAMES)}"
                      f" (N, K, S, A, B: integers){nearest_names(name, forms)}")


def parse_name(name: object) -> tuple[str, tuple[int, ...]]:
    """``(family, sizes)`` of a registry name (sizes: ``()`` for the default).

    Raises:
      ValueError: an unknown name, or sizes that ``garnet:SxAxB`` does not allow.
    """
    if not isinstance(name, str):
        raise _invalid(name)
    family, colon, size = name.partition(":")
    if family == "variant" and colon:
        sections, x, goblets = size.partition("x")
        if x and sections.isdigit() and goblets.isdigit():  # as task_names.make_task reads it
            return family, (int(sections), int(goblets))
        raise _invalid(name)
    if family == "garnet" and colon:
        sizes = garnet.sizes_of(name, size)  # raises for sizes out of range
        if sizes is None:
            raise _invalid(name)
        return family, sizes
    if family in DEFAULT_SIZES and colon:
        if size.isdigit() and size.isascii() and str(int(size)) == size:
            return family, (int(size),)
        raise _invalid(name)
    if not colon and family in _SOURCES and family not in ("variant", "garnet"):
        return family, ()
    raise _invalid(name)


def task_info(name: str) -> TaskInfo:
    """The :class:`TaskInfo` of a task (any name :func:`make_suite_task` accepts).

    Raises:
      ValueError: an unknown name.
    """
    family, sizes = parse_name(name)
    size = sizes[0] if sizes else DEFAULT_SIZES.get(family)
    if family in ("riverswim", "riverswim_normalised"):
        normalised = family == "riverswim_normalised"
        return TaskInfo(
            name, f"RiverSwim ({size} states{', normalised rewards' if normalised else ''})",
            _SOURCES[family],
            "deep exploration against a current: a small sure reward at the start hides a"
            " large one at the far bank, reached only by persistent swimming against it",
            river_swim.RIVER_SWIM_HORIZON,
            "Osband et al. 2013's episode length; swimming right is already optimal from the"
            " first step, with 30-70 times the return of staying at the start")
    if family == "sixarms":
        return TaskInfo(
            name, "SixArms", _SOURCES[family],
            "exploring arms whose entry gets ever less likely as their payoff grows (room 6:"
            " probability 0.01, reward 6000 a step)",
            river_swim.SIX_ARMS_HORIZON,
            "room 6 takes 100 tries on average; at 200 steps trying for it stays optimal at"
            " the start (about 6000 x 113 against room 5's 1660 x 167)")
    if family == "chain":
        return TaskInfo(
            name, f"n-Chain ({size} states, slip 0.2)", _SOURCES[family],
            "deep exploration: going back pays 2 a step at once, the end of the chain 10 a"
            " step after n - 1 unrewarded steps that every slip undoes",
            chain.HORIZON,
            "the paper's 1000-step phases and NChain-v0's time limit: long-run rates decide")
    if family == "deepsea":
        assert size is not None
        return TaskInfo(
            name, f"DeepSea ({size} x {size}, randomised actions, bsuite mapping seed 42)",
            _SOURCES[family],
            "deep exploration: one path of N right moves, each costing 0.01/N, to the"
            " treasure; random actions find it with probability 2^-N",
            size, "the episode's own length: every episode ends after N steps")
    if family in ("windy_gridworld", "cliff_walking"):
        windy = family == "windy_gridworld"
        return TaskInfo(
            name, "Windy gridworld (7 x 10)" if windy else "Cliff walking (4 x 12)",
            _SOURCES[family],
            "exploration that must learn how the wind moves the agent, with -1 a step and no"
            " other reward" if windy else
            "the price of exploring next to a cliff (-100 and back to the start) on the"
            " shortest path",
            gridworlds.HORIZON,
            "a safety cap (the book has no time limit): ~700 times the optimal length; the"
            " random policy reaches the goal within it with probability ~0.8", safety_cap=True)
    if family in ("frozenlake4", "frozenlake8"):
        side = "4x4" if family == "frozenlake4" else "8x8"
        return TaskInfo(
            name, f"FrozenLake {side.replace('x', ' x ')} (slippery)", _SOURCES[family],
            "exploration under heavy transition noise with one sparse reward (the goal),"
            " holes ending the episode",
            toy_text.FROZEN_LAKE_HORIZON[side],
            "gymnasium's TimeLimit, for which its registry states the optimum"
            f" ({toy_text.STATED_OPTIMUM[family]})", extra="gym")
    if family == "taxi":
        return TaskInfo(
            name, "Taxi (5 x 5, 500 states)", _SOURCES[family],
            "a sequence of sub-goals (reach, pick up, carry, drop off) with -10 for each"
            " wrong pick-up or drop-off",
            toy_text.TAXI_HORIZON, "gymnasium's TimeLimit", extra="gym")
    if family == "table_cleaning":
        return TaskInfo(
            name, "Table cleaning (the paper's text)", _SOURCES[family],
            "finding a 15-step plan among 7 actions, failures ending the episode",
            TABLE_CLEANING_HORIZON, "the repository's default truncation of the paper's task")
    if family in bandits.FAMILIES:
        assert size is not None
        kind = {"gaussian_bandit": "Gaussian bandit", "bernoulli_bandit": "Bernoulli bandit",
                "testbed": "10-armed testbed"}[family]
        means = ("arm means N(0, 1)" if family == "testbed" else "arm means uniform in [0, 1)")
        rewards = "rewards 0 or 1" if family == "bernoulli_bandit" else "unit-variance rewards"
        return TaskInfo(
            name, f"{kind} ({size} arms, {means}, {rewards}, instance seed"
            f" {bandits.INSTANCE_SEED})", _SOURCES[family],
            "exploration against reward noise alone: which arm pays most on average",
            bandits.PULLS, "one pull per episode (a run's max_steps sets more)")
    if family == "garnet":
        states, actions, branching = sizes
        return TaskInfo(
            name, f"Garnet MDP ({states} states, {actions} actions, branching {branching},"
            f" instance seed {garnet.INSTANCE_SEED})", _SOURCES[family],
            "exploration of a random MDP: sparse random transitions, a reward uniform in"
            " [0, 1) on every state-action pair", garnet.HORIZON,
            "garnet_family's episode length: no state is terminal (a run's max_steps sets"
            " another)")
    if family == "cruz2018":
        from vdbejax.envs.cruz2018 import STEP_CAP

        return TaskInfo(
            name, "Table cleaning (the authors' table)", _SOURCES[family],
            "the paper's task as the authors' code runs it: failures, aborts back to the"
            " start, no step limit", STEP_CAP,
            "a safety cap: the published code has no step limit", safety_cap=True)
    sections, goblets = sizes
    return TaskInfo(
        name, f"Table cleaning, {sections} sections and {goblets}"
        f" goblet{'s' if goblets != 1 else ''}", _SOURCES[family],
        "the table-cleaning plan at a larger size (longer plans, more states)",
        TABLE_CLEANING_HORIZON, "the repository's default truncation of the table tasks")


def make_suite_task(name: str, *, max_steps: int | None = None,
                    invalid_action: str = "noop") -> TabularMDP:
    """A task of the suite by name.

    Args:
      name: one of :data:`NAMES`: ``riverswim`` (published), ``riverswim_normalised``,
        ``sixarms``, ``chain``, ``deepsea`` (10 × 10), ``windy_gridworld``,
        ``cliff_walking``, ``frozenlake4``, ``frozenlake8``, ``taxi``, ``table_cleaning``,
        ``cruz2018``; with a size: ``riverswim:N``, ``riverswim_normalised:N``,
        ``chain:N``, ``deepsea:N``, ``variant:NxK`` (N sections, K goblets),
        ``gaussian_bandit:N``, ``bernoulli_bandit:N`` and ``testbed:N`` (N arms),
        ``garnet:SxAxB`` (S states, A actions, branching B; the instance of seed 0).
      max_steps: the truncation (default: the task's horizon, :func:`task_info`); a
        bandit's pulls per episode.
      invalid_action: ``noop`` or ``fail``, the table-cleaning tasks of the paper's text
        (``table_cleaning``, ``variant:NxK``) only.

    Returns:
      the MDP, named ``name`` (``variant:NxK``: ``table_cleaning_nN_kK``, its builder's).
      A name of :data:`FAMILY_NAMES` is its family's instance of seed 0.

    Raises:
      ValueError: an unknown name, a size the task does not allow, an invalid
        ``max_steps``, or ``invalid_action`` other than ``noop`` for a task without
        invalid actions.
      ImportError: ``frozenlake4``, ``frozenlake8`` and ``taxi`` without gymnasium.
    """
    family, sizes = parse_name(name)
    if family not in ("table_cleaning", "variant") and invalid_action != "noop":
        raise ValueError(f"invalid_action={invalid_action!r} is invalid with name={name!r}:"
                         " only table_cleaning and variant:NxK have invalid actions")
    horizon = task_info(name).horizon if max_steps is None else max_steps
    size = sizes[0] if sizes else DEFAULT_SIZES.get(family)
    if family == "riverswim":
        assert size is not None
        return river_swim.make_river_swim(size, max_steps=horizon, name=name)
    if family == "riverswim_normalised":
        assert size is not None
        return river_swim.make_river_swim_normalised(size, max_steps=horizon, name=name)
    if family == "sixarms":
        return river_swim.make_six_arms(max_steps=horizon, name=name)
    if family == "chain":
        assert size is not None
        return chain.make_chain(size, max_steps=horizon, name=name)
    if family == "deepsea":
        assert size is not None
        return deep_sea.make_deep_sea(size, max_steps=horizon, name=name)
    if family == "windy_gridworld":
        return gridworlds.make_windy_gridworld(max_steps=horizon, name=name)
    if family == "cliff_walking":
        return gridworlds.make_cliff_walking(max_steps=horizon, name=name)
    if family in ("frozenlake4", "frozenlake8"):
        return toy_text.make_frozen_lake("4x4" if family == "frozenlake4" else "8x8",
                                         max_steps=horizon, name=name)
    if family == "taxi":
        return toy_text.make_taxi(max_steps=horizon, name=name)
    if family in bandits.FAMILIES:
        assert size is not None
        return bandits.make_family_bandit(family, size, pulls=horizon, name=name)
    if family == "garnet":
        states, actions, branching = sizes
        return garnet.make_garnet(states, actions, branching, (garnet.INSTANCE_SEED,),
                                  max_steps=horizon, name=name)
    if family == "cruz2018":
        from vdbejax.envs.cruz2018 import make_authors_mdp

        return make_authors_mdp(horizon)
    from vdbejax.envs.table_cleaning import make_mdp, make_variant_mdp

    if family == "table_cleaning":
        return make_mdp(max_steps=horizon, invalid_action=invalid_action)
    sections, goblets = sizes
    return make_variant_mdp(sections, goblets, max_steps=horizon,
                            invalid_action=invalid_action)


def make_suite_family(name: str, *, max_steps: int | None = None, invalid_action: str = "noop",
                      shared: bool = False) -> TaskFamily:
    """A task family of the suite by name (:class:`~vdbejax.envs.task_instances.TaskFamily`, one
    of :data:`FAMILY_NAMES`): an instance per agent (``--instances per-agent``; a family's
    parameters as sweep axes, ``task.std``, ``task.instance``), or with ``shared`` every
    agent the named task's one instance (whose parameters a sweep can still vary).

    * ``gaussian_bandit:N``, ``bernoulli_bandit:N``, ``testbed:N``
      (:func:`.bandits.bandit_family`) and ``garnet:SxAxB`` (:func:`.garnet.garnet_family`):
      instances differ in their random tables; the named task is the instance of seed 0,
      the shared family's default.
    * ``variant:NxK`` (:func:`vdbejax.envs.table_cleaning.starts.variant_family`): instances
      are the variant with one start state each; the named task starts from several, so no
      instance is it and there is no shared family.

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


def suite_tasks() -> dict[str, TaskInfo]:
    """The :class:`TaskInfo` of every task of :data:`DEFAULT_SUITE`, in its order."""
    return {name: task_info(name) for name in DEFAULT_SUITE}


__all__ = ["DEFAULT_SIZES", "DEFAULT_SUITE", "FAMILY_NAMES", "NAMES", "TABLE_CLEANING_HORIZON",
           "TaskInfo", "make_suite_family", "make_suite_task", "parse_name", "suite_tasks",
           "task_info"]
