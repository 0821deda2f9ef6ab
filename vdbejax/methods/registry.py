"""The plug-in registry: the decorators that register a class as explorer or learner
``name`` (:func:`explorer`, :func:`learner`), the registered classes by name
(:data:`EXPLORERS`, :data:`LEARNERS`), and building a validated instance from a setting's
values (:func:`build`).
"""
from __future__ import annotations

import dataclasses
from collections.abc import Callable, Mapping
from typing import Any, TypeVar, dataclass_transform

import jax
import numpy as np

from vdbejax._pytree import pytree_dataclass
from vdbejax.methods.contract import Explorer, Learner

ExplorerT = TypeVar("ExplorerT", bound="Explorer")
LearnerT = TypeVar("LearnerT", bound="Learner")

#: Registered plug-ins by name (built-ins and any user class decorated below).
EXPLORERS: dict[str, type[Explorer]] = {}
LEARNERS: dict[str, type[Learner]] = {}


@dataclass_transform(frozen_default=True, field_specifiers=(dataclasses.field,))
def explorer(name: str, parameter: str | None = None, title: str | None = None, *,
             replace: bool = False) -> Callable[[type[ExplorerT]], type[ExplorerT]]:
    """Class decorator: make ``cls`` a pytree dataclass and register it as explorer ``name``.

    Args:
      name: the name settings use (``Setting(learner, name, param)``).
      parameter: the field a setting's ``param`` sets (its swept parameter).
      title: the name figures and tables show (default: ``name``).
      replace: replace another plug-in registered under ``name`` (never a built-in).

    Raises:
      ValueError: ``cls`` is not an :class:`Explorer` or lacks ``select``; ``name`` is a
        built-in's, or another plug-in's without ``replace``.
    """
    def register(cls: type[ExplorerT]) -> type[ExplorerT]:
        _check_class(cls, Explorer, "explorer", name, ("select",))
        cls = pytree_dataclass(cls)
        cls.name, cls.parameter, cls.title = name, parameter, title or name
        if parameter is not None and parameter not in field_names(cls):
            raise ValueError(f"explorer {name!r}: parameter={parameter!r} is not one of its fields"
                             f" {field_names(cls)}")
        _check_name(EXPLORERS, "explorer", name, cls, replace)
        EXPLORERS[name] = cls
        return cls

    return register


@dataclass_transform(frozen_default=True, field_specifiers=(dataclasses.field,))
def learner(name: str, title: str | None = None, *,
            replace: bool = False) -> Callable[[type[LearnerT]], type[LearnerT]]:
    """Class decorator: make ``cls`` a pytree dataclass and register it as learner ``name``
    (``title``: the name figures and tables show; default ``name``; ``replace``: replace
    another plug-in registered under ``name``, never a built-in).

    Raises:
      ValueError: ``cls`` is not a :class:`Learner`, lacks ``update`` or a ``gamma`` field;
        ``name`` is a built-in's, or another plug-in's without ``replace``.
    """
    def register(cls: type[LearnerT]) -> type[LearnerT]:
        _check_class(cls, Learner, "learner", name, ("update",))
        cls = pytree_dataclass(cls)
        cls.name, cls.title = name, title or name
        if "gamma" not in field_names(cls):
            raise ValueError(f"learner {name!r} has no gamma field: the engine needs the discount")
        _check_name(LEARNERS, "learner", name, cls, replace)
        LEARNERS[name] = cls
        return cls

    return register


def _check_name(registry: dict[str, Any], role: str, name: str, cls: type,
                replace: bool) -> None:
    """Refuse a plug-in that would replace another under its name without a word (its
    results would carry the other's name). The same class defined again (a notebook cell
    or a plug-in file run twice: same module and name) replaces its earlier self."""
    old = registry.get(name)
    if old is None or (old.__module__, old.__qualname__) == (cls.__module__, cls.__qualname__):
        return
    if old.__module__.startswith("vdbejax.") and not cls.__module__.startswith("vdbejax."):
        raise ValueError(f"{role} name {name!r} is a built-in's ({old.__name__}): register"
                         " yours under another name")
    if not replace:
        raise ValueError(f"{role} name {name!r} is taken by {old.__module__}.{old.__qualname__}:"
                         f" choose another name, or pass replace=True to @{role}(...)")


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

