"""Side-by-side benchmark: the same work through vdbejax and its peers.

    python -m benchmarks.compare --out benchmarks/RESULTS.md

The work is the paper's full grid (46 settings × 20 seeds × 1000 episodes, spec defaults).
Each peer runs in a fresh subprocess (clean timings and peak memory):

* ``python``: :mod:`benchmarks.python_loop` on ``--python-seeds`` seeds per setting (all
  46 settings); its full-grid time is extrapolated per agent-step (stated in the report).
* ``numba`` (reported as ``numba-1t``): :func:`benchmarks.numba_loop.run_grid`, one thread;
  compile time = the first (tiny) call, cold (empty ``NUMBA_CACHE_DIR``) and warm
  (``cache=True`` hit).
* ``numba_parallel`` (reported as ``numba-<N>t``):
  :func:`benchmarks.numba_loop.run_grid_parallel`, the same per-agent function under
  ``prange`` on ``--threads`` threads (the threads vdbejax gets; default: the CPUs this
  process may use); its own cache directory, cold and warm as above. Bit-identical
  returns to ``numba-1t`` (each agent's random stream depends on its seed alone).
* ``mushroom``: :mod:`benchmarks.mushroom_loop`, MushroomRL's ``QLearning`` / ``SARSA``
  with ``EpsGreedy`` / ``Boltzmann`` through its ``Core``, on ``--mushroom-seeds`` seeds of
  the 22 settings it has an explorer for (no VDBE); its full-grid time is extrapolated per
  agent-step. Skipped (and said so) when mushroom-rl is not installed.
* ``vdbejax``: :func:`vdbejax.engine.run_agents` on ``--threads`` threads; compile time =
  the engine's ``lower().compile()`` time, cold (empty JAX persistent compilation cache)
  and warm (cache filled by the cold run).

Every peer must reproduce vdbejax's learning curves (per-setting mean return over the
first 300 and the last 100 episodes, bootstrap CI of the difference), otherwise its speed
would mean nothing (the verdicts in ``--out``, each setting's differences in
``AGREEMENT.md`` beside it). ``--scaling`` adds throughput and memory against the number of agents
(``--mdp-factory module:function`` swaps the task, e.g. for generated variants).
"""
from __future__ import annotations

import argparse
import datetime
import importlib
import json
import os
import platform
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
DEFAULT_FACTORY = "vdbejax.envs.table_cleaning:make_mdp"
#: A RESULTS.md section from this heading on is hand-written and kept across reruns.
ANALYSIS_HEADING = "## Analysis"
#: The page beside ``--out`` with the peers' per-setting differences to vdbejax.
AGREEMENT = "AGREEMENT.md"


def _peak_rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def _load_factory(spec: str):
    module, _, name = spec.partition(":")
    return getattr(importlib.import_module(module), name)


# --------------------------------------------------------------------------- workers
def _worker_vdbejax(args) -> dict:
    import jax

    jax.config.update("jax_compilation_cache_dir", args.jax_cache)
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0)
    jax.config.update("jax_persistent_cache_min_entry_size_bytes", -1)
    from vdbejax import engine
    from vdbejax.engine import programs
    from vdbejax.methods.agents import make_agent, paper_settings, stack_agents
    from vdbejax.runs import grid_agents

    factory = _load_factory(args.mdp_factory)  # its module's import is not timed either
    rss_import = _peak_rss_mb()
    started = time.perf_counter()
    mdp = factory()
    settings = paper_settings()
    if args.agents:  # scaling: agent i runs setting i mod 46 with its own key
        n = args.agents
        per = stack_agents([make_agent(s) for s in settings])
        index = np.arange(n) % len(settings)
        params = jax.tree.map(lambda leaf: leaf[index], per)
        keys = engine.agent_keys(1, n)
    else:
        params, keys = grid_agents(settings, args.seeds)
    # One study's programs: the scaling rows' second run reuses them (traced once), so
    # that it times the run alone, as its column says.
    study = programs.Programs()
    result = engine.run_agents(mdp, params, keys, args.episodes,
                               engine.EngineOptions(strategy=args.strategy, threads=args.threads,
                                                    programs=study))
    wall = time.perf_counter() - started
    compile_time = engine.compile_seconds()
    steady = None
    if args.agents:  # scaling: time a second, fully compiled run of the same work
        again = time.perf_counter()
        engine.run_agents(mdp, params, keys, args.episodes,
                          engine.EngineOptions(strategy=args.strategy, threads=args.threads,
                                               programs=study))
        steady = time.perf_counter() - again
    return {
        "steady": steady,
        "wall": wall,
        "compile": compile_time,
        "strategy": result.strategy,
        "native": engine.native_step_loops(),
        "programs": programs.cached_programs(),
        "steps": int(result.lengths.sum()),
        "iterations": int(result.iterations),
        "lane_iterations": int(result.lane_iterations),
        "peak_rss_mb": _peak_rss_mb(),
        "rss_after_import_mb": rss_import,
        "returns": result.returns,
        # per agent, for costing a subset of the grid (not kept for the scaling runs)
        "agent_steps": [] if args.agents else result.lengths.sum(axis=1).tolist(),
    }


def _worker_numba(args) -> dict:
    from benchmarks.numba_loop import run_grid
    from vdbejax.methods.agents import paper_settings

    settings = paper_settings()
    started = time.perf_counter()
    run_grid(settings[:1], [0], 1)  # first call: compile, or load from the cache
    compile_time = time.perf_counter() - started
    returns, lengths = run_grid(settings, list(range(args.seeds)), args.episodes)
    wall = time.perf_counter() - started
    return {
        "wall": wall,
        "compile": compile_time,
        "steps": int(lengths.sum()),
        "peak_rss_mb": _peak_rss_mb(),
        "returns": returns.astype(np.float32),
    }


def _worker_numba_parallel(args) -> dict:
    import numba

    from benchmarks.numba_loop import run_grid_parallel
    from vdbejax.methods.agents import paper_settings

    settings = paper_settings()
    started = time.perf_counter()
    run_grid_parallel(settings[:1], [0], 1, threads=args.threads)  # compile or load cache
    compile_time = time.perf_counter() - started
    returns, lengths = run_grid_parallel(settings, list(range(args.seeds)), args.episodes,
                                         threads=args.threads)
    wall = time.perf_counter() - started
    return {
        "wall": wall,
        "compile": compile_time,
        "steps": int(lengths.sum()),
        "threads": args.threads,
        "threading_layer": numba.threading_layer(),
        "peak_rss_mb": _peak_rss_mb(),
        "returns": returns.astype(np.float32),
    }


def _train_each(train_agent, settings, seeds: int, seed_base: int, episodes: int, **kwargs) -> dict:
    """A per-agent peer's loop over settings × seeds: wall time, real steps, returns."""
    started = time.perf_counter()
    returns, steps = [], 0
    for setting in settings:
        for seed in range(seeds):
            r, lengths = train_agent(setting.learner, setting.explorer, setting.param,
                                     1000 * seed + seed_base, episodes, **kwargs)
            returns.append(r)
            steps += sum(lengths)
    return {"wall": time.perf_counter() - started, "compile": 0.0, "steps": steps,
            "peak_rss_mb": _peak_rss_mb(), "returns": np.asarray(returns, np.float32)}


def _worker_mushroom(args) -> dict:
    from benchmarks.mushroom_loop import covered, make_environment, train_agent
    from vdbejax.methods.agents import paper_settings

    started = time.perf_counter()
    env = make_environment()  # from vdbejax's table (traces it with JAX); not timed below
    setup = time.perf_counter() - started
    result = _train_each(train_agent, covered(paper_settings()), args.mushroom_seeds, 11,
                         args.episodes, env=env)
    return {**result, "setup": setup}


def _worker_python(args) -> dict:
    from benchmarks.python_loop import train_agent
    from vdbejax.methods.agents import paper_settings

    return _train_each(train_agent, paper_settings(), args.python_seeds, 7, args.episodes)


WORKERS = {"vdbejax": _worker_vdbejax, "numba": _worker_numba,
           "numba_parallel": _worker_numba_parallel, "mushroom": _worker_mushroom,
           "python": _worker_python}


def _mushroom_version() -> str | None:
    """The installed mushroom-rl's version (without importing it: it imports torch)."""
    from importlib import metadata

    try:
        return metadata.version("mushroom-rl")
    except metadata.PackageNotFoundError:
        return None


def _median_run(runs: list[dict]) -> dict:
    """The run of median wall time (the lower middle one of an even count), with every
    run's wall in ``walls``."""
    ordered = sorted(runs, key=lambda r: r["wall"])
    return {**ordered[(len(ordered) - 1) // 2], "walls": [r["wall"] for r in runs]}


def pythonpath_env(root: Path, env_extra: dict | None = None) -> dict:
    """This process's environment (with ``env_extra``) with ``root`` first on PYTHONPATH,
    so that a subprocess imports ``root``'s vdbejax and benchmarks."""
    env = dict(os.environ, **(env_extra or {}))
    env["PYTHONPATH"] = os.pathsep.join(
        [str(root)] + ([env["PYTHONPATH"]] if env.get("PYTHONPATH") else [])
    )
    return env


def _spawn(kind: str, args, env_extra: dict | None = None, root: Path = ROOT,
           **overrides) -> dict:
    """One worker of ``root``'s harness (another checkout's, for before-and-after runs) in
    a fresh process: its result and meta."""
    out = Path(args.tmp) / f"{kind}-{time.time_ns()}.npz"
    cmd = [
        sys.executable, "-m", "benchmarks.compare", "--worker", kind, "--worker-out", str(out),
        "--episodes", str(overrides.get("episodes", args.episodes)),
        "--seeds", str(args.seeds), "--python-seeds", str(args.python_seeds),
        "--mushroom-seeds", str(args.mushroom_seeds), "--threads", str(args.threads),
        "--jax-cache", args.jax_cache, "--mdp-factory", args.mdp_factory,
        "--agents", str(overrides.get("agents", 0)),
        "--strategy", overrides.get("strategy", args.strategy),
    ]
    subprocess.run(cmd, check=True, env=pythonpath_env(root, env_extra), cwd=root)
    data = dict(np.load(out, allow_pickle=False))
    meta = json.loads(str(data.pop("meta")))
    meta.update(data)
    return meta


# --------------------------------------------------------------------------- checks
def _bootstrap_agree(a: np.ndarray, b: np.ndarray, rng, *, tol: float, level: float = 0.999):
    """Difference of the mean of two groups of agents and a bootstrap test of equality.

    Under the null hypothesis (both peers learn alike) the agents are exchangeable, so
    both groups are resampled from the pooled agents; this stays valid when one group is
    small (the Python peer runs few seeds). Returns ``(diff, lo, hi, agree)`` where
    ``[lo, hi]`` is the ``level`` acceptance interval of the difference under the null.
    """
    diff = a.mean() - b.mean()
    pooled = np.concatenate([a, b])
    ia = rng.integers(0, len(pooled), size=(4000, len(a)))
    ib = rng.integers(0, len(pooled), size=(4000, len(b)))
    boot = pooled[ia].mean(1) - pooled[ib].mean(1)
    lo, hi = np.quantile(boot, [(1 - level) / 2, 1 - (1 - level) / 2])
    return diff, lo, hi, bool((lo <= diff <= hi) or abs(diff) <= tol)


def agreement(peer: np.ndarray, reference: np.ndarray, settings, *, tol: float = 0.02):
    """Per setting: do the peer's agents learn like vdbejax's? (first 300, last 100 eps)."""
    rng = np.random.default_rng(0)
    n = len(settings)
    peer = peer.reshape(n, -1, peer.shape[-1])
    reference = reference.reshape(n, -1, reference.shape[-1])
    rows = []
    for i, setting in enumerate(settings):
        row = {"setting": setting.label}
        for window, sl in (("early", slice(0, 300)), ("final", slice(-100, None))):
            row[window] = _bootstrap_agree(
                peer[i][:, sl].mean(1), reference[i][:, sl].mean(1), rng, tol=tol
            )
        rows.append(row)
    return rows


# --------------------------------------------------------------------------- report
def _machine() -> list[str]:
    import jax
    import numba

    cpu = "unknown"
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    mem = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES") / 2**30
    mushroom = _mushroom_version()
    return [
        f"- Machine: {platform.platform()}; CPU: {cpu}; {os.cpu_count()} logical cores; "
        f"{mem:.1f} GiB RAM; no GPU (JAX CPU backend).",
        f"- Versions: Python {platform.python_version()}, jax {jax.__version__}, "
        f"numba {numba.__version__}, numpy {np.__version__}, "
        f"mushroom-rl {mushroom or 'not installed'}.",
        f"- Date: {datetime.datetime.now(datetime.UTC):%Y-%m-%d %H:%M UTC}.",
        f"- Commit: {_commit()}.",
    ]


def _commit() -> str:
    """The repository's commit (short hash), with a note when the work tree differs."""
    try:
        head = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, check=True,
                              capture_output=True, text=True).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"],
                               cwd=ROOT, check=True, capture_output=True, text=True).stdout
    except (OSError, subprocess.CalledProcessError):
        return "unknown (not a git checkout)"
    return f"`{head}`" + (" with uncommitted changes" if dirty.strip() else "")


def _fmt_row(name, r, ref=None, note="", *, threads="1", agree=""):
    sps = r["steps"] / r["wall"]
    cells = [name, str(threads), f"{r['wall']:.2f}", f"{r['compile']:.2f}",
             f"{r['wall'] - r['compile']:.2f}", f"{sps / 1e6:.2f}", f"{r['peak_rss_mb']:.0f}",
             agree or "–"]
    if ref is not None:
        x = ref["wall"] / r["wall"]
        cells.append(f"{x:.2f}×" if x >= 0.01 else f"{x:.2g}×")
    return "| " + " | ".join(cells) + f" | {note} |"


def _seeds(n: int) -> str:
    return f"{n} seed" + ("" if n == 1 else "s")


def _extrapolate(measured: dict, grid_steps: int) -> tuple[dict, float]:
    """A peer's full-grid run estimated from its measured agents: time per real step."""
    per_step = measured["wall"] / measured["steps"]
    return dict(measured, wall=per_step * grid_steps, steps=grid_steps), per_step


def _covered_rows(returns: np.ndarray, settings, subset) -> np.ndarray:
    """The rows of a config-major grid's returns that belong to the settings ``subset``."""
    per = returns.reshape(len(settings), -1, returns.shape[-1])
    index = [settings.index(s) for s in subset]
    return per[index].reshape(-1, returns.shape[-1])


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    p.add_argument("--out", default=str(ROOT / "benchmarks" / "RESULTS.md"))
    p.add_argument("--episodes", type=int, default=1000)
    p.add_argument("--seeds", type=int, default=20)
    p.add_argument("--python-seeds", type=int, default=4,
                   help="seeds per setting for the pure-Python peer (time extrapolated)")
    p.add_argument("--skip-python", action="store_true")
    p.add_argument("--mushroom-seeds", type=int, default=4,
                   help="seeds per covered setting for the MushroomRL peer (time extrapolated)")
    p.add_argument("--skip-mushroom", action="store_true")
    p.add_argument("--skip-numba-parallel", action="store_true")
    p.add_argument("--threads", type=int, default=0,
                   help="threads of vdbejax and of the multi-threaded Numba peer "
                        "(default: the CPUs this process may use)")
    p.add_argument("--scaling", default="1,10,100,1000,10000,100000",
                   help="agent counts of the scaling benchmark ('' to skip)")
    p.add_argument("--scaling-episodes", type=int, default=20)
    p.add_argument("--mdp-factory", default=DEFAULT_FACTORY,
                   help="module:function returning the TabularMDP (vdbejax runs)")
    p.add_argument("--strategy", default="auto", choices=["auto", "sequential", "lockstep"],
                   help="vdbejax engine strategy of the main rows (the lockstep strategy "
                        "also gets a row of its own unless --skip-lockstep)")
    p.add_argument("--skip-lockstep", action="store_true")
    p.add_argument("--warm-runs", type=int, default=3,
                   help="warm runs of vdbejax and the Numba peers, interleaved; each peer's "
                        "median is reported (default 3)")
    p.add_argument("--tmp", default=None)
    p.add_argument("--jax-cache", default=None)
    p.add_argument("--worker", choices=sorted(WORKERS), help=argparse.SUPPRESS)
    p.add_argument("--worker-out", help=argparse.SUPPRESS)
    p.add_argument("--agents", type=int, default=0, help=argparse.SUPPRESS)
    args = p.parse_args(argv)
    if args.warm_runs < 1:
        p.error(f"--warm-runs={args.warm_runs} is invalid: must be >= 1")
    bad = [c for c in args.scaling.split(",") if c.strip() and not (c.strip().isdigit() and int(c) >= 1)]
    if bad:
        p.error(f"--scaling={args.scaling!r} is invalid: must be agent counts >= 1, comma-separated")
    if args.threads < 1:
        from vdbejax.engine import available_cpus

        args.threads = available_cpus()

    if args.worker:
        res = WORKERS[args.worker](args)
        returns = res.pop("returns")
        np.savez(args.worker_out, returns=returns, meta=json.dumps(res))
        return 0

    from vdbejax.methods.agents import paper_settings

    command = "python -m benchmarks.compare " + " ".join(argv if argv is not None else sys.argv[1:])
    tmp = Path(args.tmp or tempfile.mkdtemp(prefix="vdbejax-bench-"))
    args.tmp = str(tmp)
    args.jax_cache = args.jax_cache or str(tmp / "jax-cache")
    numba_cache = tmp / "numba-cache"
    numba_par_cache = tmp / "numba-parallel-cache"  # its own: a cold run compiles everything
    for folder in (args.jax_cache, numba_cache, numba_par_cache):
        shutil.rmtree(folder, ignore_errors=True)
    load_before = os.getloadavg()
    settings = paper_settings()
    threads = args.threads
    nenv = {"NUMBA_CACHE_DIR": str(numba_cache)}
    penv = {"NUMBA_CACHE_DIR": str(numba_par_cache), "NUMBA_NUM_THREADS": str(threads)}
    par_name = f"numba-{threads}t"
    mushroom_skipped = None
    if not args.skip_mushroom and _mushroom_version() is None:
        mushroom_skipped = "mushroom-rl is not installed (`pip install -e .[benchmarks]`)"
    elif args.skip_mushroom:
        mushroom_skipped = "--skip-mushroom"

    print("numba-1t (cold cache) ...", flush=True)
    numba_cold = _spawn("numba", args, nenv)
    print("vdbejax (cold cache) ...", flush=True)
    jax_cold = _spawn("vdbejax", args)
    par_cold = None
    if not args.skip_numba_parallel:
        print(f"{par_name} (cold cache) ...", flush=True)
        par_cold = _spawn("numba_parallel", args, penv)
    # Warm runs: rounds of one fresh process per peer, interleaved so that a change in
    # the machine's load falls on every peer alike; each peer's median run is reported.
    warm: dict[str, list[dict]] = {"numba": [], "vdbejax": [], "numba_parallel": []}
    for round_ in range(args.warm_runs):
        print(f"warm caches, round {round_ + 1} of {args.warm_runs}: numba-1t, vdbejax"
              + ("" if args.skip_numba_parallel else f", {par_name}") + " ...", flush=True)
        warm["numba"].append(_spawn("numba", args, nenv))
        warm["vdbejax"].append(_spawn("vdbejax", args))
        if not args.skip_numba_parallel:
            warm["numba_parallel"].append(_spawn("numba_parallel", args, penv))
    numba_warm, jax_warm = _median_run(warm["numba"]), _median_run(warm["vdbejax"])
    par_warm = _median_run(warm["numba_parallel"]) if warm["numba_parallel"] else None
    lockstep = None
    if not args.skip_lockstep and jax_warm["strategy"] != "lockstep":
        print("vdbejax lockstep strategy (cold, then warm cache) ...", flush=True)
        _spawn("vdbejax", args, strategy="lockstep")
        lockstep = _spawn("vdbejax", args, strategy="lockstep")
    mushroom = None
    if mushroom_skipped is None:
        print("mushroom ...", flush=True)
        mushroom = _spawn("mushroom", args)
    python = None
    if not args.skip_python:
        print("python ...", flush=True)
        python = _spawn("python", args)
    load_after = os.getloadavg()

    from benchmarks.mushroom_loop import covered

    mushroom_settings = covered(settings)
    steps = jax_warm["steps"]
    strategy = jax_warm["strategy"]
    jax_threads = str(threads) if strategy == "sequential" else "XLA"

    # agreement (computed first: the side-by-side table has a column for it)
    reference = jax_warm["returns"]
    checks = [("numba-1t", numba_warm["returns"], settings, reference)]
    par_identical = None
    if par_warm is not None:
        par_identical = bool(np.array_equal(par_warm["returns"], numba_warm["returns"]))
        if not par_identical:  # else its verdicts are numba-1t's, bit for bit
            checks.append((par_name, par_warm["returns"], settings, reference))
    if mushroom is not None:
        checks.append(("mushroom", mushroom["returns"], mushroom_settings,
                       _covered_rows(reference, settings, mushroom_settings)))
    if python is not None:
        checks.append(("python", python["returns"], settings, reference))
    tables, summary = {}, {}
    for n, r, subset, ref in checks:
        rows_ = agreement(r, ref, subset)
        tables[n] = {row["setting"]: row for row in rows_}
        ok = sum(row["early"][3] and row["final"][3] for row in rows_)
        summary[n] = f"{ok}/{len(subset)}"
    if par_identical:
        summary[par_name] = summary["numba-1t"] + " (= numba-1t, bit-identical)"

    lines = ["# Benchmarks: vdbejax against Numba (1 and N threads), MushroomRL and a pure-Python "
             "per-agent loop", ""]
    header = [*_machine(),
              f"- Command: `{command}` (from the repository root, in the project venv)."]
    lines += header
    lines += [
        f"- Load average (1/5/15 min) before: {load_before[0]:.1f}/{load_before[1]:.1f}/"
        f"{load_before[2]:.1f}, after: {load_after[0]:.1f}/{load_after[1]:.1f}/"
        f"{load_after[2]:.1f}. The machine is shared; a load above the core count inflates "
        "every wall time (all peers ran in the same run, one after another).",
        "- Threads: vdbejax's sequential strategy"
        + (f" and `{par_name}`" if par_warm is not None else "")
        + f" ran on {threads} threads (`--threads`; default: the CPUs the process may use); "
        "`numba-1t`, MushroomRL and pure Python are single-threaded.",
        "",
        f"## Full paper grid: {len(settings)} settings × {args.seeds} seeds × "
        f"{args.episodes} episodes",
        "",
        "Each peer ran in its own fresh subprocess; the warm rows of vdbejax and the Numba "
        f"peers are each the median of {args.warm_runs} runs, interleaved (rounds of one run "
        "per peer, so a change in the machine's load falls on all of them). "
        "*Wall* = end to end (building the task "
        "and agents, compiling, running, results on the host; interpreter start and imports "
        "excluded); *compile* = Numba's first call (compiling or loading its cache) / "
        "vdbejax's time to get its programs (tracing and lowering them, then compiling them or "
        "reading them from JAX's persistent cache, `vdbejax/engine/programs.py`); "
        "*steps/s* = real environment steps (Σ `lengths`) / wall; *peak RSS* = the "
        "subprocess's maximum resident memory (interpreter and libraries included); "
        "*curves agree* = settings whose learning curves agree with vdbejax's (next "
        "section); *vdbejax (warm) / peer* = vdbejax's warm wall time over the peer's (> 1: "
        "vdbejax is slower).",
        "",
        "The peers: `numba-1t` runs the agents one after another in one `@njit` loop; "
        f"`{par_name}` runs the same per-agent `@njit` function under `prange` "
        f"(`parallel=True`, {threads} threads, each agent with its own tables and its own "
        "random stream seeded by its seed, so its returns are those of `numba-1t` for any "
        "thread count); `mushroom` is MushroomRL's `QLearning` / `SARSA` with `EpsGreedy` / "
        "`Boltzmann` (β = 1/τ) trained through its `Core` on the task as a `FiniteMDP` "
        "(`benchmarks/mushroom_loop.py`); `python` is a plain per-agent loop.",
        "",
        "| peer | threads | wall s | compile s | run s | M steps/s | peak RSS MB | curves agree "
        "| vdbejax (warm) / peer, wall | note |",
        "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |",
    ]

    def programs(r: dict) -> str:
        return f"programs: {r.get('programs', 0)} traced and lowered"

    def same(r: dict, ref: dict) -> str:
        return ("bit-identical to warm" if np.array_equal(r["returns"], ref["returns"])
                else "returns differ from warm!")

    def walls(r: dict) -> str:
        runs = r.get("walls", [])
        return (f"median of {len(runs)} warm runs ({', '.join(f'{w:.2f}' for w in runs)} s)"
                if len(runs) > 1 else "")

    rows = [(f"vdbejax {strategy} (warm JAX cache)", jax_warm,
             "; ".join(filter(None, [programs(jax_warm), walls(jax_warm)])),
             jax_threads, "reference"),
            (f"vdbejax {strategy} (cold JAX cache)", jax_cold, programs(jax_cold),
             jax_threads, same(jax_cold, jax_warm))]
    if lockstep is not None:
        rows.append(("vdbejax lockstep (warm JAX cache)", lockstep,
                     "vectorised strategy (accelerators); " + programs(lockstep), "XLA",
                     "bit-identical" if np.array_equal(lockstep["returns"], reference)
                     else "returns differ!"))
    if par_warm is not None:
        rows += [(f"{par_name} (warm cache=True)", par_warm,
                  "; ".join(filter(None, [f"threading layer {par_warm.get('threading_layer')}",
                                          walls(par_warm)])), str(threads),
                  summary[par_name]),
                 (f"{par_name} (cold)", par_cold, "", str(threads), same(par_cold, par_warm))]
    rows += [("numba-1t (warm cache=True)", numba_warm, walls(numba_warm), "1",
              summary["numba-1t"]),
             ("numba-1t (cold)", numba_cold, "", "1", same(numba_cold, numba_warm))]
    # the candidates for "fastest peer on the same cores": warm / extrapolated full grids
    candidates = [("numba-1t (warm)", numba_warm)]
    if par_warm is not None:
        candidates.append((f"{par_name} (warm)", par_warm))
    if mushroom is not None:
        agents = len(mushroom_settings) * args.mushroom_seeds
        m_extra, m_step = _extrapolate(mushroom, steps)
        covered_steps = int(_covered_rows(np.asarray(jax_warm["agent_steps"])[:, None],
                                          settings, mushroom_settings).sum())
        rows.append((f"mushroom ({agents} agents measured)", mushroom,
                     f"{len(mushroom_settings)} ε-greedy / softmax settings × "
                     f"{_seeds(args.mushroom_seeds)}, {mushroom['steps']:,} steps; task built "
                     f"in {mushroom['setup']:.2f} s before the clock started", "1",
                     f"{summary['mushroom']} (covered settings)"))
        rows.append(("mushroom (extrapolated to the grid)", m_extra,
                     f"{m_step * 1e6:.2f} µs/step × {steps:,} steps", "1", ""))
        candidates.append(("mushroom (extrapolated)", m_extra))
    if python is not None:
        agents = len(settings) * args.python_seeds
        extrapolated, per_step = _extrapolate(python, steps)
        rows.append((f"python ({agents} agents measured)", python,
                     f"{python['steps']:,} steps", "1", summary["python"]))
        rows.append(("python (extrapolated to the grid)", extrapolated,
                     f"{per_step * 1e6:.2f} µs/step × {steps:,} steps", "1", ""))
        candidates.append(("python (extrapolated)", extrapolated))
    for name, r, note, th, agree in rows:
        lines.append(_fmt_row(name, r, jax_warm, note, threads=th, agree=agree))
    if mushroom is not None:
        lines += ["", f"MushroomRL (`mushroom`) measured: {len(mushroom_settings)} of the "
                  f"{len(settings)} settings (both learners × ε-greedy and softmax; MushroomRL "
                  f"has no VDBE / VDBE-Softmax) × {_seeds(args.mushroom_seeds)} × "
                  f"{args.episodes} episodes = {mushroom['steps']:,} real steps in "
                  f"{mushroom['wall']:.2f} s of training (building the `FiniteMDP` from "
                  "vdbejax's table excluded; imports excluded; peak RSS includes torch, which "
                  "`mushroom_rl.core` imports, and JAX, which vdbejax's settings import). "
                  f"Extrapolated: {m_step * 1e6:.2f} µs per real step × the {steps:,} real "
                  "steps of vdbejax's full grid (all 46 settings: the VDBE settings' steps "
                  "costed at the ε-greedy / softmax rate)"
                  + (f"; the covered settings alone: {m_step * covered_steps:.1f} s for "
                     f"vdbejax's {covered_steps:,} steps there" if covered_steps else "")
                  + "."]
    elif mushroom_skipped:
        lines += ["", f"MushroomRL peer not run: {mushroom_skipped}."]
    # ratios
    lines += ["", "Ratios (peer wall / vdbejax wall; > 1 means vdbejax is faster):", ""]

    def ratio(a, b):
        return b["wall"] / a["wall"]

    fastest_name, fastest = min(candidates, key=lambda c: c[1]["wall"])
    lines.append(f"- **fastest peer on the same cores** ({threads} CPUs; peers' warm or "
                 f"extrapolated full-grid wall): {fastest_name}, {fastest['wall']:.2f} s; "
                 f"{fastest_name.split(' ')[0]} / vdbejax (warm) = "
                 f"**{ratio(jax_warm, fastest):.2f}×**")
    if par_warm is not None:
        lines.append(f"- warm vs warm: {par_name} / vdbejax = **{ratio(jax_warm, par_warm):.2f}×** "
                     f"(both on {threads} threads); run time only (compile excluded): "
                     f"{(par_warm['wall'] - par_warm['compile']) / (jax_warm['wall'] - jax_warm['compile']):.2f}×; "
                     f"cold vs cold: {ratio(jax_cold, par_cold):.2f}×; {par_name} speed-up over "
                     f"numba-1t (run time): "
                     f"{(numba_warm['wall'] - numba_warm['compile']) / (par_warm['wall'] - par_warm['compile']):.2f}×")
    lines.append(f"- warm vs warm: numba-1t / vdbejax = **{ratio(jax_warm, numba_warm):.2f}×** "
                 f"(target ≥ 2); run time only (compile excluded): "
                 f"{(numba_warm['wall'] - numba_warm['compile']) / (jax_warm['wall'] - jax_warm['compile']):.2f}×")
    lines.append(f"- cold vs cold: numba-1t / vdbejax = {ratio(jax_cold, numba_cold):.2f}×")
    if mushroom is not None:
        lines.append(f"- MushroomRL (extrapolated) / vdbejax (warm) = "
                     f"**{ratio(jax_warm, m_extra):.1f}×**")
    if python is not None:
        lines.append(f"- Python (extrapolated) / vdbejax (warm) = **{ratio(jax_warm, extrapolated):.1f}×** "
                     "(target ≥ 100)")
    if strategy == "sequential":
        from vdbejax.engine import work_items

        lines.append(f"- vdbejax sequential: {jax_warm['iterations']:,} agent iterations for "
                     f"{steps:,} real steps (one per step, plus one per episode start after a "
                     f"truncation), {jax_warm['lane_iterations']:,} lane iterations of its "
                     f"{work_items.LANES}-lane loops (lane efficiency "
                     f"{jax_warm['iterations'] / max(jax_warm['lane_iterations'], 1):.1%}); "
                     f"step loops compiled natively: {jax_warm['native']}.")
    if lockstep is not None:
        same_ = np.array_equal(lockstep["returns"], jax_warm["returns"])
        lines.append(f"- Returns of the lockstep and the {strategy} strategy bit-identical: "
                     f"{same_}.")
    if par_warm is not None:
        lines.append(f"- Returns of {par_name} and numba-1t bit-identical: {par_identical}.")
    for name, r in [("lockstep", jax_warm if strategy == "lockstep" else lockstep)]:
        if r is not None:
            lines.append(
                f"- vdbejax {name}: {r['iterations']:,} iterations, {r['lane_iterations']:,} "
                f"agent-lane iterations for {steps:,} real steps (lane efficiency "
                f"{steps / max(r['lane_iterations'], 1):.0%}).")

    # agreement: the verdicts here, the per-setting differences on a page of their own
    out_path = Path(args.out)
    agreement_path = out_path.with_name(AGREEMENT)
    check = ("Per setting, the mean over agents of the return averaged over episodes 1–300 "
             "(*early*, learning speed) and 901–1000 (*final*); a peer agrees when the "
             "difference to vdbejax lies in the 99.9 % acceptance interval of a bootstrap "
             "test of equal means (agents of both resampled from the pooled agents; valid "
             "for the Python and MushroomRL peers' few seeds) or |difference| ≤ 0.02. "
             "Different random streams, so only distributions can agree; with 46 settings × "
             "2 windows a few rejections at 99.9 % would still be chance only rarely. "
             "MushroomRL is checked on the 22 settings it covers (– elsewhere).")
    lines += ["", "## Do the peers learn the same? (statistical check)", "",
              f"The check and each setting's differences: [`{AGREEMENT}`]({AGREEMENT}).", ""]
    for n, _, subset, _ in checks:
        lines.append(f"- {n}: {summary[n]} settings agree on both windows"
                     + (" (the ε-greedy and softmax settings)" if n == "mushroom" else "") + ".")
    if par_identical:
        lines.append(f"- {par_name}: returns bit-identical to numba-1t's, so the same "
                     f"{summary['numba-1t']}.")
    names = [n for n, *_ in checks]
    detail = ["| setting | " + " | ".join(f"{n} early Δ | {n} final Δ" for n in names) + " |",
              "| --- |" + " --- | --- |" * len(names)]
    for setting in settings:
        cells = []
        for n in names:
            row = tables[n].get(setting.label)
            for w in ("early", "final"):
                if row is None:
                    cells.append("–")
                    continue
                d, lo, hi, good = row[w]
                cells.append(f"{d:+.3f} [{lo:+.3f}, {hi:+.3f}]{'' if good else ' ✗'}")
        detail.append(f"| {setting.label} | " + " | ".join(cells) + " |")
    agreement_path.write_text("\n".join([
        "# Do the peers learn the same? Per-setting differences", "", *header, "", check, "",
        "Each cell: peer − vdbejax, then the 99.9 % acceptance interval under equal means"
        " (✗: outside it and |difference| > 0.02).", "", *detail]) + "\n")

    # scaling
    counts = [int(c) for c in args.scaling.split(",") if c.strip()]
    if counts:
        lines += ["", f"## Scaling: agents 1 → {counts[-1]:,} ({args.scaling_episodes} episodes "
                  f"each, task `{args.mdp_factory}`)", "",
                  "Agent *i* runs paper setting *i* mod 46 with its own key. Fresh subprocess "
                  "per count; *wall* = first run (compiles, JAX cache warm where the shape was "
                  "compiled before), *run s* = a second identical run in the same process "
                  "sharing the first run's programs (`EngineOptions(programs=...)`: traced and "
                  "compiled once); throughput = real steps / run s.", "",
                  "| agents | wall s | compile s | run s | real steps | M steps/s (run) | "
                  "lane efficiency | peak RSS MB | RSS after import MB |",
                  "| --- | --- | --- | --- | --- | --- | --- | --- | --- |"]
        scale_rows = []
        for n in counts:
            print(f"scaling: {n} agents ...", flush=True)
            try:
                r = _spawn("vdbejax", args, agents=n, episodes=args.scaling_episodes)
            except subprocess.CalledProcessError as err:  # e.g. out of memory
                lines.append(f"| {n:,} | failed ({err.returncode}) | | | | | | | |")
                break
            run = r["steady"]
            scale_rows.append((n, r["steps"] / run, r["peak_rss_mb"]))
            lines.append(
                f"| {n:,} | {r['wall']:.2f} | {r['compile']:.2f} | {run:.2f} | {r['steps']:,} | "
                f"{r['steps'] / run / 1e6:.2f} | {r['steps'] / max(r['lane_iterations'], 1):.0%} | "
                f"{r['peak_rss_mb']:.0f} | {r['rss_after_import_mb']:.0f} |")
        if scale_rows:
            png = Path(args.out).with_name("scaling.png")
            _plot_scaling(scale_rows, png)
            lines += ["", f"![throughput and memory against agents]({png.name})"]
    analysis = ""
    if out_path.exists() and ANALYSIS_HEADING in out_path.read_text():
        text = out_path.read_text()
        analysis = "\n" + text[text.index(ANALYSIS_HEADING):]  # hand-written, kept
    out_path.write_text("\n".join(lines) + "\n" + analysis)
    print("\n".join(lines))
    return 0


def _plot_scaling(rows, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    n, sps, rss = (np.array(x) for x in zip(*rows))
    fig, (a, b) = plt.subplots(1, 2, figsize=(10, 4))
    a.loglog(n, sps, "o-")
    a.set_xlabel("agents")
    a.set_ylabel("real agent-steps / s (compile excluded)")
    a.set_title("throughput")
    a.grid(True, which="both", alpha=0.3)
    b.loglog(n, rss, "o-", color="C1")
    b.set_xlabel("agents")
    b.set_ylabel("peak RSS (MB)")
    b.set_title("memory")
    b.grid(True, which="both", alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=120)


if __name__ == "__main__":
    sys.exit(main())
