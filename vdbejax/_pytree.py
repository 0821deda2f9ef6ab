"""Frozen dataclasses registered as JAX pytrees (rejax-style hyperparameter containers).

Fields are pytree leaves (so a sweep is a ``vmap``) unless declared with
``static_field()``, which makes them part of the tree structure (compile-time constants).
"""
from __future__ import annotations

import dataclasses
from typing import Any, TypeVar

import jax

T = TypeVar("T")


def static_field(default: Any = dataclasses.MISSING) -> Any:
    """A dataclass field that is compile-time static (not a pytree leaf)."""
    return dataclasses.field(default=default, metadata={"static": True})


def pytree_dataclass(cls: type[T]) -> type[T]:
    """Turn ``cls`` into a frozen dataclass registered as a pytree."""
    cls = dataclasses.dataclass(frozen=True)(cls)
    fields = dataclasses.fields(cls)
    data = [f.name for f in fields if not f.metadata.get("static", False)]
    meta = [f.name for f in fields if f.metadata.get("static", False)]
    jax.tree_util.register_dataclass(cls, data_fields=data, meta_fields=meta)
    return cls


def replace(obj: T, **changes: Any) -> T:
    """``dataclasses.replace`` for pytree dataclasses."""
    return dataclasses.replace(obj, **changes)
