"""The ``auto`` strategy's rule on a CPU, measured: sequential, lockstep and auto side by side.

    python -m benchmarks.auto_rule [--seeds 20,200,1000] [--episodes 50] [--repeats 2]
                                   [--threads N] [--json]

For each size of the paper grid (``--seeds`` agents per setting, 46 settings), the three
strategies run one after another in this process, each once to get its programs, then
``--repeats`` timed calls (best kept; ``benchmarks.lockstep.timed_grid``). It prints
agent-steps/s of each, lockstep / sequential, and auto / the better of the two: the data
:func:`vdbejax.engine.auto_strategy`'s CPU rule was set from (``benchmarks/RESULTS.md``).
"""
from __future__ import annotations

import argparse
import json
import sys
from typing import Any

from benchmarks.lockstep import timed_grid


def measure(seeds: list[int], episodes: int, repeats: int,
            threads: int | None) -> list[dict[str, Any]]:
    """One row per size: each strategy's agent-steps/s and the ratios."""
    rows = []
    for count in seeds:
        runs = {strategy: timed_grid(strategy, count, episodes, repeats, threads)
                for strategy in ("sequential", "lockstep", "auto")}
        rates = {name: run["agent_steps_per_s"] for name, run in runs.items()}
        better = max(rates["sequential"], rates["lockstep"])
        rows.append({"seeds": count, "agents": runs["auto"]["agents"], "episodes": episodes,
                     **{f"{name}_agent_steps_per_s": rate for name, rate in rates.items()},
                     "lockstep_over_sequential": round(rates["lockstep"] / rates["sequential"], 3),
                     "auto_over_better": round(rates["auto"] / better, 3)})
    return rows


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seeds", default="20,200,1000",
                        help="agents per setting, comma-separated sizes")
    parser.add_argument("--episodes", type=int, default=50)
    parser.add_argument("--repeats", type=int, default=2, help="timed calls (best kept)")
    parser.add_argument("--threads", type=int, default=None,
                        help="worker threads (default: the CPUs)")
    parser.add_argument("--json", action="store_true", help="one JSON object")
    args = parser.parse_args(argv)
    try:
        seeds = [int(part) for part in args.seeds.split(",")]
    except ValueError:
        parser.exit(2, f"--seeds must be comma-separated integers, got {args.seeds!r}\n")
    for name, value in (("seeds", min(seeds)), ("episodes", args.episodes),
                        ("repeats", args.repeats)):
        if value < 1:
            parser.exit(2, f"--{name} must be at least 1, got {value}\n")

    import vdbejax  # noqa: F401  (its XLA setting before JAX starts)
    rows = measure(seeds, args.episodes, args.repeats, args.threads)
    if args.json:
        print(json.dumps({"rows": rows}))
        return 0
    print(f"paper grid, {args.episodes} episodes; M agent-steps/s")
    print(f"{'agents':>8} {'sequential':>11} {'lockstep':>9} {'auto':>7} "
          f"{'lock/seq':>9} {'auto/better':>12}")
    for row in rows:
        print(f"{row['agents']:>8,} {row['sequential_agent_steps_per_s'] / 1e6:>11.2f} "
              f"{row['lockstep_agent_steps_per_s'] / 1e6:>9.2f} "
              f"{row['auto_agent_steps_per_s'] / 1e6:>7.2f} "
              f"{row['lockstep_over_sequential']:>8.2f}× {row['auto_over_better']:>11.2f}×")
    return 0


if __name__ == "__main__":
    sys.exit(main())
