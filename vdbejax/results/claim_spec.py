"""Claims as data: what a study states it expects, read from its sweep file and checked
against its settings before training.

A study's ``claims`` (a sweep file's ``[[claims]]`` tables, or a file of claims alone) are
each a sentence and its checks::

    [[claims]]
    claim = "ε = 0.1 finds the best arm more often than ε = 0.01"
    stated = "ε = 0.1: about 80 % optimal by pull 1,000"   # optional: the source's figure
    checks = [
      {setting = "qlearning/egreedy/epsilon=0.1", metric = "optimal_actions", above = 0.7},
      {setting = {explorer = "egreedy", epsilon = 0.1},
       higher_than = {explorer = "egreedy", epsilon = 0.01}, metric = "reward_per_step"},
    ]

A check reads a :data:`METRICS` value of a setting with its 95% interval and compares it
with exactly one of :data:`COMPARISONS`:

- a number: ``above``, ``below``, ``about`` (± ``tolerance``, a fraction of the figure,
  default :data:`ABOUT`), ``near_best = true`` (at least the task's best return less
  ``near``, default :data:`NEAR`);
- another setting: ``higher_than``, ``lower_than``, ``earlier_than`` and ``no_later_than``
  (the latter two read ``convergence_episode`` unless a metric is given; ``factor``
  multiplies the other setting's estimate), or ``beats``
  with ``probability_above`` (default 0.5): the probability of improvement
  ``P(A > B)`` of the agents' final returns with its interval;
- another setting: ``no_higher_than`` (the interval at or below the other's), ``worse_than``
  (ends lower or converges later), ``converges_first = [settings]`` (ends near the best
  return and converges no later than each listed setting that ends near it);
- an axis: ``best = [values]`` (the settings of ``among`` whose ``axis`` has these values
  lie above every other value's) or ``rank = k`` with ``value`` (that value's rank).

A selector table may give a hyperparameter a range (``sigma = {at_least = 0.1}``:
:class:`Bounds`) or a list of values (one of them); ``{every = S}`` (:class:`Every`) checks
every setting ``S`` names. A check's ``text`` is its wording in reports.

Settings are named as the run names them (``"qlearning/egreedy/epsilon=0.1"``, the
setting's label) or selected by a table of ``learner``, ``explorer`` and hyperparameter
values, or chosen by their results among those (``{best = …}``, ``{worst = …}``:
:class:`Ranked`). Checks combine: ``{all = [checks]}``, ``{any = [checks]}``, ``{not = check}``.
:func:`parse_claims` reads them (the format); :func:`check_claims` checks them against a
run's settings and records (every reference resolved, each metric recorded) before
anything is trained; :mod:`vdbejax.results.claim_scoring` scores them.
"""
from __future__ import annotations

import dataclasses
import hashlib
import json
import math
from collections.abc import Mapping, Sequence
from typing import Any

from vdbejax.methods.agents import Setting
from vdbejax.methods.grid_axes import setting_matches

#: Metrics a check may read, and what each is.
METRICS = {
    "final_return": "mean final return over the agents",
    "convergence_episode": "median convergence episode over the agents",
    "final_iqm": "interquartile mean of the agents' final returns",
    "normalised_score": "interquartile mean of the agents' normalised scores"
                        " (0 = the random policy, 1 = the optimum from the first episode)",
    "optimal_actions": "mean fraction of optimal actions in the last episodes",
    "reward_per_step": "mean reward per step in the last episodes",
    "policy_gap": "mean gap V* − V^π of the agents' greedy policies",
}
#: Metrics a run records only when asked, with what records them.
RECORDED_BY = {"optimal_actions": "record_optimal", "reward_per_step": "record_optimal",
               "policy_gap": "evaluate_every"}
#: Metrics where lower is better (ranks and "best" read them the other way).
LOWER_IS_BETTER = frozenset({"convergence_episode", "policy_gap"})
#: A check's comparison keys: exactly one per check.
COMPARISONS = ("above", "below", "about", "near_best", "higher_than", "lower_than",
               "no_higher_than", "earlier_than", "no_later_than", "worse_than",
               "converges_first", "beats", "best", "rank", "all", "any", "not")
#: The comparisons with another setting.
VERSUS = ("higher_than", "lower_than", "no_higher_than", "earlier_than", "no_later_than",
          "worse_than", "beats")
#: Default relative tolerance of ``about``.
ABOUT = 0.25
#: Default margin of ``near_best``.
NEAR = 0.05
#: Default level of ``beats``.
LEVEL = 0.5
#: The comparisons a ``factor`` may scale the other setting's estimate in.
SCALED = ("higher_than", "lower_than", "no_higher_than", "earlier_than", "no_later_than")
#: The comparisons that read two metrics of their own (``metric`` is refused with them).
TWO_METRICS = ("worse_than", "converges_first")
#: Every key a check may hold.
CHECK_KEYS = (*COMPARISONS, "setting", "metric", "tolerance", "near", "probability_above",
              "axis", "among", "value", "factor", "text")
#: The ends a range of a hyperparameter's values may give (:class:`Bounds`).
RANGE_KEYS = ("at_least", "at_most", "above", "below")
#: Settings whose ranking values are this close are tied when a ``best`` selector picks
#: one (a choice, not a verdict: verdicts come from intervals).
TIE = 0.01
#: A ranked selector's default ranking metric (``by``).
RANK_BY = "final_iqm"



@dataclasses.dataclass(frozen=True)
class Bounds:
    """A range of a hyperparameter's values in a selector table (``sigma = {at_least =
    0.1}``, ``sigma = {above = 0.01, below = 1}``): a setting matches when its value is a
    number and every end given holds."""

    at_least: float | None = None
    at_most: float | None = None
    above: float | None = None
    below: float | None = None

    def holds(self, value: Any) -> bool:
        """Whether ``value`` lies in the range."""
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            return False
        return ((self.at_least is None or value >= self.at_least)
                and (self.at_most is None or value <= self.at_most)
                and (self.above is None or value > self.above)
                and (self.below is None or value < self.below))

    def text(self) -> str:
        """The range as the claims file gives it (``{at_least = 0.1}``)."""
        return "{" + ", ".join(f"{key} = {getattr(self, key):g}" for key in RANGE_KEYS
                               if getattr(self, key) is not None) + "}"


#: A setting named outright: its label, or ``(key, value)`` pairs it must match (a value,
#: a :class:`Bounds` range, or a tuple of values, one of which it must have).
Named = str | tuple[tuple[str, Any], ...]


@dataclasses.dataclass(frozen=True)
class Ranked:
    """A setting chosen by its results among those a selector names (``{best = …}`` or
    ``{worst = …}``, with ``by`` the metric ranked, default :data:`RANK_BY`).

    ``best``: the highest by ``by`` (the lowest for :data:`LOWER_IS_BETTER`); among the
    settings within :data:`TIE` of it, the one that converges first (then the better
    ranked, then the first in the run's order). ``worst``: the lowest by ``by`` (the
    highest for :data:`LOWER_IS_BETTER`), the first in the run's order on ties. Each
    replicate picks on its own agents.
    """

    pick: str
    among: Named
    by: str = RANK_BY


@dataclasses.dataclass(frozen=True)
class Every:
    """Every setting a selector names (``{every = S}``): the check holds for each of them
    (Kleene's and); as the other setting of a comparison, against each of them."""

    among: Named


#: A setting as a claim names it: outright (:data:`Named`), by its results
#: (:class:`Ranked`), or all those a selector names (:class:`Every`).
Selector = Named | Ranked | Every


@dataclasses.dataclass(frozen=True)
class CheckSpec:
    """One check of a claim, as stated (see the module's text for the keys).

    Attributes:
      kind: the comparison (one of :data:`COMPARISONS`).
      where: the check's place in the file (``claims[0].checks[1]``), for messages.
      metric: the metric read.
      setting: the setting checked (number and setting comparisons).
      other: the other setting (:data:`VERSUS`).
      others: ``converges_first``'s rivals.
      bound: the number compared with (``above``, ``below``, ``about``; the level of
        ``beats``; the margin of ``near_best``).
      factor: what the other setting's estimate is multiplied by (:data:`SCALED`).
      tolerance: ``about``'s relative tolerance.
      axis, among, values, rank: an axis comparison's axis, settings, best values (or
        ``rank``'s one value) and rank.
      parts: the checks an ``all``, ``any`` or ``not`` combines.
      optional: a claim's check left out where a setting it names is absent from the run
        (:func:`present`), rather than refused.
      text: the check in words (reports print it before what the check read).
      requires: settings an ``optional`` check also needs in the run (else it is left out).
    """

    kind: str
    where: str
    metric: str = "final_return"
    setting: Selector | None = None
    other: Selector | None = None
    others: tuple[Selector, ...] = ()
    bound: float = math.nan
    tolerance: float = ABOUT
    factor: float = 1.0
    axis: str | None = None
    among: Named | None = None
    values: tuple[Any, ...] = ()
    rank: int = 0
    parts: tuple[CheckSpec, ...] = ()
    optional: bool = False
    text: str = ""
    requires: tuple[Named, ...] = ()


@dataclasses.dataclass(frozen=True)
class ClaimSpec:
    """A claim as stated: its sentence, the source's figure (optional) and its checks."""

    claim: str
    checks: tuple[CheckSpec, ...]
    stated: str = ""


def _number(value: Any, where: str, key: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) \
            or not math.isfinite(value):
        raise ValueError(f"{where}: {key}={value!r} is invalid: must be a finite number")
    return float(value)


def _bounds(value: Mapping[str, Any], where: str, key: str) -> Bounds:
    unknown = sorted(set(value) - set(RANGE_KEYS))
    if unknown or not value:
        raise ValueError(f"{where}: {key}={dict(value)!r} is invalid: a range gives one or more"
                         f" of {', '.join(RANGE_KEYS)}")
    return Bounds(**{end: _number(bound, where, f"{key}.{end}") for end, bound in value.items()})


def _rule_value(value: Any, where: str, key: str) -> Any:
    """A selector table's value: a :class:`Bounds` range, a tuple of values (one of), or
    the value."""
    if isinstance(value, Mapping):
        return _bounds(value, where, key)
    if isinstance(value, list):
        if not value or any(isinstance(v, (list, Mapping)) for v in value):
            raise ValueError(f"{where}: {key}={value!r} is invalid: a list of values must be"
                             " non-empty, of plain values")
        return tuple(value)
    return value


def _named(value: Any, where: str, key: str) -> Named:
    if isinstance(value, str) and value:
        return value
    if isinstance(value, Mapping) and value and all(isinstance(k, str) for k in value) \
            and not {"best", "worst", "every"} & set(value):
        return tuple(sorted((k, _rule_value(v, where, f"{key}.{k}")) for k, v in value.items()))
    raise ValueError(f"{where}: {key}={value!r} is invalid: must be a setting's name"
                     " (learner/explorer/name=value) or a table {learner, explorer, name = value}")


def _selector(value: Any, where: str, key: str) -> Selector:
    if isinstance(value, Mapping) and "every" in value:
        if set(value) != {"every"}:
            raise ValueError(f"{where}: {key}={value!r} is invalid: {{every = S}} takes no"
                             " other key")
        return Every(_named(value["every"], where, f"{key}.every"))
    if not isinstance(value, Mapping) or not {"best", "worst"} & set(value):
        return _named(value, where, key)
    picks = [pick for pick in ("best", "worst") if pick in value]
    unknown = sorted(set(value) - {"best", "worst", "by"})
    if len(picks) != 1 or unknown:
        raise ValueError(f"{where}: {key}={value!r} is invalid: a ranked selector is"
                         " {best = S} or {worst = S}, with by = a metric")
    by = _metric(value.get("by", RANK_BY), where, f"{key}.by")
    return Ranked(picks[0], _named(value[picks[0]], where, f"{key}.{picks[0]}"), by)


def _metric(value: Any, where: str, key: str) -> str:
    """``value`` if it names one of :data:`METRICS`, else one line naming ``key``."""
    if value not in METRICS:
        raise ValueError(f"{where}: {key}={value!r} is invalid: allowed are"
                         f" {', '.join(METRICS)}")
    return value


#: The keys only a claim's check (not a combined one) may hold.
TOP_KEYS = ("optional", "requires", "text")


def _top_check(data: Any, where: str) -> CheckSpec:
    """A claim's check: :func:`_check`, with ``optional``, ``requires`` and ``text``."""
    if not isinstance(data, Mapping) or not set(TOP_KEYS) & set(data):
        return _check(data, where)
    optional, text = data.get("optional", False), data.get("text", "")
    if not isinstance(optional, bool):
        raise ValueError(f"{where}: optional={optional!r} is invalid: must be true or false")
    if "text" in data and (not isinstance(text, str) or not text.strip()):
        raise ValueError(f"{where}: text={text!r} is invalid: must be the check in words")
    requires = data.get("requires", [])
    if "requires" in data and (not optional or not isinstance(requires, list) or not requires):
        raise ValueError(f"{where}: requires={requires!r} is invalid: must be a non-empty list"
                         " of settings, with optional = true")
    rest = {key: value for key, value in data.items() if key not in TOP_KEYS}
    return dataclasses.replace(_check(rest, where), optional=optional, text=text,
                               requires=tuple(_named(value, where, f"requires[{i}]")
                                              for i, value in enumerate(requires)))


def _check(data: Any, where: str) -> CheckSpec:
    if not isinstance(data, Mapping):
        raise ValueError(f"{where}={data!r} is invalid: must be a table {{setting, metric,"
                         f" comparison}} (comparisons: {', '.join(COMPARISONS)})")
    for key in TOP_KEYS:
        if key in data:
            raise ValueError(f"{where}: {key!r} is invalid inside a combination: give it on"
                             " the claim's check")
    unknown = sorted(set(data) - set(CHECK_KEYS))
    if unknown:
        raise ValueError(f"{where}: unknown key {unknown[0]!r}: allowed are"
                         f" {', '.join(CHECK_KEYS)}")
    kinds = [key for key in COMPARISONS if key in data]
    if len(kinds) != 1:
        raise ValueError(f"{where} is invalid: needs exactly one comparison of"
                         f" {', '.join(COMPARISONS)} (has {kinds or 'none'})")
    kind = kinds[0]
    if kind in ("all", "any", "not"):
        parts = [data[kind]] if kind == "not" else data[kind]
        if kind != "not" and (not isinstance(parts, list) or not parts):
            raise ValueError(f"{where}: {kind}={parts!r} is invalid: must be a non-empty list"
                             " of checks")
        extra = sorted(set(data) - {kind})
        if extra:
            raise ValueError(f"{where}: {extra[0]!r} is invalid beside {kind!r}: give it in"
                             " the combined checks")
        return CheckSpec(kind, where, parts=tuple(
            _check(part, f"{where}.{kind}" + ("" if kind == "not" else f"[{i}]"))
            for i, part in enumerate(parts)))
    default = "convergence_episode" if kind in ("earlier_than", "no_later_than",
                                                "converges_first") else "final_return"
    if kind in TWO_METRICS and "metric" in data:
        raise ValueError(f"{where}: metric={data['metric']!r} is invalid with {kind}: it reads"
                         " final_return and convergence_episode")
    metric = _metric(data.get("metric", default), where, "metric")
    if kind == "beats" and metric != "final_return":
        raise ValueError(f"{where}: metric={metric!r} is invalid with beats: P(A > B) reads"
                         " the agents' final returns (metric = \"final_return\")")
    fields: dict[str, Any] = {"metric": metric}
    if kind in ("best", "rank"):
        for key in ("axis", "among"):
            if key not in data:
                raise ValueError(f"{where}: {kind} needs {key} = …")
        if not isinstance(data["axis"], str) or not data["axis"]:
            raise ValueError(f"{where}: axis={data['axis']!r} is invalid: must be a"
                             " hyperparameter's name")
        fields.update(axis=data["axis"], among=_named(data["among"], where, "among"))
        if kind == "best":
            values = data["best"]
            if not isinstance(values, list) or not values:
                raise ValueError(f"{where}: best={values!r} is invalid: must be a non-empty"
                                 " list of the axis's values")
            fields["values"] = tuple(values)
        else:
            rank = data["rank"]
            if isinstance(rank, bool) or not isinstance(rank, int) or rank < 1:
                raise ValueError(f"{where}: rank={rank!r} is invalid: must be a whole"
                                 " number ≥ 1")
            if "value" not in data:
                raise ValueError(f"{where}: rank needs value = … (the axis's value ranked)")
            fields.update(rank=rank, values=(data["value"],))
    else:
        if "setting" not in data:
            raise ValueError(f"{where}: {kind} needs setting = … (the setting checked)")
        fields["setting"] = _selector(data["setting"], where, "setting")
        if kind == "beats" and isinstance(fields["setting"], Every):
            raise ValueError(f"{where}: setting={data['setting']!r} is invalid with beats:"
                             " name one setting")
    if kind in VERSUS:
        fields["other"] = _selector(data[kind], where, kind)
        if kind == "beats" and isinstance(fields["other"], Every):
            raise ValueError(f"{where}: beats={data[kind]!r} is invalid: name one setting")
    if kind == "converges_first":
        rivals = data[kind]
        if not isinstance(rivals, list) or not rivals:
            raise ValueError(f"{where}: converges_first={rivals!r} is invalid: must be a"
                             " non-empty list of settings")
        fields["others"] = tuple(_selector(rival, where, f"{kind}[{i}]")
                                 for i, rival in enumerate(rivals))
    if kind in ("above", "below", "about"):
        fields["bound"] = _number(data[kind], where, kind)
    if kind == "about":
        fields["tolerance"] = _number(data.get("tolerance", ABOUT), where, "tolerance")
        if fields["tolerance"] < 0:
            raise ValueError(f"{where}: tolerance={data['tolerance']!r} is invalid: must be"
                             " a number ≥ 0 (a fraction of the figure)")
    if kind in SCALED:
        fields["factor"] = _number(data.get("factor", 1.0), where, "factor")
        if fields["factor"] <= 0:
            raise ValueError(f"{where}: factor={data['factor']!r} is invalid: must be a"
                             " number > 0 (what the other setting's estimate is multiplied by)")
    if kind == "near_best" and data[kind] is not True:
        raise ValueError(f"{where}: near_best={data[kind]!r} is invalid: must be true")
    if kind in ("near_best", "converges_first"):
        fields["bound"] = _number(data.get("near", NEAR), where, "near")
    if kind == "beats":
        level = _number(data.get("probability_above", LEVEL), where, "probability_above")
        if not 0 <= level < 1:
            raise ValueError(f"{where}: probability_above={level!r} is invalid: must be in"
                             " [0, 1)")
        fields["bound"] = level
    unused = [key for key, used in (("tolerance", kind == "about"),
                                    ("near", kind in ("near_best", "converges_first")),
                                    ("probability_above", kind == "beats"),
                                    ("axis", kind in ("best", "rank")),
                                    ("among", kind in ("best", "rank")),
                                    ("value", kind == "rank"), ("factor", kind in SCALED),
                                    ("setting", kind not in ("best", "rank")))
              if key in data and not used]
    if unused:
        raise ValueError(f"{where}: {unused[0]!r} is invalid with {kind}")
    return CheckSpec(kind, where, **fields)


def parse_claims(data: Any) -> tuple[ClaimSpec, ...]:
    """A study's claims (a list of tables ``{claim, checks, stated}``) as :class:`ClaimSpec`.

    Raises:
      ValueError: one line naming the claim and the field that is malformed.
    """
    if not isinstance(data, list):
        raise ValueError(f"claims={data!r} is invalid: must be a list of tables"
                         " {claim = \"…\", checks = [...]}")
    claims = []
    for i, entry in enumerate(data):
        where = f"claims[{i}]"
        if not isinstance(entry, Mapping):
            raise ValueError(f"{where}={entry!r} is invalid: must be a table {{claim, checks}}")
        unknown = sorted(set(entry) - {"claim", "checks", "stated"})
        if unknown:
            raise ValueError(f"{where}: unknown key {unknown[0]!r}: allowed are claim,"
                             " checks, stated")
        sentence, stated = entry.get("claim"), entry.get("stated", "")
        if not isinstance(sentence, str) or not sentence.strip():
            raise ValueError(f"{where}: claim={sentence!r} is invalid: must be the claim's"
                             " sentence")
        if not isinstance(stated, str):
            raise ValueError(f"{where}: stated={stated!r} is invalid: must be text")
        checks = entry.get("checks")
        if not isinstance(checks, list) or not checks:
            raise ValueError(f"{where} ({sentence!r}): checks={checks!r} is invalid: must be a"
                             " non-empty list of checks")
        claims.append(ClaimSpec(sentence, tuple(
            _top_check(check, f"{where}.checks[{j}]") for j, check in enumerate(checks)),
            stated))
    return tuple(claims)


def claims_digest(data: Any) -> str:
    """The sha256 of a study's claims as data (canonical JSON): ``meta.json`` keeps it, so
    that a report can say whether claims were stated before the run."""
    text = json.dumps(data, sort_keys=True, ensure_ascii=False, separators=(",", ":"))
    return hashlib.sha256(text.encode()).hexdigest()


def selector_text(selector: Selector) -> str:
    """A selector as the claims file gives it (a label, ``{key = value, …}``, or
    ``{best = …, by = …}``)."""
    if isinstance(selector, Ranked):
        return (f"{{{selector.pick} = {selector_text(selector.among)}, by ="
                f" {selector.by!r}}}")
    if isinstance(selector, Every):
        return f"{{every = {selector_text(selector.among)}}}"
    if isinstance(selector, str):
        return selector
    return "{" + ", ".join(f"{k} = {v.text() if isinstance(v, Bounds) else repr(v)}"
                           for k, v in selector) + "}"


def _matches(setting: Setting, key: str, value: Any) -> bool:
    if isinstance(value, Bounds):
        return value.holds(setting.values.get(key))
    if isinstance(value, tuple):
        return any(setting_matches(setting, {key: v}) for v in value)
    return setting_matches(setting, {key: value})


def select(selector: Named, settings: Sequence[Setting]) -> list[int]:
    """The indices of the settings a selector names outright."""
    if isinstance(selector, str):
        return [c for c, s in enumerate(settings) if s.label == selector]
    return [c for c, s in enumerate(settings)
            if all(_matches(s, key, value) for key, value in selector)]


def candidates(selector: Selector, settings: Sequence[Setting], where: str,
               key: str) -> list[int]:
    """The settings a selector may name: the one it names outright (:func:`select_one`), or
    every setting a :class:`Ranked` one chooses among or an :class:`Every` one names (one
    or more).

    Raises:
      ValueError: it names none, or (outright) several.
    """
    if isinstance(selector, Every):
        found = select(selector.among, settings)
        if not found:
            select_one(selector.among, settings, where, f"{key}.every")
        return found
    if not isinstance(selector, Ranked):
        return [select_one(selector, settings, where, key)]
    found = select(selector.among, settings)
    if not found:
        select_one(selector.among, settings, where, f"{key}.{selector.pick}")
    return found


def select_one(selector: Named, settings: Sequence[Setting], where: str, key: str) -> int:
    """The one setting a selector names outright.

    Raises:
      ValueError: it names none or several.
    """
    found = select(selector, settings)
    if len(found) != 1:
        names = ", ".join(settings[c].label for c in found[:3])
        raise ValueError(f"{where}: {key}={selector_text(selector)} is invalid: it names"
                         + (f" {len(found)} settings ({names}, …); name one" if found else
                            " no setting of the run (labels: "
                            + ", ".join(s.label for s in settings[:4])
                            + (", …" if len(settings) > 4 else "") + ")"))
    return found[0]


def axis_settings(check: CheckSpec, settings: Sequence[Setting]) -> dict[int, Any]:
    """``{config: its value of the axis}`` of an axis check's settings.

    Raises:
      ValueError: ``among`` names fewer than two settings, one lacks the axis, or two
        share a value.
    """
    assert check.among is not None and check.axis is not None
    found = select(check.among, settings)
    if len(found) < 2:
        raise ValueError(f"{check.where}: among={selector_text(check.among)} is invalid: it"
                         f" names {len(found)} setting(s); an axis needs two or more")
    values: dict[int, Any] = {}
    for c in found:
        if check.axis not in settings[c].values:
            raise ValueError(f"{check.where}: axis={check.axis!r} is invalid: setting"
                             f" {settings[c].label} has no value of it")
        value = settings[c].values[check.axis]
        if any(setting_matches(settings[c], {check.axis: v}) for v in values.values()):
            raise ValueError(f"{check.where}: among={selector_text(check.among)} is invalid:"
                             f" two settings have {check.axis}={value!r}; narrow it to one"
                             " per value")
        values[c] = value
    return values


def axis_members(check: CheckSpec, settings: Sequence[Setting]) -> list[int]:
    """The configs of an axis check's chosen values (``best``'s, or ``rank``'s one).

    Raises:
      ValueError: a value the axis's settings do not have.
    """
    assert check.axis is not None
    values = axis_settings(check, settings)
    chosen = []
    for value in check.values:
        match = [c for c in values if setting_matches(settings[c], {check.axis: value})]
        if not match:
            raise ValueError(f"{check.where}: {check.axis}={value!r} is invalid: the axis's"
                             f" values are {sorted(values.values(), key=str)}")
        chosen += match
    if check.kind == "rank" and check.rank > len(values):
        raise ValueError(f"{check.where}: rank={check.rank} is invalid: the axis has"
                         f" {len(values)} values")
    return chosen


def present(check: CheckSpec, settings: Sequence[Setting]) -> bool:
    """Whether every setting a check names (however deep) or ``requires`` is in the run: an
    ``optional`` check is scored only where it is, and left out otherwise."""
    named = [selector.among if isinstance(selector, (Ranked, Every)) else selector
             for leaf in leaves(check)
             for selector in (leaf.setting, leaf.other, *leaf.others, leaf.among)
             if selector is not None] + list(check.requires)
    return all(select(selector, settings) for selector in named)


def scored_checks(claim: ClaimSpec, settings: Sequence[Setting]) -> list[CheckSpec]:
    """A claim's checks scored on a run: all but the ``optional`` ones whose settings are
    absent (:func:`present`)."""
    return [check for check in claim.checks if not check.optional or present(check, settings)]


def leaves(check: CheckSpec) -> list[CheckSpec]:
    """A check's comparisons (itself, or those it combines, however deep)."""
    return [leaf for part in check.parts for leaf in leaves(part)] if check.parts else [check]


def check_claims(claims: Sequence[ClaimSpec], settings: Sequence[Setting],
                 recorded: Sequence[str] = ()) -> None:
    """Check claims against a run before it trains: every setting they name exists (and
    once), no setting is compared with itself, every axis and value exists, and every
    metric is recorded.

    Args:
      claims: :func:`parse_claims`'s.
      settings: the run's settings.
      recorded: the optional records the run keeps (``record_optimal``,
        ``evaluate_every``: :data:`RECORDED_BY`).

    Raises:
      ValueError: one line naming the claim, the field and what is allowed.
    """
    for i, claim in enumerate(claims):
        try:
            for check in scored_checks(claim, settings):
                for leaf in leaves(check):
                    _check_leaf(leaf, settings, recorded)
        except ValueError as error:
            raise ValueError(f"claim {i + 1} ({claim.claim!r}): {error}") from None


def _check_leaf(leaf: CheckSpec, settings: Sequence[Setting], recorded: Sequence[str]) -> None:
    metrics = [("metric", leaf.metric)] + [
        (f"{key}.by", selector.by) for key, selector in (("setting", leaf.setting),
                                                         (leaf.kind, leaf.other),
                                                         *((leaf.kind, o) for o in leaf.others))
        if isinstance(selector, Ranked)]
    for key, metric in metrics:
        needs = RECORDED_BY.get(metric)
        if needs is not None and needs not in recorded:
            flag = needs.replace("_", "-")
            raise ValueError(f"{leaf.where}: {key}={metric!r} is invalid: the run does not"
                             f" record it (needs {needs} = … in the sweep file, --{flag})")
    if leaf.kind in ("best", "rank"):
        axis_members(leaf, settings)
        return
    assert leaf.setting is not None
    mine = candidates(leaf.setting, settings, leaf.where, "setting")
    for rival in (leaf.other, *leaf.others):
        if rival is None:
            continue
        other = candidates(rival, settings, leaf.where, leaf.kind)
        if set(other) & set(mine):
            same = settings[min(set(other) & set(mine))].label
            verb = "is" if len(mine) == len(other) == 1 else "may be"
            raise ValueError(f"{leaf.where}: {leaf.kind}={selector_text(rival)} is"
                             f" invalid: it {verb} the setting checked ({same});"
                             " compare two settings")


__all__ = ["ABOUT", "CHECK_KEYS", "COMPARISONS", "LEVEL", "LOWER_IS_BETTER", "METRICS", "NEAR",
           "RANGE_KEYS", "RANK_BY", "RECORDED_BY", "SCALED", "TIE", "TOP_KEYS", "TWO_METRICS",
           "VERSUS",
           "Bounds", "CheckSpec", "ClaimSpec", "Every", "Named", "Ranked", "Selector",
           "axis_members", "axis_settings", "candidates",
           "check_claims", "claims_digest", "leaves", "parse_claims", "present", "scored_checks",
           "select", "select_one", "selector_text"]
