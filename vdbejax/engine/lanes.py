"""Per-lane table access of the step rule (:mod:`vdbejax.engine.step`).

Tables are flat 1-D buffers (``[B·S·A]``, ``[B·S]``), so every access is one row per lane:
a 1-D gather or scatter for wide batches, and for a batch of a few lanes (the sequential
strategy's loops) unrolled dynamic slices — XLA's CPU backend then compiles the whole loop
into one native function (scatters would keep it on the per-op runtime).
"""
from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp

Array = jax.Array


# Per-lane buffer access. A batch of a few lanes (the CPU engine's loops) uses unrolled
# dynamic slices instead of gathers/scatters: XLA's CPU backend then compiles the whole
# loop into one native function (scatters would keep it on the per-op runtime).


#: Largest index of a flat buffer (``int32``): a batch's lanes × one agent's elements of a
#: table, or of its episode buffers, must stay within it.
FLAT_INDEX_MAX = 2**31 - 1


def lanes_within_index(elements_per_agent: int) -> int:
    """The most lanes whose flat buffers of ``elements_per_agent`` elements per agent are
    indexed by ``int32`` (:data:`FLAT_INDEX_MAX`)."""
    return max(1, FLAT_INDEX_MAX // max(1, elements_per_agent))


#: Batches of at most this many lanes access their rows by unrolled dynamic slices (the
#: sequential strategy's loops, :data:`~vdbejax.engine.work_items.LANES`); wider ones by
#: gathers and scatters.
UNROLLED_LANES_MAX = 4


def is_unrolled(index: Array) -> bool:
    """Whether a per-lane index is few enough lanes to access them one by one (unrolled
    slices: the sequential strategy's native loops) rather than by gather and scatter."""
    return index.ndim == 1 and index.shape[0] <= UNROLLED_LANES_MAX


def at_lane(values: Array, k: int) -> Array:
    """``values[k]`` along the lanes' axis, as the primitives themselves: traced in a
    fraction of the time of NumPy-style indexing (every program traces hundreds)."""
    return jax.lax.index_in_dim(values, k, keepdims=False)


def _slice(buffer: Array, start: Array, width: int) -> Array:
    """``buffer[start : start + width]``, the start clamped into the buffer. Starts are
    never negative here, so the slice skips the negative-index wrap-around (a compare and
    a select traced and run at every access)."""
    return jax.lax.dynamic_slice(buffer, (start,), (width,), allow_negative_indices=False)


def _update(buffer: Array, value: Array, start: Array) -> Array:
    """``buffer`` with ``value`` written from ``start`` (clamped as :func:`_slice`)."""
    return jax.lax.dynamic_update_slice(buffer, value, (start,), allow_negative_indices=False)


def take(buffer: Array, index: Array) -> Array:
    """``buffer[index]``, one value per lane (``[B]``)."""
    if is_unrolled(index):
        return jnp.concatenate([_slice(buffer, at_lane(index, k), 1)
                                for k in range(index.shape[0])])
    return buffer.at[index].get(mode="promise_in_bounds")


def take_row(buffer: Array, index: Array, width: int) -> Array:
    """``buffer[index + j]`` for ``j < width``, one row per lane (``[B, width]``)."""
    if is_unrolled(index):
        return jnp.stack([_slice(buffer, at_lane(index, k), width)
                          for k in range(index.shape[0])])
    columns = jnp.arange(width, dtype=index.dtype)[None, :]
    return buffer.at[index[:, None] + columns].get(mode="promise_in_bounds")


def _scatter(buffer: Array, index: Array, value: Array, rows: bool = False) -> Array:
    """``buffer[index] = value`` (``[B]``), or with ``rows`` ``buffer[index + j] =
    value[:, j]`` (``[B, width]``), for distinct in-bounds lanes (wide batches; a few
    lanes write through :func:`write_lanes`)."""
    value = value.astype(buffer.dtype)
    if not rows:
        return buffer.at[index].set(value, mode="promise_in_bounds", unique_indices=True)
    columns = jnp.arange(value.shape[1], dtype=index.dtype)[None, :]
    return buffer.at[index[:, None] + columns].set(value, mode="promise_in_bounds",
                                                   unique_indices=True)


def write_lanes(buffer: Array, index: Array, value: Array, mask: Array) -> Array:
    """Unrolled ``buffer[index[k] + j] = value[k, j]`` where ``mask[k]``, lane by lane.

    Each lane reads what it would overwrite just before writing, so a lane without
    ``mask`` rewrites the value that is there, even one another lane has just written: a
    masked lane may point anywhere (an idle lane of the sequential strategy points past
    its work item's agents, clamped onto the last one's rows)."""
    value = value.astype(buffer.dtype).reshape(index.shape[0], -1)
    for k in range(index.shape[0]):
        start = at_lane(index, k)
        old = _slice(buffer, start, value.shape[1])
        buffer = _update(buffer, jax.lax.select(
            jax.lax.broadcast(at_lane(mask, k), old.shape), at_lane(value, k), old), start)
    return buffer


def put_where(buffer: Array, index: Array, value: Array, mask: Array) -> Array:
    """``buffer[index] = value`` where ``mask``; lanes without it write nothing."""
    if is_unrolled(index):
        return write_lanes(buffer, index, value, mask)
    index = jnp.where(mask, index, buffer.shape[0])  # past the end: dropped
    return buffer.at[index].set(value.astype(buffer.dtype), mode="drop")


def put_learned(buffer: Array, index: Array, new: Array, old: Array, mask: Array,
                rows: bool = False) -> Array:
    """``buffer[index] = new`` where ``mask``, ``old`` (the value read) elsewhere; a few
    lanes write lane by lane, those without ``mask`` nothing (see :func:`write_lanes`)."""
    if is_unrolled(index):
        return write_lanes(buffer, index, new, mask)
    kept = jnp.where(mask.reshape(mask.shape + (1,) * (new.ndim - 1)), new, old)
    return _scatter(buffer, index, kept, rows)


def rows_of(tables: dict, specs: dict, state: Array, pair_base: Array, state_base: Array,
            num_actions: int) -> dict:
    """The values of ``specs``' tables at ``state`` per lane: a scalar of a per-state
    table, an ``[A]`` row of a per-(state, action) one."""
    A = num_actions
    return {name: (take(tables[name], state_base + state) if spec.per == "state"
                   else take_row(tables[name], pair_base + state * A, A))
            for name, spec in specs.items()}


def learner_rows(buffer: Array, index: Array, count: int, spec: Any) -> Array:
    """A learner table's (``spec``, a :class:`~vdbejax.methods.contract.Table`) ``count``
    consecutive pairs from pair ``index`` per lane: ``[B]`` (one pair of a per-pair
    table), ``[B, count]`` or, for a stage table of ``length`` entries per pair,
    ``[B, length]`` / ``[B, count, length]``."""
    if spec.per != "stage":
        return take(buffer, index) if count == 1 else take_row(buffer, index, count)
    width = spec.width()
    rows = take_row(buffer, index * width, count * width)
    return rows if count == 1 else rows.reshape(-1, count, width)
