"""Packed rows: a batch's per-agent scalars as one row of 32-bit words per agent.

When a lane of the sequential strategy takes the next agent, the agent's scalars (state,
action, counters, key, hyperparameters) move as one row instead of one value per field.
The packing is exact: every leaf's bits are kept (:func:`_unpack` is :func:`_pack`'s
inverse).
"""
from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

Array = jax.Array


def _words(leaf: Array) -> Array:
    """``leaf`` (``[rows, ...]``) as uint32 words, ``[rows, n]``; exact (see :func:`_unpack`)."""
    flat = leaf.reshape(leaf.shape[0], -1)
    if flat.dtype == jnp.bool_:
        return flat.astype(jnp.uint32)
    if flat.dtype.itemsize < 4:  # the bits of an 8- or 16-bit value, widened
        return jax.lax.bitcast_convert_type(flat, _UNSIGNED[flat.dtype.itemsize]).astype(jnp.uint32)
    return jax.lax.bitcast_convert_type(flat, jnp.uint32).reshape(leaf.shape[0], -1)


_UNSIGNED = {1: jnp.uint8, 2: jnp.uint16}


def _pack(tree: Any) -> Array:
    """Every leaf of ``tree`` (leading axis = rows) side by side: uint32 ``[rows, words]``."""
    return jnp.concatenate([_words(leaf) for leaf in jax.tree.leaves(tree)], axis=1)


def _unpack(packed: Array, layout: Any) -> Any:
    """:func:`_pack`'s inverse: ``layout``'s tree, leaves' dtypes and trailing shapes, on
    ``packed``'s rows."""
    leaves, treedef = jax.tree.flatten(layout)
    rows, out, start = packed.shape[0], [], 0
    for leaf in leaves:
        shape = (rows, *leaf.shape[1:])
        size = int(np.prod(leaf.shape[1:], dtype=np.int64))
        dtype = jnp.dtype(leaf.dtype)
        width = size * max(1, dtype.itemsize // 4)
        words = packed[:, start:start + width]
        start += width
        if dtype == jnp.bool_:
            value = words != 0
        elif dtype.itemsize < 4:
            value = jax.lax.bitcast_convert_type(words.astype(_UNSIGNED[dtype.itemsize]), dtype)
        elif dtype.itemsize == 4:
            value = jax.lax.bitcast_convert_type(words, dtype)
        else:
            value = jax.lax.bitcast_convert_type(
                words.reshape(rows, size, dtype.itemsize // 4), dtype)
        out.append(value.reshape(shape))
    return jax.tree.unflatten(treedef, out)
