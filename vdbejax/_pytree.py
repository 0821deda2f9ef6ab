"""Frozen dataclasses registered as JAX pytrees (rejax-style hyperparameter containers).

Fields are pytree leaves (so a sweep is a ``vmap``) unless declared with
``static_field()``, which makes them part of the tree structure (compile-time constants).
"""
from __future__ import annotations

import dataclasses
from typing import Any, TypeVar, cast, dataclass_transform

import jax

T = TypeVar("T")


def static_field(default: Any = dataclasses.MISSING) -> Any:
    """A dataclass field that is compile-time static (not a pytree leaf)."""
    return dataclasses.field(default=default, metadata={"static": True})


@dataclass_transform(frozen_default=True, field_specifiers=(dataclasses.field,))
def pytree_dataclass(cls: type[T]) -> type[T]:
    """Turn ``cls`` into a frozen dataclass registered as a pytree.

    Registered as a custom node (not with ``jax.tree_util.register_dataclass``, whose
    tree structures of two classes with the same field names compare *equal*: JAX's
    caches could then hand one class's compiled program to the other — e.g. Q-learning's
    to SARSA, whose fields are the same).
    """
    cls = dataclasses.dataclass(frozen=True)(cls)
    fields = dataclasses.fields(cast(Any, cls))
    data = tuple(f.name for f in fields if not f.metadata.get("static", False))
    meta = tuple(f.name for f in fields if f.metadata.get("static", False))
    keys = tuple(jax.tree_util.GetAttrKey(name) for name in data)

    def flatten_with_keys(obj: Any) -> tuple:
        return (tuple(zip(keys, (getattr(obj, n) for n in data), strict=True)),
                tuple(getattr(obj, n) for n in meta))

    def flatten(obj: Any) -> tuple:
        return tuple(getattr(obj, n) for n in data), tuple(getattr(obj, n) for n in meta)

    def unflatten(static: tuple, children: Any) -> Any:
        obj = object.__new__(cls)  # no __init__: leaves may be tracers or placeholders
        for name, value in zip(data, children, strict=True):
            object.__setattr__(obj, name, value)
        for name, value in zip(meta, static, strict=True):
            object.__setattr__(obj, name, value)
        return obj

    jax.tree_util.register_pytree_with_keys(cls, flatten_with_keys, unflatten, flatten)
    return cls


def replace(obj: T, **changes: Any) -> T:
    """``dataclasses.replace`` for pytree dataclasses."""
    return cast(T, dataclasses.replace(cast(Any, obj), **changes))
