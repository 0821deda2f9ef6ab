"""Where a warm run of the paper grid spends its time, phase by phase.

Each measurement runs in a fresh subprocess with JAX's persistent cache warm (a first
process fills it), as ``benchmarks.compare``'s warm vdbejax row does:

* **first call**: building the task and the agents, then ``run_agents``, split into
  tracing, lowering, stripping and keying, getting the compiled programs (JAX's cache),
  and the rest (the run itself);
* **run alone**: the same call again in that process, sharing its programs, best of 3,
  with one program for every kind (the default) and with one program per kind.

    python -m benchmarks.warm_phases [--threads 2] [--cache DIR]
"""
from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile

CHILD = r"""
import functools, json, sys, time
import jax
jax.config.update("jax_compilation_cache_dir", sys.argv[1])
jax.config.update("jax_persistent_cache_min_compile_time_secs", 0)
jax.config.update("jax_persistent_cache_min_entry_size_bytes", -1)
from jax._src import stages
from vdbejax import engine
from vdbejax.engine import programs, sequential
from vdbejax.envs.table_cleaning import make_mdp
from vdbejax.runs import grid_agents
from vdbejax.methods.agents import paper_settings

threads, per_kind = int(sys.argv[2]), sys.argv[3] == "per_kind"
if per_kind:
    sequential.can_switch = lambda kinds: False
phases = {"trace": 0.0, "lower": 0.0, "strip_and_key": 0.0, "programs_from_cache": 0.0}

def lower(call):
    jitted = jax.jit(functools.partial(call.function), static_argnames=tuple(call.static),
                     donate_argnames=call.donate)
    start = time.perf_counter()
    traced = jitted.trace(*call.args, **call.static)
    traced_at = time.perf_counter()
    lowered = traced.lower()
    lowered_at = time.perf_counter()
    programs._strip_locations(lowered)
    phases["trace"] += traced_at - start
    phases["lower"] += lowered_at - traced_at
    phases["strip_and_key"] += time.perf_counter() - lowered_at
    return lowered

def timed(name, function):
    @functools.wraps(function)
    def wrapper(*args, **kwargs):
        start = time.perf_counter()
        try:
            return function(*args, **kwargs)
        finally:
            phases[name] += time.perf_counter() - start
    return wrapper

programs._lower = lower
programs.program_key = timed("strip_and_key", programs.program_key)
stages.Lowered.compile = timed("programs_from_cache", stages.Lowered.compile)
start = time.perf_counter()
mdp = make_mdp()
params, keys = grid_agents(paper_settings(), 20)
setup = time.perf_counter() - start
options = engine.EngineOptions(threads=threads, programs=programs.Programs())
called = time.perf_counter()
engine.run_agents(mdp, params, keys, 1000, options)
first = time.perf_counter() - called
got = engine.compile_seconds()
again = []
for _ in range(3):
    called = time.perf_counter()
    engine.run_agents(mdp, params, keys, 1000, options)
    again.append(time.perf_counter() - called)
print(json.dumps({"setup": setup, "first_call": first, "getting_programs": got, **phases,
                  "run_in_first_call": first - got, "run_alone": min(again)}))
"""


def measure(cache: str, threads: int, mode: str) -> dict:
    done = subprocess.run([sys.executable, "-c", CHILD, cache, str(threads), mode],
                          capture_output=True, text=True, check=True)
    return json.loads(done.stdout.strip().splitlines()[-1])


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--cache", default=None, help="JAX cache folder (default: a new one)")
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory() as folder:
        cache = args.cache or folder
        for mode in ("one_program", "per_kind"):
            measure(cache, args.threads, mode)  # fills the cache: the next one is warm
            row = measure(cache, args.threads, mode)
            print(mode + ": " + ", ".join(f"{name} {seconds:.3f} s"
                                          for name, seconds in row.items()))
    return 0


if __name__ == "__main__":
    sys.exit(main())
