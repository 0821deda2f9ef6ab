"""Compiled programs of the engine, kept in memory and, between processes, on disk.

JAX's persistent compilation cache (``jax_compilation_cache_dir``) spares a new process
XLA's compilation, but not tracing and lowering (≈ 40 ms per engine program). :func:`compiled`
also keeps each serialised executable next to JAX's cache
(``<cache dir>/vdbejax-executables``). Its key covers everything the program depends on,
so an entry is never served for other code:

* what runs. When every class in the arguments is vdbejax's own (built-in explorers and
  learners), the code that runs is vdbejax's: the key holds a fingerprint of vdbejax's
  source files and of its *live* code (the bytecode and simple globals of every function
  and class of its loaded modules, so an edit or a monkeypatch gives new keys), and a warm
  process neither traces nor lowers. Otherwise (a user's plug-in anywhere in the
  arguments) the program is traced and the key holds its jaxpr and the bytes of its
  constants — whatever the user's code does, edited or not;
* the function (module and name) and its static arguments;
* the argument signature: tree structure (static fields included), shapes, dtypes, weak
  types and shardings;
* the per-compilation XLA options;
* jax and jaxlib versions, the backend, its version and devices, ``XLA_FLAGS`` and the JAX
  options that change lowering.

The disk copy is used only in processes that see one device: an executable serialised in
a process with several (e.g. ``--xla_force_host_platform_device_count=4``) fails to run
when loaded again; multi-device runs rely on JAX's own cache. It is used only where JAX's
persistent cache is on (the CLI and the benchmarks turn it on);
``VDBEJAX_EXECUTABLE_CACHE=off`` keeps JAX's cache but not this one. A file that cannot be
read (truncated, another jaxlib) is ignored and rewritten.
"""
from __future__ import annotations

import contextlib
import hashlib
import os
import pickle
import tempfile
import threading
import time
from concurrent.futures import ThreadPoolExecutor
import warnings
from functools import lru_cache
from pathlib import Path
from typing import Any

import jax
import numpy as np

#: In-process table: (function, static arguments, signature) -> executable.
_EXECUTABLES: dict[Any, Any] = {}
#: Seconds spent getting executables: tracing, lowering, compiling or loading.
_SECONDS = [0.0]
#: Executables loaded from / written to the disk copy in this process.
_DISK = {"loaded": 0, "stored": 0, "write_failed": 0}
#: Guards the counters above (several threads get executables: :func:`compiled_all`).
_LOCK = threading.Lock()
#: Held while JAX's persistent cache is switched off (a process-wide setting).
_CACHE_OFF_LOCK = threading.Lock()
#: JAX options that change what a function lowers to.
_LOWERING_OPTIONS = (
    "jax_enable_x64",
    "jax_default_prng_impl",
    "jax_threefry_partitionable",
    "jax_numpy_dtype_promotion",
    "jax_default_matmul_precision",
    "jax_enable_checks",
    "jax_debug_nans",
    "jax_debug_infs",
)
_FOLDER_NAME = "vdbejax-executables"


def _dtype_str(x: Any) -> str:
    dtype = getattr(x, "dtype", None)
    return np.dtype(dtype if dtype is not None else np.result_type(x)).str


def signature(args: Any) -> tuple:
    """Hashable description of ``args`` that fixes the program compiled for them."""
    leaves, treedef = jax.tree.flatten(args)
    # Sharding is part of it: an executable compiled for one layout must not run arrays
    # laid out differently.
    return treedef, tuple(
        (np.shape(x), _dtype_str(x), bool(getattr(x, "weak_type", False)), _placement(x))
        for x in leaves
    )


def _placement(x: Any) -> Any:
    """``x``'s sharding; ``None`` for host values and arrays on the default device alone
    (what a program compiled from shapes alone expects)."""
    sharding = getattr(x, "sharding", None)
    if sharding is not None and sharding.device_set == {jax.devices()[0]}:
        return None
    return sharding


def _abstract(args: Any) -> Any:
    """``args`` as ``jax.ShapeDtypeStruct``s (enough to compile the same program again)."""
    return jax.tree.map(
        lambda x: jax.ShapeDtypeStruct(np.shape(x), np.dtype(_dtype_str(x)),
                                       weak_type=bool(getattr(x, "weak_type", False))),
        args,
    )


def _node_types(treedef: Any) -> tuple:
    """The classes of a tree's nodes (JAX's treedefs of two dataclasses with the same
    field names compare equal: the in-process key must tell them apart)."""
    data = treedef.node_data()
    return (data[0] if data else None, tuple(_node_types(c) for c in treedef.children()))


def call_key(function: Any, args: tuple, static: dict[str, Any],
             compiler_options: dict[str, Any] | None = None) -> tuple:
    """The in-process table's key of a :func:`compiled` call."""
    options = dict(sorted((compiler_options or {}).items()))
    sig = signature(args)
    return (function, tuple(sorted(static.items())), sig, _node_types(sig[0]),
            tuple(options.items()))


def compiled(function: Any, args: tuple, static: dict[str, Any],
             compiler_options: dict[str, Any] | None = None) -> Any:
    """``function``'s executable for ``args`` (explicit ``trace().lower().compile()``, cached).

    Looked up in this process's table, then in the disk copy (module docstring), else
    lowered and compiled (a JAX persistent-cache read where that is warm) and kept. Call
    the result with ``args`` only: the static arguments are baked in.

    Args:
      function: a ``jax.jit``-wrapped function defined in vdbejax.
      args: its positional arguments (arrays or ``jax.ShapeDtypeStruct``).
      static: its static keyword arguments.
      compiler_options: per-compilation XLA options.

    Returns:
      the compiled executable.
    """
    executable = _EXECUTABLES.get(call_key(function, args, static, compiler_options))
    if executable is not None:  # the common case: not timed, nothing else to do
        return executable
    return compiled_all([(function, args, static, compiler_options)], threads=1)[0]


def _stored(function: Any, args: tuple, static: dict[str, Any],
            compiler_options: dict[str, Any] | None, live: str) -> tuple[Any, tuple | None]:
    """``(executable, None)`` from this process's table or the disk copy, else
    ``(None, miss)``: what :func:`_compile_miss` needs to compile it (``live``: the
    :func:`live_fingerprint` of vdbejax's code, computed once per batch of calls)."""
    key = call_key(function, args, static, compiler_options)
    executable = _EXECUTABLES.get(key)
    if executable is not None:
        return executable, None
    options = dict(key[4])
    traced = None if _vdbejax_only(key[3]) else function.trace(*args, **static)
    path = _disk_path(function, static, key[2], options, traced, live)
    executable = _load(path) if path is not None else None
    if executable is None:
        return None, (key, traced or function.trace(*args, **static), path, options)
    shapes = _abstract(args)  # not the arrays: the entry must not keep them alive
    executable = _FromDisk(executable, path, key,
                           lambda: _compile(function.trace(*shapes, **static), options))
    _EXECUTABLES[key] = executable
    return executable, None


def _compile_miss(miss: tuple) -> Any:
    """Compile a :func:`_stored` miss, keep it, and store it on disk where it has a path."""
    key, traced, path, options = miss
    executable = _compile(traced, options)
    if path is not None:
        _store(path, executable)
    _EXECUTABLES[key] = executable
    return executable


def compiled_all(calls: list[tuple], threads: int) -> list[Any]:
    """:func:`compiled` for each ``(function, args, static, compiler_options)``, on up to
    ``threads`` threads (loading a stored program and compiling one mostly run outside
    the GIL); the wall time is what :func:`compile_seconds` counts."""
    started = time.perf_counter()
    pool = (ThreadPoolExecutor(max_workers=min(threads, len(calls)))
            if threads > 1 and len(calls) > 1 else None)
    each = map if pool is None else pool.map
    try:
        live = live_fingerprint()  # ≈ 3 ms of the GIL's time: once, not once per call
        found = list(each(lambda call: _stored(*call, live), calls))
        executables = [executable for executable, _ in found]
        misses = [k for k, (executable, _) in enumerate(found) if executable is None]
        # The misses to store on disk are compiled afresh, not read from JAX's cache:
        # XLA's CPU backend serialises an executable it loaded from a cache (or compiled
        # again after loading it) incompletely, and the copy would fail to run (kernels
        # "not found"). This costs one full compilation per program when JAX's cache had
        # it but the disk copy not. The others may come from JAX's cache.
        for stored in (False, True):
            group = [k for k in misses if (found[k][1][2] is not None) == stored]
            if group:
                with _jax_cache_off() if stored else contextlib.nullcontext():
                    fresh = list(each(_compile_miss, [found[k][1] for k in group]))
                for k, executable in zip(group, fresh):
                    executables[k] = executable
    finally:
        if pool is not None:
            pool.shutdown()
    with _LOCK:
        _SECONDS[0] += time.perf_counter() - started
    return executables


def _compile(traced: Any, options: dict[str, Any]) -> Any:
    lowered = traced.lower()
    _strip_locations(lowered)
    return lowered.compile(options) if options else lowered.compile()


def _strip_locations(lowered: Any) -> None:
    """Drop the source locations and name stacks from ``lowered``'s module, in place.

    XLA keeps them as every instruction's metadata: ≈ 25 % of the bytes of the engine's
    stored programs and ≈ 15 % of the time a process takes to load them. The machine code
    is the same. The module is JAX's own (its cache of this lowering then holds the
    stripped module, which compiles to the same program); where it cannot be changed in
    place (another JAX), it compiles as it is.
    """
    try:
        from jax.extend.mlir import passmanager

        module = lowered.compiler_ir("stablehlo")
        with module.context:
            passmanager.PassManager.parse("builtin.module(strip-debuginfo)").run(
                module.operation)
    except Exception:  # noqa: BLE001  (only a smaller program is lost)
        return


class _jax_cache_off:  # noqa: N801  (a context manager, named like one)
    """JAX's persistent cache switched off for the compilations inside (process-wide: a
    JAX setting; entered by one caller at a time, others wait)."""

    def __enter__(self) -> None:
        from jax.experimental.compilation_cache import compilation_cache as jax_cache

        _CACHE_OFF_LOCK.acquire()
        self.enabled = jax.config.jax_enable_compilation_cache
        jax.config.update("jax_enable_compilation_cache", False)
        jax_cache.reset_cache()  # JAX decides once whether to use its cache: ask again

    def __exit__(self, *exc: Any) -> None:
        from jax.experimental.compilation_cache import compilation_cache as jax_cache

        try:
            jax.config.update("jax_enable_compilation_cache", self.enabled)
            jax_cache.reset_cache()
        finally:
            _CACHE_OFF_LOCK.release()


class _FromDisk:
    """An executable from the disk copy; should it fail to run, it is replaced.

    A bad entry (see :func:`compiled`) fails before computing anything, with a
    "not found" error. The entry is then deleted and the program compiled and run
    again. The engine's calls are safe to repeat: their donated arguments are
    device copies of host arrays made by the call itself.
    """

    def __init__(self, executable: Any, path: Path, key: Any, recompile: Any) -> None:
        self._executable, self._path, self._key, self._recompile = executable, path, key, recompile
        self._trusted = False

    def __call__(self, *args: Any) -> Any:
        if self._trusted:
            return self._executable(*args)
        try:
            result = self._executable(*args)
        except Exception as error:
            if "not found" not in str(error).lower():
                raise
            self._path.unlink(missing_ok=True)
            self._executable = self._recompile()
            _EXECUTABLES[self._key] = self._executable
            result = self._executable(*args)
        self._trusted = True
        return result

    def __getattr__(self, name: str) -> Any:
        return getattr(self._executable, name)


def compile_seconds() -> float:
    """Seconds this process spent getting the engine's executables (cumulative)."""
    return _SECONDS[0]


def disk_counts() -> dict[str, int]:
    """Executables this process loaded from and wrote to the disk copy."""
    return dict(_DISK)


def disk_folder() -> Path | None:
    """Folder of the disk copy, or ``None`` when it is off (module docstring)."""
    if os.environ.get("VDBEJAX_EXECUTABLE_CACHE", "").lower() == "off":
        return None
    root = jax.config.jax_compilation_cache_dir
    return Path(root) / _FOLDER_NAME if root else None


@lru_cache(maxsize=1)
def source_fingerprint() -> str:
    """SHA-256 over the paths and contents of vdbejax's ``.py`` files."""
    package = Path(__file__).resolve().parent
    digest = hashlib.sha256()
    for path in sorted(package.rglob("*.py")):
        digest.update(path.relative_to(package).as_posix().encode())
        digest.update(b"\0")
        digest.update(path.read_bytes())
        digest.update(b"\0")
    return digest.hexdigest()


def _environment() -> list[str]:
    """Everything outside the call that changes the compiled program."""
    import jaxlib

    devices = jax.devices()
    backend = devices[0].client
    return [
        jax.__version__,
        jaxlib.__version__,
        backend.platform,
        backend.platform_version,
        repr([(d.id, d.device_kind) for d in devices]),
        os.environ.get("XLA_FLAGS", ""),
        repr([(name, getattr(jax.config, name, None)) for name in _LOWERING_OPTIONS]),
        source_fingerprint(),
    ]


def _vdbejax_only(types: tuple) -> bool:
    """Whether every class in a tree of node types (:func:`_node_types`) is vdbejax's or a
    Python container."""
    node, children = types
    if node is not None and node not in (tuple, list, dict, type(None)) and not getattr(
            node, "__module__", "").startswith("vdbejax."):
        return False
    return all(_vdbejax_only(child) for child in children)


#: Digest of each code object seen (code objects are immutable; the key keeps it alive).
_CODE_DIGESTS: dict[Any, str] = {}
_SIMPLE = (bool, int, float, str, bytes, type(None))


def _plain_repr(value: Any) -> str:
    """``repr`` without memory addresses or hash-seed-dependent orders."""
    if hasattr(value, "co_code"):
        return _code_digest(value)
    if isinstance(value, _SIMPLE):
        return repr(value)
    if isinstance(value, (tuple, list)):
        return "(" + ",".join(_plain_repr(v) for v in value) + ")"
    if isinstance(value, (frozenset, set)):
        return "{" + ",".join(sorted(_plain_repr(v) for v in value)) + "}"
    if isinstance(value, dict):
        return "{" + ",".join(sorted(f"{_plain_repr(k)}:{_plain_repr(v)}" for k, v in value.items())) + "}"
    return f"<{type(value).__module__}.{type(value).__qualname__}>"


def _code_digest(code: Any) -> str:
    digest = _CODE_DIGESTS.get(code)
    if digest is None:
        parts = [code.co_code.hex(), repr(code.co_names)]
        parts += [_plain_repr(c) for c in code.co_consts]
        digest = hashlib.sha256("\0".join(parts).encode()).hexdigest()
        _CODE_DIGESTS[code] = digest
    return digest


def _value_digest(value: Any) -> str | None:
    """What a module or class attribute contributes to :func:`live_fingerprint`."""
    for wrapper in ("__func__", "fget"):  # staticmethod/classmethod, property
        value = getattr(value, wrapper, value)
    code = getattr(value, "__code__", None)
    if code is not None:
        defaults = (getattr(value, "__defaults__", None), getattr(value, "__kwdefaults__", None))
        inner = getattr(value, "__wrapped__", None)  # jax.jit and functools.wraps
        return (_code_digest(code) + _plain_repr(defaults)
                + (_value_digest(inner) or "" if inner is not None else ""))
    inner = getattr(value, "__wrapped__", None)
    if inner is not None:
        return _value_digest(inner)
    if isinstance(value, _SIMPLE) or (isinstance(value, tuple) and all(
            isinstance(v, _SIMPLE) for v in value)):
        return repr(value)
    return None


def _live_objects() -> list[tuple[str, Any]]:
    """``(qualified name, object)`` of every attribute of vdbejax's loaded modules and of
    the classes they define."""
    import sys

    objects = []
    for name in sorted(n for n in list(sys.modules) if n == "vdbejax" or n.startswith("vdbejax.")):
        for attr, value in sorted(vars(sys.modules[name]).items()):
            objects.append((f"{name}.{attr}", value))
            if isinstance(value, type) and value.__module__ == name:
                objects += [(f"{name}.{attr}.{k}", v) for k, v in sorted(vars(value).items())]
    return objects


#: ``[identities of the live objects, their fingerprint, the objects]`` of the last
#: computation (holding the objects keeps their ids from being reused).
_LIVE: list[Any] = [None, "", None]


def live_fingerprint() -> str:
    """SHA-256 of vdbejax's loaded code as it is now: every function and class of its
    modules (bytecode, defaults), their simple constants, and what is bound to each name.

    Recomputed only when a name is bound to another object (an import, an edit reloaded,
    a monkeypatch): otherwise the identities of the objects match the last computation's.
    """
    objects = _live_objects()
    identity = [(name, id(value)) for name, value in objects]
    if identity == _LIVE[0]:
        return _LIVE[1]
    digest = hashlib.sha256()
    for name, value in objects:
        text = _value_digest(value)
        if text is None:
            text = f"{type(value).__module__}.{type(value).__qualname__}"
        digest.update(f"{name}={text}\n".encode())
    _LIVE[:] = [identity, digest.hexdigest(), objects]
    return _LIVE[1]


def program_text(traced: Any) -> str:
    """The traced program as text: its jaxpr and a digest of its constants' bytes."""
    closed = traced.jaxpr
    digest = hashlib.sha256()
    for const in closed.consts:
        value = np.asarray(const)
        digest.update(f"{value.dtype.str}{value.shape}".encode())
        digest.update(value.tobytes())
    return f"{closed.jaxpr}\nconsts {digest.hexdigest()}"


def disk_key(function: Any, static: dict[str, Any], sig: tuple,
             options: dict[str, Any], program: str = "") -> str:
    """Hex key of the disk copy (module docstring lists what goes into it)."""
    treedef, leaves = sig
    parts = [
        program,
        f"{function.__module__}.{function.__qualname__}",
        repr(sorted(static.items())),
        str(treedef),
        repr(leaves),
        repr(sorted(options.items())),
        *_environment(),
    ]
    return hashlib.sha256("\n".join(parts).encode()).hexdigest()


def _disk_path(function: Any, static: dict[str, Any], sig: tuple,
               options: dict[str, Any], traced: Any, live: str) -> Path | None:
    folder = disk_folder()
    if folder is None or not getattr(function, "__module__", "").startswith("vdbejax."):
        return None
    if jax.device_count() > 1:
        return None  # see the module docstring: left to JAX's own cache
    program = live if traced is None else program_text(traced)
    return folder / f"{disk_key(function, static, sig, options, program)}.pkl"


def _load(path: Path) -> Any:
    """The executable stored at ``path``, or ``None`` (absent or unreadable)."""
    from jax.experimental.serialize_executable import deserialize_and_load

    try:
        payload, in_tree, out_tree = pickle.loads(path.read_bytes())
        executable = deserialize_and_load(payload, in_tree, out_tree)
    except Exception:  # noqa: BLE001  (absent, truncated, another jaxlib: compile again)
        return None
    with _LOCK:
        _DISK["loaded"] += 1
    return executable


def _store(path: Path, executable: Any) -> None:
    """Write ``executable`` to ``path`` atomically; failures only cost a later recompile."""
    from jax.experimental.serialize_executable import serialize

    try:
        data = pickle.dumps(serialize(executable))
    except Exception:  # noqa: BLE001  (not serialisable: it is compiled again next time)
        return
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        with tempfile.NamedTemporaryFile(dir=path.parent, suffix=".tmp", delete=False) as handle:
            handle.write(data)
        os.replace(handle.name, path)
    except OSError as error:
        if not _DISK["write_failed"]:
            warnings.warn(f"vdbejax: cannot store compiled programs in {path.parent} ({error}); "
                          "later runs will trace and lower them again", RuntimeWarning,
                          stacklevel=3)
        _DISK["write_failed"] += 1
        return
    with _LOCK:
        _DISK["stored"] += 1
