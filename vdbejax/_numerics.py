"""Float arithmetic that gives the same bits in every compiled program, and the one
categorical draw that tasks, the engine and explorers share.

XLA's CPU compiler always lets LLVM fuse a multiply and a following add into one FMA
(one rounding instead of two), and whether LLVM does depends on the code around them:
the vector body or the scalar remainder of a loop, one fusion or another, which other
branches a program kept. The same update could then round differently in the sequential
and the lockstep engine, in a batch of one or of many, or in a program specialised for
one kind of agent. :func:`rounded` makes a product round on its own before it is added,
in every program, so each agent's results depend only on its key and hyperparameters.
"""
from __future__ import annotations

import jax
import jax.numpy as jnp

Array = jax.Array


def rounded(product: Array, factor: float | Array) -> Array:
    """``product``, rounded to float32 before any later addition (never part of an FMA).

    Adding ``factor · 0`` — zero for the finite ``factor`` of the product, and a value the
    compiler cannot fold away — puts an addition between the multiply and its consumer:
    LLVM may fuse that addition with the multiply, but an FMA with a zero addend rounds
    exactly like the multiply alone.

    Args:
      product: a product ``factor · x`` (any shape).
      factor: one finite factor of it, broadcastable to ``product``.

    Returns:
      ``product`` (bit for bit, up to the sign of a zero).
    """
    if (isinstance(product, jax.Array) and isinstance(factor, jax.Array)
            and factor.dtype == product.dtype and factor.ndim in (0, product.ndim)
            and factor.shape in ((), product.shape)):
        # The same two operations, as lax's primitives: traced several times faster.
        return jax.lax.add(product, jax.lax.mul(factor, jnp.zeros((), factor.dtype)))
    return product + factor * 0.0


#: sample_categorical unrolls its prefix sums up to this many categories.
_UNROLLED_CDF_MAX = 32


def sample_categorical(weights: Array, u: Array) -> Array:
    """Inverse-CDF sample from unnormalised non-negative ``weights`` with one uniform.

    Args:
      weights: ``[n, batch...]`` non-negative weights, positive sum along axis 0.
      u: uniforms in [0, 1), shape ``[batch...]``.

    Returns:
      int32 ``[batch...]`` index ``i`` with probability ``weights[i] / sum(weights)``; an
      index of zero weight is never returned. Weights that are no distribution (a NaN,
      all zero, one infinite) give ``n``, an invalid index, which the engine flags as
      non-finite (``nonfinite_agents``) instead of silently taking some action.
    """
    n = weights.shape[0]
    # u has a 23-bit mantissa, so u * total < total and the count stays < n.
    if n > _UNROLLED_CDF_MAX:
        cdf = jnp.cumsum(weights, axis=0)
        threshold = u * cdf[-1]
        # Weights shared by a batch of uniforms ([n] against [batch]): compare per column.
        batch_dims = threshold.ndim - (cdf.ndim - 1)
        cdf = cdf.reshape(cdf.shape[:1] + (1,) * batch_dims + cdf.shape[1:])
        return n - jnp.sum(cdf > threshold, axis=0, dtype=jnp.int32)
    # Left-to-right prefix sums, unrolled: for the few actions of a tabular task this is
    # much cheaper on CPU than XLA's reduce-window cumsum. Written with lax's primitives,
    # the categories split off in one operation and the prefix sums compared at once (a
    # dozen operations to trace instead of four per category: every explorer of a
    # program draws through here).
    weights = jnp.asarray(weights)
    parts = jax.lax.split(weights, (1,) * n) if n > 1 else [weights]
    partial = [parts[0]]
    for part in parts[1:]:
        partial.append(jax.lax.add(partial[-1], part))
    total = jax.lax.squeeze(partial[-1], (0,))
    threshold = u * total  # u's and the weights' common type and shape
    cdf = jax.lax.concatenate(partial, 0)
    if cdf.dtype != threshold.dtype:
        cdf = jax.lax.convert_element_type(cdf, threshold.dtype)
    if cdf.shape[1:] != threshold.shape:  # weights shared by a batch: trailing axes align
        cdf = jax.lax.broadcast_in_dim(cdf, (n, *threshold.shape), (0, *range(
            1 + threshold.ndim - (cdf.ndim - 1), 1 + threshold.ndim)))
    above = jax.lax.gt(cdf, jax.lax.broadcast_in_dim(
        threshold, cdf.shape, tuple(range(1, cdf.ndim))))
    # n minus the prefix sums above the threshold: the same index for real weights, and n
    # (invalid, flagged by the engine) when a NaN makes every comparison false.
    count = jax.lax.reduce_sum(jax.lax.convert_element_type(above, jnp.int32), (0,))
    return jax.lax.sub(jnp.int32(n), count)
