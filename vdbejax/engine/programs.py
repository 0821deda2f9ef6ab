"""The engine's compiled programs, keyed by the lowered program itself.

Every :func:`run_agents <vdbejax.engine.run_agents>` call traces and lowers the programs it
runs, from a fresh ``jax.jit`` wrapper (so that neither JAX's trace cache nor ours can
serve a program traced from code that has since been patched, reloaded or edited). A
program is identified by the SHA-256 of its lowered StableHLO module's text (its
complete text: computation, constants, shardings, donation), the compiler
options, and the node types of its input and output trees. What runs is therefore the
code as it is at the call, by construction.

Compilation is what the key spares: in this process from a bounded table
(:data:`MAX_PROGRAMS` programs, least recently used dropped first), between processes from
JAX's persistent compilation cache (whose key is the lowered module too; vdbejax turns it
on, see :func:`vdbejax.enable_compilation_cache`). Within one run, :class:`Programs`
remembers each program by its call's signature, so that a loop of chunks or blocks
traces it once.
"""
from __future__ import annotations

import functools
import hashlib
import threading
import time
from collections import OrderedDict
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from typing import Any

import jax
import numpy as np

#: Compiled programs kept in this process (each holds its machine code; a run of the
#: paper grid uses 10).
MAX_PROGRAMS = 64

_TABLE: OrderedDict[tuple, Any] = OrderedDict()
_TABLE_LOCK = threading.Lock()
#: Seconds spent getting programs (tracing, lowering, compiling or loading them).
_SECONDS = [0.0]


#: Per-compilation XLA options of every engine program on a CPU backend. No YNNPACK
#: fusions: XLA offloads large reductions (a ``[4, 6, 200]`` stage row of UCB-H with
#: four lanes) to YNNPACK, whose fusions the CPU backend cannot put inside a native
#: ``while`` loop, so the whole step loop fell back to per-operation dispatch; and both
#: strategies then reduce with XLA's own loops, in one order.
CPU_ENGINE_OPTIONS: dict[str, Any] = {"xla_cpu_experimental_ynn_fusion_type": ""}


def backend_options() -> dict[str, Any]:
    """The engine's per-compilation options for the default backend."""
    return dict(CPU_ENGINE_OPTIONS) if jax.default_backend() == "cpu" else {}


class Call:
    """One program to get: a plain function, its arguments and how to jit it.

    ``function`` is called as ``function(*args, **static)``; ``static`` are its static
    keyword arguments, ``donate`` the names of arguments whose buffers it may reuse,
    ``options`` per-compilation XLA options.
    """

    __slots__ = ("args", "donate", "function", "options", "static")

    def __init__(self, function: Callable[..., Any], args: tuple,
                 static: dict[str, Any] | None = None, *, donate: Sequence[str] = (),
                 options: dict[str, Any] | None = None) -> None:
        self.function, self.args = function, args
        self.static = dict(static or {})
        self.donate = tuple(donate)
        self.options = dict(sorted({**backend_options(), **(options or {})}.items()))

    def signature(self) -> tuple:
        """What fixes the program within one run: the function, its static arguments and
        options, and the arguments' tree (node types included), shapes, dtypes and
        placement."""
        leaves, treedef = jax.tree.flatten(self.args)
        default = {jax.devices()[0]}
        return (self.function, tuple(sorted(self.static.items())), self.donate,
                tuple(self.options.items()), treedef, _node_types(treedef),
                tuple(_leaf_signature(leaf, default) for leaf in leaves))


def _leaf_signature(x: Any, default: set[Any]) -> tuple:
    dtype = getattr(x, "dtype", None)
    sharding = getattr(x, "sharding", None)
    # arrays on the default device alone run the program compiled from shapes alone
    placement = None if sharding is None or sharding.device_set == default else sharding
    return (np.shape(x), np.dtype(dtype if dtype is not None else np.result_type(x)).str,
            bool(getattr(x, "weak_type", False)), placement)


def _node_types(treedef: Any) -> tuple:
    """The classes of a tree's nodes (treedefs of two dataclasses with the same fields can
    compare equal; a program must not be handed another class's tree)."""
    data = treedef.node_data()
    return (data[0] if data else None, tuple(_node_types(c) for c in treedef.children()))


def _lower(call: Call) -> Any:
    """``call`` traced afresh and lowered, source locations stripped."""
    jitted = jax.jit(functools.partial(call.function), static_argnames=tuple(call.static),
                     donate_argnames=call.donate)
    lowered = jitted.trace(*call.args, **call.static).lower()
    _strip_locations(lowered)
    return lowered


def program_key(lowered: Any, options: dict[str, Any]) -> tuple:
    """The key of a lowered program: its module's digest, the compiler options and the
    node types of its input and output trees."""
    module = lowered.compiler_ir("stablehlo")
    digest = hashlib.sha256(module.operation.get_asm(binary=True)).hexdigest()
    return (digest, tuple(sorted(options.items())), lowered.in_tree,
            _node_types(lowered.in_tree), lowered.out_tree, _node_types(lowered.out_tree))


def _strip_locations(lowered: Any) -> None:
    """Drop source locations and name stacks from ``lowered``'s module, in place.

    XLA keeps them as every instruction's metadata (≈ 25 % of a program's bytes and
    ≈ 15 % of the time to load it from JAX's cache); without them the key does not change
    when only line numbers do. The machine code is the same. Where the module cannot be
    changed in place (another JAX), it compiles as it is.
    """
    try:
        from jax.extend.mlir import passmanager

        module = lowered.compiler_ir("stablehlo")
        with module.context:
            passmanager.PassManager.parse("builtin.module(strip-debuginfo)").run(
                module.operation)
    except Exception:  # only a smaller program is lost
        return


def compile_all(calls: Sequence[Call], threads: int = 1) -> list[Any]:
    """The compiled program of each call: traced and lowered here, in order (tracing holds
    the GIL), then looked up by :func:`program_key` or compiled on up to ``threads``
    threads (compiling and reading JAX's cache mostly run outside the GIL)."""
    started = time.perf_counter()
    lowered = [_lower(call) for call in calls]
    keys = [program_key(low, call.options) for low, call in zip(lowered, calls, strict=True)]
    found: list[Any] = []
    with _TABLE_LOCK:
        for key in keys:
            found.append(_TABLE.get(key))
            if found[-1] is not None:
                _TABLE.move_to_end(key)
    misses = sorted({key: k for k, key in enumerate(keys) if found[k] is None}.values())

    def compile_one(k: int) -> Any:
        options = calls[k].options
        return lowered[k].compile(options) if options else lowered[k].compile()

    if misses:
        if threads > 1 and len(misses) > 1:
            with ThreadPoolExecutor(max_workers=min(threads, len(misses))) as pool:
                fresh = list(pool.map(compile_one, misses))
        else:
            fresh = [compile_one(k) for k in misses]
        with _TABLE_LOCK:
            for k, executable in zip(misses, fresh, strict=True):
                _TABLE[keys[k]] = executable
                _TABLE.move_to_end(keys[k])
            while len(_TABLE) > MAX_PROGRAMS:
                _TABLE.popitem(last=False)
        by_key = dict(zip((keys[k] for k in misses), fresh, strict=True))
        found = [by_key[key] if executable is None else executable
                 for key, executable in zip(keys, found, strict=True)]
    with _TABLE_LOCK:
        _SECONDS[0] += time.perf_counter() - started
    return found


class Programs:
    """The programs of one run, each traced once per signature (:meth:`Call.signature`).

    A run creates its own: the next run traces its programs again, so it runs the code
    as it is then.
    """

    def __init__(self) -> None:
        self._memo: dict[tuple, Any] = {}

    def get(self, function: Callable[..., Any], args: tuple,
            static: dict[str, Any] | None = None, *, donate: Sequence[str] = (),
            options: dict[str, Any] | None = None) -> Any:
        """The compiled program of ``function(*args, **static)``; call it with ``args``."""
        return self.get_all([Call(function, args, static, donate=donate, options=options)])[0]

    def get_all(self, calls: Sequence[Call], threads: int = 1) -> list[Any]:
        """:meth:`get` for each call; the new ones compiled on up to ``threads`` threads."""
        signatures = [call.signature() for call in calls]
        new = {sig: call for sig, call in zip(signatures, calls, strict=True)
               if sig not in self._memo}
        if new:
            self._memo.update(zip(new, compile_all(list(new.values()), threads), strict=True))
        return [self._memo[sig] for sig in signatures]


def compile_seconds() -> float:
    """Seconds this process spent getting the engine's programs (cumulative)."""
    return _SECONDS[0]


def cached_programs() -> int:
    """Compiled programs held in this process's table (at most :data:`MAX_PROGRAMS`)."""
    return len(_TABLE)
