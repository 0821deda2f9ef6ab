"""Issue 21's par line, measured in one sitting: the paper grid's warm vdbejax times beside
the harness's 2-thread Numba peer (``numba-2t``).

    python -m benchmarks.par [--rounds 3] [--calls 4] [--threads 2] [--json-out F]

A first round, not counted, fills JAX's and Numba's caches. Then each round runs, one
after another (run nothing else on the machine meanwhile):

* ``harness``: :mod:`benchmarks.compare`'s vdbejax worker, a fresh process, caches warm;
* ``numba-2t``: :mod:`benchmarks.compare`'s ``numba_parallel`` worker (its wall includes
  loading its compiled loop from Numba's cache, as the harness reports it);
* ``in-process``: :mod:`benchmarks.in_process` in a fresh process, ``run_grid`` called
  ``--calls`` times; calls 2 on are the warm in-process time, split into getting the
  programs (each call traces and lowers them afresh) and the rest (running).

It prints every run and a table of medians with the ratios numba-2t / vdbejax (above 1:
vdbejax is faster; par is 1).
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any

from benchmarks import compare


def _harness(kind: str, args: argparse.Namespace) -> float:
    """Wall seconds of one of :mod:`benchmarks.compare`'s workers."""
    spawn_args = argparse.Namespace(
        tmp=args.tmp, episodes=args.episodes, seeds=args.seeds, python_seeds=1,
        mushroom_seeds=1, threads=args.threads, jax_cache=args.jax_cache,
        mdp_factory=compare.DEFAULT_FACTORY, strategy="auto")
    return float(compare._spawn(kind, spawn_args)["wall"])


def _in_process(args: argparse.Namespace) -> list[dict[str, float]]:
    """Each call's wall and programs seconds, from a fresh :mod:`benchmarks.in_process`."""
    env = dict(os.environ, VDBEJAX_CACHE_DIR=args.jax_cache)
    env["PYTHONPATH"] = os.pathsep.join(
        [str(compare.ROOT)] + ([env["PYTHONPATH"]] if env.get("PYTHONPATH") else []))
    out = subprocess.run(
        [sys.executable, "-m", "benchmarks.in_process", "--calls", str(args.calls),
         "--seeds", str(args.seeds), "--episodes", str(args.episodes),
         "--threads", str(args.threads), "--json"],
        check=True, env=env, cwd=compare.ROOT, capture_output=True, text=True).stdout
    return list(json.loads(out.strip().splitlines()[-1])["calls"])


def measure(args: argparse.Namespace) -> dict[str, Any]:
    """Every round's times (the first, warming round left out)."""
    _harness("vdbejax", args)
    _harness("numba_parallel", args)
    rounds: dict[str, list[float]] = {"harness": [], "numba-2t": [], "in-process": [],
                                      "programs": [], "running": []}
    for r in range(args.rounds):
        rounds["harness"].append(_harness("vdbejax", args))
        rounds["numba-2t"].append(_harness("numba_parallel", args))
        for call in _in_process(args)[1:]:
            rounds["in-process"].append(call["wall"])
            rounds["programs"].append(call["programs"])
            rounds["running"].append(call["wall"] - call["programs"])
        print(f"round {r + 1}: harness {rounds['harness'][-1]:.2f} s, numba-2t "
              f"{rounds['numba-2t'][-1]:.2f} s, in-process "
              + ", ".join(f"{w:.2f}" for w in rounds["in-process"][-(args.calls - 1):])
              + " s", flush=True)
    return rounds


def report(rounds: dict[str, list[float]]) -> str:
    """The table of medians and ratios (markdown)."""
    median = {name: statistics.median(values) for name, values in rounds.items()}
    numba = median["numba-2t"]
    rows = [("harness warm worker (fresh process)", "harness"),
            ("run_grid again in one process (calls 2 on)", "in-process"),
            ("… of which getting the programs", "programs"),
            ("… the rest (running)", "running")]
    lines = ["| vdbejax | median s | numba-2t / vdbejax |", "| --- | --- | --- |"]
    for label, name in rows:
        ratio = f"{numba / median[name]:.2f}×" if name != "programs" else "–"
        lines.append(f"| {label} | {median[name]:.2f} | {ratio} |")
    lines.append(f"| numba-2t (harness worker) | {numba:.2f} | 1.00× |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--calls", type=int, default=4,
                        help="run_grid calls per in-process round (at least 2)")
    parser.add_argument("--seeds", type=int, default=20)
    parser.add_argument("--episodes", type=int, default=1000)
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--jax-cache", default=None,
                        help="JAX's cache directory (default: a new one, warmed first)")
    parser.add_argument("--json-out", default=None, help="also write every time as JSON")
    args = parser.parse_args(argv)
    for name in ("rounds", "seeds", "episodes", "threads"):
        if getattr(args, name) < 1:
            parser.error(f"--{name}={getattr(args, name)} is invalid: must be >= 1")
    if args.calls < 2:
        parser.error(f"--calls={args.calls} is invalid: must be >= 2 (call 1 is not warm)")
    with tempfile.TemporaryDirectory(prefix="vdbejax-par-") as tmp:
        args.tmp = tmp
        args.jax_cache = args.jax_cache or str(Path(tmp) / "jax-cache")
        rounds = measure(args)
    print(report(rounds))
    if args.json_out:
        Path(args.json_out).write_text(json.dumps(rounds, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
