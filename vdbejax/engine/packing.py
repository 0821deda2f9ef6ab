"""Packed rows: a batch's per-agent scalars as one row of 32-bit words per agent.

When a lane of the sequential strategy takes the next agent, the agent's scalars (state,
action, counters, key, hyperparameters) move as one row instead of one value per field.
The packing is exact: every leaf's bits are kept (:func:`unpack` is :func:`pack`'s
inverse). Leaves of one dtype sit side by side and are converted to and from words
together, so a tree of many scalars packs and unpacks in about one operation per leaf
(every program traces these for every field of every kind it serves).
"""
from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

Array = jax.Array

_UNSIGNED = {1: jnp.uint8, 2: jnp.uint16}


def _groups(leaves: list[Any]) -> dict[np.dtype, list[int]]:
    """The leaves' indices by dtype, dtypes in order of first appearance."""
    groups: dict[np.dtype, list[int]] = {}
    for k, leaf in enumerate(leaves):
        groups.setdefault(np.dtype(leaf.dtype), []).append(k)
    return groups


def _columns(leaf: Any) -> int:
    """Values per row of ``leaf`` (``[rows, ...]``)."""
    return int(np.prod(leaf.shape[1:], dtype=np.int64))


def _to_words(values: Array) -> Array:
    """``[rows, n]`` values of one dtype as uint32 words ``[rows, n·w]`` (exact)."""
    dtype = values.dtype
    if dtype == jnp.bool_:
        return jax.lax.convert_element_type(values, jnp.uint32)
    if dtype.itemsize < 4:  # the bits of an 8- or 16-bit value, widened
        return jax.lax.convert_element_type(
            jax.lax.bitcast_convert_type(values, _UNSIGNED[dtype.itemsize]), jnp.uint32)
    words = jax.lax.bitcast_convert_type(values, jnp.uint32)  # [rows, n, w] when w > 1
    return (jax.lax.reshape(words, (values.shape[0], words.shape[1] * words.shape[2]))
            if words.ndim == 3 else words)


def _from_words(words: Array, dtype: np.dtype) -> Array:
    """:func:`_to_words`' inverse: ``[rows, n·w]`` words as ``[rows, n]`` of ``dtype``."""
    if dtype == jnp.bool_:
        return jax.lax.ne(words, jnp.zeros((), jnp.uint32))
    if dtype.itemsize < 4:
        return jax.lax.bitcast_convert_type(
            jax.lax.convert_element_type(words, _UNSIGNED[dtype.itemsize]), dtype)
    per = dtype.itemsize // 4
    if per > 1:
        words = jax.lax.reshape(words, (words.shape[0], words.shape[1] // per, per))
    return jax.lax.bitcast_convert_type(words, dtype)


def pack(tree: Any) -> Array:
    """Every leaf of ``tree`` (leading axis = rows): uint32 ``[rows, words]``, the leaves
    of each dtype side by side."""
    leaves = [jnp.asarray(leaf) for leaf in jax.tree.leaves(tree)]
    parts = []
    for indices in _groups(leaves).values():
        flat = [jax.lax.reshape(leaves[k], (leaves[k].shape[0], _columns(leaves[k])))
                for k in indices]
        parts.append(_to_words(flat[0] if len(flat) == 1 else jax.lax.concatenate(flat, 1)))
    return parts[0] if len(parts) == 1 else jax.lax.concatenate(parts, 1)


def unpack(packed: Array, layout: Any) -> Any:
    """:func:`pack`'s inverse: ``layout``'s tree, leaves' dtypes and trailing shapes, on
    ``packed``'s rows."""
    leaves, treedef = jax.tree.flatten(layout)
    rows, start = packed.shape[0], 0
    out: list[Any] = [None] * len(leaves)
    for dtype, indices in _groups(leaves).items():
        widths = [_columns(leaves[k]) for k in indices]
        span = sum(widths) * max(1, dtype.itemsize // 4)
        values = _from_words(jax.lax.slice_in_dim(packed, start, start + span, axis=1), dtype)
        start += span
        columns = jax.lax.split(values, widths, axis=1) if len(widths) > 1 else [values]
        for k, column in zip(indices, columns, strict=True):
            shape = (rows, *leaves[k].shape[1:])
            out[k] = column if column.shape == shape else jax.lax.reshape(column, shape)
    return jax.tree.unflatten(treedef, out)
