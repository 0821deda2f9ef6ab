"""XLA settings the CPU engine needs, applied before JAX starts its backend.

The CPU engine (:func:`vdbejax.engine.run_agents`, strategy ``"sequential"``) runs each
agent's step loop as a ``while`` loop over scalars. XLA's CPU backend compiles such a loop
into one native function only when its estimated memory traffic is below
``xla_cpu_small_while_loop_byte_threshold`` (1 kB by default, smaller than one Q-table);
above it, every one of the ~30 operations of a step is dispatched separately, about 8×
slower. The threshold is a process-wide XLA flag, read once when JAX initialises its
backend, so it is added to ``XLA_FLAGS`` when :mod:`vdbejax` is imported:

* a value the user already set in ``XLA_FLAGS`` is kept;
* ``VDBEJAX_XLA_FLAGS=off`` leaves ``XLA_FLAGS`` alone;
* if JAX already ran a computation before the import, the flag comes too late: the
  engine then warns once and falls back to its lockstep strategy (same results, slower;
  see :func:`vdbejax.engine.native_step_loops`).

Importing jax before vdbejax costs nothing (``import jax; import vdbejax`` keeps the
native loops): only a computation run before the import starts the backend. The option
cannot be given per compilation instead: ``xla_backend_extra_options`` is a map, and
``lowered.compile({"xla_backend_extra_options": ...})`` is refused by XLA ("not a valid
message value", jax 0.10.2, for every text form tried), so it stays a process-wide flag.

Raising the threshold only changes how XLA compiles small while loops (one native
function instead of per-operation dispatch); it does not change what they compute.
"""
from __future__ import annotations

import os

#: Estimated bytes below which XLA's CPU backend compiles a while loop natively: 1 TiB,
#: i.e. no limit in practice (a 10×3 task variant's tables and Q-table exceed 1 GiB).
SMALL_WHILE_LOOP_BYTES = 1 << 40
_OPTION = "xla_cpu_small_while_loop_byte_threshold"
_EXTRA = "--xla_backend_extra_options="


def with_small_loop_threshold(flags: str, threshold: int = SMALL_WHILE_LOOP_BYTES) -> str:
    """``flags`` (an ``XLA_FLAGS`` value) with the small-while-loop threshold added.

    Args:
      flags: the current ``XLA_FLAGS`` string (may be empty).
      threshold: bytes.

    Returns:
      the new string; unchanged if it already sets the threshold. An existing
      ``--xla_backend_extra_options=...`` gets the option appended to its list.
    """
    if _OPTION in flags:
        return flags
    option = f"{_OPTION}={threshold}"
    parts = flags.split()
    for i, part in enumerate(parts):
        if part.startswith(_EXTRA):
            parts[i] = part + ("," if part != _EXTRA else "") + option
            return " ".join(parts)
    return " ".join([*parts, _EXTRA + option])


def apply() -> None:
    """Add the threshold to ``os.environ["XLA_FLAGS"]`` unless ``VDBEJAX_XLA_FLAGS=off``."""
    if os.environ.get("VDBEJAX_XLA_FLAGS", "").strip().lower() == "off":
        return
    os.environ["XLA_FLAGS"] = with_small_loop_threshold(os.environ.get("XLA_FLAGS", ""))

