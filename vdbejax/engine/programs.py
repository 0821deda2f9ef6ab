"""The engine's compiled programs: traced once per process, compiled once per lowered module.

A program is traced and lowered the first time a call needs it in this process, and kept
(:data:`MAX_PROGRAMS` programs, least recently used dropped first) under its *trace key*
(:meth:`Call.trace_key`): the engine function, its static arguments and options, the
arguments' tree (node types and static fields included), shapes, dtypes and placement,
every class attribute and method of the plug-in classes in that tree (so
``Cls.method = new``, a redefined class or an edited and reloaded module is traced afresh)
and JAX's configuration. What is fixed when a program is traced, as under ``jax.jit``: a
module-level global read inside a plug-in or a helper it calls. After patching one,
:func:`forget_traced_programs` makes the next run trace again.

Compilation is keyed by the lowered program itself: the SHA-256 of its lowered StableHLO
module's text (its complete text: computation, constants, shardings, donation), the
compiler options and the node types of its input and output trees
(:func:`program_key`); in this process from a bounded table, between processes from JAX's
persistent compilation cache (whose key is the lowered module too; vdbejax turns it on,
see :mod:`vdbejax._jax_cache`). A new process therefore traces its programs
from the code as it is then, and never runs a program traced from older code.
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

_TABLE: OrderedDict[tuple, Any] = OrderedDict()  # program_key -> compiled program
_TRACED: OrderedDict[tuple, Any] = OrderedDict()  # Call.trace_key -> compiled program
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

    def trace_key(self) -> tuple:
        """What fixes the traced program in this process: :meth:`signature`, the code of
        the plug-in classes in the arguments' tree and JAX's configuration."""
        signature = self.signature()
        treedef = signature[4]  # the arguments' tree, flattened once
        return (signature, plugin_code(treedef), _jax_settings())


def plugin_code(treedef: Any) -> tuple:
    """Every attribute of every class a tree's program is traced from: its node types,
    the types of their static fields, and their base classes (methods are compared as
    function objects, so assigning a new one changes the result)."""
    classes: dict[type, None] = {}

    def visit(node: Any) -> None:
        data = node.node_data()
        if data is not None:
            classes.setdefault(data[0])
            _static_types(data[1], classes)
        for child in node.children():
            visit(child)

    visit(treedef)
    mro = dict.fromkeys(base for cls in classes for base in cls.__mro__
                        if base.__module__ != "builtins")
    return tuple((base, tuple((name, _hashable(value)) for name, value in vars(base).items()))
                 for base in mro)


def _static_types(value: Any, classes: dict[type, None]) -> None:
    """The classes of a node's static data (a tuple of field values, dict keys, None)."""
    if isinstance(value, tuple | list):
        for item in value:
            _static_types(item, classes)
    elif value is not None and type(value).__module__ != "builtins":
        classes.setdefault(type(value))


def _hashable(value: Any) -> Any:
    """``value`` if it can be a key, else its identity (mutating it in place is, like a
    module global, fixed when traced)."""
    try:
        hash(value)
    except TypeError:
        return ("id", id(value))
    return value


def _jax_settings() -> tuple:
    """JAX's configuration as it is now (thread-local overrides such as ``enable_x64``
    included): tracing depends on some of it."""
    return tuple(sorted((name, _hashable(value)) for name, value in jax.config.values.items()))


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
    """The compiled program of each call: found by its :meth:`Call.trace_key` among the
    programs traced in this process, else traced and lowered here, in order (tracing
    holds the GIL), then looked up by :func:`program_key` or compiled on up to ``threads``
    threads (compiling and reading JAX's cache mostly run outside the GIL)."""
    started = time.perf_counter()
    trace_keys = [call.trace_key() for call in calls]
    with _TABLE_LOCK:
        found = [_recent(_TRACED, key) for key in trace_keys]
    todo = [k for k, executable in enumerate(found) if executable is None]
    if todo:
        fresh = _lower_and_compile([calls[k] for k in todo], threads)
        with _TABLE_LOCK:
            for k, executable in zip(todo, fresh, strict=True):
                found[k] = executable
                _keep(_TRACED, trace_keys[k], executable)
    with _TABLE_LOCK:
        _SECONDS[0] += time.perf_counter() - started
    return found


def _recent(table: OrderedDict[tuple, Any], key: tuple) -> Any:
    """``table[key]`` marked as the most recently used, or None."""
    value = table.get(key)
    if value is not None:
        table.move_to_end(key)
    return value


def _keep(table: OrderedDict[tuple, Any], key: tuple, value: Any) -> None:
    table[key] = value
    table.move_to_end(key)
    while len(table) > MAX_PROGRAMS:
        table.popitem(last=False)


def _lower_and_compile(calls: Sequence[Call], threads: int) -> list[Any]:
    """Each call traced and lowered, then its compiled program found by
    :func:`program_key` or compiled."""
    lowered = [_lower(call) for call in calls]
    keys = [program_key(low, call.options) for low, call in zip(lowered, calls, strict=True)]
    with _TABLE_LOCK:
        found = [_recent(_TABLE, key) for key in keys]
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
                _keep(_TABLE, keys[k], executable)
        by_key = dict(zip((keys[k] for k in misses), fresh, strict=True))
        found = [by_key[key] if executable is None else executable
                 for key, executable in zip(keys, found, strict=True)]
    return found


def forget_traced_programs() -> None:
    """Trace every program again at its next use in this process (after patching a
    module-level global that a plug-in or helper reads; programs compiled from the same
    lowered text are still reused)."""
    with _TABLE_LOCK:
        _TRACED.clear()


class Programs:
    """The programs of one run, each looked up once per signature (:meth:`Call.signature`):
    a loop of chunks or blocks gets its program once (:func:`compile_all` keys the
    process's programs by :meth:`Call.trace_key`)."""

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
