"""Float arithmetic that gives the same bits in every compiled program.

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
    return product + factor * 0.0
